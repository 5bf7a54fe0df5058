"""The 1 kHz rigid-body loop: firmware speed control, traction-limited tyres, body motion.

State (body frame at the axle midpoint, REP-103): pose ``x, y`` (m) and ``yaw`` (rad) in the
world (odom) frame; forward and lateral speed ``u``, ``lat`` (m/s) of the axle midpoint; yaw
rate ``r`` (rad/s); wheel spin rates ``spin_l``, ``spin_r`` (rad/s) and angles (rad).

Each step of ``dt`` s:

1. the firmware ramps the commanded twist (``accel_limit``, ``angular_accel_limit``) and turns
   it into wheel spin targets with the NOMINAL radius and wheel distance;
2. a PI loop per wheel gives the motor torque, saturated at ``torque_limit`` (no integration
   while saturated);
3. each tyre's contact patch slides at ``s = (u -/+ r*L/2 - spin*R_eff, lat)`` (m/s, left
   minus, right plus) with the TRUE distance ``L`` and effective radius ``R_eff``; the floor
   pushes back with ``-k*s`` capped at ``mu*N`` (friction circle). While ``|k*s| < mu*N``
   the tyre grips (``|s|`` is a creep of millimetres per second); at the cap it slides;
4. Newton-Euler for the body with its centre of mass ``d`` ahead of the axle (the caster
   passes no horizontal force), and ``J*dspin/dt = torque - F_x*R_eff - b*spin`` per wheel;
5. semi-implicit Euler: speeds first, then the pose with the new speeds.

The accelerations recorded are those of the axle midpoint in the body frame (m/s^2) and the
yaw acceleration (rad/s^2), evaluated at the state of the row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion._jit import njit
from fusion.evaluation.physics_sim.body import BodyParams, ControllerParams
from fusion.evaluation.physics_sim.mission import Mission

__all__ = ["PHYSICS_RATE", "BodyTrace", "simulate_body"]

#: Physics loop rate, Hz.
PHYSICS_RATE = 1000.0

# columns of the trace array
_COLS = ("x", "y", "yaw", "u", "lat", "r", "ax", "ay", "r_dot", "spin_l", "spin_r",
         "angle_l", "angle_r", "slip_l", "slip_r")


@dataclass
class BodyTrace:
    """The physics state at every step (arrays of N rows at ``PHYSICS_RATE``).

    Attributes:
        t: s.  x, y: m (odom).  yaw: rad, continuous.  u, lat: forward and lateral speed of
        the axle midpoint, m/s.  r: yaw rate, rad/s.  ax, ay: acceleration of the axle
        midpoint in the body frame, m/s^2.  r_dot: yaw acceleration, rad/s^2.
        spin_l, spin_r: wheel spin rates, rad/s.  angle_l, angle_r: wheel angles, rad.
        slip_l, slip_r: sliding speed of each contact patch, m/s.
        wheel_distance: true wheel distance, m.  radius: true (left, right) radius at rest, m.
    """

    t: NDArray[np.float64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    yaw: NDArray[np.float64]
    u: NDArray[np.float64]
    lat: NDArray[np.float64]
    r: NDArray[np.float64]
    ax: NDArray[np.float64]
    ay: NDArray[np.float64]
    r_dot: NDArray[np.float64]
    spin_l: NDArray[np.float64]
    spin_r: NDArray[np.float64]
    angle_l: NDArray[np.float64]
    angle_r: NDArray[np.float64]
    slip_l: NDArray[np.float64]
    slip_r: NDArray[np.float64]
    wheel_distance: float
    radius: tuple[float, float]


@njit
def _tyre(sx, sy, k, cap):  # pragma: no cover - compiled or plain
    """Floor force (N) on a contact patch sliding at (sx, sy) m/s, and its sliding speed (m/s;
    0 while it grips): ``-k*s`` capped at ``cap`` (the friction circle)."""
    fx = -k * sx
    fy = -k * sy
    f = math.hypot(fx, fy)
    if f > cap:
        return fx * cap / f, fy * cap / f, math.hypot(sx, sy)
    return fx, fy, 0.0


@njit
def _loop(dt, v_cmd, w_cmd, mu, p, init, out):  # pragma: no cover - compiled or plain
    m, izz, d, L, L_nom, R_l, R_r, R_nom, c_speed, J, b_w, k, N, a_lim, al_lim, kp, ki, \
        tau_max = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], \
        p[11], p[12], p[13], p[14], p[15], p[16], p[17]
    u, r, spin_l, spin_r, v_ref, w_ref, int_l, int_r = (init[0], init[1], init[2], init[3],
                                                        init[4], init[5], init[6], init[7])
    x = 0.0
    y = 0.0
    yaw = 0.0
    lat = 0.0
    ang_l = 0.0
    ang_r = 0.0
    for i in range(v_cmd.shape[0]):
        # 1. firmware ramp and wheel targets from the nominal geometry
        dv = v_cmd[i] - v_ref
        step = a_lim * dt
        v_ref += min(max(dv, -step), step)
        dw = w_cmd[i] - w_ref
        step = al_lim * dt
        w_ref += min(max(dw, -step), step)
        tgt_l = (v_ref - 0.5 * L_nom * w_ref) / R_nom
        tgt_r = (v_ref + 0.5 * L_nom * w_ref) / R_nom
        # 2. PI speed loops with clamping anti-windup
        e_l = tgt_l - spin_l
        e_r = tgt_r - spin_r
        tau_l = kp * e_l + ki * (int_l + e_l * dt)
        tau_r = kp * e_r + ki * (int_r + e_r * dt)
        if abs(tau_l) < tau_max:
            int_l += e_l * dt
        else:
            tau_l = math.copysign(tau_max, tau_l)
        if abs(tau_r) < tau_max:
            int_r += e_r * dt
        else:
            tau_r = math.copysign(tau_max, tau_r)
        # 3. tyre forces: regularised Coulomb friction, friction circle
        re_l = R_l * (1.0 + c_speed * abs(spin_l * R_l))
        re_r = R_r * (1.0 + c_speed * abs(spin_r * R_r))
        sx_l = u - 0.5 * L * r - spin_l * re_l
        sx_r = u + 0.5 * L * r - spin_r * re_r
        cap = mu[i] * N
        fx_l, fy_l, slide_l = _tyre(sx_l, lat, k, cap)
        fx_r, fy_r, slide_r = _tyre(sx_r, lat, k, cap)
        # 4. Newton-Euler about the centre of mass (d ahead of the axle)
        fx = fx_l + fx_r
        fy = fy_l + fy_r
        r_dot = ((fx_r - fx_l) * 0.5 * L - d * fy) / izz
        lat_dot = fy / m - u * r - d * r_dot
        u_dot = fx / m + lat * r + d * r * r
        spin_l_dot = (tau_l - fx_l * re_l - b_w * spin_l) / J
        spin_r_dot = (tau_r - fx_r * re_r - b_w * spin_r) / J
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = yaw
        out[i, 3] = u
        out[i, 4] = lat
        out[i, 5] = r
        out[i, 6] = u_dot - lat * r
        out[i, 7] = lat_dot + u * r
        out[i, 8] = r_dot
        out[i, 9] = spin_l
        out[i, 10] = spin_r
        out[i, 11] = ang_l
        out[i, 12] = ang_r
        out[i, 13] = slide_l
        out[i, 14] = slide_r
        # 5. semi-implicit Euler
        u += u_dot * dt
        lat += lat_dot * dt
        r += r_dot * dt
        spin_l += spin_l_dot * dt
        spin_r += spin_r_dot * dt
        c = math.cos(yaw)
        s = math.sin(yaw)
        x += (u * c - lat * s) * dt
        y += (u * s + lat * c) * dt
        yaw += r * dt
        ang_l += spin_l * dt
        ang_r += spin_r * dt


def simulate_body(
    mission: Mission,
    body: BodyParams | None = None,
    controller: ControllerParams | None = None,
    radius_error: tuple[float, float] = (0.0, 0.0),
    radius_speed_coeff: float = 0.0,
    separation_error: float = 0.0,
) -> BodyTrace:
    """Run the physics loop over the mission at :data:`PHYSICS_RATE`.

    Args:
        mission: commands, friction patches, starting twist.
        body, controller: the robot (defaults: :class:`BodyParams`, :class:`ControllerParams`).
        radius_error: (left, right) relative error of the true radius against
            ``body.wheel_radius``, 1.
        radius_speed_coeff: effective radius ``R*(1 + c*|spin*R|)``, 1 per m/s.
        separation_error: true wheel distance = ``body.wheel_distance * (1 + this)``, 1.

    Returns:
        The trace, one row per 1 ms step from t = 0 (the state before the step).
    """
    body = body or BodyParams()
    controller = controller or ControllerParams()
    dt = 1.0 / PHYSICS_RATE
    n = round(mission.duration * PHYSICS_RATE)
    t = np.arange(n) * dt
    v_cmd, w_cmd = mission.commands(t)
    mu = mission.friction(t, body.mu)
    L = body.wheel_distance * (1.0 + separation_error)
    R_l = body.wheel_radius * (1.0 + radius_error[0])
    R_r = body.wheel_radius * (1.0 + radius_error[1])
    p = np.array([body.mass, body.yaw_inertia, body.com_ahead, L, body.wheel_distance, R_l, R_r,
                  body.wheel_radius, radius_speed_coeff, body.wheel_inertia, body.wheel_damping,
                  body.contact_stiffness, body.wheel_normal_load, controller.accel_limit,
                  controller.angular_accel_limit, controller.kp, controller.ki,
                  controller.torque_limit], dtype=float)
    init = _steady_state(mission.initial_twist, body, controller, L, R_l, R_r, radius_speed_coeff)
    out = np.empty((n, len(_COLS)))
    _loop(dt, np.ascontiguousarray(v_cmd), np.ascontiguousarray(w_cmd),
          np.ascontiguousarray(mu), p, init, out)
    cols = {name: np.ascontiguousarray(out[:, j]) for j, name in enumerate(_COLS)}
    return BodyTrace(t=t, wheel_distance=L, radius=(R_l, R_r), **cols)


def _steady_state(twist, body, controller, L, R_l, R_r, c_speed) -> NDArray[np.float64]:
    """Initial ``u, r, spin_l, spin_r, v_ref, w_ref, int_l, int_r`` of a robot already
    following ``twist`` (the firmware's wheel targets reached, the body rolling on them)."""
    v0, w0 = (float(a) for a in twist)
    R = body.wheel_radius
    spin_l = (v0 - 0.5 * body.wheel_distance * w0) / R
    spin_r = (v0 + 0.5 * body.wheel_distance * w0) / R
    ground_l = spin_l * R_l * (1.0 + c_speed * abs(spin_l * R_l))
    ground_r = spin_r * R_r * (1.0 + c_speed * abs(spin_r * R_r))
    u = 0.5 * (ground_l + ground_r)
    r = (ground_r - ground_l) / L
    ki = controller.ki
    int_l = body.wheel_damping * spin_l / ki if ki > 0 else 0.0
    int_r = body.wheel_damping * spin_r / ki if ki > 0 else 0.0
    return np.array([u, r, spin_l, spin_r, v0, w0, int_l, int_r])
