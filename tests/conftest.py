from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ROOT / "datasets"


@pytest.fixture(scope="session")
def datasets_dir() -> Path:
    return DATASETS


@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    """Run the test under each of these umasks (the process umask restored after)."""
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)
