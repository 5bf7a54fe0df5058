"""The planar EKF's model, written once: motion, process noise and every measurement.

State ``x = [x, y, yaw, v, w, b, k, c, g, s]`` (m, m, rad, m/s, rad/s, rad/s, 1, rad/m, 1, 1; see
:mod:`fusion.planar.ekf` for their meaning). Each function is plain arithmetic in numba's
subset: the compiled core (:mod:`fusion.planar._ekf_core`) calls these very functions, they
run interpreted when numba is absent, and the tests drive filterpy's own
:class:`~filterpy.kalman.ExtendedKalmanFilter` with them as the reference. Nothing else in
the project restates this algebra.

- Motion (constant twist over ``dt`` s): ``yaw += w*dt/(1 + g)``,
  ``x += v*dt/(1 + s)*cos(yaw + w*dt/(2*(1 + g)))``, ``y += v*dt/(1 + s)*sin(...)`` likewise;
  v, w, b, k, c, g, s stay. :func:`transition` (f), :func:`transition_jacobian` (F); both from
  :func:`motion_terms`.
- Process noise: random walks of v, w, b, k, c, g, s, :func:`process_noise` (Q); and
  :func:`odometry_noise`, white noise on the position per metre driven, along and across the
  heading (Q's pose block): the distance the wheels report departs from the true one by
  errors that accumulate along the path (slip, a rolling radius that changes with speed and
  load, floor texture) and that no constant scale ``s`` stands for, since the error of a
  constant scale cancels when the robot drives back.
- Gyro: ``z = w + b`` (rad/s about the world vertical). ``w`` is the yaw rate *in the gyro's
  scale*: the true rate is ``w/(1 + g)``, with ``g`` the gyro's scale error (MPU6050 datasheet:
  sensitivity tolerance +-3 %). This is ``z = (1 + g)*w_true + b`` with the variables changed
  so that no rate measurement depends on g: the gyro and the wheels only ever reveal the ratio
  of their scales (that is ``k``), never the common one, and a bilinear ``g*w`` in the gyro's
  h let the EKF drift along that unobservable direction (one gyro outlier while w was
  uncertain pushed ``1 + g`` through zero). So g moves only with an absolute yaw, and its
  variance makes the yaw's grow with the angle turned (not with time: no white process noise
  can represent it).
- Wheel frame or external twist: ``v_m = v + c*w*L^2/4``, ``w_m = (1 + k)*w + c*v_m``
  (m/s, rad/s), with ``L`` the wheel distance (m) and ``v_m`` the frame's own measured speed
  (see :func:`wheel_h`); ``k`` is the wheels' yaw-rate scale relative to the gyro's. ``v``
  is the speed *in the wheels' scale*: the true speed is ``v/(1 + s)``, ``s`` the common
  distance scale error of both wheels (``speed_ratio``), which no sensor here observes
  either (the same change of variables as for g): the position's covariance grows with the
  distance driven, along the track.
  A twist's stamp is uncertain too (transport latency and jitter, and during a ramp a
  period's mean is not exactly the speed at its midpoint): a stamp error of ``stamp_std`` s
  makes the speed err by ``dv/dt * stamp_std`` and the yaw rate by ``dw/dt * stamp_std``,
  :func:`stamp_noise`.
- Zero-velocity update (ZUPT): ``z = [v, w] = [0, 0]``.
- Absolute yaw: ``z = yaw``, the residual wrapped to (-pi, pi].

Measurement functions come in threes: ``*_h(x)`` the predicted measurement (m,),
``*_jacobian(x)`` its Jacobian (m, NX), ``*_noise(...)`` its covariance R (m, m); the wheels'
pair also takes the measured speed the radius mismatch acts on.
"""

from __future__ import annotations

import math

import numpy as np

from fusion._jit import njit
from fusion.geometry.angles import wrap_angle_scalar

__all__ = [
    "NX",
    "gyro_h",
    "gyro_jacobian",
    "gyro_noise",
    "motion_terms",
    "odometry_noise",
    "process_noise",
    "process_noise_diagonal",
    "stamp_noise",
    "ticks_measurement",
    "transition",
    "transition_jacobian",
    "twist_measurement",
    "wheel_h",
    "wheel_jacobian",
    "yaw_h",
    "yaw_jacobian",
    "yaw_noise",
    "yaw_residual",
    "zupt_h",
    "zupt_jacobian",
    "zupt_noise",
]

NX = 10  # state size


# -- motion --------------------------------------------------------------------------------------
@njit
def motion_terms(x, dt):
    """Increments and Jacobian entries of the constant-twist motion over ``dt`` s.

    Returns ``(dx, dy, dyaw, f02, f03, f04, f08, f09, f12, f13, f14, f18, f19, f24, f28)``: the
    increments of x (m), y (m) and yaw (rad), and the non-zero off-diagonal entries
    ``F[i, j] = f_ij`` of the Jacobian ``F = I + ...`` (every other entry of ``F`` is that of
    the identity).
    """
    yaw = x[2]
    v = x[3]
    w = x[4]
    r = 1.0 / (1.0 + x[8])  # true rate per gyro-scale rate
    rv = 1.0 / (1.0 + x[9])  # true speed per wheel-scale speed
    dyaw = w * dt * r
    dyaw_dg = -dyaw * r
    phi = yaw + 0.5 * dyaw
    c = dt * rv * math.cos(phi)  # dx/dv
    s = dt * rv * math.sin(phi)  # dy/dv
    dx = v * c
    dy = v * s
    return (dx, dy, dyaw,
            -dy, c, -0.5 * dy * dt * r, -0.5 * dy * dyaw_dg, -dx * rv,
            dx, s, 0.5 * dx * dt * r, 0.5 * dx * dyaw_dg, -dy * rv,
            dt * r, dyaw_dg)


@njit
def transition(x, dt):
    """f(x, dt): the state (NX,) after ``dt`` s of constant-twist motion (a new array)."""
    t = motion_terms(x, dt)
    out = x.copy()
    out[0] += t[0]
    out[1] += t[1]
    out[2] += t[2]
    return out


@njit
def transition_jacobian(x, dt):
    """F(x, dt) = df/dx (NX, NX) at the prior state ``x``."""
    t = motion_terms(x, dt)
    F = np.eye(NX)
    cols = (2, 3, 4, 8, 9)  # the columns of rows x and y that motion_terms returns
    for row in range(2):
        for n in range(5):
            F[row, cols[n]] = t[3 + 5 * row + n]
    F[2, 4] = t[13]
    F[2, 8] = t[14]
    return F


@njit
def process_noise_diagonal(dt, q_v, q_w, q_b, q_k, q_c, q_g, q_s):
    """Diagonal of Q over ``dt`` s (a tuple of NX): random walks of v ((m/s)^2/s), w and b
    ((rad/s)^2/s), k (1/s), c ((rad/m)^2/s), g and s (1/s); the pose gets no noise of its
    own."""
    return (0.0, 0.0, 0.0, q_v * dt, q_w * dt, q_b * dt, q_k * dt, q_c * dt, q_g * dt,
            q_s * dt)


@njit
def process_noise(dt, q_v, q_w, q_b, q_k, q_c, q_g, q_s):
    """Q(dt) (NX, NX), diagonal: see :func:`process_noise_diagonal`."""
    q = process_noise_diagonal(dt, q_v, q_w, q_b, q_k, q_c, q_g, q_s)
    Q = np.zeros((NX, NX))
    for i in range(NX):
        Q[i, i] = q[i]
    return Q


@njit
def odometry_noise(x, dt, along_var, cross_var):
    """Pose block of Q over ``dt`` s: ``(Q_xx, Q_xy, Q_yy)`` (m^2) of a white position noise
    that grows with the distance driven ``d = |v| dt / (1 + s)`` (m): ``along_var`` and
    ``cross_var`` (m^2 per m) along and across the heading ``yaw``."""
    d = abs(x[3]) * dt / (1.0 + x[9])
    c = math.cos(x[2])
    s = math.sin(x[2])
    return (d * (along_var * c * c + cross_var * s * s), d * (along_var - cross_var) * c * s,
            d * (along_var * s * s + cross_var * c * c))


# -- gyro: z = w + b (w in the gyro's scale) ----------------------------------------------------
@njit
def gyro_h(x):
    """Predicted gyro rate about the world vertical, rad/s: ``[w + b]``."""
    return np.array([x[4] + x[5]])


@njit
def gyro_jacobian(x):
    """d(gyro_h)/dx (1, NX)."""
    H = np.zeros((1, NX))
    H[0, 4] = 1.0
    H[0, 5] = 1.0
    return H


@njit
def gyro_noise(variance):
    """R (1, 1) of one gyro sample with ``variance`` (rad/s)^2."""
    return np.full((1, 1), variance)


# -- wheel frame or external twist: v_m = v + c*w*L^2/4, w_m = (1 + k)*w + c*u -------------------
# u is the speed the radius mismatch c acts on: the frame's own measured speed v_m. The mismatch
# turns the wheels' own travel into a spurious yaw rate, so u = v_m is the model, and it keeps
# the state's speed out of the yaw-rate Jacobian: there, the speed state's quantisation ripple,
# in step with the yaw rate's (one wheel's extra tick comes a frame before the other's), gave
# the +1-tick frames of a straight drive another H than the -1-tick ones, and the sum over a
# long straight drive without a stop walked b and c along their unobservable direction (the
# bias by 3.6 deg/s over 130 s on a 780-tick encoder; tests/test_ekf_slip.py).
@njit
def wheel_h(x, wheel_distance, speed):
    """Predicted wheel twist ``[v_m, w_m]`` (m/s, rad/s) for wheel distance ``L`` (m);
    ``speed`` (m/s) is the speed the radius mismatch ``c`` acts on (the frame's measured
    speed; the state's ``x[3]`` for the filter's own expectation of the next frame)."""
    L2 = 0.25 * wheel_distance * wheel_distance
    return np.array([x[3] + x[7] * x[4] * L2, (1.0 + x[6]) * x[4] + x[7] * speed])


@njit
def wheel_jacobian(x, wheel_distance, speed):
    """d(wheel_h)/dx (2, NX), ``speed`` held as given (a measured value, not a state)."""
    L2 = 0.25 * wheel_distance * wheel_distance
    H = np.zeros((2, NX))
    H[0, 3] = 1.0
    H[0, 4] = x[7] * L2
    H[0, 7] = x[4] * L2
    H[1, 4] = 1.0 + x[6]
    H[1, 6] = x[4]
    H[1, 7] = speed
    return H


@njit
def _add_yaw_rate_noise(R, w_m, separation_std, wheel_w_std):
    """Noise every wheel yaw rate ``w_m`` (rad/s) shares: a relative ``separation_std`` (1)
    and a white ``wheel_w_std`` (rad/s), added to ``R[1, 1]`` in place."""
    R[1, 1] += (separation_std * w_m) ** 2 + wheel_w_std ** 2


@njit
def ticks_measurement(left, right, speed_ratio, period, wheel_distance, tick_std, scale_std,
                      separation_std, wheel_w_std):
    """The twist ``z = [v_m, w_m]`` (m/s, rad/s) of one wheel frame and its R (2, 2).

    ``left``, ``right``: ticks counted in one ``period`` (s); ``speed_ratio`` m/tick;
    ``wheel_distance`` L (m). Each wheel's travel has the noise of ``tick_std`` ticks
    (quantisation) and a relative ``scale_std``; ``(v, w) = M (dl, dr) / T`` with
    ``M = [[1/2, 1/2], [-1/L, 1/L]]`` carries it over. Returns ``(z, R)``.
    """
    T = period
    L = wheel_distance
    dl = left * speed_ratio
    dr = right * speed_ratio
    v_m = 0.5 * (dl + dr) / T
    w_m = (dr - dl) / (L * T)
    tick = tick_std * speed_ratio
    var_l = tick * tick + (scale_std * dl) ** 2
    var_r = tick * tick + (scale_std * dr) ** 2
    R = np.zeros((2, 2))
    R[0, 0] = 0.25 * (var_l + var_r) / (T * T)
    R[0, 1] = 0.5 * (var_r - var_l) / (L * T * T)
    R[1, 0] = R[0, 1]
    R[1, 1] = (var_l + var_r) / (L * L * T * T)
    _add_yaw_rate_noise(R, w_m, separation_std, wheel_w_std)
    return np.array([v_m, w_m]), R


@njit
def twist_measurement(v, w, v_std, w_std, scale_std, separation_std, wheel_w_std):
    """``z = [v, w]`` (m/s, rad/s) of an external wheel odometry (nav_msgs/Odometry twist)
    and its R (2, 2): ``v_std`` plus a relative ``scale_std`` on v, ``w_std`` on w, plus the
    wheel yaw-rate noise. Returns ``(z, R)``."""
    R = np.zeros((2, 2))
    R[0, 0] = v_std ** 2 + (scale_std * v) ** 2
    R[1, 1] = w_std ** 2
    _add_yaw_rate_noise(R, w, separation_std, wheel_w_std)
    return np.array([v, w]), R


@njit
def stamp_noise(R, dv_dt, dw_dt, stamp_std):
    """Add the noise of a twist's uncertain stamp to its R (2, 2) in place: a stamp off by
    ``stamp_std`` s (standard deviation) while the speed changes at ``dv_dt`` (m/s^2) and
    the yaw rate at ``dw_dt`` (rad/s^2) adds ``(dv_dt*stamp_std)^2`` to the speed's variance
    and ``(dw_dt*stamp_std)^2`` to the yaw rate's; both errors come from the same stamp, so
    they are fully correlated (``dv_dt*dw_dt*stamp_std^2`` off the diagonal)."""
    s2 = stamp_std * stamp_std
    R[0, 0] += dv_dt * dv_dt * s2
    R[1, 1] += dw_dt * dw_dt * s2
    R[0, 1] += dv_dt * dw_dt * s2
    R[1, 0] = R[0, 1]


# -- zero-velocity update: z = [v, w] = 0 --------------------------------------------------------
@njit
def zupt_h(x):
    """Predicted ``[v, w]`` (m/s, rad/s) of the zero-velocity pseudo-measurement."""
    return np.array([x[3], x[4]])


@njit
def zupt_jacobian(x):
    """d(zupt_h)/dx (2, NX)."""
    H = np.zeros((2, NX))
    H[0, 3] = 1.0
    H[1, 4] = 1.0
    return H


@njit
def zupt_noise(v_std, w_std):
    """R (2, 2) of the ZUPT: ``v_std`` m/s, ``w_std`` rad/s."""
    R = np.zeros((2, 2))
    R[0, 0] = v_std ** 2
    R[1, 1] = w_std ** 2
    return R


# -- absolute yaw: z = yaw, residual wrapped -----------------------------------------------------
@njit
def yaw_h(x):
    """Predicted yaw, rad (continuous, not wrapped)."""
    return np.array([x[2]])


@njit
def yaw_jacobian(x):
    """d(yaw_h)/dx (1, NX)."""
    H = np.zeros((1, NX))
    H[0, 2] = 1.0
    return H


@njit
def yaw_noise(std):
    """R (1, 1) of an absolute yaw with standard deviation ``std`` rad."""
    return np.full((1, 1), std * std)


@njit
def yaw_residual(z, hx):
    """``z - hx`` (1,) wrapped to (-pi, pi] rad: a yaw near +pi and one near -pi are close."""
    return np.array([wrap_angle_scalar(z[0] - hx[0])])
