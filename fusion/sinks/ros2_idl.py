"""The ROS 2 messages of the ``ros2`` sink as DDS types (``cyclonedds`` IDL structs), declared
once here; :func:`idl_message` fills them from :func:`fusion.sinks.ros_messages.ros_messages`.

This is the DDS form every ROS 2 RMW uses on the wire: ``pkg/msg/Name`` becomes the final
(non-extensible), keyless struct ``pkg::msg::dds_::Name_`` with the message's fields in order,
serialised as little-endian XCDR1 (encapsulation ``00 01 00 00``). The layouts and the bytes are
checked against ``rosbags``' Humble and Jazzy definitions in ``tests/test_ros2_sink.py`` (the
five published messages and ``geometry_msgs/Twist`` are the same in every ROS 2 distribution).

Imports ``cyclonedds`` (the ``ros2`` extra): :class:`fusion.sinks.ros2.Ros2Sink` imports this
module when it opens.
"""

import dataclasses
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint32

__all__ = [
    "IDL_TYPES",
    "Float32",
    "Imu",
    "Odometry",
    "TFMessage",
    "Twist",
    "dds_type_name",
    "idl_message",
]


def dds_type_name(msgtype: str) -> str:
    """``nav_msgs/Odometry`` (or ``nav_msgs/msg/Odometry``) -> ``nav_msgs::msg::dds_::Odometry_``,
    the DDS type name ROS 2 gives a message."""
    pkg, *_, name = msgtype.split("/")
    return f"{pkg}::msg::dds_::{name}_"


@dataclass
class Time(IdlStruct, typename=dds_type_name("builtin_interfaces/Time")):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename=dds_type_name("std_msgs/Header")):
    stamp: Time
    frame_id: str


@dataclass
class Float32(IdlStruct, typename=dds_type_name("std_msgs/Float32")):
    data: float32


@dataclass
class Point(IdlStruct, typename=dds_type_name("geometry_msgs/Point")):
    x: float64
    y: float64
    z: float64


@dataclass
class Vector3(IdlStruct, typename=dds_type_name("geometry_msgs/Vector3")):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename=dds_type_name("geometry_msgs/Quaternion")):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename=dds_type_name("geometry_msgs/Pose")):
    position: Point
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename=dds_type_name("geometry_msgs/PoseWithCovariance")):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename=dds_type_name("geometry_msgs/Twist")):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct,
                          typename=dds_type_name("geometry_msgs/TwistWithCovariance")):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Transform(IdlStruct, typename=dds_type_name("geometry_msgs/Transform")):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename=dds_type_name("geometry_msgs/TransformStamped")):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class Odometry(IdlStruct, typename=dds_type_name("nav_msgs/Odometry")):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class TFMessage(IdlStruct, typename=dds_type_name("tf2_msgs/TFMessage")):
    transforms: sequence[TransformStamped]


@dataclass
class Imu(IdlStruct, typename=dds_type_name("sensor_msgs/Imu")):
    header: Header
    orientation: Quaternion
    orientation_covariance: array[float64, 9]
    angular_velocity: Vector3
    angular_velocity_covariance: array[float64, 9]
    linear_acceleration: Vector3
    linear_acceleration_covariance: array[float64, 9]


#: ROS message type (ROS 1 spelling, as :data:`fusion.sinks.ros_messages.MESSAGE_TYPES`) -> its
#: DDS struct, for every message the sink publishes or subscribes to.
IDL_TYPES: dict[str, type[IdlStruct]] = {
    "nav_msgs/Odometry": Odometry,
    "tf2_msgs/TFMessage": TFMessage,
    "sensor_msgs/Imu": Imu,
    "std_msgs/Float32": Float32,
    "geometry_msgs/Twist": Twist,
}


def _builder(cls: type[IdlStruct]) -> Callable[[Any], IdlStruct]:
    """A function from a plain message dict (field name -> value) to an instance of ``cls``.

    Nested structs are built recursively, a sequence of structs item by item; a
    ``builtin_interfaces/Time`` is built from integer nanoseconds (``ros_messages``' stamps).
    """
    if cls is Time:
        def time(ns: int) -> Time:
            sec, nanosec = divmod(int(ns), 1_000_000_000)
            if sec > 2**31 - 1:
                raise ValueError(f"stamp {ns} ns does not fit ROS 2's int32 seconds")
            return Time(sec, nanosec)
        return time
    hints = typing.get_type_hints(cls, include_extras=True)
    parts: list[tuple[str, Callable[[Any], Any] | None]] = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if isinstance(hint, type) and issubclass(hint, IdlStruct):
            parts.append((f.name, _builder(hint)))
            continue
        # sequence[S] is Annotated[Sequence[S], holder] with holder.subtype = S
        holder = typing.get_args(hint)[1] if typing.get_origin(hint) is typing.Annotated else None
        sub = getattr(holder, "subtype", None)
        if isinstance(sub, type) and issubclass(sub, IdlStruct):
            item = _builder(sub)
            parts.append((f.name, lambda values, item=item: [item(v) for v in values]))
        else:
            parts.append((f.name, None))  # a number, string or array of numbers, as given

    def build(value: dict[str, Any]) -> IdlStruct:
        return cls(*[value[name] if make is None else make(value[name])
                     for name, make in parts])
    return build


_BUILDERS = {msgtype: _builder(cls) for msgtype, cls in IDL_TYPES.items()}


def idl_message(msgtype: str, fields: dict[str, Any]) -> IdlStruct:
    """The DDS struct of one message dict of :func:`fusion.sinks.ros_messages.ros_messages`
    (``msgtype`` in the ROS 1 spelling, e.g. ``nav_msgs/Odometry``)."""
    try:
        build = _BUILDERS[msgtype]
    except KeyError:
        raise ValueError(f"no ROS 2 DDS type for {msgtype}; known: {sorted(IDL_TYPES)}") from None
    return build(fields)
