"""IMU calibration on the real raw MPU6050 recordings in datasets/mpu6050_raw, and on the sim.

Figures obtained on the bundled recordings (100 Hz, +-2 g = 16384 LSB/g, +-250 deg/s = 131
LSB/(deg/s), DLPF 0), stated here and asserted below:

- imu_static_test.csv (99.9 s at rest): gyro bias (-3.268, +1.118, -0.504) deg/s; per-sample
  noise std (0.075, 0.112, 0.094) deg/s, so the bias is known to about 0.001 deg/s.
- example_data_calibration.csv: 9 still poses found (z up, x down, x up, y down, y up and four
  tilted ones; the z-down pose was never held still). Fit: offset (+0.0427, -0.0220, -0.1158)
  g, scale (1.0050, 0.9971, 0.9751). Pose norms 0.908..1.038 g before, within 0.001 g of 1 g
  after.
- Cross-check on recordings not used for the fit: the mean accelerometer norm of
  imu_static_test.csv goes from 0.912 g to 1.0009 g; the still part of imu_90_x_rot.csv after
  the turn (y up) from 0.996 g to 0.9998 g.
"""

from pathlib import Path

import numpy as np
import pytest

from drivers.mpu6050 import MPU6050
from drivers.sim.mpu6050 import SimulatedMPU6050, static_trace
from fusion.calibration.imu import (
    ImuCalibration,
    SensorMovingError,
    calibrate,
    calibrate_recordings,
    check_at_rest,
    fit_accel_poses,
    gyro_bias_at_rest,
    pose_means,
    static_segments,
)
from fusion.io.imu_calibration import load_imu_calibration, save_imu_calibration
from fusion.io.mpu6050_csv import read_mpu6050_csv

G = 9.80665
RAW = Path(__file__).resolve().parent.parent / "datasets" / "mpu6050_raw"


@pytest.fixture(scope="module")
def static():
    return read_mpu6050_csv(RAW / "imu_static_test.csv")


@pytest.fixture(scope="module")
def rotation():
    return read_mpu6050_csv(RAW / "imu_90_x_rot.csv")


@pytest.fixture(scope="module")
def poses_rec():
    return read_mpu6050_csv(RAW / "example_data_calibration.csv")


@pytest.fixture(scope="module")
def fit(poses_rec):
    segs = static_segments(poses_rec.gyro_si(), poses_rec.accel_si(), poses_rec.fs_hz)
    return segs, fit_accel_poses(pose_means(poses_rec.accel_si(), segs))


# --------------------------------------------------------------------------- CSV reader
def test_reader_against_numpy_loadtxt(static):
    ref = np.loadtxt(RAW / "imu_static_test.csv", delimiter=",", skiprows=5)
    assert static.fs_hz == 100.0 and len(static) == len(ref) == 9986
    assert np.array_equal(static.accel, ref[:, :3]) and np.array_equal(static.gyro, ref[:, 3:])
    assert static.metadata["Logging Type"] == "1"
    assert np.allclose(static.gyro_si(), np.radians(ref[:, 3:] / 131.0))
    assert np.allclose(static.accel_si(), ref[:, :3] / 16384.0 * G)


@pytest.mark.parametrize("body,match", [
    ("Fs,100\nax,ay,az,gx,gy,gz\n1,2,3,4,5\n", r"bad\.csv:3: expected 6 values"),
    ("Fs,100\nax,ay,az,gx,gy,gz\n1,2,3,4,5,x\n", r"bad\.csv:3: values must be integers"),
    ("Fs,100\nax,ay,az,gx,gy,gz\n1,2,3,4,5,40000\n", r"bad\.csv:3: value outside int16"),
    ("Fs,100\n1,2,3,4,5,6\n", r"bad\.csv:2: expected a 'key,value'"),
    ("ax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n", r"no 'Fs,<Hz>'"),
    ("Fs,100\n", r"no header line"),
])
def test_reader_errors_name_file_and_line(tmp_path, body, match):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ValueError, match=match):
        read_mpu6050_csv(p)


def test_reader_takes_sensitivities_from_metadata(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("Fs,200\naccel_lsb_per_g,8192\ngyro_lsb_per_dps,65.5\nax,ay,az,gx,gy,gz\n"
                 "0,0,8192,655,0,0\n")
    r = read_mpu6050_csv(p)
    assert r.fs_hz == 200.0 and np.allclose(r.accel_g(), [[0, 0, 1.0]])
    assert np.allclose(r.gyro_dps(), [[10.0, 0, 0]])
    assert np.allclose(read_mpu6050_csv(p, accel_lsb_per_g=16384).accel_g(), [[0, 0, 0.5]])
    p.write_text("Fs,200\naccel_lsb_per_g,zero\nax,ay,az,gx,gy,gz\n0,0,1,0,0,0\n")
    with pytest.raises(ValueError, match="accel_lsb_per_g must be a positive number"):
        read_mpu6050_csv(p)


# --------------------------------------------------------------------------- gyro bias
def test_gyro_bias_on_real_static_recording(static):
    bias = np.degrees(gyro_bias_at_rest(static.gyro_si(), static.accel_si(), static.fs_hz))
    # the stated figures; tolerance 0.005 deg/s = 5x the standard error of the mean
    assert np.allclose(bias, [-3.268, 1.118, -0.504], atol=0.005)


def test_gyro_bias_refuses_the_real_rotation_recording(rotation):
    with pytest.raises(SensorMovingError, match=r"moved: gyro .* deg/s in 1[45]\.\d-1[56]\.\d s"):
        gyro_bias_at_rest(rotation.gyro_si(), rotation.accel_si(), rotation.fs_hz)


def test_still_start_of_rotation_recording_gives_the_same_bias(rotation):
    n = 14 * 100  # the first 14 s, before the turn
    bias = gyro_bias_at_rest(rotation.gyro_si()[:n], rotation.accel_si()[:n], rotation.fs_hz)
    # another power-up of the same chip: bias within 0.05 deg/s of the static recording's
    assert np.allclose(np.degrees(bias), [-3.268, 1.118, -0.504], atol=0.05)


def test_a_slow_turn_is_refused_too():
    # 2 deg/s turning on and off every 5 s: window std stays low, window means move
    t = np.arange(2000) / 100
    gyro = np.zeros((2000, 3))
    gyro[:, 2] = np.radians(2.0) * ((t // 5) % 2)
    with pytest.raises(SensorMovingError, match="mean change on z"):
        check_at_rest(gyro, None, 100.0)


# --------------------------------------------------------------------------- accelerometer
def test_pose_detection_on_real_recording(fit, poses_rec):
    segs, _ = fit
    starts = [s.start / poses_rec.fs_hz for s in segs]
    assert starts == [0.5, 48.5, 55.5, 61.5, 69.5, 75.5, 82.0, 90.5, 96.0]
    a = poses_rec.accel_g()
    for s in segs:  # every pose is still: accelerometer std at the rest noise level
        assert s.stop - s.start >= 150
        assert np.all(a[s].std(axis=0) < 0.01)
    # the handling between poses (e.g. 40-47 s, gyro std above 10 deg/s) is excluded
    assert not any(s.start < 4700 and s.stop > 4000 for s in segs)


def test_accel_fit_on_real_poses(fit, poses_rec):
    segs, f = fit
    means_g = pose_means(poses_rec.accel_si(), segs) / G
    # each axis seen pointing up (> 0.9 g) and, for x and y, down (< -0.9 g)
    assert means_g[:, 0].max() > 0.9 and means_g[:, 0].min() < -0.9
    assert means_g[:, 1].max() > 0.9 and means_g[:, 1].min() < -0.9
    assert means_g[:, 2].max() > 0.9
    assert np.allclose(f.offset / G, [0.0427, -0.0220, -0.1158], atol=0.0005)
    assert np.allclose(f.scale, [1.0050, 0.9971, 0.9751], atol=0.0005)
    before, after = f.norm_before / G, f.norm_after / G
    assert before.min() < 0.91 and before.max() > 1.03  # up to 9 % off before
    assert np.max(np.abs(after - 1.0)) < 0.001  # every pose within 1 mg after


def test_corrected_norm_on_independent_recordings(fit, static, rotation):
    _, f = fit
    cal = ImuCalibration(accel_offset=f.offset, accel_scale=f.scale)
    raw_norm = np.linalg.norm(static.accel_g(), axis=1)
    corrected = np.linalg.norm(cal.apply_accel(static.accel_si()), axis=1) / G
    # tolerance: half the per-sample standard deviation of the norm measured on this
    # recording (0.0046 g), i.e. the mean error is small beside one sample's noise
    tol = 0.5 * np.std(raw_norm)
    assert 0.0020 < tol < 0.0026
    assert abs(raw_norm.mean() - 0.912) < 0.001  # 8.8 % low before
    assert abs(corrected.mean() - 1.0) < tol  # 1.0009 g after
    after_turn = slice(24 * 100, None)  # still, y up, after the 90 deg turn
    c2 = np.linalg.norm(cal.apply_accel(rotation.accel_si()[after_turn]), axis=1) / G
    assert abs(c2.mean() - 1.0) < tol  # 0.9998 g (0.996 g before)


def test_fit_recovers_a_known_model_exactly():
    offset = np.array([0.3, -0.2, 0.5])  # m/s^2
    scale = np.array([1.02, 0.97, 1.01])
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [1, 1, 1], [-1, 1, -1]], dtype=float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    measured = dirs * G / scale + offset  # invert the model (a - o) * s = true
    f = fit_accel_poses(measured)
    assert np.allclose(f.offset, offset, atol=1e-9) and np.allclose(f.scale, scale, atol=1e-9)


def test_fit_refuses_too_few_or_degenerate_poses():
    with pytest.raises(ValueError, match="at least 6 static poses"):
        fit_accel_poses(np.tile([0, 0, G], (5, 1)))
    nearly_same = np.array([0, 0, G]) + np.random.default_rng(0).normal(0, 0.01, (8, 3))
    with pytest.raises(ValueError, match="do not determine"):
        fit_accel_poses(nearly_same)


# --------------------------------------------------------------------------- file, driver
def test_save_load_round_trip_and_bad_file(tmp_path, fit, static, poses_rec):
    _, f = fit
    cal = calibrate_recordings(static, poses_rec)
    assert np.allclose(cal.accel_offset, f.offset) and np.allclose(cal.accel_scale, f.scale)
    assert cal.info["poses"] == 9 and cal.info["pose_norm_error_max_g"] < 0.001
    p = tmp_path / "imu.json"
    save_imu_calibration(cal, p)
    back = load_imu_calibration(p)
    assert np.array_equal(back.gyro_bias, cal.gyro_bias)
    assert np.array_equal(back.accel_scale, cal.accel_scale)
    assert back.info["rest_file"] == "imu_static_test.csv"
    assert back.info["poses_file"] == "example_data_calibration.csv"
    p.write_text('{"format": "diffbot-fusion imu calibration", "version": 1, "gyro_bias": [1]}')
    with pytest.raises(ValueError, match=r"imu\.json: missing key 'accel_offset'"):
        load_imu_calibration(p)
    p.write_text("{nope")
    with pytest.raises(ValueError, match=r"imu\.json:1: not valid JSON"):
        load_imu_calibration(p)


def test_driver_applies_calibration_found_at_rest(tmp_path):
    bias_dps = np.array([1.5, -2.0, 0.7])
    sim = SimulatedMPU6050(static_trace((0, 0, G)), gyro_bias_dps=bias_dps,
                           gyro_noise_dps=0.1, accel_noise_g=0.004, seed=7)
    imu = MPU6050(sim, clock=sim.clock, sample_rate_hz=100)
    rows = []
    for _ in range(300):
        rows.append(imu.read(wait=True))
    gyro = np.array([s.gyro for s in rows])
    accel = np.array([s.accel for s in rows])
    cal = calibrate(gyro, accel, imu.sample_rate_hz)
    # noise 0.1 deg/s per sample, 300 samples: standard error 0.006 deg/s; 1 LSB = 0.0076
    assert np.allclose(np.degrees(cal.gyro_bias), bias_dps, atol=0.03)
    save_imu_calibration(cal, tmp_path / "cal.json")
    imu.calibration = load_imu_calibration(tmp_path / "cal.json")
    after = np.array([imu.read(wait=True).gyro for _ in range(300)])
    assert np.all(np.abs(np.degrees(after.mean(axis=0))) < 0.03)


def test_calibration_refuses_when_the_simulated_sensor_turns():
    def turning(t):
        w = np.zeros((len(t), 3))
        w[:, 2] = np.radians(30.0) * (t > 1.5)  # starts turning after 1.5 s
        return w, np.tile([0, 0, G], (len(t), 1))

    sim = SimulatedMPU6050(turning, gyro_noise_dps=0.1, seed=2)
    imu = MPU6050(sim, clock=sim.clock, sample_rate_hz=100)
    rows = [imu.read(wait=True) for _ in range(300)]
    with pytest.raises(SensorMovingError, match="Keep the sensor still"):
        calibrate(np.array([s.gyro for s in rows]), np.array([s.accel for s in rows]), 100.0)


def test_real_recording_replayed_through_sim_and_driver(static, fit):
    """The static recording drives the simulated chip (ArrayTrace of its SI values); the driver
    reads it through the FIFO at the recording's settings (DLPF 0, 100 Hz, +-2 g, +-250 deg/s),
    the gyro bias comes out as from the CSV, and the pose calibration applied by the driver
    brings the norm to 1 g."""
    from drivers.sim.mpu6050 import ArrayTrace

    n = 30 * 100  # 30 s
    trace = ArrayTrace(static.t[:n], static.gyro_si()[:n], static.accel_si()[:n])
    sim = SimulatedMPU6050(trace)
    imu = MPU6050(sim, clock=sim.clock, dlpf=0, sample_rate_hz=100, gyro_range_dps=250,
                  accel_range_g=2)
    imu.enable_fifo()
    samples = []
    while sim.clock.now < 29.0:
        sim.clock.sleep(0.3)
        samples += imu.read_fifo().samples
    gyro = np.array([s.gyro for s in samples])
    accel = np.array([s.accel for s in samples])
    bias = gyro_bias_at_rest(gyro, accel, imu.sample_rate_hz)
    assert np.allclose(np.degrees(bias), [-3.268, 1.118, -0.504], atol=0.01)
    _, f = fit
    imu.calibration = ImuCalibration(bias, f.offset, f.scale)
    sim.clock.sleep(0.3)
    corrected = imu.read_fifo().samples
    assert len(corrected) >= 29
    norms = np.linalg.norm([s.accel for s in corrected], axis=1) / G
    # 30 samples, per-sample norm noise 0.0046 g: the mean is within 0.0046 * 3 / sqrt(30)
    # of the recording's corrected mean 1.0009 g
    assert abs(norms.mean() - 1.0009) < 0.0025
    assert np.all(np.abs(np.degrees([s.gyro for s in corrected]).mean(axis=0)) < 0.1)
