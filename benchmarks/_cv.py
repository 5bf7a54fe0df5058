"""Leave-one-trial-out cross-validation over a precomputed table of per-trial errors.

Shared by the tuning scripts (run them as ``python benchmarks/NAME.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CvResult", "leave_one_out"]


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
