"""``fusion synth``: write a synthetic run (with ground truth) as a log directory.

For trying ``fusion replay`` and ``fusion calibrate`` without a robot, and for regression data.
Units on the command line: m, s, rad (``--gyro-bias`` in deg/s, as datasheets give it).

Two simulators: ``--simulator kinematic`` (the default, :mod:`fusion.evaluation.synthetic`) and
``--simulator physics`` (:mod:`fusion.evaluation.physics_sim`: a 1 kHz rigid-body robot with
traction-limited tyres and sensor errors no estimator here has a state for; ``--errors all``
or ``plain``, ``--with``/``--without`` per error, ``--dead-encoder S``, ``--moving-start``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from fusion.cli import CommandError

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "synth",
        help="write a synthetic run (IMU, wheel ticks, truth) as a log directory",
        description=(
            "Simulate a two-wheel robot whose robot.toml is wrong the way real ones are "
            "(wheel separation and radius errors), with an MPU6050-like gyro (bias, random "
            "walk, noise) and slip patches, and write OUTPUT/robot.toml, imu.csv, wheels.csv "
            "and truth.csv (datasets/LOGDIR.md). Deterministic for a given --seed."
        ),
    )
    p.add_argument("output", type=Path, help="log directory to create")
    p.add_argument("--scenario", choices=("mission", "square", "figure8", "turns"),
                   default="mission",
                   help="random mission (default), UMBmark square, figure eight, or (physics "
                        "only) a gyro-scale calibration run: --turns turns in place back to "
                        "a mark, for `fusion calibrate gyro-scale`")
    p.add_argument("--turns", type=int, default=None,
                   help="full turns in place of --scenario turns, signed: CCW positive "
                        "(default 10)")
    p.add_argument("--direction", choices=("cw", "ccw"),
                   help="square direction (default ccw; square only)")
    p.add_argument("--side", type=float, help="square side, m (default 4; square only)")
    p.add_argument("--duration", type=float,
                   help="mission length, s (default 300; mission only)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed: the same seed gives the same files (default 0)")
    p.add_argument("--separation-error", type=float, default=0.03,
                   help="true wheel distance is robot.toml's times (1 + this) (default 0.03)")
    p.add_argument("--radius-mismatch", type=float, default=0.005,
                   help="right/left wheel radius ratio - 1, split evenly (default 0.005)")
    p.add_argument("--gyro-bias", type=float, default=0.5,
                   help="gyro z bias, deg/s (default 0.5)")
    p.add_argument("--slip-patches", type=int,
                   help="1 s windows where one wheel over-counts by 30 %% (default 3; mission "
                        "only)")
    p.add_argument("--no-truth", action="store_true", help="do not write truth.csv")
    p.add_argument("--simulator", choices=("kinematic", "physics"), default="kinematic",
                   help="kinematic sampler (default; the options above) or the 1 kHz physics "
                        "simulator (the options below; --scenario mission only)")
    phys = p.add_argument_group(
        "physics simulator",
        "error names: radius, radius-speed, separation, gyro-scale, gyro-cross-axis, "
        "g-sensitivity, temperature, vibration, mount-tilt, quantisation, frame-loss, stamps, "
        "clock, low-friction (see fusion.evaluation.physics_sim.sensor_model)")
    phys.add_argument("--errors", choices=("all", "plain"), default=None,
                      help="all: every error and three low-friction patches (default); plain: "
                           "white noise, a constant gyro bias and a fine encoder only")
    phys.add_argument("--with", dest="with_errors", action="append", default=[],
                      metavar="NAME", help="switch this error on (repeatable)")
    phys.add_argument("--without", dest="without_errors", action="append", default=[],
                      metavar="NAME", help="switch this error off (repeatable)")
    phys.add_argument("--dead-encoder", type=float, default=None, metavar="S",
                      help="S seconds of zero ticks on both wheels while the robot drives "
                           "(default 0: none)")
    phys.add_argument("--moving-start", action="store_true",
                      help="the robot is already driving at t = 0")
    phys.add_argument("--truth-rate", type=float, default=None,
                      help="rows per second of truth.csv (the physics runs at 1000; default 200)")
    p.set_defaults(func=run)


def _physics_error_names() -> list[str]:
    from fusion.evaluation.physics_sim import ERROR_GROUPS

    return [*ERROR_GROUPS, "low-friction"]


def run_physics(args: argparse.Namespace) -> int:
    """``fusion synth --simulator physics``."""
    from fusion.evaluation.physics_sim import (
        ERROR_GROUPS,
        indoor_mission,
        simulate_physics,
        with_errors,
    )
    from fusion.evaluation.physics_sim.calibration_run import gyro_calibration_run
    from fusion.io.logdir import write_logdir

    known = _physics_error_names()
    bad = [n for n in args.with_errors + args.without_errors if n not in known]
    if bad:
        raise CommandError(f"unknown error name(s) {bad}; known: {', '.join(known)}")
    if args.scenario not in ("mission", "turns"):
        raise CommandError("--simulator physics runs --scenario mission or turns, not "
                           f"{args.scenario}")
    if args.dead_encoder < 0 or not args.truth_rate > 0 or args.truth_rate > 1000:
        raise CommandError("--dead-encoder must be >= 0 s and --truth-rate in (0, 1000] Hz")
    names = set(known) if args.errors == "all" else set()
    names = (names | set(args.with_errors)) - set(args.without_errors)
    sensors = with_errors(sorted(names & set(ERROR_GROUPS)), seed=args.seed)
    note = ""
    try:
        if args.scenario == "turns":
            run_, alignment = gyro_calibration_run(sensors, args.seed, turns=args.turns)
            note = (f"; {args.turns:+d} turns in place, stopped {math.degrees(alignment):+.2f} "
                    "deg off the mark (aligned by eye)")
        else:
            mission = indoor_mission(args.seed, args.duration, moving_start=args.moving_start,
                                     low_friction="low-friction" in names)
            run_ = simulate_physics(mission, sensors, args.seed,
                                    dead_encoder_while_driving=args.dead_encoder)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    step = max(1, round(1000.0 / args.truth_rate))
    write_logdir(out_dir := args.output, run_.robot, run_.imu_t, run_.gyro, run_.accel,
                 run_.wheel_t, run_.ticks,
                 None if args.no_truth else run_.truth_t[::step],
                 None if args.no_truth else run_.truth[::step])
    dead = ", ".join(f"{a:.1f}-{a + b:.1f} s" for a, b in run_.dead_windows()) or "none"
    print(f"{out_dir}: physics, {run_.duration:.1f} s, {run_.distance:.2f} m, "
          f"{run_.imu_t.size} IMU samples, {run_.ticks.shape[0]} wheel frames; errors: "
          f"{', '.join(sorted(names)) or 'none (plain)'}; dead encoder: {dead}; true "
          f"wheel_distance {run_.trace.wheel_distance:.5g} m (robot.toml says "
          f"{run_.robot.chassis.wheel_distance:g}){note}")
    return 0


def run(args: argparse.Namespace) -> int:
    from fusion.evaluation.synthetic import (
        EXAMPLE_ROBOT,
        EncoderModel,
        ImuModel,
        degraded_mission,
        figure_eight,
        simulate,
        square,
    )
    from fusion.io.atomic import check_target
    from fusion.io.logdir import write_synthetic_run

    physics_only = {"--errors": args.errors, "--with": args.with_errors or None,
                    "--without": args.without_errors or None,
                    "--dead-encoder": args.dead_encoder,
                    "--moving-start": args.moving_start or None, "--truth-rate": args.truth_rate}
    if args.simulator != "physics":
        given = [name for name, value in physics_only.items() if value is not None]
        if given:
            raise CommandError(f"{', '.join(given)} applies to --simulator physics only")
    args.errors = args.errors or "all"
    args.dead_encoder = 0.0 if args.dead_encoder is None else args.dead_encoder
    args.truth_rate = 200.0 if args.truth_rate is None else args.truth_rate
    out: Path = args.output
    check_target(out, folder_ok=True)  # its parent folder exists and is writable
    if out.exists() and not out.is_dir():
        raise CommandError(f"{out}: is a file; give a new directory")
    if out.exists() and any(out.iterdir()):
        raise CommandError(f"{out}: exists and is not empty; choose a new directory")
    only = {"--direction": (args.direction, "square"), "--side": (args.side, "square"),
            "--duration": (args.duration, "mission"),
            "--slip-patches": (args.slip_patches, "mission"), "--turns": (args.turns, "turns")}
    for option, (value, scenario) in only.items():
        if value is not None and args.scenario != scenario:
            raise CommandError(f"{option} applies to --scenario {scenario} only (this is "
                               f"{args.scenario})")
    args.direction = args.direction or "ccw"
    args.side = 4.0 if args.side is None else args.side
    args.duration = 300.0 if args.duration is None else args.duration
    args.slip_patches = 3 if args.slip_patches is None else args.slip_patches
    if args.duration <= 10:
        raise CommandError(f"--duration must be > 10 s, got {args.duration}")
    args.turns = 10 if args.turns is None else args.turns
    if args.scenario == "turns" and args.simulator != "physics":
        raise CommandError("--scenario turns needs --simulator physics")
    if args.scenario == "turns" and (args.moving_start or args.dead_encoder):
        raise CommandError("--moving-start and --dead-encoder apply to missions, not to "
                           "--scenario turns")
    if args.simulator == "physics":
        return run_physics(args)
    if not -0.5 < args.separation_error < 0.5 or not -0.5 < args.radius_mismatch < 0.5:
        raise CommandError("--separation-error and --radius-mismatch must be within +-0.5")
    bias = math.radians(args.gyro_bias)
    if args.scenario == "mission":
        run_ = degraded_mission(seed=args.seed, duration=args.duration,
                                separation_error=args.separation_error,
                                radius_mismatch=args.radius_mismatch, gyro_bias=bias,
                                slip_patches=args.slip_patches)
    else:
        segs = (square(side=args.side, direction=args.direction) if args.scenario == "square"
                else figure_eight())
        imu = ImuModel(gyro_bias=(0.0, 0.0, bias), gyro_bias_walk=2e-5)
        enc = EncoderModel(separation_error=args.separation_error,
                           left_scale_error=-0.5 * args.radius_mismatch,
                           right_scale_error=0.5 * args.radius_mismatch)
        run_ = simulate(segs, EXAMPLE_ROBOT, imu, enc, seed=args.seed)
    write_synthetic_run(out, run_, truth=not args.no_truth)
    print(f"{out}: {args.scenario}, {run_.duration:.1f} s, {run_.distance:.2f} m, "
          f"{run_.imu_t.size} IMU samples, {run_.ticks.shape[0]} wheel frames; true "
          f"wheel_distance {run_.true_wheel_distance:.5g} m (robot.toml says "
          f"{run_.robot.wheel_distance:g}), right/left radius ratio "
          f"{run_.true_right_ratio / run_.true_left_ratio:.5f}")
    return 0
