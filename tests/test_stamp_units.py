"""Times in s and a wheel period that fits the frames (fusion.io.stamp_units), on log
directories written the way an independent probe wrote its mistakes: imu.csv in ms, us and ns
(refused with a rate of 0.1 Hz and no file named, or a MemoryError in the fusion),
encode_sampling_time in ms (fused 1000 times too slow, silently), wheels.csv in ms.
"""

from __future__ import annotations

import numpy as np
import pytest

from fusion.cli import main
from fusion.evaluation.synthetic import degraded_mission
from fusion.io.errors import LogFormatError
from fusion.io.logdir import read_logdir, write_synthetic_run
from fusion.io.stamp_units import check_imu_stamps, check_wheel_stamps


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_synthetic_run(tmp_path_factory.mktemp("units") / "run",
                               degraded_mission(seed=3, duration=20.0))


def _scaled(src, dest, name: str, factor: float):
    """A copy of the log directory ``src`` with column t of ``name`` times ``factor``."""
    dest.mkdir()
    for f in src.iterdir():
        (dest / f.name).write_bytes(f.read_bytes())
    head, *rows = (src / name).read_text().splitlines()
    out = [head] + [f"{float(r.split(',', 1)[0]) * factor!r},{r.split(',', 1)[1]}" for r in rows]
    (dest / name).write_text("\n".join(out) + "\n")
    return dest


@pytest.mark.parametrize("unit, factor", [("ms", 1e3), ("us", 1e6), ("ns", 1e9)])
def test_imu_stamps_in_another_unit_are_refused_naming_it(log, tmp_path, unit, factor):
    bad = _scaled(log, tmp_path / unit, "imu.csv", factor)
    with pytest.raises(LogFormatError) as info:
        read_logdir(bad)
    msg = str(info.value)
    assert msg.startswith(f"{bad / 'imu.csv'}: the samples are") and f"if t is in {unit}," in msg


def test_wheel_stamps_in_ms_are_refused_naming_it(log, tmp_path):
    bad = _scaled(log, tmp_path / "wms", "wheels.csv", 1e3)
    with pytest.raises(LogFormatError, match=r"wheels\.csv: the frames are .* if t is in ms,"):
        read_logdir(bad)


def test_an_encode_sampling_time_in_ms_is_refused_with_the_value_in_s(log, tmp_path, capsys):
    bad = _scaled(log, tmp_path / "period", "wheels.csv", 1.0)
    toml = bad / "robot.toml"
    period = read_logdir(log).robot.chassis.encode_sampling_time
    text = toml.read_text().replace(f"encode_sampling_time = {period!r}",
                                    f"encode_sampling_time = {period * 1e3:g}")
    assert text != toml.read_text()
    toml.write_text(text)
    assert main(["replay", str(bad), "-o", str(tmp_path / "out.csv")]) == 2
    err = capsys.readouterr().err
    # robot.toml's own range refuses it first, at its line (no wheeled robot's period is 40 s)
    assert f"{toml}:5: [chassis] encode_sampling_time = {period * 1e3:g} s is outside" in err
    assert f"looks like ms: {period:g} s" in err
    assert not (tmp_path / "out.csv").exists()


def test_frames_faster_than_the_period_are_refused():
    # a board at 20 ms against robot.toml's 40 (within robot.toml's own range): each frame
    # counts 20 ms of ticks, which the filter would divide by 40
    with pytest.raises(LogFormatError, match=r"w\.csv: the frames are 0\.02 s apart .* 0\.5 "
                       r"times .* cannot come faster than one a period"):
        check_wheel_stamps("w.csv", np.arange(0.0, 60.0, 0.02), 0.04)


def test_lost_frames_and_rates_at_the_limits_pass():
    period = 0.04
    t = np.arange(0.0, 60.0, period)
    rng = np.random.default_rng(1)
    kept = np.sort(rng.choice(t.size, size=int(0.2 * t.size), replace=False))
    check_wheel_stamps("w.csv", t[kept], period)  # 80 % lost: the frames come, fewer
    check_wheel_stamps("w.csv", t * (1 - 1e-3), period)  # a firmware clock 0.1 % fast
    with pytest.raises(LogFormatError, match=r"95\.0% of the frames missing"):
        check_wheel_stamps("w.csv", t[::20], period)
    check_imu_stamps("i.csv", np.arange(0.0, 10.0, 0.25))  # 4 Hz
    check_imu_stamps("i.csv", np.arange(0.0, 0.1, 1e-4))  # 10 kHz
    with pytest.raises(LogFormatError, match="a rate of 2 Hz"):
        check_imu_stamps("i.csv", np.arange(0.0, 10.0, 0.5))
    check_imu_stamps("i.csv", np.array([5.0]))  # one sample: nothing to judge
    # a slow sensor stamped in s (2 Hz) is not told its t may be in ms; below 1 Hz the hint
    # is a condition ("if t is in ms"), the interval would then be 500 Hz's or faster
    with pytest.raises(LogFormatError) as info:
        check_imu_stamps("i.csv", np.arange(0.0, 100.0, 0.5))
    assert "if t is in" not in str(info.value)


def test_legitimate_wheel_logs_with_odd_stamps_pass():
    # shapes a review found refused by a whole-span mean: a recorder paused for 10 minutes,
    # a backlog of 20 frames read in one burst at the start of a short log, a very short log
    # with the serial port's jitter
    period = 0.04
    t = np.arange(0.0, 60.0, period)
    check_wheel_stamps("w.csv", np.concatenate([t, t[-1] + 600.0 + t]), period)
    burst = np.concatenate([np.full(20, 0.0) + 1e-4 * np.arange(20),
                            0.01 + np.arange(1, 31) * period])
    check_wheel_stamps("w.csv", burst, period)
    rng = np.random.default_rng(2)
    for _ in range(200):
        short = np.sort(np.arange(4) * period + rng.normal(0.0, 0.01, 4))
        check_wheel_stamps("w.csv", short, period)
