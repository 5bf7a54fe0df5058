"""Timing helper shared by the benchmark scripts (run them as ``python benchmarks/NAME.py``)."""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["cpu_rate"]


def cpu_rate(fn: Callable[[], int], seconds: float) -> float:
    """Items per CPU second of ``fn`` (which returns how many it processed), best of runs.

    CPU time of this process (not wall time), so other load on the machine disturbs the
    figures less; the best of repeated runs filters the rest. One warm-up call first (JIT
    compilation, caches).
    """
    fn()
    best = 0.0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        t0 = time.process_time()
        n = fn()
        elapsed = time.process_time() - t0
        if elapsed > 0:
            best = max(best, n / elapsed)
    return best
