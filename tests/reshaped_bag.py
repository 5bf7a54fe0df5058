"""The bundled Jackal bag rewritten in the shape of issue 11's real outdoor bag (not bundled):
the IMU resampled to 30 Hz and mounted rolled +90 deg and yawed -90 deg, the odometry at
10 Hz, the log cut to start while the robot drives and turns.

The mount is applied with scipy's rotation (URDF roll-pitch-yaw: ``v_base = Rz Ry Rx v_imu``),
independently of the library's own mount code; the bag is written with rosbags. Used by
tests/test_replay_bag_shapes.py. And :func:`rewrite_messages`: a bag copied with one topic's
messages edited (tests/test_terrain_bag.py, tests/test_odometry_motion.py);
:func:`with_static_transforms`: a bag copied with a ``/tf_static`` added (tests/test_bag_tf.py).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["IMU_TOPIC", "MOUNT_RPY", "ODOM_TOPIC", "reshape_jackal_bag", "rewrite_messages",
           "with_static_transforms"]

IMU_TOPIC = "/imu/data"
ODOM_TOPIC = "/odom"
MOUNT_RPY = (1.5708, 0.0, -1.5708)  # the real bag's --imu-mount-rpy, rad
_SOURCE_IMU = "/imu/data"
_SOURCE_ODOM = "/jackal_velocity_controller/odom"


def _stamp(t: float) -> tuple[int, int]:
    sec = int(t)
    nsec = round((t - sec) * 1e9)
    return (sec + 1, nsec - 1_000_000_000) if nsec >= 1_000_000_000 else (sec, nsec)


def reshape_jackal_bag(source: Path, dest: Path, *, cut: float = 10.0, imu_rate: float = 30.0,
                       odom_every: int = 5) -> float:
    """Write ``dest`` (ROS 1 bag) from the Jackal bag ``source``; return its first stamp, s.

    ``cut`` s are dropped from the start; the IMU (gyro and accelerometer) is linearly
    interpolated onto an ``imu_rate`` Hz grid and rotated into the mounted IMU's frame (its
    orientation field marked unknown); every ``odom_every``-th odometry message is kept.
    """
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    imu, odom = [], []
    with Reader(source) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic not in (_SOURCE_IMU, _SOURCE_ODOM):
                continue
            msg = store.deserialize_ros1(raw, conn.msgtype)
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            (imu if conn.topic == _SOURCE_IMU else odom).append((t, msg))
    t_imu = np.array([t for t, _ in imu])
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for _, m in imu])
    accel = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                       m.linear_acceleration.z] for _, m in imu])
    grid = np.arange(t_imu[0] + cut, t_imu[-1], 1.0 / imu_rate)
    to_imu = Rotation.from_euler("xyz", MOUNT_RPY).inv()  # base frame -> IMU frame
    gyro_m = to_imu.apply(np.column_stack([np.interp(grid, t_imu, gyro[:, k]) for k in range(3)]))
    accel_m = to_imu.apply(np.column_stack([np.interp(grid, t_imu, accel[:, k])
                                            for k in range(3)]))
    vec = store.types["geometry_msgs/msg/Vector3"]
    stamp = store.types["builtin_interfaces/msg/Time"]
    template = imu[0][1]
    unknown = np.zeros(9)
    unknown[0] = -1.0  # sensor_msgs/Imu: no orientation estimate
    events = []
    for k, t in enumerate(grid):
        header = dataclasses.replace(template.header, stamp=stamp(*_stamp(float(t))),
                                     frame_id="imu_link")
        events.append((float(t), 0, dataclasses.replace(
            template, header=header, angular_velocity=vec(*gyro_m[k]),
            linear_acceleration=vec(*accel_m[k]), orientation_covariance=unknown)))
    events += [(t, 1, m) for t, m in odom[::odom_every] if t >= grid[0]]
    events.sort(key=lambda e: (e[0], e[1]))
    with Writer(dest) as writer:
        conns = (writer.add_connection(IMU_TOPIC, "sensor_msgs/msg/Imu", typestore=store),
                 writer.add_connection(ODOM_TOPIC, "nav_msgs/msg/Odometry", typestore=store))
        types = ("sensor_msgs/msg/Imu", "nav_msgs/msg/Odometry")
        for t, kind, msg in events:
            writer.write(conns[kind], round(t * 1e9), store.serialize_ros1(msg, types[kind]))
    return float(grid[0])


def rewrite_messages(source: Path, dest: Path, topic: str, edit) -> None:
    """Copy the ROS 1 bag ``source`` to ``dest`` with every ``topic`` message passed through
    ``edit(msg, record_ns) -> record_ns`` (it changes the deserialised message in place and
    returns the record time to write, ns, or None to leave the message out); other topics
    are copied byte for byte."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(source) as reader, Writer(dest) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections}
        for conn, t, raw in reader.messages():
            if conn.topic == topic:
                msg = store.deserialize_ros1(raw, conn.msgtype)
                t = edit(msg, t)
                if t is None:
                    continue
                raw = store.serialize_ros1(msg, conn.msgtype)
            writer.write(conns[conn.id], t, raw)


def with_static_transforms(source: Path, dest: Path,
                           transforms: list[tuple[str, str, tuple[float, float, float, float]]]
                           ) -> None:
    """Copy the ROS 1 bag ``source`` to ``dest`` with one tf2_msgs/TFMessage on ``/tf_static``
    recorded with its first message: ``transforms`` as ``(parent, child, (x, y, z, w))``,
    the child's orientation in the parent (geometry_msgs/Transform's rotation), each
    translated by 0.1 m on x (a mount plate's offset, which the mount does not use)."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)  # has no tf2_msgs: its one-line definition
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                      "tf2_msgs/msg/TFMessage"))
    t = store.types
    with Reader(source) as reader, Writer(dest) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections}
        tf_conn = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store)
        first = True
        for conn, ns, raw in reader.messages():
            if first:
                stamp = t["builtin_interfaces/msg/Time"](ns // 1_000_000_000, ns % 1_000_000_000)
                msg = t["tf2_msgs/msg/TFMessage"]([
                    t["geometry_msgs/msg/TransformStamped"](
                        t["std_msgs/msg/Header"](0, stamp, parent), child,
                        t["geometry_msgs/msg/Transform"](
                            t["geometry_msgs/msg/Vector3"](0.1, 0.0, 0.0),
                            t["geometry_msgs/msg/Quaternion"](*q)))
                    for parent, child, q in transforms])
                writer.write(tf_conn, ns, store.serialize_ros1(msg, "tf2_msgs/msg/TFMessage"))
                first = False
            writer.write(conns[conn.id], ns, raw)
