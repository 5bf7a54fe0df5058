"""Single- and two-frame wheel count glitches (EMI, a counter read once wrong): found, left out
of a replay and said; nothing else is ever taken for one (slip, a dead feed, hard stops)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.evaluation.physics_sim import physics_scenario
from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.io.logdir import write_synthetic_run
from fusion.jobs.replay import fuse_streams, replay_logdir
from fusion.jobs.streams import Streams
from fusion.jobs.wheel_glitches import MAX_WHEEL_ACCEL, glitch_frames
from fusion.planar.robot import RobotConfig

T = EXAMPLE_ROBOT.encode_sampling_time
RATIO = EXAMPLE_ROBOT.speed_ratio


@pytest.mark.parametrize("seed", range(6))
def test_nothing_real_is_a_glitch_on_the_kinematic_simulator(seed):
    # slip patches (a wheel over-counting by 30 % for seconds), lost frames, stamp jitter
    run = degraded_mission(seed=seed, duration=300.0)
    assert not glitch_frames(run.wheel_t, run.ticks, RATIO, T).any()


@pytest.mark.parametrize("seed", range(3))
def test_nothing_real_is_a_glitch_on_the_physics_simulator(seed):
    # traction-limited slip, a dead encoder feed of 8 s while driving (ticks to 0 and back)
    run = physics_scenario("all+dead", seed=seed, duration=120.0, dead_encoder=8.0)
    chassis = run.robot.chassis
    assert not glitch_frames(run.wheel_t, run.ticks, chassis.speed_ratio,
                             chassis.encode_sampling_time).any()


def _steady(n=40, ticks=200):
    return np.arange(1, n + 1) * T, np.full((n, 2), ticks, dtype=np.int64)


def test_spikes_and_a_counter_read_once_wrong_are_found():
    t, ticks = _steady()
    ticks[10, 0] += 4096  # one bit
    ticks[20, 1] += 3000  # a count read 3000 high: this frame high, the next as much low
    ticks[21, 1] -= 3000
    assert np.flatnonzero(glitch_frames(t, ticks, RATIO, T)).tolist() == [10, 20, 21]


def test_what_a_wheel_can_do_is_never_a_glitch():
    per_frame = MAX_WHEEL_ACCEL * T * T / RATIO  # ticks: the largest change in one period
    t, ticks = _steady()
    ticks[10:15, :] = 0  # a hard stop from 0.5 m/s within one frame, and off again
    ticks[30, 0] = 200 + per_frame * 0.9  # a jolt just inside what a wheel can do
    ticks[5:8, 1] += 5000  # three frames away: the wheel's own motion, however unlikely
    assert not glitch_frames(t, ticks, RATIO, T).any()
    # the jolt beyond it is one; across a gap of lost frames more is allowed
    ticks[30, 0] = 200 + per_frame * 1.5 + 4
    assert np.flatnonzero(glitch_frames(t, ticks, RATIO, T)).tolist() == [30]
    gap = t.copy()
    gap[30:] += 2 * T  # two frames lost before it: three periods to change in
    assert not glitch_frames(gap, ticks, RATIO, T).any()


def test_a_replay_leaves_glitches_out_and_says_where(tmp_path):
    run = degraded_mission(seed=1, duration=150.0)
    clean = write_synthetic_run(tmp_path / "clean", run)
    moving = np.flatnonzero(np.abs(run.ticks).min(axis=1) > 20)
    hit = moving[[100, 900, 1800]]
    bad_ticks = run.ticks.copy()
    bad_ticks[hit, 0] += 4096 * np.array([1, 2, 4])
    pair = moving[2500]
    bad_ticks[pair, 1] += 2500
    bad_ticks[pair + 1, 1] -= 2500
    bad = tmp_path / "glitchy"
    write_synthetic_run(bad, run)
    lines = (bad / "wheels.csv").read_text().splitlines()
    for k in [*hit, pair, pair + 1]:
        stamp = lines[k + 1].split(",")[0]
        lines[k + 1] = f"{stamp},{bad_ticks[k, 0]},{bad_ticks[k, 1]}"
    (bad / "wheels.csv").write_text("\n".join(lines) + "\n")
    # fused as they are, the glitches turn the wheels' heading by hundreds of degrees, and
    # the trust checks call a good track untrustworthy
    raw = Streams(run.imu_t, run.gyro, run.accel, run.wheel_t, bad_ticks)
    as_they_are = fuse_streams(RobotConfig(chassis=EXAMPLE_ROBOT), raw, None)[3]
    assert [w.name for w in as_they_are] == ["heading_divergence"]
    ref = replay_logdir(clean, tmp_path / "clean.csv")
    res = replay_logdir(bad, tmp_path / "bad.csv")
    lines_named = ", ".join(str(k + 2) for k in sorted([*hit, pair, pair + 1]))
    assert any(n.startswith("5 wheel frame(s) left out as glitches") and
               f"wheels.csv line(s) {lines_named}" in n for n in res.notes), res.notes
    assert [w.name for w in res.warnings] == [w.name for w in ref.warnings]
    # five frames' ticks lost (about 5 cm over 150 s), nothing else changed
    assert np.hypot(res.final[0] - ref.final[0], res.final[1] - ref.final[1]) < 0.1
    assert res.truth["fused_pct"] == pytest.approx(ref.truth["fused_pct"], abs=0.1)
    # the printed wheel-only figure is the wheels' own, less five frames (their turns bend
    # it by 0.6 %), not the glitches' (dead-reckoned with them it ends 46 m from the truth)
    assert res.truth["wheel_pct"] == pytest.approx(ref.truth["wheel_pct"], abs=1.0)


def _glitchy_log(tmp_path, blank_rows=()):
    """degraded_mission seed 1 (150 s) as a log directory with three single-frame glitches
    (+4096, +8192, +16384 ticks on the left wheel while driving) and rows without values
    inserted before the given frames; returns (run, log dir, glitch frames, their lines)."""
    run = degraded_mission(seed=1, duration=150.0)
    d = write_synthetic_run(tmp_path / "glitchy", run)
    moving = np.flatnonzero(np.abs(run.ticks).min(axis=1) > 20)
    hit = moving[[100, 900, 1800]]
    lines = (d / "wheels.csv").read_text().splitlines()
    for k, extra in zip(hit, (4096, 8192, 16384), strict=True):
        stamp, left, right = lines[k + 1].split(",")
        lines[k + 1] = f"{stamp},{int(left) + extra},{right}"
    for k in sorted(blank_rows, reverse=True):
        lines.insert(k + 1, ",,")
    (d / "wheels.csv").write_text("\n".join(lines) + "\n")
    named = [k + 2 + sum(b <= k for b in blank_rows) for k in hit]
    return run, d, hit, named


def test_the_note_names_the_lines_past_rows_without_values(tmp_path):
    _, d, _, named = _glitchy_log(tmp_path, blank_rows=(5, 50))
    res = replay_logdir(d, tmp_path / "f.csv")
    (note,) = [n for n in res.notes if "left out as glitches" in n]
    assert f"wheels.csv line(s) {', '.join(map(str, named))}" in note, note
    lines = (d / "wheels.csv").read_text().splitlines()
    assert all(int(lines[n - 1].split(",")[1]) > 4000 for n in named)


def test_the_odometry_calibration_leaves_glitches_out_too(tmp_path, capsys):
    # --distance sums every frame's ticks: three glitches took speed_ratio 3.5 % off
    from fusion.cli import main

    run, d, _, named = _glitchy_log(tmp_path)
    true_path = float(np.sum(np.hypot(*np.diff(run.truth[:, :2], axis=0).T)))
    assert main(["calibrate", "odometry", str(d), "--distance", f"{true_path:.4f}"]) == 0
    out = capsys.readouterr().out
    assert f"wheels.csv line(s) {', '.join(map(str, named))}" in out
    true_mean = 0.5 * (run.true_left_ratio + run.true_right_ratio)
    speed_ratio = float(next(ln for ln in out.splitlines() if ln.startswith("speed_ratio = "))
                        .split("=")[1].split("#")[0])
    assert speed_ratio == pytest.approx(true_mean, rel=0.005)
