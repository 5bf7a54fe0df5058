"""Choose the planar EKF's defaults by leave-one-seed-out cross-validation on the physics simulator.

Tuning runs: fusion.evaluation.physics_sim scenarios "plain", "all", "all+dead" and
"moving-start" (every error, already driving at the first sample), and the kinematic
simulator's degraded mission (fusion.evaluation.synthetic), 300 s, seeds 100-105: disjoint
from seeds 0-7 that benchmarks/ekf_accuracy.py and the tests report (those are never looked at
here). Each configuration of a small grid of EkfNoise fields runs on every tuning run; a
seed's score is the mean over the scenarios of

    yaw RMSE (deg) + final position error (% of distance) + (1 - fraction of rows whose pose
    NEES lies inside its 95 % bounds)

(lower is better; the five scenarios weigh the same). For each seed the configuration best on
the other seeds is chosen and scored on the held-out seed: the mean of those held-out scores is
the cross-validated (CV) figure. The configuration best on all tuning seeds is the one to ship
as the default; its mean over them is printed too, labelled in-sample.

Last runs (2026-11-24): (1) accel_psd x yaw_fix_rate x slip_inflation x wheel_w_corr_time, 24
configurations over four scenarios: CV objective 5.165; best in-sample 5.133 with accel_psd
0.002, slip_inflation 1e4, wheel_w_corr_time 0 and yaw_fix_rate 0.25 deg/s, tied with 0.5 deg/s
(the shipped value). (2) turn_w_std x wheel_w_corr_time (five scenarios): CV objective 5.875;
best in-sample 5.761 with turn_w_std 0.5 (every fold but one chose it; 0.2 the other),
wheel_w_corr_time 0; the shipped defaults (turn_w_std 0) score 6.136. NOT adopted: with
turn_w_std 0.5 a turn teaches the wheel calibration k nothing (tests/test_ekf_acceptance.py's k
convergence fails) and the wheels cannot carry a turn while the gyro is saturated
(tests/test_ekf.py); the objective above does not see either. The lead decides.
(3) 2026-11-25, slip_accel_psd x odometry_along_var x odometry_cross_var (16 configurations):
every fold chose no odometry noise (it makes "plain" and the kinematic runs more
underconfident than it helps "all"), raw gyro CV 5.854, calibrated gyro CV 1.879.
(4) This grid (slip_accel_psd x slip_inflation), in-sample objective per configuration:
raw gyro: 5.833 (0.02, 1e4), 5.835 (0.05, 1e5), 5.836 (0.01, 1e4), 5.839 (0.05, 1e4),
5.840 (0.005, 1e4), 5.843 (0.02, 1e5), ..., 5.854 (0.002, 1e4: the former defaults), 5.875
(0.002, 1e5); CV objective 5.860. Calibrated gyro (--calibrated-gyro): 1.867 (0.02, 1e4),
1.870 (0.05, 1e4), 1.881 (0.01, 1e4), 1.889 (0.05, 1e5), 1.904 (0.02, 1e5), ..., 1.938
(former defaults); CV objective 1.879. ADOPTED: slip_accel_psd 0.02 with slip_inflation 1e5,
NOT the best (0.02, 1e4): that one lets the down-weighted speed of a slipping frame pull the
distance (tests/test_ekf.py: one wheel slipping 30 % for 1 s on a 6 m straight ends 4.0 cm
off, its bound is 3 cm; with 1e5, 1.0 cm) and the twist and tick paths apart (3.6 cm on 12.8 m,
bound 0.2 %); (0.02, 1e5) keeps both and beats the former defaults in both modes. Held out
from all of this, seeds 0-7 of "all" with the calibrated gyro: pose NEES inside its bounds on
80.0 % of the rows on average (73.8 % before), 47.9 % in the worst run (39.5 %); final error
and yaw RMSE unchanged (0.192 % / 0.270 deg mean).

(5) 2026-11-25, accel_speed_psd (0: off) x accel_offset_time, the forward specific force fed
to every run: raw gyro, every fold chose off (CV 5.945; the best "on" configuration 5.990
in-sample: the objective is dominated by the raw gyro's yaw error, which the speed does not
touch); calibrated gyro, every fold chose accel_speed_psd 0.002 (five with
accel_offset_time 2 s, one with 20 s), CV 1.214 against 1.228 for off (in-sample 1.208 for
(0.002, 2 s)). NOT adopted as the default (the figures on seeds 0-7 are in
fusion.planar.ekf's docstring); (0.002, 2 s) is the configuration to switch on.

(6) 2026-11-25, stamp_std (s; EkfNoise) x accel_speed_psd (0 or 0.002 with accel_offset_time
2 s). First form, NOT kept: the rates of change taken from the measured twists' difference, on
both shares: every fold chose 0.02-0.04 s, but by making the estimate worse (seeds 100-105,
calibrated, stamp_std 0.04: the position error of "plain" 0.034 -> 0.120 %, of the kinematic
runs 0.12 -> 0.34 %; the NEES of the underconfident runs rose because their errors did), and
a wheel starting to slip hid behind its own difference (tests/test_ekf_real.py's worst case).
Kept form: the filter's own rates (the gyro-driven w, the accelerometer-driven v; none for a
random-walk v). Grid stamp_std 0, 0.02, 0.04, 0.08, 0.12, 0.16 s: calibrated gyro, every fold
chose 0.08 s with the accelerometer on (one 0.12), CV 0.950, in-sample 0.941; raw gyro,
folds 0.08 s (accelerometer on) or 0.16 s (off), CV 5.841, in-sample 5.774 for (0.08, on).
In-sample with the accelerometer off: calibrated 1.228 (0), 1.163 (0.02), 1.073 (0.04),
0.989 (0.08), 0.974 (0.12); raw 5.945, 5.900, 5.841, 5.804, 5.798. Accuracy does not pay
for it here (calibrated, off, 0 -> 0.08 s: "moving-start" yaw RMSE 1.61 -> 0.87 deg and
final error 0.72 -> 0.47 %, "all" 0.32 -> 0.29 %, "plain" yaw 0.146 -> 0.161 deg). ADOPTED:
0.02 s, NOT the CV's 0.08 s: the objective has no skid-steer run and no saturated gyro, and
larger values break both (tests/test_ekf_real.py, the bundled Jackal bag: yaw RMSE 0.97 deg
up to 0.04 s (1.07 after main's first-gyro change), 18.5 deg with 0.05 s, 21.5 deg with
0.08 s: a noisy gyro's w makes the stamp noise large enough to hide the skid-steer's
disagreeing turns from the slip gate, so its yaw rates are never distrusted; tests/test_ekf.py's
6 rad/s spin on a saturated gyro ends 4.6 deg off with 0.04 s, bound 3).
0.02 s is the largest grid value that keeps both; it beats 0 in both modes.
(7) 2026-11-25, speed_ramp_time (s: v's random walk at least (its last rate of change)^2 x
this while driving), with stamp_std 0.02 s: in-sample calibrated 1.163 (0), 1.149 (0.04),
1.147 (0.1), 1.155 (0.3), 1.189 (1.0), five folds of six chose 0.1 s, CV 1.155; raw 5.900,
5.890, 5.887, 5.895, 5.917, five folds 0.1 s, CV 5.906 (no gain on the raw gyro, whose
heading error dominates). The objective barely moves because "all" gets more honest (mean
NEES inside 89.4 -> 92.0 %, worst run 84.2 -> 90.6 %, calibrated) while the underconfident
"plain" and kinematic runs get more so (46.8 -> 44.7 %, 27.0 -> 18.6 %); accuracy is
unchanged. ADOPTED: 0.1 s. (Also looked at, grid (7) before this one, NOT adopted: bias_psd
1e-8 (the default), 2.5e-9, 6.25e-10, 1e-10 with the accelerometer off and on: calibrated,
every fold chose 6.25e-10 with the accelerometer on (CV 1.074; off, 2.5e-9 was best, 1.139);
raw, every fold chose 1e-10 (CV 5.809 against 5.900). The modes disagree, the gains are
small, and on seeds 0-7 with the accelerometer off 6.25e-10 made the calibrated "all" runs
overconfident (NEES inside 80.8 -> 72.4 % on average) and seed 0's yaw RMSE 0.24 -> 0.33 deg.
NOTE: those seeds 0-7 figures were looked at before deciding, so for bias_psd the report
seeds are no longer held out.)
(8) 2026-11-25, odometry_along_var 0, 2.5e-5, 1e-4 x odometry_cross_var 0, 2.5e-5 (m^2/m)
again, with stamp_std and speed_ramp_time at their new defaults (the along-track error of
the physics simulator's seed 1 accumulates with the path: 28 cm at 240 s, 5 m from the
start, where the distance scale's prior allows 8 cm): every fold in both modes still chose
none (calibrated 1.147 against 1.159 for the least; raw 5.887 against 5.894). Unchanged.

(9) 2026-11-27, yaw_fix_rate (the pace at which rate measurements may correct the heading,
and at which a heading correction owed after a moving start's first stop is paid), grids
0.25-10 and 0.5-45 deg/s. Raw gyro: in-sample 5.834 (0.25), 5.839 (5), 5.840 (10, 20), 5.841
(2, 45), 5.852 (1), 5.866 (0.5, the former default); folds chose 0.25 (4 of 6) or 5 on the
first grid, 5 (5 of 6) or 10 on the second, CV 5.849 / 5.841. Calibrated gyro: 1.006 (45),
1.007 (20), 1.008 (10), 1.009 (5), 1.015 (2), 1.031 (1), 1.036 (0.25), 1.054 (0.5); folds chose
10 (5 of 6) or 2 on the first grid, 45 on the second, CV 1.017 / 1.006. Outside this
objective, issue 11's measure for its real outdoor bag (position RMSE against GPS after one
SE(2) alignment) on benchmarks/terrain's bag scenarios (outdoor-bag, hills-bag, seeds 1-6):
3.93 m (0.5), 2.99 (2), 2.77 (5), 2.76 (10), 2.75 (30); the gyro-at-stops baseline 2.50:
paying a heading owed after the first stop slowly drives the pose along a heading it knows to
be wrong, which bends the track. ADOPTED: 5 deg/s, the raw folds' choice, within 0.003 of the
best everywhere; not more, because the same budget bounds how fast any rate measurement may
turn a standing robot's pose (issue 11's 7 deg within half a second while standing: at most
1 + 2.5 deg now).

(10) 2026-11-28, calib_c_std (the prior of the wheels' radius mismatch c, rad/m; its share
of what a straight drive without a stop shows, against the bias's), grid 0.005, 0.01, 0.02,
0.05 (the default, set by hand in the first EKF), 0.1. Raw gyro: in-sample 5.823 (0.02), 5.839
(0.05), 5.857 (0.005), 5.864 (0.01), 5.877 (0.1), folds chose 0.02 (4 of 6), 0.005 or 0.05, CV
5.920. Calibrated: 1.009 (0.05), 1.018 (0.02), 1.093 (0.1), 1.125 (0.01), 1.172 (0.005), folds
0.05 (5 of 6) or 0.01, CV 1.204. Outside this objective: benchmarks/terrain's skid-steer bags
(GPS RMSE, m, mean of outdoor-bag and hills-bag), seeds 1-6 1.81 (0.01), 1.74 (0.02), 2.02
(0.05); seeds 7-12 2.62, 2.40, 2.95; the physics simulator's seeds 0-7 ("all", raw and
calibrated) unchanged within 0.3 % of NEES; but the black-box simulator's moving starts
(wheel ticks, seeds 101-106) 3.38 -> 4.46 deg of yaw RMSE with 0.02, worse on all six ("all"
unchanged). NOT adopted: the prior's best value is the robot's own mismatch (0.2 % per wheel
on the terrain bags, more on the black-box robots), which no default knows; 0.05 stays.

Run: python benchmarks/tune_ekf.py [--calibrated-gyro]   (a minute or two on one core)
"""

from __future__ import annotations

import argparse
import itertools
import math
import time

import numpy as np

from fusion.evaluation.crossval import leave_one_out
from fusion.evaluation.physics_sim import (
    all_errors,
    indoor_mission,
    physics_scenario,
    simulate_physics,
)
from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.evaluation.trajectory import (
    final_position_error_percent,
    nees,
    nees_fraction_within,
    pose_errors,
    yaw_rmse,
)
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import EkfNoise, fuse, pose_covariances
from fusion.planar.imu_motion import imu_motion_codes

SEEDS = range(100, 106)
SCENARIOS = ("plain", "all", "all+dead", "moving-start", "kinematic")
# accel_psd 0.002, slip_inflation 1e4 and yaw_fix_rate 0.5 deg/s won the earlier, wider grids,
# turn_w_std and wheel_w_corr_time the last one (see the last runs above); this one searches
# the speed's random walk after a slipping frame and the position noise per metre driven (the
# latter changes no estimate, only the covariance)
# the last grid (5): the accelerometer driving the speed (accel_speed_psd 0: off, v a random
# walk) and the time constant of its offset learnt from the wheels while driving
# (7): the speed's random walk grown by the filter's own last rate of change of the speed
# (with stamp_std at its default)
# (9): the yaw budget's refill rate
# (10): the prior of the wheels' radius mismatch c (its share of what a straight drive shows)
GRID = {
    "calib_c_std": [0.005, 0.01, 0.02, 0.05, 0.1],
}
# --calibrated-gyro: the physics runs' gyro z divided by (1 + its true scale error) and
# gyro_scale_std set to a gyro-scale calibration's uncertainty, as after the turns-in-place
# calibration (the kinematic simulator has no gyro scale error: unchanged)
CALIBRATED_SCALE_STD = 5e-4


def configs() -> list[dict]:
    keys = list(GRID)
    return [dict(zip(keys, values, strict=True)) for values in itertools.product(*GRID.values())]


def score(run, robot, codes, noise: EkfNoise, gyro_z=None) -> float:
    """The tuning objective of one run (see the module docstring); ``gyro_z`` (rad/s)
    replaces the run's gyro z when given."""
    gyro_z = run.gyro[:, 2] if gyro_z is None else gyro_z
    track, _ = fuse(robot, run.imu_t, gyro_z, run.wheel_t, run.ticks,
                    noise=noise, imu_motion=codes, accel_x=run.accel[:, 0])
    k = track.kind == core.EV_GYRO
    est = track.states[k, :3]
    if not np.isfinite(track.states[k]).all():
        return math.inf
    truth = run.truth_at(track.t[k])
    inside = nees_fraction_within(nees(pose_errors(est, truth), pose_covariances(track.states[k])),
                                  3)
    return (math.degrees(yaw_rmse(est[:, 2], truth[:, 2]))
            + final_position_error_percent(est[:, :2], truth, run.distance) + (1.0 - inside))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calibrated-gyro", action="store_true",
                    help="physics runs with the gyro scale calibrated (see CALIBRATED_SCALE_STD)")
    calibrated = ap.parse_args().calibrated_gyro
    t0 = time.perf_counter()
    grid = configs()
    table = np.zeros((len(grid), len(SEEDS)))
    for j, seed in enumerate(SEEDS):
        for scenario in SCENARIOS:
            if scenario == "kinematic":
                run = degraded_mission(seed=seed, duration=300.0)
                robot = EXAMPLE_ROBOT
            elif scenario == "moving-start":
                run = simulate_physics(indoor_mission(seed, 300.0, moving_start=True),
                                       all_errors(seed), seed)
                robot = run.robot.chassis
            else:
                run = physics_scenario(scenario, seed=seed)
                robot = run.robot.chassis
            codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
            gyro_z, extra = None, {}
            if calibrated and scenario != "kinematic":
                gyro_z = run.gyro[:, 2] / (1.0 + run.sensors.gyro_scale[2])
                extra = {"gyro_scale_std": CALIBRATED_SCALE_STD}
            for i, cfg in enumerate(grid):
                table[i, j] += score(run, robot, codes, EkfNoise(**cfg, **extra),
                                     gyro_z) / len(SCENARIOS)
    cv = leave_one_out(table)
    default = EkfNoise()
    # the accelerometer offset's time constant means nothing while the accelerometer is off
    current = next((i for i, cfg in enumerate(grid)
                    if all(getattr(default, k) == v for k, v in cfg.items()
                           if k != "accel_offset_time" or cfg.get("accel_speed_psd", 0) > 0)),
                   None)
    if current is None:
        raise ValueError(f"GRID {GRID} does not contain the current defaults "
                         f"({', '.join(f'{k}={getattr(default, k)!r}' for k in GRID)}): "
                         "add them, so that the chosen configuration is compared with them")

    def show(cfg: dict) -> str:
        return ", ".join(f"{k}={math.degrees(v):.2f} deg/s" if k == "yaw_fix_rate"
                         else f"{k}={v:g}" for k, v in cfg.items())

    print(f"EKF tuning: {len(grid)} configurations x {len(SEEDS)} seeds x "
          f"{len(SCENARIOS)} scenarios ({time.perf_counter() - t0:.0f} s)"
          + (", gyro scale calibrated" if calibrated else ", raw gyro"))
    print("objective per seed: mean over scenarios of yaw RMSE deg + final error % + "
          "(1 - NEES fraction inside 95 %)")
    for i in np.argsort(table.mean(axis=1)):
        print(f"  in-sample {table[i].mean():.3f}: {show(grid[i])}")
    for j, seed in enumerate(SEEDS):
        print(f"  seed {seed}: held out {cv.held_out[j]:.3f} with {show(grid[cv.chosen[j]])}")
    print(f"cross-validated objective (leave one seed out): {cv.cv_mean:.3f}")
    print(f"best on all tuning seeds (IN-SAMPLE {cv.in_sample:.3f}): {show(grid[cv.best])}")
    print(f"current EkfNoise defaults: {show(grid[current])}, in-sample "
          f"{table[current].mean():.3f}")


if __name__ == "__main__":
    main()
