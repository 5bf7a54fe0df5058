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
(:func:`make_package_locator`, placed first in numba's list of cache locators; the files go
where numba would put them, ``__pycache__`` or ``NUMBA_CACHE_DIR``). numba treats a cache entry
with another stamp as missing and overwrites it, so an entry written from older sources is not
loaded by a process that imported newer ones. Left: a file edited between this module's import
and the import of the module compiled from it is stamped with the older digest (the same window
numba's own per-file stamp has); and numba reuses data file names across stamps and reads the
index and the data file separately, so two processes of different source versions compiling
the same function at the same instant could still cross (microseconds; numba's own race).
Caching is switched off, with a warning, rather than risk running stale code when numba's
internal caching API is not what this expects, when ``NUMBA_CACHE_LOCATOR_CLASSES`` replaces
the locator list, or when the sources cannot be read (e.g. a zipped install).
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

__all__ = ["HAVE_NUMBA", "compiled_entry_point", "njit"]

_PACKAGE = Path(__file__).resolve().parent


def package_sources_digest(root: Path = _PACKAGE) -> str:
    """SHA-256 over the relative path and bytes of every ``*.py`` regular file under ``root``
    (editor lock files and other dangling links are skipped).

    Raises:
        OSError: no source file under ``root`` (a zipped install), or one cannot be read.
    """
    digest = hashlib.sha256()
    n_files = 0
    for path in sorted(root.rglob("*.py")):
        if not path.is_file():
            continue
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
        n_files += 1
    if n_files == 0:
        raise OSError(f"no Python source files under {root}")
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

        def __getattr__(self, name):
            # numba reads some attributes of its own locators directly (``_py_file`` when a
            # function cannot be cached): those of the wrapped one
            if name == "_inner":
                raise AttributeError(name)
            return getattr(self._inner, name)

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
    """Put this package's stamping locator first in numba's list; False, with a warning, when
    it cannot protect the cache (then nothing is cached)."""
    try:
        from numba.core import caching, config

        if getattr(config, "CACHE_LOCATOR_CLASSES", ""):
            raise RuntimeError("NUMBA_CACHE_LOCATOR_CLASSES replaces numba's locator list")
        classes = caching.CacheImpl._locator_classes
        if not isinstance(classes, list):
            raise AttributeError("numba.core.caching.CacheImpl._locator_classes is no list")
        locator = make_package_locator(_PACKAGE, package_sources_digest(), classes)
        classes.insert(0, locator)
        return True
    except (ImportError, AttributeError, OSError, RuntimeError) as exc:
        warnings.warn(f"fusion: numba's on-disk cache is off for the filter cores ({exc}); "
                      "they are compiled in every process", RuntimeWarning, stacklevel=2)
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
