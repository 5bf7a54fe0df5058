"""A folder of logs replayed on a Dask cluster (the ``cluster`` extra: ``dask[distributed]``).

``fusion replay LOGS/ --cluster local:N`` starts a local cluster of N worker processes;
``--cluster tcp://HOST:8786`` (or ``--cluster`` alone with ``DASK_SCHEDULER_ADDRESS`` set)
joins a running one. :func:`dask_client` opens either.

How the work is shared out:

- Tasks are coarse: one log, or a batch of small logs (:func:`plan_batches`), so the
  scheduler's few milliseconds per task are noise.
- Each worker warms the compiled filter cores once, when it joins (:class:`WarmUpPlugin`).
- Workers read the logs by the path the client gives: on a cluster of several machines the
  logs must be on a shared path (the same mount point on every host). Workers write nothing
  where the user sees it: each replays into a private temporary folder and returns the output
  bytes; the client commits every output exactly once, atomically
  (:func:`fusion.io.atomic.atomic_write`). So the outputs need no shared storage, a worker
  lost mid-run (whose tasks Dask runs again elsewhere) leaves no partial or doubled file, and
  the outputs are byte for byte those of the serial replay (the same code on the same input).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fusion.io.atomic import atomic_write
from fusion.jobs.engine import run_tasks
from fusion.jobs.replay import LogJob, run_log_job

__all__ = [
    "BATCH_BYTES",
    "SCHEDULER_ENV",
    "ClusterSpec",
    "LogOutputs",
    "WarmUpPlugin",
    "cluster_threads",
    "dask_client",
    "parse_cluster",
    "plan_batches",
    "replay_batch",
    "replay_logs_cluster",
    "warm_up_filters",
]

#: Logs smaller than this (bytes of their files) are batched into tasks of about this size.
BATCH_BYTES = 4_000_000

#: The environment variable naming an existing scheduler (Dask's own convention).
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"

_INSTALL = "pip install 'diffbot-fusion[cluster]'"

try:
    from distributed.diagnostics.plugin import WorkerPlugin as _WorkerPlugin
except ImportError:  # without the cluster extra: dask_client says what to install
    _WorkerPlugin = object  # type: ignore[assignment,misc]


@dataclass(frozen=True)
class ClusterSpec:
    """Which cluster: ``local`` with ``workers`` processes, or the scheduler at ``address``."""

    address: str | None = None
    workers: int | None = None

    def describe(self) -> str:
        if self.address is None:
            return f"local Dask cluster of {self.workers} worker process" \
                   f"{'es' if self.workers != 1 else ''}"
        return f"Dask cluster at {self.address}"


def parse_cluster(spec: str | None) -> ClusterSpec:
    """``local``, ``local:N``, a scheduler address (``tcp://HOST:8786``, any ``scheme://``), or
    None / ``""`` for the address in ``DASK_SCHEDULER_ADDRESS``.

    Raises:
        ValueError: an unknown form, N < 1, or no address anywhere.
    """
    if not spec:
        address = os.environ.get(SCHEDULER_ENV, "").strip()
        if not address:
            raise ValueError(f"--cluster without an address needs {SCHEDULER_ENV} set (e.g. "
                             f"tcp://HOST:8786), or give --cluster local[:N] or an address")
        return parse_cluster(address)
    if spec == "local":
        return ClusterSpec(workers=os.cpu_count() or 1)
    if spec.startswith("local:"):
        n = spec.partition(":")[2]
        if not n.isdigit() or int(n) < 1:
            raise ValueError(f"--cluster {spec}: local:N needs a worker count N >= 1")
        return ClusterSpec(workers=int(n))
    if "://" in spec and spec.split("://", 1)[1]:
        return ClusterSpec(address=spec)
    raise ValueError(f"--cluster {spec!r}: give local, local:N or a scheduler address such as "
                     "tcp://HOST:8786")


def warm_up_filters() -> None:
    """Load (or compile) the numba cores of the pipeline: a few samples through a
    :class:`~fusion.pipeline.core.FusionPipeline` (a cold cache takes ~15 s, once)."""
    import numpy as np

    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.pipeline.core import FusionPipeline
    from fusion.planar.robot import RobotConfig
    from fusion.types.constants import STANDARD_GRAVITY

    robot = RobotConfig(DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4))
    n = 8
    imu_t = 0.01 * np.arange(1, n + 1)
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, STANDARD_GRAVITY], (n, 1))
    with FusionPipeline(robot, sources=["imu", "wheels"]) as pipe:
        pipe.push_arrays(imu_t, gyro, accel, np.array([0.04, 0.08]),
                         np.array([[0, 0], [10, 12]], dtype=np.int64))


class WarmUpPlugin(_WorkerPlugin):
    """Warms the compiled filters once on every worker, when it starts or joins."""

    name = "fusion-warm-up"

    def setup(self, worker) -> None:
        warm_up_filters()


@contextlib.contextmanager
def dask_client(spec: ClusterSpec, *, connect_timeout: float = 10.0) -> Iterator[Any]:
    """A ``dask.distributed.Client`` on ``spec`` (a local cluster is started and stopped
    here), with :class:`WarmUpPlugin` registered on its workers.

    Raises:
        ValueError: Dask is not installed, the scheduler cannot be reached, or it has no
            worker within ``connect_timeout`` s.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ValueError(f"--cluster needs Dask distributed: {_INSTALL}") from None
    with contextlib.ExitStack() as stack:
        if spec.address is None:
            cluster = stack.enter_context(LocalCluster(
                n_workers=spec.workers, threads_per_worker=1, processes=True,
                # its HTTP server on a free port: never "port 8787 in use" beside another
                dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR))
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(spec.address, timeout=connect_timeout))
            except OSError as exc:
                raise ValueError(f"cannot reach the Dask scheduler at {spec.address}: "
                                 f"{exc}") from None
            try:
                client.wait_for_workers(1, timeout=connect_timeout)
            except TimeoutError:
                raise ValueError(f"the Dask scheduler at {spec.address} has no worker "
                                 f"(waited {connect_timeout:g} s); start some with "
                                 f"`dask worker {spec.address} --nthreads 1`") from None
        client.register_plugin(WarmUpPlugin())
        yield client


def cluster_threads(client: Any) -> tuple[int, int]:
    """``(workers, threads)`` the client's scheduler has now."""
    workers = client.scheduler_info().get("workers", {})
    return len(workers), sum(int(w.get("nthreads", 1)) for w in workers.values())


def _log_bytes(path: str) -> int:
    try:
        return sum(p.stat().st_size for p in Path(path).iterdir() if p.is_file())
    except OSError:
        return 0  # unreadable: its task reports why


def plan_batches(jobs: list[LogJob], workers: int, *, batch_bytes: int = BATCH_BYTES
                 ) -> list[list[LogJob]]:
    """Group ``jobs`` into tasks: a log of ``batch_bytes`` or more alone, smaller ones together
    up to about that size, and never fewer than 4 tasks per worker (while there are logs to
    spread), so no worker idles while another holds a big batch. Order is kept."""
    if not jobs:
        return []
    sizes = [_log_bytes(j.source) for j in jobs]
    target = min(batch_bytes, max(1, sum(sizes) // max(1, 4 * workers)))
    batches: list[list[LogJob]] = []
    current: list[LogJob] = []
    size = 0
    for job, n in zip(jobs, sizes):
        if current and size + n > target:
            batches.append(current)
            current, size = [], 0
        current.append(job)
        size += n
    batches.append(current)
    return batches


@dataclass
class LogOutputs:
    """One log's outcome on a worker: :func:`run_log_job`'s ``(status, value)`` and the bytes
    of its output and plot (None when it failed or drew no plot)."""

    job: LogJob
    status: str
    value: Any
    output: bytes | None = None
    plot: bytes | None = None


def _scratch_dir() -> str | None:
    """The Dask worker's own scratch folder when this runs on one (Dask removes a killed
    worker's when the next starts; a folder of the system's temporary one stays for good),
    else None (the system's)."""
    try:
        from distributed import get_worker

        return get_worker().local_directory
    except (ImportError, ValueError):  # no distributed, or not on a worker
        return None


def replay_batch(batch: list[LogJob]) -> list[LogOutputs]:
    """Replay logs into a private temporary folder and return their bytes (a worker runs
    this; it writes nothing at the jobs' own output paths)."""
    out: list[LogOutputs] = []
    scratch = _scratch_dir()
    for job in batch:
        tmp = Path(tempfile.mkdtemp(prefix="fusion-replay-", dir=scratch))
        try:
            private = dataclasses.replace(
                job, output=str(tmp / Path(job.output).name),
                plot=None if job.plot is None else str(tmp / Path(job.plot).name))
            status, value = run_log_job(private)
            if status != "ok":
                out.append(LogOutputs(job, status, value.replace(private.output, job.output)))
                continue
            value = dataclasses.replace(value, output=job.output)
            plot = None if private.plot is None else Path(private.plot).read_bytes()
            out.append(LogOutputs(job, status, value, Path(private.output).read_bytes(), plot))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def _commit(res: LogOutputs) -> tuple[str, Any]:
    """Write one log's outputs at their paths (atomically); the result for the summary."""
    if res.status != "ok":
        return res.status, res.value
    try:
        with atomic_write(res.job.output, "wb") as fh:
            fh.write(res.output)
        if res.plot is not None and res.job.plot is not None:
            with atomic_write(res.job.plot, "wb") as fh:
                fh.write(res.plot)
    except OSError as exc:
        return "error", f"{res.job.source}: cannot write its output: {exc}"
    return "ok", res.value


def replay_logs_cluster(jobs: list[LogJob], client: Any,
                        on_done: Callable[[LogJob, tuple[str, Any]], None] | None = None, *,
                        batch_bytes: int = BATCH_BYTES) -> dict[str, tuple[str, Any]]:
    """Replay many logs on the workers of a Dask ``client``; returns each job's
    :func:`run_log_job` result by source path, as :func:`fusion.jobs.replay.replay_logs`.

    The client commits each log's outputs exactly once (a batch rerun after a lost worker is
    delivered once); a failed task fails the logs of its batch only. ``on_done(job, result)``
    is called once per log, after its outputs are in place.
    """
    workers, _ = cluster_threads(client)
    batches = plan_batches(jobs, max(workers, 1), batch_bytes=batch_bytes)
    results: dict[str, tuple[str, Any]] = {}
    for i, ok, value in run_tasks(replay_batch, batches, client=client):
        outcomes = value if ok else [LogOutputs(j, "error", f"{j.source}: worker task failed: "
                                                            f"{value}") for j in batches[i]]
        for res in outcomes:
            if res.job.source in results:  # never committed twice
                continue
            results[res.job.source] = _commit(res)
            if on_done is not None:
                on_done(res.job, results[res.job.source])
    return results
