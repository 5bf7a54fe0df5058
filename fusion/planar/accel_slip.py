"""Wheel slip seen by the accelerometer: forward specific force against the wheels' dv/dt,
lateral specific force against v*w.

The gyro check of the EKF (:mod:`fusion.planar._ekf_core`, the wheel yaw rate gated against
the gyro-corrected rate) cannot see wheels that spin or skid alike (a straight run onto a
low-friction patch: the wheels report a speed the body does not have) or a body that slides
sideways in a turn. A rigid body rolling without slip obeys, at the axle midpoint
(REP-103 base frame, x forward, y left):

- forward: the acceleration along x is ``dv/dt`` of the wheels' speed ``v``;
- lateral: the acceleration along y is the centripetal ``v*w`` (``w`` the yaw rate).

The accelerometer measures the specific force ``f`` (m/s^2) in the base frame; with the
at-rest offset removed (learnt here whenever the newest wheel frame has zero ticks and the
IMU is still: gravity leaking through a mount tilt, the accelerometer bias), ``f`` is that
acceleration on a level floor (on a slope gravity leaks by a different amount, about
0.17 m/s^2 per degree along the track, which the test cannot tell from a slip). An IMU at
``lever_arm = (px, py)`` from the axle midpoint feels ``f_x = a_x - w^2 px - w' py`` and
``f_y = a_y + w' px - w^2 py`` (``w'`` the yaw acceleration); ``lever_arm`` defaults to
``(0, 0)`` (the lever arm ignored) and ``lever_arm_std`` covers an IMU up to that far from
where it is configured.

Per wheel frame ``k`` the detector compares, over the last ``n`` frames
(``n = round(window / period)``, frames ``k-n .. k`` without a gap),

- ``e_f = (v_k - v_{k-n}) - integral of a_x``: the wheels' speed change against the IMU's
  (m/s);
- ``e_l = integral of (a_y - v*w)``: the lateral speed the body would have gained (m/s),

the integrals by the trapezoid rule over the frames' mean specific force (the IMU samples
stamped inside each frame's period, ``(stamp - period - wheel_latency, stamp - wheel_latency]``),
which is exactly the kernel by which the difference of two period means of ``v`` weighs the
acceleration. The frame slips when ``e_f^2/s_f^2 + e_l^2/s_l^2`` exceeds ``gate`` (chi-square,
2 degrees of freedom; 13.82 = 0.1 % false alarms for Gaussian noise). The variances
``s_f^2``, ``s_l^2`` (m/s)^2 come from the noise figures, none fitted to a run:

- white accelerometer noise ``accel_noise`` per sample: ``accel_noise^2 * D^2 / N`` over a
  window of ``D`` s holding ``N`` samples;
- vibration while driving: the measured variance ``A^2`` of the specific force within each
  frame's period (averaged over the window); the integral over any window of a vibration
  at ``vibration_freq`` Hz or above has an RMS of at most ``A / (pi * vibration_freq)``;
- model: ``relative_std`` of the expected speed changes (wheel scale, a mount yawed by a
  degree or two, gyro scale), the lever arm's uncertainty (each coordinate off by
  ``lever_arm_std``, independently) through ``integral of w^2`` and ``delta w``, the offset's
  own uncertainty times ``D`` (``offset_std`` before any rest was
  seen), and the wheels' quantisation ``tick_std`` ticks on the speed difference.

A decision needs ``n + 1`` frames without a gap longer than ``gap_periods`` periods, each with
IMU samples in its period; until then frames are not flagged. The test looks back over the
window, so a slip is flagged once its effect exceeds the noise (within the window) and for up
to a window after it ends.

Streaming and batch agree exactly: :meth:`AccelSlipDetector.update_batch` runs one compiled
loop over the events (IMU samples and wheel frames in arrival order) with the detector's
state in arrays carried across calls.
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._jit import njit
from fusion.planar.imu_motion import MOTION_STILL

__all__ = ["CHI2_2DOF_01PCT", "AccelSlipDetector", "AccelSlipParams", "accel_slip_flags"]

#: Chi-square threshold, 2 degrees of freedom, 0.1 % upper tail (scipy.stats.chi2.isf(1e-3, 2)).
CHI2_2DOF_01PCT = 13.815510557964274

# scalar state
_S_LAST_WHEEL_T = 0  # stamp of the newest wheel frame (-inf: none)
_S_LAST_ZERO = 1  # the newest wheel frame had zero ticks on both wheels (1.0)
_S_OFF_N = 2  # IMU samples that taught the at-rest offset
_S_OFF_X = 3  # at-rest offsets: specific force x, y (m/s^2), yaw rate (rad/s)
_S_OFF_Y = 4
_S_OFF_W = 5
_S_IMU_HEAD = 6  # next slot of the IMU ring
_S_IMU_COUNT = 7  # samples in the IMU ring
_S_FRAMES = 8  # consecutive usable frames in the frame ring (reset by a gap)
_S_FRAME_HEAD = 9
_S_RES_N = 10  # driving frames that taught the measured residual variances
_S_RES_F = 11  # measured variance of e_f, e_l while driving unflagged, (m/s)^2
_S_RES_L = 12
_STATE_SIZE = 13
# IMU ring columns: stamp, f_x, f_y, rate
_IMU_RING = 2048
# frame ring columns: stamp, v, mean f_x, mean f_y, mean rate, var f_x, var f_y, samples
_FRAME_RING = 64
_F_T, _F_V, _F_AX, _F_AY, _F_W, _F_VX, _F_VY, _F_N = range(8)
# output columns per wheel frame: flag, e_f, e_l, d2
OUT_WIDTH = 4


@dataclass(frozen=True)
class AccelSlipParams:
    """Noise figures and settings of the accelerometer slip test (SI units).

    Attributes:
        window: span of the comparison, s (rounded to whole wheel periods, at least one).
        accel_noise: white noise of one accelerometer sample, m/s^2 (MPU6050: 400 ug/sqrt(Hz)
            over its ~100 Hz band, about 0.04).
        vibration_freq: lowest frequency of the vibration of a driving robot, Hz (motors,
            gears, floor texture): the integral of the vibration over a window has an RMS of
            at most ``A / (pi * vibration_freq)`` for a vibration of RMS ``A``.
        relative_std: relative uncertainty of the expected speed changes (wheel scale a few %,
            a mount yawed by 1-2 deg mixes forward and lateral, gyro scale), 1.
        lever_arm: ``(x, y)`` of the IMU from the axle midpoint in the base frame, m
            (``(0, 0)``: ignored).
        lever_arm_std: how far the IMU may be from ``lever_arm``, m.
        offset_std: uncertainty of the specific-force offset before any rest, m/s^2 (a 2 deg
            tilt leaks ``g*sin(2 deg) = 0.34``); after a rest, ``accel_noise/sqrt(samples)``.
        rest_samples: the at-rest offset averages at most this many of the newest still
            samples.
        gate: chi-square threshold on the 2-dof statistic (13.82 = 0.1 %).
        gap_periods: a wheel-frame interval longer than this many periods restarts the window.
        tick_std: quantisation noise of one wheel's count per period, ticks.
        wheel_latency: delay from a period's end to its wheel stamp, s (the EKF's).
        residual_memory: the variances of ``e_f`` and ``e_l`` measured while driving
            (unflagged frames) average over about this much driving, s.
    """

    window: float = 0.4
    accel_noise: float = 0.04
    vibration_freq: float = 10.0
    relative_std: float = 0.05
    lever_arm: tuple[float, float] = (0.0, 0.0)
    lever_arm_std: float = 0.1
    offset_std: float = 0.35
    rest_samples: int = 2000
    gate: float = CHI2_2DOF_01PCT
    gap_periods: float = 2.5
    tick_std: float = 0.5
    wheel_latency: float = 0.0
    residual_memory: float = 10.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            flat = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in flat):
                raise ValueError(f"AccelSlipParams.{f.name} must be finite numbers, got "
                                 f"{value!r}")
        if len(self.lever_arm) != 2:
            raise ValueError(f"AccelSlipParams.lever_arm must be (x, y) in m, got "
                             f"{self.lever_arm!r}")
        for name in ("window", "accel_noise", "vibration_freq", "gate", "rest_samples",
                     "residual_memory"):
            if not getattr(self, name) > 0:
                raise ValueError(f"AccelSlipParams.{name} must be > 0, got "
                                 f"{getattr(self, name)!r}")
        for name in ("relative_std", "lever_arm_std", "offset_std", "tick_std",
                     "wheel_latency"):
            if getattr(self, name) < 0:
                raise ValueError(f"AccelSlipParams.{name} must be >= 0, got "
                                 f"{getattr(self, name)!r}")
        if not self.gap_periods > 1:
            raise ValueError(f"AccelSlipParams.gap_periods must be > 1, got "
                             f"{self.gap_periods!r}")

    def as_array(self, speed_ratio: float, period: float) -> NDArray[np.float64]:
        """The parameter vector of the compiled loop, with the chassis' ``speed_ratio``
        (m/tick) and wheel ``period`` (s)."""
        n = max(1, round(self.window / period))
        values = astuple(self)
        flat = [v for item in values for v in (item if isinstance(item, tuple) else (item,))]
        return np.array([*flat, speed_ratio, period, float(min(n, _FRAME_RING - 1))])


# parameter vector indices (the order of AccelSlipParams' fields, then the chassis)
_P_ACCEL_NOISE = 1
_P_VIB_FREQ = 2
_P_REL = 3
_P_LEVER_X = 4
_P_LEVER_Y = 5
_P_LEVER_STD = 6
_P_OFFSET_STD = 7
_P_REST = 8
_P_GATE = 9
_P_GAP = 10
_P_TICK_STD = 11
_P_LATENCY = 12
_P_RES_MEMORY = 13
_P_SPEED_RATIO = 14
_P_PERIOD = 15
_P_N = 16


@njit
def _learn_rest(state, fx, fy, rate, cap):
    """Running mean of the at-rest specific force and rate over at most ``cap`` samples."""
    n = state[_S_OFF_N] + 1.0
    if n > cap:
        n = cap
    state[_S_OFF_N] = n
    state[_S_OFF_X] += (fx - state[_S_OFF_X]) / n
    state[_S_OFF_Y] += (fy - state[_S_OFF_Y]) / n
    state[_S_OFF_W] += (rate - state[_S_OFF_W]) / n


@njit
def _period_means(state, imu, t0, t1, out):
    """Mean f_x, f_y, rate and the variances of f_x, f_y of the ring's IMU samples stamped in
    ``(t0, t1]``; ``out[5]`` = their number."""
    for c in range(6):
        out[c] = 0.0
    count = int(state[_S_IMU_COUNT])
    head = int(state[_S_IMU_HEAD])
    cap = imu.shape[0]
    for i in range(count):
        row = (head - 1 - i) % cap
        t = imu[row, 0]
        if t <= t0:
            break
        if t > t1:
            continue
        out[0] += imu[row, 1]
        out[1] += imu[row, 2]
        out[2] += imu[row, 3]
        out[3] += imu[row, 1] * imu[row, 1]
        out[4] += imu[row, 2] * imu[row, 2]
        out[5] += 1.0
    n = out[5]
    if n > 0:
        for c in range(5):
            out[c] /= n
        # unbiased sample variances (one sample: none)
        unbias = n / (n - 1.0) if n > 1 else 0.0
        out[3] = max(out[3] - out[0] * out[0], 0.0) * unbias
        out[4] = max(out[4] - out[1] * out[1], 0.0) * unbias


@njit
def _decide(state, frames, par, out_row):
    """The 2-dof test over the last ``n`` frames of the ring (see the module docstring)."""
    n = int(par[_P_N])
    cap = frames.shape[0]
    head = int(state[_S_FRAME_HEAD])
    k = (head - 1) % cap
    first = (head - 1 - n) % cap
    px = par[_P_LEVER_X]
    py = par[_P_LEVER_Y]
    off_x = state[_S_OFF_X]
    off_y = state[_S_OFF_Y]
    off_w = state[_S_OFF_W]
    imu_dv = 0.0  # integral of the forward acceleration the IMU saw, m/s
    lat = 0.0  # integral of (a_y - v*w), m/s
    vw = 0.0  # integral of v*w, m/s
    w2 = 0.0  # integral of w^2, rad^2/s
    samples = 0.0
    vib_x = 0.0
    vib_y = 0.0
    for i in range(n):
        a = (first + i) % cap
        b = (first + i + 1) % cap
        dt = frames[b, _F_T] - frames[a, _F_T]
        wa = frames[a, _F_W] - off_w
        wb = frames[b, _F_W] - off_w
        sq = 0.5 * (wa * wa + wb * wb)
        fx = 0.5 * (frames[a, _F_AX] + frames[b, _F_AX]) - off_x
        fy = 0.5 * (frames[a, _F_AY] + frames[b, _F_AY]) - off_y
        c = 0.5 * (frames[a, _F_V] * wa + frames[b, _F_V] * wb)
        imu_dv += dt * (fx + sq * px)
        lat += dt * (fy + sq * py - c)
        vw += dt * c
        w2 += dt * sq
        samples += frames[b, _F_N]
        vib_x += frames[b, _F_VX]
        vib_y += frames[b, _F_VY]
    dw = (frames[k, _F_W] - frames[first, _F_W])
    imu_dv += py * dw
    lat -= px * dw
    dv = frames[k, _F_V] - frames[first, _F_V]
    e_f = dv - imu_dv
    span = frames[k, _F_T] - frames[first, _F_T]
    # noise figures (m/s)^2
    white = par[_P_ACCEL_NOISE] ** 2 * span * span / samples
    vib_scale = 1.0 / (math.pi * par[_P_VIB_FREQ]) ** 2 / n
    # f_x is off by -w^2 dx - w' dy, f_y by w' dx - w^2 dy for an IMU off by (dx, dy),
    # independent with standard deviation lever_arm_std each
    lever = par[_P_LEVER_STD] ** 2 * (w2 * w2 + dw * dw)
    if state[_S_OFF_N] > 0:
        off_var = par[_P_ACCEL_NOISE] ** 2 / state[_S_OFF_N]
    else:
        off_var = par[_P_OFFSET_STD] ** 2
    common = white + lever + off_var * span * span
    rel = par[_P_REL] ** 2 * (dv * dv + vw * vw)
    quant = (par[_P_TICK_STD] * par[_P_SPEED_RATIO] / par[_P_PERIOD]) ** 2
    var_f = common + rel + quant + vib_x * vib_scale + state[_S_RES_F]
    var_l = common + rel + vib_y * vib_scale + state[_S_RES_L]
    d2 = e_f * e_f / var_f + lat * lat / var_l
    slip = d2 > par[_P_GATE]
    if not slip and frames[k, _F_V] != 0.0:
        # what the noise figures miss (a vibration slower than vibration_freq, a sensor
        # error): the residuals' own variance while driving, exponentially weighted over
        # residual_memory s of driving from 0 (a slip that builds up over the window cannot
        # teach it its own size before it is flagged)
        m = par[_P_RES_MEMORY] / par[_P_PERIOD]
        state[_S_RES_N] += 1.0
        state[_S_RES_F] += (e_f * e_f - state[_S_RES_F]) / m
        state[_S_RES_L] += (lat * lat - state[_S_RES_L]) / m
    out_row[0] = 1.0 if slip else 0.0
    out_row[1] = e_f
    out_row[2] = lat
    out_row[3] = d2


@njit
def _slip_loop(state, imu, frames, par, kinds, t, a, b, c, d, out):
    """Events in arrival order: kind 0 an IMU sample (``a, b`` = base-frame f_x, f_y m/s^2,
    ``c`` = yaw rate rad/s, ``d`` = IMU motion code), kind 1 a wheel frame (``a, b`` = left,
    right ticks). Writes :data:`OUT_WIDTH` columns per event (NaN for IMU samples)."""
    means = np.empty(6)
    period = par[_P_PERIOD]
    latency = par[_P_LATENCY]
    n = int(par[_P_N])
    for k in range(kinds.shape[0]):
        for col in range(OUT_WIDTH):
            out[k, col] = math.nan
        if kinds[k] == 0:
            row = int(state[_S_IMU_HEAD])
            imu[row, 0] = t[k]
            imu[row, 1] = a[k]
            imu[row, 2] = b[k]
            imu[row, 3] = c[k]
            state[_S_IMU_HEAD] = (row + 1) % imu.shape[0]
            state[_S_IMU_COUNT] = min(state[_S_IMU_COUNT] + 1.0, imu.shape[0])
            fresh = t[k] - state[_S_LAST_WHEEL_T] <= par[_P_GAP] * period
            if fresh and state[_S_LAST_ZERO] == 1.0 and d[k] == MOTION_STILL:
                _learn_rest(state, a[k], b[k], c[k], par[_P_REST])
            continue
        gap = not (t[k] - state[_S_LAST_WHEEL_T] <= par[_P_GAP] * period)
        state[_S_LAST_WHEEL_T] = t[k]
        state[_S_LAST_ZERO] = 1.0 if (a[k] == 0.0 and b[k] == 0.0) else 0.0
        end = t[k] - latency
        _period_means(state, imu, end - period, end, means)
        if gap or means[5] == 0.0:
            state[_S_FRAMES] = 0.0
        if means[5] == 0.0:
            out[k, 0] = 0.0
            continue
        row = int(state[_S_FRAME_HEAD])
        frames[row, _F_T] = end
        frames[row, _F_V] = 0.5 * (a[k] + b[k]) * par[_P_SPEED_RATIO] / period
        frames[row, _F_AX] = means[0]
        frames[row, _F_AY] = means[1]
        frames[row, _F_W] = means[2]
        frames[row, _F_VX] = means[3]
        frames[row, _F_VY] = means[4]
        frames[row, _F_N] = means[5]
        state[_S_FRAME_HEAD] = (row + 1) % frames.shape[0]
        state[_S_FRAMES] += 1.0
        if state[_S_FRAMES] > n:
            _decide(state, frames, par, out[k])
        else:
            out[k, 0] = 0.0


class AccelSlipDetector:
    """Streaming accelerometer slip test over IMU samples and wheel frames (module docstring).

    Args:
        speed_ratio: m per tick; period: wheel period ``encode_sampling_time``, s.
        params: :class:`AccelSlipParams` (default: the noise figures above).
    """

    def __init__(self, speed_ratio: float, period: float,
                 params: AccelSlipParams | None = None) -> None:
        if not (math.isfinite(speed_ratio) and speed_ratio > 0 and math.isfinite(period)
                and period > 0):
            raise ValueError(f"speed_ratio (m/tick) and period (s) must be finite and > 0, got "
                             f"{speed_ratio!r}, {period!r}")
        self.params = params if params is not None else AccelSlipParams()
        self._par = self.params.as_array(float(speed_ratio), float(period))
        self._state = np.zeros(_STATE_SIZE)
        self._state[_S_LAST_WHEEL_T] = -math.inf
        self._imu = np.zeros((_IMU_RING, 4))
        self._frames = np.zeros((_FRAME_RING, 8))

    def update_batch(self, kinds: ArrayLike, t: ArrayLike, a: ArrayLike, b: ArrayLike,
                     c: ArrayLike, d: ArrayLike) -> NDArray[np.float64]:
        """Events in arrival order (wheel stamps and IMU stamps on one host clock, s):
        ``kinds`` 0 for an IMU sample (``a, b`` base-frame specific force x, y in m/s^2 with
        gravity removed or not, ``c`` its yaw rate rad/s, ``d`` its IMU motion code,
        :mod:`fusion.planar.imu_motion`), 1 for a wheel frame stamped at the end of its
        period (``a, b`` left, right ticks; ``c, d`` unused). Returns ``(N, 4)``: per wheel
        frame the flag (1.0 slip, 0.0 not), ``e_f`` and ``e_l`` (m/s) and the chi-square
        statistic (NaN where undecided); NaN rows for IMU samples. Continues from the previous
        call."""
        kinds = np.ascontiguousarray(kinds, dtype=np.int64).reshape(-1)
        cols = [np.ascontiguousarray(v, dtype=np.float64).reshape(-1) for v in (t, a, b, c, d)]
        if any(v.size != kinds.size for v in cols):
            raise ValueError(f"{kinds.size} event kinds but columns of sizes "
                             f"{[v.size for v in cols]}")
        out = np.empty((kinds.size, OUT_WIDTH))
        _slip_loop(self._state, self._imu, self._frames, self._par, kinds, *cols, out)
        return out


def accel_slip_flags(
    speed_ratio: float,
    period: float,
    imu_t: ArrayLike,
    accel_xy: ArrayLike,
    rate: ArrayLike,
    imu_motion: ArrayLike,
    wheel_t: ArrayLike,
    ticks: ArrayLike,
    params: AccelSlipParams | None = None,
) -> NDArray[np.bool_]:
    """(M,) slip flags of a recording's wheel frames (a fresh :class:`AccelSlipDetector`).

    Args:
        speed_ratio, period: chassis m/tick and wheel period s.
        imu_t, accel_xy, rate, imu_motion: IMU stamps (s), base-frame specific force x, y
            (N, 2) m/s^2, yaw rate (N,) rad/s and motion codes (N,)
            (:func:`fusion.planar.imu_motion.imu_motion_codes`).
        wheel_t, ticks: wheel frame stamps (s, end of period) and (M, 2) ticks.

    The events are taken in arrival order (host time; at equal stamps the IMU sample first),
    as the pipeline receives them.
    """
    it = np.asarray(imu_t, dtype=float).reshape(-1)
    f = np.asarray(accel_xy, dtype=float).reshape(-1, 2)
    wt = np.asarray(wheel_t, dtype=float).reshape(-1)
    tk = np.asarray(ticks, dtype=float).reshape(-1, 2)
    kinds = np.concatenate([np.zeros(it.size, np.int64), np.ones(wt.size, np.int64)])
    order = np.argsort(np.concatenate([it, wt]), kind="stable")
    cols = (np.concatenate([it, wt]), np.concatenate([f[:, 0], tk[:, 0]]),
            np.concatenate([f[:, 1], tk[:, 1]]),
            np.concatenate([np.asarray(rate, dtype=float).reshape(-1), np.zeros(wt.size)]),
            np.concatenate([np.asarray(imu_motion, dtype=float).reshape(-1), np.zeros(wt.size)]))
    out = AccelSlipDetector(speed_ratio, period, params).update_batch(
        kinds[order], *(col[order] for col in cols))
    flags = np.empty(kinds.size)
    flags[order] = out[:, 0]
    return flags[it.size:] == 1.0

