"""The accelerometer slip test on the physics simulator: does it find the slips, does it cry
wolf, and what does it do to the fused odometry?

Run: python benchmarks/accel_slip.py [--seeds 0-7] [--duration S]

Per seed, on the physics simulator (fusion.evaluation.physics_sim, whose tyre model says when
a contact patch slides: ``truth_slip``):

- ``low-friction``: plain sensors on the indoor mission with three 3 s patches of
  mu = 0.04-0.1 (the line of ``ekf_accuracy.py --breakdown``);
- ``all``: every sensor error, vibration while driving and the low-friction patches;
- ``plain``: plain sensors on a high-friction floor (no slip at all: every flag is false).

Printed: the EKF's final position error (% of distance) and yaw RMSE (deg) without and with
the accelerometer's flags (the scoring of ``ekf_accuracy.py``), the wheel frames whose
period held a true slide, how many of those were flagged, and the false alarms: flags on
frames with no true slide in their period or the window before (the test looks back over
its window, so a flag up to a window after a slide is expected).
"""

from __future__ import annotations

import argparse

import numpy as np
from ekf_accuracy import physics_slip_flags, score_physics_run

from fusion.evaluation.physics_sim import (
    indoor_mission,
    physics_scenario,
    simulate_physics,
    with_errors,
)
from fusion.planar.accel_slip import AccelSlipParams


def frame_truth(run) -> np.ndarray:
    """(M,) bool: a tyre slid during the wheel frame's true period."""
    T = run.robot.chassis.encode_sampling_time
    cs = np.concatenate([[0], np.cumsum(run.truth_slip)])
    return cs[np.searchsorted(run.truth_t, run.wheel_t_end)] > cs[
        np.searchsorted(run.truth_t, run.wheel_t_end - T)]


def flag_counts(run, flags: np.ndarray) -> tuple[int, int, int]:
    """``(slipping frames, of them flagged, false alarms)``."""
    truth = frame_truth(run)
    window = round(AccelSlipParams().window / run.robot.chassis.encode_sampling_time)
    near = np.convolve(truth, np.ones(window + 1), mode="full")[:truth.size] > 0
    return int(truth.sum()), int(np.sum(flags & truth)), int(np.sum(flags & ~near))


def scenario_run(name: str, seed: int, duration: float):
    if name == "low-friction":
        return simulate_physics(indoor_mission(seed, duration, low_friction=True),
                                with_errors([], seed=seed), seed)
    return physics_scenario(name, seed=seed, duration=duration)


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-7", help="seed range, e.g. 0-7 or 100-105")
    ap.add_argument("--duration", type=float, default=300.0, help="mission length, s")
    args = ap.parse_args()
    seeds = _seeds(args.seeds)
    print(f"{'scenario':13s} {'seed':>4s} {'before: pos % / yaw deg':>24s} "
          f"{'after: pos % / yaw deg':>24s} {'slip frames':>11s} {'flagged':>8s} "
          f"{'false':>6s} {'frames':>7s}")
    for name in ("low-friction", "all", "plain"):
        rows = []
        for seed in seeds:
            run = scenario_run(name, seed, args.duration)
            before, _ = score_physics_run(run, accel_slip=False)
            after, _ = score_physics_run(run, accel_slip=True)
            b, a = before["fused EKF"], after["fused EKF"]
            counts = flag_counts(run, physics_slip_flags(run))
            rows.append((*b, *a, *counts, run.wheel_t.size))
            print(f"{name:13s} {seed:4d} {b[0]:11.3f} / {b[1]:8.3f} {a[0]:11.3f} / {a[1]:8.3f} "
                  f"{counts[0]:11d} {counts[1]:8d} {counts[2]:6d} {run.wheel_t.size:7d}",
                  flush=True)
        r = np.array(rows)
        print(f"{name:13s} {'mean':>4s} {r[:, 0].mean():11.3f} / {r[:, 1].mean():8.3f} "
              f"{r[:, 2].mean():11.3f} / {r[:, 3].mean():8.3f} {int(r[:, 4].sum()):11d} "
              f"{int(r[:, 5].sum()):8d} {int(r[:, 6].sum()):6d} {int(r[:, 7].sum()):7d} (sums)")
        print(f"{name:13s} {'wrst':>4s} {r[:, 0].max():11.3f} / {r[:, 1].max():8.3f} "
              f"{r[:, 2].max():11.3f} / {r[:, 3].max():8.3f}", flush=True)


if __name__ == "__main__":
    main()
