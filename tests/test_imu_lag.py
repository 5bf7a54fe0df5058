"""The IMU's lag behind the odometry's stamps (fusion.calibration.time_offset) and what a
replay does with it (fusion.jobs.imu_lag), against lags injected into analytic yaw rates.

The rates are a sum of sines at incommensurate periods (no single period to alias onto) with
a gyro that has a bias, a 3 % scale error, noise and its own axes (a mount rolled and yawed):
the injected lag is the reference. The replays of recorded-shaped data (the terrain bag, the
black-box simulator's logs) are in test_terrain_bag.py and test_blackbox_replay.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.calibration.time_offset import MAX_LAG, estimate_imu_lag
from fusion.cli import main
from fusion.geometry.kinematics import DiffDriveParams
from fusion.jobs.imu_lag import LAG_LIMIT, choose_imu_lag, lag_limit, shifted
from fusion.jobs.streams import Streams

CHASSIS = DiffDriveParams(wheel_distance=0.5, speed_ratio=1e-4, encode_sampling_time=0.02)
PERIODS = (7.3, 11.9, 23.1, 41.7)  # s


def yaw_rate(t):
    """rad/s: the robot's turning, up to about 1 rad/s."""
    t = np.asarray(t, dtype=float)
    return sum(0.25 * np.sin(2 * math.pi * t / p + k) for k, p in enumerate(PERIODS))


def imu_late(lag, *, span=300.0, rate=100.0, mount=(0.0, 0.0, 0.0), seed=1, late_from=None,
             lag2=None):
    """IMU samples stamped ``lag`` s late (``lag2`` from stamp ``late_from`` on): (t, gyro,
    accel) in a mount given as URDF rpy (rad) taking IMU vectors to the base."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, span, 1.0 / rate)
    lags = np.full(t.size, float(lag))
    if late_from is not None:
        lags[t >= late_from] = lag2
    base = np.zeros((t.size, 3))
    base[:, 2] = 1.03 * yaw_rate(t - lags) + math.radians(0.5)
    base[:, :2] = rng.normal(0.0, 0.02, (t.size, 2))  # pitching and rolling
    base += rng.normal(0.0, 0.005, base.shape)
    to_imu = Rotation.from_euler("xyz", mount).inv()
    gravity = np.tile([0.0, 0.0, 9.81], (t.size, 1)) + rng.normal(0.0, 0.3, (t.size, 3))
    return t, to_imu.apply(base), to_imu.apply(gravity)


def odometry(rate=20.0, span=300.0, seed=2):
    rng = np.random.default_rng(seed)
    s = np.arange(0.0, span, 1.0 / rate)
    return s, yaw_rate(s) + rng.normal(0.0, 0.02, s.size)


@pytest.mark.parametrize("lag", [-0.7, 0.0, 0.25, 1.3, 2.6])
def test_the_injected_lag_is_found_to_5_ms(lag):
    t, gyro, accel = imu_late(lag)
    s, w = odometry()
    est = estimate_imu_lag(t, gyro, accel.mean(axis=0), s, w)
    assert est is not None
    assert abs(est.lag - lag) < 0.005, est
    # four whole pieces of 60 s in the just under 300 s the streams share
    assert est.correlation > 0.95 and len(est.piece_lags) == 4 and est.spread < 0.01


def test_a_mount_rolled_over_and_yawed_gives_the_same_lag():
    # the real outdoor bag's mount: the yaw rate is the IMU's y axis, read through the
    # accelerometer's up; an IMU upside down as well
    s, w = odometry()
    for mount in ((math.pi / 2, 0.0, -math.pi / 2), (math.pi, 0.0, 0.3)):
        t, gyro, accel = imu_late(0.4, mount=mount)
        est = estimate_imu_lag(t, gyro, accel.mean(axis=0), s, w)
        assert est is not None and abs(est.lag - 0.4) < 0.005, (mount, est)


def test_no_lag_without_turns_or_without_a_relation():
    t, gyro, accel = imu_late(0.3)
    s, w = odometry()
    up = accel.mean(axis=0)
    # a robot that drove straight: nothing to line up
    assert estimate_imu_lag(t, gyro, up, s, np.zeros_like(w)) is None
    # an odometry that does not follow the gyro at any lag (another robot's)
    other = np.random.default_rng(5).normal(0.0, 0.5, s.size)
    assert estimate_imu_lag(t, gyro, up, s, other) is None
    # streams that share less than four times the lags searched
    short = s < 3.0 * MAX_LAG
    assert estimate_imu_lag(t, gyro, up, s[short], w[short]) is None


def _streams(t, gyro, accel, s, w):
    return Streams(t, gyro, accel, twist_t=s, twist_v=np.full(s.size, 0.5), twist_w=w)


def _moved(choice):
    """(lag, note) of a LagChoice."""
    return choice.lag, choice.note


def test_a_replay_moves_a_clear_lag_and_leaves_a_small_one():
    s, w = odometry()
    streams = _streams(*imu_late(0.45), s, w)
    assert lag_limit(streams) == pytest.approx(LAG_LIMIT)  # 20 Hz: two intervals, 0.1 s
    lag, note = _moved(choose_imu_lag(streams, CHASSIS))
    assert abs(lag - 0.45) < 0.005
    assert f"ran {lag:.3f} s behind the odometry's" in note and "--imu-lag 0" in note
    moved = shifted(streams, lag)
    assert np.allclose(moved.imu_t, streams.imu_t - lag) and moved.twist_t is streams.twist_t
    assert _moved(choose_imu_lag(moved, CHASSIS)) == (0.0, "")  # nothing left to move
    # early IMU stamps, said so
    lag, note = _moved(choose_imu_lag(_streams(*imu_late(-0.3), s, w), CHASSIS))
    assert abs(lag + 0.3) < 0.005 and "ahead of" in note
    # within the limit: what a twist's interval mean looks like; left alone, nothing said
    assert _moved(choose_imu_lag(_streams(*imu_late(0.06), s, w), CHASSIS)) == (0.0, "")


def test_wheel_frames_are_expected_half_a_period_early():
    # wheel frames at 25 Hz, each the mean rate over the 40 ms it closes (what ticks are),
    # stamped at its end: on time, the estimate reads the IMU 20 ms early, which is no lag;
    # 0.3 s late, the lag moved is 0.3 s
    rng = np.random.default_rng(3)
    period, m_per_tick = 0.04, 1e-4
    ends = np.arange(period, 300.0, period)
    angle = np.array([quad_turn(e - period, e) for e in ends])  # rad turned in each period
    d = 0.5 * CHASSIS.wheel_distance * angle / m_per_tick  # ticks each wheel apart
    ticks = np.column_stack([200 - d, 200 + d]).round().astype(np.int64)
    chassis = DiffDriveParams(wheel_distance=CHASSIS.wheel_distance, speed_ratio=m_per_tick,
                              encode_sampling_time=period)
    for lag in (0.0, 0.3):
        t, gyro, accel = imu_late(lag, seed=int(rng.integers(100)))
        choice = choose_imu_lag(Streams(t, gyro, accel, ends, ticks), chassis)
        assert choice.estimate is not None
        assert abs(choice.estimate.lag - (lag - 0.5 * period)) < 0.006, choice.estimate
        assert abs(choice.lag - lag) < 0.006 if lag else choice.lag == 0.0


def quad_turn(t0, t1):
    """rad: the integral of :func:`yaw_rate` from ``t0`` to ``t1`` s."""
    x = np.linspace(t0, t1, 9)
    return float(np.trapezoid(yaw_rate(x), x))


def test_the_limit_grows_with_a_slow_stream():
    # a 5 Hz odometry: its twists are means over 0.2 s; a lag of 0.3 s is within two of them
    s, w = odometry(rate=5.0)
    streams = _streams(*imu_late(0.3), s, w)
    assert lag_limit(streams) == pytest.approx(0.4)
    assert _moved(choose_imu_lag(streams, CHASSIS)) == (0.0, "")


def test_pieces_that_disagree_leave_the_stamps_and_say_so():
    # the IMU's driver restarted at 150 s with another lag: no one lag fits the run
    s, w = odometry()
    streams = _streams(*imu_late(0.3, late_from=150.0, lag2=1.5), s, w)
    choice = choose_imu_lag(streams, CHASSIS)
    assert choice.lag == 0.0 and "do not keep one lag" in choice.note
    assert "not moved" in choice.note
    # pieces of 60 s: two before the restart, one across it, one after
    lags = choice.estimate.piece_lags
    assert len(lags) == 4 and np.allclose(lags[:2], 0.3, atol=0.01)
    assert abs(lags[3] - 1.5) < 0.01
    assert ", ".join(f"{x:+.3f}" for x in lags) in choice.note
    # -0.4 s, then +0.4 s: on the whole run about 0, which alone would pass as on time
    streams = _streams(*imu_late(-0.4, late_from=150.0, lag2=0.4), s, w)
    lag, note = _moved(choose_imu_lag(streams, CHASSIS))
    assert lag == 0.0 and "do not keep one lag" in note


def test_a_run_too_short_for_two_pieces_is_not_moved():
    # 50 s (pieces of 20 s: two would fit, but the first 20 s turn too little here)
    s, w = odometry(span=50.0)
    t, gyro, accel = imu_late(0.5, span=50.0)
    w = np.where(s < 22.0, 0.0, w)
    gyro[t < 22.5, 2] = math.radians(0.5)  # standing: the bias alone
    lag, note = _moved(choose_imu_lag(_streams(t, gyro, accel, s, w), CHASSIS))
    assert lag == 0.0 and "too short or turned too little" in note
    assert "--imu-lag 0.5" in note


def test_a_lag_beyond_the_search_is_no_estimate():
    # 3.5 s late: the best lag within +-3 s is its edge, which says nothing
    s, w = odometry()
    t, gyro, accel = imu_late(3.5)
    assert estimate_imu_lag(t, gyro, accel.mean(axis=0), s, w) is None
    assert _moved(choose_imu_lag(_streams(t, gyro, accel, s, w), CHASSIS)) == (0.0, "")


def test_a_steady_weave_is_not_lined_up_against_its_mirror_image():
    # a slalom at one 4 s period, 0.8 s late: half a period away the rates are each other's
    # negative; the correlation is signed, so the lag found is 0.8 s, not -1.2
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 300.0, 0.01)
    s = np.arange(0.0, 300.0, 0.05)
    gyro = np.zeros((t.size, 3))
    gyro[:, 2] = 0.8 * np.sin(2 * math.pi * (t - 0.8) / 4.0) + rng.normal(0, 0.01, t.size)
    accel = np.tile([0.0, 0.0, 9.81], (t.size, 1))
    w = 0.8 * np.sin(2 * math.pi * s / 4.0)
    est = estimate_imu_lag(t, gyro, accel.mean(axis=0), s, w)
    assert est is not None and abs(est.lag - 0.8) < 0.005, est


@pytest.mark.parametrize("lag", [0.3, 1.0, 2.0])
def test_without_gravity_the_axis_that_turns_is_found(lag):
    # an accelerometer that reads zero (a bag whose driver has none): the gyro's turning
    # axis is the one that lines up best with the odometry at some lag, here -y
    s, w = odometry()
    t, gyro, accel = imu_late(lag, mount=(math.pi / 2, 0.0, 0.0))
    lag_found, note = _moved(choose_imu_lag(_streams(t, gyro, 0.0 * accel, s, w), CHASSIS))
    assert abs(lag_found - lag) < 0.005 and "behind" in note


def test_a_given_lag_is_taken_as_it_is():
    s, w = odometry()
    streams = _streams(*imu_late(0.45), s, w)
    assert _moved(choose_imu_lag(streams, CHASSIS, 0.0)) == (0.0, "")  # --imu-lag 0
    lag, note = _moved(choose_imu_lag(streams, CHASSIS, 0.2))
    assert lag == 0.2 and "-0.200 s" in note and "--imu-lag" in note
    with pytest.raises(ValueError, match="finite"):
        choose_imu_lag(streams, CHASSIS, math.nan)
    with pytest.raises(ValueError, match="no IMU samples to move"):
        choose_imu_lag(Streams(twist_t=s, twist_v=w, twist_w=w), CHASSIS, 0.2)


def test_the_command_line_refuses_a_lag_that_is_not_a_number(capsys):
    with pytest.raises(SystemExit) as info:
        main(["replay", "x.bag", "-o", "out.csv", "--imu-lag", "late"])
    assert info.value.code == 2
    assert "expected s (e.g. 0.25) or 'auto', got 'late'" in capsys.readouterr().err


@pytest.mark.parametrize("seed", [0, 1])
def test_slipping_wheels_do_not_pass_for_a_driver_restart(seed):
    # The physics simulator stamps both streams on time, but its wheels slip (low friction):
    # one 22 s piece of these 90 s runs peaks 0.08-0.13 s away from the rest, where the run's
    # lag fits it almost as well (correlation 0.948 against 0.959 on seed 0). Before, that
    # said "do not keep one lag ... a driver restarted" on clean logs.
    from fusion.evaluation.physics_sim import physics_scenario

    run = physics_scenario("all", seed=seed, duration=90.0)
    streams = Streams(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    choice = choose_imu_lag(streams, run.robot.chassis)
    est = choice.estimate
    # the case: pieces that differ by more than the lag never moved, fitting the run's lag
    assert est.spread > lag_limit(streams)
    assert min(est.piece_fits) > 0.9
    assert choice.lag == 0.0 and choice.note == ""


@pytest.mark.parametrize("late", [0.5, 1.0])
def test_a_restart_on_a_noisy_odometry_is_not_moved_by_the_mean(late):
    # A review's case: the restart from on time to `late` s late at 150 s, with 0.1 rad/s of
    # white noise on the 20 Hz odometry's yaw rate. The noise flattens how much worse the
    # run's lag fits each piece (the z test alone passed it), and every stamp was moved by
    # the mean lag, the first half's good ones too.
    s, w = odometry()
    w = w + np.random.default_rng(9).normal(0.0, 0.1, w.size)
    choice = choose_imu_lag(_streams(*imu_late(0.0, late_from=150.0, lag2=late), s, w), CHASSIS)
    assert choice.lag == 0.0 and "do not keep one lag" in choice.note
    lags = choice.estimate.piece_lags
    assert abs(lags[0]) < 0.02 and abs(lags[-1] - late) < 0.02
