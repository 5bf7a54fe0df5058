"""fusion.geometry.dead_reckoning: one step of a differential-drive robot.

Oracles: a straight line, the exact geometry of a circle (centre, radius, swept angle), the
midpoint rule's known chord error, mpmath for the arc factor, and N scalar steps for the
vectorised form (bit for bit).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.geometry.dead_reckoning import (
    RULES,
    SMALL_ANGLE,
    arc_factor,
    increments,
    integrate,
    step,
    step_terms,
    wheel_motion,
)


def circle_end(pose0, radius, dtheta):
    """End pose after sweeping ``dtheta`` on a circle of signed ``radius`` (left turn > 0)."""
    x0, y0, th0 = pose0
    cx, cy = x0 - radius * math.sin(th0), y0 + radius * math.cos(th0)
    th1 = th0 + dtheta
    return cx + radius * math.sin(th1), cy - radius * math.cos(th1), th1


@pytest.mark.parametrize("rule", RULES)
def test_straight_line(rule):
    x, y, th = step(1.0, -2.0, 0.3, 0.5, 0.0, rule)
    assert (x, y, th) == pytest.approx((1.0 + 0.5 * math.cos(0.3), -2.0 + 0.5 * math.sin(0.3),
                                        0.3), abs=1e-15)
    poses = integrate(np.full(10, 0.1), np.zeros(10), (0.0, 0.0, -1.0), rule)
    np.testing.assert_allclose(poses[-1], [math.cos(-1.0), math.sin(-1.0), -1.0], atol=1e-15)


@pytest.mark.parametrize("dtheta", [3.0, 1.0, -0.7, 0.1, 1e-3, -4e-4, 2.1e-4, 1.9e-4, 1e-4,
                                    -5e-5, 1e-6])
def test_arc_rule_is_exact_circle_geometry(dtheta):
    # radii 0.3 .. 3000 m; with d = 3 mm the smallest angles fall below SMALL_ANGLE
    d = 0.003 if abs(dtheta) < 1e-2 else 0.3
    radius = d / dtheta
    pose0 = (0.4, -1.1, 2.5)
    ex, ey, eth = circle_end(pose0, radius, dtheta)
    x, y, th = step(*pose0, d, dtheta, "arc")
    # the circle formula itself rounds at the scale of the radius: |R| * 2 eps
    tol = 4e-16 * max(1.0, abs(radius))
    assert x == pytest.approx(ex, abs=tol) and y == pytest.approx(ey, abs=tol)
    assert th == eth


def test_midpoint_and_euler_errors_against_the_circle():
    d, dtheta, pose0 = 0.2, 0.4, (0.0, 0.0, 0.0)
    ex, ey, _ = circle_end(pose0, d / dtheta, dtheta)
    chord = 2 * (d / dtheta) * math.sin(dtheta / 2)
    x, y, _ = step(*pose0, d, dtheta, "midpoint")
    # same direction, chord d instead of the true chord: the excess is about d*dtheta^2/24
    assert math.hypot(x, y) - chord == pytest.approx(d * dtheta**2 / 24, rel=0.01)
    assert math.atan2(y, x) == pytest.approx(math.atan2(ey, ex), abs=1e-15)
    x, y, _ = step(*pose0, d, dtheta, "euler")
    assert (x, y) == (d, 0.0)


def test_wheel_motion_and_unknown_rule():
    assert wheel_motion(0.25, 0.75, 0.5) == (0.5, 1.0)  # exact in binary
    with pytest.raises(ValueError, match="rule"):
        step(0.0, 0.0, 0.0, 1.0, 0.1, "trapezoid")
    with pytest.raises(ValueError, match="rule"):
        increments(0.0, 1.0, 0.1, "trapezoid")


def test_arc_factor_against_mpmath_on_both_sides_of_the_threshold():
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 40
    for dth in [0.0, 1e-12, -3e-7, 1.5e-4, 1.999e-4, 2e-4, 2.001e-4, -2.5e-4, 1e-3, 0.5, 3.0]:
        s, ds = arc_factor(dth)
        a = mpmath.mpf(dth) / 2
        s_ref = mpmath.sinc(a)
        ds_ref = mpmath.diff(mpmath.sinc, a) / 2
        assert abs(s - float(s_ref)) <= math.ulp(1.0), dth  # one ulp of the factor
        # the closed-form derivative loses ~3 eps / a^2 to cancellation just above 1e-4
        assert abs(ds - float(ds_ref)) <= 1e-7 * max(abs(float(ds_ref)), 1e-12), dth
    assert SMALL_ANGLE == 1e-4


def test_step_terms_pieces():
    c, phi, s, ds, k = step_terms(0.2, 0.5, 0.3, "arc")
    assert (c, phi, k) == (0.5 * s, 0.2 + 0.15, 0.5)
    assert (s, ds) == arc_factor(0.3)
    assert step_terms(0.2, 0.5, 0.3, "midpoint") == (0.5, 0.35, 1.0, 0.0, 0.5)
    assert step_terms(0.2, 0.5, 0.3, "euler") == (0.5, 0.2, 1.0, 0.0, 0.0)


@pytest.mark.parametrize("rule", RULES)
def test_vectorised_form_equals_scalar_steps_bit_for_bit(rule):
    rng = np.random.default_rng(11)
    n = 4000
    d = rng.normal(0.01, 0.02, n)
    dth = rng.normal(0.0, 0.05, n)
    dth[::3] = rng.normal(0.0, 1e-4, dth[::3].size)  # below and around the threshold
    dth[::7] = 0.0
    pose = (0.3, -0.2, 3.0)
    batch = integrate(d, dth, pose, rule)
    out = np.empty((n, 3))
    x, y, th = pose
    for i in range(n):
        x, y, th = step(x, y, th, float(d[i]), float(dth[i]), rule)
        out[i] = (x, y, th)
    np.testing.assert_array_equal(batch, out)


def test_users_take_the_canonical_step():
    from drivers.slamware import deadreckon_from_wheels
    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.planar.odometry import WheelOdometry, integrate_wheel_travel

    dx, dy, dth_deg = deadreckon_from_wheels(40.0, 47.0, 118.0, method="arc")
    x, y, th = step(0.0, 0.0, 0.0, 43.5, 7.0 / 236.0, "arc")
    assert (dx, dy) == (x, y) and dth_deg == math.degrees(th)
    left = np.arange(60) * 3
    right = left[::-1] + 1
    for rule in RULES:
        poses = WheelOdometry(DiffDriveParams(0.2, 1e-4), rule).update_batch(left, right)
        np.testing.assert_array_equal(
            poses, integrate_wheel_travel(left * 1e-4, right * 1e-4, 0.2, method=rule))
