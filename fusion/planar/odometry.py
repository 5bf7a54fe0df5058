"""Planar dead reckoning from wheel ticks (seed 000) and from twist feedback (seed 004).

Frames (REP-105): the pose ``(x, y, theta)`` is the body frame ``base_footprint`` (x forward,
y left) expressed in ``odom``; x, y in m, theta in rad, CCW positive from the odom x axis.
``theta`` is kept continuous (unwrapped, so whole turns are counted); :attr:`OdometryState.yaw`
gives it wrapped to (-pi, pi].

One period moves the wheels by ``dl = ticks_l * speed_ratio`` and ``dr = ticks_r * speed_ratio``
(m); the pose moves by one step of :mod:`fusion.geometry.dead_reckoning` with ``method`` as
its rule: ``"midpoint"`` (seed 000's ``base_controller``, the default), ``"arc"`` (exact for
constant wheel speeds within a period) or ``"euler"`` (seed 004's twist integration).

Velocities are per period: ``v = d/T``, ``w = dtheta/T`` (T = ``encode_sampling_time``), the
wheel speeds ``dl/T``, ``dr/T`` (m/s), as seed 000 publishes them.

Covariance (instead of the seed's constant 0.01 diagonal): each wheel's travel in a period has
variance ``k_wheel*|d_wheel|`` (m^2; independent random slip, so sigma grows as the square root of
distance), the heading change gets an extra ``k_turn*|dtheta|`` (rad^2; slip when turning), and
both are propagated to ``(x, y, theta)`` through the Jacobians of the update above:
``P <- F P F^T + G Q G^T``. The pose covariance therefore grows with distance travelled and
with turning, and stays still when the robot stands still.

One core step serves :meth:`WheelOdometry.update` (streaming) and
:meth:`WheelOdometry.update_batch` (arrays); they agree exactly, and a split run equals a
single run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.geometry.angles import wrap_angle
from fusion.geometry.dead_reckoning import RULES, integrate, step_terms, wheel_motion
from fusion.geometry.kinematics import DiffDriveParams

__all__ = [
    "METHODS",
    "OdometryNoise",
    "OdometryState",
    "TwistOdometry",
    "WheelOdometry",
    "integrate_wheel_travel",
    "wrap_angle",
]

METHODS = RULES


@dataclass(frozen=True)
class OdometryNoise:
    """Odometry error model.

    Attributes:
        k_wheel: variance of a wheel's travel per metre travelled, m^2/m (sigma of a 1 m run is
            ``sqrt(k_wheel)`` m per wheel; the default 2.5e-4 gives 1.6 cm).
        k_turn: extra variance of the heading change per radian turned, rad^2/rad (the default
            1e-3 gives sigma 4.5 deg per full turn).
    """

    k_wheel: float = 2.5e-4
    k_turn: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("k_wheel", "k_turn"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"OdometryNoise.{name} must be finite and >= 0, got {value!r}")


@dataclass
class OdometryState:
    """Dead-reckoning state (saveable: copy it, restore it with ``set_state``).

    Attributes:
        x, y: position of base_footprint in odom, m.
        theta: heading, rad, continuous (not wrapped).
        v: forward speed over the last period, m/s.
        w: yaw rate over the last period, rad/s.
        vl, vr: left and right wheel ground speeds over the last period, m/s.
        cov: (3, 3) covariance of (x, y, theta), m^2, m*rad, rad^2.
        distance: total path length travelled by the wheel midpoint, m (sum of |d|).
        t: host time of the last update, s, or None.
        updates: number of periods integrated.
    """

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    v: float = 0.0
    w: float = 0.0
    vl: float = 0.0
    vr: float = 0.0
    cov: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))
    distance: float = 0.0
    t: float | None = None
    updates: int = 0

    @property
    def yaw(self) -> float:
        """Heading wrapped to (-pi, pi], rad."""
        return wrap_angle(self.theta)

    @property
    def pose(self) -> NDArray[np.float64]:
        """``[x, y, yaw]`` (m, m, rad wrapped)."""
        return np.array([self.x, self.y, self.yaw])

    def copy(self) -> OdometryState:
        return replace(self, cov=self.cov.copy())


def _advance(x, y, th, P, dl, dr, L, method, k_wheel, k_turn):
    """The core step on Python floats: pose and covariance (6 unique entries) after one
    period of wheel travel dl, dr (m). Used by every streaming and batch entry point."""
    d, dth = wheel_motion(dl, dr, L)
    c, phi, s, ds, k = step_terms(th, d, dth, method)
    cos_phi = math.cos(phi)
    sin_phi = math.sin(phi)
    # covariance P <- F P F^T + G Q G^T; F = I but for the heading column (a, b, 1)
    pxx, pxy, pxt, pyy, pyt, ptt = P
    a = -c * sin_phi
    b = c * cos_phi
    nxx = pxx + 2.0 * a * pxt + a * a * ptt
    nxy = pxy + a * pyt + b * pxt + a * b * ptt
    nxt = pxt + a * ptt
    nyy = pyy + 2.0 * b * pyt + b * b * ptt
    nyt = pyt + b * ptt
    ntt = ptt
    # Q in (d, dtheta) from independent wheel variances k*|dl|, k*|dr| (+ turn slip)
    vl = k_wheel * abs(dl)
    vr = k_wheel * abs(dr)
    q11 = 0.25 * (vl + vr)
    q12 = 0.5 * (vr - vl) / L
    q22 = (vl + vr) / (L * L) + k_turn * abs(dth)
    # G = [[gx1, gx2], [gy1, gy2], [0, 1]]
    dc = d * ds
    gx1, gx2 = s * cos_phi, dc * cos_phi + a * k
    gy1, gy2 = s * sin_phi, dc * sin_phi + b * k
    qx1 = gx1 * q11 + gx2 * q12
    qx2 = gx1 * q12 + gx2 * q22
    qy1 = gy1 * q11 + gy2 * q12
    qy2 = gy1 * q12 + gy2 * q22
    P = (
        nxx + qx1 * gx1 + qx2 * gx2,
        nxy + qx1 * gy1 + qx2 * gy2,
        nxt + qx2,
        nyy + qy1 * gy1 + qy2 * gy2,
        nyt + qy2,
        ntt + q22,
    )
    return x + c * cos_phi, y + c * sin_phi, th + dth, P, d, dth


def _p6(cov) -> tuple[float, ...]:
    (pxx, pxy, pxt), (_, pyy, pyt), (_, _, ptt) = np.asarray(cov, dtype=float).tolist()
    return pxx, pxy, pxt, pyy, pyt, ptt


def _p33(P) -> NDArray[np.float64]:
    pxx, pxy, pxt, pyy, pyt, ptt = P
    return np.array([[pxx, pxy, pxt], [pxy, pyy, pyt], [pxt, pyt, ptt]])


def integrate_wheel_travel(
    dl: ArrayLike,
    dr: ArrayLike,
    wheel_distance: float,
    pose0: ArrayLike = (0.0, 0.0, 0.0),
    method: str = "midpoint",
) -> NDArray[np.float64]:
    """Integrate per-period wheel travel (m) into poses; the batch form of the core step.

    Args:
        dl, dr: left and right wheel travel per period, m, shape (N,).
        wheel_distance: ``L``, m.
        pose0: starting ``(x, y, theta)`` in odom, m, m, rad.
        method: ``"midpoint"``, ``"arc"`` or ``"euler"`` (see module docstring).

    Returns:
        (N, 3) poses ``(x, y, theta)`` after each period, theta continuous.
    """
    dl = np.asarray(dl, dtype=float).reshape(-1)
    dr = np.asarray(dr, dtype=float).reshape(-1)
    if dl.shape != dr.shape:
        raise ValueError(f"dl and dr must have the same length, got {dl.shape} and {dr.shape}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    return integrate(*wheel_motion(dl, dr, wheel_distance), pose0, method)


class _DeadReckoner:
    """State, covariance and the core step shared by the wheel and twist integrators."""

    def __init__(
        self,
        params: DiffDriveParams,
        method: str,
        noise: OdometryNoise | None,
        state: OdometryState | None,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.params = params
        self.method = method
        self.noise = noise if noise is not None else OdometryNoise()
        self._state = state.copy() if state is not None else OdometryState()

    # -- state -------------------------------------------------------------------------------
    @property
    def state(self) -> OdometryState:
        """The current state (a live reference; use :meth:`get_state` for a snapshot)."""
        return self._state

    def get_state(self) -> OdometryState:
        return self._state.copy()

    def set_state(self, state: OdometryState) -> None:
        self._state = state.copy()

    def reset(self) -> None:
        self._state = OdometryState()

    # -- core --------------------------------------------------------------------------------
    def _step(self, dl: float, dr: float, t: float | None) -> None:
        st = self._state
        p = self.params
        st.x, st.y, st.theta, P, d, dth = _advance(
            st.x, st.y, st.theta, _p6(st.cov), dl, dr, p.wheel_distance, self.method,
            self.noise.k_wheel, self.noise.k_turn,
        )
        st.cov = _p33(P)
        T = p.encode_sampling_time
        st.v = d / T
        st.w = dth / T
        st.vl = dl / T
        st.vr = dr / T
        st.distance += abs(d)
        st.t = t
        st.updates += 1


class WheelOdometry(_DeadReckoner):
    """Dead reckoning from encoder ticks per period (seed 000), with a growing covariance.

    Args:
        params: chassis geometry (``wheel_distance`` m, ``speed_ratio`` m/tick,
            ``encode_sampling_time`` s).
        method: ``"midpoint"`` (seed 000, default), ``"arc"`` (exact arc) or ``"euler"``.
        noise: error model for the covariance.
        state: starting state (default: origin, zero covariance).

    Example:
        >>> odo = WheelOdometry(DiffDriveParams(wheel_distance=0.2, speed_ratio=1e-4))
        >>> st = odo.update(100, 100)   # both wheels 100 ticks: 1 cm straight ahead
        >>> round(st.x, 6), st.y, st.theta
        (0.01, 0.0, 0.0)
    """

    def __init__(
        self,
        params: DiffDriveParams,
        method: str = "midpoint",
        noise: OdometryNoise | None = None,
        state: OdometryState | None = None,
    ) -> None:
        super().__init__(params, method, noise, state)

    def update(self, left: int, right: int, t: float | None = None) -> OdometryState:
        """Integrate one period of encoder ticks (left, right; signed ticks per period).

        Args:
            left, right: ticks counted in one ``encode_sampling_time`` period.
            t: host time stamp of the frame, s (stored, not used for integration: the period
                is the firmware's).

        Returns:
            The updated state (live reference).
        """
        sr = self.params.speed_ratio
        self._step(float(left) * sr, float(right) * sr, t)
        return self._state

    def update_batch(
        self, left: ArrayLike, right: ArrayLike, t: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Integrate N periods of ticks; returns the (N, 3) poses ``(x, y, theta)`` after each.

        Identical (bit for bit) to N calls of :meth:`update` (the same core step); the final
        state, including the covariance, is updated too. For poses alone over long logs,
        :func:`integrate_wheel_travel` is the vectorised form.
        """
        sr = self.params.speed_ratio
        lt = np.asarray(left, dtype=float).reshape(-1)
        rt = np.asarray(right, dtype=float).reshape(-1)
        if lt.shape != rt.shape:
            raise ValueError(
                f"left and right must have the same length, got {lt.shape} and {rt.shape}"
            )
        n = lt.size
        if n == 0:
            return np.zeros((0, 3))
        st = self._state
        p = self.params
        L, method = p.wheel_distance, self.method
        kw, kt = self.noise.k_wheel, self.noise.k_turn
        x, y, th, P = st.x, st.y, st.theta, _p6(st.cov)
        out = np.empty((n, 3))
        dist = st.distance
        d = dth = dl = dr = 0.0
        for k, (a, b) in enumerate(zip(lt.tolist(), rt.tolist())):
            dl = a * sr
            dr = b * sr
            x, y, th, P, d, dth = _advance(x, y, th, P, dl, dr, L, method, kw, kt)
            out[k] = (x, y, th)
            dist += abs(d)
        T = p.encode_sampling_time
        st.x, st.y, st.theta, st.cov = x, y, th, _p33(P)
        st.v, st.w, st.vl, st.vr = d / T, dth / T, dl / T, dr / T
        st.distance = dist
        st.t = None if t is None else float(np.asarray(t, dtype=float).reshape(-1)[-1])
        st.updates += n
        return out


class TwistOdometry(_DeadReckoner):
    """Integration of body-twist feedback (seed 004's ``cmd_vel_feedback`` at a fixed dt).

    Seed 004 integrates with the heading at the start of the step (``method="euler"``, the
    default here); ``"midpoint"`` and ``"arc"`` are available. The seed's fudge factors
    (x * 1.2468, yaw * 1.125) are deliberately absent: calibrate ``wheel_distance`` instead.

    Args:
        wheel_distance: ``b``, m; used only to map the twist onto wheel travel for the
            covariance model.
        dt: default integration step, s (seed 004: 0.02).
        method, noise, state: as in :class:`WheelOdometry`.
    """

    def __init__(
        self,
        wheel_distance: float,
        dt: float = 0.02,
        method: str = "euler",
        noise: OdometryNoise | None = None,
        state: OdometryState | None = None,
    ) -> None:
        params = DiffDriveParams(wheel_distance=wheel_distance, speed_ratio=1.0,
                                 encode_sampling_time=dt)
        super().__init__(params, method, noise, state)
        self.dt = dt

    def update_twist(
        self, v: float, w: float, dt: float | None = None, t: float | None = None
    ) -> OdometryState:
        """Integrate forward speed ``v`` (m/s) and yaw rate ``w`` (rad/s) over ``dt`` s."""
        dt = self.dt if dt is None else float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be finite and > 0 s, got {dt!r}")
        half = 0.5 * self.params.wheel_distance * w
        dl = (v - half) * dt
        dr = (v + half) * dt
        self._step(dl, dr, t)
        st = self._state
        st.v, st.w = float(v), float(w)
        st.vl, st.vr = v - half, v + half
        return st
