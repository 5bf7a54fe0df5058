"""Keel: attitude estimation with gyro-bias tracking, made for hosts that stamp their samples.

Frames and units: inputs in the body (sensor) frame, angular rate rad/s, specific force m/s^2
(+g along up at rest), magnetic field in any consistent unit (uT by convention; norm and
direction are used). Output quaternion scalar first ``[w, x, y, z]``, body -> world ENU (z up;
with a magnetometer y points to magnetic north; without one the heading starts at yaw 0 and is
kept by the gyro).

How it works, per sample (the compiled core is :mod:`fusion.attitude._keel_core`):

1. **Gyro frame.** The bias-corrected gyro alone is integrated (exactly, for a rate constant
   over the step) into ``qG``: body -> a frame I that turns only by the residual gyro error.
2. **Inclination.** The accelerometer is rotated into I and low-passed there (2nd-order
   Butterworth, time constant ``accel_time_constant``). I does not turn with the body, so
   translational accelerations average out while rotations do not smear. The inclination-only
   rotation ``qA`` bringing the filtered vector onto +z gives the 6-axis attitude
   ``qA (x) qG``. Start-up: for the first ``accel_time_constant`` seconds the filter holds the
   running mean, then continues from that steady state (no step).
3. **Gyro bias**, a 3-state Kalman filter with full covariance. At rest it measures the
   low-passed gyro; in motion, the inclination correction per second measures the horizontal
   components (in the earth frame) of the bias error, seen through the rotation low-passed
   like the accelerometer; the vertical component, unobservable in motion, is pulled weakly to
   zero. Measurement variances are densities (``sigma^2`` of a one-second average), so the
   estimator behaves the same at any sample rate.
4. **Rest**: for ``rest_min_duration`` s the gyro and accelerometer stay within
   ``rest_gyro_threshold`` / ``rest_accel_threshold`` of their low-passed means and the
   low-passed rate stays below ``rest_max_rate``. A robot's own knowledge overrides the
   detector: ``still=True`` (wheels stopped) or ``still=False`` (moving: e.g. a slow spin in
   place that an IMU alone cannot tell from bias).
5. **Heading (9-axis)**: a separate scalar offset about the vertical applied on top, so a
   magnetic error can never tilt the inclination; first-order update (``mag_time_constant``,
   running-mean gain at start-up); the field is trusted while its norm and dip stay close to a
   slowly adapting reference, else the heading is held (``mag_hold_time``, then updated slowly);
   a new field consistent for ``mag_new_field_time`` s of turning is accepted.

Per-sample timestamps: every quantity above is integrated over the actual interval, so jitter
needs no special care. **Gap policy**: an interval longer than ``max_gap`` s (data lost, the
host stalled) is not integrated as one step: the sample's rate is integrated over the last
regular period, the bias covariance grows over the whole gap, and the accelerometer low-pass,
the rest detector and the heading start-up gain restart (the attitude re-acquires inclination
from the accelerometer at once, counted in ``counters.gaps``). The cost is that of one sample
for any gap. Non-finite gyro rows and rows faster than ``max_gyro`` (corrupt values) are
skipped (attitude held; the next sample integrates over their interval too); zero, non-finite
or above-``max_accel`` accelerometer rows propagate the gyro only; zero or non-finite
magnetometer rows leave the heading offset alone. Non-positive or non-finite periods and wrong
shapes raise ``ValueError``.

External knowledge (``update(..., still=, known_accel=)``): ``known_accel`` is the body-frame
kinematic acceleration, m/s^2, that the host knows (a wheeled robot turning at yaw rate w with
forward speed v has a centripetal v*w towards the turn centre, plus dv/dt along its heading);
it is subtracted from the accelerometer before the inclination update (one with a component
above ``max_accel``, a corrupt input, is ignored).

The offline (forward-backward) mode for recorded data is :func:`fusion.attitude.keel_offline`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._jit import compiled_entry_point
from fusion.attitude import _keel_core as core
from fusion.attitude._base import AttitudeFilter
from fusion.attitude._inputs import as_rows, check_dt, vec3
from fusion.types.constants import STANDARD_GRAVITY

__all__ = ["Keel", "KeelCounters", "KeelDiagnostics", "KeelParams", "KeelState"]

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class KeelParams:
    """Parameters of :class:`Keel` (immutable; derive variants with :func:`dataclasses.replace`).

    Rates in rad/s, accelerations m/s^2, times s. ``benchmarks/tune_keel.py`` chose the
    accelerometer time constants, the motion (online, offline) and rest bias sigmas, the bias
    drift, the heading
    time constant and the norm tolerance on a grid, scored by leave-one-trial-out
    cross-validation over the ten bundled BROAD trials (each trial scored with parameters
    chosen on the other nine): mean inclination RMSE 0.737 deg online, 0.521 deg offline,
    9-axis mean total RMSE 2.16 deg. The defaults are the grid point best on all ten (0.712,
    0.518, 2.05 deg there: in-sample figures). The other values come from the published VQF
    analysis (rest thresholds, bias clip, field tolerances) or were set by hand (vertical bias
    sigma, gap length, heading gate) and were not tuned.

    Attributes:
        sample_period: default period when an update gives neither ``dt`` nor timestamps.
        gravity: magnitude of gravity, m/s^2.
        accel_time_constant: low-pass time constant of the accelerometer in the gyro frame, s.
        offline_accel_time_constant: the same for the zero-phase (forward and backward)
            low-pass of :func:`~fusion.attitude.keel_offline.keel_offline`, s.
        offline_motion_bias_sigma: ``motion_bias_sigma`` of the offline bias passes, rad/s
            (with the future known, the rest phases on both sides bound the bias better).
        motion_bias_estimation, rest_bias_estimation: switch the two bias updates.
        bias_sigma_initial: initial standard deviation of each bias component, rad/s.
        bias_drift: growth of the bias standard deviation per ``sqrt(100 s)``: the process
            noise density is ``bias_drift^2 / 100 s``, rad^2/s^3.
        motion_bias_sigma: standard deviation of the horizontal rate error measured by the
            inclination correction, averaged over one second, rad/s.
        vertical_bias_sigma: same for the weak zero pull on the vertical bias in motion.
        rest_bias_sigma: same for the low-passed gyro at rest.
        bias_clip: bound on each bias component and on each innovation, rad/s.
        rest_gyro_threshold, rest_accel_threshold: largest deviation from the low-passed
            means at rest, rad/s and m/s^2.
        rest_max_rate: largest low-passed rate at rest, rad/s.
        rest_min_duration: how long the thresholds must hold, s.
        rest_time_constant: time constant of the rest detector's low-pass means, s.
        max_gap: longest interval integrated as one step, s (see the gap policy).
        mag_time_constant: time constant of the heading update, s.
        mag_norm_tolerance: relative deviation of the field norm still trusted.
        mag_dip_tolerance: deviation of the dip angle still trusted, rad.
        mag_hold_time: how long the heading is held in a disturbed field, s.
        mag_slow_factor: after the hold, the heading updates this many times slower.
        mag_new_field_time: turning time after which a consistent new field is accepted, s.
        mag_new_field_rate: least rate that counts as turning for that, rad/s.
        mag_reference_time_constant: adaptation of the reference norm and dip, s.
        mag_initial_time: the reference is the running mean over this first time, s.
        mag_heading_gate: once converged, a heading innovation larger than this (plus
            ``mag_gate_scale`` times the angle turned since the field was last trusted, which
            covers gyro scale errors) marks the field as disturbed, rad.
        mag_gate_scale: see ``mag_heading_gate`` (dimensionless, rad per rad turned).
        max_gyro: a gyro row faster than this (rad/s) is corrupt and skipped; above every
            MEMS gyro's full scale (+-4000 deg/s = 70 rad/s).
        max_accel: an accelerometer row above this (m/s^2, about 100 g) is corrupt: gyro
            only.

    Raises:
        ValueError: a value that is not a finite number > 0 (``rest_min_duration``: >= 0;
            the switches: True or False), or a ``sample_period`` longer than ``max_gap``;
            the message names the field and the value.
    """

    sample_period: float | None = None
    gravity: float = STANDARD_GRAVITY
    accel_time_constant: float = 3.0
    offline_accel_time_constant: float = 3.0
    offline_motion_bias_sigma: float = 0.2 * _DEG
    motion_bias_estimation: bool = True
    rest_bias_estimation: bool = True
    bias_sigma_initial: float = 0.5 * _DEG
    bias_drift: float = 0.1 * _DEG
    motion_bias_sigma: float = 0.05 * _DEG
    vertical_bias_sigma: float = 0.5 * _DEG
    rest_bias_sigma: float = 0.01 * _DEG
    bias_clip: float = 2.0 * _DEG
    rest_gyro_threshold: float = 2.0 * _DEG
    rest_accel_threshold: float = 0.5
    rest_max_rate: float = 2.0 * _DEG
    rest_min_duration: float = 1.5
    rest_time_constant: float = 0.5
    max_gap: float = 0.25
    mag_time_constant: float = 9.0
    mag_norm_tolerance: float = 0.05
    mag_dip_tolerance: float = 10.0 * _DEG
    mag_hold_time: float = 60.0
    mag_slow_factor: float = 2.0
    mag_new_field_time: float = 20.0
    mag_new_field_rate: float = 20.0 * _DEG
    mag_reference_time_constant: float = 30.0
    mag_initial_time: float = 2.0
    mag_heading_gate: float = 5.0 * _DEG
    mag_gate_scale: float = 0.03
    max_gyro: float = 100.0
    max_accel: float = 1000.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "sample_period":
                if value is not None:
                    check_dt(value)
            elif f.type in ("bool", bool):
                if not isinstance(value, bool):
                    raise ValueError(f"{f.name} must be True or False, got {value!r}")
            elif isinstance(value, bool):
                raise ValueError(f"{f.name} must be a number, got {value!r}")
            elif f.name == "rest_min_duration":
                if not (math.isfinite(value) and value >= 0):
                    raise ValueError(f"{f.name} must be finite and >= 0, got {value!r}")
            elif not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{f.name} must be finite and > 0, got {value!r}")
        if self.sample_period is not None and self.sample_period > self.max_gap:
            raise ValueError(f"sample_period {self.sample_period!r} s is longer than max_gap "
                             f"{self.max_gap!r} s: every sample would be a gap")

    def packed(self) -> NDArray[np.float64]:
        """The parameters as the flat float64 array the compiled core reads."""
        p = np.zeros(core.P_LEN)
        values = {
            "gravity": self.gravity, "tau_acc": self.accel_time_constant,
            "motion_bias": float(self.motion_bias_estimation),
            "rest_bias": float(self.rest_bias_estimation),
            "bias_noise": self.bias_drift ** 2 / 100.0,
            "motion_var": self.motion_bias_sigma ** 2,
            "vertical_var": self.vertical_bias_sigma ** 2,
            "rest_var": self.rest_bias_sigma ** 2,
            "bias_clip": self.bias_clip, "rest_gyro": self.rest_gyro_threshold,
            "rest_acc": self.rest_accel_threshold, "rest_rate": self.rest_max_rate,
            "rest_duration": self.rest_min_duration, "rest_tau": self.rest_time_constant,
            "max_gap": self.max_gap, "mag_tau": self.mag_time_constant,
            "mag_norm_tol": self.mag_norm_tolerance, "mag_dip_tol": self.mag_dip_tolerance,
            "mag_hold": self.mag_hold_time, "mag_slow_factor": self.mag_slow_factor,
            "mag_new_time": self.mag_new_field_time, "mag_new_rate": self.mag_new_field_rate,
            "mag_ref_tau": self.mag_reference_time_constant,
            "mag_init_time": self.mag_initial_time, "mag_gate": self.mag_heading_gate,
            "mag_gate_scale": self.mag_gate_scale,
            "max_gyro": self.max_gyro, "max_accel": self.max_accel,
        }
        for name, value in values.items():
            p[core.P_INDEX[name]] = value
        return p


@dataclass
class KeelCounters:
    """Samples handled by a documented policy since the last reset."""

    gyro_skipped: int = 0  # non-finite gyro: sample skipped, attitude held
    accel_skipped: int = 0  # zero/non-finite accelerometer: gyro-only propagation
    mag_skipped: int = 0  # zero/non-finite magnetometer in 9-axis mode: heading held
    gaps: int = 0  # intervals longer than max_gap (see the gap policy)
    rest_samples: int = 0  # samples that refined the bias at rest
    mag_disturbed: int = 0  # samples whose magnetic field was not trusted


@dataclass
class KeelState:
    """Complete estimator state; :meth:`Keel.set_state` of a saved state resumes exactly.

    Attributes:
        quaternion: attitude ``[w, x, y, z]``, body -> world ENU.
        gyro_bias: bias estimate, rad/s, body frame (subtracted from the gyro).
        bias_covariance: its covariance, (rad/s)^2, 3 x 3.
        heading_offset: rotation about up applied on top of the 6-axis attitude, rad.
        at_rest: whether the last sample was at rest.
        core: the complete packed internal state (layout private: restore it unchanged).
        last_timestamp: timestamp of the last sample given with timestamps, s, or None.
        counters: see :class:`KeelCounters`.
    """

    quaternion: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    bias_covariance: NDArray[np.float64]
    heading_offset: float
    at_rest: bool
    core: NDArray[np.float64]
    last_timestamp: float | None = None
    counters: KeelCounters = field(default_factory=KeelCounters)


@dataclass
class KeelDiagnostics:
    """Per-sample diagnostics of a batch run (N rows).

    Attributes:
        gyro_bias: (N, 3) bias estimate after each sample, rad/s, body frame.
        gyro_bias_sigma: (N, 3) its standard deviation, rad/s.
        bias_covariance: (N, 3, 3) its covariance, (rad/s)^2.
        rest: (N,) bool, rest detected (or told) at that sample.
        mag_disturbed: (N,) bool, magnetic field not trusted at that sample.
        heading_offset: (N,) heading offset of the 9-axis attitude, rad.
    """

    gyro_bias: NDArray[np.float64]
    gyro_bias_sigma: NDArray[np.float64]
    bias_covariance: NDArray[np.float64]
    rest: NDArray[np.bool_]
    mag_disturbed: NDArray[np.bool_]
    heading_offset: NDArray[np.float64]

    @classmethod
    def from_rows(cls, diag: NDArray[np.float64]) -> KeelDiagnostics:
        """Unpack the core's (N, D_LEN) diagnostics array."""
        cov = covariance_matrices(diag[:, core.D_COV:core.D_COV + 6])
        return cls(
            gyro_bias=diag[:, core.D_BIAS:core.D_BIAS + 3].copy(),
            gyro_bias_sigma=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)),
            bias_covariance=cov,
            rest=diag[:, core.D_REST] != 0.0,
            mag_disturbed=diag[:, core.D_DISTURBED] != 0.0,
            heading_offset=diag[:, core.D_DELTA].copy(),
        )


def covariance_matrices(upper: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 6) upper triangles ``xx xy xz yy yz zz`` -> (N, 3, 3) symmetric matrices."""
    i, j = np.triu_indices(3)
    cov = np.empty((upper.shape[0], 3, 3))
    cov[:, i, j] = upper
    cov[:, j, i] = upper
    return cov


_F64 = np.dtype(np.float64)
_NDARRAY = np.ndarray
_SHAPE3 = (3,)
_INF = math.inf
_FLOATS = (float, np.float64)
_NO_MAG = np.zeros(3)
_fast6 = None
_fast_full = None


def _entry_points():
    global _fast6, _fast_full
    if _fast6 is None:
        _fast6 = compiled_entry_point(core.run_one6, 2)
        _fast_full = compiled_entry_point(core.run_one, 4)
    return _fast6, _fast_full


class Keel(AttitudeFilter):
    """Keel attitude estimator, 6-axis (gyro + accelerometer) or 9-axis (+ magnetometer).

    Args:
        axes: 6 or 9. With 9, rows without a magnetometer keep the heading offset.
        sample_period: default period (s) for updates that give neither dt nor timestamps.
        initial_quaternion: known initial attitude ``[w, x, y, z]`` body -> world ENU; its
            heading is kept (a 9-axis estimator then turns towards the magnetometer at the
            normal rate instead of snapping). Without it the first sample with a valid
            accelerometer sets roll and pitch (yaw 0; 9-axis: the heading from the first
            magnetometer sample).
        params: a full :class:`KeelParams` (else built from ``sample_period`` and ``options``).
        **options: any other :class:`KeelParams` field.

    Example::

        f = Keel(sample_period=0.01)
        for t, gyro, accel in samples:               # s, rad/s, m/s^2, body frame
            q = f.update(gyro, accel, timestamp=t)   # [w, x, y, z], body -> ENU
    """

    def __init__(
        self,
        *,
        axes: int = 6,
        sample_period: float | None = None,
        initial_quaternion: ArrayLike | None = None,
        params: KeelParams | None = None,
        **options,
    ) -> None:
        if params is None:
            params = KeelParams(sample_period=sample_period, **options)
        elif sample_period is not None or options:
            raise ValueError("give either params or individual settings, not both")
        self._setup(axes, initial_quaternion, params)

    # -- parameters and state (params, with_params, quaternion, euler: AttitudeFilter) --------

    _params_class = KeelParams
    _layout = (core.B_P, core.B_C, core.B_LEN)

    def _params_changed(self) -> None:
        if hasattr(self, "_B"):
            self._S[core.DT_CACHED] = -1.0  # coefficients depend on the time constants

    def reset(self) -> None:
        """Forget everything: back to the state before the first sample."""
        self._new_buffer()
        S = self._S
        S[core.Q] = S[core.QG] = S[core.QA] = 1.0
        var = self._params.bias_sigma_initial ** 2
        S[core.COV] = S[core.COV + 3] = S[core.COV + 5] = var
        S[core.DT_CACHED] = -1.0
        if self._initial is not None:
            S[core.Q:core.Q + 4] = self._initial
            S[core.QG:core.QG + 4] = self._initial
            S[core.ACC_SEEN] = 1.0
            S[core.MAG_TIME] = self._params.mag_time_constant
        self._last_t: float | None = None

    def get_state(self) -> KeelState:
        """A copy of the complete state."""
        S = self._S
        return KeelState(
            quaternion=S[core.Q:core.Q + 4].copy(),
            gyro_bias=S[core.BIAS:core.BIAS + 3].copy(),
            bias_covariance=covariance_matrices(S[None, core.COV:core.COV + 6])[0],
            heading_offset=float(S[core.DELTA]),
            at_rest=bool(S[core.REST]),
            core=S.copy(),
            last_timestamp=self._last_t,
            counters=self.counters,
        )

    def set_state(self, state: KeelState) -> None:
        """Restore a state saved by :meth:`get_state` (its ``core`` is used as it is)."""
        s = np.asarray(state.core, dtype=np.float64)
        if s.shape != (core.S_LEN,) or not np.all(np.isfinite(s)):
            raise ValueError(f"state.core must be {core.S_LEN} finite values, got {s.shape}")
        self._new_buffer()
        self._S[:] = s
        c = state.counters
        self._C[:] = [c.gyro_skipped, c.accel_skipped, c.mag_skipped, c.gaps, c.rest_samples,
                      c.mag_disturbed]
        self._last_t = state.last_timestamp

    @property
    def gyro_bias(self) -> NDArray[np.float64]:
        """Gyro-bias estimate, rad/s, body frame: subtract it from the gyro."""
        return self._S[core.BIAS:core.BIAS + 3].copy()

    @property
    def gyro_bias_sigma(self) -> NDArray[np.float64]:
        """Standard deviation of each bias component, rad/s."""
        c = self._S[core.COV:core.COV + 6]
        return np.sqrt(np.array([c[0], c[3], c[5]]))

    @property
    def at_rest(self) -> bool:
        """Whether the last sample was at rest (detected, or told with ``still=True``)."""
        return bool(self._S[core.REST])

    @property
    def mag_disturbed(self) -> bool:
        """Whether the last magnetometer sample was rejected as disturbed."""
        return bool(self._S[core.DISTURBED])

    @property
    def heading_offset(self) -> float:
        """Heading offset (rad) applied about up on top of the 6-axis attitude."""
        return float(self._S[core.DELTA])

    @property
    def counters(self) -> KeelCounters:
        """Documented policies applied since the last reset (see :class:`KeelCounters`)."""
        return KeelCounters(*(int(c) for c in self._C))

    # -- streaming -------------------------------------------------------------------------

    def update(
        self,
        gyro: ArrayLike,
        accel: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
        *,
        timestamp: float | None = None,
        still: bool | None = None,
        known_accel: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Filter one sample and return the attitude ``[w, x, y, z]`` (body -> world ENU).

        Args:
            gyro: angular rate (3,), rad/s, body frame.
            accel: specific force (3,), m/s^2, body frame.
            mag: magnetic field (3,), uT, body frame (used with ``axes=9``).
            dt: time since the previous sample, s. Defaults to the difference of ``timestamp``
                and the previous timestamp, else ``params.sample_period``; the very first
                sample needs none (it only initialises).
            timestamp: sample time, s (see ``dt``).
            still: external knowledge: True = known still, False = known moving, None = let
                the rest detector decide.
            known_accel: known kinematic acceleration (3,), m/s^2, body frame, removed from
                ``accel`` (e.g. the centripetal v*w of a turning robot).
        """
        # Hot path of live use (float64 (3,) arrays, 6-axis, a default period or a float
        # timestamp after the first): the fewest Python operations around one compiled call.
        if (mag is None and still is None and known_accel is None and dt is None
                and type(gyro) is type(accel) is _NDARRAY and gyro.dtype is accel.dtype is _F64
                and gyro.shape == accel.shape == _SHAPE3 and _fast6 is not None):
            if timestamp is None:
                d = self._default_dt
                if d is not None:
                    _fast6(self._B, gyro, accel, d)
                    return self._q.copy()
            elif type(timestamp) in _FLOATS and self._last_t is not None:
                d = timestamp - self._last_t
                if 0.0 < d < _INF:
                    self._last_t = timestamp
                    _fast6(self._B, gyro, accel, d)
                    return self._q.copy()
        return self._update_general(gyro, accel, mag, dt, timestamp, still, known_accel)

    def _update_general(self, gyro, accel, mag, dt, timestamp, still, known_accel):
        d = self._period(dt, timestamp)
        fast6, fast_full = _entry_points()
        g, a = vec3("gyro", gyro), vec3("accel", accel)
        use_mag = self.axes == 9 and mag is not None
        m = vec3("mag", mag) if use_mag else _NO_MAG
        if use_mag or still is not None or known_accel is not None:
            x = np.array([1.0 if use_mag else 0.0,
                          -1.0 if still is None else float(bool(still)), 0.0, 0.0, 0.0])
            if known_accel is not None:
                k = vec3("known_accel", known_accel)
                if np.all(np.isfinite(k)):
                    x[2:] = k
            fast_full(self._B, g, a, m, x, d)
        else:
            fast6(self._B, g, a, d)
        return self._q.copy()

    def _period(self, dt: float | None, timestamp: float | None) -> float:
        """The period before this sample, s (0 for a first sample with none known)."""
        if timestamp is not None:
            t = float(timestamp)
            if not math.isfinite(t):
                raise ValueError(f"timestamp must be finite, got {timestamp!r}")
            last, self._last_t = self._last_t, t
            if dt is None and last is not None:
                d = t - last
                if not d > 0:
                    self._last_t = last
                    raise ValueError(f"timestamp {t!r} s is not after the previous one "
                                     f"({last!r} s)")
                return d
        if dt is not None:
            return check_dt(dt)
        if self._params.sample_period is not None:
            return self._params.sample_period
        if self._S[core.STARTED] == 0.0:
            return 0.0
        raise ValueError("no dt: pass dt=, timestamps, or set sample_period")

    # -- batch --------------------------------------------------------------------------------

    def update_batch(
        self,
        gyro: ArrayLike,
        accel: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | ArrayLike | None = None,
        *,
        timestamps: ArrayLike | None = None,
        still: ArrayLike | None = None,
        known_accel: ArrayLike | None = None,
        diagnostics: bool = False,
    ) -> NDArray[np.float64] | tuple[NDArray[np.float64], KeelDiagnostics]:
        """Filter N samples; returns the attitude after each one, shape (N, 4), and with
        ``diagnostics=True`` also a :class:`KeelDiagnostics`.

        Bit for bit the same as N calls of :meth:`update` (same compiled step).

        Args:
            gyro: (N, 3) rad/s; accel: (N, 3) m/s^2; mag: (N, 3) uT or None.
            dt: a constant period (s) or N periods (the one before each sample). Defaults to
                differences of ``timestamps``, else ``sample_period``.
            timestamps: (N,) sample times, s, strictly increasing. The first sample's period is
                measured from the previous call's last timestamp when there was one, else it
                is ``sample_period`` if set, else 0 (first sample: initialisation only).
            still: (N,) external stillness: 1/True still, 0/False moving, NaN unknown.
            known_accel: (N, 3) known kinematic acceleration, m/s^2, body frame (NaN rows:
                none known).
        """
        g, a, m, use_mag = self._batch_rows(gyro, accel, mag)
        n = g.shape[0]
        s = np.zeros(0)
        if still is not None:
            s = np.ascontiguousarray(still, dtype=np.float64).reshape(-1)
            if s.shape != (n,):
                raise ValueError(f"still must have shape ({n},), got {np.shape(still)}")
        k = as_rows("known_accel", known_accel, n) if known_accel is not None else np.zeros((0, 3))
        dts = self._batch_periods(n, dt, timestamps)
        return self._run(g, a, m, use_mag, dts, s, k, diagnostics)

    def _run(self, g, a, m, use_mag, dts, still, known, diagnostics):
        """The compiled batch over checked, contiguous float64 inputs (m, still, known may
        have 0 rows: none given)."""
        n = g.shape[0]
        out = np.empty((n, 4))
        diag = np.empty((n if diagnostics else 0, core.D_LEN))
        if n:
            core.run_batch(self._B, g, a, m, use_mag, dts, still, known, out, diag)
        if diagnostics:
            return out, KeelDiagnostics.from_rows(diag)
        return out

    def _first_period(self, t: NDArray[np.float64]) -> float:
        """The first period of a batch with no earlier timestamp: ``sample_period``, else 0
        for a first sample (it only initialises)."""
        return self._period(None, None)
