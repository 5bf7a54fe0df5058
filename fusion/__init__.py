"""diffbot-fusion: attitude, odometry and sensor fusion for two-wheel differential-drive robots.

Public names are imported lazily (no import-time work): ``from fusion import Mahony``.
Units are SI throughout (rad/s, m/s^2, m, s, rad, uT); quaternions are scalar first
``[w, x, y, z]``, body -> world ENU.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS = {
    "ImuSample": "fusion.samples",
    "WheelTicks": "fusion.samples",
    "Mahony": "fusion.mahony",
    "MahonyParams": "fusion.mahony",
    "MahonyState": "fusion.mahony",
    "DiffDriveParams": "fusion.kinematics",
    "WheelOdometry": "fusion.odometry",
    "TwistOdometry": "fusion.odometry",
    "OdometryState": "fusion.odometry",
    "OdometryNoise": "fusion.odometry",
    "FusedOdometry": "fusion.fused",
    "open_sink": "fusion.publish",
    "read_bag": "fusion.logs",
    "ImuCalibration": "fusion.calibration",
    "PlanarEKF": "fusion.ekf",
    "EkfNoise": "fusion.ekf",
    "read_logdir": "fusion.logdir",
    "write_logdir": "fusion.logdir",
    "calibrate_odometry": "fusion.odometry_calibration",
    "umbmark": "fusion.odometry_calibration",
    "FusionPipeline": "fusion.pipeline",
    "LiveRunner": "fusion.pipeline",
    "load_config": "fusion.config",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'fusion' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
