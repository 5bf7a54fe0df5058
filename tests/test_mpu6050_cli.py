"""``fusion imu`` end to end on the simulated chip (still for 5 s, then 10 deg/s about z)."""

import json

import numpy as np

from fusion.cli import main


def read_csv(path):
    lines = path.read_text().splitlines()
    assert lines[0] == "t,gx,gy,gz,ax,ay,az,temp,qw,qx,qy,qz,roll,pitch,yaw"
    return np.array([[float(v) if v else np.nan for v in ln.split(",")] for ln in lines[1:]])


def test_stream_with_calibration_and_attitude(tmp_path, capsys):
    out, cal = tmp_path / "imu.csv", tmp_path / "cal.json"
    rc = main(["imu", "--sim", "--rate", "100", "--calibrate", "--count", "1200",
               "--save-calibration", str(cal), "-o", str(out)])
    assert rc == 0
    err = capsys.readouterr().err
    # the simulator's gyro bias is (0.8, -0.5, 0.3) deg/s with 0.05 deg/s noise
    assert "gyro bias (+0.80" in err or "gyro bias (+0.79" in err
    bias = np.degrees(json.loads(cal.read_text())["gyro_bias"])
    assert np.allclose(bias, [0.8, -0.5, 0.3], atol=0.02)
    d = read_csv(out)
    assert d.shape == (1200, 15)
    t, yaw = d[:, 0], d[:, 14]
    assert np.allclose(np.diff(t), 0.01, atol=0.001)  # FIFO timestamps at 100 Hz
    assert np.allclose(d[:, 6].mean(), 9.80665, atol=0.01)  # az: 1 g at rest, m/s^2
    # the FIFO carries the die temperature: the simulator's default 25 deg C, +-1 LSB/340
    assert np.all(np.abs(d[:, 7] - 25.0) <= 1 / 340 + 0.005)
    # turning at 10 deg/s from t = 5 s: the yaw (rad) follows (bias removed, no drift before)
    assert abs(yaw[t < 5.0][-1]) < np.radians(0.2)
    end = t[-1]
    assert abs(yaw[-1] - np.radians(10.0 * (end - 5.0))) < np.radians(1.0)
    # one IMU CSV format: fusion attitude reads what fusion imu wrote (the extra columns
    # ignored by name) and its yaw is in the same unit, rad
    att = tmp_path / "att.csv"
    assert main(["attitude", str(out), "-o", str(att)]) == 0
    a = np.loadtxt(att, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(a[:, 0], t)
    assert abs(a[-1, 7] - np.radians(10.0 * (end - 5.0))) < np.radians(1.0)


def test_no_fifo_stream_has_the_same_columns(tmp_path):
    out = tmp_path / "imu.csv"
    assert main(["imu", "--sim", "--no-fifo", "--count", "20", "-o", str(out)]) == 0
    d = read_csv(out)
    assert d.shape == (20, 15)
    assert np.allclose(np.diff(d[:, 0]), 0.01, atol=0.002)  # a new sample each time
    assert np.all(np.abs(d[:, 7] - 25.0) <= 1 / 340 + 0.005)


def test_calibrate_refuses_when_moving(capsys):
    rc = main(["imu", "--sim", "--calibrate", "--calibrate-seconds", "8", "--count", "5"])
    assert rc == 2
    assert "the sensor moved" in capsys.readouterr().err


def test_missing_bus_is_a_clear_error(capsys):
    rc = main(["imu", "--bus", "250", "--count", "1"])
    assert rc == 2
    assert "/dev/i2c-250" in capsys.readouterr().err


def test_raw_recording_then_imu_calibrate(tmp_path, capsys):
    rest, cal = tmp_path / "rest.csv", tmp_path / "cal.json"
    assert main(["imu", "--sim", "--raw", "--count", "400", "-o", str(rest)]) == 0
    lines = rest.read_text().splitlines()
    # metadata for the CLI's default ranges: +-4 g = 8192 LSB/g, +-500 deg/s = 65.5 LSB/(deg/s)
    assert lines[:4] == ["Fs,100", "accel_lsb_per_g,8192", "gyro_lsb_per_dps,65.5",
                         "ax,ay,az,gx,gy,gz"]
    assert len(lines) == 4 + 400
    az = np.array([int(ln.split(",")[2]) for ln in lines[4:]])
    assert abs(az.mean() - 8192) < 5  # 1 g at rest
    assert main(["imu-calibrate", str(rest), "-o", str(cal)]) == 0
    bias = np.degrees(json.loads(cal.read_text())["gyro_bias"])
    assert np.allclose(bias, [0.8, -0.5, 0.3], atol=0.03)  # the simulator's bias


def test_imu_calibrate_on_the_bundled_recordings(tmp_path, capsys, datasets_dir):
    raw = datasets_dir / "mpu6050_raw"
    out = tmp_path / "cal.json"
    rc = main(["imu-calibrate", str(raw / "imu_static_test.csv"), "--poses",
               str(raw / "example_data_calibration.csv"), "-o", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "gyro bias (-3.268, +1.118, -0.504) deg/s" in text and "9 still poses" in text
    d = json.loads(out.read_text())
    assert np.allclose(np.array(d["accel_offset"]) / 9.80665, [0.0427, -0.0220, -0.1158],
                       atol=0.0005)


def test_imu_calibrate_bad_file(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("Fs,100\nax,ay,az,gx,gy,gz\n1,2,3\n")
    assert main(["imu-calibrate", str(bad), "-o", str(tmp_path / "c.json")]) == 2
    assert "bad.csv:3: expected 6 values" in capsys.readouterr().err
