"""Synthetic runs of a two-wheel differential-drive robot with ground truth.

A run is built from *segments* (commanded forward speed ``v`` in m/s and yaw rate ``w`` in
rad/s, CCW positive, held for a duration), which the simulated robot follows under acceleration
limits. The true motion is integrated exactly on a fine grid (default 1 ms, piecewise-constant
twist, exact circular arcs), and two sensor models sample it:

- :class:`ImuModel`: a body-mounted IMU at the wheel axle centre, level with the floor
  (body frame x forward, y left, z up). Gyro (rad/s): ``(1 + scale) * omega + bias(t) + noise``
  with a bias that follows a random walk; accelerometer (m/s^2, specific force): forward
  acceleration, centripetal ``v*w`` and ``+g`` on z, plus bias, white noise and wheel-speed
  dependent vibration. Sample times may jitter.
- :class:`EncoderModel`: Hall encoders counted per firmware period (ticks per period, as on the
  miiboo DATA-uart2 wire), with the *true* geometry differing from the nominal
  :class:`~fusion.geometry.kinematics.DiffDriveParams` that a user would write in ``robot.toml``: a
  wheel-separation error, left/right wheel-radius (metres-per-tick) errors, slip patches
  (the wheel turns faster than its contact point moves), dropped frames and timestamp jitter.

Everything is deterministic for a given ``seed``; each noise source draws from its own child
stream of ``numpy.random.SeedSequence(seed)``, so switching one source off does not change the
others.

Scenario building blocks: :func:`stop`, :func:`straight`, :func:`arc`, :func:`spin`,
:func:`accelerate`. Named scenarios: :func:`square` (UMBmark), :func:`figure_eight`,
:func:`random_mission`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.angles import wrap_angle
from fusion.geometry.dead_reckoning import integrate
from fusion.geometry.kinematics import DiffDriveParams
from fusion.types.constants import STANDARD_GRAVITY as GRAVITY

__all__ = [
    "EXAMPLE_ROBOT",
    "GRAVITY",
    "EncoderModel",
    "ImuModel",
    "Segment",
    "SlipPatch",
    "SyntheticRun",
    "accelerate",
    "arc",
    "degraded_mission",
    "figure_eight",
    "random_mission",
    "simulate",
    "spin",
    "square",
    "stop",
    "straight",
]


# -- scenario building blocks ------------------------------------------------------------------


@dataclass(frozen=True)
class Segment:
    """A commanded twist held for ``duration`` s.

    Attributes:
        v: forward speed command, m/s.
        w: yaw-rate command, rad/s, CCW positive.
        duration: s, > 0.
        ramp: if True the command moves linearly from the previous segment's command to
            ``(v, w)`` over the duration (an acceleration ramp) instead of stepping.
    """

    v: float
    w: float
    duration: float
    ramp: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"Segment.duration must be finite and > 0 s, got {self.duration!r}")
        if not (math.isfinite(self.v) and math.isfinite(self.w)):
            raise ValueError(f"Segment v, w must be finite, got v={self.v!r}, w={self.w!r}")


def stop(duration: float) -> list[Segment]:
    """Stand still for ``duration`` s."""
    return [Segment(0.0, 0.0, duration)]


def straight(distance: float, speed: float = 0.4) -> list[Segment]:
    """Drive ``distance`` m (negative: backwards) at ``speed`` m/s (> 0).

    The travelled distance is exact when the robot stands still before and after (the
    acceleration ramp at the start loses what the ramp at the end gains).
    """
    if not speed > 0:
        raise ValueError(f"speed must be > 0 m/s, got {speed!r}")
    if distance == 0:
        raise ValueError("distance must be non-zero")
    return [Segment(math.copysign(speed, distance), 0.0, abs(distance) / speed)]


def arc(radius: float, angle: float, speed: float = 0.4) -> list[Segment]:
    """Drive forward along a circular arc of ``radius`` m through ``angle`` rad (> 0: left)."""
    if not (radius > 0 and speed > 0 and angle != 0):
        raise ValueError(f"need radius > 0 m, speed > 0 m/s, angle != 0; got {radius}, {speed}, "
                         f"{angle}")
    w = math.copysign(speed / radius, angle)
    return [Segment(speed, w, abs(angle) / abs(w))]


def spin(angle: float, rate: float = 0.8) -> list[Segment]:
    """Turn on the spot through ``angle`` rad (> 0: CCW) at ``rate`` rad/s (> 0)."""
    if not (rate > 0 and angle != 0):
        raise ValueError(f"need rate > 0 rad/s and angle != 0, got {rate}, {angle}")
    return [Segment(0.0, math.copysign(rate, angle), abs(angle) / rate)]


def accelerate(v: float, duration: float, w: float = 0.0) -> list[Segment]:
    """Ramp the command linearly from the previous one to ``(v, w)`` over ``duration`` s."""
    return [Segment(v, w, duration, ramp=True)]


# -- named scenarios ---------------------------------------------------------------------------


def square(
    side: float = 4.0,
    direction: str = "ccw",
    speed: float = 0.4,
    rate: float = 0.6,
    pause: float = 1.0,
    laps: int = 1,
    rest: float = 3.0,
) -> list[Segment]:
    """UMBmark square (Borenstein & Feng 1996): ``side`` m legs, 90 deg turns on the spot.

    Starts and ends with ``rest`` s at standstill; the robot stops for ``pause`` s before and
    after each turn. ``direction`` is ``"ccw"`` (left turns) or ``"cw"``.
    """
    if direction not in ("ccw", "cw"):
        raise ValueError(f"direction must be 'ccw' or 'cw', got {direction!r}")
    turn = math.pi / 2 if direction == "ccw" else -math.pi / 2
    segs = stop(rest)
    for _ in range(laps * 4):
        segs += straight(side, speed) + stop(pause) + spin(turn, rate) + stop(pause)
    return segs + stop(rest)


def figure_eight(
    radius: float = 1.0, speed: float = 0.4, laps: int = 2, rest: float = 3.0
) -> list[Segment]:
    """Figure eight: a full left circle then a full right circle of ``radius`` m, ``laps`` times."""
    segs = stop(rest)
    for _ in range(laps):
        segs += arc(radius, 2 * math.pi, speed) + arc(radius, -2 * math.pi, speed)
    return segs + stop(rest)


def random_mission(
    duration: float = 300.0,
    seed: int = 0,
    max_speed: float = 0.5,
    max_rate: float = 1.0,
    stop_probability: float = 0.2,
    rest: float = 5.0,
) -> list[Segment]:
    """A random waypoint-like mission of about ``duration`` s (deterministic by ``seed``).

    Straights (0.5-4 m), arcs (radius 0.3-3 m, 20-180 deg), spins (30-180 deg) and, with
    ``stop_probability`` after each manoeuvre, stops of 1-4 s, as a robot driving between
    goals does. Starts and ends with ``rest`` s at standstill.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7]))
    segs = stop(rest)
    t = rest
    end = duration - rest
    while t < end:
        kind = rng.choice(["straight", "arc", "spin"], p=[0.45, 0.4, 0.15])
        speed = rng.uniform(0.2, max_speed)
        if kind == "straight":
            new = straight(rng.uniform(0.5, 4.0), speed)
        elif kind == "arc":
            angle = math.radians(rng.uniform(20, 180)) * rng.choice([-1.0, 1.0])
            new = arc(rng.uniform(0.3, 3.0), angle, speed)
            if abs(new[0].w) > max_rate:
                new = arc(speed / max_rate, angle, speed)
        else:
            angle = math.radians(rng.uniform(30, 180)) * rng.choice([-1.0, 1.0])
            new = stop(0.5) + spin(angle, rng.uniform(0.3, max_rate)) + stop(0.5)
        if rng.uniform() < stop_probability:
            new = new + stop(rng.uniform(1.0, 4.0))
        dur = sum(s.duration for s in new)
        if t + dur > end:
            break
        segs += new
        t += dur
    return segs + stop(max(rest, duration - t))


# -- sensor models -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SlipPatch:
    """A time window in which a wheel slips.

    During ``[t0, t1)`` s the wheel turns ``1 + ratio`` times as fast as its contact point moves
    over the floor (``ratio > 0``: spinning on a slippery patch, ticks over-count; ``-1 < ratio
    < 0``: skidding, ticks under-count). ``wheel`` is ``"left"``, ``"right"`` or ``"both"``.
    """

    t0: float
    t1: float
    wheel: str = "left"
    ratio: float = 0.3

    def __post_init__(self) -> None:
        if self.wheel not in ("left", "right", "both"):
            raise ValueError(f"SlipPatch.wheel must be left, right or both, got {self.wheel!r}")
        if not (self.t1 > self.t0 and self.ratio > -1):
            raise ValueError(f"SlipPatch needs t1 > t0 and ratio > -1, got {self}")


@dataclass(frozen=True)
class ImuModel:
    """IMU error model (defaults: an MPU6050 at 100 Hz, datasheet noise densities).

    Attributes:
        rate: sample rate, Hz.
        gyro_noise_density: rad/s/sqrt(Hz) (datasheet 0.005 deg/s/sqrt(Hz)); the white noise of
            one sample has sigma ``density * sqrt(rate)``, so the angle random walk is
            ``density`` rad/sqrt(s).
        gyro_bias: initial bias (3,), rad/s, body frame.
        gyro_bias_walk: bias random walk, rad/s/sqrt(s) (sigma of the bias change after 1 s).
        gyro_scale: scale-factor errors (3,), relative (0.01 = +1 %).
        accel_noise_density: m/s^2/sqrt(Hz) (datasheet 400 ug/sqrt(Hz)).
        accel_bias: (3,), m/s^2.
        vibration: accelerometer vibration amplitude per m/s of forward speed, m/s^2 per m/s
            (a sinusoid at the wheel rotation frequency plus broadband noise of equal sigma).
        wheel_radius: radius used for the vibration frequency, m.
        jitter: sigma of the timestamp error, s (order is kept: stamps stay increasing).
    """

    rate: float = 100.0
    gyro_noise_density: float = math.radians(0.005)
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_walk: float = 0.0
    gyro_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_noise_density: float = 400e-6 * GRAVITY
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vibration: float = 0.0
    wheel_radius: float = 0.0325
    jitter: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"ImuModel.rate must be > 0 Hz, got {self.rate!r}")
        for name in ("gyro_noise_density", "gyro_bias_walk", "accel_noise_density",
                     "vibration", "jitter"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"ImuModel.{name} must be >= 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class EncoderModel:
    """Wheel-encoder error model, relative to the nominal :class:`DiffDriveParams`.

    Attributes:
        separation_error: true wheel distance is ``wheel_distance * (1 + separation_error)``.
        left_scale_error, right_scale_error: true metres per tick of each wheel are
            ``speed_ratio * (1 + error)`` (a wheel-radius error). A radius *mismatch* of 0.5 %
            is e.g. ``left=-0.0025, right=+0.0025``.
        slip_patches: windows of wheel slip (:class:`SlipPatch`).
        drop_probability: probability that a frame is lost (its ticks are lost with it, as on
            the wire, where a frame carries the count of one period).
        jitter: sigma of the host timestamp error of a frame, s (order is kept).
        latency: constant delay from the end of a period to its host timestamp, s.
    """

    separation_error: float = 0.0
    left_scale_error: float = 0.0
    right_scale_error: float = 0.0
    slip_patches: tuple[SlipPatch, ...] = ()
    drop_probability: float = 0.0
    jitter: float = 0.0
    latency: float = 0.0

    def __post_init__(self) -> None:
        for name in ("separation_error", "left_scale_error", "right_scale_error"):
            if not getattr(self, name) > -0.5:
                raise ValueError(f"EncoderModel.{name} must be > -0.5, got {getattr(self, name)}")
        if not 0 <= self.drop_probability < 1:
            raise ValueError(f"drop_probability must be in [0, 1), got {self.drop_probability}")
        if not (self.jitter >= 0 and self.latency >= 0):
            raise ValueError("EncoderModel jitter and latency must be >= 0 s")

    def true_params(self, nominal: DiffDriveParams) -> tuple[float, float, float]:
        """``(wheel_distance, left m/tick, right m/tick)`` of the simulated (true) robot."""
        return (
            nominal.wheel_distance * (1 + self.separation_error),
            nominal.speed_ratio * (1 + self.left_scale_error),
            nominal.speed_ratio * (1 + self.right_scale_error),
        )


# -- the run -----------------------------------------------------------------------------------


@dataclass
class SyntheticRun:
    """Sensor streams and ground truth of one simulated run.

    Times are seconds on the host clock, which is the simulation's true clock plus the stated
    jitter and latency. Truth poses are in ``odom`` (REP-105): x, y in m, yaw in rad wrapped to
    (-pi, pi], starting at the origin.

    Attributes:
        imu_t: (N,) IMU sample stamps, s.
        gyro: (N, 3) rad/s, body frame.
        accel: (N, 3) m/s^2, body frame (specific force, +g on z at rest).
        wheel_t: (M,) stamps of the wheel frames (end of each period), s.
        ticks: (M, 2) int64 ticks per period, left and right.
        truth_t: (K,) truth stamps, s (the IMU's true sample instants).
        truth: (K, 3) ``x, y, yaw``.
        truth_v, truth_w: (K,) true forward speed (m/s) and yaw rate (rad/s).
        gyro_bias: (N, 3) true gyro bias at each IMU sample, rad/s.
        robot: the nominal parameters (what ``robot.toml`` says).
        true_wheel_distance, true_left_ratio, true_right_ratio: the simulated geometry,
            m and m/tick.
        distance: path length of the axle centre, m.
        seed: the seed used.
    """

    imu_t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    wheel_t: NDArray[np.float64]
    ticks: NDArray[np.int64]
    truth_t: NDArray[np.float64]
    truth: NDArray[np.float64]
    truth_v: NDArray[np.float64]
    truth_w: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    robot: DiffDriveParams
    true_wheel_distance: float
    true_left_ratio: float
    true_right_ratio: float
    distance: float
    seed: int
    info: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """Length of the run, s."""
        return float(self.truth_t[-1] - self.truth_t[0])

    def uart2_stream(self) -> tuple[bytes, NDArray[np.float64]]:
        """The wheel frames as the STM32 sends them on DATA-uart2 (seed 000 section 3.2).

        Returns ``(stream, arrival)``: the concatenated 11-byte frames (left = enc1,
        right = enc2) and each frame's host stamp (s), for feeding
        :class:`drivers.chassis.WheelFrameParser` or a pseudo-terminal.
        """
        from drivers.chassis import encode_wheel_frame

        stream = b"".join(encode_wheel_frame(int(a), int(b)) for a, b in self.ticks)
        return stream, self.wheel_t.copy()

    def mpu6050_registers(
        self, gyro_range_dps: int = 250, accel_range_g: int = 2, temperature: float = 25.0
    ) -> NDArray[np.uint8]:
        """The IMU samples as the MPU6050's data registers 0x3B..0x48 (14 bytes per sample).

        ACCEL_XOUT..ZOUT, TEMP_OUT, GYRO_XOUT..ZOUT, each a big-endian int16, with the register
        map's sensitivities (gyro 131/65.5/32.8/16.4 LSB per deg/s for +-250..2000 deg/s,
        accelerometer 16384/8192/4096/2048 LSB per g for +-2..16 g, g = 9.80665 m/s^2;
        temperature ``(T - 36.53)*340``), rounded to the nearest count and saturated at the
        int16 range. The IMU frame is the body frame (x forward, y left, z up).

        Returns:
            (N, 14) uint8.
        """
        gyro_lsb = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
        accel_lsb = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
        if gyro_range_dps not in gyro_lsb or accel_range_g not in accel_lsb:
            raise ValueError(f"ranges must be one of {sorted(gyro_lsb)} deg/s and "
                             f"{sorted(accel_lsb)} g, got {gyro_range_dps}, {accel_range_g}")
        n = self.imu_t.size
        values = np.empty((n, 7))
        values[:, 0:3] = self.accel / GRAVITY * accel_lsb[accel_range_g]
        values[:, 3] = (temperature - 36.53) * 340.0
        values[:, 4:7] = np.degrees(self.gyro) * gyro_lsb[gyro_range_dps]
        counts = np.clip(np.round(values), -32768, 32767).astype(">i2")
        return counts.view(np.uint8).reshape(n, 14)

    def truth_at(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Truth ``(x, y, yaw)`` linearly interpolated at times ``t`` (yaw unwrapped first)."""
        t = np.asarray(t, dtype=float)
        yaw = np.unwrap(self.truth[:, 2])
        out = np.column_stack([
            np.interp(t, self.truth_t, self.truth[:, 0]),
            np.interp(t, self.truth_t, self.truth[:, 1]),
            np.interp(t, self.truth_t, yaw),
        ])
        out[:, 2] = wrap_angle(out[:, 2])
        return out


def _commands(segments: Sequence[Segment], dt: float) -> tuple[np.ndarray, np.ndarray]:
    vs: list[np.ndarray] = []
    ws: list[np.ndarray] = []
    v_prev = w_prev = 0.0
    for seg in segments:
        n = max(1, round(seg.duration / dt))
        if seg.ramp:
            f = np.arange(1, n + 1) / n
            vs.append(v_prev + (seg.v - v_prev) * f)
            ws.append(w_prev + (seg.w - w_prev) * f)
        else:
            vs.append(np.full(n, seg.v))
            ws.append(np.full(n, seg.w))
        v_prev, w_prev = seg.v, seg.w
    return np.concatenate(vs), np.concatenate(ws)


def _rate_limit(cmd: np.ndarray, step: float) -> np.ndarray:
    out = np.empty_like(cmd)
    y = 0.0
    for i, c in enumerate(cmd.tolist()):
        d = c - y
        if d > step:
            d = step
        elif d < -step:
            d = -step
        y += d
        out[i] = y
    return out


def _stamps(t: np.ndarray, jitter: float, latency: float, rng: np.random.Generator) -> np.ndarray:
    out = t + latency
    if jitter > 0:
        out = out + rng.normal(0.0, jitter, t.shape)
        out = np.maximum.accumulate(out)
    return out


def simulate(
    segments: Sequence[Segment],
    robot: DiffDriveParams,
    imu: ImuModel | None = None,
    encoders: EncoderModel | None = None,
    seed: int = 0,
    dt: float = 1e-3,
    max_accel: float = 1.0,
    max_angular_accel: float = 4.0,
) -> SyntheticRun:
    """Simulate a run of ``segments`` on a robot whose nominal parameters are ``robot``.

    Args:
        segments: the scenario (see the building blocks).
        robot: nominal chassis parameters (wheel_distance m, speed_ratio m/tick,
            encode_sampling_time s); the true geometry differs by ``encoders``' errors.
        imu: IMU model (default: noise only, no bias).
        encoders: encoder model (default: exact geometry, no slip).
        seed: seed of all random draws.
        dt: simulation step, s (the true motion is piecewise constant over it).
        max_accel: forward acceleration limit, m/s^2.
        max_angular_accel: yaw acceleration limit, rad/s^2.

    Returns:
        A :class:`SyntheticRun`.
    """
    imu = imu or ImuModel()
    encoders = encoders or EncoderModel()
    if not segments:
        raise ValueError("segments is empty")
    if not (dt > 0 and max_accel > 0 and max_angular_accel > 0):
        raise ValueError("dt, max_accel and max_angular_accel must be > 0")
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(8)]

    v_cmd, w_cmd = _commands(segments, dt)
    v = _rate_limit(v_cmd, max_accel * dt)
    w = _rate_limit(w_cmd, max_angular_accel * dt)
    n = v.size
    t_grid = np.arange(n + 1) * dt  # knots; step i covers [t_i, t_i+1)
    # exact arcs over each step: the truth at the knots
    x, y, yaw = np.vstack([np.zeros(3), integrate(v * dt, w * dt, rule="arc")]).T
    distance = float(np.sum(np.abs(v)) * dt)

    # wheels: ground travel, then wheel rotation with slip, then encoder counts
    L_true, mpt_l, mpt_r = encoders.true_params(robot)
    gl = (v - 0.5 * L_true * w) * dt
    gr = (v + 0.5 * L_true * w) * dt
    t_mid = t_grid[:-1] + 0.5 * dt
    for p in encoders.slip_patches:
        inside = (t_mid >= p.t0) & (t_mid < p.t1)
        if p.wheel in ("left", "both"):
            gl = np.where(inside, gl * (1 + p.ratio), gl)
        if p.wheel in ("right", "both"):
            gr = np.where(inside, gr * (1 + p.ratio), gr)
    rot_l = np.concatenate(([0.0], np.cumsum(gl)))
    rot_r = np.concatenate(([0.0], np.cumsum(gr)))
    T = robot.encode_sampling_time
    t_frames = np.arange(1, math.floor(t_grid[-1] / T + 1e-9) + 1) * T
    t_frames = np.concatenate(([0.0], t_frames))
    # a small random phase of the encoder counters, so quantisation does not start aligned
    phase = streams[0].uniform(0, 1, 2)
    cnt_l = np.floor(np.interp(t_frames, t_grid, rot_l) / mpt_l + phase[0])
    cnt_r = np.floor(np.interp(t_frames, t_grid, rot_r) / mpt_r + phase[1])
    ticks = np.column_stack([np.diff(cnt_l), np.diff(cnt_r)]).astype(np.int64)
    wheel_true_t = t_frames[1:]
    keep = streams[1].uniform(size=ticks.shape[0]) >= encoders.drop_probability
    ticks = ticks[keep]
    wheel_t = _stamps(wheel_true_t[keep], encoders.jitter, encoders.latency, streams[2])

    # IMU
    n_imu = math.floor(t_grid[-1] * imu.rate + 1e-9) + 1
    t_imu = np.arange(n_imu) / imu.rate
    idx = np.minimum(np.searchsorted(t_grid, t_imu, side="right") - 1, n - 1)
    w_i = w[idx]
    v_i = v[idx]
    acc_fwd = np.diff(np.concatenate(([0.0], v))) / dt
    a_i = acc_fwd[idx]
    omega = np.zeros((n_imu, 3))
    omega[:, 2] = w_i
    rng = streams[3]
    bias = np.tile(np.asarray(imu.gyro_bias, dtype=float), (n_imu, 1))
    if imu.gyro_bias_walk > 0:
        steps = rng.normal(0.0, imu.gyro_bias_walk * math.sqrt(1.0 / imu.rate), (n_imu, 3))
        steps[0] = 0.0
        bias = bias + np.cumsum(steps, axis=0)
    gyro = (1.0 + np.asarray(imu.gyro_scale)) * omega + bias
    gyro += streams[4].normal(0.0, imu.gyro_noise_density * math.sqrt(imu.rate), gyro.shape)
    f = np.zeros((n_imu, 3))
    f[:, 0] = a_i
    f[:, 1] = v_i * w_i
    f[:, 2] = GRAVITY
    accel = f + np.asarray(imu.accel_bias, dtype=float)
    accel += streams[5].normal(0.0, imu.accel_noise_density * math.sqrt(imu.rate), accel.shape)
    if imu.vibration > 0:
        s_wheel = np.concatenate(([0.0], np.cumsum(np.abs(v) * dt)))[idx]
        phase_v = s_wheel / imu.wheel_radius
        amp = imu.vibration * np.abs(v_i)
        accel[:, 2] += amp * np.sin(phase_v)
        accel[:, 0] += 0.5 * amp * np.cos(1.7 * phase_v)
        accel += amp[:, None] * streams[6].normal(0.0, 1.0, accel.shape)
    imu_t = _stamps(t_imu, imu.jitter, 0.0, streams[7])

    truth_yaw = np.interp(t_imu, t_grid, yaw)
    truth = np.column_stack([
        np.interp(t_imu, t_grid, x),
        np.interp(t_imu, t_grid, y),
        wrap_angle(truth_yaw),
    ])
    return SyntheticRun(
        imu_t=imu_t,
        gyro=gyro,
        accel=accel,
        wheel_t=wheel_t,
        ticks=ticks,
        truth_t=t_imu,
        truth=truth,
        truth_v=v_i,
        truth_w=w_i,
        gyro_bias=bias,
        robot=robot,
        true_wheel_distance=L_true,
        true_left_ratio=mpt_l,
        true_right_ratio=mpt_r,
        distance=distance,
        seed=seed,
        info={"dt": dt, "frames_dropped": int((~keep).sum())},
    )


#: Nominal chassis of the examples: 0.3 m track, 0.1 mm per tick, 40 ms period (seed 000).
EXAMPLE_ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4, encode_sampling_time=0.04)


def degraded_mission(
    seed: int = 0,
    duration: float = 300.0,
    robot: DiffDriveParams | None = None,
    separation_error: float = 0.03,
    radius_mismatch: float = 0.005,
    gyro_bias: float = math.radians(0.5),
    gyro_bias_walk: float = 2e-5,
    slip_patches: int = 3,
) -> SyntheticRun:
    """A :func:`random_mission` on a badly calibrated robot (the fused-odometry acceptance case).

    ``robot.toml`` (``robot``, default :data:`EXAMPLE_ROBOT`) is ``separation_error`` (relative)
    off the true wheel distance; the wheels differ in radius by ``radius_mismatch`` (split
    evenly, left smaller, so the mean distance scale is right: a common scale error is a
    ``speed_ratio`` calibration, not something a gyro can observe); the gyro has a z bias of
    ``gyro_bias`` rad/s (x, y: 0.1 deg/s) walking with ``gyro_bias_walk`` rad/s/sqrt(s), the
    MPU6050's noise, and wheel-speed vibration on the accelerometer; ``slip_patches`` one-second
    windows at random times make one wheel over-count by 30 %. The robot starts at rest.
    """
    robot = robot or EXAMPLE_ROBOT
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x511F]))
    starts = np.sort(rng.uniform(0.1 * duration, 0.9 * duration, slip_patches))
    patches = tuple(
        SlipPatch(float(t0), float(t0) + 1.0, wheel=str(rng.choice(["left", "right"])), ratio=0.3)
        for t0 in starts
    )
    imu = ImuModel(
        gyro_bias=(math.radians(0.1), -math.radians(0.1), gyro_bias),
        gyro_bias_walk=gyro_bias_walk,
        vibration=0.5,
    )
    enc = EncoderModel(
        separation_error=separation_error,
        left_scale_error=-0.5 * radius_mismatch,
        right_scale_error=0.5 * radius_mismatch,
        slip_patches=patches,
    )
    return simulate(random_mission(duration, seed=seed), robot, imu, enc, seed=seed)
