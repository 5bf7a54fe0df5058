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

__all__ = ["HAVE_NUMBA", "compiled_entry_point", "njit"]

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
