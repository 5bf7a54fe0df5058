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
    "ImuSample": "fusion.types.samples",
    "WheelTicks": "fusion.types.samples",
    "Mahony": "fusion.attitude.mahony",
    "MahonyParams": "fusion.attitude.mahony",
    "MahonyState": "fusion.attitude.mahony",
    "Keel": "fusion.attitude.keel",
    "KeelParams": "fusion.attitude.keel",
    "KeelState": "fusion.attitude.keel",
    "KeelDiagnostics": "fusion.attitude.keel",
    "keel_offline": "fusion.attitude.keel_offline",
    "DiffDriveParams": "fusion.geometry.kinematics",
    "WheelOdometry": "fusion.planar.odometry",
    "TwistOdometry": "fusion.planar.odometry",
    "OdometryState": "fusion.planar.odometry",
    "OdometryNoise": "fusion.planar.odometry",
    "FusedOdometry": "fusion.types.fused",
    "open_sink": "fusion.sinks.registry",
    "read_bag": "fusion.io.bags",
    "ImuCalibration": "fusion.calibration.imu",
    "PlanarEKF": "fusion.planar.ekf",
    "EkfNoise": "fusion.planar.ekf",
    "AccelSlipDetector": "fusion.planar.accel_slip",
    "AccelSlipParams": "fusion.planar.accel_slip",
    "read_logdir": "fusion.io.logdir",
    "write_logdir": "fusion.io.logdir",
    "calibrate_odometry": "fusion.calibration.odometry",
    "umbmark": "fusion.calibration.odometry",
    "FusionPipeline": "fusion.pipeline.core",
    "LiveRunner": "fusion.pipeline.live",
    "load_config": "fusion.io.run_config",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'fusion' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
