"""``fusion replay``: run the fusion pipeline over recorded logs.

Inputs:

- a log directory (``datasets/LOGDIR.md``): robot.toml, imu.csv and wheels.csv (or a
  DATA-uart2 capture ``wheels.uart2``), optional truth.csv;
- a folder whose subfolders are log directories: every log is replayed in a worker process
  (``--jobs``), one output per log in the ``-o`` folder, and a summary table is printed;
- a DATA-uart2 capture (``*.uart2``, raw bytes or timed ``t,data`` rows, see
  :func:`fusion.io.uart2.read_uart2_capture`) with ``--robot robot.toml``: wheel odometry only;
- a ROS 1 ``.bag``, a ROS 2 bag folder or an ``.mcap`` file with ``--imu-topic``
  (sensor_msgs/Imu) and ``--odom-topic`` (nav_msgs/Odometry, whose twist is the wheel
  odometry, fused as an external twist), ``--imu-mount-rpy`` taking IMU-frame vectors into the
  base frame (URDF rpy, rad; default that of ``--robot``, else none). Needs the ``ros`` extra
  (``rosbags``).

Every input runs through :class:`fusion.pipeline.core.FusionPipeline` (its batch entry point
:meth:`~fusion.pipeline.core.FusionPipeline.push_arrays`), the object ``fusion run`` uses live; a
bag's odometry goes to the pipeline's twist input
(:meth:`~fusion.pipeline.core.FusionPipeline.push_twist`).

Outputs (``-o``/``--output``, chosen by suffix): ``.csv`` is the replay CSV below, one row per
IMU sample (or per wheel frame when the log has no IMU), the whole run; ``.mcap``
(nav_msgs/Odometry, tf, sensor_msgs/Imu, wheel speeds; the ``ros`` extra) and ``.jsonl``
(:meth:`fusion.types.fused.FusedOdometry.to_dict` per line) get the pipeline's records, one per
wheel frame (a bag: per odometry message), through :func:`fusion.sinks.registry.open_sink`. An
existing file is only ever replaced by a complete one. The replay CSV header::

    t,x,y,yaw,v,w,gyro_bias_z,wheel_rate_scale,wheel_rate_per_speed,
    var_x,var_y,var_yaw,cov_xy,cov_x_yaw,cov_y_yaw

``t`` s (host clock), pose of base_footprint in odom (m, m, rad wrapped to (-pi, pi]), v m/s,
w rad/s, gyro bias rad/s, the wheel calibration states k (1) and c (rad/m) of
:mod:`fusion.planar.ekf`, and the pose covariance (m^2, m*rad, rad^2).

``--plot out.png`` draws the fused, wheel-only and (when present) true trajectories and the
yaw error (matplotlib, the ``demo`` extra). Progress goes to standard error when it is a
terminal and the input is long (:data:`AUTO_PROGRESS_MIN_SPAN`, or a folder of logs), or with
``--progress``: a tqdm bar (the ``progress`` extra) or a plain line.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.cli import CommandError

__all__ = [
    "AUTO_PROGRESS_MIN_SPAN",
    "FUSED_CSV_COLUMNS",
    "OUTPUT_FORMATS",
    "ReplayResult",
    "find_log_dirs",
    "fuse_logdir",
    "register",
    "replay_capture",
    "replay_logdir",
    "write_fused_csv",
]

FUSED_CSV_COLUMNS = (
    "t", "x", "y", "yaw", "v", "w", "gyro_bias_z", "wheel_rate_scale", "wheel_rate_per_speed",
    "var_x", "var_y", "var_yaw", "cov_xy", "cov_x_yaw", "cov_y_yaw",
)

#: Output suffix -> format.
OUTPUT_FORMATS = {".csv": "csv", ".mcap": "mcap", ".jsonl": "jsonl"}

CAPTURE_SUFFIXES = (".uart2",)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="fused wheel + gyro odometry (EKF) of recorded logs",
        description=(
            "Run the fusion pipeline (Mahony attitude + planar EKF: wheel odometry and the "
            "gyro yaw rate with a gyro-bias state) over a log directory (robot.toml, imu.csv "
            "and/or wheels.csv or wheels.uart2, optional truth.csv; see datasets/LOGDIR.md), "
            "a folder of log directories (in parallel worker processes), a DATA-uart2 "
            "capture (*.uart2, with --robot) or a ROS bag, and write the fused odometry: "
            ".csv (the header " + ",".join(FUSED_CSV_COLUMNS) + ", one row per IMU sample), "
            ".mcap or .jsonl (the pipeline's records, one per wheel frame or bag odometry "
            "message). Prints a "
            "summary; with truth.csv, the errors of the fused and of the wheel-only odometry."
        ),
    )
    p.add_argument("input", type=Path,
                   help="log directory, folder of log directories, *.uart2 capture, or a "
                        "ROS 1 .bag / ROS 2 bag folder / .mcap file")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="fused.csv | fused.mcap | fused.jsonl (format by suffix); for a folder "
                        "of logs, the folder to write one output per log into")
    p.add_argument("--format", choices=sorted(set(OUTPUT_FORMATS.values())), default="csv",
                   help="output format of each log of a folder of logs (default csv)")
    p.add_argument("--level", action="store_true",
                   help="take the robot as level: use the gyro's z axis as the yaw rate "
                        "(default: tilt-compensate with the Mahony attitude)")
    p.add_argument("--plot", type=Path, metavar="PNG",
                   help="draw fused vs wheel-only (vs truth) trajectories and the yaw error to "
                        "this PNG (for a folder of logs: a folder, one PNG per log); needs "
                        "matplotlib (pip install 'diffbot-fusion[demo]')")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress on stderr (default: when stderr is a terminal, for logs "
                        "of 10 minutes or more and for folders of logs)")
    p.add_argument("-j", "--jobs", type=int, default=None,
                   help="worker processes for a folder of logs (default: the CPU count)")
    p.add_argument("--robot", type=Path,
                   help="robot.toml for a capture (required) or a bag (wheel_distance and "
                        "[ekf] tuning; optional)")
    bag = p.add_argument_group("ROS bags")
    bag.add_argument("--imu-topic", help="sensor_msgs/Imu topic (bags only)")
    bag.add_argument("--odom-topic", help="nav_msgs/Odometry topic of the wheel odometry "
                                          "(bags only)")
    bag.add_argument("--imu-mount-rpy", type=float, nargs=3, metavar=("R", "P", "Y"),
                     default=None,
                     help="URDF roll pitch yaw (rad) taking IMU-frame vectors into the base "
                          "frame (bags only; default: imu_mount_rpy of --robot, else 0 0 0; "
                          "a log directory has it in robot.toml)")
    p.set_defaults(func=run)


def fuse_logdir(log, tilt: bool = True):
    """Fuse a :class:`fusion.io.logdir.LogDir` with :func:`fusion.planar.ekf.fuse` (the batch filter
    alone, without the pipeline); returns ``(track, filter, rows)``.

    With ``tilt`` and an IMU, the yaw rate is the gyro rate about the world vertical, using
    the Mahony filter's attitude (6-axis); otherwise the gyro's z axis. ``rows`` is the mask of
    :meth:`fusion.planar.ekf.FusedTrack.output_rows`.
    """
    from fusion.planar.ekf import fuse, vertical_rate

    gyro_z = None
    if log.imu_t is not None and log.imu_t.size:
        if tilt and log.imu_t.size >= 2:
            from fusion.attitude.mahony import Mahony

            q = Mahony(axes=6).update_batch(log.gyro, log.accel, timestamps=log.imu_t)
            gyro_z = vertical_rate(log.gyro, q)
        else:
            gyro_z = log.gyro[:, 2].copy()
    track, ekf = fuse(log.robot.chassis, log.imu_t if gyro_z is not None else None, gyro_z,
                      log.wheel_t, log.ticks, log.robot.ekf)
    return track, ekf, track.output_rows()


def _table(t: NDArray[np.float64], states: NDArray[np.float64]) -> NDArray[np.float64]:
    """Replay CSV rows from :meth:`fusion.planar.ekf.PlanarEKF.process_batch` rows (yaw wrapped)."""
    yaw = np.pi - np.mod(np.pi - states[:, 2], 2 * np.pi)
    return np.column_stack([t, states[:, 0:2], yaw, states[:, 3:8], states[:, 8:11],
                            states[:, 16:19]])


def _write_table(path: Path, table: NDArray[np.float64]) -> None:
    from fusion.sinks.base import create_temp_file

    tmp = create_temp_file(path)  # the umask's permissions, a unique name
    try:
        np.savetxt(tmp, table, delimiter=",", header=",".join(FUSED_CSV_COLUMNS), comments="",
                   fmt="%.10g")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def write_fused_csv(path: Path, t: NDArray[np.float64], states: NDArray[np.float64]) -> None:
    """Write ``t`` and process_batch rows ``states`` as the replay CSV, atomically (an
    existing file is replaced only by a complete one)."""
    _write_table(Path(path), _table(t, states))


# -- progress -----------------------------------------------------------------------------------


class _Progress:
    """Progress of one replay on stderr: a tqdm bar if tqdm is installed, else a plain line
    at most every ``interval`` s; nothing when disabled."""

    def __init__(self, total: float, desc: str, unit: str, enabled: bool,
                 interval: float = 1.0) -> None:
        self.total = max(float(total), 0.0)
        self.desc = desc
        self.unit = unit
        self.enabled = enabled
        self.interval = interval
        self._bar = None
        self._done = 0.0
        self._last = -math.inf
        if enabled:
            try:
                from tqdm import tqdm
            except ImportError:
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=math.ceil(self.total), desc=desc, unit=unit,
                                 file=sys.stderr, leave=False, dynamic_ncols=True)

    def update_to(self, done: float) -> None:
        if not self.enabled:
            return
        done = min(max(float(done), self._done), self.total)
        self._done = done
        if self._bar is not None:
            step = int(done) - self._bar.n  # whole units
            if step > 0:
                self._bar.update(step)
            return
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self._line()

    def _line(self) -> None:
        pct = 100.0 * self._done / self.total if self.total > 0 else 100.0
        print(f"{self.desc}: {pct:3.0f}% ({self._done:.1f}/{self.total:.1f} {self.unit})",
              file=sys.stderr, flush=True)

    def close(self) -> None:
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
        else:
            self._done = self.total
            self._line()


#: Without --progress/--no-progress, a log of at least this many seconds shows its progress
#: when stderr is a terminal (a shorter one replays in about a second).
AUTO_PROGRESS_MIN_SPAN = 600.0


def _stderr_is_tty() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def _progress_for(flag: bool | None, span: float) -> bool:
    """--progress: True; --no-progress: False; None: a long log on a terminal."""
    if flag is not None:
        return bool(flag)
    return span >= AUTO_PROGRESS_MIN_SPAN and _stderr_is_tty()


# -- replay through the pipeline ------------------------------------------------------------------


@dataclass
class ReplayResult:
    """What a replay did (picklable: a worker process returns it).

    Attributes:
        source, output: input and output paths.
        span: s of log time; n_imu, n_wheels: IMU samples and wheel frames read.
        rows: rows of the replay CSV (the fused state at every IMU sample, or wheel frame
            without an IMU); records: pipeline records (one per wheel frame).
        final: last fused pose (x m, y m, yaw rad wrapped); distance: integral of |v|, m.
        gyro_bias: rad/s; k (1), c (rad/m): the EKF's wheel yaw-rate calibration states.
        stats: the pipeline's counters (:meth:`fusion.pipeline.core.PipelineStats.as_dict`).
        truth: with truth, ``distance`` m and the fused/wheel-only final position error (% of
            distance) and yaw RMSE (deg); else None.
        notes: warnings for the user.
    """

    source: str
    output: str
    span: float
    n_imu: int
    n_wheels: int
    rows: int
    records: int
    final: tuple[float, float, float]
    distance: float
    gyro_bias: float
    k: float
    c: float
    stats: dict[str, Any]
    wheel_distance: float
    truth: dict[str, float] | None = None
    notes: list[str] = field(default_factory=list)


class _StateTap:
    """Keeps the replay CSV rows from the EKF's batch calls inside the pipeline.

    Installed as the pipeline's filter (:class:`_TappedEKF`): every ``process_batch`` the
    pipeline makes hands over its events' kinds, effective times and state rows; the rows of
    the ``keep_kinds`` become the CSV (the state after every IMU sample, or without an IMU
    after every wheel frame or twist: :meth:`fusion.planar.ekf.FusedTrack.output_rows`' rule).
    """

    def __init__(self, keep_kinds: tuple[int, ...],
                 on_time: Callable[[float], None] | None) -> None:
        self.keep_kinds = keep_kinds
        self.on_time = on_time
        self._pending: list[tuple[NDArray, NDArray, NDArray]] = []
        self._chunks: list[NDArray[np.float64]] = []

    def __call__(self, kinds, t_eff, states) -> None:
        self._pending.append((np.asarray(kinds), np.asarray(t_eff), states))
        if len(self._pending) >= 256:
            self._compact()
        if self.on_time is not None and len(t_eff):
            self.on_time(float(t_eff[-1]))

    def _compact(self) -> None:
        if not self._pending:
            return
        kinds = np.concatenate([p[0] for p in self._pending])
        t = np.concatenate([p[1] for p in self._pending])
        states = np.concatenate([p[2] for p in self._pending])
        self._pending.clear()
        keep = np.isin(kinds, self.keep_kinds)
        self._chunks.append(_table(t[keep], states[keep]))

    def table(self) -> NDArray[np.float64]:
        self._compact()
        if not self._chunks:
            return np.zeros((0, len(FUSED_CSV_COLUMNS)))
        return np.concatenate(self._chunks)


def _tapped_ekf(chassis, noise, tap: _StateTap):
    from fusion.planar.ekf import PlanarEKF

    class _TappedEKF(PlanarEKF):
        def process_batch(self, kinds, t_eff, a, b):
            states, status = super().process_batch(kinds, t_eff, a, b)
            tap(kinds, t_eff, states)
            return states, status

    return _TappedEKF(chassis, noise)


def _output_format(path: Path) -> str:
    fmt = OUTPUT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise CommandError(f"{path}: unknown output type {path.suffix or '(no suffix)'!r}; "
                           "give a .csv, .mcap or .jsonl file")
    if not path.parent.is_dir():
        raise CommandError(f"{path}: the folder {path.parent} does not exist")
    if path.is_dir():
        raise CommandError(f"{path}: is a folder; give a file path")
    return fmt


def _check_plot_available(path: Path | None = None) -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CommandError("--plot needs matplotlib: pip install 'diffbot-fusion[demo]'") \
            from None
    if path is not None and not path.parent.is_dir():
        raise CommandError(f"{path}: the folder {path.parent} does not exist")


def _fuse_through_pipeline(robot, imu, wheel_t, ticks, *, tilt: bool, output: Path,
                           progress: bool | None, desc: str, odom=None):
    """Run the arrays through a :class:`fusion.pipeline.core.FusionPipeline` (batch path) into the
    output; returns ``(table, pipeline, stats)``. ``imu``: ``t, gyro, accel`` (IMU frame);
    ``odom``: ``t, v, w`` external odometry twists (a bag's nav_msgs/Odometry), or None."""
    from fusion.pipeline.core import FusionPipeline
    from fusion.planar import _ekf_core as core
    from fusion.sinks.registry import open_sink

    fmt = _output_format(output)
    has_imu = imu is not None and imu.t.size > 0
    has_wheels = wheel_t is not None and wheel_t.size > 0
    has_odom = odom is not None and odom.t.size > 0
    streams = [a for a, on in ((imu.t if has_imu else None, has_imu), (wheel_t, has_wheels),
                               (odom.t if has_odom else None, has_odom)) if on]
    t0 = min(float(a[0]) for a in streams)
    t1 = max(float(a[-1]) for a in streams)
    bar = _Progress(t1 - t0, desc, "s", _progress_for(progress, t1 - t0))
    tap = _StateTap((core.EV_GYRO,) if has_imu else (core.EV_WHEELS, core.EV_TWIST),
                    lambda t: bar.update_to(t - t0))
    sinks = [] if fmt == "csv" else [open_sink(f"{fmt}:{output}")]
    sources = [name for name, on in (("imu", has_imu), ("wheels", has_wheels),
                                     ("twist", has_odom)) if on]
    rate = 100.0  # the IMU's rate, Hz: the Mahony filter's first step (as live)
    if has_imu and imu.t.size >= 2:
        dt = float(np.median(np.diff(imu.t)))
        if math.isfinite(dt) and dt > 0:
            rate = round(1.0 / dt, 3)  # nominal: 100.0, not 99.99999 from jittered stamps
    pipe = FusionPipeline(robot, sinks, tilt=tilt, sources=sources, imu_rate_hz=rate)
    pipe.ekf = _tapped_ekf(robot.chassis, robot.ekf, tap)  # before any event: same filter
    try:
        try:
            pipe.open()
        except ImportError as exc:
            raise CommandError(f"{output}: {exc}") from None
        with pipe:
            pipe.push_arrays(imu.t if has_imu else None, imu.gyro if has_imu else None,
                             imu.accel if has_imu else None,
                             wheel_t if has_wheels else None, ticks if has_wheels else None,
                             twist_t=odom.t if has_odom else None,
                             twist_v=odom.v if has_odom else None,
                             twist_w=odom.w if has_odom else None)
        table = tap.table()
        if fmt == "csv":
            _write_table(output, table)
    finally:
        bar.close()
    return table, pipe, pipe.finish_stats()


def _load_logdir(path: Path):
    """``(robot, imu or None, wheel_t, ticks, truth_t, truth, capture_stats)``; the IMU in
    its own frame (the pipeline applies ``imu_mount_rpy``)."""
    from fusion.io.imu_csv import read_imu_csv
    from fusion.io.logdir import read_truth_csv, read_wheels_csv
    from fusion.io.robot_toml import read_robot_toml
    from fusion.pipeline.sources import capture_events

    toml_path = path / "robot.toml"
    if not toml_path.is_file():
        raise FileNotFoundError(f"{toml_path}: missing; a log directory needs robot.toml "
                                "with a [chassis] table")
    robot = read_robot_toml(toml_path)
    imu = read_imu_csv(path / "imu.csv") if (path / "imu.csv").is_file() else None
    cap_stats = None
    if (path / "wheels.csv").is_file():
        wheel_t, ticks = read_wheels_csv(path / "wheels.csv")
    elif (path / "wheels.uart2").is_file():
        frames, cap_stats = capture_events(path / "wheels.uart2",
                                           robot.chassis.encode_sampling_time)
        wheel_t, ticks = _frame_arrays(frames)
    else:
        wheel_t, ticks = np.zeros(0), np.zeros((0, 2), np.int64)
    if wheel_t.size == 0:
        raise CommandError(f"{path}: wheels.csv is missing or empty; the fused odometry needs "
                           "the wheel encoder frames")
    truth_t = truth = None
    if (path / "truth.csv").is_file():
        truth_t, truth = read_truth_csv(path / "truth.csv")
    return robot, imu, wheel_t, ticks, truth_t, truth, cap_stats


def _frame_arrays(frames) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    t = np.array([f.t for f in frames], dtype=np.float64)
    ticks = np.array([(f.left, f.right) for f in frames], dtype=np.int64).reshape(-1, 2)
    return t, ticks


def replay_logdir(path: str | Path, output: str | Path, *, tilt: bool = True,
                  plot: str | Path | None = None,
                  progress: bool | None = False) -> ReplayResult:
    """Replay a log directory through the pipeline into ``output`` (.csv/.mcap/.jsonl);
    optionally draw ``plot`` (PNG). Raises on bad input, leaving no partial output.

    ``progress``: on stderr (True), not (False), or (None) when the log spans at least
    :data:`AUTO_PROGRESS_MIN_SPAN` s and stderr is a terminal."""
    path, output = Path(path), Path(output)
    robot, imu, wheel_t, ticks, truth_t, truth, cap_stats = _load_logdir(path)
    return _finish(path, output, robot, imu, wheel_t, ticks, truth_t, truth, tilt=tilt,
                   plot=plot, progress=progress, capture_stats=cap_stats)


def replay_capture(path: str | Path, output: str | Path, robot_toml: str | Path, *,
                   plot: str | Path | None = None,
                   progress: bool | None = False) -> ReplayResult:
    """Replay a DATA-uart2 capture (wheel odometry only) with the chassis of ``robot_toml``.

    A timed capture is stamped as the live link stamps; a raw one on the firmware period
    (:func:`fusion.pipeline.sources.capture_events`)."""
    from fusion.io.robot_toml import read_robot_toml
    from fusion.pipeline.sources import capture_events

    path, output = Path(path), Path(output)
    robot = read_robot_toml(robot_toml)
    frames, stats = capture_events(path, robot.chassis.encode_sampling_time)
    if not frames:
        raise CommandError(f"{path}: no DATA-uart2 frame in the capture "
                           f"(parser counters: {stats})")
    wheel_t, ticks = _frame_arrays(frames)
    return _finish(path, output, robot, None, wheel_t, ticks, None, None, tilt=True,
                   plot=plot, progress=progress, capture_stats=stats)


def _finish(path, output, robot, imu, wheel_t, ticks, truth_t, truth, *, tilt, plot, progress,
            capture_stats) -> ReplayResult:
    from fusion.evaluation.trajectory import final_position_error_percent, path_length, yaw_rmse
    from fusion.planar.odometry import WheelOdometry

    if plot is not None:
        _check_plot_available(Path(plot))
    table, pipe, stats = _fuse_through_pipeline(robot, imu, wheel_t, ticks, tilt=tilt,
                                                output=output, progress=progress,
                                                desc=path.name)
    chassis = robot.chassis
    ekf = pipe.ekf
    n_imu = 0 if imu is None else int(imu.t.size)
    times = [a for a in ((imu.t if n_imu else None), wheel_t) if a is not None and a.size]
    span = max(float(a[-1]) for a in times) - min(float(a[0]) for a in times)
    notes = []
    if capture_stats is not None:
        bad = {k: v for k, v in capture_stats.items() if k != "frames" and v}
        if bad:
            notes.append(f"capture parser counters: {bad}")
    if n_imu and (wheel_t[-1] > imu.t[-1] + chassis.encode_sampling_time
                  or wheel_t[0] < imu.t[0] - chassis.encode_sampling_time):
        notes.append(f"wheel frames span {wheel_t[0]:.3f}-{wheel_t[-1]:.3f} s, the IMU "
                     f"{imu.t[0]:.3f}-{imu.t[-1]:.3f} s; rows are written at IMU samples "
                     "only, so the output covers the IMU's span")
    t_out, states_xy, yaw_out = table[:, 0], table[:, 1:3], table[:, 3]
    wheel = WheelOdometry(chassis).update_batch(ticks[:, 0], ticks[:, 1])
    truth_res = None
    if truth_t is not None and truth_t.size:
        tr = _truth_at(truth_t, truth, t_out)
        dist = path_length(truth)
        inside = (t_out >= truth_t[0]) & (t_out <= truth_t[-1])
        wtruth = _truth_at(truth_t, truth, wheel_t)
        w_in = (wheel_t >= truth_t[0]) & (wheel_t <= truth_t[-1])
        nan = math.nan  # a robot that did not move has no error per distance
        truth_res = {
            "distance": dist,
            "fused_pct": final_position_error_percent(states_xy[inside], tr[inside, :2], dist)
            if dist > 0 else nan,
            "fused_yaw_deg": math.degrees(yaw_rmse(yaw_out[inside], tr[inside, 2])),
            "wheel_pct": final_position_error_percent(wheel[w_in, :2], wtruth[w_in, :2], dist)
            if dist > 0 else nan,
            "wheel_yaw_deg": math.degrees(yaw_rmse(wheel[w_in, 2], wtruth[w_in, 2])),
        }
    if plot is not None:
        _plot(Path(plot), path.name, table, wheel_t, wheel, truth_t, truth)
    last = table[-1]
    return ReplayResult(
        source=str(path), output=str(output), span=span, n_imu=n_imu,
        n_wheels=int(wheel_t.size), rows=int(table.shape[0]), records=stats.records,
        final=(float(last[1]), float(last[2]), float(last[3])),
        distance=_distance(t_out, table[:, 4]), gyro_bias=float(ekf.gyro_bias),
        k=float(ekf.x[6]), c=float(ekf.x[7]),
        stats={**stats.as_dict(), "invalid": ekf.stats["invalid"]},
        wheel_distance=chassis.wheel_distance, truth=truth_res, notes=notes)


def _plot(path: Path, title: str, table, wheel_t, wheel, truth_t, truth,
          wheel_label: str = "wheel only") -> None:
    """Trajectories (fused, wheel-only, truth) and yaw error (or yaw without truth) to a PNG,
    written atomically with the umask's permissions. ``wheel_label`` names the wheel-only
    track (a bag's own odometry)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fusion.sinks.base import create_temp_file

    t = table[:, 0]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.5))
    try:
        if truth is not None:
            ax1.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="truth")
        ax1.plot(wheel[:, 0], wheel[:, 1], "-", color="tab:orange", lw=1, label=wheel_label)
        ax1.plot(table[:, 1], table[:, 2], "-", color="tab:blue", lw=1, label="fused EKF")
        ax1.set_aspect("equal", adjustable="datalim")
        ax1.set_xlabel("x (m)")
        ax1.set_ylabel("y (m)")
        ax1.grid(True, alpha=0.3)
        ax1.legend(loc="best", fontsize=9)
        ax1.set_title("Trajectory in odom")
        if truth is not None:
            def err(ts, yaw):
                ref = np.interp(ts, truth_t, np.unwrap(truth[:, 2]))
                return np.degrees(np.angle(np.exp(1j * (yaw - ref))))

            inside = (t >= truth_t[0]) & (t <= truth_t[-1])
            w_in = (wheel_t >= truth_t[0]) & (wheel_t <= truth_t[-1])
            ax2.plot(wheel_t[w_in], err(wheel_t[w_in], wheel[w_in, 2]), color="tab:orange",
                     lw=1, label=wheel_label)
            ax2.plot(t[inside], err(t[inside], table[inside, 3]), color="tab:blue", lw=1,
                     label="fused EKF")
            ax2.axhline(0.0, color="k", lw=0.8)
            ax2.set_ylabel("yaw error (deg)")
            ax2.set_title("Yaw error against the truth")
        else:
            ax2.plot(wheel_t, np.degrees(np.angle(np.exp(1j * wheel[:, 2]))),
                     color="tab:orange", lw=1, label=wheel_label)
            ax2.plot(t, np.degrees(table[:, 3]), color="tab:blue", lw=1, label="fused EKF")
            ax2.set_ylabel("yaw (deg)")
            ax2.set_title("Yaw (no truth in the log)")
        ax2.set_xlabel("t (s)")
        ax2.grid(True, alpha=0.3)
        ax2.legend(loc="best", fontsize=9)
        fig.suptitle(f"fusion replay: {title}")
        fig.tight_layout()
        tmp = create_temp_file(path)
        try:
            fig.savefig(tmp, dpi=100, format="png")
            tmp.replace(path)
        finally:
            tmp.unlink(missing_ok=True)
    finally:
        plt.close(fig)


def _print_result(r: ReplayResult, level_note: bool = True) -> None:
    s = r.stats
    print(f"{r.source}: {r.span:.1f} s, {r.n_imu} IMU samples, {r.n_wheels} wheel frames "
          f"-> {r.output} ({r.rows} rows, {r.records} records)")
    x, y, yaw = r.final
    print(f"final pose: x {x:.3f} m, y {y:.3f} m, yaw {math.degrees(yaw):.2f} deg; path "
          f"{r.distance:.2f} m")
    print(f"gyro bias {math.degrees(r.gyro_bias):+.4f} deg/s; ZUPTs {s['zupts']}, "
          f"slip frames {s['slips']}, late inputs fused {s['late_applied']}, dropped "
          f"{s['late_dropped']}, invalid {s['invalid']}; wheel gaps {s['gap_count']} "
          f"({s['frames_missing']} frames missing)")
    for note in r.notes:
        print(f"warning: {note}")
    if r.n_imu:
        print(f"wheel yaw-rate calibration seen by the gyro: k {r.k:+.4f} "
              f"(wheel_distance ~ {r.wheel_distance * (1 + r.k):.4f} m), "
              f"c {r.c:+.5f} rad/m; see `fusion calibrate odometry` for corrected parameters")
    elif level_note:
        print("no imu.csv: wheel odometry only (no gyro to fuse)")
    if r.truth is not None:
        tr = r.truth
        print(f"truth: {tr['distance']:.2f} m travelled")
        print(f"  fused:      final position error {tr['fused_pct']:.3f} % of distance, "
              f"yaw RMSE {tr['fused_yaw_deg']:.3f} deg")
        print(f"  wheel only: final position error {tr['wheel_pct']:.3f} % of distance, "
              f"yaw RMSE {tr['wheel_yaw_deg']:.3f} deg")


# -- folders of logs ------------------------------------------------------------------------------


def find_log_dirs(path: Path) -> list[Path]:
    """The subfolders of ``path`` that are log directories (have robot.toml), sorted."""
    return sorted(p for p in path.iterdir() if p.is_dir() and (p / "robot.toml").is_file())


def _replay_job(job: tuple[str, str, bool, str | None]) -> tuple[str, Any]:
    """Worker: replay one log; ``("ok", ReplayResult)`` or ``("error", message)``."""
    path, output, tilt, plot = job
    try:
        return "ok", replay_logdir(path, output, tilt=tilt, plot=plot, progress=False)
    except Exception as exc:  # reported in the summary; the other logs go on
        msg = str(exc) or type(exc).__name__
        if path not in msg:
            msg = f"{path}: {msg}"
        return "error", f"{msg} ({type(exc).__name__})"


def _run_folder(args: argparse.Namespace, logs: list[Path]) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    out_dir: Path = args.output
    if out_dir.suffix.lower() in OUTPUT_FORMATS and not out_dir.is_dir():
        raise CommandError(f"{out_dir}: for a folder of logs, -o is the folder to write one "
                           f"output per log into (choose the type with --format)")
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"{out_dir}: exists and is not a folder")
    if args.plot is not None:
        _check_plot_available()
        if args.plot.exists() and not args.plot.is_dir():
            raise CommandError(f"{args.plot}: for a folder of logs, --plot is a folder")
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 1:
        raise CommandError(f"--jobs must be >= 1, got {jobs}")
    jobs = min(jobs, len(logs))
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.plot is not None:
        args.plot.mkdir(parents=True, exist_ok=True)
    ext = {"csv": ".csv", "mcap": ".mcap", "jsonl": ".jsonl"}[args.format]
    work = [(str(p), str(out_dir / (p.name + ext)), not args.level,
             None if args.plot is None else str(args.plot / (p.name + ".png"))) for p in logs]
    results: dict[str, tuple[str, Any]] = {}
    bar = _Progress(len(work), f"replay {len(work)} logs", "logs",
                    _stderr_is_tty() if args.progress is None else args.progress,
                    interval=0.0)
    try:
        if jobs == 1:
            for w in work:
                results[w[0]] = _replay_job(w)
                bar.update_to(len(results))
        else:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                futures = {pool.submit(_replay_job, w): w[0] for w in work}
                for fut in as_completed(futures):
                    try:
                        results[futures[fut]] = fut.result()
                    except Exception as exc:  # a worker died (killed, out of memory)
                        results[futures[fut]] = ("error",
                                                 f"{futures[fut]}: worker failed: {exc!r}")
                    bar.update_to(len(results))
    finally:
        bar.close()
    failed = _print_table(work, results, jobs)
    return 1 if failed else 0


def _print_table(work, results, jobs: int) -> int:
    head = (f"{'log':<24} {'status':<6} {'time s':>8} {'IMU':>8} {'wheels':>7} "
            f"{'final x':>8} {'final y':>8} {'yaw deg':>8} {'fused %':>8} {'wheel %':>8}  output")
    print(head)
    failed = 0
    for path, output, _tilt, _plot in work:
        status, value = results[path]
        name = Path(path).name
        if status != "ok":
            failed += 1
            print(f"{name:<24} {'FAILED':<6} {value}")
            continue
        r: ReplayResult = value
        fp = wp = "-"
        if r.truth is not None:
            fp, wp = f"{r.truth['fused_pct']:.3f}", f"{r.truth['wheel_pct']:.3f}"
        print(f"{name:<24} {'ok':<6} {r.span:>8.1f} {r.n_imu:>8} {r.n_wheels:>7} "
              f"{r.final[0]:>8.3f} {r.final[1]:>8.3f} {math.degrees(r.final[2]):>8.2f} "
              f"{fp:>8} {wp:>8}  {output}")
    print(f"{len(work) - failed} of {len(work)} logs replayed ({jobs} worker process"
          f"{'es' if jobs != 1 else ''}); {failed} failed")
    for path, _o, _t, _p in work:
        status, value = results[path]
        if status != "ok":
            print(f"fusion replay: {value}", file=sys.stderr)
    return failed


# -- command --------------------------------------------------------------------------------------


def run(args: argparse.Namespace) -> int:
    path: Path = args.input
    if not path.exists():
        raise CommandError(f"{path}: no such log directory or bag")
    if _is_bag(path):
        return run_bag(args)
    if args.imu_topic or args.odom_topic:
        raise CommandError(f"{path}: --imu-topic/--odom-topic are for ROS bags; this is not "
                           "a .bag, .mcap or ROS 2 bag folder")
    progress = args.progress
    if path.is_file():
        if path.suffix.lower() not in CAPTURE_SUFFIXES:
            raise CommandError(f"{path}: is a file; replay takes a log directory "
                               "(robot.toml, imu.csv, wheels.csv; see datasets/LOGDIR.md), a "
                               "folder of them, a DATA-uart2 capture (.uart2) or a ROS bag "
                               "(.bag, .mcap, ROS 2 folder)")
        if args.robot is None:
            raise CommandError(f"{path}: a capture needs --robot robot.toml (the chassis "
                               "geometry and encode_sampling_time)")
        r = replay_capture(path, args.output, args.robot, plot=args.plot, progress=progress)
        _print_result(r, level_note=False)
        print("DATA-uart2 capture: wheel odometry only (no gyro to fuse)")
        return 0
    if not (path / "robot.toml").is_file():
        logs = find_log_dirs(path)
        if logs:
            return _run_folder(args, logs)
    r = replay_logdir(path, args.output, tilt=not args.level, plot=args.plot,
                      progress=progress)
    _print_result(r)
    return 0


def _distance(t: NDArray[np.float64], v: NDArray[np.float64]) -> float:
    """Distance travelled, m: the integral of the fused |v| (the polyline through 100 Hz
    position estimates would add their noise)."""
    v = np.abs(v)
    return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)))


def _is_bag(path: Path) -> bool:
    if path.is_file():
        return path.suffix.lower() in (".bag", ".mcap")
    return (path / "metadata.yaml").is_file()


def run_bag(args: argparse.Namespace) -> int:
    """``fusion replay BAG --imu-topic T --odom-topic T``: the bag's IMU messages and its
    odometry twists through :class:`fusion.pipeline.core.FusionPipeline` (as a log directory's
    IMU samples and wheel frames), into ``-o`` (.csv/.mcap/.jsonl) and ``--plot``."""
    import dataclasses

    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.io.bags import read_bag
    from fusion.io.robot_toml import read_robot_toml
    from fusion.planar.robot import RobotConfig

    path: Path = args.input
    if not (args.imu_topic and args.odom_topic):
        raise CommandError(f"{path}: a bag needs --imu-topic (sensor_msgs/Imu) and "
                           "--odom-topic (nav_msgs/Odometry)")
    _output_format(args.output)
    if args.plot is not None:
        _check_plot_available(Path(args.plot))
    if args.robot is not None:
        robot = read_robot_toml(args.robot)
    else:
        # wheel_distance only enters the tiny radius-mismatch term of the speed; the period
        # only the motion-onset logic: neutral values
        robot = RobotConfig(DiffDriveParams(wheel_distance=0.5, speed_ratio=1e-4,
                                            encode_sampling_time=0.02))
    if args.imu_mount_rpy is not None:  # the command line wins over robot.toml
        robot = dataclasses.replace(robot, imu_mount_rpy=tuple(args.imu_mount_rpy))
    bag = read_bag(path, imu_topic=args.imu_topic, odom_topic=args.odom_topic)
    imu, odom = bag.imu, bag.odometry
    table, pipe, stats = _fuse_through_pipeline(
        robot, imu, None, None, tilt=not args.level, output=args.output,
        progress=args.progress, desc=path.name, odom=odom)
    # the bag's own wheel odometry pose, moved to start at the origin like the fused track
    x0, y0, th0 = odom.x[0], odom.y[0], odom.yaw[0]
    c, sn = math.cos(th0), math.sin(th0)
    dx, dy = odom.x - x0, odom.y - y0
    own = np.column_stack([c * dx + sn * dy, -sn * dx + c * dy,
                           np.angle(np.exp(1j * (odom.yaw - th0)))])
    if args.plot is not None:
        _plot(Path(args.plot), path.name, table, odom.t, own, None, None,
              wheel_label=f"bag odometry ({args.odom_topic})")
    print(f"{path}: {len(imu)} IMU messages ({imu.frame_id or 'no frame_id'}), {len(odom)} "
          f"odometry messages ({odom.frame_id} -> {odom.child_frame_id}) -> {args.output} "
          f"({table.shape[0]} rows, {stats.records} records)")
    if imu.out_of_order or odom.out_of_order:
        print(f"warning: messages out of order in the bag (sorted): IMU {imu.out_of_order}, "
              f"odometry {odom.out_of_order}")
    last = table[-1]
    print(f"final pose: x {last[1]:.3f} m, y {last[2]:.3f} m, yaw {math.degrees(last[3]):.2f}"
          f" deg; path {_distance(table[:, 0], table[:, 4]):.2f} m")
    ekf = pipe.ekf
    print(f"gyro bias {math.degrees(ekf.gyro_bias):+.4f} deg/s; ZUPTs {stats.zupts}, slip "
          f"(twist/gyro disagreement) {stats.slips}, invalid {ekf.stats['invalid']}")
    print(f"bag odometry ({args.odom_topic}) final pose from its start: x {own[-1, 0]:.3f}"
          f" m, y {own[-1, 1]:.3f} m, yaw {math.degrees(own[-1, 2]):.2f} deg")
    return 0


def _truth_at(truth_t, truth, t) -> NDArray[np.float64]:
    yaw = np.unwrap(truth[:, 2])
    return np.column_stack([np.interp(t, truth_t, truth[:, 0]),
                            np.interp(t, truth_t, truth[:, 1]),
                            np.interp(t, truth_t, yaw)])
