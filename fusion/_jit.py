"""Optional numba compilation.

With numba installed (the ``fast`` extra) the filter cores are compiled to machine code; without
it the very same Python functions run interpreted, giving identical results more slowly. Set the
environment variable ``FUSION_DISABLE_JIT=1`` to force the interpreted path (tests use it to
check that both paths agree).

numba's on-disk cache (``cache=True``, files in ``__pycache__``) is keyed by the source file of
each compiled function only: a compiled function that calls one from another module (the
pipeline's event core calls the EKF core, which calls :mod:`fusion.planar.model`) would keep
its cached machine code when only that other module changed, and run the old code. So on
import, when the compiled sources (every module of the package that uses :func:`njit`) differ
from those the cache was built from, every cached file of the package is dropped first
(:func:`_drop_stale_caches`; a fingerprint in ``fusion/__pycache__``): editing one core costs
one recompilation of all of them, never a stale one.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["HAVE_NUMBA", "compiled_entry_point", "njit"]

_PACKAGE = Path(__file__).resolve().parent
_FINGERPRINT = "numba-sources.sha256"


def _compiled_sources_digest(root: Path) -> str:
    """SHA-256 over the path and bytes of every module under ``root`` that uses ``njit``."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        data = path.read_bytes()
        if b"njit" in data:
            digest.update(path.relative_to(root).as_posix().encode() + b"\0" + data + b"\0")
    return digest.hexdigest()


def _drop_stale_caches(root: Path = _PACKAGE) -> bool:
    """Delete numba's cached files (``*.nbi``, ``*.nbc``) under ``root`` when the compiled
    sources changed since they were written; returns True when it did. Best effort: a
    read-only install (nothing of ours cached there) is left alone."""
    digest = _compiled_sources_digest(root)
    stamp = root / "__pycache__" / _FINGERPRINT
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        for cached in root.rglob("__pycache__/*.nb[ic]"):
            cached.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        return False
    return True


try:
    if os.environ.get("FUSION_DISABLE_JIT", "") not in ("", "0"):
        raise ImportError("disabled by FUSION_DISABLE_JIT")
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:
    _numba = None
    HAVE_NUMBA = False
else:
    _drop_stale_caches()


def njit(*args, **kwargs):
    """``numba.njit`` (no fastmath: IEEE results equal to the interpreted path), or a no-op."""
    if _numba is not None:
        kwargs.setdefault("cache", True)
        return _numba.njit(*args, **kwargs)
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


def compiled_entry_point(dispatcher, n_vectors: int):
    """``dispatcher`` compiled for ``(float64[::1] buffer, n_vectors x float64[:], float64)``,
    callable without numba's type dispatch.

    Dispatch costs about 1 us per call, as much as a filter step itself; the compiled entry
    point of the one signature a streaming filter uses skips it (callers guarantee the types:
    float64 arrays). Falls back to the dispatcher, or to the plain Python function without
    numba.
    """
    try:
        from numba import types

        vec = types.float64[:]  # any stride: rows and columns of bigger arrays too
        sig = (types.float64[::1], *(vec,) * n_vectors, types.float64)
        dispatcher.compile(sig)
        return dispatcher.overloads[sig].entry_point
    except Exception:  # numba missing (plain function) or an internal API change
        return dispatcher
