"""Physical and wire constants shared by drivers, estimators and sinks (one copy each).

A leaf module: it imports nothing, so drivers may use it.
"""

from __future__ import annotations

__all__ = ["STANDARD_GRAVITY", "TICKS_MAX", "UNOBSERVED_VARIANCE"]

#: Standard acceleration of gravity g_n, m/s^2 (exact by definition, CGPM 1901); the scale of
#: the MPU6050's "g" units and the specific force of an IMU at rest.
STANDARD_GRAVITY = 9.80665

#: Variance that ROS drivers (seed 000 among them) put on nav_msgs/Odometry components they do
#: not estimate (z, roll, pitch of a planar filter), in the component's squared unit.
UNOBSERVED_VARIANCE = 99999.0

#: Largest magnitude of a :class:`fusion.types.samples.WheelTicks` count on the wire, ticks: a
#: DATA-uart2 field is a sign byte plus a 24-bit unsigned magnitude, so counts run over
#: ``-TICKS_MAX .. +TICKS_MAX`` = +-(2**24 - 1).
TICKS_MAX = (1 << 24) - 1
