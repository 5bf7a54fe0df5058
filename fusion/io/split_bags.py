"""ROS 1 recordings split into several files by ``rosbag record --split``.

``rosbag record --split --duration 5m -o run`` writes ``run_<date>_0.bag``, ``..._1.bag``, ...:
one recording, its topics continuing from file to file. Replayed one file at a time, each part
would start the filters afresh (a moving start, the bias unknown) and end mid-drive. Given the
first part (``_0.bag``), :func:`split_parts` returns it with every consecutive part beside it,
which :class:`fusion.io.bags._BagFile` reads as one bag (``rosbags``' AnyReader merges them
in time order), with a note naming them. Any other part is read alone, with a note saying how
to replay them all. ROS 2 bags keep their splits in one folder, read as one already.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["split_parts"]

#: A split part's name: the recording's prefix, ``_``, the part's number, ``.bag``.
_PART = re.compile(r"^(?P<prefix>.+)_(?P<n>\d+)\.bag$")


def split_parts(path: Path) -> tuple[list[Path], str]:
    """``(parts, note)``: the files to read for the ROS 1 bag ``path`` and what to tell the
    user ("" for a bag that is not part of a split recording).

    ``path`` named ``<prefix>_0.bag`` with ``<prefix>_1.bag`` beside it: the parts ``_0``,
    ``_1``, ... up to the first number missing. ``<prefix>_<n>.bag`` with ``n`` > 0 and
    ``<prefix>_0.bag`` beside it: ``[path]`` alone, with a note.
    """
    match = _PART.match(path.name)
    if match is None or not path.is_file():
        return [path], ""
    prefix, n = match["prefix"], int(match["n"])

    def part(k: int) -> Path:
        return path.with_name(f"{prefix}_{k}.bag")

    if n > 0:
        if not part(0).is_file():
            return [path], ""
        return [path], (f"{path.name} is part {n} of a recording split by rosbag record "
                        f"--split: read alone (give {part(0).name} to replay every part "
                        "as one)")
    parts = [path]
    while part(len(parts)).is_file():
        parts.append(part(len(parts)))
    if len(parts) == 1:
        return parts, ""
    others = parts[1].name if len(parts) == 2 else f"{parts[1].name} to {parts[-1].name}"
    return parts, (f"{path.name}: a recording split by rosbag record --split; read as one "
                   f"with {others} beside it ({len(parts)} parts)")
