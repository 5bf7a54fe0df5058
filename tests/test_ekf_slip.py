"""Straight drives on a coarse encoder: the wheels' quantisation and a wheel that spins a few
per cent faster than the floor must not walk the gyro bias (issue 11: "a slipping frame never
bends the heading"; a robot that never stops at the start).

The chassis: a 780-tick encoder on a 3.4 cm wheel, 23 cm apart, 50 Hz frames (one tick is
0.06 rad/s of yaw rate in one frame), driving straight at 0.45 m/s. Oracles: the synthetic
simulator's truth (the body drives straight, the true bias is 0.4 deg/s) and the same drive
without the slip.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.synthetic import (
    EncoderModel,
    ImuModel,
    SlipPatch,
    simulate,
    stop,
    straight,
)
from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.imu_motion import imu_motion_codes

COARSE = DiffDriveParams(wheel_distance=0.23, speed_ratio=2.0 * math.pi * 0.034 / 780,
                         encode_sampling_time=0.02)
BIAS = math.radians(0.4)


def _drive(patches, seed, *, moving_start, noise=None):
    """Fuse a straight drive of 60 m at 0.45 m/s (after a 3 s stop, or from 2 s into the
    drive: already moving at the first sample); returns ``(t, states, stats, truth_yaw)`` at
    the gyro rows."""
    segments = straight(60.0, 0.45) if moving_start else stop(3.0) + straight(27.0, 0.45)
    run = simulate(segments, COARSE, ImuModel(gyro_bias=(0.0, 0.0, BIAS)),
                   EncoderModel(slip_patches=patches), seed=seed)
    i = run.imu_t >= (2.0 if moving_start else 0.0)
    w = run.wheel_t >= (2.0 if moving_start else 0.0)
    track, ekf = fuse(COARSE, run.imu_t[i], run.gyro[i, 2], run.wheel_t[w], run.ticks[w],
                      noise=noise, imu_motion=imu_motion_codes(run.imu_t[i], run.gyro[i],
                                                               run.accel[i]))
    g = track.kind == core.EV_GYRO
    t = track.t[g]
    return t, track.states[g], ekf.stats, np.interp(t, run.truth_t, run.truth[:, 2])


@pytest.mark.parametrize("seed", [1, 2])
def test_a_long_straight_drive_without_a_stop_keeps_its_bias(seed):
    """130 s straight without a stop, the right wheel a fraction of a tick ahead of the left
    (it spun 1-10 % faster for half a second before the data begins). The bias and the radius
    mismatch c are unobservable apart driving straight at one speed, so nothing pulls them
    back; the wheels' quantisation must not push them either. Measured, bias at the end minus
    the true 0.4 deg/s: at most 0.23 deg/s over these 10 drives. When the yaw-rate model's
    radius mismatch acted on the speed state instead of the frame's measured speed: above
    0.3 deg/s on 6 of the 10, up to 3.7 deg/s (seed 1, 2 % shift: the heading 316 deg off at
    the end) and 2.8 deg/s (seed 2, no shift: 244 deg)."""
    for shift in (0.0, 0.01, 0.02, 0.05, 0.1):
        patches = (SlipPatch(0.5, 1.0, "right", shift),) if shift else ()
        t, states, stats, _ = _drive(patches, seed, moving_start=True)
        assert t[-1] > 130.0
        assert stats["slips"] == 0
        assert abs(math.degrees(states[-1, 5] - BIAS)) < 0.3, (shift, states[-1, 5])


@pytest.mark.parametrize("ratio", [0.03, 0.05, 0.1])
def test_a_partial_slip_before_the_first_stop_does_not_pull_the_bias(ratio):
    """Already moving, no stop yet (the bias known to about 1 deg/s), the right wheel spins
    3-10 % faster than the floor for 1.5 s: 0.06-0.2 rad/s of yaw rate the body does not
    have, many frames of it within one frame's noise of the gyro and so past the per-frame
    gate. The persistent-disagreement test (EkfNoise.slip_window) flags them. Measured, bias
    after the slip minus before: 0.11-0.15 deg/s; 0.86-3.1 deg/s with the test off."""
    patches = (SlipPatch(30.0, 31.5, "right", ratio),)
    for noise, bound in ((None, 0.2), (EkfNoise(slip_window=0.0), None)):
        t, states, stats, _ = _drive(patches, 1, moving_start=True, noise=noise)
        before, after = states[np.searchsorted(t, [29.5, 33.0]), 5]
        pulled = abs(math.degrees(after - before))
        if bound is None:  # the test off: the slip pulls the bias (the check can fail)
            assert pulled > 0.8, pulled
        else:
            assert pulled < bound, pulled
            assert stats["slips"] >= 20


@pytest.mark.parametrize("ratio", [0.03, 0.05, 0.1])
def test_a_partial_slip_after_a_stop_does_not_bend_the_heading(ratio):
    """The same slips after a 3 s stop (the bias pinned): the heading error across the slip
    changes by less than 0.05 deg. Measured 0.01-0.03 deg; 0.09-0.23 deg with the per-frame
    gate alone (slip_window 0)."""
    patches = (SlipPatch(30.0, 31.5, "right", ratio),)
    t, states, _, truth_yaw = _drive(patches, 1, moving_start=False)
    error = np.degrees(states[:, 2] - truth_yaw)
    k = np.searchsorted(t, [29.5, 33.0])
    assert abs(error[k[1]] - error[k[0]]) < 0.05, error[k]
