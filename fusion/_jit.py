"""Optional numba compilation.

With numba installed (the ``fast`` extra) the filter cores are compiled to machine code; without
it the very same Python functions run interpreted, giving identical results more slowly. Set the
environment variable ``FUSION_DISABLE_JIT=1`` to force the interpreted path (tests use it to
check that both paths agree).

numba's on-disk cache (``cache=True``, files in ``__pycache__``) is keyed by the source file of
each compiled function only: a compiled function that calls one from another module (the EKF
core calls :mod:`fusion.planar.model`) keeps its cached machine code when only that other
module changes. After editing such a module, delete the ``*.nbi``/``*.nbc`` files or touch the
caller's file (tests/test_ekf.py's filterpy reference, which calls the model directly, fails
on such a stale core).
"""

from __future__ import annotations

import os

__all__ = ["HAVE_NUMBA", "njit"]

try:
    if os.environ.get("FUSION_DISABLE_JIT", "") not in ("", "0"):
        raise ImportError("disabled by FUSION_DISABLE_JIT")
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:
    _numba = None
    HAVE_NUMBA = False


def njit(*args, **kwargs):
    """``numba.njit`` (no fastmath: IEEE results equal to the interpreted path), or a no-op."""
    if _numba is not None:
        kwargs.setdefault("cache", True)
        return _numba.njit(*args, **kwargs)
    if args and callable(args[0]):
        return args[0]
    return lambda f: f
