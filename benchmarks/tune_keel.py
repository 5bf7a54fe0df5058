"""Choose Keel's parameters by leave-one-trial-out cross-validation on the bundled BROAD trials.

Each configuration of a small grid runs once on every trial (per-trial error table); for each
trial the configuration best on the other nine is chosen and scored on the held-out trial. The
mean of those held-out scores is the cross-validated (CV) figure; the configuration best on all
ten becomes the default, and its mean over the ten is printed too, labelled in-sample.

Three stages, each nested inside the folds of the previous one (the 9-axis and offline stages
run with the 6-axis parameters chosen without the held-out trial):
1. 6-axis online: accelerometer time constant, motion and rest bias sigmas, bias drift;
   scored by inclination RMSE.
2. 6-axis offline: the zero-phase time constant and the motion bias sigma of the two bias
   passes; inclination RMSE.
3. 9-axis online: heading time constant and field norm tolerance; total RMSE (no heading
   alignment, as the BROAD paper scores).

Run: python benchmarks/tune_keel.py   (about three minutes on one core)
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fusion.attitude.keel import Keel, KeelParams
from fusion.attitude.keel_offline import keel_offline
from fusion.evaluation.crossval import leave_one_out
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad

DATA = Path(__file__).resolve().parent.parent / "datasets" / "broad"
DEG = math.pi / 180

GRID_6 = {
    "accel_time_constant": [2.0, 2.5, 3.0, 4.0],
    "motion_bias_sigma": [0.02 * DEG, 0.035 * DEG, 0.05 * DEG, 0.1 * DEG],
    "rest_bias_sigma": [0.001 * DEG, 0.003 * DEG, 0.01 * DEG],
    "bias_drift": [0.05 * DEG, 0.1 * DEG, 0.2 * DEG],
}
GRID_OFFLINE = {
    "offline_accel_time_constant": [3.0, 4.0],
    "offline_motion_bias_sigma": [0.05 * DEG, 0.2 * DEG, 1.0 * DEG],
}
GRID_9 = {
    "mag_time_constant": [5.0, 9.0, 15.0, 25.0],
    "mag_norm_tolerance": [0.05, 0.1, 0.2],
}


def configs(grid: dict) -> list[dict]:
    keys = list(grid)
    return [dict(zip(keys, values)) for values in itertools.product(*grid.values())]


def online_error(tr, params: KeelParams, axes: int) -> float:
    f = Keel(axes=axes, params=params)
    q = f.update_batch(tr.gyro, tr.accel, tr.mag if axes == 9 else None, dt=1 / tr.rate)
    e = orientation_rmse(q, tr.quat_ref, tr.movement)
    return e.inclination_deg if axes == 6 else e.total_deg


def offline_error(tr, params: KeelParams) -> float:
    q = keel_offline(tr.gyro, tr.accel, dt=1 / tr.rate, params=params)
    return orientation_rmse(q, tr.quat_ref, tr.movement).inclination_deg


def table(trials, base: KeelParams, grid: list[dict], score) -> np.ndarray:
    return np.array([[score(tr, KeelParams(**{**vars(base), **c})) for tr in trials]
                     for c in grid])


def nested_stage(trials, grid6, chosen6, grid, score):
    """CV of a stage whose base parameters are the 6-axis ones chosen in each fold."""
    tables = {}
    for j in sorted(set(chosen6)):
        tables[j] = table(trials, KeelParams(**grid6[j]), grid, score)
    held_out = []
    for i, j in enumerate(chosen6):
        others = np.delete(tables[j], i, axis=1).mean(axis=1)
        held_out.append(tables[j][int(np.argmin(others)), i])
    return np.array(held_out), tables


def show(values: dict) -> str:
    return ", ".join(f"{k} {v / DEG:g} deg/s" if "sigma" in k or "drift" in k else f"{k} {v:g}"
                     for k, v in values.items())


@dataclass
class StageResult:
    """One stage: held-out errors per trial (CV), and the per-trial errors of the
    configuration best on all trials (in-sample), with that configuration."""

    held_out: np.ndarray
    in_sample: np.ndarray
    chosen: dict


def cross_validate(trials, log=print) -> dict[str, StageResult]:
    """Run the three nested stages; returns ``online6``, ``offline6`` and ``online9``."""
    t0 = time.perf_counter()
    grid6 = configs(GRID_6)
    t6 = table(trials, KeelParams(), grid6, lambda tr, p: online_error(tr, p, 6))
    cv6 = leave_one_out(t6)
    out = {"online6": StageResult(cv6.held_out, t6[cv6.best], grid6[cv6.best])}
    log(f"6-axis online: {len(grid6)} configurations x {len(trials)} trials, folds chose "
        f"{len(set(cv6.chosen))} distinct ({time.perf_counter() - t0:.0f} s)")
    stages = (("offline6", configs(GRID_OFFLINE), offline_error),
              ("online9", configs(GRID_9), lambda tr, p: online_error(tr, p, 9)))
    for name, grid, score in stages:
        held, tabs = nested_stage(trials, grid6, cv6.chosen, grid, score)
        if cv6.best not in tabs:
            tabs[cv6.best] = table(trials, KeelParams(**grid6[cv6.best]), grid, score)
        best = int(np.argmin(tabs[cv6.best].mean(axis=1)))
        out[name] = StageResult(held, tabs[cv6.best][best], {**grid6[cv6.best], **grid[best]})
        log(f"{name}: done ({time.perf_counter() - t0:.0f} s)")
    return out


def main() -> None:
    t0 = time.perf_counter()
    trials = [read_broad(p) for p in sorted(DATA.glob("*.mat"))]
    names = [tr.name[:2] for tr in trials]
    results = cross_validate(trials)
    titles = {"online6": "6-axis online, inclination", "offline6": "6-axis offline, inclination",
              "online9": "9-axis online, total (no heading alignment)"}
    for name, r in results.items():
        print(f"\n{titles[name]} RMSE, deg")
        print("  held out: " + " ".join(f"{n}:{e:.3f}" for n, e in zip(names, r.held_out)))
        print(f"  CV mean {r.held_out.mean():.3f};  best on all trials {r.in_sample.mean():.3f} "
              f"(in-sample)")
        print(f"  chosen on all trials: {show(r.chosen)}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
