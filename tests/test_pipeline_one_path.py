"""One pipeline path: batch and streaming input run the same per-event code, so they agree bit
for bit for every reorder window and set of watermark sources; and that code follows the
stated release policy, checked against a plain-Python reference written here from the policy
(heapq + the EKF's streaming methods), not from the compiled core."""

from __future__ import annotations

import heapq
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

from fusion.evaluation.synthetic import (
    EXAMPLE_ROBOT,
    EncoderModel,
    ImuModel,
    random_mission,
    simulate,
)
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.sources import merge_by_time
from fusion.planar.accel_slip import accel_slip_flags
from fusion.planar.ekf import EkfNoise, PlanarEKF
from fusion.planar.imu_motion import imu_motion_codes
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink
from fusion.types.samples import ImuSample, WheelTicks


@pytest.fixture(scope="module")
def run():
    """20 s with jittered stamps and wheel frames arriving up to 30 ms late."""
    imu = ImuModel(gyro_bias=(0.001, -0.001, math.radians(0.5)), jitter=0.0005)
    enc = EncoderModel(separation_error=0.03, jitter=0.002, latency=0.03)
    return simulate(random_mission(20.0, seed=9), EXAMPLE_ROBOT, imu, enc, seed=9)


def _events(run):
    imu = [ImuSample(t, run.gyro[i], run.accel[i]) for i, t in enumerate(run.imu_t.tolist())]
    wheels = [WheelTicks(t, int(a), int(b))
              for t, (a, b) in zip(run.wheel_t.tolist(), run.ticks.tolist())]
    return list(merge_by_time(imu, wheels))


def _jsonl(run, batch: bool, noise: EkfNoise | None = None, **kwargs) -> tuple[str, dict]:
    buf = io.StringIO()
    robot = RobotConfig(chassis=run.robot, ekf=noise or EkfNoise())
    pipe = FusionPipeline(robot, [JsonLinesSink(buf, flush=False)], **kwargs)
    with pipe:
        if batch:
            pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
        else:
            for ev in _events(run):
                pipe.push(ev)
    return buf.getvalue(), pipe.finish_stats().as_dict()


@pytest.mark.parametrize("window", [0.0, 0.004, 0.02, None, 0.5])
@pytest.mark.parametrize("sources", [("imu", "wheels"), ("imu",), ("wheels",)])
@pytest.mark.parametrize("rate", [None, 10.0])
def test_batch_equals_streaming_for_any_window_and_sources(run, window, sources, rate):
    kw = {"reorder_window": window, "sources": sources, "publish_rate_hz": rate}
    stream, s_stats = _jsonl(run, False, **kw)
    batch, b_stats = _jsonl(run, True, **kw)
    assert stream.count("\n") > 0
    assert batch == stream
    assert b_stats == s_stats


@pytest.mark.parametrize("window", [0.0, None])
def test_batch_equals_streaming_with_the_accelerometer_driving_the_speed(run, window):
    # the forward specific force's events (EkfNoise.accel_speed_psd) take the same path in
    # both; and they change the output (the switch is live in the pipeline)
    on = EkfNoise(accel_speed_psd=0.005)
    stream, s_stats = _jsonl(run, False, noise=on, reorder_window=window)
    batch, b_stats = _jsonl(run, True, noise=on, reorder_window=window)
    assert batch == stream and b_stats == s_stats
    assert stream != _jsonl(run, True, reorder_window=window)[0]


def test_a_small_window_makes_late_frames_in_both_paths_alike(run):
    # the case that once split the two paths: with no window and only the IMU releasing, the
    # late wheel frames are older than the filter when they arrive
    _, stats = _jsonl(run, True, reorder_window=0.0, sources=("imu",))
    assert stats["late_dropped"] + stats["late_applied"] > 100


def _reference(run, window: float, sources: tuple[str, ...]):
    """The release policy from the module docstring of fusion.pipeline.core, in plain Python:
    each arriving event goes on a heap keyed (effective time, arrival); after each push,
    release everything not newer than the minimum of the sources' latest effective times,
    then everything older than the newest by ``window``; flush at the end. Returns the EKF
    state after each wheel frame."""
    robot = run.robot
    ekf = PlanarEKF(robot)
    shift = 0.5 * robot.encode_sampling_time
    motion = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    fed = run.gyro - rest_gyro_bias_by_hand(RobotConfig(chassis=robot), run.imu_t, run.gyro,
                                            motion, run.wheel_t, run.ticks)
    q = keel_by_hand(RobotConfig(chassis=robot), run.imu_t, fed, run.accel, run.wheel_t,
                     run.ticks)
    rate = tilt_rate_by_hand(RobotConfig(chassis=robot), run.imu_t, run.gyro, q, motion,
                             run.wheel_t, run.ticks)
    rate_at = dict(zip(run.imu_t.tolist(), rate.tolist()))
    motion_at = dict(zip(run.imu_t.tolist(), motion.tolist()))
    # the accelerometer's slip flags of the wheel frames (fusion.planar.accel_slip)
    slip = accel_slip_flags(robot.speed_ratio, robot.encode_sampling_time, run.imu_t,
                            run.accel[:, :2], rate, motion, run.wheel_t, run.ticks)
    slip_at = dict(zip(run.wheel_t.tolist(), slip.tolist()))
    # the ticks as the pipeline hands them to the EKF (on a slope: horizontal, heading rate)
    ticks_at = dict(zip(run.wheel_t.tolist(), heading_frame_ticks_by_hand(
        RobotConfig(chassis=robot), run.imu_t, q, rate, run.gyro[:, 2], run.wheel_t,
        run.ticks).tolist()))
    heap: list = []
    marks = {name: -math.inf for name in sources}
    newest = -math.inf
    out = []

    def apply(ev):
        kind, t, a, _ = ev
        if kind == "imu":
            ekf.update_gyro(t, a, motion_at[t])
        else:
            ekf.update_wheels(t, *ticks_at[t], slip=slip_at[t])
            out.append(ekf.x.copy())

    for n, ev in enumerate(_events(run)):
        if isinstance(ev, ImuSample):
            item, key, src = ("imu", ev.t, rate_at[ev.t], 0), ev.t, "imu"
        else:
            item, key, src = ("wheels", ev.t, ev.left, ev.right), ev.t - shift, "wheels"
        heapq.heappush(heap, (key, n, item))
        newest = max(newest, key)
        if src in marks:
            marks[src] = key
        while heap and heap[0][0] <= min(marks.values()):
            apply(heapq.heappop(heap)[2])
        while heap and heap[0][0] <= newest - window:
            apply(heapq.heappop(heap)[2])
    while heap:
        apply(heapq.heappop(heap)[2])
    return np.array(out), ekf


@pytest.mark.parametrize("window", [0.0, 0.02, 0.5])
@pytest.mark.parametrize("sources", [("imu", "wheels"), ("imu",)])
def test_release_order_follows_the_stated_policy(run, window, sources):
    want, ekf = _reference(run, window, sources)
    rows = []
    pipe = FusionPipeline(RobotConfig(chassis=run.robot), reorder_window=window,
                          sources=sources, tilt=True, on_record=rows.append, accel_slip=True)
    with pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    assert len(rows) == want.shape[0] == run.wheel_t.size
    got = np.array([[r.x, r.y, r.v, r.w] for r in rows])
    np.testing.assert_array_equal(got, want[:, [0, 1, 3, 4]])
    np.testing.assert_array_equal(pipe.ekf.x, ekf.x)
    assert pipe.ekf.stats == ekf.stats


def test_arrays_in_chunks_equal_one_call(run):
    """push_arrays(flush=False) in pieces, then flush: the same records as one call (state
    carries across calls, nothing is released early)."""
    whole, _ = _jsonl(run, True)
    buf = io.StringIO()
    pipe = FusionPipeline(RobotConfig(chassis=run.robot), [JsonLinesSink(buf, flush=False)])
    cut_i = np.searchsorted(run.imu_t, [5.0, 12.5])
    cut_w = np.searchsorted(run.wheel_t, [5.0, 12.5])
    with pipe:
        for (i0, i1), (w0, w1) in zip(zip([0, *cut_i], [*cut_i, None]),
                                      zip([0, *cut_w], [*cut_w, None])):
            pipe.push_arrays(run.imu_t[i0:i1], run.gyro[i0:i1], run.accel[i0:i1],
                             run.wheel_t[w0:w1], run.ticks[w0:w1], flush=False)
    assert buf.getvalue() == whole


def test_non_finite_stamps_are_dropped_in_both_paths(run):
    t = run.imu_t.copy()
    t[[0, 50]] = [math.nan, math.inf]
    wt = run.wheel_t.copy()
    wt[0] = math.nan  # a NaN first frame must not block every later one
    outs = []
    for batch in (False, True):
        recs = []
        pipe = FusionPipeline(RobotConfig(chassis=run.robot), on_record=recs.append)
        with pipe:
            if batch:
                pipe.push_arrays(t, run.gyro, run.accel, wt, run.ticks)
            else:
                imu = [ImuSample(s, run.gyro[i], run.accel[i]) for i, s in enumerate(t.tolist())]
                wheels = [WheelTicks(s, int(a), int(b))
                          for s, (a, b) in zip(wt.tolist(), run.ticks.tolist())]
                # arrival order of the valid stamps; the invalid ones arrive where they stand
                for ev in sorted(imu + wheels, key=lambda e: e.t if math.isfinite(e.t) else 0):
                    pipe.push(ev)
        s = pipe.finish_stats()
        assert (s.imu_invalid_stamp, s.wheel_invalid_stamp) == (2, 1)
        assert (s.imu_out_of_order, s.wheel_out_of_order) == (0, 0)
        assert len(recs) == run.wheel_t.size - 1
        outs.append([(r.t, r.x, r.y, r.yaw) for r in recs])
    assert outs[0] == outs[1]
