"""``fusion attitude``: run an attitude estimator over a BROAD trial or an IMU CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion.cli import CommandError

FILTERS = ("keel", "mahony")
MAHONY_ONLY = ("kp", "ki")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "attitude",
        help="attitude of a BROAD trial (.mat/.hdf5) or an IMU CSV (Keel or Mahony)",
        description=(
            "Run an attitude estimator over INPUT and write t,qw,qx,qy,qz,roll,pitch,yaw "
            "(quaternion body -> world ENU, angles in radians), one row per input sample. "
            "INPUT is a BROAD trial (.mat, .hdf5) or an IMU CSV whose header has "
            "t,gx,gy,gz,ax,ay,az[,mx,my,mz] (s, rad/s, m/s^2, uT; other columns, such as "
            "those fusion imu adds, are ignored). With ground truth (BROAD), the benchmark's "
            "errors are printed. The default filter is Keel (fusion.attitude.keel); "
            "--filter mahony runs the Mahony port with --kp, --ki."
        ),
    )
    p.add_argument("input", type=Path, help="BROAD trial or IMU CSV")
    p.add_argument("-o", "--output", type=Path, required=True, help="attitude CSV to write")
    p.add_argument("--axes", type=int, choices=(6, 9), default=6,
                   help="6: gyro + accelerometer (default); 9: + magnetometer")
    p.add_argument("--filter", choices=FILTERS, default="keel",
                   help="keel (default) or mahony (the faithful Mahony port)")
    p.add_argument("--offline", action="store_true",
                   help="Keel only: non-causal forward-backward estimate (recorded data)")
    p.add_argument("--kp", type=float, help="Mahony only: proportional gain (default: tuned "
                                            "for --axes)")
    p.add_argument("--ki", type=float, help="Mahony only: integral gain, 1/s (default: tuned "
                                            "for --axes)")
    p.add_argument("--initial-quaternion", type=float, nargs=4, metavar=("W", "X", "Y", "Z"),
                   help="known initial attitude body -> world ENU (replaces the automatic "
                        "initialisation from the first sample; not with --offline)")
    p.set_defaults(func=run)


def _check_options(args: argparse.Namespace) -> None:
    if args.filter != "mahony":
        given = [f"--{name}" for name in MAHONY_ONLY if getattr(args, name) is not None]
        if given:
            raise CommandError(f"{', '.join(given)}: Mahony-only option(s); add --filter mahony "
                               f"to run the Mahony port, or drop them for {args.filter}")
    elif args.offline:
        raise CommandError("--offline is a Keel mode: drop --filter mahony")
    if args.offline and args.initial_quaternion is not None:
        raise CommandError("--initial-quaternion cannot be used with --offline (the offline "
                           "estimate takes its start from the whole recording)")


def _load(path: Path, output: Path):
    from fusion.io.atomic import check_target
    from fusion.io.broad import read_broad
    from fusion.io.imu_csv import read_imu_csv

    if not path.exists():
        raise CommandError(f"{path}: no such file")
    check_target(output)  # before the work, naming the user's path
    if path.suffix.lower() in (".mat", ".hdf5", ".h5"):
        return read_broad(path)
    if path.suffix.lower() == ".csv":
        return read_imu_csv(path)
    raise CommandError(f"{path}: unknown input type (want a BROAD .mat/.hdf5 or an IMU .csv)")


def run(args: argparse.Namespace) -> int:
    from fusion.io.broad import BroadTrial
    from fusion.io.imu_csv import write_attitude_csv

    _check_options(args)
    path: Path = args.input
    log = _load(path, args.output)
    if len(log) == 0:
        raise CommandError(f"{path}: no samples")
    if args.axes == 9 and log.mag is None:
        raise CommandError(f"{path}: --axes 9 needs magnetometer columns mx,my,mz")
    mag = log.mag if args.axes == 9 else None
    # BROAD has a fixed rate; a CSV's timestamps give per-sample periods.
    timing = ({"dt": 1.0 / log.rate} if isinstance(log, BroadTrial)
              else {"timestamps": log.t})
    if args.filter == "mahony":
        q, lines = _run_mahony(args, log, mag, timing, path)
    else:
        q, lines = _run_keel(args, log, mag, timing)
    write_attitude_csv(args.output, log.t, q)

    print(f"{path.name}: {len(log)} samples over {log.t[-1] - log.t[0]:.1f} s, "
          f"{args.axes}-axis {lines[0]} -> {args.output}")
    for line in lines[1:]:
        print(line)
    if isinstance(log, BroadTrial):
        from fusion.evaluation.orientation import orientation_rmse

        e = orientation_rmse(q, log.quat_ref, log.movement)
        print(f"BROAD RMSE over {e.samples} movement samples: total {e.total_deg:.3f} deg, "
              f"heading {e.heading_deg:.3f} deg, inclination {e.inclination_deg:.3f} deg")
        if args.axes == 6:
            print("(a 6-axis filter cannot observe heading: compare inclination)")
    return 0


def _run_mahony(args, log, mag, timing, path):
    from fusion.attitude.mahony import PRESETS, Mahony

    filt = Mahony(args.kp, args.ki, axes=args.axes, initial_quaternion=args.initial_quaternion)
    if "timestamps" in timing and len(log) < 2 and filt.params.sample_period is None:
        raise CommandError(f"{path}: one sample gives no sample period")
    q = filt.update_batch(log.gyro, log.accel, mag, **timing)
    kp, ki = filt.params.kp, filt.params.ki
    tuned = "" if args.kp is not None or args.ki is not None else " (defaults)"
    lines = [f"Mahony Kp {kp:g} Ki {ki:g}{tuned}"]
    if PRESETS[args.axes].get("rest_detection") and filt.params.rest_detection:
        lines.append(f"rest detection on: {filt.counters.rest_samples} samples refined the "
                     "gyro bias")
    c = filt.counters
    lines += _warnings(log, mag, (c.gyro_skipped, c.accel_skipped, c.mag_skipped),
                       "fusion.attitude.mahony")
    bias = filt.gyro_bias
    lines.append(f"gyro bias estimate (rad/s): {bias[0]:+.5f} {bias[1]:+.5f} {bias[2]:+.5f}")
    return q, lines


def _run_keel(args, log, mag, timing):
    from fusion.attitude.keel import Keel
    from fusion.attitude.keel_offline import keel_offline

    if args.offline:
        q, diag = keel_offline(log.gyro, log.accel, mag, axes=args.axes, diagnostics=True,
                               **timing)
        lines = ["Keel offline (forward-backward)"]
        counters = None
    else:
        filt = Keel(axes=args.axes, initial_quaternion=args.initial_quaternion)
        q, diag = filt.update_batch(log.gyro, log.accel, mag, diagnostics=True, **timing)
        lines = ["Keel"]
        counters = filt.counters
    lines.append(f"at rest {int(diag.rest.sum())} samples"
                 + (f", magnetic field disturbed {int(diag.mag_disturbed.sum())} samples"
                    if args.axes == 9 else ""))
    if counters is not None:
        c = counters
        lines += _warnings(log, mag, (c.gyro_skipped, c.accel_skipped, c.mag_skipped),
                           "fusion.attitude.keel")
        if c.gaps:
            lines.append(f"warning: {c.gaps} gaps in the timestamps longer than "
                         f"{filt.params.max_gap:g} s (see the gap policy in fusion.attitude.keel)")
    bias, sigma = diag.gyro_bias[-1], diag.gyro_bias_sigma[-1]
    lines.append(f"gyro bias estimate (rad/s): {bias[0]:+.5f} {bias[1]:+.5f} {bias[2]:+.5f} "
                 f"(sigma {sigma.max():.5f})")
    return q, lines


def _warnings(log, mag, counts, module: str) -> list[str]:
    """One warning per kind of unusable row the filter counted, naming the rows."""
    whats = ("gyro rows skipped", "accelerometer rows unusable", "magnetometer rows unusable")
    return [f"warning: {n} {what} (see {module} for the policy): {_name_rows(log, rows)}"
            for what, n, rows in zip(whats, counts, _unusable_rows(log, mag)) if n]


def _unusable_rows(log, mag) -> list:
    """Indexes of the rows the filter skips (non-finite gyro) or cannot correct with (a zero
    or non-finite accelerometer or magnetometer vector), as both filters count them."""
    import numpy as np

    def bad(v):
        return ~np.isfinite(v).all(axis=1) | (np.linalg.norm(v, axis=1) == 0)

    gyro = ~np.isfinite(log.gyro).all(axis=1)
    accel = bad(log.accel) & ~gyro
    mags = bad(mag) & ~gyro if mag is not None else np.zeros(len(gyro), bool)
    return [np.flatnonzero(m) for m in (gyro, accel, mags)]


def _name_rows(log, rows, most: int = 10) -> str:
    """``FILE lines 5, 9`` for an IMU CSV, ``samples 3, 7 (from 0)`` for other logs."""
    from fusion.io.imu_csv import imu_csv_line

    shown = [int(i) for i in rows[:most]]
    more = f" and {len(rows) - most} more" if len(rows) > most else ""
    if str(log.source).lower().endswith(".csv"):
        lines = ", ".join(str(imu_csv_line(log, i)) for i in shown)
        return f"{log.source} line{'s' if len(rows) > 1 else ''} {lines}{more}"
    return f"sample{'s' if len(rows) > 1 else ''} {', '.join(map(str, shown))}{more} (from 0)"
