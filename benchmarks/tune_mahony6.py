"""Grid search of the 6-axis Mahony gains on the bundled BROAD trials (inclination RMSE), with
leave-one-trial-out cross-validation.

The defaults in fusion/attitude/mahony.py (DEFAULT_KP, DEFAULT_KI, rest detection on) were
chosen by this grid on all ten trials, so their mean over those trials is an in-sample figure.
For each variant this script prints the in-sample best and the cross-validated (CV) figure:
each trial scored with the gains chosen on the other nine. The defaults are left as they are
(changing them would change the golden pipeline replay); the CV figure is the honest estimate
of what they give on trials they were not tuned on.
Run: python benchmarks/tune_mahony6.py [--fine]   (about a minute; --fine several)
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np

from fusion.attitude.mahony import DEFAULT_KI, DEFAULT_KP, Mahony
from fusion.evaluation.crossval import leave_one_out
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad

DATA = Path(__file__).resolve().parent.parent / "datasets" / "broad"


def inclinations(trials, **settings) -> np.ndarray:
    errs = []
    for tr in trials:
        f = Mahony(axes=6, sample_period=1 / tr.rate, **settings)
        q = f.update_batch(tr.gyro, tr.accel)
        errs.append(orientation_rmse(q, tr.quat_ref, tr.movement).inclination_deg)
    return np.array(errs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--fine", action="store_true", help="finer grid (slower)")
    args = parser.parse_args()
    trials = [read_broad(p) for p in sorted(DATA.glob("*.mat"))]
    kps = [0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0]
    kis = [0.0, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02]
    if args.fine:
        kps = list(np.round(np.arange(0.05, 1.01, 0.05), 3))
        kis = [0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006]
    variants = {
        "plain": {"rest_detection": False},
        "rest": {"rest_detection": True},
        "rest+rej2": {"rest_detection": True, "accel_rejection": 2.0},
        "rest+rej4": {"rest_detection": True, "accel_rejection": 4.0},
    }
    grid = list(itertools.product(kps, kis))
    print("mean 6-axis inclination RMSE over the bundled trials, deg")
    for vname, opts in variants.items():
        table = np.array([inclinations(trials, kp=kp, ki=ki, **opts) for kp, ki in grid])
        cv = leave_one_out(table)
        print(f"{vname:10s} in-sample best {cv.in_sample:.3f} at Kp, Ki = {grid[cv.best]} "
              f"(in-sample);  CV {cv.cv_mean:.3f}  (folds chose "
              f"{sorted({grid[j] for j in cv.chosen})})")
    defaults = inclinations(trials)
    print(f"defaults (Kp {DEFAULT_KP}, Ki {DEFAULT_KI}, rest detection): "
          f"{defaults.mean():.3f} (in-sample: chosen on these trials)")


if __name__ == "__main__":
    main()
