"""InvenSense MPU-6050 driver over I2C (smbus2), with burst reads, FIFO, self-test, calibration.

Values and procedures follow the MPU-6000/MPU-6050 Register Map and Descriptions (rev 4.2) and
the Product Specification (rev 3.4).

Units and frames: samples come out as ``fusion.types.samples.ImuSample`` in SI units in the sensor's
own axes (x, y, z as printed on the chip; mount it x forward, y left, z up for the library's
body frame): angular rate in rad/s, specific force in m/s^2 (+1 g on the up axis at rest;
g = 9.80665 m/s^2 unless ``gravity`` is given), temperature in deg C, time in s on the host
clock passed as ``clock`` (``time.monotonic`` by default). Raw LSB, g and deg/s appear only in
the explicitly named raw/scaled accessors.

Bus cost: ``read()`` is one I2C transaction (a 15-byte burst at INT_STATUS: the data-ready flag,
then the three axes and the temperature of one sample, never torn between two).

Fresh samples: the chip takes a sample every 1 / ``sample_rate_hz`` s and its data registers hold
the newest one until the next. ``configure()`` (and ``set_dlpf()``) waits for the first sample
taken at the new configuration, so the first ``read()`` is never a sample of the old full-scale
range. A ``read()`` sooner than one period after the previous one returns the same sample
again: DATA_RDY_INT (INT_STATUS bit 0, cleared by reading it) tells, and the driver says so in
``RawSample.fresh`` and the ``fresh`` attribute (False: a repeat; ``stats.repeated_reads``
counts them). ``read(wait=True)`` waits for a new sample instead. ``read_fifo()`` is three
transactions whatever the number of samples: INT_STATUS, FIFO_COUNT, then one read of every
whole 12-byte frame. That last read uses ``i2c_rdwr`` (a plain I2C read of any length) when the
bus has it; smbus2's ``read_i2c_block_data`` stops at 32 bytes, so on an SMBus-only adapter the
FIFO data costs ceil(bytes / 32) transactions instead (e.g. 32 for a full FIFO of 85 frames).

Errors: OSError EIO, EREMOTEIO (121) and ENXIO from the bus (typical when motors start and
noise hits SDA/SCL) are retried ``retries`` times with a short exponential backoff, then raised
as ``MPU6050Error`` (an OSError) naming the bus, the address and the register, with what to
check. A sensor whose data registers stop changing raises ``SensorStuckError`` (or sets
``stuck`` when ``on_stuck="flag"``), see ``MPU6050``.
"""

from __future__ import annotations

import errno as _errno
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fusion.types.constants import STANDARD_GRAVITY
from fusion.types.samples import ImuSample

__all__ = [
    "ACCEL_LSB_PER_G",
    "GYRO_LSB_PER_DPS",
    "MPU6050",
    "STANDARD_GRAVITY",
    "FifoRead",
    "MPU6050Error",
    "RawSample",
    "SelfTestResult",
    "SensorStuckError",
    "SystemClock",
    "accel_factory_trim",
    "gyro_factory_trim",
]


# Register addresses (register map rev 4.2).
SELF_TEST_X = 0x0D
SMPLRT_DIV = 0x19
CONFIG = 0x1A
GYRO_CONFIG = 0x1B
ACCEL_CONFIG = 0x1C
FIFO_EN = 0x23
INT_ENABLE = 0x38
INT_STATUS = 0x3A
ACCEL_XOUT_H = 0x3B
TEMP_OUT_H = 0x41
GYRO_XOUT_H = 0x43
USER_CTRL = 0x6A
PWR_MGMT_1 = 0x6B
FIFO_COUNTH = 0x72
FIFO_R_W = 0x74
WHO_AM_I = 0x75

REGISTER_NAMES = {
    0x0D: "SELF_TEST_X", 0x0E: "SELF_TEST_Y", 0x0F: "SELF_TEST_Z", 0x10: "SELF_TEST_A",
    0x19: "SMPLRT_DIV", 0x1A: "CONFIG", 0x1B: "GYRO_CONFIG", 0x1C: "ACCEL_CONFIG",
    0x23: "FIFO_EN", 0x38: "INT_ENABLE", 0x3A: "INT_STATUS", 0x3B: "ACCEL_XOUT_H",
    0x41: "TEMP_OUT_H", 0x43: "GYRO_XOUT_H", 0x6A: "USER_CTRL", 0x6B: "PWR_MGMT_1",
    0x72: "FIFO_COUNTH", 0x74: "FIFO_R_W", 0x75: "WHO_AM_I",
}

# Sensitivity per full-scale setting (FS_SEL / AFS_SEL 0..3).
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}

_RETRY_ERRNOS = {_errno.EIO, _errno.EREMOTEIO, _errno.ENXIO}
_FIFO_SIZE = 1024
_FRAME = 12  # accel x, y, z then gyro x, y, z, big-endian int16
_FRAME_TEMP = 14  # accel x, y, z, temperature, gyro x, y, z (TEMP_FIFO_EN on)
_I2C_FUNC_I2C = 0x00000001  # smbus2.I2cFunc.I2C: the adapter does plain I2C (i2c_rdwr)
_SELF_TEST_LIMIT = 0.14  # product specification: change from factory trim within +-14 %


class SMBusLike(Protocol):
    """The subset of smbus2.SMBus the driver uses (``i2c_rdwr`` is optional)."""

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...
    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...
    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...


class MPU6050Error(OSError):
    """An I2C failure or a chip that does not behave as an MPU-6050 (bus, address, register
    are in the message; ``errno`` is the underlying bus errno when there is one)."""


class SensorStuckError(MPU6050Error):
    """The data registers returned identical values for too long (see ``MPU6050``)."""


@dataclass(frozen=True)
class RawSample:
    """One raw reading, in LSB as the registers hold it.

    Attributes:
        accel: accelerometer x, y, z (3,) int16 counts.
        gyro: gyroscope x, y, z (3,) int16 counts.
        temperature: TEMP_OUT int16 counts, or None (FIFO frames carry no temperature).
        t: host timestamp, s.
        fresh: True if the chip took this sample after the previous read (DATA_RDY_INT was
            set), False if it is the same sample again, None if unknown (DATA_RDY_EN off in
            INT_ENABLE: a chip the driver did not configure, ``reset=False``).
    """

    accel: tuple[int, int, int]
    gyro: tuple[int, int, int]
    temperature: int | None
    t: float
    fresh: bool | None = None


@dataclass(frozen=True)
class FifoRead:
    """What ``MPU6050.read_fifo`` returns.

    Attributes:
        samples: the samples read, oldest first, timestamped from the sample rate (s).
        overflow: True if the FIFO had overflowed (it was then reset).
        lost: number of samples estimated lost to an overflow or a failed read (from the
            time since the last delivered sample and the sample rate; +-1).
        transactions: I2C transactions this call issued.
        raw: the frames as read, (len(samples), 6) int16 counts: accel x, y, z, gyro x, y, z
            (the temperature of a ``enable_fifo(temperature=True)`` frame is in the samples).
    """

    samples: list[ImuSample]
    overflow: bool = False
    lost: int = 0
    transactions: int = 0
    raw: NDArray[np.int16] = field(default_factory=lambda: np.zeros((0, 6), dtype=np.int16))


@dataclass(frozen=True)
class SelfTestResult:
    """Self-test outcome per axis, order (gyro x, y, z, accel x, y, z).

    Attributes:
        factory_trim: FT from the SELF_TEST registers, LSB at +-250 deg/s / +-8 g.
        response: self-test response STR (output with self-test on minus off), same LSB.
        change: (STR - FT) / FT; NaN where the trim code is 0.
        limit: accepted |change| (0.14 per the product specification).
    """

    factory_trim: NDArray[np.float64]
    response: NDArray[np.float64]
    change: NDArray[np.float64]
    limit: float = _SELF_TEST_LIMIT

    @property
    def passed(self) -> bool:
        """True when every axis has a trim code and |change| <= limit."""
        return bool(np.all(np.abs(self.change) <= self.limit))


def gyro_factory_trim(code: int, axis: int) -> float:
    """Gyro factory trim in LSB (at +-250 deg/s) from a 5-bit XG/YG/ZG_TEST code:
    25 * 131 * 1.046^(code - 1), negated for the Y axis (axis=1); 0 when code is 0."""
    if code == 0:
        return 0.0
    ft = 25.0 * 131.0 * 1.046 ** (code - 1)
    return -ft if axis == 1 else ft


def accel_factory_trim(code: int) -> float:
    """Accelerometer factory trim in LSB (at +-8 g) from a 5-bit XA/YA/ZA_TEST code:
    4096 * 0.34 * (0.92 / 0.34)^((code - 1) / (2^5 - 2)); 0 when code is 0."""
    if code == 0:
        return 0.0
    return 4096.0 * 0.34 * (0.92 / 0.34) ** ((code - 1) / 30.0)


class SystemClock:
    """The host's monotonic clock (``time.monotonic``/``time.sleep``), s: the default clock."""

    @staticmethod
    def monotonic() -> float:
        return time.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


def _int16(hi: int, lo: int) -> int:
    v = (hi << 8) | lo
    return v - 0x10000 if v & 0x8000 else v


@dataclass
class _Stats:
    transactions: int = 0
    retries: int = 0
    failures: int = 0
    repeated_reads: int = 0  # read()/read_raw() that returned the previous sample again
    by_register: dict[int, int] = field(default_factory=dict)


class _FifoClock:
    """Maps FIFO frame index k (since a reset) to host time: t(k) = a + k * T.

    Each FIFO read tells that K frames existed at host time t_c and frame K did not, i.e.
    t(K - 1) <= t_c < t(K): the observation t_c ~ t(K - 1/2), off by at most T/2. A weighted
    least-squares line through these observations (the reset itself is the observation
    K = 0 at the reset time) with a weak prior on the nominal period estimates the phase a
    and the chip's actual period T (its oscillator is off by up to a few %). Old observations
    fade with a 30 s time constant so slow drift is followed.
    """

    _TAU_S = 30.0
    _PRIOR = 1000.0  # weight of the nominal period (frame-index^2 units): about +-1 %

    def __init__(self, t_reset: float, period: float) -> None:
        self.t0 = t_reset
        self.nominal = period
        self.s0 = self.s1 = self.s2 = self.sy = self.s1y = 0.0
        self.last_t = t_reset
        self.a, self.period = 0.5 * period, period
        self.observe(0, t_reset)

    def observe(self, frames: int, t_count: float) -> None:
        w = math.exp(-max(0.0, t_count - self.last_t) / self._TAU_S)
        self.s0, self.s1, self.s2 = self.s0 * w, self.s1 * w, self.s2 * w
        self.sy, self.s1y = self.sy * w, self.s1y * w
        self.last_t = t_count
        k, y = frames - 0.5, t_count - self.t0
        self.s0 += 1.0
        self.s1 += k
        self.s2 += k * k
        self.sy += y
        self.s1y += k * y
        p = self._PRIOR
        det = self.s0 * (self.s2 + p) - self.s1 * self.s1
        if det <= 0:
            return
        a = (self.sy * (self.s2 + p) - self.s1 * (self.s1y + p * self.nominal)) / det
        period = (self.s0 * (self.s1y + p * self.nominal) - self.s1 * self.sy) / det
        if abs(period / self.nominal - 1.0) < 0.05:  # a chip's clock is not 5 % off
            self.a, self.period = a, period

    def time_of(self, k: Any) -> Any:
        return self.t0 + self.a + np.asarray(k, dtype=float) * self.period \
            if np.ndim(k) else self.t0 + self.a + float(k) * self.period


class MPU6050:
    """MPU-6050 on an I2C bus.

    Args:
        bus: an I2C bus number (``smbus2.SMBus(bus)`` is opened here and closed by
            ``close()``) or any object with smbus2.SMBus's ``read_byte_data``,
            ``write_byte_data``, ``read_i2c_block_data`` and optionally ``i2c_rdwr``.
        address: 7-bit address, 0x68 (AD0 low) or 0x69 (AD0 high).
        gyro_range_dps: full scale 250, 500, 1000 or 2000 deg/s.
        accel_range_g: full scale 2, 4, 8 or 16 g.
        dlpf: DLPF_CFG 0..6 (accel bandwidth 260, 184, 94, 44, 21, 10, 5 Hz). It also sets the
            gyro output rate: 8 kHz for 0, 1 kHz otherwise.
        sample_rate_hz: wanted sample rate; SMPLRT_DIV is the nearest divider of the gyro
            output rate and ``sample_rate_hz`` is then the rate obtained (a request more
            than 5 % away from every achievable rate is refused).
        gravity: m/s^2 per g for the conversion of accelerometer readings.
        calibration: a ``fusion.calibration.imu.ImuCalibration`` applied by ``read()`` and
            ``read_fifo()`` (settable later through the ``calibration`` attribute).
        retries: extra attempts after an EIO/EREMOTEIO/ENXIO failure of one transaction.
        backoff_s: first wait before a retry, s; doubles on each further retry.
        clock: object with ``monotonic()`` and ``sleep(s)`` giving host time (default the
            system's monotonic clock; tests pass the simulator's clock).
        stuck_samples: the sensor is declared stuck when its 12 accel+gyro bytes stay
            identical over this many sample periods and reads (0 disables the check).
            With the real chip's noise (several LSB on each axis) 50 identical samples do
            not happen while it works; a frozen bus, a dead chip or a chip that was reset
            by a brown-out (asleep: registers frozen) does it at once.
        on_stuck: ``"raise"`` (``SensorStuckError``) or ``"flag"`` (sets ``self.stuck``).
        accept_who_am_i: WHO_AM_I values accepted (0x68 for a genuine MPU-6050).
        use_i2c_rdwr: True/False to force, None to use it when the bus offers it.
        reset: reset and configure the chip now (False: only check WHO_AM_I).

    Attributes:
        stats: transactions issued, retries and failures seen, repeated reads.
        stuck: True while the stuck condition holds (``on_stuck="flag"``).
        fresh: whether the last ``read()``/``read_raw()`` returned a new sample (see
            ``RawSample.fresh``; None before the first read).

    One driver is not safe to share between threads: give it its own thread (or a lock).
    """

    def __init__(
        self,
        bus: int | Any,
        address: int = 0x68,
        *,
        gyro_range_dps: int = 250,
        accel_range_g: int = 2,
        dlpf: int = 3,
        sample_rate_hz: float = 100.0,
        gravity: float = STANDARD_GRAVITY,
        calibration: Any | None = None,
        retries: int = 3,
        backoff_s: float = 0.002,
        clock: Any | None = None,
        stuck_samples: int = 50,
        on_stuck: str = "raise",
        accept_who_am_i: Sequence[int] = (0x68,),
        use_i2c_rdwr: bool | None = None,
        reset: bool = True,
    ) -> None:
        if gyro_range_dps not in GYRO_LSB_PER_DPS:
            raise ValueError(
                f"gyro_range_dps must be one of 250, 500, 1000, 2000 deg/s; got {gyro_range_dps}"
            )
        if accel_range_g not in ACCEL_LSB_PER_G:
            raise ValueError(f"accel_range_g must be one of 2, 4, 8, 16 g; got {accel_range_g}")
        if not 0 <= int(dlpf) <= 6:
            raise ValueError(f"dlpf must be DLPF_CFG 0..6 (7 is reserved); got {dlpf}")
        if not 0x00 <= address <= 0x7F:
            raise ValueError(f"address {address:#x} is not a 7-bit I2C address")
        for name, value, least in (("retries", retries, 0), ("stuck_samples", stuck_samples, 0)):
            if isinstance(value, bool) or not (isinstance(value, int) and value >= least):
                raise ValueError(f"{name} must be a whole number >= {least}; got {value!r}")
        if not (isinstance(backoff_s, (int, float)) and 0 <= backoff_s < math.inf):
            raise ValueError(f"backoff_s must be finite and >= 0 s; got {backoff_s!r}")
        if on_stuck not in ("raise", "flag"):
            raise ValueError(f"on_stuck must be 'raise' or 'flag'; got {on_stuck!r}")
        if not (isinstance(gravity, (int, float)) and 0 < gravity < math.inf):
            raise ValueError(f"gravity must be finite and > 0 m/s^2; got {gravity!r}")
        self.address = int(address)
        self.gyro_range_dps = int(gyro_range_dps)
        self.accel_range_g = int(accel_range_g)
        self.dlpf = int(dlpf)
        self.gravity = float(gravity)
        self.calibration = calibration
        self.retries = int(retries)
        self.backoff_s = float(backoff_s)
        self.clock = clock if clock is not None else SystemClock()
        self.stuck_samples = int(stuck_samples)
        self.on_stuck = on_stuck
        self.stats = _Stats()
        self.stuck = False
        self._owns_bus = False
        gyro_rate = self.gyro_output_rate_hz
        if not gyro_rate / 256.0 * 0.95 <= sample_rate_hz <= gyro_rate * 1.05:
            raise ValueError(
                f"sample_rate_hz {sample_rate_hz} is outside {gyro_rate / 256:.3g}.."
                f"{gyro_rate:.0f} Hz for dlpf={dlpf} (gyro output rate {gyro_rate:.0f} Hz)"
            )
        div = min(255, max(0, round(gyro_rate / sample_rate_hz) - 1))
        got = gyro_rate / (1 + div)
        if abs(got - sample_rate_hz) > 0.05 * sample_rate_hz:
            near = sorted({gyro_rate / (1 + d) for d in (max(0, div - 1), div, min(255, div + 1))})
            raise ValueError(
                f"sample_rate_hz {sample_rate_hz} cannot be made from the {gyro_rate:.0f} Hz "
                f"gyro rate; nearest: {', '.join(f'{r:.4g}' for r in near)} Hz"
            )
        self.smplrt_div = div

        if isinstance(bus, int):
            import smbus2  # only needed for real hardware

            self.bus_name = f"/dev/i2c-{bus}"
            try:
                self.bus = smbus2.SMBus(bus)
            except OSError as exc:
                raise MPU6050Error(
                    exc.errno,
                    f"cannot open I2C bus {bus} ({self.bus_name}): {exc.strerror or exc}. Check "
                    "that I2C is enabled (raspi-config / dtparam=i2c_arm=on), the bus number "
                    "(ls /dev/i2c-*) and that you may use it (group i2c)",
                ) from exc
            self._owns_bus = True
        else:
            self.bus = bus
            number = getattr(bus, "bus_number", None)
            self.bus_name = f"/dev/i2c-{number}" if number is not None else type(bus).__name__
        if use_i2c_rdwr is None:
            funcs = getattr(self.bus, "funcs", None)
            use_i2c_rdwr = hasattr(self.bus, "i2c_rdwr") and (
                funcs is None or bool(int(funcs) & _I2C_FUNC_I2C)
            )
        self.use_i2c_rdwr = bool(use_i2c_rdwr)

        self._same_raw: bytes | None = None
        self._same_count = 0
        self._same_since = 0.0
        self._int_latch = 0
        self._unread = False  # a DATA_RDY seen by data_ready() whose sample was not read yet
        self._data_rdy_on = True
        self.fresh: bool | None = None
        self._fifo_on = False
        self._frame = _FRAME
        self._fifo_index = 0
        self._fifo_clock = _FifoClock(0.0, 0.01)
        self._fifo_last_t = -math.inf

        try:
            who = self._read_byte(WHO_AM_I)
            if who not in accept_who_am_i:
                hint = {0x70: " (an MPU-6500?)", 0x71: " (an MPU-9250?)", 0x73: " (an MPU-9255?)",
                        0x98: " (a clone?)"}.get(who, "")
                raise MPU6050Error(
                    f"{self._where(WHO_AM_I)}: WHO_AM_I is {who:#04x}{hint}, expected "
                    f"{', '.join(f'{v:#04x}' for v in accept_who_am_i)} for an MPU-6050. Check "
                    "the address (i2cdetect) or pass accept_who_am_i"
                )
            if reset:
                self.configure()
            else:
                self._data_rdy_on = bool(self._read_byte(INT_ENABLE) & 0x01)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ configuration
    @property
    def gyro_output_rate_hz(self) -> float:
        """Gyroscope output rate: 8000 Hz when DLPF_CFG is 0 (or 7), else 1000 Hz."""
        return 8000.0 if self.dlpf in (0, 7) else 1000.0

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate in force: gyro output rate / (1 + SMPLRT_DIV), Hz."""
        return self.gyro_output_rate_hz / (1 + self.smplrt_div)

    @property
    def gyro_lsb_per_dps(self) -> float:
        """Gyro sensitivity of the configured range, LSB/(deg/s)."""
        return GYRO_LSB_PER_DPS[self.gyro_range_dps]

    @property
    def accel_lsb_per_g(self) -> float:
        """Accelerometer sensitivity of the configured range, LSB/g."""
        return ACCEL_LSB_PER_G[self.accel_range_g]

    def configure(self) -> None:
        """Reset the chip, wake it on the gyro PLL clock and write the configuration.

        DEVICE_RESET (PWR_MGMT_1 = 0x80), wait 100 ms for it to clear, PWR_MGMT_1 = 0x01
        (awake, CLKSEL = PLL with X gyro reference), SMPLRT_DIV, CONFIG (DLPF_CFG, keeping
        the EXT_SYNC_SET bits), GYRO_CONFIG, ACCEL_CONFIG, INT_ENABLE (DATA_RDY and
        FIFO_OFLOW), then reads the four configuration registers back to verify them, and
        waits for the first sample taken at the new configuration (at most two sample periods).
        """
        self._write_byte(PWR_MGMT_1, 0x80)
        for _ in range(10):
            self.clock.sleep(0.1)
            if not self._read_byte(PWR_MGMT_1) & 0x80:
                break
        else:
            raise MPU6050Error(f"{self._where(PWR_MGMT_1)}: DEVICE_RESET did not clear in 1 s")
        self._write_byte(PWR_MGMT_1, 0x01)
        self.clock.sleep(0.01)  # PLL start-up
        ext_sync = self._read_byte(CONFIG) & 0x38
        want = bytes([
            self.smplrt_div,
            ext_sync | self.dlpf,
            list(GYRO_LSB_PER_DPS).index(self.gyro_range_dps) << 3,
            list(ACCEL_LSB_PER_G).index(self.accel_range_g) << 3,
        ])
        for i, value in enumerate(want):
            self._write_byte(SMPLRT_DIV + i, value)
        self._write_byte(INT_ENABLE, 0x11)  # FIFO_OFLOW_EN | DATA_RDY_EN
        got = self._read_block(SMPLRT_DIV, 4)
        if got != want:
            raise MPU6050Error(
                f"{self._where(SMPLRT_DIV)}: configuration read back as {got.hex(' ')}, "
                f"wrote {want.hex(' ')}; the chip is not holding its registers (power?)"
            )
        self._fifo_on = False
        self._same_raw = None
        self._data_rdy_on = True
        self._await_new_configuration()

    def _await_new_configuration(self) -> None:
        """Wait until the data registers hold a sample taken after the configuration was
        written: clear DATA_RDY_INT (the sample it flags may predate the writes), then wait for
        the next one. Without this, a read right after ``configure()`` returns the sample the
        chip took at its reset ranges (+-2 g), scaled for the new range."""
        self._int_status()
        self._unread = False
        self.wait_data_ready(max(1.0, 3.0 / self.sample_rate_hz))

    def set_dlpf(self, dlpf: int) -> None:
        """Change DLPF_CFG (0..6) read-modify-write, keeping CONFIG's EXT_SYNC_SET bits.

        SMPLRT_DIV is kept, so moving between DLPF 0 (8 kHz gyro rate) and 1..6 (1 kHz)
        changes ``sample_rate_hz`` eightfold. Returns once a sample taken with the new setting
        is in the data registers (unless the data-ready interrupt is off, ``reset=False``).
        """
        if not 0 <= int(dlpf) <= 6:
            raise ValueError(f"dlpf must be DLPF_CFG 0..6 (7 is reserved); got {dlpf}")
        config = self._read_byte(CONFIG)
        self._write_byte(CONFIG, (config & 0xF8) | int(dlpf))
        self.dlpf = int(dlpf)
        if self._data_rdy_on and not self._fifo_on:
            self._await_new_configuration()

    # ------------------------------------------------------------------ bus I/O
    def _where(self, register: int) -> str:
        name = REGISTER_NAMES.get(register, "")
        reg = f"register {register:#04x}" + (f" ({name})" if name else "")
        return f"MPU6050 on I2C bus {self.bus_name} address {self.address:#04x}, {reg}"

    def _io(self, register: int, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        attempt = 0
        while True:
            self.stats.transactions += 1
            self.stats.by_register[register] = self.stats.by_register.get(register, 0) + 1
            try:
                return fn(*args)
            except OSError as exc:
                code = exc.errno
                if code in _RETRY_ERRNOS and attempt < self.retries:
                    self.stats.retries += 1
                    self.clock.sleep(self.backoff_s * (2**attempt))
                    attempt += 1
                    continue
                self.stats.failures += 1
                tries = f" after {attempt + 1} attempts" if attempt else ""
                raise MPU6050Error(
                    code,
                    f"{self._where(register)}: {what} failed{tries}: {exc}. Check the wiring "
                    "(SDA, SCL, pull-ups, common ground, short leads away from motor wires), the "
                    f"address ({self.address:#04x}: AD0 low = 0x68, high = 0x69; i2cdetect -y N) "
                    "and the power (VCC 3.3-5 V on a breakout, no brown-out when motors start)",
                ) from exc

    def _read_byte(self, register: int) -> int:
        return int(self._io(register, "read", self.bus.read_byte_data, self.address, register))

    def _write_byte(self, register: int, value: int) -> None:
        self._io(register, f"write of {value:#04x}", self.bus.write_byte_data, self.address,
                 register, value)

    def _read_block(self, register: int, length: int) -> bytes:
        """Read ``length`` bytes from ``register`` (auto-increment; FIFO_R_W repeats).

        One transaction when ``length <= 32`` or ``i2c_rdwr`` is available, otherwise
        ceil(length / 32) SMBus block reads.
        """
        if length <= 32 and hasattr(self.bus, "read_i2c_block_data"):
            return bytes(self._io(register, f"read of {length} bytes",
                                  self.bus.read_i2c_block_data, self.address, register, length))
        if self.use_i2c_rdwr:
            return self._io(register, f"read of {length} bytes", self._rdwr_read, register, length)
        out = bytearray()
        while len(out) < length:
            n = min(32, length - len(out))
            start = register if register == FIFO_R_W else register + len(out)
            out += bytes(self._io(start, f"read of {n} bytes", self.bus.read_i2c_block_data,
                                  self.address, start, n))
        return bytes(out)

    def _rdwr_read(self, register: int, length: int) -> bytes:
        from smbus2 import i2c_msg

        write = i2c_msg.write(self.address, [register])
        read = i2c_msg.read(self.address, length)
        self.bus.i2c_rdwr(write, read)
        return bytes(read)

    def close(self) -> None:
        """Close the bus if this driver opened it (a passed-in bus object is left open)."""
        if self._owns_bus:
            self._owns_bus = False
            self.bus.close()

    def __enter__(self) -> MPU6050:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ sample reads
    def read_raw(self) -> RawSample:
        """One 15-byte burst at INT_STATUS (one transaction): raw counts, host time (s) and
        whether the sample is new since the last read (``RawSample.fresh``)."""
        t = self.clock.monotonic()
        block = self._read_block(INT_STATUS, 15)
        status, data = block[0], block[1:]
        self._int_latch |= status & 0x10  # FIFO_OFLOW, cleared by this read: keep it
        fresh = bool(status & 0x01) or self._unread if self._data_rdy_on else None
        self._unread = False
        self.fresh = fresh
        if fresh is False:
            self.stats.repeated_reads += 1
        v = [_int16(data[i], data[i + 1]) for i in range(0, 14, 2)]
        self._check_stuck(data[0:6] + data[8:14], t, per_sample=False)
        return RawSample((v[0], v[1], v[2]), (v[4], v[5], v[6]), v[3], t, fresh)

    def _to_si(self, accel: Sequence[int] | NDArray[Any], gyro: Sequence[int] | NDArray[Any],
               calibrated: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        a = np.asarray(accel, dtype=float) * (self.gravity / self.accel_lsb_per_g)
        g = np.radians(np.asarray(gyro, dtype=float) / self.gyro_lsb_per_dps)
        if calibrated and self.calibration is not None:
            a = self.calibration.apply_accel(a)
            g = self.calibration.apply_gyro(g)
        return a, g

    def read(self, *, calibrated: bool = True, wait: bool = False,
             timeout_s: float = 1.0) -> ImuSample:
        """The newest sample as ``ImuSample``: gyro rad/s, accel m/s^2, temperature deg C
        (raw / 340 + 36.53), host time s. One I2C transaction (plus data-ready polling when
        ``wait``). The calibration, if any, is applied unless ``calibrated=False``.

        Read sooner than one sample period after the previous read, it is the same sample
        again: then ``self.fresh`` is False (see the module docstring). ``wait=True`` polls
        DATA_RDY first (up to ``timeout_s`` s), so the sample is always a new one."""
        if wait:
            self.wait_data_ready(timeout_s)
        raw = self.read_raw()
        a, g = self._to_si(raw.accel, raw.gyro, calibrated)
        temp = raw.temperature / 340.0 + 36.53 if raw.temperature is not None else None
        return ImuSample(raw.t, g, a, None, temp)

    # Accessors equivalent to the seed's MPU6050_Get_{Accel,Gyro}_{RawData,Scale,Cali}.
    def accel_raw(self) -> tuple[int, int, int]:
        """Accelerometer x, y, z in LSB (one burst read)."""
        return self.read_raw().accel

    def gyro_raw(self) -> tuple[int, int, int]:
        """Gyroscope x, y, z in LSB (one burst read)."""
        return self.read_raw().gyro

    def accel_scaled(self) -> NDArray[np.float64]:
        """Accelerometer x, y, z in g (LSB / sensitivity of the range), uncalibrated."""
        return np.asarray(self.read_raw().accel, dtype=float) / self.accel_lsb_per_g

    def gyro_scaled(self) -> NDArray[np.float64]:
        """Gyroscope x, y, z in deg/s (LSB / sensitivity of the range), uncalibrated."""
        return np.asarray(self.read_raw().gyro, dtype=float) / self.gyro_lsb_per_dps

    def accel_calibrated(self) -> NDArray[np.float64]:
        """Accelerometer x, y, z in g with the calibration applied (scaled if none)."""
        return self.read().accel / self.gravity

    def gyro_calibrated(self) -> NDArray[np.float64]:
        """Gyroscope x, y, z in deg/s with the calibration applied (scaled if none)."""
        return np.degrees(self.read().gyro)

    def temperature(self) -> float:
        """Die temperature, deg C (TEMP_OUT / 340 + 36.53; one 2-byte read)."""
        d = self._read_block(TEMP_OUT_H, 2)
        return _int16(d[0], d[1]) / 340.0 + 36.53

    # ------------------------------------------------------------------ interrupts
    def _int_status(self) -> int:
        status = self._read_byte(INT_STATUS)  # clears on read: keep FIFO_OFLOW for read_fifo
        self._int_latch |= status & 0x10
        return status

    def data_ready(self) -> bool:
        """True when a new sample arrived since the last read (DATA_RDY_INT)."""
        if self._int_status() & 0x01:
            self._unread = True  # reading INT_STATUS cleared the flag: remember it
        return self._unread

    def wait_data_ready(self, timeout_s: float = 1.0, poll_s: float | None = None) -> None:
        """Poll DATA_RDY_INT until set; ``MPU6050Error`` after ``timeout_s`` (s)."""
        poll = poll_s if poll_s is not None else min(0.001, 0.25 / self.sample_rate_hz)
        deadline = self.clock.monotonic() + timeout_s
        while not self.data_ready():
            if self.clock.monotonic() > deadline:
                raise MPU6050Error(
                    f"{self._where(INT_STATUS)}: no DATA_RDY within {timeout_s} s; is the chip "
                    "asleep (PWR_MGMT_1) or was it reset? Call configure()"
                )
            self.clock.sleep(poll)

    # ------------------------------------------------------------------ stuck sensor
    def _check_stuck(self, raw12: bytes, t: float, per_sample: bool) -> None:
        if self.stuck_samples <= 0:
            return
        if raw12 != self._same_raw:
            self._same_raw, self._same_count, self._same_since = raw12, 1, t
            self.stuck = False
            return
        self._same_count += 1
        span = self._same_count - 1 if per_sample else (t - self._same_since) * self.sample_rate_hz
        if self._same_count < self.stuck_samples or span < self.stuck_samples - 1:
            return
        self.stuck = True
        if self.on_stuck == "flag":
            return
        detail = ""
        try:
            pwr = self._read_byte(PWR_MGMT_1)
            if pwr & 0x40:
                detail = (f" PWR_MGMT_1 is {pwr:#04x}: the chip is asleep, so it was reset "
                          "(a brown-out when motors start?); call configure() to wake it.")
        except MPU6050Error:
            pass
        self._same_raw = None  # report again only after another full run
        raise SensorStuckError(
            f"{self._where(ACCEL_XOUT_H)}: accel+gyro data identical for {self._same_count} "
            f"reads over {span:.0f} sample periods ({raw12.hex()}).{detail} A working sensor's "
            "noise changes them every sample; check power and the sensor"
        )

    # ------------------------------------------------------------------ FIFO
    def enable_fifo(self, *, temperature: bool = False) -> None:
        """Put accel + gyro x, y, z (12-byte frames) into the FIFO, reset it and start.

        Samples are then collected with ``read_fifo()``. At 1 kHz the 1024-byte FIFO holds
        85 frames (85 ms), and at 400 kHz each frame takes 0.27 ms to read, during which new
        ones arrive: read at least every 60 ms (benchmarks/mpu6050_transactions.py).

        ``temperature=True`` adds the die temperature to each frame (TEMP_FIFO_EN: 14-byte
        frames, so the FIFO holds 73 of them), and the samples carry it (deg C).
        """
        self._frame = _FRAME_TEMP if temperature else _FRAME
        # XG, YG, ZG, ACCEL (+ TEMP)
        self._write_byte(FIFO_EN, 0xF8 if temperature else 0x78)
        self._fifo_reset()
        self._fifo_on = True

    def disable_fifo(self) -> None:
        """Stop filling the FIFO (USER_CTRL.FIFO_EN = 0, FIFO_EN = 0) and empty it."""
        self._write_byte(USER_CTRL, 0x04)
        self._write_byte(FIFO_EN, 0x00)
        self._fifo_on = False

    def _fifo_reset(self) -> None:
        t = self.clock.monotonic()
        self._write_byte(USER_CTRL, 0x44)  # FIFO_EN | FIFO_RESET in one write
        # Frame 0 lands within the next sample period: the reset is observation K = 0.
        self._fifo_clock = _FifoClock(t, 1.0 / self.sample_rate_hz)
        self._fifo_index = 0
        self._fifo_last_t = -math.inf
        self._int_latch &= ~0x10

    def _last_delivered_time(self) -> float:
        if math.isfinite(self._fifo_last_t):
            return self._fifo_last_t
        return float(self._fifo_clock.time_of(-1))  # nothing delivered since the reset

    def read_fifo(self, *, calibrated: bool = True) -> FifoRead:
        """Read every whole frame in the FIFO: 3 transactions however many frames.

        Timestamps (host clock, s): frame k since the last FIFO reset is at a + k * T, with
        the phase a and the chip's actual period T fitted to what every read tells (the
        frames counted were there when FIFO_COUNT was read, the next was not; see
        ``_FifoClock``), so the chip's oscillator error (about 1 %) is learnt and followed.
        Successive timestamps never go backwards and move by at most 5 % of a period per
        read while the fit settles. On the simulated chip with a +-1 % clock error they stay
        within half a period of the truth once settled (tests/test_mpu6050.py).

        Overflow (INT_STATUS.FIFO_OFLOW_INT, or a count that is not whole frames) resets the
        FIFO and reports the samples lost; so does a failed data read, since a partly read
        FIFO cannot be re-aligned.
        """
        if not self._fifo_on:
            raise MPU6050Error(f"{self._where(FIFO_R_W)}: FIFO not enabled; call enable_fifo()")
        before = self.stats.transactions
        status = self._int_status()
        overflow = bool((status | self._int_latch) & 0x10)
        t_count = self.clock.monotonic()
        d = self._read_block(FIFO_COUNTH, 2)
        count = (d[0] << 8) | d[1]
        frame = self._frame
        if overflow or count % frame or count >= _FIFO_SIZE - frame + 1:
            return self._recover(overflow=True, before=before)
        n = count // frame
        if n == 0:
            return FifoRead([], transactions=self.stats.transactions - before)
        try:
            data = self._read_block(FIFO_R_W, n * frame)
        except MPU6050Error:
            return self._recover(overflow=False, before=before)
        # n frames more since the reset were there when FIFO_COUNT was read, the next not.
        self._fifo_clock.observe(self._fifo_index + n, t_count)
        times = self._fifo_clock.time_of(self._fifo_index + np.arange(n))
        if math.isfinite(self._fifo_last_t):
            # Slew, don't jump: successive samples stay within 5 % of a period of the
            # estimated period apart while the estimate settles (never backwards).
            step = self._fifo_clock.period
            follow = self._fifo_last_t + step
            shift = min(max(times[0] - follow, -0.05 * step), 0.05 * step)
            times = times - times[0] + follow + shift
        self._fifo_last_t = float(times[-1])
        words = np.frombuffer(data, dtype=">i2").reshape(n, frame // 2).astype(np.int16)
        temps: list[float | None] = [None] * n
        if frame == _FRAME_TEMP:  # accel, temperature, gyro
            temps = [float(v) / 340.0 + 36.53 for v in words[:, 3]]
            counts = np.ascontiguousarray(np.delete(words, 3, axis=1))
        else:
            counts = words
        raw = counts.astype(float)
        accel, gyro = self._to_si(raw[:, :3], raw[:, 3:], calibrated)
        samples = []
        for i in range(n):
            t = float(times[i])
            self._check_stuck(counts[i].astype(">i2").tobytes(), t, per_sample=True)
            samples.append(ImuSample(t, gyro[i], accel[i], None, temps[i]))
        self._fifo_index += n
        return FifoRead(samples, transactions=self.stats.transactions - before, raw=counts)

    def _recover(self, *, overflow: bool, before: int) -> FifoRead:
        t = self.clock.monotonic()
        last = self._last_delivered_time()
        lost = max(0, math.floor((t - last) * self.sample_rate_hz + 1e-9))
        self._fifo_reset()
        return FifoRead([], overflow=overflow, lost=lost,
                        transactions=self.stats.transactions - before)

    # ------------------------------------------------------------------ self-test
    def self_test(self, samples: int = 20, settle_s: float = 0.05) -> SelfTestResult:
        """Self-test per the register map (section 4.1): with the gyro at +-250 deg/s and the
        accelerometer at +-8 g, average ``samples`` readings with self-test off and on,
        STR = on - off, compare with the factory trim FT decoded from SELF_TEST_X..A:
        pass when |STR - FT| / FT <= 14 %. Keep the sensor still meanwhile. The previous
        GYRO_CONFIG/ACCEL_CONFIG are restored."""
        old = self._read_block(GYRO_CONFIG, 2)
        period = 1.0 / self.sample_rate_hz

        def average(gyro_cfg: int, accel_cfg: int) -> NDArray[np.float64]:
            self._write_byte(GYRO_CONFIG, gyro_cfg)
            self._write_byte(ACCEL_CONFIG, accel_cfg)
            self.clock.sleep(settle_s)
            acc = np.zeros(6)
            for _ in range(samples):
                self.clock.sleep(period)
                d = self._read_block(ACCEL_XOUT_H, 14)
                v = np.frombuffer(d, dtype=">i2").astype(float)
                acc += np.concatenate([v[4:7], v[0:3]])
            return acc / samples

        try:
            off = average(0x00, 0x10)  # +-250 deg/s, +-8 g
            on = average(0xE0, 0xF0)  # XG/YG/ZG_ST and XA/YA/ZA_ST set
        finally:
            self._write_byte(GYRO_CONFIG, old[0])
            self._write_byte(ACCEL_CONFIG, old[1])
        st = self._read_block(SELF_TEST_X, 4)
        g_codes = [st[i] & 0x1F for i in range(3)]
        a_codes = [((st[i] >> 5) << 2) | ((st[3] >> (4 - 2 * i)) & 0x03) for i in range(3)]
        ft = np.array([gyro_factory_trim(c, i) for i, c in enumerate(g_codes)]
                      + [accel_factory_trim(c) for c in a_codes])
        response = on - off
        with np.errstate(divide="ignore", invalid="ignore"):
            change = np.where(ft != 0, (response - ft) / np.where(ft != 0, ft, 1), np.nan)
        self._same_raw = None
        return SelfTestResult(ft, response, change)
