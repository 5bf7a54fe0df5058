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
