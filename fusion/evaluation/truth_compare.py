"""A replay's tracks against a log's truth.csv: aligned at each track's start, compared at the
truth's own stamps, and not at all where the truth cannot be this log's.

An independent probe wrote truth files the ways people do and read wrong figures printed with
no word (the fused track itself was right, 0.05 % and 0.19 deg): a motion-capture truth in
its room's frame (start at 10 m, 5 m, 30 deg: 26.5 % and 30 deg printed), a yaw in degrees
(81 deg), a truth at 1 Hz (1.82 deg: the truth was interpolated onto the fused rows, cutting
the corners of every turn), a truth on another clock (100 s off: 21 % and 99 deg).

:func:`compare_with_truth`: the truth is moved onto each track at the first stamp they
share (a track starts at the origin facing x, so nothing changes for a truth in that frame
that starts with it; one that starts later is put where the track is then); the track is
interpolated onto the truth's stamps inside its span (a track's rows are
far denser than any truth's); the final position error is taken at the last of them, as a
percentage of the truth's path over them. No figures, and a note saying why, when fewer than
half of the track's span has truth (:data:`MIN_OVERLAP`), when the truth turns about 57.3
times as far as the track (:data:`DEGREE_RATIO_RANGE`: a yaw in degrees), or when its turns
do not line up with the track's (:data:`MIN_RATE_CORRELATION`: another clock).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.evaluation.trajectory import final_position_error_percent, path_length, yaw_rmse
from fusion.geometry.angles import wrap_angle

__all__ = ["DEGREE_RATIO_RANGE", "MIN_OVERLAP", "MIN_RATE_CORRELATION", "TruthComparison",
           "aligned_truth", "compare_with_truth"]

#: Share of a track's span the truth must cover for figures to be printed.
MIN_OVERLAP = 0.5
#: s: the window over which the truth's and a track's yaw rates are averaged for their
#: correlation.
RATE_WINDOW = 0.5
#: Least correlation of the truth's yaw rate with the track's for the truth to be this run's
#: on this clock (a right truth: 0.99 and more; one 100 s off: about 0).
MIN_RATE_CORRELATION = 0.5
#: The truth's total turn over the track's, within which a yaw in degrees is suspected
#: (180/pi = 57.3, give or take what the track's own heading error can make of it).
DEGREE_RATIO_RANGE = (40.0, 80.0)


@dataclass
class TruthComparison:
    """``errors`` per track name: ``{"pct": final position error, % of distance, "yaw_deg":
    yaw RMSE, deg}``; ``distance``: the truth's path over the first track's span, m (NaN:
    not compared); ``note``: why nothing was compared ("" when it was); ``aligned`` per track
    name: the truth (K, 3) as compared with it (:func:`aligned_truth`)."""

    errors: dict[str, dict[str, float]] = field(default_factory=dict)
    distance: float = math.nan
    note: str = ""
    aligned: dict[str, NDArray[np.float64]] = field(default_factory=dict)


def _rate_correlation(t, yaw, truth_t, truth_yaw) -> float | None:
    """Pearson correlation of the truth's yaw rate with the track's, both as mean rates over
    :data:`RATE_WINDOW` s (or the truth's interval, if longer: sample-to-sample rates of a
    100 Hz truth are its noise), or None where the truth hardly turns (less than 90 deg in
    all) or spans fewer than three windows."""
    if truth_t.size < 3 or _turn(truth_yaw) < math.radians(90.0):
        return None
    step = max(RATE_WINDOW, float(np.median(np.diff(truth_t))))
    grid = np.arange(max(t[0], truth_t[0]), min(t[-1], truth_t[-1]), step)
    if grid.size < 4:
        return None
    a = np.diff(np.interp(grid, t, np.unwrap(yaw)))
    b = np.diff(np.interp(grid, truth_t, np.unwrap(truth_yaw)))
    if not (np.std(a) > 0 and np.std(b) > 0):
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _turn(yaw: NDArray[np.float64]) -> float:
    return float(np.sum(np.abs(wrap_angle(np.diff(yaw))))) if yaw.size > 1 else 0.0


def aligned_truth(truth_t, truth, t, poses) -> NDArray[np.float64]:
    """The truth (K, 3) moved onto the track (``t``, ``poses``) at the first stamp they
    share: there the truth's pose is the track's (yaw unwrapped). A truth that starts with
    the track starts at the origin; one that starts later, at where the track is then."""
    t0 = max(float(t[0]), float(truth_t[0]))
    yaw = np.unwrap(truth[:, 2])
    x0, y0, a0 = (float(np.interp(t0, truth_t, c)) for c in (truth[:, 0], truth[:, 1], yaw))
    px, py, pa = (float(np.interp(t0, t, c))
                  for c in (poses[:, 0], poses[:, 1], np.unwrap(poses[:, 2])))
    turn = pa - a0
    c, s = math.cos(turn), math.sin(turn)
    dx, dy = truth[:, 0] - x0, truth[:, 1] - y0
    return np.column_stack([px + c * dx - s * dy, py + s * dx + c * dy, yaw + turn])


def compare_with_truth(tracks: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
                       truth_t: NDArray[np.float64], truth: NDArray[np.float64],
                       source: str = "truth.csv") -> TruthComparison:
    """Each track ``{name: (t (N,) s, poses (N, 3) x m, y m, yaw rad)}``, starting at the
    origin, against the truth (``truth_t`` (K,) s, ``truth`` (K, 3)); the first track's span
    decides the checks (module docstring)."""
    first_t = next(iter(tracks.values()))[0]
    t0, t1 = float(first_t[0]), float(first_t[-1])
    inside = (truth_t >= t0) & (truth_t <= t1)
    covered = (min(float(truth_t[-1]), t1) - max(float(truth_t[0]), t0)) if truth_t.size else 0.0
    if np.count_nonzero(inside) < 2 or not covered >= MIN_OVERLAP * (t1 - t0):
        span = (f"{truth_t[0]:.3f}-{truth_t[-1]:.3f} s" if truth_t.size else "nothing")
        return TruthComparison(note=(
            f"{source} spans {span}, the fused output {t0:.3f}-{t1:.3f} s: less than "
            f"{MIN_OVERLAP:.0%} of it has truth (its t on another clock?); not compared"))
    name0, (t_a, poses_a) = next(iter(tracks.items()))
    keep = (t_a >= truth_t[inside][0]) & (t_a <= truth_t[inside][-1])
    track_turn = _turn(poses_a[keep, 2])
    ratio = _turn(truth[inside, 2]) / track_turn if track_turn > math.radians(90.0) else 0.0
    if DEGREE_RATIO_RANGE[0] <= ratio <= DEGREE_RATIO_RANGE[1]:
        return TruthComparison(note=(
            f"{source}: its yaw turns {ratio:.1f} times as far as the fused heading (180/pi = "
            "57.3): in degrees? yaw must be in rad; not compared"))
    corr = _rate_correlation(t_a, poses_a[:, 2], truth_t[inside], truth[inside, 2])
    if corr is not None and corr < MIN_RATE_CORRELATION:
        return TruthComparison(note=(
            f"{source}: its turns do not line up with the fused heading's (their yaw rates "
            f"over {RATE_WINDOW:g} s correlate by {corr:.2f}): its t on another clock, or "
            "another robot's run? not compared"))
    out = TruthComparison()
    for name, (t, poses) in tracks.items():
        rel = aligned_truth(truth_t, truth, t, poses)
        out.aligned[name] = rel
        at = (truth_t >= t[0]) & (truth_t <= t[-1])
        if np.count_nonzero(at) < 2:
            continue
        tt = truth_t[at]
        est = np.column_stack([np.interp(tt, t, poses[:, 0]), np.interp(tt, t, poses[:, 1]),
                               np.interp(tt, t, np.unwrap(poses[:, 2]))])
        dist = path_length(rel[at, :2])
        if name == name0:
            out.distance = dist
        out.errors[name] = {
            "pct": final_position_error_percent(est[:, :2], rel[at, :2], dist)
            if dist > 0 else math.nan,
            "yaw_deg": math.degrees(yaw_rmse(est[:, 2], rel[at, 2])),
        }
    return out
