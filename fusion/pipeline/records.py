"""Building :class:`fusion.types.fused.FusedOdometry` records from the filters' state (the
pipeline's hot path: no validation of what the filters already guarantee).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.angles import wrap_angle_scalar
from fusion.types.constants import UNOBSERVED_VARIANCE
from fusion.types.fused import FusedOdometry, quaternion_norm

__all__ = []


def _frozen(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a.setflags(write=False)
    return a


def _record_fields(t, x, p5, q, gyro_xy, accel, wheel_speeds, frame_id,
                   child_frame_id, flags=0) -> dict[str, Any]:
    """The :class:`FusedOdometry` fields of a filter state: ``x`` (at least v and w, as
    ``[x, y, yaw, v, w, ...]``), ``p5`` the 25 values of ``P[:5, :5]`` row major, ``flags``
    the EKF's flags of the last wheel frame (bits 1 ZUPT, 2 slip, 4 encoder fault); the
    nav_msgs/Odometry covariances in the layout of :func:`fusion.planar.ekf.odometry_covariances`,
    symmetrised."""
    (p00, p01, p02, _, _, p10, p11, p12, _, _, p20, p21, p22, _, _,
     _, _, _, p33, p34, _, _, _, p43, p44) = p5
    c01, c02, c12 = 0.5 * (p01 + p10), 0.5 * (p02 + p20), 0.5 * (p12 + p21)
    u = UNOBSERVED_VARIANCE
    pose = [p00, c01, 0.0, 0.0, 0.0, c02,
            c01, p11, 0.0, 0.0, 0.0, c12,
            0.0, 0.0, u, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, u, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, u, 0.0,
            c02, c12, 0.0, 0.0, 0.0, p22]
    c34 = 0.5 * (p34 + p43)
    twist = [p33, 0.0, 0.0, 0.0, 0.0, c34,
             0.0, u, 0.0, 0.0, 0.0, 0.0,
             0.0, 0.0, u, 0.0, 0.0, 0.0,
             0.0, 0.0, 0.0, u, 0.0, 0.0,
             0.0, 0.0, 0.0, 0.0, u, 0.0,
             c34, 0.0, 0.0, 0.0, 0.0, p44]
    w = float(x[4])
    if gyro_xy is None:
        av = (0.0, 0.0, w)
    else:
        av = (gyro_xy[0], gyro_xy[1], w)
    return {
        "t": float(t), "x": float(x[0]), "y": float(x[1]),
        "yaw": wrap_angle_scalar(float(x[2])), "v": float(x[3]), "w": w,
        "pose_covariance": np.array(pose).reshape(6, 6),
        "twist_covariance": np.array(twist).reshape(6, 6),
        "orientation": None if q is None else np.asarray(q, dtype=np.float64).tolist(),
        "angular_velocity": av,
        "linear_acceleration": None if accel is None
        else np.asarray(accel, dtype=np.float64).tolist(),
        "wheel_left_speed": None if wheel_speeds is None else float(wheel_speeds[0]),
        "wheel_right_speed": None if wheel_speeds is None else float(wheel_speeds[1]),
        "frame_id": frame_id, "child_frame_id": child_frame_id,
        "zupt": bool(flags & 1), "slip": bool(flags & 2), "encoder_fault": bool(flags & 4),
        "_sum": sum(pose) + sum(twist),
    }


def _fast_record(f: dict[str, Any]) -> FusedOdometry:
    """``FusedOdometry(**f)`` for fields from :func:`_record_fields` (without its ``_sum``
    key), at a fraction of the cost (tests/test_pipeline.py checks the two are equal): the
    covariances are symmetric by construction there, so only finiteness is checked here, and
    a non-finite state goes through the validating constructor, which raises naming the
    field."""
    av, q, accel = f["angular_velocity"], f["orientation"], f["linear_acceleration"]
    total = f["_sum"] + f["t"] + f["x"] + f["y"] + f["yaw"] + f["v"] + f["w"] + av[0] + av[1]
    qn = 1.0
    if q is not None:
        qn = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        total += qn
    if accel is not None:
        total += accel[0] + accel[1] + accel[2]
    if not math.isfinite(total) or abs(qn - 1.0) > 1e-3:
        return FusedOdometry(**{k: v for k, v in f.items() if k != "_sum"})  # raises
    rec = object.__new__(FusedOdometry)
    put = object.__setattr__
    put(rec, "t", f["t"])
    put(rec, "x", f["x"])
    put(rec, "y", f["y"])
    put(rec, "yaw", f["yaw"])
    put(rec, "v", f["v"])
    put(rec, "w", f["w"])
    put(rec, "wheel_left_speed", f["wheel_left_speed"])
    put(rec, "wheel_right_speed", f["wheel_right_speed"])
    put(rec, "frame_id", f["frame_id"])
    put(rec, "child_frame_id", f["child_frame_id"])
    pose, twist = f["pose_covariance"], f["twist_covariance"]
    pose.setflags(write=False)  # fresh arrays from _record_fields
    twist.setflags(write=False)
    put(rec, "pose_covariance", pose)
    put(rec, "twist_covariance", twist)
    if q is not None:
        qa = np.array(q, dtype=np.float64)
        # what FusedOdometry does: q / quaternion_norm(q)
        put(rec, "orientation", _frozen(qa / quaternion_norm(qa)))
    else:
        put(rec, "orientation", None)
    put(rec, "angular_velocity", _frozen(np.array(av, dtype=np.float64)))
    put(rec, "linear_acceleration",
        None if accel is None else _frozen(np.array(accel, dtype=np.float64)))
    put(rec, "imu_frame_id", f["child_frame_id"])
    put(rec, "zupt", f["zupt"])
    put(rec, "slip", f["slip"])
    put(rec, "encoder_fault", f["encoder_fault"])
    return rec
