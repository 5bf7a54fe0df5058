"""The IMU's mount on the base, estimated from a log: gravity gives roll and pitch, the
accelerations of driving give the yaw.

A robot.toml whose ``imu_mount_rpy`` is not how the IMU sits makes the fusion take the heading
rate about the wrong axis (before the first stop the gyro's own z axis is fused, on the
assumption that it is near the vertical) and look for slip and stillness along the wrong
axes. An IMU on its side (the issue-11 outdoor robot: rolled +90 deg, yawed -90 deg) replayed
with the level default gave 17 m of position RMSE against GPS instead of 1.5 m.

:func:`fusion.geometry.mount.angle_from_vertical` of the mean specific force over a run, in the
base frame after the configured mount, is the check (:mod:`fusion.evaluation.trust`'s
``mount``); :func:`estimate_imu_mount` the estimate:

- roll and pitch level the mean specific force of the whole run. Over a run the horizontal
  accelerations average out (the mean of dv/dt is the speed change over the span; the
  centripetal part of consistent turns, ``v * w`` of order 0.1 m/s^2, is a few tenths of a
  degree) and the mean slope of a route is small, so the mean points up;
- the yaw is the rotation about the vertical that best carries the levelled horizontal
  specific force onto what the odometry says the base felt, forward ``dv/dt`` and left
  ``v * w`` (``w`` the levelled gyro's vertical rate): the angle of the summed cross and dot
  products (a least-squares rotation, Wahba's problem in the plane), both sides high-passed
  (a slope's gravity is slow and larger than the driving's accelerations). Its standard
  error is a jackknife over consecutive blocks. It needs the robot to have
  accelerated or turned: without that the yaw is left undetermined (``yaw_known``). Only
  the lateral slip check and the opt-in accelerometer speed use the yaw; the heading rate
  needs roll and pitch alone.

Angles in rad, accelerations in m/s^2, rates in rad/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d

from fusion.geometry.mount import imu_to_base, mount_matrix

__all__ = [
    "MAX_YAW_STD",
    "MIN_EXCITATION",
    "Handedness",
    "MountEstimate",
    "estimate_imu_mount",
    "imu_handedness",
]

#: m/s^2: RMS of the horizontal specific force the odometry explains (forward dv/dt, left
#: v * w) below which the yaw is not estimated (a robot that barely accelerated or turned).
MIN_EXCITATION = 0.05
#: rad: the largest standard error of the fitted yaw for it to be reported as known.
MAX_YAW_STD = math.radians(10.0)
#: s: the horizontal accelerations are compared as means over bins of this length (the
#: odometry's speed is differentiated over them: 10 Hz twists have no finer dv/dt).
_BIN = 0.5
#: s: the running mean taken off both sides before the fit. Slower than this are a slope's
#: gravity (10 deg of slope is 1.7 m/s^2 along the body) and the mean of long turns, which
#: drowned the fit (terrain benchmark bags, seeds 31-33: standard errors of 12-26 deg
#: without it, 2-3 deg with it; 4 s: 2-5 deg, 8 s: 3-13 deg).
_HIGH_PASS = 2.0
#: Consecutive blocks left out in turn for the yaw's standard error (a jackknife).
_BLOCKS = 8


@dataclass(frozen=True)
class MountEstimate:
    """An IMU mount estimated from a log.

    Attributes:
        rpy: URDF roll, pitch, yaw of the IMU in the base frame (rad), robot.toml's
            ``imu_mount_rpy``; the yaw is 0 when not ``yaw_known``.
        yaw_known: whether the log's accelerations determined the yaw.
        gravity: m/s^2, the mean specific force's norm (about 9.8 for a working
            accelerometer in m/s^2).
        samples: IMU samples averaged.
        excitation: m/s^2, RMS of the odometry's horizontal specific force over the bins
            compared (0 without odometry).
        yaw_std: rad, the yaw's standard error (NaN when not ``yaw_known``).
        yaw_correlation: correlation of the rotated levelled horizontal specific force with
            the odometry's, both high-passed (1: a perfect fit; NaN when not compared).
        odometry_scale: the odometry's horizontal accelerations over the accelerometer's
            along the fitted yaw (least squares of the accelerometer on the odometry, so the
            accelerometer's noise does not bias it; the odometry's own does, upwards: a test
            drive with 0.02 m/s of speed noise reads 1.5): about 1 when the speeds are in m/s
            and right, 100 for cm/s (NaN when not compared). Good for units, not for a wheel
            radius a few percent off.
    """

    rpy: tuple[float, float, float]
    yaw_known: bool
    gravity: float
    samples: int
    excitation: float
    yaw_std: float
    yaw_correlation: float
    odometry_scale: float = math.nan

    def cli_argument(self) -> str:
        """``--imu-mount-rpy R P Y`` with the estimate (rad, 4 decimals)."""
        return "--imu-mount-rpy " + " ".join(f"{a:.4f}" for a in self.rpy)

    def describe(self) -> str:
        """One sentence: the estimate and how well the log determined it."""
        r, p, y = (math.degrees(a) for a in self.rpy)
        how = (f"yaw +- {math.degrees(self.yaw_std):.1f} deg from the driving accelerations"
               if self.yaw_known else
               "yaw NOT determined (too little acceleration or turning, or no odometry): "
               "set it from how the IMU's x axis points")
        return (f"estimated from this log: roll {r:+.1f} deg, pitch {p:+.1f} deg, yaw {y:+.1f} "
                f"deg ({self.cli_argument()}; gravity {self.gravity:.2f} m/s^2 over "
                f"{self.samples} samples, {how})")


def _bin_means(t: NDArray[np.float64], values: NDArray[np.float64], edges: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per-bin means of ``values`` (N, k) at stamps ``t`` over ``edges``, and which bins hold
    a sample."""
    idx = np.searchsorted(edges, t, side="right") - 1
    inside = (idx >= 0) & (idx < edges.size - 1)
    nbins = edges.size - 1
    counts = np.bincount(idx[inside], minlength=nbins).astype(float)
    sums = np.stack([np.bincount(idx[inside], weights=values[inside, j], minlength=nbins)
                     for j in range(values.shape[1])], axis=1)
    has = counts > 0
    means = np.full_like(sums, np.nan)
    means[has] = sums[has] / counts[has, None]
    return means, has


def _levelling(f: NDArray[np.float64]) -> tuple[float, float]:
    """URDF roll and pitch (rad) of a mount that turns the mean specific force ``f`` (3,)
    m/s^2 onto the base's +z."""
    return math.atan2(f[1], f[2]), math.atan2(-f[0], math.hypot(f[1], f[2]))


def estimate_imu_mount(imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                       speed_t: ArrayLike | None = None, speed: ArrayLike | None = None
                       ) -> MountEstimate:
    """Estimate the IMU's mount from a log (module docstring).

    Args:
        imu_t: (N,) s, increasing. gyro, accel: (N, 3) rad/s and m/s^2 in the IMU frame.
        speed_t, speed: (M,) s and m/s, the odometry's forward speed (wheel frames or
            twists); None: the yaw is not estimated.

    Raises:
        ValueError: shapes that do not match, fewer than 2 finite samples, or a mean specific
            force of zero (an accelerometer that reads nothing).
    """
    t = np.asarray(imu_t, dtype=float)
    g = np.asarray(gyro, dtype=float)
    a = np.asarray(accel, dtype=float)
    if t.ndim != 1 or g.shape != (t.size, 3) or a.shape != (t.size, 3):
        raise ValueError(f"imu_t (N,), gyro and accel (N, 3) expected, got {t.shape}, "
                         f"{g.shape}, {a.shape}")
    ok = np.isfinite(t) & np.all(np.isfinite(g), axis=1) & np.all(np.isfinite(a), axis=1)
    t, g, a = t[ok], g[ok], a[ok]
    if t.size < 2:
        raise ValueError(f"{t.size} finite IMU samples: too few to estimate the mount")
    f = a.mean(axis=0)
    norm = float(np.linalg.norm(f))
    if not norm > 0:
        raise ValueError("the accelerometer's mean is zero: no gravity to level the mount by")
    roll, pitch = _levelling(f)
    level = mount_matrix((roll, pitch, 0.0))
    yaw, yaw_std, excitation, corr, scale = 0.0, math.nan, 0.0, math.nan, math.nan
    if speed_t is not None and speed is not None:
        yaw, yaw_std, excitation, corr, scale = _fit_yaw(t, imu_to_base(level, g)[:, 2],
                                                  imu_to_base(level, a)[:, :2],
                                                  np.asarray(speed_t, dtype=float),
                                                  np.asarray(speed, dtype=float))
    known = excitation >= MIN_EXCITATION and yaw_std <= MAX_YAW_STD
    return MountEstimate((roll, pitch, yaw if known else 0.0), known, norm, int(t.size),
                         excitation, yaw_std if known else math.nan, corr, scale)


def _binned_pairs(t: NDArray[np.float64], rate: NDArray[np.float64],
                  horizontal: NDArray[np.float64], speed_t: NDArray[np.float64],
                  speed: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """``(a, b, excitation)``: the levelled horizontal specific force ``a`` and the
    odometry's ``b`` = (dv/dt, v * w) (K, 2) m/s^2, as means over :data:`_BIN` s bins less
    their running mean over :data:`_HIGH_PASS` s, and the RMS of ``b`` before that; None
    with too few bins (fewer than 2 :data:`_BLOCKS` of them)."""
    ok = np.isfinite(speed_t) & np.isfinite(speed)
    speed_t, speed = speed_t[ok], speed[ok]
    if speed_t.size < 2:
        return None
    lo, hi = max(t[0], speed_t[0]), min(t[-1], speed_t[-1])
    edges = np.arange(lo, hi + 1e-9, _BIN)
    if edges.size <= 2 * _BLOCKS:
        return None
    # the odometry's speed at each IMU sample and at the bin edges (linear between its
    # stamps): bin means of v * w, and dv/dt's exact bin mean from the speeds at the edges,
    # are then what the accelerometer's bin means hold (a smoother dv/dt, e.g. a central
    # difference of bin means, shrinks the forward component alone and turns the fit)
    v = np.interp(t, speed_t, speed)
    rows = np.column_stack([horizontal, v * rate])
    means, has = _bin_means(t, rows, edges)
    if has.sum() < 2 * _BLOCKS:
        return None
    forward = np.diff(np.interp(edges, speed_t, speed)) / np.diff(edges)
    a = means[has, :2]
    b = np.column_stack([forward[has], means[has, 2]])
    excitation = float(np.sqrt(np.mean(np.sum(b * b, axis=1))))
    width = max(1, round(_HIGH_PASS / _BIN))
    a = a - uniform_filter1d(a, width, axis=0, mode="nearest")
    b = b - uniform_filter1d(b, width, axis=0, mode="nearest")
    return a, b, excitation


@dataclass(frozen=True)
class Handedness:
    """Whether the IMU's axes are right-handed, from a log's turns.

    Attributes:
        correlation: of the levelled sideways specific force (left of the forward axis the
            driving accelerations fit) with the odometry's ``v * w`` (``w`` the gyro's
            vertical rate): positive for right-handed axes (a turn's centripetal
            acceleration points into it), negative when one axis is flipped.
        std: its standard error, a jackknife over :data:`_BLOCKS` consecutive blocks.
        excitation: m/s^2, as :attr:`MountEstimate.excitation`.
    """

    correlation: float
    std: float
    excitation: float


def _sideways_correlation(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Correlation of ``a``'s component left of the forward axis fitted to ``b[:, 0]`` alone
    with ``b[:, 1]`` (arrays as :func:`_binned_pairs`' ``a`` and ``b``)."""
    yaw = math.atan2(-float(np.sum(b[:, 0] * a[:, 1])), float(np.sum(b[:, 0] * a[:, 0])))
    left = math.sin(yaw) * a[:, 0] + math.cos(yaw) * a[:, 1]
    energy = math.sqrt(float(np.sum(left * left)) * float(np.sum(b[:, 1] * b[:, 1])))
    return float(np.sum(left * b[:, 1])) / energy if energy > 0 else math.nan


def imu_handedness(imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike, speed_t: ArrayLike,
                   speed: ArrayLike) -> Handedness | None:
    """Whether the IMU's axes are right-handed (:class:`Handedness`), from the log's driving
    (arguments as :func:`estimate_imu_mount`'s, any mount: a rotation keeps handedness);
    None when the log has too little of it to compare. The forward axis alone is fitted
    (the larger signal); the sideways axis is then left of it, where a left turn's
    centripetal specific force points."""
    t = np.asarray(imu_t, dtype=float)
    g = np.asarray(gyro, dtype=float)
    a = np.asarray(accel, dtype=float)
    f = a.mean(axis=0)
    if not np.all(np.isfinite(f)) or not np.linalg.norm(f) > 0:
        return None
    level = mount_matrix((*_levelling(f), 0.0))
    pairs = _binned_pairs(t, imu_to_base(level, g)[:, 2], imu_to_base(level, a)[:, :2],
                          np.asarray(speed_t, dtype=float), np.asarray(speed, dtype=float))
    if pairs is None:
        return None
    a2, b2, excitation = pairs
    corr = _sideways_correlation(a2, b2)
    blocks = np.array_split(np.arange(a2.shape[0]), _BLOCKS)
    left_out = np.array([_sideways_correlation(np.delete(a2, k, axis=0),
                                               np.delete(b2, k, axis=0)) for k in blocks])
    spread = left_out - left_out.mean()
    std = math.sqrt((_BLOCKS - 1) / _BLOCKS * float(np.sum(spread * spread)))
    return Handedness(corr, std, excitation)


def _fit_yaw(t: NDArray[np.float64], rate: NDArray[np.float64], horizontal: NDArray[np.float64],
             speed_t: NDArray[np.float64], speed: NDArray[np.float64]
             ) -> tuple[float, float, float, float, float]:
    """``(yaw, yaw_std, excitation, correlation, odometry_scale)``: the rotation about the
    vertical taking the levelled horizontal specific force onto the odometry's ``(dv/dt,
    v * w)``, compared as means over :data:`_BIN` s bins less their running mean over
    :data:`_HIGH_PASS` s (what is slower, a slope's gravity and the mean of long turns, left
    out); ``yaw_std`` from the spread of the same fit with each of :data:`_BLOCKS`
    consecutive blocks left out (a jackknife; NaN when not fitted); ``odometry_scale`` as
    :class:`MountEstimate`'s."""
    none = (0.0, math.nan, 0.0, math.nan, math.nan)
    pairs = _binned_pairs(t, rate, horizontal, speed_t, speed)
    if pairs is None:
        return none
    a, b, excitation = pairs
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    dot = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    yaw = math.atan2(float(cross.sum()), float(dot.sum()))
    # delete-one-block jackknife: each estimate leaves one block out (a block where the
    # robot stood still weighs nothing in the fit and must not in its spread either)
    c_blocks = np.array([c.sum() for c in np.array_split(cross, _BLOCKS)])
    d_blocks = np.array([d.sum() for d in np.array_split(dot, _BLOCKS)])
    left_out = np.array([math.remainder(math.atan2(float(cross.sum() - c), float(dot.sum() - d))
                                        - yaw, 2 * math.pi)
                         for c, d in zip(c_blocks, d_blocks, strict=True)])
    spread = left_out - left_out.mean()
    yaw_std = math.sqrt((_BLOCKS - 1) / _BLOCKS * float(np.sum(spread * spread)))
    energy = math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b)))
    along = math.hypot(float(cross.sum()), float(dot.sum()))  # sum of b . (R a)
    corr = along / energy if energy > 0 else math.nan
    scale = float(np.sum(b * b)) / along if along > 0 else math.nan
    return yaw, yaw_std, excitation, corr, scale
