"""tests/conftest.py unfreezes a heap a test froze (the live tests freeze it as ``fusion run``
does). The two tests run in file order: the first freezes, the second sees nothing frozen."""

from __future__ import annotations

import gc

from fusion.cli.demo import freeze_heap


def test_a_test_may_freeze_the_heap():
    freeze_heap()
    assert gc.get_freeze_count() > 0


def test_the_next_test_finds_it_unfrozen():
    assert gc.get_freeze_count() == 0
