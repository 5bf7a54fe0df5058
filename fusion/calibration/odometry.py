"""Wheel-odometry calibration: separation and wheel-radius ratio from the gyro, and UMBmark.

Units: m, m/tick, s, rad, rad/s. Parameter names are seed 000's: ``wheel_distance`` (L, m),
``speed_ratio`` (m of wheel travel per tick), ``encode_sampling_time`` (T, s).

Gyro-referenced calibration (:func:`calibrate_odometry`)
    Over a window of consecutive wheel frames the robot turns by
    ``dpsi = (NR*s_r - NL*s_l)/L`` (``NL``, ``NR`` ticks, ``s_l``, ``s_r`` the true metres per
    tick of each wheel, ``L`` the true separation). The gyro measures ``dpsi`` directly (its
    bias taken from the standstill phases, interpolated in time), so a linear least-squares fit
    of ``dpsi = a*NR - b*NL`` over many windows gives ``a = s_r/L`` and ``b = s_l/L``; windows
    whose residual is an outlier (wheel slip) are rejected iteratively. The radius ratio is
    ``s_r/s_l = a/b``. What a gyro cannot see is the common scale: ``L`` comes out in units of
    the mean metres per tick, so the result keeps the nominal ``speed_ratio`` unless a distance
    is given (a measured straight run, or a ground-truth trajectory), from which
    ``speed_ratio`` is re-estimated too. The accuracy of ``wheel_distance`` is that of the
    gyro's scale factor (MPU6050: +-3 % uncalibrated): calibrate the gyro scale first (a few
    full turns against a known heading).

UMBmark (:func:`umbmark`)
    J. Borenstein, L. Feng, "Measurement and correction of systematic odometry errors in mobile
    robots", IEEE Trans. Robotics and Automation 12(6), 1996. Square runs of side ``S``
    clockwise and counter-clockwise; the centres of gravity of the return-position errors
    (absolute minus odometry) give the type A (wheelbase) error ``alpha`` and the type B
    (unequal diameters) error ``beta``, from which ``E_d = D_R/D_L`` and the wheelbase factor
    ``E_b`` follow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import cumulative_trapezoid

from fusion.geometry.kinematics import DiffDriveParams

__all__ = [
    "OdometryCalibration",
    "UmbmarkResult",
    "calibrate_odometry",
    "rest_bias",
    "umbmark",
]


@dataclass(frozen=True)
class OdometryCalibration:
    """Result of :func:`calibrate_odometry`.

    Attributes:
        nominal: the parameters the run was recorded with.
        wheel_distance: corrected separation, m.
        speed_ratio: mean metres per tick of the two wheels (the nominal value unless a
            distance was given), m/tick.
        left_ratio, right_ratio: metres per tick of each wheel, m/tick.
        gyro_bias: mean gyro bias over the run, rad/s.
        windows_used, windows_rejected: windows in the fit and rejected as outliers (slip).
        residual_std: robust standard deviation of the fit residuals, rad per window.
        turned: total absolute rotation in the used windows, rad (the fit's leverage on L).
        straight_distance: wheel travel in the used windows, m (the leverage on the ratio).
        scale_from_distance: whether ``speed_ratio`` was re-estimated from a distance.
    """

    nominal: DiffDriveParams
    wheel_distance: float
    speed_ratio: float
    left_ratio: float
    right_ratio: float
    gyro_bias: float
    windows_used: int
    windows_rejected: int
    residual_std: float
    turned: float
    straight_distance: float
    scale_from_distance: bool

    @property
    def radius_ratio(self) -> float:
        """Right over left wheel radius (= right over left metres per tick)."""
        return self.right_ratio / self.left_ratio

    def params(self) -> DiffDriveParams:
        """The nominal parameters with the corrected ``wheel_distance`` and ``speed_ratio``."""
        return replace(self.nominal, wheel_distance=self.wheel_distance,
                       speed_ratio=self.speed_ratio)

    def report(self) -> str:
        """Human-readable corrections in seed 000's names, ready for robot.toml."""
        n = self.nominal
        lines = [
            "[chassis]",
            f"wheel_distance = {self.wheel_distance:.6g}  # m, was {n.wheel_distance:.6g} "
            f"({100 * (self.wheel_distance / n.wheel_distance - 1):+.2f} %)",
            f"speed_ratio = {self.speed_ratio:.6g}  # m/tick, was {n.speed_ratio:.6g} "
            + (f"({100 * (self.speed_ratio / n.speed_ratio - 1):+.2f} %)"
               if self.scale_from_distance else "(kept: no distance given, a gyro cannot "
               "observe the common scale)"),
            f"# right/left wheel radius ratio {self.radius_ratio:.5f}: per wheel "
            f"{self.left_ratio:.6g} (left), {self.right_ratio:.6g} (right) m/tick; "
            "seed 000's driver has one speed_ratio, the fused EKF estimates the mismatch "
            "online",
            f"# from {self.windows_used} windows ({self.windows_rejected} rejected as slip), "
            f"{math.degrees(self.turned):.0f} deg turned, {self.straight_distance:.1f} m "
            f"driven, gyro bias {math.degrees(self.gyro_bias):+.4f} deg/s",
        ]
        return "\n".join(lines)


def rest_bias(
    imu_t: ArrayLike, gyro_z: ArrayLike, wheel_t: ArrayLike, ticks: ArrayLike, period: float,
    min_frames: int = 5, latency: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gyro bias (rad/s) at each IMU sample from the standstill phases.

    A standstill phase is a run of at least ``min_frames`` consecutive wheel frames with zero
    ticks on both wheels; the gyro mean over each phase is its bias, linearly interpolated in
    time between phases (constant before the first and after the last).

    Returns:
        ``(bias, phase_times)``: bias per IMU sample and the mid-times of the phases used.

    Raises:
        ValueError: no standstill phase (record a few seconds at rest, at least at the start).
    """
    it = np.asarray(imu_t, dtype=float)
    gz = np.asarray(gyro_z, dtype=float)
    wt = np.asarray(wheel_t, dtype=float)
    tk = np.asarray(ticks).reshape(-1, 2)
    still = np.all(tk == 0, axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(int), [0]))))
    mids, values = [], []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start < min_frames:
            continue
        # skip the first frame of a phase: the robot may still have been settling
        t0 = wt[start + 1] - period - latency
        t1 = wt[stop - 1] - latency
        sel = (it >= t0) & (it <= t1)
        if sel.sum() < 10:
            continue
        mids.append(0.5 * (t0 + t1))
        values.append(float(np.mean(gz[sel])))
    if not mids:
        raise ValueError(
            f"no standstill of at least {min_frames} wheel frames with zero ticks: the gyro "
            "bias cannot be measured; record a few seconds at rest (at least at the start)"
        )
    return np.interp(it, mids, values), np.asarray(mids)


def calibrate_odometry(
    imu_t: ArrayLike,
    gyro_z: ArrayLike,
    wheel_t: ArrayLike,
    ticks: ArrayLike,
    robot: DiffDriveParams,
    distance: float | None = None,
    truth_t: ArrayLike | None = None,
    truth: ArrayLike | None = None,
    window: int = 25,
    latency: float = 0.0,
    outlier_sigma: float = 5.0,
) -> OdometryCalibration:
    """Estimate ``wheel_distance`` and the wheel-radius ratio with the gyro as reference.

    Args:
        imu_t, gyro_z: gyro stamps (s) and rates about the vertical (rad/s).
        wheel_t, ticks: wheel frame stamps (s, end of period) and (M, 2) ticks per period.
        robot: the parameters the run was recorded with (``encode_sampling_time`` is used as
            the period; ``speed_ratio`` as the scale unless a distance is given).
        distance: path length of the axle centre over the whole run, m (all frames are
            assumed received), to re-estimate ``speed_ratio``.
        truth_t, truth: ground-truth trajectory (s; x, y m) to re-estimate ``speed_ratio``
            from the distance travelled inside the windows used (robust to drops and slip).
        window: wheel frames per fitting window (frames must be consecutive inside a window).
        latency: transport delay from the end of a period to its stamp, s.
        outlier_sigma: rejection threshold in robust standard deviations.

    Returns:
        :class:`OdometryCalibration`.

    Raises:
        ValueError: too little data, no standstill for the bias, or no turning at all.
    """
    it = np.asarray(imu_t, dtype=float).reshape(-1)
    gz = np.asarray(gyro_z, dtype=float).reshape(-1)
    wt = np.asarray(wheel_t, dtype=float).reshape(-1)
    tk = np.asarray(ticks).reshape(-1, 2).astype(float)
    if it.size != gz.size or wt.size != tk.shape[0]:
        raise ValueError("imu_t/gyro_z and wheel_t/ticks must have matching lengths")
    if it.size < 10 or wt.size < 2 * window:
        raise ValueError(f"too little data: {it.size} IMU samples, {wt.size} wheel frames "
                         f"(need >= {2 * window})")
    if window < 1:
        raise ValueError(f"window must be >= 1 frame, got {window}")
    T = robot.encode_sampling_time
    bias, _ = rest_bias(it, gz, wt, tk, T, latency=latency)
    rate = gz - bias
    # cumulative heading from the gyro (trapezoid), exact for a piecewise-linear rate
    G = cumulative_trapezoid(rate, it, initial=0.0)

    # windows of consecutive frames (a gap > 1.5 periods starts a new run)
    gap = np.diff(wt) > 1.5 * T
    run_id = np.concatenate(([0], np.cumsum(gap)))
    rows = []
    for r in np.unique(run_id):
        idx = np.flatnonzero(run_id == r)
        for s in range(0, idx.size - window + 1, window):
            w = idx[s:s + window]
            t0 = wt[w[0]] - T - latency
            t1 = wt[w[-1]] - latency
            if t0 < it[0] or t1 > it[-1]:
                continue
            nl, nr = tk[w, 0].sum(), tk[w, 1].sum()
            abs_d = np.abs(0.5 * (tk[w, 0] + tk[w, 1])).sum()
            rows.append((t0, t1, nl, nr, abs_d))
    if len(rows) < 4:
        raise ValueError(f"only {len(rows)} usable windows of {window} frames overlap the IMU "
                         "data; record a longer run")
    W = np.array(rows)
    dpsi = np.interp(W[:, 1], it, G) - np.interp(W[:, 0], it, G)
    A = np.column_stack([W[:, 3], -W[:, 2]])  # dpsi = a*NR - b*NL
    keep = np.ones(len(W), dtype=bool)
    sigma = math.inf
    for _ in range(10):
        sol, *_ = np.linalg.lstsq(A[keep], dpsi[keep], rcond=None)
        res = dpsi - A @ sol
        mad = np.median(np.abs(res[keep] - np.median(res[keep])))
        sigma = max(1.4826 * mad, 1e-9)
        new_keep = np.abs(res) <= outlier_sigma * sigma
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    a, b = float(sol[0]), float(sol[1])
    turned = float(np.abs(dpsi[keep]).sum())
    if turned < math.radians(90):
        raise ValueError(f"only {math.degrees(turned):.0f} deg of turning in the usable windows; "
                         "the separation is not observable: turn more")
    if not (a > 0 and b > 0):
        raise ValueError(f"the fit gave non-physical wheel factors a={a:g}, b={b:g} (1/tick): "
                         "the run needs turns in both directions and straight driving")
    rho = a / b  # s_r / s_l
    scale_known = distance is not None or truth_t is not None
    if truth_t is not None:
        tt = np.asarray(truth_t, dtype=float)
        tr = np.asarray(truth, dtype=float).reshape(-1, 3)
        seg = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(tr[:, :2], axis=0).T))))
        inside = keep & (W[:, 0] >= tt[0]) & (W[:, 1] <= tt[-1])
        d_true = np.interp(W[inside, 1], tt, seg) - np.interp(W[inside, 0], tt, seg)
        ticks_path = _mean_abs_ticks(tk, wt, W[inside], rho, T, latency)
        s = float(d_true.sum() / ticks_path)
    elif distance is not None:
        if not distance > 0:
            raise ValueError(f"distance must be > 0 m, got {distance!r}")
        path_ticks = np.abs((tk[:, 0] + rho * tk[:, 1]) / (1.0 + rho)).sum()
        s = float(distance / path_ticks)
    else:
        s = robot.speed_ratio
    s_l = 2.0 * s / (1.0 + rho)
    s_r = 2.0 * s * rho / (1.0 + rho)
    L = s_r / a
    return OdometryCalibration(
        nominal=robot,
        wheel_distance=float(L),
        speed_ratio=s,
        left_ratio=float(s_l),
        right_ratio=float(s_r),
        gyro_bias=float(np.mean(bias)),
        windows_used=int(keep.sum()),
        windows_rejected=int((~keep).sum()),
        residual_std=float(sigma),
        turned=turned,
        straight_distance=float(W[keep, 4].sum() * s),
        scale_from_distance=scale_known,
    )


def _mean_abs_ticks(tk, wt, windows, rho, T, latency) -> float:
    """Sum over the windows of |(NL + rho*NR)/(1 + rho)| frame by frame (ticks of path)."""
    total = 0.0
    centre = (tk[:, 0] + rho * tk[:, 1]) / (1.0 + rho)
    for t0, t1, *_ in windows:
        sel = (wt - T - latency >= t0 - 1e-9) & (wt - latency <= t1 + 1e-9)
        total += np.abs(centre[sel]).sum()
    return float(total)


@dataclass(frozen=True)
class UmbmarkResult:
    """UMBmark analysis (Borenstein & Feng 1996).

    Attributes:
        alpha: type A (wheelbase) error, rad.
        beta: type B (unequal wheel diameters) error, rad.
        diameter_ratio: ``E_d = D_R/D_L``, the right over left wheel diameter.
        wheelbase_factor: ``E_b``; the actual wheelbase is ``E_b * wheel_distance``.
        wheel_distance: corrected separation, m.
        left_factor, right_factor: factors on each wheel's metres per tick that keep the mean
            (``c_L = 2/(E_d + 1)``, ``c_R = 2/(1/E_d + 1)``).
        cw_centre, ccw_centre: centres of gravity of the return errors (x, y), m.
        max_error: the UMBmark figure of merit, ``max(r_cw, r_ccw)``, m.
    """

    alpha: float
    beta: float
    diameter_ratio: float
    wheelbase_factor: float
    wheel_distance: float
    left_factor: float
    right_factor: float
    cw_centre: tuple[float, float]
    ccw_centre: tuple[float, float]
    max_error: float


def umbmark(cw_errors: ArrayLike, ccw_errors: ArrayLike, side: float,
            wheel_distance: float) -> UmbmarkResult:
    """Systematic odometry errors from UMBmark square runs.

    Args:
        cw_errors, ccw_errors: (n, 2) return-position errors ``absolute - odometry`` (m) of the
            clockwise and counter-clockwise runs, in the frame of the start pose (x along the
            first leg, y to its left).
        side: side length of the square, m (Borenstein: 4 m).
        wheel_distance: nominal wheelbase the odometry used, m.
    """
    cw = np.asarray(cw_errors, dtype=float).reshape(-1, 2)
    ccw = np.asarray(ccw_errors, dtype=float).reshape(-1, 2)
    if cw.shape[0] < 1 or ccw.shape[0] < 1 or not side > 0 or not wheel_distance > 0:
        raise ValueError("need at least one run in each direction, side > 0 and "
                         "wheel_distance > 0")
    x_cw, y_cw = cw.mean(axis=0)
    x_ccw, y_ccw = ccw.mean(axis=0)
    # Borenstein & Feng's paper states x along the first leg with the CW square turning right;
    # eqs. (5.9)-(5.10) with the x components (the y components give the same to first order).
    alpha = (x_cw + x_ccw) / (-4.0 * side)
    beta = (x_cw - x_ccw) / (-4.0 * side)
    if beta == 0.0:
        ed = 1.0
    else:
        R = (side / 2.0) / math.sin(beta / 2.0)
        ed = (R + wheel_distance / 2.0) / (R - wheel_distance / 2.0)
    eb = (math.pi / 2.0) / (math.pi / 2.0 - alpha)
    r_cw = float(np.hypot(x_cw, y_cw))
    r_ccw = float(np.hypot(x_ccw, y_ccw))
    return UmbmarkResult(
        alpha=float(alpha),
        beta=float(beta),
        diameter_ratio=float(ed),
        wheelbase_factor=float(eb),
        wheel_distance=float(eb * wheel_distance),
        left_factor=2.0 / (ed + 1.0),
        right_factor=2.0 / (1.0 / ed + 1.0),
        cw_centre=(float(x_cw), float(y_cw)),
        ccw_centre=(float(x_ccw), float(y_ccw)),
        max_error=max(r_cw, r_ccw),
    )
