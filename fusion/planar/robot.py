"""The robot description the estimators and the pipeline run with: chassis geometry, frames,
IMU mount and EKF tuning (the content of ``robot.toml``; read and written by
:mod:`fusion.io.robot_toml`).
"""

from __future__ import annotations

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
    """

    chassis: DiffDriveParams
    odom_frame: str = "odom"
    base_frame: str = "base_footprint"
    imu_mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ekf: EkfNoise = field(default_factory=EkfNoise)

    def imu_to_base(self) -> NDArray[np.float64]:
        """Quaternion ``[w, x, y, z]`` taking IMU-frame vectors into the base frame."""
        return quat.from_euler(*self.imu_mount_rpy)
