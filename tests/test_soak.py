"""Soak test: the demo's live pipeline at 2x real time for a bounded 69 s of wall time
(45 s of warm-up, then 24 s measured: ~3400 wheel frames, ~14000 IMU samples through the real pty,
link, driver, Keel, EKF and a JSON lines file sink), checking that memory stays flat
(tracemalloc, after a warm-up), that latency does not creep up and that every event is
accounted for (fused or counted by reason).

Figures over time (printed with ``-s``): per window (``FUSION_SOAK_WINDOW`` wall s; default a
quarter of the soak, at most 300 s) the traced Python memory, the process's resident memory,
the latency p50/p99 of the window's records (robot time) and the events so far; at the end the
memory slope (least squares over the windows, bytes per hour of wall time). An hour:
``FUSION_SOAK_SECONDS=3600 python3 -m pytest tests/test_soak.py -s`` (at 2x: two hours of
robot time)."""

from __future__ import annotations

import os
import time
import tracemalloc

import numpy as np
import pytest

from drivers.mpu6050 import MPU6050
from drivers.serial_link import ChassisLink
from drivers.sim.robot import LoopingMission, ScaledClock, SimRobot, SimRobotParams
from fusion.cli.demo import freeze_heap, nominal_config, warm_up
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.live import LiveRunner
from fusion.sinks.text import JsonLinesSink

# 2x leaves headroom: tracemalloc slows Python ~2x and a CI machine may be shared.
SPEED = float(os.environ.get("FUSION_SOAK_SPEED", "2"))
# Wall seconds. The suite runs a bounded soak; for a long one (many minutes), e.g. before a
# release: FUSION_SOAK_SECONDS=1800 FUSION_SOAK_SPEED=4 pytest tests/test_soak.py -s
# Wall seconds before the first mark. Some bounded buffers of the run take about 85 s of robot
# time to fill (traced memory grows ~35 bytes per event until then, then ~8: measured with a
# 72 s soak from a 6 s warm-up, 2026-11-26); measured from a shorter warm-up the fill passed
# for growth, and whether the test failed depended on how many marks fitted in (CI flake).
WARM_S = float(os.environ.get("FUSION_SOAK_WARM", "45"))
SOAK_S = float(os.environ.get("FUSION_SOAK_SECONDS", "24"))
WINDOW_S = float(os.environ.get("FUSION_SOAK_WINDOW", min(300.0, SOAK_S / 4)))


def _rss_bytes() -> int:
    """Resident memory of this process (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return 0


@pytest.mark.slow
def test_soak_memory_flat_and_latency_stable(tmp_path):
    params = SimRobotParams()
    cfg = nominal_config(params)
    warm_up(cfg)
    freeze_heap()  # as the commands do: no long GC pauses of the source threads
    clock = ScaledClock(SPEED)
    robot = SimRobot(clock, params, keep_truth=False)  # an indefinite run: bounded history
    ch = cfg.robot.chassis
    link = ChassisLink(robot.port, period=ch.encode_sampling_time, clock=clock)
    link.start(wait=5.0)
    imu = MPU6050(robot.bus, clock=clock, sample_rate_hz=100.0, gyro_range_dps=500,
                  accel_range_g=4)
    out = tmp_path / "soak.jsonl"
    pipe = FusionPipeline(cfg.robot, [JsonLinesSink(out, flush=False)], reorder_window=0.06,
                          clock=clock, latency_window=100_000).open()
    robot.start()
    runner = LiveRunner(pipe, link=link, imu=imu).start()
    t0 = clock()
    mission = LoopingMission(link, ch, clock, t0)
    state = {"mark": None}
    wall0 = time.monotonic()
    marks = []  # (traced bytes, latencies kept, records, queued, wall s, rss bytes)

    def mark(elapsed: float) -> None:
        state["mark"] = elapsed
        marks.append((tracemalloc.get_traced_memory()[0], len(pipe.latencies),
                      pipe.stats.records, runner.queued, elapsed, _rss_bytes()))
        if len(marks) > 1:
            new = marks[-1][2] - marks[-2][2]  # the window's records: the newest latencies
            lat = np.fromiter(pipe.latencies, dtype=float)[-new:] if new else np.zeros(1)
            p50, p99 = np.percentile(lat, [50, 99])
            led = runner.ledger()
            print(f"soak {elapsed - WARM_S:7.0f} s: traced {marks[-1][0] / 1e6:7.3f} MB, rss "
                  f"{marks[-1][5] / 1e6:7.1f} MB, latency p50/p99 {p50 * 1e3:5.0f}/"
                  f"{p99 * 1e3:5.0f} ms, records {marks[-1][2]}, events in {led['in']}, "
                  f"unaccounted {led['unaccounted']}, queued {marks[-1][3]}", flush=True)

    def tick() -> bool:
        mission()
        elapsed = time.monotonic() - wall0
        done = elapsed >= WARM_S + SOAK_S
        if state["mark"] is None and elapsed >= WARM_S:
            mark(elapsed)
        elif state["mark"] is not None and (done or elapsed >= state["mark"] + WINDOW_S):
            mark(elapsed)  # the last mark is always at the end: a fixed span is measured
        return done

    # Traced from the start: bounded buffers (ring buffers, caches) fill with traced objects
    # during the warm-up and then only replace them. Started at the end of the warm-up, a
    # full buffer of untraced objects would show as growth until it has turned over.
    tracemalloc.start()
    try:
        runner.run(until=tick, poll=0.01)
    finally:
        tracemalloc.stop()
        runner.stop()
        link.close()
        robot.close()
        imu.close()
        pipe.close()

    stats = pipe.finish_stats()
    robot_s = clock() - t0
    assert robot_s > 0.8 * SPEED * (WARM_S + SOAK_S)
    assert stats.wheel_frames > 0.8 * robot_s / 0.04 and stats.imu_samples > 0.8 * robot_s * 100
    assert stats.records == stats.wheel_frames
    assert sum(1 for _ in out.open()) == stats.records  # the file sink got every record
    led = runner.ledger()
    print(f"ledger {led}")
    assert led["unaccounted"] == 0 and led["held"] == led["queued"] == 0

    # memory: traced Python memory from the first mark (after the warm-up) to the last, at
    # the end, grows by less than 100 kB + 20 bytes per event. The latency history alone
    # takes ~30 bytes per frame (~6 per event, 4 IMU samples per frame); measured 8 bytes per
    # event (2026-11-26). Keeping one sample or record per event (hundreds of bytes each)
    # exceeds it, over any soak length.
    mem = [m[0] for m in marks]
    assert len(mem) >= 4, marks
    growth = mem[-1] - mem[0]
    events = (marks[-1][2] - marks[0][2]) * 5  # records ~ frames; 4 IMU samples per frame
    wall_h = np.array([m[4] for m in marks]) / 3600.0
    slope = np.polyfit(wall_h, np.array(mem, dtype=float), 1)[0] if len(mem) > 2 else 0.0
    rss = np.array([m[5] for m in marks], dtype=float)
    rss_slope = np.polyfit(wall_h, rss, 1)[0] if len(mem) > 2 else 0.0
    print(f"traced memory at the marks: {[round(m / 1e6, 2) for m in mem]} MB; growth "
          f"{growth / 1e3:.0f} kB over ~{events} events; slope {slope / 1e3:.1f} kB/h traced, "
          f"{rss_slope / 1e6:.2f} MB/h resident (wall hours; {SOAK_S:g} s soak at {SPEED:g}x)")
    half = len(wall_h) // 2
    if len(wall_h) - half > 2:  # the second half: after the latency history is full
        late = np.polyfit(wall_h[half:], np.array(mem, dtype=float)[half:], 1)[0]
        late_rss = np.polyfit(wall_h[half:], rss[half:], 1)[0]
        print(f"second half: slope {late / 1e3:.1f} kB/h traced, {late_rss / 1e6:.2f} MB/h "
              "resident")
    assert growth < 100_000 + 20 * events

    # latency: the last third is not slower than the first (robot time, s)
    lat = np.fromiter(pipe.latencies, dtype=float)
    n = lat.size // 3
    first, last = lat[:n], lat[-n:]
    p50a, p99a = np.percentile(first, [50, 99])
    p50b, p99b = np.percentile(last, [50, 99])
    print(f"latency robot-time p50/p99 first third {p50a * 1e3:.0f}/{p99a * 1e3:.0f} ms, "
          f"last third {p50b * 1e3:.0f}/{p99b * 1e3:.0f} ms; wall = robot / {SPEED:g}")
    # no backlog builds up: a pipeline that falls behind accumulates queued events and its
    # latency grows without bound over minutes; other processes on a shared machine can
    # only shift it by a scheduling delay (a quarter second of robot time is 60 ms of wall)
    assert p50b < p50a + 0.25
    assert max(m[3] for m in marks) < 200, marks  # events waiting at each mark
