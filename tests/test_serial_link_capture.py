"""A live ChassisLink session recorded through ``on_read`` replays to the same frames and stamps.

A real pseudo-terminal pair (os.openpty): a writer thread plays DATA-uart2 bytes into the
master with line noise, frames split across writes, a frame the parser must hold back (payload
and checksum FF, decided by the next frame or a quiet line) followed by silence, and gaps of
several periods; the link reads the slave with pyserial. Its ``on_read`` hook feeds a
:class:`fusion.io.uart2.Uart2CaptureWriter`. :func:`fusion.io.uart2.read_uart2_capture` of that file
must give exactly the frames and stamps ``on_frame`` received live (the two share
:class:`drivers.chassis.FrameStamper`); the frames are also checked against what was written.
"""

from __future__ import annotations

import os
import threading
import time
import tty

import numpy as np
import pytest

from drivers.chassis import FRAME_LEN, FrameStamper, WheelFrameParser, encode_wheel_frame
from drivers.serial_link import ChassisLink
from fusion.io.uart2 import Uart2CaptureWriter, read_uart2_capture

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

PERIOD = 0.02
# left +65535, right +1: payload FF FF and checksum FF (seed 000's table: header FF FF,
# sign 1, 00 FF FF, sign 1, 00 00 01, sum 1023 -> FF): the parser waits before accepting it
HELD = encode_wheel_frame(65535, 1)


def _script() -> list[tuple[float, bytes]]:
    """(pause before, bytes) pairs and the frames they carry."""
    steps: list[tuple[float, bytes]] = []
    for k in range(30):
        f = encode_wheel_frame(100 + k, -50 - k)
        if k % 7 == 3:  # split across two writes
            steps += [(PERIOD, f[:4]), (0.003, f[4:])]
        elif k % 5 == 1:  # line noise before it
            steps.append((PERIOD, b"\x00\x13\xff\x07" + f))
        else:
            steps.append((PERIOD, f))
        if k == 12:  # a held-back frame, then silence: the link flushes it on a quiet line
            steps += [(PERIOD, HELD), (6 * PERIOD, b"")]
        if k == 20:  # a held-back frame confirmed by the next one in the same write
            steps.append((PERIOD, HELD + encode_wheel_frame(1, 2)))
    steps.append((PERIOD, HELD))  # held at the end: decided by the quiet line
    return steps


def test_a_capture_recorded_live_replays_to_the_frames_and_stamps_delivered(tmp_path):
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    cap = tmp_path / "live.uart2"
    live: list = []
    done = threading.Event()

    def play():
        for pause, data in _script():
            time.sleep(pause)
            if data:
                os.write(master, data)
        time.sleep(8 * PERIOD)  # a quiet line at the end
        done.set()

    writer = Uart2CaptureWriter(cap)
    try:
        link = ChassisLink(path, period=PERIOD, command_timeout=None, on_frame=live.append,
                           on_read=writer.write, queue_size=0)
        link.start(wait=10.0)
        try:
            th = threading.Thread(target=play, daemon=True)
            th.start()
            assert done.wait(60.0)
            th.join(5.0)
            end = time.monotonic() + 30.0  # a busy host: let the link see the quiet line
            while len(live) < 34 and time.monotonic() < end:
                time.sleep(0.01)
        finally:
            link.close(stop=False)
    finally:
        writer.close()
        os.close(master)
        os.close(slave)

    sent = [(100 + k, -50 - k) for k in range(30)]
    sent.insert(13, (65535, 1))
    sent.insert(22, (65535, 1))
    sent.insert(23, (1, 2))
    sent.append((65535, 1))
    assert [(f.left, f.right) for f in live] == sent  # every frame, none invented

    got = read_uart2_capture(cap, period=PERIOD)
    assert list(zip(got.left.tolist(), got.right.tolist())) == sent
    assert got.t.tolist() == [f.t for f in live]  # the very stamps, bit for bit
    assert got.reads > len(_script()) // 2
    text = cap.read_text().splitlines()
    assert any(line.endswith(",") for line in text[1:])  # timed-out reads are recorded


def test_frame_stamper_rule_by_hand():
    # 115200 baud 8N1: 10/115200 s per byte. Read 1 at 1.0 s: frame A and 5 bytes of B;
    # read 2 (empty) at 1.02 s; read 3 at 1.03 s: the rest of B.
    byte = 10 / 115200
    a, b = encode_wheel_frame(10, -20), encode_wheel_frame(-300, 70000)
    st = FrameStamper(WheelFrameParser(), baudrate=115200, period=0.04)
    t, left, right, off = st.feed(1.0, a + b[:5])
    assert (left.tolist(), right.tolist(), off.tolist()) == ([10], [-20], [0])
    np.testing.assert_allclose(t, [1.0 - 5 * byte], rtol=0, atol=1e-12)
    assert st.feed(1.02, b"")[0].size == 0
    t, left, _, off = st.feed(1.03, b[5:])
    # B ends at the end of read 3; its stamp is not before the empty read at 1.02 s
    assert left.tolist() == [-300] and off.tolist() == [FRAME_LEN]
    np.testing.assert_allclose(t, [1.03], rtol=0, atol=1e-12)
    # a read right after an empty one: A followed by 20 noise bytes would be stamped
    # 1.0401 - 20 bytes = 1.03836 s, before the empty read at 1.04 s: floored there
    assert st.feed(1.04, b"")[0].size == 0
    t, left, _, _ = st.feed(1.0401, a + b"\x00" * 20)
    assert left.tolist() == [10] and t.tolist() == [1.04]
    # a held-back frame is decided only on a quiet line (> 2 periods) or at the end
    st2 = FrameStamper(WheelFrameParser(), baudrate=115200, period=0.04)
    assert st2.feed(5.0, HELD)[0].size == 0
    assert st2.poll(5.07)[0].size == 0  # less than 2 periods: not yet
    t, left, _, _ = st2.poll(5.09)
    assert left.tolist() == [65535] and t.tolist() == [5.0]
