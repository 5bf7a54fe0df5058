"""``fusion attitude``: run the Mahony filter over a BROAD trial or an IMU CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion.cli import CommandError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "attitude",
        help="Mahony attitude of a BROAD trial (.mat/.hdf5) or an IMU CSV",
        description=(
            "Run the Mahony filter over INPUT and write t,qw,qx,qy,qz,roll,pitch,yaw "
            "(quaternion body -> world ENU, angles in radians), one row per input sample. "
            "INPUT is a BROAD trial (.mat, .hdf5) or an IMU CSV whose header has "
            "t,gx,gy,gz,ax,ay,az[,mx,my,mz] (s, rad/s, m/s^2, uT; other columns, such as "
            "those fusion imu adds, are ignored). With ground truth (BROAD), the benchmark's "
            "errors are printed."
        ),
    )
    p.add_argument("input", type=Path, help="BROAD trial or IMU CSV")
    p.add_argument("-o", "--output", type=Path, required=True, help="attitude CSV to write")
    p.add_argument("--axes", type=int, choices=(6, 9), default=6,
                   help="6: gyro + accelerometer (default); 9: + magnetometer")
    p.add_argument("--kp", type=float, help="proportional gain (default: tuned for --axes)")
    p.add_argument("--ki", type=float, help="integral gain, 1/s (default: tuned for --axes)")
    p.add_argument("--initial-quaternion", type=float, nargs=4, metavar=("W", "X", "Y", "Z"),
                   help="known initial attitude body -> world ENU (replaces the automatic "
                        "initialisation from the first sample)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fusion.attitude.mahony import PRESETS, Mahony
    from fusion.evaluation.orientation import orientation_rmse
    from fusion.io.atomic import check_target
    from fusion.io.broad import BroadTrial, read_broad
    from fusion.io.imu_csv import read_imu_csv, write_attitude_csv

    path: Path = args.input
    if not path.exists():
        raise CommandError(f"{path}: no such file")
    check_target(args.output)  # before the work, naming the user's path
    if path.suffix.lower() in (".mat", ".hdf5", ".h5"):
        log = read_broad(path)
    elif path.suffix.lower() == ".csv":
        log = read_imu_csv(path)
    else:
        raise CommandError(f"{path}: unknown input type (want a BROAD .mat/.hdf5 or an IMU .csv)")
    if len(log) == 0:
        raise CommandError(f"{path}: no samples")
    if args.axes == 9 and log.mag is None:
        raise CommandError(f"{path}: --axes 9 needs magnetometer columns mx,my,mz")

    filt = Mahony(args.kp, args.ki, axes=args.axes, initial_quaternion=args.initial_quaternion)
    mag = log.mag if args.axes == 9 else None
    if isinstance(log, BroadTrial):
        q = filt.update_batch(log.gyro, log.accel, mag, dt=1.0 / log.rate)
    else:
        if len(log) < 2 and filt.params.sample_period is None:
            raise CommandError(f"{path}: one sample gives no sample period")
        q = filt.update_batch(log.gyro, log.accel, mag, timestamps=log.t)
    write_attitude_csv(args.output, log.t, q)

    kp, ki = filt.params.kp, filt.params.ki
    tuned = "" if args.kp is not None or args.ki is not None else " (defaults)"
    print(f"{path.name}: {len(log)} samples over {log.t[-1] - log.t[0]:.1f} s, "
          f"{args.axes}-axis Mahony Kp {kp:g} Ki {ki:g}{tuned} -> {args.output}")
    if PRESETS[args.axes].get("rest_detection") and filt.params.rest_detection:
        print(f"rest detection on: {filt.counters.rest_samples} samples refined the gyro bias")
    c = filt.counters
    skipped = {"gyro rows skipped": c.gyro_skipped, "accelerometer rows unusable":
               c.accel_skipped, "magnetometer rows unusable": c.mag_skipped}
    for (what, n), rows in zip(skipped.items(), _unusable_rows(log, mag)):
        if n:
            print(f"warning: {n} {what} (see fusion.attitude.mahony for the policy): "
                  f"{_name_rows(log, rows)}")
    bias = filt.gyro_bias
    print(f"gyro bias estimate (rad/s): {bias[0]:+.5f} {bias[1]:+.5f} {bias[2]:+.5f}")
    if isinstance(log, BroadTrial):
        e = orientation_rmse(q, log.quat_ref, log.movement)
        print(f"BROAD RMSE over {e.samples} movement samples: total {e.total_deg:.3f} deg, "
              f"heading {e.heading_deg:.3f} deg, inclination {e.inclination_deg:.3f} deg")
        if args.axes == 6:
            print("(a 6-axis filter cannot observe heading: compare inclination)")
    return 0


def _unusable_rows(log, mag) -> list:
    """Indexes of the rows the filter skips (non-finite gyro) or cannot correct with (a zero
    or non-finite accelerometer or magnetometer vector), as fusion.attitude.mahony counts
    them."""
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
