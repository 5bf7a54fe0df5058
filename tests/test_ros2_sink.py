"""The ROS 2 sink (``fusion.sinks.ros2``) against independent ROS 2 definitions.

- Layouts and bytes: every DDS struct of ``fusion.sinks.ros2_idl`` has rosbags' Humble and Jazzy
  fields, and the bytes of every published message equal rosbags' CDR serialiser for the same
  values (messages built here from the record, not through the sink's field builders).
- On the wire: a second process (``tests/ros2_peer.py``, types built from rosbags' definitions,
  nothing of ``fusion``) subscribes over loopback, receives /odom, /tf, /imu/data and the wheel
  speeds (wire bytes == rosbags' serialiser, values == the records), and publishes /cmd_vel,
  which reaches the sink's callback.

Needs the ``ros2`` extra (cyclonedds): skipped without it, except under CI (``CI`` set), where
the imports fail the module (the test extra installs it).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import subprocess
import sys
import time
import typing
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

if importlib.util.find_spec("cyclonedds") is None and not os.environ.get("CI"):
    pytest.skip("the ros2 extra (cyclonedds) is not installed", allow_module_level=True)

from cyclonedds.idl import IdlStruct
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from test_ros1_node import LineReader, templates

from fusion.io.sink_spec import parse_sink_spec
from fusion.sinks import Topics, open_sink
from fusion.sinks.cdr import encode_cdr
from fusion.sinks.ros2 import Ros2Sink, dds_topic_name, ros_domain_id
from fusion.sinks.ros2_idl import IDL_TYPES, Twist, idl_message
from fusion.sinks.ros_messages import ros_messages
from fusion.types.fused import FusedOdometry

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

PEER = Path(__file__).with_name("ros2_peer.py")
DISTROS = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}
TOPIC_TYPES = {"/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
               "/imu/data": "sensor_msgs/msg/Imu", "/wheel_left_speed": "std_msgs/msg/Float32",
               "/wheel_right_speed": "std_msgs/msg/Float32"}


def rosbags_messages(ts, rec: FusedOdometry, imu_frame: str | None = None) -> dict[str, object]:
    """The five messages of ``rec`` as rosbags objects, built from the record's fields (units as
    the ROS messages define them: m, m/s, rad/s, m/s^2, ns)."""
    T = ts.types
    sec, nsec = divmod(round(rec.t * 1e9), 1_000_000_000)

    def header(frame: str):
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)

    def vec(v) -> object:
        return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(wxyz) -> object:
        w, x, y, z = (float(c) for c in wxyz)
        return T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    point = T["geometry_msgs/msg/Point"](x=rec.x, y=rec.y, z=0.0)
    yaw_q = quat(rec.yaw_quaternion)
    out = {
        "/odom": T["nav_msgs/msg/Odometry"](
            header=header(rec.frame_id), child_frame_id=rec.child_frame_id,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=point, orientation=yaw_q),
                covariance=np.asarray(rec.pose_covariance, float).reshape(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=vec([rec.v, 0, 0]),
                                                   angular=vec(rec.angular_velocity)),
                covariance=np.asarray(rec.twist_covariance, float).reshape(36))),
        "/tf": T["tf2_msgs/msg/TFMessage"](transforms=[T["geometry_msgs/msg/TransformStamped"](
            header=header(rec.frame_id), child_frame_id=rec.child_frame_id,
            transform=T["geometry_msgs/msg/Transform"](
                translation=vec([rec.x, rec.y, 0.0]), rotation=yaw_q))]),
    }
    # sensor_msgs/Imu: element 0 of a covariance = -1 means "this field is not provided"
    unknown = np.array([-1.0] + [0.0] * 8)
    has_q, has_a = rec.orientation is not None, rec.linear_acceleration is not None
    out["/imu/data"] = T["sensor_msgs/msg/Imu"](
        header=header(imu_frame or rec.imu_frame_id),
        orientation=quat(rec.orientation if has_q else [0, 0, 0, 0]),
        orientation_covariance=np.zeros(9) if has_q else unknown,
        angular_velocity=vec(rec.angular_velocity), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vec(rec.linear_acceleration if has_a else [0, 0, 0]),
        linear_acceleration_covariance=np.zeros(9) if has_a else unknown)
    for topic, speed in (("/wheel_left_speed", rec.wheel_left_speed),
                         ("/wheel_right_speed", rec.wheel_right_speed)):
        if speed is not None:
            out[topic] = T["std_msgs/msg/Float32"](data=speed)
    return out


# -- layouts and bytes ------------------------------------------------------------------------

def _holder(hint) -> object:
    """The cyclonedds annotation of a field (``array``, ``sequence``, ``"float64"``), or None."""
    return typing.get_args(hint)[1] if typing.get_origin(hint) is typing.Annotated else None


def _structs(cls: type[IdlStruct], seen: dict[str, type]) -> dict[str, type]:
    """``cls`` and every struct it contains, by ROS 2 name (``pkg/msg/Name``)."""
    seen[_ros_name(cls)] = cls
    for hint in typing.get_type_hints(cls, include_extras=True).values():
        inner = getattr(_holder(hint), "subtype", hint)
        if isinstance(inner, type) and issubclass(inner, IdlStruct):
            _structs(inner, seen)
    return seen


def _ros_name(cls: type[IdlStruct]) -> str:
    """``nav_msgs::msg::dds_::Odometry_`` -> ``nav_msgs/msg/Odometry``."""
    pkg, msg, dds, name = cls.__idl_typename__.split("::")
    assert (msg, dds, name[-1]) == ("msg", "dds_", "_"), cls.__idl_typename__
    return f"{pkg}/msg/{name[:-1]}"


def _rosbags_kind(node, arg) -> tuple:
    """rosbags' field definition in the form :func:`_our_kind` gives."""
    if node == Nodetype.BASE:
        return ("base", arg[0])
    if node == Nodetype.NAME:
        return ("struct", arg)
    inner = _rosbags_kind(*arg[0])
    return ("array", inner, arg[1]) if node == Nodetype.ARRAY else ("sequence", inner)


def _our_kind(hint) -> tuple:
    if hint is str:
        return ("base", "string")
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return ("struct", _ros_name(hint))
    holder = _holder(hint)
    if isinstance(holder, str):  # Annotated[float, "float64"]
        return ("base", holder)
    inner = _our_kind(holder.subtype)
    return ("array", inner, holder.length) if hasattr(holder, "length") else ("sequence", inner)


@pytest.mark.parametrize("distro", DISTROS)
def test_dds_types_have_rosbags_ros2_layouts(distro: str) -> None:
    ts = get_typestore(DISTROS[distro])
    structs: dict[str, type] = {}
    for cls in IDL_TYPES.values():
        _structs(cls, structs)
    assert len(structs) == 15  # the five messages, Twist, and the 9 structs inside them
    for name, cls in structs.items():
        ours = [(f.name, _our_kind(typing.get_type_hints(cls, include_extras=True)[f.name]))
                for f in dataclasses.fields(cls)]
        theirs = [(fname, _rosbags_kind(*spec)) for fname, spec in ts.fielddefs[name][1]]
        assert ours == theirs, name
    assert IDL_TYPES["nav_msgs/Odometry"].__idl_typename__ == "nav_msgs::msg::dds_::Odometry_"
    assert dds_topic_name("/imu/data") == "rt/imu/data"


@pytest.mark.parametrize("distro", DISTROS)
def test_published_bytes_equal_rosbags_serializer(distro: str) -> None:
    ts = get_typestore(DISTROS[distro])
    n = 0
    for rec in templates():
        expected = rosbags_messages(ts, rec)
        for _key, topic, msgtype, fields in ros_messages(rec):
            ours = idl_message(msgtype, fields).serialize(use_version_2=False)  # as the writer
            assert ours == bytes(ts.serialize_cdr(expected.pop(topic), TOPIC_TYPES[topic]))
            assert ours == encode_cdr(msgtype, fields)  # the bag sinks' encoder agrees
            n += 1
        assert not expected  # every message the record has was published
    assert n == 4 * 5 - 2  # the last template has no wheel speeds


def test_twist_reads_rosbags_bytes() -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    data = ts.serialize_cdr(T["geometry_msgs/msg/Twist"](
        linear=T["geometry_msgs/msg/Vector3"](x=0.25, y=-1.5, z=2.0),
        angular=T["geometry_msgs/msg/Vector3"](x=0.125, y=3.0, z=-0.5)), "geometry_msgs/msg/Twist")
    msg = Twist.deserialize(bytes(data))
    assert (msg.linear.x, msg.linear.y, msg.linear.z) == (0.25, -1.5, 2.0)
    assert (msg.angular.x, msg.angular.y, msg.angular.z) == (0.125, 3.0, -0.5)


# -- options ----------------------------------------------------------------------------------

def test_domain_id_comes_from_ros_domain_id() -> None:
    assert ros_domain_id({}) == 0
    assert ros_domain_id({"ROS_DOMAIN_ID": " 42 "}) == 42
    for bad in ("-1", "233", "one"):
        with pytest.raises(ValueError, match=f"ROS_DOMAIN_ID='{bad}'"):
            ros_domain_id({"ROS_DOMAIN_ID": bad})
    with pytest.raises(ValueError, match="domain_id"):
        Ros2Sink(domain_id=300)


def test_spec_and_registry() -> None:
    assert parse_sink_spec("ros2").kind == "ros2"
    with pytest.raises(ValueError, match=r"ros2 takes no argument.*ROS_DOMAIN_ID"):
        parse_sink_spec("ros2:7")
    sink = open_sink("ros2", topics=Topics(imu=None))
    assert isinstance(sink, Ros2Sink) and sink.topics.imu is None and not sink.is_open


def test_without_cyclonedds_the_error_says_which_extra(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "cyclonedds.domain", None)  # as if not installed
    with pytest.raises(ImportError, match=r"pip install 'diffbot-fusion\[ros2\]'"):
        Ros2Sink().open()


def test_non_finite_commands_are_dropped_and_counted() -> None:
    got = []
    sink = Ros2Sink(on_cmd_vel=lambda v, w: got.append((v, w)))
    for v, w in ((0.5, -0.25), (math.nan, 0.0), (0.0, math.inf)):
        sink._command(v, w)
    assert got == [(0.5, -0.25)]
    assert (sink.cmd_vel_received, sink.cmd_vel_rejected) == (1, 2)


# -- on the wire ------------------------------------------------------------------------------

def _stamp_ns(msg: dict) -> int:
    header = (msg["transforms"][0] if "transforms" in msg else msg)["header"]
    return header["stamp"]["sec"] * 1_000_000_000 + header["stamp"]["nanosec"]


def test_a_ros2_peer_process_receives_the_topics_and_drives_cmd_vel(ros2_env) -> None:
    recs = templates()
    want = {"/odom": 4, "/tf": 4, "/imu/data": 4,
            "/wheel_left_speed": 3, "/wheel_right_speed": 3}  # record 3 has no speeds
    commands: list[tuple[float, float]] = []
    sink = Ros2Sink(stamp="record", imu_frame_id="imu_link",
                    on_cmd_vel=lambda v, w: commands.append((v, w)))
    peer = subprocess.Popen([sys.executable, str(PEER), "collect",
                             *[f"{t}={n}" for t, n in want.items()], "--cmd-vel", "0.25", "-0.5"],
                            env=ros2_env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    got = None
    try:
        out = LineReader(peer, "ROS 2 peer")
        with sink:
            for i in range(800):  # 20 Hz, bounded (40 s); the peer answers within seconds
                sink.write(recs[i % len(recs)])
                if i % 4 == 3 and not out.lines.empty():
                    got = out.next_json()
                    break
                time.sleep(0.05)
            deadline = time.monotonic() + 30
            while not commands and time.monotonic() < deadline:  # the peer sends at 10 Hz
                time.sleep(0.05)
        peer.stdin.close()
        assert peer.wait(30) == 0, peer.stderr.read()
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    assert got is not None, "the peer received nothing"
    # discovery announces ROS 2's names and each topic's ROS 2 default QoS (rclcpp/rclpy's
    # default profile: reliable, volatile, keep last 10; tf2_ros's DynamicBroadcasterQoS: the
    # same with depth 100); XCDR1 as rmw_cyclonedds_cpp; the /cmd_vel reader is best effort
    types = {"rt/odom": "nav_msgs::msg::dds_::Odometry_",
             "rt/tf": "tf2_msgs::msg::dds_::TFMessage_",
             "rt/imu/data": "sensor_msgs::msg::dds_::Imu_",
             "rt/wheel_left_speed": "std_msgs::msg::dds_::Float32_",
             "rt/wheel_right_speed": "std_msgs::msg::dds_::Float32_",
             "rt/cmd_vel": "geometry_msgs::msg::dds_::Twist_"}
    assert got["endpoints"] == {topic: {
        "role": "subscriber" if topic == "rt/cmd_vel" else "publisher", "type": type_name,
        "reliability": "BestEffort" if topic == "rt/cmd_vel" else "Reliable",
        "durability": "Volatile", "history": ["KeepLast", 100 if topic == "rt/tf" else 10],
        "xcdr1_only": True} for topic, type_name in types.items()}
    got = got["messages"]
    assert {t: len(v) for t, v in got.items()} == want  # nothing unexpected or duplicated
    # /cmd_vel from the peer reached the callback as (linear.x m/s, angular.z rad/s)
    assert commands and set(commands) == {(0.25, -0.5)}
    assert sink.cmd_vel_rejected == 0

    # the wire bytes are rosbags' serialisation of the records' values (Humble and Jazzy)
    table = {round(r.t * 1e9): r for r in recs}
    for store in DISTROS.values():
        ts = get_typestore(store)
        expected = [rosbags_messages(ts, r, imu_frame="imu_link") for r in recs]
        for topic, samples in got.items():
            wire = sorted(bytes.fromhex(s["hex"]) for s in samples)
            assert wire == sorted(bytes(ts.serialize_cdr(e[topic], TOPIC_TYPES[topic]))
                                  for e in expected if topic in e), topic

    # and the values, decoded by rosbags in the peer, are the records'
    for s in got["/odom"]:
        m = s["msg"]
        rec = table[_stamp_ns(m)]
        assert (m["header"]["frame_id"], m["child_frame_id"]) == ("odom", "base_footprint")
        pose = m["pose"]["pose"]
        assert [pose["position"][a] for a in "xyz"] == [rec.x, rec.y, 0.0]
        q = np.array([pose["orientation"][a] for a in "xyzw"])
        expected_q = Rotation.from_euler("z", rec.yaw).as_quat()
        np.testing.assert_allclose(q * np.sign(q @ expected_q), expected_q, atol=1e-12)
        assert m["pose"]["covariance"] == rec.pose_covariance.reshape(36).tolist()
        assert [m["twist"]["twist"]["linear"][a] for a in "xyz"] == [rec.v, 0.0, 0.0]
        assert [m["twist"]["twist"]["angular"][a] for a in "xyz"] == list(rec.angular_velocity)
        assert m["twist"]["covariance"] == rec.twist_covariance.reshape(36).tolist()
    for s in got["/tf"]:
        tf = s["msg"]["transforms"][0]
        rec = table[_stamp_ns(s["msg"])]
        assert (tf["header"]["frame_id"], tf["child_frame_id"]) == ("odom", "base_footprint")
        assert [tf["transform"]["translation"][a] for a in "xyz"] == [rec.x, rec.y, 0.0]
    assert sorted(_stamp_ns(s["msg"]) for s in got["/imu/data"]) == sorted(table)
    for s in got["/imu/data"]:
        m = s["msg"]
        rec = table[_stamp_ns(m)]
        assert m["header"]["frame_id"] == "imu_link"  # the sink's override
        assert [m["angular_velocity"][a] for a in "xyz"] == list(rec.angular_velocity)
        has_q, has_a = rec.orientation is not None, rec.linear_acceleration is not None
        assert (m["orientation_covariance"][0] == -1.0) == (not has_q)
        assert (m["linear_acceleration_covariance"][0] == -1.0) == (not has_a)
        if has_a:
            assert [m["linear_acceleration"][a] for a in "xyz"] == [0.2, -0.1, 9.8]
    # wheel speeds, m/s (exact in float32: multiples of 1/8)
    assert sorted(s["msg"]["data"] for s in got["/wheel_left_speed"]) == [0.25, 0.375, 0.5]
    assert sorted(s["msg"]["data"] for s in got["/wheel_right_speed"]) == [0.375, 0.5, 0.625]
