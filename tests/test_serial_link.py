"""ChassisLink over real pseudo-terminal pairs (os.openpty); pyserial is not mocked."""

from __future__ import annotations

import itertools
import os
import re
import select
import time
import tty

import pytest

from drivers.chassis import WheelFrameParser, encode_wheel_frame
from drivers.serial_link import ChassisLink

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

TIMEOUT = 5.0  # generous I/O waits; tests assert behaviour, not speed


class Pty:
    """A pty pair whose slave is reached through a symlink that can be re-pointed (as udev
    symlinks do when a USB adapter comes back)."""

    def __init__(self, link_path: str):
        self.link_path = link_path
        self.master = -1
        self.slave = -1
        self.open()

    def open(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no line discipline before pyserial configures it
        tmp = self.link_path + ".tmp"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link_path)

    def vanish(self) -> None:
        os.unlink(self.link_path)
        os.close(self.master)
        os.close(self.slave)

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def read_until(self, n: int, timeout: float = TIMEOUT) -> bytes:
        out = b""
        end = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < end:
            r, _, _ = select.select([self.master], [], [], 0.05)
            if r:
                out += os.read(self.master, 4096)
        return out

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if os.path.lexists(self.link_path):
            os.unlink(self.link_path)


@pytest.fixture
def pty_pair(tmp_path):
    p = Pty(str(tmp_path / "ttyCHASSIS"))
    yield p
    p.close()


def wait_for(pred, timeout=TIMEOUT):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return False


def kinds(link):
    return [e.kind for e in link.events]


def test_frames_are_received_in_order_and_stamped(pty_pair):
    with ChassisLink(pty_pair.link_path, command_timeout=None) as link:
        values = [(i, -2 * i) for i in range(50)] + [(255, 65535)]
        t0 = time.monotonic()
        stream = b"\x00\x13" + b"".join(encode_wheel_frame(a, b) for a, b in values)
        pty_pair.write(stream[:7])
        time.sleep(0.02)
        pty_pair.write(stream[7:])
        got = []
        assert wait_for(lambda: got.extend(link.drain()) or len(got) >= len(values))
        t1 = time.monotonic()
        assert [(w.left, w.right) for w in got] == values
        # stamps: never before the read that preceded the bytes (at most one read timeout,
        # i.e. one period, before t0), never after their delivery
        assert all(t0 - link.period - 0.01 <= w.t <= t1 for w in got)
        assert all(a.t <= b.t for a, b in itertools.pairwise(got))
        assert link.parser.stats.bytes_skipped == 2
        assert link.last_frame_time == got[-1].t


def test_send_ticks_writes_the_frame(pty_pair):
    with ChassisLink(pty_pair.link_path, command_timeout=None) as link:
        assert link.send_ticks(120, -80)
        assert pty_pair.read_until(11) == encode_wheel_frame(120, -80)
        with pytest.raises(ValueError, match="24-bit"):
            link.send_ticks(1 << 24, 0)
    # closing sends a stop frame
    assert pty_pair.read_until(11) == encode_wheel_frame(0, 0)


def test_stale_command_is_stopped(pty_pair):
    link = ChassisLink(pty_pair.link_path, command_timeout=0.3).start()
    try:
        link.send_ticks(50, 50)
        assert pty_pair.read_until(11) == encode_wheel_frame(50, 50)
        # no new target: after 0.3 s the link sends a stop by itself
        assert pty_pair.read_until(11) == encode_wheel_frame(0, 0)
        assert wait_for(lambda: "command_stale" in kinds(link))  # reported after the write
        n = len(kinds(link))
        time.sleep(0.5)
        assert kinds(link)[n:].count("command_stale") == 0  # once, not repeatedly
    finally:
        link.close(stop=False)


def test_silence_and_alive_events(pty_pair):
    with ChassisLink(pty_pair.link_path, period=0.02, silence_periods=5,
                     command_timeout=None) as link:
        pty_pair.write(encode_wheel_frame(1, 1))
        assert link.get(TIMEOUT) is not None
        assert wait_for(lambda: "silent" in kinds(link))
        assert not link.alive
        pty_pair.write(encode_wheel_frame(2, 2))
        assert wait_for(lambda: "alive" in kinds(link))
        assert link.get(TIMEOUT).left == 2


def test_reconnect_when_the_port_vanishes_and_returns(pty_pair):
    with ChassisLink(pty_pair.link_path, reconnect_interval=0.05,
                     command_timeout=None) as link:
        pty_pair.write(encode_wheel_frame(1, 2))
        assert link.get(TIMEOUT).right == 2
        pty_pair.vanish()
        assert wait_for(lambda: "disconnected" in kinds(link))
        assert not link.connected
        assert link.send_ticks(10, 10) is False  # kept, sent on reconnect
        assert wait_for(lambda: "open_failed" in kinds(link))
        pty_pair.open()
        assert wait_for(lambda: link.connected)
        assert link.reconnects == 1
        # the fresh target is re-sent to the new port, and frames flow again
        assert pty_pair.read_until(11) == encode_wheel_frame(10, 10)
        pty_pair.write(encode_wheel_frame(3, 4))
        got = link.get(TIMEOUT)
        assert (got.left, got.right) == (3, 4)
        assert kinds(link).count("connected") == 2


def test_deferred_frame_is_flushed_on_a_quiet_line(pty_pair):
    # a frame whose checksum byte is 0xFF must wait for what follows (rule 3 of the parser);
    # on a quiet line the link decides it after two periods
    frame = encode_wheel_frame(255, -1)
    assert frame[10] == 0xFF
    with ChassisLink(pty_pair.link_path, period=0.02, command_timeout=None) as link:
        pty_pair.write(frame)
        got = link.get(TIMEOUT)
        assert got is not None and (got.left, got.right) == (255, -1)
        assert link.parser.stats.deferred == 1


def test_loop_url_and_parser_factory():
    # loop:// echoes what is written: the same frame format both ways
    with ChassisLink("loop://", command_timeout=None,
                     parser_factory=lambda: WheelFrameParser(max_ticks=1000)) as link:
        link.send_ticks(999, -999)
        link.send_ticks(1001, 0)  # implausible for this parser
        link.send_ticks(5, 6)
        got = [link.get(TIMEOUT) for _ in range(2)]
        assert [(g.left, g.right) for g in got] == [(999, -999), (5, 6)]
        assert wait_for(lambda: link.parser.stats.implausible == 1)


def test_open_failure_names_the_port(tmp_path):
    missing = str(tmp_path / "no_such_tty")
    link = ChassisLink(missing)
    with pytest.raises(OSError, match="no_such_tty"):
        link.start(wait=0.3)
    link.close(stop=False)
    assert not link.connected


def test_send_twist_uses_the_seed_command_path(pty_pair):
    from fusion.geometry.kinematics import DiffDriveParams

    geo = DiffDriveParams(wheel_distance=0.3, speed_ratio=3e-4, encode_sampling_time=0.04,
                          cmd_vel_linear_max=0.4)
    with ChassisLink(pty_pair.link_path, command_timeout=None) as link:
        # v clamped to 0.4; vl = 0.4 - 0.15 = 0.25 -> 0.25*0.04/3e-4 = 33.3 -> 33;
        # vr = 0.55 -> 73.3 -> 73 (truncation, as the seed's int assignment)
        link.send_twist(1.0, 1.0, geo)
        assert pty_pair.read_until(11) == encode_wheel_frame(33, 73)


def test_noisy_line_over_the_pty_is_exact(pty_pair):
    """Frames with noise bursts and frames cut short, written in odd pieces on a real pty."""
    import numpy as np

    rng = np.random.default_rng(11)
    values = [(int(a), int(b)) for a, b in rng.integers(-2000, 2000, (400, 2))]
    values[::37] = [(255, -1)] * len(values[::37])  # checksum 0xFF: deferred decisions
    stream = b""
    for i, (a, b) in enumerate(values):
        stream += encode_wheel_frame(a, b)
        if i % 9 == 4:
            stream += rng.integers(0, 256, int(rng.integers(1, 20)), dtype=np.uint8).tobytes()
        elif i % 9 == 7:
            stream += encode_wheel_frame(*values[i - 3])[: int(rng.integers(2, 11))]
    with ChassisLink(pty_pair.link_path, command_timeout=None, period=0.02) as link:
        i = 0
        while i < len(stream):
            k = int(rng.integers(1, 64))
            pty_pair.write(stream[i : i + k])
            i += k
            if rng.random() < 0.1:
                time.sleep(0.002)
        got = []
        assert wait_for(lambda: got.extend(link.drain()) or len(got) >= len(values))
        time.sleep(0.1)
        got.extend(link.drain())
    assert [(w.left, w.right) for w in got] == values


def test_callback_only_and_bounded_queue(pty_pair):
    seen = []
    with ChassisLink(pty_pair.link_path, command_timeout=None, queue_size=0,
                     on_frame=seen.append) as link:
        pty_pair.write(b"".join(encode_wheel_frame(i, i) for i in range(5)))
        assert wait_for(lambda: len(seen) == 5)
        assert link.get(0.05) is None and link.frames_dropped == 0
    with ChassisLink(pty_pair.link_path, command_timeout=None, queue_size=3) as link:
        pty_pair.write(b"".join(encode_wheel_frame(i, i) for i in range(5)))
        assert wait_for(lambda: link.frames_received == 5)
        assert [w.left for w in link.drain()] == [2, 3, 4]  # the oldest were dropped
        assert link.frames_dropped == 2


def _seed_frame(sig1: int, val1: int, sig2: int, val2: int) -> bytes:
    """A DATA-uart2 frame built from the seed's table (FF FF, sign byte, 24-bit big-endian
    value, twice; checksum: the low byte of the sum of bytes 0-9), not by the driver."""
    body = bytes([0xFF, 0xFF, sig1, *val1.to_bytes(3, "big"), sig2, *val2.to_bytes(3, "big")])
    return body + bytes([sum(body) & 0xFF])


@pytest.mark.parametrize(("sent", "said"), [
    # nothing at all: a port that opens with no board behind it
    (b"", "since it opened: nothing received"),
    # what a wrong baud rate delivers: bytes that never make a frame
    (bytes(range(7, 250, 3)) * 2, "bytes received, none a frame (no frame header"),
    # sign bytes of 2 (the seed's host takes any non-zero as +; the firmware sends 0/1)
    (_seed_frame(2, 10, 2, 10) * 6, "6 checksum-valid frames refused as implausible"),
    # checksum-valid frames far beyond any wheel: 5,000,000 ticks per period
    (_seed_frame(1, 5_000_000, 1, 5_000_000) * 6, "refused as implausible (more than"),
])
def test_a_port_that_gives_no_frame_is_said_and_what_it_gave(pty_pair, sent, said):
    # an independent probe: all four ran fusion run to the end with "0 frames" and no word
    # 0.5 s of silence: the bytes written at once are read well before it (a loaded machine)
    with ChassisLink(pty_pair.link_path, period=0.02, silence_periods=25,
                     command_timeout=None) as link:
        if sent:
            pty_pair.write(sent)
        assert wait_for(lambda: "silent" in kinds(link))
        (event,) = [e for e in link.events if e.kind == "silent"]
        assert said in event.message, event.message
        assert link.get(0.1) is None


@pytest.mark.parametrize(("every", "factor"), [(0.02, 0.5), (0.08, 2.0), (0.04, None)])
def test_frames_at_another_period_than_configured_are_said(pty_pair, every, factor):
    # an independent probe's board at 20 and 80 ms against 40 configured: the speeds were read
    # at half and at twice their value, and nothing said so
    with ChassisLink(pty_pair.link_path, period=0.04, silence_periods=50,
                     command_timeout=None) as link:
        start = time.monotonic()
        for k in itertools.count():  # on a schedule: late writes do not add up
            if time.monotonic() - start > 2.5:
                break
            pty_pair.write(_seed_frame(1, 10, 1, 10))
            time.sleep(max(0.0, start + (k + 1) * every - time.monotonic()))
        said = [e.message for e in link.events if e.kind == "period"]
    if factor is None:
        assert said == []
    else:
        (text,) = said
        # the reads' timing jitters: the period is measured, not assumed
        read = float(re.search(r"speeds read (\S+) times their true value", text).group(1))
        assert read == pytest.approx(factor, rel=0.2), text


def test_a_stall_at_the_start_or_a_late_board_is_no_false_alarm(pty_pair):
    # a 0.6 s stall in the first 2 s then its backlog in one burst (a review: the mean
    # interval had said "speeds read 1.4 times"), and a board that starts 1 s after the port
    # opens (many reset then): no period to report, and no silence but the stall's
    with ChassisLink(pty_pair.link_path, period=0.04, command_timeout=None) as link:
        time.sleep(1.0)
        start = time.monotonic()
        for k in itertools.count():
            now = time.monotonic() - start
            if now > 3.0:
                break
            if not 0.5 <= now < 1.1:  # the stall; its frames then come at once
                pty_pair.write(_seed_frame(1, 10, 1, 10) * (16 if 1.1 <= now < 1.14 else 1))
            time.sleep(max(0.0, start + (k + 1) * 0.04 - time.monotonic()))
        assert link.frames_received > 60
        assert not [e for e in link.events if e.kind == "period"]
        # the stall is a silence (0.6 s, 15 periods), the board's late start is not
        (silent,) = [e.message for e in link.events if e.kind == "silent"]
        assert "since it opened" not in silent, silent


def test_a_reconnected_port_that_stays_mute_is_said_again(pty_pair):
    with ChassisLink(pty_pair.link_path, period=0.02, silence_periods=5,
                     reconnect_interval=0.05, command_timeout=None) as link:
        pty_pair.write(_seed_frame(1, 1, 1, 1))
        assert link.get(TIMEOUT) is not None
        assert wait_for(lambda: "silent" in kinds(link))
        pty_pair.vanish()
        pty_pair.open()  # back, and mute
        assert wait_for(lambda: kinds(link).count("connected") == 2)
        assert wait_for(lambda: kinds(link).count("silent") == 2)
        assert link.events[-1].message.endswith("since it opened: nothing received (check the "
                                                "wiring and that the board is on)")


def test_refused_frames_that_lengthen_the_period_are_named_first(pty_pair):
    # every other frame refused (a sign byte of 2): the accepted ones come every 80 ms; an
    # independent probe's such stream was told to change encode_sampling_time
    with ChassisLink(pty_pair.link_path, period=0.04, silence_periods=50,
                     command_timeout=None) as link:
        start = time.monotonic()
        for k in itertools.count():
            if time.monotonic() - start > 2.5:
                break
            pty_pair.write(_seed_frame(1, 10, 1, 10) if k % 2 else _seed_frame(2, 10, 2, 10))
            time.sleep(max(0.0, start + (k + 1) * 0.04 - time.monotonic()))
        (text,) = [e.message for e in link.events if e.kind == "period"]
    assert "frames were broken, refused as implausible or skipped on this connection" in text
    assert "if the board does send every 0.04 s they are the cause" in text


def test_what_the_parser_refused_is_in_the_live_status(pty_pair):
    # refused frames mid-run had been said nowhere but the missing count
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT
    from fusion.pipeline import FusionPipeline
    from fusion.pipeline.live import LiveRunner
    from fusion.planar.robot import RobotConfig

    bad_sum = bytearray(_seed_frame(1, 5, 1, 5))
    bad_sum[-1] ^= 0x01
    with ChassisLink(pty_pair.link_path, command_timeout=None) as link:
        runner = LiveRunner(FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT)), link=link)
        pty_pair.write(_seed_frame(1, 1, 1, 1) + bytes(bad_sum) + _seed_frame(2, 9, 2, 9)
                       + _seed_frame(1, 2, 1, 2) + _seed_frame(1, 3, 1, 3))
        assert wait_for(lambda: link.frames_received == 3)
        counts = runner.status()["link_parser"]
    assert counts == {"checksum_failures": 1, "implausible": 1, "bytes_skipped": 22}
