"""Errors of the readers and configuration parsers: each names the file and, where it applies,
the line and the key.
"""

from __future__ import annotations

__all__ = ["ConfigError", "LogFormatError"]


class LogFormatError(ValueError):
    """A log file that does not match its format; the message names file and line."""


class ConfigError(ValueError):
    """A configuration file that cannot be used; the message names file, line and key.

    Not a :class:`LogFormatError`: a bad ``fusion run`` configuration is not a malformed log.
    """
