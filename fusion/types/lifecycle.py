"""The open -> write -> close/abort lifecycle shared by sinks and the fusion pipeline.

States: ``new`` -> ``open`` -> ``closed`` (finished normally) or ``aborted`` (stopped on an
error; file outputs discard their partial content). ``with obj:`` opens a new object, and on
leaving closes it (normal exit) or aborts it (an exception). An object opens once.
"""

from __future__ import annotations

__all__ = ["Lifecycle"]


class Lifecycle:
    """Base class: subclasses implement ``_open``, ``_close`` and ``_abort``, and optionally
    ``_finish`` (work that needs the object still open at ``close()``: a pipeline fuses what
    it holds). If ``_finish`` raises, the object is aborted and the error propagates."""

    _state = "new"

    @property
    def is_open(self) -> bool:
        """True between ``open()`` and ``close()``/``abort()``."""
        return self._state == "open"

    def _reuse_error(self) -> Exception:
        return RuntimeError(f"{self!r} was already opened")

    def open(self):
        """Acquire what the object needs (files, servers, sinks); once."""
        if self._state != "new":
            raise self._reuse_error()
        self._open()
        self._state = "open"
        return self

    def close(self) -> None:
        """Finish normally (outputs complete and in place afterwards); a no-op unless open."""
        if self._state != "open":
            return
        try:
            self._finish()
        except BaseException:
            self.abort()
            raise
        self._state = "closed"
        self._close()

    def abort(self) -> None:
        """Stop without finishing; a no-op unless open."""
        if self._state != "open":
            return
        self._state = "aborted"
        self._abort()

    def __enter__(self):
        if self._state == "new":
            self.open()
        elif self._state != "open":
            raise self._reuse_error()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _open(self) -> None:
        pass

    def _finish(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _abort(self) -> None:
        self._close()
