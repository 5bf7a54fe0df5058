"""Every script in benchmarks/ still imports against the library (a moved or renamed module
breaks a benchmark silently otherwise: tests never run them, they take minutes). Peer
libraries (vqf, imufusion, ahrs) are imported inside the scripts' functions, so this needs
only the library itself."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("*.py"))


def test_there_are_benchmark_scripts():
    assert {"attitude_speed", "ekf_accuracy", "pipeline_replay", "tune_ekf"} <= set(SCRIPTS)


@pytest.mark.parametrize("name", SCRIPTS)
def test_benchmark_script_imports(name, monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # the scripts import their siblings
    monkeypatch.delitem(sys.modules, name, raising=False)
    module = importlib.import_module(name)
    if not name.startswith("_"):
        assert callable(getattr(module, "main", None)), f"benchmarks/{name}.py has no main()"
