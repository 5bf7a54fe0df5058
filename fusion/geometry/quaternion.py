"""Vectorised quaternion helpers.

Conventions (see DESIGN.md): Hamilton quaternions, scalar first ``[w, x, y, z]``, mapping the
body (sensor) frame to the world frame, world ENU (x east, y north, z up), body x forward,
y left, z up (REP-103). Euler angles are roll, pitch, yaw of the ZYX (yaw-pitch-roll) sequence,
in radians. Every function accepts a single quaternion of shape ``(4,)`` or a stack ``(..., 4)``
and broadcasts like numpy.

scipy's :class:`~scipy.spatial.transform.Rotation` is scalar-last; the crossing happens only in
:func:`to_scipy` and :func:`from_scipy`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "IDENTITY",
    "conjugate",
    "from_accel",
    "from_accel_mag",
    "from_euler",
    "from_matrix",
    "from_rotation_vector",
    "from_scipy",
    "multiply",
    "normalize",
    "rotate",
    "rotate_inverse",
    "to_euler",
    "to_matrix",
    "to_scipy",
]

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _as_quat(q: ArrayLike, name: str = "q") -> NDArray[np.float64]:
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (4,):
        raise ValueError(f"{name} must have shape (..., 4) [w, x, y, z], got {q.shape}")
    return q


def _as_vec(v: ArrayLike, name: str = "v") -> NDArray[np.float64]:
    v = np.asarray(v, dtype=float)
    if v.shape[-1:] != (3,):
        raise ValueError(f"{name} must have shape (..., 3), got {v.shape}")
    return v


def multiply(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p``)."""
    p = _as_quat(p, "p")
    q = _as_quat(q, "q")
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> NDArray[np.float64]:
    """Conjugate ``[w, -x, -y, -z]``: the inverse rotation of a unit quaternion."""
    q = _as_quat(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: ArrayLike) -> NDArray[np.float64]:
    """Scale to unit norm. Raises ``ValueError`` for a zero or non-finite quaternion."""
    q = _as_quat(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n == 0.0):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return q / n


def to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix ``R`` (..., 3, 3) of a unit quaternion: ``v_world = R @ v_body``."""
    w, x, y, z = np.moveaxis(_as_quat(q), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (scalar first, ``w >= 0``) of a rotation matrix (..., 3, 3).

    Uses the numerically stable branch on the largest of ``w, x, y, z`` (Shepperd's method).
    """
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got {R.shape}")
    m = R.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    # 4 * squared components, each from the diagonal: pick the largest for stability.
    cand = np.stack(
        [1 + tr, 1 + 2 * m[:, 0, 0] - tr, 1 + 2 * m[:, 1, 1] - tr, 1 + 2 * m[:, 2, 2] - tr], -1
    )
    k = np.argmax(cand, axis=-1)
    q = np.empty((m.shape[0], 4))
    s = np.sqrt(np.maximum(cand[np.arange(len(k)), k], 0.0)) * 2.0  # s = 4 * |component|
    d21, d02, d10 = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    s01, s02, s12 = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    rows = {
        0: (s / 4, d21 / s, d02 / s, d10 / s),
        1: (d21 / s, s / 4, s01 / s, s02 / s),
        2: (d02 / s, s01 / s, s / 4, s12 / s),
        3: (d10 / s, s02 / s, s12 / s, s / 4),
    }
    with np.errstate(divide="ignore", invalid="ignore"):
        for branch, comps in rows.items():
            sel = k == branch
            if np.any(sel):
                q[sel] = np.stack([c[sel] for c in comps], -1)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape((*R.shape[:-2], 4))


def rotate(q: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """Rotate vectors by ``q``: body-frame ``v`` (..., 3) to world frame, ``q v q*``."""
    q = _as_quat(q)
    v = _as_vec(v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotate_inverse(q: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """Rotate world-frame vectors into the body frame, ``q* v q``."""
    return rotate(conjugate(q), v)


def to_euler(q: ArrayLike) -> NDArray[np.float64]:
    """Roll, pitch, yaw (..., 3) in radians, ZYX sequence, with the seed's formulas.

    roll = atan2(2(wx + yz), 1 - 2(x^2 + y^2)), pitch = asin(2(wy - xz)) (argument clipped to
    [-1, 1] so rounding at +-90 deg cannot give NaN), yaw = atan2(2(wz + xy), 1 - 2(y^2 + z^2)).
    """
    w, x, y, z = np.moveaxis(_as_quat(q), -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def from_euler(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> NDArray[np.float64]:
    """Quaternion of ZYX Euler angles (radians): ``q = qz(yaw) * qy(pitch) * qx(roll)``."""
    hr, hp, hy = (np.asarray(a, dtype=float) / 2 for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def from_rotation_vector(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Quaternion of a rotation vector (axis * angle, radians), exact for any angle."""
    r = _as_vec(rotvec, "rotvec")
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = angle / 2
    # sin(half)/angle -> 1/2 as angle -> 0 (Taylor series avoids 0/0).
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(angle > 1e-8, np.sin(half) / angle, 0.5 - angle**2 / 48)
    return np.concatenate([np.cos(half), r * k], axis=-1)


def from_accel(accel: ArrayLike) -> NDArray[np.float64]:
    """Attitude (yaw = 0) from a static accelerometer reading (specific force, m/s^2, body).

    At rest the accelerometer measures +g along world up, so roll = atan2(ay, az) and
    pitch = atan2(-ax, sqrt(ay^2 + az^2)). Raises ``ValueError`` for a zero vector.
    """
    a = _as_vec(accel, "accel")
    n = np.linalg.norm(a, axis=-1)
    if np.any(~np.isfinite(n)) or np.any(n == 0.0):
        raise ValueError("accelerometer vector must be finite and non-zero")
    roll = np.arctan2(a[..., 1], a[..., 2])
    pitch = np.arctan2(-a[..., 0], np.hypot(a[..., 1], a[..., 2]))
    return from_euler(roll, pitch, np.zeros_like(roll))


def from_accel_mag(accel: ArrayLike, mag: ArrayLike) -> NDArray[np.float64]:
    """Attitude body -> ENU from an accelerometer and a magnetometer reading (body frame).

    Up is the measured specific force, east = mag x up, north = up x east; yaw is relative to
    magnetic north (no declination). Raises ``ValueError`` when the vectors are zero or parallel.
    """
    up = _as_vec(accel, "accel")
    m = _as_vec(mag, "mag")
    east = np.cross(m, up)
    north = np.cross(up, east)
    axes = [east, north, up]
    norms = [np.linalg.norm(a, axis=-1, keepdims=True) for a in axes]
    if any(np.any(~np.isfinite(n)) or np.any(n == 0.0) for n in norms):
        raise ValueError("accelerometer and magnetometer must be finite, non-zero, not parallel")
    # Rows of R (body -> world) are the world axes expressed in the body frame.
    R = np.stack([a / n for a, n in zip(axes, norms)], axis=-2)
    return from_matrix(R)


def to_scipy(q: ArrayLike):
    """scipy ``Rotation`` of scalar-first quaternions (the one scalar-first -> last crossing)."""
    from scipy.spatial.transform import Rotation

    q = _as_quat(q)
    return Rotation.from_quat(np.roll(q, -1, axis=-1))


def from_scipy(rotation) -> NDArray[np.float64]:
    """Scalar-first quaternions of a scipy ``Rotation`` (sign as scipy returns it)."""
    return np.roll(rotation.as_quat(), 1, axis=-1)
