"""The bag odometry's own track across a driver's pose reset (fusion.io.pose_track), against
an analytic track: a robot driving an arc at constant speed and yaw rate."""

from __future__ import annotations

import math

import numpy as np

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


def test_a_reset_to_the_origin_is_spliced_out():
    t, x, y, yaw, v, w = arc()
    truth = relative(t, x, y, yaw)
    k = 250  # the driver restarts: from here its poses start again at the origin
    c, s = math.cos(yaw[k]), math.sin(yaw[k])
    rx, ry = x.copy(), y.copy()
    rx[k:] = c * (x[k:] - x[k]) + s * (y[k:] - y[k])
    ry[k:] = -s * (x[k:] - x[k]) + c * (y[k:] - y[k])
    ryaw = yaw.copy()
    ryaw[k:] = yaw[k:] - yaw[k]
    out = own_track(t, rx, ry, ryaw, v, w)
    assert out.resets == [t[k]] and "100.000" not in out.note and f"{t[k]:.3f}" in out.note
    # the twist over the interval is exact here (a constant arc): the track is the truth
    assert np.allclose(out.track[:, :2], truth[:, :2], atol=1e-9)
    assert np.allclose(np.unwrap(out.track[:, 2]), truth[:, 2], atol=1e-9)
    assert own_track(t, x, y, yaw, v, w).resets == []  # untouched: nothing to splice


def test_misordered_poses_that_come_back_are_no_reset():
    # pairs of poses swapped (a recorder's bursts): steps far longer than the robot moves,
    # but a second later the poses are back on the track
    t, x, y, yaw, v, w = arc()
    for k in range(100, 500, 37):
        x[[k, k + 1]], y[[k, k + 1]] = x[[k + 1, k]], y[[k + 1, k]]
    x[300] += 5.0  # one pose far off, then back
    out = own_track(t, x, y, yaw, v, w)
    assert out.resets == [] and out.note == ""


def test_short_and_empty_inputs():
    assert own_track([], [], [], [], [], []).track.shape == (0, 3)
    one = own_track([1.0], [2.0], [3.0], [0.5], [0.0], [0.0])
    assert np.array_equal(one.track, [[0.0, 0.0, 0.0]]) and one.resets == []
