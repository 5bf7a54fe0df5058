"""Text sinks: JSON lines (stdout or a file) and CSV.

Both write a file in one of two modes: offline (default), a hidden temporary file renamed over
the target on close (:class:`fusion.io.atomic.AtomicFile`: an existing file is replaced only by
a complete one), or ``live=True``, a recording that grows at the target and is synced every
``sync_interval`` seconds (:class:`fusion.io.incremental.IncrementalFile`: a crash loses at
most the last interval; an abort keeps what was written).
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
from fusion.io.incremental import DEFAULT_SYNC_INTERVAL, IncrementalFile
from fusion.sinks.base import Sink, SinkError
from fusion.types.fused import FusedOdometry

__all__ = ["CsvSink", "JsonLinesSink"]


class _FileOutput(Sink):
    """The file of a text sink, offline (atomic) or live (incremental); see the module."""

    def __init__(self, *, live: bool, sync_interval: float) -> None:
        super().__init__()
        self.live = live
        self.sync_interval = sync_interval
        self._out: AtomicFile | None = None

    def _open_file(self, path: str | Path, **kwargs) -> IO[str]:
        if self.live:
            self._out = IncrementalFile(path, "w", sync_interval=self.sync_interval, **kwargs)
        else:
            self._out = AtomicFile(path, "w", **kwargs)
        return self._out.file

    def _synced(self) -> None:
        """After each record: a live file is synced when its interval has passed."""
        if isinstance(self._out, IncrementalFile):
            self._out.sync_if_due()

    def _close(self) -> None:
        if self._out is not None:
            self._out.commit()

    def _abort(self) -> None:
        if self._out is None:
            return
        if self.live and self.records_written:  # a live recording keeps what it has
            self._out.commit()
        else:
            self._out.discard()


class JsonLinesSink(_FileOutput):
    """One JSON object per record and line (:meth:`FusedOdometry.to_dict`).

    Args:
        target: a text stream (default ``sys.stdout``; flushed after each line, never closed
            by the sink), or a path: offline, written to a temporary file and renamed into
            place on close (so an existing file is replaced only by a complete one); with
            ``live``, a recording that grows in place (see the module docstring).
        flush: flush the stream after each line (live use).
        live: for a path, record live (crash-safe) instead of replacing the file atomically.
        sync_interval: with ``live``, seconds between syncs to the disk.
    """

    def __init__(self, target: IO[str] | str | Path | None = None, *, flush: bool = True,
                 live: bool = False, sync_interval: float = DEFAULT_SYNC_INTERVAL):
        super().__init__(live=live, sync_interval=sync_interval)
        self._target = target
        self._flush = flush
        self._stream: IO[str] | None = None

    def __repr__(self) -> str:
        return f"JsonLinesSink({self._target if self._target is not None else 'stdout'})"

    def _open(self) -> None:
        if self._target is None or self._target == "-":
            self._stream = sys.stdout
        elif isinstance(self._target, (str, Path)):
            self._stream = self._open_file(self._target, encoding="utf-8")
        else:
            self._stream = self._target

    def _write(self, record: FusedOdometry) -> None:
        assert self._stream is not None
        self._stream.write(json.dumps(record.to_dict(), allow_nan=False,
                                      separators=(",", ":")) + "\n")
        if self._flush:
            self._stream.flush()
        self._synced()

    def write_status(self, status: dict) -> None:
        """One status line ``{"status": status}`` (a record has no ``status`` key, so a
        reader tells the two apart by it; NaN and infinite numbers become null): what
        ``fusion run`` and ``fusion replay`` write after the last record (counters and trust
        warnings, :mod:`fusion.jobs.status`), and ``fusion run --status S`` every S seconds
        (the ledger of events, sources' health, latency)."""
        if self._state != "open" or self._stream is None:
            raise SinkError(f"{self!r} is not open (state {self._state})")
        self._stream.write(json.dumps({"status": _json_safe(status)}, allow_nan=False,
                                      separators=(",", ":")) + "\n")
        if self._flush:
            self._stream.flush()
        self._synced()


def _json_safe(value):
    """``value`` with NaN and infinite floats replaced by None (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


class CsvSink(_FileOutput):
    """Fused records as rows of the fused CSV (:mod:`fusion.io.fused_csv`), one per record.

    ``t`` s; ``x, y`` m and ``yaw`` rad (wrapped to (-pi, pi]) of ``child_frame_id`` in
    ``frame_id``; ``v`` m/s, ``w`` rad/s; the pose covariance terms of x, y, yaw and the twist
    variances of vx and wz from the record's 6x6 matrices; wheel speeds m/s. A record carries
    no EKF bias states: those cells are empty (``fusion replay`` fills them). Written to a
    temporary file and renamed into place on close, like :class:`JsonLinesSink`, or with
    ``live=True`` recorded live (crash-safe, synced every ``sync_interval`` s; see the module
    docstring).
    """

    def __init__(self, path: str | Path, *, live: bool = False,
                 sync_interval: float = DEFAULT_SYNC_INTERVAL) -> None:
        super().__init__(live=live, sync_interval=sync_interval)
        self.path = Path(path)
        self._fh: IO[str] | None = None

    def __repr__(self) -> str:
        return f"CsvSink({str(self.path)!r})"

    def _open(self) -> None:
        self._fh = self._open_file(self.path, encoding="ascii", newline="\n")
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
            Q[0, 0], Q[5, 5], record.wheel_left_speed, record.wheel_right_speed,
            record.zupt, record.slip, record.encoder_fault)))
        self._synced()
