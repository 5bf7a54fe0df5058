"""DATA-uart2 captures of the chassis link (:func:`read_uart2_capture`): raw bytes as read from
the port, or a timed capture, a text file whose first line is ``t,data`` and whose rows are
``t`` (s, host clock, when the read returned) and ``data`` (the bytes of that read in hex),
written by :class:`Uart2CaptureWriter`. Frames are decoded by
:class:`drivers.chassis.WheelFrameParser`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.io.atomic import AtomicFile
from fusion.io.errors import LogFormatError

__all__ = ["Uart2Capture", "Uart2CaptureWriter", "read_uart2_capture"]


UART2_CAPTURE_HEADER = "t,data"


@dataclass
class Uart2Capture:
    """Wheel frames decoded from a DATA-uart2 capture.

    Attributes:
        left, right: (N,) int64 ticks counted in each frame's sampling period (left, right).
        offset: (N,) int64 byte offset of each frame's first byte in the capture's stream.
        t: (N,) s, each frame's stamp on the capture's host clock (timed captures; see
            :func:`read_uart2_capture`), or None for a raw capture.
        stats: the parser's counters (:class:`drivers.chassis.ParserStats` as a dict).
        reads: number of reads (rows) of a timed capture, 0 for a raw one.
        source: the file read.
    """

    left: NDArray[np.int64]
    right: NDArray[np.int64]
    offset: NDArray[np.int64]
    t: NDArray[np.float64] | None
    stats: dict[str, int]
    reads: int = 0
    source: str = ""

    def __len__(self) -> int:
        return len(self.left)

    def frame_times(self, period: float, t0: float = 0.0) -> NDArray[np.float64]:
        """Each frame's stamp, s: the recorded host time of a timed capture; for a raw capture
        (no clock) frame k (0-based, stream order) gets ``t0 + (k + 1) * period`` (``period``
        s, the firmware's ``encode_sampling_time``; dropped frames cannot be seen)."""
        if self.t is not None:
            return self.t
        return t0 + (np.arange(len(self)) + 1) * period

    def wheel_ticks(self) -> list[Any]:
        """The frames as :class:`fusion.types.samples.WheelTicks` (timed captures only)."""
        from fusion.types.samples import WheelTicks

        if self.t is None:
            raise ValueError(f"{self.source}: a raw capture has no times; record a timed "
                             "capture (Uart2CaptureWriter) to replay it on a clock")
        return [WheelTicks(float(t), int(lft), int(rgt))
                for t, lft, rgt in zip(self.t, self.left, self.right)]


class Uart2CaptureWriter:
    """Writes a timed DATA-uart2 capture: ``t,data`` rows (s, hex bytes), one per read.

    The capture is streamed into a hidden temporary file next to ``path``
    (:class:`fusion.io.atomic.AtomicFile`) and moved to ``path`` by :meth:`close`, also when a
    ``with`` block ends with an exception (KeyboardInterrupt included): the reads recorded so
    far are kept, as complete lines. Lines are flushed as they are written, so after a hard
    crash of the recorder (kill, power loss) the reads up to the last one are in the hidden
    ``.<name>.<random>.partial`` file, and ``path`` is still the old file if there was one.
    An existing file is a FileExistsError unless ``overwrite=True``.
    """

    def __init__(self, path: str | Path, *, overwrite: bool = False) -> None:
        self.path = Path(path)
        self._out = AtomicFile(self.path, "w", encoding="ascii", newline="\n",
                               overwrite=overwrite)
        self._fh = self._out.file
        self._fh.write(UART2_CAPTURE_HEADER + "\n")
        self._last = -math.inf

    def write(self, t: float, data: bytes | bytearray | memoryview) -> None:
        """One read: its return time ``t`` (s) and its bytes."""
        t = float(t)
        if not math.isfinite(t) or t < self._last:
            raise ValueError(f"{self.path}: read times must be finite and not decrease, got "
                             f"{t!r} after {self._last!r}")
        self._last = t
        self._fh.write(f"{t!r},{bytes(data).hex()}\n")
        self._fh.flush()

    def close(self) -> None:
        """Finish the capture: it is at ``path`` after this."""
        self._out.commit()

    def __enter__(self) -> Uart2CaptureWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_timed_capture(path: Path) -> tuple[list[float], list[bytes]]:
    times: list[float] = []
    chunks: list[bytes] = []
    with path.open(encoding="ascii", errors="replace", newline=None) as fh:
        fh.readline()
        for lineno, line in enumerate(fh, start=2):
            line = line.strip()
            if not line:
                continue
            parts = line.split(",")
            if len(parts) != 2:
                raise LogFormatError(f"{path}:{lineno}: expected 't,data', got {line[:60]!r}")
            try:
                t = float(parts[0])
            except ValueError:
                raise LogFormatError(f"{path}:{lineno}: t is not a number: {parts[0]!r}") from None
            try:
                data = bytes.fromhex(parts[1])
            except ValueError:
                raise LogFormatError(
                    f"{path}:{lineno}: data is not hex bytes: {parts[1][:60]!r}") from None
            if not math.isfinite(t) or (times and t < times[-1]):
                raise LogFormatError(f"{path}:{lineno}: t = {parts[0]} is not finite or goes "
                                     f"back in time (previous {times[-1] if times else None})")
            times.append(t)
            chunks.append(data)
    return times, chunks


def read_uart2_capture(
    path: str | Path,
    *,
    max_ticks: int | None = None,
    strict_sign: bool = True,
    baudrate: int = 115200,
    period: float = 0.04,
) -> Uart2Capture:
    """Decode a DATA-uart2 capture (raw bytes, or a timed ``t,data`` capture).

    A timed capture is replayed read by read through :class:`drivers.chassis.FrameStamper`,
    the stamping rule of :class:`drivers.serial_link.ChassisLink`: the read's time minus the
    transmission time (10 bits per byte at ``baudrate``) of the bytes that followed the frame
    up to the end of the read, never earlier than the previous read; a frame the parser holds
    back is decided when the line has been quiet for more than ``2 * period`` s (as the link's
    housekeeping does) or at the end. A capture recorded from the link's ``on_read`` hook
    holds every read, empty ones included, and replays to exactly the frames and stamps the
    link delivered; in a capture without empty reads, a gap of more than 2 periods between
    two reads is taken as the quiet line the link would have seen.

    Args:
        path: the capture file.
        max_ticks: the parser's plausibility bound, ticks per period (default: the parser's).
        strict_sign: accept only sign bytes 0/1 (see :class:`drivers.chassis.WheelFrameParser`).
        baudrate: line speed, for the transmission-time correction, bit/s.
        period: firmware sampling period (seed 000's ``encode_sampling_time``), s.
    """
    from drivers.chassis import DEFAULT_MAX_TICKS, FrameStamper, WheelFrameParser

    path = Path(path)
    if baudrate <= 0 or not period > 0:
        raise ValueError(f"baudrate and period must be > 0, got {baudrate}, {period}")
    parser = WheelFrameParser(max_ticks=DEFAULT_MAX_TICKS if max_ticks is None else max_ticks,
                              strict_sign=strict_sign)
    with path.open("rb") as fh:
        head = fh.read(len(UART2_CAPTURE_HEADER) + 2)
    timed = head.rstrip(b"\r\n") == UART2_CAPTURE_HEADER.encode() or head.startswith(
        (UART2_CAPTURE_HEADER + "\n").encode())
    if not timed:
        data = path.read_bytes()
        off, left, right = parser.feed_arrays(data)
        tail = parser.finish()
        off = np.concatenate([off, [f.offset for f in tail]]).astype(np.int64)
        left = np.concatenate([left, [f.left for f in tail]]).astype(np.int64)
        right = np.concatenate([right, [f.right for f in tail]]).astype(np.int64)
        return Uart2Capture(left=left, right=right, offset=off, t=None,
                            stats=parser.stats.as_dict(), source=str(path))

    times, chunks = _read_timed_capture(path)
    # the link's own stamping rule, read by read (feed, then the quiet-line check)
    stamper = FrameStamper(parser, baudrate=baudrate, period=period)
    parts = []
    prev_empty = True
    for t_read, data in zip(times, chunks):
        if data and not prev_empty:
            # two data reads more than 2 periods apart with no timed-out read between: a
            # capture that does not record empty reads (the link's reads time out after a
            # period, so it would have checked the quiet line in the gap)
            parts.append(stamper.poll(t_read))
        parts.append(stamper.feed(t_read, data))
        parts.append(stamper.poll(t_read))
        prev_empty = not data
    parts.append(stamper.finish())
    parser.finish()
    out_t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
    left, right, off = (np.concatenate([p[i] for p in parts]).astype(np.int64)
                        if parts else np.zeros(0, dtype=np.int64) for i in (1, 2, 3))
    return Uart2Capture(left=left, right=right, offset=off, t=np.asarray(out_t, dtype=float),
                        stats=parser.stats.as_dict(), reads=len(times), source=str(path))
