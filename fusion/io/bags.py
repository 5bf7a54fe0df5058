"""ROS 1/2 bags and MCAP files.

Bags (:func:`read_bag`, :func:`read_bag_imu`, :func:`read_bag_odometry`,
:func:`read_bag_twist`, :func:`read_bag_fixes`, :func:`bag_topics`) through the pure-Python
``rosbags`` package (``pip install 'diffbot-fusion[ros]'``): a ROS 1 ``.bag`` file, a ROS 2
bag folder (with ``metadata.yaml``; sqlite3 or MCAP storage) or a single ``.mcap`` file (read
with the ``mcap`` package, messages decoded by ``rosbags`` from the schemas inside). Message
types: sensor_msgs/Imu, nav_msgs/Odometry, geometry_msgs/Twist and TwistStamped,
sensor_msgs/NavSatFix (GPS: a reference to compare the odometry with). Times are s; by default
each message's ``header.stamp`` (``stamps="header"``), or the time the bag recorded it
(``stamps="bag"``, the only choice for Twist). Errors name the file and topic; a missing
topic lists the topics present.

A ROS 1 recording split by ``rosbag record --split`` is read as one bag from its first part
(``<prefix>_0.bag``; :mod:`fusion.io.split_bags`), and :attr:`BagLog.note` names the parts.

An ``.mcap`` file without its summary section (a live recording whose writer was killed or lost
power: :class:`fusion.sinks.bag.McapSink` ``live=True``) is read front to back up to its last
complete record; :attr:`BagLog.note` says so.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.io.errors import LogFormatError
from fusion.io.imu_csv import ImuLog
from fusion.io.repeated_stamps import spread_repeated_stamps
from fusion.io.split_bags import split_parts

__all__ = [
    "BagImuLog",
    "BagLog",
    "FixLog",
    "OdometryLog",
    "TwistLog",
    "bag_topics",
    "open_bag",
    "read_bag",
    "read_bag_fixes",
    "read_bag_imu",
    "read_bag_odometry",
    "read_bag_twist",
]


#: The first 8 bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"


IMU_TYPES = ("sensor_msgs/Imu",)


ODOMETRY_TYPES = ("nav_msgs/Odometry",)


TWIST_TYPES = ("geometry_msgs/Twist", "geometry_msgs/TwistStamped")


FIX_TYPES = ("sensor_msgs/NavSatFix",)


@dataclass
class BagImuLog(ImuLog):
    """sensor_msgs/Imu messages of one topic (beyond :class:`ImuLog`'s ``t``, ``gyro`` rad/s
    and ``accel`` m/s^2, in the message's frame ``frame_id``).

    Attributes:
        orientation: (N, 4) the messages' attitude ``[w, x, y, z]`` (frame_id -> the driver's
            world frame), NaN rows where a message has none (``orientation_covariance[0] ==
            -1`` or an all-zero quaternion); None when no message has one.
        frame_id: ``header.frame_id`` (the same in every message, else a LogFormatError).
        topic: the topic read.
        bag_time: (N,) s, when the bag recorded each message.
        out_of_order: messages whose stamp was earlier than one recorded before it (the
            arrays are sorted by ``t``, stably; 0 for a clean recording).
    """

    orientation: NDArray[np.float64] | None = None
    frame_id: str = ""
    topic: str = ""
    bag_time: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    out_of_order: int = 0


@dataclass
class OdometryLog:
    """nav_msgs/Odometry messages of one topic.

    Attributes:
        t: (N,) s, sorted (see ``out_of_order``).
        x, y: (N,) position of ``child_frame_id`` in ``frame_id``, m.
        yaw: (N,) heading from the pose quaternion (ZYX yaw), rad in (-pi, pi].
        v: (N,) forward speed, ``twist.linear.x``, m/s in ``child_frame_id``.
        vy: (N,) lateral speed, ``twist.linear.y``, m/s (0 for a differential drive).
        w: (N,) yaw rate, ``twist.angular.z``, rad/s.
        pose_covariance, twist_covariance: (N, 36) row major, nav_msgs/Odometry layout.
        frame_id, child_frame_id: frame names (the same in every message).
        topic, source: the topic and the file read.
        bag_time: (N,) s, when the bag recorded each message.
        out_of_order: messages whose stamp was earlier than one recorded before it.
    """

    t: NDArray[np.float64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    yaw: NDArray[np.float64]
    v: NDArray[np.float64]
    vy: NDArray[np.float64]
    w: NDArray[np.float64]
    pose_covariance: NDArray[np.float64]
    twist_covariance: NDArray[np.float64]
    frame_id: str = ""
    child_frame_id: str = ""
    topic: str = ""
    source: str = ""
    bag_time: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    out_of_order: int = 0

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class TwistLog:
    """geometry_msgs/Twist or TwistStamped messages of one topic (e.g. ``/cmd_vel``).

    Attributes:
        t: (N,) s: ``header.stamp`` of TwistStamped, else the bag's record time.
        v: (N,) ``linear.x``, m/s.  vy: (N,) ``linear.y``, m/s.  w: (N,) ``angular.z``, rad/s.
        frame_id: ``header.frame_id`` of TwistStamped, "" for Twist.
        topic, source, bag_time, out_of_order: as in :class:`OdometryLog`.
    """

    t: NDArray[np.float64]
    v: NDArray[np.float64]
    vy: NDArray[np.float64]
    w: NDArray[np.float64]
    frame_id: str = ""
    topic: str = ""
    source: str = ""
    bag_time: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    out_of_order: int = 0

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class FixLog:
    """sensor_msgs/NavSatFix messages of one topic that hold a fix (GPS).

    Attributes:
        t: (N,) s, sorted (see ``out_of_order``).
        latitude, longitude: (N,) WGS84, deg.
        altitude: (N,) m above the WGS84 ellipsoid (a message without one, NaN in the
            message, gets the first known altitude, or 0).
        status: (N,) ``status.status``: 0 fix, 1 satellite-based augmentation, 2 ground-based
            augmentation (DGPS, RTK).
        position_covariance: (N, 9) m^2, east-north-up, row major, as in the message;
            meaningful only where ``covariance_type`` > 0.
        covariance_type: (N,) ``position_covariance_type``: 0 unknown, 1 approximated,
            2 diagonal known, 3 known.
        no_fix: messages left out: ``status.status`` < 0 (no fix), a latitude or longitude
            that is not finite, or both exactly 0 (zeros filled in without a fix).
        frame_id, topic, source, bag_time, out_of_order: as in :class:`OdometryLog`.
    """

    t: NDArray[np.float64]
    latitude: NDArray[np.float64]
    longitude: NDArray[np.float64]
    altitude: NDArray[np.float64]
    status: NDArray[np.int64]
    position_covariance: NDArray[np.float64]
    covariance_type: NDArray[np.int64]
    no_fix: int = 0
    frame_id: str = ""
    topic: str = ""
    source: str = ""
    bag_time: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    out_of_order: int = 0

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class BagLog:
    """What :func:`read_bag` read: one log per requested topic (None if not requested),
    ``topics``, every topic of the file as ``{topic: (type, message count)}``, and ``note``:
    "" or, for an unfinished MCAP recording (a writer killed before it wrote the summary
    section), what was read of it; ``topic_notes``: per topic, what the reader did to its
    messages (stamps shared by consecutive messages spread or copies left out,
    :func:`fusion.io.repeated_stamps.spread_repeated_stamps`; IMU linear accelerations
    flagged as not provided read as zero)."""

    imu: BagImuLog | None
    odometry: OdometryLog | None
    twist: TwistLog | None
    topics: dict[str, tuple[str, int]]
    source: str
    note: str = ""
    fixes: FixLog | None = None
    topic_notes: tuple[str, ...] = ()


def _ros1_name(msgtype: str) -> str:
    """``sensor_msgs/msg/Imu`` -> ``sensor_msgs/Imu`` (one spelling for ROS 1 and 2)."""
    parts = msgtype.split("/")
    return f"{parts[0]}/{parts[-1]}" if len(parts) == 3 else msgtype


def _ros2_name(msgtype: str) -> str:
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def _need_rosbags(path: Path) -> Any:
    try:
        import rosbags.highlevel
        import rosbags.typesys
    except ImportError as exc:
        raise ImportError(
            f"{path}: reading bags needs rosbags: pip install 'diffbot-fusion[ros]'"
        ) from exc
    return rosbags


class _BagFile:
    """One bag or MCAP file behind a small interface: ``topics`` and ``messages(topics)``."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such bag file or folder")
        self.is_mcap_file = path.is_file() and path.suffix.lower() == ".mcap"
        self.topics: dict[str, tuple[str, int]] = {}
        # what was recovered from an unfinished MCAP recording; a split recording's parts
        self.note = ""
        self.truncated = False

    def __enter__(self) -> _BagFile:
        rosbags = _need_rosbags(self.path)
        if self.is_mcap_file:
            self._open_mcap(rosbags)
        else:
            if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
                raise LogFormatError(f"{self.path}: a folder without metadata.yaml is not a "
                                     "ROS 2 bag")
            parts, self.note = (split_parts(self.path) if self.path.suffix.lower() == ".bag"
                                else ([self.path], ""))
            try:
                self._reader = rosbags.highlevel.AnyReader(parts)
                self._reader.open()
            except Exception as exc:  # rosbags' errors, struct errors of truncated files
                hint = {".bag": "; a ROS 1 bag cut short (a recorder killed, a full disk) "
                                "lacks its index: `rosbag reindex` rebuilds it",
                        ".active": "; a recording rosbag record did not finish: `rosbag "
                                   "reindex` it, then rename it to .bag"
                        }.get(self.path.suffix.lower(), "")
                if self.path.suffix.lower() == ".bag" and self.path.suffix != ".bag":
                    hint = (f"; rosbags knows a ROS 1 bag by its lowercase .bag suffix: "
                            f"rename it to {self.path.stem}.bag")
                if len(parts) > 1:
                    others = ", ".join(p.name for p in parts[1:])
                    hint += f" (read as one with its split parts {others}: it may be one of them)"
                raise LogFormatError(f"{self.path}: not a readable ROS bag ({exc}){hint}"
                                     ) from exc
            for c in self._reader.connections:
                name = _ros1_name(c.msgtype)
                old = self.topics.get(c.topic, (name, 0))
                self.topics[c.topic] = (name, old[1] + c.msgcount)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.is_mcap_file:
            self._fh.close()
        else:
            self._reader.close()

    def _open_mcap(self, rosbags: Any) -> None:
        try:
            from mcap.reader import make_reader
        except ImportError as exc:
            raise ImportError(
                f"{self.path}: reading .mcap files needs mcap: pip install 'diffbot-fusion[ros]'"
            ) from exc
        typesys = rosbags.typesys
        size = self.path.stat().st_size
        self._fh = self.path.open("rb")
        magic = self._fh.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            self._fh.close()
            why = ("the file is empty" if size == 0 else
                   f"it does not start with the MCAP magic bytes {MCAP_MAGIC!r} (found "
                   f"{magic!r}): not an MCAP file")
            raise LogFormatError(f"{self.path}: not a readable MCAP file ({why})")
        self._fh.seek(0)
        try:
            self._mcap = make_reader(self._fh)
            summary = self._mcap.get_summary()
        except Exception:  # mcap's errors, struct errors: no usable summary at the end
            summary = None
        self._streamed = summary is None
        if summary is None:  # an unfinished recording (killed writer): read what is complete
            schemas, channels, counts = self._scan_mcap(size)
        else:
            schemas, channels = summary.schemas, summary.channels
            counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self._ts = typesys.get_typestore(typesys.Stores.EMPTY)
        self._encoding: dict[str, tuple[str, str]] = {}
        for ch in channels.values():
            schema = schemas.get(ch.schema_id)
            if schema is None or schema.encoding not in ("ros2msg", "ros1msg"):
                continue  # not a ROS message (protobuf, JSON...): not ours to read
            rostype = _ros2_name(schema.name)
            try:
                self._ts.register(typesys.get_types_from_msg(schema.data.decode(), rostype))
            except Exception as exc:
                raise LogFormatError(
                    f"{self.path}: topic {ch.topic}: bad {schema.encoding} schema "
                    f"{schema.name!r} ({exc})") from exc
            self._encoding[ch.topic] = (ch.message_encoding, rostype)
            name = _ros1_name(rostype)
            old = self.topics.get(ch.topic, (name, 0))
            self.topics[ch.topic] = (name, old[1] + counts.get(ch.id, 0))

    def _stream_mcap(self) -> Iterator[tuple[Any, Any, Any]]:
        """``(schema, channel, message)`` read front to back, up to the last complete record
        (no summary needed); sets ``self.truncated`` when the file ends inside a record."""
        from mcap.reader import NonSeekingReader

        self._fh.seek(0)
        try:
            yield from NonSeekingReader(self._fh).iter_messages(log_time_order=False)
        except Exception:  # EndOfFile, struct.error, a cut chunk: which one depends on the cut
            if self._fh.tell() < self.path.stat().st_size:
                raise  # it failed before the end: a corrupt record, not a cut one
            self.truncated = True

    def _scan_mcap(self, size: int) -> tuple[dict, dict, dict[int, int]]:
        """Schemas, channels and message counts of an MCAP file without a summary section."""
        schemas: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        counts: dict[int, int] = {}
        try:
            for schema, channel, _msg in self._stream_mcap():
                if schema is not None:
                    schemas[schema.id] = schema
                channels[channel.id] = channel
                counts[channel.id] = counts.get(channel.id, 0) + 1
        except Exception as exc:  # a corrupt record (not merely a missing end)
            self._fh.close()
            raise LogFormatError(f"{self.path}: not a readable MCAP file (no summary section, "
                                 f"and reading it from the start failed: {exc!r})") from exc
        n = sum(counts.values())
        if self.truncated:
            self.note = (f"{self.path}: unfinished MCAP recording ({size} bytes, no summary "
                         f"section: its writer was stopped abruptly); read the {n} complete "
                         "messages, up to the last complete chunk (`mcap recover` rewrites it "
                         "as a complete file)")
        if not n:
            self._fh.close()
            raise LogFormatError(f"{self.path}: not a readable MCAP file (no summary section "
                                 "and no complete message: an unfinished recording stopped "
                                 "before its first sync?)")
        return schemas, channels, counts

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any, str | None]]:
        """``(topic, bag time ns, message, publisher)`` of the given topics, in the bag's
        record order; ``publisher`` is the node a ROS 1 bag recorded it from (its
        connection's callerid), None where the format does not say (ROS 2 bags, MCAP)."""
        if self.is_mcap_file:
            wanted = set(topics)
            if self._streamed:
                source = (m for m in self._stream_mcap() if m[1].topic in wanted)
            else:
                source = self._mcap.iter_messages(topics=list(topics))
            for _schema, ch, msg in source:
                encoding, rostype = self._encoding[ch.topic]
                if encoding == "cdr":
                    obj = self._ts.deserialize_cdr(msg.data, rostype)
                elif encoding == "ros1":
                    obj = self._ts.deserialize_ros1(msg.data, rostype)
                else:
                    raise LogFormatError(f"{self.path}: topic {ch.topic}: message encoding "
                                         f"{encoding!r} is neither cdr nor ros1")
                yield ch.topic, msg.log_time, obj, None
            return
        conns = [c for c in self._reader.connections if c.topic in topics]
        for c, ns, raw in self._reader.messages(connections=conns):
            yield (c.topic, ns, self._reader.deserialize(raw, c.msgtype),
                   getattr(c.ext, "callerid", None))


def open_bag(path: str | Path) -> _BagFile:
    """A bag or MCAP file to read, as a context manager: ``topics`` (as :func:`bag_topics`)
    and ``messages(topics)``, ``(topic, record time ns, message, publisher or None)`` in
    record order (for topics :func:`read_bag` does not read, e.g. ``/tf_static``)."""
    return _BagFile(Path(path))


def bag_topics(path: str | Path) -> dict[str, tuple[str, int]]:
    """Every topic of a bag or MCAP file: ``{topic: (type as pkg/Type, message count)}``."""
    with _BagFile(Path(path)) as bag:
        return dict(bag.topics)


def _describe_topics(topics: dict[str, tuple[str, int]]) -> str:
    if not topics:
        return "the file has no ROS topics"
    return "topics present: " + ", ".join(
        f"{t} ({typ}, {n} messages)" for t, (typ, n) in sorted(topics.items()))


def _stamp(header: Any) -> float:
    """header.stamp in s (integer seconds plus nanoseconds, as ROS's to_sec())."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _ns_to_s(ns: int) -> float:
    """Integer nanoseconds in s, computed like :func:`_stamp` so both agree exactly."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return sec + nsec * 1e-9


class _Collector:
    """Rows of one topic: the stamp source, frame ids, and per-message values."""

    def __init__(self, path: Path, topic: str, kind: str, msgtype: str, stamps: str) -> None:
        self.path, self.topic, self.kind, self.msgtype = path, topic, kind, msgtype
        self.use_header = stamps == "header" and msgtype != "geometry_msgs/Twist"
        self.t: list[float] = []
        self.bag_t: list[float] = []
        self.rows: list[tuple[float, ...]] = []
        self.frames: dict[str, str] = {}
        self.note = ""  # what arrays() did: repeated stamps, absent accelerations
        self.no_accel = 0  # IMU messages whose linear acceleration was flagged as absent
        # publisher (a ROS 1 connection's callerid) -> [messages, first, last record time s]
        self.publishers: dict[str, list[float]] = {}

    def _check_publishers(self, where: str) -> None:
        """Refuse a topic two nodes published at once (record-time spans overlapping by
        more than :data:`PUBLISHER_OVERLAP`): merged, their messages interleave (a driver and
        a filter remapped onto one odometry topic had been fused as one robot: 3.6 m of GPS
        RMSE on the terrain outdoor bag, no word). One after the other (a node restarted
        under a new name) is one stream."""
        spans = sorted(self.publishers.items(), key=lambda item: item[1][1])
        for (a, (na, a0, a1)), (b, (nb, b0, b1)) in itertools.combinations(spans, 2):
            if min(a1, b1) - max(a0, b0) > PUBLISHER_OVERLAP:
                raise LogFormatError(
                    f"{where}: published by two nodes at once, {a} ({na:.0f} messages, "
                    f"recorded {a0:.3f}-{a1:.3f} s) and {b} ({nb:.0f}, {b0:.3f}-{b1:.3f} s): "
                    "their messages interleave, and fused as one stream they describe two "
                    "robots; keep one node's messages (the bag's connections name each "
                    "node as their callerid) or record each on its own topic")

    def _frame(self, key: str, value: str) -> None:
        old = self.frames.setdefault(key, value)
        if old != value:
            raise LogFormatError(
                f"{self.path}: topic {self.topic}: {key} changes from {old!r} to {value!r} "
                f"at message {len(self.t) + 1}")

    def add(self, ns: int, msg: Any, publisher: str | None = None) -> None:
        if publisher is not None:
            seen = self.publishers.setdefault(publisher, [0, _ns_to_s(ns), 0.0])
            seen[0] += 1
            seen[2] = _ns_to_s(ns)
        header = getattr(msg, "header", None)
        if header is not None:
            self._frame("frame_id", header.frame_id)
        if self.kind == "odometry":
            self._frame("child_frame_id", msg.child_frame_id)
        bag_t = _ns_to_s(ns)
        self.bag_t.append(bag_t)
        self.t.append(_stamp(header) if self.use_header else bag_t)
        if self.kind == "imu":
            q, a, g = msg.orientation, msg.linear_acceleration, msg.angular_velocity
            no_q = msg.orientation_covariance[0] == -1 or (q.w == q.x == q.y == q.z == 0)
            if msg.angular_velocity_covariance[0] == -1:  # REP-145: "not provided"
                raise LogFormatError(
                    f"{self.path}: topic {self.topic}: message {len(self.t)} says it has no "
                    "angular velocity (angular_velocity_covariance[0] = -1): the fusion needs "
                    "the gyro's rates in every message (an orientation-only IMU driver?)")
            accel = (a.x, a.y, a.z)
            if msg.linear_acceleration_covariance[0] == -1:
                # not provided: zero rows, which the attitude filter propagates without and
                # the accelerometer checks leave out
                accel = (0.0, 0.0, 0.0)
                self.no_accel += 1
            self.rows.append((g.x, g.y, g.z, *accel,
                              *((math.nan,) * 4 if no_q else (q.w, q.x, q.y, q.z))))
        elif self.kind == "odometry":
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
            yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            self.rows.append((p.x, p.y, yaw, lin.x, lin.y, ang.z,
                              *msg.pose.covariance, *msg.twist.covariance))
        elif self.kind == "fix":
            self.rows.append((msg.latitude, msg.longitude, msg.altitude, msg.status.status,
                              *msg.position_covariance, msg.position_covariance_type))
        else:
            tw = msg.twist if self.msgtype == "geometry_msgs/TwistStamped" else msg
            self.rows.append((tw.linear.x, tw.linear.y, tw.angular.z))

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                              int]:
        """``(t, bag_time, rows)`` sorted by t, and how many messages were out of order."""
        where = f"{self.path}: topic {self.topic}"
        if not self.t:
            raise LogFormatError(f"{where}: no messages")
        self._check_publishers(where)
        t = np.asarray(self.t, dtype=np.float64)
        if self.use_header and not np.any(t > 0):
            raise LogFormatError(f"{where}: every header.stamp is zero; read it with "
                                 "stamps='bag' (the bag's record times; `fusion replay "
                                 "--stamps bag`)")
        rows = np.asarray(self.rows, dtype=np.float64)
        # a NavSatFix without a fix has NaN coordinates by definition: _fix_log leaves it out
        check = {"twist": rows, "fix": rows[:, 3:4]}.get(self.kind, rows[:, :6])
        bad = np.flatnonzero(~np.all(np.isfinite(check), axis=1))
        bag_t = np.asarray(self.bag_t, dtype=np.float64)
        notes = []
        if bad.size:
            i = int(bad[0])
            first = (f"message {i + 1} (t = {t[i]:.9f} s) has a non-finite value: "
                     f"{check[i].tolist()}")
            if bad.size > NONFINITE_SHARE * t.size:
                raise LogFormatError(f"{where}: {bad.size} of its {t.size} messages have a "
                                     f"non-finite value (more than {NONFINITE_SHARE:.0%}: a "
                                     f"driver's fault, not a glitch); {first}")
            keep = np.ones(t.size, dtype=bool)
            keep[bad] = False
            t, bag_t, rows = t[keep], bag_t[keep], rows[keep]
            notes.append(f"{where}: {bad.size} message(s) with a non-finite value left out "
                         f"(the first: {first})")
        if self.use_header:
            t, bag_t, rows, stray_note = _without_stray_stamps(where, t, bag_t, rows)
            if stray_note:
                notes.append(stray_note)
        running_max = np.maximum.accumulate(t)
        out_of_order = int(np.count_nonzero(t[1:] < running_max[:-1]))
        if out_of_order:
            order = np.argsort(t, kind="stable")
            t, bag_t, rows = t[order], bag_t[order], rows[order]
        if self.no_accel:
            notes.append(f"{where}: {self.no_accel} of {t.size} messages have no linear "
                         "acceleration (linear_acceleration_covariance[0] = -1): read as zero "
                         "(stillness from the gyro alone; without any, no tilt compensation)")
        if self.kind in _SPREAD_COLUMNS:
            fix = spread_repeated_stamps(t, rows[:, _SPREAD_COLUMNS[self.kind]], where,
                                         record_t=bag_t if self.use_header else None)
            if fix.note:
                t, bag_t, rows = fix.t, bag_t[fix.keep], rows[fix.keep]
                notes.append(fix.note)
        self.note = "; ".join(notes)
        return t, bag_t, rows, out_of_order


#: Largest share of a topic's messages with a NaN or infinite value that are left out, with a
#: note, as glitches (one in an hour-long bag had refused the whole bag); more is refused.
NONFINITE_SHARE = 0.1

#: s: two publishers of one topic whose record-time spans overlap by more than this publish
#: at once (refused); less is one node after the other (a restart under a new name).
PUBLISHER_OVERLAP = 1.0

#: s: a header stamp further than this from its message's record time, against the median of
#: that difference over the topic (a stable transport and recording latency), is stray: a
#: corrupt stamp, or a clock that jumped. Sorting such stamps in lays hours of nothing (or
#: two stretches of the run interleaved) into the replay.
STAMP_OFFSET_LIMIT = 10.0
#: Largest share of a topic's messages with stray stamps that are left out as corrupt; more
#: is a clock that jumped, refused with the way out (the record times).
STRAY_STAMP_SHARE = 0.01


def _without_stray_stamps(where: str, t: NDArray[np.float64], bag_t: NDArray[np.float64],
                          rows: NDArray[np.float64]
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                     NDArray[np.float64], str]:
    """``(t, bag_t, rows, note)`` without the messages whose header stamp strays from their
    record time (:data:`STAMP_OFFSET_LIMIT`), and a note naming them ("" when none did).

    Raises:
        LogFormatError: more than :data:`STRAY_STAMP_SHARE` of the messages stray.
    """
    offset = t - bag_t
    usual = float(np.median(offset))
    stray = np.abs(offset - usual) > STAMP_OFFSET_LIMIT
    n = int(np.count_nonzero(stray))
    if not n:
        return t, bag_t, rows, ""
    first = int(np.flatnonzero(stray)[0])
    if n > STRAY_STAMP_SHARE * t.size:
        jump = int(np.flatnonzero(np.abs(offset - offset[0]) > STAMP_OFFSET_LIMIT)[0])
        raise LogFormatError(
            f"{where}: {n} of {t.size} header stamps are more than {STAMP_OFFSET_LIMIT:g} s "
            "off the usual difference from when the bag recorded their messages: "
            f"header.stamp - record time is {offset[0]:+.3f} s at message 1 and "
            f"{offset[jump]:+.3f} s at message {jump + 1}; the stamping clock jumped. Read "
            "the bag with its record times (`fusion replay --stamps bag`)")
    numbers = ", ".join(str(i + 1) for i in np.flatnonzero(stray)[:5])
    more = f" and {n - 5} more" if n > 5 else ""
    note = (f"{where}: {n} messages (number {numbers}{more}) left out: their header stamps "
            f"are more than {STAMP_OFFSET_LIMIT:g} s off when the bag recorded them (e.g. "
            f"{offset[first] - usual:+.1f} s against the others), corrupt stamps")
    keep = ~stray
    return t[keep], bag_t[keep], rows[keep], note


#: The row columns a repeated stamp's messages are compared on (a copy equals in all of
#: them; :func:`fusion.io.repeated_stamps.spread_repeated_stamps`): the IMU's rates and
#: specific force, the odometry's pose and twist, the twist. Not GPS fixes (a receiver
#: repeats its fix at its own rate).
_SPREAD_COLUMNS = {"imu": slice(0, 6), "odometry": slice(0, 6), "twist": slice(0, 3)}

_KINDS = {"imu": IMU_TYPES, "odometry": ODOMETRY_TYPES, "twist": TWIST_TYPES,
          "fix": FIX_TYPES}


def read_bag(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    odom_topic: str | None = None,
    twist_topic: str | None = None,
    stamps: str = "header",
    fix_topic: str | None = None,
) -> BagLog:
    """Read IMU, odometry, twist and GPS fix topics of a bag or MCAP file in one pass.

    Args:
        path: ROS 1 ``.bag``, ROS 2 bag folder, or ``.mcap`` file.
        imu_topic: a sensor_msgs/Imu topic (e.g. ``/imu/data``), or None.
        odom_topic: a nav_msgs/Odometry topic (e.g. ``/odom``), or None.
        twist_topic: a geometry_msgs/Twist or TwistStamped topic (e.g. ``/cmd_vel``), or None.
        fix_topic: a sensor_msgs/NavSatFix topic (e.g. ``/gps/fix``), or None.
        stamps: ``"header"`` (each message's header.stamp) or ``"bag"`` (record times).

    Raises:
        FileNotFoundError: no such path.
        LogFormatError: not a bag; a topic missing (the message lists the topics present),
            of another type, empty, with changing frame ids, zero stamps or non-finite values
            (a fix topic: no message with a fix).
        ImportError: rosbags (or mcap for .mcap files) is not installed.
    """
    path = Path(path)
    if stamps not in ("header", "bag"):
        raise ValueError(f"stamps must be 'header' or 'bag', got {stamps!r}")
    wanted = {k: t for k, t in (("imu", imu_topic), ("odometry", odom_topic),
                                ("twist", twist_topic), ("fix", fix_topic)) if t is not None}
    if not wanted:
        raise ValueError("give at least one of imu_topic, odom_topic, twist_topic, fix_topic")
    if len(set(wanted.values())) != len(wanted):
        raise ValueError(f"one topic cannot be read as two kinds: {wanted}")
    with _BagFile(path) as bag:
        collectors: dict[str, _Collector] = {}
        for kind, topic in wanted.items():
            if topic not in bag.topics:
                raise LogFormatError(
                    f"{path}: no topic {topic!r}; {_describe_topics(bag.topics)}")
            msgtype = bag.topics[topic][0]
            if msgtype not in _KINDS[kind]:
                raise LogFormatError(
                    f"{path}: topic {topic} is {msgtype}, expected {' or '.join(_KINDS[kind])}")
            collectors[topic] = _Collector(path, topic, kind, msgtype, stamps)
        try:
            for topic, ns, msg, publisher in bag.messages(list(collectors)):
                collectors[topic].add(ns, msg, publisher)
        except LogFormatError:
            raise
        except Exception as exc:  # a truncated chunk, a message that does not decode
            raise LogFormatError(
                f"{path}: reading {', '.join(collectors)} failed: {exc!r}") from exc
        topics, note = dict(bag.topics), bag.note
    log = BagLog(
        imu=_imu_log(collectors.get(imu_topic)) if imu_topic else None,
        odometry=_odometry_log(collectors.get(odom_topic)) if odom_topic else None,
        twist=_twist_log(collectors.get(twist_topic)) if twist_topic else None,
        topics=topics, source=str(path), note=note,
        fixes=_fix_log(collectors.get(fix_topic)) if fix_topic else None,
    )
    log.topic_notes = tuple(c.note for c in collectors.values() if c.note)
    return log


def _imu_log(c: _Collector) -> BagImuLog:
    t, bag_t, rows, ooo = c.arrays()
    q = np.ascontiguousarray(rows[:, 6:10])
    has_q = np.all(np.isfinite(q), axis=1)
    if has_q.any():
        q[has_q] /= np.linalg.norm(q[has_q], axis=1, keepdims=True)
    return BagImuLog(
        t=t, gyro=np.ascontiguousarray(rows[:, 0:3]), accel=np.ascontiguousarray(rows[:, 3:6]),
        source=str(c.path), orientation=q if has_q.any() else None,
        frame_id=c.frames.get("frame_id", ""), topic=c.topic, bag_time=bag_t, out_of_order=ooo,
    )


def _odometry_log(c: _Collector) -> OdometryLog:
    t, bag_t, rows, ooo = c.arrays()
    col = [np.ascontiguousarray(rows[:, i]) for i in range(6)]
    return OdometryLog(
        t=t, x=col[0], y=col[1], yaw=col[2], v=col[3], vy=col[4], w=col[5],
        pose_covariance=np.ascontiguousarray(rows[:, 6:42]),
        twist_covariance=np.ascontiguousarray(rows[:, 42:78]),
        frame_id=c.frames.get("frame_id", ""), child_frame_id=c.frames.get("child_frame_id", ""),
        topic=c.topic, source=str(c.path), bag_time=bag_t, out_of_order=ooo,
    )


def _twist_log(c: _Collector) -> TwistLog:
    t, bag_t, rows, ooo = c.arrays()
    return TwistLog(
        t=t, v=np.ascontiguousarray(rows[:, 0]), vy=np.ascontiguousarray(rows[:, 1]),
        w=np.ascontiguousarray(rows[:, 2]), frame_id=c.frames.get("frame_id", ""),
        topic=c.topic, source=str(c.path), bag_time=bag_t, out_of_order=ooo,
    )


def _fix_log(c: _Collector) -> FixLog:
    t, bag_t, rows, ooo = c.arrays()
    # latitude and longitude both exactly 0 ("null island", in the Gulf of Guinea): a receiver
    # or driver that fills in zeros without a fix, whatever its status says (an independent
    # probe's three such fixes made the printed GPS RMSE 186541 m)
    has = ((rows[:, 3] >= 0) & np.isfinite(rows[:, 0]) & np.isfinite(rows[:, 1])
           & ~((rows[:, 0] == 0.0) & (rows[:, 1] == 0.0)))
    wild = np.flatnonzero(has & ((np.abs(rows[:, 0]) > 90.0) | (np.abs(rows[:, 1]) > 180.0)))
    if wild.size:
        i = int(wild[0])
        raise LogFormatError(
            f"{c.path}: topic {c.topic}: message {i + 1} (t = {t[i]:.9f} s) has latitude "
            f"{float(rows[i, 0])!r}, longitude {float(rows[i, 1])!r}: not degrees in [-90, 90] and "
            f"[-180, 180] (NMEA ddmm.mmmm values not converted?)")
    if not np.any(has):
        raise LogFormatError(f"{c.path}: topic {c.topic}: none of its {len(t)} messages holds "
                             f"a fix (status.status < 0, no latitude/longitude, or both 0)")
    alt = rows[has, 2]
    known = np.isfinite(alt)
    alt = np.where(known, alt, alt[known][0] if np.any(known) else 0.0)
    return FixLog(
        t=t[has], latitude=np.ascontiguousarray(rows[has, 0]),
        longitude=np.ascontiguousarray(rows[has, 1]), altitude=alt,
        status=rows[has, 3].astype(np.int64),
        position_covariance=np.ascontiguousarray(rows[has, 4:13]),
        covariance_type=rows[has, 13].astype(np.int64),
        no_fix=int(np.count_nonzero(~has)), frame_id=c.frames.get("frame_id", ""),
        topic=c.topic, source=str(c.path), bag_time=bag_t[has], out_of_order=ooo,
    )


def read_bag_fixes(path: str | Path, topic: str = "/gps/fix", *,
                   stamps: str = "header") -> FixLog:
    """sensor_msgs/NavSatFix of one topic, the messages with a fix (see :func:`read_bag`)."""
    log = read_bag(path, fix_topic=topic, stamps=stamps).fixes
    assert log is not None
    return log


def read_bag_imu(path: str | Path, topic: str = "/imu/data", *,
                 stamps: str = "header") -> BagImuLog:
    """sensor_msgs/Imu of one topic (see :func:`read_bag`)."""
    log = read_bag(path, imu_topic=topic, stamps=stamps).imu
    assert log is not None
    return log


def read_bag_odometry(path: str | Path, topic: str = "/odom", *,
                      stamps: str = "header") -> OdometryLog:
    """nav_msgs/Odometry of one topic (see :func:`read_bag`)."""
    log = read_bag(path, odom_topic=topic, stamps=stamps).odometry
    assert log is not None
    return log


def read_bag_twist(path: str | Path, topic: str = "/cmd_vel", *,
                   stamps: str = "header") -> TwistLog:
    """geometry_msgs/Twist or TwistStamped of one topic (see :func:`read_bag`)."""
    log = read_bag(path, twist_topic=topic, stamps=stamps).twist
    assert log is not None
    return log
