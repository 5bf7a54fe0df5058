"""Sinks for fused odometry: JSON lines, CSV, rosbag2/MCAP files, a Foxglove live server, ROS 1
and ROS 2.

Every sink has the same small interface: ``open()``, ``write(record)`` with a
:class:`fusion.types.fused.FusedOdometry`, ``close()``, and use as a context manager (``with sink:``
opens it and closes it; an exception inside the block calls ``abort()`` instead, which for file
sinks discards the partial output and leaves any existing file untouched).

The ROS-shaped sinks publish seed 000's interface (topics configurable through :class:`Topics`):

=====================  ======================  =================================================
topic                  type                    content
=====================  ======================  =================================================
``/odom``              nav_msgs/Odometry       pose of ``child_frame_id`` in ``frame_id`` (m,
                                               yaw-only quaternion), twist in the child frame
                                               (m/s, rad/s), both covariances (6x6 row major)
``/tf``                tf2_msgs/TFMessage      ``frame_id`` -> ``child_frame_id`` (odom ->
                                               base_footprint)
``/imu/data``          sensor_msgs/Imu         attitude (if known, else orientation covariance
                                               [0] = -1), body rate rad/s, specific force m/s^2
                                               (if known, else its covariance [0] = -1);
                                               only with an IMU sample behind the record
``/wheel_left_speed``  std_msgs/Float32        left wheel rim speed, m/s (when the record has it)
``/wheel_right_speed`` std_msgs/Float32        right wheel rim speed, m/s
=====================  ======================  =================================================

Stamps are the record's ``t`` (s) as integer nanoseconds; ROS time cannot be negative, so a
record with ``t < 0`` is a ValueError in the ROS-shaped sinks. The live sinks (the ROS 1
node, the ROS 2 participant and the Foxglove server) also take velocity commands on ``/cmd_vel``
(geometry_msgs/Twist) and hand ``(linear.x m/s, angular.z rad/s)`` to an ``on_cmd_vel``
callback.

Optional dependencies: ``rosbags`` for the bag sinks (``pip install 'diffbot-fusion[ros]'``),
``foxglove-sdk`` for the live server (``[foxglove]``), ``cyclonedds`` for ROS 2 (``[ros2]``),
Debian's ``python3-rospy`` and message packages for the ROS 1 node (:mod:`fusion.sinks.ros1`).
They are imported when a sink opens.
"""

from __future__ import annotations

from typing import Any

from fusion.io.atomic import create_temp_file  # re-exported: fusion replay's outputs use it
from fusion.types.fused import FusedOdometry
from fusion.types.lifecycle import Lifecycle

__all__ = ["Sink", "SinkError", "create_temp_file"]


class SinkError(RuntimeError):
    """A sink used out of order (write before open, after close) or a failed output."""


class Sink(Lifecycle):
    """Base of all sinks: ``open()``, ``write(record)``, ``close()``, ``abort()``
    (:class:`fusion.types.lifecycle.Lifecycle`).

    ``with sink:`` opens, and on leaving closes (normal exit) or aborts (an exception).
    Subclasses implement ``_open``, ``_write``, ``_close`` and optionally ``_abort``.
    """

    def __init__(self) -> None:
        self._state = "new"
        self.records_written = 0

    def _reuse_error(self) -> Exception:
        return SinkError(f"{self!r} was already opened")

    def write(self, record: FusedOdometry) -> None:
        """Publish or store one record."""
        if self._state != "open":
            raise SinkError(f"{self!r} is not open (state {self._state})")
        if not isinstance(record, FusedOdometry):
            raise TypeError(f"sinks take FusedOdometry records, got {type(record).__name__}")
        self._write(record)
        self.records_written += 1

    def _write(self, record: FusedOdometry) -> None:
        raise NotImplementedError


def _need(module: str, extra: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(
            f"this sink needs the {module.split('.')[0]!r} package: "
            f"pip install 'diffbot-fusion[{extra}]'"
        ) from exc
