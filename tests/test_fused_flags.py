"""Per-record EKF flags (ZUPT, slip, encoder fault) in the fused CSV and the JSON lines output;
older fused CSVs without the flag columns still read; epoch stamps keep every distinct value.

Oracles: the EKF's own status codes of the same run (fusion.planar.ekf.fuse), the physics
simulator's dead-encoder window, and the stamps written into the log.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from fusion.evaluation.physics_sim import physics_scenario
from fusion.io.fused_csv import FUSED_CSV_COLUMNS, read_fused_csv
from fusion.io.logdir import write_logdir
from fusion.jobs.replay import replay_logdir
from fusion.pipeline import FusionPipeline
from fusion.sinks.text import JsonLinesSink


@pytest.fixture(scope="module")
def dead():
    """60 s of the physics simulator with every error and a dead encoder feed while driving,
    on epoch stamps (1.7e9 s: a float's resolution there is 0.24 us)."""
    run = physics_scenario("all+dead", seed=11, duration=60.0)
    return run, 1.7e9


def test_replay_csv_flags_and_epoch_stamps(dead, tmp_path):
    run, epoch = dead
    d = write_logdir(tmp_path / "log", run.robot.chassis, run.imu_t + epoch, run.gyro,
                     run.accel, run.wheel_t + epoch, run.ticks)
    out = tmp_path / "fused.csv"
    result = replay_logdir(d, out, tilt=False)
    with open(out) as fh:
        assert tuple(fh.readline().strip().split(",")) == FUSED_CSV_COLUMNS
    f = read_fused_csv(out)
    # every IMU stamp comes back exactly: distinct stamps all kept
    np.testing.assert_array_equal(f["t"], run.imu_t + epoch)
    assert np.unique(f["t"]).size == run.imu_t.size
    for name in ("zupt", "slip", "encoder_fault"):
        assert set(np.unique(f[name]).tolist()) <= {0.0, 1.0}
    (t0, length), = run.dead_windows()
    t = f["t"] - epoch
    inside = (t > t0 + 0.3) & (t < t0 + length)
    moving = (np.abs(np.interp(t, run.truth_t, run.truth_v)) > 0.05) | (
        np.abs(np.interp(t, run.truth_t, run.truth_w)) > 0.05)
    assert (inside & moving).sum() > 500
    assert f["encoder_fault"][inside & moving].mean() > 0.95
    assert f["encoder_fault"][~inside & (t > 1.0)].mean() < 0.02
    assert f["zupt"][inside].sum() == 0 and f["zupt"].sum() > 0
    assert result.stats["encoder_faults"] >= 0.95 * round(length / run.robot.chassis
                                                         .encode_sampling_time)


def test_json_lines_carry_the_flags(dead):
    run, _ = dead
    buf = io.StringIO()
    pipe = FusionPipeline(run.robot, [JsonLinesSink(buf, flush=False)], tilt=False)
    with pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    recs = [json.loads(line) for line in buf.getvalue().splitlines()]
    assert len(recs) == run.wheel_t.size
    faults = np.array([r["encoder_fault"] for r in recs])
    assert all(isinstance(r["zupt"], bool) and isinstance(r["slip"], bool) for r in recs)
    assert faults.sum() == pipe.finish_stats().encoder_faults > 0
    assert sum(r["zupt"] for r in recs) == pipe.stats.zupts


def test_an_old_fused_csv_without_flags_still_reads(tmp_path):
    old = FUSED_CSV_COLUMNS[:19]
    p = tmp_path / "old.csv"
    p.write_text(",".join(old) + "\n" + ",".join(["1700000000.125"] + ["0.5"] * 18) + "\n")
    f = read_fused_csv(p)
    assert f["t"][0] == 1700000000.125 and f["wheel_right_speed"][0] == 0.5
    assert np.isnan(f["zupt"][0]) and np.isnan(f["encoder_fault"][0])
