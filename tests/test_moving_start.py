"""The first stop of a moving start (fusion.jobs.moving_start) and the bias prior it gives
(EkfNoise.initial_bias); the end-to-end check on the independent simulator is in
tests/test_blackbox_replay.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.trust import RADIUS_MISMATCH_LIMIT, WHEEL_SCALE_LIMIT
from fusion.jobs.moving_start import (
    MIN_STOP,
    MOVING_START_DELAY,
    STOP_EDGE,
    STOP_MERGE_GAP,
    first_stop,
    wheel_prior,
)
from fusion.planar.ekf import EkfNoise, PlanarEKF


def _rows(zupt_spans, duration=100.0, rate=50.0):
    """Rows at ``rate`` Hz: the rate and bias states (rad/s; their sum the gyro's reading, a
    different value each row), the bias's variance, the ZUPT flag over ``zupt_spans`` (s)."""
    t = np.arange(0.0, duration, 1.0 / rate) + 1000.0   # a log's clock need not start at 0
    zupt = np.zeros(t.size, bool)
    for a, b in zupt_spans:
        zupt |= (t >= 1000.0 + a) & (t <= 1000.0 + b)
    bias = np.full(t.size, 0.03)                         # the filter's own, off
    w = 0.01 + 1e-4 * (t - t[0]) - bias                  # reading 0.01 + 1e-4 (t - t0)
    var = np.full(t.size, 1e-6)
    return t, w, bias, var, zupt


def test_a_robot_that_starts_at_rest_has_no_moving_start():
    t, w, bias, var, zupt = _rows([(0.1, 5.0), (40.0, 45.0)])
    assert first_stop(t, w, bias, var, zupt, 1e-8) is None
    # nor one whose first stop comes within the delay
    t, w, bias, var, zupt = _rows([(MOVING_START_DELAY - 0.1, 10.0)])
    assert first_stop(t, w, bias, var, zupt, 1e-8) is None


def test_a_robot_that_never_stops_has_none_to_learn_from():
    t, w, bias, var, zupt = _rows([])
    assert first_stop(t, w, bias, var, zupt, 1e-8) is None


def test_the_first_stop_ends_where_its_updates_pause_longer_than_the_merge_gap():
    # updates 30-31 s and 31.5-34 s are one stop (0.5 s apart), 60-62 s another
    t, w, bias, var, zupt = _rows([(30.0, 31.0), (31.0 + 0.5 * STOP_MERGE_GAP, 34.0),
                                (60.0, 62.0)])
    var[t <= 1034.0] = 4e-6
    psd = 2e-8
    s = first_stop(t, w, bias, var, zupt, psd)
    assert s is not None
    end = int(np.flatnonzero(t <= 1034.0)[-1])
    inner = (t >= 1030.0 + STOP_EDGE) & (t <= t[end] - STOP_EDGE)
    assert (s.start, s.stop_begin, s.stop_end) == pytest.approx((1000.0, 1030.0, t[end]))
    # the gyro's readings (rate + bias) over the stop less its edges: their median, not the
    # filter's bias state (0.03 here)
    reading = (w + bias)[inner]
    assert s.bias == pytest.approx(np.median(reading))
    assert s.bias == pytest.approx(0.01 + 1e-4 * (0.5 * (30.0 + 34.0)), abs=1e-6)
    # the filter's variance there, the readings' spread over their number, and the random
    # walk over the 32 s back to the start
    mid = np.median(t[inner])
    assert s.bias_std == pytest.approx(math.sqrt(4e-6 + np.var(reading) / inner.sum()
                                                 + psd * (mid - 1000.0)))
    assert "drove 30.0 s before its first stop" in s.note
    assert f"{math.degrees(s.bias):+.3f} +- {math.degrees(s.bias_std):.3f} deg/s" in s.note


def test_a_pause_shorter_than_a_stop_is_passed_over():
    # a pause of 0.3 s at 20 s (before a turn in place, say), then a stop of 3 s at 50 s
    t, w, bias, var, zupt = _rows([(20.0, 20.0 + 0.3 * MIN_STOP), (50.0, 53.0)])
    s = first_stop(t, w, bias, var, zupt, 1e-8)
    assert s is not None and s.stop_begin == pytest.approx(1050.0)
    assert s.bias == pytest.approx(0.01 + 1e-4 * 51.5, abs=1e-6)
    # a log whose stops are all pauses has none
    t, w, bias, var, zupt = _rows([(20.0, 20.0 + 0.3 * MIN_STOP), (50.0, 50.0 + 0.5 * MIN_STOP)])
    assert first_stop(t, w, bias, var, zupt, 1e-8) is None


def test_the_prior_mean_of_the_bias_starts_the_filter():
    ekf = PlanarEKF(_chassis(), EkfNoise(initial_bias=0.004, initial_bias_std=1e-3))
    assert ekf.x[5] == 0.004 and ekf.P[5, 5] == pytest.approx(1e-6)
    assert PlanarEKF(_chassis(), EkfNoise()).x[5] == 0.0
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match=r"EkfNoise\.initial_bias must be finite"):
            EkfNoise(initial_bias=bad)


def _chassis():
    from fusion.geometry.kinematics import DiffDriveParams

    return DiffDriveParams(wheel_distance=0.3, speed_ratio=5e-5, encode_sampling_time=0.04)


def test_a_folder_replay_passes_one_pass_to_each_log(tmp_path):
    # a log that drives from its first row (a synthetic run from 10 s on: first stop at
    # 45 s), in a folder: two passes by default, one with --one-pass (as for a single log)
    from fusion.cli import main
    from fusion.evaluation.synthetic import degraded_mission
    from fusion.io.logdir import write_synthetic_run

    full = write_synthetic_run(tmp_path / "full", degraded_mission(seed=2, duration=120.0))
    moving = tmp_path / "logs" / "moving"
    moving.mkdir(parents=True)
    (moving / "robot.toml").write_text((full / "robot.toml").read_text())
    for name in ("imu.csv", "wheels.csv"):
        head, *rows = (full / name).read_text().splitlines()
        kept = [r for r in rows if float(r.split(",")[0]) >= 10.0]
        (moving / name).write_text("\n".join([head, *kept]) + "\n")
    tables = {}
    for name, extra in (("two", []), ("one", ["--one-pass"])):
        assert main(["replay", str(tmp_path / "logs"), "-o", str(tmp_path / name),
                     "--jobs", "1", *extra]) == 0
        tables[name] = np.genfromtxt(tmp_path / name / "moving.csv", delimiter=",",
                                     names=True)
    two, one = tables["two"], tables["one"]
    np.testing.assert_array_equal(two["t"], one["t"])
    # the second pass starts from the first stop's bias; one pass from 0
    assert two["gyro_bias_z"][0] != 0.0 and one["gyro_bias_z"][0] == pytest.approx(0.0,
                                                                                   abs=1e-3)


def test_the_wheel_calibration_is_the_runs_last_with_its_walk_and_half_its_weight():
    t = np.linspace(1000.0, 1300.0, 301)
    k, c = np.linspace(0.0, -0.04, t.size), np.linspace(0.0, 0.002, t.size)
    k_var, c_var = np.full(t.size, 4e-6), np.full(t.size, 1e-6)

    def prior(k=k, c=c, k_var=k_var, c_var=c_var):
        return wheel_prior(t, k, k_var, c, c_var, 0.05, 0.05, 1e-9, 2e-9)

    got = prior()
    assert (got.k, got.c) == (-0.04, 0.002)
    # the walk back over the run's 300 s, then twice the variance: the data is fused twice
    assert got.k_std == pytest.approx(math.sqrt(2 * (4e-6 + 1e-9 * 300.0)), rel=1e-12)
    assert got.c_std == pytest.approx(math.sqrt(2 * (1e-6 + 2e-9 * 300.0)), rel=1e-12)
    assert "yaw-rate scale -0.0400 +- 0.0029" in got.describe()
    # beyond the trust checks' limits (a gyro in deg/s ends with k = -0.98): a fault
    assert prior(k=np.full(t.size, -WHEEL_SCALE_LIMIT - 0.01)) is None
    assert prior(c=np.full(t.size, RADIUS_MISMATCH_LIMIT + 0.01)) is None
    # neither learnt (odometry whose yaw rate was never fused): the note claims nothing
    assert prior(k_var=np.full(t.size, 0.05 ** 2), c_var=np.full(t.size, 0.05 ** 2)) is None
    only_c = prior(k_var=np.full(t.size, 0.05 ** 2))  # c was learnt, k was not
    assert (only_c.k, only_c.k_std) == (0.0, 0.05)  # k keeps the robot's own prior
    assert only_c.c == 0.002
    # a learnt state never gets looser than its prior
    assert prior(c_var=np.full(t.size, 0.04 ** 2)).c_std == 0.05
    bad = c.copy()
    bad[-1] = np.nan
    assert prior(c=bad) is None


def test_the_wheel_calibration_prior_is_the_filters_initial_state():
    noise = EkfNoise(wheel_rate_scale=-0.03, calib_k_std=0.001, wheel_rate_per_speed=0.004,
                     calib_c_std=0.0005)
    from fusion.geometry.kinematics import DiffDriveParams

    ekf = PlanarEKF(DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4), noise)
    assert (ekf.x[6], ekf.x[7]) == (-0.03, 0.004)
    assert (ekf.P[6, 6], ekf.P[7, 7]) == pytest.approx((0.001 ** 2, 0.0005 ** 2), rel=1e-12)
    with pytest.raises(ValueError, match="wheel_rate_scale must be finite, in"):
        EkfNoise(wheel_rate_scale=-0.5)
    with pytest.raises(ValueError, match="wheel_rate_per_speed must be finite"):
        EkfNoise(wheel_rate_per_speed=math.inf)
