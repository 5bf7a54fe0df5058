"""The simulated robot's true body and its firmware: masses, tyres, motors, speed controller.

Frames and units: body frame x forward, y left, z up (REP-103) with its origin at the midpoint
of the wheel axle (``base_footprint``); SI units throughout (m, kg, s, N, rad).

The robot is a rigid body on a level floor carried by two driven wheels on the axle and a
free-swivel caster ahead of it. The caster carries part of the weight and passes no horizontal
force; the wheels' share of the weight is ``wheel_load_fraction`` (from the centre of mass lying
``com_ahead`` in front of the axle and the caster ``caster_ahead`` in front of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["BodyParams", "ControllerParams"]


@dataclass(frozen=True)
class BodyParams:
    """True mechanical parameters of the robot (what the robot owner does NOT know exactly).

    Attributes:
        mass: total mass, kg.
        yaw_inertia: moment of inertia about the vertical axis through the centre of mass,
            kg m^2.
        com_ahead: centre of mass ahead of the axle midpoint, m.
        caster_ahead: caster contact ahead of the axle midpoint, m (> ``com_ahead``).
        wheel_radius: nominal (unloaded) wheel radius, m; the owner's robot.toml derives
            ``speed_ratio`` from it.
        wheel_distance: nominal distance between the wheel contact points, m (robot.toml's
            ``wheel_distance``); the true one is set by the errors.
        wheel_inertia: rotational inertia of one wheel with its gearbox and motor rotor
            reflected to the wheel shaft, kg m^2.
        wheel_damping: viscous drag torque of one drive train, N m per rad/s.
        contact_stiffness: tyre force per unit slip velocity of the contact patch (a
            regularised Coulomb friction), N per m/s; the force is capped by the friction
            circle ``mu * normal load``.
        mu: floor friction coefficient where no low-friction patch lies (1).
        imu_position: IMU position in the body frame, m (lever arm for the accelerations).
        gravity: m/s^2.
    """

    mass: float = 8.0
    yaw_inertia: float = 0.12
    com_ahead: float = 0.04
    caster_ahead: float = 0.20
    wheel_radius: float = 0.05
    wheel_distance: float = 0.30
    wheel_inertia: float = 0.008
    wheel_damping: float = 0.002
    contact_stiffness: float = 1500.0
    mu: float = 0.8
    imu_position: tuple[float, float, float] = (0.05, 0.0, 0.08)
    gravity: float = 9.80665

    def __post_init__(self) -> None:
        for name in ("mass", "yaw_inertia", "caster_ahead", "wheel_radius", "wheel_distance",
                     "wheel_inertia", "contact_stiffness", "mu", "gravity"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"BodyParams.{name} must be finite and > 0, got {value!r}")
        if not 0 <= self.com_ahead < self.caster_ahead:
            raise ValueError(f"BodyParams needs 0 <= com_ahead < caster_ahead, got "
                             f"{self.com_ahead!r}, {self.caster_ahead!r}")
        if not (math.isfinite(self.wheel_damping) and self.wheel_damping >= 0):
            raise ValueError(f"BodyParams.wheel_damping must be >= 0, got {self.wheel_damping!r}")

    @property
    def wheel_load_fraction(self) -> float:
        """Share of the weight on the two driven wheels (static moment balance), 1."""
        return 1.0 - self.com_ahead / self.caster_ahead

    @property
    def wheel_normal_load(self) -> float:
        """Normal load on one driven wheel, N."""
        return 0.5 * self.mass * self.gravity * self.wheel_load_fraction

    def traction_limit(self, mu: float | None = None) -> float:
        """Largest forward acceleration the wheels can give the whole robot, m/s^2:
        ``mu * g * wheel_load_fraction`` (both wheels at their friction limit)."""
        mu = self.mu if mu is None else mu
        return mu * self.gravity * self.wheel_load_fraction


@dataclass(frozen=True)
class ControllerParams:
    """The chassis firmware: command ramp and per-wheel PI speed loop (it uses robot.toml's
    NOMINAL geometry to turn a commanded twist into wheel speeds).

    Attributes:
        accel_limit: ramp of the commanded forward speed, m/s^2.
        angular_accel_limit: ramp of the commanded yaw rate, rad/s^2.
        kp: proportional gain, N m per rad/s of wheel-speed error.
        ki: integral gain, N m per rad of integrated wheel-speed error.
        torque_limit: motor torque saturation at the wheel shaft, N m.
    """

    accel_limit: float = 1.0
    angular_accel_limit: float = 3.0
    kp: float = 0.6
    ki: float = 4.0
    torque_limit: float = 1.5

    def __post_init__(self) -> None:
        for name in ("accel_limit", "angular_accel_limit", "kp", "torque_limit"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ControllerParams.{name} must be finite and > 0, got "
                                 f"{value!r}")
        if not (math.isfinite(self.ki) and self.ki >= 0):
            raise ValueError(f"ControllerParams.ki must be >= 0, got {self.ki!r}")
