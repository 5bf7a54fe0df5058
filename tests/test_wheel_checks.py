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
    "right negated": (lambda l, r: (l, -r), {"wheel_sign"}),
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
    if case.endswith("negated"):
        (w,) = [w for w in r.warnings if w.name == "wheel_sign"]
        assert f"the {case.split()[0]} one" in w.message
    if case == "16-bit totals":
        (w,) = [w for w in r.warnings if w.name == "wheel_totals"]
        assert "a 16-bit counter that wraps" in w.message


def test_per_period_counts_at_a_wrong_scale_are_not_called_totals(log, tmp_path):
    # speed_ratio written in mm (1000 times too large): the counts exceed max_speed like
    # running totals, but they return to 0 where the robot stops (a review's case)
    bad = _edited(log, tmp_path / "mm", lambda l, r: (l, r))
    toml = bad / "robot.toml"
    text = toml.read_text()
    ratio = float(text.split("speed_ratio = ")[1].split()[0])
    toml.write_text(text.replace(f"speed_ratio = {ratio!r}", f"speed_ratio = {ratio * 1e3!r}"))
    assert toml.read_text() != text
    names = {w.name for w in replay_logdir(bad, tmp_path / "out.csv").warnings}
    assert names & {"wheel_totals", "wheel_sign", "wheel_dead"} == set(), names
    assert "speed_scale" in names


def test_a_slow_scan_in_place_is_no_flipped_wheel(tmp_path):
    # a healthy robot turning in place at 2 deg/s for a minute, its gyro biased by 1 deg/s:
    # the wheels count opposite ways, and the gyro sees the turn they mean
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT
    from fusion.jobs.streams import Streams
    from fusion.jobs.wheel_checks import wheel_count_warnings
    from fusion.planar.robot import RobotConfig

    c = EXAMPLE_ROBOT
    w = np.radians(2.0)
    wheel_t = np.arange(c.encode_sampling_time, 60.0, c.encode_sampling_time)
    per = w * c.wheel_distance / 2.0 * c.encode_sampling_time / c.speed_ratio  # ticks
    ticks = np.column_stack([np.full(wheel_t.size, -per), np.full(wheel_t.size, per)])
    ticks = np.rint(ticks).astype(np.int64)
    assert np.all(np.abs(ticks) >= 2)
    imu_t = np.arange(0.0, 60.0, 0.01)
    gyro = np.column_stack([np.zeros(imu_t.size), np.zeros(imu_t.size),
                            np.full(imu_t.size, w + np.radians(1.0))])
    accel = np.tile([0.0, 0.0, 9.81], (imu_t.size, 1))
    streams = Streams(imu_t, gyro, accel, wheel_t, ticks)
    assert wheel_count_warnings(streams, RobotConfig(chassis=c)) == []


def test_swapped_wheels_are_not_blamed_on_the_gyro_alone(log, tmp_path):
    # the rates cannot tell which is flipped; the warning names both, and the accelerometer's
    # reading says the mount is not the cause
    r = replay_logdir(_edited(log, tmp_path / "swap", lambda l, r: (r, l)),
                      tmp_path / "out.csv")
    (w,) = [w for w in r.warnings if w.name == "gyro_axis"]
    assert "or the odometry (its left and right wheels swapped" in w.message
    assert "the accelerometer reads the IMU upright as configured, so not the mount" in (
        w.message)
