"""``fusion replay LOGDIR``: output CSV, agreement with the library, summary, errors."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from fusion.cli import main
from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.geometry.quaternion import from_euler, rotate_inverse
from fusion.io.fused_csv import FUSED_CSV_COLUMNS, read_fused_csv
from fusion.io.logdir import write_logdir, write_synthetic_run
from fusion.planar.ekf import fuse
from fusion.planar.imu_motion import imu_motion_codes
from fusion.planar.robot import RobotConfig


@pytest.fixture(scope="module")
def run():
    return degraded_mission(seed=4, duration=60.0)


@pytest.fixture(scope="module")
def logdir(run, tmp_path_factory):
    return write_synthetic_run(tmp_path_factory.mktemp("logs") / "run4", run)


def _read(path):
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    cols = read_fused_csv(path)
    return header, np.column_stack([cols[name] for name in FUSED_CSV_COLUMNS])


def test_replay_writes_the_fused_track(run, logdir, tmp_path, capsys):
    out = tmp_path / "fused.csv"
    assert main(["replay", str(logdir), "-o", str(out), "--level"]) == 0
    header, data = _read(out)
    assert tuple(header) == FUSED_CSV_COLUMNS
    assert header[:6] == ["t", "x", "y", "yaw", "v", "w"]
    # one row per IMU sample: the whole run
    assert data.shape == (run.imu_t.size, len(FUSED_CSV_COLUMNS))
    np.testing.assert_allclose(data[:, 0], run.imu_t, atol=1e-9)
    # the same numbers as the library on the same (level) gyro rates
    track, _ = fuse(EXAMPLE_ROBOT, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                    imu_motion=imu_motion_codes(run.imu_t, run.gyro, run.accel))
    gyro = track.kind == 0
    np.testing.assert_allclose(data[:, 1:3], track.states[gyro, :2], rtol=1e-9, atol=1e-9)
    assert np.all(np.abs(data[:, 3]) <= math.pi)
    # accuracy against the truth the simulator wrote
    truth = run.truth_at(data[:, 0])
    err = math.hypot(*(data[-1, 1:3] - truth[-1, :2]))
    assert err / run.distance < 0.005
    text = capsys.readouterr().out
    assert "fused:      final position error" in text
    assert "wheel only: final position error" in text
    assert "slip frames" in text


def test_mounted_imu_and_tilt_compensation(run, tmp_path):
    # The IMU mounted rotated (roll 180 deg, yaw 90 deg): the log holds IMU-frame vectors and
    # robot.toml the mount. Replay (tilt-compensated by the attitude) must match the level replay
    # of the base-frame log closely.
    rpy = (math.pi, 0.0, math.pi / 2)
    q = from_euler(*rpy)
    d = write_logdir(tmp_path / "mounted", RobotConfig(EXAMPLE_ROBOT, imu_mount_rpy=rpy),
                     run.imu_t, rotate_inverse(q, run.gyro), rotate_inverse(q, run.accel),
                     run.wheel_t, run.ticks, run.truth_t, run.truth)
    plain = tmp_path / "plain.csv"
    mounted = tmp_path / "mounted.csv"
    base = write_logdir(tmp_path / "base", EXAMPLE_ROBOT, run.imu_t, run.gyro, run.accel,
                        run.wheel_t, run.ticks)
    assert main(["replay", str(base), "-o", str(plain), "--level"]) == 0
    assert main(["replay", str(d), "-o", str(mounted)]) == 0
    _, a = _read(plain)
    _, b = _read(mounted)
    assert a.shape == b.shape
    yaw_diff = np.degrees(np.abs(np.angle(np.exp(1j * (a[:, 3] - b[:, 3])))))
    assert yaw_diff.max() < 0.5
    assert np.hypot(*(a[-1, 1:3] - b[-1, 1:3])) < 0.05


def test_an_imu_csv_stamped_in_batches_replays_like_the_on_time_one(run, logdir, tmp_path,
                                                                     capsys):
    # imu.csv as a logger writes it that reads the IMU's FIFO eight samples at a time and
    # stamps each as it handles it, 10 us apart: without fusion.io.repeated_stamps the
    # replay refused it ("the samples are 1e-05 s apart (median of t), a rate of 1e+05 Hz";
    # 0.1 ms apart it would have run the attitude filter at 10 kHz: see test_terrain_bag).
    batch = 8
    n = run.imu_t.size // batch * batch
    read = np.repeat(run.imu_t[batch - 1:n:batch], batch)
    stamps = read + np.tile(np.arange(batch) * 1e-5, n // batch)
    d = write_logdir(tmp_path / "batched", EXAMPLE_ROBOT, stamps, run.gyro[:n], run.accel[:n],
                     run.wheel_t, run.ticks)
    on_time = write_logdir(tmp_path / "on_time", EXAMPLE_ROBOT, run.imu_t[:n], run.gyro[:n],
                           run.accel[:n], run.wheel_t, run.ticks)
    assert main(["replay", str(on_time), "-o", str(tmp_path / "a.csv")]) == 0
    capsys.readouterr()
    assert main(["replay", str(d), "-o", str(tmp_path / "b.csv")]) == 0
    text = capsys.readouterr().out
    said = [ln for ln in text.splitlines() if "stamped less than" in ln]
    assert len(said) == 1 and f"{n - n // batch} messages" in said[0], text
    _, a = _read(tmp_path / "a.csv")
    _, b = _read(tmp_path / "b.csv")
    assert a.shape == b.shape
    # every sample back on its own time (the first batch: on the period before its read)
    np.testing.assert_allclose(b[batch:, 0], a[batch:, 0], rtol=0, atol=1e-6)
    assert np.hypot(*(a[-1, 1:3] - b[-1, 1:3])) < 0.01
    yaw_diff = np.degrees(np.abs(np.angle(np.exp(1j * (a[:, 3] - b[:, 3])))))
    assert yaw_diff.max() < 0.1


def test_wheels_only_log(run, tmp_path, capsys):
    d = write_logdir(tmp_path / "w", EXAMPLE_ROBOT, wheel_t=run.wheel_t, ticks=run.ticks)
    out = tmp_path / "w.csv"
    assert main(["replay", str(d), "-o", str(out)]) == 0
    _, data = _read(out)
    assert data.shape[0] == run.wheel_t.size
    assert "wheel odometry only" in capsys.readouterr().out


def test_errors_exit_2_with_a_message(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "missing"), "-o", str(tmp_path / "o.csv")]) == 2
    assert "no such log directory" in capsys.readouterr().err
    (tmp_path / "f.csv").write_bytes(b"")
    assert main(["replay", str(tmp_path / "f.csv"), "-o", str(tmp_path / "o.csv")]) == 2
    assert "replay takes a log directory" in capsys.readouterr().err
    (tmp_path / "f.bag").write_bytes(b"")
    assert main(["replay", str(tmp_path / "f.bag"), "--imu-topic", "/imu", "--odom-topic",
                 "/odom", "-o", str(tmp_path / "o.csv")]) == 2
    assert "f.bag" in capsys.readouterr().err
    d = tmp_path / "bad"
    d.mkdir()
    (d / "robot.toml").write_text("[chassis]\nwheel_distance = 0.3\n")
    assert main(["replay", str(d), "-o", str(tmp_path / "o.csv")]) == 2
    assert "robot.toml:1: [chassis] needs speed_ratio" in capsys.readouterr().err  # with its line
    assert not (tmp_path / "o.csv").exists()


def test_a_gyro_reading_exactly_zero_through_turns_is_refused(run, tmp_path, capsys):
    # imu.csv whose rates are all 0 (a recorder that wrote the orientation and no rates):
    # fused, the heading stayed straight through every turn. Refused, naming the file and
    # the turns the wheels made; the same gyro on a log that never turns is replayed (a
    # driver's deadband reads exactly 0 at rest).
    wheel_turn = np.sum(np.abs(np.diff(run.truth[:, 2])))
    assert wheel_turn > 1.0  # the mission turns
    zero = np.zeros_like(run.gyro)
    d = write_logdir(tmp_path / "z", EXAMPLE_ROBOT, run.imu_t, zero, run.accel, run.wheel_t,
                     run.ticks)
    out = tmp_path / "z.csv"
    assert main(["replay", str(d), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(d / "imu.csv") in err and "exactly 0 while the odometry turned" in err, err
    assert not out.exists()
    straight = np.column_stack([run.ticks[:, 0], run.ticks[:, 0]])  # both wheels alike
    d = write_logdir(tmp_path / "s", EXAMPLE_ROBOT, run.imu_t, zero, run.accel, run.wheel_t,
                     straight)
    assert main(["replay", str(d), "-o", str(out)]) == 0


def test_imu_and_wheels_on_different_clocks_are_refused(logdir, tmp_path, capsys):
    # wheels.csv moved onto another clock (a day later): no stamp of it overlaps imu.csv's
    import shutil

    d = tmp_path / "clocks"
    shutil.copytree(logdir, d)
    lines = (d / "wheels.csv").read_text().splitlines()
    moved = [lines[0]] + [",".join([repr(float(r.split(",")[0]) + 86400.0),
                                    *r.split(",")[1:]]) for r in lines[1:]]
    (d / "wheels.csv").write_text("\n".join(moved) + "\n")
    assert main(["replay", str(d), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "they do not overlap, so they are on different clocks" in err, err
    assert "wheel frames" in err and not (tmp_path / "o.csv").exists()


def test_real_command_line(logdir, tmp_path):
    out = tmp_path / "cli.csv"
    proc = subprocess.run([sys.executable, "-m", "fusion", "replay", str(logdir), "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert out.read_text().startswith("t,x,y,yaw,v,w,")


def test_replay_of_the_sample_ros_bag(datasets_dir, tmp_path, capsys):
    # Plumbing only: the bag is a simulated Jackal whose odometry twist and gyro disagree
    # (datasets/rosbag/README.md), so no accuracy is claimed; the run must be complete.
    pytest.importorskip("rosbags")
    bag = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    out = tmp_path / "jackal.csv"
    assert main(["replay", str(bag), "--imu-topic", "/imu/data", "--odom-topic",
                 "/jackal_velocity_controller/odom", "-o", str(out)]) == 0
    header, data = _read(out)
    assert tuple(header) == FUSED_CSV_COLUMNS
    assert data.shape[0] == 3061  # one row per IMU message
    assert data[0, 0] == pytest.approx(47.58)
    assert np.all(np.isfinite(data[:, :17]))
    assert np.all(np.isnan(data[:, 17:19]))  # a bag's twists carry no wheel speeds
    assert set(np.unique(data[:, 19:22]).tolist()) <= {0.0, 1.0}  # zupt, slip, fault flags
    assert np.all(np.diff(data[:, 0]) > 0)
    text = capsys.readouterr().out
    assert "3061 IMU messages (base_link), 3060 odometry messages (odom -> base_link)" in text
    assert main(["replay", str(bag), "-o", str(out)]) == 2
    assert "needs --imu-topic" in capsys.readouterr().err
    assert main(["replay", str(bag), "--imu-topic", "/imu", "--odom-topic", "/odom",
                 "-o", str(out)]) == 2
    assert "no topic '/imu'" in capsys.readouterr().err


def test_tilt_compensation_of_an_unknown_imu_tilt(tmp_path):
    # The IMU sits 4 deg rolled and 6 deg pitched on the base, and robot.toml does not know:
    # the gyro's z axis then sees the yaw rate scaled by about cos(7 deg) and mixed with x, y.
    # The attitude filter (gravity) finds the tilt and the vertical rate restores the heading.
    # Measured when written (seed 2, 300 s): level 2.10 % / 4.25 deg, compensated 0.36 % /
    # 0.71 deg.
    from fusion.evaluation.trajectory import final_position_error_percent, yaw_rmse
    from fusion.jobs.replay import replay_logdir

    run = degraded_mission(seed=2, duration=300.0)
    q = from_euler(math.radians(4.0), math.radians(-6.0), 0.3)
    d = write_logdir(tmp_path / "tilted", EXAMPLE_ROBOT, run.imu_t, rotate_inverse(q, run.gyro),
                     rotate_inverse(q, run.accel), run.wheel_t, run.ticks)
    result = {}
    for tilt in (True, False):
        replay_logdir(d, tmp_path / "f.csv", tilt=tilt)
        f = read_fused_csv(tmp_path / "f.csv")
        truth = run.truth_at(f["t"])
        xy = np.column_stack([f["x"], f["y"]])
        result[tilt] = (
            final_position_error_percent(xy, truth, run.distance),
            math.degrees(yaw_rmse(f["yaw"], truth[:, 2])),
        )
    assert result[True][0] <= 0.5 and result[True][1] <= 1.5
    assert result[False][0] > 1.0 and result[False][1] > 3.0


def test_synth_then_replay_and_calibrate(tmp_path, capsys):
    d = tmp_path / "run"
    assert main(["synth", str(d), "--seed", "5", "--duration", "120"]) == 0
    out = capsys.readouterr().out
    assert "true wheel_distance 0.309 m (robot.toml says 0.3)" in out
    assert sorted(p.name for p in d.iterdir()) == [
        "imu.csv", "robot.toml", "truth.csv", "wheels.csv"]
    # identical to the library's degraded mission with the same seed
    again = write_synthetic_run(tmp_path / "again", degraded_mission(seed=5, duration=120.0))
    for name in ("imu.csv", "wheels.csv", "truth.csv", "robot.toml"):
        assert (d / name).read_bytes() == (again / name).read_bytes()
    assert main(["replay", str(d), "-o", str(tmp_path / "f.csv")]) == 0
    assert "fused:      final position error" in capsys.readouterr().out
    assert main(["calibrate", "odometry", str(d)]) == 0
    assert "wheel_distance = 0.309" in capsys.readouterr().out
    assert main(["synth", str(d)]) == 2  # not empty
    assert "not empty" in capsys.readouterr().err


def test_synth_squares_feed_umbmark(tmp_path, capsys):
    dirs = {}
    for direction in ("cw", "ccw"):
        dirs[direction] = str(tmp_path / direction)
        assert main(["synth", dirs[direction], "--scenario", "square", "--direction",
                     direction]) == 0
    capsys.readouterr()
    assert main(["calibrate", "umbmark", "--cw", dirs["cw"], "--ccw", dirs["ccw"]]) == 0
    out = capsys.readouterr().out
    assert "E_d = D_R/D_L = 1.005" in out
