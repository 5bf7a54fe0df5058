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


def _shifted(source: Path, dest: Path, seconds: float) -> None:
    """``source`` copied to ``dest`` with every record time ``seconds`` later."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(source) as reader, Writer(dest) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                             md5sum=c.digest) for c in reader.connections}
        for c, ns, raw in reader.messages():
            writer.write(conns[c.id], ns + round(seconds * 1e9), raw)


def test_parts_that_do_not_carry_on_are_left_out_and_named(datasets_dir, tmp_path):
    whole = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    parts = _split(whole, tmp_path, (15.0, 30.0, 45.0))  # _0 to _3
    # a gap in the numbering: _2 gone, _3 is not reached
    parts[2].rename(tmp_path / "elsewhere.bag")
    # an unfinished part a recorder left (rosbag's .bag.active)
    (tmp_path / f"{PREFIX}_4.bag.active").write_bytes(parts[3].read_bytes()[:1000])
    got, note = split_parts(parts[0])
    assert got == parts[:2]
    assert f"with {PREFIX}_1.bag beside it (2 parts)" in note
    assert f"{PREFIX}_3.bag (after a gap in the numbering at {PREFIX}_2.bag)" in note
    assert f"{PREFIX}_4.bag.active (an unfinished recording: `rosbag reindex`" in note
    # a part that does not carry on from the one before (another recording, an hour later)
    (tmp_path / "elsewhere.bag").rename(parts[2])
    later = tmp_path / "later.bag"
    _shifted(parts[2], later, 3600.0)
    later.replace(parts[2])
    got, note = split_parts(parts[0])
    assert got == parts[:2]
    assert (f"{PREFIX}_2.bag (its first message 3600 s after {PREFIX}_1.bag's last: another "
            "recording?)") in note
    # a part without messages (rosbags' span of one runs backwards): said as such
    from rosbags.rosbag1 import Writer

    parts[2].unlink()
    with Writer(parts[2]):
        pass
    got, note = split_parts(parts[0])
    assert got == parts[:2] and f"{PREFIX}_2.bag (no messages)" in note
    assert f"{PREFIX}_3.bag (after {PREFIX}_2.bag, left out above)" in note
    # a part that cannot be read (cut short: no index)
    parts[2].write_bytes(parts[1].read_bytes()[:5000])
    got, note = split_parts(parts[0])
    assert got == parts[:2] and f"{PREFIX}_2.bag (not readable (" in note


def test_names_that_only_look_like_parts_are_bags_of_their_own(datasets_dir, tmp_path):
    whole = datasets_dir / "rosbag" / "jackal_sim_test2.bag"
    parts = _split(whole, tmp_path, (20.0,))
    # a later part given alone is itself; a first part without a second, or a part without
    # its first, or a name without a number, likewise
    assert split_parts(parts[1]) == ([parts[1]], f"{PREFIX}_1.bag is part 1 of a recording "
                                     f"split by rosbag record --split: read alone (give "
                                     f"{PREFIX}_0.bag to replay every part as one)")
    parts[1].unlink()
    assert split_parts(parts[0]) == ([parts[0]], "")
    lone = tmp_path / "other_1.bag"
    parts[0].rename(lone)
    assert split_parts(lone) == ([lone], "")
    assert split_parts(whole) == ([whole], "")


def test_an_uppercase_bag_suffix_is_named_with_the_way_out(datasets_dir, tmp_path):
    # rosbags knows a ROS 1 bag by its lowercase suffix; the error had blamed a cut file
    from fusion.io.bags import read_bag
    from fusion.io.errors import LogFormatError

    upper = tmp_path / "RUN_0.BAG"
    upper.write_bytes((datasets_dir / "rosbag" / "jackal_sim_test2.bag").read_bytes())
    with pytest.raises(LogFormatError, match=r"RUN_0.BAG: not a readable ROS bag .*by its "
                                             r"lowercase \.bag suffix: rename it to RUN_0\.bag"):
        read_bag(upper, imu_topic=IMU, odom_topic=ODOM)
