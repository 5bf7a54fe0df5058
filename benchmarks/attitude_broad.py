"""Attitude accuracy on the bundled BROAD trials: Keel and Mahony beside vqf, imufusion and ahrs.

Prints per trial and on average, all run in this process on the same data:
- 6-axis (gyro + accelerometer) inclination RMSE: heading is unobservable without a
  magnetometer, so inclination is the fair comparison;
- 9-axis total RMSE with no heading alignment (as the BROAD paper scores): every filter's
  heading is taken as it comes, in ENU (imufusion is set to its ENU convention).

Keel's figures are cross-validated (CV): each trial is scored with parameters chosen on the
other nine by ``tune_keel.py`` (leave one trial out). Keel with its shipped defaults, which are
the parameters best on all ten, is shown too, labelled in-sample; so are Mahony's defaults
(tuned on these trials: in-sample). Each peer runs with its own defaults: ``vqf VQF`` is the
causal (online) filter, ``vqf offlineVQF`` its non-causal mode for recorded data. All return
scalar-first quaternions body -> world with z up.
Also checks our 9-axis Mahony against the dataset's published Mahony numbers.

Run: python benchmarks/attitude_broad.py [--skip-ahrs] [--no-cv]   (needs the `bench` extra;
the CV takes about two minutes, ahrs (pure Python) about three)
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import numpy as np
from tune_keel import cross_validate  # benchmarks/tune_keel.py (scripts run from benchmarks/)

from fusion.attitude.keel import Keel
from fusion.attitude.keel_offline import keel_offline
from fusion.attitude.mahony import PRESETS, Mahony
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad
from fusion.types.constants import STANDARD_GRAVITY as GRAVITY

DATA = Path(__file__).resolve().parent.parent / "datasets" / "broad"


def keel(tr, mag):
    return Keel(axes=9 if mag else 6).update_batch(tr.gyro, tr.accel, tr.mag if mag else None,
                                                  dt=1 / tr.rate)


def keel_off(tr, mag):
    return keel_offline(tr.gyro, tr.accel, tr.mag if mag else None, dt=1 / tr.rate,
                        axes=9 if mag else 6)


def mahony(tr, mag):
    f = Mahony(axes=9 if mag else 6, sample_period=1 / tr.rate)
    return f.update_batch(tr.gyro, tr.accel, tr.mag if mag else None)


def vqf_online(tr, mag):
    from vqf import VQF

    v = VQF(1 / tr.rate)
    m = np.ascontiguousarray(tr.mag) if mag else None
    out = v.updateBatch(np.ascontiguousarray(tr.gyro), np.ascontiguousarray(tr.accel), m)
    return out["quat9D" if mag else "quat6D"]


def vqf_offline(tr, mag):
    from vqf import offlineVQF

    m = np.ascontiguousarray(tr.mag) if mag else None
    out = offlineVQF(np.ascontiguousarray(tr.gyro), np.ascontiguousarray(tr.accel), m,
                     1 / tr.rate)
    return out["quat9D" if mag else "quat6D"]


def imufusion_ahrs(tr, mag):
    import imufusion

    ahrs = imufusion.Ahrs()
    settings = imufusion.AhrsSettings()
    settings.convention = imufusion.CONVENTION_ENU
    ahrs.set_settings(settings)
    ahrs.set_sample_period(1 / tr.rate)
    gyro_dps, acc_g = np.degrees(tr.gyro), tr.accel / GRAVITY
    out = np.empty((len(tr), 4))
    for i in range(len(tr)):
        if mag:
            ahrs.update(gyro_dps[i], acc_g[i], tr.mag[i])
        else:
            ahrs.update_no_magnetometer(gyro_dps[i], acc_g[i])
        out[i] = ahrs.get_quaternion()  # [w, x, y, z]
    return out


def ahrs_mahony(tr, mag):
    from ahrs.filters import Mahony as AhrsMahony

    if mag:
        return AhrsMahony(gyr=tr.gyro, acc=tr.accel, mag=tr.mag, frequency=tr.rate).Q
    return AhrsMahony(gyr=tr.gyro, acc=tr.accel, frequency=tr.rate).Q


def print_table(title, columns: dict[str, list[float]], names) -> None:
    width = max(16, *(len(c) + 2 for c in columns))
    print(f"\n{title}")
    print(f"{'trial':46s}" + "".join(f"{c:>{width}s}" for c in columns))
    for i, name in enumerate(names):
        print(f"{name:46s}" + "".join(f"{v[i]:{width}.3f}" for v in columns.values()))
    print(f"{'mean':46s}" + "".join(f"{np.mean(v):{width}.3f}" for v in columns.values()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--skip-ahrs", action="store_true", help="skip the slow ahrs runs")
    parser.add_argument("--no-cv", action="store_true",
                        help="skip the cross-validation (Keel's in-sample figures only)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    trials = [read_broad(p) for p in sorted(DATA.glob("*.mat"))]
    names = [tr.name for tr in trials]

    cv = None if args.no_cv else cross_validate(trials, log=lambda s: None)
    filters = {"Keel (in-sample)": keel, "Keel offline (in-s.)": keel_off,
               "Mahony defaults (in-s.)": mahony}
    peers = {"vqf VQF (online)": ("vqf", vqf_online), "vqf offlineVQF": ("vqf", vqf_offline),
             "imufusion": ("imufusion", imufusion_ahrs), "ahrs Mahony": ("ahrs", ahrs_mahony)}
    for label, (module, fn) in peers.items():
        if module == "ahrs" and args.skip_ahrs:
            continue
        if importlib.util.find_spec(module) is None:
            print(f"{module}: not installed (pip install 'diffbot-fusion[bench]')")
            continue
        filters[label] = fn

    for mag in (False, True):
        columns = {}
        if cv is not None:
            key = "online9" if mag else "online6"
            columns["Keel (CV)"] = list(cv[key].held_out)
            if not mag:
                columns["Keel offline (CV)"] = list(cv["offline6"].held_out)
        for label, fn in filters.items():
            errs = []
            for tr in trials:
                e = orientation_rmse(fn(tr, mag), tr.quat_ref, tr.movement)
                errs.append(e.total_deg if mag else e.inclination_deg)
            columns[label] = errs
        title = ("9-axis total RMSE, deg, no heading alignment (lower is better)" if mag
                 else "6-axis inclination RMSE, deg (lower is better)")
        print_table(title, columns, names)
        ref = "Keel (CV)" if cv is not None else "Keel (in-sample)"
        width = max(16, *(len(c) + 2 for c in columns))
        print(f"{'ratio to ' + ref:46s}" + "".join(
            f"{np.mean(v) / np.mean(columns[ref]):{width}.2f}" for v in columns.values()))
    print("\nMahony 9-axis preset: Kp {kp}, Ki {ki} (the BROAD authors' trial-agnostic gains); "
          "Mahony 6-axis defaults were tuned on these trials.".format(**PRESETS[9]))

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
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
