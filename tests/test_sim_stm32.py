"""The simulated STM32 firmware: PID, motor and encoder against hand computations, the
DEBUG-uart1 replies, and end to end over ptys with ChassisLink and the odometry."""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest

from drivers.chassis import (
    DebugReplyParser,
    encode_pid_request,
    encode_pid_reset,
    encode_pid_set,
    encode_wheel_frame,
)
from drivers.serial_link import ChassisLink
from drivers.sim.stm32 import PtyStm32, Stm32Sim, Stm32SimParams, _Pid
from fusion.geometry.kinematics import DiffDriveParams, twist_to_ticks
from fusion.planar.odometry import WheelOdometry

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

TIMEOUT = 5.0


def test_incremental_pid_by_hand():
    pid = _Pid()
    kw = dict(kp=1.0, ki=0.5, kd=0.25, ka=1.0, limit=30000)
    # e=10, e1=e2=0: du = 1*(10-0) + 0.5*10 + 0.25*(10-0+0) = 17.5 -> int 17
    assert pid.step(10, 0, **kw) == 17
    # e=6, e1=10, e2=0: du = (6-10) + 3 + 0.25*(6-20+0) = -4.5 -> int(12.5) = 12
    assert pid.step(10, 4, **kw) == 12
    # e=2, e1=6, e2=10: du = (2-6) + 1 + 0.25*(2-12+10) = -3 -> 9
    assert pid.step(10, 8, **kw) == 9
    # negative: C truncation toward zero: e=-3 from rest: du = -3 - 1.5 - 0.75 = -5.25 -> -5
    assert _Pid().step(-3, 0, **kw) == -5
    # clamp to the PWM limit
    assert _Pid().step(100000, 0, 1.0, 1.0, 0.0, 1.0, 30000) == 30000
    # brake on zero target: output 0 and history cleared
    assert pid.step(0, 8, **kw) == 0
    assert (pid.u, pid.e1, pid.e2) == (0, 0, 0)


def test_motor_first_order_open_loop():
    p = Stm32SimParams(period=0.04, motor_tau=0.1, wheel_speed_full=1.2, pwm_max=35999)
    sim = Stm32Sim(p)
    u = 18000
    sim._physics(u, -u)  # one period at constant PWM from rest
    ss = u / 35999 * 1.2  # steady rim speed, m/s
    # v(t) = ss * (1 - exp(-t/tau)); travel = ss*(t - tau*(1 - exp(-t/tau)))
    t = 0.04
    assert sim.left.speed == pytest.approx(ss * (1 - math.exp(-t / 0.1)), rel=1e-12)
    travel = ss * (t - 0.1 * (1 - math.exp(-t / 0.1)))
    assert sim.left.enc * p.speed_ratio == pytest.approx(travel, rel=1e-12)
    assert sim.right.enc == pytest.approx(-sim.left.enc, rel=1e-12)
    # turning in place about the centre: x, y stay 0; theta = (dr - dl)/L
    assert sim.pose[0] == pytest.approx(0.0, abs=1e-15)
    assert sim.pose[2] == pytest.approx(-2 * travel / p.wheel_distance, rel=1e-12)


def test_encoder_counts_are_quantised_but_never_lost():
    sim = Stm32Sim()
    sim.target = (333, -123)
    for _ in range(100):
        sim.step()
    counts = np.array(sim.ticks_counted)
    assert counts.dtype.kind == "i"
    # the running sum of counts is floor(rotation): error in [0, 1) tick, never accumulating
    total = counts.sum(axis=0)
    assert total[0] == math.floor(sim.left.enc_read)
    assert 0 <= sim.left.enc - total[0] < 1 + abs(sim.left.speed) * sim.params.period / 5e-5


def test_closed_loop_reaches_target():
    sim = Stm32Sim()
    sim.target = (400, -250)
    for _ in range(50):  # 2 s
        sim.step()
    last = np.array(list(sim.ticks_counted)[-10:])
    assert np.all(np.abs(last[:, 0] - 400) <= 1)
    assert np.all(np.abs(last[:, 1] + 250) <= 1)
    # zero target brakes: PWM 0 at once
    sim.command_bytes(encode_wheel_frame(0, 0))
    sim.step()
    assert sim.pwm == (0, 0)


def test_slip_and_dropped_frames():
    p = Stm32SimParams(slip=(0.1, 0.1), drop_prob=0.3, seed=4)
    sim = Stm32Sim(p)
    sim.command_bytes(encode_wheel_frame(300, 300))
    for _ in range(100):
        sim.step()
    enc_travel = sim.left.enc * p.speed_ratio
    # straight line: ground moves 90 % of the encoder travel
    assert sim.pose[0] == pytest.approx(0.9 * enc_travel, rel=1e-9)
    assert sim.dropped == 100 - len(sim.ticks_sent)
    assert 15 < sim.dropped < 45  # binomial(100, 0.3): mean 30, sd 4.6


def test_debug_uart1_replies():
    sim = Stm32Sim(Stm32SimParams(firmware_version=(2, 1, 7)))
    rp = DebugReplyParser()
    ev = rp.feed(sim.take_debug_output())
    assert [e.kind for e in ev] == ["banner", "version"]
    assert ev[1].values == (2, 1, 7)
    sim.debug_bytes(encode_pid_set(1.5, -0.25, 0.0001))
    ev = rp.feed(sim.take_debug_output())
    assert [e.kind for e in ev] == ["response", "gains"]
    assert ev[1].values == (1.5, -0.25, 0.0001)
    assert sim.gains == (1.5, -0.25, 0.0001)
    sim.debug_bytes(encode_pid_request())
    ev = rp.feed(sim.take_debug_output())
    assert [e.kind for e in ev] == ["response", "version", "gains"]
    sim.debug_bytes(b"\x00garbage" + encode_pid_reset())
    ev = rp.feed(sim.take_debug_output())
    d = Stm32SimParams()
    assert ev[-1].values == (d.kp, d.ki, d.kd)
    assert sim.gains == (d.kp, d.ki, d.kd)


def wait_periods(chassis, n: int) -> None:
    """Wait for n firmware periods (not wall-clock time: the host may be loaded)."""
    p0 = chassis.sim.periods
    end = time.monotonic() + 30
    while chassis.sim.periods < p0 + n and time.monotonic() < end:
        time.sleep(0.01)


@pytest.fixture
def chassis(tmp_path):
    params = Stm32SimParams(period=0.02)
    sim = PtyStm32(Stm32Sim(params), data_link=str(tmp_path / "data"),
                   debug_link=str(tmp_path / "debug")).start()
    yield sim
    sim.close()


def test_end_to_end_odometry_matches_truth(chassis):
    p = chassis.sim.params
    geo = DiffDriveParams(wheel_distance=p.wheel_distance, speed_ratio=p.speed_ratio,
                          encode_sampling_time=p.period)
    odo = WheelOdometry(geo, method="arc")
    with ChassisLink(chassis.data_port, period=p.period, command_timeout=None) as link:
        left, right = twist_to_ticks(0.3, 0.8, geo, rounding="nearest")
        link.send_ticks(left, right)
        wait_periods(chassis, 70)
        link.send_ticks(0, 0)
        wait_periods(chassis, 20)
        chassis.stop()  # stop the firmware: every frame it sent is now on the wire
        frames = []
        end = time.monotonic() + TIMEOUT
        while len(frames) < len(chassis.sim.ticks_sent) and time.monotonic() < end:
            f = link.get(0.1)
            if f is not None:
                frames.append(f)
    sent = list(chassis.sim.ticks_sent)
    got = [(f.left, f.right) for f in frames]
    assert len(got) == len(sent), (len(got), len(sent), got[-3:], sent[-3:])
    assert got == sent  # none lost, none invented
    # the commanded wheels really turned: after 30 periods of the command, counts within
    # 2 ticks of the targets (periods counted by the firmware, whatever the host load)
    tg = list(chassis.sim.targets)
    on = [i for i in range(30, len(tg)) if all(t == (left, right) for t in tg[i - 30 : i + 1])]
    assert len(on) >= 10
    steady = np.array([chassis.sim.ticks_counted[i] for i in on])
    assert np.all(np.abs(steady - [left, right]) <= 2)
    for f in frames:
        odo.update(f.left, f.right, t=f.t)
    truth = chassis.sim.pose_at_sent[-1]
    st = odo.state
    # Quantisation bound: each wheel's cumulative count is floor(rotation), less than 1 tick
    # (5e-5 m) behind; heading error < 2 ticks * ratio / L = 3.3e-4 rad; along a path of D m
    # that heading error moves the position by < D * 3.3e-4 m, plus the 1-tick along-track.
    q = p.speed_ratio
    dth_bound = 2 * q / p.wheel_distance
    D = st.distance
    assert abs(st.theta - truth[2]) < dth_bound
    assert math.hypot(st.x - truth[0], st.y - truth[1]) < D * dth_bound + 2 * q
    assert D > 0.3  # it drove


def test_unplug_and_replug_resumes(chassis):
    p = chassis.sim.params
    events = []
    with ChassisLink(chassis.data_port, period=p.period, reconnect_interval=0.05,
                     command_timeout=None, on_event=events.append) as link:
        link.send_ticks(200, 200)
        assert link.get(TIMEOUT) is not None
        chassis.unplug()
        end = time.monotonic() + TIMEOUT
        while link.connected and time.monotonic() < end:
            time.sleep(0.01)
        assert not link.connected
        assert any(e.kind == "disconnected" and "data" in e.message for e in events)
        time.sleep(0.2)
        chassis.sim.target = (0, 0)  # the firmware lost its target meanwhile (say, a reset)
        chassis.replug()
        end = time.monotonic() + TIMEOUT
        while not link.connected and time.monotonic() < end:
            time.sleep(0.01)
        assert link.connected and link.reconnects == 1
        link.drain()
        # the link re-sent the current target: the wheels turn again
        end = time.monotonic() + TIMEOUT
        f = None
        while time.monotonic() < end:
            f = link.get(0.5)
            if f is not None and abs(f.left - 200) <= 5:
                break
        assert f is not None and abs(f.left - 200) <= 5
        assert chassis.sim.target == (200, 200)


def test_module_runs_as_a_program(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "drivers.sim.stm32", "--link-dir", str(tmp_path),
         "--duration", "0.3"],
        capture_output=True, text=True, timeout=30,
    )
    assert out.returncode == 0, out.stderr
    assert str(tmp_path / "data") in out.stdout
    assert str(tmp_path / "debug") in out.stdout


def _traced_growth(history: int | None, warm: int, more: int) -> int:
    """Bytes still allocated after ``more`` periods, beyond what ``warm`` periods held."""
    import tracemalloc

    from drivers.chassis import encode_wheel_frame as frame

    sim = Stm32Sim(Stm32SimParams(history=history, substeps=1, drop_prob=0.1, seed=1))
    sim.command_bytes(frame(300, -200))
    tracemalloc.start()
    try:
        for _ in range(warm):
            sim.step()
        before = tracemalloc.get_traced_memory()[0]
        for _ in range(more):
            sim.step()
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert sim.periods == warm + more
    return after - before


def test_a_long_run_keeps_flat_memory():
    # 10000 periods (under 7 min of firmware time at 40 ms) after the history has filled: with
    # ring buffers nothing accumulates; the unbounded records (history=None) grow by a few
    # hundred bytes per period (a pose array and tuples), which is what ran the memory up
    growth = _traced_growth(200, 500, 10000)
    unbounded = _traced_growth(None, 500, 10000)
    assert unbounded > 10000 * 200
    assert growth < 20_000  # noise of the allocator, not a per-period leak


def test_history_keeps_the_newest_periods():
    sim = Stm32Sim(Stm32SimParams(history=5, substeps=1))
    for k in range(12):
        sim.target = (k, -k)
        sim.step()
    assert list(sim.targets) == [(k, -k) for k in range(7, 12)]
    assert len(sim.ticks_counted) == len(sim.pose_at_read) == 5
    assert sim.periods == 12
    with pytest.raises(ValueError, match="history"):
        Stm32SimParams(history=0)


def test_the_scaled_clock_runs_speed_times_the_wall_clock_from_its_start():
    from drivers.sim.robot import ScaledClock

    clock = ScaledClock(20.0, start=1000.0)
    w0, r0 = time.monotonic(), clock()
    assert 1000.0 <= r0 < 1001.0  # read right after it was made
    clock.sleep(10.0)  # 0.5 wall s: 5 % of it is 25 ms for a busy machine's scheduling
    w1, r1 = time.monotonic(), clock()
    assert r1 - r0 == pytest.approx(20.0 * (w1 - w0), rel=0.05)
    assert r1 - r0 >= 10.0
    for bad in ({"speed": 0.0}, {"speed": math.inf}, {"start": math.nan}, {"start": -5.0}):
        with pytest.raises(ValueError):
            ScaledClock(**bad)
