"""``fusion replay`` on a large log, as a real subprocess: ``--progress`` shows the loading of
imu.csv (seconds before the first replayed second), and SIGINT stops it with status 130 and a
message saying what was written and what was kept."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.io.logdir import write_logdir

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def big_log(tmp_path_factory) -> Path:
    """20 minutes at rest: 120,000 IMU rows (about 17 MB of imu.csv) and the wheel frames."""
    n = 120_000
    rng = np.random.default_rng(5)
    t = np.arange(n) * 0.01
    wheel_t = np.arange(1, n // 4) * 0.04
    return write_logdir(tmp_path_factory.mktemp("big") / "long", EXAMPLE_ROBOT, t,
                        rng.normal(0, 0.01, (n, 3)),
                        rng.normal(0, 0.05, (n, 3)) + np.array([0.0, 0.0, 9.81]), wheel_t,
                        np.zeros((wheel_t.size, 2), dtype=np.int64))


def _default_sigint() -> None:
    # A shell without job control starts background commands with SIGINT ignored, and the
    # child would inherit that (Python then installs no KeyboardInterrupt handler): give the
    # command Ctrl-C's default, as in a terminal, however pytest itself was started.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(*argv: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "fusion", "replay", *argv], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=_default_sigint)


def _read_until(stream, text: str) -> str:
    seen = ""
    while text not in seen:
        c = stream.read(1)
        if not c:
            break
        seen += c
    return seen


def test_progress_shows_the_loading_then_the_replay(big_log, tmp_path) -> None:
    proc = _start(str(big_log), "-o", str(tmp_path / "f.csv"), "--progress")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    load, replay = err.find("long: loading imu.csv"), err.find("long: ")
    assert load >= 0 and err.find("long: loading wheels.csv") > load
    assert replay == load  # nothing before the loading line
    assert "1200.0 s, 120000 IMU samples" in out


def test_sigint_says_what_was_kept(big_log, tmp_path) -> None:
    target = tmp_path / "f.csv"
    target.write_text("an earlier replay\n")
    plot = tmp_path / "p.png"
    proc = _start(str(big_log), "-o", str(target), "--plot", str(plot), "--progress")
    seen = _read_until(proc.stderr, "loading imu.csv")
    assert "loading imu.csv" in seen, seen
    proc.send_signal(signal.SIGINT)  # while it loads: nothing written yet
    _out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert "Traceback" not in err
    assert (f"fusion replay: interrupted: {target} left as it was (an existing file is only "
            "replaced by a complete one)") in err
    assert f"fusion replay: interrupted: {plot} not written (nothing partial left)" in err
    assert target.read_text() == "an earlier replay\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.csv"]  # no temporary left
    assert not plot.exists()
