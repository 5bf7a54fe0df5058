"""Cross-validation across runs (trials, logs): folds, and selection from a table of errors.

- :func:`kfold_splits`: k folds of run indices, each held out once (``fusion tune``).
- :func:`leave_one_out`: for a precomputed table of per-trial errors (a grid of
  configurations), each trial scored by the configuration best on the others (the tuning
  scripts in ``benchmarks/``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CvResult", "kfold_splits", "leave_one_out"]


@dataclass
class CvResult:
    """Outcome of leave-one-trial-out selection over ``table[config, trial]``.

    Attributes:
        held_out: (T,) error of each trial under the configuration chosen without it.
        chosen: (T,) index of that configuration, per fold.
        best: index of the configuration best on all trials (the defaults to ship).
        in_sample: mean error of ``best`` on all trials: an in-sample figure.
    """

    held_out: np.ndarray
    chosen: np.ndarray
    best: int
    in_sample: float

    @property
    def cv_mean(self) -> float:
        """The cross-validated mean error: each trial scored by parameters not tuned on it."""
        return float(np.mean(self.held_out))


def leave_one_out(table: np.ndarray) -> CvResult:
    """For each trial, choose the configuration with the lowest mean error on the others."""
    table = np.asarray(table, dtype=float)
    n_trials = table.shape[1]
    held_out = np.empty(n_trials)
    chosen = np.empty(n_trials, dtype=int)
    for i in range(n_trials):
        others = np.delete(table, i, axis=1).mean(axis=1)
        chosen[i] = int(np.argmin(others))
        held_out[i] = table[chosen[i], i]
    means = table.mean(axis=1)
    best = int(np.argmin(means))
    return CvResult(held_out, chosen, best, float(means[best]))


def kfold_splits(n: int, k: int) -> list[tuple[list[int], list[int]]]:
    """``k`` folds of ``range(n)``: ``(train, test)`` index lists, every index in exactly one
    ``test``. Runs are dealt round-robin (fold ``i`` tests ``i, i + k, ...``), so folds
    differ in size by at most one and neighbouring runs (often alike) fall in different
    folds; ``k == n`` is leave-one-out.

    Raises:
        ValueError: ``k`` < 2 or ``k`` > ``n``.
    """
    if not 2 <= k <= n:
        raise ValueError(f"k-fold cross-validation needs 2 <= k <= runs; got k = {k} for "
                         f"{n} run{'s' if n != 1 else ''}")
    folds = []
    for i in range(k):
        test = list(range(i, n, k))
        folds.append(([j for j in range(n) if j % k != i], test))
    return folds
