"""Compiled core of the planar EKF (private; see :mod:`fusion.planar.ekf` for the filter and units).

The algebra (motion, process noise, each measurement's h, Jacobian and R) is that of
:mod:`fusion.planar.model`; this module adds the Kalman equations and the filter's logic (time
bookkeeping, ZUPTs, slip gating, the late-input policy). Plain loops over NX x NX matrices in the
numba subset: numba compiles them (``fast`` extra), or they run interpreted with identical IEEE
results. One function, :func:`step_core`, handles one input event (time bookkeeping,
prediction, update); the streaming methods and the batch loop of
:class:`fusion.planar.ekf.PlanarEKF` both call it, so they agree exactly.

State ``x = [x, y, yaw, v, w, b, k, c, g, s]``. Parameter vector ``par`` and bookkeeping vector
``aux`` use the index constants below.
"""

from __future__ import annotations

import math

import numpy as np

from fusion._jit import njit
from fusion.geometry.angles import wrap_angle_scalar  # noqa: F401  (the old name, re-exported)
from fusion.planar.model import (
    NX,
    gyro_h,
    gyro_jacobian,
    gyro_noise,
    motion_terms,
    odometry_noise,
    process_noise_diagonal,
    stamp_noise,
    ticks_measurement,
    twist_measurement,
    wheel_h,
    wheel_jacobian,
    yaw_h,
    yaw_jacobian,
    yaw_noise,
    yaw_residual,
    zupt_h,
    zupt_jacobian,
    zupt_noise,
)

__all__ = ["ACCEL_HOLD", "AUX_SIZE", "PAR_SIZE", "ROW_WIDTH", "UNKNOWN_RATE_VAR",
           "UNKNOWN_SPEED_VAR", "batch_core", "held_pose_offset", "predict_core",
           "reported_pose_covariance", "step_core", "update_core"]

# par indices
P_SPEED_RATIO = 0
P_WHEEL_DISTANCE = 1
P_PERIOD = 2
P_Q_V = 3
P_Q_W = 4
P_Q_B = 5
P_GYRO_VAR = 6
P_TICK_STD = 7
P_SCALE_STD = 8
P_SEP_STD = 9
P_ZUPT_V_STD = 10
P_ZUPT_W_STD = 11
P_GATE = 12
P_SLIP_INFLATION = 13
P_ZUPT_FRAMES = 14
P_LATE_TOLERANCE = 15
P_MAX_DT = 16
P_WHEEL_W_STD = 17
P_Q_K = 18
P_Q_C = 19
P_STILL_SCALE = 20
P_TWIST_V_STD = 21
P_TWIST_W_STD = 22
P_TWIST_ZERO_V = 23
P_TWIST_ZERO_W = 24
P_GYRO_LIMIT = 25
P_STOP_DECEL = 26
P_YAW_FIX_RATE = 27
P_YAW_FIX_BURST = 28
P_WHEEL_W_CORR = 29
P_TURN_W_STD = 30
P_HORIZON = 31
P_SPEED_VAR0 = 32
P_MAX_RATE = 33
P_MAX_SPEED = 34
P_Q_G = 35
P_Q_S = 36
P_TRUST_TIME = 37  # time constant of the wheel yaw rate's slip share, s
P_MAX_SLIP_SHARE = 38  # above this slip share the wheels' yaw rates are not fused
P_PROOF_TIME = 39  # s of agreeing turns before the wheels' yaw rates are fused
P_ODO_ALONG = 40
P_ODO_CROSS = 41
P_SLIP_Q_V = 42
P_ACCEL_Q_V = 43  # > 0: the forward specific force drives v, with this PSD, (m/s)^2/s
P_OFFSET_TIME = 44  # s, time constant of the accelerometer offset learnt while driving
P_STAMP_STD = 45  # s, standard deviation of a wheel frame's or twist's stamp
P_SPEED_RAMP_TIME = 46  # s: v's random walk is at least (last rate of change)^2 x this
P_SLIP_WINDOW = 47  # s, time constant of the persistent-disagreement test (0: off)
P_STRAIGHT_RATE = 48  # rad/s: an untrusted wheel yaw rate below this says "straight" (0: off)
P_K_STD = 49  # 1: prior standard deviation of k (calib_k_std); see _refit_wheel_scale
P_C_STD = 50  # rad/m: prior standard deviation of c (calib_c_std)
P_REFIT = 51  # prior sigmas of k the wheels' fitted scale may be off before k restarts (0: off)
P_C_MEAN = 52  # rad/m: prior mean of c (wheel_rate_per_speed), where a restart puts it
PAR_SIZE = 53
# aux indices
A_T = 0
A_ZERO_COUNT = 1
A_LATE_DROPPED = 2
A_LATE_APPLIED = 3
A_SLIPS = 4
A_ZUPTS = 5
A_LAST_D2 = 6
A_UPDATES = 7
A_ERROR = 8
A_SATURATED = 9
A_IMU_MOTION = 10  # the last IMU sample's motion code (fusion.planar.imu_motion)
A_FAULTS = 11  # wheel frames or twists flagged as encoder faults
A_FLAGS = 12  # flags of the last wheel frame or twist: FLAG_ZUPT | FLAG_SLIP | FLAG_FAULT
A_WHEEL_T = 13  # effective time of the last wheel frame or twist (NaN: none yet)
A_YAW_BUDGET = 14  # yaw correction rate measurements may still make now, rad
# gap policy (see _advance), per speed state v (+0) and w (+1):
A_V_T = 15  # filter time of the last measurement of v (NaN: forgotten)
A_W_T = 16  # the same for w
A_V_FORGOT = 17  # filter time at which v was forgotten
A_W_FORGOT = 18
A_V_RMS2 = 19  # second moment of v when forgotten, (m/s)^2
A_W_RMS2 = 20  # the same for w, (rad/s)^2
A_SPEED_RESETS = 21  # v or w forgotten after max_extrapolation without a measurement
A_PREDICTIONS = 22  # predict_core calls
A_SLIP_SHARE = 23  # exponentially weighted share of wheel frames or twists above the gate
A_DISTRUST = 24  # 1: the wheels' yaw rates are not fused (their slip share is too high)
A_DISTRUSTED = 25  # turning wheel frames or twists whose yaw rate was not fused for that
# (disproven), or that disagreed before an external odometry was proven
A_CLIPPED = 26  # filter time of the last saturated gyro sample (NaN: none yet)
A_AGREED = 27  # s of turning wheel frames or twists that agreed with the gyro
A_YAW_PENDING = 28  # heading correction owed beyond the yaw budget, rad (_rate_update)
A_ACCEL_SLIPS = 29  # wheel frames the accelerometer flagged as slipping (EV_WHEELS_SLIP)
A_FX = 30  # the last forward specific force (EV_ACCEL), m/s^2 (NaN: none yet)
A_FX_T = 31  # its filter time, s
A_FX_OFFSET = 32  # the accelerometer's forward offset (bias + gravity), m/s^2 (NaN: unknown)
A_FX_REST_N = 33  # samples averaged into the offset during the current stop
A_FIRST_GYRO = 34  # 1: the next gyro sample is the first and measures w alone (see step_core)
# after the previous wheel twist (frame or external twist; not an encoder-fault frame): its
# effective time (NaN: none yet) and the twist wheel_h of the posterior, m/s and rad/s, for the
# stamp noise
A_TWIST_T = 35
A_TWIST_V = 36
A_TWIST_W = 37
A_SPEED_RATE = 38  # m/s^2, the speed's rate of change between the last two wheel twists
A_FIRST_SPEED = 39  # 1: the next fused wheel frame or twist is the first and sets v alone
# least-squares fit of the wheels' yaw rate against the gyro's (bias included) over turning
# frames: count and sums of x, y, x^2, x*y (rad/s; _rate_scale_agrees)
A_FIT_N = 40
A_FIT_SX = 41
A_FIT_SY = 42
A_FIT_SXX = 43
A_FIT_SXY = 44
# the position error (m) the held heading has driven into the pose: while a heading correction
# is owed (A_YAW_PENDING), the pose is propagated along a heading off by that amount
# (held_pose_offset)
A_HELD_X = 45
A_HELD_Y = 46
# the persistent-disagreement test (_persistent_disagreement): filter time of its last frame,
# exponentially weighted sums of the yaw-rate innovations (rad/s), of their variances without
# the stamp's share ((rad/s)^2, weights squared) and of that share's standard deviation
# (rad/s, signed: one stamp error for all), and when the current disagreement began (NaN: none)
A_WIN_T = 47
A_WIN_Y = 48
A_WIN_VAR = 49
A_WIN_STAMP = 50
A_WIN_SINCE = 51
# the same sums (same order: _fit_add) plus y^2 over every moving frame (_rates_linear): the
# zero of a straight drive counts too, so that one turn's rate beside it shows whether the
# source's rate is linear
A_LIN_N = 52
A_LIN_SX = 53
A_LIN_SY = 54
A_LIN_SXX = 55
A_LIN_SXY = 56
A_LIN_SYY = 57
A_STRAIGHTS = 58  # straight-driving updates from untrusted yaw rates (_straight_update)
A_REFITS = 59  # times k was set from the wheels' fitted yaw-rate slope (_refit_wheel_scale)
# the same sums over the moving wheel-tick frames alone (no twist, none the accelerometer
# flagged), since the last restart of k, and the s of turning among them (_refit_wheel_scale)
A_TICK_N = 60
A_TICK_SYY = 65
A_TICK_TURNING = 66
# a stop whose ZUPTs keep finding the gyro offset by the same rate the bias does not explain
# (_relearn_bias_at_stop): w at the first of them and its filter time (NaN: none), and the
# times the bias's variance was opened for it
A_STEADY_W = 67
A_STEADY_T = 68
A_BIAS_RELEARNT = 69
A_GYRO_T = 70  # filter time of the last gyro sample fused (NaN: none yet)
A_SPIKE_RUN = 71  # gyro samples rejected as spikes since the last one fused
A_GYRO_SPIKES = 72  # gyro samples rejected as spikes in all
A_FAULT_TURN = 73  # rad: the rate state integrated over the odometry's encoder-fault intervals
# for _spinning: the effective time of the last wheel frame with ticks, or twist above zero
# (s; NaN: none yet), and the wheels' recent yaw rate (rad/s; NaN: none yet), averaged over
# SPIN_TAU s of the frames not taken for encoder faults
A_MOVED_T = 74
A_MOVED_W = 75
A_FAULT_RUN = 76  # encoder-fault frames since the last frame that was not one
A_CATCH_UPS = 77  # frames taken as catching up the counts of the encoder faults before them
AUX_SIZE = 78
#: rad/s^2: no ground robot's yaw rate changes faster (a differential drive's wheels at 5
#: m/s^2 on a 0.3 m track: 33 rad/s^2); a gyro reading further from the predicted rate
#: than this times the time since the last fused sample, plus SPIKE_SIGMAS standard
#: deviations of the innovation, is a spike (a glitch on the bus), not the robot.
MAX_ANGULAR_ACCEL = 200.0
SPIKE_SIGMAS = 6.0
#: A reading off by that much this many times in a row is the rate, not a spike: it is
#: fused with w forgotten (an impact, a gyro that restarted with another offset).
SPIKE_RUN = 3
#: s: with no gyro sample fused for longer than this (none in the log, a gap in the IMU's
#: feed), the wheels' yaw rate is all there is: fused without the slip gate, since the rate
#: state it would be tested against is set by nothing but the wheels' own past. Twice the
#: interval of the slowest IMU the pipeline takes (4 Hz). A wheels-only replay had flagged
#: 993 of 11999 frames as slips (every turn's onset) and ended 44.7 % of its distance off
#: with the yaw 97 deg off (RMS), where the same ticks dead-reckoned give 0.19 % and 0.35 deg.
GYRO_SILENT = 0.5
#: s: a forward specific force older than this drives v no more (the IMU feed stopped)
ACCEL_HOLD = 0.1
#: (rad/s)^2 added to w's variance before the first gyro sample (A_FIRST_GYRO): w is then
#: unknown (100 rad/s, above every MEMS gyro's full scale), so that sample sets w, not the bias
UNKNOWN_RATE_VAR = 1e4
#: (m/s)^2 added to v's variance before the first wheel frame or twist that is fused
#: (A_FIRST_SPEED): v is then unknown (100 m/s, above every robot's speed), so that frame sets
#: v, whatever the slip gate says of its yaw rate
UNKNOWN_SPEED_VAR = 1e4
# per-frame flags
FLAG_ZUPT = 1
FLAG_SLIP = 2
FLAG_FAULT = 4
# IMU motion codes (fusion.planar.imu_motion)
MOTION_UNKNOWN = 0
MOTION_STILL = 1
MOTION_UNSURE = 2
MOTION_MOVING = 3
# rate measurements correct the states from here on: never x, y (only through the motion
# model); yaw at a bounded rate (see update_core)
FIRST_RATE_STATE = 2
# event kinds
EV_GYRO = 0
EV_WHEELS = 1
EV_YAW = 2
EV_TWIST = 3
# a wheel frame that the accelerometer says slips (fusion.planar.accel_slip): fused as a
# slipping frame whatever the gyro gate says
EV_WHEELS_SLIP = 4
# the forward specific force of an IMU sample (base frame x, m/s^2), at the IMU stamp
EV_ACCEL = 5
# a state row (batch output, pipeline trace): x (NX), diag(P) (NX), P[x,y], P[x,yaw], P[y,yaw];
# the pose entries are reported_pose_covariance's (the held pose's)
ROW_WIDTH = 2 * NX + 3


@njit
def predict_core(x, P, dt, q_v, q_w, q_b, q_k, q_c, q_g, q_s):
    """Propagate ``x`` and ``P`` (in place) by ``dt`` s: ``x = f(x, dt)``,
    ``P <- F P F^T + Q`` with ``F`` the Jacobian at the prior state
    (:func:`fusion.planar.model.motion_terms`) and ``Q`` the random walks of v, w, b, k, c, g,
    s with intensities ``q_v`` ((m/s)^2/s), ``q_w``, ``q_b`` ((rad/s)^2/s), ``q_k`` (1/s),
    ``q_c`` ((rad/m)^2/s), ``q_g``, ``q_s`` (1/s)
    (:func:`fusion.planar.model.process_noise_diagonal`).
    """
    (dx, dy, dyaw, f02, f03, f04, f08, f09, f12, f13, f14, f18, f19, f24,
     f28) = motion_terms(x, dt)
    x[0] += dx
    x[1] += dy
    x[2] += dyaw
    # F = I + the off-diagonal terms f_ij (rows 0, 1, 2)
    # A = F P (only rows 0, 1, 2 differ from P)
    A = P.copy()
    for j in range(NX):
        A[0, j] = (P[0, j] + f02 * P[2, j] + f03 * P[3, j] + f04 * P[4, j] + f08 * P[8, j]
                   + f09 * P[9, j])
        A[1, j] = (P[1, j] + f12 * P[2, j] + f13 * P[3, j] + f14 * P[4, j] + f18 * P[8, j]
                   + f19 * P[9, j])
        A[2, j] = P[2, j] + f24 * P[4, j] + f28 * P[8, j]
    # P = A F^T (only columns 0, 1, 2 differ from A)
    for i in range(NX):
        P[i, 0] = (A[i, 0] + f02 * A[i, 2] + f03 * A[i, 3] + f04 * A[i, 4] + f08 * A[i, 8]
                   + f09 * A[i, 9])
        P[i, 1] = (A[i, 1] + f12 * A[i, 2] + f13 * A[i, 3] + f14 * A[i, 4] + f18 * A[i, 8]
                   + f19 * A[i, 9])
        P[i, 2] = A[i, 2] + f24 * A[i, 4] + f28 * A[i, 8]
        for j in range(3, NX):
            P[i, j] = A[i, j]
    q = process_noise_diagonal(dt, q_v, q_w, q_b, q_k, q_c, q_g, q_s)
    for i in range(NX):
        P[i, i] += q[i]


@njit
def innovation_variance(P, H, R, i):
    """Variance (``S[i, i]``, ``S = H P H^T + R``) of component ``i`` of the innovation
    ``z - h(x)`` of a measurement with Jacobian ``H`` (m, NX) and noise ``R`` (m, m)."""
    acc = R[i, i]
    for k in range(NX):
        if H[i, k] != 0.0:
            row = 0.0
            for j in range(NX):
                row += P[k, j] * H[i, j]
            acc += H[i, k] * row
    return acc


@njit
def _cholesky_solve_rows(S, B, m, out):
    """Solve ``S X = B`` for X (m x n) with S symmetric positive definite (m x m).

    Returns False when S is not positive definite.
    """
    L = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                L[i, i] = math.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    n = B.shape[1]
    for col in range(n):
        # forward: L y = b
        for i in range(m):
            acc = B[i, col]
            for k in range(i):
                acc -= L[i, k] * out[k, col]
            out[i, col] = acc / L[i, i]
        # backward: L^T x = y
        for i in range(m - 1, -1, -1):
            acc = out[i, col]
            for k in range(i + 1, m):
                acc -= L[k, i] * out[k, col]
            out[i, col] = acc / L[i, i]
    return True


@njit
def update_core(x, P, y, H, R, gate_index, gate, inflation, first):
    """Kalman update (in place) with innovation ``y`` (m,), Jacobian ``H`` (m, NX), noise ``R``.

    Joseph form ``P = (I-KH) P (I-KH)^T + K R K^T``, gain by a Cholesky solve of ``S``.
    Only the states ``first..NX-1`` are corrected: the gain rows of the states before ``first``
    are zero (a Schmidt "consider" update; the Joseph form keeps ``P`` the covariance of the
    estimate for that gain). Rate measurements pass ``first = FIRST_RATE_STATE`` so that
    they never move the position (x, y) except through the motion model (the heading's pace
    is :func:`_rate_update`'s). Gating: the squared Mahalanobis distance of component
    ``gate_index`` of the innovation (``-1``: of the whole vector) is compared with
    ``gate``; above it, ``R`` is multiplied by ``inflation`` before the update
    (``inflation <= 0``: the update is skipped).

    Returns ``(d2, status)`` with status 0 = applied, 1 = applied down-weighted,
    2 = skipped by the gate, 3 = skipped because S was not positive definite.
    """
    m = y.shape[0]
    PHt = np.zeros((NX, m))
    for i in range(NX):
        for j in range(m):
            acc = 0.0
            for k in range(NX):
                acc += P[i, k] * H[j, k]
            PHt[i, j] = acc
    S = np.zeros((m, m))
    for i in range(m):
        for j in range(m):
            acc = R[i, j]
            for k in range(NX):
                acc += H[i, k] * PHt[k, j]
            S[i, j] = acc
    # Mahalanobis distance for the gate
    if gate_index >= 0:
        d2 = y[gate_index] * y[gate_index] / S[gate_index, gate_index]
    else:
        yy = np.zeros((m, 1))
        for i in range(m):
            yy[i, 0] = y[i]
        sol = np.zeros((m, 1))
        if not _cholesky_solve_rows(S, yy, m, sol):
            return math.inf, 3
        d2 = 0.0
        for i in range(m):
            d2 += y[i] * sol[i, 0]
    status = 0
    Reff = R.copy()
    if d2 > gate:
        if inflation <= 0.0:
            return d2, 2
        status = 1
        for i in range(m):
            for j in range(m):
                Reff[i, j] = R[i, j] * inflation
                S[i, j] += R[i, j] * (inflation - 1.0)
    # K^T = S^-1 (P H^T)^T
    Bt = np.zeros((m, NX))
    for i in range(m):
        for j in range(NX):
            Bt[i, j] = PHt[j, i]
    Kt = np.zeros((m, NX))
    if not _cholesky_solve_rows(S, Bt, m, Kt):
        return d2, 3
    for j in range(m):
        for i in range(first):
            Kt[j, i] = 0.0
    for i in range(NX):
        acc = 0.0
        for j in range(m):
            acc += Kt[j, i] * y[j]
        x[i] += acc
    # Joseph form
    IKH = np.zeros((NX, NX))
    for i in range(NX):
        for j in range(NX):
            acc = 1.0 if i == j else 0.0
            for k in range(m):
                acc -= Kt[k, i] * H[k, j]
            IKH[i, j] = acc
    A = np.zeros((NX, NX))
    for i in range(NX):
        for j in range(NX):
            acc = 0.0
            for k in range(NX):
                acc += IKH[i, k] * P[k, j]
            A[i, j] = acc
    KR = np.zeros((NX, m))
    for i in range(NX):
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += Kt[k, i] * Reff[k, j]
            KR[i, j] = acc
    for i in range(NX):
        for j in range(i, NX):
            acc = 0.0
            for k in range(NX):
                acc += A[i, k] * IKH[j, k]
            for k in range(m):
                acc += KR[i, k] * Kt[k, j]
            P[i, j] = acc
    for i in range(NX):
        for j in range(i):
            P[i, j] = P[j, i]
    return d2, status


@njit
def _forget_speed(x, P, aux, i, t, var0):
    """Speed state ``i`` (3 = v, 4 = w) becomes unknown at filter time ``t``: mean 0, variance
    its second moment ``x_i^2 + P_ii`` (at least the prior ``var0``), uncorrelated with the
    rest (and kept so while forgotten, see :func:`_predict_step`)."""
    var = x[i] * x[i] + P[i, i]
    if not var >= var0:
        var = var0
    for j in range(NX):
        P[i, j] = 0.0
        P[j, i] = 0.0
    P[i, i] = var
    x[i] = 0.0
    aux[A_V_T + i - 3] = math.nan
    aux[A_V_FORGOT + i - 3] = t
    aux[A_V_RMS2 + i - 3] = var
    aux[A_ZERO_COUNT] = 0.0  # standing still is no longer known either
    aux[A_SPEED_RESETS] += 1.0


@njit
def _accel_input(aux, par, t):
    """The forward acceleration (m/s^2) that drives v in a prediction step starting at
    filter time ``t``: the last forward specific force minus the learnt offset; NaN when the
    accelerometer does not drive v (switched off, no sample within :data:`ACCEL_HOLD` s, no
    offset learnt yet, standing still, or v forgotten)."""
    if not (par[P_ACCEL_Q_V] > 0.0) or math.isnan(aux[A_V_T]):
        return math.nan
    if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES] or not t - aux[A_FX_T] <= ACCEL_HOLD:
        return math.nan
    return aux[A_FX] - aux[A_FX_OFFSET]


@njit
def _predict_step(x, P, aux, par, t, h, q_v, q_w, q_v_accel):
    """One prediction over ``h`` s from filter time ``t``.

    When the accelerometer drives v (:func:`_accel_input` not NaN), ``v += a * h`` after
    the constant-twist motion and v's process noise is ``q_v_accel`` instead of ``q_v``.

    A forgotten speed (mean 0, uncorrelated) takes no part in the motion's covariance
    propagation; instead the pose gets the envelope of an unknown motion at that speed's
    second moment ``r``: ``r * s^2`` on the variance of x and y (v) or of yaw (w), ``s`` the
    time since it was forgotten (added as ``r * ((s + h)^2 - s^2)``, so any split of an
    interval into steps gives the same covariance). Nothing correlates the pose with it, so
    a speed measured after a gap does not move the pose by the distance of the gap.
    """
    v_lost = math.isnan(aux[A_V_T])
    w_lost = math.isnan(aux[A_W_T])
    p_vv = P[3, 3]
    p_ww = P[4, 4]
    if v_lost:
        P[3, 3] = 0.0
    if w_lost:
        P[4, 4] = 0.0
    accel = _accel_input(aux, par, t)
    driven = not math.isnan(accel)
    if driven:
        q_v = q_v_accel
    q_xx, q_xy, q_yy = _predict_held(x, P, aux, par, h, q_v, q_w)
    if driven:
        x[3] += accel * h
    P[0, 0] += q_xx
    P[0, 1] += q_xy
    P[1, 0] += q_xy
    P[1, 1] += q_yy
    aux[A_PREDICTIONS] += 1.0
    if v_lost:
        P[3, 3] += p_vv
        s = t - aux[A_V_FORGOT]
        grow = aux[A_V_RMS2] * (h * (2.0 * s + h))
        P[0, 0] += grow
        P[1, 1] += grow
    if w_lost:
        P[4, 4] += p_ww
        s = t - aux[A_W_FORGOT]
        P[2, 2] += aux[A_W_RMS2] * (h * (2.0 * s + h))


@njit
def _advance(x, P, aux, par, t):
    """Bring the filter to time ``t``; returns False when the input is too late to use.

    Gap policy (cost bounded for any interval): v and w are extrapolated at most
    ``par[P_HORIZON]`` s past their last measurement (in steps of at most ``max_dt``); then
    each is forgotten (:func:`_forget_speed`) until it is measured again: the pose stops
    moving with it and its covariance grows by the envelope of :func:`_predict_step`.
    While both are forgotten nothing moves and the covariance growth is in closed form, so
    the rest of the interval is one step.
    """
    t_now = aux[A_T]
    if math.isnan(t_now):
        aux[A_T] = t
        aux[A_V_T] = t  # x0's speeds count as known at the first input
        aux[A_W_T] = t
        return True
    dt = t - t_now
    if dt > 0.0:
        aux[A_YAW_BUDGET] = min(aux[A_YAW_BUDGET] + par[P_YAW_FIX_RATE] * dt,
                                par[P_YAW_FIX_BURST])
        _release_pending_yaw(x, aux)
    if dt < 0.0:
        if -dt <= par[P_LATE_TOLERANCE]:
            aux[A_LATE_APPLIED] += 1.0
            return True
        aux[A_LATE_DROPPED] += 1.0
        return False
    max_dt = par[P_MAX_DT]
    horizon = par[P_HORIZON]
    while dt > 0.0:
        q_v = par[P_Q_V]
        q_w = par[P_Q_W]
        if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES]:
            # standing still: v and w stay (almost) where the ZUPT put them
            q_v *= par[P_STILL_SCALE]
            q_w *= par[P_STILL_SCALE]
        else:
            # a speed ramp goes on: the speed may keep changing as fast as it last did
            # (speed_ramp_time), which the constant-speed model does not predict
            q_v = max(q_v, aux[A_SPEED_RATE] * aux[A_SPEED_RATE] * par[P_SPEED_RAMP_TIME])
        q_v_accel = par[P_ACCEL_Q_V]
        if aux[A_FLAGS] == FLAG_SLIP:
            # after a slipping frame (its speed down-weighted) the speed changes as the robot
            # drives, with no frame to hold it until the next one
            q_v = max(q_v, par[P_SLIP_Q_V])
            q_v_accel = max(q_v_accel, par[P_SLIP_Q_V])
        # up to the next moment a speed state is forgotten, if one falls in this interval
        span = dt
        to_v = aux[A_V_T] + horizon - t_now  # NaN once forgotten: never smaller
        to_w = aux[A_W_T] + horizon - t_now
        if to_v < span:
            span = to_v if to_v > 0.0 else 0.0
        if to_w < span:
            span = to_w if to_w > 0.0 else 0.0
        forget_v = to_v <= span
        forget_w = to_w <= span
        if math.isnan(aux[A_V_T]) and math.isnan(aux[A_W_T]):
            if span > 0.0:  # nothing moves the mean any more: one step
                _predict_step(x, P, aux, par, t_now, span, q_v, q_w, q_v_accel)
        else:
            left = span
            t_step = t_now
            while left > 0.0:
                h = left if left <= max_dt else max_dt
                _predict_step(x, P, aux, par, t_step, h, q_v, q_w, q_v_accel)
                left -= h
                t_step += h
        dt -= span
        t_now += span
        if forget_v:
            _forget_speed(x, P, aux, 3, t_now, par[P_SPEED_VAR0])
        if forget_w:
            _forget_speed(x, P, aux, 4, t_now, par[P_SPEED_VAR0])
    aux[A_T] = t
    return True


@njit
def _rate_update(x, P, aux, y, H, R):
    """:func:`update_core` for a rate measurement (gyro, wheels, twist, ZUPT): the position
    is not corrected, the heading by at most the yaw budget, which the update spends.

    The budget refills at ``yaw_fix_rate`` rad/s up to ``yaw_fix_burst`` rad
    (:func:`_advance`): over any interval of ``T`` s, rate measurements change the heading by
    at most ``yaw_fix_burst + yaw_fix_rate*T``. What the update would move the heading beyond
    the budget is owed, not dropped (``A_YAW_PENDING``): ``P`` is that of the full update,
    and :func:`_release_pending_yaw` pays the rest as the budget refills. (Scaling the gain
    instead would throw away what the measurement taught: a bias learnt at the first stop
    after a moving start could no longer correct the heading drifted before it.) Returns
    ``(d2, status)``.
    """
    yaw = x[2]
    d2, status = update_core(x, P, y, H, R, -1, math.inf, 0.0, FIRST_RATE_STATE)
    dyaw = x[2] - yaw
    budget = aux[A_YAW_BUDGET]
    if abs(dyaw) > budget:
        applied = math.copysign(budget, dyaw)
        aux[A_YAW_PENDING] += dyaw - applied
        x[2] = yaw + applied
    aux[A_YAW_BUDGET] = max(budget - abs(x[2] - yaw), 0.0)
    return d2, status


@njit
def _release_pending_yaw(x, aux):
    """Pay the heading correction owed (``A_YAW_PENDING``, rad) from the yaw budget."""
    owed = aux[A_YAW_PENDING]
    if owed == 0.0:
        return
    pay = min(abs(owed), aux[A_YAW_BUDGET])
    x[2] += math.copysign(pay, owed)
    aux[A_YAW_PENDING] = owed - math.copysign(pay, owed)
    aux[A_YAW_BUDGET] -= pay


#: A frame whose measured or expected yaw rate exceeds this (rad/s, 6 deg/s) is a turn: only
#: turns test whether the wheels' yaw rate can be trusted (standing or driving straight,
#: any wheels agree with the gyro).
TURN_RATE = 0.1
#: Turning twists prove their source only while the slope of their yaw rate against the
#: gyro's, fitted over all turning frames so far, is within this share of 1: a two-wheel base's
#: twist is off by its wheel distance's error (a few %), a skid-steer base's by 30-100 %. The
#: slip gate alone passes a skid-steer's gentle turns while the bias and the wheel calibration
#: are still uncertain: yaw rates 1.6 times the gyro's, starting to drive at once, proved
#: themselves after 14 s of arcs, were fused and pulled the bias by 3 deg/s (yaw RMSE 105 deg
#: over 3 minutes without a stop). A slope, unlike a per-frame ratio, does not see the bias (it
#: goes into the intercept): comparing each frame with the bias-corrected rate kept a correct
#: two-wheel twist from being proven on gentle arcs with 2 deg/s of bias not yet learnt.
PROOF_TOLERANCE = 0.1
#: rad/s: the standard deviation the fitted gyro rates must spread over before the slope
#: counts: turns of one rate and direction alone cannot tell a scale error from the bias, so
#: on gentle arcs one way a correct twist source waits for a turn the other way (36 s on
#: tests/test_ekf.py's gentle drive; 0.03-0.1 rad/s gave the same)
PROOF_SPREAD = 0.05
#: s: the longest run of wheel frames or twists that a persistent disagreement alone keeps
#: from teaching the yaw-rate states. A slip lasts a second or two (a wheel on a wet patch, a
#: skid in a turn); a disagreement that goes on is the wheel model's (a radius mismatch beyond
#: c's prior), which the frames must be allowed to teach, or the wheels would never be heard
#: again. Slips longer than this that the per-frame gate misses leak a few frames every
#: 3 s. Set by hand from that reasoning, not tuned.
PERSISTENT_SLIP_MAX = 3.0


@njit
def _fit_add(aux, first, gyro_rate, wheel_rate):
    """Add one pair of rates (rad/s) to the least-squares sums ``aux[first:first + 5]``:
    count, sum of x, of y, of x^2 and of x*y (x the gyro's rate, y the wheels')."""
    aux[first] += 1.0
    aux[first + 1] += gyro_rate
    aux[first + 2] += wheel_rate
    aux[first + 3] += gyro_rate * gyro_rate
    aux[first + 4] += gyro_rate * wheel_rate


@njit
def _fit_moments(aux, first):
    """``(n, mean_y, var_x, cov_xy)`` of the sums at ``aux[first:first + 5]`` (see
    :func:`_fit_add`); the moments are NaN below two pairs."""
    n = aux[first]
    if n < 2.0:
        return n, math.nan, math.nan, math.nan
    mean_x = aux[first + 1] / n
    mean_y = aux[first + 2] / n
    return (n, mean_y, aux[first + 3] / n - mean_x * mean_x,
            aux[first + 4] / n - mean_x * mean_y)


@njit
def _rate_scale_agrees(aux, gyro_rate, wheel_rate, turning):
    """Add a turning frame (the gyro-scale rate with its bias, ``gyro_rate``, and the wheels'
    ``wheel_rate``, rad/s) to the least-squares fit of the one against the other; True once
    the fitted rates spread by :data:`PROOF_SPREAD` and the slope is within
    :data:`PROOF_TOLERANCE` of 1."""
    if turning:
        _fit_add(aux, A_FIT_N, gyro_rate, wheel_rate)
    n, _, var_x, cov = _fit_moments(aux, A_FIT_N)
    if n < 2.0 or var_x < PROOF_SPREAD * PROOF_SPREAD:
        return False
    return abs(cov / var_x - 1.0) <= PROOF_TOLERANCE


@njit
def _wheel_rate_trust(aux, par, interval, slip, turning, proven, close):
    """Account one wheel frame or twist (``slip``: above the gate; ``turning``; ``interval``
    s after the previous one; ``close``: the wheels' yaw-rate scale fitted so far agrees
    with the gyro's, :func:`_rate_scale_agrees`) and return ``(fuse_rate, disproven)``:
    whether its yaw rate may be fused, and whether the wheels' yaw rate has shown it does not
    measure the rotation.

    Only turns test the wheels (standing or driving straight, any wheels agree with the
    gyro). Proven: the source is this library's two-wheel differential chassis (``proven``:
    wheel ticks), or the wheels have agreed with the gyro (below the gate, and ``close``) over
    ``wheel_rate_proof_time`` s of turning; before that an external odometry's yaw rates are
    not fused (it may come from a skid-steer base, whose yaw rate is no measurement of the
    rotation even driving straight, and while the bias is still uncertain the gate passes its
    first turns), nor is a twist above the gate a slip (:func:`_wheel_update`). Disproven:
    the share of turning frames above the gate, an exponentially weighted mean with time
    constant ``wheel_rate_trust_time``, exceeds ``max_slip_share`` (a skid-steer base's
    odometry, a wrong wheel distance, a floor that slips everywhere); then a disagreement is
    no sign of slip, only the speed is fused, and trust returns below half that share.
    """
    share = aux[A_SLIP_SHARE]
    if turning:
        alpha = min(1.0, interval / par[P_TRUST_TIME])
        share += alpha * ((1.0 if slip else 0.0) - share)
        aux[A_SLIP_SHARE] = share
        if not slip and close:
            aux[A_AGREED] += interval
    if share > par[P_MAX_SLIP_SHARE]:
        aux[A_DISTRUST] = 1.0
    elif share < 0.5 * par[P_MAX_SLIP_SHARE]:
        aux[A_DISTRUST] = 0.0
    disproven = aux[A_DISTRUST] == 1.0
    return (not disproven) and (proven or aux[A_AGREED] >= par[P_PROOF_TIME]), disproven


@njit
def _persistent_disagreement(aux, par, y_w, s_w, stamp_w):
    """Add one wheel frame's or twist's yaw-rate innovation ``y_w`` (rad/s, variance ``s_w``,
    of which ``stamp_w^2`` is its stamp's share, ``stamp_w`` signed) to an exponentially
    weighted sum with time constant ``slip_window`` and return True when that sum is
    significant: its square above ``slip_gate`` times its variance (chi-square, 1 dof).

    Why: the per-frame gate weighs one frame against one frame's noise, which on a coarse
    encoder is large (a tick is 0.06 rad/s of yaw rate at 50 Hz on a 780-tick, 3.4 cm wheel).
    A wheel spinning 5 % faster than the floor at 0.45 m/s reads 0.1 rad/s of yaw rate while
    the body drives straight: 2.3 standard deviations per frame, passed by the gate, and 75
    such frames in 1.5 s pulled the bias by 3 deg/s before the first stop
    (tests/test_ekf_slip.py). Summed over frames the slip is plain: innovations of a consistent
    filter are white, so the sum's variance is the sum of theirs (a tick's quantisation
    telescopes, so this over-counts it: the test errs toward silence), except the stamp's
    share, one latency for all frames, whose standard deviations add up instead. A frame above
    the per-frame gate counts as one standard deviation its way. 0: off. A disagreement that
    lasts longer than :data:`PERSISTENT_SLIP_MAX` starts the sum afresh and is not reported
    (see there)."""
    tau = par[P_SLIP_WINDOW]
    if tau <= 0.0:
        return False
    t = aux[A_T]
    last = aux[A_WIN_T]  # NaN before the first frame
    decay = 1.0
    if math.isnan(last) or t > last:
        if t > last:
            decay = math.exp(-(t - last) / tau)
        aux[A_WIN_T] = t
    # a frame the per-frame gate caught (a slip already) counts as one standard deviation of
    # disagreement its way: enough to keep the sum pointing the slip's way, too little to keep
    # it significant long after a big slip ends
    if y_w * y_w > par[P_GATE] * s_w:
        y_w = math.copysign(math.sqrt(s_w), y_w)
    aux[A_WIN_Y] = decay * aux[A_WIN_Y] + y_w
    aux[A_WIN_VAR] = decay * decay * aux[A_WIN_VAR] + max(s_w - stamp_w * stamp_w, 0.0)
    aux[A_WIN_STAMP] = decay * aux[A_WIN_STAMP] + stamp_w
    var = aux[A_WIN_VAR] + aux[A_WIN_STAMP] * aux[A_WIN_STAMP]
    if not aux[A_WIN_Y] * aux[A_WIN_Y] > par[P_GATE] * var:
        aux[A_WIN_SINCE] = math.nan
        return False
    if math.isnan(aux[A_WIN_SINCE]):
        aux[A_WIN_SINCE] = t
    elif t - aux[A_WIN_SINCE] > PERSISTENT_SLIP_MAX:
        aux[A_WIN_Y] = 0.0
        aux[A_WIN_VAR] = 0.0
        aux[A_WIN_STAMP] = 0.0
        aux[A_WIN_SINCE] = math.nan
        return False
    return True


@njit
def _silent_rate_scale(aux, par, kind):
    """The factor by which a wheel frame's or twist's yaw rate is divided to be fused while the
    gyro is silent (:data:`GYRO_SILENT`), or 0 to fuse only its speed (the yaw rate then held
    by the motion model, its variance growing).

    1 where the gyro never spoke (a wheels-only log: the wheels are all there is) or where the
    source had earned the gyro's trust (:func:`_wheel_rate_trust`). Otherwise, a source the
    gyro had not proven or had disproven, its rate is fused in the gyro's scale: divided by
    the slope of its rate against the gyro's over the moving frames so far, where the two
    correlate (:func:`_rates_linear`), else not at all. A skid-steer base's twists turn 1.5
    times as fast as the robot: fused as they were over an independent probe's twenty IMU
    gaps of 0.5-2 s, they made its outdoor bag's GPS RMSE 3.96 m instead of 1.55."""
    if math.isnan(aux[A_GYRO_T]):
        return 1.0
    if aux[A_DISTRUST] != 1.0 and (kind == EV_WHEELS or aux[A_AGREED] >= par[P_PROOF_TIME]):
        return 1.0
    _, slope, corr = _linear_fit(aux, A_LIN_N)
    return slope if corr >= LINEAR_SOURCE_CORRELATION else 0.0


@njit
def _wheel_update(x, P, aux, par, z, R, interval, kind, accel_slip, stamp_w):
    """Fuse a wheel twist ``z = [v_m, w_m]`` (a wheel frame, ``kind`` 1, or an external
    twist, 3) with noise ``R``, ``interval`` s after the previous frame; returns
    ``(d2, status)``.

    The yaw-rate component is gated (chi-square, 1 dof, against the gyro-corrected rate
    state): a frame above the gate is a slip, and only its speed is fused, with its noise
    multiplied by ``slip_inflation`` (0: nothing is fused). So is one that the persistent
    test (:func:`_persistent_disagreement`, only for yaw rates that would be fused) finds
    within a significant run of disagreement, its speed with its own noise. A slipping
    frame's yaw rate is never fused, so it cannot bend the heading. Nor is any twist's
    before the external odometry has proven itself in turns, or any frame's once most turns
    disagree (:func:`_wheel_rate_trust`):
    then only the speed is fused, with its own noise (and, once disproven, no slip flag: the
    yaw rates' disagreement says nothing about slipping), unless the gyro was
    saturated within ``wheel_rate_proof_time`` (the wheels are then the only yaw rate; their
    slip share is left as it is). A frame the accelerometer flagged (``accel_slip``: its
    speed change or v*w contradicted, :mod:`fusion.planar.accel_slip`) is a slip whatever
    the gyro gate and the wheels' trust say; it does not count in the wheels' slip share,
    which is about their yaw rate.
    """
    moving = abs(z[0]) > par[P_TWIST_ZERO_V]
    turning = abs(z[1]) > TURN_RATE or abs(x[4]) > TURN_RATE
    silent = not aux[A_T] - aux[A_GYRO_T] <= GYRO_SILENT  # NaN: no gyro sample yet
    # without a gyro the rate state is the wheels' own: no pair for the fit
    linear = _rates_linear(aux, x[4] + x[5], z[1], moving and not silent)
    if kind == EV_WHEELS and moving and not accel_slip and not silent:
        _refit_wheel_scale(x, P, aux, par, z[1], interval if turning else 0.0)
    L = par[P_WHEEL_DISTANCE]
    H = wheel_jacobian(x, L, z[0])
    rate_scale = _silent_rate_scale(aux, par, kind) if silent else 1.0
    if silent:
        # without a gyro the wheels' yaw-rate scale k and radius mismatch c are unobservable:
        # they are not measured, and keep what a gyro taught them (a wheels-only replay had
        # walked k to -0.45 and c to -0.15 rad/m, the heading 89 deg off in RMS)
        H[0, 7] = 0.0
        H[1, 6] = 0.0
        H[1, 7] = 0.0
        if rate_scale > 0.0 and rate_scale != 1.0:
            R = R.copy()
            R[0, 1] /= rate_scale
            R[1, 0] /= rate_scale
            R[1, 1] /= rate_scale * rate_scale
    y = wheel_h(x, L, z[0])
    y[0] = z[0] - y[0]
    y[1] = (z[1] / rate_scale if rate_scale > 0.0 else z[1]) - y[1]
    s_w = innovation_variance(P, H, R, 1)
    d2 = y[1] * y[1] / s_w
    slip = d2 > par[P_GATE]
    gated = slip
    if silent:
        # no gyro (GYRO_SILENT): nothing to test the wheels against; a yaw rate the gyro had
        # not come to trust is fused in the gyro's scale, or not at all (rate_scale 0)
        fuse_rate, disproven = rate_scale > 0.0, aux[A_DISTRUST] == 1.0
        slip = gated = False
    elif aux[A_T] - aux[A_CLIPPED] < par[P_PROOF_TIME]:
        # the gyro is (or was just) saturated: the wheels are all there is, and the gyro's
        # rate state around the saturation is no test of them
        fuse_rate, disproven = True, False
    else:
        close = _rate_scale_agrees(aux, x[4] + x[5], z[1], turning)
        fuse_rate, disproven = _wheel_rate_trust(aux, par, interval, slip, turning,
                                                 kind == EV_WHEELS, close)
        if fuse_rate:
            # only yaw rates that would be fused: a disagreement nothing absorbs (an
            # unproven or disproven odometry) would keep the sum significant forever
            slip = _persistent_disagreement(aux, par, y[1], s_w, stamp_w) or gated
    if not slip and fuse_rate and not accel_slip:
        _, status = _rate_update(x, P, aux, y, H, R)
        return d2, status
    if disproven:
        # wheels whose yaw rate does not measure the rotation: a disagreement with the gyro
        # says nothing about slipping, and the speed is as good as ever
        if turning:
            aux[A_DISTRUSTED] += 1.0
        slip = False
    elif kind == EV_TWIST and aux[A_AGREED] < par[P_PROOF_TIME]:
        # an external odometry not yet proven in turns: its disagreement is no sign of slip
        # either (a skid-steer base's twists disagree from the first turn, and the Jackal
        # bag's even driving straight), and its speed is as good as ever; down-weighted as a
        # slip's, the speed of a robot speeding up from 1 to 2 m/s lagged by up to 2 m/s, and
        # by more than 0.1 m/s for 3.3 s, until most turns had disagreed. It still counts in
        # the slip share that disproves it.
        if turning and slip:
            aux[A_DISTRUSTED] += 1.0
        slip = False
    if accel_slip:
        aux[A_ACCEL_SLIPS] += 1.0
        slip = True
    if slip:
        aux[A_SLIPS] += 1.0
        aux[A_FLAGS] = FLAG_SLIP
    if slip and (gated or accel_slip):
        inflation = par[P_SLIP_INFLATION]
    else:
        # agreeing wheels not yet proven in turns, or disproven ones, or a frame only the
        # persistent test flags (its yaw rate off by a few per cent of the speed at most, its
        # speed by half that): their speed only, with its own noise
        inflation = 1.0
    if inflation <= 0.0:
        return d2, 2
    # the speed alone: the wheel yaw-rate model's small c*w term is left out of the
    # Jacobian, so that a frame whose rotation is not trusted teaches nothing about it
    # (through c and w it would reach the gyro bias)
    H1 = np.zeros((1, NX))
    H1[0, 3] = H[0, 3]
    _, status = _rate_update(x, P, aux, np.array([y[0]]), H1,
                             np.full((1, 1), R[0, 0] * inflation))
    if (status == 0 and not slip and not accel_slip and not fuse_rate
            and abs(z[1]) < par[P_STRAIGHT_RATE] and moving and linear):
        _straight_update(x, P, aux, par, z, R, interval)
    return d2, 1 if status == 0 and slip else status


#: The least correlation of a wheel source's yaw rate with the gyro's over its moving frames
#: so far (:func:`_rates_linear`) for its near-zero rates to count as driving straight
#: although the rates themselves are not trusted. A skid-steer base's twist is the rotation
#: times a factor (its effective track over the nominal one): over their turning frames the
#: terrain benchmark's bags correlate at 0.998-0.999 with a factor of 1.5. The bundled Jackal
#: bag's twists turn 1.4-4 times as fast as the gyro and read up to 0.05 rad/s driving
#: straight: 0.53-0.67, and straight driving taken from them pulled the bias by 1.6 deg/s
#: (the bag's own attitude says about 0). Set between the two, not tuned.
LINEAR_SOURCE_CORRELATION = 0.9
#: The relative standard deviation of an untrusted wheel yaw rate's scale in a straight-
#: driving update (:func:`_straight_update`): nothing is known of it beyond its sign, so a
#: rate may be wrong by its whole size (a skid-steer's factor 1.5 is off by a half).
STRAIGHT_SCALE_STD = 1.0
#: s: how long that scale error lasts. It is no white noise: through a gentle arc it is the
#: same in every frame (the first version, without this, pulled the bias by 0.8 deg/s on an
#: arc a skid-steer twist read at 1.75 times its rate), so a straight-driving frame counts
#: as one of a run this long (its noise times this over its interval). 0 and 2 s were tried
#: on the terrain benchmark's bags (seeds 1-6: 1.94 / 3.12 and 2.02 / 2.92 m mean / worst
#: against GPS); 2 s for the smaller worst case and the reason above.
STRAIGHT_CORR_TIME = 2.0


@njit
def _linear_fit(aux, first):
    """``(n, slope, correlation)`` of the wheels' yaw rate against the gyro's over the moving
    frames summed so far (:func:`_rates_linear`); slope and correlation are NaN until the
    gyro's rates spread by :data:`PROOF_SPREAD` (turns of one rate cannot tell a scale), the
    correlation also while the wheels' rate has not varied."""
    n, mean_y, var_x, cov = _fit_moments(aux, first)
    if not (n >= 2.0 and var_x >= PROOF_SPREAD * PROOF_SPREAD):
        return n, math.nan, math.nan
    var_y = aux[first + 5] / n - mean_y * mean_y
    corr = cov / math.sqrt(var_x * var_y) if var_y > 0.0 else math.nan
    return n, cov / var_x, corr


@njit
def _rates_linear(aux, gyro_rate, wheel_rate, moving):
    """Add a moving frame (the gyro-scale rate with its bias, ``gyro_rate``, and the wheels'
    ``wheel_rate``, rad/s) to the sums of every moving frame so far, and return True once
    the wheels' rate correlates with the gyro's by at least
    :data:`LINEAR_SOURCE_CORRELATION` (:func:`_linear_fit`): whatever its scale, the source's
    rate is then a rate of the robot's rotation, and near zero means not turning."""
    if moving:
        _fit_add(aux, A_LIN_N, gyro_rate, wheel_rate)
        aux[A_LIN_SYY] += wheel_rate * wheel_rate
    return _linear_fit(aux, A_LIN_N)[2] >= LINEAR_SOURCE_CORRELATION


@njit
def _refit_wheel_scale(x, P, aux, par, wheel_rate, turned):
    """Add a moving wheel-tick frame (its yaw rate ``wheel_rate``, rad/s; ``turned``, s: its
    interval if it turns, else 0) to the fit of the ticks' yaw rate against the gyro's
    (``A_TICK_*``: tick frames only, none the accelerometer flagged, since the last restart);
    then restart ``k`` at that fit's slope when the two correlate (by
    :data:`LINEAR_SOURCE_CORRELATION`), the fit holds ``wheel_rate_proof_time`` s of
    turning, and the slope is more than ``wheel_scale_refit`` prior standard deviations of
    ``k`` (``calib_k_std``) off ``1 + k``. The radius mismatch ``c`` restarts at its prior
    mean (``wheel_rate_per_speed``: 0, or a calibration's radius ratio). Both get
    their prior variances and lose their correlations with the other states; the bias keeps
    its own. The fit then starts afresh, so that one episode cannot ratchet ``k`` step by
    step. Off by default (``wheel_scale_refit`` 0): see there.

    The turning time: the first turn's onset alone misled a fit over all frames by up to
    24 % on 4 of the black-box simulator's 32 runs; twists of another source in the same fit
    turned a correct base's ``k`` to +0.25 (review). A slip of one wheel still misleads it: a
    correct base whose right wheel slips by 10 % (30 %) for 6 s at 10 s into the drive
    restarts once (twice, there and back): yaw RMSE 2.05 (2.51) deg against 1.23 without.

    Why: a skid-steer base counted as a two-wheel one (its geometric track as
    wheel_distance, its wheels turning 1.5 times as fast as it does) or a mistyped wheel
    distance is no calibration error of a few per cent that ``k`` follows from its prior.
    Until it had, the turns' disagreement went into the gyro bias and ``c``: driving from
    the first sample, the terrain benchmark's outdoor runs (such a base) had the bias at
    -1.5 deg/s after 10 s (truth +0.4) and a yaw RMSE of 17.8 deg (52.9 on the worst seed).
    ``c`` must restart too: with ``k`` alone restarted, the ``c*v`` it had taken (0.03-0.07
    rad/s) was balanced by a bias of 2-5 deg/s. A fitted slope sees the scale alone (the
    bias and ``c*v`` at a steady speed go into its intercept)."""
    if par[P_K_STD] <= 0.0 or par[P_REFIT] <= 0.0:
        return  # off, or k held at its prior value by choice
    gyro_rate = x[4] + x[5]
    _fit_add(aux, A_TICK_N, gyro_rate, wheel_rate)
    aux[A_TICK_SYY] += wheel_rate * wheel_rate
    aux[A_TICK_TURNING] += turned
    if aux[A_TICK_TURNING] < par[P_PROOF_TIME]:
        return  # as much turning as proves an external odometry (a turn's onset misleads)
    _, slope, corr = _linear_fit(aux, A_TICK_N)
    if not corr >= LINEAR_SOURCE_CORRELATION:
        return
    if abs(slope - 1.0 - x[6]) <= par[P_REFIT] * par[P_K_STD]:
        return
    x[6] = slope - 1.0
    x[7] = par[P_C_MEAN]
    for i in (6, 7):
        P[i, :] = 0.0
        P[:, i] = 0.0
    P[6, 6] = par[P_K_STD] ** 2
    P[7, 7] = par[P_C_STD] ** 2
    aux[A_REFITS] += 1.0
    for i in range(A_TICK_N, A_TICK_TURNING + 1):
        aux[i] = 0.0  # fresh evidence for any further restart


@njit
def _straight_update(x, P, aux, par, z, R, interval):
    """Fuse an untrusted wheel yaw rate ``z[1]`` near zero (below ``straight_rate``) as a
    measurement of driving straight: the wheel model's yaw-rate row (so the radius mismatch
    ``c`` takes its share: a straight drive reveals ``b + c*v``, which only speeds that vary
    or a stop separate), its noise widened by the rate's unknown scale,
    :data:`STRAIGHT_SCALE_STD` times the rate, times :data:`STRAIGHT_CORR_TIME` over the
    frame's ``interval`` (s), and gated like any frame (above the gate it is not fused).

    Why: a skid-steer base's twist, or any odometry not yet proven in turns, says nothing
    of how fast the robot turns, but its zero is the robot's: before the first stop that is
    the only measure of the gyro's bias (issue 11's outdoor bag never stands at the start;
    the terrain benchmark's bags drifted 35 deg in the first minute without it)."""
    L = par[P_WHEEL_DISTANCE]
    H = wheel_jacobian(x, L, z[0])
    H1 = np.zeros((1, NX))
    H1[0, :] = H[1, :]
    y = np.array([z[1] - wheel_h(x, L, z[0])[1]])
    R1 = np.full((1, 1), (R[1, 1] + (STRAIGHT_SCALE_STD * z[1]) ** 2)
                 * max(1.0, STRAIGHT_CORR_TIME / max(interval, par[P_PERIOD])))
    if y[0] * y[0] > par[P_GATE] * innovation_variance(P, H1, R1, 0):
        return
    aux[A_STRAIGHTS] += 1.0
    _rate_update(x, P, aux, y, H1, R1)


#: A zero frame is in a turn the wheels went dead in when the filter's yaw rate is within
#: this share of itself from the wheels' recent rate (wheel distance and scrub errors are a
#: few %; a skid-steer's twist turns up to 1.5 times the gyro).
SPIN_MATCH = 0.5
#: s: the time constant the wheels' recent yaw rate is averaged over, frame by frame (one
#: frame's rate is no measure at a turn's tail: a lone tick on a 0.3 m track at 20 ms is
#: 4.8 deg/s, which matched a 9.5 deg/s bias step in a review).
SPIN_TAU = 0.2


@njit
def _track_wheel_rate(aux, rate, interval):
    """Average the yaw rate ``rate`` (rad/s) a wheel frame or twist measured over
    ``interval`` s into ``A_MOVED_W`` (:data:`SPIN_TAU`), for :func:`_spinning`."""
    if math.isnan(aux[A_MOVED_W]):
        aux[A_MOVED_W] = rate
    else:
        aux[A_MOVED_W] += min(1.0, interval / SPIN_TAU) * (rate - aux[A_MOVED_W])


#: s: how long the ZUPTs of a stop must keep finding the same unexplained yaw rate before
#: the bias is relearnt (a twist would have to be this late to hide a turn's start)
STEADY_TIME = 0.5
#: "the same": within this many standard deviations of the difference of two gyro samples
STEADY_SIGMAS = 4.0


@njit
def _no_steady_offset(aux):
    """Forget the run of ZUPTs with an unexplained offset (the wheels moved, or a fault)."""
    aux[A_STEADY_W] = math.nan
    aux[A_STEADY_T] = math.nan


@njit
def _relearn_bias_at_stop(x, P, aux, par, imu_still):
    """Before a ZUPT: a bias that is off by more than its variance admits makes every gyro
    sample of the stop fail the still model's gate (read as motion onset), which frees ``w``
    to carry the offset, so the ZUPT pins ``w`` and hardly moves the bias: a bias that went
    wrong once (a late twist's zero rates over a turn's start: 1 deg/s) stayed wrong at every
    later stop. A turn starting grows ``w``; a wrong bias gives the same ``w`` at every ZUPT.
    So when the ZUPTs of :data:`STEADY_TIME` s, with the IMU still, all find ``w`` beyond
    the gate (against the bias's variance and one gyro sample's noise: the freed ``w``'s own
    variance admits anything) and within :data:`STEADY_SIGMAS` of the first of them, the
    bias's variance is opened by ``w^2``: the next gyro sample puts the offset into it."""
    w = x[4]
    if not imu_still or w * w <= par[P_GATE] * (P[5, 5] + par[P_GYRO_VAR]):
        _no_steady_offset(aux)
        return
    first = aux[A_STEADY_W]
    if math.isnan(first) or abs(w - first) > STEADY_SIGMAS * math.sqrt(2.0 * par[P_GYRO_VAR]):
        aux[A_STEADY_W] = w  # a new run starts here
        aux[A_STEADY_T] = aux[A_T]
    elif aux[A_T] - aux[A_STEADY_T] >= STEADY_TIME:
        P[5, 5] += w * w
        aux[A_BIAS_RELEARNT] += 1.0
        _no_steady_offset(aux)


@njit
def _spinning(x, P, aux, par, kind, t):
    """True at a zero wheel frame or twist (``kind``, effective time ``t`` s) in a turn the
    wheels were making when they last turned and the gyro says goes on, whatever the IMU's
    shaking says. All of:

    - the rate ``w`` less ``sqrt(gate)`` standard deviations of the bias and one gyro sample
      (what a wrong bias could explain; not w's own variance, which a motion onset widens
      for a moment) is above :data:`TURN_RATE`;
    - the wheels' recent yaw rate (:func:`_track_wheel_rate`, over the frames not taken for
      faults: a stop's zero frames bring it to 0) is within :data:`SPIN_MATCH` of ``w``
      (the wheels went dead in this turn);
    - at that rate the wheels would have turned by more than two ticks since they last read
      any (a twist: faster than twice its zero speed);
    - a gyro was heard within :data:`GYRO_SILENT` s (without one w is the wheels' own).

    Why: a steady turn does not shake an IMU on a smooth floor, so the window statistic
    calls it still (:mod:`fusion.planar.imu_motion`), and zero wheel speed in such a turn was
    taken as a stop: its ZUPTs pinned w, the bias was relearnt to the turn's rate and the
    heading lost (130 deg in a review's spin on the kinematic simulator). Since the wheels
    last turned, not over one frame: a slow spin (0.2 rad/s on a 0.3 m track) turns each
    wheel by 1.2 ticks of 0.5 mm per 20 ms frame, so no single zero frame proves it, but
    two ZUPT frames in a row would have. Why the wheels' recent rate: a rate the gyro shows
    at a stop may be a bias the filter does not know yet (a moving start's first stop with
    25 deg/s, past the MPU6050's +-20 deg/s tolerance) or one that stepped while standing
    (a review: 6.5-20 deg/s steps); without it both were taken for spins, every frame a
    fault, no ZUPT to relearn the bias, and the heading lost (117 deg; up to 180). The
    wheels' measured rate holds no gyro bias: a robot that stopped had slowed its turn
    first. Not covered: encoders that die at rest before the robot turns (or a robot turned
    by hand), which still pass for a stop."""
    if not aux[A_T] - aux[A_GYRO_T] <= GYRO_SILENT:  # NaN: no gyro sample yet
        return False
    w = x[4]
    low = abs(w) - math.sqrt(par[P_GATE] * (P[5, 5] + par[P_GYRO_VAR]))
    if low <= TURN_RATE or not abs(w - aux[A_MOVED_W]) <= SPIN_MATCH * abs(w):  # NaN: never
        return False
    rim = 0.5 * par[P_WHEEL_DISTANCE] * low  # m/s, each wheel's speed in a spin at `low`
    if kind != EV_WHEELS:
        return rim > 2.0 * par[P_TWIST_ZERO_V]
    return rim * max(t - aux[A_MOVED_T], par[P_PERIOD]) > 2.0 * par[P_SPEED_RATIO]


@njit
def _impossible_stop(x, P, aux, par, t):
    """True when zero wheel speed at ``t`` needs a harder braking than ``stop_decel`` since
    the last wheel frame, or since v was last measured (three standard deviations of v
    allowed on top). The latter ends a run of zero frames that no IMU calls motion (none, or
    one that cannot tell): once braking from the last measured speed since then fits
    ``stop_decel``, they are a stop. Judged over each frame's own period alone, an
    independent probe's wheels-only robot stopping from 0.3 m/s within one frame coasted on
    for 1.8 s (0.53 m), until v's own variance grew to cover it. (An IMU that shows motion
    keeps v measured at every such frame: for it nothing changes.)"""
    dt = par[P_PERIOD]
    if not math.isnan(aux[A_WHEEL_T]) and t - aux[A_WHEEL_T] > dt:
        dt = t - aux[A_WHEEL_T]
    if not math.isnan(aux[A_V_T]) and t - aux[A_V_T] > dt:
        dt = t - aux[A_V_T]
    return abs(x[3]) > par[P_STOP_DECEL] * dt + 3.0 * math.sqrt(P[3, 3])


@njit
def _remember_twist(x, aux, par, t):
    """Keep the twist the wheels should read after an update at effective time ``t`` (s),
    ``wheel_h`` of the posterior state ``x`` (m/s, rad/s), for :func:`_add_stamp_noise`,
    and the rate of change of its speed since the previous one (m/s^2, ``A_SPEED_RATE``,
    for the speed's random walk in :func:`_advance`). Rates are taken over at least one
    wheel period: two frames a millisecond apart (one serial read) must not make them huge."""
    h = wheel_h(x, par[P_WHEEL_DISTANCE], x[3])
    if t > aux[A_TWIST_T]:
        aux[A_SPEED_RATE] = (h[0] - aux[A_TWIST_V]) / max(t - aux[A_TWIST_T], par[P_PERIOD])
    aux[A_TWIST_T] = t
    aux[A_TWIST_V] = h[0]
    aux[A_TWIST_W] = h[1]


@njit
def _add_stamp_noise(R, x, aux, par, t):
    """Add to ``R`` the noise of a wheel twist's uncertain stamp at effective time ``t`` (s)
    (``stamp_std``, :func:`fusion.planar.model.stamp_noise`), the speed's and yaw rate's
    rates of change being the filter's own: the change of the twist the wheels should read
    (``wheel_h``) from the previous wheel twist's posterior (:func:`_remember_twist`) to this
    one's prior, per second. That is the gyro's change of the yaw rate (the state w follows
    every gyro sample) and the accelerometer's of the speed when it drives v (else v does not
    change between frames: no speed share). Not the measured twists' difference: a wheel
    that starts to slip changes that abruptly, and its own noise would hide the slip from the
    gate. Nothing is added for the first twist; rates over at least one wheel period (as in
    :func:`_remember_twist`). Returns the yaw rate's share as a signed standard deviation,
    ``alpha*stamp_std`` (rad/s; 0 when nothing is added)."""
    if par[P_STAMP_STD] > 0.0 and t > aux[A_TWIST_T]:
        dt = max(t - aux[A_TWIST_T], par[P_PERIOD])
        h = wheel_h(x, par[P_WHEEL_DISTANCE], x[3])
        dw_dt = (h[1] - aux[A_TWIST_W]) / dt
        stamp_noise(R, (h[0] - aux[A_TWIST_V]) / dt, dw_dt, par[P_STAMP_STD])
        return dw_dt * par[P_STAMP_STD]
    return 0.0


@njit
def _wheel_event(x, P, aux, par, kind, t, a, b):
    """A wheel frame (kind 1; kind 4: one the accelerometer flagged as slipping) or an
    external twist (kind 3); returns ``(d2, status)``.

    Zero wheel speed is a stop only if the IMU agrees: with the IMU moving while the state
    expects the wheels to turn by more than two ticks per period (a twist: twice
    ``twist_zero_v``), or, unless the IMU is still, a stop harder than ``stop_decel`` allows,
    or a fault already under way while the IMU is not still (and known), or a turn the gyro
    proves whatever the bias and the wheels were making (:func:`_spinning`), it is an
    encoder fault, flagged and not fused (status 7): the pose coasts on the motion model, its
    covariance growing; the fault lasts until the ticks come back or the IMU is still (in a
    turn the gyro proves: until the turn ends). A stop
    that lasts ``zupt_frames`` frames with a still IMU (or no IMU information) gives a ZUPT;
    before that, or with the IMU unsure, the zero speed is fused as an ordinary frame.
    """
    accel_slip = kind == EV_WHEELS_SLIP
    if accel_slip:
        kind = EV_WHEELS
    # the accelerometer drove v since the last input, driving straight: the wheels'
    # correction of v then teaches the offset (in a turn an IMU off the axle adds its
    # centripetal w^2 r: 0.07 m/s^2 spinning at 1.2 rad/s 5 cm ahead of it)
    learn = abs(x[4]) <= TURN_RATE and not math.isnan(_accel_input(aux, par, aux[A_T]))
    in_fault = aux[A_FLAGS] == FLAG_FAULT
    interval = par[P_PERIOD]
    if not math.isnan(aux[A_WHEEL_T]) and t - aux[A_WHEEL_T] > 0.0:
        interval = t - aux[A_WHEEL_T]
    aux[A_FLAGS] = 0.0
    if kind == 1:
        still = a == 0.0 and b == 0.0
    else:
        still = abs(a) <= par[P_TWIST_ZERO_V] and abs(b) <= par[P_TWIST_ZERO_W]
    imu = aux[A_IMU_MOTION]
    if still:
        if kind == 1:
            creep = 2.0 * par[P_SPEED_RATIO] / par[P_PERIOD]
        else:
            creep = 2.0 * par[P_TWIST_ZERO_V]
        turning = abs(x[3]) + 0.5 * par[P_WHEEL_DISTANCE] * abs(x[4]) > creep
        spinning = _spinning(x, P, aux, par, kind, t)
        fault = ((imu == MOTION_MOVING and turning) or spinning
                 or (in_fault and (imu == MOTION_UNSURE or imu == MOTION_MOVING))
                 or (imu != MOTION_STILL and _impossible_stop(x, P, aux, par, t)))
        aux[A_WHEEL_T] = t
        if fault:
            _no_steady_offset(aux)
            aux[A_FAULTS] += 1.0
            aux[A_FAULT_RUN] += 1.0
            # the turn the filter's rate (the gyro's, bias removed) made while the odometry,
            # dead, could not see it (the trust checks leave it out)
            aux[A_FAULT_TURN] += x[4] * interval
            aux[A_FLAGS] = FLAG_FAULT
            aux[A_ZERO_COUNT] = 0.0
            if imu == MOTION_MOVING or imu == MOTION_UNSURE or spinning:
                # a dead encoder feed on a moving robot is no gap: the speed keeps being
                # extrapolated (the pose coasts, its covariance growing) instead of being
                # forgotten after max_extrapolation
                aux[A_V_T] = aux[A_T]
            return math.nan, 7
        _track_wheel_rate(aux, 0.0, interval)
        aux[A_FAULT_RUN] = 0.0
        aux[A_ZERO_COUNT] += 1.0
        if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES] and (imu == MOTION_STILL
                                                        or imu == MOTION_UNKNOWN):
            _relearn_bias_at_stop(x, P, aux, par, imu == MOTION_STILL)
            y = -zupt_h(x)  # z = [0, 0]
            d2, status = _rate_update(x, P, aux, y, zupt_jacobian(x),
                                      zupt_noise(par[P_ZUPT_V_STD], par[P_ZUPT_W_STD]))
            if status == 0:
                status = 4
                aux[A_ZUPTS] += 1.0
                aux[A_FLAGS] = FLAG_ZUPT
                aux[A_FIRST_SPEED] = 0.0  # standing still: v is known
            _remember_twist(x, aux, par, t)
            return d2, status
    else:
        if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES]:
            # motion onset after a stop: the speed may have grown during this period at the
            # moving robot's pace, not the still one's
            P[3, 3] += par[P_Q_V] * par[P_PERIOD]
        aux[A_ZERO_COUNT] = 0.0
        aux[A_WHEEL_T] = t
        _no_steady_offset(aux)
        share = _catch_up(x, par, kind, a, b, aux[A_FAULT_RUN])
        aux[A_FAULT_RUN] = 0.0
        if share > 1.0:
            aux[A_CATCH_UPS] += 1.0
            a /= share
            b /= share
    L = par[P_WHEEL_DISTANCE]
    if kind == 1:
        z, R = ticks_measurement(a, b, par[P_SPEED_RATIO], par[P_PERIOD], L,
                                 par[P_TICK_STD], par[P_SCALE_STD], par[P_SEP_STD],
                                 par[P_WHEEL_W_STD])
    else:
        # a twist from someone else's wheel odometry (nav_msgs/Odometry)
        z, R = twist_measurement(a, b, par[P_TWIST_V_STD], par[P_TWIST_W_STD],
                                 par[P_SCALE_STD], par[P_SEP_STD], par[P_WHEEL_W_STD])
    if not still:
        aux[A_MOVED_T] = t
        _track_wheel_rate(aux, z[1], interval)
    # the wheels' yaw-rate error is correlated over wheel_w_corr_time s (skid, slip, tyre
    # creep): frames closer together than that do not average it down
    # in a turn the wheels' yaw rate is off by a share of the rate (scrub, tyre creep), which
    # must not teach the gyro bias: noise relative to the state's rate (not the measured one,
    # so that a slip on a straight line does not hide behind its own rate)
    R[1, 1] += (par[P_TURN_W_STD] * x[4]) ** 2
    inflate = par[P_WHEEL_W_CORR] / interval
    if inflate > 1.0:
        R[1, 1] *= inflate
        R[0, 1] *= math.sqrt(inflate)
        R[1, 0] = R[0, 1]
    stamp_w = _add_stamp_noise(R, x, aux, par, t)
    first = aux[A_FIRST_SPEED] == 1.0
    if first:
        # The robot may be driving at any speed when the filter starts (issue 11's outdoor
        # bag starts at 1-2 m/s). Under v's prior (0.05 m/s: at rest) a first frame whose yaw
        # rate fails the slip gate has its speed fused 1e5 times down-weighted, and v stays
        # near 0 for as long as the frames slip. So v is forgotten first: this frame sets it,
        # slipping or not (a slipping one leaves v's variance wide, for the next to correct).
        aux[A_FIRST_SPEED] = 0.0
        P[3, 3] += UNKNOWN_SPEED_VAR
        learn = False  # v's jump is no error of the accelerometer's offset
    v_prior = x[3]
    d2, status = _wheel_update(x, P, aux, par, z, R, interval, kind, accel_slip, stamp_w)
    if first and status == 2:
        # nothing fused (a slip with slip_inflation 0): v is as unknown as before the frame,
        # so its prior comes back and the next fused frame sets it
        P[3, 3] -= UNKNOWN_SPEED_VAR
        aux[A_FIRST_SPEED] = 1.0
    _remember_twist(x, aux, par, t)
    if learn and (status == 0 or status == 1):
        # what the wheels corrected, per second, is the offset's error (a slope, a drifting
        # bias), learnt slowly
        gain = min(1.0, interval / par[P_OFFSET_TIME])
        aux[A_FX_OFFSET] -= gain * (x[3] - v_prior) / interval
    return d2, status


#: Encoder-fault frames a later frame may carry the counts of (a read that came back empty,
#: then one that caught up), and how close (relative) its speed must be to that many times
#: the coasted speed. More is a dead feed, whose return reads one period's counts.
MAX_CATCH_UP = 3
CATCH_UP_TOLERANCE = 0.25
#: m/s: the least coasted speed a catch-up is taken at. Slower, a robot speeding up at 1 m/s^2
#: doubles its speed within two 40 ms periods, which reads as a catch-up (review: 0.1 m/s
#: at 0.8-1.5 m/s^2); from here a doubling in two periods needs 3 m/s^2.
CATCH_UP_MIN_SPEED = 0.25


@njit
def _catch_up(x, par, kind, a, b, run):
    """How many periods of motion the first frame after ``run`` encoder-fault frames carries
    (1 but for a catch-up): a driver whose read missed its counts sends zero, then the
    missed counts with the next period's, twice the speed; a twist computed from the counts
    does the same. The faulted frames' motion was already coasted at the filter's speed
    ``x[3]`` (:func:`_wheel_event`), so a frame whose speed (a twist's ``a``, or the mean of
    the ticks ``a``, ``b`` over a period) is within
    :data:`CATCH_UP_TOLERANCE` of ``run + 1`` times it, and nearer that than the coasted
    speed itself, is divided by ``run + 1``. Fused whole, an independent probe's bag with
    every tenth twist zero and the next doubled drove 7 % too far (GPS RMSE 1.55 -> 2.66 m)."""
    if run < 1.0 or run > MAX_CATCH_UP:
        return 1.0
    v = x[3]
    if kind == EV_WHEELS:
        v_m = 0.5 * (a + b) * par[P_SPEED_RATIO] / par[P_PERIOD]
        slow = 4.0 * par[P_SPEED_RATIO] / par[P_PERIOD]
    else:
        v_m = a
        slow = 10.0 * par[P_TWIST_ZERO_V]
    if abs(v) <= max(slow, CATCH_UP_MIN_SPEED):
        return 1.0
    n = run + 1.0
    if abs(v_m - n * v) <= CATCH_UP_TOLERANCE * n * abs(v) and abs(v_m - n * v) < abs(v_m - v):
        return n
    return 1.0


@njit
def _accel_sample(aux, par, f_x):
    """Keep the forward specific force ``f_x`` (m/s^2) of an IMU sample for the prediction
    of v; standing still (a ZUPT's conditions: ``zupt_frames`` zero frames, the IMU still
    or unknown) it is the offset: the mean over the current stop."""
    aux[A_FX] = f_x
    aux[A_FX_T] = aux[A_T]
    imu = aux[A_IMU_MOTION]
    if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES] and (imu == MOTION_STILL
                                                    or imu == MOTION_UNKNOWN):
        n = aux[A_FX_REST_N] + 1.0
        aux[A_FX_REST_N] = n
        if n == 1.0:
            aux[A_FX_OFFSET] = f_x
        else:
            aux[A_FX_OFFSET] += (f_x - aux[A_FX_OFFSET]) / n
    else:
        aux[A_FX_REST_N] = 0.0


@njit
def _implausible(kind, a, b, par):
    """True for an input no sensor of this robot can produce (a corrupt value): a rate above
    ``max_rate`` rad/s or a (wheel) speed above ``max_speed`` m/s."""
    if kind == 0:
        return abs(a) > par[P_MAX_RATE]
    if kind == 1 or kind == 4:
        k = par[P_SPEED_RATIO] / par[P_PERIOD]
        return abs(a) * k > par[P_MAX_SPEED] or abs(b) * k > par[P_MAX_SPEED]
    if kind == 3:
        return abs(a) > par[P_MAX_SPEED] or abs(b) > par[P_MAX_RATE]
    return False


@njit
def step_core(x, P, aux, par, kind, t, a, b):
    """Process one input event at effective time ``t`` (s); returns the update status.

    kind 0 (gyro): ``a`` = yaw rate about the world z axis, rad/s; ``b`` = the sample's IMU
    motion code (:mod:`fusion.planar.imu_motion`; 0 = unknown).
    kind 1 (wheels): ``a``, ``b`` = left, right ticks in one period; ``t`` is the period's
    midpoint (stamp - period/2 - latency), the instant whose speed the period's mean equals.
    kind 2 (absolute yaw): ``a`` = yaw, rad; ``b`` = its standard deviation, rad.
    kind 3 (twist): ``a`` = forward speed m/s, ``b`` = yaw rate rad/s of an external wheel
    odometry (nav_msgs/Odometry twist), taken as instantaneous at ``t``.
    kind 4 (wheels, slipping): as kind 1, for a frame the accelerometer flagged as slipping
    (:mod:`fusion.planar.accel_slip`): fused as a slip (status 1) whatever the gyro gate
    says, unless it is a stop or an encoder fault.
    kind 5 (accelerometer): ``a`` = forward specific force (base frame x, m/s^2) of an IMU
    sample, ``b`` unused (0); kept to drive v in the predictions that follow (when
    ``par[P_ACCEL_Q_V]`` > 0), and averaged into the offset while standing still; status 0,
    no update counted.

    Only the absolute yaw corrects the pose directly; the rate measurements (gyro, wheels,
    twist, ZUPT) correct v, w, b, k, c, and the pose follows through the motion model.

    Status: 0 applied, 1 slip (yaw rate not fused; speed fused down-weighted, or with its own
    noise when only the persistent-disagreement test flagged the frame), 2 gated out
    (or a saturated gyro sample skipped, or a gyro spike: :data:`MAX_ANGULAR_ACCEL`),
    3 S not positive definite,
    4 zero-velocity update, 5 dropped as too late, 6 invalid input,
    7 encoder fault (zero wheel speed while the IMU, the speed or a turn the gyro proves
    says the robot moves; not fused).
    """
    if not (math.isfinite(t) and math.isfinite(a) and math.isfinite(b)) or _implausible(
            kind, a, b, par):
        aux[A_ERROR] += 1.0
        return 6
    if not _advance(x, P, aux, par, t):
        return 5
    if kind == 0:
        if b == MOTION_STILL or b == MOTION_UNSURE or b == MOTION_MOVING:
            aux[A_IMU_MOTION] = b
        else:
            aux[A_IMU_MOTION] = MOTION_UNKNOWN
        if abs(a) >= par[P_GYRO_LIMIT]:
            # a saturated gyro reads the full-scale value, not the rate: skip it and let the
            # wheels carry the yaw rate until the gyro is back in range
            aux[A_SATURATED] += 1.0
            aux[A_CLIPPED] = aux[A_T]
            return 2
        if aux[A_FIRST_GYRO] == 1.0:
            # The robot may be turning at any rate when the filter starts. Under w's prior
            # the first reading would be split between w and the bias by their variances
            # (0.1 % of it into the bias with 1 rad/s against 2 deg/s), and a robot that never
            # stops, whose wheels' yaw rate is not trusted, never undoes that: starting at
            # 0.45 rad/s, a bias error of 0.03 deg/s. So w is forgotten first: the reading
            # sets w; the bias keeps its prior, correlated with w as it should be.
            aux[A_FIRST_GYRO] = 0.0
            P[4, 4] += UNKNOWN_RATE_VAR
        H = gyro_jacobian(x)
        R = gyro_noise(par[P_GYRO_VAR])
        y = gyro_h(x)
        y[0] = a - y[0]
        if aux[A_GYRO_T] == aux[A_GYRO_T]:  # not the first gyro sample
            # since the last one fused, in filter time (a late sample is fused at it)
            step = (MAX_ANGULAR_ACCEL * (aux[A_T] - aux[A_GYRO_T])
                    + SPIKE_SIGMAS * math.sqrt(innovation_variance(P, H, R, 0)))
            if abs(y[0]) > step:
                if aux[A_SPIKE_RUN] < SPIKE_RUN - 1:
                    # a single glitch of 30 rad/s at 30 Hz turned the heading by 57 deg
                    aux[A_SPIKE_RUN] += 1.0
                    aux[A_GYRO_SPIKES] += 1.0
                    return 2
                P[4, 4] += UNKNOWN_RATE_VAR
        aux[A_SPIKE_RUN] = 0.0
        aux[A_GYRO_T] = aux[A_T]
        if aux[A_ZERO_COUNT] >= par[P_ZUPT_FRAMES]:
            # motion onset while standing still: a gyro reading the still model cannot
            # explain, or an IMU that shakes, ends the stationary phase and gives w its
            # freedom back (otherwise the first turn would leak into the bias)
            if (y[0] * y[0] / innovation_variance(P, H, R, 0) > par[P_GATE]
                    or aux[A_IMU_MOTION] == MOTION_MOVING):
                aux[A_ZERO_COUNT] = 0.0
                P[4, 4] += par[P_Q_W] * par[P_PERIOD]
        d2, status = _rate_update(x, P, aux, y, H, R)
    elif kind == 1 or kind == 3 or kind == 4:
        d2, status = _wheel_event(x, P, aux, par, kind, t, a, b)
        if status == 7:
            return status
    elif kind == EV_ACCEL:
        _accel_sample(aux, par, a)
        return 0
    elif kind == 2:
        # an absolute yaw is no rate measurement: what is owed is paid at once
        x[2] += aux[A_YAW_PENDING]
        aux[A_YAW_PENDING] = 0.0
        y = yaw_residual(np.array([a]), yaw_h(x))
        d2, status = update_core(x, P, y, yaw_jacobian(x), yaw_noise(b), -1, math.inf, 0.0, 0)
    else:
        aux[A_ERROR] += 1.0
        return 6
    aux[A_LAST_D2] = d2
    aux[A_UPDATES] += 1.0
    # measured speeds: extrapolated again for up to max_extrapolation (see _advance)
    if kind == 0:
        if status == 0:
            aux[A_W_T] = aux[A_T]
    elif kind != 2 and (status == 0 or status == 1 or status == 4):
        aux[A_V_T] = aux[A_T]
        aux[A_W_T] = aux[A_T]
    return status


@njit
def _predict_held(x, P, aux, par, h, q_v, q_w):
    """:func:`predict_core` over ``h`` s while the heading held in ``x`` may lag the
    estimate's by the owed ``A_YAW_PENDING``: ``P`` (its Jacobian) and the odometry noise are
    those of the estimate, at the heading ``x[2] + owed``; the held pose steps along the held
    heading (the estimate's step turned back by the owed angle), and the difference goes into
    ``A_HELD_X``, ``A_HELD_Y``. Returns the odometry noise's pose block
    ``(q_xx, q_xy, q_yy)`` (:func:`fusion.planar.model.odometry_noise`)."""
    owed = aux[A_YAW_PENDING]
    yaw = x[2]
    x[2] = yaw + owed
    q = odometry_noise(x, h, par[P_ODO_ALONG], par[P_ODO_CROSS])
    x0, y0 = x[0], x[1]
    predict_core(x, P, h, q_v, q_w, par[P_Q_B], par[P_Q_K], par[P_Q_C], par[P_Q_G],
                 par[P_Q_S])
    if owed != 0.0:
        x[2] -= owed
        dx, dy = x[0] - x0, x[1] - y0
        c = math.cos(owed)
        s = math.sin(owed)
        held_dx = c * dx + s * dy
        held_dy = -s * dx + c * dy
        x[0] = x0 + held_dx
        x[1] = y0 + held_dy
        aux[A_HELD_X] += held_dx - dx
        aux[A_HELD_Y] += held_dy - dy
    return q


@njit
def held_pose_offset(aux):
    """``(dx m, dy m, dyaw rad)``: how far the held pose is from the filter's estimate.

    A heading correction beyond the yaw budget is owed (``A_YAW_PENDING``, :func:`_rate_update`)
    while ``P`` is that of the full update (and is propagated at the estimate's heading,
    :func:`_predict_held`): the held heading is off by ``-owed``, and every step driven along
    it puts into the position the difference to that step along the estimate's heading
    (``A_HELD_X``, ``A_HELD_Y``), which rate measurements never take back."""
    return aux[A_HELD_X], aux[A_HELD_Y], -aux[A_YAW_PENDING]


@njit
def reported_pose_covariance(P, aux, i, j):
    """Element ``(i, j)`` (i, j < 3) of the pose's mean square error about the held pose:
    ``P + d d^T`` with ``d`` the :func:`held_pose_offset` (the held pose is the estimate
    shifted by the known ``d``, so its error is the estimate's plus ``d``)."""
    dx, dy, dyaw = held_pose_offset(aux)
    d = (dx, dy, dyaw)
    return P[i, j] + d[i] * d[j]


@njit
def write_state_row(out, o, x, P, aux):
    """One state row (:data:`ROW_WIDTH` values) into ``out[o:]``: the state ``x`` (NX), the
    diagonal of ``P`` (NX) and its pose cross terms P[x,y], P[x,yaw], P[y,yaw]; the pose
    block is :func:`reported_pose_covariance` (that of the held pose)."""
    for i in range(NX):
        out[o + i] = x[i]
        out[o + NX + i] = P[i, i]
    for i in range(3):
        out[o + NX + i] = reported_pose_covariance(P, aux, i, i)
    out[o + 2 * NX] = reported_pose_covariance(P, aux, 0, 1)
    out[o + 2 * NX + 1] = reported_pose_covariance(P, aux, 0, 2)
    out[o + 2 * NX + 2] = reported_pose_covariance(P, aux, 1, 2)


@njit
def batch_core(x, P, aux, par, kinds, ts, aa, bb, out, status):
    """Run :func:`step_core` over N events; ``out[k]`` = the state row after event k
    (:func:`write_state_row`)."""
    for k in range(kinds.shape[0]):
        status[k] = step_core(x, P, aux, par, kinds[k], ts[k], aa[k], bb[k])
        write_state_row(out[k], 0, x, P, aux)
