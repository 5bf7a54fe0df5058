"""numba's on-disk cache never serves machine code built from older sources (fusion._jit).

numba keys each cached function by its own file's stamp only, so a compiled function that calls
one from another module (the pipeline's event core calls the EKF core) kept its old machine code
when only the callee's file changed: a replay then ran the previous core (seen while checking a
mutation of the EKF core in issue 11's work). fusion._jit drops every cached file of the package
when any module that uses ``njit`` changed. Checked here on a package of real files in a
temporary folder.
"""

from __future__ import annotations

from fusion._jit import _FINGERPRINT, _drop_stale_caches


def _package(tmp_path):
    root = tmp_path / "pkg"
    (root / "sub" / "__pycache__").mkdir(parents=True)
    (root / "core.py").write_text("from fusion._jit import njit\n@njit\ndef f(x):\n    return x\n")
    (root / "sub" / "caller.py").write_text("from fusion._jit import njit\n")
    (root / "plain.py").write_text("X = 1\n")
    return root


def _cache_files(root, name="caller.g-3.py311"):
    files = [root / "sub" / "__pycache__" / f"{name}.nbi",
             root / "sub" / "__pycache__" / f"{name}.1.nbc"]
    for f in files:
        f.write_bytes(b"machine code")
    return files


def test_cached_code_is_dropped_when_a_compiled_source_changes(tmp_path):
    root = _package(tmp_path)
    old = _cache_files(root)
    assert _drop_stale_caches(root)  # no fingerprint yet: nothing known about these files
    assert not any(f.exists() for f in old)
    assert (root / "__pycache__" / _FINGERPRINT).is_file()

    kept = _cache_files(root)  # compiled from the current sources
    assert not _drop_stale_caches(root)
    assert all(f.exists() for f in kept)

    (root / "plain.py").write_text("X = 2\n")  # no njit in it: the machine code still holds
    assert not _drop_stale_caches(root)
    assert all(f.exists() for f in kept)

    # the callee changes, not the caller whose cache numba would have trusted
    (root / "core.py").write_text("from fusion._jit import njit\n@njit\ndef f(x):\n"
                                  "    return -x\n")
    assert _drop_stale_caches(root)
    assert not any(f.exists() for f in kept)
    assert not _drop_stale_caches(root)

