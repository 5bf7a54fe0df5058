"""The fifth, independent simulator (benchmarks/sim5, written by an outside tester from the
README and LOGDIR.md only) replayed as a user would: its EMI glitch frames are exactly the
frames the replay leaves out, its 8 s dead encoder feed is said where the simulator put it,
and neither raises a trust warning on a track that is fine (12 of its 32 runs had ended in
"should not be trusted" before). Its own metadata is the reference."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

from fusion.jobs.replay import replay_logdir

SIM5 = Path(__file__).resolve().parent.parent / "benchmarks" / "sim5"


@pytest.fixture(scope="module")
def sim5():
    """benchmarks/sim5/sim.py as a module of its own name (benchmarks/blackbox has a sim.py
    too, which tests import by its bare name)."""
    spec = importlib.util.spec_from_file_location("sim5_sim", SIM5 / "sim.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(sim5, tmp_path, scenario, seed):
    sim5.write_run(str(tmp_path), scenario, seed, 120.0)
    meta = json.loads((tmp_path / "sim_meta.json").read_text())
    return meta, replay_logdir(tmp_path / "log", tmp_path / "fused.csv")


def test_its_glitch_frames_are_left_out_and_nothing_else(sim5, tmp_path):
    meta, res = _run(sim5, tmp_path, "glitch", 1)
    glitches = np.array([g[0] for g in meta["encoders"]["glitches"]])
    assert glitches.size >= 5
    (note,) = [n for n in res.notes if "left out as glitches" in n]
    assert note.startswith(f"{glitches.size} wheel frame(s) left out as glitches")
    lines = [int(x) for x in re.search(r"line\(s\) ([\d, ]+)", note)[1].split(", ")]
    rows = (tmp_path / "log" / "wheels.csv").read_text().splitlines()
    named = np.array([float(rows[n - 1].split(",")[0]) for n in lines])
    # the simulator records each glitch frame's stamp; the note lists the first five
    np.testing.assert_allclose(named, np.sort(glitches)[:len(named)], rtol=0, atol=1e-6)
    assert res.warnings == []


def test_its_dead_feed_is_said_where_it_was(sim5, tmp_path):
    meta, res = _run(sim5, tmp_path, "dead", 2)
    start, end = meta["encoders"]["dead"]
    (note,) = [n for n in res.notes if "read zero while the IMU showed the robot moving" in n]
    said = re.search(r": ([\d.]+) s from t = ([\d.]+) s", note)
    assert float(said[1]) == pytest.approx(end - start, abs=0.1)
    assert float(said[2]) == pytest.approx(start, abs=0.1)
    assert "heading_divergence" not in [w.name for w in res.warnings]


def test_a_warming_gyro_is_fused_with_the_walk_its_stops_show(sim5, tmp_path):
    # Seed 11 of 'all' (every error on, 300 s): the gyro's bias rises by 0.66 deg/s over the
    # run (warm-up and temperature), between stops by up to 0.28 deg/s, where bias_psd's
    # walk allows 0.07. The stops say so (fusion.jobs.bias_walk), and the log is fused again
    # with the walk they fit: yaw RMSE 3.75 -> 3.11 deg against the truth (the final position
    # 0.73 -> 1.05 % of the distance); the one-pass replay (as live) only says it. The
    # simulator's seed 11 was first run while this was built (the stops' variance floor,
    # STOP_BIAS_STD, went from 0.02 to the 0.01 deg/s after its moving start had
    # not been caught): in-sample for that choice.
    sim5.write_run(str(tmp_path), "all", 11, 300.0)
    fused = replay_logdir(tmp_path / "log", tmp_path / "fused.csv")
    live = replay_logdir(tmp_path / "log", tmp_path / "live.csv", one_pass=True)
    # it starts at rest: no moving-start pass, so the one-pass replay differs by the walk alone
    assert fused.moving_start is None and live.moving_start is None
    (note,) = [n for n in fused.notes if "bias moved between stops" in n]
    assert "fused again" in note
    psd = float(re.search(r"fit best is bias_psd = ([\d.e+-]+)", note)[1])
    assert psd > 5e-8  # the configured walk is 1e-8
    (said,) = [n for n in live.notes if "bias moved between stops" in n]
    assert "a live run would follow it" in said
    assert fused.truth["fused_yaw_deg"] < live.truth["fused_yaw_deg"] - 0.4, (
        fused.truth, live.truth)


def test_a_moving_start_on_a_warming_gyro_learns_the_bias_from_the_straight_driving(sim5,
                                                                                   tmp_path):
    # Seed 7 of 'moving' (300 s): the robot drives off at once and first stops 82 s later,
    # while its gyro warms up by 0.38 deg/s. The second pass starts from the first stop's
    # bias; it also takes the wheels' yaw-rate calibration the first pass ended with
    # (fusion.jobs.moving_start.wheel_prior). Without it the radius mismatch state soaked up
    # the bias's error on the straight stretches (the bias stayed within 0.07 deg/s of the
    # stop's: 0.24, 0.15 and 0.08 deg/s off the truth at 20, 40 and 60 s, and the heading
    # was 13.5 deg off at the stop). Oracle:
    # the simulator's true bias about the vertical and its true heading. In-sample: this seed
    # was the case the change was made for; held-out figures are in the module's docstring.
    sim5.write_run(str(tmp_path), "moving", 7, 300.0)
    res = replay_logdir(tmp_path / "log", tmp_path / "fused.csv")
    assert res.moving_start is not None and res.moving_start.wheels is not None
    assert "with the wheels' yaw-rate scale" in res.moving_start.note
    aux = np.load(tmp_path / "sim_aux.npz")
    fused = np.genfromtxt(tmp_path / "fused.csv", delimiter=",", names=True)
    truth = np.genfromtxt(tmp_path / "log" / "truth.csv", delimiter=",", names=True)
    t0 = fused["t"][0]
    at = np.searchsorted(fused["t"], t0 + np.array([20.0, 40.0, 60.0]))
    true_bias = np.interp(fused["t"][at], aux["imu_t"], aux["bias_z_true"])
    off = np.degrees(np.abs(fused["gyro_bias_z"][at] - true_bias))
    assert np.all(off < [0.12, 0.05, 0.05]), off   # measured 0.10, 0.01, 0.02
    stop = res.moving_start.stop_begin
    i = int(np.searchsorted(fused["t"], stop))
    yaw_true = np.interp(fused["t"][i], truth["t"], np.unwrap(truth["yaw"]))
    heading = np.degrees(abs(np.angle(np.exp(1j * (fused["yaw"][i] - yaw_true)))))
    assert heading < 10.0, heading   # measured 8.8 deg (13.5 before)
