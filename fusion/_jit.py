"""Optional numba compilation.

With numba installed (the ``fast`` extra) the filter cores are compiled to machine code; without
it the very same Python functions run interpreted, giving identical results more slowly. Set the
environment variable ``FUSION_DISABLE_JIT=1`` to force the interpreted path (tests use it to
check that both paths agree).

numba's on-disk cache (``cache=True``) checks each compiled function against its own source
file only: a function that calls one from another module (the pipeline's event core calls the
EKF core, which calls :mod:`fusion.planar.model`), or reads a module-level constant frozen into
its machine code, kept its cached code when only that other module changed, and ran the old
code. So every function of this package is cached under a stamp that also holds a SHA-256 of
all the package's Python sources, taken when this module is imported
(:class:`_PackageStampLocator`, placed first in numba's list of cache locators; the files go
where numba would put them, ``__pycache__`` or ``NUMBA_CACHE_DIR``). numba treats a cache entry
with another stamp as missing and overwrites it, so a process that imported older sources can
only write entries that a newer one ignores. Left: a file edited between this module's import
and the import of the module compiled from it is stamped with the older digest (the same window
numba's own per-file stamp has). When numba's internal caching API is not what this expects,
caching is switched off rather than risk running stale code.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["HAVE_NUMBA", "compiled_entry_point", "njit"]

_PACKAGE = Path(__file__).resolve().parent


def package_sources_digest(root: Path = _PACKAGE) -> str:
    """SHA-256 over the relative path and bytes of every ``*.py`` file under ``root``."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def make_package_locator(root: Path, digest: str, locator_classes):
    """A numba cache locator class for functions defined in files under ``root``: it finds the
    locator numba would use among ``locator_classes`` (tried in order) and stamps its entries
    with ``(numba's own source stamp, digest)``. Functions from other files are left to
    numba (``from_function`` returns None)."""
    root = Path(root).resolve()

    class _PackageStampLocator:
        def __init__(self, inner):
            self._inner = inner

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                inside = Path(py_file).resolve().is_relative_to(root)
            except (OSError, ValueError):
                inside = False
            if not inside:
                return None
            for other in locator_classes:
                if other is cls:
                    continue
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
            return None

        def ensure_cache_path(self):
            self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        def get_source_stamp(self):
            return (self._inner.get_source_stamp(), digest)

    return _PackageStampLocator


def _install_package_locator() -> bool:
    """Put this package's stamping locator first in numba's list; False when numba's internal
    API has changed (then nothing is cached)."""
    try:
        from numba.core import caching

        classes = caching.CacheImpl._locator_classes
        if not isinstance(classes, list):
            return False
        locator = make_package_locator(_PACKAGE, package_sources_digest(), classes)
        classes.insert(0, locator)
        return True
    except (ImportError, AttributeError, OSError):
        return False


try:
    if os.environ.get("FUSION_DISABLE_JIT", "") not in ("", "0"):
        raise ImportError("disabled by FUSION_DISABLE_JIT")
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:
    _numba = None
    HAVE_NUMBA = False
    _CACHE_IS_SAFE = False
else:
    _CACHE_IS_SAFE = _install_package_locator()


def njit(*args, **kwargs):
    """``numba.njit`` (no fastmath: IEEE results equal to the interpreted path), or a no-op."""
    if _numba is not None:
        kwargs.setdefault("cache", _CACHE_IS_SAFE)
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
