"""Sinks for fused odometry: JSON lines, CSV, rosbag2/MCAP files, a Foxglove live server, ROS 1.

Every sink has the same small interface: ``open()``, ``write(record)`` with a
:class:`fusion.fused.FusedOdometry`, ``close()``, and use as a context manager (``with sink:``
opens it and closes it; an exception inside the block calls ``abort()`` instead, which for file
sinks discards the partial output and leaves any existing file untouched).

The ROS-shaped sinks publish seed 000's interface (topics configurable through :class:`Topics`):

=====================  ======================  =================================================
topic                  type                    content
=====================  ======================  =================================================
``/odom``              nav_msgs/Odometry       pose of ``child_frame_id`` in ``frame_id`` (m,
                                               yaw-only quaternion), twist in the child frame
                                               (m/s, rad/s), both covariances (6x6 row major)
``/tf``                tf2_msgs/TFMessage      ``frame_id`` -> ``child_frame_id`` (odom ->
                                               base_footprint)
``/imu/data``          sensor_msgs/Imu         attitude (if known, else orientation covariance
                                               [0] = -1), body rate rad/s, specific force m/s^2
                                               (if known, else its covariance [0] = -1)
``/wheel_left_speed``  std_msgs/Float32        left wheel rim speed, m/s (when the record has it)
``/wheel_right_speed`` std_msgs/Float32        right wheel rim speed, m/s
=====================  ======================  =================================================

Stamps are the record's ``t`` (s) as integer nanoseconds; ROS time cannot be negative, so a
record with ``t < 0`` is a ValueError in the ROS-shaped sinks. The two live sinks (the ROS 1
node and the Foxglove server) also take velocity commands on ``/cmd_vel``
(geometry_msgs/Twist) and hand ``(linear.x m/s, angular.z rad/s)`` to an ``on_cmd_vel``
callback.

Optional dependencies: ``rosbags`` for the bag sinks (``pip install 'diffbot-fusion[ros]'``),
``foxglove-sdk`` for the live server (``[foxglove]``), Debian's ``python3-rospy`` and message
packages for the ROS 1 node (:mod:`fusion.ros1`). They are imported when a sink opens.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import shutil
import struct
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from fusion.fused import FusedOdometry

__all__ = [
    "FUSED_RECORD_CSV_COLUMNS",
    "CsvSink",
    "FoxgloveSink",
    "JsonLinesSink",
    "McapSink",
    "Rosbag2Sink",
    "Sink",
    "SinkError",
    "Topics",
    "create_temp_file",
    "encode_cdr",
    "open_sink",
    "ros_messages",
    "stamp_ns",
]


class SinkError(RuntimeError):
    """A sink used out of order (write before open, after close) or a failed output."""


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
    record: FusedOdometry, topics: Topics | None = None
) -> list[tuple[str, str, str, dict[str, Any]]]:
    """The ROS messages of one record as plain nested dicts, library neutral.

    Returns ``[(key, topic, msgtype, fields), ...]`` in the order odom, tf, imu, wheel_left,
    wheel_right, skipping topics set to None and wheel speeds the record does not have.
    ``key`` is the :class:`Topics` field name, ``msgtype`` the ROS 1 spelling
    (``nav_msgs/Odometry``). Header stamps are integer nanoseconds (:func:`stamp_ns`); each
    backend turns ``stamp`` into its own time type. Arrays (covariances) are float lists.
    """
    topics = topics or Topics()
    ns = stamp_ns(record.t)
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
    if topics.imu:
        unknown = [-1.0] + [0.0] * 8  # sensor_msgs/Imu: element 0 = -1 means "not provided"
        has_q = record.orientation is not None
        has_a = record.linear_acceleration is not None
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


class Sink:
    """Base of all sinks: ``open()``, ``write(record)``, ``close()``, ``abort()``.

    ``with sink:`` opens, and on leaving closes (normal exit) or aborts (an exception).
    Subclasses implement ``_open``, ``_write``, ``_close`` and optionally ``_abort``.
    """

    def __init__(self) -> None:
        self._state = "new"
        self.records_written = 0

    @property
    def is_open(self) -> bool:
        """True between ``open()`` and ``close()``/``abort()``."""
        return self._state == "open"

    def open(self) -> None:
        """Acquire the output (file, server, node); a sink opens once."""
        if self._state != "new":
            raise SinkError(f"{self!r} was already opened")
        self._open()
        self._state = "open"

    def write(self, record: FusedOdometry) -> None:
        """Publish or store one record."""
        if self._state != "open":
            raise SinkError(f"{self!r} is not open (state {self._state})")
        if not isinstance(record, FusedOdometry):
            raise TypeError(f"sinks take FusedOdometry records, got {type(record).__name__}")
        self._write(record)
        self.records_written += 1

    def close(self) -> None:
        """Finish the output (files are complete and in place after this)."""
        if self._state == "open":
            self._state = "closed"
            self._close()

    def abort(self) -> None:
        """Stop without finishing: file sinks discard their partial output."""
        if self._state == "open":
            self._state = "aborted"
            self._abort()

    def __enter__(self) -> Sink:
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _open(self) -> None:
        pass

    def _write(self, record: FusedOdometry) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        pass

    def _abort(self) -> None:
        self._close()


def _temp_sibling(path: Path, *, directory: bool) -> Path:
    """A fresh temporary name next to ``path`` (same file system, so a rename is atomic)."""
    parent = path.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"{path}: the folder {parent} does not exist")
    prefix = f".{path.name}."
    if directory:
        # private while being built; only the bag folder made inside it is moved into place
        return Path(tempfile.mkdtemp(prefix=prefix, suffix=".partial", dir=parent))
    return create_temp_file(path)


def create_temp_file(path: Path) -> Path:
    """Create a fresh empty file next to ``path`` (``.<name>.<random>.partial``) with the
    permissions an ordinary ``open(path, "w")`` would give (0666 minus the umask: 0644 under
    umask 022), so the renamed output is not private the way a :func:`tempfile.mkstemp` file
    (0600) would be."""
    for _ in range(100):
        name = path.parent / f".{path.name}.{secrets.token_hex(6)}.partial"
        try:
            fd = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return name
    raise FileExistsError(f"{path}: could not create a temporary file next to it")


class JsonLinesSink(Sink):
    """One JSON object per record and line (:meth:`FusedOdometry.to_dict`).

    Args:
        target: a text stream (default ``sys.stdout``; flushed after each line, never closed
            by the sink), or a path written to a temporary file and renamed into place on
            close (so an existing file is replaced only by a complete one).
        flush: flush the stream after each line (live use).
    """

    def __init__(self, target: IO[str] | str | Path | None = None, *, flush: bool = True):
        super().__init__()
        self._target = target
        self._flush = flush
        self._stream: IO[str] | None = None
        self._tmp: Path | None = None

    def __repr__(self) -> str:
        return f"JsonLinesSink({self._target if self._target is not None else 'stdout'})"

    def _open(self) -> None:
        if self._target is None or self._target == "-":
            self._stream = sys.stdout
        elif isinstance(self._target, (str, Path)):
            path = Path(self._target)
            self._tmp = _temp_sibling(path, directory=False)
            self._stream = self._tmp.open("w", encoding="utf-8")
        else:
            self._stream = self._target

    def _write(self, record: FusedOdometry) -> None:
        assert self._stream is not None
        self._stream.write(json.dumps(record.to_dict(), allow_nan=False,
                                      separators=(",", ":")) + "\n")
        if self._flush:
            self._stream.flush()

    def _close(self) -> None:
        if self._tmp is not None:
            assert self._stream is not None
            self._stream.close()
            self._tmp.replace(Path(self._target))  # type: ignore[arg-type]
            self._tmp = None

    def _abort(self) -> None:
        if self._tmp is not None:
            assert self._stream is not None
            self._stream.close()
            self._tmp.unlink(missing_ok=True)
            self._tmp = None


#: Columns of :class:`CsvSink` (the first six as in ``fusion replay``'s CSV).
FUSED_RECORD_CSV_COLUMNS = (
    "t", "x", "y", "yaw", "v", "w", "var_x", "var_y", "var_yaw", "cov_xy", "cov_x_yaw",
    "cov_y_yaw", "var_v", "var_w", "wheel_left_speed", "wheel_right_speed",
)


class CsvSink(Sink):
    """Fused records as CSV rows (:data:`FUSED_RECORD_CSV_COLUMNS`), one per record.

    ``t`` s; ``x, y`` m and ``yaw`` rad (wrapped to (-pi, pi]) of ``child_frame_id`` in
    ``frame_id``; ``v`` m/s, ``w`` rad/s; the pose covariance terms of x, y, yaw (m^2, m*rad,
    rad^2) and the twist variances of vx and wz from the record's 6x6 matrices; wheel speeds
    m/s (empty when the record has none). Numbers are written with Python's shortest exact
    repr, so equal records give byte-identical files. Written to a temporary file and renamed
    into place on close, like :class:`JsonLinesSink`.
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        self.path = Path(path)
        self._tmp: Path | None = None
        self._fh: IO[str] | None = None

    def __repr__(self) -> str:
        return f"CsvSink({str(self.path)!r})"

    def _open(self) -> None:
        self._tmp = _temp_sibling(self.path, directory=False)
        self._fh = self._tmp.open("w", encoding="ascii", newline="\n")
        self._fh.write(",".join(FUSED_RECORD_CSV_COLUMNS) + "\n")

    def _write(self, record: FusedOdometry) -> None:
        assert self._fh is not None
        P, Q = record.pose_covariance, record.twist_covariance
        yaw = math.remainder(record.yaw, math.tau)
        if yaw == -math.pi:
            yaw = math.pi
        values = (record.t, record.x, record.y, yaw, record.v, record.w, P[0, 0], P[1, 1],
                  P[5, 5], P[0, 1], P[0, 5], P[1, 5], Q[0, 0], Q[5, 5])
        speeds = (record.wheel_left_speed, record.wheel_right_speed)
        self._fh.write(",".join([*(repr(float(v)) for v in values),
                                 *("" if s is None else repr(s) for s in speeds)]) + "\n")

    def _close(self) -> None:
        if self._tmp is not None and self._fh is not None:
            self._fh.close()
            self._tmp.replace(self.path)
            self._tmp = None

    def _abort(self) -> None:
        if self._tmp is not None and self._fh is not None:
            self._fh.close()
            self._tmp.unlink(missing_ok=True)
            self._tmp = None


def _need(module: str, extra: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(
            f"this sink needs the {module.split('.')[0]!r} package: "
            f"pip install 'diffbot-fusion[{extra}]'"
        ) from exc


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


class Rosbag2Sink(Sink):
    """A rosbag2 recording (folder with ``metadata.yaml``) of the topics of :class:`Topics`.

    Written with the ``rosbags`` package in ROS 2 CDR encoding (Jazzy message definitions; the
    five message types are identical in every ROS 2 distribution) with bag metadata version 8,
    the oldest that ``rosbags`` writes (a ROS 2 release older than that metadata version may
    refuse ``metadata.yaml``; the MCAP data file inside is self-contained). The bag is built in a
    temporary folder next to ``path`` and renamed into place on close; an existing bag at
    ``path`` is a FileExistsError at ``open()`` unless ``overwrite=True``, and is replaced only
    by a complete one.

    Args:
        path: the bag folder to create.
        storage: ``"mcap"`` (default) or ``"sqlite3"``.
        topics: topic names (:class:`Topics`).
        overwrite: replace an existing bag at ``path``.
        compression: ``"zstd"`` compresses MCAP chunks (every MCAP reader, Foxglove and
            ``ros2 bag`` included, reads them; files several times smaller); None does not;
            ``"auto"`` (default) is zstd for MCAP, none for sqlite3.
    """

    def __init__(self, path: str | Path, *, storage: str = "mcap", topics: Topics | None = None,
                 overwrite: bool = False, compression: str | None = "auto") -> None:
        super().__init__()
        if storage not in ("mcap", "sqlite3"):
            raise ValueError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
        if compression == "auto":
            compression = "zstd" if storage == "mcap" else None
        if compression not in (None, "zstd") or (compression and storage != "mcap"):
            raise ValueError(f"compression must be None or 'zstd' (MCAP storage only), got "
                             f"{compression!r} with {storage}")
        self.path = Path(path)
        self.storage = storage
        self.compression = compression
        self.topics = topics or Topics()
        self.overwrite = overwrite
        self._tmpdir: Path | None = None
        self._writer: Any = None
        self._connections: dict[str, Any] = {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r})"

    def _check_target(self) -> None:
        if self.path.exists() and not self.overwrite:
            raise FileExistsError(f"{self.path}: exists; choose another path or overwrite=True")

    def _open(self) -> None:
        rosbag2 = _need("rosbags.rosbag2", "ros")
        typesys = _need("rosbags.typesys", "ros")
        self._check_target()
        self._ts = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
        self._tmpdir = _temp_sibling(self.path, directory=True)
        plugin = {"mcap": rosbag2.StoragePlugin.MCAP,
                  "sqlite3": rosbag2.StoragePlugin.SQLITE3}[self.storage]
        try:
            self._writer = rosbag2.Writer(self._tmpdir / self._bag_name(), version=8,
                                          storage_plugin=plugin)
            if self.compression == "zstd":  # zstd-compressed MCAP chunks
                self._writer.set_compression(rosbag2.CompressionMode.STORAGE,
                                             rosbag2.CompressionFormat.ZSTD)
            self._writer.open()
            for key, topic in self.topics.as_dict().items():
                if topic is not None:
                    self._connections[key] = self._writer.add_connection(
                        topic, _ros2_type(MESSAGE_TYPES[key]), typestore=self._ts)
        except BaseException:
            self._discard()
            raise

    def _write(self, record: FusedOdometry) -> None:
        for key, _topic, msgtype, fields in ros_messages(record, self.topics):
            data = encode_cdr(msgtype, fields)
            self._writer.write(self._connections[key], stamp_ns(record.t), data)

    def _finish_writer(self) -> Path:
        assert self._writer is not None and self._tmpdir is not None
        writer, self._writer = self._writer, None
        writer.close()
        return self._tmpdir / self._bag_name()

    def _bag_name(self) -> str:
        return self.path.name

    def _close(self) -> None:
        try:
            built = self._finish_writer()
            self._install(built)
        except BaseException:
            self._discard()
            raise
        self._discard()

    def _install(self, built: Path) -> None:
        """Move the finished bag folder to ``path`` (replacing an old one if allowed)."""
        self._check_target()
        old = None
        if self.path.exists():
            assert self._tmpdir is not None
            old = self._tmpdir / (self.path.name + ".old")
            self.path.rename(old)
        try:
            built.rename(self.path)
        except BaseException:
            if old is not None:
                old.rename(self.path)
            raise

    def _discard(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            with contextlib.suppress(Exception):
                writer.close()
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def _abort(self) -> None:
        self._discard()


class McapSink(Rosbag2Sink):
    """One self-contained ``.mcap`` file (ROS 2 profile, CDR messages with their ``ros2msg``
    schemas) that Foxglove and any MCAP reader open directly.

    It is the data file of a :class:`Rosbag2Sink` bag with MCAP storage, moved to ``path`` by an
    atomic rename on close: an existing file at ``path`` is replaced only by a complete one
    (``overwrite`` defaults to True here, as for any single output file).
    """

    def __init__(self, path: str | Path, *, topics: Topics | None = None,
                 overwrite: bool = True, compression: str | None = "zstd") -> None:
        super().__init__(path, storage="mcap", topics=topics, overwrite=overwrite,
                         compression=compression)

    def _bag_name(self) -> str:
        # rosbags names the data file "<bag>.mcap" and records that name inside the file:
        # a bag named after the stem makes it the final name (and the bytes independent of
        # the temporary folder, so equal records give byte-identical files)
        return self.path.stem if self.path.suffix == ".mcap" else self.path.name

    def _install(self, built: Path) -> None:
        self._check_target()
        files = sorted(built.glob("*.mcap"))
        if len(files) != 1:
            raise SinkError(f"{self.path}: expected one MCAP file in the bag, found {files}")
        if self.path.is_dir():
            raise IsADirectoryError(f"{self.path}: is a folder, not an .mcap file path")
        files[0].replace(self.path)


# JSON schemas of the Foxglove sink's JSON channels (ROS field names, so layouts carry over).
_IMU_SCHEMA = {
    "title": "sensor_msgs/Imu",
    "type": "object",
    "properties": {
        "header": {"type": "object"},
        "orientation": {"type": "object"},
        "orientation_covariance": {"type": "array", "items": {"type": "number"}},
        "angular_velocity": {"type": "object"},
        "angular_velocity_covariance": {"type": "array", "items": {"type": "number"}},
        "linear_acceleration": {"type": "object"},
        "linear_acceleration_covariance": {"type": "array", "items": {"type": "number"}},
    },
}
_FLOAT32_SCHEMA = {"title": "std_msgs/Float32", "type": "object",
                   "properties": {"data": {"type": "number"}}}


def _json_header(fields: dict[str, Any]) -> dict[str, Any]:
    """Stamp ns -> ``{"sec", "nsec"}`` (Foxglove's JSON time) inside a message dict."""
    out = dict(fields)
    sec, nsec = divmod(out["header"]["stamp"], 1_000_000_000)
    out["header"] = {**out["header"], "stamp": {"sec": sec, "nsec": nsec}}
    return out


class FoxgloveSink(Sink):
    """A Foxglove WebSocket server (``foxglove-sdk``) streaming the fused odometry live.

    Channels (names from :class:`Topics`):

    - ``/odom``: ``foxglove.Odometry`` (protobuf): pose in ``frame_id`` with the yaw-only
      quaternion, linear velocity ``(v, 0, 0)`` m/s and angular velocity rad/s in the body
      frame, both 6x6 covariances row major.
    - ``/tf``: ``foxglove.FrameTransforms`` (protobuf): ``frame_id`` -> ``child_frame_id``.
    - ``/imu/data``: JSON with sensor_msgs/Imu's fields.
    - ``/wheel_left_speed``, ``/wheel_right_speed``: JSON ``{"data": m/s}``.

    Every message is logged with ``log_time`` = the record's stamp in ns. Open Foxglove and
    connect to ``ws://HOST:PORT``.

    Velocity commands: the server accepts client publishing (JSON) and hands each
    geometry_msgs/Twist a client sends on ``cmd_vel_topic`` (Foxglove's Teleop panel does) to
    ``on_cmd_vel(linear.x m/s, angular.z rad/s)``, like the ROS 1 node's /cmd_vel. It runs on
    the server's thread; malformed messages are counted in :attr:`cmd_vel_rejected`.

    Args:
        host: address to bind; default loopback. Binding to all interfaces (``0.0.0.0``)
            exposes the stream, and the command channel, to the network: do it deliberately.
        port: TCP port; 0 picks a free one (read it from :attr:`port` after ``open()``).
        topics: channel names.
        name: server name shown in the client.
        cmd_vel_topic: topic of client velocity commands, or None to refuse client publishing.
        on_cmd_vel: ``callback(v, w)`` for each valid command.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *,
                 topics: Topics | None = None, name: str = "diffbot-fusion",
                 cmd_vel_topic: str | None = "/cmd_vel",
                 on_cmd_vel: Callable[[float, float], None] | None = None) -> None:
        super().__init__()
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be 0..65535, got {port}")
        self.host = host
        self._port = int(port)
        self.topics = topics or Topics()
        self.name = name
        self.cmd_vel_topic = cmd_vel_topic
        self.on_cmd_vel = on_cmd_vel
        self.cmd_vel_received = 0
        self.cmd_vel_rejected = 0
        self._client_channels: dict[tuple[int, int], tuple[str, str]] = {}
        self._server: Any = None
        self._channels: dict[str, Any] = {}

    def __repr__(self) -> str:
        return f"FoxgloveSink({self.host}:{self._port})"

    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one when opened with 0)."""
        return self._server.port if self._server is not None else self._port

    def _open(self) -> None:
        foxglove = _need("foxglove", "foxglove")
        channels = _need("foxglove.channels", "foxglove")
        ctx = foxglove.Context()
        extra: dict[str, Any] = {}
        if self.cmd_vel_topic is not None:
            from foxglove.websocket import Capability

            extra = {"capabilities": [Capability.ClientPublish],
                     "supported_encodings": ["json"],
                     "server_listener": _CommandListener(self)}
        try:
            self._server = foxglove.start_server(name=self.name, host=self.host,
                                                 port=self._port, context=ctx, **extra)
        except Exception as exc:
            raise OSError(f"Foxglove server on {self.host}:{self._port}: {exc}") from exc
        t = self.topics
        if t.odom:
            self._channels["odom"] = channels.OdometryChannel(t.odom, context=ctx)
        if t.tf:
            self._channels["tf"] = channels.FrameTransformsChannel(t.tf, context=ctx)
        if t.imu:
            self._channels["imu"] = foxglove.Channel(t.imu, schema=_IMU_SCHEMA, context=ctx)
        for key in ("wheel_left", "wheel_right"):
            topic = getattr(t, key)
            if topic:
                self._channels[key] = foxglove.Channel(topic, schema=_FLOAT32_SCHEMA,
                                                       context=ctx)
        self._ctx = ctx

    def _write(self, record: FusedOdometry) -> None:
        from foxglove import messages as fm

        ns = stamp_ns(record.t)
        sec, nsec = divmod(ns, 1_000_000_000)
        stamp = fm.Timestamp(sec=sec, nsec=nsec)
        qw, qx, qy, qz = (float(v) for v in record.yaw_quaternion)
        position = fm.Vector3(x=record.x, y=record.y, z=0.0)
        rotation = fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
        ch = self._channels
        if "odom" in ch:
            wx, wy, wz = (float(v) for v in record.angular_velocity)
            ch["odom"].log(fm.Odometry(
                timestamp=stamp, frame_id=record.frame_id, body_frame_id=record.child_frame_id,
                pose=fm.Pose(position=position, orientation=rotation),
                linear_velocity=fm.Vector3(x=record.v, y=0.0, z=0.0),
                angular_velocity=fm.Vector3(x=wx, y=wy, z=wz),
                pose_covariance=record.pose_covariance.reshape(36).tolist(),
                velocity_covariance=record.twist_covariance.reshape(36).tolist(),
            ), log_time=ns)
        if "tf" in ch:
            ch["tf"].log(fm.FrameTransforms(transforms=[fm.FrameTransform(
                timestamp=stamp, parent_frame_id=record.frame_id,
                child_frame_id=record.child_frame_id, translation=position, rotation=rotation,
            )]), log_time=ns)
        json_keys = ("imu", "wheel_left", "wheel_right")
        for key, _topic, _type, fields in ros_messages(record, self.topics):
            if key in json_keys and key in ch:
                ch[key].log(_json_header(fields) if "header" in fields else fields,
                            log_time=ns)

    def _client_message(self, client_id: int, channel_id: int, data: bytes) -> None:
        topic, encoding = self._client_channels.get((client_id, channel_id), ("", ""))
        if topic != self.cmd_vel_topic:
            return
        try:
            if encoding != "json":
                raise ValueError(encoding)
            msg = json.loads(data)
            v, w = float(msg["linear"]["x"]), float(msg["angular"]["z"])
            if not (math.isfinite(v) and math.isfinite(w)):
                raise ValueError((v, w))
        except (ValueError, KeyError, TypeError):
            self.cmd_vel_rejected += 1
            return
        self.cmd_vel_received += 1
        if self.on_cmd_vel is not None:
            self.on_cmd_vel(v, w)

    def _close(self) -> None:
        for channel in self._channels.values():
            with contextlib.suppress(Exception):
                channel.close()
        self._channels.clear()
        if self._server is not None:
            server, self._server = self._server, None
            self._port = server.port
            server.stop()


class _CommandListener:
    """foxglove-sdk ServerListener: tracks client channels, forwards their messages."""

    def __init__(self, sink: FoxgloveSink) -> None:
        self.sink = sink

    def on_client_advertise(self, client: Any, channel: Any) -> None:
        self.sink._client_channels[(client.id, channel.id)] = (channel.topic, channel.encoding)

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        self.sink._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        self.sink._client_message(client.id, client_channel_id, data)


def open_sink(spec: str, *, topics: Topics | None = None) -> Sink:
    """A sink from a command-line spec (not yet opened).

    ``jsonl`` (stdout) | ``jsonl:PATH`` | ``csv:PATH`` | ``mcap:PATH`` (one .mcap file) |
    ``rosbag2:PATH`` (bag folder, MCAP storage) | ``foxglove`` (127.0.0.1:8765) |
    ``foxglove:PORT`` | ``foxglove:HOST:PORT`` | ``ros1`` (a ROS 1 node, :mod:`fusion.ros1`).
    """
    kind, _, arg = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "jsonl":
        return JsonLinesSink(arg or None)
    if kind == "csv":
        if not arg:
            raise ValueError(f"sink {spec!r}: give a path, e.g. csv:fused.csv")
        return CsvSink(arg)
    if kind in ("mcap", "rosbag2"):
        if not arg:
            raise ValueError(f"sink {spec!r}: give a path, e.g. {kind}:out.mcap")
        return McapSink(arg, topics=topics) if kind == "mcap" else Rosbag2Sink(arg, topics=topics)
    if kind == "foxglove":
        host, port = "127.0.0.1", "8765"
        if arg:
            host, _, port = arg.rpartition(":") if ":" in arg else ("127.0.0.1", "", arg)
        try:
            return FoxgloveSink(host or "127.0.0.1", int(port), topics=topics)
        except ValueError as exc:
            raise ValueError(f"sink {spec!r}: want foxglove[:HOST]:PORT ({exc})") from None
    if kind == "ros1":
        if arg:
            raise ValueError(f"sink {spec!r}: ros1 takes no argument (use the config file)")
        from fusion.ros1 import Ros1Sink

        return Ros1Sink(topics=topics)
    raise ValueError(
        f"unknown sink {spec!r}: want jsonl[:PATH], csv:PATH, mcap:PATH, rosbag2:PATH, "
        "foxglove[:HOST:PORT] or ros1"
    )
