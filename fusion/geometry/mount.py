"""The IMU mount rotation, the rate about the world vertical and the heading rate (tilt
compensation).

Frames: the IMU frame is the sensor's own axes; the base frame is ``base_footprint`` (x forward,
y left, z up, REP-103); the world frame is ENU (z up). The mount is given as URDF ``rpy`` of the
IMU link in the base frame: roll about x, pitch about y, yaw about z, fixed axes, so
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` takes IMU-frame vectors into the base frame.

The products are written out term by term (``R[i][0]*x + R[i][1]*y + R[i][2]*z``), not left
to BLAS, so that one sample (Python floats) and a batch (numpy columns) give the same floats:
IEEE multiplication and addition round the same way in both, while a matrix product may fuse
or reorder them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.geometry import quaternion as quat

__all__ = [
    "MIN_COS2_PITCH",
    "angle_from_vertical",
    "base_to_imu",
    "heading_coefficients",
    "heading_rate",
    "imu_to_base",
    "mount_matrix",
    "vertical_rate",
]


def mount_matrix(rpy: ArrayLike) -> NDArray[np.float64]:
    """(3, 3) rotation matrix taking IMU-frame vectors into the base frame.

    Args:
        rpy: URDF roll, pitch, yaw of the IMU in the base frame, rad.

    Raises:
        ValueError: ``rpy`` that is not three finite numbers.
    """
    r = np.asarray(rpy, dtype=float)
    if r.shape != (3,) or not np.isfinite(r).all():
        raise ValueError(f"rpy must be three finite angles in rad, got {rpy!r}")
    return quat.to_matrix(quat.from_euler(r[0], r[1], r[2]))


def angle_from_vertical(v: ArrayLike) -> float:
    """rad: the angle between a vector (3,), e.g. a mean specific force (at rest it points
    up), and the +z axis of its frame; NaN for a zero or non-finite vector. Over 90 deg: the
    frame is upside down."""
    f = np.asarray(v, dtype=float).reshape(3)
    n = float(np.linalg.norm(f))
    if not (np.isfinite(n) and n > 0):
        return float("nan")
    return float(np.arccos(np.clip(f[2] / n, -1.0, 1.0)))


def _vectors(v: ArrayLike) -> NDArray[np.float64]:
    a = np.asarray(v, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"vectors must have shape (..., 3), got {a.shape}")
    return a


def imu_to_base(R: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """IMU-frame vectors ``v`` (..., 3) -> base frame, ``R @ v`` for each (units of ``v``).

    ``R`` is :func:`mount_matrix` (an array or nested lists). Same floats for one vector and
    for a stack of them (module docstring).
    """
    R = np.asarray(R, dtype=np.float64).tolist()
    a = _vectors(v)
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    return np.stack([R[0][0] * x + R[0][1] * y + R[0][2] * z,
                     R[1][0] * x + R[1][1] * y + R[1][2] * z,
                     R[2][0] * x + R[2][1] * y + R[2][2] * z], axis=-1)


def base_to_imu(R: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """Base-frame vectors ``v`` (..., 3) -> IMU frame, ``R.T @ v`` (what the sensor measures)."""
    return imu_to_base(np.asarray(R, dtype=np.float64).T, v)


def _gyro_rates(gyro: ArrayLike) -> NDArray[np.float64]:
    """``gyro`` as float rates (..., 3), rad/s; ValueError naming any other shape."""
    g = np.asarray(gyro, dtype=float)
    if g.shape[-1:] != (3,):
        raise ValueError(f"gyro must have shape (..., 3), got {g.shape}")
    return g


def vertical_rate(gyro: ArrayLike, quaternion: ArrayLike | None = None) -> NDArray[np.float64]:
    """Rate about the world vertical (rad/s) from body-frame gyro rates (..., 3).

    With ``quaternion`` (scalar first ``[w, x, y, z]``, body -> world ENU, e.g. the Keel
    attitude; normalised here) the body rate is rotated into the world frame and its z
    component returned: ``R[2, :] @ gyro``, the tilt-compensated yaw rate. Without it the
    robot is taken as level and ``gyro[..., 2]`` is returned.

    Raises:
        ValueError: ``gyro`` not (..., 3) or ``quaternion`` not (..., 4).
    """
    g = _gyro_rates(gyro)
    if quaternion is None:
        return g[..., 2].copy()
    q = np.asarray(quaternion, dtype=float)
    if q.shape[-1:] != (4,):
        raise ValueError(f"quaternion must have shape (..., 4) [w, x, y, z], got {q.shape}")
    if q.size == 4 and g.size == 3:
        # one vector (a live sample): the same operations on Python floats, at a fraction
        # of the cost of numpy's per-call overhead, giving the same bits
        (w, x, y, z), (gx, gy, gz) = q.reshape(4).tolist(), g.reshape(3).tolist()
        n2 = w * w + x * x + y * y + z * z
        rate = (2.0 * (x * z - w * y) / n2 * gx + 2.0 * (y * z + w * x) / n2 * gy
                + (1.0 - 2.0 * (x * x + y * y) / n2) * gz)
        return np.full(g.shape[:-1], rate)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    n2 = w * w + x * x + y * y + z * z
    # third row of the rotation matrix of the normalised quaternion
    r20 = 2.0 * (x * z - w * y) / n2
    r21 = 2.0 * (y * z + w * x) / n2
    r22 = 1.0 - 2.0 * (x * x + y * y) / n2
    return r20 * g[..., 0] + r21 * g[..., 1] + r22 * g[..., 2]


#: Floor of ``cos(pitch)^2`` in :func:`heading_rate` (a pitch of about 84 deg): the heading of a
#: body pointing straight up is undefined, and no ground robot drives there.
MIN_COS2_PITCH = 0.01


def heading_coefficients(quaternion: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(ky, kz)``: the heading rate is ``ky * gyro_y + kz * gyro_z`` at attitude
    ``quaternion`` (``[w, x, y, z]``, body -> world ENU, normalised here; (..., 4)); the x
    rate does not enter it. ``ky = sin(roll)/cos(pitch)``, ``kz = cos(roll)/cos(pitch)``
    (:func:`heading_rate`), written with the rotation matrix's third row,
    ``ky = R21 / (1 - R20^2)`` and ``kz = R22 / (1 - R20^2)``, 1."""
    q = np.asarray(quaternion, dtype=float)
    if q.shape[-1:] != (4,):
        raise ValueError(f"quaternion must have shape (..., 4) [w, x, y, z], got {q.shape}")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    n2 = w * w + x * x + y * y + z * z
    r20 = 2.0 * (x * z - w * y) / n2
    r21 = 2.0 * (y * z + w * x) / n2
    r22 = 1.0 - 2.0 * (x * x + y * y) / n2
    c2 = np.maximum(1.0 - r20 * r20, MIN_COS2_PITCH)
    return r21 / c2, r22 / c2


def heading_rate(gyro: ArrayLike, quaternion: ArrayLike | None = None) -> NDArray[np.float64]:
    """Rate of the heading (the ZYX Euler yaw: the direction of the body x axis projected on
    the horizontal plane, what planar odometry integrates), rad/s, from body-frame gyro rates
    (..., 3) at attitude ``quaternion`` (``[w, x, y, z]``, body -> world ENU, e.g. the Keel
    attitude; normalised here).

    ``psi_dot = (gyro_y * sin(roll) + gyro_z * cos(roll)) / cos(pitch)``. This is not the
    rate about the world vertical (:func:`vertical_rate`): that one differs by
    ``roll_dot * sin(pitch)``, which does not average out when roll and pitch change together
    (driving across rolling hills: about 1.5 deg RMS of heading over 300 s on 10-15 deg
    slopes, benchmarks/terrain). Both agree on a level floor, on a constant tilt (a mount
    tilt) and whenever the robot turns about the world vertical. The pitch's cosine is
    floored (:data:`MIN_COS2_PITCH`). Exact on an exact attitude; with an estimated one, a
    pitch error scales every turn (``tan(pitch) * error``), where the vertical rate's error
    is of second order: the fusion pipeline adds the roll term to the vertical rate instead
    (``FusionPipeline._roll_term``). Without ``quaternion`` the robot is taken as level and
    ``gyro[..., 2]`` is returned.

    Raises:
        ValueError: ``gyro`` not (..., 3) or ``quaternion`` not (..., 4).
    """
    g = _gyro_rates(gyro)
    if quaternion is None:
        return g[..., 2].copy()
    ky, kz = heading_coefficients(quaternion)
    return ky * g[..., 1] + kz * g[..., 2]
