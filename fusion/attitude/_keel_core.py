"""Compiled core of the Keel attitude estimator (see :mod:`fusion.attitude.keel`).

Everything here works on flat float64 arrays so that numba compiles it and the very same code
runs interpreted under ``FUSION_DISABLE_JIT=1``. One buffer ``B`` holds the state ``S``, the
parameters ``P`` and the counters ``C`` (the streaming call then passes a single array).

Frames: body (sensor) frame B; the "gyro frame" I, in which the bias-corrected gyro is
integrated alone (``S[QG]`` = B -> I), so I turns only by the residual gyro error; the 6-axis
earth frame E6 (z up, heading arbitrary), ``S[QA]`` = I -> E6 is an inclination-only rotation
(no vertical component); the earth frame E (ENU; y = magnetic north with a magnetometer),
E = Rz(delta) E6 with the scalar heading offset ``delta``. Output ``q = qz(delta) (x) qA (x) qG``.
"""

from __future__ import annotations

import math

import numpy as np

from fusion._jit import njit

__all__: list[str] = []  # private module: the names below are used by fusion.attitude.keel


def _layout(*fields):
    """Index of each (name, width) field in a flat array, and the total length."""
    index, offset = {}, 0
    for name, width in fields:
        index[name] = offset
        offset += width
    return index, offset


_S, S_LEN = _layout(
    ("q", 4), ("qg", 4), ("qa", 4), ("bias", 3), ("cov", 6),
    ("acc_lp", 6),          # low-passed accelerometer in I: value (3), rate (3)
    ("rot_lp", 18),         # low-passed B -> E6 rotation matrix: value (9), rate (9)
    ("acc_time", 1),        # time since the low-pass (re)started, s
    ("rest_gyro", 3), ("rest_acc", 3), ("rest_ready", 1), ("rest_time", 1), ("rest", 1),
    ("dt_cached", 1), ("coef", 4), ("rest_alpha", 1),
    ("last_dt", 1), ("pending_dt", 1), ("started", 1), ("acc_seen", 1),
    ("delta", 1), ("mag_time", 1), ("ref_norm", 1), ("ref_dip", 1), ("ref_time", 1),
    ("cand_norm", 1), ("cand_dip", 1), ("cand_time", 1), ("disturbed", 1), ("hold_time", 1),
    ("gap", 1), ("heading_unc", 1),
)
_P, P_LEN = _layout(
    ("gravity", 1), ("tau_acc", 1), ("motion_bias", 1), ("rest_bias", 1),
    ("bias_noise", 1), ("motion_var", 1), ("vertical_var", 1), ("rest_var", 1),
    ("bias_clip", 1), ("rest_gyro", 1), ("rest_acc", 1), ("rest_rate", 1), ("rest_duration", 1),
    ("rest_tau", 1), ("max_gap", 1),
    ("mag_tau", 1), ("mag_norm_tol", 1), ("mag_dip_tol", 1), ("mag_hold", 1),
    ("mag_slow_factor", 1), ("mag_new_time", 1), ("mag_new_rate", 1), ("mag_ref_tau", 1),
    ("mag_init_time", 1), ("mag_gate", 1), ("mag_gate_scale", 1),
    ("max_gyro", 1), ("max_accel", 1),
)
_C, C_LEN = _layout(
    ("gyro_skipped", 1), ("accel_skipped", 1), ("mag_skipped", 1), ("gaps", 1),
    ("rest_samples", 1), ("mag_disturbed", 1),
)
S_INDEX, P_INDEX, C_INDEX = _S, _P, _C

# Plain integer constants (numba folds module-level ints into the compiled code).
Q, QG, QA, BIAS, COV = _S["q"], _S["qg"], _S["qa"], _S["bias"], _S["cov"]
ACC_LP, ROT_LP, ACC_TIME = _S["acc_lp"], _S["rot_lp"], _S["acc_time"]
REST_GYRO, REST_ACC, REST_READY = _S["rest_gyro"], _S["rest_acc"], _S["rest_ready"]
REST_TIME, REST = _S["rest_time"], _S["rest"]
DT_CACHED, COEF, REST_ALPHA = _S["dt_cached"], _S["coef"], _S["rest_alpha"]
LAST_DT, PENDING_DT, STARTED, ACC_SEEN = (_S["last_dt"], _S["pending_dt"], _S["started"],
                                          _S["acc_seen"])
DELTA, MAG_TIME, REF_NORM, REF_DIP, REF_TIME = (_S["delta"], _S["mag_time"], _S["ref_norm"],
                                                 _S["ref_dip"], _S["ref_time"])
CAND_NORM, CAND_DIP, CAND_TIME = _S["cand_norm"], _S["cand_dip"], _S["cand_time"]
DISTURBED, HOLD_TIME, GAP, HEADING_UNC = (_S["disturbed"], _S["hold_time"], _S["gap"],
                                          _S["heading_unc"])

P_G, P_TAU_ACC, P_MOTION_BIAS, P_REST_BIAS = (_P["gravity"], _P["tau_acc"], _P["motion_bias"],
                                              _P["rest_bias"])
P_BIAS_NOISE, P_MOTION_VAR, P_VERTICAL_VAR, P_REST_VAR = (
    _P["bias_noise"], _P["motion_var"], _P["vertical_var"], _P["rest_var"])
P_BIAS_CLIP, P_REST_GYRO, P_REST_ACC, P_REST_RATE = (_P["bias_clip"], _P["rest_gyro"],
                                                     _P["rest_acc"], _P["rest_rate"])
P_REST_DURATION, P_REST_TAU, P_MAX_GAP = _P["rest_duration"], _P["rest_tau"], _P["max_gap"]
P_MAG_TAU, P_MAG_NORM_TOL, P_MAG_DIP_TOL, P_MAG_HOLD = (_P["mag_tau"], _P["mag_norm_tol"],
                                                       _P["mag_dip_tol"], _P["mag_hold"])
P_MAG_SLOW, P_MAG_NEW_TIME, P_MAG_NEW_RATE = (_P["mag_slow_factor"], _P["mag_new_time"],
                                             _P["mag_new_rate"])
P_MAG_REF_TAU, P_MAG_INIT_TIME, P_MAG_GATE, P_MAG_GATE_SCALE = (
    _P["mag_ref_tau"], _P["mag_init_time"], _P["mag_gate"], _P["mag_gate_scale"])
P_MAX_GYRO, P_MAX_ACCEL = _P["max_gyro"], _P["max_accel"]

C_GYRO_SKIP, C_ACC_SKIP, C_MAG_SKIP = _C["gyro_skipped"], _C["accel_skipped"], _C["mag_skipped"]
C_GAPS, C_REST, C_MAG_DIST = _C["gaps"], _C["rest_samples"], _C["mag_disturbed"]

B_S, B_P, B_C = 0, S_LEN, S_LEN + P_LEN
B_LEN = S_LEN + P_LEN + C_LEN

# Columns of the per-sample diagnostics array written by the batch runner.
D_BIAS, D_COV, D_REST, D_DISTURBED, D_DELTA, D_LEN = 0, 3, 9, 10, 11, 12

_TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------------------------


@njit
def lowpass_coefficients(dt, tau, coef):
    """Exact discretisation over ``dt`` (s) of the 2nd-order Butterworth low-pass
    ``y'' + (2/tau) y' + (2/tau^2) y = (2/tau^2) u`` (natural frequency sqrt(2)/tau, damping
    1/sqrt(2)) for an input held constant over the step. Writes the transition matrix
    ``[[c0, c1], [c2, c3]]`` of the deviation ``(y - u, y')`` into ``coef``.

    The state (value and rate) is physical, so steps of any length follow each other exactly:
    no fixed sample rate is assumed.
    """
    x = dt / tau
    decay = math.exp(-x)
    c, s = math.cos(x), math.sin(x)
    coef[0] = decay * (c + s)
    coef[1] = decay * tau * s
    coef[2] = -decay * (2.0 / tau) * s
    coef[3] = decay * (c - s)


@njit
def lowpass_step(state, i, n, u, coef):
    """Advance channel ``i`` of a bank of ``n`` filters (values ``state[i]``, rates
    ``state[n + i]``) by one step towards input ``u``."""
    dev = state[i] - u
    rate = state[n + i]
    state[i] = u + coef[0] * dev + coef[1] * rate
    state[n + i] = coef[2] * dev + coef[3] * rate


@njit
def tilt_quaternion(vx, vy, vz):
    """Shortest rotation taking the direction (vx, vy, vz) onto +z: ``[w, x, y, 0]``.

    Returns w, x, y. A vector pointing straight down gets the half turn about x.
    """
    n = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    if vz < -1.0 + 1e-12:
        return 0.0, 1.0, 0.0
    k = 1.0 / math.sqrt(2.0 * (1.0 + vz))
    return (1.0 + vz) * k, vy * k, -vx * k


@njit
def rotate(q0, q1, q2, q3, x, y, z):
    """``R(q) v`` for a unit quaternion ``[q0, q1, q2, q3]``."""
    tx = 2.0 * (q2 * z - q3 * y)
    ty = 2.0 * (q3 * x - q1 * z)
    tz = 2.0 * (q1 * y - q2 * x)
    return (x + q0 * tx + q2 * tz - q3 * ty,
            y + q0 * ty + q3 * tx - q1 * tz,
            z + q0 * tz + q1 * ty - q2 * tx)


@njit
def qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    """Quaternion product ``a (x) b`` (scalar first)."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@njit
def gyro_step(q0, q1, q2, q3, wx, wy, wz, dt):
    """``q (x) exp(w dt / 2)``: exact for a rate ``w`` (rad/s, body) constant over ``dt``."""
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    half = 0.5 * rate * dt
    if not half > 0.0:
        return q0, q1, q2, q3
    c = math.cos(half)
    k = math.sin(half) / rate
    n0, n1, n2, n3 = qmul(q0, q1, q2, q3, c, wx * k, wy * k, wz * k)
    inv = 1.0 / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
    return n0 * inv, n1 * inv, n2 * inv, n3 * inv


@njit
def wrap_angle(a):
    """``a`` wrapped to [-pi, pi)."""
    return a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)


@njit
def _scalar_update(S, hx, hy, hz, innovation, variance, clip):
    """Kalman update of the gyro bias ``S[BIAS]`` (covariance ``S[COV]``, upper triangle
    xx xy xz yy yz zz) with one scalar measurement ``innovation = h . (b_true - b) + noise``."""
    c = COV
    pxx, pxy, pxz, pyy, pyz, pzz = S[c], S[c + 1], S[c + 2], S[c + 3], S[c + 4], S[c + 5]
    phx = pxx * hx + pxy * hy + pxz * hz
    phy = pxy * hx + pyy * hy + pyz * hz
    phz = pxz * hx + pyz * hy + pzz * hz
    s = hx * phx + hy * phy + hz * phz + variance
    if innovation > clip:
        innovation = clip
    elif innovation < -clip:
        innovation = -clip
    kx, ky, kz = phx / s, phy / s, phz / s
    S[BIAS] += kx * innovation
    S[BIAS + 1] += ky * innovation
    S[BIAS + 2] += kz * innovation
    S[c] = pxx - kx * phx
    S[c + 1] = pxy - kx * phy
    S[c + 2] = pxz - kx * phz
    S[c + 3] = pyy - ky * phy
    S[c + 4] = pyz - ky * phz
    S[c + 5] = pzz - kz * phz


@njit
def _clip_bias(S, clip):
    for k in range(3):
        if S[BIAS + k] > clip:
            S[BIAS + k] = clip
        elif S[BIAS + k] < -clip:
            S[BIAS + k] = -clip


# --------------------------------------------------------------------------------------------
# Magnetometer: scalar heading offset with disturbance rejection
# --------------------------------------------------------------------------------------------


@njit
def mag_step(S, P, C, q0, q1, q2, q3, mx, my, mz, rate, dt):
    """Update the heading offset ``S[DELTA]`` (rad) from one magnetometer sample.

    ``q`` is the 6-axis attitude (B -> E6), ``rate`` the bias-corrected angular rate
    magnitude (rad/s). The field is trusted while its norm is within ``mag_norm_tol`` (relative)
    and its dip within ``mag_dip_tol`` (rad) of a slowly adapting reference; while disturbed the
    heading is held, for at most ``mag_hold`` s, then updated ``mag_slow_factor`` times slower.
    A new field that stays consistent for ``mag_new_time`` s of turning faster than
    ``mag_new_rate`` becomes the reference. Returns False when the sample is unusable.
    """
    norm = math.sqrt(mx * mx + my * my + mz * mz)
    if not (math.isfinite(norm) and norm > 0.0):
        C[C_MAG_SKIP] += 1
        return False
    ex, ey, ez = rotate(q0, q1, q2, q3, mx, my, mz)
    horizontal = math.sqrt(ex * ex + ey * ey)
    dip = math.atan2(ez, horizontal)
    measured = math.atan2(ex, ey)  # rotation about up that brings the field onto +y (north)
    innovation = wrap_angle(measured - S[DELTA])
    # How far the heading may have moved since the field was last trusted: turning adds
    # mag_gate_scale of the angle turned (gyro scale error), trusted updates shrink it.
    S[HEADING_UNC] += P[P_MAG_GATE_SCALE] * rate * dt

    if S[REF_TIME] < P[P_MAG_INIT_TIME]:
        # First seconds: the reference is the running mean; the field is trusted.
        w = dt / (S[REF_TIME] + dt) if S[REF_TIME] + dt > 0.0 else 1.0
        S[REF_NORM] += w * (norm - S[REF_NORM])
        S[REF_DIP] += w * (dip - S[REF_DIP])
        S[REF_TIME] += dt
        disturbed = False
    else:
        ok = (abs(norm - S[REF_NORM]) < P[P_MAG_NORM_TOL] * S[REF_NORM]
              and abs(dip - S[REF_DIP]) < P[P_MAG_DIP_TOL]
              and (abs(innovation) < P[P_MAG_GATE] + S[HEADING_UNC]
                   or S[MAG_TIME] < P[P_MAG_TAU]))
        if ok:
            disturbed = False
            S[HOLD_TIME] = 0.0
            S[CAND_NORM], S[CAND_TIME] = 0.0, 0.0
            beta = dt / (P[P_MAG_REF_TAU] + dt)
            S[REF_NORM] += beta * (norm - S[REF_NORM])
            S[REF_DIP] += beta * (dip - S[REF_DIP])
        else:
            disturbed = True
            S[HOLD_TIME] += dt
            consistent = (S[CAND_NORM] > 0.0
                          and abs(norm - S[CAND_NORM]) < P[P_MAG_NORM_TOL] * S[CAND_NORM]
                          and abs(dip - S[CAND_DIP]) < P[P_MAG_DIP_TOL])
            if consistent:
                if rate > P[P_MAG_NEW_RATE]:
                    S[CAND_TIME] += dt
                w = dt / (S[CAND_TIME] + dt) if S[CAND_TIME] + dt > 0.0 else 1.0
                S[CAND_NORM] += w * (norm - S[CAND_NORM])
                S[CAND_DIP] += w * (dip - S[CAND_DIP])
            else:
                S[CAND_NORM], S[CAND_DIP], S[CAND_TIME] = norm, dip, 0.0
            if S[CAND_TIME] >= P[P_MAG_NEW_TIME]:
                # A field that stayed consistent while turning is a new homogeneous field.
                S[REF_NORM], S[REF_DIP] = S[CAND_NORM], S[CAND_DIP]
                S[CAND_NORM], S[CAND_TIME], S[HOLD_TIME] = 0.0, 0.0, 0.0
                disturbed = False
    S[DISTURBED] = 1.0 if disturbed else 0.0
    if disturbed:
        C[C_MAG_DIST] += 1
    if horizontal <= 0.0:
        return True
    tau = P[P_MAG_TAU]
    if not disturbed:
        gain = 1.0 - math.exp(-dt / tau)
        start = dt / (S[MAG_TIME] + dt) if S[MAG_TIME] + dt > 0.0 else 1.0
        if start > gain:
            gain = start
        S[MAG_TIME] += dt
        S[HEADING_UNC] *= 1.0 - gain
    elif S[HOLD_TIME] > P[P_MAG_HOLD]:
        gain = 1.0 - math.exp(-dt / (tau * P[P_MAG_SLOW]))
    else:
        gain = 0.0
    S[DELTA] = wrap_angle(S[DELTA] + gain * innovation)
    return True


# --------------------------------------------------------------------------------------------
# One sample
# --------------------------------------------------------------------------------------------


@njit
def step(S, P, C, gx, gy, gz, ax, ay, az, mx, my, mz, use_mag, still, kx, ky, kz, dt):
    """Advance the state by one sample (see the module docstring of fusion.attitude.keel).

    ``dt`` is the time since the previous sample (s; 0 only for a first sample with no known
    period). ``still``: 1 known still, 0 known moving, -1 unknown. ``k*``: known kinematic
    acceleration in the body frame, m/s^2, subtracted from the accelerometer.
    """
    mg = P[P_MAX_GYRO]  # components first (false for NaN), so 1e200 never overflows
    if not (abs(gx) <= mg and abs(gy) <= mg and abs(gz) <= mg
            and gx * gx + gy * gy + gz * gz <= mg * mg):  # non-finite or corrupt
        C[C_GYRO_SKIP] += 1
        S[PENDING_DT] += dt  # the next sample integrates over the skipped interval too
        return
    dt += S[PENDING_DT]
    S[PENDING_DT] = 0.0

    # -- gap policy: never integrate one giant step ------------------------------------------
    dt_int = dt
    S[GAP] = 0.0
    if S[STARTED] != 0.0 and dt > P[P_MAX_GAP]:
        C[C_GAPS] += 1
        S[GAP] = 1.0
        dt_int = S[LAST_DT]  # this sample's rate, over the last regular period
        S[ACC_TIME] = 0.0  # the inertial-frame history no longer lines up: restart it
        S[REST_TIME] = 0.0
        S[REST_READY] = 0.0
        S[MAG_TIME] = 0.0  # re-acquire the heading at the start-up gain
        S[HOLD_TIME] = 0.0
    elif dt > 0.0:
        S[LAST_DT] = dt
    S[STARTED] = 1.0

    # -- coefficients for this step length (cached: equal periods cost nothing) ---------------
    if dt_int != S[DT_CACHED]:
        S[DT_CACHED] = dt_int
        if dt_int > 0.0:
            lowpass_coefficients(dt_int, P[P_TAU_ACC], S[COEF:COEF + 4])
            S[REST_ALPHA] = 1.0 - math.exp(-dt_int / P[P_REST_TAU])
        else:
            S[COEF], S[COEF + 1], S[COEF + 2], S[COEF + 3] = 1.0, 0.0, 0.0, 1.0
            S[REST_ALPHA] = 0.0

    # -- strapdown integration of the bias-corrected gyro (exact for a constant rate) ---------
    wx, wy, wz = gx - S[BIAS], gy - S[BIAS + 1], gz - S[BIAS + 2]
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    q0, q1, q2, q3 = gyro_step(S[QG], S[QG + 1], S[QG + 2], S[QG + 3], wx, wy, wz, dt_int)

    # -- bias covariance: process noise over the whole interval (gaps included) --------------
    grow = P[P_BIAS_NOISE] * dt
    S[COV] += grow
    S[COV + 3] += grow
    S[COV + 5] += grow

    ma = P[P_MAX_ACCEL]
    anorm = 0.0
    if abs(ax) <= ma and abs(ay) <= ma and abs(az) <= ma:  # false for NaN and inf
        anorm = math.sqrt(ax * ax + ay * ay + az * az)
    acc_ok = 0.0 < anorm <= ma
    if not acc_ok:
        C[C_ACC_SKIP] += 1
    if acc_ok and S[ACC_SEEN] == 0.0:
        # First accelerometer sample: start the gyro frame level (roll, pitch from gravity,
        # yaw 0), so the inclination correction starts near identity.
        roll = math.atan2(ay, az)
        pitch = math.atan2(-ax, math.sqrt(ay * ay + az * az))
        cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
        cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
        q0, q1, q2, q3 = cp * cr, cp * sr, sp * cr, -sp * sr
        S[ACC_SEEN] = 1.0
    S[QG], S[QG + 1], S[QG + 2], S[QG + 3] = q0, q1, q2, q3

    # -- rest detection ----------------------------------------------------------------------
    rest = False
    if acc_ok:
        if S[REST_READY] == 0.0:
            S[REST_GYRO], S[REST_GYRO + 1], S[REST_GYRO + 2] = gx, gy, gz
            S[REST_ACC], S[REST_ACC + 1], S[REST_ACC + 2] = ax, ay, az
            S[REST_READY] = 1.0
        al = S[REST_ALPHA]
        S[REST_GYRO] += al * (gx - S[REST_GYRO])
        S[REST_GYRO + 1] += al * (gy - S[REST_GYRO + 1])
        S[REST_GYRO + 2] += al * (gz - S[REST_GYRO + 2])
        S[REST_ACC] += al * (ax - S[REST_ACC])
        S[REST_ACC + 1] += al * (ay - S[REST_ACC + 1])
        S[REST_ACC + 2] += al * (az - S[REST_ACC + 2])
        if still < 0.0:
            dgx, dgy, dgz = gx - S[REST_GYRO], gy - S[REST_GYRO + 1], gz - S[REST_GYRO + 2]
            dax, day, daz = ax - S[REST_ACC], ay - S[REST_ACC + 1], az - S[REST_ACC + 2]
            lg = (S[REST_GYRO] * S[REST_GYRO] + S[REST_GYRO + 1] * S[REST_GYRO + 1]
                  + S[REST_GYRO + 2] * S[REST_GYRO + 2])
            thr_g, thr_a, thr_r = P[P_REST_GYRO], P[P_REST_ACC], P[P_REST_RATE]
            quiet = (dgx * dgx + dgy * dgy + dgz * dgz < thr_g * thr_g
                     and dax * dax + day * day + daz * daz < thr_a * thr_a
                     and lg < thr_r * thr_r)
        else:
            quiet = still > 0.0
        if quiet:
            S[REST_TIME] += dt_int
            rest = S[REST_TIME] >= P[P_REST_DURATION]
        else:
            S[REST_TIME] = 0.0
    elif still == 0.0:
        S[REST_TIME] = 0.0
    S[REST] = 1.0 if rest else 0.0

    # -- inclination: low-pass the accelerometer in the gyro frame ---------------------------
    moving_update = False
    ex = ey = 0.0
    if acc_ok:
        if not (abs(kx) <= ma and abs(ky) <= ma and abs(kz) <= ma):
            kx = ky = kz = 0.0  # a known acceleration no robot has (a corrupt input): unknown
        fx, fy, fz = ax - kx, ay - ky, az - kz
        ix, iy, iz = rotate(q0, q1, q2, q3, fx, fy, fz)
        # B -> E6 rotation matrix, low-passed alongside (the bias update's measurement model).
        a0, a1, a2, a3 = S[QA], S[QA + 1], S[QA + 2], S[QA + 3]
        r0, r1, r2, r3 = qmul(a0, a1, a2, a3, q0, q1, q2, q3)
        m00 = 1.0 - 2.0 * (r2 * r2 + r3 * r3)
        m01 = 2.0 * (r1 * r2 - r0 * r3)
        m02 = 2.0 * (r1 * r3 + r0 * r2)
        m10 = 2.0 * (r1 * r2 + r0 * r3)
        m11 = 1.0 - 2.0 * (r1 * r1 + r3 * r3)
        m12 = 2.0 * (r2 * r3 - r0 * r1)
        m20 = 2.0 * (r1 * r3 - r0 * r2)
        m21 = 2.0 * (r2 * r3 + r0 * r1)
        m22 = 1.0 - 2.0 * (r1 * r1 + r2 * r2)
        lp = S[ACC_LP:ACC_LP + 6]
        rl = S[ROT_LP:ROT_LP + 18]
        t = S[ACC_TIME]
        if t < P[P_TAU_ACC]:
            # Start-up: the running mean (time-weighted), rates zero; at tau the filter takes
            # over from this steady state, with no step.
            w = dt_int / (t + dt_int) if t + dt_int > 0.0 else 1.0
            lp[0] += w * (ix - lp[0])
            lp[1] += w * (iy - lp[1])
            lp[2] += w * (iz - lp[2])
            lp[3] = lp[4] = lp[5] = 0.0
            rl[0] += w * (m00 - rl[0])
            rl[1] += w * (m01 - rl[1])
            rl[2] += w * (m02 - rl[2])
            rl[3] += w * (m10 - rl[3])
            rl[4] += w * (m11 - rl[4])
            rl[5] += w * (m12 - rl[5])
            rl[6] += w * (m20 - rl[6])
            rl[7] += w * (m21 - rl[7])
            rl[8] += w * (m22 - rl[8])
            for j in range(9, 18):
                rl[j] = 0.0
        else:
            cf = S[COEF:COEF + 4]
            lowpass_step(lp, 0, 3, ix, cf)
            lowpass_step(lp, 1, 3, iy, cf)
            lowpass_step(lp, 2, 3, iz, cf)
            lowpass_step(rl, 0, 9, m00, cf)
            lowpass_step(rl, 1, 9, m01, cf)
            lowpass_step(rl, 2, 9, m02, cf)
            lowpass_step(rl, 3, 9, m10, cf)
            lowpass_step(rl, 4, 9, m11, cf)
            lowpass_step(rl, 5, 9, m12, cf)
            lowpass_step(rl, 6, 9, m20, cf)
            lowpass_step(rl, 7, 9, m21, cf)
            lowpass_step(rl, 8, 9, m22, cf)
            moving_update = dt_int > 0.0
        S[ACC_TIME] = t + dt_int
        vx, vy, vz = lp[0], lp[1], lp[2]
        if vx * vx + vy * vy + vz * vz > 0.0:
            n0, n1, n2 = tilt_quaternion(vx, vy, vz)
            # Correction since the last sample, as a rotation vector in E6:
            # qa_new (x) conj(qa_old), both with zero z component.
            c0, cx, cy, _ = qmul(n0, n1, n2, 0.0, a0, -a1, -a2, -a3)
            if c0 < 0.0:
                cx, cy = -cx, -cy
            ex, ey = 2.0 * cx, 2.0 * cy
            S[QA], S[QA + 1], S[QA + 2], S[QA + 3] = n0, n1, n2, 0.0
            if n0 < 0.9238795325112867:
                # More than 45 deg between the gyro frame and level: fold the correction
                # into the gyro frame (exactly; the low-pass is linear) and start again at
                # identity, so the correction never nears its singularity.
                _fold_correction(S)
                q0, q1, q2, q3 = S[QG], S[QG + 1], S[QG + 2], S[QG + 3]

    # -- gyro-bias Kalman filter -----------------------------------------------------------
    clip = P[P_BIAS_CLIP]
    if dt_int > 0.0:
        if rest and P[P_REST_BIAS] != 0.0:
            var = P[P_REST_VAR] / dt_int
            _scalar_update(S, 1.0, 0.0, 0.0, S[REST_GYRO] - S[BIAS], var, clip)
            _scalar_update(S, 0.0, 1.0, 0.0, S[REST_GYRO + 1] - S[BIAS + 1], var, clip)
            _scalar_update(S, 0.0, 0.0, 1.0, S[REST_GYRO + 2] - S[BIAS + 2], var, clip)
            C[C_REST] += 1
        elif moving_update and P[P_MOTION_BIAS] != 0.0:
            # The correction rate -e/dt measures the horizontal E6 components of the bias
            # error, seen through the low-passed rotation (same lag as the accelerometer).
            rl = S[ROT_LP:ROT_LP + 9]
            var = P[P_MOTION_VAR] / dt_int
            _scalar_update(S, rl[0], rl[1], rl[2], -ex / dt_int, var, clip)
            _scalar_update(S, rl[3], rl[4], rl[5], -ey / dt_int, var, clip)
            # The vertical component is unobservable while moving: a weak pull to zero.
            vz = -(rl[6] * S[BIAS] + rl[7] * S[BIAS + 1] + rl[8] * S[BIAS + 2])
            _scalar_update(S, rl[6], rl[7], rl[8], vz, P[P_VERTICAL_VAR] / dt_int, clip)
        _clip_bias(S, clip)

    # -- output: heading offset (9-axis) on top of the 6-axis attitude -----------------------
    a0, a1, a2, a3 = S[QA], S[QA + 1], S[QA + 2], S[QA + 3]
    r0, r1, r2, r3 = qmul(a0, a1, a2, a3, q0, q1, q2, q3)
    if use_mag:
        if S[ACC_SEEN] != 0.0:
            mag_step(S, P, C, r0, r1, r2, r3, mx, my, mz, rate, dt_int)
        elif not (math.isfinite(mx * mx + my * my + mz * mz) and mx * mx + my * my + mz * mz > 0):
            C[C_MAG_SKIP] += 1  # counted as mag_step counts (no attitude yet to use it with)
    d = S[DELTA]
    if d != 0.0:
        r0, r1, r2, r3 = qmul(math.cos(0.5 * d), 0.0, 0.0, math.sin(0.5 * d), r0, r1, r2, r3)
    S[Q], S[Q + 1], S[Q + 2], S[Q + 3] = r0, r1, r2, r3


@njit
def _fold_correction(S):
    """qg <- qa (x) qg; the low-passed accelerometer (in I) turns with it; qa <- identity."""
    a0, a1, a2, a3 = S[QA], S[QA + 1], S[QA + 2], S[QA + 3]
    q0, q1, q2, q3 = S[QG], S[QG + 1], S[QG + 2], S[QG + 3]
    S[QG], S[QG + 1], S[QG + 2], S[QG + 3] = qmul(a0, a1, a2, a3, q0, q1, q2, q3)
    for base in (ACC_LP, ACC_LP + 3):
        x, y, z = rotate(a0, a1, a2, a3, S[base], S[base + 1], S[base + 2])
        S[base], S[base + 1], S[base + 2] = x, y, z
    S[QA], S[QA + 1], S[QA + 2], S[QA + 3] = 1.0, 0.0, 0.0, 0.0


# --------------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------------


@njit
def run_batch(B, gyro, acc, mag, use_mag, dt, still, known, out, diag):
    """``step`` over N rows. ``dt`` has N entries or 1 (constant); ``still`` N entries (NaN:
    unknown) or none; ``known`` (N, 3) or (0, 3); ``diag`` (N, D_LEN) or (0, D_LEN)."""
    S, P, C = B[B_S:B_P], B[B_P:B_C], B[B_C:]
    n = gyro.shape[0]
    const_dt = dt.shape[0] == 1
    have_still = still.shape[0] > 0
    have_known = known.shape[0] > 0
    record = diag.shape[0] > 0
    for i in range(n):
        d = dt[0] if const_dt else dt[i]
        mx = my = mz = 0.0
        if use_mag:
            mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
        s = -1.0
        if have_still:
            v = still[i]
            if v == v:
                s = 1.0 if v != 0.0 else 0.0
        kx = ky = kz = 0.0
        if have_known:
            kx, ky, kz = known[i, 0], known[i, 1], known[i, 2]
            if not (math.isfinite(kx) and math.isfinite(ky) and math.isfinite(kz)):
                kx = ky = kz = 0.0
        step(S, P, C, gyro[i, 0], gyro[i, 1], gyro[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
             mx, my, mz, use_mag, s, kx, ky, kz, d)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = S[Q], S[Q + 1], S[Q + 2], S[Q + 3]
        if record:
            for j in range(3):
                diag[i, D_BIAS + j] = S[BIAS + j]
            for j in range(6):
                diag[i, D_COV + j] = S[COV + j]
            diag[i, D_REST] = S[REST]
            diag[i, D_DISTURBED] = S[DISTURBED]
            diag[i, D_DELTA] = S[DELTA]


@njit
def run_one6(B, g, a, dt):
    """Streaming entry, no magnetometer, no external knowledge."""
    step(B[B_S:B_P], B[B_P:B_C], B[B_C:], g[0], g[1], g[2], a[0], a[1], a[2],
         0.0, 0.0, 0.0, False, -1.0, 0.0, 0.0, 0.0, dt)


@njit
def run_one(B, g, a, m, x, dt):
    """Streaming entry with everything: ``m`` the field (used when ``x[0]`` != 0),
    ``x[1]`` stillness (1, 0, or -1 unknown), ``x[2:5]`` known kinematic acceleration."""
    step(B[B_S:B_P], B[B_P:B_C], B[B_C:], g[0], g[1], g[2], a[0], a[1], a[2],
         m[0], m[1], m[2], x[0] != 0.0, x[1], x[2], x[3], x[4], dt)


# --------------------------------------------------------------------------------------------
# Offline (non-causal) building blocks
# --------------------------------------------------------------------------------------------


@njit
def strapdown(gyro, bias, dt_int, q_start, out):
    """Integrate ``gyro - bias`` (rad/s, rows) over the periods ``dt_int`` (s) from
    ``q_start``; non-finite gyro rows hold the attitude. Writes (N, 4) ``out``."""
    q0, q1, q2, q3 = q_start[0], q_start[1], q_start[2], q_start[3]
    for i in range(gyro.shape[0]):
        wx, wy, wz = gyro[i, 0] - bias[i, 0], gyro[i, 1] - bias[i, 1], gyro[i, 2] - bias[i, 2]
        if math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz):
            q0, q1, q2, q3 = gyro_step(q0, q1, q2, q3, wx, wy, wz, dt_int[i])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3


@njit
def lowpass_pass(x, dt_int, restart, tau, out):
    """Causal low-pass of the rows of ``x`` (N, 3) with the start-up rule of ``step`` (running
    mean for the first ``tau`` s after the start and after each ``restart``). Non-finite rows
    are skipped (the output holds). ``dt_int[i]`` is the period before row i."""
    st = np.zeros(6)
    coef = np.array([1.0, 0.0, 0.0, 1.0])
    cached = -1.0
    t = 0.0
    for i in range(x.shape[0]):
        if restart[i]:
            t = 0.0
        d = dt_int[i]
        u0, u1, u2 = x[i, 0], x[i, 1], x[i, 2]
        if math.isfinite(u0) and math.isfinite(u1) and math.isfinite(u2):
            if t < tau:
                w = d / (t + d) if t + d > 0.0 else 1.0
                st[0] += w * (u0 - st[0])
                st[1] += w * (u1 - st[1])
                st[2] += w * (u2 - st[2])
                st[3] = st[4] = st[5] = 0.0
            else:
                if d != cached:
                    cached = d
                    lowpass_coefficients(d, tau, coef)
                lowpass_step(st, 0, 3, u0, coef)
                lowpass_step(st, 1, 3, u1, coef)
                lowpass_step(st, 2, 3, u2, coef)
            t += d
        out[i, 0], out[i, 1], out[i, 2] = st[0], st[1], st[2]


@njit
def tilt_corrected(qg, v, out):
    """Per row: the inclination-only correction bringing ``v`` (low-passed accelerometer in I)
    onto +z, applied on the left of ``qg``: ``out = tilt(v) (x) qg`` (B -> E6)."""
    for i in range(qg.shape[0]):
        a0, a1, a2 = tilt_quaternion(v[i, 0], v[i, 1], v[i, 2])
        q0, q1, q2, q3 = qg[i, 0], qg[i, 1], qg[i, 2], qg[i, 3]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = qmul(a0, a1, a2, 0.0, q0, q1, q2, q3)


@njit
def heading_pass(B, q6, mag, rates, dt_int, restart, out_delta, out_disturbed):
    """Run ``mag_step`` over rows of a given 6-axis attitude; writes the heading offset and
    the disturbance flag per row (the state buffer ``B`` supplies parameters and state)."""
    S, P, C = B[B_S:B_P], B[B_P:B_C], B[B_C:]
    for i in range(q6.shape[0]):
        if restart[i]:
            S[MAG_TIME] = 0.0
            S[HOLD_TIME] = 0.0
        if math.isfinite(q6[i, 0]):
            mag_step(S, P, C, q6[i, 0], q6[i, 1], q6[i, 2], q6[i, 3],
                     mag[i, 0], mag[i, 1], mag[i, 2], rates[i], dt_int[i])
        out_delta[i] = S[DELTA]
        out_disturbed[i] = S[DISTURBED]
