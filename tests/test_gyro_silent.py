"""Without a gyro (a log without imu.csv, or a gap in the IMU's feed) the wheels' yaw rate is
all there is (fusion.planar._ekf_core.GYRO_SILENT): fused without the slip gate, and without
teaching the wheels' yaw-rate scale k and radius mismatch c, which only a gyro can.

Found by an independent probe of log directories: a wheels-only replay flagged every turn's
onset as a slip and walked k to -0.45, ending 44.7 % of its distance off with the yaw 97 deg
off in RMS, where the same ticks dead-reckoned give 0.19 % and 0.35 deg; a 2 s IMU gap in a
turn left the heading 13 deg off. Oracles: the simulator's truth, and the ticks dead-reckoned
here with numpy (not the library's code).
"""

from __future__ import annotations

import numpy as np
import pytest

from fusion.evaluation.synthetic import degraded_mission
from fusion.io.logdir import write_synthetic_run
from fusion.io.robot_toml import read_robot_toml
from fusion.jobs.replay import replay_logdir


def _replay(log, out):
    """The replay's counters and its fused CSV's columns."""
    r = replay_logdir(log, out)
    return r.stats, np.genfromtxt(out, delimiter=",", names=True)


@pytest.fixture(scope="module")
def run_and_log(tmp_path_factory):
    # a well calibrated robot on a floor that does not slip: its ticks alone hold the heading
    run = degraded_mission(seed=4, duration=120.0, separation_error=0.0, radius_mismatch=0.0,
                           slip_patches=0)
    return run, write_synthetic_run(tmp_path_factory.mktemp("silent") / "run", run)


def _yaw_rmse(t, yaw, run) -> float:
    truth = np.interp(t, run.truth_t, np.unwrap(run.truth[:, 2]))
    err = np.angle(np.exp(1j * (yaw - truth)))
    return float(np.degrees(np.sqrt(np.mean(err ** 2))))


def _dead_reckoned_yaw(run, wheel_distance: float, speed_ratio: float) -> np.ndarray:
    turn = (run.ticks[:, 1] - run.ticks[:, 0]) * speed_ratio / wheel_distance
    return run.truth[0, 2] + np.cumsum(turn)


def test_a_wheels_only_log_holds_the_heading_its_ticks_give(run_and_log, tmp_path):
    run, log = run_and_log
    only = tmp_path / "only"
    only.mkdir()
    for name in ("robot.toml", "wheels.csv", "truth.csv"):
        (only / name).write_bytes((log / name).read_bytes())
    stats, table = _replay(only, tmp_path / "fused.csv")
    c = read_robot_toml(only / "robot.toml").chassis
    own = _yaw_rmse(run.wheel_t, _dead_reckoned_yaw(run, c.wheel_distance, c.speed_ratio), run)
    fused = _yaw_rmse(table["t"], table["yaw"], run)
    assert own < 2.0  # the ticks do hold it
    assert fused < own + 0.5, (fused, own)
    assert stats["slips"] == 0
    # k and c keep their priors: nothing without a gyro measures them
    assert np.all(table["wheel_rate_scale"] == 0.0)
    assert np.all(table["wheel_rate_per_speed"] == 0.0)


def test_a_gap_in_the_imu_feed_during_a_turn_leaves_the_wheels_the_heading(run_and_log,
                                                                            tmp_path):
    run, log = run_and_log
    # 2 s without IMU samples where the robot turns fastest
    w = np.abs(run.truth_w)
    middle = (run.truth_t > 10.0) & (run.truth_t < run.truth_t[-1] - 10.0)
    t0 = float(run.truth_t[middle][np.argmax(w[middle])]) - 1.0
    gap = tmp_path / "gap"
    gap.mkdir()
    for f in log.iterdir():
        (gap / f.name).write_bytes(f.read_bytes())
    head, *rows = (log / "imu.csv").read_text().splitlines()
    kept = [r for r in rows if not t0 <= float(r.split(",", 1)[0]) < t0 + 2.0]
    assert len(rows) - len(kept) > 100
    (gap / "imu.csv").write_text("\n".join([head, *kept]) + "\n")
    _, whole = _replay(log, tmp_path / "whole.csv")
    _, holed = _replay(gap, tmp_path / "holed.csv")

    def yaw_error_at(table, t):
        i = int(np.searchsorted(table["t"], t))
        truth = np.interp(table["t"][i], run.truth_t, np.unwrap(run.truth[:, 2]))
        return float(np.degrees(np.angle(np.exp(1j * (table["yaw"][i] - truth)))))

    turned = float(np.degrees(np.interp(t0 + 2.0, run.truth_t, np.unwrap(run.truth[:, 2]))
                              - np.interp(t0, run.truth_t, np.unwrap(run.truth[:, 2]))))
    assert abs(turned) > 30.0  # it does turn through the gap
    # the heading after the gap as good as with the gyro, to a degree
    after = yaw_error_at(holed, t0 + 2.1) - yaw_error_at(holed, t0 - 0.1)
    assert abs(after) < 1.0, (after, turned)
    assert _yaw_rmse(holed["t"], holed["yaw"], run) < (
        _yaw_rmse(whole["t"], whole["yaw"], run) + 0.3)
