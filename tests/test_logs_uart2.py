"""DATA-uart2 capture reader of fusion.io: raw and timed captures, frames derived by hand
from seed 000's table (byte 0-1 FF FF, 2 enc1_sig, 3-5 enc1 BE, 6 enc2_sig, 7-9 enc2 BE,
10 = low byte of the sum of bytes 0..9; sig 0 = negative)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.chassis import encode_wheel_frame
from fusion.io.errors import LogFormatError
from fusion.io.uart2 import Uart2CaptureWriter, read_uart2_capture
from fusion.types.samples import WheelTicks

# left +10, right -20
A = bytes([0xFF, 0xFF,        # header
           0x01, 0x00, 0x00, 0x0A,  # enc1: positive, 10
           0x00, 0x00, 0x00, 0x14,  # enc2: negative, 20
           0x1D])             # 255+255+1+10+20 = 541 = 0x21D -> 0x1D
# left -300, right +70000
B = bytes([0xFF, 0xFF,
           0x00, 0x00, 0x01, 0x2C,  # enc1: negative, 0x00012C = 300
           0x01, 0x01, 0x11, 0x70,  # enc2: positive, 0x011170 = 70000
           0xAE])             # 255+255+1+44+1+1+17+112 = 686 = 0x2AE -> 0xAE
# left 0, right 0
C = bytes([0xFF, 0xFF, 0x01, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00,
           0x00])             # 255+255+1+1 = 512 = 0x200 -> 0x00
# left +65535, right +1: payload FF FF and checksum FF, so the parser must wait for the
# next frame (or a quiet line) before accepting it
D = bytes([0xFF, 0xFF, 0x01, 0x00, 0xFF, 0xFF, 0x01, 0x00, 0x00, 0x01,
           0xFF])             # 255+255+1+255+255+1+1 = 1023 = 0x3FF -> 0xFF

BYTE = 10 / 115200  # s per byte at 115200 8N1


def test_hand_frames_agree_with_the_codec() -> None:
    assert encode_wheel_frame(10, -20) == A
    assert encode_wheel_frame(-300, 70000) == B
    assert encode_wheel_frame(0, 0) == C
    assert encode_wheel_frame(65535, 1) == D


def test_raw_capture_with_noise(tmp_path: Path) -> None:
    cap = tmp_path / "uart2.bin"
    cap.write_bytes(b"\x00\x13\xff" + A + b"\xff\xff\x05" + B + C)
    got = read_uart2_capture(cap)
    assert got.t is None and got.reads == 0
    assert got.left.tolist() == [10, -300, 0]
    assert got.right.tolist() == [-20, 70000, 0]
    assert got.offset.tolist() == [3, 17, 28]
    assert got.stats["frames"] == 3 and got.stats["bytes_skipped"] == 6
    with pytest.raises(ValueError, match="raw capture has no times"):
        got.wheel_ticks()


def test_timed_capture_stamps_like_the_link(tmp_path: Path) -> None:
    cap = tmp_path / "uart2.csv"
    with Uart2CaptureWriter(cap) as w:
        w.write(1.0, A + B[:5])   # A ends 5 bytes before this read's end
        w.write(1.04, B[5:] + C)  # B ends 11 bytes before the end, C at the end
    got = read_uart2_capture(cap)
    assert got.reads == 2
    assert got.left.tolist() == [10, -300, 0]
    np.testing.assert_allclose(got.t, [1.0 - 5 * BYTE, 1.04 - 11 * BYTE, 1.04], atol=1e-12)
    assert got.wheel_ticks() == [WheelTicks(got.t[0], 10, -20),
                                 WheelTicks(got.t[1], -300, 70000), WheelTicks(1.04, 0, 0)]


def test_held_back_frame_is_decided_by_the_next_frame_or_a_quiet_line(tmp_path: Path) -> None:
    busy = tmp_path / "busy.csv"
    with Uart2CaptureWriter(busy) as w:
        w.write(2.0, D)
        w.write(2.01, C)  # 10 ms later: C confirms D
    got = read_uart2_capture(busy)
    assert got.left.tolist() == [65535, 0] and got.offset.tolist() == [0, 11]
    # D delivered with C's read: 11 bytes (C) after its end
    np.testing.assert_allclose(got.t, [2.01 - 11 * BYTE, 2.01], atol=1e-12)

    quiet = tmp_path / "quiet.csv"
    with Uart2CaptureWriter(quiet) as w:
        w.write(2.0, D)
        w.write(2.5, C)  # silence > 2 periods of 40 ms: the link would flush D at 2.0
    got = read_uart2_capture(quiet)
    assert got.left.tolist() == [65535, 0]
    np.testing.assert_allclose(got.t, [2.0, 2.5], atol=1e-12)

    alone = tmp_path / "alone.csv"
    with Uart2CaptureWriter(alone) as w:
        w.write(3.0, D)
    got = read_uart2_capture(alone)  # end of capture decides it
    assert got.left.tolist() == [65535] and got.t.tolist() == [3.0]


def test_stamps_never_go_before_the_previous_read(tmp_path: Path) -> None:
    cap = tmp_path / "slow.csv"
    with Uart2CaptureWriter(cap) as w:
        w.write(5.0, A)
        # the next read returns 0.5 ms later with 22 bytes (1.9 ms of line time): C's
        # transmission-time estimate would fall before 5.0, so it is clamped to it
        w.write(5.0005, B + C)
    got = read_uart2_capture(cap)
    np.testing.assert_allclose(got.t, [5.0, 5.0, 5.0005], atol=1e-12)


def test_timed_capture_errors_name_the_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text(f"t,data\n1.0,{A.hex()}\n1.1,zz{B.hex()}\n")
    with pytest.raises(LogFormatError, match=rf"{bad}:3: data is not hex"):
        read_uart2_capture(bad)
    back = tmp_path / "back.csv"
    back.write_text(f"t,data\n1.0,{A.hex()}\n1.1,{B.hex()}\n0.9,{C.hex()}\n")
    with pytest.raises(LogFormatError, match=rf"{back}:4: t = 0.9 .*back in time"):
        read_uart2_capture(back)
    odd = tmp_path / "odd.csv"
    odd.write_text("t,data\n1.0\n")
    with pytest.raises(LogFormatError, match=rf"{odd}:2: expected 't,data'"):
        read_uart2_capture(odd)


def test_writer_refuses_to_overwrite_and_checks_times(tmp_path: Path) -> None:
    cap = tmp_path / "c.csv"
    cap.write_text("precious")
    with pytest.raises(FileExistsError):
        Uart2CaptureWriter(cap)
    assert cap.read_text() == "precious"
    with Uart2CaptureWriter(cap, overwrite=True) as w:
        w.write(1.0, A)
        with pytest.raises(ValueError, match="not decrease"):
            w.write(0.5, B)
    assert cap.read_text() == f"t,data\n1.0,{A.hex()}\n"
