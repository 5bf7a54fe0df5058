"""Grid search of the 6-axis Mahony gains on the bundled BROAD trials (inclination RMSE).

The defaults in fusion/mahony.py (DEFAULT_KP, DEFAULT_KI) and the recommended options come from
this script. Run: python benchmarks/tune_mahony6.py [--fine]
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np

from fusion.attitude.mahony import Mahony
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad

DATA = Path(__file__).resolve().parent.parent / "datasets" / "broad"


def mean_inclination(trials, **settings) -> float:
    errs = []
    for tr in trials:
        f = Mahony(axes=6, sample_period=1 / tr.rate, **settings)
        q = f.update_batch(tr.gyro, tr.accel)
        errs.append(orientation_rmse(q, tr.quat_ref, tr.movement).inclination_deg)
    return float(np.mean(errs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--fine", action="store_true", help="finer grid (slower)")
    args = parser.parse_args()
    trials = [read_broad(p) for p in sorted(DATA.glob("*.mat"))]
    kps = [0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0]
    kis = [0.0, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02]
    if args.fine:
        kps = list(np.round(np.arange(0.1, 1.01, 0.05), 3))
        kis = [0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006]
    variants = {
        "plain": {},
        "rest": {"rest_detection": True},
        "rest+rej2": {"rest_detection": True, "accel_rejection": 2.0},
        "rest+rej4": {"rest_detection": True, "accel_rejection": 4.0},
    }
    for vname, opts in variants.items():
        best = (np.inf, None)
        for kp, ki in itertools.product(kps, kis):
            e = mean_inclination(trials, kp=kp, ki=ki, **opts)
            if e < best[0]:
                best = (e, (kp, ki))
        print(f"{vname:12s} best mean inclination RMSE {best[0]:.3f} deg at Kp, Ki = {best[1]}")


if __name__ == "__main__":
    main()
