"""Text sinks: JSON lines (stdout or a file) and CSV.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import IO

from fusion.geometry.angles import wrap_angle_scalar
from fusion.io.atomic import AtomicFile
from fusion.io.fused_csv import FUSED_CSV_COLUMNS, format_fused_row
from fusion.sinks.base import Sink
from fusion.types.fused import FusedOdometry

__all__ = ["CsvSink", "JsonLinesSink"]


class JsonLinesSink(Sink):
    """One JSON object per record and line (:meth:`FusedOdometry.to_dict`).

    Args:
        target: a text stream (default ``sys.stdout``; flushed after each line, never closed
            by the sink), or a path written to a temporary file and renamed into place on
            close (so an existing file is replaced only by a complete one).
        flush: flush the stream after each line (live use).
    """

    def __init__(self, target: IO[str] | str | Path | None = None, *, flush: bool = True):
        super().__init__()
        self._target = target
        self._flush = flush
        self._stream: IO[str] | None = None
        self._out: AtomicFile | None = None

    def __repr__(self) -> str:
        return f"JsonLinesSink({self._target if self._target is not None else 'stdout'})"

    def _open(self) -> None:
        if self._target is None or self._target == "-":
            self._stream = sys.stdout
        elif isinstance(self._target, (str, Path)):
            self._out = AtomicFile(self._target, "w", encoding="utf-8")
            self._stream = self._out.file
        else:
            self._stream = self._target

    def _write(self, record: FusedOdometry) -> None:
        assert self._stream is not None
        self._stream.write(json.dumps(record.to_dict(), allow_nan=False,
                                      separators=(",", ":")) + "\n")
        if self._flush:
            self._stream.flush()

    def _close(self) -> None:
        if self._out is not None:
            self._out.commit()

    def _abort(self) -> None:
        if self._out is not None:
            self._out.discard()


class CsvSink(Sink):
    """Fused records as rows of the fused CSV (:mod:`fusion.io.fused_csv`), one per record.

    ``t`` s; ``x, y`` m and ``yaw`` rad (wrapped to (-pi, pi]) of ``child_frame_id`` in
    ``frame_id``; ``v`` m/s, ``w`` rad/s; the pose covariance terms of x, y, yaw and the twist
    variances of vx and wz from the record's 6x6 matrices; wheel speeds m/s. A record carries
    no EKF bias states: those cells are empty (``fusion replay`` fills them). Written to a
    temporary file and renamed into place on close, like :class:`JsonLinesSink`.
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        self.path = Path(path)
        self._out: AtomicFile | None = None
        self._fh: IO[str] | None = None

    def __repr__(self) -> str:
        return f"CsvSink({str(self.path)!r})"

    def _open(self) -> None:
        self._out = AtomicFile(self.path, "w", encoding="ascii", newline="\n")
        self._fh = self._out.file
        self._fh.write(",".join(FUSED_CSV_COLUMNS) + "\n")

    def _write(self, record: FusedOdometry) -> None:
        assert self._fh is not None
        P, Q = record.pose_covariance, record.twist_covariance
        yaw = record.yaw
        if not -math.pi < yaw <= math.pi:  # wrapping a wrapped angle again may move its last bit
            yaw = wrap_angle_scalar(yaw)
        self._fh.write(format_fused_row((
            record.t, record.x, record.y, yaw, record.v, record.w,
            None, None, None, P[0, 0], P[1, 1], P[5, 5], P[0, 1], P[0, 5], P[1, 5],
            Q[0, 0], Q[5, 5], record.wheel_left_speed, record.wheel_right_speed)))

    def _close(self) -> None:
        if self._out is not None:
            self._out.commit()

    def _abort(self) -> None:
        if self._out is not None:
            self._out.discard()
