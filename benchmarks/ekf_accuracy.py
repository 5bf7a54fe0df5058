"""Fused-odometry accuracy: wheel-only, gyro-heading and fused EKF on degraded synthetic missions.

Run: python benchmarks/ekf_accuracy.py [--seeds N] [--duration S]

Missions: fusion.evaluation.synthetic.degraded_mission (robot.toml's wheel_distance 3 % off, 0.5 %
left/right radius mismatch, gyro z bias 0.5 deg/s with a 2e-5 rad/s/sqrt(s) random walk,
MPU6050 noise, three 1 s slip patches of 30 %, start at rest). Contenders:

- wheel only: seed 000's dead reckoning (fusion.planar.odometry.WheelOdometry, midpoint rule);
- gyro heading: heading integrated from the gyro minus its mean over the first 4 s at rest,
  translation from the wheels' distance (the classic gyrodometry, no filter);
- fused EKF: fusion.planar.ekf with its defaults except the bias walk set to the simulated one.

Printed per contender: final position error in % of the distance travelled and yaw RMSE, as
mean and worst over the seeds.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.evaluation.trajectory import final_position_error_percent, yaw_rmse
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.odometry import WheelOdometry

ROBOT = EXAMPLE_ROBOT


def gyro_heading(run) -> tuple[np.ndarray, np.ndarray]:
    """Gyrodometry: (t, poses) at the wheel frames."""
    rest = run.imu_t < 4.0
    rate = run.gyro[:, 2] - run.gyro[rest, 2].mean()
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) *
                                                np.diff(run.imu_t))))
    T = ROBOT.encode_sampling_time
    d = 0.5 * (run.ticks[:, 0] + run.ticks[:, 1]) * ROBOT.speed_ratio
    mid = np.interp(run.wheel_t - 0.5 * T, run.imu_t, heading)
    x = np.cumsum(d * np.cos(mid))
    y = np.cumsum(d * np.sin(mid))
    yaw = np.interp(run.wheel_t, run.imu_t, heading)
    return run.wheel_t, np.column_stack([x, y, yaw])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--duration", type=float, default=300.0, help="mission length, s")
    args = ap.parse_args()
    noise = EkfNoise(bias_psd=(2e-5) ** 2)
    results: dict[str, list[tuple[float, float]]] = {"wheel only": [], "gyro heading": [],
                                                     "fused EKF": []}
    for seed in range(args.seeds):
        run = degraded_mission(seed=seed, duration=args.duration)
        wheel = WheelOdometry(ROBOT).update_batch(run.ticks[:, 0], run.ticks[:, 1])
        tw = run.truth_at(run.wheel_t)
        results["wheel only"].append((
            final_position_error_percent(wheel[:, :2], tw, run.distance),
            math.degrees(yaw_rmse(wheel[:, 2], tw[:, 2]))))
        _, gh = gyro_heading(run)
        results["gyro heading"].append((
            final_position_error_percent(gh[:, :2], tw, run.distance),
            math.degrees(yaw_rmse(gh[:, 2], tw[:, 2]))))
        track, _ = fuse(ROBOT, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, noise)
        g = track.kind == 0
        tf = run.truth_at(track.t[g])
        results["fused EKF"].append((
            final_position_error_percent(track.states[g, :2], tf, run.distance),
            math.degrees(yaw_rmse(track.states[g, 2], tf[:, 2]))))
    print(f"{args.seeds} degraded missions of {args.duration:.0f} s (3 % separation error, "
          "0.5 % radius mismatch, 0.5 deg/s gyro bias + walk, slip patches)")
    print(f"{'odometry':14s} {'final pos. error % of distance':>32s} {'yaw RMSE deg':>22s}")
    print(f"{'':14s} {'mean':>15s} {'worst':>16s} {'mean':>10s} {'worst':>11s}")
    for name, vals in results.items():
        v = np.array(vals)
        print(f"{name:14s} {v[:, 0].mean():15.3f} {v[:, 0].max():16.3f} "
              f"{v[:, 1].mean():10.3f} {v[:, 1].max():11.3f}")


if __name__ == "__main__":
    main()
