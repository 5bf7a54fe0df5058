"""fusion.pipeline: one pipeline object for live and replay (Keel -> EKF -> sinks)."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from keel_feed_reference import keel_by_hand  # tests/keel_feed_reference.py
from tilt_rate_reference import (  # tests/tilt_rate_reference.py
    heading_frame_ticks_by_hand,
    heading_frame_twists_by_hand,
    rest_gyro_bias_by_hand,
    tilt_rate_by_hand,
)

from drivers.chassis import encode_wheel_frame
from fusion.evaluation.synthetic import (
    EXAMPLE_ROBOT,
    EncoderModel,
    ImuModel,
    SlipPatch,
    random_mission,
    simulate,
)
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.records import _fast_record, _record_fields
from fusion.pipeline.sources import capture_events, logdir_events, merge_by_time, replay
from fusion.planar import _ekf_core as core
from fusion.planar.accel_slip import accel_slip_flags
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.imu_motion import imu_motion_codes
from fusion.planar.model import NX
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink
from fusion.types.fused import FusedOdometry
from fusion.types.samples import ImuSample, WheelTicks


@pytest.fixture(scope="module")
def run():
    """60 s degraded mission with jittered stamps (no two inputs share an effective time)."""
    imu = ImuModel(gyro_bias=(0.001, -0.001, math.radians(0.5)), gyro_bias_walk=2e-5,
                   vibration=0.5, jitter=0.0005)
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025,
                       right_scale_error=0.0025, jitter=0.002,
                       slip_patches=(SlipPatch(20.0, 21.0, "left", 0.3),))
    return simulate(random_mission(60.0, seed=4), EXAMPLE_ROBOT, imu, enc, seed=4)


def events(run):
    imu = [ImuSample(t, run.gyro[i], run.accel[i]) for i, t in enumerate(run.imu_t.tolist())]
    wheels = [WheelTicks(t, int(a), int(b))
              for t, (a, b) in zip(run.wheel_t.tolist(), run.ticks.tolist())]
    return list(merge_by_time(imu, wheels))


@pytest.mark.parametrize("noise", [EkfNoise(), EkfNoise(accel_speed_psd=0.005)],
                         ids=["default", "accel-speed"])
def test_streaming_pipeline_equals_the_filters_composed_by_hand(run, noise):
    """Oracle: Keel told the wheels' knowledge (tests/keel_feed_reference.py) ->
    imu_motion_codes, the tilt-compensated rate (tests/tilt_rate_reference.py), the
    accelerometer slip flags of the base-frame specific force -> ekf.fuse (batch,
    merge_events' own ordering; with accel_speed_psd also the base-frame forward specific
    force), composed here from the library's pieces. The
    pipeline, fed one event at a time in host order, must publish exactly the fused state
    after every wheel frame."""
    robot = RobotConfig(chassis=run.robot, ekf=noise)
    motion = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    fed = run.gyro - rest_gyro_bias_by_hand(robot, run.imu_t, run.gyro, motion, run.wheel_t,
                                            run.ticks)
    q = keel_by_hand(robot, run.imu_t, fed, run.accel, run.wheel_t, run.ticks)
    gz = tilt_rate_by_hand(robot, run.imu_t, run.gyro, q, motion, run.wheel_t, run.ticks)
    slip = accel_slip_flags(run.robot.speed_ratio, run.robot.encode_sampling_time, run.imu_t,
                            run.accel[:, :2], gz, motion, run.wheel_t, run.ticks)
    accel_x = run.accel[:, 0] if noise.accel_speed_psd > 0 else None
    ticks = heading_frame_ticks_by_hand(robot, run.imu_t, q, gz, run.gyro[:, 2], run.wheel_t,
                                        run.ticks)
    track, ekf = fuse(run.robot, run.imu_t, gz, run.wheel_t, ticks, noise,
                      imu_motion=motion, wheel_slip=slip, accel_x=accel_x)
    rows = track.states[track.kind == core.EV_WHEELS]
    t_rows = track.t_filter[track.kind == core.EV_WHEELS]

    records = []
    pipe = FusionPipeline(robot, on_record=records.append, imu_rate_hz=100.0, accel_slip=True)
    stats = replay(pipe, events(run))
    assert stats.records == len(records) == run.wheel_t.size == rows.shape[0]
    got = np.array([[r.t, r.x, r.y, r.yaw, r.v, r.w, r.pose_covariance[0, 0],
                     r.pose_covariance[5, 5], r.twist_covariance[5, 5]] for r in records])
    want = np.column_stack([t_rows, rows[:, 0], rows[:, 1],
                            np.pi - np.mod(np.pi - rows[:, 2], 2 * np.pi), rows[:, 3],
                            rows[:, 4], rows[:, NX], rows[:, NX + 2], rows[:, NX + 4]])
    np.testing.assert_array_equal(got, want)
    assert stats.slips == ekf.stats["slips"] > 0 and stats.zupts == ekf.stats["zupts"] > 0
    assert stats.accel_slips == ekf.stats["accel_slips"] == slip.sum()
    assert stats.late_dropped == 0 and stats.imu_samples == run.imu_t.size
    # the record carries the attitude of the last fused IMU sample and the frame's speeds
    last = records[-1]
    k_last = np.flatnonzero(track.kind == core.EV_WHEELS)[-1]
    n_gyro = int(np.sum(track.kind[:k_last] == core.EV_GYRO))  # gyro samples fused before
    np.testing.assert_allclose(last.orientation, q[n_gyro - 1] / np.linalg.norm(q[n_gyro - 1]),
                               rtol=0, atol=1e-15)
    T = run.robot.encode_sampling_time
    assert last.wheel_left_speed == run.ticks[-1, 0] * (run.robot.speed_ratio / T)


def test_the_horizontal_gyro_bias_is_learnt_at_the_stops(run):
    # the simulator's gyro biases about x and y are 0.001 and -0.001 rad/s (plus a random
    # walk of 2e-5 rad/s/sqrt(s)); the pipeline's estimate is their mean over the samples at
    # which the wheels and the IMU stood still
    pipe = FusionPipeline(RobotConfig(chassis=run.robot))
    assert pipe.horizontal_gyro_bias == (0.0, 0.0, 0)
    with pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    bx, by, samples = pipe.horizontal_gyro_bias
    assert samples > 300  # the mission stops for several seconds
    assert bx == pytest.approx(0.001, abs=3e-4) and by == pytest.approx(-0.001, abs=3e-4)


@pytest.mark.parametrize("rate", [None, 10.0])
def test_batch_entry_point_gives_the_same_bytes_as_streaming(run, rate):
    """push_arrays (Keel and EKF batch cores) == push() one event at a time, byte for byte
    in the JSON lines output, with a tilted IMU mount and both publish modes."""
    robot = RobotConfig(chassis=run.robot, imu_mount_rpy=(0.02, -0.01, 0.3))
    out = []
    for batch in (False, True):
        buf = io.StringIO()
        pipe = FusionPipeline(robot, [JsonLinesSink(buf, flush=False)], publish_rate_hz=rate)
        if batch:
            with pipe:
                pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
        else:
            replay(pipe, events(run))
        out.append(buf.getvalue())
    assert out[0] == out[1]
    n = out[0].count("\n")
    if rate is None:
        assert n == run.wheel_t.size
    else:
        t = np.array([json.loads(line)["t"] for line in out[0].splitlines()])
        # one record per 0.1 s of filter time: the first event at or after each grid point
        assert abs(n - run.duration * rate) <= 2
        assert np.all(np.floor(t[1:] * rate + 1e-9) > np.floor(t[:-1] * rate + 1e-9))
        assert np.max(np.diff(t)) < 0.1 + 0.02


def test_fast_record_equals_the_validating_constructor(run):
    robot = RobotConfig(chassis=run.robot)
    pipe = FusionPipeline(robot)
    with pipe:
        for ev in events(run)[:3000]:
            pipe.push(ev)
        last = pipe.current_record()
        g = last.angular_velocity
        f = _record_fields(pipe.ekf.t, pipe.ekf.x, pipe.ekf.P[:5, :5].ravel().tolist(),
                           last.orientation, (g[0], g[1]), last.linear_acceleration,
                           (last.wheel_left_speed, last.wheel_right_speed), "odom",
                           "base_footprint")
    slow = FusedOdometry(**{k: v for k, v in f.items() if k != "_sum"})
    fast = _fast_record(f)
    assert fast == slow and fast.to_dict() == slow.to_dict()
    for name in ("pose_covariance", "twist_covariance", "orientation", "angular_velocity",
                 "linear_acceleration"):
        assert not getattr(fast, name).flags.writeable
        assert getattr(fast, name).dtype == np.float64
    # a non-finite state is refused by the validating constructor, naming the field
    with pytest.raises(ValueError, match="x must be finite"):
        _fast_record({**f, "x": math.nan})


def test_single_lost_wheel_frames_are_counted_and_stamp_jitter_is_not():
    # 25 Hz frames for 20 s with every 10th one lost (50 frames, each alone: no interval
    # reaches gap_periods), then a 5-frame hole, and stamps jittered by up to 0.4 periods:
    # every lost frame is counted, the hole alone is a gap, and jitter loses nothing.
    T = EXAMPLE_ROBOT.encode_sampling_time
    rng = np.random.default_rng(3)
    k = np.arange(1, 502)  # the last one kept: a frame lost after the last is unobservable
    kept = k[(k % 10 != 0) & ((k < 300) | (k > 304))]
    stamps = kept * T + rng.uniform(-0.2, 0.2, kept.size) * T
    lost = k.size - kept.size  # 49 single frames (k = 10 .. 500 but 300) + the hole's 5
    g, a = np.zeros(3), np.array([0.0, 0.0, 9.80665])
    pipe = FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT))
    with pipe:
        for t in stamps:
            pipe.push(ImuSample(float(t) - 0.001, g, a))
            pipe.push(WheelTicks(float(t), 0, 0))
    s = pipe.finish_stats()
    assert s.wheel_frames == kept.size
    assert s.frames_missing == lost == 54
    assert s.gap_count == 1 and s.gaps[0].missing == 5  # k = 300 .. 304


@pytest.mark.parametrize("case", ["late", "drift", "slow", "backlog"])
def test_frames_that_all_came_count_none_missing(case):
    # every frame arrives, but not on the period's grid: each 4th one 1.25 periods late (an
    # independent probe's frames split in two writes 50 ms apart: 80 counted missing), a
    # firmware clock 0.1 % slow over 2000 frames, a board whose period is 10 % long, or a
    # host that stalls for 10 periods and then reads the backlog in one burst, 1 ms apart
    T = EXAMPLE_ROBOT.encode_sampling_time
    k = np.arange(1, 2002, dtype=float)  # the last on time (a late last one looks lost)
    if case == "late":  # a serial stream keeps order: the next frame queues behind it
        stamps = np.maximum.accumulate(k * T + np.where(k % 4 == 0, 1.25 * T, 0.0))
        stamps += 0.001 * (np.diff(stamps, prepend=0.0) == 0.0)
    elif case == "drift":
        stamps = k * T * 1.001
    elif case == "slow":  # a board 10 % slower than its nominal period (a grid took 200)
        stamps = k * T * 1.1
    else:
        stamps = k * T
        stall = (k > 500) & (k <= 510)
        stamps[stall] = 510 * T + 0.001 * (k[stall] - 500)
    g, a = np.zeros(3), np.array([0.0, 0.0, 9.80665])
    with FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT)) as pipe:
        for t in stamps:
            pipe.push(ImuSample(float(t) - 0.001, g, a))
            pipe.push(WheelTicks(float(t), 0, 0))
    s = pipe.finish_stats()
    assert s.wheel_frames == k.size
    assert s.frames_missing == 0


def test_lost_frames_of_a_board_faster_than_its_nominal_period_are_counted():
    # 3 % fast, every 10th frame lost in the second half (99): a grid that could not follow
    # the period had counted 54 (a review)
    T = EXAMPLE_ROBOT.encode_sampling_time
    k = np.arange(1, 2001, dtype=float)
    kept = ~((k > 1000) & (k % 10 == 0))
    kept[-1] = True
    stamps = (k * T * 0.97)[kept]
    with FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT), sources=("wheels",)) as pipe:
        pipe.push_arrays(wheel_t=stamps, ticks=np.zeros((stamps.size, 2), np.int64))
    assert pipe.finish_stats().frames_missing == int((~kept).sum()) == 99


def test_out_of_order_inputs_are_dropped_and_counted_and_gaps_reported():
    robot = RobotConfig(chassis=EXAMPLE_ROBOT)
    recs = []
    pipe = FusionPipeline(robot, on_record=recs.append)
    g, a = np.zeros(3), np.array([0.0, 0.0, 9.80665])
    with pipe:  # host time order, except where stated
        for k in range(1, 10):
            pipe.push(ImuSample(0.01 * k, g, a))
            if k == 4:
                pipe.push(WheelTicks(0.04, 0, 0))
                pipe.push(WheelTicks(0.04, 0, 0))  # same stamp again
            if k == 8:
                pipe.push(WheelTicks(0.08, 0, 0))
        pipe.push(ImuSample(0.05, g, a))  # older than the last IMU sample
        for k in range(10, 41):
            pipe.push(ImuSample(0.01 * k, g, a))
        pipe.push(WheelTicks(0.40, 0, 0))  # 7 frames missing (0.12 .. 0.36)
    s = pipe.finish_stats()
    assert (s.imu_samples, s.imu_out_of_order) == (40, 1)
    assert (s.wheel_frames, s.wheel_out_of_order) == (3, 1)
    assert s.gap_count == 1 and s.frames_missing == 7 and s.late_dropped == 0
    gap = s.gaps[0]
    assert (gap.t_start, gap.t_end, gap.missing) == (0.08, 0.40, 7)
    assert len(recs) == 3 and s.zupts >= 1


def test_an_exception_aborts_file_sinks_leaving_no_partial_output(tmp_path):
    target = tmp_path / "fused.jsonl"
    target.write_text("old complete output\n")
    pipe = FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT), [JsonLinesSink(target)])

    def broken():
        yield WheelTicks(0.04, 10, 10)
        yield WheelTicks(0.08, 10, 10)
        raise RuntimeError("source failed")

    with pytest.raises(RuntimeError, match="source failed"):
        replay(pipe, broken())
    assert target.read_text() == "old complete output\n"
    assert [p.name for p in tmp_path.iterdir()] == ["fused.jsonl"]


def test_publish_needs_an_open_pipeline():
    pipe = FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT))
    with pytest.raises(RuntimeError, match="not open"):
        pipe.push(WheelTicks(0.04, 1, 1))
    with pipe, pytest.raises(TypeError, match="ImuSample or WheelTicks"):
        pipe.push((0.0, 1, 1))  # type: ignore[arg-type]


def test_captures_raw_and_timed_give_the_frames_sent(tmp_path):
    """fusion.io decodes; a raw capture is stamped on the firmware period, a timed one as
    the live link stamps (fusion.io' own tests cover that rule)."""
    from fusion.io.uart2 import Uart2CaptureWriter

    ticks = [(0, 0), (120, -118), (-5, 7), (255, 65535), (0, 0)]
    data = b"\x00\xff\x13"  # line noise before the first frame
    for k, (left, right) in enumerate(ticks):
        data += encode_wheel_frame(left, right)
        if k == 2:
            data += b"\xff\xff\x01\x02"  # a truncated frame
    raw = tmp_path / "raw.uart2"
    raw.write_bytes(data)
    frames, stats = capture_events(raw, 0.04, t0=10.0)
    assert [(f.left, f.right) for f in frames] == ticks
    assert [f.t for f in frames] == [10.0 + 0.04 * (k + 1) for k in range(len(ticks))]
    assert stats["frames"] == len(ticks) and stats["bytes_skipped"] == 7
    timed = tmp_path / "timed.uart2"
    with Uart2CaptureWriter(timed) as cap:
        for k, (left, right) in enumerate(ticks):
            cap.write(0.04 * (k + 1) + 0.002, encode_wheel_frame(left, right))
    frames, _ = capture_events(timed, 0.04, t0=10.0)  # t0 is for raw captures only
    assert [(f.left, f.right) for f in frames] == ticks
    want = [0.04 * (k + 1) + 0.002 for k in range(5)]
    # frame 3 (255, 65535) holds FF FF in its payload: the parser waits for the next frame to
    # decide, so it leaves with the next read, less the line time of the 11 bytes after it
    want[3] = want[4] - 11 * 10 / 115200
    np.testing.assert_allclose([f.t for f in frames], want, rtol=0, atol=1e-12)


def test_logdir_replay_keeps_the_imu_frame_for_the_pipeline(tmp_path, run):
    """A log directory with a mount rotation: the pipeline rotates (once) what the reader
    gives, so the result equals the arrays path with the same robot."""
    robot = RobotConfig(chassis=run.robot, imu_mount_rpy=(0.0, 0.0, math.pi / 2))
    from fusion.io.logdir import write_logdir

    # IMU-frame vectors of a sensor mounted with yaw 90 deg: base x = imu -y ...
    g_imu = np.column_stack([run.gyro[:, 1], -run.gyro[:, 0], run.gyro[:, 2]])
    a_imu = np.column_stack([run.accel[:, 1], -run.accel[:, 0], run.accel[:, 2]])
    write_logdir(tmp_path / "log", robot, run.imu_t, g_imu, a_imu, run.wheel_t, run.ticks)
    robot2, evs = logdir_events(tmp_path / "log")
    assert robot2 == robot
    recs = []
    replay(FusionPipeline(robot2, on_record=recs.append), evs)
    # against the level, unrotated data: equal to rounding of the rotation
    ref = []
    replay(FusionPipeline(RobotConfig(chassis=run.robot), on_record=ref.append), events(run))
    assert len(recs) == len(ref)
    assert abs(recs[-1].x - ref[-1].x) < 1e-6 and abs(recs[-1].y - ref[-1].y) < 1e-6


def test_watermark_releases_a_wheel_frame_once_the_imu_has_passed_its_period_middle():
    """Live latency: a frame is fused as soon as every source has delivered events at least
    as new as its effective time (each source is in order: nothing older can come); the
    window is only the bound for a stalled source."""
    robot = RobotConfig(chassis=EXAMPLE_ROBOT)
    g, a = np.zeros(3), np.array([0.0, 0.0, 9.80665])
    recs = []
    pipe = FusionPipeline(robot, reorder_window=0.5, on_record=recs.append)
    with pipe:
        for k in range(1, 4):  # IMU up to 0.03 s
            pipe.push(ImuSample(0.01 * k, g, a))
        pipe.push(WheelTicks(0.04, 0, 0))  # middle of its period: 0.02 <= 0.03: out at once
        assert len(recs) == 1 and recs[0].t == 0.02
        pipe.push(WheelTicks(0.08, 0, 0))  # middle 0.06: the IMU is at 0.03, it waits
        assert len(recs) == 1
        pipe.push(ImuSample(0.05, g, a))
        assert len(recs) == 1
        pipe.push(ImuSample(0.06, g, a))  # now the IMU has passed 0.06
        assert len(recs) == 2 and recs[1].t == 0.06
    # with the wheels as the only source a frame goes out on arrival
    recs.clear()
    pipe = FusionPipeline(robot, reorder_window=0.5, sources=("wheels",),
                          on_record=recs.append)
    with pipe:
        pipe.push(WheelTicks(0.04, 0, 0))
        assert len(recs) == 1
    with pytest.raises(ValueError, match="sources"):
        FusionPipeline(robot, sources=("gps",))


# -- external odometry twists (a ROS bag's nav_msgs/Odometry) ----------------------------------


class _Twist:
    """A twist event for merge_by_time (it only needs ``t``)."""

    def __init__(self, t: float, v: float, w: float) -> None:
        self.t, self.v, self.w = t, v, w


def _twists(run, step=4):
    """True twists every ``step``-th truth instant, 3.1 ms late (so no twist shares a stamp
    with an IMU sample or a wheel frame's effective time), with 5 mm/s and 5 mrad/s noise
    while moving (standing still, a wheel odometry reads exactly zero)."""
    rng = np.random.default_rng(11)
    t = run.truth_t[::step] + 0.0031
    moving = (run.truth_v[::step] != 0.0) | (run.truth_w[::step] != 0.0)
    v = run.truth_v[::step] + moving * rng.normal(0.0, 0.005, t.size)
    w = run.truth_w[::step] + moving * rng.normal(0.0, 0.005, t.size)
    return t, v, w


def _push_any(pipe, ev):
    if type(ev) is _Twist:
        pipe.push_twist(ev.t, ev.v, ev.w)
    else:
        pipe.push(ev)


def test_twists_stream_into_the_ekfs_own_twist_update(run):
    """Oracle: Keel told the twists' v*w and stillness (tests/keel_feed_reference.py) ->
    imu_motion_codes, the tilt-compensated rate (tests/tilt_rate_reference.py) ->
    ekf.fuse(twist_t=...) composed by hand (merge_events' ordering). IMU samples and twists
    pushed one at a time in host order must publish exactly the fused state after every
    twist."""
    robot = RobotConfig(chassis=run.robot)
    tt, tv, tw = _twists(run)
    motion = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    fed = run.gyro - rest_gyro_bias_by_hand(robot, run.imu_t, run.gyro, motion, twist_t=tt,
                                            twist_v=tv, twist_w=tw)
    q = keel_by_hand(robot, run.imu_t, fed, run.accel, twist_t=tt, twist_v=tv, twist_w=tw)
    gz = tilt_rate_by_hand(robot, run.imu_t, run.gyro, q, motion, twist_t=tt, twist_v=tv,
                           twist_w=tw)
    fv, fw = heading_frame_twists_by_hand(robot, run.imu_t, q, gz, run.gyro[:, 2], tt, tv, tw)
    track, ekf = fuse(run.robot, run.imu_t, gz, noise=EkfNoise(), twist_t=tt, twist_v=fv,
                      twist_w=fw, imu_motion=motion)
    is_t = track.kind == core.EV_TWIST
    rows, t_rows = track.states[is_t], track.t_filter[is_t]

    imu = [ImuSample(t, run.gyro[i], run.accel[i]) for i, t in enumerate(run.imu_t.tolist())]
    tws = [_Twist(*x) for x in zip(tt.tolist(), tv.tolist(), tw.tolist())]
    recs = []
    pipe = FusionPipeline(robot, sources=("imu", "twist"), on_record=recs.append,
                          imu_rate_hz=100.0)
    with pipe:
        for ev in merge_by_time(imu, tws):
            _push_any(pipe, ev)
    stats = pipe.finish_stats()
    assert stats.twist_messages == len(recs) == tt.size == rows.shape[0]
    got = np.array([[r.t, r.x, r.y, r.yaw, r.v, r.w, r.pose_covariance[0, 0],
                     r.twist_covariance[0, 0]] for r in recs])
    want = np.column_stack([t_rows, rows[:, 0], rows[:, 1],
                            np.pi - np.mod(np.pi - rows[:, 2], 2 * np.pi), rows[:, 3],
                            rows[:, 4], rows[:, NX], rows[:, NX + 3]])
    np.testing.assert_array_equal(got, want)
    assert stats.slips == ekf.stats["slips"] and stats.zupts == ekf.stats["zupts"] > 0
    assert stats.late_dropped == 0 and stats.wheel_frames == 0
    # a twist carries no wheel speeds: the record says unknown rather than inventing them
    assert recs[-1].wheel_left_speed is None and recs[-1].wheel_right_speed is None
    # the fused path follows the true one (the twists are the truth plus 5 mm/s noise)
    assert math.hypot(recs[-1].x - run.truth[-1, 0], recs[-1].y - run.truth[-1, 1]) < 0.5


@pytest.mark.parametrize("rate", [None, 10.0])
def test_batch_twists_give_the_same_bytes_as_streaming(run, rate):
    """push_arrays(twist_t=...) == push_imu/push_wheels/push_twist one event at a time,
    byte for byte, with all three sources, a tilted mount, a repeated and an older twist."""
    robot = RobotConfig(chassis=run.robot, imu_mount_rpy=(0.02, -0.01, 0.3))
    tt, tv, tw = _twists(run, step=7)
    k = tt.size // 2
    # a repeated stamp and a stamp older than its predecessor: both dropped, both counted
    tt = np.concatenate([tt[:k], [tt[k - 1], tt[k - 3]], tt[k:]])
    tv = np.concatenate([tv[:k], [0.7, 0.7], tv[k:]])
    tw = np.concatenate([tw[:k], [0.3, 0.3], tw[k:]])
    tws = [_Twist(*x) for x in zip(tt.tolist(), tv.tolist(), tw.tolist())]
    out, stats = [], []
    for batch in (False, True):
        buf = io.StringIO()
        pipe = FusionPipeline(robot, [JsonLinesSink(buf, flush=False)], publish_rate_hz=rate,
                              sources=("imu", "wheels", "twist"))
        with pipe:
            if batch:
                pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks,
                                 twist_t=tt, twist_v=tv, twist_w=tw)
            else:
                for ev in merge_by_time(events(run), tws):
                    _push_any(pipe, ev)
        out.append(buf.getvalue())
        stats.append(pipe.finish_stats().as_dict())
    assert out[0] == out[1]
    assert stats[0] == stats[1]
    assert stats[0]["twist_out_of_order"] == 2 and stats[0]["twist_messages"] == tt.size - 2
    if rate is None:  # one record per wheel frame and per twist
        assert out[0].count("\n") == run.wheel_t.size + tt.size - 2


def test_push_twist_order_watermark_and_errors():
    robot = RobotConfig(chassis=EXAMPLE_ROBOT)
    recs = []
    pipe = FusionPipeline(robot, sources=("twist",), reorder_window=0.5,
                          on_record=recs.append)
    with pytest.raises(RuntimeError, match="not open"):
        pipe.push_twist(0.1, 0.0, 0.0)
    with pipe:
        pipe.push_twist(0.1, 0.2, 0.0)  # the only source: out on arrival (watermark)
        assert len(recs) == 1 and recs[0].t == 0.1
        pipe.push_twist(0.1, 0.2, 0.0)
        pipe.push_twist(0.05, 0.2, 0.0)
        assert len(recs) == 1
        with pytest.raises(ValueError, match="3 twist stamps but 2 v"):
            FusionPipeline(robot).__enter__().push_arrays(twist_t=[1, 2, 3], twist_v=[0, 0],
                                                          twist_w=[0, 0, 0])
    s = pipe.finish_stats()
    assert (s.twist_messages, s.twist_out_of_order) == (1, 2)
    with pytest.raises(ValueError, match="sources"):
        FusionPipeline(robot, sources=("odom",))
