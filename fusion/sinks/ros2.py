"""ROS 2 on the wire without a ROS 2 install: a DDS participant (``cyclonedds``, the ``ros2``
extra) that ROS 2 nodes see as publishers of the fused odometry and a /cmd_vel subscriber.

ROS 2 nodes talk DDS; a ROS 2 topic ``/odom`` of type ``nav_msgs/msg/Odometry`` is the DDS topic
``rt/odom`` of type ``nav_msgs::msg::dds_::Odometry_``, in little-endian XCDR1. This sink
publishes exactly that (the types are declared in :mod:`fusion.sinks.ros2_idl`):

=====================  ======================  ==============================================
ROS 2 topic            type                    DDS QoS (the ROS 2 default of that topic)
=====================  ======================  ==============================================
``/odom``              nav_msgs/Odometry       reliable, volatile, keep last 10 (rclcpp's and
                                               rclpy's default profile)
``/tf``                tf2_msgs/TFMessage      reliable, volatile, keep last 100 (tf2_ros's
                                               ``DynamicBroadcasterQoS``)
``/imu/data``          sensor_msgs/Imu         reliable, volatile, keep last 10
``/wheel_left_speed``  std_msgs/Float32        reliable, volatile, keep last 10
``/wheel_right_speed`` std_msgs/Float32        reliable, volatile, keep last 10
``/cmd_vel`` (sub.)    geometry_msgs/Twist     best effort, volatile, keep last 10
=====================  ======================  ==============================================

A reliable publisher reaches reliable and best-effort subscribers alike (``ros2 topic echo``,
rviz, robot_localization's sensor-data QoS); the /cmd_vel reader is best effort so that it
matches every publisher, reliable (teleop_twist_keyboard, Nav2) or best effort (some joystick
drivers). All endpoints use XCDR1 (the only representation ``rmw_cyclonedds_cpp`` accepts),
automatic liveliness, and writers do not dispose on unregister, like rmw_cyclonedds_cpp's.

The domain is ``ROS_DOMAIN_ID`` (default 0) and Cyclone DDS reads its configuration from
``CYCLONEDDS_URI`` (network interface, peers, multicast), as a ROS 2 node with
``RMW_IMPLEMENTATION=rmw_cyclonedds_cpp`` does. The participant does not publish ROS 2's
``ros_discovery_info``: ROS 2 tools list and echo its topics, but ``ros2 node list`` does not
show it (endpoints appear with an unknown node name).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from fusion.sinks.base import _need
from fusion.sinks.ros_messages import MESSAGE_TYPES, Topics, ros_messages
from fusion.sinks.ros_node import RosNodeSink
from fusion.types.fused import FusedOdometry

__all__ = ["TOPIC_HISTORY", "Ros2Sink", "dds_topic_name", "ros_domain_id"]

_log = logging.getLogger(__name__)

#: Keep-last depth of each published topic (:class:`Topics` field): ROS 2's default profile
#: (10), and tf2_ros's ``DynamicBroadcasterQoS`` (100) for /tf.
TOPIC_HISTORY = {"odom": 10, "tf": 100, "imu": 10, "wheel_left": 10, "wheel_right": 10}

#: Highest domain id Cyclone DDS accepts (its port mapping, 7400 + 250 * id, stays < 65536).
MAX_DOMAIN_ID = 232


def dds_topic_name(topic: str) -> str:
    """``/odom`` -> ``rt/odom``: the DDS topic of a ROS 2 topic (ROS 2's ``rt`` prefix)."""
    if not topic.startswith("/"):
        raise ValueError(f"ROS topic names here are absolute like '/odom', got {topic!r}")
    return "rt" + topic


def ros_domain_id(environ: Mapping[str, str] | None = None) -> int:
    """The ROS 2 domain id of the ``ROS_DOMAIN_ID`` environment variable (0 if unset or empty).

    Raises:
        ValueError: not an integer within 0..232, quoting the value.
    """
    env = os.environ if environ is None else environ
    text = env.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS_DOMAIN_ID={text!r}: want an integer 0..{MAX_DOMAIN_ID}")
    return value


class Ros2Sink(RosNodeSink):
    """Publishes each :class:`FusedOdometry` record on ROS 2 topics over DDS (see the module doc).

    Args:
        topics: ROS 2 topic names (:class:`fusion.sinks.ros_messages.Topics`; None leaves one
            out).
        cmd_vel_topic, on_cmd_vel, rate_hz, frame_id, child_frame_id, imu_frame_id, stamp: as
            :class:`fusion.sinks.ros_node.RosNodeSink` (``stamp="now"``: the wall clock,
            which is ROS 2's time). ``on_cmd_vel`` runs on the sink's listener thread.
        domain_id: DDS domain, 0..232; None (default) reads ``ROS_DOMAIN_ID``.
        node_name: the participant's entity name (visible to DDS tools).
    """

    def __init__(
        self,
        topics: Topics | None = None,
        *,
        cmd_vel_topic: str | None = "/cmd_vel",
        on_cmd_vel: Callable[[float, float], None] | None = None,
        rate_hz: float | None = None,
        frame_id: str | None = None,
        child_frame_id: str | None = None,
        imu_frame_id: str | None = None,
        stamp: str = "now",
        domain_id: int | None = None,
        node_name: str = "diffbot_fusion",
    ) -> None:
        super().__init__(topics, cmd_vel_topic=cmd_vel_topic, on_cmd_vel=on_cmd_vel,
                         rate_hz=rate_hz, frame_id=frame_id, child_frame_id=child_frame_id,
                         imu_frame_id=imu_frame_id, stamp=stamp)
        if domain_id is not None and not (isinstance(domain_id, int)
                                          and 0 <= domain_id <= MAX_DOMAIN_ID):
            raise ValueError(f"domain_id must be an integer 0..{MAX_DOMAIN_ID} or None, got "
                             f"{domain_id!r}")
        self.domain_id = domain_id
        self.node_name = node_name
        self._participant: Any = None
        self._writers: dict[str, Any] = {}
        self._listener: threading.Thread | None = None
        self._stop = threading.Event()

    def __repr__(self) -> str:
        return f"Ros2Sink(domain={self.domain_id})"

    def _open(self) -> None:
        _need("cyclonedds.domain", "ros2")
        from cyclonedds.core import DDSException, Policy, Qos
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        from fusion.sinks import ros2_idl

        domain = ros_domain_id() if self.domain_id is None else self.domain_id
        self.domain_id = domain
        try:
            participant = DomainParticipant(domain, qos=Qos(Policy.EntityName(self.node_name)))
        except DDSException as exc:
            uri = os.environ.get("CYCLONEDDS_URI")
            where = f"CYCLONEDDS_URI={uri!r}" if uri else "Cyclone DDS's default configuration"
            raise OSError(f"no DDS participant on domain {domain} ({where}): {exc}") from exc
        self._participant = participant
        common = [Policy.Durability.Volatile,
                  Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
                  Policy.DataRepresentation(use_cdrv0_representation=True)]  # XCDR1 only
        try:
            for key, topic in self.topics.as_dict().items():
                if topic is None:
                    continue
                qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                          Policy.History.KeepLast(TOPIC_HISTORY[key]),
                          Policy.WriterDataLifecycle(autodispose=False), *common)
                dds_topic = Topic(participant, dds_topic_name(topic),
                                  ros2_idl.IDL_TYPES[MESSAGE_TYPES[key]])
                self._writers[key] = DataWriter(participant, dds_topic, qos=qos)
            if self.cmd_vel_topic is not None:
                qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(10), *common)
                self._start_listener(participant, qos)
        except BaseException:
            self._release()
            raise

    def _start_listener(self, participant: Any, qos: Any) -> None:
        from cyclonedds.core import (
            GuardCondition,
            InstanceState,
            ReadCondition,
            SampleState,
            ViewState,
            WaitSet,
        )
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from fusion.sinks.ros2_idl import Twist

        assert self.cmd_vel_topic is not None
        topic = Topic(participant, dds_topic_name(self.cmd_vel_topic), Twist)
        reader = DataReader(participant, topic, qos=qos)
        waitset = WaitSet(participant)
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
        wake = GuardCondition(participant)
        waitset.attach(wake)
        self._wake = wake
        self._stop.clear()
        self._listener = threading.Thread(target=self._listen, args=(reader, waitset, Twist),
                                          name="ros2-cmd_vel", daemon=True)
        self._listener.start()

    def _listen(self, reader: Any, waitset: Any, twist: type) -> None:
        from cyclonedds.util import duration

        while not self._stop.is_set():
            waitset.wait(duration(milliseconds=500))
            for msg in reader.take(64):
                if self._stop.is_set():
                    return
                if not isinstance(msg, twist):  # an unregistered writer, not a command
                    continue
                try:
                    self._command(msg.linear.x, msg.angular.z)
                except Exception:  # the callback's error must not end the listener
                    _log.exception("on_cmd_vel failed for (%s, %s)", msg.linear.x,
                                   msg.angular.z)

    def _write(self, record: FusedOdometry) -> None:
        from fusion.sinks.ros2_idl import idl_message

        due = self._due(record)
        if due is None:
            return
        now = time.time_ns() if self.stamp == "now" else None  # one stamp per record
        for key, _topic, msgtype, fields in ros_messages(due, self.topics, stamp=now):
            self._writers[key].write(idl_message(msgtype, fields))

    def _release(self) -> None:
        """Stop the listener, then delete the participant and with it every endpoint (ROS 2
        peers see the publishers go)."""
        self._stop.set()
        if self._listener is not None:
            self._wake.set(True)
            self._listener.join(timeout=5.0)
            self._listener = None
        self._writers.clear()
        participant, self._participant = self._participant, None
        if participant is not None:
            participant.__del__()  # dds_delete of the participant and all its children

    def _close(self) -> None:
        self._release()
