"""The log directory: one recorded (or synthetic) run of a differential-drive robot.

A directory holding (format documented in ``datasets/LOGDIR.md``):

- ``imu.csv``: ``t,gx,gy,gz,ax,ay,az[,mx,my,mz]`` (s, rad/s, m/s^2, uT; IMU frame, which is
  the body frame x forward, y left, z up unless ``robot.toml`` gives a mount rotation). Read by
  :func:`fusion.io.imu_csv.read_imu_csv`.
- ``wheels.csv``: ``t,left,right``: host time stamp (s) of the end of each firmware period and
  the signed encoder ticks counted in that period (integers, as on the DATA-uart2 wire); or,
  instead, ``wheels.uart2``: a DATA-uart2 capture (:func:`fusion.io.uart2.read_uart2_capture`,
  timed or raw), stamped as the live link stamps.
- ``truth.csv`` (optional): ``t,x,y,yaw`` ground truth of base_footprint in odom (s, m, m,
  rad).
- ``robot.toml``: ``[chassis]`` with seed 000's names (``wheel_distance`` m, ``speed_ratio``
  m/tick, ``encode_sampling_time`` s, optional limits ``cmd_vel_linear_max`` m/s,
  ``cmd_vel_angular_max`` rad/s, ``wheel_speed_max`` m/s); optional ``[frames]`` (``odom``,
  ``base``, ``imu_mount_rpy`` = URDF roll, pitch, yaw in rad taking IMU-frame vectors into the
  base frame); optional ``[ekf]`` with :class:`fusion.planar.ekf.EkfNoise` field names.

At least one of ``imu.csv`` and ``wheels.csv`` must exist. Every error names the file and,
for CSV content, the line.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.geometry.kinematics import DiffDriveParams
from fusion.geometry.mount import imu_to_base, mount_matrix
from fusion.io.atomic import atomic_write
from fusion.io.errors import LogFormatError
from fusion.io.imu_csv import read_imu_csv
from fusion.io.read_progress import LineProgress, ReadProgress
from fusion.io.repeated_stamps import spread_repeated_stamps
from fusion.io.robot_toml import write_robot_toml
from fusion.io.run_config import read_log_robot
from fusion.io.stamp_units import check_imu_stamps, check_wheel_stamps
from fusion.io.uart2 import read_uart2_capture
from fusion.planar.robot import RobotConfig
from fusion.types.constants import TICKS_MAX

if TYPE_CHECKING:
    from fusion.evaluation.synthetic import SyntheticRun

__all__ = ["LogDir", "read_logdir", "read_truth_csv", "read_wheels_csv", "wheels_csv_lines",
           "write_logdir", "write_synthetic_run"]


WHEELS_COLUMNS = ("t", "left", "right")


TRUTH_COLUMNS = ("t", "x", "y", "yaw")


@dataclass
class LogDir:
    """A loaded log directory (arrays in SI units, see the module docstring).

    Attributes:
        path: the directory.
        robot: :class:`RobotConfig`.
        imu_t, gyro, accel, mag: IMU stamps (s) and base-frame vectors (rad/s, m/s^2, uT;
            rotated by ``imu_mount_rpy``), or None without ``imu.csv`` (``mag`` None without
            magnetometer columns).
        wheel_t, ticks: wheel frame stamps (s) and (M, 2) int64 ticks, or None.
        truth_t, truth: ground truth stamps (s) and (K, 3) ``x, y, yaw``, or None.
        imu_frame: ``"base"`` (vectors rotated by ``imu_mount_rpy``) or ``"imu"`` (as
            recorded).
        capture_stats: the DATA-uart2 parser's counters when the wheel frames came from
            ``wheels.uart2``, else None.
        notes: what reading changed, for the user (IMU samples stamped in batches, spread
            back onto their sampling times: :mod:`fusion.io.repeated_stamps`).
    """

    path: Path
    robot: RobotConfig
    imu_t: NDArray[np.float64] | None = None
    gyro: NDArray[np.float64] | None = None
    accel: NDArray[np.float64] | None = None
    mag: NDArray[np.float64] | None = None
    wheel_t: NDArray[np.float64] | None = None
    ticks: NDArray[np.int64] | None = None
    truth_t: NDArray[np.float64] | None = None
    truth: NDArray[np.float64] | None = None
    imu_frame: str = "base"
    capture_stats: dict[str, int] | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def time_span(self) -> tuple[float, float]:
        """First and last stamp over all streams, s."""
        ts = [a for a in (self.imu_t, self.wheel_t) if a is not None and a.size]
        if not ts:
            raise ValueError(f"{self.path}: the log has no samples")
        return float(min(a[0] for a in ts)), float(max(a[-1] for a in ts))


def _read_csv(path: Path, columns: tuple[str, ...], progress: ReadProgress | None = None
              ) -> tuple[NDArray[np.float64], NDArray]:
    with path.open(newline="") as fh:
        reader = csv.reader(fh if progress is None
                            else LineProgress(fh, path.stat().st_size, progress))
        header = next(reader, None)
        if header is None or tuple(h.strip() for h in header) != columns:
            raise LogFormatError(f"{path}:1: header must be {','.join(columns)}, got "
                                 f"{','.join(header) if header else 'an empty file'!r}")
        rows = []
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(columns):
                raise LogFormatError(f"{path}:{lineno}: expected {len(columns)} fields, "
                                     f"got {len(row)}")
            try:
                values = [float(c) for c in row]
            except ValueError:
                bad = next(c for c in row if not _is_float(c))
                raise LogFormatError(f"{path}:{lineno}: not a number: {bad!r}") from None
            if not all(math.isfinite(v) for v in values):
                raise LogFormatError(f"{path}:{lineno}: non-finite value in {row}")
            rows.append((lineno, values))
    data = np.array([r[1] for r in rows], dtype=float).reshape(-1, len(columns))
    lines = np.array([r[0] for r in rows], dtype=int)
    bad = np.flatnonzero(~(np.diff(data[:, 0]) > 0)) if len(data) > 1 else []
    if len(bad):
        i = int(bad[0]) + 1
        raise LogFormatError(f"{path}:{lines[i]}: time stamp {float(data[i, 0])!r} does not "
                             f"increase (previous {float(data[i - 1, 0])!r})")
    return data, lines


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def read_wheels_csv(path: str | Path, progress: ReadProgress | None = None
                    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Read ``wheels.csv``; returns ``(t, ticks)`` with ticks (M, 2) int64 (left, right).

    Raises:
        LogFormatError: wrong header, non-integer ticks, ticks beyond the 24-bit wire range,
            stamps that do not increase; the message names file and line.
    """
    path = Path(path)
    data, lines = _read_csv(path, WHEELS_COLUMNS, progress)
    ticks = data[:, 1:]
    frac = np.flatnonzero(np.any(ticks != np.round(ticks), axis=1))
    if frac.size:
        raise LogFormatError(f"{path}:{lines[frac[0]]}: ticks must be integers, got "
                             f"{ticks[frac[0]].tolist()}")
    big = np.flatnonzero(np.any(np.abs(ticks) > TICKS_MAX, axis=1))
    if big.size:
        raise LogFormatError(f"{path}:{lines[big[0]]}: ticks {ticks[big[0]].tolist()} exceed "
                             f"the 24-bit range +-{TICKS_MAX} of a DATA-uart2 frame")
    return data[:, 0].copy(), ticks.astype(np.int64)


def wheels_csv_lines(path: str | Path) -> NDArray[np.int64]:
    """(M,) the line of ``wheels.csv`` (1-based) holding each frame :func:`read_wheels_csv`
    returns (rows without values are skipped by the reader, so lines are not indices + 2)."""
    return np.asarray(_read_csv(Path(path), WHEELS_COLUMNS)[1], dtype=np.int64)


def read_truth_csv(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read ``truth.csv``; returns ``(t, poses)`` with poses (K, 3) ``x, y, yaw`` (m, m, rad)."""
    path = Path(path)
    data, _ = _read_csv(path, TRUTH_COLUMNS)
    return data[:, 0].copy(), np.ascontiguousarray(data[:, 1:])


def read_logdir(path: str | Path, *, imu_frame: str = "base", truth: bool = True,
                progress: Callable[[str, int, int], None] | None = None) -> LogDir:
    """Read a log directory (see the module docstring): the one loader of the project.

    Args:
        path: the directory.
        imu_frame: ``"base"``: IMU vectors rotated into the base frame by ``imu_mount_rpy``;
            ``"imu"``: as recorded (the pipeline applies the mount itself).
        truth: read ``truth.csv`` when present.
        progress: ``progress(file name, bytes done, bytes in all)`` while imu.csv and
            wheels.csv are parsed (seconds for large logs).

    Raises:
        FileNotFoundError: the directory or ``robot.toml`` is missing.
        LogFormatError: a file does not match its format, or there is no ``imu.csv``,
            ``wheels.csv`` or ``wheels.uart2``.
    """
    if imu_frame not in ("base", "imu"):
        raise ValueError(f"imu_frame must be 'base' or 'imu', got {imu_frame!r}")
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: not a directory (expected a log directory with "
                                "robot.toml, imu.csv and/or wheels.csv)")
    toml_path = path / "robot.toml"
    if not toml_path.is_file():
        raise FileNotFoundError(f"{toml_path}: missing; a log directory needs robot.toml "
                                "with a [chassis] table")
    robot = read_log_robot(toml_path)  # or the `fusion run` configuration it ran with
    log = LogDir(path=path, robot=robot, imu_frame=imu_frame)
    if (path / "imu.csv").is_file():
        imu = read_imu_csv(path / "imu.csv", _for_file(progress, "imu.csv"))
        log.imu_t, log.gyro, log.accel, log.mag = imu.t, imu.gyro, imu.accel, imu.mag
        if imu_frame == "base":
            R = mount_matrix(robot.imu_mount_rpy)
            log.gyro = imu_to_base(R, imu.gyro) if imu.gyro.size else imu.gyro
            log.accel = imu_to_base(R, imu.accel) if imu.accel.size else imu.accel
            if imu.mag is not None and imu.mag.size:
                log.mag = imu_to_base(R, imu.mag)
    if (path / "wheels.csv").is_file():
        log.wheel_t, log.ticks = read_wheels_csv(path / "wheels.csv",
                                                 _for_file(progress, "wheels.csv"))
    elif (path / "wheels.uart2").is_file():
        period = robot.chassis.encode_sampling_time
        cap = read_uart2_capture(path / "wheels.uart2", period=period)
        log.wheel_t = np.asarray(cap.frame_times(period), dtype=np.float64)
        log.ticks = np.column_stack([cap.left, cap.right]).astype(np.int64).reshape(-1, 2)
        log.capture_stats = cap.stats
    if log.imu_t is None and log.wheel_t is None:
        raise LogFormatError(f"{path}: no imu.csv, wheels.csv or wheels.uart2 found")
    if log.imu_t is not None and log.imu_t.size:
        # samples stamped as a driver handled a batch read at once, microseconds apart
        fix = spread_repeated_stamps(log.imu_t, np.hstack([log.gyro, log.accel]),
                                     str(path / "imu.csv"))
        if fix.note:
            log.imu_t = fix.t
            log.gyro, log.accel = log.gyro[fix.keep], log.accel[fix.keep]
            log.mag = None if log.mag is None else log.mag[fix.keep]
            log.notes.append(fix.note)
    # times in s, and a period that fits the frames (fusion.io.stamp_units)
    if log.imu_t is not None:
        check_imu_stamps(path / "imu.csv", log.imu_t)
    if log.wheel_t is not None and log.capture_stats is None:
        check_wheel_stamps(path / "wheels.csv", log.wheel_t,
                           robot.chassis.encode_sampling_time)
    if truth and (path / "truth.csv").is_file():
        log.truth_t, log.truth = read_truth_csv(path / "truth.csv")
    return log


def _for_file(progress: Callable[[str, int, int], None] | None, name: str
              ) -> ReadProgress | None:
    return None if progress is None else (lambda done, total: progress(name, done, total))


def _write_table(path: Path, header: tuple[str, ...], cols: list[ArrayLike],
                 fmts: list[str]) -> None:
    arrays = [np.asarray(c) for c in cols]
    with atomic_write(path, encoding="ascii", newline="") as fh:
        fh.write(",".join(header) + "\n")
        fmt = ",".join(fmts) + "\n"
        for row in zip(*arrays, strict=True):
            fh.write(fmt % row)


def write_logdir(
    path: str | Path,
    robot: RobotConfig | DiffDriveParams,
    imu_t: ArrayLike | None = None,
    gyro: ArrayLike | None = None,
    accel: ArrayLike | None = None,
    wheel_t: ArrayLike | None = None,
    ticks: ArrayLike | None = None,
    truth_t: ArrayLike | None = None,
    truth: ArrayLike | None = None,
    mag: ArrayLike | None = None,
) -> Path:
    """Write a log directory (created if needed); returns its path.

    Values are written with 17 significant digits (``%.17g``), so reading the directory back
    gives the very same floats. Each file is written atomically
    (:func:`fusion.io.atomic.atomic_write`: replaced only by a complete one); the directory as
    a whole is not (a failure part way leaves the files written before it).
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    write_robot_toml(path / "robot.toml", robot)
    g17 = "%.17g"
    if imu_t is not None:
        t = np.asarray(imu_t, dtype=float)
        g = np.asarray(gyro, dtype=float).reshape(-1, 3)
        a = np.asarray(accel, dtype=float).reshape(-1, 3)
        cols = [t, *g.T, *a.T]
        header = ("t", "gx", "gy", "gz", "ax", "ay", "az")
        if mag is not None:
            m = np.asarray(mag, dtype=float).reshape(-1, 3)
            cols += list(m.T)
            header += ("mx", "my", "mz")
        _write_table(path / "imu.csv", header, cols, [g17] * len(cols))
    if wheel_t is not None:
        tk = np.asarray(ticks).reshape(-1, 2)
        if not np.all(tk == np.round(tk)):
            raise ValueError("ticks must be integers")
        tk = tk.astype(np.int64)
        _write_table(path / "wheels.csv", WHEELS_COLUMNS,
                     [np.asarray(wheel_t, dtype=float), tk[:, 0], tk[:, 1]], [g17, "%d", "%d"])
    if truth_t is not None:
        tr = np.asarray(truth, dtype=float).reshape(-1, 3)
        _write_table(path / "truth.csv", TRUTH_COLUMNS,
                     [np.asarray(truth_t, dtype=float), *tr.T], [g17] * 4)
    return path


def write_synthetic_run(path: str | Path, run: SyntheticRun, truth: bool = True) -> Path:
    """Write a simulated run (:mod:`fusion.evaluation.synthetic`) as a log directory: its
    nominal robot, IMU samples (rad/s, m/s^2), wheel ticks and, with ``truth``, the true pose
    (m, rad). Returns the path.
    """
    return write_logdir(
        path, run.robot, run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks,
        run.truth_t if truth else None, run.truth if truth else None,
    )
