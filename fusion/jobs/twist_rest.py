"""Odometry twists that never read exactly zero at rest: the stop thresholds from their noise.

The EKF takes a twist as standing still only below ``[ekf] twist_zero_v`` and
``twist_zero_w`` (1 mm/s and 1 mrad/s), which a driver that differences its encoders meets
exactly. A driver whose speeds come from a motor controller's estimate or a filter reports a
few mm/s of noise at rest instead: then no twist is ever a stop, no zero-velocity update is
taken and the gyro bias is never learnt at the stops, without a word (an independent probe's
outdoor bags with 2 mm/s of noise on v and w: 162 updates fell to 8 and the GPS RMSE rose
from 1.6 to 4.1 m).

:func:`with_twist_rest_floor` reads that noise where the IMU says the robot is still
(:mod:`fusion.planar.imu_motion`), among the twists small enough to be a stop, and raises the
two thresholds to cover it, for the replay only and with a note. A robot creeping in one
direction, or turning slowly, with its IMU still keeps its sign, and is not a stop: each still
stretch whose mean is off zero by more than :data:`CREEP_SIGMAS` standard errors is left out
first, and the rest must scatter around zero (about as many positive as negative twists, once
a slow stop's one-signed tail is trimmed). The thresholds are capped (:data:`MAX_ZERO_V`,
:data:`MAX_ZERO_W`) at what a stop's zero-velocity update may safely pin to zero.

A driver may instead report a steady offset at rest: a base whose odometry's yaw rate comes
from its own gyro reads that gyro's residual bias, a speed estimator its own offset. Every
still stretch is then one-signed, so each read as a creep and nothing was raised: an
independent probe's outdoor bag with 5 mrad/s added to every twist's yaw rate lost all 98 of
its zero-velocity updates, silently (GPS RMSE 1.55 -> 6.58 m; a note said the robot never
stopped). Twists and an IMU cannot tell such an offset from a robot that turns (or creeps)
at that very rate whenever it stops (a constant added to the twists is a gyro bias the other
way): :func:`_steady_offset` takes the offset reading where :data:`MIN_OFFSET_STRETCHES` or
more still stretches each hold one steady value (a median absolute deviation under
:data:`STEADY_SHARE` of their median) and agree on it (within :data:`OFFSET_AGREEMENT`): a
motion repeated at one rate at every stop is the less likely of the two. The threshold then
covers the offset and its noise, within the same caps, and the note names both readings.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fusion.geometry.mount import imu_to_base, mount_matrix
from fusion.jobs.streams import Streams, two_digits_up
from fusion.planar.imu_motion import MOTION_STILL, imu_motion_codes
from fusion.planar.robot import RobotConfig

__all__ = ["MAX_ZERO_V", "MAX_ZERO_W", "with_twist_rest_floor"]

#: m/s, rad/s: twists at most this fast, where the IMU is still, are the candidates for rest.
CANDIDATE_V = 0.05
CANDIDATE_W = 0.05
#: The fewest candidates the noise is read from (2 s of twists at 10 Hz).
MIN_CANDIDATES = 20
#: The thresholds set: this many times the candidates' median magnitude (for Gaussian noise,
#: 2.7 standard deviations: 99.3 % of the twists at rest pass on each of v and w).
MEDIAN_FACTOR = 4.0
#: Robust standard deviations (1.4826 median magnitudes) beyond which a candidate is left out
#: of the noise (a slow stop's tail).
TRIM = 3.0
#: Twists scatter around zero when the shares of positive and negative ones differ by at most
#: this (0 for noise, 1 for a steady creep; 2.2 standard deviations of noise's own at
#: :data:`MIN_CANDIDATES`).
MAX_SIGN_IMBALANCE = 0.5
#: m/s: the largest twist_zero_v set (a robot creeping this slowly is taken as stopped).
MAX_ZERO_V = 0.02
#: rad/s: the largest twist_zero_w set (0.57 deg/s: a zero-velocity update pins the yaw rate
#: to zero, and the gyro bias it teaches is off by as much as a turn this slow).
MAX_ZERO_W = 0.01
#: s: the longest an IMU sample's code stands for a twist stamped after it.
CODE_REACH = 0.5


def _candidates(streams: Streams, robot: RobotConfig) -> np.ndarray:
    """Mask of the twists stamped where the IMU's window statistic says still (in the base
    frame, as the pipeline's detector sees it), small enough to be a stop."""
    R = mount_matrix(robot.imu_mount_rpy)
    codes = imu_motion_codes(streams.imu_t, imu_to_base(R, streams.gyro),
                             imu_to_base(R, streams.accel), robot.imu_motion)
    i = np.searchsorted(streams.imu_t, streams.twist_t, side="right") - 1
    known = i >= 0
    still = np.zeros(streams.twist_t.size, dtype=bool)
    idx = i[known]
    still[known] = ((codes[idx] == MOTION_STILL)
                    & (streams.twist_t[known] - streams.imu_t[idx] <= CODE_REACH))
    return (still & (np.abs(streams.twist_v) <= CANDIDATE_V)
            & (np.abs(streams.twist_w) <= CANDIDATE_W))


def _noise_floor(values: np.ndarray) -> tuple[float, bool]:
    """(the threshold that covers ``values``' scatter about zero, whether they scatter around
    it): the values beyond :data:`TRIM` robust standard deviations are left out first (the
    IMU already reads still while a smooth stop creeps to its halt: a one-signed tail)."""
    magnitude = float(np.median(np.abs(values)))
    if magnitude == 0.0:
        return 0.0, True
    core = values[np.abs(values) <= TRIM * 1.4826 * magnitude]
    imbalance = abs(float(np.mean(np.sign(core))))
    return MEDIAN_FACTOR * float(np.median(np.abs(core))), imbalance <= MAX_SIGN_IMBALANCE


#: Twists in a row a still stretch needs for its own creep test.
MIN_STRETCH = 5
#: Standard errors of its mean beyond which a still stretch creeps (or turns slowly) one way.
CREEP_SIGMAS = 3.0


def _without_creeping_stretches(values: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """``rest`` less the stretches of consecutive candidates whose ``values`` keep one sign:
    a mean more than :data:`CREEP_SIGMAS` standard errors from zero (a robot creeping, or
    turning slowly, with its IMU still; pooled with noisy stops elsewhere, its twists had
    read as noise and the raised threshold took the creep for a stop, review)."""
    keep = rest.copy()
    idx = np.flatnonzero(rest)
    if idx.size == 0:
        return keep
    breaks = np.flatnonzero(np.diff(idx) > 1)
    for run in np.split(idx, breaks + 1):
        if run.size < MIN_STRETCH:
            continue
        x = values[run]
        spread = float(np.std(x, ddof=1))
        if abs(float(np.mean(x))) > CREEP_SIGMAS * spread / math.sqrt(run.size):
            keep[run] = False
    return keep


#: Still stretches (of :data:`MIN_STRETCH` twists or more) that must hold one offset.
MIN_OFFSET_STRETCHES = 3
#: A stretch holds a steady value when its median absolute deviation is at most this share
#: of its median (a slow stop's decaying tail spreads about as much as its middle value).
STEADY_SHARE = 0.5
#: Stretch medians agree on an offset when each is within this share of their median.
OFFSET_AGREEMENT = 0.25


def _steady_offset(values: np.ndarray, rest: np.ndarray) -> float | None:
    """The offset every still stretch of ``values`` holds (module docstring), or None."""
    idx = np.flatnonzero(rest)
    if idx.size == 0:
        return None
    middles = []
    for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
        if run.size < MIN_STRETCH:
            continue
        x = values[run]
        middle = float(np.median(x))  # robust to the stop's edges the IMU already calls still
        if middle == 0.0 or not (float(np.median(np.abs(x - middle)))
                                 <= STEADY_SHARE * abs(middle)):
            return None  # zero at rest, noise around it, or a tail: no steady offset
        middles.append(middle)
    if len(middles) < MIN_OFFSET_STRETCHES:
        return None
    m = np.asarray(middles)
    offset = float(np.median(m))
    if not np.all(np.abs(m - offset) <= OFFSET_AGREEMENT * abs(offset)):
        return None
    return offset


def with_twist_rest_floor(robot: RobotConfig, streams: Streams) -> tuple[RobotConfig, str]:
    """``robot`` with ``[ekf] twist_zero_v`` and ``twist_zero_w`` raised to the odometry
    twists' noise at rest (module docstring), and a note saying so ("" when nothing changed:
    no twists or no IMU, fewer than :data:`MIN_CANDIDATES` twists where the IMU was still,
    twists there that read zero, or that do not scatter around it). Never lowers a
    threshold robot.toml set."""
    if not (streams.has_imu and streams.has_twist):
        return robot, ""
    ekf = robot.ekf
    rest = _candidates(streams, robot)
    if np.count_nonzero(rest) < MIN_CANDIDATES:
        return robot, ""
    raised, offsets = {}, {}
    for name, values, cap in (("twist_zero_v", streams.twist_v, MAX_ZERO_V),
                              ("twist_zero_w", streams.twist_w, MAX_ZERO_W)):
        still = _without_creeping_stretches(values, rest)
        if np.count_nonzero(still) >= MIN_CANDIDATES:
            floor, scattered = _noise_floor(values[still])
            new = min(cap, two_digits_up(floor)) if floor > 0.0 else 0.0
            if scattered and new > getattr(ekf, name):  # raised, never lowered
                raised[name] = new
                continue
        offset = _steady_offset(values, rest)
        if offset is None:
            continue
        floor, scattered = _noise_floor(values[rest] - offset)
        new = two_digits_up(abs(offset) + floor)
        if scattered and new <= cap and new > getattr(ekf, name):
            raised[name] = new
            offsets[name] = offset
    if not raised:
        return robot, ""
    v, w = streams.twist_v[rest], streams.twist_w[rest]
    settings = ", ".join(f"{k} = {x:g}" for k, x in raised.items())
    capped = any(raised[k] == c for k, c in (("twist_zero_v", MAX_ZERO_V),
                                             ("twist_zero_w", MAX_ZERO_W)) if k in raised)
    units = {"twist_zero_v": ("v", "m/s"), "twist_zero_w": ("w", "rad/s")}
    steady = "; ".join(f"{units[k][0]} held {x:+.2g} {units[k][1]} at every stop"
                       for k, x in offsets.items())
    noise = "scattered around zero: its driver reports noise at rest"
    what = (noise if not offsets else
            f"{steady}: its driver's offset at rest (a base whose odometry's yaw rate is its "
            "own gyro's, a speed estimator's bias), taken so, or the robot moved at that rate "
            "whenever it stopped (then lower the setting below again)"
            + (f"; the other {noise}" if len(raised) > len(offsets) else ""))
    note = (f"the odometry's twists where the IMU was still ({v.size} of them) read "
            f"|v| {np.median(np.abs(v)):.2g} m/s and |w| {np.median(np.abs(w)):.2g} rad/s "
            f"(medians), {what}, which the stop thresholds would never take for a stop; "
            f"this replay uses {settings} (set them in robot.toml's [ekf] to keep them)"
            + ("; capped: noise this large also hides slow motion, so some stops may still be "
               "missed" if capped else ""))
    return dataclasses.replace(robot, ekf=dataclasses.replace(ekf, **raised)), note
