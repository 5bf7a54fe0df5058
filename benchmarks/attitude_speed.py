"""Attitude filter speed: samples/s of Keel and Mahony (batch and streaming) beside vqf,
imufusion and ahrs, all in one run on the same data, with ratios.

Batch: ``Keel.update_batch`` and ``Mahony.update_batch`` beside vqf's ``VQF.updateBatch`` (C++)
and ``BasicVQF.updateBatch`` (C++, no bias estimation or magnetic rejection), ``offlineVQF``
and ahrs. Streaming (one call per sample, the quaternion read back): ``Keel.update`` beside
``VQF.update`` and imufusion's ``Ahrs.update_no_magnetometer``. Then the split of one
streaming call: our Python wrapper, numba's call boundary (an empty compiled function of the
same signature) and the filter step itself.

Run: python benchmarks/attitude_speed.py [--seconds S]   (needs the `bench` and `fast` extras)
Peers that are not installed are reported as missing, not skipped silently.
"""

from __future__ import annotations

import argparse
import importlib.util

import numpy as np
from _timing import cpu_rate  # benchmarks/_timing.py (scripts run from benchmarks/)

from fusion._jit import HAVE_NUMBA, compiled_entry_point, njit
from fusion.attitude import keel as keel_module
from fusion.attitude.keel import Keel
from fusion.attitude.mahony import Mahony

DT = 0.01


def data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    gyro = rng.normal(0.0, 0.3, (n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.3, (n, 3))
    return gyro, accel


def batch_calls(gyro, accel):
    n = len(gyro)

    def keel():
        Keel(sample_period=DT).update_batch(gyro, accel)
        return n

    def mahony():
        Mahony(sample_period=DT).update_batch(gyro, accel)
        return n

    calls = {"diffbot-fusion Keel.update_batch": keel,
             "diffbot-fusion Mahony.update_batch": mahony}
    if importlib.util.find_spec("vqf"):
        from vqf import VQF, BasicVQF, offlineVQF

        def vqf_batch():
            VQF(DT).updateBatch(gyro, accel)
            return n

        def basic_batch():
            BasicVQF(DT).updateBatch(gyro, accel)
            return n

        def vqf_offline():
            offlineVQF(gyro, accel, None, DT)
            return n

        calls["vqf VQF.updateBatch"] = vqf_batch
        calls["vqf BasicVQF.updateBatch"] = basic_batch
        calls["vqf offlineVQF"] = vqf_offline
    if importlib.util.find_spec("ahrs"):
        from ahrs.filters import Mahony as AhrsMahony

        def ahrs_batch():
            AhrsMahony(gyr=gyro[: n // 50], acc=accel[: n // 50], frequency=1 / DT)
            return n // 50

        calls["ahrs Mahony(gyr=, acc=)"] = ahrs_batch
    return calls


def streaming_loops(gyro, accel):
    n = len(gyro)
    rows = list(zip(gyro, accel))

    def keel():
        f = Keel(sample_period=DT)
        for g, a in rows:
            f.update(g, a)
        return n

    def keel_timestamps():
        f = Keel()
        t = 0.0
        for g, a in rows:
            t += DT
            f.update(g, a, timestamp=t)
        return n

    def mahony():
        f = Mahony(sample_period=DT)
        for g, a in rows:
            f.update(g, a)
        return n

    loops = {"diffbot-fusion Keel.update": keel,
             "diffbot-fusion Keel.update(timestamp=)": keel_timestamps,
             "diffbot-fusion Mahony.update": mahony}
    if importlib.util.find_spec("vqf"):
        from vqf import VQF

        def vqf_loop():
            v = VQF(DT)
            for g, a in rows:
                v.update(g, a)
                v.getQuat6D()
            return n

        loops["vqf VQF.update + getQuat6D"] = vqf_loop
    if importlib.util.find_spec("imufusion"):
        import imufusion

        rows_deg = list(zip(np.degrees(gyro), accel / 9.81))  # deg/s and g, converted before

        def imufusion_loop():
            ahrs = imufusion.Ahrs()
            ahrs.set_sample_period(DT)
            for g, a in rows_deg:
                ahrs.update_no_magnetometer(g, a)
                ahrs.get_quaternion()
            return n

        loops["imufusion update + get_quaternion"] = imufusion_loop
    return loops


@njit
def _empty(B, g, a, dt):
    """Same signature as Keel's streaming entry point, no work: the call boundary alone."""
    return None


def call_split(gyro, accel, seconds: float) -> None:
    """Split one streaming call: wrapper, numba call boundary, filter step."""
    n = len(gyro)
    rows = list(zip(gyro, accel))
    f = Keel(sample_period=DT)
    f.update(gyro[0], accel[0])
    fast6, _ = keel_module._entry_points()
    empty = compiled_entry_point(_empty, 2)
    B = f._B

    def whole():
        for g, a in rows:
            f.update(g, a)
        return n

    def entry():
        for g, a in rows:
            fast6(B, g, a, DT)
        return n

    def boundary():
        for g, a in rows:
            empty(B, g, a, DT)
        return n

    def loop_only():
        for _g, _a in rows:
            pass
        return n

    rates = {name: cpu_rate(fn, seconds) for name, fn in
             (("whole", whole), ("entry", entry), ("boundary", boundary), ("loop", loop_only))}
    ns = {k: 1e9 / v for k, v in rates.items()}
    print("\nsplit of one Keel.update call (ns per sample, CPU time):")
    print(f"  whole call                        {ns['whole'] - ns['loop']:7.0f}")
    print(f"  Python wrapper (checks, copy)     {ns['whole'] - ns['entry']:7.0f}")
    print(f"  numba call boundary (empty fn)    {ns['boundary'] - ns['loop']:7.0f}")
    print(f"  filter step (entry - boundary)    {ns['entry'] - ns['boundary']:7.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=3.0, help="time per measurement")
    args = parser.parse_args()
    print(f"numba: {'yes' if HAVE_NUMBA else 'NO (interpreted core)'}")
    for peer in ("imufusion", "vqf", "ahrs"):
        if not importlib.util.find_spec(peer):
            print(f"{peer}: not installed (pip install 'diffbot-fusion[bench]')")
    tables = (("batch over arrays (1 M samples, 6-axis)", batch_calls(*data(1_000_000))),
              ("streaming, one call per sample (6-axis)", streaming_loops(*data(20_000))))
    for title, table in tables:
        print(f"\n{title}:")
        results = {name: cpu_rate(fn, args.seconds) for name, fn in table.items()}
        ours = next(iter(results.values()))
        for name, r in results.items():
            print(f"  {name:42s} {r / 1e6:8.3f} M samples/s   Keel/this = {ours / r:6.2f}")
    call_split(*data(20_000), args.seconds)


if __name__ == "__main__":
    main()
