"""fusion.io.run_config: the robot configuration file of ``fusion run`` (TOML)."""

from __future__ import annotations

import math
import textwrap

import pytest

from fusion.io.errors import LogFormatError
from fusion.io.robot_toml import read_robot_toml
from fusion.io.run_config import RUN_OPTIONS, SCHEMA, ConfigError, RunConfig, load_config

FULL = """\
# a complete file, every table
[chassis]
wheel_distance = 0.31
speed_ratio = 5e-5
encode_sampling_time = 0.04
cmd_vel_linear_max = 0.5
cmd_vel_angular_max = 2.0

[frames]
odom = "odom"
base = "base_link"
imu_mount_rpy = [0.0, 0.0, 1.5707963267948966]

[ekf]
gyro_std = 0.002

[imu]
source = "i2c:1"
address = 0x69
rate_hz = 200.0
gyro_range_dps = 1000
accel_range_g = 8
dlpf = 2
fifo_interval = 0.01
calibration = "cal/imu.json"
tilt = false

[link]
port = "/dev/ttyUSB0"
baudrate = 115200
command_timeout = 0.4
silence_periods = 4

[publish]
sinks = ["jsonl", "mcap:out.mcap"]
rate_hz = 10
reorder_window = 0.08

[run]
duration = 30
speed = 2
status = 0

[topics]
odom = "/wheel/odom"
imu = ""
cmd_vel = "/cmd"
"""


def write(tmp_path, text: str, name: str = "robot.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_full_file_reads_every_key(tmp_path):
    cfg = load_config(write(tmp_path, FULL))
    c = cfg.robot.chassis
    assert (c.wheel_distance, c.speed_ratio, c.encode_sampling_time) == (0.31, 5e-5, 0.04)
    assert (c.cmd_vel_linear_max, c.cmd_vel_angular_max) == (0.5, 2.0)
    assert math.isinf(c.wheel_speed_max)  # not given: no limit
    assert cfg.robot.base_frame == "base_link"
    assert cfg.robot.imu_mount_rpy == (0.0, 0.0, math.pi / 2)
    assert cfg.robot.ekf.gyro_std == 0.002
    assert (cfg.imu, cfg.imu_address, cfg.imu_rate_hz) == ("i2c:1", 0x69, 200.0)
    assert (cfg.gyro_range_dps, cfg.accel_range_g, cfg.dlpf) == (1000, 8, 2)
    assert cfg.fifo_interval == 0.01 and cfg.tilt is False
    # a relative calibration path is relative to the config file
    assert cfg.imu_calibration == str(tmp_path / "cal" / "imu.json")
    assert (cfg.chassis, cfg.baudrate, cfg.command_timeout) == ("/dev/ttyUSB0", 115200, 0.4)
    assert cfg.silence_periods == 4.0
    assert cfg.publish == ("jsonl", "mcap:out.mcap")
    assert cfg.publish_rate_hz == 10.0 and cfg.reorder_window == 0.08
    assert cfg.topics["odom"] == "/wheel/odom" and cfg.topics["imu"] is None
    assert cfg.topics["tf"] == "/tf"  # default kept
    assert cfg.cmd_vel_topic == "/cmd"
    assert (cfg.duration, cfg.speed, cfg.status) == (30.0, 2.0, 0.0)


def test_robot_tables_parse_like_a_log_directory_robot_toml(tmp_path):
    """[chassis]/[frames]/[ekf] are parsed by fusion.io.logdir's code: same result."""
    text = FULL.split("[imu]")[0]
    a = load_config(write(tmp_path, text, "a.toml")).robot
    b = read_robot_toml(write(tmp_path, text, "b.toml"))
    assert a == b


def test_a_byte_order_mark_is_no_toml(tmp_path):
    """A file saved by Notepad starts with a UTF-8 byte order mark (EF BB BF), which TOML does
    not allow; both readers skip it (it had read "Invalid statement (at line 1, column 1)"),
    and still name the line of a bad key."""
    text = FULL.split("[imu]")[0]
    for name, load in (("run.toml", load_config), ("robot.toml", read_robot_toml)):
        plain, marked = tmp_path / f"plain_{name}", tmp_path / f"bom_{name}"
        plain.write_text(text)
        marked.write_bytes(b"\xef\xbb\xbf" + text.encode())
        a, b = load(marked), load(plain)
        assert getattr(a, "robot", a) == getattr(b, "robot", b)
    marked.write_bytes(b"\xef\xbb\xbf[chassis]\nwheel_distance = 0.3\nspeed_ratio = 1e-4\n"
                       b"encode_sampling_time = 0.04\nwheel_distanse = 0.3\n")
    with pytest.raises(LogFormatError, match=r"bom_robot\.toml:5: .*wheel_distanse"):
        read_robot_toml(marked)


def test_empty_file_gives_the_defaults(tmp_path):
    cfg = load_config(write(tmp_path, "# nothing\n"))
    d = RunConfig()
    assert cfg.robot == d.robot and cfg.imu == "sim" and cfg.chassis == "sim"
    assert cfg.publish_rate_hz is None and cfg.publish == ("jsonl",)


def test_rate_zero_means_every_wheel_frame(tmp_path):
    assert load_config(write(tmp_path, "[publish]\nrate_hz = 0\n")).publish_rate_hz is None


def test_overrides_ignore_options_not_given():
    cfg = RunConfig().with_overrides(imu="i2c:3", chassis=None, publish=("mcap:x.mcap",))
    assert cfg.imu == "i2c:3" and cfg.chassis == "sim" and cfg.publish == ("mcap:x.mcap",)


def test_every_run_option_has_a_key_in_the_schema():
    for option, (table, key) in RUN_OPTIONS.items():
        assert key in SCHEMA[table], option


def test_every_fusion_run_option_can_come_from_the_file():
    """The command's own parser: each option but --config is mapped to a table and key."""
    import argparse

    from fusion.cli import build_parser

    sub = next(a for a in build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    dests = {a.dest for a in sub.choices["run"]._actions} - {"help", "config"}
    assert dests == set(RUN_OPTIONS)


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        # a typo in a key: named, with the allowed keys
        ("[imu]\nrate_hz = 100\nsorce = 'sim'\n", 3, ["[imu]", "sorce", "source"]),
        # a wrong type
        ("[link]\nbaudrate = 'fast'\n", 2, ["[link] baudrate", "number"]),
        # a value out of range
        ("[imu]\n\naddress = 0x200\n", 3, ["[imu] address", "<= 119"]),
        ("[imu]\ngyro_range_dps = 300\n", 2, ["gyro_range_dps", "250, 500, 1000, 2000"]),
        ("[imu]\nsource = 'spi:0'\n", 2, ["[imu] source", "i2c:N"]),
        ("[publish]\nsinks = ['bogus']\n", 2, ["[publish] sinks", "unknown sink 'bogus'"]),
        ("[publish]\nsinks = ['mcap']\n", 2, ["[publish] sinks", "give a path"]),
        ("[publish]\nsinks = ['foxglove:70000']\n", 2, ["[publish] sinks", "0..65535"]),
        # ros1 is checked without rospy: only its spec, not the node
        ("[publish]\nsinks = ['ros1:x']\n", 2, ["[publish] sinks", "takes no argument"]),
        ("[topics]\nodom = 'odom'\n", 2, ["[topics] odom", "absolute"]),
        ("[imu]\ntilt = 1\n", 2, ["[imu] tilt", "true or false"]),
        # an unknown table
        ("[imu]\nrate_hz = 100\n[serial]\nport = 'x'\n", 3, ["unknown table [serial]"]),
        # the robot tables, through fusion.io.logdir's parser, still get the line
        ("[chassis]\nwheel_distance = 0.3\nspeed_ratio = -1\nencode_sampling_time = 0.04\n",
         3, ["speed_ratio", "> 0"]),
        ("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 1e-4\nencode_sampling_time = 0.04\n"
         "wheel_distanse = 0.3\n", 5, ["unknown key", "wheel_distanse"]),
        ("[chassis]\nwheel_distance = 0.3\nencode_sampling_time = 0.04\n", 1,
         ["[chassis] needs speed_ratio"]),
        ("[frames]\nodom = 'odom'\n", 1, ["need a [chassis] table"]),
        # values 1000 times off (an independent probe: mm and ms ran, the odometry 1000 x off)
        ("[chassis]\nwheel_distance = 300\nspeed_ratio = 5e-5\nencode_sampling_time = 0.04\n",
         2, ["[chassis] wheel_distance = 300 m is outside 0.02-10 m", "looks like mm: 0.3 m"]),
        ("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\nencode_sampling_time = 40\n",
         4, ["encode_sampling_time = 40 s is outside", "looks like ms: 0.04 s"]),
        ("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 0.5\nencode_sampling_time = 0.04\n",
         3, ["speed_ratio = 0.5 m/tick is outside", "looks like mm per tick: 0.0005 m/tick"]),
        ("[chassis]\nwheel_distance = 0.003\nspeed_ratio = 5e-5\nencode_sampling_time = 0.04\n",
         2, ["wheel_distance = 0.003 m is outside 0.02-10 m, no wheeled robot's"]),
    ],
)
def test_bad_content_names_file_line_and_key(tmp_path, text, line, words):
    path = write(tmp_path, text, "bad.toml")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:{line}:"), msg
    for w in words:
        assert w in msg, (w, msg)


def test_config_error_is_not_a_log_format_error(tmp_path):
    # a bad run configuration is not a malformed log: `except LogFormatError` must not catch it
    path = write(tmp_path, "[imu]\nsorce = 'sim'\n", "bad.toml")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert isinstance(info.value, ValueError)
    assert not isinstance(info.value, LogFormatError)


def test_invalid_toml_names_file_and_line(tmp_path):
    path = write(tmp_path, "[imu]\nrate_hz = = 3\n", "broken.toml")
    with pytest.raises(ConfigError, match=r"broken\.toml: invalid TOML: .*line 2"):
        load_config(path)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.toml"):
        load_config(tmp_path / "nope.toml")
