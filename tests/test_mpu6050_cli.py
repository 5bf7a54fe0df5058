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
    # turning at 10 deg/s from t = 5 s: the yaw follows (bias removed, no drift before)
    assert abs(yaw[t < 5.0][-1]) < 0.2
    end = t[-1]
    assert abs(yaw[-1] - 10.0 * (end - 5.0)) < 1.0


def test_calibrate_refuses_when_moving(capsys):
    rc = main(["imu", "--sim", "--calibrate", "--calibrate-seconds", "8", "--count", "5"])
    assert rc == 2
    assert "the sensor moved" in capsys.readouterr().err


def test_missing_bus_is_a_clear_error(capsys):
    rc = main(["imu", "--bus", "250", "--count", "1"])
    assert rc == 2
    assert "/dev/i2c-250" in capsys.readouterr().err
