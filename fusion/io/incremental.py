"""Crash-safe live recording: a file that grows in place and is synced every few seconds.

:class:`IncrementalFile` is the live counterpart of :class:`fusion.io.atomic.AtomicFile`
(whole-file atomic replacement, for offline outputs). It is written in the hidden temporary
sibling ``.<name>.<random>.partial`` until its first :meth:`~IncrementalFile.sync`, which
flushes and fsyncs it and renames it over ``path``; from then on the same open file keeps
growing at ``path`` and every sync (at most every ``sync_interval`` seconds, when the writer
calls :meth:`~IncrementalFile.sync_if_due`) flushes and fsyncs it.

Guarantee: after a SIGKILL or a power loss, ``path`` holds everything written up to the last
sync (the last ``sync_interval`` seconds may be lost), or, if the crash came before the first
sync, the previous file at ``path`` is untouched (the hidden ``.partial`` file is left
behind). A writer that stops without a clean close (:meth:`~IncrementalFile.discard` after
data was synced) keeps that data: a live recording is never thrown away.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

from fusion.io.atomic import AtomicFile, _fsync_folder, check_target

__all__ = ["DEFAULT_SYNC_INTERVAL", "IncrementalFile"]

#: Seconds between syncs of a live recording: what a crash can lose at most (plus what the
#: writer itself buffers, e.g. nothing for the text sinks, one open MCAP chunk that
#: :class:`fusion.sinks.bag.McapSink` closes at each sync).
DEFAULT_SYNC_INTERVAL = 1.0


class IncrementalFile(AtomicFile):
    """A live output file: visible at ``path`` from its first sync, synced every interval.

    Args:
        path, mode, encoding, newline, overwrite: as for :class:`AtomicFile` (an existing
            file at ``path`` is replaced at the first sync, not before).
        sync_interval: seconds between the syncs :meth:`sync_if_due` makes (> 0).
    """

    def __init__(self, path: str | Path, mode: str = "w", *, encoding: str | None = None,
                 newline: str | None = None, overwrite: bool = True,
                 sync_interval: float = DEFAULT_SYNC_INTERVAL) -> None:
        if not sync_interval > 0:
            raise ValueError(f"sync_interval must be > 0 s, got {sync_interval}")
        super().__init__(path, mode, encoding=encoding, newline=newline, overwrite=overwrite)
        self.sync_interval = sync_interval
        self.published = False  # renamed to path yet
        self._last_sync = time.monotonic()

    def __repr__(self) -> str:
        return f"IncrementalFile({str(self.path)!r})"

    def sync_interval_passed(self) -> bool:
        """True when ``sync_interval`` has passed since the last sync (or the opening)."""
        return time.monotonic() - self._last_sync >= self.sync_interval

    def sync_if_due(self) -> bool:
        """:meth:`sync` if ``sync_interval`` has passed since the last one; True if it did."""
        if not self.sync_interval_passed():
            return False
        self.sync()
        return True

    def sync(self) -> None:
        """Flush and fsync what was written; the first time, rename the file to ``path``."""
        if self._done:
            return
        self.file.flush()
        os.fsync(self.file.fileno())
        if not self.published:
            if not self.overwrite:
                check_target(self.path, overwrite=False)
            os.replace(self._tmp, self.path)
            self.published = True
            _fsync_folder(self.path.parent)
        self._last_sync = time.monotonic()

    def commit(self) -> None:
        """Sync and close: the file at ``path`` is complete."""
        if self._done:
            return
        try:
            self.sync()
        except BaseException:
            self.discard()
            raise
        self._done = True
        self.file.close()

    def discard(self) -> None:
        """Stop writing. Before the first sync the hidden file is removed (``path`` is as it
        was); after it, the file at ``path`` is flushed and kept (a recording is never lost)."""
        if self._done:
            return
        if not self.published:
            super().discard()
            return
        self._done = True
        try:
            with contextlib.suppress(OSError):  # keep what reached the disk
                self.file.flush()
                os.fsync(self.file.fileno())
        finally:
            self.file.close()
