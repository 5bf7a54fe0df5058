"""ROS 1 recordings split into several files by ``rosbag record --split``.

``rosbag record --split --duration 5m -o run`` writes ``run_<date>_0.bag``, ``..._1.bag``, ...:
one recording, its topics continuing from file to file. Replayed one file at a time, each part
would start the filters afresh (a moving start, the bias unknown) and end mid-drive. Given the
first part (``_0.bag``), :func:`split_parts` returns it with the consecutive parts beside it
that carry on from it (each starting within :data:`SPLIT_GAP` of the one before it ending),
which :class:`fusion.io.bags._BagFile` reads as one bag (``rosbags``' AnyReader merges them
in time order), with a note naming them and every file of the recording's name left out
(a part after a gap in the numbering, one that does not carry on, one that cannot be read,
an unfinished ``.bag.active``). Any other part is read alone, with a note saying how to
replay them all. ROS 2 bags keep their splits in one folder, read as one already.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["SPLIT_GAP", "split_parts"]

#: A split part's name: the recording's prefix, ``_``, the part's number, ``.bag`` (lowercase:
#: rosbags reads no other), ``.active`` while rosbag record is still writing it.
_PART = re.compile(r"^(?P<prefix>.+)_(?P<n>\d+)(?P<suffix>\.bag)(?P<active>\.active)?$")
#: s: a part carries on from the one before when its first message comes at most this long
#: after that one's last (rosbag starts the next file with the next message).
SPLIT_GAP = 5.0


def _span(path: Path) -> tuple[float, float] | str:
    """(first, last) record time, s, of a ROS 1 bag, or why it cannot be read."""
    from rosbags.rosbag1 import Reader

    try:
        with Reader(path) as reader:
            first, last = reader.start_time, reader.end_time
    except Exception as exc:  # rosbags' errors, struct errors of a truncated file
        return f"not readable ({exc}); `rosbag reindex` rebuilds a cut file's index"
    if first > last:  # rosbags' span of a bag without messages
        return "no messages"
    return first * 1e-9, last * 1e-9


def split_parts(path: Path) -> tuple[list[Path], str]:
    """``(parts, note)``: the files to read for the ROS 1 bag ``path`` and what to tell the
    user ("" for a bag that is not part of a split recording).

    ``path`` named ``<prefix>_0.bag`` with ``<prefix>_1.bag`` beside it: the parts ``_0``,
    ``_1``, ... up to the first number missing, or the first that does not carry on from the
    one before it (:data:`SPLIT_GAP`) or cannot be read. ``<prefix>_<n>.bag`` with ``n`` > 0
    and ``<prefix>_0.bag`` beside it: ``[path]`` alone, with a note.
    """
    match = _PART.match(path.name)
    if match is None or match["active"] or not path.is_file():
        return [path], ""
    prefix, n, suffix = match["prefix"], int(match["n"]), match["suffix"]

    def part(k: int) -> Path:
        return path.with_name(f"{prefix}_{k}{suffix}")

    if n > 0:
        if not part(0).is_file():
            return [path], ""
        return [path], (f"{path.name} is part {n} of a recording split by rosbag record "
                        f"--split: read alone (give {part(0).name} to replay every part "
                        "as one)")
    if not part(1).is_file():
        return [path], ""
    parts, why = [path], {}
    span = _span(path)
    while isinstance(span, tuple) and part(len(parts)).is_file():
        following = part(len(parts))
        after = _span(following)
        if isinstance(after, str):
            why[following.name] = after
            break
        if not after[0] - span[1] <= SPLIT_GAP:
            why[following.name] = (f"its first message {after[0] - span[1]:.0f} s after "
                                   f"{parts[-1].name}'s last: another recording?")
            break
        parts.append(following)
        span = after
    for other in sorted(path.parent.iterdir()):
        named = _PART.match(other.name)
        if (named and named["prefix"] == prefix and other not in parts
                and other.name not in why and other.is_file()):
            stop = f"{prefix}_{len(parts)}{suffix}"
            why[other.name] = ("an unfinished recording: `rosbag reindex` it and rename it "
                               "to .bag" if named["active"] else
                               f"after {stop}, left out above" if stop in why else
                               f"after a gap in the numbering at {stop}"
                               if int(named["n"]) > len(parts) else "not read")
    if len(parts) == 1 and not why:
        return parts, ""
    others = ("no other part" if len(parts) == 1 else parts[1].name if len(parts) == 2
              else f"{parts[1].name} to {parts[-1].name}")
    note = (f"{path.name}: a recording split by rosbag record --split; read as one with "
            f"{others} beside it ({len(parts)} part{'s' if len(parts) > 1 else ''})")
    if why:
        note += "; left out: " + "; ".join(f"{name} ({reason})" for name, reason in why.items())
    return parts, note
