"""Missions for the physics simulator: a commanded twist over time and the floor's friction.

A mission is a sequence of segments, each a constant commanded forward speed ``v`` (m/s) and
yaw rate ``w`` (rad/s, CCW positive) held for ``duration`` s; the firmware ramps between them
(:class:`~fusion.evaluation.physics_sim.body.ControllerParams`). Low-friction patches are time
windows in which the floor under the wheels has friction ``mu`` (a wet or dusty patch the
robot crosses); the robot may start moving (``initial_twist``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Mission", "Segment", "circle_mission", "indoor_mission"]

KINDS = ("stop", "straight", "arc", "spin", "sharp")


@dataclass(frozen=True)
class Segment:
    """One commanded twist: ``kind`` (one of ``stop straight arc spin sharp``), ``duration``
    s, ``v`` m/s, ``w`` rad/s."""

    kind: str
    duration: float
    v: float
    w: float

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Segment.kind must be one of {KINDS}, got {self.kind!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"Segment.duration must be > 0 s, got {self.duration!r}")
        if not (math.isfinite(self.v) and math.isfinite(self.w)):
            raise ValueError(f"Segment v, w must be finite, got {self.v!r}, {self.w!r}")


@dataclass(frozen=True)
class Mission:
    """Commanded twists over time, floor friction, starting twist.

    Attributes:
        segments: the commands in order.
        friction_patches: ``(start s, duration s, mu)`` windows of low friction.
        initial_twist: ``(v m/s, w rad/s)`` the robot already has at t = 0 (the body, wheels
            and firmware ramp start in that steady state); (0, 0): at rest.
    """

    segments: tuple[Segment, ...]
    friction_patches: tuple[tuple[float, float, float], ...] = ()
    initial_twist: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError("Mission needs at least one segment")
        for start, duration, mu in self.friction_patches:
            if not (duration > 0 and mu > 0):
                raise ValueError(f"friction patch ({start!r}, {duration!r}, {mu!r}) needs "
                                 "duration > 0 s and mu > 0")

    @property
    def duration(self) -> float:
        """Total length, s."""
        return float(sum(s.duration for s in self.segments))

    @property
    def starts(self) -> NDArray[np.float64]:
        """Start time of each segment, s."""
        return np.concatenate(([0.0], np.cumsum([s.duration for s in self.segments])[:-1]))

    def commands(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Commanded ``(v m/s, w rad/s)`` at times ``t`` (s); the last segment holds past
        the end."""
        t = np.asarray(t, dtype=float)
        i = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0,
                    len(self.segments) - 1)
        v = np.array([s.v for s in self.segments])
        w = np.array([s.w for s in self.segments])
        return v[i], w[i]

    def friction(self, t: ArrayLike, mu: float) -> NDArray[np.float64]:
        """Floor friction coefficient at times ``t`` (s); ``mu`` outside the patches."""
        t = np.asarray(t, dtype=float)
        out = np.full(t.shape, float(mu))
        for start, duration, patch_mu in self.friction_patches:
            out[(t >= start) & (t < start + duration)] = patch_mu
        return out


def circle_mission(v: float, w: float, duration: float, settle: float = 0.0) -> Mission:
    """Constant ``(v, w)`` for ``duration`` s, optionally after ``settle`` s at rest."""
    segs = ([Segment("stop", settle, 0.0, 0.0)] if settle > 0 else []) + \
        [Segment("arc" if w else "straight", duration, v, w)]
    return Mission(tuple(segs))


def _moving_segment(rng: np.random.Generator, kind: str) -> Segment:
    if kind == "straight":
        v = rng.uniform(0.3, 0.6)
        return Segment(kind, rng.uniform(1.0, 5.0) / v, v, 0.0)
    if kind == "arc":
        v = rng.uniform(0.25, 0.5)
        w = rng.choice([-1.0, 1.0]) * v / rng.uniform(0.5, 2.0)
        return Segment(kind, rng.uniform(math.pi / 4, math.pi) / abs(w), v, w)
    if kind == "spin":
        w = rng.choice([-1.0, 1.0]) * rng.uniform(0.8, 1.5)
        return Segment(kind, rng.choice([0.5, 1.0]) * math.pi / abs(w), 0.0, w)
    # sharp: a fast, tight arc (lateral acceleration 0.5-0.7 m/s^2)
    v = rng.uniform(0.45, 0.55)
    w = rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 1.3)
    return Segment(kind, rng.uniform(math.pi / 3, math.pi / 2) / abs(w), v, w)


def indoor_mission(seed: int = 0, duration: float = 300.0, moving_start: bool = False,
                   low_friction: bool = False) -> Mission:
    """An indoor-style drive of ``duration`` s, deterministic for ``seed``.

    Straight runs of 1-5 m at 0.3-0.6 m/s, arcs of 0.5-2 m radius, turns in place of 90 or
    180 deg at 0.8-1.5 rad/s, a few sharp arcs, and a stop of 2-6 s after every 1-4 moving
    segments. It starts with 3 s at rest (or, with ``moving_start``, already driving straight
    at 0.4 m/s) and ends with 3 s at rest. With ``low_friction``, three 3 s patches of
    mu = 0.04-0.1 begin 0.5 s before three of the moving segments after the first 20 s (the
    firmware's 1 m/s^2 ramp then asks for more than friction gives: the wheels slip).
    """
    if not duration > 10:
        raise ValueError(f"duration must be > 10 s, got {duration!r}")
    rng = np.random.default_rng([seed, 303])
    segs: list[Segment] = []
    if moving_start:
        segs.append(Segment("straight", 4.0, 0.4, 0.0))
        initial = (0.4, 0.0)
    else:
        segs.append(Segment("stop", 3.0, 0.0, 0.0))
        initial = (0.0, 0.0)
    body_end = duration - 3.0
    elapsed = segs[0].duration
    until_stop = int(rng.integers(1, 5))
    while elapsed < body_end:
        if until_stop == 0:
            seg = Segment("stop", rng.uniform(2.0, 6.0), 0.0, 0.0)
            until_stop = int(rng.integers(1, 5))
        else:
            kind = str(rng.choice(["straight", "arc", "spin", "sharp"], p=[0.4, 0.3, 0.22, 0.08]))
            seg = _moving_segment(rng, kind)
            until_stop -= 1
        if elapsed + seg.duration > body_end:
            seg = Segment(seg.kind, body_end - elapsed, seg.v, seg.w)
        segs.append(seg)
        elapsed += seg.duration
    segs.append(Segment("stop", 3.0, 0.0, 0.0))
    patches: list[tuple[float, float, float]] = []
    if low_friction:
        starts = np.concatenate(([0.0], np.cumsum([s.duration for s in segs])[:-1]))
        movers = [float(t0) for t0, s in zip(starts, segs)
                  if s.kind in ("straight", "arc", "sharp") and 20.0 <= t0 < body_end - 5.0]
        picks = sorted(rng.choice(movers, size=min(3, len(movers)), replace=False).tolist())
        patches = [(t0 - 0.5, 3.0, float(rng.uniform(0.04, 0.1))) for t0 in picks]
    return Mission(tuple(segs), tuple(patches), initial)
