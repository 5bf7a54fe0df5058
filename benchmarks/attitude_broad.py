"""Attitude accuracy on the bundled BROAD trials: our Mahony beside imufusion, vqf and ahrs.

Prints the inclination RMSE (deg) per trial and the mean, for 6-axis filters (gyro +
accelerometer), all run in this process on the same data. Inclination is the fair comparison
for 6-axis filters: heading is unobservable without a magnetometer. Each peer runs with its own
defaults. All four return scalar-first quaternions body -> world with z up (checked on a static
tilted input), so no frame conversion is needed for inclination.
Also prints our 9-axis filter against the dataset's published Mahony numbers.

Run: python benchmarks/attitude_broad.py [--skip-ahrs]   (needs the `bench` extra; ahrs is
pure Python and takes about two minutes over the ten trials)
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np

from fusion.attitude.mahony import Mahony
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad
from fusion.types.constants import STANDARD_GRAVITY as GRAVITY

DATA = Path(__file__).resolve().parent.parent / "datasets" / "broad"


def ours(tr):
    return Mahony(sample_period=1 / tr.rate).update_batch(tr.gyro, tr.accel)


def ours_plain(tr):
    return Mahony(sample_period=1 / tr.rate, rest_detection=False).update_batch(tr.gyro, tr.accel)


def imufusion_6(tr):
    import imufusion

    ahrs = imufusion.Ahrs()
    ahrs.set_sample_period(1 / tr.rate)
    gyro_dps, acc_g = np.degrees(tr.gyro), tr.accel / GRAVITY
    out = np.empty((len(tr), 4))
    for i in range(len(tr)):
        ahrs.update_no_magnetometer(gyro_dps[i], acc_g[i])
        out[i] = ahrs.get_quaternion()  # [w, x, y, z]
    return out


def vqf_6(tr):
    from vqf import offlineVQF

    return offlineVQF(tr.gyro, tr.accel, None, 1 / tr.rate)["quat6D"]


def ahrs_6(tr):
    from ahrs.filters import Mahony as AhrsMahony

    return AhrsMahony(gyr=tr.gyro, acc=tr.accel, frequency=tr.rate).Q


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--skip-ahrs", action="store_true", help="skip the slow ahrs run")
    args = parser.parse_args()
    trials = [read_broad(p) for p in sorted(DATA.glob("*.mat"))]
    filters = {"ours (defaults)": ours, "ours (no rest det.)": ours_plain}
    peers = {"imufusion": imufusion_6, "vqf": vqf_6, "ahrs": ahrs_6}
    for name, fn in peers.items():
        if name == "ahrs" and args.skip_ahrs:
            continue
        if importlib.util.find_spec(name) is None:
            print(f"{name}: not installed (pip install 'diffbot-fusion[bench]')")
            continue
        filters[name] = fn

    print("6-axis inclination RMSE, deg (BROAD; lower is better)")
    print(f"{'trial':40s}" + "".join(f"{n:>21s}" for n in filters))
    table = {n: [] for n in filters}
    for tr in trials:
        row = f"{tr.name:40s}"
        for name, fn in filters.items():
            e = orientation_rmse(fn(tr), tr.quat_ref, tr.movement).inclination_deg
            table[name].append(e)
            row += f"{e:21.3f}"
        print(row, flush=True)
    print(f"{'mean':40s}" + "".join(f"{np.mean(v):21.3f}" for v in table.values()))
    base = np.mean(table["ours (defaults)"])
    print(f"{'ratio peer/ours':40s}" + "".join(f"{np.mean(v) / base:21.2f}"
                                              for v in table.values()))

    published = json.loads((DATA / "published_mahony_average_rmse.json").read_text())
    print("\n9-axis Mahony (Kp 0.74, Ki 0.0012, dataset's initial state) vs published total RMSE")
    worst = 0.0
    for tr in trials:
        f = Mahony(0.74, 0.0012, axes=9, sample_period=1 / tr.rate,
                   initial_quaternion=tr.reference_initial_quaternion())
        got = orientation_rmse(f.update_batch(tr.gyro, tr.accel, tr.mag), tr.quat_ref,
                               tr.movement).total_deg
        want = published["trials"][tr.name]["tagp_parameters"]["total_rmse_deg"]
        worst = max(worst, abs(got - want))
        print(f"  {tr.name:40s} ours {got:8.4f}  published {want:8.4f}  diff {got - want:+.5f}")
    print(f"  largest difference {worst:.5f} deg")


if __name__ == "__main__":
    main()
