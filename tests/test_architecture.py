"""The layering rules of ARCHITECTURE.md hold: import-linter's contracts in pyproject.toml, and
no import cycle between any two modules of fusion/ and drivers/ (grimp's import graph).

Imports inside functions count (import-linter and grimp read the source, not what ran), so a
lazy import does not get around a rule.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from collections import deque
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib" if sys.version_info >= (3, 11) else "tomli")
grimp = pytest.importorskip("grimp")
pytest.importorskip("importlinter")

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("fusion", "drivers")
LINT = ("import sys; from importlinter.cli import lint_imports_command; "
        "sys.exit(lint_imports_command())")


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """Run ``lint-imports`` on the packages and pyproject.toml under ``root``."""
    env = {**os.environ, "PYTHONPATH": str(root), "COLUMNS": "300", "NO_COLOR": "1"}
    return subprocess.run([sys.executable, "-c", LINT, "--no-cache"], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)


def contracts() -> dict[str, dict]:
    with open(ROOT / "pyproject.toml", "rb") as fh:
        config = tomllib.load(fh)["tool"]["importlinter"]
    return {c["id"]: c for c in config["contracts"]}


def module_cycles(graph) -> list[list[str]]:
    """One shortest cycle per strongly connected component of more than one module (Tarjan,
    iterative), each as ``[a, b, ..., a]``.
    """
    imports = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []
    for root in sorted(imports):
        if root in index:
            continue
        work = [(root, iter(imports[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(imports[nxt])))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        component.add(m)
                        if m == node:
                            break
                    if len(component) > 1:
                        components.append(component)
    cycles = []
    for component in components:
        start = min(component)
        previous = {start: None}
        queue = deque([start])
        while queue:  # breadth first inside the component, back to start
            node = queue.popleft()
            if start in imports[node]:
                path = [node]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                cycles.append([*reversed(path), start])
                break
            for nxt in imports[node]:
                if nxt in component and nxt not in previous:
                    previous[nxt] = node
                    queue.append(nxt)
    return sorted(cycles)


def test_import_linter_contracts_are_kept():
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"Contracts: {len(contracts())} kept, 0 broken." in result.stdout


def test_no_import_cycle_between_modules():
    # acyclic_siblings sees cycles between sibling packages; this also sees the ones through a
    # package's own __init__ (e.g. fusion.io.x -> fusion.io -> fusion.io.x)
    graph = grimp.build_graph(*PROJECT, cache_dir=None)
    assert module_cycles(graph) == []


def test_cycle_search_names_each_cycle(tmp_path, monkeypatch):
    pkg = tmp_path / "cyclepkg_arch"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "",
        "a.py": "from cyclepkg_arch import b\n",
        "b.py": "def f():\n    from cyclepkg_arch import c\n",  # a lazy import counts
        "c.py": "import cyclepkg_arch.a\n",
        "d.py": "import cyclepkg_arch.a\n",  # imports into a cycle, is not part of it
        "sub/__init__.py": "from cyclepkg_arch.sub.x import X\n\nLIMIT = 3\n",
        "sub/x.py": "from cyclepkg_arch.sub import LIMIT\n\nX = LIMIT\n",  # via __init__
        "sub/y.py": "from cyclepkg_arch.sub import x\n",  # a submodule: no cycle
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    graph = grimp.build_graph("cyclepkg_arch", cache_dir=None)
    assert module_cycles(graph) == [
        ["cyclepkg_arch.a", "cyclepkg_arch.b", "cyclepkg_arch.c", "cyclepkg_arch.a"],
        ["cyclepkg_arch.sub", "cyclepkg_arch.sub.x", "cyclepkg_arch.sub"],
    ]


def test_contracts_name_every_subpackage():
    # a new subpackage of fusion must be placed: in a layer, and forbidden to drivers unless
    # it is a leaf layer
    children = grimp.build_graph(*PROJECT, cache_dir=None).find_children("fusion")
    c = contracts()
    leaves = {"fusion.types", "fusion.geometry"}
    assert set(c["drivers"]["forbidden_modules"]) == children - leaves
    in_layers = {m.strip() for layer in c["layers"]["layers"] for m in layer.split("|")}
    assert in_layers == children - {"fusion._jit", "fusion.__main__"}


BAD_IMPORTS = [
    # (file, import added at its end, contracts that must break). An upward import usually
    # closes a cycle between packages too, and a forbidden module reached through a chain
    # counts: evaluation.synthetic -> drivers.chassis -> fusion.io breaks the layers.
    ("drivers/chassis.py", "import fusion.io.errors", {"drivers", "layers"}),
    ("fusion/geometry/quaternion.py", "import fusion.sinks.base",
     {"acyclic", "drivers", "estimation", "layers"}),
    ("fusion/io/errors.py", "from fusion.cli import main", {"acyclic", "cli", "layers"}),
    # geometry imports types (fusion.types.constants), so this closes a cycle as well
    ("fusion/types/samples.py", "from fusion.geometry import kinematics", {"acyclic", "layers"}),
    ("fusion/planar/robot.py", "import fusion.attitude.mahony", {"layers"}),
    ("fusion/geometry/kinematics.py", "from drivers import slamware", {"leaves"}),
    # a cycle inside one layer: imu_csv imports errors
    ("fusion/io/errors.py", "import fusion.io.imu_csv", {"acyclic"}),
    # a cycle between packages, not modules: io.robot_toml -> sinks.registry -> io.sink_spec
    ("fusion/io/robot_toml.py", "def f():\n    import fusion.sinks.registry",
     {"acyclic", "layers"}),
]


@pytest.fixture(scope="module")
def project_copy(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("arch")
    for package in PROJECT:
        shutil.copytree(ROOT / package, root / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", root)
    return root


@pytest.mark.parametrize(("path", "line", "broken"), BAD_IMPORTS,
                         ids=[f"{p}+{line.split()[-1]}" for p, line, _ in BAD_IMPORTS])
def test_contracts_catch_a_bad_import(project_copy, path, line, broken):
    target = project_copy / path
    original = target.read_text()
    target.write_text(original + "\n" + textwrap.dedent(line) + "\n")
    try:
        result = lint_imports(project_copy)
    finally:
        target.write_text(original)
    report = result.stdout + result.stderr
    assert result.returncode == 1, report
    names = {cid: c["name"] for cid, c in contracts().items()}
    found = {cid for cid, name in names.items() if f"{name} BROKEN" in report}
    assert found == broken, report
    for cid in set(names) - broken:
        assert f"{names[cid]} KEPT" in report, report


def test_the_unmodified_copy_passes(project_copy):
    # the failures above come from the added lines, not from copying
    result = lint_imports(project_copy)
    assert result.returncode == 0, result.stdout + result.stderr
