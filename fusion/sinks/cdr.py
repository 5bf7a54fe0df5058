"""ROS 2 CDR (little-endian XCDR1) encoding of the messages of :mod:`fusion.sinks.ros_messages`.
"""

from __future__ import annotations

import struct
from typing import Any

__all__ = ["encode_cdr"]


def _ros2_type(msgtype: str) -> str:
    """``nav_msgs/Odometry`` -> ``nav_msgs/msg/Odometry``."""
    pkg, name = msgtype.split("/")
    return f"{pkg}/msg/{name}"


class _Cdr:
    """Little-endian XCDR1 (what ROS 2 and rosbag2 use) for the fixed shapes of our messages.

    Alignment is relative to the byte after the 4-byte encapsulation header; strings are a
    uint32 length that counts the terminating NUL, then the bytes and the NUL. The output is
    checked byte for byte against rosbags' serialiser in the tests.
    """

    __slots__ = ("parts", "pos")

    def __init__(self) -> None:
        self.parts: list[bytes] = [b"\x00\x01\x00\x00"]
        self.pos = 0

    def _put(self, align: int, data: bytes) -> None:
        pad = -self.pos % align
        if pad:
            self.parts.append(b"\x00" * pad)
        self.parts.append(data)
        self.pos += pad + len(data)

    def header(self, h: dict[str, Any]) -> None:
        sec, nsec = divmod(int(h["stamp"]), 1_000_000_000)
        if sec > 2**31 - 1:
            raise ValueError(f"stamp {h['stamp']} ns does not fit ROS 2's int32 seconds")
        self._put(4, _I_I.pack(sec, nsec))
        self.string(h["frame_id"])

    def string(self, text: str) -> None:
        raw = text.encode() + b"\x00"
        self._put(4, len(raw).to_bytes(4, "little") + raw)

    def doubles(self, values: list[float]) -> None:
        self._put(8, struct.pack(f"<{len(values)}d", *values))

    def u32(self, n: int) -> None:
        self._put(4, n.to_bytes(4, "little"))

    def f32(self, value: float) -> None:
        self._put(4, struct.pack("<f", value))

    def getvalue(self) -> bytes:
        return b"".join(self.parts)


_I_I = struct.Struct("<iI")


def _xyz(v: dict[str, float]) -> list[float]:
    return [v["x"], v["y"], v["z"]]


def _xyzw(q: dict[str, float]) -> list[float]:
    return [q["x"], q["y"], q["z"], q["w"]]


def encode_cdr(msgtype: str, m: dict[str, Any]) -> bytes:
    """CDR bytes of one message dict of :func:`ros_messages` (ROS 1 type spelling)."""
    c = _Cdr()
    if msgtype == "nav_msgs/Odometry":
        c.header(m["header"])
        c.string(m["child_frame_id"])
        pose, twist = m["pose"], m["twist"]
        c.doubles(_xyz(pose["pose"]["position"]) + _xyzw(pose["pose"]["orientation"])
                  + pose["covariance"] + _xyz(twist["twist"]["linear"])
                  + _xyz(twist["twist"]["angular"]) + twist["covariance"])
    elif msgtype == "tf2_msgs/TFMessage":
        c.u32(len(m["transforms"]))
        for tr in m["transforms"]:
            c.header(tr["header"])
            c.string(tr["child_frame_id"])
            c.doubles(_xyz(tr["transform"]["translation"]) + _xyzw(tr["transform"]["rotation"]))
    elif msgtype == "sensor_msgs/Imu":
        c.header(m["header"])
        c.doubles(_xyzw(m["orientation"]) + m["orientation_covariance"]
                  + _xyz(m["angular_velocity"]) + m["angular_velocity_covariance"]
                  + _xyz(m["linear_acceleration"]) + m["linear_acceleration_covariance"])
    elif msgtype == "std_msgs/Float32":
        c.f32(m["data"])
    else:
        raise ValueError(f"no CDR encoder for {msgtype}")
    return c.getvalue()
