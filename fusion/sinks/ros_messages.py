"""ROS message content of a fused record (seed 000's topics), as plain dicts any ROS-shaped sink
encodes: nav_msgs/Odometry, tf2_msgs/TFMessage, sensor_msgs/Imu, std_msgs/Float32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fusion.types.fused import FusedOdometry

__all__ = ["Topics", "ros_messages", "stamp_ns"]


@dataclass(frozen=True)
class Topics:
    """Topic names of the ROS-shaped sinks; None leaves a topic out.

    Defaults are seed 000's driver (``/odom``, ``/tf``, ``/wheel_left_speed``,
    ``/wheel_right_speed``) plus ``/imu/data`` (the name of the imu_tools/robot_localization
    convention).
    """

    odom: str | None = "/odom"
    tf: str | None = "/tf"
    imu: str | None = "/imu/data"
    wheel_left: str | None = "/wheel_left_speed"
    wheel_right: str | None = "/wheel_right_speed"

    def __post_init__(self) -> None:
        names = [n for n in self.as_dict().values() if n is not None]
        for name in names:
            if not isinstance(name, str) or not name.startswith("/") or name.endswith("/"):
                raise ValueError(f"topic names must be absolute like '/odom', got {name!r}")
        if len(set(names)) != len(names):
            raise ValueError(f"topic names must be distinct, got {names}")

    def as_dict(self) -> dict[str, str | None]:
        """``{"odom": ..., "tf": ..., "imu": ..., "wheel_left": ..., "wheel_right": ...}``."""
        return {"odom": self.odom, "tf": self.tf, "imu": self.imu,
                "wheel_left": self.wheel_left, "wheel_right": self.wheel_right}


#: ROS message type (ROS 1 spelling ``pkg/Type``) of each :class:`Topics` field.
MESSAGE_TYPES = {
    "odom": "nav_msgs/Odometry",
    "tf": "tf2_msgs/TFMessage",
    "imu": "sensor_msgs/Imu",
    "wheel_left": "std_msgs/Float32",
    "wheel_right": "std_msgs/Float32",
}


def stamp_ns(t: float) -> int:
    """A time in s as integer nanoseconds (rounded); negative times are a ValueError."""
    ns = round(float(t) * 1e9)
    if ns < 0:
        raise ValueError(f"ROS time stamps cannot be negative, got t = {t} s")
    return ns


def _vec3(a: Any) -> dict[str, float]:
    return {"x": float(a[0]), "y": float(a[1]), "z": float(a[2])}


def _quat(q: Any) -> dict[str, float]:
    """``[w, x, y, z]`` -> ROS's field-named quaternion."""
    return {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])}


def ros_messages(
    record: FusedOdometry, topics: Topics | None = None, *, stamp: int | None = None
) -> list[tuple[str, str, str, dict[str, Any]]]:
    """The ROS messages of one record as plain nested dicts, library neutral.

    Returns ``[(key, topic, msgtype, fields), ...]`` in the order odom, tf, imu, wheel_left,
    wheel_right, skipping topics set to None and wheel speeds the record does not have.
    ``key`` is the :class:`Topics` field name, ``msgtype`` the ROS 1 spelling
    (``nav_msgs/Odometry``). Header stamps are integer nanoseconds (:func:`stamp_ns`); each
    backend turns ``stamp`` into its own time type; ``stamp`` (ns, >= 0) replaces the record's
    ``t`` in the headers (a live sink's wall-clock time). Arrays (covariances) are float lists.
    """
    topics = topics or Topics()
    if stamp is not None and not (isinstance(stamp, int) and stamp >= 0):
        raise ValueError(f"stamp must be a non-negative integer of ns, got {stamp!r}")
    ns = stamp_ns(record.t) if stamp is None else stamp
    yaw_q = _quat(record.yaw_quaternion)
    position = {"x": record.x, "y": record.y, "z": 0.0}
    out: list[tuple[str, str, str, dict[str, Any]]] = []
    if topics.odom:
        out.append(("odom", topics.odom, MESSAGE_TYPES["odom"], {
            "header": {"stamp": ns, "frame_id": record.frame_id},
            "child_frame_id": record.child_frame_id,
            "pose": {"pose": {"position": position, "orientation": yaw_q},
                     "covariance": record.pose_covariance.reshape(36).tolist()},
            "twist": {"twist": {"linear": {"x": record.v, "y": 0.0, "z": 0.0},
                                "angular": _vec3(record.angular_velocity)},
                      "covariance": record.twist_covariance.reshape(36).tolist()},
        }))
    if topics.tf:
        out.append(("tf", topics.tf, MESSAGE_TYPES["tf"], {"transforms": [{
            "header": {"stamp": ns, "frame_id": record.frame_id},
            "child_frame_id": record.child_frame_id,
            "transform": {"translation": position, "rotation": yaw_q},
        }]}))
    has_q = record.orientation is not None
    has_a = record.linear_acceleration is not None
    # no IMU sample behind the record (wheels only, or none yet): no sensor_msgs/Imu, whose
    # angular_velocity would be the wheels' yaw rate passed off as a gyro's (an independent
    # probe's --imu none run published 0.4 rad/s on /imu/data)
    if topics.imu and (has_q or has_a):
        unknown = [-1.0] + [0.0] * 8  # sensor_msgs/Imu: element 0 = -1 means "not provided"
        out.append(("imu", topics.imu, MESSAGE_TYPES["imu"], {
            "header": {"stamp": ns, "frame_id": record.imu_frame_id},
            "orientation": _quat(record.orientation if has_q else [0.0, 0.0, 0.0, 0.0]),
            "orientation_covariance": [0.0] * 9 if has_q else unknown,
            "angular_velocity": _vec3(record.angular_velocity),
            "angular_velocity_covariance": [0.0] * 9,
            "linear_acceleration": _vec3(
                record.linear_acceleration if has_a else [0.0, 0.0, 0.0]),
            "linear_acceleration_covariance": [0.0] * 9 if has_a else unknown,
        }))
    for key, speed in (("wheel_left", record.wheel_left_speed),
                       ("wheel_right", record.wheel_right_speed)):
        topic = getattr(topics, key)
        if topic and speed is not None:
            out.append((key, topic, MESSAGE_TYPES[key], {"data": speed}))
    return out
