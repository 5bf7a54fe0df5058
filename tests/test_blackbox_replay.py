"""``fusion replay`` on the third, independent simulator (benchmarks/blackbox, issue 11).

benchmarks/blackbox/sim.py was written by someone shown neither the EKF nor the project's two
simulators: 1 kHz rigid-body physics with friction-circle contacts, firmware driving the wheels
with the wrong geometry, encoder clock drift, jitter and lost frames, an MPU6050 with warm-up
drift, scale and cross-axis errors, an unstated mount tilt, vibration and its low-pass filter.
Its "dead" scenario adds 8 s of zero ticks on both wheels while the robot drives. Everything
is scored here against the simulator's own truth and against baselines computed from the log
files alone (benchmarks/blackbox/run_all.py: wheel-only dead reckoning, gyro with its bias
taken at the stops), none of it from the library.

The checks are issue 11's requirements, not figures measured on this run: a dead encoder
feed is flagged for its whole length and nowhere else; zero-velocity updates only while the
robot truly stands; no step between rows beyond 3 x the fastest speed x the row interval;
the fused track ends closer than both baselines. One seed (101) that no parameter was chosen
on; the yaw RMSE is not asserted against the gyro baseline, which it does not beat on every
seed (seeds 101-106: fused 1.06-2.31 deg, gyro at stops 0.70-2.15 deg; the closing note of
issue 11).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import main

BLACKBOX = Path(__file__).resolve().parent.parent / "benchmarks" / "blackbox"
SEED = 101


@pytest.fixture(scope="module")
def blackbox():
    """The benchmark's two scripts as modules (they import each other by bare name), taken out
    of ``sys.modules`` again afterwards so that no other test sees a module called ``sim``."""
    sys.path.insert(0, str(BLACKBOX))
    try:
        sim = importlib.import_module("sim")
        run_all = importlib.import_module("run_all")
    finally:
        sys.path.remove(str(BLACKBOX))
    yield sim, run_all
    for name in ("sim", "run_all"):
        sys.modules.pop(name, None)


@pytest.fixture(scope="module")
def dead_run(blackbox, tmp_path_factory):
    sim, run_all = blackbox
    truth_run = sim.simulate(sim.make_config("dead", SEED))
    folder = sim.write_run(truth_run, tmp_path_factory.mktemp("blackbox") / f"dead_{SEED}")
    assert main(["replay", str(folder), "-o", str(folder / "fused.csv")]) == 0
    read = run_all.read_csv_cols
    files = {name: read(folder / f"{name}.csv") for name in ("fused", "truth", "wheels", "imu")}
    return truth_run, folder, files


def _true_speed(truth):
    """Speed (m/s) and yaw rate (rad/s) of the simulator's truth, at its own stamps."""
    t = truth["t"]
    speed = np.hypot(np.gradient(truth["x"], t), np.gradient(truth["y"], t))
    return speed, np.gradient(np.unwrap(truth["yaw"]), t)


def test_a_dead_encoder_feed_is_flagged_for_its_length_and_nowhere_else(dead_run):
    truth_run, _, files = dead_run
    fused = files["fused"]
    start, end = truth_run["dead"]
    t = fused["t"]
    fault = fused["encoder_fault"] == 1
    period = truth_run["cfg"].wheel_period
    # inside: every row once the first frame of zero ticks has arrived (one period)
    inside = (t >= start + period) & (t <= end)
    assert inside.sum() > 500 and fault[inside].all(), np.flatnonzero(inside & ~fault)
    # outside: at most the frame that ends the window (its period straddles it)
    assert not np.any(fault & ((t < start) | (t > end + 2 * period)))


def test_zero_velocity_updates_only_while_the_robot_stands(dead_run):
    _, _, files = dead_run
    fused, truth = files["fused"], files["truth"]
    zupt = fused["zupt"] == 1
    assert zupt.sum() > 1000  # the mission stops several times
    speed, rate = _true_speed(truth)
    t = fused["t"][zupt]
    assert np.interp(t, truth["t"], speed).max() < 0.02  # m/s
    assert np.abs(np.interp(t, truth["t"], rate)).max() < 0.1  # rad/s


def test_no_step_between_rows_beyond_what_the_motion_allows(dead_run):
    _, _, files = dead_run
    fused, truth = files["fused"], files["truth"]
    speed, _ = _true_speed(truth)
    steps = np.hypot(np.diff(fused["x"]), np.diff(fused["y"]))
    assert np.all(steps <= 3.0 * speed.max() * np.diff(fused["t"]) + 1e-9)


def test_the_fused_track_ends_closer_than_both_baselines(dead_run, blackbox):
    _, run_all = blackbox
    _, folder, files = dead_run
    fused, truth, wheels, imu = (files[k] for k in ("fused", "truth", "wheels", "imu"))
    distance = run_all.path_length(truth)
    geometry = run_all.read_robot(folder / "robot.toml")
    wheel_t, wheel_pose = run_all.wheel_only(wheels, *geometry)
    stops = run_all.find_stops(wheels, imu)
    (gyro_t, gyro_pose), _ = run_all.gyro_at_stops(wheels, imu, geometry[1], geometry[2], stops)
    pose = np.column_stack([fused["x"], fused["y"], fused["yaw"]])
    final, yaw, _ = run_all.errors(fused["t"], pose, truth, distance)
    final_wheels, yaw_wheels, _ = run_all.errors(wheel_t, wheel_pose, truth, distance)
    final_gyro, _, _ = run_all.errors(gyro_t, gyro_pose, truth, distance)
    assert final < final_wheels and final < final_gyro
    assert yaw < yaw_wheels
