"""Validation at every public setter and configuration (issue 12, item 6), table-driven: NaN,
infinities, zero or negative noise and absurd rates raise ``ValueError`` naming the parameter
and the value (configuration files: the file, line and key); nothing reaches the compiled
cores as a crash or a poisoned state."""

from __future__ import annotations

import math
import textwrap
from dataclasses import fields

import numpy as np
import pytest

from drivers.mpu6050 import MPU6050
from drivers.serial_link import ChassisLink
from drivers.sim.mpu6050 import SimulatedMPU6050
from fusion.attitude.keel import KeelParams
from fusion.attitude.mahony import Mahony, MahonyParams
from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.io.errors import LogFormatError
from fusion.io.robot_toml import read_robot_toml
from fusion.io.run_config import ConfigError, RunConfig, load_config
from fusion.pipeline.core import FusionPipeline
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import EkfNoise, PlanarEKF
from fusion.planar.model import NX
from fusion.planar.robot import RobotConfig
from fusion.types.constants import STANDARD_GRAVITY as G
from fusion.types.samples import ImuSample, WheelTicks

NAN, INF = math.nan, math.inf
UP = np.array([0.0, 0.0, G])


def raises_naming(call, *words):
    """``call()`` raises ValueError whose message contains every one of ``words``."""
    with pytest.raises(ValueError) as info:
        call()
    for w in words:
        assert w in str(info.value), (w, str(info.value))
    return info.value


def assert_names_file_line(error, call, path, line, words):
    """``call()`` raises ``error`` whose message starts with ``path:line:`` and names
    ``words``."""
    with pytest.raises(error) as info:
        call()
    msg = str(info.value)
    assert msg.startswith(f"{path}:{line}:") and all(w in msg for w in words), (words, msg)


# -- EkfNoise ---------------------------------------------------------------------------------

EKF_BAD = [
    ("gyro_std", 0.0), ("gyro_std", NAN), ("gyro_std", -1e-3),
    ("tick_std", 0.0), ("twist_v_std", 0.0), ("twist_w_std", INF),
    ("zupt_v_std", 0.0), ("initial_speed_std", 0.0), ("initial_bias_std", NAN),
    ("accel_psd", -0.1), ("accel_psd", INF), ("bias_psd", NAN), ("scale_std", -1.0),
    ("slip_gate", 0.0), ("slip_inflation", NAN), ("late_tolerance", -0.01),
    ("max_dt", 0.0), ("max_dt", INF), ("max_extrapolation", 0.0), ("max_extrapolation", NAN),
    ("max_rate", INF), ("max_speed", 0.0), ("wheel_latency", INF), ("still_scale", 2.0),
    ("zupt_frames", 0), ("zupt_frames", 2.5), ("gyro_limit", 0.0), ("gyro_limit", NAN),
    ("max_dt", 1e-9),  # absurd: 5e8 prediction steps per input
    ("twist_zero_v", True),  # not a number
]


@pytest.mark.parametrize(("name", "value"), EKF_BAD)
def test_ekf_noise_refuses_a_bad_value_naming_field_and_value(name, value):
    raises_naming(lambda: EkfNoise(**{name: value}), f"EkfNoise.{name}", repr(value))


def test_all_zero_ekf_noise_is_refused():
    raises_naming(lambda: EkfNoise(**{f.name: 0.0 for f in fields(EkfNoise)}), "EkfNoise.")


@pytest.mark.parametrize("name", [f.name for f in fields(EkfNoise)])
def test_every_field_at_zero_is_refused_or_runs_without_a_crash(name):
    """A zero that passes validation (a switched-off noise term or a random walk) must not
    reach a division by zero in the compiled core: a run with moving, still and slipping
    frames, gyro samples and twists stays finite."""
    try:
        noise = EkfNoise(**{name: 0 if name == "zupt_frames" else 0.0})
    except ValueError:
        return
    ekf = PlanarEKF(EXAMPLE_ROBOT, noise)
    T = EXAMPLE_ROBOT.encode_sampling_time
    for k in range(200):
        t = k * 0.01
        ekf.update_gyro(t, 0.3 if k > 100 else 0.0)
        if k % 4 == 3:
            ticks = (0, 0) if k < 60 else (40, 90) if k < 150 else (40, 400)  # still, turn, slip
            ekf.update_wheels(t + 0.5 * T, *ticks)
        if k % 10 == 5:
            ekf.update_twist(t, 0.1, 0.3)
    assert np.all(np.isfinite(ekf.x)) and np.all(np.isfinite(ekf.P))


# -- attitude filters -------------------------------------------------------------------------

MAHONY_BAD = [
    ("kp", NAN), ("kp", -1.0), ("ki", INF), ("gravity", 0.0), ("rest_gyro_threshold", NAN),
    ("rest_min_duration", -1.0), ("ramp_time", INF), ("max_gap", 0.0), ("max_gyro", INF),
    ("max_accel", NAN), ("sample_period", 0.0), ("sample_period", NAN),
    ("sample_period", 1.0),  # longer than max_gap: every sample a gap
    ("accel_rejection", -1.0), ("rest_detection", "yes"),
]


@pytest.mark.parametrize(("name", "value"), MAHONY_BAD)
def test_mahony_params_refuse_a_bad_value(name, value):
    words = ["sample period dt"] if name == "sample_period" and value != 1.0 else [name]
    raises_naming(lambda: MahonyParams(**{name: value}), *words, repr(value))


KEEL_BAD = [
    ("accel_time_constant", 0.0), ("bias_drift", NAN), ("motion_bias_sigma", -1.0),
    ("max_gap", INF), ("max_gyro", 0.0), ("max_accel", NAN), ("mag_gate_scale", INF),
    ("rest_min_duration", NAN), ("sample_period", 1.0), ("motion_bias_estimation", 1),
    ("bias_clip", True),
]


@pytest.mark.parametrize(("name", "value"), KEEL_BAD)
def test_keel_params_refuse_a_bad_value(name, value):
    raises_naming(lambda: KeelParams(**{name: value}), name, repr(value))


@pytest.mark.parametrize(
    ("bias", "words"),
    [
        ([NAN, 0.0, 0.0], ["gyro_bias", "finite"]),
        ([0.0, INF, 0.0], ["gyro_bias", "finite"]),
        ([0.0, 0.0, 1e200], ["gyro_bias", "max_gyro"]),
        ([0.0, 0.0], ["gyro_bias", "3 components"]),
    ],
)
def test_mahony_gyro_bias_setter_refuses_bad_values_and_keeps_the_state(bias, words):
    f = Mahony(sample_period=0.01)
    f.update(np.zeros(3), UP)
    state = f.get_state()

    def set_it():
        f.gyro_bias = bias

    raises_naming(set_it, *words)
    np.testing.assert_array_equal(f.get_state().integral, state.integral)
    assert np.all(np.isfinite(f.update(np.zeros(3), UP)))


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"quaternion": np.array([NAN, 0, 0, 0])}, ["state.quaternion"]),
        ({"quaternion": np.zeros(4)}, ["state.quaternion", "non-zero"]),
        ({"integral": np.array([0, NAN, 0])}, ["state.integral"]),
        ({"gyro_lowpass": np.array([0, 0, 1e200])}, ["state.gyro_lowpass", "max_gyro"]),
        ({"accel_lowpass": np.array([INF, 0, 0])}, ["state.accel_lowpass"]),
        ({"elapsed": -1.0}, ["state.elapsed"]),
        ({"rest_timer": NAN}, ["state.rest_timer"]),
        ({"last_period": INF}, ["state.last_period"]),
        ({"last_timestamp": NAN}, ["state.last_timestamp"]),
    ],
)
def test_mahony_set_state_refuses_a_poisoned_state_and_keeps_its_own(change, words):
    f = Mahony(sample_period=0.01)
    for _ in range(5):
        f.update(np.zeros(3), UP)
    good = f.get_state()
    bad = f.get_state()
    for k, v in change.items():
        setattr(bad, k, v)
    raises_naming(lambda: f.set_state(bad), *words)
    np.testing.assert_array_equal(f.quaternion, good.quaternion)
    assert f.get_state().elapsed == good.elapsed


# -- robot and run configuration --------------------------------------------------------------

@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"imu_mount_rpy": (NAN, 0.0, 0.0)}, ["imu_mount_rpy", "nan"]),
        ({"imu_mount_rpy": (0.0, INF, 0.0)}, ["imu_mount_rpy", "inf"]),
        ({"imu_mount_rpy": (0.0, 0.0)}, ["imu_mount_rpy"]),
        ({"odom_frame": ""}, ["odom_frame"]),
        ({"base_frame": " base"}, ["base_frame"]),
        ({"ekf": {"gyro_std": 1.0}}, ["RobotConfig.ekf"]),
        ({"chassis": None}, ["RobotConfig.chassis"]),
    ],
)
def test_robot_config_refuses_bad_values(change, words):
    kw = {"chassis": EXAMPLE_ROBOT, **change}
    raises_naming(lambda: RobotConfig(**kw), *words)


CHASSIS = "[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\nencode_sampling_time = 0.04\n"


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        (CHASSIS + "[ekf]\ngyro_std = nan\n", 6, ["[ekf]", "gyro_std", "nan"]),
        (CHASSIS + "[ekf]\ntick_std = 0.0\n", 6, ["[ekf]", "tick_std", "> 0"]),
        (CHASSIS + "[ekf]\nmax_extrapolation = inf\n", 6, ["max_extrapolation", "inf"]),
        (CHASSIS + "[ekf]\nzupt_frames = 2.5\n", 6, ["zupt_frames", "2.5"]),
        (CHASSIS + "[frames]\nimu_mount_rpy = [nan, 0.0, 0.0]\n", 6, ["imu_mount_rpy", "nan"]),
        (CHASSIS + "[frames]\nodom = ''\n", 6, ["[frames] odom"]),
        (CHASSIS + "[attitude]\nfilter = 'keel'\nmax_gap = nan\n", 7, ["[attitude] max_gap"]),
        (CHASSIS + "[attitude]\nfilter = 'mahony'\nmax_gyro = 0\n", 7,
         ["[attitude] max_gyro", "> 0"]),
        ("[chassis]\nwheel_distance = inf\nspeed_ratio = 5e-5\nencode_sampling_time = 0.04\n", 2,
         ["wheel_distance", "inf"]),
    ],
)
def test_robot_toml_names_file_line_and_key(tmp_path, text, line, words):
    path = tmp_path / "robot.toml"
    path.write_text(textwrap.dedent(text))
    assert_names_file_line(LogFormatError, lambda: read_robot_toml(path), path, line, words)


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("[imu]\nrate_hz = nan\n", 2, ["[imu] rate_hz", "nan"]),
        ("[imu]\nfifo_interval = 0\n", 2, ["[imu] fifo_interval", "> 0.0"]),
        ("[run]\nspeed = inf\n", 2, ["[run] speed", "inf"]),
        ("[publish]\nreorder_window = nan\n", 2, ["[publish] reorder_window", "nan"]),
        ("[link]\ncommand_timeout = -1\n", 2, ["[link] command_timeout", "-1"]),
        (CHASSIS + "[ekf]\nbias_psd = -1e-9\n", 6, ["[ekf]", "bias_psd"]),
    ],
)
def test_run_config_file_names_file_line_and_key(tmp_path, text, line, words):
    path = tmp_path / "run.toml"
    path.write_text(text)
    assert_names_file_line(ConfigError, lambda: load_config(path), path, line, words)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"imu_rate_hz": NAN}, ["--rate", "rate_hz", "nan"]),
        ({"speed": 50.0}, ["--speed", "50.0"]),
        ({"status": -1.0}, ["--status", "-1.0"]),
        ({"duration": INF}, ["--duration", "inf"]),
        ({"imu_address": 0x200}, ["--address", "512"]),
        ({"baudrate": 0}, ["--baudrate", "0"]),
        ({"publish": ("bogus",)}, ["--publish", "bogus"]),
        ({"fifo_interval": NAN}, ["RunConfig.fifo_interval", "nan"]),  # no option: the field
    ],
)
def test_run_config_overrides_name_the_option_and_value(change, words):
    raises_naming(lambda: RunConfig().with_overrides(**change), *words)
    raises_naming(lambda: RunConfig(**change), "RunConfig.", *words[1:])


# -- pipeline and drivers ---------------------------------------------------------------------

ROBOT_CONFIG = RobotConfig(chassis=EXAMPLE_ROBOT)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"imu_rate_hz": NAN}, ["imu_rate_hz", "nan"]),
        ({"imu_rate_hz": 0.0}, ["imu_rate_hz", "0.0"]),
        ({"imu_rate_hz": 1e9}, ["imu_rate_hz", "1000000000.0"]),
        ({"publish_rate_hz": INF}, ["publish_rate_hz", "inf"]),
        ({"publish_rate_hz": -10.0}, ["publish_rate_hz"]),
        ({"reorder_window": NAN}, ["reorder_window", "nan"]),
        ({"reorder_window": INF}, ["reorder_window", "inf"]),
        ({"gap_periods": INF}, ["gap_periods", "inf"]),
        ({"gap_periods": 0.5}, ["gap_periods", "0.5"]),
        ({"latency_window": 0}, ["latency_window", "0"]),
        ({"sources": ("imu", "gps")}, ["sources", "gps"]),
        ({"state_rows": ("pose",)}, ["state_rows", "pose"]),
    ],
)
def test_pipeline_constructor_refuses_bad_arguments(kw, words):
    raises_naming(lambda: FusionPipeline(ROBOT_CONFIG, **kw), *words)


def test_pipeline_counts_a_corrupt_gyro_sample_and_goes_on():
    records = []
    with FusionPipeline(ROBOT_CONFIG, on_record=records.append) as pipe:
        T = EXAMPLE_ROBOT.encode_sampling_time
        for k in range(100):
            t = k * 0.01
            gyro = np.array([0.0, 0.0, 1e200 if k == 50 else 0.0])
            pipe.push(ImuSample(t, gyro, UP))
            if k % 4 == 3:
                pipe.push(WheelTicks(t, 10, 10))
        stats = pipe.finish_stats()
    assert stats.invalid == 1  # the EKF refused the vertical rate of the corrupt sample
    assert pipe.attitude.counters.gyro_skipped == 1
    assert all(math.isfinite(r.x) and math.isfinite(r.yaw) for r in records)
    assert len(records) == stats.wheel_frames and T > 0


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"period": NAN}, ["period", "nan"]),
        ({"period": INF}, ["period", "inf"]),
        ({"silence_periods": 0.0}, ["silence_periods"]),
        ({"reconnect_interval": NAN}, ["reconnect_interval"]),
        ({"command_timeout": NAN}, ["command_timeout", "nan"]),
        ({"baudrate": 0}, ["baudrate", "0"]),
    ],
)
def test_chassis_link_refuses_bad_settings_naming_the_port(kw, words):
    raises_naming(lambda: ChassisLink("loop://", **kw), "loop://", *words)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"sample_rate_hz": NAN}, ["sample_rate_hz", "nan"]),
        ({"sample_rate_hz": 1e6}, ["sample_rate_hz"]),
        ({"gravity": INF}, ["gravity", "inf"]),
        ({"gravity": NAN}, ["gravity", "nan"]),
        ({"backoff_s": NAN}, ["backoff_s", "nan"]),
        ({"retries": -1}, ["retries", "-1"]),
        ({"retries": 2.5}, ["retries", "2.5"]),
        ({"stuck_samples": -3}, ["stuck_samples", "-3"]),
        ({"gyro_range_dps": 300}, ["gyro_range_dps", "300"]),
    ],
)
def test_mpu6050_refuses_bad_settings(kw, words):
    raises_naming(lambda: MPU6050(SimulatedMPU6050(), **kw), *words)


def _ekf_with_state() -> PlanarEKF:
    ekf = PlanarEKF(EXAMPLE_ROBOT)
    ekf.update_gyro(0.0, 0.1)
    return ekf


def _bad_state(key: str, value) -> dict:
    state = _ekf_with_state().get_state()
    state[key] = value
    return state


def _held_offset_nan() -> dict:
    """A state whose held-pose offset is NaN: it would poison every reported covariance."""
    state = _ekf_with_state().get_state()
    state["aux"][core.A_HELD_X] = NAN
    return state


@pytest.mark.parametrize(
    ("call", "words"),
    [
        (lambda e: PlanarEKF(EXAMPLE_ROBOT, x0=[0, 0, 0, NAN, 0, 0, 0, 0]), ["x0", "nan"]),
        (lambda e: PlanarEKF(EXAMPLE_ROBOT, P0=np.full((NX, NX), INF)), ["P0", "finite"]),
        (lambda e: PlanarEKF(EXAMPLE_ROBOT, P0=np.triu(np.ones((NX, NX)))), ["P0", "symmetric"]),
        (lambda e: PlanarEKF(EXAMPLE_ROBOT, P0=-np.eye(NX)), ["P0", "non-negative"]),
        (lambda e: PlanarEKF(EXAMPLE_ROBOT, noise={"gyro_std": 1.0}), ["noise", "EkfNoise"]),
        (lambda e: e.set_state(_bad_state("x", np.full(NX, NAN))), ["state['x']", "nan"]),
        (lambda e: e.set_state(_bad_state("P", np.eye(NX) * NAN)), ["state['P']"]),
        (lambda e: e.set_state(_bad_state("aux", np.zeros(3))), ["state['aux']"]),
        (lambda e: e.set_state(_held_offset_nan()), ["state['aux']", "A_HELD_X", "nan"]),
        (lambda e: e.update_yaw(0.1, 0.0, INF), ["yaw std", "inf"]),
        (lambda e: e.update_yaw(0.1, 0.0, 0.0), ["yaw std", "0.0"]),
        (lambda e: e.predict_to(NAN), ["predict_to", "nan"]),
        (lambda e: e.predict(dt=INF), ["dt", "inf"]),
    ],
)
def test_planar_ekf_setters_refuse_bad_values_and_keep_the_state(call, words):
    ekf = _ekf_with_state()
    before = ekf.get_state()
    raises_naming(lambda: call(ekf), *words)
    after = ekf.get_state()
    np.testing.assert_array_equal(after["x"], before["x"])
    np.testing.assert_array_equal(after["P"], before["P"])
    np.testing.assert_array_equal(after["aux"], before["aux"])


def test_reorder_buffer_refuses_a_nan_time():
    from fusion.planar.ekf import ReorderBuffer

    buf = ReorderBuffer(0.05)
    raises_naming(lambda: buf.push(NAN, "event"), "ReorderBuffer.push", "nan")
    assert len(buf) == 0
