"""The robot configuration file (TOML) of ``fusion run`` and ``fusion demo``.

One file describes a robot and how to run the live pipeline on it. Tables (all optional
except ``[chassis]`` on a real robot; every error names the file, the line and the key)::

    [chassis]                     # seed 000's names (fusion.io.robot_toml, same as robot.toml)
    wheel_distance = 0.3          # m, distance between the wheel contact points
    speed_ratio = 5e-5            # m of wheel travel per encoder tick
    encode_sampling_time = 0.04   # s, firmware period
    cmd_vel_linear_max = 0.5      # m/s, clamp on /cmd_vel (optional)
    cmd_vel_angular_max = 2.0     # rad/s (optional)
    wheel_speed_max = 1.0         # m/s, curvature-preserving wheel limit (optional)

    [frames]                      # REP-105 names and the IMU mount (fusion.io.logdir)
    odom = "odom"
    base = "base_footprint"
    imu_mount_rpy = [0.0, 0.0, 0.0]   # rad, URDF roll pitch yaw of the IMU in the base frame

    [ekf]                         # any fusion.planar.ekf.EkfNoise field (fusion.io.logdir)

    [attitude]                    # the pipeline's attitude filter (fusion.io.robot_toml)
    filter = "keel"               # "keel" (default) or "mahony"
    wheel_knowledge = true        # Keel: feed the wheels' v*w and stillness (default: on)
    accel_time_constant = 3.0     # any other key: a KeelParams / MahonyParams field, SI

    [imu]
    source = "i2c:1"              # "i2c:N" (/dev/i2c-N), "sim" or "none"
    address = 0x68
    rate_hz = 100.0               # MPU6050 sample rate, Hz
    gyro_range_dps = 500
    accel_range_g = 4
    dlpf = 3                      # DLPF_CFG 0..6
    fifo_interval = 0.02          # s between FIFO reads
    calibration = "imu_cal.json"  # from fusion imu-calibrate (optional; relative to this file)
    tilt = true                   # tilt-compensate the gyro with the attitude filter

    [link]                        # the chassis DATA-uart2 port
    port = "/dev/ttyUSB0"         # device, socket://host:port, loop://, or "sim"
    baudrate = 115200
    command_timeout = 0.5         # s without /cmd_vel before the wheels are stopped
    silence_periods = 5.0         # periods without a frame before the link reports silence

    [publish]
    sinks = ["ros1"]              # jsonl[:PATH] mcap:PATH rosbag2:PATH foxglove[:HOST:PORT]
                                  # ros1 ros2
    rate_hz = 10.0                # records per second (seed 000: 10 Hz); 0 = every wheel frame
    reorder_window = 0.06         # s events are held to be put in time order (default: enough
                                  # for the IMU FIFO interval plus half a wheel period)

    [run]                         # the session (fusion run's --duration, --speed, --status)
    duration = 0                  # s, 0 = until Ctrl-C
    speed = 1.0                   # robot time per wall second, simulated chassis only
    status = 10.0                 # s between status lines on stderr, 0 = none
    strict = false                # exit status 3 when the inputs disagree (fusion.jobs.status)

    [topics]                      # ROS topic names (fusion.sinks.Topics); "" leaves one out
    odom = "/odom"
    tf = "/tf"
    imu = "/imu/data"
    wheel_left = "/wheel_left_speed"
    wheel_right = "/wheel_right_speed"
    cmd_vel = "/cmd_vel"

:data:`RUN_OPTIONS` maps each ``fusion run`` command-line option to its table and key, so
every option can come from the file; an option given on the command line wins.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.errors import ConfigError, LogFormatError
from fusion.io.robot_toml import (
    ROBOT_TABLES,
    read_robot_toml,
    robot_config_from_tables,
    where,
)
from fusion.io.sink_spec import parse_sink_spec
from fusion.planar.robot import RobotConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = [
    "DEMO_ROBOT",
    "RUN_OPTIONS",
    "SCHEMA",
    "ConfigError",
    "RunConfig",
    "load_config",
    "parse_config",
    "read_log_robot",
]


#: Nominal chassis of the simulated robot (``sim``) and of ``fusion demo``: 0.3 m track,
#: 0.05 mm per tick, 40 ms period, as the simulated STM32's defaults.
DEMO_ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=5e-5, encode_sampling_time=0.04,
                             cmd_vel_linear_max=0.8, cmd_vel_angular_max=2.5,
                             wheel_speed_max=1.0)


@dataclass(frozen=True)
class RunConfig:
    """Everything ``fusion run`` needs (units SI; see the module docstring for the file).

    Attributes:
        robot: chassis, frames (IMU mount), EKF tuning and attitude filter.
        imu: ``"i2c:N"``, ``"sim"`` or ``"none"``.
        imu_address, imu_rate_hz, gyro_range_dps, accel_range_g, dlpf: MPU6050 settings
            (I2C address, Hz, deg/s, g, DLPF_CFG).
        fifo_interval: s between FIFO reads.
        imu_calibration: calibration JSON path, or None.
        tilt: tilt-compensate the gyro with the attitude filter's attitude.
        chassis: the DATA-uart2 port (device path or pyserial URL) or ``"sim"``.
        baudrate, command_timeout, silence_periods: serial link settings (bit/s, s, periods).
        publish: sink specs (:func:`fusion.io.sink_spec.parse_sink_spec`).
        publish_rate_hz: records per second, None for one per wheel frame.
        reorder_window: s (None: the pipeline's default for the IMU FIFO interval).
        topics: topic names (odom, tf, imu, wheel_left, wheel_right; None leaves one out).
        cmd_vel_topic: velocity command topic of the ROS 1, ROS 2 and Foxglove sinks, or None.
        duration: s to run, None until stopped; speed: robot time per wall second
            (simulated chassis); status: s between status lines, 0 none; strict: exit
            with an error status when the trust checks fail (:mod:`fusion.evaluation.trust`).
        source: the file this came from, or None.
        chassis_given: whether the file has a ``[chassis]`` table (else :attr:`robot` has
            the simulated robot's geometry, :data:`DEMO_ROBOT`, which a real port must not
            take).

    Raises:
        ConfigError: a field that the file's checks (:data:`SCHEMA`) refuse (NaN, infinite,
            out of range, wrong type), naming the field, its table and key, and the value.
    """

    robot: RobotConfig = field(default_factory=lambda: RobotConfig(chassis=DEMO_ROBOT))
    imu: str = "sim"
    imu_address: int = 0x68
    imu_rate_hz: float = 100.0
    gyro_range_dps: int = 500
    accel_range_g: int = 4
    dlpf: int = 3
    fifo_interval: float = 0.02
    imu_calibration: str | None = None
    tilt: bool = True
    chassis: str = "sim"
    baudrate: int = 115200
    command_timeout: float = 0.5
    silence_periods: float = 5.0
    publish: tuple[str, ...] = ("jsonl",)
    publish_rate_hz: float | None = None
    reorder_window: float | None = None
    topics: dict[str, str | None] = field(default_factory=lambda: {
        "odom": "/odom", "tf": "/tf", "imu": "/imu/data",
        "wheel_left": "/wheel_left_speed", "wheel_right": "/wheel_right_speed"})
    cmd_vel_topic: str | None = "/cmd_vel"
    duration: float | None = None
    speed: float = 1.0
    status: float = 10.0
    strict: bool = False
    chassis_given: bool = False
    source: Path | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.robot, RobotConfig):
            raise ConfigError(f"RunConfig.robot must be a RobotConfig, got {self.robot!r}")
        for name in _FIELD_CHECKS:
            _check_field(name, self._value(name), f"RunConfig.{name}")

    def _value(self, name: str) -> Any:
        if name.startswith("topics."):
            return self.topics.get(name[7:])
        value = getattr(self, name)
        return list(value) if name == "publish" else value

    def with_overrides(self, **changes: Any) -> RunConfig:
        """A copy with the given fields changed; None values are ignored (option not given).

        Raises:
            ConfigError: a value the file's checks refuse, naming the ``fusion run`` option
                (or the field) and the value.
        """
        given = {k: v for k, v in changes.items() if v is not None}
        for name, value in given.items():
            if name in _FIELD_CHECKS:
                _check_field(name, list(value) if name == "publish" else value,
                             _OPTION_OF.get(name, f"RunConfig.{name}"))
        return replace(self, **given)


# -- value checks ------------------------------------------------------------------------------

Check = Callable[[Any], Any]


def _number(lo: float = -math.inf, hi: float = math.inf, *, integer: bool = False,
            open_lo: bool = False) -> Check:
    def check(v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"must be a number, got {v!r}")
        if integer and not (isinstance(v, int) or float(v).is_integer()):
            raise ValueError(f"must be an integer, got {v!r}")
        if not math.isfinite(v) or v < lo or v > hi or (open_lo and v == lo):
            side = ">" if open_lo else ">="
            raise ValueError(f"must be {side} {lo}" + (f" and <= {hi}" if hi < math.inf else "")
                             + f", got {v!r}")
        return int(v) if integer else float(v)
    return check


def _choice(*values: Any) -> Check:
    def check(v: Any) -> Any:
        if isinstance(v, bool) or v not in values:
            raise ValueError(f"must be one of {', '.join(map(str, values))}, got {v!r}")
        return v
    return check


def _string(v: Any) -> str:
    if not isinstance(v, str):
        raise ValueError(f"must be a string, got {v!r}")
    return v


def _boolean(v: Any) -> bool:
    if not isinstance(v, bool):
        raise ValueError(f"must be true or false, got {v!r}")
    return v


def _imu_source(v: Any) -> str:
    s = _string(v)
    if s in ("sim", "none") or re.fullmatch(r"i2c:\d+", s):
        return s
    raise ValueError(f"must be 'i2c:N' (bus number), 'sim' or 'none', got {s!r}")


def _sinks(v: Any) -> tuple[str, ...]:
    if isinstance(v, str):
        v = [s for s in v.split(",") if s.strip()]
    if not isinstance(v, list) or not all(isinstance(s, str) and s.strip() for s in v):
        raise ValueError(f"must be a list of sink specs like [\"jsonl\", \"mcap:out.mcap\"], "
                         f"got {v!r}")
    for spec in v:
        parse_sink_spec(spec)
    return tuple(s.strip() for s in v)


def _rate(v: Any) -> float | None:
    r = _number(0.0)(v)
    return None if r == 0 else r


def _topic(v: Any) -> str | None:
    s = _string(v)
    if s == "":
        return None
    if not s.startswith("/") or s.endswith("/") or " " in s:
        raise ValueError(f"must be an absolute topic name like '/odom' (or \"\" for none), "
                         f"got {s!r}")
    return s


#: table -> key -> (RunConfig field, check). [chassis], [frames], [ekf], [attitude] go to
#: fusion.io.robot_toml.
SCHEMA: dict[str, dict[str, tuple[str, Check]]] = {
    "imu": {
        "source": ("imu", _imu_source),
        "address": ("imu_address", _number(0x08, 0x77, integer=True)),
        "rate_hz": ("imu_rate_hz", _number(4.0, 1000.0)),
        "gyro_range_dps": ("gyro_range_dps", _choice(250, 500, 1000, 2000)),
        "accel_range_g": ("accel_range_g", _choice(2, 4, 8, 16)),
        "dlpf": ("dlpf", _number(0, 6, integer=True)),
        "fifo_interval": ("fifo_interval", _number(0.0, 0.08, open_lo=True)),
        "calibration": ("imu_calibration", _string),
        "tilt": ("tilt", _boolean),
    },
    "link": {
        "port": ("chassis", _string),
        "baudrate": ("baudrate", _number(1, integer=True)),
        "command_timeout": ("command_timeout", _number(0.0, open_lo=True)),
        "silence_periods": ("silence_periods", _number(0.0, open_lo=True)),
    },
    "publish": {
        "sinks": ("publish", _sinks),
        "rate_hz": ("publish_rate_hz", _rate),
        "reorder_window": ("reorder_window", _number(0.0, 1.0)),
    },
    "run": {
        "duration": ("duration", _rate),
        "speed": ("speed", _number(0.1, 20.0)),
        "status": ("status", _number(0.0)),
        "strict": ("strict", _boolean),
    },
    "topics": {
        "odom": ("topics.odom", _topic),
        "tf": ("topics.tf", _topic),
        "imu": ("topics.imu", _topic),
        "wheel_left": ("topics.wheel_left", _topic),
        "wheel_right": ("topics.wheel_right", _topic),
        "cmd_vel": ("cmd_vel_topic", _topic),
    },
}
#: RunConfig field -> (table, key, check), from SCHEMA.
_FIELD_CHECKS = {name: (table, key, check) for table, spec in SCHEMA.items()
                 for key, (name, check) in spec.items()}


def _check_field(name: str, value: Any, origin: str) -> None:
    """``ConfigError`` naming ``origin`` (a field or an option), the table and key, unless the
    file's check of ``name`` accepts ``value`` (None: an optional field not set)."""
    if value is None:
        return
    table, key, check = _FIELD_CHECKS[name]
    try:
        check(value)
    except ValueError as exc:
        raise ConfigError(f"{origin} {exc} (in a file: [{table}] {key})") from None


#: ``fusion run`` option (argparse dest) -> (table, key) in the file.
RUN_OPTIONS: dict[str, tuple[str, str]] = {
    "imu": ("imu", "source"),
    "address": ("imu", "address"),
    "rate": ("imu", "rate_hz"),
    "calibration": ("imu", "calibration"),
    "chassis": ("link", "port"),
    "baudrate": ("link", "baudrate"),
    "publish": ("publish", "sinks"),
    "publish_rate": ("publish", "rate_hz"),
    "duration": ("run", "duration"),
    "speed": ("run", "speed"),
    "status": ("run", "status"),
    "strict": ("run", "strict"),
}
#: RunConfig field -> the ``fusion run`` option that sets it.
_OPTION_OF = {SCHEMA[table][key][0]: "--" + dest.replace("_", "-")
              for dest, (table, key) in RUN_OPTIONS.items()}


def parse_config(doc: dict[str, Any], path: str | Path = "<config>", text: str = "") -> RunConfig:
    """A :class:`RunConfig` from a loaded TOML document (``text`` locates lines in errors).

    Raises:
        ConfigError: an unknown table or key, or a bad value, naming file, line and key.
    """
    path = Path(path)
    known = set(SCHEMA) | set(ROBOT_TABLES)
    for table in doc:
        if table not in known:
            raise ConfigError(f"{where(path, text, table)}: unknown table [{table}]; "
                              f"allowed: {', '.join(sorted(known))}")
        if not isinstance(doc[table], dict):
            raise ConfigError(f"{path}: {table} must be a table [{table}], got {doc[table]!r}")
    robot_doc = {t: doc[t] for t in ROBOT_TABLES if t in doc}
    if robot_doc:
        if "chassis" not in robot_doc:
            if set(robot_doc) != {"attitude"}:
                raise ConfigError(f"{where(path, text, next(iter(robot_doc)))}: [frames]/[ekf] "
                                  "need a [chassis] table (wheel_distance, speed_ratio, "
                                  "encode_sampling_time)")
            robot_doc["chassis"] = asdict(DEMO_ROBOT)  # [attitude] alone: the demo chassis
        try:
            robot = robot_config_from_tables(path, robot_doc, text)  # errors name the line
        except LogFormatError as exc:
            raise ConfigError(str(exc)) from None
    else:
        robot = RunConfig().robot
    values: dict[str, Any] = {"robot": robot, "source": path,
                              "chassis_given": "chassis" in doc}
    topics = dict(RunConfig().topics)
    for table, spec in SCHEMA.items():
        for key, value in doc.get(table, {}).items():
            if key not in spec:
                raise ConfigError(f"{where(path, text, table, key)}: [{table}] unknown key "
                                  f"{key!r}; allowed: {', '.join(sorted(spec))}")
            name, check = spec[key]
            try:
                checked = check(value)
            except ValueError as exc:
                raise ConfigError(f"{where(path, text, table, key)}: [{table}] {key} "
                                  f"{exc}") from None
            if name.startswith("topics."):
                topics[name[7:]] = checked
            else:
                values[name] = checked
    if values.get("imu_calibration"):
        cal = Path(values["imu_calibration"])
        values["imu_calibration"] = str(cal if cal.is_absolute() else path.parent / cal)
    names = [t for t in topics.values() if t is not None]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where(path, text, 'topics')}: [topics] names must be distinct, "
                          f"got {names}")
    values["topics"] = topics
    return RunConfig(**values)


def load_config(path: str | Path) -> RunConfig:
    """Read a configuration file (see the module docstring).

    Raises:
        FileNotFoundError: no such file.
        ConfigError: invalid TOML (with TOML's line and column) or content, naming the file,
            line and key.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (Notepad) is no TOML
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: configuration file not found") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text ({exc})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    return parse_config(doc, path, text)


def read_log_robot(path: str | Path) -> RobotConfig:
    """The robot of a log directory's ``robot.toml``, which may also be the ``fusion run``
    configuration the log was recorded with (README's calibration: ``cp robot.toml ccw/``):
    its run tables (``[link]``, ``[run]``, ...) are checked as ``fusion run`` checks them and
    left out, and ``[chassis]`` is required as in any robot.toml.

    Raises:
        FileNotFoundError: no such file.
        LogFormatError: anything :func:`fusion.io.robot_toml.read_robot_toml` refuses, or a
            bad run table; the message names the file, line and key.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
        doc = tomllib.loads(text)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return read_robot_toml(path)  # which says what is wrong, in its words
    extra = set(doc) - set(ROBOT_TABLES)
    if not extra or not extra <= set(SCHEMA):
        return read_robot_toml(path)  # a robot.toml, or one with tables nobody knows
    try:
        parse_config(doc, path, text)
    except ConfigError as exc:
        raise LogFormatError(str(exc)) from None
    return robot_config_from_tables(path, {t: doc[t] for t in ROBOT_TABLES if t in doc}, text)
