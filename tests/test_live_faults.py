"""Fault injection into the live pipeline (issue 12): for every fault, every event the sources
delivered is fused or counted under a named reason (0 unaccounted), and the outputs are valid
afterwards (the MCAP file readable with every record, the CSV complete).

Real parts where a robot has them: the simulated STM32 firmware on a real pty read by the real
ChassisLink, the register-level simulated MPU6050 read through the real driver's FIFO, real
files. Robot time runs on a :class:`drivers.sim.robot.ScaledClock` (4-60x), so a minute of
robot time costs seconds. The burst and the overloaded consumer use a synthetic source on the
same clock (a register-level chip cannot hold a 10,000-sample backlog; its FIFO holds 85).

Each test prints one row of the fault table (``pytest -s``): fault, events in, fused, counted
by reason, lost (unaccounted), recovery time in robot seconds.
"""

from __future__ import annotations

import csv
import dataclasses
import errno
import math
import threading

import numpy as np
import pytest
from sim_hardware import NackBursts, sim_hardware  # tests/sim_hardware.py

from drivers.sim.robot import ScaledClock, SimRobotParams, send_twist
from fusion.cli.demo import freeze_heap, nominal_config, warm_up
from fusion.io.fused_csv import FUSED_CSV_COLUMNS
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.live import (
    ImuFifoSource,
    LinkSource,
    LiveRunner,
    SourceFailedError,
)
from fusion.sinks.bag import McapSink
from fusion.sinks.text import CsvSink
from fusion.types.constants import STANDARD_GRAVITY
from fusion.types.samples import ImuSample, WheelTicks

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

PARAMS = SimRobotParams(slip_patches=())
CFG = nominal_config(PARAMS)


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up(CFG)  # compile (or load) the numba cores before any clock starts


# -- sources that inject faults -------------------------------------------------------------
class Mangled:
    """Wraps a source: ``fn(index, event, t)`` returns the event to deliver (a changed
    stamp), ``index`` counting the wrapped source's events from 0, ``t`` the rig's time."""

    def __init__(self, inner, rig, fn) -> None:
        self.inner, self.rig, self.fn = inner, rig, fn
        self.name = inner.name
        self.count = 0

    def start(self) -> None:
        getattr(self.inner, "start", lambda: None)()

    def read(self):
        out = []
        for ev in self.inner.read():
            out.append(self.fn(self.count, ev, self.rig.now()))
            self.count += 1
        return out

    def restart(self) -> None:
        self.inner.restart()


class Paused:
    """Wraps a source: it is not read between rig times ``t0`` and ``t1`` (a hung bus)."""

    def __init__(self, inner, rig, t0: float, t1: float) -> None:
        self.inner, self.rig, self.t0, self.t1 = inner, rig, t0, t1
        self.name = inner.name

    def start(self) -> None:
        getattr(self.inner, "start", lambda: None)()

    def read(self):
        now = self.rig.now()
        if self.t0 <= now < self.t1:
            self.rig.clock.sleep(min(0.05, self.t1 - now))
            return []
        return self.inner.read()

    def restart(self) -> None:
        self.inner.restart()


class Raising:
    """Wraps a source: ``read`` raises when ``when(t, raised_so_far)`` (``t`` the rig's
    time)."""

    def __init__(self, inner, rig, when) -> None:
        self.inner, self.rig, self.when = inner, rig, when
        self.name = inner.name
        self.raised = 0
        self.restarts = 0
        self.first_raise = self.last_restart = None  # rig times

    def start(self) -> None:
        getattr(self.inner, "start", lambda: None)()

    def read(self):
        if self.when(self.rig.now(), self.raised):
            if self.first_raise is None:
                self.first_raise = self.rig.now()
            self.raised += 1
            raise RuntimeError(f"injected fault {self.raised} in source {self.name}")
        return self.inner.read()

    def restart(self) -> None:
        self.restarts += 1
        self.last_restart = self.rig.now()
        self.inner.restart()


class Synthetic:
    """IMU samples (``rate`` Hz, a robot at rest) or wheel frames (``rate`` Hz, constant
    ticks) stamped on ``clock``; each read delivers every event due since the last one.
    With ``hold_until`` (clock time) nothing comes until then, then the backlog at once (a
    reader catching up)."""

    def __init__(self, name: str, clock, rate: float, hold_until: float | None = None) -> None:
        self.name, self.clock, self.rate = name, clock, rate
        self.k = None
        self._hold_until = hold_until

    def read(self):
        now = self.clock()
        if self.k is None:
            self.k = math.floor(now * self.rate) + 1
        if self._hold_until is not None and now < self._hold_until:
            self.clock.sleep(0.01)
            return []
        n = math.floor(now * self.rate) + 1 - self.k
        self.clock.sleep(0.01)
        if n <= 0:
            return []
        t = (self.k + np.arange(n)) / self.rate
        self.k += n
        if self.name == "imu":
            g, a = np.zeros(3), np.array([0.0, 0.0, STANDARD_GRAVITY])
            return [ImuSample(float(s), g, a) for s in t]
        return [WheelTicks(float(s), 400, 410) for s in t]

    def restart(self) -> None:
        pass


# -- the rig ------------------------------------------------------------------------------
class Rig:
    """A pipeline with two real file sinks recorded live as ``fusion run`` does (MCAP, CSV)
    and any ``extra_sinks``, fed by a :class:`LiveRunner`: from the simulated robot (real
    pty, register-level chip) or from ``make_sources(rig)``; ``wrap(source, rig)`` wraps
    each source (fault injection)."""

    def __init__(self, tmp_path, *, speed: float = 4.0, link_path: str | None = None,
                 make_sources=None, wrap=None, extra_sinks=(),
                 pipeline_sources=("imu", "wheels"), publish_rate_hz=None,
                 **runner_kw) -> None:
        freeze_heap()  # as the commands do: no long GC pauses of the source threads
        # a host clock up for a while (the time since boot): a stamp stepped back 10 s is
        # out of order, not below 0 (test_stamps_below_zero_are_counted_not_written)
        self.clock = ScaledClock(speed, start=1000.0)
        self.faults: list[tuple[str, str]] = []
        self.sink_errors: list[str] = []
        self.mcap = tmp_path / "out.mcap"
        self.csv = tmp_path / "out.csv"
        self.sinks = [McapSink(self.mcap, live=True), CsvSink(self.csv, live=True),
                      *extra_sinks]
        self.records = []
        self.robot = self.link = self.imu = None
        if make_sources is None:
            self.robot, self.link, self.imu = sim_hardware(self.clock, PARAMS, CFG,
                                                           link_path=link_path,
                                                           keep_truth=False)
            self.imu_source = ImuFifoSource(self.imu, 0.02)
            sources = [self.imu_source, LinkSource(self.link)]
        else:
            sources = make_sources(self)
        if wrap is not None:
            sources = [wrap(s, self) for s in sources]
        self.pipe = FusionPipeline(
            CFG.robot, self.sinks, reorder_window=0.1, clock=self.clock, max_stamp_lead=1.0,
            sources=pipeline_sources, publish_rate_hz=publish_rate_hz,
            on_record=self.records.append,
            on_sink_error=lambda sink, exc, text: self.sink_errors.append(text)).open()
        if self.robot is not None:
            self.robot.start()
        # the rig's time starts with the sources (not the set-up), and before their threads:
        # a wrapper reads it from the first read on (set after them, a set-up that took over
        # 2 robot s made the raising source fail at once on the old origin, and its outage
        # was measured across two origins: 0.44 robot s for 2.8 in a full-suite run)
        self.t0 = self.clock()
        self.runner = LiveRunner(self.pipe, sources=sources,
                                 on_fault=lambda n, text: self.faults.append((n, text)),
                                 **runner_kw).start()
        self.sent = -1.0
        self.trace: list[tuple[float, int, int]] = []  # (t, IMU samples, frames accepted)

    def now(self) -> float:
        """Robot s since the rig was made."""
        return self.clock() - self.t0

    def drive_until(self, t_end: float, hook=None, on_event=None) -> None:
        """Run until rig time ``t_end`` s, driving an arc (0.3 m/s, 0.3 rad/s)."""
        def tick() -> bool:
            t = self.now()
            st = self.pipe.stats
            self.trace.append((t, st.imu_samples, st.wheel_frames))
            if hook is not None:
                hook(t)
            if self.link is not None and t - self.sent > 0.1:
                send_twist(self.link, CFG.robot.chassis, *((0.0, 0.0) if t < 0.5
                                                          else (0.3, 0.3)))
                self.sent = t
            return t >= t_end

        self.runner.run(until=tick, poll=0.01, on_event=on_event)

    def recovery(self, t_fault_end: float, column: int) -> float:
        """Robot s from ``t_fault_end`` until the source's next accepted event (column 1:
        IMU samples, 2: wheel frames), to the resolution of the run loop's turns."""
        trace = np.array(self.trace)
        after = trace[trace[:, 0] >= t_fault_end]
        moved = after[after[:, column] > after[0, column]]
        return float(moved[0, 0] - t_fault_end) if moved.size else math.inf

    def close(self, close_error: type | None = None) -> dict:
        """Stop the sources (pushing what they queued), close the pipeline; returns the
        final ledger. ``close_error``: the error close must raise (a failed sink)."""
        try:
            self.runner.stop()
        finally:
            for dev in (self.link, self.robot, self.imu):
                if dev is not None:
                    dev.close()
            if close_error is None:
                self.pipe.close()
            else:
                with pytest.raises(close_error):
                    self.pipe.close()
        return self.runner.ledger()

    def check(self, led: dict, fault: str, recovery) -> None:
        """0 unaccounted and valid outputs; prints the fault table's row."""
        assert led["unaccounted"] == 0, led
        assert led["held"] == 0 and led["queued"] == 0, led
        assert led["in"] == led["fused"] + sum(led["dropped"].values()), led
        n = self.pipe.stats.records
        assert n == len(self.records) > 0
        from mcap.reader import make_reader

        with open(self.mcap, "rb") as fh:  # readable, with every record
            odom = sum(1 for _s, ch, _m in make_reader(fh).iter_messages()
                       if ch.topic == "/odom")
        assert odom == n
        rows = _csv_rows(self.csv)  # complete: one full row per record
        assert [float(r["t"]) for r in rows] == [r.t for r in self.records]
        reasons = ", ".join(f"{k} {v}" for k, v in led["dropped"].items() if v) or "none"
        rec = recovery if isinstance(recovery, str) else f"{recovery:.2f}"
        print(f"\nFAULT ROW | {fault} | {led['in']} | {led['fused']} | {reasons} | "
              f"{led['unaccounted']} | {rec}")


def _csv_rows(path) -> list[dict]:
    text = path.read_text()
    assert text.endswith("\n")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == tuple(FUSED_CSV_COLUMNS)
        rows = list(reader)
    assert all(None not in r and None not in r.values() for r in rows)
    return rows


def _restamp(ev, t: float):
    return dataclasses.replace(ev, t=t)


# -- the faults ----------------------------------------------------------------------------
class Burst:
    """An IMU source that delivers ``n`` samples (1 kHz, rest) at once when the rig's time
    passes ``at`` s (a reader that hung, then caught up), stamped up to 0.5 s before then."""

    name = "imu"

    def __init__(self, rig, n: int, at: float) -> None:
        self.rig, self.n, self.at, self.sent = rig, n, at, False

    def read(self):
        self.rig.clock.sleep(0.01)
        if self.sent or self.rig.now() < self.at:
            return []
        self.sent = True
        t = self.rig.clock() - 0.5 - (self.n - np.arange(self.n)) / 1000.0
        g, a = np.zeros(3), np.array([0.0, 0.0, STANDARD_GRAVITY])
        return [ImuSample(float(s), g, a) for s in t]

    def restart(self) -> None:
        pass


def test_a_burst_of_10000_events_keeps_its_order_and_loses_none(tmp_path):
    seen = []
    # a reader that hung for 10 s delivers its 10,000 samples at once
    rig = Rig(tmp_path, make_sources=lambda rig: [Burst(rig, 10_000, 10.5)],
              pipeline_sources=("imu",), publish_rate_hz=10.0, speed=10.0)
    rig.drive_until(11.0, on_event=lambda ev: seen.append(ev.t))
    rig.runner.run(until=lambda: rig.runner.events_pushed >= 10_000 or rig.now() > 300,
                   on_event=lambda ev: seen.append(ev.t))
    led = rig.close()
    # in order: not one sample dropped as out of order (the old runner put the 1001st of a
    # burst back at the tail of its queue, behind newer samples)
    assert len(seen) == led["in"] == 10_000 and np.all(np.diff(seen) > 0)
    assert led["fused"] == 10_000, led
    rig.check(led, "burst of 10,000 events", 0.0)


def test_ctrl_c_inside_a_batch_puts_the_rest_of_it_back(tmp_path):
    # 1,000 samples arrive at once and the consumer takes them as one batch; Ctrl-C
    # (KeyboardInterrupt, here raised by on_event) comes at the 300th. The 701 events in hand
    # that the pipeline never saw go back to the front of the queue, and stop() pushes them:
    # the old runner lost them (701 unaccounted in the final ledger; `fusion run`'s Ctrl-C
    # test caught 2 of them once).
    seen = []

    def interrupt_at_300(ev) -> None:
        seen.append(ev.t)
        if len(seen) == 300:
            raise KeyboardInterrupt

    # at 3 s: stamps from 1.5 s on (the rig's time; its clock reads 1000 s more)
    rig = Rig(tmp_path, make_sources=lambda rig: [Burst(rig, 1000, 3.0)],
              pipeline_sources=("imu",), publish_rate_hz=10.0, speed=10.0)
    with pytest.raises(KeyboardInterrupt):
        rig.runner.run(until=lambda: rig.now() > 300, poll=0.01, on_event=interrupt_at_300)
    assert rig.runner.events_pushed == 299 and rig.runner.ledger()["queued"] == 701
    led = rig.close()
    assert led["fused"] == 1000 and led["dropped"]["out_of_order"] == 0, led
    rig.check(led, "Ctrl-C inside a batch of 1,000", "-")


def test_a_producer_faster_than_the_consumer_for_60_s_loses_the_oldest_counted(tmp_path):
    def sources(rig):
        return [Synthetic("imu", rig.clock, 100.0), Synthetic("wheels", rig.clock, 25.0)]

    rig = Rig(tmp_path, make_sources=sources, speed=60.0, max_queue=200)
    pause = threading.Event()
    rig.drive_until(60.0, on_event=lambda ev: pause.wait(0.0005))  # ~2000 events/wall s
    led = rig.close()
    overflow = led["dropped"]["queue_overflow"]
    assert led["in"] > 0.9 * 60.0 * 125 and overflow > 0.3 * led["in"], led
    h = rig.runner.health
    assert h["imu"].overflow + h["wheels"].overflow == overflow
    assert led["dropped"]["out_of_order"] == 0  # drop-oldest keeps each source in order
    rig.check(led, "producer faster than consumer for 60 s", "n/a (overloaded throughout)")


def test_clock_jumps_of_plus_1e9_s_and_minus_10_s_are_counted(tmp_path):
    def jump(ev, t):
        if 2.0 <= t < 2.5:
            return _restamp(ev, ev.t + 1e9)  # an epoch stamp among monotonic ones
        if t >= 3.5:
            return _restamp(ev, ev.t - 10.0)  # the host clock stepped back 10 s
        return ev

    # the windows by each event's own stamp on the rig's time, not by when it was read: 0.5
    # s of robot time is 62 ms of wall time at 8x, which a reader held up that long (a
    # garbage collection in a long test session) skipped whole (invalid_stamp 0 in two
    # full-suite runs of 2026-11-29)
    rig = Rig(tmp_path, speed=8.0, wrap=lambda s, rig: Mangled(
        s, rig, lambda i, ev, t: jump(ev, ev.t - rig.t0)))
    rig.drive_until(16.0)
    led = rig.close()
    d = led["dropped"]
    # +1e9: ahead of the host clock: invalid stamps; -10 s: out of order until the stamps
    # pass the last accepted ones again, 10 s of robot time later
    assert d["invalid_stamp"] > 0.8 * 0.5 * 125, d
    assert d["out_of_order"] > 0.9 * 10 * 125, d
    rec = rig.recovery(13.5 - 0.3, 2)
    assert rec < 1.0
    rig.check(led, "clock jumps +1e9 s (for 0.5 s), then -10 s",
              f"0 (+1e9 s); {10 - 0.3 + rec:.2f} (-10 s)")


def test_nan_and_inf_stamps_first_and_mid_stream_are_counted(tmp_path):
    bad = {0: math.nan, 1: math.inf, 80: math.nan, 81: -math.inf, 82: math.inf}

    def poison(i, ev, t):
        return _restamp(ev, bad[i]) if i in bad else ev

    rig = Rig(tmp_path, speed=8.0, wrap=lambda s, rig: Mangled(s, rig, poison))
    rig.drive_until(5.0)
    led = rig.close()
    assert led["dropped"]["invalid_stamp"] == 2 * len(bad), led  # both sources
    assert led["dropped"]["out_of_order"] == 0
    st = rig.pipe.stats
    assert st.imu_invalid_stamp == st.wheel_invalid_stamp == len(bad)
    # a NaN first frame blocks nothing: the wheels go on (about 25 frames per s)
    assert st.wheel_frames > 0.8 * 25 * 5.0 - len(bad)
    rig.check(led, "NaN and inf stamps, first and mid-stream", "0 (the next event)")


def test_stamps_below_zero_are_counted_not_written(tmp_path):
    # the first events stamped below 0 (a clock stepped back further than it had run): fused,
    # their negative stamps reached the MCAP sink, which refused them at close (ROS time
    # cannot be negative); live they are invalid stamps, and the outputs hold every record
    def early(i, ev, t):
        return _restamp(ev, ev.t - 2000.0) if i < 5 else ev

    rig = Rig(tmp_path, speed=8.0, wrap=lambda s, rig: Mangled(s, rig, early))
    rig.drive_until(3.0)
    led = rig.close()
    assert led["dropped"]["invalid_stamp"] == 2 * 5, led  # both sources
    assert min(r.t for r in rig.records) > 0
    rig.check(led, "stamps below 0 (the first 5 of each source)", "0 (the next event)")


def test_30_s_of_silence_of_the_imu(tmp_path):
    rig = Rig(tmp_path, speed=10.0,
              wrap=lambda s, rig: Paused(s, rig, 1.0, 31.0) if s.name == "imu" else s)
    rig.drive_until(34.0)
    led = rig.close()
    rec = rig.recovery(31.0, 1)
    # the FIFO overflowed meanwhile: the driver counted the samples lost upstream
    assert rig.imu_source.lost > 0.9 * 30 * 100
    assert rig.imu_source.overflows >= 1
    assert rec < 0.5
    # the wheels went on alone (the reorder window released them)
    assert rig.pipe.stats.wheel_frames > 0.8 * 25 * 34
    rig.check(led, "30 s silence of the IMU", rec)
    print(f"(IMU samples lost upstream, counted by the driver: {rig.imu_source.lost})")


def test_a_source_thread_raising_is_reported_and_restarted(tmp_path):
    def when(t, raised):
        return t >= 2.0 and raised < 3  # three failures in a row, then it works again

    rig = Rig(tmp_path, speed=8.0,
              wrap=lambda s, rig: Raising(s, rig, when) if s.name == "wheels" else s)
    rig.drive_until(6.0)
    led = rig.close()
    h = rig.runner.health["wheels"]
    assert (h.faults, h.restarts, h.failed) == (3, 3, False)
    assert len(rig.faults) == 3
    name, text = rig.faults[0]
    assert name == "wheels" and "Traceback" in text and "injected fault 1" in text
    recs = np.array([r.t for r in rig.records]) - rig.t0
    assert np.sum(recs > 4.0) > 30  # records again after the restarts
    src = rig.runner._sources[1]
    # out from the first fault to the first frame accepted after the last restart (the
    # backoff: 0.05 + 0.1 + 0.2 wall s, 2.8 robot s at 8x)
    out = src.last_restart - src.first_raise + rig.recovery(src.last_restart, 2)
    assert 0.35 * 8 * 0.9 < out < 0.35 * 8 + 2.0
    rig.check(led, "a source thread raising (3 times, restarted)", out)


def test_a_source_that_keeps_raising_stops_the_run_with_a_clear_error(tmp_path):
    rig = Rig(tmp_path, speed=8.0, max_restarts=2, backoff=0.01,
              wrap=lambda s, rig: Raising(s, rig, lambda t, n: t >= 1.5)
              if s.name == "imu" else s)
    with pytest.raises(SourceFailedError, match="source 'imu' failed 3 times") as info:
        rig.drive_until(30.0)
    assert isinstance(info.value.__cause__, RuntimeError)
    assert rig.now() < 10.0  # it stopped; it did not run on without the IMU
    led = rig.close()  # the outputs still get everything that was fused
    assert rig.runner.health["imu"].failed
    rig.check(led, "a source that keeps raising (run stops)", "stops: SourceFailedError")


def test_the_serial_port_pulled_and_restored(tmp_path):
    rig = Rig(tmp_path, speed=4.0, link_path=str(tmp_path / "ttyCHASSIS"))
    state = {}

    def hook(t: float) -> None:
        if t >= 2.0 and "pulled" not in state:
            rig.robot.unplug()
            state["pulled"] = t
        if t >= 4.0 and "back" not in state:
            rig.robot.replug()
            state["back"] = t

    rig.drive_until(7.0, hook)
    led = rig.close()
    assert rig.link.reconnects == 1
    gaps = [g for g in rig.pipe.stats.gaps if g.missing > 20]
    assert len(gaps) == 1  # the pipeline noted the gap (frames missing upstream)
    rec = rig.recovery(state["back"], 2)
    assert rec < 1.0
    rig.check(led, "serial port pulled for 2 s and restored", rec)
    print(f"(wheel frames missing upstream in the gap: {gaps[0].missing})")


def test_i2c_error_bursts(tmp_path):
    rig = Rig(tmp_path, speed=4.0)
    bursts = NackBursts(rig.robot.bus, long_at=3.0)
    rig.drive_until(6.0, bursts)
    led = rig.close()
    assert bursts.short >= 6 and rig.imu.stats.retries >= 2 * bursts.short
    assert rig.imu_source.errors >= 1  # the long burst: reported, the loop goes on
    assert "INT_STATUS" in rig.imu_source.last_error or "FIFO" in rig.imu_source.last_error
    rec = rig.recovery(bursts.long_t + 0.1, 1)
    assert rec < 1.0
    rig.check(led, "I2C error bursts (2 NACKs every 0.5 s, 12 at once)", rec)
    print(f"(failed FIFO reads {rig.imu_source.errors}, samples lost upstream "
          f"{rig.imu_source.lost})")


class _DiskFullCsv(CsvSink):
    """An offline CSV sink whose disk fills up after ``ok`` records."""

    def __init__(self, path, ok: int) -> None:
        super().__init__(path)
        self.ok = ok

    def _write(self, record) -> None:
        if self.records_written >= self.ok:
            raise OSError(errno.ENOSPC, "No space left on device", str(self._target_path))
        super()._write(record)


def test_a_sink_whose_writes_fail_leaves_the_old_file_and_the_others_go_on(tmp_path):
    old = tmp_path / "old.csv"
    old.write_text("an older run's complete file\n")
    failing = _DiskFullCsv(old, ok=20)
    failing._target_path = old
    rig = Rig(tmp_path, speed=8.0, extra_sinks=[failing])
    rig.drive_until(5.0)
    led = rig.close(close_error=OSError)
    assert old.read_text() == "an older run's complete file\n"  # untouched
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".old.csv")]
    assert len(rig.sink_errors) == 1 and "No space left on device" in rig.sink_errors[0]
    sink, _exc, missed = rig.pipe.sink_failures[0]
    assert sink is failing and missed == rig.pipe.stats.records - 20
    assert failing not in rig.pipe.working_sinks and len(rig.pipe.working_sinks) == 2
    rig.check(led, "a sink whose writes fail (disk full after 20 records)",
              "0 (other sinks); the failed one keeps the old file")
