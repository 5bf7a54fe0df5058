"""A bag's twist that runs against its own pose: which of the two has its sign flipped, asked
of the IMU, and the twist corrected when the IMU says it is the twist.

:mod:`fusion.io.twist_against_pose` finds a twist whose forward speed or yaw rate runs
against its pose's motion; the odometry alone cannot tell which is wrong. The IMU can:

- the forward speed: the accelerometer's horizontal specific force, levelled, against the
  twist's (dv/dt, v w) (:func:`fusion.calibration.mount.estimate_imu_mount` on the IMU
  turned into the base frame by the configured mount): a residual yaw near 0 says the twist's
  accelerations are the IMU's, near 180 deg that they are the opposite. On the terrain
  outdoor bag with ``linear.x`` negated (pose untouched) the fused track had come out turned
  by 180 deg (x -25.8 m where the bag's odometry ends at +54.5 m) without a warning;
- the yaw rate: the gyro's vertical axis (base frame) at the twists' stamps, whose cosine with
  the twist's yaw rate is positive when they turn the same way.

The verdict (:class:`SignCheck`): the twist's component taken as the IMU says (negated when
the IMU sides with the pose, with a note), or, when the IMU cannot tell (too little driving
acceleration, no accelerometer, a gyro that does not follow either), a trust warning
``twist_pose`` (:class:`fusion.evaluation.trust.TrustWarning`) saying what disagrees. Angles in
rad, rates in rad/s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.calibration.mount import estimate_imu_mount
from fusion.evaluation.trust import TrustWarning
from fusion.geometry.mount import imu_to_base, mount_matrix
from fusion.io.odometry_motion import OdometryMotion
from fusion.io.twist_against_pose import MIN_TURN, TwistPoseFit, fit_of

__all__ = ["GYRO_VERDICT_COSINE", "YAW_VERDICT", "SignCheck", "check_twist_signs"]

#: rad: the accelerometer sides with the twist when the residual yaw of the mount it implies
#: is within this of 0, with the pose within this of pi (and determined: its standard error
#: under :data:`fusion.calibration.mount.MAX_YAW_STD`).
YAW_VERDICT = math.radians(45.0)
#: The gyro sides with the twist's yaw rate when their cosine is at least this, with the pose
#: when at most minus this (a skid-steer twist turns faster than the gyro, but the same way).
GYRO_VERDICT_COSINE = 0.5


@dataclass
class SignCheck:
    """What :func:`check_twist_signs` found: the twists to fuse (``motion``, corrected where
    the IMU said so), the fit, notes (what was corrected, or that the pose is the one
    flipped) and trust warnings (what the IMU could not settle)."""

    motion: OdometryMotion
    fit: TwistPoseFit | None = None
    notes: list[str] = field(default_factory=list)
    warnings: list[TrustWarning] = field(default_factory=list)


def check_twist_signs(odom: Any, motion: OdometryMotion, imu: Any,
                      imu_mount_rpy: tuple[float, float, float]) -> SignCheck:
    """Check the twists ``motion`` of the bag odometry ``odom`` (an
    :class:`fusion.io.bags.OdometryLog`) against its poses and settle a disagreement with the
    IMU log ``imu`` (``t``, ``gyro``, ``accel`` in the IMU frame) mounted at
    ``imu_mount_rpy`` (module docstring). Twists taken from the poses are not checked."""
    if motion.source == "pose" or motion.t.size != odom.t.size:
        return SignCheck(motion)
    fit = fit_of(odom, motion.v)
    out = SignCheck(motion, fit)
    name = odom.topic or "the odometry"
    if fit.turn >= MIN_TURN and not np.any(motion.w) and np.all(np.diff(odom.t) > 0):
        # a driver that leaves angular.z at 0 while its pose turns: the yaw rate its poses
        # show (else the odometry 'never turned' against the gyro: heading_divergence on a
        # good track)
        rate = np.gradient(np.unwrap(odom.yaw), odom.t)
        out.notes.append(f"{name}: its twist's yaw rate is 0 in every message while its pose "
                         f"turned {math.degrees(fit.turn):.0f} deg: the yaw rate is taken "
                         "from the pose's headings")
        motion = out.motion = dataclasses.replace(motion, w=rate)
    if not (fit.speed_opposite or fit.rate_opposite):
        return out
    R = mount_matrix(imu_mount_rpy)
    gyro, accel = imu_to_base(R, imu.gyro), imu_to_base(R, imu.accel)
    v, w = motion.v, motion.w
    if fit.speed_opposite:
        side, how = _speed_verdict(imu.t, gyro, accel, motion)
        what = (f"{name}: its twist's forward speed runs against its pose's travel (cosine "
                f"{fit.speed_cosine:+.3f} over {fit.intervals} intervals, {fit.path:.1f} m)")
        v = _settle(out, "speed", side, what, how, v, fit)
    if fit.rate_opposite:
        side, how = _rate_verdict(imu.t, gyro, motion)
        what = (f"{name}: its twist's yaw rate turns against its pose's heading (cosine "
                f"{fit.rate_cosine:+.3f} over {fit.intervals} intervals, "
                f"{math.degrees(fit.turn):.0f} deg of turns)")
        w = _settle(out, "rate", side, what, how, w, fit)
    if v is not motion.v or w is not motion.w:
        out.motion = dataclasses.replace(motion, v=v, w=w)
    return out


def _settle(out: SignCheck, quantity: str, side: str, what: str, how: str,
            values: NDArray[np.float64], fit: TwistPoseFit) -> NDArray[np.float64]:
    """Record the verdict on one quantity; the values to fuse (negated when the IMU sides
    with the pose)."""
    if side == "pose":
        out.notes.append(f"{what}; the IMU sides with the pose ({how}): the twist's sign is "
                         "taken as flipped and it is fused negated")
        return -values
    if side == "twist":
        out.notes.append(f"{what}; the IMU sides with the twist ({how}): the pose is the one "
                         "flipped (the fusion takes the twist; the bag's odometry printed and "
                         "plotted is its pose)")
        return values
    cosine = fit.speed_cosine if quantity == "speed" else fit.rate_cosine
    out.warnings.append(TrustWarning(
        "twist_pose",
        f"{what}: one of them has its sign flipped, and the IMU cannot tell which ({how}); "
        "the fusion takes the twist as written",
        {f"twist_pose_{quantity}_cosine": cosine}))
    return values


def _speed_verdict(t: NDArray[np.float64], gyro: NDArray[np.float64],
                   accel: NDArray[np.float64], motion: OdometryMotion) -> tuple[str, str]:
    """("twist" | "pose" | "", the reason): whose forward direction the accelerometer's
    driving accelerations share."""
    try:
        est = estimate_imu_mount(t, gyro, accel, motion.t, motion.v)
    except ValueError as exc:
        return "", f"the accelerometer: {exc}"
    if not est.yaw_known:
        return "", ("the accelerometer's driving accelerations do not determine a direction: "
                    f"{est.excitation:.2f} m/s^2 of odometry accelerations")
    yaw = est.rpy[2]
    said = (f"the accelerometer's driving accelerations lie {math.degrees(yaw):+.0f} +- "
            f"{math.degrees(est.yaw_std):.0f} deg from the twist's")
    if abs(yaw) <= YAW_VERDICT:
        return "twist", said
    if abs(math.remainder(yaw - math.pi, 2 * math.pi)) <= YAW_VERDICT:
        return "pose", said
    return "", said + " (check the IMU's mount)"


def _rate_verdict(t: NDArray[np.float64], gyro: NDArray[np.float64], motion: OdometryMotion
                  ) -> tuple[str, str]:
    """("twist" | "pose" | "", the reason): whose turning the gyro's vertical axis shares."""
    inside = (motion.t >= t[0]) & (motion.t <= t[-1])
    rate = np.interp(motion.t[inside], t, gyro[:, 2])
    w = motion.w[inside]
    norm = float(np.sqrt(np.dot(rate, rate) * np.dot(w, w)))
    if not norm > 0.0:
        return "", "the gyro's vertical axis reads no turning"
    cosine = float(np.dot(rate, w)) / norm
    said = f"the gyro's vertical axis against the twist's yaw rate: cosine {cosine:+.2f}"
    if cosine >= GYRO_VERDICT_COSINE:
        return "twist", said
    if cosine <= -GYRO_VERDICT_COSINE:
        return "pose", said
    return "", said
