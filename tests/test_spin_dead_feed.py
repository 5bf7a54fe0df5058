"""A dead encoder feed during a smooth spin on the spot, with an IMU that does not shake.

The IMU's window statistic calls a steady turn "still" (nothing varies), so zero ticks there
used to pass for a stop: the ZUPTs pinned the rate, the bias was relearnt to the spin's rate
and the heading lost (review of session 18: about 130 deg). The gyro's rate, beyond what a
wrong bias could explain, now makes those frames an encoder fault
(``fusion.planar._ekf_core._spinning``). The reference is the kinematic simulator's truth.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation import synthetic as sim
from fusion.io.fused_csv import read_fused_csv
from fusion.io.logdir import write_logdir
from fusion.jobs.replay import replay_logdir
from fusion.planar.imu_motion import MOTION_STILL, imu_motion_codes
from fusion.planar.robot import DiffDriveParams

ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=0.0005, encode_sampling_time=0.02)
BIAS = math.radians(0.5)  # rad/s, the gyro's z bias


def _replay(run, tmp_path, gyro=None, ticks=None):
    """Write ``run`` (with ``gyro``/``ticks`` in place of its own where given) as a log
    directory, replay it; the replay's result and its fused table."""
    gyro = run.gyro if gyro is None else gyro
    ticks = run.ticks if ticks is None else ticks
    log = write_logdir(tmp_path / "log", ROBOT, run.imu_t, gyro, run.accel, run.wheel_t,
                       ticks, run.truth_t, run.truth)
    result = replay_logdir(log, tmp_path / "fused.csv")
    return result, read_fused_csv(tmp_path / "fused.csv")


def _spin_run(rate: float, tmp_path, kill: bool = True):
    """Stop 5 s, 2 m straight, one turn on the spot at ``rate`` rad/s, 2 m straight, stop 5 s;
    with ``kill`` the wheels read zero from 0.5 s into the turn to 0.5 s before its end.
    Returns the run, the dead window (s) and the replay's result and fused table."""
    segments = (sim.stop(5.0) + sim.straight(2.0) + sim.spin(2 * math.pi, rate)
                + sim.straight(2.0) + sim.stop(5.0))
    run = sim.simulate(segments, ROBOT, imu=sim.ImuModel(gyro_bias=(0.0, 0.0, BIAS)), seed=1)
    spin_start = 5.0 + 2.0 / 0.4
    window = (spin_start + 0.5, spin_start + 2 * math.pi / rate - 0.5)
    ticks = run.ticks.copy()
    if kill:
        ticks[(run.wheel_t >= window[0]) & (run.wheel_t < window[1])] = 0
    result, fused = _replay(run, tmp_path, ticks=ticks)
    return run, window, result, fused


def _yaw_error_deg(run, fused) -> np.ndarray:
    truth = np.interp(fused["t"], run.truth_t, np.unwrap(run.truth[:, 2]))
    return np.degrees(np.angle(np.exp(1j * (fused["yaw"] - truth))))


@pytest.mark.parametrize("rate", [0.2, 0.8])
def test_zero_ticks_in_a_smooth_spin_are_a_fault_not_a_stop(tmp_path, rate):
    run, (t0, t1), result, fused = _spin_run(rate, tmp_path)
    # the scenario: the IMU's window statistic sees no motion during the spin
    codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    inside = (run.imu_t > t0 + 0.5) & (run.imu_t < t1)
    assert np.mean(codes[inside] == MOTION_STILL) > 0.9
    dead = (fused["t"] > t0 + 0.05) & (fused["t"] < t1 - 0.05)  # a frame in from each end
    assert (fused["encoder_fault"][dead] == 1).all()
    assert (fused["zupt"][dead] == 0).all()
    assert "encoder_fault" in {w.name for w in result.warnings}
    # the heading holds through the turn (before: tens of degrees lost)
    err = _yaw_error_deg(run, fused)
    assert np.abs(err).max() < 1.0
    # the bias is still the gyro's, not the spin's rate (the last stop's ZUPTs had it right)
    assert fused["gyro_bias_z"][-1] == pytest.approx(BIAS, abs=math.radians(0.05))
    # the turn the odometry could not see is the one the robot made while it was dead
    true_turn = np.interp(t1, run.truth_t, np.unwrap(run.truth[:, 2])) - np.interp(
        t0, run.truth_t, np.unwrap(run.truth[:, 2]))
    assert result.stats["fault_turn"] == pytest.approx(true_turn, rel=0.03)


def test_a_real_stop_after_a_spin_is_still_a_stop(tmp_path):
    # the same run with the wheels alive: no frame is a fault, and both stops give ZUPTs
    run, _, result, fused = _spin_run(0.8, tmp_path, kill=False)
    assert result.stats["encoder_faults"] == 0
    assert not fused["encoder_fault"].any()
    last_stop = fused["t"] > run.truth_t[-1] - 4.0
    assert fused["zupt"][last_stop].mean() > 0.9


def test_a_moving_starts_first_stop_is_a_stop_whatever_the_bias(tmp_path):
    # Driving from the first sample with a 25 deg/s bias (past the MPU6050's +-20 deg/s):
    # at the first stop the filter's rate is the unlearnt bias; the wheels had slowed their
    # turn before, so it is no spin, and that stop's ZUPTs relearn it (taken for a spin:
    # 117 deg lost).
    segments = (sim.straight(3.0) + sim.arc(1.0, 1.5) + sim.stop(5.0) + sim.straight(2.0)
                + sim.stop(5.0))
    bias = math.radians(25.0)
    run = sim.simulate(segments, ROBOT, imu=sim.ImuModel(gyro_bias=(0.0, 0.0, bias)), seed=1)
    result, fused = _replay(run, tmp_path)
    assert result.stats["encoder_faults"] == 0
    assert np.abs(_yaw_error_deg(run, fused)).max() < 1.0
    assert fused["gyro_bias_z"][-1] == pytest.approx(bias, abs=math.radians(0.05))


def test_a_bias_that_steps_during_a_stop_is_relearnt_not_taken_for_a_spin(tmp_path):
    # A review's case: the ZUPTs of a first stop learnt the bias; 3 s into a second 20 s stop
    # it steps by 10 deg/s (a driver re-zeroing its offsets, a shock). The wheels stood
    # still before: a stop, relearnt (taken for a spin, every later zero frame was a fault
    # and the heading was lost: 180 deg at worst).
    segments = (sim.stop(5.0) + sim.straight(2.0) + sim.stop(20.0) + sim.straight(2.0)
                + sim.stop(10.0))
    run = sim.simulate(segments, ROBOT, imu=sim.ImuModel(gyro_bias=(0.0, 0.0, BIAS)), seed=1)
    gyro = run.gyro.copy()
    step = math.radians(10.0)
    gyro[run.imu_t >= 13.0, 2] += step
    result, fused = _replay(run, tmp_path, gyro=gyro)
    assert result.stats["encoder_faults"] == 0
    assert fused["gyro_bias_z"][-1] == pytest.approx(BIAS + step, abs=math.radians(0.05))


def test_a_spin_whose_wheels_die_before_any_stop_is_a_fault(tmp_path):
    # driving from the first sample, no stop before the wheels die in the turn
    segments = sim.straight(2.0) + sim.spin(2 * math.pi, 0.8) + sim.straight(2.0) + sim.stop(5.0)
    run = sim.simulate(segments, ROBOT, imu=sim.ImuModel(gyro_bias=(0.0, 0.0, BIAS)), seed=1)
    t0, t1 = 5.5, 5.0 + 2 * math.pi / 0.8 - 0.5
    ticks = run.ticks.copy()
    ticks[(run.wheel_t >= t0) & (run.wheel_t < t1)] = 0
    _, fused = _replay(run, tmp_path, ticks=ticks)
    dead = (fused["t"] > t0 + 0.05) & (fused["t"] < t1 - 0.05)
    assert (fused["encoder_fault"][dead] == 1).all()
    assert np.abs(_yaw_error_deg(run, fused)).max() < 1.0
