"""EKF speed: input events per second of the fused-odometry EKF, beside a plain filterpy EKF
driven by the same model.

Run: python benchmarks/ekf_speed.py [--seconds S]   (numba from the `fast` extra for the core)

Rows (same events: a 60 s degraded mission, gyro 100 Hz + wheel frames 25 Hz, ZUPTs, slips):
- ``PlanarEKF.process_batch``: the compiled loop over the compiled step (numba).
- ``PlanarEKF.update_*`` streaming: one Python call per event into the same compiled step.
- the same step run interpreted (what runs when numba is absent, or with
  ``FUSION_DISABLE_JIT=1``), in a child process;
- filterpy's own ``ExtendedKalmanFilter`` (numpy NX x NX matrices, ``inv(S)``) driven by
  fusion.planar.model's functions and the same filter logic: tests/filterpy_reference.py,
  the reference of tests/test_ekf.py (equal to the core to 1e-11).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from _timing import cpu_rate  # benchmarks/_timing.py (scripts run from benchmarks/)

from fusion._jit import HAVE_NUMBA
from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import PlanarEKF, merge_events

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from filterpy_reference import FilterpyReference  # tests/filterpy_reference.py


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="time per contender (CPU)")
    ap.add_argument("--interpreted-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()

    run = degraded_mission(seed=0, duration=60.0)
    kinds, t_eff, a, b, stamp = merge_events(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                                             EXAMPLE_ROBOT.encode_sampling_time)
    n = kinds.size
    events = list(zip(kinds.tolist(), stamp.tolist(), a.tolist(), b.tolist(), strict=True))

    def batch() -> int:
        PlanarEKF(EXAMPLE_ROBOT).process_batch(kinds, t_eff, a, b)
        return n

    def streaming() -> int:
        f = PlanarEKF(EXAMPLE_ROBOT)
        gyro, wheels = f.update_gyro, f.update_wheels
        for k, t, x, y in events:
            if k == core.EV_GYRO:
                gyro(t, x)
            else:
                wheels(t, int(x), int(y))
        return n

    m = 1500  # filterpy is slow: a prefix of the same events

    def filterpy() -> int:
        start = PlanarEKF(EXAMPLE_ROBOT)
        f = FilterpyReference(EXAMPLE_ROBOT, start.noise, start.x, start.P)
        for k in range(m):
            f.step(int(kinds[k]), t_eff[k], a[k], b[k])
        return m

    if args.interpreted_child:
        print(cpu_rate(batch, args.seconds))
        return
    env = dict(os.environ, FUSION_DISABLE_JIT="1")
    child = subprocess.run([sys.executable, __file__, "--interpreted-child", "--seconds",
                            str(args.seconds)], env=env, capture_output=True, text=True,
                           check=True)
    rows = [
        ("PlanarEKF.process_batch (compiled loop)", cpu_rate(batch, args.seconds)),
        ("PlanarEKF.update_gyro/update_wheels (streaming)", cpu_rate(streaming, args.seconds)),
        ("same core interpreted (no numba)",
         float(child.stdout.strip().splitlines()[-1])),
        ("filterpy ExtendedKalmanFilter, same model", cpu_rate(filterpy, args.seconds)),
    ]
    ref = rows[-1][1]
    print(f"EKF events per CPU second ({n} events: 100 Hz gyro + 25 Hz wheels; numba "
          f"{'on' if HAVE_NUMBA else 'OFF: interpreted core'})")
    for name, r in rows:
        print(f"  {name:52s} {r:12,.0f} /s   x{r / ref:7.1f} vs filterpy")
    target = 100_000
    best = max(r for _, r in rows[:2])
    print(f"target >= {target:,} events/s on one core: "
          f"{'met' if best >= target else 'NOT met'} ({best:,.0f}/s)")


if __name__ == "__main__":
    main()
