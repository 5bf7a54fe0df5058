"""The physics simulator against physics and analytic oracles (short runs, seconds in total)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fusion.evaluation.physics_sim import (
    ERROR_GROUPS,
    BodyParams,
    ControllerParams,
    Mission,
    Segment,
    SensorModel,
    all_errors,
    circle_mission,
    indoor_mission,
    physics_scenario,
    plain_sensors,
    simulate_body,
    simulate_physics,
    with_errors,
)

G = 9.80665


def _fit_circle(x: np.ndarray, y: np.ndarray) -> float:
    """Radius of the least-squares circle through the points (algebraic fit)."""
    A = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    cx, cy, c = np.linalg.lstsq(A, x * x + y * y, rcond=None)[0]
    return float(math.sqrt(c + cx * cx + cy * cy))


@pytest.mark.parametrize(("v", "w"), [(0.4, 0.5), (0.3, -1.0)])
def test_constant_command_traces_a_circle_of_radius_v_over_w(v, w):
    # CoM on the axle: the tyres carry only the centripetal force sideways and no yaw moment,
    # so the path is the commanded one up to a lateral creep of m*v*w/k = 1e-3 m/s.
    body = BodyParams(com_ahead=0.0)
    tr = simulate_body(circle_mission(v, w, 20.0, settle=1.0), body)
    steady = tr.t > 8.0
    assert _fit_circle(tr.x[steady], tr.y[steady]) == pytest.approx(v / abs(w), rel=5e-4)
    assert tr.r[steady] == pytest.approx(w, rel=5e-4)
    assert not (tr.slip_l > 0).any() and not (tr.slip_r > 0).any()


def test_centre_of_mass_ahead_bends_the_circle_by_tyre_creep_only():
    # With the CoM d ahead of the axle the tyres must also cancel the yaw moment d*m*v*w,
    # a longitudinal creep of about d*m*v*w/(L*k) per wheel: 0.2 % of the path radius here.
    tr = simulate_body(circle_mission(0.4, 0.5, 20.0, settle=1.0))
    steady = tr.t > 8.0
    assert _fit_circle(tr.x[steady], tr.y[steady]) == pytest.approx(0.8, rel=5e-3)


def test_straight_run_at_commanded_speed_with_exact_geometry():
    tr = simulate_body(circle_mission(0.5, 0.0, 6.0))
    assert tr.u[-1] == pytest.approx(0.5, rel=1e-3)
    # the firmware ramp of 1 m/s^2 takes 0.5 s to reach 0.5 m/s: 0.125 m lost to the ramp
    assert tr.x[-1] == pytest.approx(0.5 * 6.0 - 0.125, abs=0.01)
    assert np.abs(tr.y).max() < 1e-9 and np.abs(tr.yaw).max() < 1e-9


def _launch(accel: float, mu: float):
    body = BodyParams(mu=mu)
    ctrl = ControllerParams(accel_limit=accel)
    mission = Mission((Segment("stop", 0.5, 0.0, 0.0), Segment("straight", 2.5, 1.0, 0.0)))
    tr = simulate_body(mission, body, ctrl)
    surface = 0.5 * (tr.spin_l + tr.spin_r) * body.wheel_radius
    return tr, np.abs(surface - tr.u).max()


def test_slip_only_when_the_commanded_acceleration_exceeds_traction():
    body = BodyParams()
    limit = body.traction_limit(0.2)  # mu * g * share of the weight on the driven wheels
    assert limit == pytest.approx(0.2 * G * (1 - 0.04 / 0.20))
    tr, creep = _launch(0.8 * limit, 0.2)
    assert not ((tr.slip_l > 0) | (tr.slip_r > 0)).any()
    assert creep < 0.01  # m/s: grip, the tyre only creeps
    tr, slide = _launch(1.2 * limit, 0.2)
    assert ((tr.slip_l > 0) & (tr.slip_r > 0)).any()
    assert slide > 0.05
    # while sliding the body accelerates at the traction limit, not at the commanded rate
    acc = np.gradient(tr.u, tr.t)[(tr.slip_l > 0) & (tr.t > 0.6)]
    assert np.median(acc) == pytest.approx(limit, rel=0.02)


def test_ticks_integrate_to_the_wheel_travel_within_one_count():
    sensors = SensorModel(encoder_ticks_per_rev=1024)
    # CoM on the axle: in the steady turn no tyre force along the wheels, so no creep
    run = simulate_physics(circle_mission(0.4, 0.6, 12.0, settle=1.0), sensors, seed=3,
                           body=BodyParams(com_ahead=0.0))
    per_rad = 1024 / (2 * math.pi)
    # ideal stamps: each frame's stamp is the end of its period (first period starts 40 ms
    # before the first stamp)
    t0, t1 = run.wheel_t[0] - 0.04, run.wheel_t[-1]
    for side, angle in enumerate((run.trace.angle_l, run.trace.angle_r)):
        counted = int(run.ticks[:, side].sum())
        true = (np.interp(t1, run.trace.t, angle) - np.interp(t0, run.trace.t, angle)) * per_rad
        assert abs(counted - true) < 1.0
    # the wheels roll without sliding: counts * speed_ratio = ground travel of each wheel,
    # within a count (0.3 mm) and the creep while the ramp accelerates the robot (about
    # m/2 * 1 m/s^2 / k = 2.7 mm/s for 0.4 s)
    L = run.trace.wheel_distance
    sel = (run.trace.t >= t0) & (run.trace.t < t1)
    for side, sign in ((0, -1.0), (1, 1.0)):
        ground = np.sum((run.trace.u + sign * 0.5 * L * run.trace.r)[sel]) * 1e-3
        travel = run.ticks[:, side].sum() * run.robot.chassis.speed_ratio
        assert travel == pytest.approx(ground, abs=1.5e-3)


def test_stationary_imu_reads_gravity_and_its_bias():
    mission = Mission((Segment("stop", 10.0, 0.0, 0.0),))
    ideal = simulate_physics(mission, SensorModel(), seed=0)
    assert np.linalg.norm(ideal.accel, axis=1) == pytest.approx(G, abs=1e-12)
    assert np.abs(ideal.gyro).max() == 0.0
    s = plain_sensors(4)
    run = simulate_physics(mission, s, seed=4)
    n = run.imu_t.size
    assert n == pytest.approx(10.0 * 200, abs=2)
    norm = np.linalg.norm(run.accel.mean(axis=0))
    assert abs(norm - G) <= math.sqrt(3) * 0.05 + 4 * 0.04 / math.sqrt(n)
    assert run.accel.mean(axis=0) == pytest.approx(np.add(s.accel_bias, [0, 0, G]),
                                                   abs=4 * 0.04 / math.sqrt(n))
    assert run.gyro.mean(axis=0) == pytest.approx(s.gyro_bias, abs=4 * 7e-4 / math.sqrt(n))
    assert run.gyro.std(axis=0) == pytest.approx([7e-4] * 3, rel=0.1)


def test_stationary_gyro_shows_temperature_drift_and_g_sensitivity():
    s = replace(with_errors(["temperature", "g-sensitivity"], seed=2), temperature_tau=20.0)
    run = simulate_physics(Mission((Segment("stop", 60.0, 0.0, 0.0),)), s, seed=2)
    Gm = np.array(s.gyro_g_sensitivity).reshape(3, 3)
    for t0 in (0.0, 50.0):
        sel = (run.imu_t >= t0) & (run.imu_t < t0 + 10.0)
        T = s.temperature_end - (s.temperature_end - 25.0) * np.exp(-(t0 + 5.0) / 20.0)
        expected = np.array(s.gyro_bias) + np.array(s.gyro_bias_tempco) * (T - 25.0) \
            + Gm[:, 2] * G
        # the bias drifts within the 10 s window: allow its change over 5 s plus noise
        drift = np.abs(np.array(s.gyro_bias_tempco)) * (s.temperature_end - 25.0) * \
            (np.exp(-t0 / 20.0) - np.exp(-(t0 + 10) / 20.0)) / 2
        assert run.gyro[sel].mean(axis=0) == pytest.approx(expected, abs=drift.max() + 1e-4)


def test_vibration_scales_with_speed():
    s = with_errors(["vibration"], seed=1)
    mission = Mission((Segment("straight", 6.0, 0.25, 0.0), Segment("straight", 6.0, 0.5, 0.0)))
    run = simulate_physics(mission, s, seed=1)
    slow = (run.imu_t > 2.0) & (run.imu_t < 5.5)
    fast = run.imu_t > 8.0
    ratio = run.accel[fast, 0].std() / run.accel[slow, 0].std()
    assert ratio == pytest.approx(2.0, rel=0.15)
    assert run.accel[fast, :2].std(axis=0).max() > 0.5  # m/s^2: of order 1 while driving


def test_dead_encoder_window_gives_zero_ticks_exactly_there():
    run = physics_scenario("all+dead", seed=5, duration=120.0, dead_encoder=8.0)
    (start, duration), = run.dead_windows()
    s = run.sensors
    # the robot drives throughout the window
    sel = (run.truth_t >= start) & (run.truth_t < start + duration)
    assert np.abs(run.truth_v[sel]).min() > 0.1
    # frames of a driving robot with zero ticks on both wheels: exactly those whose period
    # ended inside the window (host stamp = period end + latency + jitter below 5 sigma)
    driving = np.abs(np.interp(run.wheel_t, run.truth_t, run.truth_v)) > 0.05
    zero = (run.ticks == 0).all(axis=1) & driving
    end = run.wheel_t - s.wheel_latency
    surely_in = (end - 5 * s.wheel_jitter >= start) & (end < start + duration)
    surely_out = (end < start) | (end - 5 * s.wheel_jitter >= start + duration)
    assert zero[surely_in].all()
    assert not zero[surely_out].any()
    assert zero.sum() >= round(duration / 0.04) * 0.95  # 1 % of the frames are lost
    assert np.array_equal(zero, run.wheel_dead & driving)


def test_same_seed_same_run_other_seed_other_run():
    a = physics_scenario("all", seed=7, duration=40.0)
    b = physics_scenario("all", seed=7, duration=40.0)
    c = physics_scenario("all", seed=8, duration=40.0)
    for name in ("imu_t", "gyro", "accel", "wheel_t", "ticks", "truth"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(a.truth, c.truth)
    assert a.sensors == b.sensors != c.sensors


def test_moving_start_begins_in_steady_motion():
    run = simulate_physics(indoor_mission(1, 30.0, moving_start=True), seed=1)
    first = run.truth_t < 2.0
    assert run.truth_v[first] == pytest.approx(0.4, abs=1e-3)
    assert run.ticks[0].min() > 0


def test_stamps_increase_and_carry_the_latency():
    s = with_errors(["stamps", "frame-loss"], seed=0)
    run = simulate_physics(indoor_mission(0, 40.0), s, seed=0)
    assert (np.diff(run.imu_t) > 0).all() and (np.diff(run.wheel_t) > 0).all()
    for delay, latency, jitter in ((run.wheel_t - run.wheel_t_end, s.wheel_latency,
                                    s.wheel_jitter),
                                   (run.imu_t - run.imu_t_true, s.imu_latency, s.imu_jitter)):
        assert delay.min() >= latency
        # half-normal jitter: mean sigma*sqrt(2/pi), standard deviation sigma*sqrt(1 - 2/pi)
        sd = jitter * math.sqrt(1 - 2 / math.pi) / math.sqrt(delay.size)
        assert delay.mean() == pytest.approx(latency + jitter * math.sqrt(2 / math.pi),
                                             abs=4 * sd)
    periods = np.round(np.diff(run.wheel_t_end) / 0.04)
    assert (periods >= 1).all() and (periods > 1).sum() > 0  # 1 % of the frames lost
    assert run.ticks.shape[0] == pytest.approx(40.0 / 0.04 * (1 - s.wheel_frame_loss), rel=0.03)


def test_indoor_mission_shape():
    m = indoor_mission(3, 300.0, low_friction=True)
    assert m.duration == pytest.approx(300.0)
    kinds = {s.kind for s in m.segments}
    assert {"stop", "straight", "arc", "spin"} <= kinds
    assert m.segments[0].kind == "stop" and m.segments[-1].kind == "stop"
    assert len(m.friction_patches) == 3
    assert m == indoor_mission(3, 300.0, low_friction=True)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="wheel_radius"):
        BodyParams(wheel_radius=0.0)
    with pytest.raises(ValueError, match="wheel_frame_loss"):
        SensorModel(wheel_frame_loss=1.0)
    with pytest.raises(ValueError, match="unknown sensor error"):
        with_errors(["gyro-scael"])
    with pytest.raises(ValueError, match="scenario"):
        physics_scenario("everything")
    assert all_errors(1).separation_error != 0.0


def test_gyro_scale_and_cross_axis_on_a_spin():
    s = replace(SensorModel(), gyro_scale=(0.0, 0.0, 0.02), gyro_cross_axis=(0, 0, 0, 0, 0, 0))
    run = simulate_physics(circle_mission(0.0, 1.2, 6.0), s, seed=0)
    steady = run.imu_t > 2.0
    true_w = np.interp(run.imu_t[steady], run.truth_t, run.truth_w)
    assert true_w == pytest.approx(1.2, rel=1e-3)
    assert run.gyro[steady, 2] == pytest.approx(1.02 * true_w, rel=1e-6, abs=1e-9)
    s = replace(SensorModel(), gyro_cross_axis=(0, 0.01, 0, -0.02, 0, 0))
    run = simulate_physics(circle_mission(0.0, 1.2, 6.0), s, seed=0)
    true_w = np.interp(run.imu_t[steady], run.truth_t, run.truth_w)
    assert run.gyro[steady, 0] == pytest.approx(0.01 * true_w, rel=1e-6)
    assert run.gyro[steady, 1] == pytest.approx(-0.02 * true_w, rel=1e-6)


def test_mount_tilt_rotates_gravity_like_scipy():
    from scipy.spatial.transform import Rotation

    rpy = (math.radians(1.2), math.radians(-0.8), math.radians(30.0))
    run = simulate_physics(Mission((Segment("stop", 2.0, 0.0, 0.0),)),
                           SensorModel(mount_rpy=rpy), seed=0)
    # URDF rpy = fixed-axis x, y, z rotations taking IMU vectors into the base frame
    expected = Rotation.from_euler("xyz", rpy).inv().apply([0.0, 0.0, G])
    assert run.accel == pytest.approx(np.tile(expected, (run.imu_t.size, 1)), abs=1e-12)



def test_every_error_group_together_is_all_errors():
    assert with_errors(list(ERROR_GROUPS), seed=3) == all_errors(3)
