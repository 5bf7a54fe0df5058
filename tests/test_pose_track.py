"""The bag odometry's own track across a driver's pose reset (fusion.io.pose_track), against
an analytic track: a robot driving an arc at constant speed and yaw rate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.io.pose_track import own_track

V, W, DT = 1.2, 0.15, 0.1  # m/s, rad/s, s


def arc(n=600, x0=3.0, y0=-2.0, yaw0=0.4):
    """Poses of a constant arc from (x0, y0, yaw0), exact, every DT s."""
    t = 100.0 + DT * np.arange(n)
    yaw = yaw0 + W * (t - t[0])
    r = V / W
    x = x0 + r * (np.sin(yaw) - math.sin(yaw0))
    y = y0 - r * (np.cos(yaw) - math.cos(yaw0))
    return t, x, y, yaw, np.full(n, V), np.full(n, W)


def relative(track_t, x, y, yaw):
    """The poses from the first, in its frame (what the untouched bag's track is)."""
    c, s = math.cos(yaw[0]), math.sin(yaw[0])
    dx, dy = x - x[0], y - y[0]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, yaw - yaw[0]])


def _reset_at(k, x, y, yaw):
    """The poses from index ``k`` on re-zeroed (the driver's origin moved to pose ``k``)."""
    c, s = math.cos(yaw[k]), math.sin(yaw[k])
    rx, ry, ryaw = x.copy(), y.copy(), yaw.copy()
    rx[k:] = c * (x[k:] - x[k]) + s * (y[k:] - y[k])
    ry[k:] = -s * (x[k:] - x[k]) + c * (y[k:] - y[k])
    ryaw[k:] = yaw[k:] - yaw[k]
    return rx, ry, ryaw


@pytest.mark.parametrize("twist", ["as driven", "empty", "negated"])
def test_a_reset_to_the_origin_is_spliced_out(twist):
    # the splice continues by the poses' own motion: a twist left at 0 (a pose-only driver)
    # or with its signs flipped changes nothing
    t, x, y, yaw, v, w = arc()
    truth = relative(t, x, y, yaw)
    v, w = {"as driven": (v, w), "empty": (0 * v, 0 * w), "negated": (-v, -w)}[twist]
    k = 250  # the driver restarts: from here its poses start again at the origin
    out = own_track(t, *_reset_at(k, x, y, yaw), v, w)
    assert out.resets == [t[k]] and f"{t[k]:.3f}" in out.note
    # a constant arc: the interval before moved exactly as the reset's did
    assert np.allclose(out.track[:, :2], truth[:, :2], atol=1e-9)
    assert np.allclose(np.unwrap(out.track[:, 2]), truth[:, 2], atol=1e-9)
    assert own_track(t, x, y, yaw, v, w).resets == []  # untouched: nothing to splice


def test_two_resets_compose():
    t, x, y, yaw, v, w = arc()
    truth = relative(t, x, y, yaw)
    rx, ry, ryaw = _reset_at(200, x, y, yaw)
    rx, ry, ryaw = _reset_at(420, rx, ry, ryaw)
    out = own_track(t, rx, ry, ryaw, v, w)
    assert out.resets == [t[200], t[420]]
    assert np.allclose(out.track[:, :2], truth[:, :2], atol=1e-9)


def test_misordered_and_stray_poses_are_no_reset():
    # poses 15 apart swapped (1.8 m: a recorder's misordered burst), then one, two and three
    # stray poses 5 m off in a row: each is a step longer than the robot moves, but a second
    # later the poses are back on the track
    t, x, y, yaw, v, w = arc()
    for k in (60, 140):
        x[[k, k + 15]], y[[k, k + 15]] = x[[k + 15, k]], y[[k + 15, k]]
    for start, count in ((250, 1), (350, 2), (450, 3)):
        x[start:start + count] += 5.0
    out = own_track(t, x, y, yaw, v, w)
    assert out.resets == [] and out.note == ""
    drawn = relative(t, x, y, yaw)  # as published
    assert np.allclose(out.track[:, :2], drawn[:, :2], atol=1e-12)
    assert np.allclose(np.unwrap(out.track[:, 2]), drawn[:, 2], atol=1e-12)


def test_a_slow_pose_only_driver_that_often_stands_is_no_reset():
    # 1 Hz poses, no twist, the robot standing for two thirds of the time and driving at
    # 1.5 m/s in between: 1.5 m steps, more than the whole log's median speed allows
    t = np.arange(0.0, 200.0, 1.0)
    speed = np.where((t // 30) % 3 == 1, 1.5, 0.0)
    x = np.concatenate([[0.0], np.cumsum(speed[:-1])])
    zero = np.zeros_like(t)
    out = own_track(t, x, zero, zero, zero, zero)
    assert out.resets == []
    assert out.track[-1, 0] == pytest.approx(x[-1])


def test_short_and_empty_inputs():
    assert own_track([], [], [], [], [], []).track.shape == (0, 3)
    one = own_track([1.0], [2.0], [3.0], [0.5], [0.0], [0.0])
    assert np.array_equal(one.track, [[0.0, 0.0, 0.0]]) and one.resets == []


def test_a_gap_the_robot_drove_through_is_no_reset_but_a_restart_with_one_is():
    t, x, y, yaw, v, w = arc()
    keep = np.r_[0:200, 400:600]  # 20 s without poses while it drove on (24 m, 172 deg)
    out = own_track(t[keep], x[keep], y[keep], yaw[keep], v[keep], w[keep])
    assert out.resets == []
    # the driver restarted: 3 s without poses, then from the origin, 45 m from the robot (a
    # restart within reach of 3 s of driving, 3 x 1.2 m/s x 3 s + 1 m, is not told from it)
    t, x, y, yaw, v, w = arc(x0=40.0, y0=-25.0)
    rx, ry, ryaw = _reset_at(280, x, y, yaw)
    keep = np.r_[0:250, 280:600]
    out = own_track(t[keep], rx[keep], ry[keep], ryaw[keep], v[keep], w[keep])
    assert out.resets == [t[280]]
