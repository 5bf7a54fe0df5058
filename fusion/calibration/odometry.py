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

The fused EKF takes a radius ratio as its radius-mismatch state's prior
(:func:`radius_mismatch_rate`; robot.toml's ``[ekf] wheel_rate_per_speed``): seed 000's
driver has one ``speed_ratio`` for both wheels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import cumulative_trapezoid

from fusion.geometry.kinematics import DiffDriveParams

__all__ = [
    "RATIO_DRIFT_STD",
    "OdometryCalibration",
    "UmbmarkResult",
    "calibrate_odometry",
    "ekf_radius_lines",
    "radius_mismatch_rate",
    "radius_ratio_from_mismatch",
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
        wheel_distance_std: standard deviation of ``wheel_distance``, m: the fit's (its
            residuals, the stretches between stops as clusters: ``_fit_covariance``) and the
            gyro scale's (``gyro_scale_std`` of :func:`calibrate_odometry`).
        radius_ratio_std: standard deviation of :attr:`radius_ratio` (the fit's), 1.
        windows_saturated: windows left out because the gyro saturated in them.
        windows_not_finite: windows left out because they span an IMU sample that is not a
            finite number (the angle turned across it is unknown).
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
    wheel_distance_std: float = math.nan
    radius_ratio_std: float = math.nan
    windows_saturated: int = 0
    windows_not_finite: int = 0

    @property
    def radius_ratio(self) -> float:
        """Right over left wheel radius (= right over left metres per tick)."""
        return self.right_ratio / self.left_ratio

    @property
    def ekf_radius_mismatch(self) -> tuple[float, float]:
        """``(c, std)`` rad/m: :attr:`radius_ratio` as the EKF's radius mismatch
        (:func:`radius_mismatch_rate`, at the corrected ``wheel_distance``) and its standard
        deviation from :attr:`radius_ratio_std`, at least :data:`RATIO_DRIFT_STD` (the ratio
        moves with load and tyre pressure; the fit's own, 2e-5 on a 120 s run, would pin the
        EKF's state to one run's conditions; review)."""
        r, L = self.radius_ratio, self.wheel_distance
        spread = max(self.radius_ratio_std, RATIO_DRIFT_STD)
        return radius_mismatch_rate(r, L), 4.0 / (L * (1.0 + r) ** 2) * spread

    def params(self) -> DiffDriveParams:
        """The nominal parameters with the corrected ``wheel_distance`` and ``speed_ratio``."""
        return replace(self.nominal, wheel_distance=self.wheel_distance,
                       speed_ratio=self.speed_ratio)

    def report(self) -> str:
        """Human-readable corrections in seed 000's names, ready for robot.toml."""
        n = self.nominal
        lines = [
            "[chassis]",
            f"wheel_distance = {self.wheel_distance:.6g}  # m +- {self.wheel_distance_std:.2g} "
            f"(1 sigma: the fit's and the gyro scale's), was {n.wheel_distance:.6g} "
            f"({100 * (self.wheel_distance / n.wheel_distance - 1):+.2f} %)",
            f"speed_ratio = {self.speed_ratio:.6g}  # m/tick, was {n.speed_ratio:.6g} "
            + (f"({100 * (self.speed_ratio / n.speed_ratio - 1):+.2f} %)"
               if self.scale_from_distance else "(kept: no distance given, a gyro cannot "
               "observe the common scale)"),
            f"# right/left wheel radius ratio {self.radius_ratio:.5f} +- "
            f"{self.radius_ratio_std:.2g}: per wheel "
            f"{self.left_ratio:.6g} (left), {self.right_ratio:.6g} (right) m/tick; "
            "seed 000's driver has one speed_ratio: [ekf] below gives the mismatch to the "
            "fused EKF",
            f"# from {self.windows_used} windows ({self.windows_rejected} rejected as slip"
            + (f", {self.windows_saturated} left out: the gyro saturated"
               if self.windows_saturated else "")
            + (f", {self.windows_not_finite} left out: across IMU samples that are not "
               "finite numbers" if self.windows_not_finite else "")
            + f"), {math.degrees(self.turned):.0f} deg turned, {self.straight_distance:.1f} m "
            f"driven, gyro bias {math.degrees(self.gyro_bias):+.4f} deg/s",
            "[ekf]",
            *ekf_radius_lines(*self.ekf_radius_mismatch),
        ]
        if self.radius_ratio_std > RATIO_STD_NOTE:
            lines.append(
                f"note: the radius ratio is poorly measured (+- {self.radius_ratio_std:.2g}): "
                "it needs straight driving, which this run has little of "
                f"({self.straight_distance:.1f} m of wheel travel in the windows used)")
        total = self.windows_used + self.windows_rejected
        if self.windows_rejected > REJECTED_SHARE * total:
            lines.append(
                f"note: {self.windows_rejected} of {total} windows disagree with the gyro and "
                "were left out: wheels slipping much of the time, or the IMU's stamps off the "
                "wheels' (--imu-lag); the rest still fit, but check the floor and the clocks")
        return "\n".join(lines)


#: The least standard deviation of a calibrated right/left radius ratio handed to the EKF:
#: 0.1 %, as a tyre's rolling radius moves with load and pressure (a value set by hand).
RATIO_DRIFT_STD = 1e-3


def radius_mismatch_rate(radius_ratio: float, wheel_distance: float) -> float:
    """rad/m: the yaw rate per m/s of speed that wheels whose right/left radius ratio is
    ``radius_ratio`` (``r``) read on a straight drive, counted with one metres-per-tick for
    both over ``wheel_distance`` (``L``, m): the fused EKF's radius mismatch ``c``
    (``w_m = (1 + k) w + c v_m``, :func:`fusion.planar.model.wheel_h`; robot.toml's ``[ekf]
    wheel_rate_per_speed``).

    With the true travel per tick ``2/(1 + r)`` (left) and ``2r/(1 + r)`` (right) times
    ``speed_ratio`` (the mean kept, as UMBmark's and ``fusion tune``'s factors), a straight
    drive of ``d`` m per wheel counts ``d (1 + r)/2`` and ``d (1 + r)/(2r)`` nominal metres:
    a turn of ``(1/r - 1) d (1 + r)/(2L)`` over a mean travel of ``d (1 + r)^2/(4r)``, so
    ``c = 2 (1 - r) / ((1 + r) L)`` (about ``-(r - 1)/L``).
    """
    if not (0 < radius_ratio < math.inf and 0 < wheel_distance < math.inf):
        raise ValueError(f"radius_ratio and wheel_distance must be finite and > 0, got "
                         f"{radius_ratio!r} and {wheel_distance!r}")
    return 2.0 * (1.0 - radius_ratio) / ((1.0 + radius_ratio) * wheel_distance)


def radius_ratio_from_mismatch(mismatch: float, wheel_distance: float) -> float:
    """The right/left wheel radius ratio whose :func:`radius_mismatch_rate` over
    ``wheel_distance`` (m) is ``mismatch`` (rad/m): ``r = (2 - c L)/(2 + c L)``."""
    cl = mismatch * wheel_distance
    if not (abs(cl) < 2.0 and wheel_distance > 0):
        raise ValueError(f"no radius ratio gives a mismatch of {mismatch!r} rad/m over "
                         f"{wheel_distance!r} m")
    return (2.0 - cl) / (2.0 + cl)


def ekf_radius_lines(c: float, std: float = math.nan) -> list[str]:
    """robot.toml ``[ekf]`` lines (without the header) giving the EKF the radius mismatch
    ``c`` (rad/m), and ``std`` (rad/m) as its prior's standard deviation when it is known."""
    lines = [f"wheel_rate_per_speed = {c:.6g}  # rad/m: the radius ratio's yaw rate per m/s "
             "(the EKF's radius mismatch, learnt on from there)"]
    if math.isfinite(std) and std > 0:
        lines.append(f"calib_c_std = {std:.2g}  # rad/m: the calibration's standard deviation")
    return lines


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
    saturated: ArrayLike | None = None,
    gyro_scale_std: float = 0.0,
    max_change: float = 0.5,
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
        saturated: (N,) bool per IMU sample, the gyro at its full scale
            (:func:`fusion.calibration.gyro_limits.saturated_samples`): the windows whose
            heading integral uses one are left out. A ``gyro_z`` that is NaN or infinite
            (a corrupt log row) is dropped, and so are the windows across it.
        gyro_scale_std: relative standard deviation of the gyro's scale (robot.toml's
            ``[ekf] gyro_scale_std``): ``wheel_distance`` inherits it.
        max_change: a ``wheel_distance`` further than this share from ``robot``'s is refused
            (no robot.toml is 50 % off; the gyro's units, or wheels slipping most of the
            time, are).

    The fit starts from the least median of squares over pairs of windows (half the windows
    may slip, and the start still sees the others), then rejects residuals beyond
    ``outlier_sigma`` robust standard deviations and refits, until the set holds.

    Returns:
        :class:`OdometryCalibration`.

    Raises:
        ValueError: too little data, no standstill for the bias, no turning at all (saying
            how many windows the gyro's saturation took), wheels turning opposite to the
            gyro (left and right swapped), or a ``wheel_distance`` beyond ``max_change``.
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
    clipped = (np.zeros(it.size, dtype=bool) if saturated is None
               else np.asarray(saturated, dtype=bool).reshape(-1))
    if clipped.size != it.size:
        raise ValueError(f"saturated has {clipped.size} flags for {it.size} IMU samples")
    # a non-finite sample is dropped; its kept neighbours mark the windows across the hole
    bad = ~(np.isfinite(gz) & np.isfinite(it))
    near_bad = (np.concatenate(([False], bad[:-1])) | np.concatenate((bad[1:], [False])))[~bad]
    it, gz, clipped = it[~bad], gz[~bad], clipped[~bad]
    if it.size < 10:
        raise ValueError(f"too little data: {it.size} finite IMU samples")
    T = robot.encode_sampling_time
    bias, phase_mids = rest_bias(it, gz, wt, tk, T, latency=latency)
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
    hit_clipped = _windows_using(clipped, it, W)
    hit_bad = _windows_using(near_bad, it, W) & ~hit_clipped
    n_saturated, n_not_finite = int(hit_clipped.sum()), int(hit_bad.sum())
    W = W[~(hit_clipped | hit_bad)]
    if len(W) < 4:
        advice = ("each IMU sample that is not a number costs the windows across it: repair "
                  "imu.csv or record the run again" if n_not_finite > n_saturated
                  else "record a longer run, turning slower")
        raise ValueError(f"only {len(W)} usable windows ({n_saturated} left out because the "
                         f"gyro saturated in them, {n_not_finite} across IMU samples that "
                         f"are not finite numbers); {advice}")
    dpsi = np.interp(W[:, 1], it, G) - np.interp(W[:, 0], it, G)
    A = np.column_stack([W[:, 3], -W[:, 2]])  # dpsi = a*NR - b*NL
    keep = _least_median_start(A, dpsi, outlier_sigma)
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
        left_out = (f" ({n_saturated} windows were left out because the gyro saturated in "
                    "them: turn slower)" if n_saturated else "")
        raise ValueError(f"only {math.degrees(turned):.0f} deg of turning in the usable windows"
                         f"{left_out}; the separation is not observable: turn more")
    if a < 0 and b < 0:
        raise ValueError(f"the wheels turn the robot opposite to the gyro (wheel factors a={a:g}, "
                         f"b={b:g} per tick, both negative): left and right are swapped in the "
                         "wheel log, or the IMU's mount (imu_mount_rpy) turns it upside down")
    if not (a > 0 and b > 0):
        raise ValueError(f"the fit gave non-physical wheel factors a={a:g}, b={b:g} (1/tick): "
                         "the run needs turns in both directions and straight driving")
    cov = _fit_covariance(A[keep], dpsi[keep] - A[keep] @ sol, W[keep], phase_mids)
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
    L = s_r / a  # = 2 s / (a + b)
    change = L / robot.wheel_distance - 1.0
    if abs(change) > max_change:
        units = (" The ratio is pi/180's: the gyro is in deg/s, not rad/s."
                 if abs(L / robot.wheel_distance * 180.0 / math.pi - 1.0) < 0.1 else "")
        raise ValueError(
            f"the fit gives wheel_distance {L:.4g} m, {100 * change:+.0f} % from robot.toml's "
            f"{robot.wheel_distance:.4g} m, beyond max_change ({100 * max_change:g} %): "
            "likelier the gyro's units, wheels slipping much of the time, or the wrong "
            f"robot.toml (the residuals spread by {math.degrees(sigma):.2g} deg per window)."
            f"{units} Nothing was written; if robot.toml's value was a placeholder, allow "
            "more (--max-change in fusion calibrate odometry)")
    var_sum = cov[0, 0] + cov[1, 1] + 2.0 * cov[0, 1]
    L_std = L * math.sqrt(var_sum / (a + b) ** 2 + gyro_scale_std ** 2)
    # rho = a/b: d rho = (da - rho db)/b
    rho_std = math.sqrt(max(cov[0, 0] - 2 * rho * cov[0, 1] + rho * rho * cov[1, 1], 0.0)) / b
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
        wheel_distance_std=float(L_std),
        radius_ratio_std=float(rho_std),
        windows_saturated=n_saturated,
        windows_not_finite=n_not_finite,
    )


def _windows_using(flags: NDArray[np.bool_], it: NDArray[np.float64],
                   windows: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which windows' heading integral uses a flagged IMU sample: the integral over
    ``[t0, t1]`` interpolates from the last sample before ``t0`` to the first after ``t1``."""
    count = np.concatenate(([0], np.cumsum(flags)))
    lo = np.searchsorted(it, windows[:, 0])
    hi = np.searchsorted(it, windows[:, 1], side="right")
    return count[np.minimum(hi + 1, it.size)] - count[np.maximum(lo - 1, 0)] > 0


#: above this share of the windows rejected, the report says what else than slip does it
REJECTED_SHARE = 0.3
#: above this standard deviation of the radius ratio, the report says it needs straights
RATIO_STD_NOTE = 0.01
#: rad: windows turning by more than this angle (by the gyro) tell the separation
#: (_least_median_start); the other moving windows tell the radius ratio
TURNING_WINDOW_ANGLE = math.radians(5.0)
#: candidate fits of _least_median_start at most (pairs drawn with a fixed seed beyond)
MAX_CANDIDATES = 20_000


def _fit_covariance(A: NDArray[np.float64], res: NDArray[np.float64],
                    windows: NDArray[np.float64],
                    phase_mids: NDArray[np.float64]) -> NDArray[np.float64]:
    """(2, 2) covariance of the fit's ``(a, b)`` from the windows kept: rows ``A``, residuals
    ``res`` (rad), ``windows`` (their ``t0, t1`` in the first two columns, s), and the
    mid-times of the standstill phases the bias was taken from (s).

    The larger (in the variance of ``a + b``, which ``wheel_distance`` follows) of the
    classical ``s^2 (A'A)^-1`` and the cluster-robust sandwich with the windows between two
    standstill phases as one cluster: the bias is interpolated between phases, so its error is
    shared by every window of a stretch, and windows taken as independent understated the
    standard deviation of wheel_distance by 1.6 to 1.8 (RMS of error/std over simulated
    missions; 1.0 and 1.1 with this). The classical one where there are fewer than two
    stretches, or where the clusters' estimate, noisy with few of them, is the smaller. Stop
    windows (rows of zeros) tell nothing and do not count; the model has no intercept.
    """
    informative = np.any(A != 0.0, axis=1)
    A, res, windows = A[informative], res[informative], windows[informative]
    n = res.size
    if n <= 2:
        return np.zeros((2, 2))
    inv = np.linalg.inv(A.T @ A)
    cov = inv * float(res @ res) / (n - 2)
    cluster = np.searchsorted(phase_mids, 0.5 * (windows[:, 0] + windows[:, 1]))
    groups = np.unique(cluster)
    if groups.size < 2:
        return cov
    meat = np.zeros((2, 2))
    for c in groups:
        score = A[cluster == c].T @ res[cluster == c]
        meat += np.outer(score, score)
    robust = inv @ meat @ inv * groups.size / (groups.size - 1) * (n - 1) / (n - 2)
    ones = np.ones(2)
    return robust if ones @ robust @ ones > ones @ cov @ ones else cov


def _least_median_start(A: NDArray[np.float64], y: NDArray[np.float64],
                        outlier_sigma: float) -> NDArray[np.bool_]:
    """The windows to start the fit ``y = A @ sol`` (2 unknowns) with, chosen so that half
    the windows of each kind may slip without pulling the start: an independent probe's
    wheel spinning 40 % of the time gave a least-squares wheel_distance 87 % off, and every
    window within 5 sigma of that fit.

    Turning windows (``|y| > TURNING_WINDOW_ANGLE``) tell the separation; straight ones the radius
    ratio, which turns in place leave open; stops (no ticks) tell neither and are kept.
    Each candidate solves a pair of windows (turning with turning or with straight: all such
    pairs up to :data:`MAX_CANDIDATES`); the start is the candidate with the least sum of the
    median squared residual over the turning windows and over the straight ones (a median
    per kind: straights, often the majority, fit any separation). The windows within
    ``outlier_sigma`` robust standard deviations of it, each kind against its own, are the
    start. All windows with fewer than 6 turning ones."""
    n = len(y)
    moving = np.any(A != 0.0, axis=1)
    turning = np.flatnonzero(moving & (np.abs(y) > TURNING_WINDOW_ANGLE))
    straight = np.flatnonzero(moving & (np.abs(y) <= TURNING_WINDOW_ANGLE))
    if turning.size < 6:
        return np.ones(n, dtype=bool)
    pairs = turning.size * (turning.size - 1) // 2 + turning.size * straight.size
    if pairs <= MAX_CANDIDATES:
        ti, tj = np.triu_indices(turning.size, k=1)
        i = np.concatenate([turning[ti], np.repeat(turning, straight.size)])
        j = np.concatenate([turning[tj], np.tile(straight, turning.size)])
    else:  # drawn, never all built: a long log has millions of pairs
        rng = np.random.default_rng(0)
        i = turning[rng.integers(0, turning.size, MAX_CANDIDATES)]
        others = np.concatenate([turning, straight])
        j = others[rng.integers(0, others.size, MAX_CANDIDATES)]
        distinct = i != j
        i, j = i[distinct], j[distinct]
    det = A[i, 0] * A[j, 1] - A[i, 1] * A[j, 0]
    ok = np.abs(det) > 1e-12 * (np.abs(A[i]).max(axis=1) * np.abs(A[j]).max(axis=1))
    if not ok.any():
        return np.ones(n, dtype=bool)
    i, j, det = i[ok], j[ok], det[ok]
    a = (y[i] * A[j, 1] - A[i, 1] * y[j]) / det
    b = (A[i, 0] * y[j] - y[i] * A[j, 0]) / det

    def median_squares(rows, cand):
        res = y[rows][None, :] - np.outer(a[cand], A[rows, 0]) - np.outer(b[cand], A[rows, 1])
        return np.median(res ** 2, axis=1) if rows.size else np.zeros(res.shape[0])

    best, best_k = np.inf, 0
    for start in range(0, a.size, 2000):  # (candidates x windows) in blocks
        cand = np.arange(start, min(start + 2000, a.size))
        score = median_squares(turning, cand) + median_squares(straight, cand)
        k = int(np.argmin(score))
        if score[k] < best:
            best, best_k = float(score[k]), int(cand[k])
    res = y - A[:, 0] * a[best_k] - A[:, 1] * b[best_k]
    keep = np.ones(n, dtype=bool)
    for rows in (turning, straight):
        if rows.size > 2:
            # Rousseeuw's scale of LMedS residuals, with its small-sample correction
            scale = 1.4826 * (1.0 + 5.0 / (rows.size - 2)) * math.sqrt(
                float(np.median(res[rows] ** 2)))
            keep[rows] = np.abs(res[rows]) <= outlier_sigma * max(scale, 1e-12)
    return keep


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
