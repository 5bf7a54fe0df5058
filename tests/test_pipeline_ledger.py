"""The pipeline's ledger on a run with faults the estimator must flag: the independent physics
simulator's dead encoder feed (zero ticks on both wheels for 8 s while the robot drives).
Every event handed in is fused or counted under a reason: encoder-fault frames are counted,
not silently skipped."""

from __future__ import annotations

import pytest

from fusion.evaluation.physics_sim import physics_scenario
from fusion.pipeline.core import DROP_REASONS, FusionPipeline


@pytest.fixture(scope="module")
def dead_feed():
    return physics_scenario("all+dead", seed=3, duration=90.0)


def test_encoder_faults_are_counted_in_the_ledger(dead_feed):
    run = dead_feed
    (t0, length), = run.dead_windows()
    with FusionPipeline(run.robot, []) as pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    ledger = pipe.ledger()
    assert set(ledger["dropped"]) == set(DROP_REASONS)
    assert ledger["in"] == run.imu_t.size + run.wheel_t.size
    assert ledger["unaccounted"] == 0
    assert ledger["held"] == 0
    # most frames of the dead window (25 Hz wheels) are flagged and counted, not fused
    dead_frames = int(((run.wheel_t > t0) & (run.wheel_t < t0 + length)).sum())
    assert dead_frames > 150
    assert 0.8 * dead_frames <= ledger["dropped"]["encoder_fault"] <= dead_frames + 5
    assert ledger["fused"] == ledger["in"] - sum(ledger["dropped"].values())
