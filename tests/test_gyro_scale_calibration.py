"""Gyro scale calibration (turns in place back to a mark) and its use by the EKF.

Oracles: a constructed stream whose angle is known in closed form; the physics simulator's
own sensor matrices (written without looking at the EKF or the calibration) for the true
scale of the rate about the vertical; the simulator's ground truth for the fused track.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.calibration.gyro_scale import calibrate_gyro_scale, combine_gyro_scales
from fusion.evaluation.physics_sim import all_errors, physics_scenario
from fusion.evaluation.physics_sim.calibration_run import gyro_calibration_run
from fusion.evaluation.trajectory import final_position_error_percent, yaw_rmse
from fusion.geometry.mount import base_to_imu, mount_matrix
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.imu_motion import imu_motion_codes

G = 9.80665


def _turns_stream(turns, scale, bias0, drift, rate=1.0, rest=5.0, fs=200.0, mount=(0, 0, 0)):
    """Rest, a constant true rate for exactly ``turns`` turns, rest; gyro = (1+scale)*rate +
    bias0 + drift*t about the base vertical, then rotated into a tilted IMU."""
    spin = 2 * math.pi * abs(turns) / rate
    t = np.arange(0.0, 2 * rest + spin, 1.0 / fs)
    true = np.where((t >= rest) & (t < rest + spin), math.copysign(rate, turns), 0.0)
    # the sample grid does not hit the turn's ends exactly: make the trapezoid integral exact
    z = (1 + scale) * true + bias0 + drift * t
    R = mount_matrix(mount)
    gyro = base_to_imu(R, np.column_stack([np.zeros_like(t), np.zeros_like(t), z]))
    accel = base_to_imu(R, np.tile([0.0, 0.0, G], (t.size, 1)))
    angle_true = float(np.sum(0.5 * (true[1:] + true[:-1]) * np.diff(t)))
    return t, gyro, accel, angle_true


def test_scale_bias_drift_and_tilt_recovered_in_closed_form():
    mount = (math.radians(2.0), math.radians(-1.5), 0.3)
    t, gyro, accel, angle = _turns_stream(8, 0.0137, math.radians(0.4), math.radians(0.002),
                                          mount=mount)
    # the turn's ends fall between samples; declare the angle the samples really hold
    cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi))
    assert cal.scale_error == pytest.approx(0.0137, abs=1e-9)
    # linear drift is removed exactly; the first rest (0-4.5 s, the last 0.5 s before the
    # turn trimmed) has the drift line's value at its middle, within 0.05 s of drift
    assert cal.bias_before == pytest.approx(math.radians(0.4) + math.radians(0.002) * 2.25,
                                            abs=math.radians(0.002) * 0.05)
    assert math.degrees(cal.mount_tilt) == pytest.approx(2.5, abs=0.01)


def test_clockwise_turns_give_the_same_scale():
    t, gyro, accel, angle = _turns_stream(-5, -0.021, math.radians(-0.3), 0.0)
    cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi))
    assert cal.scale_error == pytest.approx(-0.021, abs=1e-9)
    assert cal.measured_turns < 0
    # no noise, no drift: the uncertainty is the 1 deg mark over 5 turns
    assert cal.scale_error_std == pytest.approx(math.radians(1.0) / abs(angle), rel=1e-6)


def test_a_miscount_is_refused_with_both_counts():
    t, gyro, accel, _ = _turns_stream(10, 0.01, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"measured \+10\.1.* \+9 were declared"):
        calibrate_gyro_scale(t, gyro, accel, 9)


def test_too_short_a_rest_is_refused():
    t, gyro, accel, _ = _turns_stream(3, 0.01, 0.0, 0.0, rest=1.5)
    with pytest.raises(ValueError, match="stand still for at least 3 s"):
        calibrate_gyro_scale(t, gyro, accel, 3)


def test_combined_runs_are_the_inverse_variance_mean():
    # 1.0 and 1.1 %, standard deviations 0.080 and 0.027 % (a 0.01 rad mark over 2 and 6
    # turns): 1.2 standard deviations apart, which the agreement test lets through
    t, gyro, accel, angle = _turns_stream(2, 0.010, 0.0, 0.0)
    a = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), mark_std=0.01)
    t, gyro, accel, angle = _turns_stream(-6, 0.011, 0.0, 0.0)
    b = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), mark_std=0.01)
    c = combine_gyro_scales([a, b])
    wa, wb = a.scale_error_std ** -2, b.scale_error_std ** -2
    assert c.scale_error == pytest.approx((wa * 0.010 + wb * 0.011) / (wa + wb), abs=1e-9)
    assert c.scale_error_std == pytest.approx((wa + wb) ** -0.5)
    assert c.declared_turns == pytest.approx(8.0, abs=0.01)


def test_runs_that_disagree_beyond_their_uncertainties_are_refused_naming_each():
    # 1 % and 2 % with the same 0.01 rad mark: 12 standard deviations apart (an independent
    # probe's two gyros, or one run a few degrees off its mark): the mean of the two would
    # be stated to 0.02 % and be wrong for both
    t, gyro, accel, angle = _turns_stream(2, 0.01, 0.0, 0.0)
    a = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), mark_std=0.01)
    t, gyro, accel, angle = _turns_stream(-6, 0.02, 0.0, 0.0)
    b = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), mark_std=0.01)
    with pytest.raises(ValueError, match=r"disagree.*\+1\.000 % \+- 0\.080 %, \+2\.000 %"):
        combine_gyro_scales([a, b])


def _effective_vertical_scale(sensors, vertical):
    """The simulator's true scale of ``gyro . vertical`` for a rotation about the base
    vertical: its own scale/cross-axis matrix and mount (sensor_model.py, sensors.py)."""
    sx, sy, sz = sensors.gyro_scale
    cxy, cxz, cyx, cyz, czx, czy = sensors.gyro_cross_axis
    M = np.array([[1 + sx, cxy, cxz], [cyx, 1 + sy, cyz], [czx, czy, 1 + sz]])
    z_imu = base_to_imu(mount_matrix(sensors.mount_rpy), np.array([[0.0, 0.0, 1.0]]))[0]
    return float(np.asarray(vertical) @ M @ z_imu) - 1.0


@pytest.mark.parametrize("seed", range(8))
def test_physics_calibration_run_recovers_the_true_scale(seed):
    """Every error of the physics simulator on (warming bias, g-sensitivity, cross-axis,
    mount tilt, vibration, lost samples, jittered stamps), 10 turns, a 1 deg mark."""
    sensors = all_errors(seed)
    run, alignment = gyro_calibration_run(sensors, seed, turns=10)
    assert abs(alignment) < math.radians(4)  # the owner's error, N(0, 1 deg)
    cal = calibrate_gyro_scale(run.imu_t, run.gyro, run.accel, 10)
    truth = _effective_vertical_scale(sensors, cal.vertical)
    assert abs(truth - sensors.gyro_scale[2]) < 0.002  # z's own scale dominates
    assert abs(cal.scale_error - truth) < 3 * cal.scale_error_std
    assert cal.scale_error_std < 6e-4


def _fused_errors(run, noise, rate):
    track, _ = fuse(run.robot.chassis, run.imu_t, rate, run.wheel_t, run.ticks, noise=noise,
                    imu_motion=imu_motion_codes(run.imu_t, run.gyro, run.accel))
    k = track.kind == 0
    est, truth = track.states[k, :3], run.truth_at(track.t[k])
    return (final_position_error_percent(est[:, :2], truth, run.distance),
            math.degrees(yaw_rmse(est[:, 2], truth[:, 2])))


@pytest.mark.parametrize("scenario", ["all", "all+dead"])
def test_calibrated_ekf_meets_issue_11_targets_on_every_seed(scenario):
    """Issue 11's acceptance on the second simulator, with the gyro calibrated by the owner's
    10 turns (a separate simulated run of the same sensors): final error <= 0.5 % of the
    distance and yaw RMSE <= 1.5 deg on each of seeds 0-7 for every error on; yaw RMSE <= 1.5
    deg with an 8 s dead encoder feed while driving. Without the calibration the gyro's
    0.5-2 % scale error alone costs up to 9 deg (benchmarks/ekf_accuracy.py)."""
    for seed in range(8):
        run = physics_scenario(scenario, seed=seed)
        cal_run, _ = gyro_calibration_run(run.sensors, seed, turns=10)
        cal = calibrate_gyro_scale(cal_run.imu_t, cal_run.gyro, cal_run.accel, 10)
        rate = run.gyro @ np.asarray(cal.vertical)
        final, yaw = _fused_errors(run, EkfNoise(**cal.ekf_fields()), rate)
        assert yaw <= 1.5, (seed, final, yaw)
        if scenario == "all":
            assert final <= 0.5, (seed, final, yaw)


# -- what an independent probe of the command found (2026-11-29): each once a traceback or a
# -- silent wrong scale, now a refusal that says what happened


def test_a_three_percent_gyro_over_ten_turns_and_one_and_a_half_over_twenty_are_measured():
    # the datasheet's +-3 %: 10 turns read 10.3; the former 0.25-turn tolerance refused them
    # as miscounts ("count the turns again")
    for turns, scale in ((10, 0.03), (20, 0.015), (-10, -0.03)):
        t, gyro, accel, angle = _turns_stream(turns, scale, math.radians(0.5), 0.0)
        cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi))
        assert cal.scale_error == pytest.approx(scale, abs=1e-9)
        # beyond 2 % the report says what else gives it: a robot off its mark
        assert ("caution" in cal.report()) == (abs(scale) > 0.02)


def test_a_miscount_by_one_of_up_to_nineteen_turns_is_refused():
    for made, declared in ((18, 19), (20, 19), (5, 6)):
        t, gyro, accel, _ = _turns_stream(made, 0.0, 0.0, 0.0)
        with pytest.raises(ValueError, match=f"but \\+{declared} were declared, a scale error"):
            calibrate_gyro_scale(t, gyro, accel, declared)


def test_no_rest_at_either_end_is_refused_not_an_index_error():
    # turning from the first sample to the last: the end's rest length was 0 and
    # t[t.size - 0] raised IndexError
    t = np.arange(0.0, 30.0, 0.005)
    gyro = np.column_stack([np.zeros_like(t), np.zeros_like(t),
                            1.0 + 0.1 * t])
    accel = np.tile([0.0, 0.0, G], (t.size, 1))
    with pytest.raises(ValueError, match=r"found 0\.0 s at the start"):
        calibrate_gyro_scale(t, gyro, accel, 5)
    still = np.zeros_like(gyro)
    with pytest.raises(ValueError, match="no turn in this run"):
        calibrate_gyro_scale(t, still, accel, 5)


def test_a_gyro_in_degrees_per_second_is_named():
    t, gyro, accel, _ = _turns_stream(10, 0.01, math.radians(0.5), 0.0)
    with pytest.raises(ValueError, match=r"reads up to 5\d\.\d rad/s on one axis.*deg/s"):
        calibrate_gyro_scale(t, np.degrees(gyro), accel, 10)
    # turning slowly (0.2 rad/s: 11.5 'rad/s' in deg/s, within a full scale): the count says it
    t, gyro, accel, _ = _turns_stream(2, 0.0, 0.0, 0.0, rate=0.2)
    with pytest.raises(ValueError, match="180/pi's: the gyro is in deg/s"):
        calibrate_gyro_scale(t, np.degrees(gyro), accel, 2)


def test_a_gap_during_the_turns_is_refused_naming_it():
    # 1.8 s without a sample over the deceleration: the trapezoid drew a straight line
    # across it and the probe's +1.2 % gyro came out +0.11 % +- 0.03 %
    t, gyro, accel, _ = _turns_stream(3, 0.012, 0.0, 0.0)
    keep = (t < 14.0) | (t > 15.8)
    with pytest.raises(ValueError, match=r"no IMU sample for 1\.8.* s after t = 13\.99"):
        calibrate_gyro_scale(t[keep], gyro[keep], accel[keep], 3)


def test_a_non_finite_sample_is_named_by_its_index_and_time():
    t, gyro, accel, _ = _turns_stream(3, 0.0, 0.0, 0.0)
    gyro[3000, 2] = np.nan
    with pytest.raises(ValueError, match=r"IMU sample 3000 \(t = 15\.0 s\) is not finite"):
        calibrate_gyro_scale(t, gyro, accel, 3)


#: the wheels of the tests below: 0.1 mm per tick, 0.2 m apart (one tick of difference per
#: 40 ms frame turns the robot at 1.4 deg/s)
GEOMETRY = (1e-4, 0.2)


def _turn_ticks(t_frames, turns, rate=1.0, rest=5.0, offset=0.0):
    """Wheel frames (40 ms) of _turns_stream's turn in place, stamped ``offset`` s off the
    IMU's clock: right forward, left back, at the true rate."""
    spin = 2 * math.pi * abs(turns) / rate
    turning = (t_frames - offset >= rest) & (t_frames - offset < rest + spin)
    per_frame = rate * 0.04 * GEOMETRY[1] / 2 / GEOMETRY[0]  # ticks per wheel per frame
    right = np.where(turning, round(math.copysign(per_frame, turns)), 0)
    return np.column_stack([-right, right]).astype(np.int64)


def test_wheels_turning_during_a_rest_are_refused():
    # the robot creeping at 0.3 deg/s through its "rests" reads as bias; the probe's +1.2 %
    # gyro came out +0.78 % without a word. Its wheels, where logged, tell.
    t, gyro, accel, angle = _turns_stream(3, 0.01, 0.0, 0.0)
    wheel_t = np.arange(0.02, t[-1], 0.04)
    ticks = _turn_ticks(wheel_t, 3)
    cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), wheel_t=wheel_t,
                               ticks=ticks, wheel_geometry=GEOMETRY)
    assert cal.scale_error == pytest.approx(0.01, abs=1e-9)
    creeping = ticks.copy()
    creeping[wheel_t < 4.0] = [-1, 1]  # 1.4 deg/s: 27 deg over the 19 s of turning
    with pytest.raises(ValueError, match=r"the wheels turned the robot by \+4\.\d+ deg during "
                                         r"the rest before the turns"):
        calibrate_gyro_scale(t, gyro, accel, 3, wheel_t=wheel_t, ticks=creeping,
                             wheel_geometry=GEOMETRY)


def test_wheel_stamps_off_the_imus_by_a_second_or_a_gearbox_settling_are_no_motion():
    # the turn's own ticks 0.6 s early or late (another clock), or 5 ticks of one wheel
    # settling as the robot stops, fall in the second next to the turns, which the check
    # leaves out
    t, gyro, accel, angle = _turns_stream(3, 0.01, 0.0, 0.0)
    wheel_t = np.arange(0.02, t[-1], 0.04)
    for offset in (-0.6, 0.6):
        ticks = _turn_ticks(wheel_t, 3, offset=offset)
        cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), wheel_t=wheel_t,
                                   ticks=ticks, wheel_geometry=GEOMETRY)
        assert cal.scale_error == pytest.approx(0.01, abs=1e-9)
    settling = _turn_ticks(wheel_t, 3)
    end = 5.0 + 6 * math.pi
    settling[(wheel_t > end) & (wheel_t < end + 0.2), 1] = 1
    assert calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), wheel_t=wheel_t,
                                ticks=settling, wheel_geometry=GEOMETRY).scale_error == \
        pytest.approx(0.01, abs=1e-9)


def test_an_encoder_toggling_on_an_edge_is_no_motion():
    t, gyro, accel, angle = _turns_stream(3, 0.01, 0.0, 0.0)
    wheel_t = np.arange(0.02, t[-1], 0.04)
    ticks = _turn_ticks(wheel_t, 3)
    ticks[5:40:2, 0] += 1  # +1, -1, +1, ...: net 0 or 1
    ticks[6:40:2, 0] -= 1
    cal = calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi), wheel_t=wheel_t,
                               ticks=ticks, wheel_geometry=GEOMETRY)
    assert cal.scale_error == pytest.approx(0.01, abs=1e-9)


def test_runs_that_differ_a_little_more_than_their_uncertainties_widen_the_std():
    # +1.00 % and +1.10 % with a 0.0025 rad mark over 6 turns each (0.0066 % each): 11 std
    # apart, as a gyro whose scale differs a little with the turning direction gives
    runs = []
    for turns, scale in ((6, 0.010), (-6, 0.011)):
        t, gyro, accel, angle = _turns_stream(turns, scale, 0.0, 0.0)
        runs.append(calibrate_gyro_scale(t, gyro, accel, angle / (2 * math.pi),
                                         mark_std=0.0025))
    c = combine_gyro_scales(runs)
    plain = 1.0 / math.sqrt(sum(r.scale_error_std ** -2 for r in runs))
    assert c.scale_error == pytest.approx(0.0105, abs=1e-9)
    # widened so that the two runs are within about a standard deviation of the mean
    assert c.scale_error_std > 2.0 * plain and c.scale_error_std >= 0.0004
    assert "widened" in c.report()
