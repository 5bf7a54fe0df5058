"""``fusion calibrate``: odometry calibration from log directories.

- ``fusion calibrate odometry LOGDIR``: wheel separation and left/right radius ratio with the
  gyro as reference (and ``speed_ratio`` with ``--distance`` or ``--use-truth``); prints the
  corrected ``[chassis]`` parameters (seed 000's names).
- ``fusion calibrate umbmark --cw DIR... --ccw DIR...``: Borenstein & Feng's UMBmark from
  square runs whose log directories carry ``truth.csv``.
- ``fusion calibrate gyro-scale LOGDIR... --turns N...``: the gyro's scale error from turns in
  place back to a mark (:mod:`fusion.calibration.gyro_scale`); prints robot.toml's ``[ekf]``
  ``gyro_scale`` and ``gyro_scale_std``. Do it before ``odometry``, which uses the gyro as its
  reference (it applies the calibrated scale).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from fusion.cli import CommandError
from fusion.cli.replay import imu_lag_arg

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="odometry calibration (wheel separation, radius ratio, UMBmark)",
        description="Calibrate the wheel odometry from recorded log directories "
                    "(see datasets/LOGDIR.md).",
    )
    sub = p.add_subparsers(dest="what", metavar="WHAT")
    o = sub.add_parser(
        "odometry",
        help="wheel_distance and radius ratio from a run, with the gyro as reference",
        description=(
            "Fit the wheels' turning against the gyro over windows of consecutive frames: "
            "gives wheel_distance and the right/left wheel radius ratio. The run needs a few "
            "seconds at rest (gyro bias), turns in both directions and straight driving. A "
            "gyro cannot observe the common distance scale: speed_ratio is kept unless "
            "--distance or --use-truth is given."
        ),
    )
    o.add_argument("input", type=Path, help="log directory with imu.csv and wheels.csv")
    o.add_argument("--distance", type=float,
                   help="path length driven in the whole run, m (measured), to correct "
                        "speed_ratio")
    o.add_argument("--use-truth", action="store_true",
                   help="correct speed_ratio from truth.csv (distance travelled)")
    o.add_argument("--window", type=int, default=25,
                   help="wheel frames per fitting window (default 25, one second at 40 ms)")
    o.add_argument("--level", action="store_true",
                   help="use the gyro z axis (default: tilt-compensated with Mahony)")
    o.add_argument("--imu-lag", type=imu_lag_arg, default=None, metavar="S|auto",
                   help="s by which the IMU's stamps are later than the wheel frames' (taken "
                        "off them; 0 leaves them). Default auto: as fusion replay, estimated "
                        "from the turns and moved only when clearly off, with a note")
    o.add_argument("--max-change", type=float, default=50.0, metavar="PERCENT",
                   help="refuse a wheel_distance further than this from robot.toml's "
                        "(default 50: the gyro's units or constant slip are likelier than so "
                        "wrong a robot.toml; raise it for a placeholder robot.toml)")
    o.add_argument("--write", type=Path, metavar="TOML",
                   help="also write a robot.toml with the corrected [chassis] and the radius "
                        "ratio as [ekf] wheel_rate_per_speed and calib_c_std (frames and the "
                        "rest of [ekf] copied from the log's robot.toml); refuses to overwrite "
                        "the log's own")
    o.set_defaults(func=run_odometry)
    u = sub.add_parser(
        "umbmark",
        help="UMBmark (Borenstein & Feng 1996) from square runs with ground truth",
        description=(
            "Each DIR is a log directory of one square run (start and end at the same pose) "
            "with truth.csv; the return error is truth minus wheel-only odometry at the end."
        ),
    )
    u.add_argument("--cw", type=Path, nargs="+", required=True, help="clockwise runs")
    u.add_argument("--ccw", type=Path, nargs="+", required=True, help="counter-clockwise runs")
    u.add_argument("--side", type=float, default=4.0, help="side of the square, m (default 4)")
    u.set_defaults(func=run_umbmark)
    g = sub.add_parser(
        "gyro-scale",
        help="the gyro's scale error from turns in place back to a mark",
        description=(
            "Each LOGDIR (imu.csv) is one run: at least 3 s at rest on a mark, N full turns in "
            "place, back on the mark, at least 3 s at rest. Prints the gyro's scale error and "
            "its uncertainty (several runs are combined; do one clockwise and one "
            "counter-clockwise)."
        ),
    )
    g.add_argument("input", type=Path, nargs="+", help="log directories, one run each")
    g.add_argument("--turns", type=int, nargs="+", required=True,
                   help="full turns of each run, signed: CCW positive (one per LOGDIR)")
    g.add_argument("--mark-std", type=float, default=1.0,
                   help="how well the robot was put back on the mark, deg (default 1)")
    g.add_argument("--write", type=Path, metavar="TOML",
                   help="also write a robot.toml with [ekf] gyro_scale and gyro_scale_std "
                        "set (the rest copied from the first log's robot.toml); refuses to "
                        "overwrite a log's own")
    g.set_defaults(func=run_gyro_scale)
    p.set_defaults(func=lambda args: _missing_what(p))


def _missing_what(parser) -> int:
    parser.print_help()
    return 2


def run_odometry(args: argparse.Namespace) -> int:
    from fusion.calibration.gyro_limits import check_gyro_units, saturated_samples
    from fusion.calibration.odometry import calibrate_odometry
    from fusion.geometry.mount import base_to_imu, mount_matrix, vertical_rate
    from fusion.io.logdir import read_logdir
    from fusion.jobs.imu_lag import choose_imu_lag
    from fusion.jobs.streams import Streams

    if not args.input.is_dir():
        raise CommandError(f"{args.input}: not a log directory")
    _check_write_target(args.write, [args.input])  # before the fit, not after
    log = read_logdir(args.input)
    if log.imu_t is None or log.wheel_t is None:
        raise CommandError(f"{args.input}: odometry calibration needs both imu.csv and "
                           "wheels.csv")
    if args.use_truth and log.truth_t is None:
        raise CommandError(f"{args.input}: --use-truth but there is no truth.csv")
    if args.distance is not None and args.use_truth:
        raise CommandError("give --distance or --use-truth, not both")
    if not (math.isfinite(args.max_change) and args.max_change > 0):
        raise CommandError(f"--max-change must be > 0 %, got {args.max_change}")
    # glitch frames out, as fusion replay leaves them (a --distance sums every frame's ticks)
    wheel_t, ticks = _wheels_without_glitches(args.input, log)
    # a corrupt row is left out with the windows across it (calibrate_odometry), and said
    finite = _finite_imu_rows(args.input, log)
    imu_t, gyro, accel = log.imu_t[finite], log.gyro[finite], log.accel[finite]
    # the full scale shows in the IMU's own axes (a clipped axis repeats its limit)
    raw_gyro = base_to_imu(mount_matrix(log.robot.imu_mount_rpy), gyro)
    try:
        check_gyro_units(raw_gyro, f"{args.input / 'imu.csv'}: the gyro")
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    saturated = np.zeros(finite.size, dtype=bool)
    saturated[finite] = saturated_samples(raw_gyro)
    if args.level:
        vertical = gyro[:, 2]
    else:
        from fusion.attitude.mahony import Mahony

        q = Mahony(axes=6).update_batch(gyro, accel, timestamps=imu_t)
        vertical = vertical_rate(gyro, q)
    gyro_z = np.full(finite.size, np.nan)
    gyro_z[finite] = vertical / (1.0 + log.robot.ekf.gyro_scale)  # as a calibrated gyro
    # the IMU's stamps on the wheels' clock, as fusion replay puts them
    lag = choose_imu_lag(Streams(imu_t, gyro, accel, wheel_t, ticks),
                         log.robot.chassis, args.imu_lag)
    if lag.note:
        print(f"note: {lag.note}")
    if lag.lag:
        Streams(log.imu_t - lag.lag, wheel_t=wheel_t).check_overlap(
            str(args.input), f"after moving the IMU's stamps by {-lag.lag:+.3f} s (--imu-lag)")
    cal = calibrate_odometry(
        log.imu_t - lag.lag, gyro_z, wheel_t, ticks, log.robot.chassis,
        distance=args.distance,
        truth_t=log.truth_t if args.use_truth else None,
        truth=log.truth if args.use_truth else None,
        window=args.window,
        latency=log.robot.ekf.wheel_latency,
        saturated=saturated,
        gyro_scale_std=log.robot.ekf.gyro_scale_std,
        max_change=args.max_change / 100.0,
    )
    print(f"{args.input}: odometry calibration with the gyro as reference")
    print(cal.report())
    if log.robot.ekf.gyro_scale == 0.0:
        print(f"note: the gyro's scale is not calibrated ([ekf] gyro_scale in "
              f"{args.input / 'robot.toml'}): wheel_distance carries its error (MPU6050: up to "
              f"3 %; +- {100 * log.robot.ekf.gyro_scale_std:.2g} % is in the std above); run "
              "`fusion calibrate gyro-scale` first and copy its [ekf] lines into robot.toml")
    if args.write is not None:
        from dataclasses import replace

        from fusion.io.robot_toml import write_robot_toml

        target = args.write
        c, c_std = cal.ekf_radius_mismatch
        ekf = replace(log.robot.ekf, wheel_rate_per_speed=c)
        if math.isfinite(c_std) and c_std > 0:
            ekf = replace(ekf, calib_c_std=c_std)
        write_robot_toml(target, replace(log.robot, chassis=cal.params(), ekf=ekf))
        print(f"wrote {target}")
    return 0


def _check_write_target(target: Path | None, logs: list[Path]) -> None:
    """Refuse an unwritable ``--write`` target, or a log's own robot.toml, before any work."""
    if target is None:
        return
    from fusion.io.atomic import check_target

    check_target(target)
    for log in logs:
        if target.resolve() == (log / "robot.toml").resolve():
            raise CommandError(f"{target}: refusing to overwrite the log's own robot.toml "
                               "(it describes how the log was recorded)")


def run_gyro_scale(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from fusion.calibration.gyro_scale import calibrate_gyro_scale, combine_gyro_scales
    from fusion.io.logdir import read_logdir

    if len(args.turns) != len(args.input):
        raise CommandError(f"give one --turns per log directory: {len(args.input)} "
                           f"directories, {len(args.turns)} turn counts")
    if not (math.isfinite(args.mark_std) and args.mark_std > 0):
        raise CommandError(f"--mark-std must be > 0 deg, got {args.mark_std}")
    _check_write_target(args.write, args.input)
    seen = {}
    for d in args.input:
        if d.resolve() in seen:
            raise CommandError(f"{d}: given twice (as {seen[d.resolve()]} too): each run counts "
                               "once, or its uncertainty would be understated")
        seen[d.resolve()] = d
    runs = []
    robot = None
    for d, turns in zip(args.input, args.turns, strict=True):
        if not d.is_dir():
            raise CommandError(f"{d}: not a log directory")
        # the IMU's own axes: the vertical is found from the accelerometer (any mount), and a
        # clipped axis shows as such only unrotated
        log = read_logdir(d, imu_frame="imu")
        if log.imu_t is None:
            raise CommandError(f"{d}: gyro-scale calibration needs imu.csv")
        _refuse_non_finite(d, log)
        chassis = log.robot.chassis
        wheel_t, ticks = (None, None) if log.wheel_t is None else _wheels_without_glitches(
            d, log)
        try:
            # the wheels, where logged, prove the rests were rests
            cal = calibrate_gyro_scale(log.imu_t, log.gyro, log.accel, turns,
                                       mark_std=math.radians(args.mark_std),
                                       wheel_t=wheel_t, ticks=ticks,
                                       wheel_geometry=(chassis.speed_ratio,
                                                       chassis.wheel_distance))
        except ValueError as exc:
            raise CommandError(f"{d}: {exc}") from exc
        print(f"{d}:")
        print(cal.report())
        runs.append(cal)
        robot = robot or log.robot
    try:
        cal = combine_gyro_scales(runs)
    except ValueError as exc:
        raise CommandError(f"{', '.join(map(str, args.input))}: {exc}") from exc
    if len(runs) > 1:
        print(f"combined ({len(runs)} runs): g = {100 * cal.scale_error:+.3f} % +- "
              f"{100 * cal.scale_error_std:.3f} %")
        if cal.note:
            print(f"note: {cal.note}")
    print("[ekf]")
    for key, value in cal.ekf_fields().items():
        print(f"{key} = {value:.6g}")
    if args.write is not None:
        from fusion.io.robot_toml import write_robot_toml

        write_robot_toml(args.write, replace(robot, ekf=replace(robot.ekf, **cal.ekf_fields())))
        print(f"wrote {args.write}")
    return 0


def _wheels_without_glitches(d: Path, log) -> tuple[np.ndarray, np.ndarray]:
    """The log's wheel frames (stamps s, ticks) without glitch frames
    (:mod:`fusion.jobs.wheel_glitches`, as ``fusion replay`` leaves them out), with a note."""
    from fusion.jobs.streams import Streams
    from fusion.jobs.wheel_glitches import in_log, without_glitches

    wheels, note = without_glitches(Streams(wheel_t=log.wheel_t, ticks=log.ticks),
                                    log.robot.chassis, in_log(d, log.wheel_t))
    if note:
        print(f"note: {note}")
    return wheels.wheel_t, wheels.ticks


def _finite_imu_rows(d: Path, log) -> np.ndarray:
    """(N,) bool, the IMU rows whose values are all finite numbers; a note names the first
    other row by imu.csv's line."""
    finite = np.isfinite(log.gyro).all(axis=1) & np.isfinite(log.accel).all(axis=1)
    if not finite.all():
        print(f"note: {_first_non_finite(d, finite)}: left out, with the windows across them "
              "(as fusion replay skips them)")
    return finite


def _first_non_finite(d: Path, finite: np.ndarray) -> str:
    """imu.csv's line of the first row not in ``finite``, and how many there are."""
    from fusion.io.imu_csv import imu_csv_lines

    (line,) = imu_csv_lines(d / "imu.csv", [int(np.flatnonzero(~finite)[0])])
    return f"{d / 'imu.csv'}:{line}: not a finite number ({int((~finite).sum())} such rows)"


def _refuse_non_finite(d: Path, log) -> None:
    """A NaN or infinite IMU value, named by imu.csv's line: the angle across it is unknown,
    and the gyro-scale calibration's one angle spans the whole run (``fusion replay`` and the
    odometry calibration skip such samples, :func:`_finite_imu_rows`)."""
    finite = np.isfinite(log.gyro).all(axis=1) & np.isfinite(log.accel).all(axis=1)
    if not finite.all():
        raise CommandError(f"{_first_non_finite(d, finite)}: a calibration needs every "
                           "sample; record the run again or remove the rows")


def run_umbmark(args: argparse.Namespace) -> int:
    from fusion.calibration.odometry import ekf_radius_lines, radius_mismatch_rate, umbmark
    from fusion.io.logdir import read_logdir
    from fusion.planar.odometry import WheelOdometry

    def errors(dirs: list[Path], clockwise: bool) -> tuple[np.ndarray, float]:
        out = []
        L = None
        for d in dirs:
            log = read_logdir(d)
            if log.truth is None or log.wheel_t is None:
                raise CommandError(f"{d}: UMBmark needs wheels.csv and truth.csv")
            _check_square_run(d, log.truth, clockwise=clockwise, side=args.side)
            _, ticks = _wheels_without_glitches(d, log)
            pose = WheelOdometry(log.robot.chassis).update_batch(ticks[:, 0], ticks[:, 1])[-1]
            # express the truth in the start frame of the run
            x0, y0, th0 = log.truth[0]
            dx, dy = log.truth[-1, 0] - x0, log.truth[-1, 1] - y0
            c, s = math.cos(th0), math.sin(th0)
            out.append((c * dx + s * dy - pose[0], -s * dx + c * dy - pose[1]))
            if L is not None and L != log.robot.chassis.wheel_distance:
                raise CommandError(f"{d}: wheel_distance differs from the other runs")
            L = log.robot.chassis.wheel_distance
        return np.array(out), float(L)

    cw, L = errors(args.cw, clockwise=True)
    ccw, L2 = errors(args.ccw, clockwise=False)
    if L != L2:
        raise CommandError("the CW and CCW runs use different wheel_distance values")
    r = umbmark(cw, ccw, args.side, L)
    print(f"UMBmark: {len(cw)} CW and {len(ccw)} CCW runs of a {args.side:g} m square")
    print(f"  centres of gravity of the return errors: CW ({r.cw_centre[0]:+.4f}, "
          f"{r.cw_centre[1]:+.4f}) m, CCW ({r.ccw_centre[0]:+.4f}, {r.ccw_centre[1]:+.4f}) m; "
          f"E_max,syst {r.max_error:.4f} m")
    print(f"  type A (wheelbase) alpha {math.degrees(r.alpha):+.4f} deg, type B (diameters) "
          f"beta {math.degrees(r.beta):+.4f} deg")
    print(f"  E_d = D_R/D_L = {r.diameter_ratio:.5f}; E_b = {r.wheelbase_factor:.5f}")
    print("[chassis]")
    print(f"wheel_distance = {r.wheel_distance:.6g}  # m, was {L:.6g}")
    print(f"# per-wheel factors on speed_ratio: left {r.left_factor:.5f}, right "
          f"{r.right_factor:.5f}")
    if not r.diameter_ratio > 0:  # a square shorter than the wheel distance can give this
        print(f"note: E_d {r.diameter_ratio:.5f} is no radius ratio: no [ekf] "
              "wheel_rate_per_speed (check --side against the squares driven)")
    else:
        print("[ekf]")
        print("\n".join(ekf_radius_lines(radius_mismatch_rate(r.diameter_ratio,
                                                              r.wheel_distance))))
    print("note: UMBmark's correction is first-order: drive the squares again with the "
          "corrected values and repeat until the return errors stop shrinking "
          "(Borenstein & Feng iterate too)")
    return 0


#: What a square run's truth must show, where it has the samples to show it (at least
#: SQUARE_TRUTH_ROWS: a hand-measured start and end pose shows neither): the way it turned,
#: where it turned by more than half a turn, and a path of four sides within
#: SQUARE_PATH_SHARE (the robot drives its sides by its own odometry, so their length holds
#: even where its turns are off). An independent probe's exchanged lists (E_d inverted) and
#: wrong --side (wheel_distance 3-4 % off) were corrected with confidence.
SQUARE_TRUTH_ROWS = 20
SQUARE_PATH_SHARE = 0.15
#: m: the path is measured between truth points at least this far apart (a motion capture's
#: millimetre noise would add up to metres over thousands of samples)
PATH_STEP = 0.02


def _check_square_run(d: Path, truth: np.ndarray, *, clockwise: bool, side: float) -> None:
    """Refuse a run whose ground truth shows another square than the one it is given as."""
    if len(truth) < SQUARE_TRUTH_ROWS:
        return
    yaw = np.unwrap(truth[:, 2])
    turned = float(yaw[-1] - yaw[0])
    if abs(turned) > math.pi and (turned > 0) == clockwise:
        raise CommandError(
            f"{d}: truth.csv turns {math.degrees(turned):+.0f} deg, a "
            f"{'clockwise' if clockwise else 'counter-clockwise'} square turns "
            f"{'-' if clockwise else '+'}: the run belongs under "
            f"{'--ccw' if clockwise else '--cw'}")
    path = _path_length(truth[:, :2], PATH_STEP)
    if abs(path / (4.0 * side) - 1.0) > SQUARE_PATH_SHARE:
        raise CommandError(
            f"{d}: truth.csv's path is {path:.2f} m, a square of side {side:g} m (--side) is "
            f"{4.0 * side:g} m: give the side driven, or the run is no square")


def _path_length(xy: np.ndarray, step: float) -> float:
    """Length (m) of the polyline through the points of ``xy`` (m) each at least ``step`` m
    from the one kept before it."""
    total, last = 0.0, xy[0]
    for point in xy[1:]:
        d = math.hypot(point[0] - last[0], point[1] - last[1])
        if d >= step:
            total += d
            last = point
    return total
