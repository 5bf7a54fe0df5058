"""``fusion replay BAG`` through :class:`fusion.pipeline.core.FusionPipeline` (the bag's
nav_msgs/Odometry twists as the pipeline's twist input), on the bundled ROS 1 bag
(datasets/rosbag/jackal_sim_test2.bag: a simulated Jackal, 3061 sensor_msgs/Imu messages at
50 Hz on /imu/data, 3060 nav_msgs/Odometry on /jackal_velocity_controller/odom).

Oracles: the pipeline fed by hand, one message at a time, from :func:`fusion.io.bags.read_bag`;
the filters composed by hand (Keel told the twists' v*w and stillness, as
tests/keel_feed_reference.py states it -> vertical_rate -> ekf.fuse with twists); the mcap
package reading the .mcap output back.
"""

from __future__ import annotations

import heapq
import io
import json
import os
import stat

import numpy as np
import pytest
from keel_feed_reference import keel_by_hand  # tests/keel_feed_reference.py
from tilt_rate_reference import (  # tests/tilt_rate_reference.py
    heading_frame_twists_by_hand,
    rest_gyro_bias_by_hand,
    tilt_rate_by_hand,
)

from fusion.cli import main
from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.fused_csv import write_fused_csv
from fusion.jobs.replay import fused_table
from fusion.pipeline.core import FusionPipeline
from fusion.planar.ekf import fuse
from fusion.planar.imu_motion import imu_motion_codes
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink

pytest.importorskip("rosbags")

IMU_TOPIC = "/imu/data"
ODOM_TOPIC = "/jackal_velocity_controller/odom"
N_IMU, N_ODOM = 3061, 3060  # messages on the two topics (rosbag info)
# what `fusion replay` uses for a bag without --robot: neutral chassis values
NEUTRAL = RobotConfig(DiffDriveParams(wheel_distance=0.5, speed_ratio=1e-4,
                                      encode_sampling_time=0.02))


@pytest.fixture(scope="module")
def bag(datasets_dir):
    return datasets_dir / "rosbag" / "jackal_sim_test2.bag"


@pytest.fixture(scope="module")
def msgs(bag):
    from fusion.io.bags import read_bag

    return read_bag(bag, imu_topic=IMU_TOPIC, odom_topic=ODOM_TOPIC)


def _replay(bag, out, *extra) -> int:
    return main(["replay", str(bag), "--imu-topic", IMU_TOPIC, "--odom-topic", ODOM_TOPIC,
                 "-o", str(out), *extra])


def _by_hand(msgs, robot, sinks=(), **kw) -> FusionPipeline:
    """A FusionPipeline fed one message at a time in stamp order (IMU first at equal
    stamps), as a live node would receive the two topics."""
    imu, odom = msgs.imu, msgs.odometry
    evs = heapq.merge(((t, 0, i) for i, t in enumerate(imu.t.tolist())),
                      ((t, 1, i) for i, t in enumerate(odom.t.tolist())))
    pipe = FusionPipeline(robot, list(sinks), sources=("imu", "twist"),
                          imu_rate_hz=50.0, **kw)  # the bag's nominal IMU rate
    from fusion.types.samples import ImuSample

    with pipe:
        for t, kind, i in evs:
            if kind == 0:
                pipe.push_imu(ImuSample(t, imu.gyro[i], imu.accel[i]))
            else:
                pipe.push_twist(t, float(odom.v[i]), float(odom.w[i]))
    return pipe


def test_jsonl_equals_the_pipeline_fed_by_hand_from_read_bag(bag, msgs, tmp_path, capsys):
    out = tmp_path / "fused.jsonl"
    assert _replay(bag, out) == 0
    text = capsys.readouterr().out
    assert f"{N_IMU} IMU messages (base_link), {N_ODOM} odometry messages" in text
    assert f"-> {out} ({N_ODOM} records)" in text  # a .jsonl has records, not rows
    buf = io.StringIO()
    pipe = _by_hand(msgs, NEUTRAL, [JsonLinesSink(buf, flush=False)])
    lines = out.read_text().splitlines(keepends=True)
    assert "".join(lines[:-1]) == buf.getvalue()  # byte for byte, then the status record
    assert [w["name"] for w in json.loads(lines[-1])["status"]["warnings"]] == [
        "slip", "heading_divergence"]  # tests/test_trust.py
    recs = [json.loads(x) for x in buf.getvalue().splitlines()]
    assert len(recs) == N_ODOM == pipe.stats.twist_messages  # one record per odometry msg
    # each record is stamped with its odometry message's header stamp
    np.testing.assert_array_equal([r["t"] for r in recs], msgs.odometry.t)
    # a mounted IMU (--imu-mount-rpy) is the pipeline's mount rotation
    rpy = (0.02, -0.01, 0.3)
    assert _replay(bag, out, "--imu-mount-rpy", *map(str, rpy)) == 0
    buf = io.StringIO()
    _by_hand(msgs, RobotConfig(NEUTRAL.chassis, imu_mount_rpy=rpy),
             [JsonLinesSink(buf, flush=False)])
    assert "".join(out.read_text().splitlines(keepends=True)[:-1]) == buf.getvalue()


def _twist_flags(track):
    """Per event, the flags of the last twist before it, from the EKF's status codes (4 ZUPT,
    1 or 2 slip, 7 encoder fault): bits 1, 2, 4."""
    code = np.select([track.status == 4, np.isin(track.status, (1, 2)), track.status == 7],
                     [1.0, 2.0, 4.0], 0.0)
    is_twist = track.kind == 3
    last = np.maximum.accumulate(np.where(is_twist, np.arange(track.kind.size), -1))
    return np.where(last >= 0, code[np.maximum(last, 0)], 0.0)


def test_csv_equals_the_filters_composed_by_hand(bag, msgs, tmp_path):
    """The CSV (state after every IMU message) is the fuse()-based output, byte for byte,
    with the attitude of Keel told the odometry twists' v*w and stillness
    (tests/keel_feed_reference.py), its first step the nominal IMU period (0.02 s) as in the
    pipeline, and the tilt-compensated rate of tests/tilt_rate_reference.py."""
    imu, odom = msgs.imu, msgs.odometry
    out = tmp_path / "fused.csv"
    for level in (False, True):
        assert _replay(bag, out, *(["--level"] if level else [])) == 0
        codes = imu_motion_codes(imu.t, imu.gyro, imu.accel)
        twist_v, twist_w = odom.v, odom.w
        if level:
            gz = imu.gyro[:, 2]
        else:
            fed = imu.gyro - rest_gyro_bias_by_hand(NEUTRAL, imu.t, imu.gyro, codes,
                                                    twist_t=odom.t, twist_v=odom.v,
                                                    twist_w=odom.w)
            q = keel_by_hand(NEUTRAL, imu.t, fed, imu.accel, twist_t=odom.t,
                             twist_v=odom.v, twist_w=odom.w, sample_period=0.02)
            gz = tilt_rate_by_hand(NEUTRAL, imu.t, imu.gyro, q, codes, twist_t=odom.t,
                                   twist_v=odom.v, twist_w=odom.w)
            twist_v, twist_w = heading_frame_twists_by_hand(NEUTRAL, imu.t, q, gz,
                                                            imu.gyro[:, 2], odom.t, odom.v,
                                                            odom.w)
        track, _ = fuse(NEUTRAL.chassis, imu.t, gz, noise=NEUTRAL.ekf, twist_t=odom.t,
                        twist_v=twist_v, twist_w=twist_w, imu_motion=codes)
        rows = track.output_rows()
        assert rows.sum() == N_IMU
        no_wheels = np.full((int(rows.sum()), 2), np.nan)
        write_fused_csv(tmp_path / "ref.csv", fused_table(
            np.column_stack([track.t[rows], track.states[rows], no_wheels,
                             _twist_flags(track)[rows]]), 1.0))
        assert out.read_bytes() == (tmp_path / "ref.csv").read_bytes()


def test_mcap_output_reads_back(bag, tmp_path):
    from mcap.reader import make_reader

    out = tmp_path / "fused.mcap"
    assert _replay(bag, out) == 0
    counts: dict[str, int] = {}
    with open(out, "rb") as fh:
        for _s, channel, _m in make_reader(fh).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts["/odom"] == counts["/tf"] == N_ODOM
    m = os.umask(0)
    os.umask(m)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~m
    # the same run read back with rosbags: the last /odom is the last .jsonl record
    from rosbags.highlevel import AnyReader

    assert _replay(bag, tmp_path / "f.jsonl") == 0
    last = json.loads((tmp_path / "f.jsonl").read_text().splitlines()[-2])  # [-1]: status
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == "/odom"]
        *_, (conn, _t, raw) = reader.messages(connections=conns)
        msg = reader.deserialize(raw, conn.msgtype)
    assert msg.pose.pose.position.x == last["x"] and msg.pose.pose.position.y == last["y"]
    assert msg.twist.twist.linear.x == last["v"] and msg.twist.twist.angular.z == last["w"]


def test_plot_of_a_bag(bag, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    png = tmp_path / "jackal.png"
    assert _replay(bag, tmp_path / "f.csv", "--plot", str(png)) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["replay", str(bag), "--imu-topic", IMU_TOPIC, "--odom-topic", ODOM_TOPIC,
                 "-o", str(tmp_path / "g.csv"), "--plot", str(tmp_path / "no" / "p.png")]) == 2
    assert "the folder" in capsys.readouterr().err
    assert not (tmp_path / "g.csv").exists()


def test_the_mount_comes_from_robot_toml_unless_given(bag, tmp_path):
    """--robot robot.toml with imu_mount_rpy: the pipeline rotates the IMU by it (the same
    bytes as --imu-mount-rpy with the same values); --imu-mount-rpy overrides it."""
    from fusion.io.robot_toml import read_robot_toml, write_robot_toml

    rpy = (0.0, 0.0, 1.2)  # an IMU mounted yawed by 1.2 rad
    toml = tmp_path / "robot.toml"
    write_robot_toml(toml, RobotConfig(NEUTRAL.chassis, imu_mount_rpy=rpy))
    assert read_robot_toml(toml).imu_mount_rpy == rpy
    outs = {}
    for name, extra in (("toml", ["--robot", str(toml)]),
                        ("flag", ["--imu-mount-rpy", *map(str, rpy)]),
                        ("override", ["--robot", str(toml), "--imu-mount-rpy", "0", "0", "0"]),
                        ("none", [])):
        assert _replay(bag, tmp_path / f"{name}.jsonl", *extra) == 0
        outs[name] = (tmp_path / f"{name}.jsonl").read_text()
    assert outs["toml"] == outs["flag"]
    assert outs["override"] == outs["none"]
    assert outs["toml"] != outs["none"]  # the records carry the mounted IMU's vectors
    a = json.loads(outs["toml"].splitlines()[-2])  # the last records ([-1]: the status)
    b = json.loads(outs["none"].splitlines()[-2])
    assert a["linear_acceleration"] != b["linear_acceleration"]


def test_a_driver_that_leaves_header_stamps_at_zero_replays_with_stamps_bag(bag, tmp_path,
                                                                           capsys):
    # Some IMU drivers publish header.stamp = 0. The default refuses and says what to do;
    # --stamps bag replays on the record times, as the same bag with its stamps intact does.
    from reshaped_bag import rewrite_messages

    def zero_stamp(msg, ns):
        msg.header.stamp.sec = msg.header.stamp.nanosec = 0
        return ns

    zero = tmp_path / "zero_stamps.bag"
    rewrite_messages(bag, zero, IMU_TOPIC, zero_stamp)
    out = tmp_path / "zero.csv"
    assert _replay(zero, out) == 2
    err = capsys.readouterr().err
    assert f"topic {IMU_TOPIC}: every header.stamp is zero" in err and "--stamps bag" in err
    assert not out.exists()
    assert _replay(zero, out, "--stamps", "bag") == 0
    intact = tmp_path / "intact.csv"
    assert _replay(bag, intact, "--stamps", "bag") == 0
    assert out.read_bytes() == intact.read_bytes()
    assert _replay(bag, tmp_path / "header.csv") == 0
    assert (tmp_path / "header.csv").read_bytes() != intact.read_bytes()
