"""Replay recorded logs through the fusion pipeline into outputs, with a summary.

Inputs: a log directory (``datasets/LOGDIR.md``: robot.toml, imu.csv, wheels.csv or
wheels.uart2, optional truth.csv; read by :func:`fusion.io.logdir.read_logdir`), a DATA-uart2
capture with a robot.toml, or a ROS bag (the IMU messages and a nav_msgs/Odometry twist).
Every input runs through :class:`fusion.pipeline.core.FusionPipeline`'s batch entry point, the
same object and code ``fusion run`` uses live.

Outputs by suffix (:data:`OUTPUT_FORMATS`): ``.csv`` is the fused CSV
(:mod:`fusion.io.fused_csv`) with the EKF state after every IMU sample (after every wheel
frame or twist without an IMU); ``.mcap`` and ``.jsonl`` get the pipeline's records (one per
wheel frame or twist) through :func:`fusion.sinks.registry.open_sink`. An existing file is only
ever replaced by a complete one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import trapezoid

from fusion.evaluation.gps import GpsComparison, compare_with_fixes, fixes_to_enu
from fusion.evaluation.trust import TrustWarning, units_caveat, units_first
from fusion.evaluation.truth_compare import compare_with_truth
from fusion.geometry.angles import wrap_angle
from fusion.io.errors import LogFormatError
from fusion.io.fused_csv import FUSED_CSV_COLUMNS, write_fused_csv
from fusion.io.imu_csv import imu_csv_lines
from fusion.io.logdir import read_logdir
from fusion.io.odometry_motion import OdometryMotion, odometry_motion
from fusion.io.pose_track import own_track
from fusion.io.robot_toml import read_robot_toml
from fusion.io.uart2 import read_uart2_capture
from fusion.jobs.bias_walk import fit_bias_walk
from fusion.jobs.dead_feed import dead_feed_notes
from fusion.jobs.engine import run_tasks
from fusion.jobs.imu_lag import choose_imu_lag, shifted
from fusion.jobs.moving_start import MovingStart, first_stop, last_estimate, wheel_prior
from fusion.jobs.odometry_signs import check_twist_signs
from fusion.jobs.status import pipeline_warnings, status_record, write_status
from fusion.jobs.streams import (
    Streams,
    coverage_warnings,
    gyro_axes_warnings,
    handedness_warnings,
    speed_scale_warnings,
    stillness_warnings,
    with_gyro_limit,
    with_mount_estimate,
)
from fusion.jobs.twist_rest import with_twist_rest_floor
from fusion.jobs.wheel_checks import wheel_count_warnings
from fusion.jobs.wheel_glitches import in_log, stamped, without_glitches
from fusion.pipeline.core import FusionPipeline, PipelineStats
from fusion.planar.model import NX
from fusion.planar.odometry import WheelOdometry
from fusion.planar.robot import RobotConfig
from fusion.sinks.registry import open_sink

__all__ = [
    "CAPTURE_SUFFIXES",
    "OUTPUT_FORMATS",
    "BagReplay",
    "LogJob",
    "ReplayResult",
    "Streams",
    "check_plot_output",
    "distance_travelled",
    "find_log_dirs",
    "fuse_streams",
    "fused_table",
    "is_bag",
    "output_format",
    "replay_bag",
    "replay_capture",
    "replay_logdir",
    "replay_logs",
    "run_log_job",
]

#: Output suffix -> format.
OUTPUT_FORMATS = {".csv": "csv", ".mcap": "mcap", ".jsonl": "jsonl"}

CAPTURE_SUFFIXES = (".uart2",)

#: ``callback(done, total)``: seconds of log time replayed so far and in all.
Progress = Callable[[float, float], None]


@dataclass
class ReplayResult:
    """What a replay did (picklable: a worker process returns it).

    Attributes:
        source, output: input and output paths.
        span: s of log time; n_imu, n_wheels: IMU samples and wheel frames read (a bag:
            odometry messages).
        rows: rows of the fused table (the state at every IMU sample, or wheel frame without
            an IMU); records: pipeline records (one per wheel frame or twist).
        final: last fused pose (x m, y m, yaw rad wrapped); distance: integral of |v|, m.
        gyro_bias: rad/s; k (1), c (rad/m): the EKF's wheel yaw-rate calibration states.
        stats: the pipeline's counters (:meth:`fusion.pipeline.core.PipelineStats.as_dict`),
            the EKF's ``invalid`` count and the ``ledger`` (every event fused or counted by
            reason: :meth:`fusion.pipeline.core.FusionPipeline.ledger`).
        wheel_distance: robot.toml's wheel separation, m.
        truth: with truth, ``distance`` m and the fused/wheel-only final position error (% of
            distance) and yaw RMSE (deg); else None.
        notes: warnings for the user about the input files.
        warnings: the trust checks that failed (:mod:`fusion.evaluation.trust`: the inputs
            disagree beyond what the model explains).
        gyro_scale: the EKF's final gyro scale error ``g`` (1; robot.toml's
            ``[ekf] gyro_scale`` unless an absolute yaw moved it).
        moving_start: where the robot drove off at once, the gyro bias its first stop
            taught, taken as the prior from the start (:mod:`fusion.jobs.moving_start`;
            with ``one_pass`` not taken, only said: ``fused_again`` False).
        imu_lag: s taken off the IMU's stamps before fusing (:mod:`fusion.jobs.imu_lag`;
            the output's ``t`` is then on the wheel frames' clock, not imu.csv's).
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
    warnings: list[TrustWarning] = field(default_factory=list)
    gyro_scale: float = 0.0
    moving_start: MovingStart | None = None
    imu_lag: float = 0.0


def output_format(path: Path) -> str:
    """The output format of ``path`` by suffix; checks that it can be written there.

    Raises:
        ValueError: unknown suffix, missing folder, or a folder at ``path``.
    """
    fmt = OUTPUT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"{path}: unknown output type {path.suffix or '(no suffix)'!r}; "
                         "give a .csv, .mcap or .jsonl file")
    if not path.parent.is_dir():
        raise ValueError(f"{path}: the folder {path.parent} does not exist")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; give a file path")
    return fmt


def is_bag(path: Path) -> bool:
    """A ROS 1 .bag (or the .bag.active rosbag record leaves when it is killed), an .mcap
    file or a ROS 2 bag folder (metadata.yaml)."""
    if path.is_file():
        return (path.suffix.lower() in (".bag", ".mcap")
                or path.name.lower().endswith(".bag.active"))
    return (path / "metadata.yaml").is_file()


def find_log_dirs(path: Path) -> list[Path]:
    """The subfolders of ``path`` that are log directories (have robot.toml), sorted."""
    return sorted(p for p in path.iterdir() if p.is_dir() and (p / "robot.toml").is_file())


def fuse_streams(robot: RobotConfig, streams: Streams, output: Path | None, *,
                 tilt: bool = True, progress: Progress | None = None,
                 one_pass: bool = False, checked: Sequence[TrustWarning] = (),
                 bias_walk: bool = True
                 ) -> tuple[NDArray[np.float64], FusionPipeline, PipelineStats,
                            list[TrustWarning], MovingStart | None, str]:
    """Run ``streams`` through a :class:`FusionPipeline` into ``output`` (.csv/.mcap/.jsonl;
    None: no file, the table only).

    Returns ``(table, pipeline, stats, warnings, moving_start, walk_note)``: ``table`` (N, 22)
    in the fused CSV's columns (:data:`fusion.io.fused_csv.FUSED_CSV_COLUMNS`), the state
    after every IMU sample (after every wheel frame or twist without an IMU); the trust
    warnings (:func:`fusion.jobs.status.pipeline_warnings`), also in a .jsonl output's last
    line, the status record (:func:`fusion.jobs.status.status_record`); where the robot drove
    off at once, the gyro bias its first stop taught (:mod:`fusion.jobs.moving_start`), which
    a second pass took as the prior from the start (not with ``one_pass``: as a live run;
    its ``fused_again`` is then False and its note says what the first pass cost), else
    None. ``bias_walk``: where the stops show the gyro bias walking faster than
    ``[ekf] bias_psd`` (:mod:`fusion.jobs.bias_walk`), the log is fused again with the walk
    they fit (not with ``one_pass``), and ``walk_note`` says so ("" otherwise).
    ``progress`` sees the first pass as the first half of the work, and not the walk's pass.
    An IMU whose accelerometer does not read gravity (:meth:`Streams.level_note`: not
    provided, gravity removed, other units) is fused level (``tilt`` False): an attitude from
    the gyro alone drifts, and projecting the rates through it cost more than the tilt it
    compensates (benchmarks/terrain's outdoor bag: 6.3 m of GPS RMSE against 1.6 m level;
    gravity removed: 13.1 m against 1.5 m). ``checked``: warnings found on the inputs before
    the fusion (a bag's twist against its pose), put first.
    """
    tilt = tilt and not streams.level_note()
    fused = _fuse_from_the_start(robot, streams, output, tilt, progress, one_pass, checked)
    table, pipe = fused[0], fused[1]
    walk = fit_bias_walk(table[:, 0], table[:, 6], pipe.state_rows[:, 1 + NX + 5],
                         table[:, 19] > 0, robot.ekf.bias_psd) if bias_walk else None
    if walk is None or not walk.rejected:
        return (*fused, "")
    if one_pass:
        return (*fused, walk.note(fused_again=False))
    walked = dataclasses.replace(robot, ekf=dataclasses.replace(robot.ekf, bias_psd=walk.psd))
    again = _fuse_from_the_start(walked, streams, output, tilt, None, one_pass, checked)
    return (*again, walk.note(fused_again=True))


def _fuse_from_the_start(robot: RobotConfig, streams: Streams, output: Path | None,
                         tilt: bool, progress: Progress | None, one_pass: bool,
                         checked: Sequence[TrustWarning]
                         ) -> tuple[NDArray[np.float64], FusionPipeline, PipelineStats,
                                    list[TrustWarning], MovingStart | None]:
    """One fusion of :func:`fuse_streams`, with a moving start's second pass."""
    first = _fuse_once(robot, streams, output, tilt, progress, 0.0 if one_pass else 0.5,
                       checked=checked)
    table, pipe = first[0], first[1]
    var = pipe.state_rows[:, 1 + NX + 5]  # diag(P) of the bias
    start = first_stop(table[:, 0], table[:, 5], table[:, 6], var, table[:, 19] > 0,
                       robot.ekf.bias_psd) or last_estimate(
        table[:, 0], table[:, 6], var, table[:, 19] > 0, robot.ekf.bias_psd)
    if start is None or not start.bias_std < robot.ekf.initial_bias_std:
        start = None
    else:
        n, rows = robot.ekf, pipe.state_rows
        # wheels whose scale is refitted when it jumps (opt-in) have no one calibration; a
        # run that never stopped learnt c and the bias together (c * v reads as a bias on
        # straights), and carrying the two apart would claim what it never separated
        wheels = None if (one_pass or n.wheel_scale_refit > 0 or start.never_stopped) else \
            wheel_prior(table[:, 0], table[:, 7], rows[:, 1 + NX + 6], table[:, 8],
                        rows[:, 1 + NX + 7], n.calib_k_std, n.calib_c_std, n.calib_k_psd,
                        n.calib_c_psd)
        start = dataclasses.replace(start, prior=robot.ekf.initial_bias,
                                    fused_again=not one_pass, wheels=wheels)
    if start is not None and not one_pass:
        noise = dataclasses.replace(robot.ekf, initial_bias=start.bias,
                                    initial_bias_std=start.bias_std)
        if start.wheels is not None:
            w = start.wheels
            noise = dataclasses.replace(noise, wheel_rate_scale=w.k, calib_k_std=w.k_std,
                                        wheel_rate_per_speed=w.c, calib_c_std=w.c_std)
        second = _fuse_once(dataclasses.replace(robot, ekf=noise), streams, output, tilt,
                            progress, 0.5, 0.5, checked)
        return (*second, start)
    if progress is not None and not one_pass:
        t0, t1 = streams.span()
        progress(t1 - t0, t1 - t0)
    return (*first, start)


def _fuse_once(robot: RobotConfig, streams: Streams, output: Path | None, tilt: bool,
               progress: Progress | None, share: float, offset: float = 0.0,
               checked: Sequence[TrustWarning] = ()
               ) -> tuple[NDArray[np.float64], FusionPipeline, PipelineStats,
                          list[TrustWarning]]:
    """One pass of :func:`fuse_streams`; ``progress`` sees it as ``share`` of the work (all
    of it for 0) after ``offset`` of it."""
    fmt = None if output is None else output_format(output)
    t0, t1 = streams.span()
    span = t1 - t0
    part = share or 1.0
    sources = [name for name, on in (("imu", streams.has_imu), ("wheels", streams.has_wheels),
                                     ("twist", streams.has_twist)) if on]
    sinks = [] if fmt in (None, "csv") else [open_sink(f"{fmt}:{output}")]
    pipe = FusionPipeline(
        robot, sinks, tilt=tilt, sources=sources, imu_rate_hz=streams.nominal_imu_rate(),
        state_rows=("imu",) if streams.has_imu else ("wheels", "twist"),
        on_progress=None if progress is None
        else (lambda t: progress(offset * span + part * (t - t0), span)))
    with pipe:
        pipe.push_arrays(streams.imu_t, streams.gyro, streams.accel, streams.wheel_t,
                         streams.ticks, twist_t=streams.twist_t, twist_v=streams.twist_v,
                         twist_w=streams.twist_w)
        warnings = units_first([
            *checked, *with_mount_estimate(pipeline_warnings(pipe), robot, streams),
            *gyro_axes_warnings(streams, robot), *handedness_warnings(streams, robot),
            *stillness_warnings(streams, robot, pipe.finish_stats().zupts),
            *speed_scale_warnings(streams, robot), *wheel_count_warnings(streams, robot)])
        write_status(pipe, status_record(pipe, warnings))
    table = fused_table(pipe.state_rows, robot.chassis.speed_ratio
                         / robot.chassis.encode_sampling_time)
    if fmt == "csv":
        write_fused_csv(output, table)
    if progress is not None and offset + part >= 1.0:
        progress(span, span)
    return table, pipe, pipe.finish_stats(), warnings


def fused_table(rows: NDArray[np.float64], m_per_tick_s: float) -> NDArray[np.float64]:
    """Fused CSV rows (:data:`fusion.io.fused_csv.FUSED_CSV_COLUMNS`) from the rows of
    :attr:`FusionPipeline.state_rows` (yaw wrapped; wheel ticks times ``m_per_tick_s``,
    m/tick/s, give rim speeds in m/s). The gyro scale state g is not a CSV column."""
    var = 1 + NX  # diag(P) columns
    cross = 1 + 2 * NX  # P[x,y], P[x,yaw], P[y,yaw], then left, right ticks, flags
    out = np.empty((rows.shape[0], len(FUSED_CSV_COLUMNS)))
    out[:, 0] = rows[:, 0]  # t
    out[:, 1:3] = rows[:, 1:3]  # x, y
    out[:, 3] = wrap_angle(rows[:, 3])
    out[:, 4:9] = rows[:, 4:9]  # v, w, b, k, c
    out[:, 9:12] = rows[:, var:var + 3]  # var x, y, yaw
    out[:, 12:15] = rows[:, cross:cross + 3]  # cov xy, x yaw, y yaw
    out[:, 15:17] = rows[:, var + 3:var + 5]  # var v, w
    out[:, 17:19] = rows[:, cross + 3:cross + 5] * m_per_tick_s
    flags = rows[:, cross + 5].astype(np.int64)
    for i, bit in enumerate((1, 2, 4)):  # zupt, slip, encoder fault
        out[:, 19 + i] = (flags & bit) != 0
    return out


def replay_logdir(path: str | Path, output: str | Path, *, tilt: bool = True,
                  plot: str | Path | None = None, robot: RobotConfig | None = None,
                  imu_mount_rpy: tuple[float, float, float] | None = None,
                  progress: Progress | None = None,
                  load_progress: Callable[[str, int, int], None] | None = None,
                  one_pass: bool = False, imu_lag: float | None = None) -> ReplayResult:
    """Replay a log directory into ``output``; optionally draw ``plot`` (PNG).

    ``progress(done, total)``: s of log time replayed; ``load_progress(file name, done,
    total)``: bytes of imu.csv and wheels.csv parsed (:func:`fusion.io.logdir.read_logdir`).

    ``robot`` replaces the directory's own robot.toml (geometry, IMU mount, EKF tuning);
    ``imu_mount_rpy`` (URDF roll, pitch, yaw, rad) replaces the IMU mount of either;
    ``one_pass``: fuse as a live run would, without taking a moving start's bias back from
    its first stop (:func:`fuse_streams`). ``imu_lag``: s to take off the IMU's stamps to
    put them on the odometry's clock; None: estimated from the turns, and moved only when
    clearly late or early (:mod:`fusion.jobs.imu_lag`, with a note).
    Raises on bad input, leaving no partial output.
    """
    path, output = Path(path), Path(output)
    log = read_logdir(path, imu_frame="imu", progress=load_progress)
    robot = robot or log.robot
    if imu_mount_rpy is not None:
        robot = dataclasses.replace(robot, imu_mount_rpy=tuple(float(a) for a in imu_mount_rpy))
    if log.wheel_t is None or log.wheel_t.size == 0:
        raise ValueError(f"{path}: wheels.csv is missing or empty; the fused odometry needs "
                         "the wheel encoder frames")
    imu_t, gyro, accel, note = _finite_imu_rows(path / "imu.csv", log.imu_t, log.gyro,
                                                log.accel)
    streams, glitch_note = without_glitches(
        Streams(imu_t, gyro, accel, log.wheel_t, log.ticks), robot.chassis,
        in_log(path, log.wheel_t))
    streams.check_gyro(f"{path / 'imu.csv'}", robot.chassis)
    try:
        lag = choose_imu_lag(streams, robot.chassis, imu_lag)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    streams = shifted(streams, lag.lag)
    robot, limit_note = with_gyro_limit(robot, streams)
    result = _finish(path, output, robot, streams, log.truth_t, log.truth,
                     tilt=tilt, plot=plot, progress=progress, capture_stats=log.capture_stats,
                     one_pass=one_pass)
    result.notes.extend(n for n in (*log.notes, note, glitch_note, lag.note, limit_note) if n)
    result.imu_lag = lag.lag
    return result




def _finite_imu_rows(csv: Path, t, gyro, accel):
    """``(t, gyro, accel, note)``: the IMU rows without a NaN or infinity, and a note naming
    the lines of the rows left out (None when none was)."""
    if t is None or not t.size:
        return t, gyro, accel, None
    ok = np.isfinite(np.hstack([gyro, accel])).all(axis=1)
    if ok.all():
        return t, gyro, accel, None
    bad = np.flatnonzero(~ok)
    lines = imu_csv_lines(csv, bad[:5].tolist())
    more = f" and {bad.size - 5} more" if bad.size > 5 else ""
    note = (f"{csv}: {bad.size} sample(s) with a NaN or infinite value skipped: line(s) "
            f"{', '.join(map(str, lines))}{more}")
    return t[ok], gyro[ok], accel[ok], note


def replay_capture(path: str | Path, output: str | Path, robot: RobotConfig | str | Path, *,
                   plot: str | Path | None = None,
                   progress: Progress | None = None) -> ReplayResult:
    """Replay a DATA-uart2 capture (wheel odometry only) with the chassis of ``robot`` (a
    :class:`RobotConfig` or a robot.toml path). A timed capture is stamped as the live link
    stamps; a raw one on the firmware period (:meth:`fusion.io.uart2.Uart2Capture.frame_times`).
    """
    path, output = Path(path), Path(output)
    if not isinstance(robot, RobotConfig):
        robot = read_robot_toml(robot)
    period = robot.chassis.encode_sampling_time
    cap = read_uart2_capture(path, period=period)
    if not len(cap):
        raise ValueError(f"{path}: no DATA-uart2 frame in the capture (parser counters: "
                         f"{cap.stats})")
    cap_t = np.asarray(cap.frame_times(period), dtype=np.float64)
    streams, glitch_note = without_glitches(
        Streams(wheel_t=cap_t,
                ticks=np.column_stack([cap.left, cap.right]).astype(np.int64)),
        robot.chassis, lambda idx: f"{path} {stamped(cap_t[idx])}")
    result = _finish(path, output, robot, streams, None, None, tilt=True, plot=plot,
                     one_pass=True, progress=progress, capture_stats=cap.stats)
    result.notes.extend([glitch_note] if glitch_note else [])
    return result


def _finish(path: Path, output: Path, robot: RobotConfig, streams: Streams, truth_t, truth, *,
            tilt: bool, plot, progress, capture_stats, one_pass: bool) -> ReplayResult:
    if plot is not None:
        check_plot_output(Path(plot))
    streams.check_overlap(str(path), "a log's stamps are all on the host clock that stamped "
                          "the samples as they arrived")
    table, pipe, stats, warnings, start, walk_note = fuse_streams(
        robot, streams, output, tilt=tilt, progress=progress, one_pass=one_pass)
    chassis = robot.chassis
    ekf = pipe.ekf
    wheel_t, ticks = streams.wheel_t, streams.ticks
    n_imu = int(streams.imu_t.size) if streams.has_imu else 0
    t0, t1 = streams.span()
    level = streams.level_note() if tilt else ""
    notes = [n for n in (level, walk_note) if n]
    if capture_stats is not None:
        bad = {k: v for k, v in capture_stats.items() if k not in ("frames", "bytes_in") and v}
        if bad:
            notes.append(f"capture parser counters: {bad}")
    if n_imu and streams.has_wheels:
        notes.extend(coverage_warnings(streams.imu_t, wheel_t, robot.ekf.max_extrapolation,
                                       "wheel frames", fused=table))
    if n_imu:  # without an IMU a fault is only a stop harder than stop_decel allows
        notes.extend(n + units_caveat(warnings)
                     for n in dead_feed_notes(wheel_t, ~ticks.any(axis=1), table,
                                              chassis.encode_sampling_time, "wheel frames"))
    t_out = table[:, 0]
    wheel = WheelOdometry(chassis).update_batch(ticks[:, 0], ticks[:, 1])
    truth_res = None
    if truth_t is not None and truth_t.size:
        truth_res, truth_note, drawn = _truth_errors(t_out, table[:, 1:4], wheel_t, wheel,
                                                     truth_t, truth, str(path / "truth.csv"))
        notes.extend([truth_note] if truth_note else [])
    else:
        drawn = None
    if plot is not None:
        from fusion.jobs.plots import plot_replay

        # the truth as compared (moved onto the fused track), or none where it was not
        plot_replay(Path(plot), path.name, t_out, table[:, 1:4], wheel_t, wheel,
                    None if drawn is None else truth_t, drawn)
    last = table[-1]
    return ReplayResult(
        source=str(path), output=str(output), span=t1 - t0, n_imu=n_imu,
        n_wheels=int(wheel_t.size), rows=int(table.shape[0]), records=stats.records,
        final=(float(last[1]), float(last[2]), float(last[3])),
        distance=_distance(t_out, table[:, 4]), gyro_bias=float(ekf.gyro_bias),
        k=float(ekf.x[6]), c=float(ekf.x[7]), gyro_scale=float(ekf.x[8]),
        stats={**stats.as_dict(), "invalid": ekf.stats["invalid"], "ledger": pipe.ledger()},
        wheel_distance=chassis.wheel_distance, truth=truth_res, notes=notes,
        warnings=warnings, moving_start=start)


def _truth_errors(t, poses, wheel_t, wheel, truth_t, truth, source: str
                  ) -> tuple[dict[str, float] | None, str, NDArray[np.float64] | None]:
    """``(figures, note, drawn)``: final position error (% of the true distance) and yaw
    RMSE (deg) of the fused and the wheel-only tracks at the truth's stamps inside their
    spans, the truth aligned at each track's start (:func:`fusion.evaluation.truth_compare.
    compare_with_truth`), and the truth as aligned with the fused track (for the plot); None,
    why, None where the truth cannot be this log's."""
    cmp = compare_with_truth({"fused": (t, poses), "wheel": (wheel_t, wheel)}, truth_t,
                             truth, source)
    if cmp.note:
        return None, cmp.note, None
    nan = {"pct": math.nan, "yaw_deg": math.nan}
    fused, wheels = cmp.errors.get("fused", nan), cmp.errors.get("wheel", nan)
    return ({"distance": cmp.distance, "fused_pct": fused["pct"],
             "fused_yaw_deg": fused["yaw_deg"], "wheel_pct": wheels["pct"],
             "wheel_yaw_deg": wheels["yaw_deg"]}, "", cmp.aligned.get("fused"))


def check_plot_output(path: Path | None = None) -> None:
    """Refuse a plot before any work: matplotlib missing, or ``path``'s folder missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ValueError("--plot needs matplotlib: pip install 'diffbot-fusion[demo]'") \
            from None
    if path is not None and not path.parent.is_dir():
        raise ValueError(f"{path}: the folder {path.parent} does not exist")


@dataclass
class BagReplay:
    """What :func:`replay_bag` did: the fused table (fused CSV columns), the pipeline, its
    counters, the bag's own odometry pose moved to start at the origin and spliced across a
    driver's pose reset (:mod:`fusion.io.pose_track`; (K, 3) x m, y m, yaw rad at
    ``odom_t``), the bag's IMU and odometry (:func:`fusion.io.bags.read_bag`), the
    trust warnings (:mod:`fusion.evaluation.trust`) and, given a GPS topic, its fixes and the
    fused track, the bag's odometry and the gyro-at-stops baseline against them
    (:mod:`fusion.evaluation.gps`; tracks ``"fused"``, ``"bag odometry"``, ``"gyro at
    stops"``), or in ``gps_note`` why they could not be compared; ``motion``: the twists
    fused (:func:`fusion.io.odometry_motion.odometry_motion`: the odometry's own, or its
    poses' differences where its twist is empty, and why in ``motion.note``);
    ``moving_start``: as :attr:`ReplayResult.moving_start`; ``notes``: what the reader said
    about the file (an unfinished MCAP recording, messages that shared a stamp);
    ``coverage``: what the output cannot cover (:func:`coverage_warnings`); ``imu_lag``: s
    taken off the IMU's stamps (the output's ``t`` then on the odometry's clock)."""

    table: NDArray[np.float64]
    pipeline: FusionPipeline
    stats: PipelineStats
    odom_t: NDArray[np.float64]
    own: NDArray[np.float64]
    imu: Any
    odom: Any
    warnings: list[TrustWarning] = field(default_factory=list)
    fixes: Any = None
    gps: GpsComparison | None = None
    gps_note: str = ""
    motion: OdometryMotion | None = None
    moving_start: MovingStart | None = None
    notes: list[str] = field(default_factory=list)
    coverage: list[str] = field(default_factory=list)
    imu_lag: float = 0.0


def replay_bag(path: str | Path, output: str | Path, *, imu_topic: str, odom_topic: str,
               fix_topic: str | None = None, stamps: str = "header",
               robot: RobotConfig | None = None,
               imu_mount_rpy: tuple[float, float, float] | None = None, tilt: bool = True,
               plot: str | Path | None = None,
               progress: Progress | None = None, one_pass: bool = False,
               imu_lag: float | None = None) -> BagReplay:
    """Replay a ROS bag's IMU messages and odometry twists (the ``ros`` extra).

    ``robot``: wheel_distance and [ekf] tuning (default: neutral values; the wheel distance
    only enters the small radius-mismatch term of the speed); ``imu_mount_rpy`` (rad)
    replaces the robot's IMU mount. ``stamps``: ``"header"`` (each message's header.stamp) or
    ``"bag"`` (when the bag recorded it; for drivers that leave header stamps at zero or on
    another clock; :func:`fusion.io.bags.read_bag`). ``fix_topic``: a sensor_msgs/NavSatFix
    topic to score the fused track, the bag's odometry and the gyro-at-stops baseline against
    (position RMSE after one SE(2) alignment each; refused before anything is written when
    fewer than 2 fixes fall inside the span the IMU and the odometry share) and to draw on the
    plot. ``one_pass``, ``imu_lag``: as in :func:`replay_logdir` (the IMU's stamps moved
    for everything after: the fusion, the gyro-at-stops baseline, the plot).
    """
    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.io.bags import read_bag

    path, output = Path(path), Path(output)
    output_format(output)
    if plot is not None:
        check_plot_output(Path(plot))
    given = ("--imu-mount-rpy" if imu_mount_rpy is not None
             else "the robot's imu_mount_rpy" if robot is not None else None)
    if robot is None:
        robot = RobotConfig(DiffDriveParams(wheel_distance=0.5, speed_ratio=1e-4,
                                            encode_sampling_time=0.02))
    if imu_mount_rpy is not None:
        robot = dataclasses.replace(robot, imu_mount_rpy=tuple(imu_mount_rpy))
    bag = read_bag(path, imu_topic=imu_topic, odom_topic=odom_topic, fix_topic=fix_topic,
                   stamps=stamps)
    imu, odom = bag.imu, bag.odometry
    robot, mount_note = _mount_from_tf(path, robot, given, imu.frame_id, odom.child_frame_id)
    where = f"{path}: topics {imu_topic} and {odom_topic}"
    motion = odometry_motion(odom)
    Streams(imu.t, imu.gyro, imu.accel, twist_t=motion.t).check_overlap(
        where, "a driver stamping with its device's clock: --stamps bag takes when the bag "
        "recorded each message" if stamps == "header" else
        "the bag recorded them at different times")
    # the signs before the lag: the lag's correlation is signed, on the repaired twists
    signs = check_twist_signs(odom, motion, imu, robot.imu_mount_rpy)
    motion = signs.motion
    streams = Streams(imu.t, imu.gyro, imu.accel, twist_t=motion.t, twist_v=motion.v,
                      twist_w=motion.w)
    lag = choose_imu_lag(streams, robot.chassis, imu_lag)
    if lag.lag:
        imu = dataclasses.replace(imu, t=imu.t - lag.lag)
        streams = shifted(streams, lag.lag)
        streams.check_overlap(where, f"after moving the IMU's stamps by {-lag.lag:+.3f} s "
                                     "(--imu-lag)")
    streams.check_gyro(f"{path}: topic {imu_topic}", robot.chassis)
    robot, limit_note = with_gyro_limit(robot, streams)
    robot, rest_note = with_twist_rest_floor(robot, streams)
    fixes, fix_note = bag.fixes, ""
    if fixes is not None:
        if stamps == "header":
            fixes, fix_note = _fixes_on_odometry_clock(fixes, odom)
        _check_fixes_overlap(path, fixes, imu.t, odom.t)
    table, pipe, stats, warnings, start, walk_note = fuse_streams(
        robot, streams, output, tilt=tilt, progress=progress, one_pass=one_pass,
        checked=signs.warnings)
    spliced = own_track(odom.t, odom.x, odom.y, odom.yaw, odom.v, odom.w)
    own = spliced.track
    gps, gps_note = None, ""
    if fixes is not None:
        fx = fixes
        try:
            gps = compare_with_fixes(fx.t, fixes_to_enu(fx.latitude, fx.longitude, fx.altitude),
                                     {"fused": (table[:, 0], table[:, 1:3]),
                                      "bag odometry": (odom.t, own[:, :2]),
                                      "gyro at stops": _gyro_at_stops_track(robot, imu,
                                                                            motion)})
        except ValueError as exc:  # the output is written: no GPS figure, and why
            gps_note = f"GPS topic {fix_topic}: not compared: {exc}"
    if plot is not None:
        from fusion.jobs.plots import plot_replay

        more = []
        if imu.orientation is not None:  # the bag's own attitude estimate, where it has one
            from fusion.geometry.quaternion import to_euler

            q = imu.orientation
            yaw = np.full(q.shape[0], np.nan)
            has = np.isfinite(q).all(axis=1)
            yaw[has] = to_euler(q[has])[:, 2]
            more.append((f"the bag's own IMU orientation ({imu_topic})", imu.t, yaw))
        points = []
        if gps is not None:
            points.append((f"GPS ({fix_topic}), aligned to the fused track",
                           gps.gps_in_track_frame["fused"]))
        plot_replay(Path(plot), path.name, table[:, 0], table[:, 1:4], odom.t, own, None,
                    None, ref_label=f"the bag's own odometry ({odom_topic})", more_yaw=more,
                    more_xy=points)
    notes = [n for n in (mount_note, bag.note, *bag.topic_notes, *signs.notes, lag.note,
                         limit_note, rest_note, walk_note,
                         fix_note, spliced.note, tilt and streams.level_note()) if n]
    if motion.t.size > 1:
        still = ((np.abs(motion.v) <= robot.ekf.twist_zero_v)
                 & (np.abs(motion.w) <= robot.ekf.twist_zero_w))
        notes.extend(n + units_caveat(warnings)
                     for n in dead_feed_notes(motion.t, still, table,
                                              float(np.median(np.diff(motion.t))),
                                              f"odometry twists ({odom_topic})"))
    coverage = coverage_warnings(imu.t, motion.t, robot.ekf.max_extrapolation, fused=table)
    return BagReplay(table, pipe, stats, odom.t, own, imu, odom, warnings, fixes, gps,
                     gps_note, motion, start, notes, coverage, lag.lag)


#: rad: a mount given for a bag further than this from its /tf_static one is said (a URDF's
#: rounding and a levelling tweak stay inside; a forgotten axis swap is 90 deg).
MOUNT_TF_TOLERANCE = math.radians(5.0)


def _mount_from_tf(path: Path, robot: RobotConfig, given: str | None, imu_frame: str,
                   base_frame: str) -> tuple[RobotConfig, str]:
    """``(robot, note)``: with no mount ``given`` (its origin's name, e.g. "--imu-mount-rpy"),
    the robot with the mount of the bag's ``/tf_static`` from ``base_frame`` to ``imu_frame``
    (:mod:`fusion.io.bag_tf`) and a note saying so; with one given, the robot as it is and a
    note where the bag's mount is more than :data:`MOUNT_TF_TOLERANCE` from it (the
    ``mount`` trust check then says whether the accelerometer sides with it); "" otherwise."""
    from fusion.io.bag_tf import mount_angle, read_static_mount

    found = read_static_mount(path, base_frame, imu_frame)
    if found is None:
        return robot, ""
    if given is None:
        return (dataclasses.replace(robot, imu_mount_rpy=found.rpy),
                f"IMU mount from the bag's {found.describe()} (--imu-mount-rpy overrides it)")
    apart = mount_angle(found.rpy, robot.imu_mount_rpy)
    if not apart > MOUNT_TF_TOLERANCE:
        return robot, ""
    r, p, y = robot.imu_mount_rpy
    return robot, (f"the bag's {found.describe()}, is {math.degrees(apart):.1f} deg from "
                   f"{given} (roll {r:.4f} pitch {p:.4f} yaw {y:.4f} rad), which was used")


#: s: GPS header stamps whose offset from their record times differs from the odometry's by
#: more than this are on another clock (:func:`_fixes_on_odometry_clock`); transport and
#: recording latencies differ by milliseconds.
GPS_CLOCK_LIMIT = 1.0


def _fixes_on_odometry_clock(fixes: Any, odom: Any) -> tuple[Any, str]:
    """``(fixes, note)``: the GPS fixes with their stamps moved onto the odometry's clock
    when their header-minus-record offset differs from the odometry's by more than
    :data:`GPS_CLOCK_LIMIT` (a receiver stamping GPS time, 18 leap seconds ahead of UTC: all
    three tracks of the outdoor bag scored 13 m instead of 1.5, nothing said), and a note
    saying so ("" when unchanged). Only the comparison with the GPS uses them."""
    if fixes.bag_time.size != fixes.t.size or odom.bag_time.size != odom.t.size:
        return fixes, ""
    offset = (float(np.median(fixes.t - fixes.bag_time))
              - float(np.median(odom.t - odom.bag_time)))
    if not abs(offset) > GPS_CLOCK_LIMIT:
        return fixes, ""
    leap = " (GPS time against UTC: leap seconds)" if abs(abs(offset) - 18.0) < 1.0 else ""
    note = (f"GPS topic {fixes.topic}: its header stamps are {offset:+.3f} s off the "
            f"odometry's clock, against when the bag recorded each{leap}; compared after "
            "taking that out")
    return dataclasses.replace(fixes, t=fixes.t - offset), note


def _check_fixes_overlap(path: Path, fixes: Any, imu_t: NDArray[np.float64],
                         odom_t: NDArray[np.float64]) -> None:
    """Refuse, before anything is written, GPS fixes that cannot be compared: fewer than 2
    inside the span the IMU and the odometry share (LogFormatError naming both spans)."""
    start, end = max(imu_t[0], odom_t[0]), min(imu_t[-1], odom_t[-1])
    n = int(np.count_nonzero((fixes.t >= start) & (fixes.t <= end)))
    if n < 2:
        raise LogFormatError(
            f"{path}: topic {fixes.topic}: {n} of its {len(fixes)} fixes (stamped "
            f"{fixes.t[0]:.3f}-{fixes.t[-1]:.3f} s) lie inside the span the IMU and the "
            f"odometry share, {start:.3f}-{end:.3f} s; need at least 2 to compare (are the "
            f"GPS stamps on another clock?)")


def _gyro_at_stops_track(robot: RobotConfig, imu, motion: OdometryMotion
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(t s, (K, 2) x, y m) of the naive baseline issue 11 scored a real bag with: the mounted
    gyro's vertical axis, its bias re-learnt at every stop, with the odometry's speed (the
    twists the fusion took, ``motion``; :func:`fusion.evaluation.baselines.gyro_at_stops_twist`)."""
    from fusion.evaluation.baselines import gyro_at_stops_twist
    from fusion.geometry.mount import imu_to_base, mount_matrix

    R = mount_matrix(robot.imu_mount_rpy)
    b = gyro_at_stops_twist(imu.t, imu_to_base(R, imu.gyro), imu_to_base(R, imu.accel),
                            motion.t, motion.v, motion.w, still_v=robot.ekf.twist_zero_v,
                            still_w=robot.ekf.twist_zero_w)
    return b.t, b.poses[:, :2]


@dataclass(frozen=True)
class LogJob:
    """One log of a folder replay: input and output paths, tilt compensation, optional PNG,
    one pass, the IMU's lag (None: estimated) (:func:`replay_logdir`)."""

    source: str
    output: str
    tilt: bool = True
    plot: str | None = None
    one_pass: bool = False
    imu_lag: float | None = None


def run_log_job(job: LogJob) -> tuple[str, Any]:
    """Replay one log; ``("ok", ReplayResult)`` or ``("error", message)`` (the message names
    the log; a worker process runs this)."""
    try:
        return "ok", replay_logdir(job.source, job.output, tilt=job.tilt, plot=job.plot,
                                   one_pass=job.one_pass, imu_lag=job.imu_lag)
    except Exception as exc:  # reported in the summary; the other logs go on
        msg = str(exc) or type(exc).__name__
        if job.source not in msg:
            msg = f"{job.source}: {msg}"
        return "error", f"{msg} ({type(exc).__name__})"


def replay_logs(jobs: list[LogJob], workers: int,
                on_done: Callable[[LogJob, tuple[str, Any]], None] | None = None
                ) -> dict[str, tuple[str, Any]]:
    """Replay many logs in ``workers`` processes (1: in this process); returns each job's
    :func:`run_log_job` result by source path. A worker that dies fails its log only."""
    results: dict[str, tuple[str, Any]] = {}
    for i, ok, value in run_tasks(run_log_job, jobs, jobs=workers):
        job = jobs[i]  # (a worker died, killed or out of memory, when not ok)
        results[job.source] = value if ok else ("error", f"{job.source}: worker failed: "
                                                         f"{value}")
        if on_done is not None:
            on_done(job, results[job.source])
    return results


def _distance(t: NDArray[np.float64], v: NDArray[np.float64]) -> float:
    """Distance travelled, m: the integral of the fused |v| (the polyline through 100 Hz
    position estimates would add their noise)."""
    v = np.abs(v)
    return float(trapezoid(v, t))


def distance_travelled(table: NDArray[np.float64]) -> float:
    """Distance travelled in a fused table, m (the integral of the fused |v|)."""
    return _distance(table[:, 0], table[:, 4])


def _truth_at(truth_t, truth, t) -> NDArray[np.float64]:
    yaw = np.unwrap(truth[:, 2])
    return np.column_stack([np.interp(t, truth_t, truth[:, 0]),
                            np.interp(t, truth_t, truth[:, 1]),
                            np.interp(t, truth_t, yaw)])
