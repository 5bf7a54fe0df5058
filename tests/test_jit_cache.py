"""numba's on-disk cache never serves machine code built from older sources (fusion._jit).

numba checks each cached function against its own file only, so a compiled function that calls
one from another module (the pipeline's event core calls the EKF core) kept its old machine code
when only the callee's file changed: a replay then ran the previous core (seen while checking a
mutation of the EKF core in issue 11's work). fusion._jit stamps the package's cache entries
with a digest of all its sources. Checked here with real numba compiling a two-module package
of real files in a temporary folder, in fresh interpreters, as a user's runs would.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import fusion
from fusion._jit import package_sources_digest

_RUNNER = textwrap.dedent("""
    import sys
    from pathlib import Path
    from numba.core import caching
    from fusion._jit import make_package_locator, package_sources_digest

    root = Path(sys.argv[1])
    if sys.argv[2] == "stamped":
        classes = caching.CacheImpl._locator_classes
        classes.insert(0, make_package_locator(root, package_sources_digest(root), classes))
    sys.path.insert(0, str(root.parent))
    module = __import__("pkg." + sys.argv[3], fromlist=["f"])
    print(module.f(1.0))
""")


def _write_callee(root, increment):
    (root / "callee.py").write_text(
        f"from numba import njit\n\n@njit(cache=True)\ndef g(x):\n    return x + {increment}\n")


def _package(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text("")
    _write_callee(root, 1.0)
    (root / "caller.py").write_text(
        "from numba import njit\nfrom pkg.callee import g\n\n"
        "@njit(cache=True)\ndef f(x):\n    return 10.0 * g(x)\n")
    return root


def _clean_env():
    """This interpreter's environment without numba settings, with this checkout importable."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    checkout = str(Path(fusion.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [checkout, env.get("PYTHONPATH")]))
    return env


def _run(tmp_path, root, mode, env, module="caller"):
    runner = tmp_path / "runner.py"
    runner.write_text(_RUNNER)
    out = subprocess.run([sys.executable, str(runner), str(root), mode, module], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return float(out.stdout.strip())


@pytest.mark.parametrize("cache_dir", ["in-tree", "NUMBA_CACHE_DIR"])
def test_edit_of_a_callee_module_recompiles_its_caller(tmp_path, cache_dir):
    pytest.importorskip("numba")
    root = _package(tmp_path)
    env = _clean_env()
    if cache_dir == "NUMBA_CACHE_DIR":
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba-cache")
    assert _run(tmp_path, root, "stamped", env) == 20.0
    where = tmp_path / "numba-cache" if cache_dir == "NUMBA_CACHE_DIR" else root / "__pycache__"
    assert any(where.rglob("caller.f-*.nbi")), "the caller was not cached where expected"

    _write_callee(root, 2.0)  # the caller's file is untouched: numba alone would trust its cache
    assert _run(tmp_path, root, "stamped", env) == 30.0
    assert _run(tmp_path, root, "stamped", env) == 30.0  # and the fresh entry is served again


def test_unstamped_numba_serves_the_stale_caller(tmp_path):
    """The failure the stamp exists for, shown on numba alone (if a numba release fixes it,
    this test says so and the stamp may go)."""
    pytest.importorskip("numba")
    root = _package(tmp_path)
    env = _clean_env()
    assert _run(tmp_path, root, "numba-alone", env) == 20.0
    _write_callee(root, 2.0)
    assert _run(tmp_path, root, "numba-alone", env) == 20.0


def test_digest_covers_every_python_file(tmp_path):
    root = tmp_path / "p"
    (root / "sub").mkdir(parents=True)
    (root / "sub" / "constants.py").write_text("GRAVITY = 9.81\n")  # frozen into machine code
    (root / "core.py").write_text("X = 1\n")
    (root / "notes.txt").write_text("a")
    before = package_sources_digest(root)
    (root / "notes.txt").write_text("b")
    assert package_sources_digest(root) == before
    (root / "sub" / "constants.py").write_text("GRAVITY = 9.80665\n")
    assert package_sources_digest(root) != before


def test_a_function_numba_cannot_cache_still_compiles(tmp_path):
    """A global array over 1 MB is a dynamic global: numba compiles without caching and warns;
    it reads the locator's ``_py_file`` for that, which the stamping locator hands on."""
    pytest.importorskip("numba")
    root = _package(tmp_path)
    (root / "big.py").write_text(
        "import numpy as np\nfrom numba import njit\n\nBIG = np.arange(300_000.0)\n\n"
        "@njit(cache=True)\ndef f(x):\n    return BIG[int(x) + 1]\n")
    assert _run(tmp_path, root, "stamped", _clean_env(), module="big") == 2.0


def test_the_package_cache_is_stamped_when_numba_is_there():
    numba = pytest.importorskip("numba")
    import fusion._jit as jit

    if not jit.HAVE_NUMBA:
        pytest.skip("FUSION_DISABLE_JIT is set")
    assert jit._CACHE_IS_SAFE
    first = numba.core.caching.CacheImpl._locator_classes[0]
    assert first.__name__ == "_PackageStampLocator"


def test_a_replaced_locator_list_switches_the_cache_off():
    """``NUMBA_CACHE_LOCATOR_CLASSES`` makes numba ignore the list the stamp is in: caching
    the cores would then run stale code, so it is off, and the user is told."""
    pytest.importorskip("numba")
    env = _clean_env()
    env["NUMBA_CACHE_LOCATOR_CLASSES"] = "InTreeCacheLocator"
    out = subprocess.run([sys.executable, "-c", "import fusion._jit as j; print(j._CACHE_IS_SAFE)"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    assert "cache is off" in out.stderr and "NUMBA_CACHE_LOCATOR_CLASSES" in out.stderr


def test_digest_skips_dangling_links_and_refuses_an_empty_tree(tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    with pytest.raises(OSError, match="no Python source files"):
        package_sources_digest(root)  # e.g. a zipped install: nothing to stamp with
    (root / "core.py").write_text("X = 1\n")
    before = package_sources_digest(root)
    (root / ".#core.py").symlink_to(root / "missing")  # an editor's lock file
    assert package_sources_digest(root) == before
