"""Live recordings survive a crash: ``fusion run`` files grow in place and are synced every
second (:mod:`fusion.io.incremental`); offline outputs stay atomic (tests/test_publish.py).

The reference for "what was written" is the records the process reported on stderr before it
was killed, and an independent reader: the ``mcap`` package's StreamReader (no summary needed),
never the project's own writer.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fusion.io.bags import read_bag
from fusion.io.errors import LogFormatError
from fusion.io.incremental import IncrementalFile
from fusion.sinks.bag import McapSink
from fusion.sinks.text import CsvSink, JsonLinesSink
from fusion.types.fused import FusedOdometry

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

pytest.importorskip("mcap")
pytest.importorskip("rosbags")


def _independent_odom_stamps(path: Path) -> tuple[list[int], bool]:
    """/odom log times (ns) read front to back by mcap's StreamReader, and whether the file
    ended inside a record (EndOfFile) instead of at its footer."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    odom, stamps = None, []
    with path.open("rb") as fh:
        try:
            for rec in StreamReader(fh).records:
                if isinstance(rec, Channel) and rec.topic == "/odom":
                    odom = rec.id
                elif isinstance(rec, Message) and rec.channel_id == odom:
                    stamps.append(rec.log_time)
        except Exception:  # EndOfFile or a short read inside the last, cut record
            assert fh.tell() == path.stat().st_size  # it failed at the end, not before
            return stamps, True
    return stamps, False


def _start_run(tmp_path: Path, publish: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "fusion", "run", "--imu", "sim", "--chassis", "sim",
         "--publish", publish, "--speed", "4", "--status", "0.3"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _wait_for_records(proc: subprocess.Popen, at_least: int) -> int:
    """Read status lines until one reports ``at_least`` records; return that count."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"fusion run ended early: {proc.wait()}")
        if " records;" in line:
            n = int(line.split(" records;")[0].split()[-1])
            if n >= at_least:
                return n
    raise AssertionError("no status line with enough records")


def test_sigkill_keeps_every_record_up_to_the_last_sync(tmp_path: Path) -> None:
    proc = _start_run(tmp_path, "mcap:run.mcap,jsonl:run.jsonl,csv:run.csv")
    try:
        reported = _wait_for_records(proc, 150)
        time.sleep(2.5)  # more than two sync intervals (1 s) after those records were written
        proc.kill()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    # visible files, no hidden temporary left: each was renamed into place at its first sync
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.jsonl", "run.mcap"]

    stamps, ended_inside = _independent_odom_stamps(tmp_path / "run.mcap")
    assert ended_inside  # no footer: the writer never finished
    assert len(stamps) >= reported
    bag = read_bag(tmp_path / "run.mcap", odom_topic="/odom")
    assert "unfinished MCAP recording" in bag.note
    odom = bag.odometry
    assert odom is not None and len(odom) == len(stamps)
    # every record kept at its stamp; but two records the busy writer stamped a millisecond
    # apart (under a tenth of the mean interval) are a batch to the reader, which spreads it
    # back over the interval before (fusion.io.repeated_stamps: a CI run had records 1 ms
    # apart at 40 ms): those stamps only may differ
    steps = np.diff(stamps)
    near = np.flatnonzero((steps > 0) & (steps < 0.1 * np.mean(steps)))
    batched = np.zeros(len(stamps), dtype=bool)
    batched[near] = batched[near + 1] = True
    read = np.round(odom.t * 1e9).astype(np.int64)
    np.testing.assert_array_equal(read[~batched], np.asarray(stamps)[~batched])

    lines = (tmp_path / "run.jsonl").read_text().splitlines()
    records = [r for r in map(json.loads, lines) if "status" not in r]  # every line complete
    assert len(records) >= reported
    # the same records in every file, in the same order (MCAP stamps are whole ns)
    n = min(len(records), len(odom))
    assert [round(r["t"] * 1e9) for r in records[:n]] == stamps[:n]
    rows = np.loadtxt(tmp_path / "run.csv", delimiter=",", skiprows=1, usecols=[0], ndmin=2)
    assert rows.shape[0] >= reported
    np.testing.assert_array_equal(rows[:n, 0], [r["t"] for r in records[:n]])


def test_sigterm_finishes_the_files(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    proc = _start_run(tmp_path, "mcap:run.mcap,csv:run.csv")
    try:
        _wait_for_records(proc, 50)
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    stamps, ended_inside = _independent_odom_stamps(tmp_path / "run.mcap")
    assert not ended_inside  # read through to the footer
    with (tmp_path / "run.mcap").open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary.statistics.channel_message_counts[1] == len(stamps)
    assert read_bag(tmp_path / "run.mcap", odom_topic="/odom").note == ""
    rows = np.loadtxt(tmp_path / "run.csv", delimiter=",", skiprows=1, usecols=[0], ndmin=2)
    assert rows.shape[0] == len(stamps)


def _records(n: int) -> list[FusedOdometry]:
    return [FusedOdometry(t=1.0 + 0.04 * k, x=0.01 * k, y=0.0, yaw=0.0, v=0.25, w=0.0)
            for k in range(n)]


def test_incremental_file_is_hidden_until_its_first_sync(tmp_path: Path) -> None:
    target = tmp_path / "rec.txt"
    target.write_text("older recording\n")
    out = IncrementalFile(target, sync_interval=3600)
    out.file.write("a\n")
    out.file.flush()
    assert target.read_text() == "older recording\n"  # untouched until the first sync
    assert not out.sync_if_due()
    out.sync()
    assert target.read_text() == "a\n" and out.published
    out.file.write("b\n")
    out.discard()  # after a sync the recording is kept, not thrown away
    assert target.read_text() == "a\nb\n"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.txt"]
    # discarded before its first sync: the old file stays and nothing is left behind
    out = IncrementalFile(target, sync_interval=3600)
    out.file.write("c\n")
    out.discard()
    assert target.read_text() == "a\nb\n"
    assert [p.name for p in tmp_path.iterdir()] == ["rec.txt"]
    with pytest.raises(ValueError, match="sync_interval"):
        IncrementalFile(target, sync_interval=0)


@pytest.mark.parametrize("kind", ["mcap", "jsonl", "csv"])
def test_an_aborted_live_recording_keeps_its_records(tmp_path: Path, kind: str) -> None:
    path = tmp_path / f"rec.{kind}"
    make = {"mcap": McapSink, "jsonl": JsonLinesSink, "csv": CsvSink}[kind]
    with pytest.raises(RuntimeError, match="source lost"):
        with make(path, live=True) as sink:
            for rec in _records(7):
                sink.write(rec)
            raise RuntimeError("source lost")
    if kind == "mcap":  # finished properly: a summary, every message
        stamps, ended_inside = _independent_odom_stamps(path)
        assert not ended_inside and len(stamps) == 7
    else:
        assert len(path.read_text().splitlines()) == 7 + (kind == "csv")
    # offline, the same abort leaves nothing
    off = tmp_path / f"off.{kind}"
    with pytest.raises(RuntimeError):
        with make(off) as sink:
            sink.write(_records(1)[0])
            raise RuntimeError("x")
    assert not off.exists()


def test_mcap_cut_anywhere_reads_up_to_its_last_complete_chunk(tmp_path: Path) -> None:
    whole = tmp_path / "whole.mcap"
    with McapSink(whole, live=True, sync_interval=1e-9) as sink:  # a chunk per record
        for rec in _records(20):
            sink.write(rec)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    previous = 0
    for size in range(len(data) // 4, len(data) - 1, 233):
        cut.write_bytes(data[:size])
        stamps, _ = _independent_odom_stamps(cut)
        try:
            bag = read_bag(cut, odom_topic="/odom")
        except LogFormatError as exc:  # cut before the first complete chunk of /odom
            assert not stamps
            assert "no complete message" in str(exc) or "no topic '/odom'" in str(exc)
            continue
        n = len(bag.odometry)
        assert n == len(stamps) >= previous  # what the independent reader sees
        np.testing.assert_allclose(bag.odometry.t, [r.t for r in _records(n)])
        previous = n
    assert previous >= 15


@pytest.mark.parametrize(
    ("content", "why"),
    [(b"", "the file is empty"),
     (b"t,x,y\n1,2,3\n", "does not start with the MCAP magic bytes"),
     (b"\x89MCAP0\r\n", "no complete message")],
)
def test_unreadable_mcap_says_why(tmp_path: Path, content: bytes, why: str) -> None:
    path = tmp_path / "f.mcap"
    path.write_bytes(content)
    with pytest.raises(LogFormatError, match=f"{path}: not a readable MCAP file .*{why}"):
        read_bag(path, odom_topic="/odom")
