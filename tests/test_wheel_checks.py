"""Wheel counts that cannot be one period's ticks of two working encoders are named
(fusion.jobs.wheel_checks), on a synthetic log rewritten the ways an independent probe wrote its
wheels.csv: an unplugged left encoder, a mirrored left motor, running totals (also of a 16-bit
counter), left and right swapped. Each had been fused and blamed on something else."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.evaluation.synthetic import degraded_mission
from fusion.io.logdir import write_synthetic_run
from fusion.jobs.replay import replay_logdir


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_synthetic_run(tmp_path_factory.mktemp("wheels") / "run",
                               degraded_mission(seed=5, duration=90.0))


def _edited(log, dest, edit):
    dest.mkdir()
    for f in log.iterdir():
        (dest / f.name).write_bytes(f.read_bytes())
    data = np.loadtxt(log / "wheels.csv", delimiter=",", skiprows=1)
    t, left, right = data[:, 0], data[:, 1].astype(np.int64), data[:, 2].astype(np.int64)
    left, right = edit(left, right)
    rows = [f"{float(a)!r},{int(b)},{int(c)}" for a, b, c in zip(t, left, right)]
    (dest / "wheels.csv").write_text("\n".join(["t,left,right", *rows]) + "\n")
    return dest


CASES = {
    "untouched": (lambda l, r: (l, r), set()),
    "left dead": (lambda l, r: (0 * l, r), {"wheel_dead"}),
    "left negated": (lambda l, r: (-l, r), {"wheel_sign"}),
    "running totals": (lambda l, r: (np.cumsum(l) + 40000, np.cumsum(r) + 40000),
                       {"wheel_totals"}),
    "16-bit totals": (lambda l, r: ((np.cumsum(l) + 65000) % 65536,
                                    (np.cumsum(r) + 65000) % 65536), {"wheel_totals"}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_each_wheel_mistake_is_named_and_only_it(log, tmp_path, case):
    edit, expected = CASES[case]
    r = replay_logdir(_edited(log, tmp_path / "x", edit), tmp_path / "out.csv")
    names = {w.name for w in r.warnings}
    assert names & {"wheel_dead", "wheel_sign", "wheel_totals"} == expected, names
    if case == "16-bit totals":
        (w,) = [w for w in r.warnings if w.name == "wheel_totals"]
        assert "a 16-bit counter that wraps" in w.message


def test_swapped_wheels_are_not_blamed_on_the_gyro_alone(log, tmp_path):
    # the rates cannot tell which is flipped; the warning names both, and the accelerometer's
    # reading says the mount is not the cause
    r = replay_logdir(_edited(log, tmp_path / "swap", lambda l, r: (r, l)),
                      tmp_path / "out.csv")
    (w,) = [w for w in r.warnings if w.name == "gyro_axis"]
    assert "or the odometry (its left and right wheels swapped" in w.message
    assert "the accelerometer reads the IMU upright as configured, so not the mount" in (
        w.message)
