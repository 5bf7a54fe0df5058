"""One dead-reckoning step of a differential-drive robot: the pose after one period.

Frames and units: the pose ``(x, y, theta)`` is the body frame in the odometry frame, x and y
in m, theta in rad, CCW positive (REP-103/105). Over one period the wheel contact points travel
``dl`` and ``dr`` (m); with the wheel separation ``L`` (m) the robot moves ``d = (dl + dr)/2``
along its path and turns ``dtheta = (dr - dl)/L``. The step moves the pose by a straight
displacement of length ``c`` along the heading ``phi``::

    x += c*cos(phi),  y += c*sin(phi),  theta += dtheta

with, by ``rule``:

- ``"arc"``: exact for a circular arc (constant wheel speeds over the period):
  ``phi = theta + dtheta/2``, ``c = d * sin(a)/a`` with ``a = dtheta/2`` (the chord);
- ``"midpoint"`` (seed 000's ``base_controller``): ``phi = theta + dtheta/2``, ``c = d``,
  which overstates the chord by ``1/sinc(a)``, about ``d*dtheta**2/24`` per period;
- ``"euler"`` (seed 004's twist integration): ``phi = theta``, ``c = d``.

The small-angle threshold, :data:`SMALL_ANGLE` = 1e-4 rad on ``|a|``: below it ``sin(a)/a`` is
taken as its series ``1 - a**2/6`` and its derivative as ``-a/3`` (d/da; ``-a/6`` d/d dtheta).
The neglected term ``a**4/120`` is below 8.4e-19 there, under a hundredth of the spacing of
doubles just below 1.0 (1.1e-16), so the factor equals the quotient to within one ulp, and it
is defined at ``a = 0``. The closed-form derivative ``(a*cos(a) - sin(a))/a**2`` loses digits
to cancellation as ``a`` shrinks (relative error about ``3*eps/a**2``: 7e-8 at 1e-4), while the
series errs by ``a**2/10`` (1e-9 at 1e-4). 1e-4 is also the value the wheel odometry has
always used, so its results are unchanged.

:func:`step` / :func:`step_terms` work on Python floats (one period, streaming);
:func:`increments` and :func:`integrate` are the vectorised form over many periods. They apply
the very same operations (``cumsum`` adds in order, like a loop), so they agree bit for bit
wherever numpy's ``sin``/``cos`` are the C library's, as on the platforms this is tested on
(``tests/test_dead_reckoning.py`` checks it). :func:`motion_between` is the inverse of
``"arc"``: the travel and turn between given poses.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "RULES",
    "SMALL_ANGLE",
    "arc_factor",
    "increments",
    "integrate",
    "motion_between",
    "step",
    "step_terms",
    "wheel_motion",
]

RULES = ("midpoint", "arc", "euler")

#: |dtheta/2| (rad) below which sin(a)/a is evaluated by its series (module docstring).
SMALL_ANGLE = 1e-4


def wheel_motion(dl: float, dr: float, wheel_distance: float) -> tuple[float, float]:
    """Wheel travels ``dl``, ``dr`` (m) -> ``(d m, dtheta rad)`` over the period."""
    return 0.5 * (dl + dr), (dr - dl) / wheel_distance


def arc_factor(dtheta: float) -> tuple[float, float]:
    """``s = sin(a)/a`` with ``a = dtheta/2``, and ``ds/d(dtheta)`` (1/rad); series below
    :data:`SMALL_ANGLE`."""
    a = 0.5 * dtheta
    if abs(a) < SMALL_ANGLE:
        return 1.0 - a * a / 6.0, -a / 6.0
    return math.sin(a) / a, 0.5 * (a * math.cos(a) - math.sin(a)) / (a * a)


def step_terms(theta: float, d: float, dtheta: float,
               rule: str = "arc") -> tuple[float, float, float, float, float]:
    """The pieces of one step: ``(c, phi, s, ds, k)``.

    ``c`` (m) is the straight displacement along the heading ``phi`` (rad); ``c = d*s`` and
    ``phi = theta + k*dtheta``, with ``ds = ds/d(dtheta)``: what an error propagation needs
    for the Jacobians.

    Raises:
        ValueError: an unknown ``rule``.
    """
    if rule == "arc":
        s, ds = arc_factor(dtheta)
        return d * s, theta + 0.5 * dtheta, s, ds, 0.5
    if rule == "midpoint":
        return d, theta + 0.5 * dtheta, 1.0, 0.0, 0.5
    if rule == "euler":
        return d, theta, 1.0, 0.0, 0.0
    raise ValueError(f"rule must be one of {RULES}, got {rule!r}")


def step(x: float, y: float, theta: float, d: float, dtheta: float,
         rule: str = "arc") -> tuple[float, float, float]:
    """Pose ``(x m, y m, theta rad)`` after moving ``d`` (m) and turning ``dtheta`` (rad).

    For wheel travels use ``step(x, y, theta, *wheel_motion(dl, dr, L), rule)``.
    """
    c, phi, *_ = step_terms(theta, d, dtheta, rule)
    return x + c * math.cos(phi), y + c * math.sin(phi), theta + dtheta


def increments(theta: ArrayLike, d: ArrayLike, dtheta: ArrayLike,
               rule: str = "arc") -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Vectorised displacement ``(dx, dy)`` (m) of periods starting at headings ``theta``."""
    theta = np.asarray(theta, dtype=float)
    d = np.asarray(d, dtype=float)
    dtheta = np.asarray(dtheta, dtype=float)
    if rule == "arc":
        a = 0.5 * dtheta
        small = np.abs(a) < SMALL_ANGLE
        a_safe = np.where(small, 1.0, a)
        c = d * np.where(small, 1.0 - a * a / 6.0, np.sin(a_safe) / a_safe)
        phi = theta + 0.5 * dtheta
    elif rule == "midpoint":
        c, phi = d, theta + 0.5 * dtheta
    elif rule == "euler":
        c, phi = d, theta
    else:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    return c * np.cos(phi), c * np.sin(phi)


def integrate(d: ArrayLike, dtheta: ArrayLike, pose0: ArrayLike = (0.0, 0.0, 0.0),
              rule: str = "arc") -> NDArray[np.float64]:
    """Poses after each of N periods of travel ``d`` (m) and turn ``dtheta`` (rad), (N, 3).

    Starts at ``pose0 = (x, y, theta)``; theta stays continuous. Equal to N calls of
    :func:`step` (module docstring).
    """
    d = np.asarray(d, dtype=float).reshape(-1)
    dtheta = np.asarray(dtheta, dtype=float).reshape(-1)
    if d.shape != dtheta.shape:
        raise ValueError(f"d and dtheta must have the same length, got {d.shape} and "
                         f"{dtheta.shape}")
    x0, y0, th0 = (float(p) for p in pose0)
    theta = np.cumsum(np.concatenate(([th0], dtheta)))
    dx, dy = increments(theta[:-1], d, dtheta, rule)
    x = np.cumsum(np.concatenate(([x0], dx)))[1:]
    y = np.cumsum(np.concatenate(([y0], dy)))[1:]
    return np.column_stack([x, y, theta[1:]])


def motion_between(x: ArrayLike, y: ArrayLike, theta: ArrayLike
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The travel ``d`` (m, negative backwards) and turn ``dtheta`` (rad, wrapped to
    (-pi, pi]) of each period between N consecutive poses (``x``, ``y`` m, ``theta`` rad),
    and the displacement across the heading ``lateral`` (m): three (N - 1,) arrays.

    The inverse of the ``"arc"`` rule (:func:`integrate` of its output gives the poses back):
    the displacement's component along ``phi = theta + dtheta/2`` is the chord ``d*sin(a)/a``
    (``a = dtheta/2``). A differential drive never moves across its heading, so ``lateral``
    is 0 for poses it integrated with that rule or ``"midpoint"`` (whose chord error shows in
    ``d`` instead, about ``d*dtheta**2/24`` too long); more is motion it cannot make (a pose
    that jumped, a holonomic base).
    """
    x, y, theta = (np.asarray(a, dtype=float).reshape(-1) for a in (x, y, theta))
    if not x.shape == y.shape == theta.shape:
        raise ValueError(f"x, y and theta must have the same length, got {x.shape}, "
                         f"{y.shape} and {theta.shape}")
    # wrapped as fusion.geometry.angles.wrap_angle does (not imported: drivers use this
    # module, and angles needs fusion._jit)
    dtheta = np.pi - np.mod(np.pi - np.diff(theta), 2.0 * np.pi)
    phi = theta[:-1] + 0.5 * dtheta
    dx, dy = np.diff(x), np.diff(y)
    chord = dx * np.cos(phi) + dy * np.sin(phi)
    lateral = -dx * np.sin(phi) + dy * np.cos(phi)
    a = 0.5 * dtheta
    small = np.abs(a) < SMALL_ANGLE
    a_safe = np.where(small, 1.0, a)
    return chord / np.where(small, 1.0 - a * a / 6.0, np.sin(a_safe) / a_safe), dtheta, lateral
