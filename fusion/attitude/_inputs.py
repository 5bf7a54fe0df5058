"""Input checks shared by the attitude filters (shapes, periods), with clear messages."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.geometry import quaternion as quat

__all__ = [
    "as_rows",
    "check_dt",
    "check_dts",
    "explicit_periods",
    "finite_vec3",
    "timestamps_array",
    "unit_quaternion",
    "vec3",
]

_F64 = np.dtype(np.float64)


def check_dt(dt: float) -> float:
    """``dt`` as a float, or ``ValueError`` unless it is finite and > 0 (s)."""
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"sample period dt must be finite and > 0 s, got {dt!r}")
    return dt


def check_dts(dts: NDArray, message: str) -> None:
    """``ValueError`` naming the first index whose period is not finite and > 0."""
    bad = ~(np.isfinite(dts) & (dts > 0))
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{message} {i} (dt = {dts[i]!r} s)")


def as_rows(name: str, a: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
    """``a`` as a C-contiguous float64 (N, 3) array (with ``n`` rows when given)."""
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} rows but gyro has {n}")
    return arr


def vec3(name: str, v: ArrayLike) -> NDArray[np.float64]:
    """``v`` as a float64 (3,) array; the common case costs one type check."""
    if type(v) is np.ndarray and v.dtype is _F64 and v.shape == (3,):
        return v
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got shape {arr.shape}")
    return arr


def finite_vec3(name: str, v: ArrayLike) -> NDArray[np.float64]:
    """``v`` as a finite float64 (3,) array (a copy); ``ValueError`` naming ``name`` else."""
    arr = np.array(v, dtype=np.float64)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def unit_quaternion(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """A finite non-zero (4,) quaternion, normalised; ``ValueError`` naming ``name`` else."""
    q = np.asarray(value, dtype=np.float64)
    if q.shape != (4,):
        raise ValueError(f"{name} must have shape (4,), got {q.shape}")
    if not (np.all(np.isfinite(q)) and np.any(q != 0.0)):
        raise ValueError(f"{name} must be finite and non-zero, got {value!r}")
    return quat.normalize(q)


def timestamps_array(timestamps: ArrayLike, n: int) -> NDArray[np.float64]:
    """``timestamps`` as a finite float64 (n,) array (s), or ``ValueError`` naming the index."""
    t = np.asarray(timestamps, dtype=np.float64)
    if t.shape != (n,):
        raise ValueError(f"timestamps must have shape ({n},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(f"timestamps[{bad}] is not finite ({t[bad]!r})")
    return t


def explicit_periods(dt: float | ArrayLike, n: int) -> NDArray[np.float64]:
    """A constant period or n per-sample periods (s) as a checked contiguous array."""
    dts = np.atleast_1d(np.asarray(dt, dtype=np.float64))
    if dts.shape not in ((1,), (n,)):
        raise ValueError(f"dt must be a scalar or have shape ({n},), got {dts.shape}")
    check_dts(dts, "dt must be finite and > 0 s: at index")
    return np.ascontiguousarray(dts)
