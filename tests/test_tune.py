"""``fusion tune``: k-fold cross-validated parameters from logs with truth.

The synthetic logs are driven by a robot whose true wheel separation is 3 % wider than its
robot.toml says (0.309 m against 0.300 m; no radius mismatch, no slip): tuning the odometry
must recover the true separation, and its cross-validated score must be the true geometry's.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from fusion.calibration.odometry import radius_mismatch_rate
from fusion.cli import main
from fusion.evaluation.crossval import kfold_splits
from fusion.evaluation.synthetic import degraded_mission
from fusion.io.logdir import read_logdir, write_synthetic_run
from fusion.io.robot_toml import read_robot_toml
from fusion.jobs import tune as job

NOMINAL = 0.300  # m, robot.toml's wheel_distance (EXAMPLE_ROBOT)
TRUE = NOMINAL * 1.03  # m, the simulated robot's


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("tune")
    for i in range(6):
        run = degraded_mission(seed=100 + i, duration=25.0, separation_error=0.03,
                               radius_mismatch=0.0, slip_patches=0)
        assert run.true_wheel_distance == pytest.approx(TRUE)
        write_synthetic_run(root / f"log{i}", run)
    return root


def test_tune_odometry_recovers_the_true_wheel_separation(logs, tmp_path, capsys):
    out = tmp_path / "robot.toml"
    assert main(["tune", "odometry", str(logs), "--folds", "3", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    tuned = read_robot_toml(out).chassis.wheel_distance
    # tolerance: 0.3 % of the separation (0.9 mm); the robot.toml was 3 % off
    assert tuned == pytest.approx(TRUE, rel=3e-3)
    assert f"wheel_distance = {tuned!r}" in printed  # the robot.toml section printed
    folds = re.findall(r"fold (\d): CV ([\d.]+)  in-sample ([\d.]+)  defaults ([\d.]+)", printed)
    assert sorted(f[0] for f in folds) == ["1", "2", "3"]
    cv, defaults = map(float, re.search(r"cross-validated ([\d.]+), defaults ([\d.]+)",
                                        printed).groups())
    # reference: every log's wheel-only yaw RMSE with the true geometry and with robot.toml's
    base = read_robot_toml(logs / "log0" / "robot.toml")
    true_robot = job.apply_parameters(base, {"wheel_distance": TRUE}, job.TARGETS["odometry"])
    assert re.search(r"# right/left wheel radius ratio 1\.000\d* ", printed)  # none simulated
    # the ratio goes to the EKF's radius mismatch, printed and in the robot.toml written
    ratio = float(re.search(r"radius ratio ([\d.]+)", printed)[1])
    c = read_robot_toml(out).ekf.wheel_rate_per_speed
    # the ratio is printed to 8 digits (+-5e-8: c within 2 * 5e-8 / 0.3 m)
    assert c == pytest.approx(radius_mismatch_rate(ratio, tuned), abs=5e-7)
    assert abs(c) < 0.01
    assert f"[ekf]\nwheel_rate_per_speed = {c:.6g}" in printed
    loaded = [read_logdir(p, imu_frame="imu") for p in sorted(logs.iterdir())]
    true_score = np.mean([job.odometry_yaw_rmse(true_robot, log) for log in loaded])
    default_score = np.mean([job.odometry_yaw_rmse(base, log) for log in loaded])
    assert defaults == pytest.approx(default_score, abs=1e-4)
    assert default_score > 1.0  # deg: the 3 % error shows
    assert cv == pytest.approx(true_score, abs=0.005)  # as good as the truth, held out


def test_umbmark_squares_separate_the_separation_from_the_radius_ratio(tmp_path):
    """cw and ccw squares of a robot with both systematic errors (Borenstein's types A and
    B): the separation alone would absorb the radius mismatch's yaw; both are recovered."""
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT, EncoderModel, ImuModel, simulate, square

    ratio = 1.0025 / 0.9975  # right/left radius: +-0.25 % per wheel
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025,
                       right_scale_error=0.0025)
    for direction in ("cw", "ccw"):
        for seed in (1, 2):
            run = simulate(square(side=2.0, direction=direction), EXAMPLE_ROBOT, ImuModel(),
                           enc, seed=seed)
            assert run.true_right_ratio / run.true_left_ratio == pytest.approx(ratio, rel=1e-9)
            write_synthetic_run(tmp_path / f"{direction}{seed}", run)
    base = read_robot_toml(tmp_path / "cw1" / "robot.toml")
    result = job.tune("odometry", [tmp_path], base, folds=2)
    assert result.final.values["wheel_distance"] == pytest.approx(TRUE, rel=3e-3)
    assert result.final.values["radius_ratio"] == pytest.approx(ratio, abs=5e-4)
    assert result.robot.chassis.wheel_distance == result.final.values["wheel_distance"]
    assert result.cv_score < 0.1 * result.default_score


def test_a_robot_with_a_radius_mismatch_starts_the_search_from_its_ratio(logs):
    # robot.toml keeps a radius ratio as its EKF's radius mismatch ([ekf]
    # wheel_rate_per_speed): the defaults the search starts from and scores are that ratio
    import dataclasses

    base = read_robot_toml(logs / "log0" / "robot.toml")
    c = radius_mismatch_rate(1.004, base.chassis.wheel_distance)
    calibrated = dataclasses.replace(base, ekf=dataclasses.replace(base.ekf,
                                                                   wheel_rate_per_speed=c))
    values = job.TARGETS["odometry"].base_values(calibrated)
    assert values["radius_ratio"] == pytest.approx(1.004, rel=1e-12)
    assert job.TARGETS["odometry"].base_values(base)["radius_ratio"] == 1.0
    back = job.apply_parameters(base, values, job.TARGETS["odometry"])
    assert back.ekf.wheel_rate_per_speed == pytest.approx(c, rel=1e-12)


def test_process_pool_gives_the_serial_result(logs):
    base = read_robot_toml(logs / "log0" / "robot.toml")
    serial = job.tune("odometry", [logs], base, folds=2, budget=8)
    pooled = job.tune("odometry", [logs], base, folds=2, budget=8, jobs=2)
    assert pooled.final.values == serial.final.values
    assert [f.test_scores for _, f in pooled.folds] == [f.test_scores for _, f in serial.folds]
    assert sorted(i for test, _ in serial.folds for i in test) == list(range(6))


def test_ekf_target_scores_the_fused_odometry(logs):
    """Two logs, two folds, a few evaluations: the search never ends worse than the
    defaults in-sample, and its held-out scores are real scores."""
    paths = sorted(logs.iterdir())[:2]
    base = read_robot_toml(paths[0] / "robot.toml")
    result = job.tune("ekf", paths, base, folds=2, budget=4)
    assert result.final.evaluations == 4
    assert result.final.train_score <= result.final.default_train_score
    assert set(result.final.values) == {"gyro_std", "bias_psd", "scale_std"}
    log = read_logdir(paths[1], imu_frame="imu")
    assert result.folds[1][1].default_test_scores == [job.fused_position_rmse(base, log)]
    assert "[ekf]\ngyro_std = " in job.tuned_section(result)


def test_a_log_without_truth_is_named(logs, tmp_path, capsys):
    folder = tmp_path / "logs"
    shutil.copytree(logs, folder)
    (folder / "log3" / "truth.csv").unlink()
    assert main(["tune", "odometry", str(folder)]) == 2
    assert f"{folder / 'log3'}: no truth.csv" in capsys.readouterr().err


def test_search_minimises_within_the_budget():
    calls = []

    def bowl(u):
        calls.append(u.copy())
        return float(np.sum((u - np.array([0.3, -0.2])) ** 2))

    u, value, n = job.search(bowl, [(-1.0, 1.0), (-1.0, 1.0)], 60)
    assert n == len(calls) <= 60
    assert np.all(calls[0] == 0.0)  # the defaults first
    assert u == pytest.approx([0.3, -0.2], abs=0.02)
    assert value == pytest.approx(bowl(u), abs=0) and value < 1e-3
    u1, value1, n1 = job.search(lambda u: float((u[0] - 0.4) ** 2), [(-1.0, 1.0)], 20)
    assert n1 <= 20 and u1[0] == pytest.approx(0.4, abs=1e-3) and value1 < 1e-6
    u0, _, n0 = job.search(bowl, [(-1.0, 1.0), (-1.0, 1.0)], 1)
    assert n0 == 1 and np.all(u0 == 0.0)


def test_kfold_splits_partition_the_runs():
    folds = kfold_splits(7, 3)
    tests = [t for _, t in folds]
    assert tests == [[0, 3, 6], [1, 4], [2, 5]]
    for train, test in folds:
        assert sorted(train + test) == list(range(7))
    assert [t for _, t in kfold_splits(4, 4)] == [[0], [1], [2], [3]]  # leave-one-out
    for n, k in ((3, 1), (3, 4)):
        with pytest.raises(ValueError, match="2 <= k <= runs"):
            kfold_splits(n, k)


def test_attitude_target_on_broad_trials():
    """Two bundled BROAD trials, two folds, three evaluations each: Keel's defaults are the
    first evaluation (their held-out score is the published recipe's inclination RMSE of
    the default Keel), and the printed [attitude] table names the filter."""
    from fusion.attitude.keel import Keel
    from fusion.evaluation.orientation import orientation_rmse
    from fusion.io.broad import read_broad

    broad = Path(__file__).resolve().parent.parent / "datasets" / "broad"
    trials = [broad / "14_undisturbed_slow_translation_with_breaks_B.mat",
              broad / "28_disturbed_stationary_magnet_A.mat"]
    result = job.tune("attitude", trials, folds=2, budget=3)
    assert result.final.evaluations == 3
    assert result.final.train_score <= result.final.default_train_score
    tr = read_broad(trials[0])
    q = Keel(axes=6).update_batch(tr.gyro, tr.accel, dt=1 / tr.rate)
    default = orientation_rmse(q, tr.quat_ref, tr.movement).inclination_deg
    assert result.folds[0][1].default_test_scores == [pytest.approx(default, rel=1e-12)]
    assert job.tuned_section(result).startswith('[attitude]\nfilter = "keel"\n')


def test_attitude_into_a_robot_toml(tmp_path, capsys):
    """-o needs the robot whose [attitude] table gets the values; the file written reads
    back with them (the other tables as they were)."""
    broad = Path(__file__).resolve().parent.parent / "datasets" / "broad"
    trials = [str(broad / "14_undisturbed_slow_translation_with_breaks_B.mat"),
              str(broad / "28_disturbed_stationary_magnet_A.mat")]
    out = tmp_path / "r.toml"
    assert main(["tune", "attitude", *trials, "-o", str(out), "--budget", "2"]) == 2
    assert "-o for the attitude target needs --robot" in capsys.readouterr().err
    assert not out.exists()
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT
    from fusion.io.robot_toml import write_robot_toml

    base = tmp_path / "base.toml"
    write_robot_toml(base, EXAMPLE_ROBOT)
    assert main(["tune", "attitude", *trials, "--robot", str(base), "-o", str(out), "--folds",
                 "2", "--budget", "2"]) == 0
    printed = capsys.readouterr().out
    written = read_robot_toml(out)
    assert written.attitude.filter == "keel"
    values = dict(written.attitude.params)
    assert set(values) == {"accel_time_constant", "motion_bias_sigma", "rest_bias_sigma",
                           "bias_drift"}
    for name, value in values.items():
        assert f"{name} = {value!r}" in printed
    assert written.chassis == read_robot_toml(base).chassis
