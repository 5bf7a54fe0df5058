"""What the live ROS sinks share (the ROS 1 node :mod:`fusion.sinks.ros1`, the ROS 2 participant
:mod:`fusion.sinks.ros2`): a record-time rate limit, frame-name overrides, the stamp mode, and
velocity commands from ``/cmd_vel`` handed to a callback.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from fusion.sinks.base import Sink
from fusion.sinks.ros_messages import Topics
from fusion.types.fused import FusedOdometry

__all__ = ["RateLimiter", "RosNodeSink"]


class RateLimiter:
    """Passes an event when at least ``1 / rate_hz`` s (of the events' own clock) have gone
    by since the last one that passed; ``rate_hz=None`` passes everything.

    The first event always passes; a clock that steps back restarts the schedule.
    """

    def __init__(self, rate_hz: float | None) -> None:
        if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate must be a positive number of Hz or None, got {rate_hz}")
        self.period = 0.0 if rate_hz is None else 1.0 / rate_hz
        self._last: float | None = None

    def due(self, t: float) -> bool:
        """True if an event at ``t`` (s) should be published."""
        last = self._last
        # 1e-9 s of slack: events on an exact grid (0.1 s at 10 Hz) are not lost to rounding
        if last is None or t < last or t - last >= self.period - 1e-9:
            self._last = t
            return True
        return False


class RosNodeSink(Sink):
    """Base of the live ROS sinks: checks and keeps the options they share.

    Args:
        topics: topic names (:class:`fusion.sinks.ros_messages.Topics`; None leaves a topic out).
        cmd_vel_topic: velocity command topic (geometry_msgs/Twist), or None not to subscribe.
        on_cmd_vel: ``callback(v, w)`` with linear.x (m/s) and angular.z (rad/s) of every
            command received (unclamped; commands with a non-finite value are dropped and
            counted in :attr:`cmd_vel_rejected`).
        rate_hz: most records published per second of record time; None publishes every one.
        frame_id, child_frame_id, imu_frame_id: override the record's frame names.
        stamp: ``"now"`` stamps messages with the wall clock at publication (live robots,
            whose pipeline runs on a monotonic clock); ``"record"`` uses the record's ``t``
            (replay, tests).
    """

    def __init__(
        self,
        topics: Topics | None = None,
        *,
        cmd_vel_topic: str | None = "/cmd_vel",
        on_cmd_vel: Callable[[float, float], None] | None = None,
        rate_hz: float | None = None,
        frame_id: str | None = None,
        child_frame_id: str | None = None,
        imu_frame_id: str | None = None,
        stamp: str = "now",
    ) -> None:
        super().__init__()
        if stamp not in ("now", "record"):
            raise ValueError(f"stamp must be 'now' or 'record', got {stamp!r}")
        if cmd_vel_topic is not None and not cmd_vel_topic.startswith("/"):
            raise ValueError(f"cmd_vel_topic must be absolute like '/cmd_vel', got "
                             f"{cmd_vel_topic!r}")
        for name, value in (("frame_id", frame_id), ("child_frame_id", child_frame_id),
                            ("imu_frame_id", imu_frame_id)):
            if value is not None and (not isinstance(value, str) or not value):
                raise ValueError(f"{name} must be a non-empty string or None, got {value!r}")
        self.topics = topics or Topics()
        self.cmd_vel_topic = cmd_vel_topic
        self.on_cmd_vel = on_cmd_vel
        self.limiter = RateLimiter(rate_hz)
        self.frames = {"frame_id": frame_id, "child_frame_id": child_frame_id,
                       "imu_frame_id": imu_frame_id}
        self.stamp = stamp
        self.cmd_vel_received = 0
        self.cmd_vel_rejected = 0

    def _due(self, record: FusedOdometry) -> FusedOdometry | None:
        """The record to publish with the frame overrides applied, or None if the rate limit
        drops it."""
        if not self.limiter.due(record.t):
            return None
        overrides = {k: v for k, v in self.frames.items() if v is not None}
        if overrides:
            record = FusedOdometry(**{**record.__dict__, **overrides})
        return record

    def _command(self, v: float, w: float) -> None:
        """One velocity command (linear.x m/s, angular.z rad/s) from the ROS graph."""
        v, w = float(v), float(w)
        if not (math.isfinite(v) and math.isfinite(w)):
            self.cmd_vel_rejected += 1
            return
        self.cmd_vel_received += 1
        if self.on_cmd_vel is not None:
            self.on_cmd_vel(v, w)
