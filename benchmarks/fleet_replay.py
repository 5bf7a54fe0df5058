"""Logs per second of a folder replay: serial, ``--jobs 2``, and a local Dask cluster of 2
workers; and the engines' per-task overhead.

A folder of synthetic logs (``--logs`` of ``--duration`` s each: 100 Hz IMU, 25 Hz wheel
frames, truth) is replayed to fused CSVs three ways, each on the same list:

1. serial: :func:`fusion.jobs.replay.replay_logs` with one worker (this process);
2. ``--jobs 2``: the same function with a pool of 2 processes (pool start-up included, as a
   user pays it);
3. ``--cluster local:2``: :func:`fusion.jobs.cluster.replay_logs_cluster` on a local cluster of
   2 one-thread workers; its start-up (processes, imports, warm-up of the compiled cores) is
   printed apart, since a long-running cluster pays it once.

The outputs of 2 and 3 are checked byte for byte against 1. The per-task overhead is the
wall time per trivial task (``float(i)``) pushed through each engine's :func:`run_tasks`,
which is what batching small logs into one task (:func:`fusion.jobs.cluster.plan_batches`)
amortises. Wall-clock figures: other load on the machine slows all three (the script prints
the load average); the ratios to serial are the figures to compare.

Usage: python benchmarks/fleet_replay.py [--logs 24] [--duration 60]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def make_logs(root: Path, n: int, duration: float) -> list[Path]:
    from fusion.evaluation.synthetic import degraded_mission
    from fusion.io.logdir import write_synthetic_run

    return [write_synthetic_run(root / f"log{i:03d}", degraded_mission(seed=i,
                                                                       duration=duration))
            for i in range(n)]


def task_overhead(n: int, **engine) -> float:
    """Wall seconds per trivial task through :func:`run_tasks` with ``engine``."""
    from fusion.jobs.engine import run_tasks

    list(run_tasks(float, range(8), **engine))  # start-up (a pool's processes) not counted
    t0 = time.perf_counter()
    assert sum(1 for _ in run_tasks(float, range(n), **engine)) == n
    return (time.perf_counter() - t0) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", type=int, default=24, help="number of logs (default 24)")
    parser.add_argument("--duration", type=float, default=60.0,
                        help="seconds of each log (default 60)")
    args = parser.parse_args()

    from fusion.jobs.cluster import (
        dask_client,
        parse_cluster,
        replay_logs_cluster,
        warm_up_filters,
    )
    from fusion.jobs.replay import LogJob, replay_logs

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        logs = make_logs(root / "logs", args.logs, args.duration)
        size = sum(f.stat().st_size for p in logs for f in p.iterdir()) / len(logs)
        print(f"{len(logs)} logs of {args.duration:g} s ({size / 1e6:.2f} MB each); load "
              f"average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")

        def jobs(name: str) -> list[LogJob]:
            (root / name).mkdir()
            return [LogJob(str(p), str(root / name / f"{p.name}.csv")) for p in logs]

        def same_as_serial(name: str) -> bool:
            return all((root / name / f"{p.name}.csv").read_bytes()
                       == (root / "serial" / f"{p.name}.csv").read_bytes() for p in logs)

        warm_up_filters()
        t0 = time.perf_counter()
        replay_logs(jobs("serial"), 1)
        serial = time.perf_counter() - t0
        rates = {"serial (this process)": len(logs) / serial}

        t0 = time.perf_counter()
        replay_logs(jobs("pool"), 2)
        rates["--jobs 2 (process pool)"] = len(logs) / (time.perf_counter() - t0)
        pool_same = same_as_serial("pool")

        t0 = time.perf_counter()
        with dask_client(parse_cluster("local:2")) as client:
            startup = time.perf_counter() - t0
            t0 = time.perf_counter()
            replay_logs_cluster(jobs("dask"), client)
            rates["--cluster local:2 (Dask)"] = len(logs) / (time.perf_counter() - t0)
            dask_overhead = task_overhead(200, client=client)
        dask_same = same_as_serial("dask")
        pool_overhead = task_overhead(200, jobs=2)

    print(f"{'engine':<28} {'logs/s':>8} {'x serial':>9}")
    for name, rate in rates.items():
        print(f"{name:<28} {rate:>8.2f} {rate / rates['serial (this process)']:>9.2f}")
    print(f"local cluster start-up (2 workers, warm-up included): {startup:.1f} s, once")
    print(f"per-task overhead: process pool {pool_overhead * 1e3:.2f} ms, Dask "
          f"{dask_overhead * 1e3:.2f} ms (one log replays in "
          f"{serial / len(logs) * 1e3:.0f} ms serially)")
    print(f"outputs byte-identical to serial: --jobs 2 {pool_same}, Dask {dask_same}")


if __name__ == "__main__":
    main()
