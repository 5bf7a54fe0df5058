"""The ``fusion`` command.

Each sub-command lives in its own module of this package and exposes
``register(subparsers) -> None``, which adds its parser and sets ``func`` (a callable taking the
parsed arguments and returning an exit code). Modules are discovered at run time, so adding a
command means adding a module; nothing here changes.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from pathlib import Path

__all__ = ["CommandError", "build_parser", "is_user_error", "main"]


class CommandError(Exception):
    """An error the user can act on; printed without a traceback, exit status 2."""


def is_user_error(exc: BaseException) -> bool:
    """True for errors the user can act on, whose message names what to fix (file:line,
    port, register, key or value):

    - :class:`CommandError`, the readers' and the configuration's errors
      (``fusion.io.errors``);
    - operating-system errors (a file, a disk, a serial port, an I2C register: the drivers'
      errors are OSErrors);
    - a ``ValueError`` raised by this project's own code (``fusion``, ``drivers``), which
      raises it only for a value it was given (issue 12: validation names the value);
    - a live source that kept failing (its tracebacks were reported as it failed), several
      sinks that failed with such errors.

    Anything else is a bug and keeps its traceback: a ``ValueError`` from inside numpy or
    another library (the project called it wrongly), a TypeError, a KeyError, ..."""
    from fusion.io.errors import ConfigError, LogFormatError

    if isinstance(exc, (CommandError, ConfigError, LogFormatError, OSError)):
        return True
    if isinstance(exc, ValueError):
        return _raised_here(exc)
    if type(exc).__name__ == "SourceFailedError":
        return True
    errors = getattr(exc, "errors", None)
    return type(exc).__name__ == "SinkFailures" and all(is_user_error(e) for _, e in errors)


_FUSION = str(Path(__file__).resolve().parents[1])  # this package's fusion/ and drivers/
_DRIVERS = str(Path(__file__).resolve().parents[2] / "drivers")


def _raised_here(exc: BaseException) -> bool:
    """True when the innermost frame of ``exc``'s traceback is in ``fusion`` or ``drivers``."""
    tb = exc.__traceback__
    if tb is None:
        return True
    while tb.tb_next is not None:
        tb = tb.tb_next
    where = str(Path(tb.tb_frame.f_code.co_filename).resolve())
    return where.startswith((_FUSION + "/", _DRIVERS + "/"))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fusion",
        description="IMU attitude, wheel odometry and EKF fusion for differential-drive robots.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="print the traceback of every error (not only of internal ones)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def _version() -> str:
    """The installed distribution's version (``diffbot-fusion``), or "unknown" when it runs
    from a source tree that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diffbot-fusion")
    except PackageNotFoundError:
        return "unknown (not installed)"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        if not _stdout_closed():
            raise
        return 1  # the reader of our output went away (`fusion ... | head`): no message
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        if is_user_error(exc) and not args.debug:
            print(f"fusion {args.command}: error: {exc}", file=sys.stderr)
            return 2
        import traceback

        traceback.print_exc(file=sys.stderr)
        if is_user_error(exc):
            return 2
        print(f"fusion {args.command}: internal error: {type(exc).__name__}: {exc} (a bug: "
              "please report it with the traceback above)", file=sys.stderr)
        return 1


def _stdout_closed() -> bool:
    """True when standard output's reader has gone (a pipe whose reader closed: poll says
    POLLERR); standard output then points at /dev/null so that the interpreter's own final
    flush is quiet too."""
    import os
    import select

    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        broken = any(ev & select.POLLERR for _fd, ev in poller.poll(0))
    except (AttributeError, ValueError, OSError):
        return False
    if broken:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
    return broken


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
