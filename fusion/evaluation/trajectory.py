"""Errors of planar trajectories against ground truth.

Poses are ``(x, y, yaw)`` in one frame (``odom``), x and y in m, yaw in rad. Angle differences
are wrapped to (-pi, pi] before any statistic, so a yaw of 179 deg against a truth of -179 deg
is an error of 2 deg.

- :func:`final_position_error_percent`: end-point error as a percentage of the path length
  (the "error % of distance" of seed 002's 5 % requirement).
- :func:`yaw_rmse`, :func:`position_rmse`: root mean square errors over a run.
- :func:`se2_alignment`, :func:`aligned_position_rmse`: the position RMSE after the one rigid
  planar motion that fits a track best to a reference in another frame (a GPS track in east,
  north; the absolute trajectory error of Sturm et al., IROS 2012, in the plane).
- :func:`nees`, :func:`nees_bounds`, :func:`nees_fraction_within`: normalised estimation error
  squared, the chi-square consistency test of a filter's covariance (Bar-Shalom, Li,
  Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, sec. 5.4).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from fusion.geometry.angles import wrap_angle

__all__ = [
    "aligned_position_rmse",
    "final_position_error_percent",
    "nees",
    "nees_bounds",
    "nees_fraction_within",
    "path_length",
    "pose_errors",
    "position_rmse",
    "se2_alignment",
    "wrap_angle",
    "yaw_rmse",
]


def _poses(p: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[1] < 2:
        raise ValueError(f"{name} must have shape (N, 2) or (N, 3), got {p.shape}")
    return p


def pose_errors(estimate: ArrayLike, truth: ArrayLike) -> NDArray[np.float64]:
    """(N, 3) errors ``estimate - truth`` of ``(x, y, yaw)`` rows, yaw wrapped (m, m, rad)."""
    e = _poses(estimate, "estimate")
    t = _poses(truth, "truth")
    if e.shape != t.shape or e.shape[1] != 3:
        raise ValueError(f"estimate and truth must both be (N, 3), got {e.shape}, {t.shape}")
    d = e - t
    d[:, 2] = wrap_angle(d[:, 2])
    return d


def path_length(xy: ArrayLike) -> float:
    """Length of the polyline through the (N, 2+) positions, m."""
    p = _poses(xy, "xy")[:, :2]
    return float(np.sum(np.hypot(*np.diff(p, axis=0).T)))


def final_position_error_percent(
    estimate_xy: ArrayLike, truth_xy: ArrayLike, distance: float | None = None
) -> float:
    """End-point position error as a percentage of the distance travelled.

    Args:
        estimate_xy, truth_xy: (N, 2+) positions, m; the last rows are compared.
        distance: path length, m (default: :func:`path_length` of the truth).
    """
    e = _poses(estimate_xy, "estimate_xy")
    t = _poses(truth_xy, "truth_xy")
    dist = path_length(t) if distance is None else float(distance)
    if not dist > 0:
        raise ValueError(f"distance travelled must be > 0 m, got {dist!r}")
    return float(100.0 * np.hypot(*(e[-1, :2] - t[-1, :2])) / dist)


def yaw_rmse(estimate_yaw: ArrayLike, truth_yaw: ArrayLike) -> float:
    """Root mean square of the wrapped yaw error, rad."""
    d = wrap_angle(np.asarray(estimate_yaw, dtype=float) - np.asarray(truth_yaw, dtype=float))
    if d.size == 0:
        raise ValueError("no samples")
    return float(np.sqrt(np.mean(d * d)))


def position_rmse(estimate_xy: ArrayLike, truth_xy: ArrayLike) -> float:
    """Root mean square of the position error (absolute trajectory error), m."""
    e = _poses(estimate_xy, "estimate_xy")[:, :2]
    t = _poses(truth_xy, "truth_xy")[:, :2]
    if e.shape != t.shape:
        raise ValueError(f"shapes differ: {e.shape} vs {t.shape}")
    return float(np.sqrt(np.mean(np.sum((e - t) ** 2, axis=1))))


def se2_alignment(estimate_xy: ArrayLike, reference_xy: ArrayLike
                  ) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """The rotation ``theta`` (rad) and translation ``t`` (2,) m that minimise the sum of
    squared distances ``|R(theta) e_i + t - r_i|^2`` between paired points of a track
    ``estimate_xy`` and a reference ``reference_xy`` ((N, 2) or wider, m), in closed form; and
    the track moved by them (N, 2). No scale: a distance error stays in the residual.

    When either side does not move (all its points equal), every rotation fits equally well:
    ``theta`` is then 0 (or whatever rounding makes of it) and the residual is still the
    least-squares one.

    Raises:
        ValueError: shapes differ, fewer than 2 points, or a value that is not finite.
    """
    e = _poses(estimate_xy, "estimate_xy")[:, :2]
    r = _poses(reference_xy, "reference_xy")[:, :2]
    if e.shape != r.shape:
        raise ValueError(f"shapes differ: {e.shape} vs {r.shape}")
    if e.shape[0] < 2:
        raise ValueError(f"need at least 2 paired points, got {e.shape[0]}")
    for name, a in (("estimate_xy", e), ("reference_xy", r)):
        bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
        if bad.size:
            raise ValueError(f"{name}: point {int(bad[0])} is not finite: {a[bad[0]].tolist()}")
    e_mean, r_mean = e.mean(axis=0), r.mean(axis=0)
    ec, rc = e - e_mean, r - r_mean
    dot = float(np.sum(ec * rc))
    cross = float(np.sum(ec[:, 0] * rc[:, 1] - ec[:, 1] * rc[:, 0]))
    theta = float(np.arctan2(cross, dot))
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s], [s, c]])
    t = r_mean - rot @ e_mean
    return theta, t, e @ rot.T + t


def aligned_position_rmse(estimate_xy: ArrayLike, reference_xy: ArrayLike) -> float:
    """Position RMSE, m, of ``estimate_xy`` against ``reference_xy`` (paired points) after
    :func:`se2_alignment`."""
    _, _, moved = se2_alignment(estimate_xy, reference_xy)
    return position_rmse(moved, reference_xy)


def nees(errors: ArrayLike, covariances: ArrayLike) -> NDArray[np.float64]:
    """Normalised estimation error squared ``e^T P^-1 e`` per sample.

    Args:
        errors: (N, k) estimation errors (angles already wrapped).
        covariances: (N, k, k) covariances the filter reported for them.

    Returns:
        (N,) values; for a consistent filter each is chi-square with k degrees of freedom.
    """
    e = np.asarray(errors, dtype=float)
    P = np.asarray(covariances, dtype=float)
    if e.ndim != 2 or P.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise ValueError(f"errors (N, k) and covariances (N, k, k) expected, got {e.shape}, "
                         f"{P.shape}")
    sol = np.linalg.solve(P, e[..., None])[..., 0]
    return np.einsum("ni,ni->n", e, sol)


def nees_bounds(dof: int, runs: int = 1, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` bounds of the NEES averaged over ``runs`` Monte Carlo runs.

    ``runs`` times the average is chi-square with ``runs*dof`` degrees of freedom.
    """
    if dof < 1 or runs < 1 or not 0 < probability < 1:
        raise ValueError(f"need dof >= 1, runs >= 1, 0 < probability < 1; got {dof}, {runs}, "
                         f"{probability}")
    a = (1.0 - probability) / 2.0
    lo, hi = stats.chi2.ppf([a, 1.0 - a], runs * dof)
    return float(lo / runs), float(hi / runs)


def nees_fraction_within(values: ArrayLike, dof: int, runs: int = 1,
                         probability: float = 0.95) -> float:
    """Fraction of ``values`` (NEES averaged over ``runs``) inside :func:`nees_bounds`."""
    v = np.asarray(values, dtype=float)
    lo, hi = nees_bounds(dof, runs, probability)
    return float(np.mean((v >= lo) & (v <= hi)))
