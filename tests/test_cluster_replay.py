"""``fusion replay LOGS/ --cluster``: a folder of logs on Dask, against the serial replay.

A real ``dask scheduler`` and two ``dask worker --nthreads 1`` processes on 127.0.0.1 (free
ports, torn down by the fixture), and separately a local cluster, replay 20 short synthetic
logs; every output must equal the serial replay's byte for byte. One test SIGKILLs a worker
while it holds tasks: every log must still come back exactly once, each output committed
once.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from fusion.cli import main
from fusion.evaluation.synthetic import degraded_mission
from fusion.io.logdir import write_synthetic_run
from fusion.jobs import cluster as dask_jobs
from fusion.jobs.replay import LogJob, find_log_dirs, replay_logs

# a dask scheduler and workers on loopback (timeouts in wall-clock seconds)
pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

N_LOGS = 20
REPO = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    return env


class DaskProcesses:
    """A scheduler and named workers started as ``python -m dask ...`` subprocesses."""

    def __init__(self, tmp: Path, n_workers: int) -> None:
        self.address = f"tcp://127.0.0.1:{_free_port()}"
        self.logs = tmp
        # the processes' own temporary folder (TMPDIR), to see what a killed worker leaves
        self.tmp = tmp / "tmp"
        self.tmp.mkdir()
        self.procs: dict[str, subprocess.Popen] = {}
        self._start("scheduler", ["scheduler", "--host", "127.0.0.1",
                                  "--port", self.address.rsplit(":", 1)[1], "--no-dashboard"])
        for i in range(n_workers):
            self._start(f"w{i}", ["worker", self.address, "--nthreads", "1", "--no-nanny",
                                  "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{i}"])

    def _start(self, name: str, args: list[str]) -> None:
        log = open(self.logs / f"{name}.log", "wb")  # the child keeps its own handle
        self.procs[name] = subprocess.Popen([sys.executable, "-m", "dask", *args],
                                            stdout=log, stderr=subprocess.STDOUT,
                                            env={**_env(), "TMPDIR": str(self.tmp)})
        log.close()

    def kill(self, name: str) -> None:
        self.procs[name].send_signal(signal.SIGKILL)
        self.procs[name].wait(10)

    def stop(self) -> None:
        """SIGKILL (a graceful shutdown takes seconds; test processes hold nothing)."""
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def dask_processes(tmp_path_factory):
    """A scheduler and two workers shared by the tests that leave them running."""
    procs = DaskProcesses(tmp_path_factory.mktemp("dask"), 2)
    try:
        yield procs
    finally:
        procs.stop()


@pytest.fixture()
def doomed_dask_processes(tmp_path):
    """A scheduler and two workers of one test's own (it kills one)."""
    procs = DaskProcesses(tmp_path, 2)
    try:
        yield procs
    finally:
        procs.stop()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """20 short synthetic logs and their serial replay (the reference outputs)."""
    root = tmp_path_factory.mktemp("fleet")
    logs = root / "logs"
    for i in range(N_LOGS):
        write_synthetic_run(logs / f"log{i:02d}",
                            degraded_mission(seed=i, duration=12.0, slip_patches=1))
    serial = root / "serial"
    serial.mkdir()
    jobs = [LogJob(str(p), str(serial / f"{p.name}.csv")) for p in find_log_dirs(logs)]
    results = replay_logs(jobs, 1)
    assert all(status == "ok" for status, _ in results.values())
    return logs, serial


def _jobs(logs: Path, out: Path) -> list[LogJob]:
    out.mkdir()
    return [LogJob(str(p), str(out / f"{p.name}.csv")) for p in find_log_dirs(logs)]


def _assert_same_as_serial(out: Path, serial: Path) -> None:
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(p.name for p in serial.iterdir())  # no stray temporary file
    assert len(names) == N_LOGS
    for name in names:
        assert (out / name).read_bytes() == (serial / name).read_bytes(), name


def _client(address: str):
    from distributed import Client

    client = Client(address, timeout=30)
    client.wait_for_workers(2, timeout=60)
    return client


def test_dask_scheduler_and_two_workers_match_serial_byte_for_byte(fleet, dask_processes,
                                                                   tmp_path, capsys):
    """``fusion replay LOGS/ -o out/ --cluster tcp://...`` (the command, in this process)."""
    logs, serial = fleet
    out = tmp_path / "out"
    assert main(["replay", str(logs), "-o", str(out), "--cluster",
                 dask_processes.address]) == 0
    printed = capsys.readouterr().out
    assert (f"{N_LOGS} of {N_LOGS} logs replayed (Dask cluster at "
            f"{dask_processes.address}); 0 failed") in printed
    assert printed.count(" ok ") == N_LOGS
    _assert_same_as_serial(out, serial)


def test_scheduler_address_from_the_environment(fleet, dask_processes, tmp_path, monkeypatch,
                                                capsys):
    """``--cluster`` alone joins DASK_SCHEDULER_ADDRESS; a broken log fails alone, named."""
    logs, _ = fleet
    folder = tmp_path / "two"
    folder.mkdir()
    (folder / "good").symlink_to(logs / "log00")
    bad = folder / "bad"
    bad.mkdir()
    (bad / "robot.toml").write_text((logs / "log00" / "robot.toml").read_text())
    (bad / "wheels.csv").write_text("t,left,right\n0.04,1,1\n0.08,x,2\n")
    out = tmp_path / "out"
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", dask_processes.address)
    assert main(["replay", str(folder), "-o", str(out), "--cluster"]) == 1
    printed = capsys.readouterr()
    assert f"1 of 2 logs replayed (Dask cluster at {dask_processes.address})" in printed.out
    assert f"{bad / 'wheels.csv'}:3" in printed.err
    assert sorted(p.name for p in out.iterdir()) == ["good.csv"]


def test_local_cluster_matches_serial(fleet, tmp_path):
    logs, serial = fleet
    out = tmp_path / "out"
    jobs = _jobs(logs, out)
    with dask_jobs.dask_client(dask_jobs.parse_cluster("local:2")) as client:
        assert dask_jobs.cluster_threads(client) == (2, 2)
        results = dask_jobs.replay_logs_cluster(jobs, client)
    assert all(status == "ok" for status, _ in results.values())
    assert {r.output for _, r in results.values()} == {j.output for j in jobs}
    _assert_same_as_serial(out, serial)


def test_worker_killed_mid_run_every_log_once(fleet, doomed_dask_processes, tmp_path,
                                              monkeypatch):
    logs, serial = fleet
    out = tmp_path / "out"
    jobs = _jobs(logs, out)
    commits: dict[str, int] = {}
    real_atomic_write = dask_jobs.atomic_write

    def counting_atomic_write(path, *args, **kwargs):
        commits[str(path)] = commits.get(str(path), 0) + 1
        return real_atomic_write(path, *args, **kwargs)

    monkeypatch.setattr(dask_jobs, "atomic_write", counting_atomic_write)
    dask_processes = doomed_dask_processes
    done: list[str] = []
    killed: dict[str, int] = {}
    client = _client(dask_processes.address)

    def on_done(job, result) -> None:
        done.append(job.source)
        if killed:
            return
        # kill a worker that holds tasks right now: they must run again on the other one
        names = {addr: w["name"] for addr, w in client.scheduler_info()["workers"].items()}
        busy = {a: len(keys) for a, keys in client.processing().items() if keys}
        if busy:
            victim = max(busy, key=busy.get)
            dask_processes.kill(names[victim])
            killed[names[victim]] = busy[victim]

    try:
        results = dask_jobs.replay_logs_cluster(jobs, client, on_done)
    finally:
        client.close()
    assert killed and next(iter(killed.values())) >= 1  # it died holding tasks
    assert dask_processes.procs[next(iter(killed))].returncode == -signal.SIGKILL
    assert sorted(done) == sorted(j.source for j in jobs)  # every log once
    assert all(status == "ok" for status, _ in results.values())
    assert commits == {j.output: 1 for j in jobs}  # every output written once
    _assert_same_as_serial(out, serial)
    # the killed worker's private replay folder was in its Dask scratch space (which Dask
    # clears for a dead worker), not left in the temporary folder for good
    # (measured: worker-*/fusion-replay-*/.log04.csv.*.partial in the scratch space)
    assert not list(dask_processes.tmp.glob("fusion-replay-*"))


def test_plan_batches_groups_small_logs_and_keeps_order(fleet):
    logs, _ = fleet
    jobs = [LogJob(str(p), f"/nowhere/{p.name}.csv") for p in find_log_dirs(logs)]
    size = sum(f.stat().st_size for f in Path(jobs[0].source).iterdir())
    batches = dask_jobs.plan_batches(jobs, 2, batch_bytes=3 * size)
    assert [j for b in batches for j in b] == jobs
    assert len(batches) >= 4 * 2 or len(batches) == len(jobs)
    assert max(len(b) for b in batches) > 1  # small logs share a task
    assert dask_jobs.plan_batches(jobs, 100) == [[j] for j in jobs]  # many workers: one each


@pytest.mark.parametrize(("spec", "expected"), [
    ("local:3", dask_jobs.ClusterSpec(workers=3)),
    ("tcp://10.0.0.5:8786", dask_jobs.ClusterSpec(address="tcp://10.0.0.5:8786")),
])
def test_parse_cluster(spec, expected):
    assert dask_jobs.parse_cluster(spec) == expected


@pytest.mark.parametrize("spec", ["local:0", "local:x", "10.0.0.5:8786", "tcp://"])
def test_parse_cluster_refuses(spec):
    with pytest.raises(ValueError, match="--cluster"):
        dask_jobs.parse_cluster(spec)


def test_cluster_and_jobs_together_refused(fleet, tmp_path, capsys):
    logs, _ = fleet
    assert main(["replay", str(logs), "-o", str(tmp_path / "o"), "--cluster", "local:2",
                 "--jobs", "2"]) == 2
    assert "--cluster and --jobs exclude each other" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_no_scheduler_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0"):
        with dask_jobs.dask_client(dask_jobs.ClusterSpec(address=f"tcp://127.0.0.1:"
                                                                 f"{_free_port()}"),
                                   connect_timeout=1.0):
            pass


def test_tune_on_the_dask_workers_matches_serial(fleet, dask_processes):
    """``fusion tune``'s folds as tasks on the same engine: the result of the serial run."""
    from fusion.io.robot_toml import read_robot_toml
    from fusion.jobs.tune import tune

    logs, _ = fleet
    paths = find_log_dirs(logs)[:4]
    base = read_robot_toml(paths[0] / "robot.toml")
    serial = tune("odometry", paths, base, folds=2, budget=6)
    client = _client(dask_processes.address)
    try:
        distributed = tune("odometry", paths, base, folds=2, budget=6, client=client)
    finally:
        client.close()
    assert distributed.final.values == serial.final.values
    assert [f.test_scores for _, f in distributed.folds] == \
        [f.test_scores for _, f in serial.folds]
