"""Sensor setup and the sensor errors of the physics simulator, each switchable.

Every field defaults to an ideal sensor (no noise, no error), so ``SensorModel()`` gives exact
readings of the physics state; :func:`plain_sensors` adds what every estimator is built for
(white noise, a constant gyro bias, a fine encoder) and :func:`all_errors` adds, on top, every
error listed in :data:`ERROR_GROUPS`, with magnitudes and signs drawn from the seed.

Frames: the IMU frame is the sensor's own axes; ``mount_rpy`` is the TRUE URDF roll, pitch, yaw
of the IMU in the base frame (robot.toml states 0 0 0). Units are SI unless a name says
otherwise; temperatures in degC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = ["ERROR_GROUPS", "SensorModel", "all_errors", "plain_sensors", "with_errors"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class SensorModel:
    """Sensor clocks and errors (defaults: ideal).

    Setup:
        imu_rate: IMU sample rate on the IMU's own clock, Hz.
        wheel_period: firmware encoder period on the firmware clock, s (robot.toml's
            ``encode_sampling_time``).
        imu_lowpass: cut-off of the IMU's first-order digital low-pass, Hz (0: none).
        encoder_ticks_per_rev: encoder counts per wheel revolution (quantisation: robot.toml's
            ``speed_ratio = 2*pi*wheel_radius / encoder_ticks_per_rev``).

    Wheel errors:
        radius_error: (left, right) relative error of the true rolling radius against the
            nominal one, 1.
        radius_speed_coeff: effective rolling radius ``R * (1 + c * |wheel surface speed|)``
            (tyre compression changing with speed), 1 per m/s.
        separation_error: true wheel distance = nominal * (1 + this), 1.
        encoder_dead_windows: ((start s, duration s), ...) host-time windows in which every
            frame carries zero ticks on BOTH wheels (a dead encoder feed; the counts are lost)
            while frames keep arriving.
        wheel_frame_loss: probability that a wheel frame is lost (its ticks with it), 1.
        firmware_clock_error: firmware clock rate error, 1 (the true period is
            ``wheel_period * (1 + this)``).
        wheel_latency: constant delay from the end of a period to its host stamp, s.
        wheel_jitter: scale of the extra delay (half-normal), s.

    IMU errors (applied in the IMU frame):
        gyro_noise_std: white noise per gyro sample, rad/s.
        accel_noise_std: white noise per accelerometer sample, m/s^2.
        gyro_bias: additive gyro bias at ``temperature_start``, rad/s.
        accel_bias: additive accelerometer bias, m/s^2.
        gyro_scale: relative scale error per axis, 1.
        gyro_cross_axis: off-diagonal sensitivities ``(xy, xz, yx, yz, zx, zy)``: the
            reading of axis i gains ``c_ij * rate_j``, 1.
        gyro_g_sensitivity: row-major 3x3 rate error per unit specific force,
            (rad/s) per (m/s^2) (MPU6050 datasheet: 0.1 deg/s/g = 1.8e-4).
        gyro_bias_tempco: bias change per kelvin, (rad/s)/K.
        temperature_start, temperature_end, temperature_tau: the IMU warms as
            ``end - (end - start) * exp(-t/tau)``: degC, degC, s.
        vibration_accel: RMS accelerometer vibration per m/s of forward speed,
            (m/s^2)/(m/s), band-limited around ``vibration_frequency``.
        vibration_gyro: RMS gyro vibration per m/s of forward speed, (rad/s)/(m/s).
        vibration_frequency: centre of the vibration band, Hz.
        mount_rpy: true mount of the IMU, rad (robot.toml says 0 0 0).
        imu_sample_loss: probability that an IMU sample is lost, 1.
        imu_clock_error: IMU clock rate error, 1.
        imu_latency, imu_jitter: delay and half-normal extra delay of the host stamps, s.
    """

    imu_rate: float = 200.0
    wheel_period: float = 0.04
    imu_lowpass: float = 0.0
    encoder_ticks_per_rev: int = 65536
    radius_error: tuple[float, float] = (0.0, 0.0)
    radius_speed_coeff: float = 0.0
    separation_error: float = 0.0
    encoder_dead_windows: tuple[tuple[float, float], ...] = ()
    wheel_frame_loss: float = 0.0
    firmware_clock_error: float = 0.0
    wheel_latency: float = 0.0
    wheel_jitter: float = 0.0
    gyro_noise_std: float = 0.0
    accel_noise_std: float = 0.0
    gyro_bias: Vec3 = (0.0, 0.0, 0.0)
    accel_bias: Vec3 = (0.0, 0.0, 0.0)
    gyro_scale: Vec3 = (0.0, 0.0, 0.0)
    gyro_cross_axis: tuple[float, float, float, float, float, float] = (0.0,) * 6
    gyro_g_sensitivity: tuple[float, ...] = (0.0,) * 9
    gyro_bias_tempco: Vec3 = (0.0, 0.0, 0.0)
    temperature_start: float = 25.0
    temperature_end: float = 25.0
    temperature_tau: float = 150.0
    vibration_accel: float = 0.0
    vibration_gyro: float = 0.0
    vibration_frequency: float = 28.0
    mount_rpy: Vec3 = (0.0, 0.0, 0.0)
    imu_sample_loss: float = 0.0
    imu_clock_error: float = 0.0
    imu_latency: float = 0.0
    imu_jitter: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            flat = np.asarray(value, dtype=float).ravel()
            if not np.isfinite(flat).all():
                raise ValueError(f"SensorModel.{f.name} must be finite, got {value!r}")
        for name in ("imu_rate", "wheel_period", "temperature_tau"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SensorModel.{name} must be > 0, got {getattr(self, name)!r}")
        if self.imu_lowpass < 0 or self.imu_lowpass >= 500.0:
            raise ValueError(f"SensorModel.imu_lowpass must be in [0, 500) Hz, got "
                             f"{self.imu_lowpass!r}")
        if int(self.encoder_ticks_per_rev) != self.encoder_ticks_per_rev or \
                self.encoder_ticks_per_rev < 1:
            raise ValueError(f"SensorModel.encoder_ticks_per_rev must be a positive integer, "
                             f"got {self.encoder_ticks_per_rev!r}")
        for name in ("wheel_frame_loss", "imu_sample_loss"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"SensorModel.{name} must be in [0, 1), got "
                                 f"{getattr(self, name)!r}")
        for name in ("wheel_latency", "wheel_jitter", "imu_latency", "imu_jitter",
                     "vibration_accel", "vibration_gyro", "gyro_noise_std", "accel_noise_std"):
            if getattr(self, name) < 0:
                raise ValueError(f"SensorModel.{name} must be >= 0, got {getattr(self, name)!r}")
        for start, duration in self.encoder_dead_windows:
            if duration <= 0:
                raise ValueError(f"SensorModel.encoder_dead_windows: duration must be > 0 s, "
                                 f"got ({start!r}, {duration!r})")

    def temperature(self, t: np.ndarray) -> np.ndarray:
        """IMU temperature at host times ``t`` (s), degC."""
        return self.temperature_end - (self.temperature_end - self.temperature_start) * \
            np.exp(-np.asarray(t, dtype=float) / self.temperature_tau)

    def gyro_bias_at(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) additive gyro bias in the IMU frame at times ``t`` (s), rad/s."""
        dT = self.temperature(t) - self.temperature_start
        return np.asarray(self.gyro_bias) + np.asarray(self.gyro_bias_tempco) * dT[:, None]


#: The switchable errors (beyond :func:`plain_sensors`) and the SensorModel fields each sets.
#: ``low-friction``, ``dead-encoder`` and ``moving-start`` are mission options
#: (:mod:`fusion.evaluation.physics_sim.scenarios`), not sensor fields.
ERROR_GROUPS: dict[str, tuple[str, ...]] = {
    "radius": ("radius_error",),
    "radius-speed": ("radius_speed_coeff",),
    "separation": ("separation_error",),
    "gyro-scale": ("gyro_scale",),
    "gyro-cross-axis": ("gyro_cross_axis",),
    "g-sensitivity": ("gyro_g_sensitivity",),
    "temperature": ("gyro_bias_tempco", "temperature_start", "temperature_end",
                    "temperature_tau"),
    "vibration": ("vibration_accel", "vibration_gyro", "vibration_frequency"),
    "mount-tilt": ("mount_rpy",),
    "quantisation": ("encoder_ticks_per_rev",),
    "frame-loss": ("wheel_frame_loss", "imu_sample_loss"),
    "stamps": ("wheel_latency", "wheel_jitter", "imu_latency", "imu_jitter"),
    "clock": ("firmware_clock_error", "imu_clock_error"),
}


def _signed(rng: np.random.Generator, lo: float, hi: float, n: int | None = None):
    mag = rng.uniform(lo, hi, size=n)
    sign = rng.choice([-1.0, 1.0], size=n)
    out = mag * sign
    return tuple(float(v) for v in out) if n is not None else float(out)


def plain_sensors(seed: int = 0) -> SensorModel:
    """Sensors with only what every estimator models: MPU6050-like white noise
    (gyro 7e-4 rad/s = 0.04 deg/s and accelerometer 0.04 m/s^2 per sample at 200 Hz, a 44 Hz
    low-pass), a constant gyro bias of 0.2-0.8 deg/s per axis (random sign), an accelerometer
    bias up to 0.05 m/s^2, and a fine encoder (65536 counts per revolution)."""
    rng = np.random.default_rng([seed, 101])
    return SensorModel(
        imu_lowpass=44.0,
        gyro_noise_std=7e-4,
        accel_noise_std=0.04,
        gyro_bias=_signed(rng, math.radians(0.2), math.radians(0.8), 3),
        accel_bias=tuple(float(v) for v in rng.uniform(-0.05, 0.05, 3)),
    )


def all_errors(seed: int = 0) -> SensorModel:
    """:func:`plain_sensors` plus every error of :data:`ERROR_GROUPS`; magnitudes (drawn from
    the seed, random signs):

    - radius: each wheel N(0, 0.4 %); radius-speed: 0.5-1.5 % per m/s;
      separation: 2-5 % (robot.toml wrong by that much);
    - gyro-scale: 0.5-2 % per axis; gyro-cross-axis: 0.5-2 % per term (MPU6050: +-3 %, +-2 %);
    - g-sensitivity: 0.05-0.2 deg/s/g per term;
    - temperature: 25 -> 40-50 degC with a 2-4 min time constant, 0.005-0.02 deg/s/K;
    - vibration: 1.5-2.5 (m/s^2)/(m/s) and 0.01-0.03 (rad/s)/(m/s) around 20-35 Hz
      (about 1 m/s^2 RMS at 0.5 m/s);
    - mount-tilt: 0.5-1.5 deg roll and pitch, 0.5-1.5 deg yaw;
    - quantisation: 1024 counts per wheel revolution (0.31 mm of travel per count);
    - frame-loss: 1 % of the wheel frames, 0.5 % of the IMU samples;
    - stamps: wheel frames 15 ms late with 4 ms jitter, IMU samples 3 ms late with 1 ms jitter;
    - clock: firmware clock 0.02-0.1 % off, IMU clock 0.1-0.5 % off.
    """
    base = plain_sensors(seed)
    rng = np.random.default_rng([seed, 202])
    g_sens = math.radians(1.0) / 9.80665  # (rad/s)/(m/s^2) per deg/s/g
    tempco = _signed(rng, math.radians(0.005), math.radians(0.02), 3)
    return replace(
        base,
        radius_error=tuple(float(v) for v in rng.normal(0.0, 0.004, 2)),
        radius_speed_coeff=_signed(rng, 0.005, 0.015),
        separation_error=_signed(rng, 0.02, 0.05),
        gyro_scale=_signed(rng, 0.005, 0.02, 3),
        gyro_cross_axis=_signed(rng, 0.005, 0.02, 6),
        gyro_g_sensitivity=tuple(v * g_sens for v in _signed(rng, 0.05, 0.2, 9)),
        gyro_bias_tempco=tempco,
        temperature_start=25.0,
        temperature_end=float(rng.uniform(40.0, 50.0)),
        temperature_tau=float(rng.uniform(120.0, 240.0)),
        vibration_accel=float(rng.uniform(1.5, 2.5)),
        vibration_gyro=float(rng.uniform(0.01, 0.03)),
        vibration_frequency=float(rng.uniform(20.0, 35.0)),
        mount_rpy=tuple(math.radians(v) for v in _signed(rng, 0.5, 1.5, 3)),
        encoder_ticks_per_rev=1024,
        wheel_frame_loss=0.01,
        imu_sample_loss=0.005,
        wheel_latency=0.015,
        wheel_jitter=0.004,
        imu_latency=0.003,
        imu_jitter=0.001,
        firmware_clock_error=_signed(rng, 2e-4, 1e-3),
        imu_clock_error=_signed(rng, 1e-3, 5e-3),
    )


def with_errors(names: list[str] | tuple[str, ...], seed: int = 0) -> SensorModel:
    """:func:`plain_sensors` with only the named groups of :data:`ERROR_GROUPS` switched on
    (values of :func:`all_errors` for the same seed).

    Raises:
        ValueError: an unknown name (the message lists the known ones).
    """
    unknown = [n for n in names if n not in ERROR_GROUPS]
    if unknown:
        raise ValueError(f"unknown sensor error(s) {unknown}; known: {sorted(ERROR_GROUPS)}")
    full = all_errors(seed)
    chosen = {f: getattr(full, f) for n in names for f in ERROR_GROUPS[n]}
    return replace(plain_sensors(seed), **chosen)
