"""One fused odometry output record, the unit every sink in :mod:`fusion.sinks` consumes.

Frames follow ROS REP-105 and REP-103: the pose is ``child_frame_id`` (``base_footprint``, x
forward, y left, z up) in ``frame_id`` (``odom``, ENU-like, z up); the twist is in the child
frame. Covariances use nav_msgs/Odometry's layout: 6x6 row major over
``(x, y, z, roll, pitch, yaw)`` for the pose and ``(vx, vy, vz, wx, wy, wz)`` for the twist.
Units are SI: s, m, rad, m/s, rad/s, m/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.types.constants import UNOBSERVED_VARIANCE

__all__ = ["FusedOdometry", "quaternion_norm", "yaw_quaternion"]



def yaw_quaternion(yaw: float) -> NDArray[np.float64]:
    """Quaternion ``[w, x, y, z]`` of a rotation by ``yaw`` (rad) about +z."""
    return np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])


def quaternion_norm(q: NDArray[np.float64]) -> float:
    """Euclidean norm of a (4,) quaternion, summed left to right in plain floats.

    Not ``q @ q`` or ``np.linalg.norm``: those go through BLAS, whose kernel (and so the last
    bit of the result) depends on the CPU, and the records must be the same bytes on every
    machine (tests/test_pipeline_golden.py).
    """
    w, x, y, z = q.tolist()
    return math.sqrt(w * w + x * x + y * y + z * z)


def _frozen(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a.setflags(write=False)
    return a


def _vector(name: str, value: ArrayLike, size: int) -> NDArray[np.float64]:
    a = np.array(value, dtype=np.float64).reshape(-1)
    if a.shape != (size,):
        raise ValueError(f"{name} must have {size} elements, got shape {np.shape(value)}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return _frozen(a)


def _default_covariance(observed: tuple[int, ...]) -> NDArray[np.float64]:
    diag = np.full(6, UNOBSERVED_VARIANCE)
    diag[list(observed)] = 0.0
    return _frozen(np.diag(diag))


# shared read-only defaults: building them per record would cost more than the record
_DEFAULT_POSE_COV = _default_covariance((0, 1, 5))
_DEFAULT_TWIST_COV = _default_covariance((0, 5))


def _covariance(
    name: str, value: ArrayLike | None, default: NDArray[np.float64]
) -> NDArray[np.float64]:
    if value is None:
        return default
    a = np.array(value, dtype=np.float64)
    if a.size != 36 or a.ndim not in (1, 2) or (a.ndim == 2 and a.shape != (6, 6)):
        raise ValueError(f"{name} must be 6x6 or 36 elements (row major), got shape {a.shape}")
    a = a.reshape(6, 6)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    # symmetric to rounding: |a - a.T| <= 1e-9 * max|a| (+ 1e-12 absolute); exact is common
    if not (a == a.T).all() and np.abs(a - a.T).max() > 1e-9 * np.abs(a).max() + 1e-12:
        raise ValueError(f"{name} must be symmetric, got\n{a}")
    return _frozen(a)


@dataclass(frozen=True, eq=False)
class FusedOdometry:
    """The fused planar state at one instant, with what the ROS/Foxglove sinks publish.

    Attributes:
        t: stamp, s (the host clock of the live pipeline, or the log's stamps in replay).
        x, y: position of ``child_frame_id`` in ``frame_id``, m.
        yaw: heading about +z in ``frame_id``, rad (any range; sinks use it through
            :func:`yaw_quaternion`, which is 2*pi periodic).
        v: forward speed in ``child_frame_id``, m/s.
        w: yaw rate, rad/s.
        pose_covariance: (6, 6) over ``(x, y, z, roll, pitch, yaw)`` (m^2, m*rad, rad^2);
            a (36,) row-major array is accepted. Default: 0 (unknown) on x, y, yaw and
            seed 000's 99999 on z, roll, pitch, which a planar filter does not estimate.
        twist_covariance: (6, 6) over ``(vx, vy, vz, wx, wy, wz)`` ((m/s)^2, rad^2/s^2);
            default 0 on vx and wz, 99999 on the rest.
        orientation: full attitude ``[w, x, y, z]`` of the body in ENU from the attitude filter
            (unit norm, normalised here), or None; :attr:`orientation_or_yaw` falls back to the
            yaw-only quaternion. The odometry pose and tf always use the yaw-only quaternion
            (``base_footprint`` is planar); the IMU message uses this one.
        angular_velocity: (3,) body rate, rad/s (gyro, bias-corrected if the filter did so).
        linear_acceleration: (3,) specific force, m/s^2 (+g up at rest), or None.
        wheel_left_speed, wheel_right_speed: wheel rim speeds, m/s, or None.
        frame_id, child_frame_id: frame names (REP-105 defaults ``odom``, ``base_footprint``).
        imu_frame_id: frame of the IMU message (default: ``child_frame_id``).
        zupt, slip, encoder_fault: what the EKF made of the last wheel frame (or odometry
            twist) before this record: a zero-velocity update (wheels and IMU still), a slip
            (its yaw rate disagreed with the gyro and was not fused), an encoder fault (zero
            wheel speed while the IMU showed motion; not fused, the pose coasted).
    """

    t: float
    x: float
    y: float
    yaw: float
    v: float
    w: float
    pose_covariance: NDArray[np.float64] | None = None
    twist_covariance: NDArray[np.float64] | None = None
    orientation: NDArray[np.float64] | None = None
    angular_velocity: NDArray[np.float64] | None = None
    linear_acceleration: NDArray[np.float64] | None = None
    wheel_left_speed: float | None = None
    wheel_right_speed: float | None = None
    frame_id: str = "odom"
    child_frame_id: str = "base_footprint"
    imu_frame_id: str | None = field(default=None)
    zupt: bool = False
    slip: bool = False
    encoder_fault: bool = False

    def __post_init__(self) -> None:
        put = partial(object.__setattr__, self)  # the dataclass is frozen
        scalars = (float(self.t), float(self.x), float(self.y), float(self.yaw), float(self.v),
                   float(self.w))
        if not math.isfinite(sum(scalars)):  # any inf or nan makes the sum non-finite
            for name, value in zip(("t", "x", "y", "yaw", "v", "w"), scalars):
                if not math.isfinite(value):
                    raise ValueError(f"FusedOdometry.{name} must be finite, got {value}")
        for name, value in zip(("t", "x", "y", "yaw", "v", "w"), scalars):
            put(name, value)
        put("pose_covariance",
            _covariance("pose_covariance", self.pose_covariance, _DEFAULT_POSE_COV))
        put("twist_covariance",
            _covariance("twist_covariance", self.twist_covariance, _DEFAULT_TWIST_COV))
        if self.orientation is not None:
            q = np.array(self.orientation, dtype=np.float64).reshape(-1)
            if q.shape != (4,) or not np.isfinite(q).all():
                raise ValueError(f"orientation must be a finite [w, x, y, z], got {q.tolist()}")
            n = quaternion_norm(q)
            if abs(n - 1.0) > 1e-3:
                raise ValueError(f"orientation must be a unit quaternion, norm is {n:.6g}")
            put("orientation", _frozen(q / n))
        if self.angular_velocity is None:
            put("angular_velocity", _frozen(np.array([0.0, 0.0, self.w])))
        else:
            put("angular_velocity", _vector("angular_velocity", self.angular_velocity, 3))
        if self.linear_acceleration is not None:
            put("linear_acceleration",
                _vector("linear_acceleration", self.linear_acceleration, 3))
        for name in ("wheel_left_speed", "wheel_right_speed"):
            value = getattr(self, name)
            if value is not None:
                value = float(value)
                if not math.isfinite(value):
                    raise ValueError(f"FusedOdometry.{name} must be finite, got {value}")
                put(name, value)
        for name in ("frame_id", "child_frame_id"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise ValueError(f"FusedOdometry.{name} must be a non-empty string")
        if self.imu_frame_id is None:
            put("imu_frame_id", self.child_frame_id)
        for name in ("zupt", "slip", "encoder_fault"):
            put(name, bool(getattr(self, name)))

    @property
    def yaw_quaternion(self) -> NDArray[np.float64]:
        """Yaw-only orientation ``[w, x, y, z]`` of ``child_frame_id`` in ``frame_id``."""
        return yaw_quaternion(self.yaw)

    @property
    def orientation_or_yaw(self) -> NDArray[np.float64]:
        """The full attitude when known, else the yaw-only quaternion, ``[w, x, y, z]``."""
        return self.orientation if self.orientation is not None else self.yaw_quaternion

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (floats, lists, strings; None for absent optional fields).

        Covariances are flattened to 36 row-major numbers, as in nav_msgs/Odometry.
        """
        def opt(a: NDArray[np.float64] | None) -> list[float] | None:
            return None if a is None else [float(v) for v in a.reshape(-1)]

        return {
            "t": self.t, "x": self.x, "y": self.y, "yaw": self.yaw, "v": self.v, "w": self.w,
            "pose_covariance": opt(self.pose_covariance),
            "twist_covariance": opt(self.twist_covariance),
            "orientation": opt(self.orientation),
            "angular_velocity": opt(self.angular_velocity),
            "linear_acceleration": opt(self.linear_acceleration),
            "wheel_left_speed": self.wheel_left_speed,
            "wheel_right_speed": self.wheel_right_speed,
            "frame_id": self.frame_id,
            "child_frame_id": self.child_frame_id,
            "imu_frame_id": self.imu_frame_id,
            "zupt": self.zupt,
            "slip": self.slip,
            "encoder_fault": self.encoder_fault,
        }

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FusedOdometry):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]  # holds arrays: not hashable

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FusedOdometry:
        """Inverse of :meth:`to_dict` (unknown keys are a ValueError naming them)."""
        names = set(cls.__dataclass_fields__)
        extra = sorted(set(d) - names)
        if extra:
            raise ValueError(f"unknown FusedOdometry fields: {', '.join(extra)}")
        return cls(**d)
