"""File sinks and other atomic outputs get the permissions of an ordinary ``open()``.

Regression: the sinks built their output in a :func:`tempfile.mkstemp` file (mode 0600) and
renamed it into place, so a fused CSV or JSON-lines file was private to its writer. The
reference is the mode a plain ``open(path, "w")`` gives in the same folder under the same umask.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from fusion.io.imu_csv import write_attitude_csv
from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.base import create_temp_file
from fusion.sinks.text import CsvSink, JsonLinesSink
from fusion.types.fused import FusedOdometry


def _plain_mode(folder: Path) -> int:
    ref = folder / "reference.txt"
    with open(ref, "w") as fh:
        fh.write("x")
    mode = stat.S_IMODE(ref.stat().st_mode)
    ref.unlink()
    return mode


def _record(k: int) -> FusedOdometry:
    cov = np.diag([0.01, 0.01, 99999.0, 99999.0, 99999.0, 0.02])
    return FusedOdometry(t=1.0 + 0.04 * k, x=0.1 * k, y=0.0, yaw=0.01 * k, v=0.1, w=0.0,
                         pose_covariance=cov, twist_covariance=cov)


def _write(sink) -> None:
    with sink:
        for k in range(3):
            sink.write(_record(k))


@pytest.mark.parametrize("kind", ["jsonl", "csv"])
def test_text_sinks_respect_the_umask(tmp_path: Path, umask: int, kind: str) -> None:
    expected = 0o666 & ~umask
    assert _plain_mode(tmp_path) == expected  # the reference itself
    path = tmp_path / f"fused.{kind}"
    _write(JsonLinesSink(path) if kind == "jsonl" else CsvSink(path))
    assert stat.S_IMODE(path.stat().st_mode) == expected
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left


def test_under_umask_022_a_fused_file_is_0644(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        _write(JsonLinesSink(tmp_path / "f.jsonl"))
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "f.jsonl").stat().st_mode) == 0o644


def test_bag_sinks_respect_the_umask(tmp_path: Path, umask: int) -> None:
    pytest.importorskip("rosbags")
    expected = 0o666 & ~umask
    _write(McapSink(tmp_path / "fused.mcap"))
    assert stat.S_IMODE((tmp_path / "fused.mcap").stat().st_mode) == expected
    _write(Rosbag2Sink(tmp_path / "bag"))
    bag = tmp_path / "bag"
    # the folder is the one rosbags makes (mkdir mode 0755, minus the umask; not the private
    # 0700 temporary folder it is built in), its files like open()
    assert stat.S_IMODE(bag.stat().st_mode) == 0o755 & ~umask
    for f in bag.iterdir():
        assert stat.S_IMODE(f.stat().st_mode) == expected, f


def test_attitude_csv_respects_the_umask(tmp_path: Path, umask: int) -> None:
    path = tmp_path / "att.csv"
    write_attitude_csv(path, np.array([0.0, 0.01]), np.array([[1.0, 0, 0, 0]] * 2))
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_create_temp_file_is_fresh_each_time(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    a, b = create_temp_file(target), create_temp_file(target)
    assert a != b and a.parent == b.parent == tmp_path
    assert a.name.startswith(".out.csv.") and a.name.endswith(".partial")
    assert a.stat().st_size == 0
    assert not target.exists()
