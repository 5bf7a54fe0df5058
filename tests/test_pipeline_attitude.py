"""The pipeline's attitude filter: Keel by default, Mahony selectable in robot.toml's
``[attitude]`` table (bad keys refused naming file:line), and what the wheels tell Keel.

Oracles: the filters run directly on the same samples and composed with the EKF by hand
(tests/tilt_rate_reference.py -> fuse); tests/keel_feed_reference.py (the feed as stated,
plain Python);
the simulator's truth (its robot drives on a level floor: the true tilt is 0).
"""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from keel_feed_reference import keel_by_hand  # tests/keel_feed_reference.py
from tilt_rate_reference import (  # tests/tilt_rate_reference.py
    heading_frame_ticks_by_hand,
    rest_gyro_bias_by_hand,
    tilt_rate_by_hand,
)

from fusion.attitude.keel import Keel
from fusion.attitude.mahony import Mahony
from fusion.evaluation.synthetic import (
    EXAMPLE_ROBOT,
    EncoderModel,
    ImuModel,
    Segment,
    random_mission,
    simulate,
    stop,
)
from fusion.io.errors import LogFormatError
from fusion.io.robot_toml import read_robot_toml, write_robot_toml
from fusion.io.run_config import ConfigError, load_config
from fusion.pipeline.core import FusionPipeline
from fusion.planar import _ekf_core as core
from fusion.planar.accel_slip import accel_slip_flags
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.imu_motion import imu_motion_codes
from fusion.planar.robot import AttitudeConfig, RobotConfig
from fusion.sinks.text import JsonLinesSink

CHASSIS = """[chassis]
wheel_distance = 0.3
speed_ratio = 0.0001
encode_sampling_time = 0.04
"""


@pytest.fixture(scope="module")
def run():
    """30 s random mission (turns, stops) with jittered stamps and a gyro bias."""
    imu = ImuModel(gyro_bias=(0.002, -0.001, math.radians(0.5)), vibration=0.3, jitter=0.0005)
    enc = EncoderModel(separation_error=0.03, jitter=0.002)
    return simulate(random_mission(30.0, seed=11), EXAMPLE_ROBOT, imu, enc, seed=11)


def _records(robot: RobotConfig, run, **kw) -> list:
    recs: list = []
    with FusionPipeline(robot, on_record=recs.append, **{"accel_slip": True, **kw}) as pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    return recs


def _fed(run) -> np.ndarray:
    """The gyro the pipeline's attitude filter sees: less the horizontal bias learnt at rest
    (tests/tilt_rate_reference.py)."""
    motion = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    return run.gyro - rest_gyro_bias_by_hand(RobotConfig(chassis=run.robot), run.imu_t,
                                             run.gyro, motion, run.wheel_t, run.ticks)


def _by_hand(run, q) -> np.ndarray:
    """The EKF's state after each wheel frame with the yaw rate of attitudes ``q``
    (tests/tilt_rate_reference.py) and the accelerometer's slip flags of the specific force
    as measured."""
    motion = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    rate = tilt_rate_by_hand(RobotConfig(chassis=run.robot), run.imu_t, run.gyro, q, motion,
                             run.wheel_t, run.ticks)
    slip = accel_slip_flags(run.robot.speed_ratio, run.robot.encode_sampling_time, run.imu_t,
                            run.accel[:, :2], rate, motion, run.wheel_t, run.ticks)
    ticks = heading_frame_ticks_by_hand(RobotConfig(chassis=run.robot), run.imu_t, q, rate,
                                        run.gyro[:, 2], run.wheel_t, run.ticks)
    track, _ = fuse(run.robot, run.imu_t, rate, run.wheel_t, ticks, EkfNoise(),
                    imu_motion=motion, wheel_slip=slip)
    return track.states[track.kind == core.EV_WHEELS]


def _xyvw(recs) -> np.ndarray:
    return np.array([[r.x, r.y, r.v, r.w] for r in recs])


def _toml(tmp_path, attitude: str):
    path = tmp_path / "robot.toml"
    path.write_text(CHASSIS + "\n[attitude]\n" + attitude, encoding="utf-8")
    return path


def test_robot_toml_selects_mahony_and_the_output_is_a_direct_mahony_run(run, tmp_path):
    robot = read_robot_toml(_toml(tmp_path, 'filter = "mahony"\nkp = 0.5\nki = 0.001\n'))
    assert robot.attitude == AttitudeConfig("mahony", (("kp", 0.5), ("ki", 0.001)))
    robot = RobotConfig(chassis=run.robot, attitude=robot.attitude)
    got = _xyvw(_records(robot, run))
    q = Mahony(0.5, 0.001, axes=6, sample_period=0.01).update_batch(_fed(run), run.accel,
                                                                    timestamps=run.imu_t)
    np.testing.assert_array_equal(got, _by_hand(run, q)[:, [0, 1, 3, 4]])
    # and it is not the default (Keel) output
    default = _xyvw(_records(RobotConfig(chassis=run.robot), run))
    assert not np.array_equal(got, default)


def test_robot_toml_selects_keel_parameters_and_the_feed(run, tmp_path):
    path = _toml(tmp_path, 'filter = "keel"\nwheel_knowledge = false\n'
                           'accel_time_constant = 2.0\n')
    att = read_robot_toml(path).attitude
    assert att == AttitudeConfig("keel", (("accel_time_constant", 2.0),), False)
    got = _xyvw(_records(RobotConfig(chassis=run.robot, attitude=att), run))
    q = Keel(sample_period=0.01, accel_time_constant=2.0).update_batch(
        _fed(run), run.accel, timestamps=run.imu_t)
    np.testing.assert_array_equal(got, _by_hand(run, q)[:, [0, 1, 3, 4]])
    # the default: Keel with its defaults, told the wheels' knowledge
    robot = RobotConfig(chassis=run.robot)
    want = keel_by_hand(robot, run.imu_t, _fed(run), run.accel, run.wheel_t, run.ticks)
    np.testing.assert_array_equal(_xyvw(_records(robot, run)),
                                  _by_hand(run, want)[:, [0, 1, 3, 4]])
    assert not np.array_equal(got, _xyvw(_records(robot, run)))


def test_attitude_table_round_trips_and_defaults_are_not_written(tmp_path):
    path = tmp_path / "robot.toml"
    robot = RobotConfig(chassis=EXAMPLE_ROBOT)
    write_robot_toml(path, robot)
    assert "[attitude]" not in path.read_text()
    assert read_robot_toml(path) == robot
    for att in (AttitudeConfig("mahony", (("kp", 0.3), ("rest_detection", False))),
                AttitudeConfig("keel", (("max_gap", 0.5),), False)):
        robot = RobotConfig(chassis=EXAMPLE_ROBOT, attitude=att)
        write_robot_toml(path, robot)
        assert read_robot_toml(path) == robot


@pytest.mark.parametrize("body, line, words", [
    ('filter = "madgwick"\n', 7, "filter must be one of 'keel', 'mahony', got 'madgwick'"),
    ('filter = "keel"\nkp = 1.0\n', 8, "unknown key 'kp' for the keel filter; allowed:"),
    ('filter = "mahony"\naccel_time_constant = 2.0\n', 8, "unknown key 'accel_time_constant'"),
    ('sample_period = 0.01\n', 7, "unknown key 'sample_period'"),
    ('accel_time_constant = "3"\n', 7, "accel_time_constant must be a number, got '3'"),
    ('accel_time_constant = -1.0\n', 7, "accel_time_constant must be finite and > 0"),
    ('filter = "mahony"\nkp = -0.5\n', 8, "kp must be finite and >= 0"),
    ('wheel_knowledge = 1\n', 7, "wheel_knowledge must be true or false, got 1"),
    ('filter = "mahony"\nwheel_knowledge = true\n', 8, "wheel_knowledge is a Keel input"),
    ('motion_bias_estimation = "yes"\n', 7, "motion_bias_estimation must be true or false"),
])
def test_bad_attitude_keys_are_refused_naming_file_and_line(tmp_path, body, line, words):
    path = _toml(tmp_path, body)
    with pytest.raises(LogFormatError) as err:
        read_robot_toml(path)
    assert f"{path}:{line}: [attitude]" in str(err.value)
    assert words in str(err.value)


def test_run_config_takes_the_attitude_table(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text('[attitude]\nfilter = "mahony"\n', encoding="utf-8")
    assert load_config(path).robot.attitude == AttitudeConfig("mahony")
    path.write_text('[imu]\nrate_hz = 100.0\n\n[attitude]\nfilter = "keel"\nkp = 2.0\n',
                    encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"{path}:6: \[attitude\] unknown key 'kp'"):
        load_config(path)


def test_a_configured_filter_is_passed_as_attitude_and_mahony_still_works(run):
    robot = RobotConfig(chassis=run.robot)
    by_arg = _xyvw(_records(robot, run, attitude=Mahony(axes=6, sample_period=0.01)))
    by_toml = _xyvw(_records(RobotConfig(chassis=run.robot,
                                         attitude=AttitudeConfig("mahony")), run))
    np.testing.assert_array_equal(by_arg, by_toml)
    with pytest.warns(DeprecationWarning, match="attitude="):
        old = _xyvw(_records(robot, run, mahony=Mahony(axes=6, sample_period=0.01)))
    np.testing.assert_array_equal(old, by_toml)
    with pytest.raises(ValueError, match="not both"):
        FusionPipeline(robot, attitude=Keel(), mahony=Mahony())
    with pytest.raises(ValueError, match="give one"):
        FusionPipeline(RobotConfig(chassis=run.robot, attitude=AttitudeConfig("mahony")),
                       attitude=Keel())
    with pytest.raises(ValueError, match="Keel input"):
        FusionPipeline(RobotConfig(chassis=run.robot,
                                   attitude=AttitudeConfig(wheel_knowledge=True)),
                       attitude=Mahony())
    with pytest.raises(TypeError, match="Keel or a Mahony"):
        FusionPipeline(robot, attitude=object())


def _jsonl(robot, run, events) -> str:
    buf = io.StringIO()
    with FusionPipeline(robot, [JsonLinesSink(buf, flush=False)],
                        sources=("imu", "wheels", "twist")) as pipe:
        if events == "batch":
            pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks,
                             *run.twists)
        else:
            for kind, i in events:
                if kind == 0:
                    pipe.push_arrays(run.imu_t[i:i + 1], run.gyro[i:i + 1],
                                     run.accel[i:i + 1], flush=False)
                elif kind == 1:
                    pipe.push_arrays(wheel_t=run.wheel_t[i:i + 1], ticks=run.ticks[i:i + 1],
                                     flush=False)
                else:
                    pipe.push_twist(*(float(x[i]) for x in run.twists))
    return buf.getvalue()


def test_streaming_equals_batch_with_wheels_twists_and_a_stalled_wheel_stream(run):
    """The feed depends only on what arrived before each IMU sample: one event at a time
    (wheel frames, twists and IMU samples interleaved, wheels silent for 2 s) gives the
    same bytes as one call, and the same attitudes as the plain-Python reference."""
    keep = (run.wheel_t < 10.0) | (run.wheel_t > 12.0)  # a 2 s stall: the feed goes stale
    twist_t = np.arange(0.013, 30.0, 0.1)
    twist_v = np.interp(twist_t, run.truth_t, run.truth_v)
    twist_w = np.interp(twist_t, run.truth_t, run.truth_w)

    class Run:
        robot = run.robot
        imu_t, gyro, accel = run.imu_t, run.gyro, run.accel
        wheel_t, ticks = run.wheel_t[keep], run.ticks[keep]
        twists = (twist_t, twist_v, twist_w)

    order = sorted([(t, 0, i) for i, t in enumerate(Run.imu_t.tolist())]
                   + [(t, 1, i) for i, t in enumerate(Run.wheel_t.tolist())]
                   + [(t, 2, i) for i, t in enumerate(twist_t.tolist())])
    robot = RobotConfig(chassis=run.robot)
    batch = _jsonl(robot, Run, "batch")
    assert batch.count("\n") == Run.wheel_t.size + twist_t.size
    assert _jsonl(robot, Run, [(k, i) for _, k, i in order]) == batch
    # without the twists, against the reference (the stall included)
    want = keel_by_hand(robot, Run.imu_t, _fed(Run), Run.accel, Run.wheel_t, Run.ticks)
    np.testing.assert_array_equal(_xyvw(_records(robot, Run)),
                                  _by_hand(Run, want)[:, [0, 1, 3, 4]])


def test_the_wheels_knowledge_removes_the_lean_in_a_sustained_turn():
    """A 20 s circle at 0.8 m/s and 0.5 rad/s (centripetal v*w = 0.4 m/s^2, 2.3 deg if
    taken for gravity) between stops, on a level floor (true tilt 0). Without the wheels'
    knowledge Keel leans about 1.9 deg in the steady turn and 3.5 deg at the stop; told v*w
    and dv/dt it stays within 0.3 deg throughout."""
    imu = ImuModel(gyro_bias=(0.002, -0.001, math.radians(0.5)), vibration=0.3)
    sim = simulate([*stop(2.0), Segment(0.8, 0.5, 20.0), *stop(3.0)], EXAMPLE_ROBOT, imu,
                   EncoderModel(separation_error=0.03), seed=7)

    def tilt(att: AttitudeConfig):
        recs = _records(RobotConfig(chassis=sim.robot, attitude=att), sim)
        q = np.array([r.orientation for r in recs])
        t = np.array([r.t for r in recs])
        deg = np.degrees(np.arccos(np.clip(1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))
        steady = (t > 12.0) & (t < 22.0)  # the turn, 10 s after it began
        return deg[steady].mean(), deg.max()

    fed_turn, fed_max = tilt(AttitudeConfig())
    blind_turn, blind_max = tilt(AttitudeConfig(wheel_knowledge=False))
    assert blind_turn > 1.5 and blind_max > 3.0  # the effect is real
    assert fed_turn < 0.2 and fed_max < 0.3


def test_turning_wheels_keep_a_slow_spin_from_being_learnt_as_gyro_bias():
    """A spin in place at 1 deg/s after 4 s at rest (true gyro bias 0.5 deg/s about z). To
    the IMU alone the spin looks like rest (below Keel's 2 deg/s rest thresholds), so Keel
    learns spin + bias, 1.5 deg/s; told that the wheels turn, it keeps what it learnt at
    rest (within 0.15 deg/s of the truth)."""
    imu = ImuModel(gyro_bias=(0.002, -0.001, math.radians(0.5)), vibration=0.3)
    sim = simulate([*stop(4.0), Segment(0.0, math.radians(1.0), 30.0)], EXAMPLE_ROBOT, imu,
                   EncoderModel(), seed=3)

    def bias_z(att: AttitudeConfig) -> float:
        with FusionPipeline(RobotConfig(chassis=sim.robot, attitude=att)) as pipe:
            pipe.push_arrays(sim.imu_t, sim.gyro, sim.accel, sim.wheel_t, sim.ticks)
        return math.degrees(pipe.attitude.gyro_bias[2])

    assert abs(bias_z(AttitudeConfig(wheel_knowledge=False)) - 1.5) < 0.1
    assert abs(bias_z(AttitudeConfig()) - 0.5) < 0.15
