"""miiboo STM32 chassis protocols (seed 000 section 3), sans-I/O: bytes in, frames out.

DATA-uart2 (115200 8N1), the same 11-byte frame in both directions::

    byte  0     1     2         3..5                 6         7..9                 10
          0xFF  0xFF  enc1_sig  enc1_val (24-bit BE)  enc2_sig  enc2_val (24-bit BE)  checksum

enc1 is the left wheel, enc2 the right; ``sig`` is 0 for a negative value and non-zero
otherwise (senders write 1); checksum is the low byte of the sum of bytes 0..9. STM32 -> host
frames carry the encoder ticks counted in the last sampling period (40 ms on the miiboo
firmware); host -> STM32 frames carry target ticks per period. No I/O happens here: the serial
link (:mod:`drivers.serial_link`) and the simulator feed bytes in.

DEBUG-uart1 (115200): the host sends 15-byte frames ``FF FF kp_sig kp(3) ki_sig ki(3) kd_sig
kd(3) checksum`` (gains as ``round(|k| * 10000)``); twelve data bytes of 0x00 request the
firmware version and PID gains, twelve of 0xFF restore the default gains. The firmware answers
with printf text lines (``kp_set:%f`` ...), parsed by :class:`DebugReplyParser`.

Resynchronisation design of :class:`WheelFrameParser`
-----------------------------------------------------
The seed's driver slides an 11-byte window over the stream and accepts the first window that
starts ``FF FF`` and has a matching checksum. Payload and checksum bytes can be 0xFF too, so a
window can match that starts inside line noise and ends inside the real frame that follows
(for example a frame that lost its checksum byte, followed by the next frame: the next frame's
first 0xFF completes the truncated one with a 1/256 chance). Accepting it consumes the start of
the real frame, which is then lost; a window made of noise alone can invent a frame.

This parser decides with three rules:

1. **Validity**: header ``FF FF``, checksum, and plausibility: both magnitudes at most
   ``max_ticks`` (default 100000 ticks per period; derive it from the robot with
   :meth:`WheelFrameParser.for_chassis`) and sign bytes 0 or 1 (what every known sender
   writes; ``strict_sign=False`` accepts any non-zero byte as positive, like the seed).
   Plausibility is what stops noise from injecting jumps; rejected windows are counted.
2. **A window is accepted at once only if no other frame can start inside it.** A real frame
   that begins inside a candidate window must put its own ``FF FF`` header there: at window
   bytes ``(i, i+1)`` for some ``i`` in 1..9, or at byte 10 (the next byte being the second
   0xFF). A valid window whose bytes 1..10 contain no ``FF FF`` pair and whose checksum byte
   is not 0xFF cannot hide the start of another frame, so it is accepted immediately: zero
   added latency for the vast majority of frames.
3. **Otherwise the decision waits for the next frame** (consistency with the frame period):
   the candidate and every valid rival starting inside it are checked for a valid frame
   exactly 11 bytes later; the earliest confirmed one wins. If none is confirmed (noise on
   both sides), the rival is preferred over the window that contains its header, because a
   genuine frame would need that FF FF header inside its own payload while a false window
   only needs the bytes before the rival (noise, or a frame cut short, which itself begins
   FF FF) to pass the checksum; these decisions are counted in ``stats.ambiguous``.
   :meth:`WheelFrameParser.flush` decides pending candidates with the data at hand (end of a
   capture, or a quiet line).

With rule 2, a false frame needs a window made entirely of noise that passes the checksum and
the plausibility bound (for uniform noise about 2^-52 per noise byte with the defaults, 2^-38
without ``strict_sign``); a false window overlapping a real frame is resolved by rule 3. What
no parser can undo: a frame that lost its checksum byte followed by noise (the 8-bit
checksum passes by chance 1 time in 256), or noise shaped exactly like a frame.

Speed: the parser never loops over bytes in Python. Headers are found with ``bytes.find``,
and the common case (frames back to back) checks whole runs of 11-byte rows with numpy.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.types.constants import TICKS_MAX

__all__ = [
    "DEBUG_FRAME_LEN",
    "DEFAULT_MAX_TICKS",
    "FRAME_LEN",
    "GAIN_SCALE",
    "HEADER",
    "TICKS_MAX",
    "DebugCommand",
    "DebugCommandParser",
    "DebugEvent",
    "DebugReplyParser",
    "FrameStamper",
    "ParserStats",
    "WheelFrame",
    "WheelFrameParser",
    "checksum",
    "decode_debug_frame",
    "decode_wheel_frame",
    "encode_pid_request",
    "encode_pid_reset",
    "encode_pid_set",
    "encode_wheel_frame",
    "gain_from_wire",
    "gain_to_wire",
]

HEADER = b"\xff\xff"
FRAME_LEN = 11
DEBUG_FRAME_LEN = 15
#: default plausibility bound, ticks per period
DEFAULT_MAX_TICKS = 100_000
#: gains travel as round(|k| * GAIN_SCALE)
GAIN_SCALE = 10_000


def checksum(data: bytes | bytearray | memoryview) -> int:
    """Low 8 bits of the byte sum (the checksum of both miiboo protocols)."""
    return sum(data) & 0xFF


def _field(value: int, what: str) -> bytes:
    """Sign byte + 24-bit big-endian magnitude."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{what} must be an integer number of ticks, got {value!r}")
    value = int(value)
    if abs(value) > TICKS_MAX:
        raise ValueError(f"{what} = {value} is outside the 24-bit range +-{TICKS_MAX}")
    mag = abs(value)
    return bytes((0 if value < 0 else 1, mag >> 16, (mag >> 8) & 0xFF, mag & 0xFF))


def encode_wheel_frame(left: int, right: int) -> bytes:
    """Encode one DATA-uart2 frame (either direction): left, right ticks per period.

    Raises:
        ValueError: a value that is not an integer or lies outside +-(2^24 - 1).
    """
    body = HEADER + _field(left, "left") + _field(right, "right")
    return body + bytes((checksum(body),))


def _signed(sig: int, b0: int, b1: int, b2: int) -> int:
    mag = (b0 << 16) | (b1 << 8) | b2
    return mag if sig > 0 else -mag


def decode_wheel_frame(frame: bytes | bytearray) -> tuple[int, int]:
    """Decode one 11-byte DATA-uart2 frame into ``(left, right)`` ticks.

    Raises:
        ValueError: wrong length, missing header or checksum mismatch (the message says which).
    """
    if len(frame) != FRAME_LEN:
        raise ValueError(f"a DATA-uart2 frame has {FRAME_LEN} bytes, got {len(frame)}")
    if frame[0] != 0xFF or frame[1] != 0xFF:
        raise ValueError(f"frame header must be FF FF, got {frame[0]:02X} {frame[1]:02X}")
    cs = checksum(frame[:10])
    if cs != frame[10]:
        raise ValueError(
            f"checksum mismatch: bytes 0..9 sum to {cs:02X}, byte 10 is {frame[10]:02X}"
        )
    return _signed(*frame[2:6]), _signed(*frame[6:10])


@dataclass(frozen=True, slots=True)
class WheelFrame:
    """One decoded DATA-uart2 frame.

    Attributes:
        left: left wheel ticks per period (enc1), signed.
        right: right wheel ticks per period (enc2), signed.
        offset: byte offset of the frame's first byte in the stream fed to the parser.
    """

    left: int
    right: int
    offset: int = -1


@dataclass
class ParserStats:
    """Counters of a :class:`WheelFrameParser` (monotonic).

    Attributes:
        bytes_in: bytes fed.
        frames: frames accepted.
        bytes_skipped: bytes that are not part of any accepted frame.
        checksum_failures: skipped windows that started FF FF but failed the checksum.
        implausible: skipped windows with a good checksum but a value beyond the bound (or a
            sign byte other than 0/1 with ``strict_sign``).
        resyncs: frames that do not begin where the previous accepted frame ended (bytes were
            skipped before them).
        deferred: frames whose acceptance waited for the next frame (rule 3).
        ambiguous: deferred decisions that no following frame confirmed.
    """

    bytes_in: int = 0
    frames: int = 0
    bytes_skipped: int = 0
    checksum_failures: int = 0
    implausible: int = 0
    resyncs: int = 0
    deferred: int = 0
    ambiguous: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


_IDX11 = np.arange(FRAME_LEN)


class WheelFrameParser:
    """Stream parser for DATA-uart2 frames: ``feed(bytes) -> list[WheelFrame]``.

    Args:
        max_ticks: plausibility bound on |ticks| per period for each wheel (1..2^24-1).
        strict_sign: accept only sign bytes 0 and 1 (default): what the miiboo firmware and the
            seed's host driver send. ``False`` decodes like the seed (any non-zero sign byte is
            positive) at the price of more windows that can pass by chance (see below).

    See the module docstring for the resynchronisation rules. The parser keeps at most the
    bytes of an undecided frame and the following one.
    """

    def __init__(
        self,
        max_ticks: int = DEFAULT_MAX_TICKS,
        strict_sign: bool = True,
    ) -> None:
        if not 1 <= int(max_ticks) <= TICKS_MAX:
            raise ValueError(f"max_ticks must be in 1..{TICKS_MAX}, got {max_ticks!r}")
        self.max_ticks = int(max_ticks)
        self.strict_sign = bool(strict_sign)
        self.stats = ParserStats()
        self._buf = b""
        self._base = 0  # stream offset of self._buf[0]
        self._last_end = 0  # stream offset just after the last accepted frame

    @classmethod
    def for_chassis(
        cls, wheel_speed_max: float, speed_ratio: float, encode_sampling_time: float,
        margin: float = 1.5, **kwargs,
    ) -> WheelFrameParser:
        """A parser whose bound is ``margin`` times the ticks per period at ``wheel_speed_max``.

        Args:
            wheel_speed_max: fastest plausible wheel ground speed, m/s.
            speed_ratio: m per tick.
            encode_sampling_time: firmware period, s.
            margin: factor above the nominal maximum (slip, spikes), >= 1.
        """
        if not (wheel_speed_max > 0 and speed_ratio > 0 and encode_sampling_time > 0):
            raise ValueError("wheel_speed_max, speed_ratio and encode_sampling_time must be > 0")
        if margin < 1:
            raise ValueError(f"margin must be >= 1, got {margin!r}")
        bound = math.ceil(margin * wheel_speed_max * encode_sampling_time / speed_ratio)
        return cls(max_ticks=min(max(bound, 1), TICKS_MAX), **kwargs)

    # -- checks --
    def _good_starts(self, a: NDArray[np.uint8]) -> NDArray[np.int64]:
        """Sorted starts of all windows in ``a`` that are valid and clean (rules 1 and 2)."""
        n = a.size
        if n < FRAME_LEN:
            return np.zeros(0, dtype=np.int64)
        ff = a == 0xFF
        h = np.flatnonzero(ff[: n - FRAME_LEN + 1] & ff[1 : n - FRAME_LEN + 2])
        if h.size == 0:
            return h.astype(np.int64)
        rows = a[h[:, None] + _IDX11]
        ok = (rows[:, :10].sum(axis=1, dtype=np.uint32) & 0xFF) == rows[:, 10]
        r = rows.astype(np.int32)
        ok &= ((r[:, 3] << 16) | (r[:, 4] << 8) | r[:, 5]) <= self.max_ticks
        ok &= ((r[:, 7] << 16) | (r[:, 8] << 8) | r[:, 9]) <= self.max_ticks
        if self.strict_sign:
            ok &= (rows[:, 2] <= 1) & (rows[:, 6] <= 1)
        fr = ff[h[:, None] + _IDX11]
        ok &= ~((fr[:, 1:10] & fr[:, 2:11]).any(axis=1) | fr[:, 10])
        return h[ok].astype(np.int64)

    def _status(self, b: bytes, q: int) -> int:
        """Window at q (complete): 0 no header, 1 bad checksum, 2 implausible, 3 valid."""
        if b[q] != 0xFF or b[q + 1] != 0xFF:
            return 0
        w = b[q : q + FRAME_LEN]
        if sum(w[:10]) & 0xFF != w[10]:
            return 1
        mx = self.max_ticks
        if ((w[3] << 16) | (w[4] << 8) | w[5]) > mx or ((w[7] << 16) | (w[8] << 8) | w[9]) > mx:
            return 2
        if self.strict_sign and (w[2] > 1 or w[6] > 1):
            return 2
        return 3

    @staticmethod
    def _clean(b: bytes, q: int) -> bool:
        """Rule 2: no FF FF pair in window bytes 1..10 and checksum byte not 0xFF."""
        return b[q + 10] != 0xFF and HEADER not in b[q + 1 : q + FRAME_LEN]

    def _valid_at(self, b: bytes, q: int, n: int) -> bool | None:
        """Is there a valid frame at buffer index q? None if its bytes have not all arrived."""
        if q + FRAME_LEN > n:
            return None
        return self._status(b, q) == 3

    def _count_skipped(self, b: bytes, start: int, stop: int, n: int) -> None:
        """Account for bytes [start, stop) that belong to no accepted frame."""
        if stop <= start:
            return
        self.stats.bytes_skipped += stop - start
        q = b.find(HEADER, start)
        while 0 <= q < stop and q + FRAME_LEN <= n:
            st = self._status(b, q)
            if st == 1:
                self.stats.checksum_failures += 1
            elif st == 2:
                self.stats.implausible += 1
            q = b.find(HEADER, q + 1)

    def _search(self, b: bytes, pos: int, n: int, final: bool) -> tuple[str, int]:
        """Find the next frame at or after ``pos``: ('accept', i) or ('wait', i)."""
        q = b.find(HEADER, pos)
        while q >= 0 and q + FRAME_LEN <= n:
            if self._status(b, q) == 3:
                break
            q = b.find(HEADER, q + 1)
        else:
            # no valid window yet; nothing before the first incomplete header can start one
            return "wait", (q if q >= 0 else max(pos, n - 1))
        p = q
        if self._clean(b, p):
            return "accept", p
        # rule 3: the candidate may hide the start of a real frame; decide on the next frame
        nxt = self._valid_at(b, p + FRAME_LEN, n)
        if nxt is None and not final:
            return "wait", p
        if nxt:
            self.stats.deferred += 1
            return "accept", p
        rivals = [q for q in range(p + 1, p + FRAME_LEN) if self._valid_at(b, q, n)]
        for q in rivals:
            conf = self._valid_at(b, q + FRAME_LEN, n)
            if conf is None and not final:
                return "wait", p
            if conf:
                self.stats.deferred += 1
                return "accept", q
        if not rivals:
            self.stats.deferred += 1
            return "accept", p
        # nothing confirmed (noise after the frame too): a valid frame never hides the start of
        # another one, so follow the rivals to one with no valid rival inside it. For the
        # earlier window to be genuine its own payload would have to contain the rival's
        # FF FF header; for the later one to be genuine only the bytes before it (noise, or a
        # frame cut short, which begins FF FF) have to pass a checksum: far more likely.
        c = rivals[0]
        while True:
            status = [self._valid_at(b, q, n) for q in range(c + 1, c + FRAME_LEN)]
            if None in status and not final:
                return "wait", p  # decide only on complete data: replay is chunking-proof
            inner = [c + 1 + i for i, ok in enumerate(status) if ok]
            if not inner:
                self.stats.deferred += 1
                self.stats.ambiguous += 1
                return "accept", c
            c = inner[0]

    def _process(self, final: bool) -> tuple[NDArray[np.int64], bytes]:
        """Decide as much of the buffer as possible.

        Returns the accepted starts (indices into the old buffer) and that buffer.
        """
        b = self._buf
        n = len(b)
        good = self._good_starts(np.frombuffer(b, dtype=np.uint8))
        # runs of back-to-back good windows: good[i..e] with good[k+1] - good[k] == 11
        breaks = np.flatnonzero(np.diff(good) != FRAME_LEN)
        pos = 0
        runs: list[NDArray[np.int64]] = []
        while n - pos >= FRAME_LEN:
            i = int(np.searchsorted(good, pos))
            if i < good.size and good[i] == pos:
                # fast path: accept the whole run at once
                k = int(np.searchsorted(breaks, i))
                e = int(breaks[k]) if k < breaks.size else good.size - 1
                runs.append(good[i : e + 1])
                pos = int(good[e]) + FRAME_LEN
                continue
            # slow path: search, possibly deciding a deferred candidate
            kind, where = self._search(b, pos, n, final)
            self._count_skipped(b, pos, where, n)
            if kind == "wait":
                pos = where
                break
            runs.append(np.array([where], dtype=np.int64))
            pos = where + FRAME_LEN
        self._buf = b[pos:]
        if not runs:
            return np.zeros(0, dtype=np.int64), b
        return np.concatenate(runs), b

    @staticmethod
    def _decode(b: bytes, starts: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        if starts.size == 0:
            return starts.copy(), starts.copy()
        a = np.frombuffer(b, dtype=np.uint8)
        rows = a[starts[:, None] + _IDX11].astype(np.int64)
        left = (rows[:, 3] << 16) | (rows[:, 4] << 8) | rows[:, 5]
        right = (rows[:, 7] << 16) | (rows[:, 8] << 8) | rows[:, 9]
        left = np.where(rows[:, 2] > 0, left, -left)
        right = np.where(rows[:, 6] > 0, right, -right)
        return left, right

    def _run(self, data: bytes, final: bool):
        if data:
            self.stats.bytes_in += len(data)
            self._buf = self._buf + data
        base = self._base
        before = len(self._buf)
        starts, b = self._process(final)
        self._base = base + (before - len(self._buf))
        self.stats.frames += int(starts.size)
        left, right = self._decode(b, starts)
        offsets = starts + base
        if offsets.size:
            # a resync: a frame that does not begin where the previous one ended
            prev_end = np.concatenate(([self._last_end], offsets[:-1] + FRAME_LEN))
            self.stats.resyncs += int(np.count_nonzero(offsets != prev_end))
            self._last_end = int(offsets[-1]) + FRAME_LEN
        return offsets, left, right

    # -- public API ------------------------------------------------------------------------------
    def feed_arrays(
        self, data: bytes | bytearray | memoryview
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """Feed bytes; returns ``(offsets, left, right)`` int64 arrays of the accepted frames."""
        return self._run(bytes(data), final=False)

    def feed(self, data: bytes | bytearray | memoryview) -> list[WheelFrame]:
        """Feed bytes from the wire; returns the frames accepted so far, in stream order."""
        off, left, right = self._run(bytes(data), final=False)
        return [WheelFrame(int(l), int(r), int(o)) for o, l, r in zip(off, left, right)]

    def flush(self) -> list[WheelFrame]:
        """Decide deferred candidates with the bytes at hand (a quiet line, end of capture).

        Incomplete trailing bytes stay buffered: they may be the start of a frame.
        """
        off, left, right = self._run(b"", final=True)
        return [WheelFrame(int(l), int(r), int(o)) for o, l, r in zip(off, left, right)]

    def flush_arrays(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """:meth:`flush` returning ``(offsets, left, right)`` arrays like :meth:`feed_arrays`."""
        return self._run(b"", final=True)

    def finish(self) -> list[WheelFrame]:
        """End of stream: :meth:`flush`, then count the leftover bytes as skipped."""
        frames = self.flush()
        if self._buf:
            self._count_skipped(self._buf, 0, len(self._buf), len(self._buf))
            self._base += len(self._buf)
            self._buf = b""
        return frames

    @property
    def pending(self) -> int:
        """Bytes buffered but not yet decided."""
        return len(self._buf)


class FrameStamper:
    """Host stamps for DATA-uart2 frames read in chunks: the one stamping rule of the project
    (:class:`drivers.serial_link.ChassisLink` live, :func:`fusion.io.uart2.read_uart2_capture` on
    a recorded capture), sans-I/O.

    Give it every read of the port in order: :meth:`feed` with the read's return time on the
    host clock (s) and its bytes, *empty reads included* (a read that returned nothing still
    tells that no byte had arrived by then); then :meth:`poll` at the same time.

    Rule: a frame's stamp is the estimated arrival time of its last byte, the read's return
    time minus the transmission time (10 bits per byte, 8N1, at ``baudrate``) of the bytes that
    came after it up to the end of the read, but never earlier than the previous read's return
    (its bytes had not arrived then). A frame the parser holds back (its acceptance waits for
    the next frame) is decided by :meth:`poll` once the line has been quiet for more than
    ``2 * period`` s, and stamped as of the read that brought its bytes; :meth:`finish`
    decides it at the end of a capture.

    Each method returns ``(t, left, right, offsets)``: stamps s (float64), ticks per period and
    stream offsets (int64), in stream order.

    Args:
        parser: the frame parser (fed by this object only).
        baudrate: line speed, bit/s.
        period: firmware sampling period ``encode_sampling_time``, s.
    """

    def __init__(self, parser: WheelFrameParser, *, baudrate: int = 115200,
                 period: float = 0.04) -> None:
        if not baudrate > 0 or not period > 0:
            raise ValueError(f"baudrate and period must be > 0, got {baudrate!r}, {period!r}")
        self.parser = parser
        self.byte_time = 10.0 / baudrate
        self.period = float(period)
        self.bytes_fed = 0
        self.last_byte_time: float | None = None  # return time of the last non-empty read
        self._prev_read: float | None = None  # return time of the previous read (any)
        self._floor_of_last_data: float | None = None  # the floor of that non-empty read

    def _stamp(self, arrays, t_read: float, floor: float | None):
        off, left, right = arrays
        t = t_read - (self.bytes_fed - (off + FRAME_LEN)) * self.byte_time
        if floor is not None:
            t = np.maximum(t, floor)
        return t.astype(np.float64), left, right, off

    def feed(self, t_read: float, data: bytes | bytearray | memoryview):
        """One read: its return time (s) and its bytes (possibly none)."""
        floor = self._prev_read
        self._prev_read = t_read
        if not data:
            return _no_frames()
        self.last_byte_time = t_read
        self._floor_of_last_data = floor
        self.bytes_fed += len(data)
        return self._stamp(self.parser.feed_arrays(data), t_read, floor)

    def poll(self, now: float):
        """Decide held-back frames if the line has been quiet for more than 2 periods."""
        if (self.parser.pending and self.last_byte_time is not None
                and now - self.last_byte_time > 2 * self.period):
            return self._flush()
        return _no_frames()

    def finish(self):
        """End of the stream: decide what the parser still holds."""
        if self.last_byte_time is None:
            return _no_frames()
        return self._flush()

    def _flush(self):
        return self._stamp(self.parser.flush_arrays(), self.last_byte_time,
                           self._floor_of_last_data)


def _no_frames():
    e = np.zeros(0, dtype=np.int64)
    return np.zeros(0, dtype=np.float64), e, e, e


# ---------------------------------------------------------------------------------------------
# DEBUG-uart1
# ---------------------------------------------------------------------------------------------


def gain_to_wire(k: float, name: str = "gain") -> int:
    """``round(|k| * 10000)`` with checks: finite, at most 2^24-1, and no finer than 1e-4.

    Raises:
        ValueError: a gain that is not finite, too large for 24 bits, or has digits below
            1e-4 (it would be silently changed by the firmware's fixed-point).
    """
    if not isinstance(k, (int, float)) or isinstance(k, bool) or not math.isfinite(k):
        raise ValueError(f"{name} must be a finite number, got {k!r}")
    scaled = abs(k) * GAIN_SCALE
    wire = round(scaled)
    if wire > TICKS_MAX:
        raise ValueError(
            f"{name} = {k!r} is out of range: |{name}| * {GAIN_SCALE} must be <= {TICKS_MAX} "
            f"(|{name}| <= {TICKS_MAX / GAIN_SCALE})"
        )
    if abs(scaled - wire) > 1e-6 * max(1.0, scaled):
        raise ValueError(
            f"{name} = {k!r} is finer than the wire resolution 1/{GAIN_SCALE}: "
            f"it would become {math.copysign(wire / GAIN_SCALE, k)!r}"
        )
    return wire


def gain_from_wire(sig: int, b0: int, b1: int, b2: int) -> float:
    """Sign byte and 24-bit magnitude -> gain (value / 10000; sign byte 0 = negative)."""
    return _signed(sig, b0, b1, b2) / GAIN_SCALE


def _debug_frame(data: bytes) -> bytes:
    body = HEADER + data
    return body + bytes((checksum(body),))


def encode_pid_request() -> bytes:
    """The 15-byte "request firmware version and PID" frame (data bytes all 0x00)."""
    return _debug_frame(bytes(12))


def encode_pid_reset() -> bytes:
    """The 15-byte "restore default PID" frame (data bytes all 0xFF)."""
    return _debug_frame(b"\xff" * 12)


def encode_pid_set(kp: float, ki: float, kd: float) -> bytes:
    """The 15-byte "set PID" frame; each gain as sign byte (0 = negative) + round(|k|*1e4).

    Raises:
        ValueError: see :func:`gain_to_wire`.
    """
    data = b""
    for name, k in (("kp", kp), ("ki", ki), ("kd", kd)):
        wire = gain_to_wire(k, name)
        data += bytes((0 if k < 0 else 1, wire >> 16, (wire >> 8) & 0xFF, wire & 0xFF))
    return _debug_frame(data)


@dataclass(frozen=True, slots=True)
class DebugCommand:
    """A decoded DEBUG-uart1 command: kind is "request", "reset" or "set" (gains for "set")."""

    kind: str
    kp: float = 0.0
    ki: float = 0.0
    kd: float = 0.0


def decode_debug_frame(frame: bytes | bytearray) -> DebugCommand:
    """Decode one 15-byte DEBUG-uart1 command frame.

    Raises:
        ValueError: wrong length, header or checksum.
    """
    if len(frame) != DEBUG_FRAME_LEN:
        raise ValueError(f"a DEBUG-uart1 frame has {DEBUG_FRAME_LEN} bytes, got {len(frame)}")
    if frame[0] != 0xFF or frame[1] != 0xFF:
        raise ValueError(f"frame header must be FF FF, got {frame[0]:02X} {frame[1]:02X}")
    cs = checksum(frame[:14])
    if cs != frame[14]:
        raise ValueError(
            f"checksum mismatch: bytes 0..13 sum to {cs:02X}, byte 14 is {frame[14]:02X}"
        )
    data = bytes(frame[2:14])
    if data == bytes(12):
        return DebugCommand("request")
    if data == b"\xff" * 12:
        return DebugCommand("reset")
    return DebugCommand(
        "set", gain_from_wire(*data[0:4]), gain_from_wire(*data[4:8]), gain_from_wire(*data[8:12])
    )


class DebugCommandParser:
    """Firmware-side parser of DEBUG-uart1 commands (what the STM32 does; used by the simulator).

    Like the firmware it accepts the earliest 15-byte window with header and checksum. Commands
    are rare and typed by a human, so the resynchronisation subtleties of the wheel stream do
    not arise; bytes before an accepted frame are counted in ``skipped``.
    """

    def __init__(self) -> None:
        self._buf = b""
        self.skipped = 0
        self.frames = 0

    def feed(self, data: bytes) -> list[DebugCommand]:
        self._buf += bytes(data)
        out: list[DebugCommand] = []
        pos = 0
        buf = self._buf
        while True:
            p = buf.find(HEADER, pos)
            if p < 0 or p + DEBUG_FRAME_LEN > len(buf):
                keep = p if p >= 0 else max(pos, len(buf) - 1)
                self.skipped += keep - pos
                pos = keep
                break
            window = buf[p : p + DEBUG_FRAME_LEN]
            if checksum(window[:14]) == window[14]:
                self.skipped += p - pos
                out.append(decode_debug_frame(window))
                self.frames += 1
                pos = p + DEBUG_FRAME_LEN
            else:
                self.skipped += p + 1 - pos
                pos = p + 1
        self._buf = buf[pos:]
        return out


@dataclass(frozen=True, slots=True)
class DebugEvent:
    """One reply from the firmware's DEBUG-uart1 text.

    kind:
        ``"banner"`` (welcome line), ``"response"`` (``[stm32 response:]``), ``"version"``
        (values = (major, minor, patch)), ``"gains"`` (values = (kp, ki, kd), emitted when the
        kd_set line completes a kp/ki/kd group), ``"target"`` (values = (wheel 1|2, ticks) from
        ``enc1_target:`` / ``enc2_target:``), ``"text"`` (anything else).
    """

    kind: str
    values: tuple = ()
    line: str = ""


_RE_VERSION = re.compile(r"firmware\s+version\s*:\s*(\d+)\.(\d+)\.(\d+)", re.I)
_RE_GAIN = re.compile(r"^\s*(kp|ki|kd)_set\s*:\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*$")
_RE_TARGET = re.compile(r"^\s*enc([12])_target\s*:\s*([-+]?\d+)\s*$")


@dataclass
class DebugReplyParser:
    """Parser of the firmware's DEBUG-uart1 printf lines; ``feed(bytes) -> list[DebugEvent]``.

    Lines end in ``\\n`` (``\\r`` stripped). Bytes that are not UTF-8 are replaced, never
    raised on. A line longer than ``max_line`` bytes without a newline is emitted as text.
    The latest gains and version are kept in ``gains`` and ``version``.
    """

    max_line: int = 512
    gains: tuple[float, float, float] | None = None
    version: tuple[int, int, int] | None = None
    _buf: bytes = b""
    _partial: dict = field(default_factory=dict)

    def feed(self, data: bytes) -> list[DebugEvent]:
        self._buf += bytes(data)
        events: list[DebugEvent] = []
        while True:
            i = self._buf.find(b"\n")
            if i < 0:
                if len(self._buf) > self.max_line:
                    line, self._buf = self._buf[: self.max_line], self._buf[self.max_line :]
                    events.extend(self._line(line))
                    continue
                break
            line, self._buf = self._buf[:i], self._buf[i + 1 :]
            events.extend(self._line(line))
        return events

    def _line(self, raw: bytes) -> list[DebugEvent]:
        line = raw.decode("utf-8", errors="replace").strip("\r\n\x00 ")
        if not line:
            return []
        m = _RE_VERSION.search(line)
        if m:
            self.version = tuple(int(g) for g in m.groups())  # type: ignore[assignment]
            return [DebugEvent("version", self.version, line)]
        m = _RE_GAIN.match(line)
        if m:
            self._partial[m.group(1)] = float(m.group(2))
            if m.group(1) == "kd" and {"kp", "ki"} <= self._partial.keys():
                self.gains = (self._partial["kp"], self._partial["ki"], self._partial["kd"])
                self._partial = {}
                return [DebugEvent("gains", self.gains, line)]
            return []
        m = _RE_TARGET.match(line)
        if m:
            return [DebugEvent("target", (int(m.group(1)), int(m.group(2))), line)]
        if "stm32 response" in line:
            self._partial = {}
            return [DebugEvent("response", (), line)]
        if "welcome" in line.lower():
            return [DebugEvent("banner", (), line)]
        return [DebugEvent("text", (), line)]
