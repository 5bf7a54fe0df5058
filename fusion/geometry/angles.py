"""Angle wrapping to (-pi, pi], one definition in an array form and a scalar form.

Both forms compute ``pi - ((pi - a) mod 2*pi)`` with the floored modulo of Python's ``%`` and
numpy's :func:`numpy.mod` (the remainder takes the sign of ``2*pi``: ``fmod`` then one
correction), so they agree bit for bit, interpreted or compiled by numba.

The convention, exactly (``pi`` below is the double ``math.pi``):

- ``wrap(pi) == pi`` and ``wrap(-pi) == pi``: the seam belongs to ``+pi``;
- ``wrap(0.0) == wrap(-0.0) == wrap(2*pi) == wrap(-2*pi) == 0.0`` (+0.0);
- every result lies in ``[-pi, pi]``; ``-pi`` comes out only by rounding, from inputs within
  about one ulp of ``2*pi`` of the seam (the double just above ``pi`` gives ``-pi``, and the
  double just above ``-pi`` gives ``pi``): the wrapped value is congruent to ``a`` modulo
  ``2*pi`` up to that rounding (``fmod`` itself is exact);
- ``nan`` and ``+-inf`` give ``nan``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._jit import njit

__all__ = ["wrap_angle", "wrap_angle_scalar"]


@njit
def wrap_angle_scalar(a: float) -> float:
    """Wrap one angle ``a`` (rad) to (-pi, pi] (module docstring: the exact convention).

    Plain math in numba's subset: callable from Python and from numba-compiled cores alike.
    """
    return math.pi - (math.pi - a) % (2.0 * math.pi)


def wrap_angle(a: ArrayLike) -> float | NDArray[np.float64]:
    """Wrap angles ``a`` (rad, any shape) to (-pi, pi]; bit for bit :func:`wrap_angle_scalar`.

    Returns a Python float for a scalar input, else a float64 array of the input's shape.
    """
    w = np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)
    return float(w) if np.ndim(a) == 0 else w
