"""A ROS 1 recording split by ``rosbag record --split`` replays as one from its first part.

Oracle: the bundled Jackal bag replayed whole. Its messages are cut at two record times into
``<prefix>_0.bag``, ``_1.bag``, ``_2.bag`` (rosbags' writer, each connection as in the source);
the replay of ``_0.bag`` must write the very same file, byte for byte.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from fusion.cli import main
from fusion.io.split_bags import split_parts

IMU, ODOM = "/imu/data", "/jackal_velocity_controller/odom"
PREFIX = "run_2023-01-01-00-00-00"


def _split(source: Path, folder: Path, cuts_s: tuple[float, ...]) -> list[Path]:
    """``source`` written as parts ``PREFIX_<k>.bag`` in ``folder``, a new part from each of
    ``cuts_s`` (s of record time after the first message)."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Reader, Writer

    with Reader(source) as reader:
        first = reader.start_time
        connections = list(reader.connections)
        messages = [(c.id, ns, raw) for c, ns, raw in reader.messages()]
    bounds = [first + round(c * 1e9) for c in cuts_s]
    parts = [folder / f"{PREFIX}_{k}.bag" for k in range(len(bounds) + 1)]
    writers = [Writer(p) for p in parts]
    for w in writers:
        w.open()
    conns = [{c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
              for c in connections} for w in writers]
    for cid, ns, raw in messages:
        k = sum(ns >= b for b in bounds)
        writers[k].write(conns[k][cid], ns, raw)
    for w in writers:
        w.close()
    return parts


def _replay(bag: Path, out: Path, capsys) -> str:
    assert main(["replay", str(bag), "--imu-topic", IMU, "--odom-topic", ODOM, "-o", str(out),
                 "--no-progress"]) == 0
    return capsys.readouterr().out


def test_the_first_part_replays_the_whole_recording(datasets_dir, tmp_path, capsys):
    whole = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    parts = _split(whole, tmp_path, (20.0, 40.0))
    _replay(whole, tmp_path / "whole.csv", capsys)
    printed = _replay(parts[0], tmp_path / "split.csv", capsys)
    assert (tmp_path / "split.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
    assert (f"note: {PREFIX}_0.bag: a recording split by rosbag record --split; read as one "
            f"with {PREFIX}_1.bag to {PREFIX}_2.bag beside it (3 parts)") in printed
    # a later part alone is that part only, and says how to have them all
    printed = _replay(parts[1], tmp_path / "part1.csv", capsys)
    assert f"{PREFIX}_1.bag is part 1 of a recording split" in printed
    assert f"give {PREFIX}_0.bag to replay every part as one" in printed
    rows = sum(1 for _ in (tmp_path / "part1.csv").open()) - 1
    whole_rows = sum(1 for _ in (tmp_path / "whole.csv").open()) - 1
    assert 0.2 * whole_rows < rows < 0.5 * whole_rows  # 20 of the bag's 61 s


def test_the_parts_are_the_consecutive_numbers_from_zero(tmp_path):
    for k in (0, 1, 3):
        (tmp_path / f"{PREFIX}_{k}.bag").write_bytes(b"")
    (tmp_path / "other_0.bag").write_bytes(b"")
    parts, note = split_parts(tmp_path / f"{PREFIX}_0.bag")
    assert parts == [tmp_path / f"{PREFIX}_0.bag", tmp_path / f"{PREFIX}_1.bag"]
    assert f"with {PREFIX}_1.bag beside it (2 parts)" in note
    # a bag whose name only looks like a first part, or a part without its first, is itself
    assert split_parts(tmp_path / "other_0.bag") == ([tmp_path / "other_0.bag"], "")
    (tmp_path / f"{PREFIX}_0.bag").unlink()
    assert split_parts(tmp_path / f"{PREFIX}_1.bag") == ([tmp_path / f"{PREFIX}_1.bag"], "")
    assert split_parts(tmp_path / "run.bag") == ([tmp_path / "run.bag"], "")
