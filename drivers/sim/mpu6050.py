"""A simulated MPU-6050 at register level, behind an object with smbus2.SMBus's methods.

The model follows the MPU-6000/MPU-6050 Register Map and Descriptions (rev 4.2) and the Product
Specification (rev 3.4). It is written independently of ``drivers.mpu6050`` (its own register
constants and sensitivity tables) so that driver tests check one reading of the datasheet
against another.

What is modelled:

* a 128-byte register file with the documented reset values: asleep at power-on
  (PWR_MGMT_1 = 0x40), WHO_AM_I = 0x68 (also when AD0 is high and the address is 0x69);
  DEVICE_RESET (PWR_MGMT_1 bit 7) restores them; read-only registers ignore writes;
* sampling: the gyroscope output rate is 8 kHz when DLPF_CFG is 0 or 7, else 1 kHz, and the
  sample rate is that rate / (1 + SMPLRT_DIV). At each sample instant the data registers
  0x3B..0x48 are updated atomically (a burst read sees one sample) and, when enabled, the
  frame is pushed into the FIFO. The DLPF's filtering is optional (``model_dlpf``); the
  accelerometer is sampled at the same instants as the gyroscope;
* range-dependent scaling (131 / 65.5 / 32.8 / 16.4 LSB/(deg/s), 16384 / 8192 / 4096 / 2048
  LSB/g), rounding to integers and saturation at the int16 limits; temperature
  raw = (T - 36.53) * 340;
* the FIFO: 1024 bytes, frames written in register order (accel, temp, gyro x, y, z) for the
  sources enabled in FIFO_EN; on overflow the oldest *bytes* are dropped (so frame alignment is
  lost, as on the chip) and FIFO_OFLOW_INT (INT_STATUS bit 4) is set when enabled in
  INT_ENABLE; DATA_RDY_INT (bit 0) likewise; INT_STATUS clears when read;
* self-test: the factory trim codes in SELF_TEST_X/Y/Z/A and a self-test response added to the
  outputs of the axes whose XG_ST.. / XA_ST.. bits are set;
* a motion trace (true angular rate in rad/s and specific force in m/s^2, body frame, as a
  function of time) plus optional bias and white noise;
* fault injection: NACK bursts (OSError with errno EREMOTEIO 121 or EIO), an absent device, stuck
  data registers, a brown-out (registers back to power-on values);
* a transaction counter, and optionally a simulated clock advanced by the time each transfer
  takes on the wire, so tests are deterministic.

Not modelled: the DLPF's effect on the signal unless ``model_dlpf=True`` (a one-pole
approximation of its bandwidth), the accelerometer's own
1 kHz rate when the gyro runs at 8 kHz, cycle mode and PWR_MGMT_2 standby bits, the auxiliary
I2C master and slave FIFO sources' data, the DMP, the INT pin, and register-read latency after
a DEVICE_RESET (the chip answers at once).

Time is in seconds on the clock passed in (``SimClock`` by default), rates in rad/s, specific
force in m/s^2.
"""

from __future__ import annotations

import ctypes
import errno as _errno
import math
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

# The host clock is the driver's (one definition); registers stay local on purpose.
from drivers.mpu6050 import SystemClock
from fusion.types.constants import STANDARD_GRAVITY

__all__ = [
    "ArrayTrace",
    "SimClock",
    "SimulatedMPU6050",
    "SystemClock",
    "static_trace",
]


# Register addresses (register map rev 4.2), kept local to the simulator on purpose.
_SELF_TEST_X, _SELF_TEST_Y, _SELF_TEST_Z, _SELF_TEST_A = 0x0D, 0x0E, 0x0F, 0x10
_SMPLRT_DIV, _CONFIG, _GYRO_CONFIG, _ACCEL_CONFIG = 0x19, 0x1A, 0x1B, 0x1C
_FIFO_EN = 0x23
_INT_ENABLE, _INT_STATUS = 0x38, 0x3A
_DATA_FIRST, _DATA_LAST = 0x3B, 0x48  # ACCEL_XOUT_H .. GYRO_ZOUT_L
_USER_CTRL, _PWR_MGMT_1, _PWR_MGMT_2 = 0x6A, 0x6B, 0x6C
_FIFO_COUNTH, _FIFO_COUNTL, _FIFO_R_W, _WHO_AM_I = 0x72, 0x73, 0x74, 0x75
_READ_ONLY = {*range(_DATA_FIRST, _DATA_LAST + 1), _INT_STATUS, _FIFO_COUNTH, _FIFO_COUNTL,
              _WHO_AM_I, *range(0x49, 0x61)}

_FIFO_SIZE = 1024
# DLPF_CFG 0..6 bandwidths (register map, CONFIG table), Hz; 7 is reserved (not filtered here).
_ACCEL_BW_HZ = (260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0, 0.0)
_GYRO_BW_HZ = (256.0, 188.0, 98.0, 42.0, 20.0, 10.0, 5.0, 0.0)
_GYRO_LSB_PER_DPS = (131.0, 65.5, 32.8, 16.4)
_ACCEL_LSB_PER_G = (16384.0, 8192.0, 4096.0, 2048.0)

# A motion trace maps sample times (N,) in s to (angular rate (N, 3) rad/s,
# specific force (N, 3) m/s^2), body frame.
MotionTrace = Callable[[NDArray[np.float64]], tuple[ArrayLike, ArrayLike]]


class SimClock:
    """A deterministic clock in seconds: ``monotonic()`` reads it, ``sleep()`` advances it."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = float(start)

    def monotonic(self) -> float:
        """Current simulated time, s."""
        return self.now

    def sleep(self, seconds: float) -> None:
        """Advance simulated time by ``seconds`` (negative values are ignored)."""
        if seconds > 0:
            self.now += float(seconds)

    advance = sleep


def static_trace(
    specific_force: Sequence[float] = (0.0, 0.0, STANDARD_GRAVITY),
    rate: Sequence[float] = (0.0, 0.0, 0.0),
) -> MotionTrace:
    """A motion trace that is constant: ``rate`` in rad/s, ``specific_force`` in m/s^2.

    The default is a sensor lying flat, z up, at rest (+1 g on z).
    """
    w = np.asarray(rate, dtype=float).reshape(3)
    f = np.asarray(specific_force, dtype=float).reshape(3)

    def trace(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n = len(t)
        return np.broadcast_to(w, (n, 3)), np.broadcast_to(f, (n, 3))

    return trace


@dataclass(frozen=True)
class ArrayTrace:
    """A motion trace from arrays, linearly interpolated (held constant outside the range).

    Attributes:
        t: sample times (N,), s, increasing.
        rate: true angular rate (N, 3), rad/s, body frame.
        specific_force: true specific force (N, 3), m/s^2, body frame.
    """

    t: NDArray[np.float64]
    rate: NDArray[np.float64]
    specific_force: NDArray[np.float64]

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        w = np.asarray(self.rate, dtype=float)
        f = np.asarray(self.specific_force, dtype=float)
        if t.ndim != 1 or len(t) < 1 or np.any(np.diff(t) <= 0):
            raise ValueError("ArrayTrace: t must be a 1-D strictly increasing array of times (s)")
        if w.shape != (len(t), 3) or f.shape != (len(t), 3):
            raise ValueError(
                f"ArrayTrace: rate and specific_force must be ({len(t)}, 3); "
                f"got {w.shape} and {f.shape}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "rate", w)
        object.__setattr__(self, "specific_force", f)

    def __call__(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        w = np.column_stack([np.interp(t, self.t, self.rate[:, i]) for i in range(3)])
        f = np.column_stack([np.interp(t, self.t, self.specific_force[:, i]) for i in range(3)])
        return w, f


def _gyro_factory_trim(code: int, axis: int) -> float:
    # Register map rev 4.2 section 4.1: FT = 25 * 131 * 1.046^(G_TEST - 1), negative for Y.
    if code == 0:
        return 0.0
    ft = 25.0 * 131.0 * 1.046 ** (code - 1)
    return -ft if axis == 1 else ft


def _accel_factory_trim(code: int) -> float:
    # FT = 4096 * 0.34 * (0.92 / 0.34)^((A_TEST - 1) / (2^5 - 2)).
    if code == 0:
        return 0.0
    return 4096.0 * 0.34 * (0.92 / 0.34) ** ((code - 1) / 30.0)


class SimulatedMPU6050:
    """A register-level MPU-6050 on a simulated I2C bus (smbus2.SMBus-compatible methods).

    Args:
        motion: true motion, a callable ``f(t (N,) s) -> (rate (N,3) rad/s, specific force
            (N,3) m/s^2)`` in the body frame (see ``static_trace`` and ``ArrayTrace``).
            Default: at rest, z up.
        address: 7-bit I2C address the chip answers (0x68 with AD0 low, 0x69 with AD0 high).
        bus_number: the number this bus pretends to be (for error messages only).
        clock: an object with ``monotonic()`` (and ``sleep()``); default a fresh ``SimClock``.
            If it has ``advance(seconds)``, each transaction advances it by its wire time.
        i2c_hz: bus clock used for the wire time of each transaction, Hz.
        gyro_bias_dps, accel_bias_g: constant sensor errors added to the truth (deg/s, g).
        gyro_noise_dps, accel_noise_g: white-noise standard deviation per sample (deg/s, g).
        temperature_c: die temperature, deg C.
        clock_error: relative error of the chip's sample clock (0.01 = runs 1 % fast).
        gyro_trim_codes, accel_trim_codes: factory self-test codes (XG_TEST.. 5 bits,
            XA_TEST.. 5 bits) stored in SELF_TEST_X/Y/Z/A.
        self_test_deviation: per-axis relative deviation of the self-test response from the
            factory trim, order (gx, gy, gz, ax, ay, az); the datasheet passes |dev| <= 14 %.
        seed: seed of the noise generator.
        model_dlpf: pass the truth through a one-pole low-pass of the DLPF_CFG bandwidth
            (accel 260/184/94/44/21/10/5 Hz, gyro 256/188/98/42/20/10/5 Hz), evaluated at
            the gyro output rate and read at each sample; noise is added after it. An
            approximation of the chip's filter (its delay is close, its shape is not
            documented). Off by default: the outputs then follow the trace exactly.

    Counters: ``transactions`` (one per method call; an ``i2c_rdwr`` of several messages is
    one combined transaction), ``calls`` (per method name), ``bytes_read``,
    ``bytes_written``, ``wire_time_s`` (the transfers' duration at ``i2c_hz``: 9 bits a byte
    including address and register bytes, plus start/stop), ``samples_produced`` (since
    power-on), ``fifo_frames_written`` and ``fifo_bytes_dropped`` (since the last FIFO reset).
    """

    def __init__(
        self,
        motion: MotionTrace | None = None,
        *,
        address: int = 0x68,
        bus_number: int = 1,
        clock: object | None = None,
        i2c_hz: float = 400_000.0,
        gyro_bias_dps: Sequence[float] = (0.0, 0.0, 0.0),
        accel_bias_g: Sequence[float] = (0.0, 0.0, 0.0),
        gyro_noise_dps: float = 0.0,
        accel_noise_g: float = 0.0,
        temperature_c: float = 25.0,
        clock_error: float = 0.0,
        gyro_trim_codes: Sequence[int] = (14, 15, 16),
        accel_trim_codes: Sequence[int] = (18, 17, 19),
        self_test_deviation: Sequence[float] = (0.02, -0.03, 0.01, 0.04, -0.02, 0.0),
        seed: int = 0,
        model_dlpf: bool = False,
    ) -> None:
        if not 0x08 <= address <= 0x77:
            raise ValueError(f"SimulatedMPU6050: address {address:#x} is not a 7-bit address")
        self.motion = motion if motion is not None else static_trace()
        self.address = address
        self.bus_number = bus_number
        self.clock = clock if clock is not None else SimClock()
        self.i2c_hz = float(i2c_hz)
        self.gyro_bias_dps = np.asarray(gyro_bias_dps, dtype=float).reshape(3)
        self.accel_bias_g = np.asarray(accel_bias_g, dtype=float).reshape(3)
        self.gyro_noise_dps = float(gyro_noise_dps)
        self.accel_noise_g = float(accel_noise_g)
        self.temperature_c = float(temperature_c)
        self.clock_error = float(clock_error)
        codes = [int(c) for c in (*gyro_trim_codes, *accel_trim_codes)]
        if len(codes) != 6 or any(not 0 <= c <= 31 for c in codes):
            raise ValueError("SimulatedMPU6050: trim codes must be three 5-bit values each")
        self._gyro_codes = codes[:3]
        self._accel_codes = codes[3:]
        self.self_test_deviation = np.asarray(self_test_deviation, dtype=float).reshape(6)
        self._rng = np.random.default_rng(seed)
        self.model_dlpf = bool(model_dlpf)
        self._lp_state: NDArray[np.float64] | None = None

        # fault injection state
        self._nack_remaining = 0
        self._nack_errno = _errno.EREMOTEIO
        self.absent = False
        self._stuck: bytes | None = None

        self.transactions = 0
        self.calls: Counter[str] = Counter()
        self.bytes_read = 0
        self.bytes_written = 0
        self.wire_time_s = 0.0
        self.samples_produced = 0
        self.closed = False
        self._power_on()

    # ------------------------------------------------------------------ chip state
    def _power_on(self) -> None:
        self.regs = bytearray(128)
        self.regs[_PWR_MGMT_1] = 0x40  # SLEEP
        self.regs[_WHO_AM_I] = 0x68  # bits 6:1 of the address, AD0 not reflected
        g, a = self._gyro_codes, self._accel_codes
        self.regs[_SELF_TEST_X] = ((a[0] >> 2) << 5) | g[0]
        self.regs[_SELF_TEST_Y] = ((a[1] >> 2) << 5) | g[1]
        self.regs[_SELF_TEST_Z] = ((a[2] >> 2) << 5) | g[2]
        self.regs[_SELF_TEST_A] = ((a[0] & 3) << 4) | ((a[1] & 3) << 2) | (a[2] & 3)
        self.fifo = bytearray()
        self._lp_state = None
        self.fifo_frames_written = 0
        self.fifo_bytes_dropped = 0
        self._last_fifo_byte = 0
        self._reanchor(self.clock.monotonic())

    def _reanchor(self, t: float) -> None:
        self._grid_t0 = t  # sample n happens at _grid_t0 + n / rate
        self._next_n = 1

    @property
    def grid_start(self) -> float:
        """Time of sample 0 of the current sampling grid, s (set at wake-up and by writes to
        SMPLRT_DIV or CONFIG): sample n is at ``grid_start + n / (sample_rate_hz * (1 +
        clock_error))``, n >= 1."""
        return self._grid_t0

    @property
    def asleep(self) -> bool:
        """True while PWR_MGMT_1.SLEEP is set (no sampling)."""
        return bool(self.regs[_PWR_MGMT_1] & 0x40)

    @property
    def gyro_output_rate_hz(self) -> float:
        """8 kHz when DLPF_CFG is 0 or 7, else 1 kHz."""
        return 8000.0 if (self.regs[_CONFIG] & 0x07) in (0, 7) else 1000.0

    @property
    def sample_rate_hz(self) -> float:
        """Nominal sample rate: gyro output rate / (1 + SMPLRT_DIV), Hz."""
        return self.gyro_output_rate_hz / (1 + self.regs[_SMPLRT_DIV])

    def _frame_bytes(self) -> int:
        en = self.regs[_FIFO_EN]
        n = 6 if en & 0x08 else 0
        n += 2 * sum(1 for bit in (0x80, 0x40, 0x20, 0x10) if en & bit)
        return n

    def _update(self) -> None:
        """Produce every sample whose instant has passed since the last update."""
        now = self.clock.monotonic()
        if self.asleep:
            self._reanchor(now)
            return
        period = 1.0 / (self.sample_rate_hz * (1.0 + self.clock_error))
        last_n = math.floor((now - self._grid_t0) / period + 1e-9)
        if last_n < self._next_n:
            return
        count = last_n - self._next_n + 1
        fifo_on = bool(self.regs[_USER_CTRL] & 0x40) and self._frame_bytes() > 0
        # Only the newest frames can matter: the registers hold the last one and the FIFO
        # keeps at most 1024 bytes. Older ones only count as produced (and dropped).
        keep = min(count, _FIFO_SIZE // 2 + 1 if fifo_on else 1)
        compute = keep
        if self.model_dlpf:
            # the filter needs its history: the skipped samples of the last 10 time
            # constants of the slowest pole (older ones no longer matter; restart there)
            settle = math.ceil(10.0 / (2.0 * math.pi * 5.0) / period)
            compute = min(count, max(keep, settle))
            if compute < count:
                self._lp_state = None
        first = last_n - compute + 1
        times = self._grid_t0 + np.arange(first, last_n + 1) * period
        frames = self._sample(times, period)[compute - keep :]
        if fifo_on:
            skipped = count - keep
            if skipped:  # their bytes are certain to be pushed out: account, don't store
                nbytes = skipped * self._frame_bytes()
                stored = min(nbytes, _FIFO_SIZE)
                self.fifo_frames_written += skipped
                self.fifo_bytes_dropped += nbytes - stored
                self._push_fifo(bytes(stored), count_frames=0)
            for raw in frames:
                self._push_fifo(self._fifo_frame(raw), count_frames=1)
        if self._stuck is None:
            self.regs[_DATA_FIRST : _DATA_LAST + 1] = frames[-1]
        else:
            self.regs[_DATA_FIRST : _DATA_LAST + 1] = self._stuck
        if self.regs[_INT_ENABLE] & 0x01:
            self.regs[_INT_STATUS] |= 0x01
        self.samples_produced += count
        self._next_n = last_n + 1

    def _truth(self, times: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        w, f = self.motion(times)
        w = np.asarray(w, dtype=float).reshape(len(times), 3)
        f = np.asarray(f, dtype=float).reshape(len(times), 3)
        return np.degrees(w) + self.gyro_bias_dps, f / STANDARD_GRAVITY + self.accel_bias_g

    def _filtered_truth(
        self, times: NDArray[np.float64], period: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The truth through a one-pole low-pass of the DLPF bandwidth, run at the gyro
        output rate (1 + SMPLRT_DIV ticks per sample) and read at the sample instants."""
        cfg = self.regs[_CONFIG] & 0x07
        ticks = 1 + self.regs[_SMPLRT_DIV]
        tick = period / ticks
        t_all = (times[:, None] - tick * np.arange(ticks - 1, -1, -1)[None, :]).ravel()
        gyro, accel = self._truth(t_all)
        x = np.hstack([accel, gyro])
        bw = np.array([_ACCEL_BW_HZ[cfg]] * 3 + [_GYRO_BW_HZ[cfg]] * 3)
        from scipy.signal import lfilter

        y = np.empty_like(x)
        prev = x[0].copy() if self._lp_state is None else self._lp_state
        for cols in (slice(0, 3), slice(3, 6)):  # y[k] = p y[k-1] + (1 - p) x[k]
            p = math.exp(-2.0 * math.pi * bw[cols][0] * tick)
            y[:, cols], _ = lfilter([1.0 - p], [1.0, -p], x[:, cols], axis=0,
                                    zi=(p * prev[cols])[None, :])
        self._lp_state = y[-1].copy()
        out = y[ticks - 1 :: ticks]
        return out[:, 3:], out[:, :3]

    def _sample(self, times: NDArray[np.float64], period: float) -> list[bytes]:
        if self.model_dlpf and (self.regs[_CONFIG] & 0x07) != 7:
            gyro_dps, accel_g = self._filtered_truth(times, period)
        else:
            gyro_dps, accel_g = self._truth(times)
        if self.gyro_noise_dps:
            gyro_dps = gyro_dps + self._rng.normal(0.0, self.gyro_noise_dps, gyro_dps.shape)
        if self.accel_noise_g:
            accel_g = accel_g + self._rng.normal(0.0, self.accel_noise_g, accel_g.shape)
        fs_sel = (self.regs[_GYRO_CONFIG] >> 3) & 3
        afs_sel = (self.regs[_ACCEL_CONFIG] >> 3) & 3
        graw = gyro_dps * _GYRO_LSB_PER_DPS[fs_sel]
        araw = accel_g * _ACCEL_LSB_PER_G[afs_sel]
        # self-test responses, defined at +-250 deg/s and +-8 g, scaled to the current range
        gst, ast = self.regs[_GYRO_CONFIG] >> 5, self.regs[_ACCEL_CONFIG] >> 5
        for axis in range(3):
            bit = 0x04 >> axis  # XG_ST is bit 7 -> bit 2 of the shifted value
            if gst & bit:
                resp = _gyro_factory_trim(self._gyro_codes[axis], axis)
                resp *= 1.0 + self.self_test_deviation[axis]
                graw[:, axis] += resp * _GYRO_LSB_PER_DPS[fs_sel] / 131.0
            if ast & bit:
                resp = _accel_factory_trim(self._accel_codes[axis])
                resp *= 1.0 + self.self_test_deviation[3 + axis]
                araw[:, axis] += resp * _ACCEL_LSB_PER_G[afs_sel] / 4096.0
        temp_raw = np.full((len(times), 1), (self.temperature_c - 36.53) * 340.0)
        allraw = np.hstack([araw, temp_raw, graw])
        ints = np.clip(np.rint(allraw), -32768, 32767).astype(">i2")
        return [row.tobytes() for row in ints]

    def _fifo_frame(self, raw14: bytes) -> bytes:
        en = self.regs[_FIFO_EN]
        out = b""
        if en & 0x08:
            out += raw14[0:6]
        if en & 0x80:
            out += raw14[6:8]
        for i, bit in enumerate((0x40, 0x20, 0x10)):
            if en & bit:
                out += raw14[8 + 2 * i : 10 + 2 * i]
        return out

    def _push_fifo(self, data: bytes, count_frames: int) -> None:
        self.fifo += data
        self.fifo_frames_written += count_frames
        excess = len(self.fifo) - _FIFO_SIZE
        if excess > 0:
            del self.fifo[:excess]  # the oldest bytes are lost; alignment goes with them
            self.fifo_bytes_dropped += excess
            if self.regs[_INT_ENABLE] & 0x10:
                self.regs[_INT_STATUS] |= 0x10

    def _read_reg(self, reg: int) -> int:
        if reg == _FIFO_R_W:
            if self.fifo:
                self._last_fifo_byte = self.fifo.pop(0)
            return self._last_fifo_byte  # empty FIFO: the last byte again (simulator's choice)
        if reg == _FIFO_COUNTH:
            return (len(self.fifo) >> 8) & 0xFF
        if reg == _FIFO_COUNTL:
            return len(self.fifo) & 0xFF
        value = self.regs[reg & 0x7F]
        if reg == _INT_STATUS:
            self.regs[_INT_STATUS] = 0  # cleared on read
        return value

    def _read_block(self, reg: int, n: int) -> bytes:
        if reg == _FIFO_R_W:  # no auto-increment on the FIFO port
            return bytes(self._read_reg(_FIFO_R_W) for _ in range(n))
        if reg == _FIFO_COUNTH and n >= 2:  # the count is latched for the burst
            count = len(self.fifo)
            head = bytes([(count >> 8) & 0xFF, count & 0xFF])
            return head + bytes(self._read_reg((reg + 2 + i) & 0x7F) for i in range(n - 2))
        return bytes(self._read_reg((reg + i) & 0x7F) for i in range(n))

    def _write_reg(self, reg: int, value: int) -> None:
        value &= 0xFF
        reg &= 0x7F
        if reg == _FIFO_R_W:
            self._push_fifo(bytes([value]), 0)
            return
        if reg in _READ_ONLY:
            return
        if reg == _PWR_MGMT_1 and value & 0x80:
            self._power_on()  # DEVICE_RESET: every register back to its reset value
            return
        if reg == _USER_CTRL:
            if value & 0x04:  # FIFO_RESET, self-clearing
                self.fifo.clear()
                self.fifo_frames_written = 0
                self.fifo_bytes_dropped = 0
                self.regs[_INT_STATUS] &= ~0x10 & 0xFF
            if value & 0x01:  # SIG_COND_RESET clears the sensor registers
                self.regs[_DATA_FIRST : _DATA_LAST + 1] = bytes(14)
            value &= ~0x07 & 0xFF
        was_asleep = self.asleep
        self.regs[reg] = value
        if reg in (_SMPLRT_DIV, _CONFIG) or (was_asleep and not self.asleep):
            self._reanchor(self.clock.monotonic())

    # ------------------------------------------------------------------ bus plumbing
    def _begin(self, method: str, addr: int, wire_bytes: int) -> None:
        if self.closed:
            raise ValueError("I/O operation on a closed simulated bus")
        self.transactions += 1
        self.calls[method] += 1
        # wire time: 9 bits per byte (8 + ACK) plus start/stop, at i2c_hz
        advance = getattr(self.clock, "advance", None)
        # sample state first (what the chip latches when the transfer starts)
        if addr == self.address and not self.absent:
            self._update()
        duration = (9 * wire_bytes + 2) / self.i2c_hz if self.i2c_hz > 0 else 0.0
        self.wire_time_s += duration
        if advance is not None:
            advance(duration)
        if addr != self.address or self.absent:
            raise OSError(_errno.EREMOTEIO, f"{os.strerror(_errno.EREMOTEIO)} (no ACK from "
                          f"address {addr:#04x})")
        if self._nack_remaining > 0:
            self._nack_remaining -= 1
            raise OSError(self._nack_errno, os.strerror(self._nack_errno))

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        self._begin("read_byte_data", i2c_addr, 4)
        self.bytes_read += 1
        return self._read_reg(register & 0x7F)

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        self._begin("write_byte_data", i2c_addr, 3)
        self.bytes_written += 1
        self._write_reg(register, value)

    def read_word_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """SMBus word read: low byte first on the wire, as smbus2 returns it."""
        self._begin("read_word_data", i2c_addr, 5)
        self.bytes_read += 2
        data = self._read_block(register & 0x7F, 2)
        return data[0] | (data[1] << 8)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if length > 32:  # smbus2's I2C_SMBUS_BLOCK_MAX
            raise ValueError("Desired block length over 32 bytes")
        self._begin("read_i2c_block_data", i2c_addr, 3 + length)
        self.bytes_read += length
        return list(self._read_block(register & 0x7F, length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: Sequence[int], force: bool | None = None
    ) -> None:
        if len(data) > 32:
            raise ValueError("Data length cannot exceed 32 bytes")
        self._begin("write_i2c_block_data", i2c_addr, 2 + len(data))
        self.bytes_written += len(data)
        for i, value in enumerate(data):
            self._write_reg((register + i) & 0x7F, value)

    def i2c_rdwr(self, *msgs: object) -> None:
        """Combined transfer of smbus2 ``i2c_msg`` objects (repeated start between them).

        A write message's first byte sets the register pointer and the rest are written;
        a read message fills its buffer from the pointer (auto-incrementing, except at
        FIFO_R_W). Any length is accepted, as on an I2C adapter (Linux caps one message
        at 8192 bytes).
        """
        total = sum(int(m.len) + 1 for m in msgs)  # type: ignore[attr-defined]
        addr = int(msgs[0].addr) if msgs else self.address  # type: ignore[attr-defined]
        self._begin("i2c_rdwr", addr, total)
        pointer = 0
        for m in msgs:
            if int(m.addr) != self.address:  # type: ignore[attr-defined]
                raise OSError(_errno.EREMOTEIO, os.strerror(_errno.EREMOTEIO))
            n = int(m.len)  # type: ignore[attr-defined]
            if int(m.flags) & 0x0001:  # I2C_M_RD  # type: ignore[attr-defined]
                data = self._read_block(pointer, n)
                self.bytes_read += n
                ctypes.memmove(m.buf, data, n)  # type: ignore[attr-defined]
                if pointer != _FIFO_R_W:
                    pointer = (pointer + n) & 0x7F
            else:
                payload = bytes(m)  # type: ignore[call-overload]
                if not payload:
                    continue
                pointer = payload[0] & 0x7F
                for value in payload[1:]:
                    self._write_reg(pointer, value)
                    self.bytes_written += 1
                    if pointer != _FIFO_R_W:
                        pointer = (pointer + 1) & 0x7F

    def close(self) -> None:
        self.closed = True

    def __enter__(self) -> SimulatedMPU6050:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ fault injection
    def inject_nack(self, count: int, errno: int = _errno.EREMOTEIO) -> None:
        """Make the next ``count`` transactions fail with ``OSError(errno)`` (EREMOTEIO 121,
        EIO 5, ...), as when motor noise corrupts the bus."""
        if count < 0:
            raise ValueError("inject_nack: count must be >= 0")
        self._nack_remaining = int(count)
        self._nack_errno = int(errno)

    def stick(self, raw14: bytes | None = None) -> None:
        """Freeze the data registers 0x3B..0x48 at ``raw14`` (default: their current bytes),
        from now until ``unstick()``. The FIFO keeps receiving real samples."""
        self._update()
        data = bytes(self.regs[_DATA_FIRST : _DATA_LAST + 1]) if raw14 is None else bytes(raw14)
        if len(data) != 14:
            raise ValueError("stick: need the 14 bytes of registers 0x3B..0x48")
        self._stuck = data
        self.regs[_DATA_FIRST : _DATA_LAST + 1] = data

    def unstick(self) -> None:
        """Let the data registers follow the samples again."""
        self._stuck = None

    def brown_out(self) -> None:
        """A supply dip: every register returns to its power-on value (asleep, ranges
        +-250 deg/s and +-2 g, FIFO off and empty)."""
        self._update()
        self._power_on()
