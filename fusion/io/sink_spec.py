"""The text form of a sink: ``jsonl[:PATH]``, ``csv:PATH``, ``mcap:PATH``, ``rosbag2:PATH``,
``foxglove[:HOST:PORT]``, ``ros1``, ``ros2``.

Parsed and checked here, without importing any sink, so the run configuration
(:mod:`fusion.io.run_config`) can reject a bad spec with its file and line;
:func:`fusion.sinks.registry.open_sink` builds the sink from the parsed spec.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SINK_KINDS", "SinkSpec", "parse_sink_spec"]

#: The sink kinds a spec can name.
SINK_KINDS = ("jsonl", "csv", "mcap", "rosbag2", "foxglove", "ros1", "ros2")


@dataclass(frozen=True)
class SinkSpec:
    """A parsed sink spec.

    Attributes:
        kind: one of :data:`SINK_KINDS`.
        path: the output file or bag folder (``jsonl``: None for stdout; ``csv``, ``mcap``,
            ``rosbag2``: always set; ``foxglove``, ``ros1``, ``ros2``: None).
        host: ``foxglove``: the interface the server listens on.
        port: ``foxglove``: TCP port 0..65535 (0: any free port).
    """

    kind: str
    path: str | None = None
    host: str = "127.0.0.1"
    port: int = 8765


def parse_sink_spec(spec: str) -> SinkSpec:
    """Parse a command-line sink spec (see the module docstring).

    Raises:
        ValueError: an unknown kind, a missing path, a bad Foxglove port, or an argument to
            ``ros1`` or ``ros2``; the message quotes the spec.
    """
    kind, _, arg = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "jsonl":
        return SinkSpec(kind, path=arg or None)
    if kind in ("csv", "mcap", "rosbag2"):
        if not arg:
            example = "fused.csv" if kind == "csv" else "out.mcap"
            raise ValueError(f"sink {spec!r}: give a path, e.g. {kind}:{example}")
        return SinkSpec(kind, path=arg)
    if kind == "foxglove":
        host, port = "127.0.0.1", "8765"
        if arg:
            host, _, port = arg.rpartition(":") if ":" in arg else ("127.0.0.1", "", arg)
        try:
            number = int(port)
            if not 0 <= number <= 65535:
                raise ValueError(f"port must be 0..65535, got {number}")
        except ValueError as exc:
            raise ValueError(f"sink {spec!r}: want foxglove[:HOST]:PORT ({exc})") from None
        return SinkSpec(kind, host=host or "127.0.0.1", port=number)
    if kind in ("ros1", "ros2"):
        if arg:
            where = "the config file" if kind == "ros1" else "ROS_DOMAIN_ID and CYCLONEDDS_URI"
            raise ValueError(f"sink {spec!r}: {kind} takes no argument (use {where})")
        return SinkSpec(kind)
    raise ValueError(
        f"unknown sink {spec!r}: want jsonl[:PATH], csv:PATH, mcap:PATH, rosbag2:PATH, "
        "foxglove[:HOST:PORT], ros1 or ros2"
    )
