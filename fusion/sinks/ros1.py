"""ROS 1 node sink with seed 000's interface (miiboo_bringup's base_controller).

Publishes (names configurable through :class:`fusion.sinks.ros_messages.Topics`):

- ``/odom`` nav_msgs/Odometry: pose of ``child_frame_id`` in ``frame_id`` (m, yaw-only
  quaternion), twist in the child frame (m/s, rad/s), both 6x6 covariances row major over
  ``(x, y, z, roll, pitch, yaw)`` / ``(vx, vy, vz, wx, wy, wz)``;
- ``/tf`` tf2_msgs/TFMessage: ``frame_id`` -> ``child_frame_id`` (odom -> base_footprint);
- ``/imu/data`` sensor_msgs/Imu (attitude if known, rad/s, m/s^2);
- ``/wheel_left_speed``, ``/wheel_right_speed`` std_msgs/Float32, wheel rim speeds in m/s.

Subscribes ``/cmd_vel`` (geometry_msgs/Twist) and hands ``(linear.x m/s, angular.z rad/s)``
to a callback, unclamped; the caller applies seed 000's limits and sends wheel targets through
the chassis link. The callback runs on a rospy thread.

rospy comes from Debian's ``python3-rospy`` (with ``python3-nav-msgs``, ``python3-tf2-msgs``,
``python3-sensor-msgs``, ``python3-geometry-msgs``, ``python3-std-msgs``) for Debian's
``/usr/bin/python3``; it is imported when the sink opens, never at module import. Use a venv
made with ``/usr/bin/python3 -m venv --system-site-packages`` to run this package with it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fusion.sinks.ros_messages import MESSAGE_TYPES, Topics, ros_messages
from fusion.sinks.ros_node import RateLimiter, RosNodeSink
from fusion.types.fused import FusedOdometry

__all__ = ["RateLimiter", "Ros1Sink"]


class Ros1Sink(RosNodeSink):
    """A ROS 1 node that publishes each :class:`FusedOdometry` record (see the module doc).

    Args:
        topics: topic names (:class:`fusion.sinks.ros_messages.Topics`; None leaves a topic out).
        node_name: ROS node name (used when this sink initialises the node).
        cmd_vel_topic: velocity command topic, or None not to subscribe.
        on_cmd_vel: ``callback(v, w)`` with linear.x (m/s) and angular.z (rad/s) of every
            Twist received (one with a non-finite value is dropped and counted in
            ``cmd_vel_rejected``).
        rate_hz: most records published per second of record time (seed 000 uses 10 Hz);
            None publishes every record.
        frame_id, child_frame_id, imu_frame_id: override the record's frame names.
        stamp: ``"now"`` stamps messages with ``rospy.Time.now()`` (live robots, whose
            pipeline runs on a monotonic clock); ``"record"`` uses the record's ``t``
            (replay, tests).
        master_uri: ROS master (default: the ``ROS_MASTER_URI`` environment variable).
        init_node: initialise a node if the process has none (rospy allows one per process,
            so inside an existing node pass False or leave True: an initialised process is
            detected and reused).
        queue_size: publisher queue size.
    """

    def __init__(
        self,
        topics: Topics | None = None,
        *,
        node_name: str = "diffbot_fusion",
        cmd_vel_topic: str | None = "/cmd_vel",
        on_cmd_vel: Callable[[float, float], None] | None = None,
        rate_hz: float | None = None,
        frame_id: str | None = None,
        child_frame_id: str | None = None,
        imu_frame_id: str | None = None,
        stamp: str = "now",
        master_uri: str | None = None,
        init_node: bool = True,
        queue_size: int = 10,
    ) -> None:
        super().__init__(topics, cmd_vel_topic=cmd_vel_topic, on_cmd_vel=on_cmd_vel,
                         rate_hz=rate_hz, frame_id=frame_id, child_frame_id=child_frame_id,
                         imu_frame_id=imu_frame_id, stamp=stamp)
        self.node_name = node_name
        self.master_uri = master_uri
        self.init_node = init_node
        self.queue_size = queue_size
        self._publishers: dict[str, Any] = {}
        self._subscriber: Any = None
        self._owns_node = False

    def __repr__(self) -> str:
        return f"Ros1Sink(node={self.node_name!r})"

    def _open(self) -> None:
        try:
            import rospy
            from roslib.message import get_message_class
        except ImportError as exc:
            raise ImportError(
                "the ROS 1 sink needs rospy: on Debian, apt-get install python3-rospy "
                "python3-nav-msgs python3-tf2-msgs python3-sensor-msgs python3-geometry-msgs "
                "python3-std-msgs, and run with /usr/bin/python3 (or a venv made from it with "
                "--system-site-packages)"
            ) from exc
        self._rospy = rospy
        self._classes: dict[str, Any] = {}
        self._get_class = get_message_class
        if not rospy.core.is_initialized():
            if not self.init_node:
                raise RuntimeError("no ROS node in this process and init_node=False")
            import rosgraph

            # rospy would otherwise start and publish into the void, retrying in the background
            if not rosgraph.is_master_online(self.master_uri):
                uri = self.master_uri or rosgraph.get_master_uri()
                raise ConnectionError(f"no ROS master at {uri}: start roscore, or set "
                                      "ROS_MASTER_URI / master_uri")
            argv = [f"__master:={self.master_uri}"] if self.master_uri else None
            rospy.init_node(self.node_name, anonymous=False, disable_signals=True,
                            argv=argv)
            self._owns_node = True
        for key, topic in self.topics.as_dict().items():
            if topic is not None:
                self._publishers[key] = rospy.Publisher(
                    topic, self._class(MESSAGE_TYPES[key]), queue_size=self.queue_size)
        if self.cmd_vel_topic is not None:
            self._subscriber = rospy.Subscriber(
                self.cmd_vel_topic, self._class("geometry_msgs/Twist"), self._on_twist,
                queue_size=self.queue_size)

    def _class(self, msgtype: str) -> Any:
        cls = self._classes.get(msgtype)
        if cls is None:
            cls = self._get_class(msgtype)
            if cls is None:
                raise ImportError(f"ROS message type {msgtype} is not installed")
            self._classes[msgtype] = cls
        return cls

    def _on_twist(self, msg: Any) -> None:
        self._command(msg.linear.x, msg.angular.z)

    def _build(self, msgtype: str, value: dict[str, Any], now: Any = None) -> Any:
        """A plain dict from :func:`fusion.sinks.ros_messages.ros_messages` -> a rospy message
        (stamps become ``now`` when given, else the dict's nanoseconds)."""
        cls = self._class(msgtype)
        kwargs = {}
        for name, slot_type in zip(cls.__slots__, cls._slot_types):
            if name not in value:
                continue  # e.g. Header.seq, filled in by rospy
            v = value[name]
            if slot_type == "time":
                if now is not None:
                    kwargs[name] = now
                else:
                    sec, nsec = divmod(int(v), 1_000_000_000)
                    kwargs[name] = self._rospy.Time(sec, nsec)
            elif slot_type.endswith("[]") and "/" in slot_type:
                kwargs[name] = [self._build(slot_type[:-2], item, now) for item in v]
            elif "/" in slot_type:
                kwargs[name] = self._build(slot_type, v, now)
            else:
                kwargs[name] = v
        return cls(**kwargs)

    def _write(self, record: FusedOdometry) -> None:
        record = self._due(record)
        if record is None:
            return
        now = self._rospy.Time.now() if self.stamp == "now" else None  # one stamp per record
        for key, _topic, msgtype, fields in ros_messages(record, self.topics):
            self._publishers[key].publish(self._build(msgtype, fields, now))

    def _close(self) -> None:
        if self._subscriber is not None:
            self._subscriber.unregister()
            self._subscriber = None
        for pub in self._publishers.values():
            pub.unregister()
        self._publishers.clear()
        if self._owns_node:
            self._rospy.signal_shutdown("fusion Ros1Sink closed")
