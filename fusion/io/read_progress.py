"""Progress of reading a large text file: a line iterator that counts the bytes it hands out.

Readers that parse line by line (``np.loadtxt`` over an iterable, ``csv.reader``) take a
:class:`LineProgress` instead of the open file; it calls ``callback(done, total)`` (bytes) at
most every :data:`REPORT_EVERY` bytes and once at the end.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import IO

__all__ = ["REPORT_EVERY", "LineProgress", "ReadProgress"]

#: ``callback(done, total)``: bytes of the file read so far and in all.
ReadProgress = Callable[[int, int], None]

#: Bytes between two reports.
REPORT_EVERY = 1 << 20


class LineProgress:
    """Iterate the lines of ``fh`` (a text file opened by the caller, at its start), telling
    ``callback`` how many of ``total`` bytes were read (characters: exact for ASCII CSV)."""

    def __init__(self, fh: IO[str], total: int, callback: ReadProgress) -> None:
        self._fh = fh
        self.total = int(total)
        self.done = 0
        self._next_report = REPORT_EVERY
        self._callback = callback

    def __iter__(self) -> Iterator[str]:
        return self

    def __next__(self) -> str:
        line = self._fh.readline()
        if not line:
            self._callback(self.total, self.total)
            raise StopIteration
        self.done += len(line)
        if self.done >= self._next_report:
            self._next_report = self.done + REPORT_EVERY
            self._callback(self.done, self.total)
        return line
