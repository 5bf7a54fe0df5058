"""Errors of the readers and configuration parsers: each names the file and, where it applies,
the line and the key.
"""

from __future__ import annotations

__all__ = ["LogFormatError"]


class LogFormatError(ValueError):
    """A log file that does not match its format; the message names file and line."""
