"""What the attitude filters (:class:`fusion.attitude.keel.Keel`,
:class:`fusion.attitude.mahony.Mahony`) share around their compiled cores: settings, the one
packed buffer (state, parameters, counters) the core works on, parameter swaps, Euler angles,
batch inputs and the periods of a batch.

Only plumbing lives here; the per-sample hot path (``update``) stays in each filter, written
for the fewest Python operations around one compiled call.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.attitude._inputs import (
    as_rows,
    check_dts,
    explicit_periods,
    timestamps_array,
    unit_quaternion,
)
from fusion.geometry import quaternion as quat

__all__ = ["AttitudeFilter", "check_axes"]

_F = TypeVar("_F", bound="AttitudeFilter")


def check_axes(axes: int) -> int:
    """``axes`` (6 or 9), or ``ValueError``."""
    if axes not in (6, 9):
        raise ValueError(f"axes must be 6 or 9, got {axes!r}")
    return axes


class AttitudeFilter:
    """Base of the attitude filters. A subclass sets:

    - ``_params_class``: its frozen parameter dataclass (with ``sample_period`` and
      ``packed()``, the flat float64 array its core reads);
    - ``_layout``: ``(B_P, B_C, B_LEN)``, where the parameters and the counters start in the
      packed buffer and its length (the state starts at 0, the quaternion in its first 4);

    and implements ``reset()`` and ``_first_period(t)`` (the period before the first sample of
    a batch given with timestamps when no earlier timestamp is known, s).
    """

    _params_class: type
    _layout: tuple[int, int, int]

    def _setup(self, axes: int, initial_quaternion: ArrayLike | None, params: Any) -> None:
        self.axes = check_axes(axes)
        self._initial = None
        if initial_quaternion is not None:
            self._initial = unit_quaternion("initial_quaternion", initial_quaternion)
        self.params = params
        self.reset()

    def reset(self) -> None:  # pragma: no cover - every subclass implements it
        raise NotImplementedError

    # -- parameters ---------------------------------------------------------------------------

    @property
    def params(self) -> Any:
        """The parameters (immutable; assign a new object to change them)."""
        return self._params

    @params.setter
    def params(self, params: Any) -> None:
        cls = self._params_class
        if not isinstance(params, cls):
            raise ValueError(f"params must be a {cls.__name__}, got {type(params).__name__}")
        self._params = params
        self._default_dt = params.sample_period
        self._params_changed()
        if hasattr(self, "_B"):
            self._P[:] = params.packed()

    def _params_changed(self) -> None:
        """Hook run when the parameters change (before they are packed into a live buffer)."""

    def with_params(self: _F, **changes: Any) -> _F:
        """A fresh filter with the same settings and some parameters changed."""
        return type(self)(axes=self.axes, initial_quaternion=self._initial,
                          params=replace(self._params, **changes))

    def _new_buffer(self) -> None:
        """A zeroed packed buffer (state, parameters, counters) with the parameters packed."""
        b_p, b_c, b_len = self._layout
        self._B = np.zeros(b_len)
        self._S = self._B[:b_p]
        self._P = self._B[b_p:b_c]
        self._C = self._B[b_c:]
        self._q = self._B[0:4]
        self._P[:] = self._params.packed()

    # -- outputs ------------------------------------------------------------------------------

    @property
    def quaternion(self) -> NDArray[np.float64]:
        """Current attitude ``[w, x, y, z]``, body -> world ENU."""
        return self._q.copy()

    @property
    def euler(self) -> NDArray[np.float64]:
        """Current roll, pitch, yaw in radians (ZYX)."""
        return quat.to_euler(self.quaternion)

    # -- batch inputs ---------------------------------------------------------------------------

    def _batch_rows(self, gyro: ArrayLike, accel: ArrayLike, mag: ArrayLike | None):
        """``(g, a, m, use_mag)``: checked contiguous (N, 3) rows; ``m`` has 0 rows when the
        magnetometer is not used (6-axis filter or none given)."""
        g = as_rows("gyro", gyro)
        n = g.shape[0]
        a = as_rows("accel", accel, n)
        use_mag = self.axes == 9 and mag is not None
        m = as_rows("mag", mag, n) if use_mag else np.zeros((0, 3))
        return g, a, m, use_mag

    def _first_period(self, t: NDArray[np.float64]) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def _batch_periods(self, n: int, dt: float | ArrayLike | None,
                       timestamps: ArrayLike | None) -> NDArray[np.float64]:
        """The period before each of ``n`` samples (s): N values, or 1 for a constant one.

        ``dt`` wins over ``timestamps``; timestamps must increase strictly, also from the
        previous call's last one (then the first period is measured from it, else it is
        :meth:`_first_period`); without either, the default ``sample_period``."""
        if timestamps is not None:
            t = timestamps_array(timestamps, n)
            if n == 0:
                return np.zeros(1)
            if dt is None:
                dts = np.empty(n)
                dts[1:] = np.diff(t)
                dts[0] = 1.0 if self._last_t is None else t[0] - self._last_t
                check_dts(dts, "timestamps must increase strictly: at index")
                if self._last_t is None:
                    dts[0] = self._first_period(t)
                self._last_t = float(t[-1])
                return dts
            self._last_t = float(t[-1])
        if dt is None:
            if self._params.sample_period is None:
                raise ValueError("no dt: pass dt=, timestamps=, or set sample_period")
            return np.array([self._params.sample_period])
        return explicit_periods(dt, n)
