"""The robot description the estimators and the pipeline run with: chassis geometry, frames,
IMU mount, EKF tuning and the attitude filter's choice (the content of ``robot.toml``; read and
written by :mod:`fusion.io.robot_toml`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.geometry import quaternion as quat
from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.ekf import EkfNoise
from fusion.planar.imu_motion import MotionThresholds

__all__ = ["ATTITUDE_FILTERS", "AttitudeConfig", "RobotConfig"]

#: Attitude filters the pipeline can run (``[attitude] filter``).
ATTITUDE_FILTERS = ("keel", "mahony")


@dataclass(frozen=True)
class AttitudeConfig:
    """The ``[attitude]`` table: which attitude filter the pipeline runs, with what parameters.

    Plain data (this layer does not import the filters): the names are checked against the
    filter's parameter class by :mod:`fusion.io.robot_toml` and the filter is built by
    :func:`fusion.attitude.select.build_attitude_filter`.

    Attributes:
        filter: ``"keel"`` (default) or ``"mahony"``.
        params: ``(name, value)`` pairs of the filter's parameter class (SI units:
            :class:`fusion.attitude.keel.KeelParams` or
            :class:`fusion.attitude.mahony.MahonyParams`; not ``sample_period``, which the
            pipeline sets from the IMU rate); the others keep their defaults.
        wheel_knowledge: feed the wheels' knowledge into the filter (Keel only: the centripetal
            acceleration v*w and known stillness, see :class:`fusion.pipeline.core.FusionPipeline`).
            None: on where the filter takes it (Keel), off for Mahony.
    """

    filter: str = "keel"
    params: tuple[tuple[str, Any], ...] = ()
    wheel_knowledge: bool | None = None

    def __post_init__(self) -> None:
        if self.filter not in ATTITUDE_FILTERS:
            raise ValueError(f"attitude filter must be one of {', '.join(ATTITUDE_FILTERS)}, "
                             f"got {self.filter!r}")
        if self.wheel_knowledge and self.filter != "keel":
            raise ValueError(f"wheel_knowledge is a Keel input: the {self.filter} filter "
                             "cannot use it")

    @property
    def uses_wheels(self) -> bool:
        """Whether the pipeline feeds the wheels' knowledge into the filter."""
        return self.filter == "keel" and self.wheel_knowledge is not False


@dataclass(frozen=True)
class RobotConfig:
    """The content of ``robot.toml``.

    Attributes:
        chassis: geometry and limits (seed 000's names).
        odom_frame, base_frame: REP-105 frame names of the published odometry.
        imu_mount_rpy: URDF roll, pitch, yaw (rad) of the IMU in the base frame.
        ekf: filter tuning (defaults where ``[ekf]`` is absent).
        attitude: the attitude filter of the pipeline (Keel with the wheels' knowledge where
            ``[attitude]`` is absent).
        imu_motion: when the IMU counts as still or moving for the zero-velocity updates and
            encoder faults (``[imu_motion]``; raise the stillness thresholds for an IMU that
            vibrates at rest: an engine, fans, a loose mount).

    Raises:
        ValueError: a chassis, tuning or attitude setting of the wrong type, an empty or blank
            frame name, or a mount angle that is not a finite number; the message names the
            field and the value.
    """

    chassis: DiffDriveParams
    odom_frame: str = "odom"
    base_frame: str = "base_footprint"
    imu_mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ekf: EkfNoise = field(default_factory=EkfNoise)
    attitude: AttitudeConfig = field(default_factory=AttitudeConfig)
    imu_motion: MotionThresholds = field(default_factory=MotionThresholds)

    def __post_init__(self) -> None:
        if not isinstance(self.chassis, DiffDriveParams):
            raise ValueError(f"RobotConfig.chassis must be a DiffDriveParams, got "
                             f"{self.chassis!r}")
        if not isinstance(self.ekf, EkfNoise):
            raise ValueError(f"RobotConfig.ekf must be an EkfNoise, got {self.ekf!r}")
        if not isinstance(self.imu_motion, MotionThresholds):
            raise ValueError(f"RobotConfig.imu_motion must be a MotionThresholds, got "
                             f"{self.imu_motion!r}")
        if not isinstance(self.attitude, AttitudeConfig):
            raise ValueError(f"RobotConfig.attitude must be an AttitudeConfig, got "
                             f"{self.attitude!r}")
        for name in ("odom_frame", "base_frame"):
            value = getattr(self, name)
            if not (isinstance(value, str) and value.strip() and value == value.strip()):
                raise ValueError(f"RobotConfig.{name} must be a frame name without spaces "
                                 f"around it, got {value!r}")
        rpy = self.imu_mount_rpy
        if not (isinstance(rpy, (tuple, list)) and len(rpy) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in rpy)):
            raise ValueError(f"RobotConfig.imu_mount_rpy must be 3 finite angles (roll, pitch, "
                             f"yaw) in rad, got {rpy!r}")

    def imu_to_base(self) -> NDArray[np.float64]:
        """Quaternion ``[w, x, y, z]`` taking IMU-frame vectors into the base frame."""
        return quat.from_euler(*self.imu_mount_rpy)
