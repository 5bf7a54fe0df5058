"""Sinks for fused odometry: JSON lines, CSV, rosbag2/MCAP files, a Foxglove server, ROS 1, ROS 2.

One lifecycle for all (:class:`fusion.sinks.base.Sink`); :func:`open_sink` builds one from a
short spec. Optional dependencies are imported when a sink opens, so importing this package
is cheap.
"""

from fusion.sinks.bag import McapSink, Rosbag2Sink
from fusion.sinks.base import Sink, SinkError
from fusion.sinks.foxglove import FoxgloveSink
from fusion.sinks.registry import open_sink
from fusion.sinks.ros2 import Ros2Sink
from fusion.sinks.ros_messages import Topics, ros_messages
from fusion.sinks.text import CsvSink, JsonLinesSink

__all__ = [
    "CsvSink",
    "FoxgloveSink",
    "JsonLinesSink",
    "McapSink",
    "Ros2Sink",
    "Rosbag2Sink",
    "Sink",
    "SinkError",
    "Topics",
    "open_sink",
    "ros_messages",
]
