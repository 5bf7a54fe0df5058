"""``fusion imu``: stream MPU6050 samples and the Mahony attitude to the terminal or a CSV.

Examples::

    fusion imu --bus 1 --rate 100 --calibrate -o imu.csv     # a real chip on /dev/i2c-1
    fusion imu --sim --count 500                              # the simulated chip
    fusion imu --bus 1 --raw --count 3000 -o rest.csv         # raw counts, to calibrate from
    fusion imu-calibrate rest.csv --poses poses.csv -o imu_cal.json
    fusion imu --bus 1 --calibration imu_cal.json             # apply it

Columns (:data:`fusion.io.imu_csv.IMU_RECORD_COLUMNS`, the IMU CSV that ``fusion attitude``
and ``fusion replay`` read): ``t`` (s, host clock; simulated seconds with ``--sim``),
``gx gy gz`` (rad/s), ``ax ay az`` (m/s^2), ``temp`` (deg C; the FIFO carries it too),
``qw qx qy qz`` (body -> world ENU), ``roll pitch yaw`` (rad, ZYX). With ``--raw``: the raw
recording format of
``fusion.io.mpu6050_csv`` (``Fs`` and sensitivity lines, then ``ax,ay,az,gx,gy,gz`` int16
counts). Status lines go to standard error.

``fusion imu-calibrate REST.csv [--poses POSES.csv] -o FILE``: gyro bias from a recording at
rest (refused if the sensor moved) and, with ``--poses``, accelerometer offset/scale from a
recording holding the sensor still in several poses (each axis up and down, a few seconds
each); writes the calibration JSON that ``--calibration`` applies.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from fusion.cli import CommandError
from fusion.types.constants import STANDARD_GRAVITY

__all__ = ["register", "run", "run_calibrate"]

_SIM_STILL_S = 5.0  # the simulated robot stays still this long, then turns


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "imu",
        help="stream MPU6050 samples and the Mahony attitude",
        description="Stream MPU6050 samples and the Mahony attitude to the terminal or a CSV: "
                    "t (s), gx gy gz (rad/s), ax ay az (m/s^2), temp (deg C), qw qx qy qz "
                    "(body -> ENU), roll pitch yaw (rad): the IMU CSV that fusion attitude "
                    "and fusion replay read. Status lines go to stderr.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--bus", type=int, metavar="N", help="I2C bus number (/dev/i2c-N)")
    src.add_argument("--sim", action="store_true",
                     help="simulated chip: still for 5 s, then turning at 10 deg/s about z; "
                          "runs in simulated time unless --realtime")
    p.add_argument("--address", type=lambda s: int(s, 0), default=0x68,
                   help="I2C address (0x68 with AD0 low, 0x69 high; default 0x68)")
    p.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                   help="sample rate, Hz (default 100)")
    p.add_argument("--gyro-range", type=int, default=500, choices=(250, 500, 1000, 2000),
                   help="gyro full scale, deg/s (default 500)")
    p.add_argument("--accel-range", type=int, default=4, choices=(2, 4, 8, 16),
                   help="accelerometer full scale, g (default 4)")
    p.add_argument("--dlpf", type=int, default=3, choices=range(7), metavar="0-6",
                   help="DLPF_CFG (default 3: 44 Hz accel / 42 Hz gyro bandwidth)")
    p.add_argument("--calibrate", action="store_true",
                   help="measure the gyro bias first (keep the sensor still)")
    p.add_argument("--calibrate-seconds", type=float, default=3.0, metavar="S",
                   help="duration of the --calibrate rest measurement (default 3 s)")
    p.add_argument("--calibration", type=Path, metavar="FILE",
                   help="apply a calibration JSON file (fusion.calibration.imu.ImuCalibration)")
    p.add_argument("--save-calibration", type=Path, metavar="FILE",
                   help="write the calibration in force (after --calibrate) to FILE")
    p.add_argument("--no-fifo", action="store_true",
                   help="poll DATA_RDY and burst-read each sample instead of using the FIFO")
    p.add_argument("--raw", action="store_true",
                   help="write raw int16 counts in the recording format (no attitude)")
    p.add_argument("--count", type=int, metavar="N", help="stop after N samples")
    p.add_argument("--realtime", action="store_true", help="with --sim: pace to the wall clock")
    p.add_argument("-o", "--output", type=Path, metavar="CSV", help="write to CSV, not stdout")
    p.set_defaults(func=run)

    c = subparsers.add_parser(
        "imu-calibrate",
        help="IMU calibration file from raw MPU6050 recordings",
        description="Gyro bias from a raw recording at rest and accelerometer offset/scale "
                    "from a raw recording of still poses (format of fusion imu --raw and "
                    "datasets/mpu6050_raw); writes JSON in SI units.",
    )
    c.add_argument("rest", type=Path, help="raw CSV recorded with the sensor still")
    c.add_argument("--poses", type=Path, help="raw CSV of still poses (each axis up and down)")
    c.add_argument("-o", "--output", type=Path, required=True, help="calibration JSON to write")
    c.set_defaults(func=run_calibrate)


def run_calibrate(args: argparse.Namespace) -> int:
    from fusion.calibration.imu import calibrate_recordings
    from fusion.io.imu_calibration import save_imu_calibration
    from fusion.io.mpu6050_csv import read_mpu6050_csv

    rest = read_mpu6050_csv(args.rest)
    poses = read_mpu6050_csv(args.poses) if args.poses else None
    cal = calibrate_recordings(rest, poses)
    save_imu_calibration(cal, args.output)
    bias = ", ".join(f"{v:+.3f}" for v in np.degrees(cal.gyro_bias))
    print(f"gyro bias ({bias}) deg/s from {len(rest)} samples")
    if poses is not None:
        g = STANDARD_GRAVITY
        print(f"{cal.info['poses']} still poses; accel offset "
              f"({', '.join(f'{v:+.4f}' for v in cal.accel_offset / g)}) g, scale "
              f"({', '.join(f'{v:.4f}' for v in cal.accel_scale)}); worst pose norm error "
              f"{cal.info['pose_norm_error_max_g'] * 1000:.2f} mg after correction")
    print(f"written to {args.output}")
    return 0


def _sim_motion(t_start: float) -> Any:
    """Still until ``t_start + 5 s`` (clock time), then 10 deg/s about z; 1 g on z."""

    def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = np.zeros((len(t), 3))
        w[:, 2] = np.radians(10.0) * (t - t_start >= _SIM_STILL_S)
        return w, np.tile([0.0, 0.0, STANDARD_GRAVITY], (len(t), 1))

    return motion


def _open(args: argparse.Namespace) -> Any:
    from drivers.mpu6050 import MPU6050
    from fusion.io.imu_calibration import load_imu_calibration

    calibration = load_imu_calibration(args.calibration) if args.calibration else None
    kw = dict(gyro_range_dps=args.gyro_range, accel_range_g=args.accel_range, dlpf=args.dlpf,
              sample_rate_hz=args.rate, calibration=calibration)
    if args.sim:
        from drivers.sim.mpu6050 import SimClock, SimulatedMPU6050, SystemClock

        clock = SystemClock() if args.realtime else SimClock()
        # the simulated chip is wired like a breakout with AD0 low: it answers at 0x68 only
        sim = SimulatedMPU6050(_sim_motion(clock.monotonic()), address=0x68, clock=clock,
                               gyro_bias_dps=(0.8, -0.5, 0.3), gyro_noise_dps=0.05,
                               accel_noise_g=0.003, seed=1, model_dlpf=True)
        return MPU6050(sim, args.address, clock=clock, **kw)
    return MPU6050(args.bus, args.address, **kw)


def _calibrate(imu: Any, seconds: float, out: TextIO) -> None:
    from fusion.calibration.imu import ImuCalibration, gyro_bias_at_rest

    n = max(20, round(seconds * imu.sample_rate_hz))
    print(f"calibrating: keep the sensor still for {n / imu.sample_rate_hz:.1f} s", file=out)
    rows = [imu.read(calibrated=False, wait=True) for _ in range(n)]
    gyro = np.array([s.gyro for s in rows])
    accel = np.array([s.accel for s in rows])
    bias = gyro_bias_at_rest(gyro, accel, imu.sample_rate_hz)
    old = imu.calibration or ImuCalibration()
    imu.calibration = old.with_gyro_bias(bias)
    deg = ", ".join(f"{v:+.3f}" for v in np.degrees(bias))
    print(f"gyro bias ({deg}) deg/s", file=out)


def run(args: argparse.Namespace) -> int:
    from fusion.attitude.mahony import Mahony

    if args.count is not None and args.count < 1:
        raise CommandError(f"--count must be >= 1; got {args.count}")
    if args.realtime and not args.sim:
        raise CommandError("--realtime only applies to --sim")
    if args.raw and args.calibration:
        raise CommandError("--calibration does not apply to --raw (raw counts are written "
                         "uncalibrated; --save-calibration keeps a --calibrate result)")
    from fusion.io.atomic import AtomicFile, check_target
    from fusion.io.imu_calibration import save_imu_calibration

    for path in (args.output, args.save_calibration):
        if path:
            check_target(path)  # before the sensor is opened and calibrated
    status = sys.stderr
    imu = _open(args)
    try:
        if args.calibrate:
            _calibrate(imu, args.calibrate_seconds, status)
        if args.save_calibration:
            if imu.calibration is None:
                raise CommandError("--save-calibration needs --calibrate or --calibration")
            save_imu_calibration(imu.calibration, args.save_calibration)
            print(f"calibration written to {args.save_calibration}", file=status)
        mahony = Mahony(sample_period=1.0 / imu.sample_rate_hz)
        # Compile the filter now (numba, about a second the first time), not while the FIFO
        # fills: 85 frames last 0.85 s at 100 Hz.
        Mahony(sample_period=0.01).update(np.zeros(3), np.array([0.0, 0.0, 9.8]))
        out = AtomicFile(args.output, encoding="utf-8") if args.output else None
        try:
            _stream(imu, args, mahony, out.file if out else sys.stdout, status)
        finally:
            if out is not None:
                # a recording: what was read is kept, also when Ctrl-C or an error stopped it
                out.commit()
    finally:
        imu.close()
    return 0


def _stream(imu: Any, args: argparse.Namespace, mahony: Any, sink: TextIO,
            status: TextIO) -> None:
    if args.raw:
        from fusion.io.mpu6050_csv import format_header

        sink.write(format_header(imu.sample_rate_hz, imu.accel_lsb_per_g, imu.gyro_lsb_per_dps))
    else:
        from fusion.io.imu_csv import IMU_RECORD_COLUMNS

        print(",".join(IMU_RECORD_COLUMNS), file=sink)
    written = 0
    use_fifo = not args.no_fifo
    if use_fifo:
        imu.enable_fifo(temperature=not args.raw)  # the CSV's temp column
    poll = min(0.05, 40.0 / imu.sample_rate_hz)  # well inside the 85-frame FIFO
    while args.count is None or written < args.count:
        if use_fifo:
            imu.clock.sleep(poll)
            got = imu.read_fifo()
            if got.overflow or got.lost:
                print(f"FIFO: {got.lost} samples lost (overflow={got.overflow}); "
                      "read more often", file=status)
            batch = got.samples
            raw = [(r[:3], r[3:]) for r in got.raw]
        else:
            if args.raw:
                imu.wait_data_ready()
                r = imu.read_raw()
                raw = [(r.accel, r.gyro)]
                batch = [None]
            else:
                batch = [imu.read(wait=True)]
        for i, s in enumerate(batch):
            if args.raw:
                from fusion.io.mpu6050_csv import format_row

                sink.write(format_row(*raw[i]))
                written += 1
                if args.count is not None and written >= args.count:
                    break
                continue
            q = mahony.update(s.gyro, s.accel, timestamp=s.t)
            rpy = mahony.euler  # rad
            temp = "" if s.temperature is None else f"{s.temperature:.2f}"
            print(f"{s.t:.6f},{s.gyro[0]:.6f},{s.gyro[1]:.6f},{s.gyro[2]:.6f},"
                  f"{s.accel[0]:.5f},{s.accel[1]:.5f},{s.accel[2]:.5f},{temp},"
                  f"{q[0]:.6f},{q[1]:.6f},{q[2]:.6f},{q[3]:.6f},"
                  f"{rpy[0]:.6f},{rpy[1]:.6f},{rpy[2]:.6f}", file=sink)
            written += 1
            if args.count is not None and written >= args.count:
                break
        sink.flush()
