"""Synthetic runs: exact geometry against analytic paths, sensor models against their specs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.synthetic import (
    GRAVITY,
    EncoderModel,
    ImuModel,
    Segment,
    SlipPatch,
    arc,
    degraded_mission,
    figure_eight,
    random_mission,
    simulate,
    spin,
    square,
    stop,
    straight,
)
from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.odometry import WheelOdometry

ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4, encode_sampling_time=0.04)
FAST = {"max_accel": 1e9, "max_angular_accel": 1e9}  # steps instead of ramps


def test_same_seed_same_run_and_other_seed_differs():
    segs = random_mission(40.0, seed=3)
    imu = ImuModel(gyro_bias_walk=1e-4, vibration=0.5, jitter=1e-4)
    enc = EncoderModel(drop_probability=0.05, jitter=1e-3)
    a = simulate(segs, ROBOT, imu, enc, seed=7)
    b = simulate(segs, ROBOT, imu, enc, seed=7)
    c = simulate(segs, ROBOT, imu, enc, seed=8)
    for name in ("imu_t", "gyro", "accel", "wheel_t", "ticks", "truth"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.gyro, c.gyro)
    assert random_mission(40.0, seed=3) == segs
    assert random_mission(40.0, seed=4) != segs


def test_square_truth_closes_and_hits_the_corners():
    run = simulate(square(side=2.0, direction="ccw"), ROBOT, seed=0)
    # Ramps lose at the start of a leg exactly what they gain at its end: corners are exact.
    np.testing.assert_allclose(run.truth[-1], [0.0, 0.0, 0.0], atol=1e-4)
    for corner in ([2.0, 0.0], [2.0, 2.0], [0.0, 2.0]):
        d = np.min(np.hypot(*(run.truth[:, :2] - corner).T))
        assert d < 2e-3
    assert run.distance == pytest.approx(8.0, rel=1e-6)
    cw = simulate(square(side=2.0, direction="cw"), ROBOT, seed=0)
    assert np.min(cw.truth[:, 1]) == pytest.approx(-2.0, abs=2e-3)


def test_constant_twist_is_an_exact_circle():
    # v = 0.5 m/s, w = 0.5 rad/s: radius 1 m about (0, 1), one full turn in 4 pi s.
    run = simulate([Segment(0.5, 0.5, 4 * math.pi)], ROBOT, seed=0, **FAST)
    r = np.hypot(run.truth[:, 0], run.truth[:, 1] - 1.0)
    np.testing.assert_allclose(r, 1.0, atol=1e-9)
    expected_yaw = np.pi - np.mod(np.pi - 0.5 * run.truth_t, 2 * np.pi)
    np.testing.assert_allclose(np.angle(np.exp(1j * (run.truth[:, 2] - expected_yaw))), 0,
                               atol=1e-9)


def test_figure_eight_returns_to_start():
    run = simulate(figure_eight(radius=1.0, laps=1), ROBOT, seed=0)
    np.testing.assert_allclose(run.truth[-1, :2], [0, 0], atol=5e-3)
    assert run.distance == pytest.approx(4 * math.pi, rel=1e-3)


def test_encoder_counts_follow_the_true_geometry():
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.01, right_scale_error=0.02)
    L = 0.3 * 1.03
    # 2 m straight: each wheel counts 2 m / its own metres per tick
    run = simulate(stop(1) + straight(2.0, 0.4) + stop(1), ROBOT, encoders=enc, seed=1)
    left, right = run.ticks.sum(axis=0)
    assert abs(left - 2.0 / (1e-4 * 0.99)) <= 1
    assert abs(right - 2.0 / (1e-4 * 1.02)) <= 1
    # a full spin: wheels travel -/+ pi*L_true
    run = simulate(stop(1) + spin(2 * math.pi, 0.8) + stop(1), ROBOT, encoders=enc, seed=1)
    left, right = run.ticks.sum(axis=0)
    assert abs(left + math.pi * L / (1e-4 * 0.99)) <= 1
    assert abs(right - math.pi * L / (1e-4 * 1.02)) <= 1
    assert run.true_wheel_distance == pytest.approx(L)
    # ticks are per period of encode_sampling_time, stamped at the end of the period
    np.testing.assert_allclose(np.diff(run.wheel_t), 0.04, atol=1e-9)


def test_exact_geometry_dead_reckoning_matches_truth():
    # Independent integration (fusion.planar.odometry, seed 000's midpoint rule) of the simulated
    # ticks lands on the truth: the only errors left are quantisation and the midpoint rule.
    run = simulate(square(side=3.0), ROBOT, seed=2)
    pose = WheelOdometry(ROBOT).update_batch(run.ticks[:, 0], run.ticks[:, 1])[-1]
    np.testing.assert_allclose(pose[:2], run.truth[-1, :2], atol=5e-3)
    assert math.remainder(pose[2] - run.truth[-1, 2], 2 * math.pi) == pytest.approx(0, abs=2e-3)


def test_slip_patch_over_counts_one_wheel():
    base = stop(1) + straight(4.0, 0.4) + stop(1)
    patch = SlipPatch(3.0, 4.0, wheel="left", ratio=0.3)
    clean = simulate(base, ROBOT, seed=0)
    slip = simulate(base, ROBOT, encoders=EncoderModel(slip_patches=(patch,)), seed=0)
    extra = slip.ticks.sum(axis=0) - clean.ticks.sum(axis=0)
    # 1 s at 0.4 m/s, 30 % extra on the left: 0.12 m = 1200 ticks; right unchanged
    assert abs(extra[0] - 1200) <= 2
    assert abs(extra[1]) <= 1
    np.testing.assert_array_equal(slip.truth, clean.truth)


def test_dropped_frames_and_jitter_keep_order():
    enc = EncoderModel(drop_probability=0.1, jitter=0.004)
    run = simulate(random_mission(60, seed=1), ROBOT, encoders=enc, seed=3)
    n_all = run.ticks.shape[0] + run.info["frames_dropped"]
    assert 0.07 < run.info["frames_dropped"] / n_all < 0.13
    assert np.all(np.diff(run.wheel_t) >= 0)


def test_gyro_model_noise_bias_and_scale():
    dens = math.radians(0.005)
    imu = ImuModel(rate=200.0, gyro_noise_density=dens, gyro_bias=(0.01, -0.02, 0.03),
                   gyro_scale=(0.0, 0.0, 0.02))
    run = simulate(stop(20) + spin(4 * math.pi, 1.0) + stop(1), ROBOT, imu=imu, seed=4, **FAST)
    rest = run.imu_t < 19.9
    sigma = dens * math.sqrt(200.0)
    n = rest.sum()
    np.testing.assert_allclose(run.gyro[rest].mean(axis=0), [0.01, -0.02, 0.03],
                               atol=5 * sigma / math.sqrt(n))
    np.testing.assert_allclose(run.gyro[rest].std(axis=0), sigma, rtol=0.05)
    spinning = (run.imu_t > 20.5) & (run.imu_t < 20 + 4 * math.pi - 0.5)
    assert run.gyro[spinning, 2].mean() == pytest.approx(1.02 * 1.0 + 0.03, abs=1e-3)


def test_gyro_bias_random_walk_has_the_stated_growth():
    walk = 1e-3
    imu = ImuModel(gyro_bias_walk=walk, gyro_noise_density=0.0)
    runs = [simulate(stop(100), ROBOT, imu=imu, seed=s) for s in range(30)]
    change = np.array([r.gyro_bias[-1] - r.gyro_bias[0] for r in runs]).ravel()
    # sigma after 100 s = walk*sqrt(100); 90 samples: the sample std within 25 %
    assert np.std(change) == pytest.approx(walk * 10, rel=0.25)


def test_accelerometer_sees_gravity_and_centripetal_force():
    imu = ImuModel(accel_noise_density=0.0)
    run = simulate([*stop(1), Segment(0.5, 1.0, 5.0)], ROBOT, imu=imu, seed=0, **FAST)
    rest = run.imu_t < 0.9
    np.testing.assert_allclose(run.accel[rest], [[0, 0, GRAVITY]] * rest.sum(), atol=1e-12)
    turning = (run.imu_t > 1.5) & (run.imu_t < 5.5)
    np.testing.assert_allclose(run.accel[turning, 1], 0.5 * 1.0, atol=1e-9)  # v*w


def test_degraded_mission_is_what_it_says():
    run = degraded_mission(seed=1, duration=60)
    assert run.true_wheel_distance == pytest.approx(0.3 * 1.03)
    assert run.true_right_ratio / run.true_left_ratio == pytest.approx(1.0025 / 0.9975)
    assert run.gyro_bias[0, 2] == pytest.approx(math.radians(0.5))
    assert run.truth_v[:100].max() == 0  # starts at rest


@pytest.mark.parametrize(
    "bad",
    [
        lambda: Segment(0.1, 0.0, 0.0),
        lambda: straight(0.0),
        lambda: arc(-1.0, 1.0),
        lambda: spin(1.0, 0.0),
        lambda: SlipPatch(2.0, 1.0),
        lambda: SlipPatch(1.0, 2.0, wheel="front"),
        lambda: ImuModel(rate=0),
        lambda: EncoderModel(drop_probability=1.0),
        lambda: square(direction="up"),
        lambda: simulate([], ROBOT),
    ],
)
def test_bad_parameters_raise_value_error(bad):
    with pytest.raises(ValueError):
        bad()


def test_uart2_stream_decodes_to_the_ticks_with_the_driver_parser():
    from drivers.chassis import WheelFrameParser

    run = simulate(random_mission(30, seed=2), ROBOT, seed=2)
    stream, arrival = run.uart2_stream()
    assert len(stream) == 11 * run.ticks.shape[0]
    # first frame by hand: FF FF, sign (1 = non-negative), 24-bit big-endian magnitudes, sum
    left, right = (int(v) for v in run.ticks[0])
    first = bytes([0xFF, 0xFF, 1 if left >= 0 else 0, *abs(left).to_bytes(3, "big"),
                   1 if right >= 0 else 0, *abs(right).to_bytes(3, "big")])
    assert stream[:11] == first + bytes([sum(first) & 0xFF])
    frames = []
    parser = WheelFrameParser()
    for k in range(0, len(stream), 7):  # arbitrary read sizes
        frames += parser.feed(stream[k:k + 7])
    got = np.array([(f.left, f.right) for f in frames])
    np.testing.assert_array_equal(got, run.ticks)
    np.testing.assert_array_equal(arrival, run.wheel_t)


def test_mpu6050_registers_follow_the_register_map():
    run = simulate(stop(1) + spin(math.pi, 2.0) + stop(1), ROBOT,
                   imu=ImuModel(gyro_bias=(0.01, 0.0, 0.0)), seed=3)
    regs = run.mpu6050_registers(gyro_range_dps=500, accel_range_g=4, temperature=30.0)
    assert regs.shape == (run.imu_t.size, 14) and regs.dtype == np.uint8
    words = (regs[:, 0::2].astype(np.int32) << 8) | regs[:, 1::2]
    words = np.where(words >= 32768, words - 65536, words)  # two's complement by hand
    np.testing.assert_allclose(words[:, 0:3] / 8192.0 * GRAVITY, run.accel,
                               atol=0.5 / 8192.0 * GRAVITY + 1e-12)
    assert np.all(words[:, 3] == round((30.0 - 36.53) * 340.0))
    np.testing.assert_allclose(np.radians(words[:, 4:7] / 65.5), run.gyro,
                               atol=np.radians(0.5 / 65.5) + 1e-12)
    # a 2 rad/s spin (114.6 deg/s, 15013 counts at 131 LSB per deg/s) fits +-250 deg/s
    assert np.abs(run.mpu6050_registers()[:, 12:14].view(">i2")).max() < 32767
    fast = simulate(stop(0.5) + spin(4 * math.pi, 6.0), ROBOT, seed=3)
    sat = fast.mpu6050_registers(gyro_range_dps=250)[:, 12:14].copy().view(">i2")
    assert sat.max() == 32767  # 344 deg/s beyond +-250 deg/s: clipped, not wrapped


def test_accelerate_ramps_the_command_linearly():
    # 0 -> 0.5 m/s over 2 s (0.25 m/s^2, below the 1 m/s^2 limit), hold 1 s, ramp down:
    # v(t) = 0.25 t on the ramp; distance = 0.5 + 0.5 + 0.5 m
    from fusion.evaluation.synthetic import accelerate

    segs = [*accelerate(0.5, 2.0), Segment(0.5, 0.0, 1.0), *accelerate(0.0, 2.0), *stop(0.5)]
    run = simulate(segs, ROBOT, seed=0)
    ramp = (run.truth_t > 0.1) & (run.truth_t < 1.9)
    np.testing.assert_allclose(run.truth_v[ramp], 0.25 * run.truth_t[ramp], atol=2e-3)
    assert run.distance == pytest.approx(1.5, abs=1e-3)
    np.testing.assert_allclose(run.accel[ramp, 0].mean(), 0.25, atol=0.01)


class _RegisterReplay:
    """A register file on a fake I2C bus that serves the synthetic data registers, one
    14-byte sample per burst read at ACCEL_XOUT_H (0x3B), or at INT_STATUS (0x3A) preceded by
    DATA_RDY (a new sample for every read); PWR_MGMT_1's reset bit self-clears and WHO_AM_I
    (0x75) reads 0x68, as on the chip."""

    def __init__(self, rows):
        self.regs = bytearray(128)
        self.regs[0x75] = 0x68
        self.rows = rows
        self.k = 0

    def read_byte_data(self, addr, reg):
        return 0x01 if reg == 0x3A else self.regs[reg]  # INT_STATUS: DATA_RDY

    def write_byte_data(self, addr, reg, value):
        self.regs[reg] = value & 0x7F if reg == 0x6B else value

    def read_i2c_block_data(self, addr, reg, length):
        if reg in (0x3A, 0x3B):
            row = list(self.rows[self.k])
            self.k += 1
            return ([0x01, *row] if reg == 0x3A else row)[:length]
        return list(self.regs[reg:reg + length])


class _Clock:
    def __init__(self):
        self.t = 0.0

    def monotonic(self):
        return self.t

    def sleep(self, s):
        self.t += s


def test_end_to_end_through_both_drivers():
    # The synthetic run leaves as DATA-uart2 bytes and MPU6050 registers, comes back through
    # drivers.chassis.WheelFrameParser and drivers.mpu6050.MPU6050, and fuses to what the
    # arrays fuse to, up to the sensors' quantisation.
    from drivers.chassis import WheelFrameParser
    from drivers.mpu6050 import MPU6050
    from fusion.evaluation.synthetic import degraded_mission
    from fusion.planar.ekf import fuse

    run = degraded_mission(seed=3, duration=40.0)
    regs = run.mpu6050_registers(gyro_range_dps=500, accel_range_g=4)
    imu = MPU6050(_RegisterReplay(regs), gyro_range_dps=500, accel_range_g=4, clock=_Clock())
    samples = [imu.read(calibrated=False) for _ in range(len(regs))]
    gyro = np.array([s.gyro for s in samples])
    accel = np.array([s.accel for s in samples])
    np.testing.assert_allclose(gyro, run.gyro, atol=np.radians(0.5 / 65.5) + 1e-12)
    np.testing.assert_allclose(accel, run.accel, atol=0.5 / 8192 * GRAVITY + 1e-12)
    stream, arrival = run.uart2_stream()
    frames = WheelFrameParser().feed(stream)
    ticks = np.array([(f.left, f.right) for f in frames])
    np.testing.assert_array_equal(ticks, run.ticks)
    _, direct = fuse(ROBOT, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks)
    _, via = fuse(ROBOT, run.imu_t, gyro[:, 2], arrival, ticks)
    assert math.hypot(*(via.x[:2] - direct.x[:2])) < 0.01
    assert abs(math.degrees(via.x[2] - direct.x[2])) < 0.1
