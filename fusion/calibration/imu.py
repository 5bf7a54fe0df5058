"""IMU calibration: gyroscope bias at rest, accelerometer offset and scale from static poses.

Units: inputs and stored values are SI, body (sensor) frame: angular rate rad/s, specific force
m/s^2. The model applied to a measurement is::

    gyro_corrected  = gyro - gyro_bias                          (rad/s)
    accel_corrected = (accel - accel_offset) * accel_scale       (m/s^2, per axis)

an axis-aligned model (no cross-axis terms): offset and scale per axis, the six numbers a set of
static poses determines well. Calibrations are saved as a small JSON file
(:mod:`fusion.io.imu_calibration`), and ``drivers.mpu6050.MPU6050(calibration=...)`` applies them.

Default thresholds of the "at rest" check come from the bundled raw MPU6050 recordings
(``datasets/mpu6050_raw``, DLPF 0, 100 Hz): at rest the gyro's per-sample standard deviation is
0.07-0.13 deg/s per axis and the accelerometer's 0.003-0.005 g; over 0.5 s windows the means
move by less than 0.05 deg/s and 0.002 g. The limits below (0.5 deg/s window std, 0.5 deg/s
change of a window mean, 0.02 g for the accelerometer) sit four to ten times above that noise
and well below what handling the sensor produces (several deg/s, 0.1 g).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.types.constants import STANDARD_GRAVITY
from fusion.types.samples import ImuSample

__all__ = [
    "AccelFit",
    "ImuCalibration",
    "SensorMovingError",
    "calibrate",
    "calibrate_recordings",
    "check_at_rest",
    "fit_accel_poses",
    "gyro_bias_at_rest",
    "pose_means",
    "static_segments",
]

_FORMAT = "diffbot-fusion imu calibration"
_DEG = math.pi / 180.0


class SensorMovingError(ValueError):
    """The sensor was not at rest during a calibration that needs it still."""


@dataclass(frozen=True)
class ImuCalibration:
    """Gyro bias and accelerometer offset/scale, SI units, body frame.

    Attributes:
        gyro_bias: (3,) rad/s, subtracted from the gyro.
        accel_offset: (3,) m/s^2, subtracted from the accelerometer before scaling.
        accel_scale: (3,) dimensionless, multiplies the offset-corrected accelerometer.
        info: free-form provenance (sample counts, residuals, source files), JSON-serialisable.
    """

    gyro_bias: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    accel_offset: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    accel_scale: NDArray[np.float64] = field(default_factory=lambda: np.ones(3))
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("gyro_bias", "accel_offset", "accel_scale"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"ImuCalibration.{name} must be 3 finite numbers; got {v!r}")
            object.__setattr__(self, name, v)
        if np.any(self.accel_scale <= 0):
            raise ValueError(f"ImuCalibration.accel_scale must be > 0; got {self.accel_scale}")

    def apply_gyro(self, gyro: ArrayLike) -> NDArray[np.float64]:
        """Bias-corrected angular rate, rad/s; ``gyro`` is (..., 3) rad/s."""
        return np.asarray(gyro, dtype=float) - self.gyro_bias

    def apply_accel(self, accel: ArrayLike) -> NDArray[np.float64]:
        """Corrected specific force, m/s^2; ``accel`` is (..., 3) m/s^2."""
        return (np.asarray(accel, dtype=float) - self.accel_offset) * self.accel_scale

    def apply(self, sample: ImuSample) -> ImuSample:
        """A copy of ``sample`` with gyro and accelerometer corrected."""
        return ImuSample(sample.t, self.apply_gyro(sample.gyro), self.apply_accel(sample.accel),
                         sample.mag, sample.temperature)

    def with_gyro_bias(self, gyro_bias: ArrayLike) -> ImuCalibration:
        """The same calibration with a new gyro bias (rad/s)."""
        return ImuCalibration(np.asarray(gyro_bias, dtype=float), self.accel_offset,
                              self.accel_scale, dict(self.info))

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": _FORMAT,
            "version": 1,
            "units": {"gyro_bias": "rad/s", "accel_offset": "m/s^2", "accel_scale": "1"},
            "gyro_bias": [float(v) for v in self.gyro_bias],
            "accel_offset": [float(v) for v in self.accel_offset],
            "accel_scale": [float(v) for v in self.accel_scale],
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "calibration") -> ImuCalibration:
        if d.get("format") != _FORMAT:
            raise ValueError(f"{source}: not an IMU calibration file (format {d.get('format')!r})")
        if d.get("version") != 1:
            raise ValueError(f"{source}: unsupported calibration version {d.get('version')!r}")
        try:
            return cls(d["gyro_bias"], d["accel_offset"], d["accel_scale"], d.get("info", {}))
        except KeyError as exc:
            raise ValueError(f"{source}: missing key {exc.args[0]!r}") from None
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None


def _rows(name: str, a: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be an (N, 3) array; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


def _windows(x: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    m = len(x) // n
    return x[: m * n].reshape(m, n, x.shape[1])


def check_at_rest(
    gyro: ArrayLike,
    accel: ArrayLike | None,
    fs_hz: float,
    *,
    window_s: float = 0.5,
    max_gyro_std_dps: float = 0.5,
    max_gyro_drift_dps: float = 0.5,
    max_accel_std_g: float = 0.02,
    max_accel_drift_g: float = 0.02,
    gravity: float = STANDARD_GRAVITY,
) -> None:
    """Raise ``SensorMovingError`` unless the sensor was still throughout.

    ``gyro`` (N, 3) rad/s and ``accel`` (N, 3) m/s^2 (or None) sampled at ``fs_hz``. The data
    are cut in windows of ``window_s``; in every window the standard deviation of each axis
    must stay below ``max_*_std`` and the window mean within ``max_*_drift`` of the median of
    all window means (a slow steady turn has a small std but a shifted mean only if it
    changes; a constant turn cannot be told from a bias by any rest test). The message names
    the first offending window's time, axis and value.
    """
    g = _rows("gyro", gyro) / _DEG
    a = None if accel is None else _rows("accel", accel) / gravity
    if a is not None and len(a) != len(g):
        raise ValueError(f"gyro and accel lengths differ: {len(g)} vs {len(a)}")
    n = max(2, round(window_s * fs_hz))
    if len(g) < 2 * n:
        raise ValueError(
            f"need at least {2 * n} samples ({2 * window_s} s at {fs_hz} Hz) at rest; got {len(g)}"
        )
    checks = [("gyro", g, "deg/s", max_gyro_std_dps, max_gyro_drift_dps)]
    if a is not None:
        checks.append(("accelerometer", a, "g", max_accel_std_g, max_accel_drift_g))
    for label, x, unit, max_std, max_drift in checks:
        w = _windows(x, n)
        std = w.std(axis=1)
        mean = w.mean(axis=1)
        drift = np.abs(mean - np.median(mean, axis=0))
        for what, value, limit in (("standard deviation", std, max_std),
                                   ("mean change", drift, max_drift)):
            bad = np.argwhere(value > limit)
            if len(bad):
                i, axis = bad[0]
                raise SensorMovingError(
                    f"the sensor moved: {label} {what} on {'xyz'[axis]} is "
                    f"{value[i, axis]:.3g} {unit} in {i * n / fs_hz:.1f}-{(i + 1) * n / fs_hz:.1f} "
                    f"s (limit {limit:g} {unit}; {int((value > limit).any(axis=1).sum())} of "
                    f"{len(w)} windows exceed it). Keep the sensor still (motors off) and retry"
                )


def gyro_bias_at_rest(
    gyro: ArrayLike, accel: ArrayLike | None, fs_hz: float, **limits: float
) -> NDArray[np.float64]:
    """Gyro bias (3,) rad/s: the mean rate of a recording at rest.

    ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s^2 or None, ``fs_hz`` the sample rate. Refuses
    with ``SensorMovingError`` when ``check_at_rest`` (same keyword limits) finds motion.
    """
    check_at_rest(gyro, accel, fs_hz, **limits)
    return _rows("gyro", gyro).mean(axis=0)


def static_segments(
    gyro: ArrayLike,
    accel: ArrayLike,
    fs_hz: float,
    *,
    window_s: float = 0.5,
    min_duration_s: float = 1.5,
    max_gyro_std_dps: float = 2.0,
    max_accel_std_g: float = 0.015,
    max_pose_change_g: float = 0.02,
    gravity: float = STANDARD_GRAVITY,
) -> list[slice]:
    """Index ranges where the sensor holds a still pose, for accelerometer calibration.

    Windows of ``window_s`` whose gyro and accelerometer standard deviations are below the
    limits are still; consecutive still windows whose accelerometer means agree within
    ``max_pose_change_g`` form one pose; poses shorter than ``min_duration_s`` are dropped.
    ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s^2 at ``fs_hz``. One window is trimmed from
    each end of a pose, where the hand was still settling.

    The gyro limit is looser than ``check_at_rest``'s: a sensor held by hand in a pose shows
    0.5-1.2 deg/s of tremor (bundled ``example_data_calibration.csv``) while its
    accelerometer std stays at the 0.003-0.008 g of rest, and the pose's mean is what counts.
    """
    g = _rows("gyro", gyro) / _DEG
    a = _rows("accel", accel) / gravity
    n = max(2, round(window_s * fs_hz))
    gw, aw = _windows(g, n), _windows(a, n)
    still = (gw.std(axis=1) < max_gyro_std_dps).all(axis=1) & (
        aw.std(axis=1) < max_accel_std_g
    ).all(axis=1)
    means = aw.mean(axis=1)
    segments: list[slice] = []
    start = None
    for i in range(len(still) + 1):
        joins = (
            i < len(still) and still[i] and start is not None
            and np.all(np.abs(means[i] - means[i - 1]) < max_pose_change_g)
        )
        if joins:
            continue
        if start is not None:
            first, last = start + 1, i - 1  # trim a window at each end
            if (last - first) * n >= min_duration_s * fs_hz:
                segments.append(slice(first * n, last * n))
            start = None
        if i < len(still) and still[i]:
            start = i
    return segments


@dataclass(frozen=True)
class AccelFit:
    """Result of ``fit_accel_poses``.

    Attributes:
        offset: (3,) m/s^2.  scale: (3,) dimensionless.
        norm_before: |pose mean| of each pose, m/s^2, uncorrected.
        norm_after: |corrected pose mean| of each pose, m/s^2.
        condition: condition number of the fit's Jacobian (large: poses too alike).
    """

    offset: NDArray[np.float64]
    scale: NDArray[np.float64]
    norm_before: NDArray[np.float64]
    norm_after: NDArray[np.float64]
    condition: float


def fit_accel_poses(
    pose_means: ArrayLike, gravity: float = STANDARD_GRAVITY, *, max_condition: float = 1e4
) -> AccelFit:
    """Fit the axis-aligned model |(m_i - offset) * scale| = g to static pose means.

    ``pose_means`` (M, 3) m/s^2, M >= 6, ideally with each axis pointing up and down once.
    A linear least-squares ellipsoid fit (A x^2 + B y^2 + C z^2 + D x + E y + F z = 1) gives
    the start, refined by nonlinear least squares on the norm residuals (scipy). Poses that
    do not pin down all six parameters (Jacobian condition above ``max_condition``) raise
    ``ValueError``.
    """
    from scipy.optimize import least_squares

    m = _rows("pose_means", pose_means)
    if len(m) < 6:
        raise ValueError(
            f"need at least 6 static poses for offset and scale on 3 axes; got {len(m)}. Hold the "
            "sensor with each axis up and then down (6 faces), a few seconds each"
        )
    design = np.column_stack([m**2, m])
    coef, *_ = np.linalg.lstsq(design, np.ones(len(m)), rcond=None)
    quad, lin = coef[:3], coef[3:]
    if np.all(quad > 0):
        offset0 = -lin / (2 * quad)
        r = 1.0 + np.sum(quad * offset0**2)
        scale0 = gravity * np.sqrt(quad / r) if r > 0 else np.ones(3)
    else:
        offset0, scale0 = np.zeros(3), np.ones(3)

    def residual(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.linalg.norm((m - p[:3]) * p[3:], axis=1) - gravity

    sol = least_squares(residual, np.concatenate([offset0, scale0]), method="lm")
    jac = sol.jac
    sv = np.linalg.svd(jac, compute_uv=False)
    condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    if condition > max_condition or np.any(sol.x[3:] <= 0):
        raise ValueError(
            f"the {len(m)} poses do not determine offset and scale on every axis (condition "
            f"{condition:.3g}); include poses with each axis pointing up and down"
        )
    offset, scale = sol.x[:3], sol.x[3:]
    return AccelFit(offset, scale, np.linalg.norm(m, axis=1),
                    np.linalg.norm((m - offset) * scale, axis=1), condition)


def calibrate(
    rest_gyro: ArrayLike,
    rest_accel: ArrayLike | None,
    fs_hz: float,
    pose_means: ArrayLike | None = None,
    *,
    gravity: float = STANDARD_GRAVITY,
    info: dict[str, Any] | None = None,
    **limits: float,
) -> ImuCalibration:
    """Build an ``ImuCalibration``: gyro bias from a rest recording (rad/s, m/s^2 at
    ``fs_hz``), accelerometer offset/scale from ``pose_means`` (M, 3) m/s^2 if given."""
    bias = gyro_bias_at_rest(rest_gyro, rest_accel, fs_hz, **limits)
    details: dict[str, Any] = {"rest_samples": len(np.asarray(rest_gyro)), "fs_hz": fs_hz}
    offset, scale = np.zeros(3), np.ones(3)
    if pose_means is not None:
        fit = fit_accel_poses(pose_means, gravity)
        offset, scale = fit.offset, fit.scale
        details.update(
            poses=len(fit.norm_after),
            pose_norm_error_max_g=float(np.max(np.abs(fit.norm_after / gravity - 1))),
        )
    details.update(info or {})
    return ImuCalibration(bias, offset, scale, details)


def pose_means(accel: ArrayLike, segments: Sequence[slice]) -> NDArray[np.float64]:
    """Mean specific force (M, 3) of each segment of ``accel`` (N, 3), same unit."""
    a = _rows("accel", accel)
    return np.array([a[s].mean(axis=0) for s in segments])



def calibrate_recordings(
    rest: Any, poses: Any | None = None, *, gravity: float = STANDARD_GRAVITY
) -> ImuCalibration:
    """Calibration from raw recordings (``fusion.io.mpu6050_csv.RawImuRecording``): the gyro
    bias from ``rest`` (refused if it moved), the accelerometer offset/scale from the still
    poses found in ``poses`` by ``static_segments``. The file names, the number of poses and
    the pose norms before/after (g) go into ``info``."""
    info: dict[str, Any] = {"rest_file": Path(rest.path).name}
    means = None
    if poses is not None:
        segments = static_segments(poses.gyro_si(), poses.accel_si(gravity), poses.fs_hz,
                                   gravity=gravity)
        means = pose_means(poses.accel_si(gravity), segments)
        info["poses_file"] = Path(poses.path).name
        info["pose_times_s"] = [[s.start / poses.fs_hz, s.stop / poses.fs_hz] for s in segments]
    cal = calibrate(rest.gyro_si(), rest.accel_si(gravity), rest.fs_hz, means, gravity=gravity,
                    info=info)
    return cal
