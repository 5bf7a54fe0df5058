"""The robot description the estimators and the pipeline run with: chassis geometry, frames,
IMU mount and EKF tuning (the content of ``robot.toml``; read and written by
:mod:`fusion.io.robot_toml`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.geometry import quaternion as quat
from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.ekf import EkfNoise

__all__ = ["RobotConfig"]


@dataclass(frozen=True)
class RobotConfig:
    """The content of ``robot.toml``.

    Attributes:
        chassis: geometry and limits (seed 000's names).
        odom_frame, base_frame: REP-105 frame names of the published odometry.
        imu_mount_rpy: URDF roll, pitch, yaw (rad) of the IMU in the base frame.
        ekf: filter tuning (defaults where ``[ekf]`` is absent).

    Raises:
        ValueError: a chassis or tuning of the wrong type, an empty or blank frame name, or a
            mount angle that is not a finite number; the message names the field and value.
    """

    chassis: DiffDriveParams
    odom_frame: str = "odom"
    base_frame: str = "base_footprint"
    imu_mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ekf: EkfNoise = field(default_factory=EkfNoise)

    def __post_init__(self) -> None:
        if not isinstance(self.chassis, DiffDriveParams):
            raise ValueError(f"RobotConfig.chassis must be a DiffDriveParams, got "
                             f"{self.chassis!r}")
        if not isinstance(self.ekf, EkfNoise):
            raise ValueError(f"RobotConfig.ekf must be an EkfNoise, got {self.ekf!r}")
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
