"""A dead encoder feed while driving (the physics simulator's 8 s of zero ticks, written by
``fusion synth`` as a user's log): the replay says when and for how long, and the turn the
EKF counts over it (``fault_turn``, left out of the trust checks' heading comparison) is the
simulator's true turn over the window, within the gyro's scale error."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from fusion.cli import main
from fusion.evaluation.physics_sim import physics_scenario
from fusion.jobs.replay import replay_logdir

DURATION = 90.0


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_a_dead_feed_is_said_where_and_for_how_long(tmp_path, seed):
    run = physics_scenario("all+dead", seed=seed, duration=DURATION, dead_encoder=8.0)
    ((start, length),) = run.dead_windows()
    log = tmp_path / "log"
    assert main(["synth", str(log), "--simulator", "physics", "--seed", str(seed),
                 "--duration", str(DURATION), "--dead-encoder", "8"]) == 0
    res = replay_logdir(log, tmp_path / "fused.csv")
    (note,) = [n for n in res.notes if "read zero while the IMU showed the robot moving" in n]
    said = re.search(r": ([\d.]+) s from t = ([\d.]+) s", note)
    assert float(said[1]) == pytest.approx(length, abs=0.1)
    assert float(said[2]) == pytest.approx(start, abs=0.1)
    # the truth's turn over the window (seeds 0 1 3: -72.2, -80.8, +2.0 deg; counted -70.6,
    # -79.9, +2.0): the gyro's scale error (0.5-2 %) and a frame at either end
    yaw = run.truth_at(np.array([start, start + length]))[:, 2]
    turn = math.degrees(yaw[1] - yaw[0])
    assert math.degrees(res.stats["fault_turn"]) == pytest.approx(turn, abs=0.03 * abs(turn) + 1)
    assert "heading_divergence" not in [w.name for w in res.warnings]


def test_no_dead_feed_is_said_where_there_is_none(tmp_path):
    log = tmp_path / "log"
    assert main(["synth", str(log), "--simulator", "physics", "--seed", "0", "--duration",
                 str(DURATION)]) == 0
    res = replay_logdir(log, tmp_path / "fused.csv")
    assert not [n for n in res.notes if "read zero while the IMU" in n]
    # a few frames at hard stops may read as faults (measured 0.2 deg of turn in all)
    assert abs(math.degrees(res.stats["fault_turn"])) < 1.0
