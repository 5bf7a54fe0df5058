"""Log readers: BROAD benchmark trials, plain IMU CSV files, ROS 1/2 bags and MCAP files.

IMU CSV schema (header line required)::

    t,gx,gy,gz,ax,ay,az[,mx,my,mz]

``t`` in s (strictly increasing), gyro in rad/s, accelerometer (specific force) in m/s^2,
magnetometer in uT, all in the body frame (x forward, y left, z up).

Errors name the file and, where it applies, the line (1-based, as an editor shows it).

Bags (:func:`read_bag`, :func:`read_bag_imu`, :func:`read_bag_odometry`,
:func:`read_bag_twist`, :func:`bag_topics`) through the pure-Python ``rosbags`` package
(``pip install 'diffbot-fusion[ros]'``): a ROS 1 ``.bag`` file, a ROS 2 bag folder (with
``metadata.yaml``; sqlite3 or MCAP storage) or a single ``.mcap`` file (read with the ``mcap``
package, messages decoded by ``rosbags`` from the schemas inside). Message types:
sensor_msgs/Imu, nav_msgs/Odometry, geometry_msgs/Twist and TwistStamped. Times are s; by
default each message's ``header.stamp`` (``stamps="header"``), or the time the bag recorded it
(``stamps="bag"``, the only choice for Twist). Errors name the file and topic; a missing
topic lists the topics present.

DATA-uart2 captures of the chassis link (:func:`read_uart2_capture`): raw bytes as read from
the port, or a timed capture, a text file whose first line is ``t,data`` and whose rows are
``t`` (s, host clock, when the read returned) and ``data`` (the bytes of that read in hex),
written by :class:`Uart2CaptureWriter`. Frames are decoded by
:class:`drivers.chassis.WheelFrameParser`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion import quaternion as quat

__all__ = [
    "IMU_CSV_COLUMNS",
    "BagImuLog",
    "BagLog",
    "BroadTrial",
    "ImuLog",
    "LogFormatError",
    "OdometryLog",
    "TwistLog",
    "Uart2Capture",
    "Uart2CaptureWriter",
    "bag_topics",
    "read_bag",
    "read_bag_imu",
    "read_bag_odometry",
    "read_bag_twist",
    "read_broad",
    "read_imu_csv",
    "read_uart2_capture",
    "write_attitude_csv",
]

IMU_CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")
MAG_COLUMNS = ("mx", "my", "mz")
ATTITUDE_CSV_COLUMNS = ("t", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw")


class LogFormatError(ValueError):
    """A log file that does not match its format; the message names file and line."""


@dataclass
class ImuLog:
    """IMU samples: ``t`` (N,) s, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s^2, ``mag`` uT."""

    t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    mag: NDArray[np.float64] | None = None
    source: str = ""

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class BroadTrial(ImuLog):
    """One BROAD trial: IMU data plus optical ground truth.

    Attributes (beyond :class:`ImuLog`):
        quat_ref: (N, 4) ground-truth attitude, ``[w, x, y, z]``, sensor -> earth (ENU-like,
            z up); NaN rows where the markers were lost.
        pos_ref: (N, 3) ground-truth position, m.
        movement: (N,) bool, the motion phases the errors are computed over.
        rate: sampling rate, Hz.
        name: trial name (file stem).
    """

    quat_ref: NDArray[np.float64] | None = None
    pos_ref: NDArray[np.float64] | None = None
    movement: NDArray[np.bool_] | None = None
    rate: float = 0.0
    name: str = ""

    def reference_initial_quaternion(self) -> NDArray[np.float64]:
        """The initial state of the dataset's published Mahony runs, in ENU.

        Exactly the dataset's recipe (datasets/broad/README.md), including its quirk: with
        ``a``, ``m`` the first accelerometer and magnetometer samples, ``z = a``,
        ``x = (z x -m) x z``, ``y = z x x``, ``R = [x, y, z]`` (normalised columns),
        ``q0 = quat(R)``, returned as ``qz(+90 deg) * q0``. It is not the physically correct
        attitude; use it only to reproduce the published numbers.
        """
        if self.mag is None:
            raise ValueError(f"{self.source}: the trial has no magnetometer data")
        z = self.accel[0]
        x = np.cross(np.cross(z, -self.mag[0]), z)
        y = np.cross(z, x)
        R = np.column_stack([v / np.linalg.norm(v) for v in (x, y, z)])
        q0 = quat.from_matrix(R)
        qz = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
        return quat.multiply(qz, q0)


_BROAD_KEYS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement", "sampling_rate")


def read_broad(path: str | Path) -> BroadTrial:
    """Read a BROAD trial from its ``.mat`` (scipy) or ``.hdf5``/``.h5`` (h5py) file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mat":
        from scipy.io import loadmat
        from scipy.io.matlab import MatReadError

        try:
            raw = loadmat(path, variable_names=_BROAD_KEYS)
        except (MatReadError, ValueError, TypeError, OSError) as exc:
            if isinstance(exc, FileNotFoundError):
                raise
            raise LogFormatError(f"{path}: not a readable MATLAB file ({exc})") from exc
    elif suffix in (".hdf5", ".h5"):
        try:
            import h5py
        except ImportError as exc:
            raise ImportError(
                f"{path}: reading HDF5 needs h5py: pip install 'diffbot-fusion[hdf5]'"
            ) from exc
        with h5py.File(path, "r") as f:
            raw = {k: np.asarray(f[k]) for k in _BROAD_KEYS if k in f}
    else:
        raise LogFormatError(f"{path}: unknown BROAD file type {suffix!r} (want .mat or .hdf5)")
    missing = [k for k in _BROAD_KEYS if k not in raw]
    if missing:
        raise LogFormatError(f"{path}: not a BROAD trial, missing {', '.join(missing)}")

    def rows(key: str, width: int) -> NDArray[np.float64]:
        a = np.asarray(raw[key], dtype=np.float64)
        if a.ndim == 2 and a.shape[0] == width and a.shape[1] != width:
            a = a.T  # column-major writers store (width, N)
        if a.ndim != 2 or a.shape[1] != width:
            raise LogFormatError(f"{path}: {key} has shape {a.shape}, expected (N, {width})")
        return np.ascontiguousarray(a)

    gyro, accel, mag = rows("imu_gyr", 3), rows("imu_acc", 3), rows("imu_mag", 3)
    quat_ref, pos_ref = rows("opt_quat", 4), rows("opt_pos", 3)
    movement = np.asarray(raw["movement"]).reshape(-1).astype(bool)
    rate = float(np.asarray(raw["sampling_rate"]).reshape(-1)[0])
    n = gyro.shape[0]
    for key, arr in (("imu_acc", accel), ("imu_mag", mag), ("opt_quat", quat_ref),
                     ("opt_pos", pos_ref), ("movement", movement)):
        if arr.shape[0] != n:
            raise LogFormatError(f"{path}: {key} has {arr.shape[0]} rows, imu_gyr has {n}")
    if not rate > 0:
        raise LogFormatError(f"{path}: sampling_rate must be > 0 Hz, got {rate}")
    return BroadTrial(
        t=np.arange(n) / rate, gyro=gyro, accel=accel, mag=mag, source=str(path),
        quat_ref=quat_ref, pos_ref=pos_ref, movement=movement, rate=rate, name=path.stem,
    )


def read_imu_csv(path: str | Path) -> ImuLog:
    """Read an IMU CSV (schema in the module docstring).

    Raises :class:`LogFormatError` naming the file and line for a wrong header, a row with the
    wrong number of fields or a non-numeric value, and timestamps that do not increase.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        header_line = fh.readline()
    header = [h.strip() for h in header_line.strip().split(",")]
    width = len(header)
    if tuple(header[:7]) != IMU_CSV_COLUMNS or width not in (7, 10) or (
        width == 10 and tuple(header[7:]) != MAG_COLUMNS
    ):
        raise LogFormatError(
            f"{path}:1: header must be {','.join(IMU_CSV_COLUMNS)}[,mx,my,mz], "
            f"got {header_line.strip()!r}"
        )
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError:
        _raise_bad_csv_line(path, width)
        raise
    if data.shape[0] and data.shape[1] != width:
        _raise_bad_csv_line(path, width)
    if data.shape[0] == 0:
        data = np.zeros((0, width))
    t = data[:, 0].copy()
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        line = int(bad[0]) + 3  # header is line 1, data row i is line i + 2
        raise LogFormatError(
            f"{path}:{line}: timestamp {t[bad[0] + 1]!r} does not increase "
            f"(previous {t[bad[0]]!r})"
        )
    return ImuLog(
        t=t,
        gyro=np.ascontiguousarray(data[:, 1:4]),
        accel=np.ascontiguousarray(data[:, 4:7]),
        mag=np.ascontiguousarray(data[:, 7:10]) if width == 10 else None,
        source=str(path),
    )


def _raise_bad_csv_line(path: Path, width: int) -> None:
    """Find the first malformed data line of a CSV and raise naming it."""
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        next(reader, None)
        for lineno, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != width:
                raise LogFormatError(
                    f"{path}:{lineno}: expected {width} fields, got {len(row)}"
                )
            for name, value in zip(_columns(width), row):
                try:
                    float(value)
                except ValueError:
                    raise LogFormatError(
                        f"{path}:{lineno}: column {name!r} is not a number: {value!r}"
                    ) from None


def _columns(width: int) -> tuple[str, ...]:
    return IMU_CSV_COLUMNS + (MAG_COLUMNS if width == 10 else ())


def write_attitude_csv(
    path: str | Path, t: NDArray, quaternions: NDArray
) -> None:
    """Write ``t,qw,qx,qy,qz,roll,pitch,yaw`` (s, quaternion body -> ENU, radians).

    Written to a temporary file first and renamed, so an existing file is never left half
    written.
    """
    path = Path(path)
    q = np.asarray(quaternions, dtype=float)
    euler = quat.to_euler(q)
    table = np.column_stack([np.asarray(t, dtype=float), q, euler])
    tmp = path.with_name(path.name + ".partial")
    try:
        np.savetxt(tmp, table, delimiter=",", header=",".join(ATTITUDE_CSV_COLUMNS),
                   comments="", fmt="%.10g")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


# -- ROS 1/2 bags and MCAP -------------------------------------------------------------------

IMU_TYPES = ("sensor_msgs/Imu",)
ODOMETRY_TYPES = ("nav_msgs/Odometry",)
TWIST_TYPES = ("geometry_msgs/Twist", "geometry_msgs/TwistStamped")


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
class BagLog:
    """What :func:`read_bag` read: one log per requested topic (None if not requested), and
    ``topics``, every topic of the file as ``{topic: (type, message count)}``."""

    imu: BagImuLog | None
    odometry: OdometryLog | None
    twist: TwistLog | None
    topics: dict[str, tuple[str, int]]
    source: str


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

    def __enter__(self) -> _BagFile:
        rosbags = _need_rosbags(self.path)
        if self.is_mcap_file:
            self._open_mcap(rosbags)
        else:
            if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
                raise LogFormatError(f"{self.path}: a folder without metadata.yaml is not a "
                                     "ROS 2 bag")
            try:
                self._reader = rosbags.highlevel.AnyReader([self.path])
                self._reader.open()
            except Exception as exc:  # rosbags' errors, struct errors of truncated files
                raise LogFormatError(f"{self.path}: not a readable ROS bag ({exc})") from exc
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
            from mcap.exceptions import McapError
            from mcap.reader import make_reader
        except ImportError as exc:
            raise ImportError(
                f"{self.path}: reading .mcap files needs mcap: pip install 'diffbot-fusion[ros]'"
            ) from exc
        typesys = rosbags.typesys
        self._fh = self.path.open("rb")
        try:
            self._mcap = make_reader(self._fh)
            summary = self._mcap.get_summary()
        except (McapError, ValueError, EOFError) as exc:
            self._fh.close()
            raise LogFormatError(f"{self.path}: not a readable MCAP file ({exc})") from exc
        if summary is None:
            self._fh.close()
            raise LogFormatError(f"{self.path}: MCAP file without a summary section "
                                 "(unfinished recording?); run `mcap recover` on it")
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self._ts = typesys.get_typestore(typesys.Stores.EMPTY)
        self._encoding: dict[str, tuple[str, str]] = {}
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
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

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """``(topic, bag time ns, message)`` of the given topics, in the bag's record order."""
        if self.is_mcap_file:
            for _schema, ch, msg in self._mcap.iter_messages(topics=list(topics)):
                encoding, rostype = self._encoding[ch.topic]
                if encoding == "cdr":
                    obj = self._ts.deserialize_cdr(msg.data, rostype)
                elif encoding == "ros1":
                    obj = self._ts.deserialize_ros1(msg.data, rostype)
                else:
                    raise LogFormatError(f"{self.path}: topic {ch.topic}: message encoding "
                                         f"{encoding!r} is neither cdr nor ros1")
                yield ch.topic, msg.log_time, obj
            return
        conns = [c for c in self._reader.connections if c.topic in topics]
        for c, ns, raw in self._reader.messages(connections=conns):
            yield c.topic, ns, self._reader.deserialize(raw, c.msgtype)


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

    def _frame(self, key: str, value: str) -> None:
        old = self.frames.setdefault(key, value)
        if old != value:
            raise LogFormatError(
                f"{self.path}: topic {self.topic}: {key} changes from {old!r} to {value!r} "
                f"at message {len(self.t) + 1}")

    def add(self, ns: int, msg: Any) -> None:
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
            self.rows.append((g.x, g.y, g.z, a.x, a.y, a.z,
                              *((math.nan,) * 4 if no_q else (q.w, q.x, q.y, q.z))))
        elif self.kind == "odometry":
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
            yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            self.rows.append((p.x, p.y, yaw, lin.x, lin.y, ang.z,
                              *msg.pose.covariance, *msg.twist.covariance))
        else:
            tw = msg.twist if self.msgtype == "geometry_msgs/TwistStamped" else msg
            self.rows.append((tw.linear.x, tw.linear.y, tw.angular.z))

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                              int]:
        """``(t, bag_time, rows)`` sorted by t, and how many messages were out of order."""
        where = f"{self.path}: topic {self.topic}"
        if not self.t:
            raise LogFormatError(f"{where}: no messages")
        t = np.asarray(self.t, dtype=np.float64)
        if self.use_header and not np.any(t > 0):
            raise LogFormatError(f"{where}: every header.stamp is zero; read it with "
                                 "stamps='bag' (the bag's record times)")
        rows = np.asarray(self.rows, dtype=np.float64)
        check = rows[:, :6] if self.kind != "twist" else rows
        bad = np.flatnonzero(~np.all(np.isfinite(check), axis=1))
        if bad.size:
            i = int(bad[0])
            raise LogFormatError(
                f"{where}: message {i + 1} (t = {t[i]:.9f} s) has a non-finite value: "
                f"{check[i].tolist()}")
        running_max = np.maximum.accumulate(t)
        out_of_order = int(np.count_nonzero(t[1:] < running_max[:-1]))
        bag_t = np.asarray(self.bag_t, dtype=np.float64)
        if out_of_order:
            order = np.argsort(t, kind="stable")
            t, bag_t, rows = t[order], bag_t[order], rows[order]
        return t, bag_t, rows, out_of_order


_KINDS = {"imu": IMU_TYPES, "odometry": ODOMETRY_TYPES, "twist": TWIST_TYPES}


def read_bag(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    odom_topic: str | None = None,
    twist_topic: str | None = None,
    stamps: str = "header",
) -> BagLog:
    """Read IMU, odometry and twist topics of a bag or MCAP file in one pass.

    Args:
        path: ROS 1 ``.bag``, ROS 2 bag folder, or ``.mcap`` file.
        imu_topic: a sensor_msgs/Imu topic (e.g. ``/imu/data``), or None.
        odom_topic: a nav_msgs/Odometry topic (e.g. ``/odom``), or None.
        twist_topic: a geometry_msgs/Twist or TwistStamped topic (e.g. ``/cmd_vel``), or None.
        stamps: ``"header"`` (each message's header.stamp) or ``"bag"`` (record times).

    Raises:
        FileNotFoundError: no such path.
        LogFormatError: not a bag; a topic missing (the message lists the topics present),
            of another type, empty, with changing frame ids, zero stamps or non-finite values.
        ImportError: rosbags (or mcap for .mcap files) is not installed.
    """
    path = Path(path)
    if stamps not in ("header", "bag"):
        raise ValueError(f"stamps must be 'header' or 'bag', got {stamps!r}")
    wanted = {k: t for k, t in (("imu", imu_topic), ("odometry", odom_topic),
                                ("twist", twist_topic)) if t is not None}
    if not wanted:
        raise ValueError("give at least one of imu_topic, odom_topic, twist_topic")
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
            for topic, ns, msg in bag.messages(list(collectors)):
                collectors[topic].add(ns, msg)
        except LogFormatError:
            raise
        except Exception as exc:  # a truncated chunk, a message that does not decode
            raise LogFormatError(
                f"{path}: reading {', '.join(collectors)} failed: {exc!r}") from exc
        topics = dict(bag.topics)
    return BagLog(
        imu=_imu_log(collectors.get(imu_topic)) if imu_topic else None,
        odometry=_odometry_log(collectors.get(odom_topic)) if odom_topic else None,
        twist=_twist_log(collectors.get(twist_topic)) if twist_topic else None,
        topics=topics, source=str(path),
    )


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


# -- DATA-uart2 captures ---------------------------------------------------------------------

UART2_CAPTURE_HEADER = "t,data"


@dataclass
class Uart2Capture:
    """Wheel frames decoded from a DATA-uart2 capture.

    Attributes:
        left, right: (N,) int64 ticks counted in each frame's sampling period (left, right).
        offset: (N,) int64 byte offset of each frame's first byte in the capture's stream.
        t: (N,) s, each frame's stamp on the capture's host clock (timed captures; see
            :func:`read_uart2_capture`), or None for a raw capture.
        stats: the parser's counters (:class:`drivers.chassis.ParserStats` as a dict).
        reads: number of reads (rows) of a timed capture, 0 for a raw one.
        source: the file read.
    """

    left: NDArray[np.int64]
    right: NDArray[np.int64]
    offset: NDArray[np.int64]
    t: NDArray[np.float64] | None
    stats: dict[str, int]
    reads: int = 0
    source: str = ""

    def __len__(self) -> int:
        return len(self.left)

    def wheel_ticks(self) -> list[Any]:
        """The frames as :class:`fusion.samples.WheelTicks` (timed captures only)."""
        from fusion.samples import WheelTicks

        if self.t is None:
            raise ValueError(f"{self.source}: a raw capture has no times; record a timed "
                             "capture (Uart2CaptureWriter) to replay it on a clock")
        return [WheelTicks(float(t), int(lft), int(rgt))
                for t, lft, rgt in zip(self.t, self.left, self.right)]


class Uart2CaptureWriter:
    """Writes a timed DATA-uart2 capture: ``t,data`` rows (s, hex bytes), one per read.

    Lines are flushed as they are written, so a capture survives a crash of the recorder up to
    its last read. An existing file is a FileExistsError unless ``overwrite=True``.
    """

    def __init__(self, path: str | Path, *, overwrite: bool = False) -> None:
        self.path = Path(path)
        self._fh = self.path.open("w" if overwrite else "x", encoding="ascii", newline="\n")
        self._fh.write(UART2_CAPTURE_HEADER + "\n")
        self._last = -math.inf

    def write(self, t: float, data: bytes | bytearray | memoryview) -> None:
        """One read: its return time ``t`` (s) and its bytes."""
        t = float(t)
        if not math.isfinite(t) or t < self._last:
            raise ValueError(f"{self.path}: read times must be finite and not decrease, got "
                             f"{t!r} after {self._last!r}")
        self._last = t
        self._fh.write(f"{t!r},{bytes(data).hex()}\n")
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> Uart2CaptureWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_timed_capture(path: Path) -> tuple[list[float], list[bytes]]:
    times: list[float] = []
    chunks: list[bytes] = []
    with path.open(encoding="ascii", errors="replace", newline=None) as fh:
        fh.readline()
        for lineno, line in enumerate(fh, start=2):
            line = line.strip()
            if not line:
                continue
            parts = line.split(",")
            if len(parts) != 2:
                raise LogFormatError(f"{path}:{lineno}: expected 't,data', got {line[:60]!r}")
            try:
                t = float(parts[0])
            except ValueError:
                raise LogFormatError(f"{path}:{lineno}: t is not a number: {parts[0]!r}") from None
            try:
                data = bytes.fromhex(parts[1])
            except ValueError:
                raise LogFormatError(
                    f"{path}:{lineno}: data is not hex bytes: {parts[1][:60]!r}") from None
            if not math.isfinite(t) or (times and t < times[-1]):
                raise LogFormatError(f"{path}:{lineno}: t = {parts[0]} is not finite or goes "
                                     f"back in time (previous {times[-1] if times else None})")
            times.append(t)
            chunks.append(data)
    return times, chunks


def read_uart2_capture(
    path: str | Path,
    *,
    max_ticks: int | None = None,
    strict_sign: bool = True,
    baudrate: int = 115200,
    period: float = 0.04,
) -> Uart2Capture:
    """Decode a DATA-uart2 capture (raw bytes, or a timed ``t,data`` capture).

    A timed capture is replayed read by read through :class:`drivers.chassis.FrameStamper`,
    the stamping rule of :class:`drivers.serial_link.ChassisLink`: the read's time minus the
    transmission time (10 bits per byte at ``baudrate``) of the bytes that followed the frame
    up to the end of the read, never earlier than the previous read; a frame the parser holds
    back is decided when the line has been quiet for more than ``2 * period`` s (as the link's
    housekeeping does) or at the end. A capture recorded from the link's ``on_read`` hook
    holds every read, empty ones included, and replays to exactly the frames and stamps the
    link delivered; in a capture without empty reads, a gap of more than 2 periods between
    two reads is taken as the quiet line the link would have seen.

    Args:
        path: the capture file.
        max_ticks: the parser's plausibility bound, ticks per period (default: the parser's).
        strict_sign: accept only sign bytes 0/1 (see :class:`drivers.chassis.WheelFrameParser`).
        baudrate: line speed, for the transmission-time correction, bit/s.
        period: firmware sampling period (seed 000's ``encode_sampling_time``), s.
    """
    from drivers.chassis import DEFAULT_MAX_TICKS, FrameStamper, WheelFrameParser

    path = Path(path)
    if baudrate <= 0 or not period > 0:
        raise ValueError(f"baudrate and period must be > 0, got {baudrate}, {period}")
    parser = WheelFrameParser(max_ticks=DEFAULT_MAX_TICKS if max_ticks is None else max_ticks,
                              strict_sign=strict_sign)
    with path.open("rb") as fh:
        head = fh.read(len(UART2_CAPTURE_HEADER) + 2)
    timed = head.rstrip(b"\r\n") == UART2_CAPTURE_HEADER.encode() or head.startswith(
        (UART2_CAPTURE_HEADER + "\n").encode())
    if not timed:
        data = path.read_bytes()
        off, left, right = parser.feed_arrays(data)
        tail = parser.finish()
        off = np.concatenate([off, [f.offset for f in tail]]).astype(np.int64)
        left = np.concatenate([left, [f.left for f in tail]]).astype(np.int64)
        right = np.concatenate([right, [f.right for f in tail]]).astype(np.int64)
        return Uart2Capture(left=left, right=right, offset=off, t=None,
                            stats=parser.stats.as_dict(), source=str(path))

    times, chunks = _read_timed_capture(path)
    # the link's own stamping rule, read by read (feed, then the quiet-line check)
    stamper = FrameStamper(parser, baudrate=baudrate, period=period)
    parts = []
    prev_empty = True
    for t_read, data in zip(times, chunks):
        if data and not prev_empty:
            # two data reads more than 2 periods apart with no timed-out read between: a
            # capture that does not record empty reads (the link's reads time out after a
            # period, so it would have checked the quiet line in the gap)
            parts.append(stamper.poll(t_read))
        parts.append(stamper.feed(t_read, data))
        parts.append(stamper.poll(t_read))
        prev_empty = not data
    parts.append(stamper.finish())
    parser.finish()
    out_t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
    left, right, off = (np.concatenate([p[i] for p in parts]).astype(np.int64)
                        if parts else np.zeros(0, dtype=np.int64) for i in (1, 2, 3))
    return Uart2Capture(left=left, right=right, offset=off, t=np.asarray(out_t, dtype=float),
                        stats=parser.stats.as_dict(), reads=len(times), source=str(path))
