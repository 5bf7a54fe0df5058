"""The accelerometer slip test (fusion.planar.accel_slip) and its way into the EKF and outputs.

Oracles: closed-form motions (the specific force of a rigid body rolling without slip is
``dv/dt`` forward and ``v*w`` lateral, so the statistics have exact expected values), the
physics simulator's own tyre state (``truth_slip``: a contact patch at the friction limit,
computed by the 1 kHz tyre model, not by anything the detector or the EKF uses), and the
detector's own streaming path against its batch path (bit for bit).
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from fusion.evaluation.physics_sim import (
    Mission,
    Segment,
    indoor_mission,
    simulate_physics,
    with_errors,
)
from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.fused_csv import read_fused_csv, write_fused_csv
from fusion.jobs.replay import fused_table
from fusion.pipeline.core import FusionPipeline
from fusion.planar import _ekf_core as core
from fusion.planar.accel_slip import (
    CHI2_2DOF_01PCT,
    AccelSlipDetector,
    AccelSlipParams,
    accel_slip_flags,
)
from fusion.planar.ekf import fuse
from fusion.planar.imu_motion import MOTION_MOVING, MOTION_STILL, imu_motion_codes
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink

ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4, encode_sampling_time=0.04)


def _kinematic(speed, yaw_rate, fx, fy, duration=4.0, imu_rate=200.0):
    """Exact inputs of a planar motion: wheel frames of ``speed(t)`` and ``yaw_rate(t)``
    (ticks from the travelled distance of each wheel, floored as an encoder counts) and IMU
    samples whose specific force is ``fx(t)``, ``fy(t)`` (no noise), at rest before 1 s."""
    T, L, sr = ROBOT.encode_sampling_time, ROBOT.wheel_distance, ROBOT.speed_ratio
    t = np.arange(0.0, duration, 1e-4)
    v, w = speed(t), yaw_rate(t)
    dist_l = np.concatenate(([0.0], np.cumsum((v - 0.5 * L * w)[:-1] * 1e-4)))
    dist_r = np.concatenate(([0.0], np.cumsum((v + 0.5 * L * w)[:-1] * 1e-4)))
    wheel_t = np.arange(T, duration, T)
    counts = np.column_stack([np.floor(np.interp(wheel_t, t, d) / sr + 1e-9)
                              for d in (dist_l, dist_r)])
    ticks = np.diff(np.vstack([[0.0, 0.0], counts]), axis=0)
    imu_t = np.arange(0.5 / imu_rate, duration, 1.0 / imu_rate)
    accel = np.column_stack([fx(imu_t), fy(imu_t)])
    motion = np.where(imu_t < 1.0, MOTION_STILL, MOTION_MOVING)
    return imu_t, accel, yaw_rate(imu_t), motion, wheel_t, ticks


def _detect(imu_t, accel, rate, motion, wheel_t, ticks, params=None):
    """(M, 4) detector outputs of the wheel frames, events in host order."""
    kinds = np.concatenate([np.zeros(imu_t.size, np.int64), np.ones(wheel_t.size, np.int64)])
    t = np.concatenate([imu_t, wheel_t])
    order = np.argsort(t, kind="stable")
    cols = (t, np.concatenate([accel[:, 0], ticks[:, 0]]),
            np.concatenate([accel[:, 1], ticks[:, 1]]), np.concatenate([rate, 0 * wheel_t]),
            np.concatenate([motion, 0 * wheel_t]))
    det = AccelSlipDetector(ROBOT.speed_ratio, ROBOT.encode_sampling_time, params)
    out = det.update_batch(kinds[order], *(c[order] for c in cols))
    res = np.empty_like(out)
    res[order] = out
    return res[imu_t.size:], (kinds[order], *(c[order] for c in cols))


def _ramp(t, a=0.5):
    return np.clip(a * (t - 1.0), 0.0, None)


def test_rolling_without_slip_is_never_flagged_and_the_residuals_vanish():
    # 0.5 m/s^2 from 1 s on, the IMU reads exactly dv/dt; then a steady turn at 0.5 rad/s
    # whose IMU reads v*w: both residuals are quantisation only
    speed = _ramp
    def yaw_rate(t): return np.where(t > 2.0, 0.5, 0.0)
    def fx(t): return np.where(t > 1.0, 0.5, 0.0)
    def fy(t): return speed(t) * yaw_rate(t)
    out, _ = _detect(*_kinematic(speed, yaw_rate, fx, fy))
    decided = ~np.isnan(out[:, 3])
    assert decided.sum() > 80
    assert not out[decided, 0].any()
    # trapezoid integrals against the period means: off by at most a tick and the kinks
    assert np.nanmax(np.abs(out[:, 1])) < 0.02 and np.nanmax(np.abs(out[:, 2])) < 0.02


def test_straight_wheel_spin_is_flagged_with_the_speed_it_invents():
    # the wheels speed up at 1 m/s^2 while the body (the IMU) gains 0.5 m/s^2: over the
    # 0.4 s window the wheels invent 0.2 m/s; both wheels alike, so the gyro sees nothing
    def speed(t): return _ramp(t, 1.0)
    def zero(t): return 0.0 * t
    def fx(t): return np.where(t > 1.0, 0.5, 0.0)
    out, _ = _detect(*_kinematic(speed, zero, fx, zero))
    late = np.flatnonzero(~np.isnan(out[:, 3]))[-40:]  # well into the spin
    assert out[late, 0].all()
    np.testing.assert_allclose(out[late, 1], 0.2, atol=0.01)
    np.testing.assert_allclose(out[late, 2], 0.0, atol=1e-9)


def test_a_sideways_slide_in_a_turn_is_flagged_with_its_lateral_speed():
    # constant 0.4 m/s, turning at 1 rad/s from 2 s, but the body feels only half of
    # v*w = 0.4 m/s^2: over 0.4 s it lacks 0.08 m/s of lateral speed
    def speed(t): return np.where(t > 1.0, 0.4, 0.0)
    def yaw_rate(t): return np.where(t > 2.0, 1.0, 0.0)
    def fx(t): return 0.0 * t
    def fy(t): return 0.5 * speed(t) * yaw_rate(t)
    params = AccelSlipParams(lever_arm_std=0.0)  # no lever arm to hide it behind
    out, _ = _detect(*_kinematic(speed, yaw_rate, fx, fy), params=params)
    wheel_t = np.arange(1, out.shape[0] + 1) * ROBOT.encode_sampling_time
    turning = (wheel_t > 2.5) & ~np.isnan(out[:, 3])
    assert turning.sum() > 30 and out[turning, 0].all()
    np.testing.assert_allclose(out[turning, 2], -0.08, atol=0.004)


def test_a_tilt_offset_learnt_at_rest_is_removed():
    # the specific force carries 0.3 m/s^2 of gravity on x (a 1.75 deg pitch) all the time:
    # learnt during the first second at rest, it is no acceleration
    def zero(t): return 0.0 * t
    def fx(t): return 0.3 + np.where(t > 1.0, 0.5, 0.0)
    out, _ = _detect(*_kinematic(_ramp, zero, fx, zero))
    assert not np.nan_to_num(out[:, 0]).any()
    assert np.nanmax(np.abs(out[:, 1])) < 0.02


def test_streaming_equals_batch_bit_for_bit():
    def speed(t): return _ramp(t, 1.0)
    def zero(t): return 0.0 * t
    def fx(t): return np.where(t > 1.0, 0.5, 0.0)
    inputs = _kinematic(speed, zero, fx, zero)
    batch, events = _detect(*inputs)
    kinds = events[0]
    det = AccelSlipDetector(ROBOT.speed_ratio, ROBOT.encode_sampling_time)
    rows = [det.update_batch(*(np.array([c[i]]) for c in events)) for i in range(kinds.size)]
    stream = np.vstack(rows)[kinds == 1]
    np.testing.assert_array_equal(stream, batch)
    assert batch[:, 0].sum() > 10


@pytest.mark.parametrize("field, value", [("window", 0.0), ("gate", -1.0),
                                          ("lever_arm", (0.1,)), ("offset_std", math.nan),
                                          ("gap_periods", 1.0), ("relative_std", -0.1)])
def test_bad_parameters_are_refused_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        AccelSlipParams(**{field: value})


def test_the_gate_is_the_chi_square_quantile():
    from scipy.stats import chi2
    assert CHI2_2DOF_01PCT == pytest.approx(chi2.isf(1e-3, 2), rel=1e-12)
    assert AccelSlipParams().gate == CHI2_2DOF_01PCT


# -- the physics simulator: its tyre model says when the wheels slip ------------------------

def _straight_onto_ice(seed=1):
    """20 s: 3 s at rest, then 0.5 m/s straight ahead starting on a 3 s patch of mu = 0.05
    (the firmware's 1 m/s^2 ramp asks for more than the 0.31 m/s^2 friction gives: both
    wheels spin alike), vibration while driving."""
    mission = Mission((Segment("stop", 3.0, 0.0, 0.0), Segment("straight", 17.0, 0.5, 0.0)),
                      friction_patches=((2.8, 3.0, 0.05),))
    return simulate_physics(mission, with_errors(["vibration"], seed=seed), seed)


def _flags(run):
    c = run.robot.chassis
    codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    return accel_slip_flags(c.speed_ratio, c.encode_sampling_time, run.imu_t, run.accel[:, :2],
                            run.gyro[:, 2], codes, run.wheel_t, run.ticks), codes


def _truth_slip(run):
    """Per wheel frame: a tyre of the physics slid during its period."""
    T = run.robot.chassis.encode_sampling_time
    cs = np.concatenate([[0], np.cumsum(run.truth_slip)])
    return cs[np.searchsorted(run.truth_t, run.wheel_t_end)] > cs[
        np.searchsorted(run.truth_t, run.wheel_t_end - T)]


def test_straight_wheel_spin_on_ice_is_flagged_and_fused_as_a_slip():
    run = _straight_onto_ice()
    truth = _truth_slip(run)
    flags, codes = _flags(run)
    assert truth.sum() > 20  # the simulator's tyres slide
    # flagged while the tyres slide (or within one window after): no false alarm elsewhere
    window = round(0.4 / run.robot.chassis.encode_sampling_time)
    near = np.convolve(truth, np.ones(window + 1), mode="full")[:truth.size] > 0
    assert flags.sum() >= 10 and not (flags & ~near).any()
    # the wheels' yaw rates agree (both spin): the gyro gate alone lets the frames through
    c = run.robot.chassis
    plain, _ = fuse(c, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, imu_motion=codes)
    track, ekf = fuse(c, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, imu_motion=codes,
                      wheel_slip=flags)
    wheel = track.kind == core.EV_WHEELS
    assert plain.stats["slips"] == 0
    assert ekf.stats["accel_slips"] == flags.sum() == ekf.stats["slips"]
    np.testing.assert_array_equal(track.status[wheel] == 1, flags)


def test_no_false_alarm_while_driving_with_vibration_on_a_high_friction_floor():
    # 90 s of the indoor mission (straights, arcs, turns in place, stops) with the strongest
    # vibration of the acceptance scenarios; the tyres never reach the friction limit
    from dataclasses import replace
    mission = indoor_mission(seed=3, duration=90.0)
    sensors = replace(with_errors(["vibration", "mount-tilt"], seed=3), vibration_accel=2.5)
    run = simulate_physics(mission, sensors, seed=3)
    assert not _truth_slip(run).any()
    flags, _ = _flags(run)
    assert flags.sum() == 0


def test_the_pipeline_flag_reaches_the_slip_column():
    run = _straight_onto_ice(seed=2)
    truth = _truth_slip(run)
    out = {}
    for accel_slip in (True, False):
        buf = io.StringIO()
        pipe = FusionPipeline(RobotConfig(chassis=run.robot.chassis),
                              [JsonLinesSink(buf, flush=False)], accel_slip=accel_slip)
        with pipe:
            pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
        recs = [json.loads(line) for line in buf.getvalue().splitlines()]
        out[accel_slip] = (np.array([r["slip"] for r in recs]), pipe.finish_stats())
    slip, stats = out[True]
    assert slip.size == run.wheel_t.size  # one record per wheel frame
    assert stats.accel_slips >= 10 and slip.sum() == stats.slips
    window = round(0.4 / run.robot.chassis.encode_sampling_time)
    near = np.convolve(truth, np.ones(window + 1), mode="full")[:truth.size] > 0
    assert not (slip & ~near).any()
    # without the accelerometer test nothing sees the straight spin
    assert out[False][0].sum() == 0 and out[False][1].accel_slips == 0


def test_the_fused_csv_slip_column_carries_the_flag(tmp_path):
    # the pipeline with the test on, written as the fused CSV (one row per IMU sample, the
    # flags of the last wheel frame): slip rows appear only while the simulator's tyres slide
    # (or within a window after), and the pipeline counts them as the accelerometer's
    run = _straight_onto_ice(seed=4)
    chassis = run.robot.chassis
    with FusionPipeline(RobotConfig(chassis=chassis), sources=("imu", "wheels"),
                        state_rows=("imu",), accel_slip=True) as pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    stats = pipe.finish_stats()
    out = tmp_path / "fused.csv"
    write_fused_csv(out, fused_table(pipe.state_rows,
                                     chassis.speed_ratio / chassis.encode_sampling_time))
    f = read_fused_csv(out)
    slip = f["slip"] == 1.0
    assert stats.accel_slips >= 10 and slip.sum() >= 5 * stats.accel_slips
    slides = run.truth_t[run.truth_slip]
    assert slides.size > 0
    # every slip row lies within [first slide, last slide + window + one frame]
    t = f["t"][slip]
    assert t.min() >= slides.min() and t.max() <= slides.max() + 0.4 + 0.1
