"""The simulated MPU-6050 against the register map (rev 4.2), through its SMBus-like methods.

Every address, bit and constant below is written from the register map, not taken from the
simulator or the driver.
"""

import errno
import math

import numpy as np
import pytest
from smbus2 import i2c_msg

from drivers.sim.mpu6050 import ArrayTrace, SimClock, SimulatedMPU6050, static_trace

ADDR = 0x68
G = 9.80665


def s16(hi, lo):
    v = (hi << 8) | lo
    return v - 65536 if v >= 32768 else v


def wake(sim, div=9, dlpf=3):
    sim.write_byte_data(ADDR, 0x6B, 0x01)  # PWR_MGMT_1: SLEEP=0, CLKSEL=1
    sim.write_byte_data(ADDR, 0x19, div)  # SMPLRT_DIV
    sim.write_byte_data(ADDR, 0x1A, dlpf)  # CONFIG.DLPF_CFG


def test_power_on_values():
    sim = SimulatedMPU6050()
    assert sim.read_byte_data(ADDR, 0x6B) == 0x40  # PWR_MGMT_1 reset value: SLEEP
    assert sim.read_byte_data(ADDR, 0x75) == 0x68  # WHO_AM_I
    for reg in (0x19, 0x1A, 0x1B, 0x1C, 0x23, 0x38, 0x6A):
        assert sim.read_byte_data(ADDR, reg) == 0x00
    # asleep: time passes, the data registers stay at zero
    sim.clock.sleep(1.0)
    assert sim.read_i2c_block_data(ADDR, 0x3B, 14) == [0] * 14


def test_who_am_i_ignores_ad0():
    sim = SimulatedMPU6050(address=0x69)
    assert sim.read_byte_data(0x69, 0x75) == 0x68  # bits 6:1 of 0x68; AD0 not reflected
    with pytest.raises(OSError) as exc:
        sim.read_byte_data(0x68, 0x75)
    assert exc.value.errno == errno.EREMOTEIO


def test_device_reset_restores_registers_and_read_only_registers_ignore_writes():
    sim = SimulatedMPU6050()
    wake(sim)
    sim.write_byte_data(ADDR, 0x1B, 0x18)
    sim.write_byte_data(ADDR, 0x75, 0x00)  # WHO_AM_I is read-only
    assert sim.read_byte_data(ADDR, 0x75) == 0x68
    sim.write_byte_data(ADDR, 0x6B, 0x80)  # DEVICE_RESET
    assert sim.read_byte_data(ADDR, 0x6B) == 0x40  # bit 7 clear again, asleep
    assert sim.read_byte_data(ADDR, 0x1B) == 0x00


@pytest.mark.parametrize("dlpf,div,rate", [(0, 0, 8000), (0, 7, 1000), (7, 79, 100),
                                           (1, 0, 1000), (3, 9, 100), (6, 199, 5)])
def test_sample_rate_from_dlpf_and_divider(dlpf, div, rate):
    # gyro output rate 8 kHz for DLPF_CFG 0 or 7, else 1 kHz; rate = that / (1 + SMPLRT_DIV)
    sim = SimulatedMPU6050()
    wake(sim, div, dlpf)
    start = sim.samples_produced
    sim.clock.sleep(2.0)
    sim.read_byte_data(ADDR, 0x3A)
    produced = sim.samples_produced - start
    assert abs(produced - 2.0 * rate) <= 1


@pytest.mark.parametrize("fs_sel,lsb", [(0, 131.0), (1, 65.5), (2, 32.8), (3, 16.4)])
@pytest.mark.parametrize("afs_sel,lsb_g", [(0, 16384.0), (1, 8192.0), (2, 4096.0), (3, 2048.0)])
def test_scaling_every_range(fs_sel, lsb, afs_sel, lsb_g):
    rate = np.radians([10.0, -20.0, 100.0])  # deg/s -> rad/s
    force = np.array([0.1, -0.25, 0.5]) * G
    sim = SimulatedMPU6050(static_trace(force, rate), temperature_c=30.0)
    wake(sim)
    sim.write_byte_data(ADDR, 0x1B, fs_sel << 3)
    sim.write_byte_data(ADDR, 0x1C, afs_sel << 3)
    sim.clock.sleep(0.05)
    d = sim.read_i2c_block_data(ADDR, 0x3B, 14)
    v = [s16(d[i], d[i + 1]) for i in range(0, 14, 2)]
    assert v[0:3] == [round(0.1 * lsb_g), round(-0.25 * lsb_g), round(0.5 * lsb_g)]
    assert v[4:7] == [round(10 * lsb), round(-20 * lsb), round(100 * lsb)]
    assert v[3] == round((30.0 - 36.53) * 340)  # T = raw / 340 + 36.53


def test_saturation_at_int16():
    # 3 g on z at +-2 g and +-300 deg/s at +-250 deg/s clip to the int16 limits
    sim = SimulatedMPU6050(static_trace((0, 0, 3 * G), np.radians([300.0, -300.0, 0])))
    wake(sim)
    sim.clock.sleep(0.05)
    d = sim.read_i2c_block_data(ADDR, 0x3B, 14)
    assert s16(d[4], d[5]) == 32767  # ACCEL_ZOUT
    assert s16(d[8], d[9]) == 32767  # GYRO_XOUT
    assert s16(d[10], d[11]) == -32768  # GYRO_YOUT


def test_fifo_frames_in_register_order_and_no_auto_increment():
    t = np.array([0.0, 10.0])
    rate = np.radians([[1.0, 2.0, 3.0]] * 2)
    force = np.array([[0.5, -0.5, 0.25]] * 2) * G
    sim = SimulatedMPU6050(ArrayTrace(t, rate, force))
    wake(sim)  # 100 Hz
    sim.write_byte_data(ADDR, 0x23, 0x78)  # FIFO_EN: XG YG ZG ACCEL
    sim.write_byte_data(ADDR, 0x6A, 0x44)  # USER_CTRL: FIFO_EN | FIFO_RESET
    sim.clock.sleep(0.0505)  # 5 samples
    hi, lo = sim.read_i2c_block_data(ADDR, 0x72, 2)  # FIFO_COUNTH, FIFO_COUNTL
    count = (hi << 8) | lo
    assert count == 5 * 12
    frame = sim.read_i2c_block_data(ADDR, 0x74, 12)  # FIFO_R_W: 12 bytes of one frame
    v = [s16(frame[i], frame[i + 1]) for i in range(0, 12, 2)]
    # accel x, y, z (16384 LSB/g), then gyro x, y, z (131 LSB/(deg/s))
    assert v == [8192, -8192, 4096, 131, 262, 393]
    hi, lo = sim.read_i2c_block_data(ADDR, 0x72, 2)
    assert (hi << 8) | lo == 4 * 12


def test_fifo_limit_overflow_flag_and_reset():
    sim = SimulatedMPU6050()
    wake(sim, div=0, dlpf=1)  # 1 kHz
    sim.write_byte_data(ADDR, 0x38, 0x10)  # INT_ENABLE.FIFO_OFLOW_EN
    sim.write_byte_data(ADDR, 0x23, 0x78)
    sim.write_byte_data(ADDR, 0x6A, 0x44)
    sim.clock.sleep(0.080)  # 80 frames = 960 bytes: fits
    assert sim.read_byte_data(ADDR, 0x3A) & 0x10 == 0
    sim.clock.sleep(0.010)  # 90 frames = 1080 bytes > 1024
    hi, lo = sim.read_i2c_block_data(ADDR, 0x72, 2)
    assert (hi << 8) | lo == 1024
    assert sim.read_byte_data(ADDR, 0x3A) & 0x10  # FIFO_OFLOW_INT (bit 4)
    assert sim.read_byte_data(ADDR, 0x3A) & 0x10 == 0  # cleared by the read
    assert sim.fifo_bytes_dropped >= 1080 - 1024
    sim.write_byte_data(ADDR, 0x6A, 0x44)  # FIFO_RESET
    hi, lo = sim.read_i2c_block_data(ADDR, 0x72, 2)
    assert (hi << 8) | lo == 0


def test_data_ready_flag_only_when_enabled_and_cleared_on_read():
    sim = SimulatedMPU6050()
    wake(sim)
    sim.clock.sleep(0.05)
    assert sim.read_byte_data(ADDR, 0x3A) & 0x01 == 0  # DATA_RDY_EN off
    sim.write_byte_data(ADDR, 0x38, 0x01)
    sim.clock.sleep(0.011)
    assert sim.read_byte_data(ADDR, 0x3A) & 0x01
    assert sim.read_byte_data(ADDR, 0x3A) & 0x01 == 0


def test_self_test_registers_hold_trim_codes():
    sim = SimulatedMPU6050(gyro_trim_codes=(1, 2, 3), accel_trim_codes=(0b10110, 0b01001, 0b11111))
    x, y, z, a = sim.read_i2c_block_data(ADDR, 0x0D, 4)
    assert x == (0b101 << 5) | 1  # XA_TEST[4:2], XG_TEST
    assert y == (0b010 << 5) | 2
    assert z == (0b111 << 5) | 3
    assert a == (0b10 << 4) | (0b01 << 2) | 0b11  # XA_TEST[1:0], YA_TEST[1:0], ZA_TEST[1:0]


def test_self_test_response_added_when_bits_set():
    # gyro X code 1 -> FT = 25 * 131 * 1.046^0 = 3275 LSB at +-250 deg/s
    sim = SimulatedMPU6050(gyro_trim_codes=(1, 1, 1), self_test_deviation=(0,) * 6)
    wake(sim)
    sim.write_byte_data(ADDR, 0x1B, 0x80)  # XG_ST
    sim.clock.sleep(0.05)
    d = sim.read_i2c_block_data(ADDR, 0x43, 6)
    assert [s16(d[0], d[1]), s16(d[2], d[3]), s16(d[4], d[5])] == [3275, 0, 0]


def test_transactions_counted_and_i2c_rdwr_reads_any_length():
    sim = SimulatedMPU6050()
    wake(sim, div=0, dlpf=1)
    sim.write_byte_data(ADDR, 0x23, 0x78)
    sim.write_byte_data(ADDR, 0x6A, 0x44)
    sim.clock.sleep(0.0605)  # 60 frames = 720 bytes
    before = sim.transactions
    w, r = i2c_msg.write(ADDR, [0x74]), i2c_msg.read(ADDR, 720)
    sim.i2c_rdwr(w, r)
    assert sim.transactions == before + 1
    data = bytes(r)
    assert len(data) == 720 and data[4:6] == bytes([0x40, 0x00])  # az = +1 g = 16384
    with pytest.raises(ValueError):
        sim.read_i2c_block_data(ADDR, 0x74, 33)  # smbus2's 32-byte block limit


def test_nack_burst_and_wire_time():
    clock = SimClock()
    sim = SimulatedMPU6050(clock=clock, i2c_hz=100_000)
    sim.inject_nack(2, errno.EIO)
    for _ in range(2):
        with pytest.raises(OSError) as exc:
            sim.read_byte_data(ADDR, 0x75)
        assert exc.value.errno == errno.EIO
    t0 = clock.now
    assert sim.read_byte_data(ADDR, 0x75) == 0x68
    # 4 bytes on the wire (addr+W, reg, addr+R, data) x 9 bits + start/stop at 100 kHz
    assert math.isclose(clock.now - t0, (4 * 9 + 2) / 100_000)


def test_brown_out_returns_to_sleep():
    sim = SimulatedMPU6050()
    wake(sim)
    sim.brown_out()
    assert sim.read_byte_data(ADDR, 0x6B) == 0x40


def test_array_trace_validates():
    with pytest.raises(ValueError, match="increasing"):
        ArrayTrace(np.array([0.0, 0.0]), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        ArrayTrace(np.arange(3.0), np.zeros((2, 3)), np.zeros((3, 3)))


@pytest.mark.parametrize("dlpf,bw", [(6, 5.0), (4, 20.0)])
def test_optional_dlpf_model_step_response(dlpf, bw):
    # gyro z steps from 0 to 100 deg/s at t = 1 s; a first-order low-pass of bandwidth bw
    # (register map: gyro 5 Hz for DLPF_CFG 6, 20 Hz for 4) answers 100 (1 - exp(-2 pi bw dt))
    def step(t):
        w = np.zeros((len(t), 3))
        w[:, 2] = np.radians(100.0) * (t >= 1.0)
        return w, np.tile([0.0, 0.0, G], (len(t), 1))

    sim = SimulatedMPU6050(step, model_dlpf=True)
    wake(sim, div=0, dlpf=dlpf)  # 1 kHz
    t0 = sim.grid_start
    sim.clock.sleep(0.9)
    t, z = [], []
    for _ in range(400):  # poll GYRO_ZOUT every 1 ms from 0.9 s to 1.3 s
        sim.clock.sleep(0.001)
        n = math.floor((sim.clock.now - t0) * 1000 + 1e-9)  # the newest sample's index
        d = sim.read_i2c_block_data(ADDR, 0x47, 2)
        t.append(t0 + n / 1000)
        z.append(s16(d[0], d[1]) / 131.0)
    t, z = np.array(t), np.array(z)
    after = t - 1.0

    def response(dt):  # continuous first-order step response, deg/s
        return np.where(dt >= 0, 100.0 * (1 - np.exp(-2 * np.pi * bw * np.maximum(dt, 0))), 0)

    # A one-pole run at 1 kHz has seen the step since its first tick at or after 1.0 s, so
    # its output lies between the continuous response now and one tick (1 ms) later,
    # to within the rounding to 1 LSB (1/131 deg/s).
    lsb = 1 / 131
    assert np.all(z >= response(after) - lsb)
    assert np.all(z <= response(after + 0.001) + lsb)
    assert 0.3 < after[-1] and z[-1] > 99.9  # settled after more than 9 time constants
    assert z[(after > 0.005) & (after < 0.02)].max() < 95  # and it was a slow rise
    assert z[after < -0.002].max() < 0.01  # nothing before the step


def test_dlpf_model_off_by_default_follows_the_trace():
    sim = SimulatedMPU6050(static_trace((0, 0, G), np.radians([0, 0, 50.0])))
    wake(sim, div=0, dlpf=6)
    sim.clock.sleep(0.002)
    d = sim.read_i2c_block_data(ADDR, 0x47, 2)
    assert s16(d[0], d[1]) == 50 * 131
