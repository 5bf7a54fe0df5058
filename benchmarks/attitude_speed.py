"""Attitude filter speed: samples/s of our Mahony (streaming and batch) beside imufusion, vqf
and ahrs, all in one run on the same data, with ratios.

Run: python benchmarks/attitude_speed.py [--seconds S]   (needs the `bench` and `fast` extras)
Peers that are not installed are reported as missing, not skipped silently.
"""

from __future__ import annotations

import argparse
import importlib.util

import numpy as np
from _timing import cpu_rate  # benchmarks/_timing.py (scripts run from benchmarks/)

from fusion._jit import HAVE_NUMBA
from fusion.attitude.mahony import Mahony

DT = 0.01


def data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    gyro = rng.normal(0.0, 0.3, (n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.3, (n, 3))
    return gyro, accel


def streaming_loops(gyro, accel):
    n = len(gyro)
    rows = list(zip(gyro, accel))

    def ours():
        f = Mahony(sample_period=DT)
        for g, a in rows:
            f.update(g, a)
        return n

    loops = {"diffbot-fusion Mahony.update": ours}
    if importlib.util.find_spec("imufusion"):
        import imufusion

        # imufusion takes deg/s and g; convert before timing so only the filter is measured.
        rows_deg = list(zip(np.degrees(gyro), accel / 9.81))

        def imufusion_ahrs():
            ahrs = imufusion.Ahrs()
            ahrs.set_sample_period(DT)
            return ahrs

        def imufusion_loop():
            ahrs = imufusion_ahrs()
            for g, a in rows_deg:
                ahrs.update_no_magnetometer(g, a)
            return n

        def imufusion_loop_q():
            ahrs = imufusion_ahrs()
            for g, a in rows_deg:
                ahrs.update_no_magnetometer(g, a)
                ahrs.get_quaternion()
            return n

        loops["imufusion Ahrs.update_no_magnetometer"] = imufusion_loop
        loops["imufusion update + read quaternion"] = imufusion_loop_q
    if importlib.util.find_spec("vqf"):
        from vqf import VQF

        def vqf_loop():
            v = VQF(DT)
            for g, a in rows:
                v.update(g, a)
            return n

        loops["vqf VQF.update"] = vqf_loop
    if importlib.util.find_spec("ahrs"):
        from ahrs.filters import Mahony as AhrsMahony

        def ahrs_loop():
            m = AhrsMahony(frequency=1 / DT)
            q = np.array([1.0, 0.0, 0.0, 0.0])
            for g, a in rows[: n // 20]:  # pure Python and slow: a subset
                q = m.updateIMU(q, g, a)
            return n // 20

        loops["ahrs Mahony.updateIMU"] = ahrs_loop
    return loops


def batch_calls(gyro, accel):
    n = len(gyro)

    def ours():
        Mahony(sample_period=DT).update_batch(gyro, accel)
        return n

    calls = {"diffbot-fusion Mahony.update_batch": ours}
    if importlib.util.find_spec("vqf"):
        from vqf import offlineVQF

        def vqf_offline():
            offlineVQF(np.ascontiguousarray(gyro), np.ascontiguousarray(accel), None, DT)
            return n

        calls["vqf offlineVQF"] = vqf_offline
    if importlib.util.find_spec("ahrs"):
        from ahrs.filters import Mahony as AhrsMahony

        def ahrs_batch():
            AhrsMahony(gyr=gyro[: n // 20], acc=accel[: n // 20], frequency=1 / DT)
            return n // 20

        calls["ahrs Mahony(gyr=, acc=)"] = ahrs_batch
    return calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=3.0, help="time per measurement")
    args = parser.parse_args()
    print(f"numba: {'yes' if HAVE_NUMBA else 'NO (interpreted core)'}")
    for peer in ("imufusion", "vqf", "ahrs"):
        if not importlib.util.find_spec(peer):
            print(f"{peer}: not installed (pip install 'diffbot-fusion[bench]')")
    gyro, accel = data(20_000)
    for title, table in (("streaming, one call per sample", streaming_loops(gyro, accel)),
                         ("batch over arrays", batch_calls(*data(1_000_000)))):
        print(f"\n{title}:")
        results = {name: cpu_rate(fn, args.seconds) for name, fn in table.items()}
        ours = next(iter(results.values()))
        for name, r in results.items():
            print(f"  {name:42s} {r / 1e6:8.3f} M samples/s   ours/this = {ours / r:6.2f}")


if __name__ == "__main__":
    main()
