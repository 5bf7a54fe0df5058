"""The MPU-6050 driver against the simulated chip.

Sensitivities, register addresses and the self-test formulas are written here from the
MPU-6000/MPU-6050 Register Map (rev 4.2), never read from the driver's tables.
"""

import errno
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mpu6050 import MPU6050, MPU6050Error, SensorStuckError
from drivers.sim.mpu6050 import ArrayTrace, SimulatedMPU6050, static_trace
from fusion.calibration.imu import ImuCalibration

G = 9.80665
GYRO_LSB = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}  # LSB/(deg/s), register map 4.19
ACCEL_LSB = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}  # LSB/g, register map 4.17


def make(sim=None, **kw):
    sim = sim if sim is not None else SimulatedMPU6050()
    return MPU6050(sim, clock=sim.clock, **kw), sim


def test_init_writes_the_documented_configuration():
    imu, sim = make(gyro_range_dps=1000, accel_range_g=8, dlpf=3, sample_rate_hz=200)
    r = sim.regs
    assert r[0x6B] == 0x01  # PWR_MGMT_1: awake, CLKSEL = 1 (PLL, X gyro)
    assert r[0x19] == 4  # SMPLRT_DIV: 1 kHz / (1 + 4) = 200 Hz
    assert r[0x1A] & 0x07 == 3  # DLPF_CFG
    assert r[0x1B] == 2 << 3  # FS_SEL = 2: +-1000 deg/s
    assert r[0x1C] == 2 << 3  # AFS_SEL = 2: +-8 g
    assert r[0x38] == 0x11  # FIFO_OFLOW_EN | DATA_RDY_EN
    assert imu.sample_rate_hz == 200.0


def test_set_dlpf_keeps_ext_sync_bits():
    imu, sim = make(dlpf=3)
    sim.regs[0x1A] = (5 << 3) | 3  # EXT_SYNC_SET = 5 (bits 5:3), as another user left it
    imu.set_dlpf(6)
    assert sim.regs[0x1A] == (5 << 3) | 6
    assert imu.sample_rate_hz == 1000 / (1 + 9)


def test_wrong_who_am_i_names_the_value():
    sim = SimulatedMPU6050()
    sim.regs[0x75] = 0x70
    with pytest.raises(MPU6050Error, match=r"WHO_AM_I is 0x70 \(an MPU-6500\?\).*0x68"):
        MPU6050(sim, clock=sim.clock)


def test_absent_device_error_names_bus_address_register():
    sim = SimulatedMPU6050(address=0x69, bus_number=3)
    with pytest.raises(MPU6050Error) as exc:
        MPU6050(sim, 0x68, clock=sim.clock, retries=2)
    msg = str(exc.value)
    assert "/dev/i2c-3" in msg and "0x68" in msg and "0x75 (WHO_AM_I)" in msg
    assert "after 3 attempts" in msg and "AD0" in msg and "wiring" in msg and "power" in msg
    assert exc.value.errno == errno.EREMOTEIO


@pytest.mark.parametrize("gyro_range", [250, 500, 1000, 2000])
@pytest.mark.parametrize("accel_range", [2, 4, 8, 16])
def test_read_scales_every_range_combination(gyro_range, accel_range):
    true_dps = np.array([0.6, -0.3, 0.9]) * gyro_range  # within range
    true_g = np.array([-0.4, 0.7, 0.5]) * accel_range
    sim = SimulatedMPU6050(static_trace(true_g * G, np.radians(true_dps)), temperature_c=41.0)
    imu, _ = make(sim, gyro_range_dps=gyro_range, accel_range_g=accel_range)
    sim.clock.sleep(0.05)
    before = sim.transactions
    s = imu.read()
    assert sim.transactions - before == 1  # one 14-byte burst
    # expected from the register map sensitivities; tolerance half an LSB (rounding)
    lsb_g, lsb_dps = ACCEL_LSB[accel_range], GYRO_LSB[gyro_range]
    assert np.allclose(s.accel, true_g * G, atol=0.5 / lsb_g * G + 1e-12)
    assert np.allclose(np.degrees(s.gyro), true_dps, atol=0.5 / lsb_dps + 1e-12)
    raw = imu.read_raw()
    assert raw.gyro == tuple(int(v) for v in np.rint(true_dps * lsb_dps))
    assert abs(s.temperature - 41.0) <= 0.5 / 340


def test_seed_accessors_raw_scaled_calibrated():
    sim = SimulatedMPU6050(static_trace((0, 0, G), np.radians([2.0, 0, 0])))
    imu, _ = make(sim)
    sim.clock.sleep(0.05)
    assert imu.accel_raw() == (0, 0, 16384)
    assert imu.gyro_raw() == (262, 0, 0)
    assert np.allclose(imu.accel_scaled(), [0, 0, 1.0])
    assert np.allclose(imu.gyro_scaled(), [2.0, 0, 0])
    imu.calibration = ImuCalibration(gyro_bias=np.radians([2.0, 0, 0]),
                                     accel_offset=[0, 0, 0.5 * G], accel_scale=[1, 1, 2.0])
    assert np.allclose(imu.gyro_calibrated(), [0, 0, 0], atol=1e-12)
    assert np.allclose(imu.accel_calibrated(), [0, 0, 1.0])  # (1 g - 0.5 g) * 2
    assert np.allclose(imu.read(calibrated=False).accel, [0, 0, G])


def test_burst_read_is_one_sample_not_torn():
    # a ramp on every axis: all six values must come from the same sample instant
    # 0 -> 200 deg/s and 0 -> 1 g over 1 s: each value encodes its sample time to < 0.1 ms
    t = np.array([0.0, 1.0])
    rate = np.radians(np.array([[0.0, 0, 0], [200.0, 200, 200]]))
    force = np.array([[0.0, 0, 0], [1.0, 1, 1]]) * G
    sim = SimulatedMPU6050(ArrayTrace(t, rate, force))
    imu, _ = make(sim, sample_rate_hz=1000, dlpf=1)
    for _ in range(20):
        sim.clock.sleep(0.0137)
        raw = imu.read_raw()
        ts = [v / 131.0 / 200.0 for v in raw.gyro] + [v / 16384.0 for v in raw.accel]
        # one sample instant (1 ms apart from the next) within the rounding of the values
        assert max(ts) - min(ts) < 0.0002


def test_sample_rate_choices_and_refusals():
    imu, _ = make(dlpf=0, sample_rate_hz=8000)
    assert imu.smplrt_div == 0 and imu.sample_rate_hz == 8000.0
    imu, _ = make(dlpf=0, sample_rate_hz=1000)
    assert imu.smplrt_div == 7
    with pytest.raises(ValueError, match="outside"):
        make(dlpf=3, sample_rate_hz=2000)
    with pytest.raises(ValueError, match="nearest"):
        make(dlpf=3, sample_rate_hz=450)  # 1000/2 = 500 or 1000/3 = 333
    with pytest.raises(ValueError, match="gyro_range_dps"):
        make(gyro_range_dps=300)


# --------------------------------------------------------------------------- FIFO
def ramp_sim(**kw):
    """Gyro x encodes the sample time: 1 deg/s per second... at +-2000 deg/s, 16.4 LSB per
    deg/s; the slope 100 deg/s per s gives 1640 LSB/s, so t = raw / 1640 to 0.6 ms."""
    t = np.array([0.0, 19.0])
    rate = np.radians(np.array([[0.0, 0, 0], [1900.0, 0, 0]]))
    force = np.array([[0, 0, G], [0, 0, G]])
    return SimulatedMPU6050(ArrayTrace(t, rate, force), **kw)


@pytest.mark.parametrize("n_frames", [1, 10, 80])
def test_fifo_read_costs_three_transactions_whatever_n(n_frames):
    sim = ramp_sim()
    imu, _ = make(sim, gyro_range_dps=2000, dlpf=1, sample_rate_hz=1000)
    imu.enable_fifo()
    sim.clock.sleep(n_frames / 1000 + 0.0002)
    before = sim.transactions
    r = imu.read_fifo()
    assert len(r.samples) == n_frames
    assert sim.transactions - before == 3 == r.transactions  # INT_STATUS, COUNT, data


def test_fifo_without_i2c_rdwr_falls_back_to_32_byte_blocks():
    sim = ramp_sim()
    imu, _ = make(sim, gyro_range_dps=2000, dlpf=1, sample_rate_hz=1000, use_i2c_rdwr=False)
    imu.enable_fifo()
    sim.clock.sleep(0.0802)  # 80 frames = 960 bytes
    before = sim.transactions
    r = imu.read_fifo()
    assert len(r.samples) == 80
    assert sim.transactions - before == 2 + math.ceil(960 / 32)


@pytest.mark.parametrize("clock_error", [0.0, 0.01, -0.01])
def test_fifo_timestamps_within_one_period_of_truth(clock_error):
    sim = ramp_sim(clock_error=clock_error)
    imu, _ = make(sim, gyro_range_dps=2000, dlpf=1, sample_rate_hz=1000)
    imu.enable_fifo()
    samples = []
    for _ in range(200):  # 10 s, read every 50 ms
        sim.clock.sleep(0.05)
        samples += imu.read_fifo().samples
    t_true = np.array([np.degrees(s.gyro[0]) / 100.0 for s in samples])  # 100 deg/s per s
    t_est = np.array([s.t for s in samples])
    assert len(samples) > 9800
    err = t_est - t_true
    # the value encodes time to 1/1640 s; timestamps must be within one 1 ms period
    assert np.max(np.abs(err)) < 0.001 + 1 / 1640
    # once the chip's period is learnt (after 2 s): within half a period (+ encoding rounding)
    assert np.max(np.abs(err[2000:])) < 0.0005 + 0.5 / 1640
    assert np.all(np.diff(t_est) > 0)


def test_fifo_overflow_is_detected_reset_and_losses_counted():
    sim = ramp_sim()
    imu, _ = make(sim, gyro_range_dps=2000, dlpf=1, sample_rate_hz=1000)
    imu.enable_fifo()
    produced0 = sim.samples_produced
    got = []
    sim.clock.sleep(0.05)
    got += imu.read_fifo().samples
    sim.clock.sleep(0.3)  # 300 frames: far beyond 85
    r = imu.read_fifo()
    assert r.overflow and r.samples == []
    sim.clock.sleep(0.05)
    r2 = imu.read_fifo()
    assert not r2.overflow and len(r2.samples) >= 45
    got += r2.samples
    # after the reset, the ramp continues from the right time
    assert abs(np.degrees(r2.samples[0].gyro[0]) / 100 - r2.samples[0].t) < 0.002
    # every frame produced is either delivered or reported lost (+-1 at the reset edge);
    # the frames still in the FIFO after the last read are neither
    sim.read_byte_data(0x68, 0x3A)
    in_fifo = len(sim.fifo) // 12
    produced = sim.samples_produced - produced0
    assert abs(len(got) + r.lost + in_fifo - produced) <= 1


def test_fifo_failed_data_read_resyncs_and_reports_loss():
    sim = ramp_sim()
    imu, _ = make(sim, gyro_range_dps=2000, dlpf=1, sample_rate_hz=1000, retries=1)
    imu.enable_fifo()
    produced0 = sim.samples_produced  # as of the FIFO reset, the last transaction
    sim.clock.sleep(0.02)
    delivered = len(imu.read_fifo().samples)
    assert delivered >= 19
    discarded = []

    class FailingData:  # INT_STATUS and FIFO_COUNT go through; the long data read fails
        def __getattr__(self, name):
            return getattr(sim, name)

        def i2c_rdwr(self, *msgs):
            discarded.append(len(sim.fifo) // 12)
            raise OSError(errno.EREMOTEIO, "Remote I/O error")

    imu.bus = FailingData()
    sim.clock.sleep(0.04)
    r = imu.read_fifo()
    assert r.samples == [] and not r.overflow
    assert len(discarded) == 2 and discarded[-1] >= 40  # one attempt + one retry, then reset
    # every frame produced until the reset (the last transaction) was delivered or lost
    assert abs(delivered + r.lost - (sim.samples_produced - produced0)) <= 1
    imu.bus = sim
    sim.clock.sleep(0.02)
    r = imu.read_fifo()
    assert 19 <= len(r.samples) <= 21
    assert abs(np.degrees(r.samples[0].gyro[0]) / 100 - r.samples[0].t) < 0.002


# --------------------------------------------------------------------------- errors
def test_nack_burst_is_retried_with_backoff():
    imu, sim = make(retries=3, backoff_s=0.002)
    sim.clock.sleep(0.05)
    sim.inject_nack(3, errno.EREMOTEIO)
    t0 = sim.clock.now
    s = imu.read()
    assert np.isfinite(s.accel).all()
    assert imu.stats.retries == 3
    # waited 2 + 4 + 8 ms (plus four transfers on the wire)
    assert sim.clock.now - t0 >= 0.014


@pytest.mark.parametrize("code", [errno.EIO, errno.EREMOTEIO, errno.ENXIO])
def test_retry_exhaustion_raises_driver_error(code):
    imu, sim = make(retries=2)
    sim.inject_nack(3, code)
    with pytest.raises(MPU6050Error) as exc:
        imu.read()
    assert exc.value.errno == code
    # the sample burst starts at INT_STATUS (data-ready flag + the 14 data bytes)
    assert "0x3a (INT_STATUS)" in str(exc.value) and "after 3 attempts" in str(exc.value)
    assert isinstance(exc.value, OSError)


def test_other_errno_is_not_retried():
    imu, sim = make(retries=5)
    sim.inject_nack(1, errno.EINVAL)
    with pytest.raises(MPU6050Error) as exc:
        imu.read()
    assert exc.value.errno == errno.EINVAL and imu.stats.retries == 0


def test_stuck_sensor_raises():
    sim = SimulatedMPU6050(gyro_noise_dps=0.05, accel_noise_g=0.002, seed=3)
    imu, _ = make(sim, stuck_samples=50)
    for _ in range(200):  # a noisy working sensor is never "stuck"
        sim.clock.sleep(0.01)
        imu.read()
    sim.stick()
    with pytest.raises(SensorStuckError, match="identical for 50 reads"):
        for _ in range(60):
            sim.clock.sleep(0.01)
            imu.read()


def test_reading_faster_than_the_sample_rate_is_not_stuck():
    imu, sim = make(sim=SimulatedMPU6050(seed=1), stuck_samples=20)  # noiseless sim
    for _ in range(100):  # identical data, but 100 reads within 10 sample periods
        sim.clock.sleep(0.001)
        imu.read()
    assert not imu.stuck


def test_brown_out_detected_as_stuck_with_sleep_hint_and_recovered():
    sim = SimulatedMPU6050(gyro_noise_dps=0.05, accel_noise_g=0.002)
    imu, _ = make(sim, stuck_samples=10)
    sim.clock.sleep(0.05)
    imu.read()
    sim.brown_out()
    with pytest.raises(SensorStuckError, match=r"asleep.*brown-out.*configure\(\)"):
        for _ in range(20):
            sim.clock.sleep(0.01)
            imu.read()
    imu.configure()
    sim.clock.sleep(0.05)
    assert abs(imu.read().accel[2] - G) < 0.05


def test_stuck_flag_mode():
    imu, sim = make(sim=SimulatedMPU6050(), stuck_samples=5, on_stuck="flag")
    for _ in range(10):
        sim.clock.sleep(0.01)
        imu.read()
    assert imu.stuck  # noiseless sim: identical data over 10 periods


# --------------------------------------------------------------------------- self-test
def expected_trim(gcodes, acodes):
    ft = [25 * 131 * 1.046 ** (c - 1) if c else 0.0 for c in gcodes]
    ft[1] = -ft[1]  # FT[Yg] is negative
    ft += [4096 * 0.34 * (0.92 / 0.34) ** ((c - 1) / (2**5 - 2)) if c else 0.0 for c in acodes]
    return np.array(ft)


def test_self_test_passes_with_factory_trim_from_register_map():
    gc, ac = (14, 15, 16), (18, 17, 19)
    dev = (0.02, -0.03, 0.01, 0.04, -0.02, 0.0)
    sim = SimulatedMPU6050(static_trace((0, 0, G)), gyro_trim_codes=gc, accel_trim_codes=ac,
                           self_test_deviation=dev)
    imu, _ = make(sim, gyro_range_dps=2000, accel_range_g=16)
    res = imu.self_test()
    assert np.allclose(res.factory_trim, expected_trim(gc, ac))
    assert np.allclose(res.change, dev, atol=0.002)  # rounding of the averaged LSB
    assert res.passed
    assert sim.regs[0x1B] == 3 << 3 and sim.regs[0x1C] == 3 << 3  # ranges restored


def test_self_test_fails_outside_14_percent():
    sim = SimulatedMPU6050(self_test_deviation=(0, 0, 0.20, 0, 0, 0))
    imu, _ = make(sim)
    res = imu.self_test()
    assert not res.passed and abs(res.change[2] - 0.20) < 0.002


# --------------------------------------------------------------------------- data ready, bus
def test_data_ready_polling():
    imu, sim = make(sample_rate_hz=100)
    imu.read(wait=True)
    t0 = sim.clock.now
    imu.read(wait=True)
    assert 0.0 < sim.clock.now - t0 <= 0.0115  # the next sample came within one period
    sim.brown_out()  # asleep: no more samples
    with pytest.raises(MPU6050Error, match="no DATA_RDY"):
        imu.wait_data_ready(timeout_s=0.05)


def test_bus_number_that_does_not_exist():
    with pytest.raises(MPU6050Error, match=r"cannot open I2C bus 250 \(/dev/i2c-250\)"):
        MPU6050(250)


# --------------------------------------------------------------------------- decoding
@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-32768, 32767), min_size=7, max_size=7))
def test_decoding_of_any_register_contents(values):
    # registers 0x3B..0x48 hold accel x, y, z, temp, gyro x, y, z as big-endian int16
    raw14 = b"".join(v.to_bytes(2, "big", signed=True) for v in values)
    sim = SimulatedMPU6050()
    imu, _ = make(sim, gyro_range_dps=500, accel_range_g=4, stuck_samples=0)
    sim.stick(raw14)
    raw = imu.read_raw()
    assert raw.accel == tuple(values[0:3]) and raw.temperature == values[3]
    assert raw.gyro == tuple(values[4:7])
    s = imu.read()
    assert np.allclose(s.accel, np.array(values[0:3]) / 8192.0 * G)
    assert np.allclose(s.gyro, np.radians(np.array(values[4:7]) / 65.5))
    assert s.temperature == pytest.approx(values[3] / 340.0 + 36.53)


# --------------------------------------------------------------------------- fresh samples
@pytest.mark.parametrize("accel_range", [4, 8, 16])
def test_first_read_after_configuration_is_at_the_configured_range(accel_range):
    # at rest, z up: +1 g. The chip's reset range is +-2 g (16384 LSB/g); a sample taken
    # before ACCEL_CONFIG was written, read with the new sensitivity, would show
    # 16384 / ACCEL_LSB[range] g (2, 4 or 8 g)
    sim = SimulatedMPU6050(static_trace())
    imu = MPU6050(sim, 0x68, accel_range_g=accel_range, clock=sim.clock)
    s = imu.read()
    assert s.accel[2] == pytest.approx(G, abs=0.5 / ACCEL_LSB[accel_range] * G)
    assert imu.fresh is True  # the sample configure() waited for, not read yet
    # a reconfiguration at another range: the same holds
    imu.accel_range_g = 2
    imu.configure()
    assert imu.read().accel[2] == pytest.approx(G, abs=0.5 / ACCEL_LSB[2] * G)


def test_set_dlpf_returns_with_a_sample_taken_at_the_new_rate():
    sim = SimulatedMPU6050(static_trace())
    imu, _ = make(sim, dlpf=3, sample_rate_hz=100)
    produced = sim.samples_produced
    imu.set_dlpf(0)  # 8 kHz gyro rate with the same divider: 800 Hz
    assert sim.samples_produced > produced
    assert imu.read().accel[2] == pytest.approx(G, abs=1e-3)


def test_reads_faster_than_the_sample_rate_say_they_repeat_a_sample():
    # a ramp of 100 deg/s per s on x: consecutive 100 Hz samples differ by 1 deg/s
    t = np.array([0.0, 10.0])
    rate = np.radians(np.array([[0.0, 0, 0], [1000.0, 0, 0]]))
    sim = SimulatedMPU6050(ArrayTrace(t, rate, np.array([[0, 0, G], [0, 0, G]])))
    imu, _ = make(sim, gyro_range_dps=2000, sample_rate_hz=100)
    first = imu.read()
    assert imu.fresh is True
    again = imu.read()  # within the same 10 ms sample period
    assert imu.fresh is False and imu.stats.repeated_reads == 1
    np.testing.assert_array_equal(again.gyro, first.gyro)  # the very same sample
    sim.clock.sleep(0.0101)  # one sample period later: a new sample
    raw = imu.read_raw()
    assert raw.fresh is True and imu.stats.repeated_reads == 1
    assert np.degrees(imu.read(wait=True).gyro[0]) > np.degrees(first.gyro[0]) + 1.5
    assert imu.fresh is True  # wait=True always returns a new one
    # data_ready() reads (and so clears) DATA_RDY_INT: the next read still counts as new
    sim.clock.sleep(0.0101)
    assert imu.data_ready() and imu.data_ready()
    assert imu.read_raw().fresh is True and not imu.data_ready()


def test_freshness_is_unknown_on_a_chip_left_without_the_data_ready_interrupt():
    sim = SimulatedMPU6050(static_trace())
    make(sim)  # configured: awake, sampling
    sim.regs[0x38] = 0x00  # INT_ENABLE: DATA_RDY_EN off, as another program may leave it
    imu = MPU6050(sim, clock=sim.clock, reset=False)
    assert imu.read_raw().fresh is None and imu.fresh is None
