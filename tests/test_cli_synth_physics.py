"""``fusion synth --simulator physics``: writes a log directory the readers and replay accept."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.cli import main
from fusion.evaluation.physics_sim import (
    ERROR_GROUPS,
    indoor_mission,
    simulate_physics,
    with_errors,
)
from fusion.io.logdir import read_logdir


def test_help_names_every_error(capsys):
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    text = "".join(capsys.readouterr().out.split())  # argparse wraps lines at hyphens
    for name in (*ERROR_GROUPS, "low-friction"):
        assert name in text, name


def test_physics_run_written_and_read_back(tmp_path, capsys):
    d = tmp_path / "run"
    assert main(["synth", str(d), "--simulator", "physics", "--seed", "2", "--duration", "40",
                 "--without", "vibration", "--dead-encoder", "3"]) == 0
    out = capsys.readouterr().out
    assert "physics" in out and "dead encoder: " in out
    log = read_logdir(d)
    names = sorted(set(ERROR_GROUPS) - {"vibration"})
    mission = indoor_mission(2, 40.0, low_friction=True)
    run = simulate_physics(mission, with_errors(names, seed=2), 2, dead_encoder_while_driving=3.0)
    # robot.toml holds the nominal geometry, not the true one
    assert log.robot.chassis == run.robot.chassis
    assert log.robot.chassis.wheel_distance != pytest.approx(run.trace.wheel_distance)
    assert np.array_equal(log.imu_t, run.imu_t) and np.array_equal(log.gyro, run.gyro)
    assert np.array_equal(log.ticks, run.ticks) and np.array_equal(log.wheel_t, run.wheel_t)
    assert np.array_equal(log.truth, run.truth[::5]) and np.array_equal(log.truth_t,
                                                                         run.truth_t[::5])
    assert main(["replay", str(d), "-o", str(tmp_path / "fused.csv")]) == 0


def test_bad_physics_options(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "a"), "--simulator", "physics", "--with",
                 "gyro-scael"]) == 2
    assert "gyro-scale" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "b"), "--simulator", "physics", "--scenario",
                 "square"]) == 2
