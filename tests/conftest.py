from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ROOT / "datasets"


@pytest.fixture(scope="session")
def datasets_dir() -> Path:
    return DATASETS


@pytest.fixture(scope="module")
def terrain_run():
    """benchmarks/terrain's run.py as a module (it imports sim.py by bare name: that one is
    ``sys.modules["sim"]``), both taken out of ``sys.modules`` again afterwards so that no
    other test sees a module called ``sim``."""
    saved = sys.path[:]  # run.py puts its own folder on sys.path too
    sys.path.insert(0, str(ROOT / "benchmarks" / "terrain"))
    try:
        run = importlib.import_module("run")
    finally:
        sys.path[:] = saved
    yield run
    for name in ("sim", "run"):
        sys.modules.pop(name, None)


@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    """Run the test under each of these umasks (the process umask restored after)."""
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


#: Cyclone DDS on loopback only: no multicast (CI runners have none), the peers found by unicast
#: on 127.0.0.1 (participant indices probed from 0).
LOOPBACK_DDS = ('<CycloneDDS><Domain Id="any"><General><Interfaces>'
                '<NetworkInterface address="127.0.0.1"/></Interfaces>'
                '<AllowMulticast>false</AllowMulticast></General>'
                '<Discovery><Peers><Peer address="127.0.0.1"/></Peers>'
                '<ParticipantIndex>auto</ParticipantIndex></Discovery></Domain></CycloneDDS>')


@pytest.fixture
def ros2_env(monkeypatch) -> dict[str, str]:
    """A fresh ROS_DOMAIN_ID (1..101, so concurrent runs rarely meet) and CYCLONEDDS_URI pinned
    to loopback, set in this process (for sinks opened here) and returned as the environment
    for child processes."""
    import random

    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 101)))
    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK_DDS)
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


@pytest.fixture(autouse=True)
def _heap_unfrozen_after_each_test():
    """A test that freezes the heap as ``fusion run`` does (``fusion.cli.demo.freeze_heap``:
    ``gc.freeze``) gets it unfrozen after it, so the objects it and the tests after it
    allocate are collected as usual (tests/test_gc_freeze.py)."""
    import gc

    yield
    if gc.get_freeze_count():
        gc.unfreeze()
