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
