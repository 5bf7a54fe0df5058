"""``open_sink(spec)``: a sink from a short text spec (``jsonl``, ``csv:F``, ``mcap:F``, ...).
"""

from __future__ import annotations

from fusion.io.sink_spec import parse_sink_spec
from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.base import Sink
from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.ros2 import Ros2Sink
from fusion.sinks.ros_messages import Topics
from fusion.sinks.text import CsvSink, JsonLinesSink

__all__ = ["open_sink"]


def open_sink(spec: str, *, topics: Topics | None = None, live: bool = False) -> Sink:
    """A sink from a command-line spec (not yet opened).

    ``live=True`` (``fusion run``) records the ``jsonl:PATH``, ``csv:PATH`` and ``mcap:PATH``
    files live: they grow in place and are synced every second, so a crash loses at most the
    last second (:mod:`fusion.io.incremental`). Offline (the default, ``fusion replay``) each
    file is replaced atomically by a complete one. A ``rosbag2`` folder is always built aside
    and moved into place when it is closed.

    ``jsonl`` (stdout) | ``jsonl:PATH`` | ``csv:PATH`` | ``mcap:PATH`` (one .mcap file) |
    ``rosbag2:PATH`` (bag folder, MCAP storage) | ``foxglove`` (127.0.0.1:8765) |
    ``foxglove:PORT`` | ``foxglove:HOST:PORT`` | ``ros1`` (a ROS 1 node, :mod:`fusion.sinks.ros1`) |
    ``ros2`` (ROS 2 topics over DDS, :mod:`fusion.sinks.ros2`; domain ``ROS_DOMAIN_ID``).

    Raises:
        ValueError: a spec :func:`fusion.io.sink_spec.parse_sink_spec` rejects.
    """
    parsed = parse_sink_spec(spec)
    if parsed.kind == "jsonl":
        return JsonLinesSink(parsed.path, live=live)
    if parsed.kind == "csv":
        return CsvSink(parsed.path, live=live)
    if parsed.kind == "mcap":
        return McapSink(parsed.path, topics=topics, live=live)
    if parsed.kind == "rosbag2":
        return Rosbag2Sink(parsed.path, topics=topics)
    if parsed.kind == "foxglove":
        return FoxgloveSink(parsed.host, parsed.port, topics=topics)
    if parsed.kind == "ros2":
        return Ros2Sink(topics=topics)
    from fusion.sinks.ros1 import Ros1Sink  # the only kind left (SINK_KINDS)

    return Ros1Sink(topics=topics)
