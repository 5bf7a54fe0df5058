"""``open_sink(spec)``: a sink from a short text spec (``jsonl``, ``csv:F``, ``mcap:F``, ...).
"""

from __future__ import annotations

from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.base import Sink
from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.ros_messages import Topics
from fusion.sinks.text import CsvSink, JsonLinesSink

__all__ = ["open_sink"]


def open_sink(spec: str, *, topics: Topics | None = None) -> Sink:
    """A sink from a command-line spec (not yet opened).

    ``jsonl`` (stdout) | ``jsonl:PATH`` | ``csv:PATH`` | ``mcap:PATH`` (one .mcap file) |
    ``rosbag2:PATH`` (bag folder, MCAP storage) | ``foxglove`` (127.0.0.1:8765) |
    ``foxglove:PORT`` | ``foxglove:HOST:PORT`` | ``ros1`` (a ROS 1 node, :mod:`fusion.sinks.ros1`).
    """
    kind, _, arg = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "jsonl":
        return JsonLinesSink(arg or None)
    if kind == "csv":
        if not arg:
            raise ValueError(f"sink {spec!r}: give a path, e.g. csv:fused.csv")
        return CsvSink(arg)
    if kind in ("mcap", "rosbag2"):
        if not arg:
            raise ValueError(f"sink {spec!r}: give a path, e.g. {kind}:out.mcap")
        return McapSink(arg, topics=topics) if kind == "mcap" else Rosbag2Sink(arg, topics=topics)
    if kind == "foxglove":
        host, port = "127.0.0.1", "8765"
        if arg:
            host, _, port = arg.rpartition(":") if ":" in arg else ("127.0.0.1", "", arg)
        try:
            return FoxgloveSink(host or "127.0.0.1", int(port), topics=topics)
        except ValueError as exc:
            raise ValueError(f"sink {spec!r}: want foxglove[:HOST]:PORT ({exc})") from None
    if kind == "ros1":
        if arg:
            raise ValueError(f"sink {spec!r}: ros1 takes no argument (use the config file)")
        from fusion.sinks.ros1 import Ros1Sink

        return Ros1Sink(topics=topics)
    raise ValueError(
        f"unknown sink {spec!r}: want jsonl[:PATH], csv:PATH, mcap:PATH, rosbag2:PATH, "
        "foxglove[:HOST:PORT] or ros1"
    )
