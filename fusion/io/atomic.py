"""Atomic file output: every file the library writes goes through here.

:func:`atomic_write` (or :class:`AtomicFile` for a file kept open across calls, as the sinks do)
writes a hidden temporary sibling ``.<name>.<random>.partial`` in the target's own folder,
flushes and fsyncs it, and renames it over the target (:func:`os.replace`) only when the
writing finished; any exception in between, KeyboardInterrupt included, removes the temporary
file and leaves the target as it was.

Guarantee (for files; folders: :class:`AtomicDirectory`): at every moment, and after a crash
or power loss at any point, ``path`` is either the old file (or absent, if there was none) or
the complete new one, never a mix or a truncated file. A hard kill (SIGKILL, power loss)
during the writing can leave the hidden ``.partial`` file behind; nothing else does.

Permissions are those of a plain ``open(path, "w")``: a new file gets 0666 minus the umask
(0644 under umask 022; not the 0600 of :func:`tempfile.mkstemp`), a replaced file keeps the
permission bits of the file it replaces. The folder is checked before anything is written: a
missing or read-only folder is an OSError that names the caller's ``path``, never the
temporary name. A symbolic link at ``path`` is replaced by the new file, not written through.

:class:`AtomicDirectory` does the same for outputs built by another library under a name of
its own choosing (a rosbag2 folder): they are built inside a private temporary folder next to
``path`` and moved into place by :meth:`AtomicDirectory.commit`.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["AtomicDirectory", "AtomicFile", "atomic_write", "check_target", "create_temp_file"]

_MODES = ("w", "wt", "wb")


def check_target(path: str | Path, *, overwrite: bool = True, folder_ok: bool = False) -> Path:
    """Refuse up front an output ``path`` that cannot be written atomically; returns it as a Path.

    Raises:
        FileNotFoundError: the folder of ``path`` does not exist.
        NotADirectoryError: the "folder" of ``path`` is a file.
        PermissionError: the folder is not writable (no file can be created in it).
        FileExistsError: ``path`` exists and ``overwrite`` is False.
        IsADirectoryError: ``path`` is a folder and ``folder_ok`` is False.
    """
    path = Path(path)
    folder = path.parent
    if not folder.exists():
        raise FileNotFoundError(f"{path}: cannot write it, the folder {folder} does not exist")
    if not folder.is_dir():
        raise NotADirectoryError(f"{path}: cannot write it, {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(f"{path}: cannot write it, the folder {folder} is not writable")
    if path.is_dir() and not folder_ok:
        raise IsADirectoryError(f"{path}: is a folder, not a file path")
    _refuse_special(path)
    if not overwrite and (path.exists() or path.is_symlink()):
        raise FileExistsError(f"{path}: exists; choose another path or allow overwriting")
    return path


def _refuse_special(path: Path) -> None:
    """Raise FileExistsError when ``path`` exists and is neither a regular file nor a folder
    (a device, a FIFO, a socket): the output would be renamed over it. An independent probe's
    ``csv:/dev/full`` replaced the machine's /dev/full with a regular file; as root,
    ``csv:/dev/null`` would have replaced /dev/null."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # absent (or a dangling link): a new file
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        kind = ("a character device" if stat.S_ISCHR(mode) else "a block device"
                if stat.S_ISBLK(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a socket"
                if stat.S_ISSOCK(mode) else "not a regular file")
        raise FileExistsError(f"{path}: is {kind}; an output is written next to its path and "
                              "renamed over it, which would replace it: give a file path "
                              "(for standard output: jsonl with no path)")


def create_temp_file(path: str | Path) -> Path:
    """Create a fresh empty file next to ``path`` (``.<name>.<random>.partial``, O_EXCL) with
    the permissions an ordinary ``open(path, "w")`` would give a new file (0666 minus the
    umask), and return its name; the caller renames or removes it. FileExistsError when
    ``path`` is a device, a FIFO or a socket (:func:`_refuse_special`)."""
    _refuse_special(Path(path))
    fd, name = _create_temp(Path(path))
    os.close(fd)
    return name


def _create_temp(path: Path) -> tuple[int, Path]:
    for _ in range(100):
        name = path.parent / f".{path.name}.{secrets.token_hex(6)}.partial"
        try:
            return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), name
        except FileExistsError:
            continue
        except OSError as exc:
            raise type(exc)(exc.errno, f"{path}: cannot create a temporary file next to it: "
                                       f"{exc.strerror}") from None
    raise FileExistsError(f"{path}: could not create a temporary file next to it")


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every file system allows it)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class AtomicFile:
    """An output file that appears at ``path`` only complete: :meth:`commit` or :meth:`discard`.

    Write through :attr:`file` (a text or binary file object on the hidden temporary sibling)
    for as long as needed, e.g. a live session streamed record by record; ``commit()`` flushes,
    fsyncs and renames it over ``path``; ``discard()`` removes it. As a context manager it
    commits on a normal exit and discards on any exception (KeyboardInterrupt included).

    Args:
        path: the target file.
        mode: ``"w"`` (text) or ``"wb"`` (binary).
        encoding, newline: as for :func:`open` (text mode only).
        overwrite: replace an existing ``path``; if False an existing one is a FileExistsError,
            checked here and again just before the rename.

    Raises:
        OSError naming ``path`` (see :func:`check_target`), ValueError for another mode.
    """

    def __init__(self, path: str | Path, mode: str = "w", *, encoding: str | None = None,
                 newline: str | None = None, overwrite: bool = True) -> None:
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {_MODES}, got {mode!r}")
        self.path = check_target(path, overwrite=overwrite)
        self.overwrite = overwrite
        fd, self._tmp = _create_temp(self.path)
        try:
            with contextlib.suppress(OSError):  # a replaced file keeps its permission bits
                st = self.path.stat()
                if stat.S_ISREG(st.st_mode):
                    os.fchmod(fd, stat.S_IMODE(st.st_mode))
            kwargs: dict[str, Any] = {} if "b" in mode else {"encoding": encoding,
                                                              "newline": newline}
            self.file: IO[Any] = os.fdopen(fd, mode, **kwargs)
        except BaseException:
            os.close(fd)
            self._tmp.unlink(missing_ok=True)
            raise
        self._done = False

    def __repr__(self) -> str:
        return f"AtomicFile({str(self.path)!r})"

    @property
    def done(self) -> bool:
        """True after :meth:`commit` or :meth:`discard`."""
        return self._done

    def commit(self) -> None:
        """Flush, fsync, close and rename the file over ``path``; on failure it is discarded
        and ``path`` is left as it was."""
        if self._done:
            return
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            if not self.overwrite:
                check_target(self.path, overwrite=False)
            os.replace(self._tmp, self.path)
        except BaseException:
            self.discard()
            raise
        self._done = True
        _fsync_folder(self.path.parent)

    def discard(self) -> None:
        """Close and remove the temporary file; ``path`` is untouched."""
        if self._done:
            return
        self._done = True
        try:
            with contextlib.suppress(OSError):  # its buffered data is thrown away anyway
                self.file.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", *, encoding: str | None = None,
                 newline: str | None = None, overwrite: bool = True) -> Iterator[IO[Any]]:
    """``with atomic_write(path) as fh:`` write ``fh``; ``path`` is replaced when the block
    ends normally and untouched if it raises (see :class:`AtomicFile` for the arguments)."""
    with AtomicFile(path, mode, encoding=encoding, newline=newline,
                    overwrite=overwrite) as out:
        yield out.file


class AtomicDirectory:
    """Build an output under a private temporary folder next to ``path``, then move it there.

    For writers that create their output themselves (the ``rosbags`` writer makes the bag
    folder and names its files): build it at or inside :attr:`staging`, a fresh folder
    ``.<name>.<random>.partial`` (mode 0700, so half-built output is not visible to others;
    the output's own files and folders get the modes their writer gives them), then
    :meth:`commit` the finished file or folder.

    A file moved over an existing file is atomic like :class:`AtomicFile`. A folder replacing
    an existing folder takes two renames (the old one is moved into the staging folder first):
    a crash between them leaves ``path`` absent and the old folder inside the hidden staging
    folder, never a partial new one at ``path``.

    Args:
        path: the target (file or folder).
        overwrite: replace an existing ``path`` (checked here and again in ``commit``).
    """

    def __init__(self, path: str | Path, *, overwrite: bool = True) -> None:
        self.path = check_target(path, overwrite=overwrite, folder_ok=True)
        self.overwrite = overwrite
        try:
            self.staging = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.",
                                                 suffix=".partial", dir=self.path.parent))
        except OSError as exc:
            raise type(exc)(exc.errno, f"{self.path}: cannot create a temporary folder next "
                                       f"to it: {exc.strerror}") from None
        self._done = False

    def __repr__(self) -> str:
        return f"AtomicDirectory({str(self.path)!r})"

    def commit(self, built: str | Path) -> None:
        """fsync ``built`` (a file or folder inside :attr:`staging`) and move it to ``path``;
        the staging folder is removed. On failure everything is discarded and ``path`` is as
        it was."""
        if self._done:
            raise ValueError(f"{self.path}: already committed or discarded")
        built = Path(built)
        try:
            if self.staging not in built.parents:
                raise ValueError(f"{built}: not inside the staging folder {self.staging}")
            _fsync_tree(built)
            check_target(self.path, overwrite=self.overwrite, folder_ok=built.is_dir())
            if built.is_dir() and self.path.exists():
                if not self.path.is_dir():
                    raise NotADirectoryError(f"{self.path}: is a file, not a folder")
                old = self.staging / ".old"
                self.path.rename(old)
                try:
                    built.rename(self.path)
                except BaseException:
                    old.rename(self.path)
                    raise
            else:
                os.replace(built, self.path)
        finally:
            self.discard()
        _fsync_folder(self.path.parent)

    def discard(self) -> None:
        """Remove the staging folder and whatever is in it; ``path`` is untouched."""
        self._done = True
        shutil.rmtree(self.staging, ignore_errors=True)


def _fsync_tree(path: Path) -> None:
    if path.is_dir():
        for sub in path.iterdir():
            _fsync_tree(sub)
        _fsync_folder(path)
    else:
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
