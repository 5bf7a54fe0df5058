"""Offline (non-causal) Keel for recorded data: every sample sees the past and the future.

Steps (frames and units as in :mod:`fusion.attitude.keel`):

1. Run :class:`~fusion.attitude.keel.Keel` forward, and again over the time-reversed data with
   the gyro negated (its bias is then the negated bias), both with the motion bias sigma
   ``offline_motion_bias_sigma``; fuse the two bias estimates of each sample by inverse
   covariance.
2. Integrate the gyro minus the fused bias into the gyro frame (the same gap policy as online:
   an interval longer than ``max_gap`` is integrated over the last regular period and
   restarts the accelerometer filter).
3. Rotate the accelerometer into that frame and low-pass it forward, then backward (zero
   phase) with time constant ``offline_accel_time_constant``; the inclination-only rotation
   that brings it onto +z gives the 6-axis attitude.
4. 9-axis: the scalar heading offset runs forward and backward over that attitude (same
   disturbance rejection as online); the two are averaged on the circle.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.attitude import _keel_core as core
from fusion.attitude._inputs import as_rows
from fusion.attitude.keel import Keel, KeelDiagnostics, KeelParams
from fusion.geometry import quaternion as quat

__all__ = ["keel_offline"]


def keel_offline(
    gyro: ArrayLike,
    accel: ArrayLike,
    mag: ArrayLike | None = None,
    dt: float | ArrayLike | None = None,
    *,
    timestamps: ArrayLike | None = None,
    still: ArrayLike | None = None,
    known_accel: ArrayLike | None = None,
    axes: int = 6,
    params: KeelParams | None = None,
    diagnostics: bool = False,
    **options,
) -> NDArray[np.float64] | tuple[NDArray[np.float64], KeelDiagnostics]:
    """Attitude of every sample of a recording, (N, 4) ``[w, x, y, z]`` body -> world ENU.

    Arguments as :meth:`Keel.update_batch` (gyro rad/s, accel m/s^2, mag uT, body frame;
    ``dt`` or ``timestamps`` in s; ``still`` and ``known_accel`` external knowledge); ``axes``
    6 or 9; ``params`` or ``**options`` (:class:`KeelParams` fields, e.g.
    ``sample_period=``). With ``diagnostics=True`` also returns a :class:`KeelDiagnostics`
    whose bias is the fused one and whose flags are set where either pass set them.
    """
    p = Keel(axes=6, params=params, **options).params
    forward = Keel(axes=6, params=replace(p, motion_bias_sigma=p.offline_motion_bias_sigma))
    g = as_rows("gyro", gyro)
    n = g.shape[0]
    a = as_rows("accel", accel, n)
    use_mag = axes == 9 and mag is not None
    if axes not in (6, 9):
        raise ValueError(f"axes must be 6 or 9, got {axes!r}")
    m = as_rows("mag", mag, n) if use_mag else None
    k = as_rows("known_accel", known_accel, n) if known_accel is not None else None
    s = None if still is None else np.asarray(still, dtype=np.float64).reshape(-1)
    dts = forward._batch_periods(n, dt, timestamps)
    if n == 0:
        return (np.empty((0, 4)), _empty_diagnostics()) if diagnostics else np.empty((0, 4))
    dts = np.broadcast_to(dts, (n,)).copy()

    # 1. Bias, forward and backward, fused by inverse covariance.
    none = np.zeros((0, 3))
    s = np.zeros(0) if s is None else np.ascontiguousarray(s)
    if s.shape not in ((0,), (n,)):
        raise ValueError(f"still must have shape ({n},), got {s.shape}")
    kk = none if k is None else k
    _, fwd = forward._run(g, a, none, False, dts, s, kk, True)
    backward = Keel(axes=6, params=forward.params)
    _, bwd = backward._run(np.ascontiguousarray(-g[::-1]), np.ascontiguousarray(a[::-1]), none,
                           False, _reversed_periods(dts), np.ascontiguousarray(s[::-1]),
                           np.ascontiguousarray(kk[::-1]), True)
    bias, cov = _fuse(fwd.gyro_bias, fwd.bias_covariance,
                      -bwd.gyro_bias[::-1], bwd.bias_covariance[::-1])

    # 2. Gyro frame with the fused bias (rows skipped online are skipped here too:
    # non-finite or faster than max_gyro).
    with np.errstate(over="ignore", invalid="ignore"):
        gyro_ok = np.linalg.norm(g, axis=1) <= p.max_gyro
        acc_norm = np.linalg.norm(a, axis=1)
    dt_int, restart = _integration_periods(dts, gyro_ok, p.max_gap)
    if not gyro_ok.all():
        g = g.copy()
        g[~gyro_ok] = np.nan  # strapdown holds the attitude over them
    valid_acc = (acc_norm > 0.0) & (acc_norm <= p.max_accel)
    first = int(np.argmax(valid_acc)) if np.any(valid_acc) else None
    q_start = quat.from_accel(a[first]) if first is not None else quat.IDENTITY.copy()
    qg = np.empty((n, 4))
    core.strapdown(g, bias, dt_int, q_start, qg)

    # 3. Zero-phase low-pass of the accelerometer in the gyro frame; inclination.
    f = a - k if k is not None else a.copy()
    f[~valid_acc] = np.nan
    acc_i = quat.rotate(qg, f)
    tau = p.offline_accel_time_constant
    once, twice = np.empty((n, 3)), np.empty((n, 3))
    core.lowpass_pass(acc_i, dt_int, restart, tau, once)
    core.lowpass_pass(once[::-1].copy(), _reversed_periods(dt_int),
                      _reversed_periods(restart), tau, twice)
    q6 = np.empty((n, 4))
    core.tilt_corrected(qg, np.ascontiguousarray(twice[::-1]), q6)

    # 4. Heading offset, forward and backward, averaged on the circle.
    delta = np.zeros(n)
    disturbed = np.zeros(n, dtype=bool)
    if use_mag:
        rates = np.where(gyro_ok, np.linalg.norm(g - bias, axis=1), 0.0)  # skipped: no turn
        d_f, x_f = _heading(p, q6, m, rates, dt_int, restart)
        d_b, x_b = _heading(p, q6[::-1], m[::-1], rates[::-1], _reversed_periods(dt_int),
                            _reversed_periods(restart))
        delta = np.arctan2(np.sin(d_f) + np.sin(d_b[::-1]), np.cos(d_f) + np.cos(d_b[::-1]))
        disturbed = x_f | x_b[::-1]
        half = 0.5 * delta
        zeros = np.zeros(n)
        q = quat.multiply(np.column_stack([np.cos(half), zeros, zeros, np.sin(half)]), q6)
    else:
        q = q6
    if not diagnostics:
        return q
    return q, KeelDiagnostics(
        gyro_bias=bias,
        gyro_bias_sigma=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)),
        bias_covariance=cov,
        rest=fwd.rest | bwd.rest[::-1],
        mag_disturbed=disturbed,
        heading_offset=delta,
    )


def _reversed_periods(x: NDArray) -> NDArray:
    """Per-sample "before this sample" values for the time-reversed sequence: reversed sample
    j (original i = N-1-j) follows the interval between originals i and i+1, which is
    ``x[i + 1]``; the first reversed sample has none (0)."""
    out = np.zeros_like(x)
    out[1:] = x[:0:-1]
    return out


def _fuse(b1, p1, b2, p2) -> tuple[NDArray, NDArray]:
    """Inverse-covariance fusion of two estimates per row: (N, 3), (N, 3, 3) each."""
    i1, i2 = np.linalg.inv(p1), np.linalg.inv(p2)
    cov = np.linalg.inv(i1 + i2)
    info = np.einsum("nij,nj->ni", i1, b1) + np.einsum("nij,nj->ni", i2, b2)
    return np.einsum("nij,nj->ni", cov, info), cov


def _integration_periods(dts: NDArray, gyro_ok: NDArray, max_gap: float):
    """The online gap policy, vectorised: (period integrated at each row, restart flag).

    Skipped (non-finite gyro) rows hand their interval on to the next valid row; an interval
    above ``max_gap`` is integrated over the last regular period and flags a restart.
    """
    total = np.cumsum(dts)
    good = np.flatnonzero(gyro_ok)
    dt_int = np.zeros_like(dts)
    if good.size:
        start = np.concatenate([[total[good[0]] - dts[good[0]]], total[good[:-1]]])
        dt_int[good] = total[good] - start
    dt_int[0] = 0.0  # the first sample initialises (as online)
    gap = dt_int > max_gap
    gap[0] = False
    regular = np.where(gap | (dt_int <= 0.0), np.nan, dt_int)
    idx = np.where(np.isfinite(regular), np.arange(len(dts)), 0)
    np.maximum.accumulate(idx, out=idx)
    last_regular = np.where(np.isfinite(regular[idx]), regular[idx], 0.0)
    previous = np.concatenate([[0.0], last_regular[:-1]])
    dt_int[gap] = previous[gap]
    return dt_int, gap


def _heading(params: KeelParams, q6, mag, rates, dt_int, restart):
    est = Keel(axes=9, params=replace(params, sample_period=None))
    out_delta = np.empty(q6.shape[0])
    out_disturbed = np.empty(q6.shape[0])
    core.heading_pass(est._B, np.ascontiguousarray(q6), np.ascontiguousarray(mag),
                      np.ascontiguousarray(rates), np.ascontiguousarray(dt_int),
                      np.ascontiguousarray(restart), out_delta, out_disturbed)
    return out_delta, out_disturbed != 0.0


def _empty_diagnostics() -> KeelDiagnostics:
    return KeelDiagnostics.from_rows(np.empty((0, core.D_LEN)))
