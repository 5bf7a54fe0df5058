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
from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.io.fused_csv import FUSED_CSV_COLUMNS
from fusion.io.logdir import write_logdir
from fusion.jobs.dead_feed import dead_feed_notes
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


PERIOD = 0.01  # s: a 100 Hz wheel firmware


def _table(rate_hz, flagged_from, flagged_to, end=60.0):
    """Fused rows at ``rate_hz`` whose encoder_fault flag is set over [from, to) s (a row
    carries the flag of the last frame before it)."""
    table = np.zeros((int(end * rate_hz), len(FUSED_CSV_COLUMNS)))
    table[:, 0] = np.arange(table.shape[0]) / rate_hz
    t = table[:, 0]
    table[(t >= flagged_from) & (t < flagged_to), FUSED_CSV_COLUMNS.index("encoder_fault")] = 1
    return table


def test_the_stretch_is_made_of_frames_not_of_rows():
    frames = np.arange(1, 6001) * PERIOD
    zero = (frames > 20.0) & (frames <= 28.0)
    # fused rows at 40 Hz, slower than the frames: still one 8 s stretch
    (note,) = dead_feed_notes(frames, zero, _table(40.0, 20.0, 28.0), PERIOD, "wheel frames")
    assert ": 8.0 s from t = 20.000 s" in note
    # five zero frames, then no frame for 20 s: the rows keep the flag, the frames do not
    gap = (frames <= 20.05) | (frames > 40.0)
    assert dead_feed_notes(frames[gap], (zero & gap)[gap], _table(200.0, 20.0, 40.0), PERIOD,
                           "wheel frames") == []
    # zero frames the EKF did not flag (a stop) are no dead feed
    assert dead_feed_notes(frames, zero, _table(200.0, 0.0, 0.0), PERIOD, "x") == []


def test_short_dead_stretches_are_counted_where_they_add_up():
    frames = np.arange(1, 6001) * PERIOD
    starts = np.arange(5.0, 55.0, 8.0)  # 0.6 s each, 7 of them: 4.2 s in all
    zero = np.any([(frames > s) & (frames <= s + 0.6) for s in starts], axis=0)
    table = _table(200.0, 0.0, 0.0)
    for s in starts:
        table[(table[:, 0] > s) & (table[:, 0] <= s + 0.6), FUSED_CSV_COLUMNS.index(
            "encoder_fault")] = 1
    (note,) = dead_feed_notes(frames, zero, table, PERIOD, "wheel frames")
    assert ": 7 shorter one(s), 4.2 s in all;" in note
    # one alone is a few frames the EKF rides through: nothing said
    one = zero & (frames < 10.0)
    assert dead_feed_notes(frames, one, table, PERIOD, "wheel frames") == []


def test_without_an_imu_a_hard_stop_is_not_called_a_dead_feed(tmp_path):
    # wheels only, 3.5 m/s, stopped dead within one frame: the EKF takes the first zero frames
    # for faults until braking fits stop_decel, but no IMU showed anything
    robot = EXAMPLE_ROBOT
    period = robot.encode_sampling_time
    n = 500
    per_frame = round(3.5 * period / robot.speed_ratio)
    ramp = np.minimum(np.arange(n) * 40, per_frame)
    ticks = np.column_stack([ramp, ramp]).astype(np.int64)
    ticks[300:] = 0
    write_logdir(tmp_path / "log", robot, wheel_t=np.arange(1, n + 1) * period, ticks=ticks)
    res = replay_logdir(tmp_path / "log", tmp_path / "fused.csv")
    assert res.stats["encoder_faults"] > 0
    assert not [n for n in res.notes if "read zero" in n]
