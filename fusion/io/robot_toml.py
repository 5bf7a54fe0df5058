"""``robot.toml``: read and write a :class:`fusion.planar.robot.RobotConfig` (format in
``datasets/LOGDIR.md``). Every error names the file, the table and the key.

The optional ``[attitude]`` table chooses the pipeline's attitude filter::

    [attitude]
    filter = "keel"             # "keel" (default) or "mahony"
    wheel_knowledge = true      # Keel only: feed v*w and wheel stillness (default: on)
    accel_time_constant = 3.0   # any other key: a field of KeelParams / MahonyParams, SI

The optional ``[imu_motion]`` table sets when the IMU counts as still or moving
(:class:`fusion.planar.imu_motion.MotionThresholds`; standard deviations over a short
window, rad/s and m/s^2): an IMU that vibrates at rest needs higher stillness thresholds for
its stops to be zero-velocity updates::

    [imu_motion]
    accel_still = 0.3           # default 0.15 m/s^2
    gyro_still = 0.02           # default 0.01 rad/s
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from fusion.attitude.select import build_attitude_filter, parameter_kinds
from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.atomic import atomic_write
from fusion.io.errors import LogFormatError
from fusion.planar.ekf import EkfNoise
from fusion.planar.imu_motion import MotionThresholds
from fusion.planar.robot import ATTITUDE_FILTERS, AttitudeConfig, RobotConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["key_line", "read_robot_toml", "robot_config_from_tables", "where", "write_robot_toml"]


_CHASSIS_KEYS = {f.name for f in fields(DiffDriveParams)}


_FRAME_KEYS = {"odom", "base", "imu_mount_rpy"}


_EKF_KEYS = {f.name for f in fields(EkfNoise)}


_MOTION_KEYS = {f.name for f in fields(MotionThresholds)}


#: The tables of robot.toml.
ROBOT_TABLES = ("chassis", "frames", "ekf", "attitude", "imu_motion")


def key_line(text: str, table: str, key: str | None) -> int | None:
    """1-based line of ``key`` in ``[table]`` of the TOML ``text`` (or of the table header
    when ``key`` is None or not found), or None."""
    current = None
    header = None
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        m = re.fullmatch(r"\[\s*([A-Za-z0-9_.-]+)\s*\]", line)
        if m:
            current = m.group(1)
            if current == table and header is None:
                header = n
            continue
        if current == table and key is not None:
            m = re.match(r"([A-Za-z0-9_-]+|\"[^\"]*\")\s*=", line)
            if m and m.group(1).strip('"') == key:
                return n
    return header


def where(path: Path, text: str, table: str, key: str | None = None) -> str:
    """``path:line`` of ``key`` in ``[table]`` (just ``path`` when the line is unknown)."""
    line = key_line(text, table, key)
    return f"{path}:{line}" if line is not None else str(path)


def _number(at: str, table: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise LogFormatError(f"{at}: [{table}] {key} must be a number, got {value!r}")
    return float(value)


def read_robot_toml(path: str | Path) -> RobotConfig:
    """Read ``robot.toml`` (see the module docstring).

    Raises:
        LogFormatError: invalid TOML, a missing ``[chassis]`` key, an unknown key (typos are
            not silently ignored) or a value out of range; the message names the file.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (Notepad) is no TOML
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:  # its message has the line and column
        raise LogFormatError(f"{path}: invalid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise LogFormatError(f"{path}: not UTF-8 text ({exc})") from None
    unknown = set(doc) - set(ROBOT_TABLES)
    if unknown:
        first = sorted(unknown)[0]
        raise LogFormatError(f"{where(path, text, first)}: unknown table(s) "
                             f"{sorted(unknown)}; allowed: {', '.join(ROBOT_TABLES)}")
    return robot_config_from_tables(path, doc, text)


#: [chassis] key -> (least, largest plausible value, SI unit, the unit 1000 times smaller):
#: an independent probe's wheel_distance = 300 (mm) and encode_sampling_time = 40 (ms) ran
#: without a word, the odometry 1000 times off. Wide on purpose: a toy robot's 2 cm track, a
#: tractor's 10 m; a 1 ms to a 1 s frame period; 0.1 um to 10 cm of travel per tick.
PLAUSIBLE_CHASSIS = {
    "wheel_distance": (0.02, 10.0, "m", "mm"),
    "encode_sampling_time": (0.001, 1.0, "s", "ms"),
    "speed_ratio": (1e-7, 0.1, "m/tick", "mm per tick"),
}


def robot_config_from_tables(path: str | Path, doc: dict[str, Any],
                             text: str = "") -> RobotConfig:
    """:class:`RobotConfig` from the ``[chassis]``, ``[frames]``, ``[ekf]`` and ``[attitude]``
    tables of an already loaded TOML document (other tables are the caller's:
    :func:`read_robot_toml` refuses them, :mod:`fusion.io.run_config` has its own). ``path``
    names the file in errors, with the line of the key when the document's ``text`` is given.

    Raises:
        LogFormatError: as :func:`read_robot_toml`.
    """
    path = Path(path)

    def at(table: str, key: str | None = None) -> str:
        return where(path, text, table, key)

    chassis = doc.get("chassis")
    if not isinstance(chassis, dict):
        raise LogFormatError(f"{path}: missing [chassis] table (wheel_distance, speed_ratio, "
                             "encode_sampling_time)")
    bad = set(chassis) - _CHASSIS_KEYS
    if bad:
        raise LogFormatError(f"{at('chassis', sorted(bad)[0])}: [chassis] unknown key(s) "
                             f"{sorted(bad)}; allowed: {sorted(_CHASSIS_KEYS)}")
    for key in ("wheel_distance", "speed_ratio", "encode_sampling_time"):
        if key not in chassis:
            raise LogFormatError(f"{at('chassis')}: [chassis] needs {key}")
    values = {k: _number(at("chassis", k), "chassis", k, v) for k, v in chassis.items()}
    for key, (low, high, unit, smaller) in PLAUSIBLE_CHASSIS.items():
        value = values[key]
        if value > 0 and not low <= value <= high:
            hint = (f"; {value:g} looks like {smaller}: {value / 1000:g} {unit}"
                    if value > high else "")
            raise LogFormatError(f"{at('chassis', key)}: [chassis] {key} = {value:g} {unit} "
                                 f"is outside {low:g}-{high:g} {unit}, no wheeled robot's"
                                 f"{hint}")
    try:
        params = DiffDriveParams(**values)
    except ValueError as exc:
        named = next((k for k in chassis if k in str(exc)), None)
        raise LogFormatError(f"{at('chassis', named)}: [chassis] {exc}") from exc

    frames = doc.get("frames", {})
    if not isinstance(frames, dict) or set(frames) - _FRAME_KEYS:
        bad_keys = sorted(set(frames) - _FRAME_KEYS) if isinstance(frames, dict) else [None]
        raise LogFormatError(f"{at('frames', bad_keys[0])}: [frames] allows only "
                             f"{sorted(_FRAME_KEYS)}")
    rpy = frames.get("imu_mount_rpy", [0.0, 0.0, 0.0])
    if not (isinstance(rpy, list) and len(rpy) == 3):
        raise LogFormatError(f"{at('frames', 'imu_mount_rpy')}: [frames] imu_mount_rpy must "
                             f"be [roll, pitch, yaw] in rad, got {rpy!r}")
    rpy_t = tuple(_number(at("frames", "imu_mount_rpy"), "frames", "imu_mount_rpy", v)
                  for v in rpy)
    if not all(math.isfinite(v) for v in rpy_t):
        raise LogFormatError(f"{at('frames', 'imu_mount_rpy')}: [frames] imu_mount_rpy must "
                             f"be finite angles in rad, got {rpy!r}")
    for key in ("odom", "base"):
        if key in frames and not isinstance(frames[key], str):
            raise LogFormatError(f"{at('frames', key)}: [frames] {key} must be a string")

    ekf_tab = doc.get("ekf", {})
    if not isinstance(ekf_tab, dict) or set(ekf_tab) - _EKF_KEYS:
        bad = sorted(set(ekf_tab) - _EKF_KEYS) if isinstance(ekf_tab, dict) else ekf_tab
        first = bad[0] if isinstance(bad, list) and bad else None
        raise LogFormatError(f"{at('ekf', first)}: [ekf] unknown key(s) {bad}; allowed: "
                             f"{sorted(_EKF_KEYS)}")
    ekf_values = {k: _number(at("ekf", k), "ekf", k, v) for k, v in ekf_tab.items()}
    if "zupt_frames" in ekf_values and ekf_values["zupt_frames"].is_integer():
        ekf_values["zupt_frames"] = int(ekf_values["zupt_frames"])  # else EkfNoise refuses it
    try:
        ekf = EkfNoise(**ekf_values)
    except ValueError as exc:
        named = next((k for k in ekf_tab if k in str(exc)), None)
        raise LogFormatError(f"{at('ekf', named)}: [ekf] {exc}") from exc
    attitude = _attitude_config(doc.get("attitude", {}), at)
    motion = _motion_thresholds(doc.get("imu_motion", {}), at)
    try:
        return RobotConfig(
            chassis=params,
            odom_frame=frames.get("odom", "odom"),
            base_frame=frames.get("base", "base_footprint"),
            imu_mount_rpy=rpy_t,  # type: ignore[arg-type]
            ekf=ekf,
            attitude=attitude,
            imu_motion=motion,
        )
    except ValueError as exc:  # a frame name: the only check left to RobotConfig
        key = "base" if "base_frame" in str(exc) else "odom"
        raise LogFormatError(f"{at('frames', key)}: [frames] {key}: {exc}") from exc


def _motion_thresholds(table: Any, at: Any) -> MotionThresholds:
    """The ``[imu_motion]`` table (see the module docstring)."""
    if not isinstance(table, dict) or set(table) - _MOTION_KEYS:
        bad = sorted(set(table) - _MOTION_KEYS) if isinstance(table, dict) else [None]
        raise LogFormatError(f"{at('imu_motion', bad[0])}: [imu_motion] allows only "
                             f"{sorted(_MOTION_KEYS)}")
    values = {k: _number(at("imu_motion", k), "imu_motion", k, v) for k, v in table.items()}
    try:
        return MotionThresholds(**values)
    except ValueError as exc:
        named = next((k for k in table if k in str(exc)), None)
        raise LogFormatError(f"{at('imu_motion', named)}: [imu_motion] {exc}") from exc


def _attitude_config(table: Any, at: Any) -> AttitudeConfig:
    """The ``[attitude]`` table (see the module docstring); ``at(table, key)`` locates keys."""
    if not isinstance(table, dict):
        raise LogFormatError(f"{at('attitude')}: attitude must be a table [attitude], "
                             f"got {table!r}")
    name = table.get("filter", "keel")
    if name not in ATTITUDE_FILTERS:
        raise LogFormatError(f"{at('attitude', 'filter')}: [attitude] filter must be one of "
                             f"{', '.join(map(repr, ATTITUDE_FILTERS))}, got {name!r}")
    kinds = parameter_kinds(name)
    allowed = ["filter", "wheel_knowledge", *sorted(kinds)]
    params = []
    for key, value in table.items():
        if key == "filter":
            continue
        kind = bool if key == "wheel_knowledge" else kinds.get(key)
        if kind is None:
            raise LogFormatError(f"{at('attitude', key)}: [attitude] unknown key {key!r} for "
                                 f"the {name} filter; allowed: {', '.join(allowed)}")
        if kind is bool and not isinstance(value, bool):
            raise LogFormatError(f"{at('attitude', key)}: [attitude] {key} must be true or "
                                 f"false, got {value!r}")
        if kind is float:
            value = _number(at("attitude", key), "attitude", key, value)
        if key != "wheel_knowledge":
            params.append((key, value))
    try:
        config = AttitudeConfig(name, tuple(params), table.get("wheel_knowledge"))
        build_attitude_filter(name, params)  # the filter's own range checks
    except ValueError as exc:
        named = next((k for k in table if k != "filter" and k in str(exc)), None)
        raise LogFormatError(f"{at('attitude', named)}: [attitude] {exc}") from exc
    return config


def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):  # numpy scalars as plain TOML numbers
        v = float(v)
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    return repr(v)


def write_robot_toml(path: str | Path, robot: RobotConfig | DiffDriveParams) -> None:
    """Write ``robot.toml`` for ``robot`` (infinite limits are left out), atomically
    (:func:`fusion.io.atomic.atomic_write`)."""
    if isinstance(robot, DiffDriveParams):
        robot = RobotConfig(chassis=robot)
    c = robot.chassis
    units = {"wheel_distance": "m", "speed_ratio": "m per encoder tick",
             "encode_sampling_time": "s, firmware period", "cmd_vel_linear_max": "m/s",
             "cmd_vel_angular_max": "rad/s", "wheel_speed_max": "m/s"}
    lines = ["# robot.toml: chassis parameters with the names of the miiboo driver (seed 000)",
             "[chassis]"]
    for f in fields(DiffDriveParams):
        v = getattr(c, f.name)
        if isinstance(v, float) and math.isinf(v):
            continue
        lines.append(f"{f.name} = {_toml_value(v)}  # {units.get(f.name, '')}")
    lines += ["", "[frames]", f"odom = {_toml_value(robot.odom_frame)}",
              f"base = {_toml_value(robot.base_frame)}",
              f"imu_mount_rpy = {_toml_value(list(robot.imu_mount_rpy))}  # rad, URDF rpy"]
    default = EkfNoise()
    changed = {f.name: getattr(robot.ekf, f.name) for f in fields(EkfNoise)
               if getattr(robot.ekf, f.name) != getattr(default, f.name)}
    if changed:
        lines += ["", "[ekf]"] + [f"{k} = {_toml_value(v)}" for k, v in changed.items()]
    att = robot.attitude
    if att != AttitudeConfig():
        lines += ["", "[attitude]", f"filter = {_toml_value(att.filter)}"]
        if att.wheel_knowledge is not None:
            lines.append(f"wheel_knowledge = {_toml_value(att.wheel_knowledge)}")
        lines += [f"{k} = {_toml_value(v)}" for k, v in att.params]
    still = MotionThresholds()
    moved = {f.name: getattr(robot.imu_motion, f.name) for f in fields(MotionThresholds)
             if getattr(robot.imu_motion, f.name) != getattr(still, f.name)}
    if moved:
        lines += ["", "[imu_motion]"] + [f"{k} = {_toml_value(v)}" for k, v in moved.items()]
    with atomic_write(path, encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
