"""Log directories: exact round trip, robot.toml parsing, mount rotation, errors naming lines."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.errors import LogFormatError
from fusion.io.logdir import read_logdir, read_wheels_csv, write_logdir, write_synthetic_run
from fusion.io.robot_toml import read_robot_toml, write_robot_toml
from fusion.planar.robot import RobotConfig

ROBOT_TOML = """\
# a hand-written robot.toml
[chassis]
wheel_distance = 0.185        # m
speed_ratio = 0.000123        # m per tick
encode_sampling_time = 0.04   # s
cmd_vel_linear_max = 0.5
cmd_vel_angular_max = 2.0

[frames]
odom = "odom"
base = "base_link"
imu_mount_rpy = [3.141592653589793, 0.0, 0.0]

[ekf]
bias_psd = 4e-10
zupt_frames = 3
"""


def _logdir(tmp_path, toml=ROBOT_TOML, wheels="t,left,right\n0.04,1,2\n0.08,3,4\n"):
    d = tmp_path / "log"
    d.mkdir()
    (d / "robot.toml").write_text(toml)
    if wheels is not None:
        (d / "wheels.csv").write_text(wheels)
    return d


def test_synthetic_run_round_trips_exactly(tmp_path):
    run = degraded_mission(seed=2, duration=20.0)
    write_synthetic_run(tmp_path / "run", run)
    log = read_logdir(tmp_path / "run")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "imu.csv", "robot.toml", "truth.csv", "wheels.csv"]
    np.testing.assert_array_equal(log.imu_t, run.imu_t)
    np.testing.assert_array_equal(log.gyro, run.gyro)
    np.testing.assert_array_equal(log.accel, run.accel)
    np.testing.assert_array_equal(log.wheel_t, run.wheel_t)
    np.testing.assert_array_equal(log.ticks, run.ticks)
    np.testing.assert_array_equal(log.truth, run.truth)
    assert log.robot.chassis == EXAMPLE_ROBOT
    assert log.mag is None
    assert log.time_span == (0.0, pytest.approx(run.wheel_t[-1]))


def test_hand_written_robot_toml(tmp_path):
    d = _logdir(tmp_path)
    cfg = read_robot_toml(d / "robot.toml")
    assert cfg.chassis == DiffDriveParams(0.185, 0.000123, 0.04, 0.5, 2.0)
    assert cfg.base_frame == "base_link" and cfg.odom_frame == "odom"
    assert cfg.ekf.bias_psd == 4e-10 and cfg.ekf.zupt_frames == 3
    # and it survives a write/read cycle
    write_robot_toml(tmp_path / "again.toml", cfg)
    assert read_robot_toml(tmp_path / "again.toml") == cfg


def test_a_fusion_run_configuration_is_a_logs_robot_toml(tmp_path):
    # README's calibration recipe copies the robot's configuration into each log directory
    # (`cp robot.toml ccw/`); for `fusion run` that file also has [link] and [run], which an
    # independent probe's `fusion calibrate gyro-scale` refused as unknown tables
    d = _logdir(tmp_path)
    text = (d / "robot.toml").read_text()
    (d / "robot.toml").write_text(text + '\n[link]\nport = "/dev/ttyUSB0"\n\n'
                                  '[run]\nduration = 60\n')
    assert read_logdir(d).robot == read_robot_toml(_robot_only(tmp_path, text))
    # its run tables are still checked: a typo is named, not ignored
    (d / "robot.toml").write_text(text + '\n[link]\nprot = "/dev/ttyUSB0"\n')
    with pytest.raises(LogFormatError, match=r"robot\.toml:\d+: \[link\] unknown key 'prot'"):
        read_logdir(d)
    # and a table neither knows is refused as before
    (d / "robot.toml").write_text(text + "\n[wheels]\nleft = 1\n")
    with pytest.raises(LogFormatError, match=r"unknown table\(s\) \['wheels'\]"):
        read_logdir(d)


def _robot_only(tmp_path, text):
    path = tmp_path / "robot_only.toml"
    path.write_text(text)
    return path


def test_imu_mount_rotation_is_applied(tmp_path):
    # IMU mounted upside down (roll = pi about x): its y and z axes point right and down, so a
    # CCW yaw rate of the robot (+z in base) reads -z in the IMU, and gravity's reaction (+g up)
    # reads -g on the IMU's z. Reading must give base-frame vectors back.
    d = _logdir(tmp_path)
    (d / "imu.csv").write_text("t,gx,gy,gz,ax,ay,az\n0.0,0.1,0.2,-0.5,1.0,-2.0,-9.8\n"
                               "0.01,0.1,0.2,-0.5,1.0,-2.0,-9.8\n")
    log = read_logdir(d)
    np.testing.assert_allclose(log.gyro[0], [0.1, -0.2, 0.5], atol=1e-12)
    np.testing.assert_allclose(log.accel[0], [1.0, 2.0, 9.8], atol=1e-12)


def test_wheels_only_directory(tmp_path):
    log = read_logdir(_logdir(tmp_path))
    assert log.imu_t is None
    np.testing.assert_array_equal(log.ticks, [[1, 2], [3, 4]])
    assert log.ticks.dtype == np.int64


@pytest.mark.parametrize(
    ("wheels", "message"),
    [
        ("t,l,r\n0.04,1,2\n", ":1: header must be t,left,right"),
        ("t,left,right\n0.04,1,2\n0.08,1\n", ":3: expected 3 fields, got 2"),
        ("t,left,right\n0.04,1,2\n0.08,x,4\n", ":3: not a number: 'x'"),
        ("t,left,right\n0.04,1,2\n0.08,3,4\n0.08,5,6\n", ":4: time stamp 0.08 does not increase"),
        ("t,left,right\n0.04,1.5,2\n", ":2: ticks must be integers"),
        ("t,left,right\n0.04,1,2\n\n0.08,16777216,2\n", ":4: ticks [16777216.0, 2.0] exceed"),
        ("t,left,right\n0.04,nan,2\n", ":2: non-finite value"),
    ],
)
def test_bad_wheels_csv_names_file_and_line(tmp_path, wheels, message):
    d = _logdir(tmp_path, wheels=wheels)
    with pytest.raises(LogFormatError, match=r"wheels\.csv") as info:
        read_wheels_csv(d / "wheels.csv")
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ("[chassis]\nwheel_distance = 0.2\nspeed_ratio = 1e-4\n", "needs encode_sampling_time"),
        ("[chassis]\nwheel_distance = 0.2\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n"
         "wheel_distanse = 0.3\n", "unknown key(s) ['wheel_distanse']"),
        ("[chassis]\nwheel_distance = -0.2\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n",
         "wheel_distance must be finite and > 0"),
        ("[chassis]\nwheel_distance = '0.2'\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n",
         "must be a number"),
        ("[chasis]\n", "unknown table(s) ['chasis']"),
        ("[chassis\n", "invalid TOML"),
        ("[chassis]\nwheel_distance = 0.2\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n"
         "[frames]\nimu_mount_rpy = [0, 0]\n", "imu_mount_rpy must be [roll, pitch, yaw]"),
        ("[chassis]\nwheel_distance = 0.2\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n"
         "[ekf]\ngyro_sdt = 0.1\n", "[ekf] unknown key(s) ['gyro_sdt']"),
    ],
)
def test_bad_robot_toml_is_refused(tmp_path, toml, message):
    d = _logdir(tmp_path, toml=toml)
    with pytest.raises(LogFormatError, match=r"robot\.toml") as info:
        read_logdir(d)
    assert message in str(info.value)


def test_missing_pieces(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a directory"):
        read_logdir(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"robot\.toml"):
        read_logdir(tmp_path / "empty")
    d = _logdir(tmp_path, wheels=None)
    with pytest.raises(LogFormatError, match=r"no imu\.csv, wheels\.csv or wheels\.uart2"):
        read_logdir(d)


def test_write_refuses_fractional_ticks(tmp_path):
    with pytest.raises(ValueError, match="integers"):
        write_logdir(tmp_path / "x", EXAMPLE_ROBOT, wheel_t=[0.04], ticks=[[1.5, 2]])


def test_robot_config_mount_quaternion():
    cfg = RobotConfig(chassis=EXAMPLE_ROBOT, imu_mount_rpy=(0.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(cfg.imu_to_base(), [math.cos(math.pi / 4), 0, 0,
                                                   math.sin(math.pi / 4)], atol=1e-15)
