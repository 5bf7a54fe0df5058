"""``fusion replay`` on the third, independent simulator (benchmarks/blackbox, issue 11).

benchmarks/blackbox/sim.py was written by someone shown neither the EKF nor the project's two
simulators: 1 kHz rigid-body physics with friction-circle contacts, firmware driving the wheels
with the wrong geometry, encoder clock drift, jitter and lost frames, an MPU6050 with warm-up
drift, scale and cross-axis errors, an unstated mount tilt, vibration and its low-pass filter.
Its "dead" scenario adds 8 s of zero ticks on both wheels while the robot drives. Everything
is scored here against the simulator's own truth and against baselines computed from the log
files alone (benchmarks/blackbox/run_all.py: wheel-only dead reckoning, gyro with its bias
taken at the stops), none of it from the library.

The checks are issue 11's requirements, not figures measured on this run: a dead encoder
feed is flagged for its whole length and nowhere else; zero-velocity updates only while the
robot truly stands; no step between rows beyond 3 x the fastest speed x the row interval;
the fused track ends closer than both baselines. One seed (101) that no parameter was chosen
on; the yaw RMSE is not asserted against the gyro baseline, which it does not beat on every
seed (seeds 101-106: fused 1.06-2.31 deg, gyro at stops 0.70-2.15 deg; the closing note of
issue 11).
"""

from __future__ import annotations

import importlib
import io
import math
import re
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import main

BLACKBOX = Path(__file__).resolve().parent.parent / "benchmarks" / "blackbox"
SEED = 101


@pytest.fixture(scope="module")
def blackbox():
    """The benchmark's two scripts as modules (they import each other by bare name), taken out
    of ``sys.modules`` again afterwards so that no other test sees a module called ``sim``."""
    sys.path.insert(0, str(BLACKBOX))
    try:
        sim = importlib.import_module("sim")
        run_all = importlib.import_module("run_all")
    finally:
        sys.path.remove(str(BLACKBOX))
    yield sim, run_all
    for name in ("sim", "run_all"):
        sys.modules.pop(name, None)


@pytest.fixture(scope="module")
def dead_run(blackbox, tmp_path_factory):
    sim, run_all = blackbox
    truth_run = sim.simulate(sim.make_config("dead", SEED))
    folder = sim.write_run(truth_run, tmp_path_factory.mktemp("blackbox") / f"dead_{SEED}")
    printed = io.StringIO()
    with redirect_stdout(printed):
        assert main(["replay", str(folder), "-o", str(folder / "fused.csv")]) == 0
    (folder / "replay.txt").write_text(printed.getvalue())
    read = run_all.read_csv_cols
    files = {name: read(folder / f"{name}.csv") for name in ("fused", "truth", "wheels", "imu")}
    return truth_run, folder, files


def test_the_benchmark_reads_every_counter_the_replay_prints(dead_run, blackbox):
    # run_all.parse_replay reads the counters off the replay's printed summary: a wording
    # change there must not turn them into None unnoticed (two patterns were stale)
    _, run_all = blackbox
    _, folder, _ = dead_run
    parsed = run_all.parse_replay((folder / "replay.txt").read_text())
    assert all(v is not None for v in parsed.values()), parsed
    assert parsed["enc_faults"] > 100 and parsed["zupts"] > 0
    assert parsed["wheel_scale_refits"] == 0  # off by default


def _true_speed(truth):
    """Speed (m/s) and yaw rate (rad/s) of the simulator's truth, at its own stamps."""
    t = truth["t"]
    speed = np.hypot(np.gradient(truth["x"], t), np.gradient(truth["y"], t))
    return speed, np.gradient(np.unwrap(truth["yaw"]), t)


def test_a_dead_encoder_feed_is_flagged_for_its_length_and_nowhere_else(dead_run):
    truth_run, _, files = dead_run
    fused = files["fused"]
    start, end = truth_run["dead"]
    t = fused["t"]
    fault = fused["encoder_fault"] == 1
    period = truth_run["cfg"].wheel_period
    # inside: every row once the first frame of zero ticks has arrived (one period)
    inside = (t >= start + period) & (t <= end)
    assert inside.sum() > 500 and fault[inside].all(), np.flatnonzero(inside & ~fault)
    # outside: at most the frame that ends the window (its period straddles it)
    assert not np.any(fault & ((t < start) | (t > end + 2 * period)))


def test_zero_velocity_updates_only_while_the_robot_stands(dead_run):
    _, _, files = dead_run
    fused, truth = files["fused"], files["truth"]
    zupt = fused["zupt"] == 1
    assert zupt.sum() > 1000  # the mission stops several times
    speed, rate = _true_speed(truth)
    t = fused["t"][zupt]
    assert np.interp(t, truth["t"], speed).max() < 0.02  # m/s
    assert np.abs(np.interp(t, truth["t"], rate)).max() < 0.1  # rad/s


def test_no_step_between_rows_beyond_what_the_motion_allows(dead_run):
    _, _, files = dead_run
    fused, truth = files["fused"], files["truth"]
    speed, _ = _true_speed(truth)
    steps = np.hypot(np.diff(fused["x"]), np.diff(fused["y"]))
    assert np.all(steps <= 3.0 * speed.max() * np.diff(fused["t"]) + 1e-9)


def test_the_fused_track_ends_closer_than_both_baselines(dead_run, blackbox):
    _, run_all = blackbox
    _, folder, files = dead_run
    fused, truth, wheels, imu = (files[k] for k in ("fused", "truth", "wheels", "imu"))
    distance = run_all.path_length(truth)
    geometry = run_all.read_robot(folder / "robot.toml")
    wheel_t, wheel_pose = run_all.wheel_only(wheels, *geometry)
    stops = run_all.find_stops(wheels, imu)
    (gyro_t, gyro_pose), _ = run_all.gyro_at_stops(wheels, imu, geometry[1], geometry[2], stops)
    pose = np.column_stack([fused["x"], fused["y"], fused["yaw"]])
    final, yaw, _ = run_all.errors(fused["t"], pose, truth, distance)
    final_wheels, yaw_wheels, _ = run_all.errors(wheel_t, wheel_pose, truth, distance)
    final_gyro, _, _ = run_all.errors(gyro_t, gyro_pose, truth, distance)
    assert final < final_wheels and final < final_gyro
    assert yaw < yaw_wheels



def test_the_readmes_gyro_scale_calibration_brings_the_dead_feed_within_issue_11s_bound(
        dead_run, blackbox, tmp_path):
    """Issue 11 asks for a yaw RMSE of at most 1.5 deg with an 8 s dead encoder feed while
    driving; this simulator's gyro has a scale error of 0.3-1 % that nothing on the robot
    observes, so uncalibrated it is out of reach (here 1.69 deg, its reference 1.67). The
    README's remedy, done here as a user would on the same simulated robot and IMU: 10 turns
    in place each way back to a mark (the robot stopped within 0.5 deg of it, as by eye),
    ``fusion calibrate gyro-scale ... --write``, then ``fusion replay --robot`` with the
    written robot.toml. Nothing was chosen on these runs (the procedure's numbers are the
    README's). Measured when written: g -0.753 +- 0.021 %, the simulated gyro's -0.762 %
    about the accelerometer's vertical (-0.663 % about the base's true vertical: the
    accelerometer's bias tilts the vertical by 2.2 deg, and the pipeline's rate carries the
    same tilt); yaw RMSE 0.58 deg, final error 0.16 % (gyro at stops with the same
    calibration 0.45 deg, 2.88 %). Held out, seeds 417-424 (run_all.py --calibrate): "dead"
    0.18-0.94 deg on all eight, "all" 0.22-0.95."""
    sim, run_all = blackbox
    truth_run, folder, files = dead_run
    config = sim.make_config("dead", SEED)
    rng = np.random.default_rng(20_000 + SEED)
    runs = []
    for name, turns in (("ccw", 10), ("cw", -10)):
        calibration, mark_error = run_all.calibration_run(config, truth_run["gyro_matrix"],
                                                          turns, rng)
        assert abs(mark_error) < 1.5  # degrees off the mark: the 1 deg --mark-std's range
        runs.append(str(sim.write_run(calibration, tmp_path / name)))
    written = tmp_path / "robot-gyro.toml"
    printed = io.StringIO()
    with redirect_stdout(printed):
        assert main(["calibrate", "gyro-scale", *runs, "--turns", "10", "-10",
                     "--write", str(written)]) == 0
        assert main(["replay", str(folder), "--robot", str(written),
                     "-o", str(tmp_path / "fused.csv")]) == 0
    g, g_std = run_all.read_gyro_scale(written)
    true_g = run_all.scale_about_accel_vertical(calibration)
    assert abs(g - true_g) < 3.0 * g_std, (g, g_std, true_g)
    truth = files["truth"]
    distance = run_all.path_length(truth)

    def yaw_rmse(fused):
        pose = np.column_stack([fused["x"], fused["y"], fused["yaw"]])
        return run_all.errors(fused["t"], pose, truth, distance)[:2]

    final, yaw = yaw_rmse(run_all.read_csv_cols(tmp_path / "fused.csv"))
    _, yaw_uncalibrated = yaw_rmse(files["fused"])
    assert yaw <= 1.5, yaw
    assert yaw < 0.5 * yaw_uncalibrated, (yaw, yaw_uncalibrated)
    assert final <= 0.5, final


def _yaw_with_horizontal_gyro_bias(blackbox, tmp_path, bias_x: float, bias_y: float):
    """(fused yaw RMSE, reference yaw RMSE), deg, of ``fusion replay`` on scenario "all" of
    seed SEED with the simulated gyro's x and y biases set to ``bias_x``, ``bias_y`` deg/s
    (the reference: run_all.reference_yaw_rmse)."""
    sim, run_all = blackbox
    config = sim.make_config("all", SEED)
    config.gyro_bias_dps = (float(bias_x), float(bias_y), config.gyro_bias_dps[2])
    truth_run = sim.simulate(config)
    folder = sim.write_run(truth_run, tmp_path / f"all_{SEED}")
    assert main(["replay", str(folder), "-o", str(folder / "fused.csv")]) == 0
    fused = run_all.read_csv_cols(folder / "fused.csv")
    truth = run_all.read_csv_cols(folder / "truth.csv")
    pose = np.column_stack([fused["x"], fused["y"], fused["yaw"]])
    _, yaw, _ = run_all.errors(fused["t"], pose, truth, run_all.path_length(truth))
    return yaw, run_all.reference_yaw_rmse(truth_run)


def test_a_real_mpu6050s_horizontal_gyro_bias_does_not_leak_into_the_heading(
        blackbox, datasets_dir, tmp_path):
    """The tilt projection mixes the gyro's x and y rates into the vertical one, and the
    attitude's tilt is not the same at rest (where the EKF learns its bias) and while driving;
    the pipeline keeps that leak of the horizontal bias at its value at rest
    (``FusionPipeline._bias_leak``). Here the simulator's MPU6050 gets the x and y gyro biases
    measured on the bundled real one standing still (datasets/mpu6050_raw/imu_static_test.csv,
    131 LSB per deg/s: about -3.3 and +1.1 deg/s; the simulator draws 0.2-2), scenario "all",
    the seed of the tests above. Bound: the yaw RMSE of the heading integrated from the gyro
    with the TRUE bias about the TRUE vertical (run_all.reference_yaw_rmse: what the gyro's
    scale and cross-axis errors leave) plus 0.5 deg.

    Measured, seeds 101-106 of "all" and "dead" with these biases (fused / reference, deg):
    with the leak kept at rest 2.22/2.18 3.50/3.57 5.08/3.47 0.97/1.03 3.04/1.87 2.25/3.44,
    dead 1.89/1.67 2.91/2.61 2.05/1.64 1.35/1.22 2.15/1.09 1.15/1.89 (mean 2.38, reference
    2.14); without it 6.23 4.96 3.80 2.18 0.72 5.10, dead 3.48 3.69 1.11 1.82 1.09 2.75 (mean
    3.08). Seeds 103 and 105 stay above this bound (the tilt error's own share, not the
    bias's)."""
    raw = np.loadtxt(datasets_dir / "mpu6050_raw" / "imu_static_test.csv", delimiter=",",
                     skiprows=5)
    bias_x, bias_y = raw[:, 3:5].mean(axis=0) / 131.0  # deg/s
    assert abs(bias_x) > 2.0 and abs(bias_y) > 0.5  # the recording's, far above 0.2-2
    yaw, reference = _yaw_with_horizontal_gyro_bias(blackbox, tmp_path, bias_x, bias_y)
    assert yaw <= reference + 0.5, (yaw, reference)


def test_a_horizontal_gyro_bias_at_the_datasheets_limit_does_not_tilt_the_attitude(
        blackbox, tmp_path):
    """An MPU6050's x and y gyro biases may be up to +-20 deg/s before calibration
    (datasheet, zero-rate output tolerance); Keel's own bias estimate stops at 2 deg/s
    (``bias_clip``), so the attitude leaned and the tilt-projected yaw rate was wrong while
    driving: with 15 and -10 deg/s on "all" seed 101 the fused yaw RMSE was 107 deg (seed
    102: 91 deg). The pipeline now feeds the attitude filter the gyro less the horizontal bias
    learnt at rest (``FusionPipeline._rest_gyro_bias``). Measured: 2.61 deg against a
    reference of 2.18 (seed 102: 4.40 against 3.57; dead 101 and 102: 1.63 / 1.67 and 3.19 /
    2.61). Bound: the reference + 1 deg (the attitude's residual tilt error at such biases
    costs a few tenths more than the +0.5 deg of the test above)."""
    yaw, reference = _yaw_with_horizontal_gyro_bias(blackbox, tmp_path, 15.0, -10.0)
    assert yaw <= reference + 1.0, (yaw, reference)


@pytest.fixture(scope="module")
def moving_run(blackbox, tmp_path_factory):
    """Scenario "moving" (driving from the first sample, first stop after about a minute),
    replayed as shipped (two passes) and with --one-pass (as a live run)."""
    sim, run_all = blackbox
    truth_run = sim.simulate(sim.make_config("moving", SEED))
    folder = sim.write_run(truth_run, tmp_path_factory.mktemp("blackbox") / f"moving_{SEED}")
    out = {}
    for name, extra in (("two", []), ("one", ["--one-pass"])):
        printed = io.StringIO()
        with redirect_stdout(printed):
            assert main(["replay", str(folder), "-o", str(folder / f"{name}.csv"),
                         *extra]) == 0
        out[name] = (printed.getvalue(), run_all.read_csv_cols(folder / f"{name}.csv"))
    return truth_run, run_all.read_csv_cols(folder / "truth.csv"), out


def test_a_moving_start_takes_the_first_stops_bias_back_to_the_start(moving_run, blackbox):
    # Measured when written (seed 101): yaw RMSE 1.91 deg in one pass (the bias unknown for
    # the first 67 s), 1.38 in two (reference 1.63), the stop's bias -0.879 +- 0.048 deg/s
    # against -0.893 true at the start; seeds 201-204, which nothing was chosen on either:
    # 4.86 5.45 5.16 1.59 -> 4.64 1.76 1.80 0.93 deg
    _, run_all = blackbox
    truth_run, truth, out = moving_run
    (text, two), (text_one, one) = out["two"], out["one"]
    notes = [ln for ln in text.splitlines() if ln.startswith("note: moving start")]
    assert len(notes) == 1, text
    # one pass is not fused again; it says what the same stop taught and what it cost
    (once,) = [ln for ln in text_one.splitlines() if ln.startswith("note: moving start")]
    assert "fused once (--one-pass, as a live run)" in once, once
    said = re.search(r"drove ([0-9.]+) s before its first stop; the gyro bias learnt there, "
                     r"([-+0-9.]+) \+- ([0-9.]+) deg/s", notes[0])
    drove, bias, std = (float(g) for g in said.groups())
    imu_t = truth_run["imu"][0]
    true_start_bias = math.degrees(truth_run["bias_vert"][0])
    assert 30.0 < drove < 120.0
    said_once = re.search(r"\(after ([0-9.]+) s\), ([-+0-9.]+) \+- [0-9.]+ deg/s, is "
                          r"([-+0-9.]+) deg/s off the prior", once)
    # the one pass's own first stop: where and what the two-pass run found, from a 0 prior
    assert float(said_once.group(1)) == pytest.approx(drove, abs=1.0)
    assert float(said_once.group(2)) == pytest.approx(bias, abs=0.05)
    assert float(said_once.group(3)) == pytest.approx(float(said_once.group(2)), abs=1e-3)
    # the stop's bias as the prior at the start: within its stated uncertainty of the truth
    assert abs(bias - true_start_bias) < 3.0 * std, (bias, std, true_start_bias)
    # the bias state before the first stop, against the simulator's (warm-up drift included)
    before = two["t"] < two["t"][0] + drove
    true_bias = np.degrees(np.interp(two["t"], imu_t, truth_run["bias_vert"]))
    err_two = np.sqrt(np.mean((np.degrees(two["gyro_bias_z"]) - true_bias)[before] ** 2))
    err_one = np.sqrt(np.mean((np.degrees(one["gyro_bias_z"]) - true_bias)[before] ** 2))
    assert err_two < 0.5 * err_one, (err_two, err_one)
    distance = run_all.path_length(truth)
    yaw = {}
    for name, fused in (("two", two), ("one", one)):
        pose = np.column_stack([fused["x"], fused["y"], fused["yaw"]])
        _, yaw[name], _ = run_all.errors(fused["t"], pose, truth, distance)
    assert yaw["two"] < yaw["one"], yaw
    # near what the gyro's scale and cross-axis errors alone leave (the bias known exactly)
    assert yaw["two"] < run_all.reference_yaw_rmse(truth_run) + 0.5, yaw


def test_an_imu_log_stamped_half_a_second_late_is_moved_back(dead_run, tmp_path):
    # The same log with every imu.csv stamp 0.5 s later (an IMU driver stamping when its
    # buffer drains): the replay finds the lag from the turns, moves the IMU's stamps back
    # with a note, and scores against the simulator's truth as the untouched log does;
    # --imu-lag 0 keeps the stamps and loses the heading. The untouched log's small
    # interval-mean lag is left alone. A folder replay says so per log.
    import shutil

    from fusion.jobs.replay import replay_logdir

    _, folder, _ = dead_run
    late = tmp_path / "late"
    late.mkdir()
    for name in ("robot.toml", "wheels.csv", "truth.csv"):
        shutil.copy(folder / name, late / name)
    lines = (folder / "imu.csv").read_text().splitlines()
    rows = [line.split(",", 1) for line in lines[1:] if line]
    (late / "imu.csv").write_text("\n".join(
        [lines[0], *(f"{float(t) + 0.5:.9f},{rest}" for t, rest in rows)]) + "\n")
    untouched = replay_logdir(folder, tmp_path / "on_time.csv")
    moved = replay_logdir(late, tmp_path / "moved.csv")
    kept = replay_logdir(late, tmp_path / "kept.csv", imu_lag=0.0)
    assert untouched.imu_lag == 0.0 and not any("IMU's" in n for n in untouched.notes)
    found = moved.imu_lag
    assert abs(found - 0.5) < 0.01, found  # the wheel frames' half period accounted for
    assert any(f"ran {found:.3f} s behind" in n for n in moved.notes), moved.notes
    assert kept.imu_lag == 0.0
    on_time = untouched.truth
    assert abs(moved.truth["fused_yaw_deg"] - on_time["fused_yaw_deg"]) < 0.2, (
        moved.truth, on_time)
    assert abs(moved.truth["fused_pct"] - on_time["fused_pct"]) < 0.2, (moved.truth, on_time)
    print(f"IMU 0.5 s late: found {found:.3f} s; yaw RMSE {on_time['fused_yaw_deg']:.2f} deg "
          f"on time, {moved.truth['fused_yaw_deg']:.2f} moved, "
          f"{kept.truth['fused_yaw_deg']:.2f} kept; final error {on_time['fused_pct']:.2f} %, "
          f"{moved.truth['fused_pct']:.2f}, {kept.truth['fused_pct']:.2f}")
    assert kept.truth["fused_yaw_deg"] > moved.truth["fused_yaw_deg"] + 0.5, kept.truth
    folder = tmp_path / "logs"
    folder.mkdir()
    late.rename(folder / "late")
    printed = io.StringIO()
    with redirect_stdout(printed):
        assert main(["replay", str(folder), "-o", str(tmp_path / "out"), "--jobs", "1"]) == 0
    assert f"warning: late: the IMU's stamps ran {found:.3f} s behind" in printed.getvalue()
