"""``fusion synth --scenario turns`` and ``fusion calibrate gyro-scale``: the owner's workflow
from a calibration run to a replay with the calibrated robot.toml, against the simulator's
ground truth."""

from __future__ import annotations

import re

import pytest

from fusion.cli import main
from fusion.evaluation.physics_sim import all_errors
from fusion.io.robot_toml import read_robot_toml


def test_calibrate_then_replay_meets_the_targets(tmp_path, capsys):
    cw, ccw, run = tmp_path / "cw", tmp_path / "ccw", tmp_path / "run"
    assert main(["synth", str(ccw), "--simulator", "physics", "--scenario", "turns",
                 "--seed", "3"]) == 0
    assert main(["synth", str(cw), "--simulator", "physics", "--scenario", "turns",
                 "--turns", "-10", "--seed", "3"]) == 0
    assert main(["synth", str(run), "--simulator", "physics", "--seed", "3"]) == 0
    capsys.readouterr()
    toml = tmp_path / "robot.toml"
    assert main(["calibrate", "gyro-scale", str(ccw), str(cw), "--turns", "10", "-10",
                 "--write", str(toml)]) == 0
    out = capsys.readouterr().out
    assert "combined (2 runs)" in out and "gyro_scale = " in out
    robot = read_robot_toml(toml)
    true_z = all_errors(3).gyro_scale[2]
    assert abs(robot.ekf.gyro_scale - true_z) < 1e-3
    assert 0 < robot.ekf.gyro_scale_std < 5e-4
    assert robot.chassis == read_robot_toml(run / "robot.toml").chassis

    def replay(extra):
        assert main(["replay", str(run), "-o", str(tmp_path / "out.csv"), *extra]) == 0
        text = capsys.readouterr().out
        m = re.search(r"fused: +final position error ([\d.]+) % of distance, yaw RMSE "
                      r"([\d.]+) deg", text)
        return float(m.group(1)), float(m.group(2))

    raw = replay([])
    calibrated = replay(["--robot", str(toml)])
    # issue 11's targets hold with the calibration; the uncalibrated run misses them by far
    assert calibrated[0] <= 0.5 and calibrated[1] <= 1.5, calibrated
    assert raw[1] > 2 * calibrated[1], (raw, calibrated)


def test_bad_invocations_say_what_to_fix(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "gyro-scale", str(tmp_path), "--turns"])
    assert main(["calibrate", "gyro-scale", str(tmp_path / "a"), str(tmp_path / "b"),
                 "--turns", "10"]) != 0
    assert "one --turns per log directory" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "k"), "--scenario", "turns"]) != 0
    assert "--scenario turns needs --simulator physics" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "m"), "--simulator", "physics", "--turns", "3"]) != 0
    assert "--turns applies to --scenario turns only" in capsys.readouterr().err


def _write_turns_log(folder, turns=3, nan_row=None):
    """A log directory of ``turns`` in place (rest, 1 rad/s, rest) at 200 Hz, with zero-tick
    wheel frames throughout (the wheels are not what is calibrated here)."""
    import math

    import numpy as np

    folder.mkdir()
    (folder / "robot.toml").write_text("[chassis]\nwheel_distance = 0.2\nspeed_ratio = 1e-4\n"
                                       "encode_sampling_time = 0.04\n")
    spin = 2 * math.pi * abs(turns)
    t = np.arange(0.0, 10.0 + spin, 0.005)
    gz = np.where((t >= 5.0) & (t < 5.0 + spin), math.copysign(1.0, turns), 0.0)
    rows = [f"{ti:.4f},0,0,{g:.6f},0,0,9.80665" for ti, g in zip(t, gz, strict=True)]
    if nan_row is not None:
        rows[nan_row] = rows[nan_row].replace(",0,0,", ",nan,0,", 1)
    (folder / "imu.csv").write_text("t,gx,gy,gz,ax,ay,az\n" + "\n".join(rows) + "\n")


def test_a_nan_row_is_named_by_file_and_line(tmp_path, capsys):
    _write_turns_log(tmp_path / "ccw", nan_row=1000)
    assert main(["calibrate", "gyro-scale", str(tmp_path / "ccw"), "--turns", "3"]) != 0
    err = capsys.readouterr().err
    assert f"{tmp_path / 'ccw' / 'imu.csv'}:1002: not a finite number (1 such rows)" in err


def test_the_same_run_given_twice_is_refused(tmp_path, capsys):
    _write_turns_log(tmp_path / "ccw")
    assert main(["calibrate", "gyro-scale", str(tmp_path / "ccw"),
                 str(tmp_path / "x" / ".." / "ccw"), "--turns", "3", "3"]) != 0
    assert "given twice" in capsys.readouterr().err
    assert main(["calibrate", "gyro-scale", str(tmp_path / "ccw"), "--turns", "3"]) == 0
