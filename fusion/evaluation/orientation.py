"""Orientation error metrics of the BROAD benchmark.

Definitions (D. Laidig et al., BROAD, Data 6(7):72, 2021; datasets/broad/README.md): with
``q_err = q_est * conj(q_ref)`` (both body -> world, the error expressed in the world frame),

- total error = ``2 * acos(|w|)``,
- heading error = ``2 * atan(|z / w|)`` (the rotation about the vertical),
- inclination error = ``2 * acos(sqrt(w^2 + z^2))`` (the tilt),

each reported as an RMSE in degrees over the samples where ``movement`` is set and both the
estimate and the reference are finite.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.geometry import quaternion as quat

__all__ = ["OrientationErrors", "error_angles", "orientation_rmse"]


def error_angles(q_est: ArrayLike, q_ref: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Per-sample total, heading and inclination errors in radians, shape (N,) each.

    Rows where either input is non-finite give NaN.
    """
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    if q_est.shape != q_ref.shape:
        raise ValueError(f"q_est {q_est.shape} and q_ref {q_ref.shape} differ in shape")
    e = quat.multiply(q_est, quat.conjugate(q_ref))
    e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    w, z = e[..., 0], e[..., 3]
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        heading = 2.0 * np.arctan(np.abs(z / w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return total, heading, inclination


@dataclass(frozen=True)
class OrientationErrors:
    """RMSE of the BROAD error angles, degrees, and how many samples entered them."""

    total_deg: float
    heading_deg: float
    inclination_deg: float
    samples: int


def orientation_rmse(
    q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None
) -> OrientationErrors:
    """BROAD RMSEs (degrees) over ``mask`` (e.g. the trial's ``movement``) and finite rows."""
    total, heading, incl = error_angles(q_est, q_ref)
    valid = np.isfinite(total) & np.isfinite(heading) & np.isfinite(incl)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool).reshape(-1)
        if mask.shape != valid.shape:
            raise ValueError(f"mask has {mask.shape[0]} rows, the estimates {valid.shape[0]}")
        valid &= mask
    n = int(np.count_nonzero(valid))
    if n == 0:
        raise ValueError("no valid samples to compute the errors over")

    def rmse(x: NDArray) -> float:
        return float(np.degrees(np.sqrt(np.mean(x[valid] ** 2))))

    return OrientationErrors(rmse(total), rmse(heading), rmse(incl), n)
