"""A ROS 2 peer for the tests: another process on the DDS domain of ``ROS_DOMAIN_ID`` (discovery
as ``CYCLONEDDS_URI`` says), whose message types are built from ``rosbags``' ROS 2 message
definitions, not from this project's declarations (it imports nothing of ``fusion``).

It reads the DDS wire bytes of each sample (``rt/<topic>``, type ``<pkg>::msg::dds_::<Name>_``),
decodes them with rosbags' CDR deserialiser, and publishes ``geometry_msgs/Twist`` on
``rt/cmd_vel`` at 10 Hz. It prints one JSON line, then exits.

``collect TOPIC=N ... --cmd-vel V W``: until each topic has N distinct messages and the other
participant's /cmd_vel reader is discovered, print ``{"messages": {topic: [{"hex": wire bytes,
"msg": decoded fields}, ...]}, "endpoints": {DDS topic: what discovery says of the other
participants' endpoints}}``, keep publishing the command until standard input closes.

``drive --cmd-vel V W --seconds S``: wait for the first /odom, publish the command for S seconds
and a zero command for 1 s, print what /odom said before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import threading
import time

import numpy as np
from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import make_idl_struct
from cyclonedds.idl import types as idl
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
TOPIC_TYPES = {"/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
               "/imu/data": "sensor_msgs/msg/Imu", "/wheel_left_speed": "std_msgs/msg/Float32",
               "/wheel_right_speed": "std_msgs/msg/Float32", "/cmd_vel": "geometry_msgs/msg/Twist"}
PRIMITIVES = {"float64": idl.float64, "float32": idl.float32, "int32": idl.int32,
              "uint32": idl.uint32, "string": str}
_STRUCTS: dict[str, type] = {}


def dds_struct(name: str) -> type:
    """The cyclonedds struct of a ROS 2 message (``pkg/msg/Name``), from rosbags' fields."""
    if name not in _STRUCTS:
        pkg, _msg, short = name.split("/")
        fields = {fname: field_type(node, arg) for fname, (node, arg)
                  in TYPESTORE.fielddefs[name][1]}
        _STRUCTS[name] = make_idl_struct(short, f"{pkg}::msg::dds_::{short}_", fields)
    return _STRUCTS[name]


def field_type(node: Nodetype, arg) -> object:
    if node == Nodetype.BASE:
        return PRIMITIVES[arg[0]]
    if node == Nodetype.NAME:
        return dds_struct(arg)
    inner = field_type(*arg[0])
    if node == Nodetype.ARRAY:
        return idl.array[inner, arg[1]]
    return idl.sequence[inner]  # Nodetype.SEQUENCE, unbounded


class WireSample:
    """What a reader's take() returns here: the serialised sample as received."""

    def __init__(self, data: bytes) -> None:
        self.data = bytes(data)


def raw_reader(participant, topic: str) -> DataReader:
    """A reader whose samples are the wire bytes (the struct's own decoding is bypassed)."""
    struct = dds_struct(TOPIC_TYPES[topic])
    struct.deserialize = classmethod(lambda cls, data, **kw: WireSample(data))
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(100))
    return DataReader(participant, Topic(participant, "rt" + topic, struct), qos=qos)


def plain(value):
    """rosbags' message objects as JSON-able values."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.name != "__msgtype__"}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


def decode(topic: str, data: bytes):
    return plain(TYPESTORE.deserialize_cdr(data, TOPIC_TYPES[topic]))


def twist_writer(participant, v: float, w: float):
    struct = dds_struct(TOPIC_TYPES["/cmd_vel"])
    vector3 = dds_struct("geometry_msgs/msg/Vector3")
    writer = DataWriter(participant, Topic(participant, "rt/cmd_vel", struct),
                        qos=Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                Policy.History.KeepLast(10)))

    def send(scale: float = 1.0) -> None:
        writer.write(struct(linear=vector3(x=v * scale, y=0.0, z=0.0),
                            angular=vector3(x=0.0, y=0.0, z=w * scale)))
    return send


def _kind(policy) -> str:
    """``Policy.Reliability.Reliable(...)`` -> ``Reliable``."""
    return repr(policy).split("(")[0].rsplit(".", 1)[1]


class Endpoints:
    """The other participants' endpoints as SEDP discovery announces them: DDS topic -> type
    name, publisher or subscriber, and the QoS ROS 2 matches on."""

    def __init__(self, participant) -> None:
        self.mine = participant.guid
        self.readers = {"publisher": BuiltinDataReader(participant, BuiltinTopicDcpsPublication),
                        "subscriber": BuiltinDataReader(participant,
                                                        BuiltinTopicDcpsSubscription)}
        self.seen: dict[str, dict] = {}

    def poll(self) -> None:
        for role, reader in self.readers.items():
            for ep in reader.take(100):
                qos = getattr(ep, "qos", None)
                if qos is None or ep.participant_key == self.mine:
                    continue  # an endpoint going away, or one of this peer's own
                self.seen[ep.topic_name] = {
                    "role": role, "type": ep.type_name,
                    "reliability": _kind(qos[Policy.Reliability]),
                    "durability": _kind(qos[Policy.Durability]),
                    "history": [_kind(qos[Policy.History]),
                                getattr(qos[Policy.History], "depth", None)],
                    "xcdr1_only": repr(qos[Policy.DataRepresentation]) == repr(
                        Policy.DataRepresentation(use_cdrv0_representation=True))}


def collect(participant, want: dict[str, int], v: float, w: float) -> None:
    endpoints = Endpoints(participant)
    readers = {t: raw_reader(participant, t) for t in want}
    send = twist_writer(participant, v, w)
    got: dict[str, dict[bytes, None]] = {t: {} for t in want}
    closed = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), closed.set()), daemon=True).start()
    reported = False
    for _ in range(1200):  # bounded: at most ~120 s
        send()
        endpoints.poll()
        for topic, reader in readers.items():
            for sample in reader.take(100):
                if isinstance(sample, WireSample):
                    got[topic].setdefault(sample.data, None)
        if not reported and all(len(got[t]) >= n for t, n in want.items()) \
                and "rt/cmd_vel" in endpoints.seen:
            print(json.dumps({"messages": {t: [{"hex": b.hex(), "msg": decode(t, b)}
                                               for b in got[t]] for t in want},
                              "endpoints": endpoints.seen}), flush=True)
            reported = True
        if closed.wait(0.1):
            return


def drive(participant, v: float, w: float, seconds: float) -> None:
    odom, tf = raw_reader(participant, "/odom"), raw_reader(participant, "/tf")
    send = twist_writer(participant, v, w)
    seen: list[dict] = []
    n_tf = 0

    def poll() -> None:
        nonlocal n_tf
        seen.extend(decode("/odom", s.data) for s in odom.take(100)
                    if isinstance(s, WireSample))
        n_tf += sum(isinstance(s, WireSample) for s in tf.take(100))

    deadline = time.monotonic() + 60
    while not seen and time.monotonic() < deadline:  # the publisher is up
        poll()
        time.sleep(0.1)
    before = len(seen)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        send()
        poll()
        time.sleep(0.1)
    for _ in range(10):
        send(0.0)
        poll()
        time.sleep(0.1)

    def pose(m: dict) -> list:
        return [m["header"]["frame_id"], m["child_frame_id"], m["pose"]["pose"]["position"]["x"],
                m["pose"]["pose"]["position"]["y"]]

    print(json.dumps({"n_before": before, "n": len(seen), "tf": n_tf,
                      "before": pose(seen[before - 1]) if before else None,
                      "last": pose(seen[-1]) if seen else None,
                      "vmax": max((m["twist"]["twist"]["linear"]["x"] for m in seen),
                                  default=None)}), flush=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["collect", "drive"])
    p.add_argument("want", nargs="*", help="collect: TOPIC=N")
    p.add_argument("--cmd-vel", nargs=2, type=float, default=[0.0, 0.0])
    p.add_argument("--seconds", type=float, default=3.0)
    a = p.parse_args()
    participant = DomainParticipant(int(os.environ["ROS_DOMAIN_ID"]))
    if a.mode == "collect":
        want = {t: int(n) for t, n in (item.split("=") for item in a.want)}
        collect(participant, want, *a.cmd_vel)
    else:
        drive(participant, *a.cmd_vel, a.seconds)


if __name__ == "__main__":
    main()
