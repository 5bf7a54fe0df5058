"""Wheel and twist odometry against analytic paths (line, circle) and a Monte Carlo oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.odometry import (
    OdometryNoise,
    TwistOdometry,
    WheelOdometry,
    integrate_wheel_travel,
    wrap_angle,
)

# Circle of radius R = 0.5 m: left wheel 400 ticks, right 600 ticks of 1e-5 m per period:
# dl = 4 mm, dr = 6 mm, d = 5 mm, dtheta = 2 mm / L.
RATIO = 1e-5
DL, DR = 400, 600


def circle_params(n_per_turn: int) -> DiffDriveParams:
    # choose L so that n_per_turn periods make exactly one turn: dtheta = 2 pi / n
    L = (DR - DL) * RATIO * n_per_turn / (2 * math.pi)
    return DiffDriveParams(wheel_distance=L, speed_ratio=RATIO, encode_sampling_time=0.04)


@pytest.mark.parametrize("method", ["midpoint", "arc", "euler"])
def test_straight_line(method):
    p = DiffDriveParams(wheel_distance=0.2, speed_ratio=1e-4, encode_sampling_time=0.04)
    odo = WheelOdometry(p, method=method)
    for _ in range(100):
        st = odo.update(100, 100)  # 1 cm per period
    assert st.x == pytest.approx(1.0, abs=1e-12)
    assert st.y == 0.0 and st.theta == 0.0
    assert st.v == pytest.approx(0.25)  # 0.01 m / 0.04 s
    assert st.w == 0.0
    assert st.vl == pytest.approx(0.25) and st.vr == pytest.approx(0.25)
    assert st.distance == pytest.approx(1.0)


def test_exact_arc_lands_on_circle():
    n = 360
    p = circle_params(n)
    dth = 2 * math.pi / n
    R = 0.5 * (DL + DR) * RATIO / dth  # d / dtheta
    odo = WheelOdometry(p, method="arc")
    for k in range(1, n + 1):
        st = odo.update(DL, DR)
        th = k * dth
        # centre (0, R): x = R sin th, y = R (1 - cos th)
        assert st.x == pytest.approx(R * math.sin(th), abs=1e-12)
        assert st.y == pytest.approx(R * (1 - math.cos(th)), abs=1e-12)
        assert st.theta == pytest.approx(th, abs=1e-12)
    # a whole turn comes back to the origin
    assert abs(st.x) < 1e-12 and abs(st.y) < 1e-12
    assert st.yaw == pytest.approx(0.0, abs=1e-12)
    assert st.w == pytest.approx(dth / 0.04)


def test_midpoint_rule_known_error():
    n = 36  # coarse: 10 deg per period makes the error visible
    p = circle_params(n)
    dth = 2 * math.pi / n
    d = 0.5 * (DL + DR) * RATIO
    R = d / dth
    a = dth / 2
    sinc = math.sin(a) / a
    left = np.full(n, DL)
    right = np.full(n, DR)
    arc = WheelOdometry(p, method="arc").update_batch(left, right)
    mid = WheelOdometry(p, method="midpoint").update_batch(left, right)
    # the midpoint rule walks the same directions with chord d instead of d*sinc(dth/2):
    # every position is the exact one scaled by 1/sinc about the start
    np.testing.assert_allclose(mid[:, :2], arc[:, :2] / sinc, atol=1e-13)
    np.testing.assert_allclose(mid[:, 2], arc[:, 2], atol=1e-13)
    # so it sits on a circle of radius R/sinc: radial error R*(1/sinc - 1) about (0, R/sinc)
    r_mid = np.hypot(mid[:, 0], mid[:, 1] - R / sinc)
    np.testing.assert_allclose(r_mid, R / sinc, rtol=1e-12)
    err = np.hypot(mid[:, 0] - arc[:, 0], mid[:, 1] - arc[:, 1])
    # the error per period is d*dth^2/24 to leading order, and it never exceeds 2R(1/sinc - 1)
    assert err.max() <= 2 * R * (1 / sinc - 1) + 1e-12
    assert err[0] == pytest.approx(d * dth**2 / 24, rel=0.01)


def test_euler_is_midpoint_rotated_back():
    n = 36
    p = circle_params(n)
    dth = 2 * math.pi / n
    left, right = np.full(n, DL), np.full(n, DR)
    mid = WheelOdometry(p, method="midpoint").update_batch(left, right)
    eul = WheelOdometry(p, method="euler").update_batch(left, right)
    c, s = math.cos(-dth / 2), math.sin(-dth / 2)
    rot = np.column_stack([c * mid[:, 0] - s * mid[:, 1], s * mid[:, 0] + c * mid[:, 1]])
    np.testing.assert_allclose(eul[:, :2], rot, atol=1e-13)


def test_batch_equals_streaming_and_split_run():
    rng = np.random.default_rng(1)
    left = rng.integers(-3000, 3000, 500)
    right = rng.integers(-3000, 3000, 500)
    p = DiffDriveParams(wheel_distance=0.23, speed_ratio=7.3e-5)
    for method in ("midpoint", "arc", "euler"):
        a = WheelOdometry(p, method=method)
        stream = np.array([[*(lambda s: (s.x, s.y, s.theta))(a.update(l, r))]
                           for l, r in zip(left, right)])
        b = WheelOdometry(p, method=method)
        batch = b.update_batch(left, right)
        np.testing.assert_array_equal(batch, stream)
        np.testing.assert_array_equal(a.state.cov, b.state.cov)
        assert a.state.distance == pytest.approx(b.state.distance, rel=1e-13)
        # split run: first half, save, restore into a new object, second half
        c = WheelOdometry(p, method=method)
        c.update_batch(left[:200], right[:200])
        saved = c.get_state()
        c.update(1, 2)  # mutate, then restore
        d = WheelOdometry(p, method=method, state=saved)
        second = d.update_batch(left[200:], right[200:])
        np.testing.assert_array_equal(second, batch[200:])
        np.testing.assert_array_equal(d.state.cov, b.state.cov)


def test_integrate_wheel_travel_matches_class():
    p = DiffDriveParams(wheel_distance=0.2, speed_ratio=1e-4)
    left, right = np.arange(50), np.arange(50)[::-1] * 2
    poses = integrate_wheel_travel(left * 1e-4, right * 1e-4, 0.2, method="arc")
    # vectorised numpy vs the scalar core: equal up to the last bits of sin/cos
    np.testing.assert_allclose(poses, WheelOdometry(p, "arc").update_batch(left, right),
                               rtol=1e-13, atol=1e-15)


def test_covariance_straight_line_analytic():
    k = 1e-4
    L = 0.2
    p = DiffDriveParams(wheel_distance=L, speed_ratio=1e-4)
    odo = WheelOdometry(p, noise=OdometryNoise(k_wheel=k, k_turn=0.0))
    n, ticks = 100, 100
    for _ in range(n):
        odo.update(ticks, ticks)
    d = ticks * 1e-4
    P = odo.state.cov
    # per period var(dl) = var(dr) = k*d: var(d) = k*d/2, var(dth) = 2*k*d/L^2
    assert P[0, 0] == pytest.approx(n * k * d / 2, rel=1e-12)  # x: along-track
    assert P[2, 2] == pytest.approx(n * 2 * k * d / L**2, rel=1e-12)  # heading random walk
    # y: heading error integrated along the run; the linearised recursion written out by hand
    # (F: y += d*theta, G: y += (d/2)*dth, theta += dth, with var(dth) = 2*k*d/L^2)
    var_th = 2 * k * d / L**2
    Pyy = 0.0
    Pyt = 0.0
    Ptt = 0.0
    for _ in range(n):
        # F: y += d*theta (linearised), G: y += (d/2)*dth, theta += dth
        Pyy = Pyy + 2 * d * Pyt + d * d * Ptt + (d / 2) ** 2 * var_th
        Pyt = Pyt + d * Ptt + (d / 2) * var_th
        Ptt = Ptt + var_th
    assert P[1, 1] == pytest.approx(Pyy, rel=1e-12)
    assert np.all(np.linalg.eigvalsh(P) >= -1e-18)


def test_covariance_grows_with_distance_and_turning_not_at_rest():
    p = DiffDriveParams(wheel_distance=0.2, speed_ratio=1e-4)
    odo = WheelOdometry(p)
    odo.update(0, 0)
    assert np.all(odo.state.cov == 0.0)
    traces = []
    for _ in range(20):
        odo.update(100, 100)
        traces.append(np.trace(odo.state.cov))
    assert np.all(np.diff(traces) > 0)
    # turning in place: heading variance grows although the midpoint does not move
    spin = WheelOdometry(p, noise=OdometryNoise(k_wheel=0.0, k_turn=1e-3))
    for _ in range(100):
        spin.update(-100, 100)  # dth = 0.02/0.2 = 0.1 rad per period
    assert spin.state.theta == pytest.approx(10.0)
    assert spin.state.cov[2, 2] == pytest.approx(1e-3 * 10.0, rel=1e-12)
    assert spin.state.cov[0, 0] == 0.0 and spin.state.x == 0.0


def test_covariance_matches_monte_carlo():
    """Propagated covariance vs the sample covariance of 4000 noisy runs along a curve."""
    k = 1e-6  # small noise keeps the linearisation honest
    L = 0.25
    p = DiffDriveParams(wheel_distance=L, speed_ratio=1e-4)
    n = 60
    left = np.linspace(50, 150, n)
    right = np.linspace(150, 60, n)
    odo = WheelOdometry(p, method="arc", noise=OdometryNoise(k_wheel=k, k_turn=0.0))
    odo.update_batch(left, right)
    P = odo.state.cov
    rng = np.random.default_rng(7)
    dl, dr = left * 1e-4, right * 1e-4
    ends = []
    for _ in range(4000):
        nl = dl + rng.normal(size=n) * np.sqrt(k * np.abs(dl))
        nr = dr + rng.normal(size=n) * np.sqrt(k * np.abs(dr))
        ends.append(integrate_wheel_travel(nl, nr, L, method="arc")[-1])
    S = np.cov(np.array(ends).T)
    # sample variances of 4000 draws have relative sd ~ sqrt(2/4000) = 2.2 %: allow 10 %
    np.testing.assert_allclose(np.diag(P), np.diag(S), rtol=0.10)
    corr_p = P[0, 1] / math.sqrt(P[0, 0] * P[1, 1])
    corr_s = S[0, 1] / math.sqrt(S[0, 0] * S[1, 1])
    assert corr_p == pytest.approx(corr_s, abs=0.05)


def test_twist_odometry_seed004_reference():
    # the seed's loop, written out: x += v cos(th) dt; y += v sin(th) dt; th += w dt
    v, w, dt = 0.3, 0.8, 0.02
    x = y = th = 0.0
    odo = TwistOdometry(wheel_distance=0.2, dt=dt)
    for _ in range(200):
        x += v * math.cos(th) * dt
        y += v * math.sin(th) * dt
        th += w * dt
        st = odo.update_twist(v, w)
    assert st.x == pytest.approx(x, abs=1e-12)
    assert st.y == pytest.approx(y, abs=1e-12)
    assert st.theta == pytest.approx(th, abs=1e-12)
    assert st.v == v and st.w == w
    # the exact arc option lands on the circle of radius v/w
    arc = TwistOdometry(wheel_distance=0.2, dt=dt, method="arc")
    for _ in range(200):
        s2 = arc.update_twist(v, w)
    R, T = v / w, 200 * dt * w
    assert s2.x == pytest.approx(R * math.sin(T), abs=1e-12)
    assert s2.y == pytest.approx(R * (1 - math.cos(T)), abs=1e-12)
    assert not hasattr(odo, "update")  # ticks have no meaning for a twist source


def test_wrap_and_errors():
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    p = DiffDriveParams(0.2, 1e-4)
    with pytest.raises(ValueError, match="method"):
        WheelOdometry(p, method="rk4")
    with pytest.raises(ValueError, match="k_wheel"):
        OdometryNoise(k_wheel=-1.0)
    with pytest.raises(ValueError, match="same length"):
        WheelOdometry(p).update_batch([1, 2], [1])
    with pytest.raises(ValueError, match="dt"):
        TwistOdometry(0.2).update_twist(0.1, 0.0, dt=0.0)
