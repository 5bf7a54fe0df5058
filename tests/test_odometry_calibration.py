"""Odometry calibration against the simulator's true geometry; UMBmark on simulated squares."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fusion.calibration.odometry import (
    calibrate_odometry,
    radius_mismatch_rate,
    radius_ratio_from_mismatch,
    rest_bias,
    umbmark,
)
from fusion.evaluation.synthetic import (
    EXAMPLE_ROBOT,
    EncoderModel,
    ImuModel,
    degraded_mission,
    simulate,
    spin,
    square,
    stop,
    straight,
)
from fusion.io.logdir import write_synthetic_run
from fusion.planar.odometry import WheelOdometry

ROBOT = EXAMPLE_ROBOT


@pytest.mark.parametrize("seed", [0, 3, 6])
def test_separation_and_radius_ratio_within_0p3_percent(seed):
    # 3 % separation error, 0.5 % radius mismatch, bias 0.5 deg/s with random walk, three slip
    # patches (degraded_mission). The gyro is the reference; the truth is the simulator's.
    run = degraded_mission(seed=seed, duration=300.0)
    cal = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT)
    true_ratio = run.true_right_ratio / run.true_left_ratio
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert cal.radius_ratio == pytest.approx(true_ratio, rel=0.003)
    # measured when written: |L error| <= 0.03 %, |ratio error| <= 0.01 %
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=5e-4)
    assert cal.radius_ratio == pytest.approx(true_ratio, rel=2e-4)
    assert cal.speed_ratio == ROBOT.speed_ratio  # no distance given: scale kept
    assert not cal.scale_from_distance
    assert cal.windows_rejected >= 1  # the slip windows were thrown out
    text = cal.report()
    assert "wheel_distance = " in text and "speed_ratio = " in text


def test_speed_ratio_from_ground_truth_and_from_a_known_distance():
    # Both wheels 1 % and 1.5 % larger than robot.toml says: a common scale error the gyro
    # cannot see. With the ground truth (or a measured distance) it is recovered.
    enc = EncoderModel(separation_error=-0.02, left_scale_error=0.010, right_scale_error=0.015)
    segs = stop(4) + straight(3.0) + spin(math.pi) + straight(3.0) + spin(-math.pi / 2) \
        + straight(1.0) + spin(2 * math.pi) + stop(3)
    run = simulate(segs, ROBOT, ImuModel(gyro_bias=(0, 0, 0.01)), enc, seed=9)
    true_mean = 0.5 * (run.true_left_ratio + run.true_right_ratio)
    cal = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                             truth_t=run.truth_t, truth=run.truth, window=10)
    assert cal.speed_ratio == pytest.approx(true_mean, rel=0.003)
    assert cal.left_ratio == pytest.approx(run.true_left_ratio, rel=0.003)
    assert cal.right_ratio == pytest.approx(run.true_right_ratio, rel=0.003)
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    cal_d = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                               distance=run.distance, window=10)
    assert cal_d.speed_ratio == pytest.approx(true_mean, rel=0.003)
    assert cal_d.params().speed_ratio == cal_d.speed_ratio
    assert cal_d.params().wheel_distance == cal_d.wheel_distance


def test_rest_bias_is_the_mean_at_standstill():
    run = simulate(stop(5) + straight(1.0) + stop(5), ROBOT,
                   ImuModel(gyro_bias=(0, 0, 0.02)), seed=1)
    bias, mids = rest_bias(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, 0.04)
    assert len(mids) == 2
    assert bias[0] == pytest.approx(0.02, abs=4 * 8.7e-4 / math.sqrt(400))
    moving = simulate(straight(2.0), ROBOT, seed=1)
    with pytest.raises(ValueError, match="no standstill"):
        calibrate_odometry(moving.imu_t, moving.gyro[:, 2], moving.wheel_t, moving.ticks, ROBOT,
                           window=5)


def test_no_turning_is_refused():
    run = simulate(stop(3) + straight(4.0) + stop(3), ROBOT, seed=2)
    with pytest.raises(ValueError, match="not observable"):
        calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT, window=10)


def _slipping_run(share: float, seed: int = 4):
    """A 300 s random mission whose right wheel spins 40 % faster than the floor moves under
    it for ``share`` of the time (2 s patches, evenly spaced), 3 % separation error."""
    from fusion.evaluation.synthetic import SlipPatch, random_mission

    period = 2.0 / share
    patches = tuple(SlipPatch(t0, t0 + 2.0, wheel="right", ratio=0.4)
                    for t0 in np.arange(8.0, 292.0, period))
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025,
                       right_scale_error=0.0025, slip_patches=patches)
    return simulate(random_mission(300, seed=seed), ROBOT, ImuModel(), enc, seed=seed)


def test_a_wheel_slipping_forty_percent_of_the_time_does_not_pull_the_fit():
    """An independent probe's wheel spinning 40 % of the time gave a least-squares
    wheel_distance 87 % off with every window within 5 sigma of it. The fit now starts from
    the least median of squares over pairs of windows, per kind (turning, straight), which
    half of each may spoil. Measured when written: +0.03 %, 110 of 300 windows rejected (the
    least-squares start on the same run: +83 %, none rejected)."""
    run = _slipping_run(0.4)
    cal = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT)
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert cal.radius_ratio == pytest.approx(run.true_right_ratio / run.true_left_ratio,
                                             rel=0.003)
    assert cal.windows_rejected > 0.3 * (cal.windows_used + cal.windows_rejected)
    assert "windows disagree with the gyro" in cal.report()


def test_the_stated_uncertainty_of_wheel_distance_covers_its_error():
    """Missions with three slip patches each (degraded_mission): the errors against the
    simulator's true separation, in units of the stated standard deviation (the fit's; the
    gyro here is exact, gyro_scale_std 0). With the windows taken as independent the RMS was
    1.55 on seeds 0-5 and 1.82 on seeds 6-17 (the bias interpolated between stops errs alike
    over a whole stretch); with the stretches as clusters (_fit_covariance) 1.04 on 0-5, where
    the problem was seen, and 1.14 on 6-17, asserted here."""
    z = []
    for seed in range(6, 18):
        run = degraded_mission(seed=seed, duration=300.0)
        cal = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT)
        z.append((cal.wheel_distance - run.true_wheel_distance) / cal.wheel_distance_std)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 < rms < 1.4, z
    # and the gyro scale's own uncertainty adds on: 3 % (uncalibrated) dominates
    cal3 = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                              gyro_scale_std=0.03)
    assert cal3.wheel_distance_std == pytest.approx(0.03 * cal3.wheel_distance, rel=0.05)


def test_windows_where_the_gyro_saturated_are_left_out_and_said():
    # the mask is what the command gives (fusion.calibration.gyro_limits.saturated_samples,
    # tested in tests/test_gyro_limits.py); here the faster turns' samples
    run = degraded_mission(seed=2, duration=300.0)
    limit = 0.7  # rad/s
    gyro = np.clip(run.gyro, -limit, limit)
    clipped = np.abs(run.gyro[:, 2]) > limit
    assert clipped.sum() > 500
    cal = calibrate_odometry(run.imu_t, gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                             saturated=clipped)
    assert cal.windows_saturated >= 10 and "the gyro saturated" in cal.report()
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    # everything clipped: the refusal says why there is no turning left
    with pytest.raises(ValueError, match=r"left out because the gyro saturated"):
        calibrate_odometry(run.imu_t, gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                           saturated=np.abs(run.gyro[:, 2]) > 0.05)


def test_windows_across_non_finite_gyro_samples_are_left_out_and_said():
    # a corrupt row in a turn: the heading integral across it is unknown, so the windows that
    # span it go, the rest fit as without it (fusion replay skips such samples too)
    run = degraded_mission(seed=2, duration=300.0)
    gz = run.gyro[:, 2].copy()
    turning = np.flatnonzero(np.abs(gz) > 0.5)
    holes = turning[np.linspace(0, turning.size - 1, 12).astype(int)]
    gz[holes] = np.nan
    gz[holes[3] + 1] = np.inf  # two in a row
    clean = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT)
    cal = calibrate_odometry(run.imu_t, gz, run.wheel_t, run.ticks, ROBOT)
    assert 6 <= cal.windows_not_finite <= 24  # one or two windows per hole
    assert "across IMU samples that are not finite numbers" in cal.report()
    assert cal.windows_used + cal.windows_rejected + cal.windows_not_finite == (
        clean.windows_used + clean.windows_rejected)
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    # 10 of 299 windows fewer (and the slip rejection redrawn around them: 24 -> 20) move
    # the fit within its stated uncertainty (measured 1.8 std)
    assert abs(cal.wheel_distance - clean.wheel_distance) < 2 * clean.wheel_distance_std


def test_swapped_wheels_and_other_units_are_named():
    run = degraded_mission(seed=1, duration=150.0)
    with pytest.raises(ValueError, match="left and right are swapped"):
        calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks[:, ::-1], ROBOT)
    with pytest.raises(ValueError, match="the gyro is in deg/s"):
        calibrate_odometry(run.imu_t, np.degrees(run.gyro[:, 2]), run.wheel_t, run.ticks,
                           ROBOT)


def _return_errors(direction, enc, runs=5):
    out = []
    for s in range(runs):
        run = simulate(square(side=4.0, direction=direction), ROBOT, ImuModel(), enc, seed=s)
        pose = WheelOdometry(ROBOT).update_batch(run.ticks[:, 0], run.ticks[:, 1])[-1]
        out.append(run.truth[-1, :2] - pose[:2])
    return np.array(out)


def test_umbmark_finds_the_simulated_errors():
    # Borenstein & Feng's 4 m squares, 5 runs each way, wheel-only odometry against the truth.
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025, right_scale_error=0.0025)
    res = umbmark(_return_errors("cw", enc), _return_errors("ccw", enc), 4.0,
                  ROBOT.wheel_distance)
    true_ed = 1.0025 / 0.9975
    # UMBmark is a first-order method: measured when written E_d 1.00544 (true 1.00501) and
    # wheelbase 0.3107 m (true 0.309, +0.54 %).
    assert res.diameter_ratio == pytest.approx(true_ed, rel=1e-3)
    assert res.wheel_distance == pytest.approx(0.3 * 1.03, rel=0.01)
    assert res.wheelbase_factor > 1 and res.diameter_ratio > 1
    assert res.left_factor * res.diameter_ratio == pytest.approx(res.right_factor)
    assert res.max_error > 0.5  # a 3 % wheelbase error is far off after 16 m
    # errors of a perfectly calibrated robot: no systematic error left
    clean = EncoderModel()
    res0 = umbmark(_return_errors("cw", clean, 2), _return_errors("ccw", clean, 2), 4.0,
                   ROBOT.wheel_distance)
    assert abs(res0.diameter_ratio - 1) < 2e-4 and abs(res0.wheelbase_factor - 1) < 1e-3


def test_umbmark_validation():
    with pytest.raises(ValueError):
        umbmark(np.zeros((0, 2)), np.zeros((1, 2)), 4.0, 0.3)


def _value(text, key):
    line = next(ln for ln in text.splitlines() if ln.startswith(key + " = "))
    return float(line.split("=")[1].split("#")[0])


def test_cli_calibrate_odometry(tmp_path, capsys):
    from fusion.cli import main

    run = degraded_mission(seed=1, duration=150.0)
    d = write_synthetic_run(tmp_path / "run", run)
    assert main(["calibrate", "odometry", str(d)]) == 0
    out = capsys.readouterr().out
    assert _value(out, "wheel_distance") == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert _value(out, "speed_ratio") == ROBOT.speed_ratio
    # robot.toml has no calibrated gyro scale: said, and its 3 % is in the stated std
    assert "note: the gyro's scale is not calibrated" in out
    assert re.search(r"wheel_distance = [\d.]+  # m \+- 0\.009", out), out
    assert main(["calibrate", "odometry", str(d), "--use-truth", "--level"]) == 0
    out = capsys.readouterr().out
    true_mean = 0.5 * (run.true_left_ratio + run.true_right_ratio)
    assert _value(out, "speed_ratio") == pytest.approx(true_mean, rel=0.003)
    assert main(["calibrate", "odometry", str(tmp_path / "none")]) == 2
    assert "not a log directory" in capsys.readouterr().err
    # --write: a corrected robot.toml that the log-directory reader accepts
    from fusion.io.robot_toml import read_robot_toml

    assert main(["calibrate", "odometry", str(d), "--write", str(tmp_path / "new.toml")]) == 0
    out = capsys.readouterr().out
    cfg = read_robot_toml(tmp_path / "new.toml")
    assert cfg.chassis.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert cfg.chassis.encode_sampling_time == ROBOT.encode_sampling_time
    # the radius ratio (0.5 % simulated) as the EKF's radius mismatch and its 1 sigma
    c_true = radius_mismatch_rate(run.true_right_ratio / run.true_left_ratio,
                                  run.true_wheel_distance)
    assert cfg.ekf.wheel_rate_per_speed == pytest.approx(c_true, rel=0.05)
    # its std: the ratio's fit gives 2e-5, floored at 0.1 % (a tyre's radius moves with load
    # and pressure; the fit's alone would pin the EKF's state to this run's conditions)
    ratio = run.true_right_ratio / run.true_left_ratio
    assert cfg.ekf.calib_c_std == pytest.approx(
        4.0 / (cfg.chassis.wheel_distance * (1.0 + ratio) ** 2) * 1e-3, rel=1e-3)
    assert f"wheel_rate_per_speed = {cfg.ekf.wheel_rate_per_speed:.6g}" in out
    assert main(["calibrate", "odometry", str(d), "--write", str(d / "robot.toml")]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err


def test_cli_calibrate_odometry_leaves_out_corrupt_imu_rows_and_names_them(tmp_path, capsys):
    from fusion.cli import main

    run = degraded_mission(seed=1, duration=150.0)
    d = write_synthetic_run(tmp_path / "run", run)
    lines = (d / "imu.csv").read_text().splitlines()
    turning = np.flatnonzero(np.abs(run.gyro[:, 2]) > 0.5)
    for k in turning[[10, 250, 500]]:
        head, rest = lines[k + 1].split(",", 1)  # line 1 is the header
        lines[k + 1] = head + ",nan," + rest.split(",", 1)[1]
    (d / "imu.csv").write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "odometry", str(d)]) == 0
    out = capsys.readouterr().out
    assert (f"note: {d / 'imu.csv'}:{turning[10] + 2}: not a finite number (3 such rows): "
            "left out") in out
    assert re.search(r"\d+ left out: across IMU samples that are not finite numbers", out)
    assert _value(out, "wheel_distance") == pytest.approx(run.true_wheel_distance, rel=0.003)


def test_cli_calibrate_odometry_bound_on_the_change_can_be_raised(tmp_path, capsys):
    # a robot.toml whose wheel_distance is a placeholder half the true one: refused by
    # default (+100 %), measured with --max-change 150
    from fusion.cli import main

    run = degraded_mission(seed=1, duration=150.0)
    d = write_synthetic_run(tmp_path / "run", run)
    toml = (d / "robot.toml").read_text()
    assert "wheel_distance = 0.3  #" in toml
    (d / "robot.toml").write_text(toml.replace("wheel_distance = 0.3  #",
                                               "wheel_distance = 0.15  #"))
    assert main(["calibrate", "odometry", str(d)]) == 2
    err = capsys.readouterr().err
    assert "beyond max_change (50 %)" in err and "--max-change" in err
    assert main(["calibrate", "odometry", str(d), "--max-change", "150"]) == 0
    out = capsys.readouterr().out
    assert _value(out, "wheel_distance") == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert main(["calibrate", "odometry", str(d), "--max-change", "0"]) == 2
    assert "--max-change must be > 0 %" in capsys.readouterr().err


def test_cli_calibrate_odometry_puts_a_late_imu_on_the_wheels_clock(tmp_path, capsys):
    # the same log with imu.csv stamped 0.7 s late: fitted as stamped, the gyro's turns meet
    # the wheels' 0.7 s apart; the command moves the IMU's stamps as fusion replay does
    from fusion.cli import main

    run = degraded_mission(seed=1, duration=150.0)
    d = write_synthetic_run(tmp_path / "run", run)
    lines = (d / "imu.csv").read_text().splitlines()
    rows = [line.split(",", 1) for line in lines[1:] if line]
    (d / "imu.csv").write_text("\n".join(
        [lines[0], *(f"{float(t) + 0.7:.9f},{rest}" for t, rest in rows)]) + "\n")
    assert main(["calibrate", "odometry", str(d), "--level"]) == 0
    out = capsys.readouterr().out
    assert "note: the IMU's stamps ran 0.7" in out and "behind the odometry's" in out
    fitted = _value(out, "wheel_distance")
    assert fitted == pytest.approx(run.true_wheel_distance, rel=0.003)
    # as stamped (--imu-lag 0): most windows' gyro and wheels disagree on when the robot
    # turned; the robust start keeps those that agree (the middle of long turns), and the
    # report says what else than slip leaves so many out
    assert main(["calibrate", "odometry", str(d), "--level", "--imu-lag", "0"]) == 0
    out = capsys.readouterr().out
    assert _value(out, "wheel_distance") == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert "windows disagree with the gyro" in out and "--imu-lag" in out
    # a lag that moves the IMU off the wheels' span altogether is said as such
    assert main(["calibrate", "odometry", str(d), "--imu-lag", "1000"]) == 2
    err = capsys.readouterr().err
    assert "they do not overlap" in err and "after moving the IMU's stamps by -1000.000 s" in err


def test_cli_umbmark(tmp_path, capsys):
    from fusion.cli import main

    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025, right_scale_error=0.0025)
    dirs = {}
    for direction in ("cw", "ccw"):
        dirs[direction] = []
        for s in range(2):
            run = simulate(square(side=4.0, direction=direction), ROBOT, ImuModel(), enc, seed=s)
            dirs[direction].append(str(write_synthetic_run(tmp_path / f"{direction}{s}", run)))
    assert main(["calibrate", "umbmark", "--cw", *dirs["cw"], "--ccw", *dirs["ccw"]]) == 0
    out = capsys.readouterr().out
    assert _value(out, "wheel_distance") == pytest.approx(0.3 * 1.03, rel=0.01)
    assert "E_d = D_R/D_L = 1.005" in out
    # E_d as the EKF's radius mismatch (robot.toml's [ekf]), against the simulated radii:
    # UMBmark is first-order, its E_d 1.0054 for the true 1.0050 (c 8 % off)
    c_true = radius_mismatch_rate(1.0025 / 0.9975, 0.3 * 1.03)
    assert "\n[ekf]\nwheel_rate_per_speed = " in out
    assert _value(out, "wheel_rate_per_speed") == pytest.approx(c_true, rel=0.12)
    assert "repeat until the return errors stop shrinking" in out
    # the truth shows what the runs are: an independent probe's exchanged lists (E_d came out
    # inverted), a wrong --side (wheel_distance 4 % off) were corrected with confidence
    assert main(["calibrate", "umbmark", "--cw", *dirs["ccw"], "--ccw", *dirs["cw"]]) == 2
    assert "a clockwise square turns -: the run belongs under --ccw" in \
        capsys.readouterr().err
    assert main(["calibrate", "umbmark", "--cw", *dirs["cw"], "--ccw", *dirs["ccw"],
                 "--side", "2"]) == 2
    assert "a square of side 2 m (--side) is 8 m" in capsys.readouterr().err
    # a motion capture's millimetre noise does not lengthen the path measured (it had: 16 m
    # squares measured 21 m at 1 mm, refused)
    rng = np.random.default_rng(3)
    for d in (*dirs["cw"], *dirs["ccw"]):
        head, *rows = (Path(d) / "truth.csv").read_text().splitlines()
        noisy = [",".join([c[0], *(f"{float(v) + rng.normal(0, 0.001):.6f}" for v in c[1:3]),
                           *c[3:]]) for c in (r.split(",") for r in rows)]
        (Path(d) / "truth.csv").write_text("\n".join([head, *noisy]) + "\n")
    assert main(["calibrate", "umbmark", "--cw", *dirs["cw"], "--ccw", *dirs["ccw"]]) == 0
    capsys.readouterr()
    # a hand-measured end pose (truth.csv of the start and end only) cannot show either:
    # the runs are taken as given (the former check refused them as "no square")
    for d in (*dirs["cw"], *dirs["ccw"]):
        lines = (Path(d) / "truth.csv").read_text().splitlines()
        (Path(d) / "truth.csv").write_text("\n".join([lines[0], lines[1], lines[-1]]) + "\n")
    assert main(["calibrate", "umbmark", "--cw", *dirs["cw"], "--ccw", *dirs["ccw"]]) == 0
    assert _value(capsys.readouterr().out, "wheel_distance") == pytest.approx(0.3 * 1.03,
                                                                          rel=0.01)


def test_calibration_with_dropped_frames_jitter_and_latency():
    # 5 % of the frames lost (windows must be consecutive frames, so about half the windows
    # survive), 2 ms stamp jitter, 5 ms latency (given), slips. Measured when written:
    # L -0.07..+0.07 %, ratio within 0.01 %, speed_ratio (from the truth) within 0.04 %.
    from fusion.evaluation.synthetic import SlipPatch, random_mission

    patches = tuple(SlipPatch(t0, t0 + 1, wheel="left", ratio=0.3) for t0 in (60, 150, 240))
    imu = ImuModel(gyro_bias=(0.002, -0.002, math.radians(0.5)), gyro_bias_walk=2e-5,
                   vibration=0.5, jitter=5e-4)
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025, right_scale_error=0.0025,
                       slip_patches=patches, drop_probability=0.05, jitter=0.002, latency=0.005)
    run = simulate(random_mission(300, seed=2), ROBOT, imu, enc, seed=2)
    cal = calibrate_odometry(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks, ROBOT,
                             latency=0.005, truth_t=run.truth_t, truth=run.truth)
    assert cal.wheel_distance == pytest.approx(run.true_wheel_distance, rel=0.003)
    assert cal.radius_ratio == pytest.approx(run.true_right_ratio / run.true_left_ratio,
                                             rel=0.003)
    true_mean = 0.5 * (run.true_left_ratio + run.true_right_ratio)
    assert cal.speed_ratio == pytest.approx(true_mean, rel=0.003)
    assert cal.windows_used > 100


@pytest.mark.parametrize("ratio", [0.98, 1.0, 1.005, 1.03])
def test_a_radius_ratio_is_the_ekfs_radius_mismatch_on_a_straight_drive(ratio):
    # the two wheels roll 2 cm each in one period; with the right radius `ratio` times the
    # left (the mean metres per tick kept) their ticks, read by the EKF's own wheel
    # measurement at the nominal metres per tick, turn by c times the speed they read
    from fusion.planar.model import ticks_measurement

    sr, period, wheel_distance, travel = 1e-4, 0.04, 0.3, 0.02
    left, right = travel / (sr * 2 / (1 + ratio)), travel / (sr * 2 * ratio / (1 + ratio))
    (v_m, w_m), _ = ticks_measurement(left, right, sr, period, wheel_distance, 1.0, 0.0, 0.0,
                                      0.0)
    assert w_m == pytest.approx(radius_mismatch_rate(ratio, wheel_distance) * v_m, abs=1e-15)
    c = radius_mismatch_rate(ratio, wheel_distance)
    assert radius_ratio_from_mismatch(c, wheel_distance) == pytest.approx(ratio, rel=1e-12)
    with pytest.raises(ValueError, match="no radius ratio gives"):
        radius_ratio_from_mismatch(2.0 / wheel_distance, wheel_distance)
    with pytest.raises(ValueError, match="must be finite and > 0"):
        radius_mismatch_rate(-ratio, wheel_distance)


@pytest.mark.parametrize("mismatch", [0.01, -0.01])
def test_the_ekf_learns_the_radius_mismatch_the_ratio_gives(mismatch, tmp_path):
    # the synthetic robot's wheels differ in radius by 1 % (either way); over 150 s the
    # fused EKF's own radius-mismatch state ends at the value the simulated radii give
    # (measured within 0.3 %): the sign and the size robot.toml's [ekf] wheel_rate_per_speed
    # takes from a calibration
    from fusion.io.robot_toml import read_robot_toml
    from fusion.jobs.replay import replay_logdir

    run = degraded_mission(seed=3, duration=150.0, radius_mismatch=mismatch,
                           separation_error=0.0, slip_patches=0)
    d = write_synthetic_run(tmp_path / "log", run)
    replay_logdir(d, tmp_path / "fused.csv")
    fused = np.genfromtxt(tmp_path / "fused.csv", delimiter=",", names=True)
    wheel_distance = read_robot_toml(d / "robot.toml").chassis.wheel_distance
    want = radius_mismatch_rate(run.true_right_ratio / run.true_left_ratio, wheel_distance)
    assert abs(want) > 0.03
    assert fused["wheel_rate_per_speed"][-1] == pytest.approx(want, rel=0.02)
