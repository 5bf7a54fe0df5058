"""Independent simulator of a two-wheel differential-drive robot with an MPU6050.

Structure (written from scratch for this acceptance test, not derived from the project):

1. Mission planner: a list of (duration, v_target, w_target) legs (straights, turns in place,
   arcs, stops), passed through an acceleration limiter at 1 kHz -> commanded (v, w).
2. Firmware / motors: the firmware turns (v, w) into wheel tick rates with *its* configured
   geometry; a speed PID (modelled as a first-order lag plus load ripple) makes each wheel's
   rim turn at that tick rate, so the true rim speed is scaled by R_true / R_nominal.
   On a slippery patch the wheel loses load and spins up (multiplier 1.2-1.4).
3. Planar rigid-body dynamics (x, y, yaw, u, v_lat, r) at 1 kHz: each wheel contact produces
   a longitudinal force proportional to the slip velocity (rim - contact point speed) and a
   lateral force proportional to the contact's lateral velocity, the vector sum saturated at
   mu * N (friction circle). A caster adds rolling resistance. Lateral skid in fast arcs and
   slip on low-mu patches come out of this model, not from an injected error.
4. Sensors: the encoders count the true wheel angle (quantised ticks, per-period frames on the
   firmware clock, host stamps with USB latency and jitter, lost frames, dead-encoder window);
   the MPU6050 sees the body rate and the specific force at its lever arm, in its (slightly
   tilted) frame, with scale / cross-axis errors, bias + warm-up drift + random walk, white
   noise at the datasheet density, vibration, a 2nd-order 42 Hz DLPF, and LSB quantisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, lfilter

G = 9.80665
DEG = math.pi / 180.0


@dataclass
class SimConfig:
    seed: int = 0
    scenario: str = "all"  # "plain" | "all" | "dead" | "moving"
    duration: float = 300.0
    dt: float = 0.001  # physics step
    # robot (true)
    radius: float = 0.04  # nominal wheel radius, m
    track: float = 0.22  # true wheel separation, m
    cpr: int = 1000  # encoder ticks per wheel revolution
    wheel_period: float = 0.04  # firmware frame period, s
    imu_rate: float = 100.0  # Hz
    mass: float = 3.0
    inertia: float = 0.035  # kg m^2 about z
    k_long: float = 400.0  # N/(m/s) longitudinal contact stiffness
    c_lat: float = 400.0  # N/(m/s) lateral contact stiffness
    mu: float = 0.8
    caster_x: float = -0.12
    caster_load: float = 0.2  # fraction of weight on the caster
    caster_crr: float = 0.05
    imu_lever: tuple = (0.05, 0.01, 0.06)
    # errors (filled per scenario by make_config)
    radius_mismatch: float = 0.0  # R_L = R(1+e), R_R = R(1-e)
    track_cfg_error: float = 0.0  # robot.toml wheel_distance = track * (1 + err)
    gyro_bias_dps: tuple = (0.0, 0.0, 0.0)
    gyro_drift_dps: float = 0.0  # warm-up drift amplitude on z (exponential), deg/s
    gyro_drift_tau: float = 150.0
    gyro_rw: float = 0.0  # bias random walk, deg/s/sqrt(s)
    gyro_scale_z: float = 0.0
    gyro_cross: float = 0.0
    gyro_nd: float = 0.005  # deg/s/sqrt(Hz) (MPU6050 datasheet)
    accel_nd: float = 400e-6 * G  # m/s^2/sqrt(Hz) (MPU6050 datasheet 400 ug/sqrt(Hz))
    accel_bias: tuple = (0.0, 0.0, 0.0)
    mount_tilt_deg: tuple = (0.0, 0.0)
    vib_accel_rms: float = 0.0  # m/s^2 at cruise, after the DLPF
    vib_gyro_rms_dps: tuple = (0.0, 0.0, 0.0)
    slip_episodes: int = 0
    skid: bool = False  # low lateral stiffness (skids in fast arcs)
    wheel_jitter: float = 0.0  # s, std of host-stamp jitter
    lost_frame_prob: float = 0.0
    dead_encoder: float = 0.0  # s of zero ticks while driving (0: none)
    start_moving: bool = False
    motor_ripple: float = 0.0
    quantize: bool = True
    # a given mission instead of a planned one: [(duration s, v m/s, w rad/s, kind), ...]
    legs: list | None = None
    # the gyro's 3x3 scale and cross-axis matrix instead of a drawn one (the same chip on
    # another run: a calibration of the unit a mission was driven with)
    gyro_matrix: np.ndarray | None = None


def make_config(scenario: str, seed: int) -> SimConfig:
    rng = np.random.default_rng(10_000 + seed)
    c = SimConfig(seed=seed, scenario=scenario)
    c.radius = float(rng.uniform(0.033, 0.05))
    c.track = float(rng.uniform(0.16, 0.30))
    c.cpr = int(rng.choice([330, 500, 780, 1000, 1440]))
    c.wheel_period = float(rng.choice([0.02, 0.025, 0.04, 0.05]))
    c.imu_rate = float(rng.choice([100.0, 200.0]))
    c.inertia = c.mass * (c.track**2 + 0.2**2) / 12.0 * 1.3
    sgn = lambda: float(rng.choice([-1.0, 1.0]))  # noqa: E731
    bias_z = sgn() * rng.uniform(0.2, 1.0)
    c.gyro_bias_dps = (sgn() * rng.uniform(0.2, 2.0), sgn() * rng.uniform(0.2, 2.0), bias_z)
    if scenario == "plain":
        return c
    c.gyro_drift_dps = sgn() * rng.uniform(0.05, 0.2)
    c.gyro_drift_tau = float(rng.uniform(80, 250))
    c.gyro_rw = 0.0005
    c.gyro_scale_z = sgn() * rng.uniform(0.003, 0.01)
    c.gyro_cross = 0.01
    c.accel_bias = tuple(float(v) for v in rng.uniform(-0.4, 0.4, 3))
    c.mount_tilt_deg = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)))
    c.vib_accel_rms = 1.0
    c.vib_gyro_rms_dps = (1.0, 1.0, 0.3)
    c.radius_mismatch = sgn() * rng.uniform(0.004, 0.006) / 2  # ~0.5 % left/right
    c.track_cfg_error = sgn() * rng.uniform(0.01, 0.03)
    c.slip_episodes = int(rng.integers(3, 6))
    c.skid = True
    c.c_lat = 80.0
    c.wheel_jitter = 0.003
    c.lost_frame_prob = 0.005
    c.motor_ripple = 0.01
    if scenario == "dead":
        c.dead_encoder = 8.0
    if scenario == "moving":
        c.start_moving = True
    return c


# ----------------------------------------------------------------------------- mission
def plan_mission(c: SimConfig, rng: np.random.Generator):
    """Legs (duration, v, w) filling c.duration."""
    legs = []
    t = 0.0
    if not c.start_moving:
        d = float(rng.uniform(3, 5))
        legs.append((d, 0.0, 0.0, "stop"))
        t += d
    since_stop = 0
    next_stop = int(rng.integers(2, 5))
    while t < c.duration:
        no_stop = c.start_moving and t < 62.0
        if since_stop >= next_stop and not no_stop:
            d = float(rng.uniform(2, 10))
            legs.append((d, 0.0, 0.0, "stop"))
            since_stop, next_stop = 0, int(rng.integers(2, 5))
        else:
            kind = rng.choice(["straight", "straight", "turn", "arc", "arc"])
            if kind == "straight":
                v = float(rng.uniform(0.2, 0.5))
                d = float(rng.uniform(1.0, 4.0)) / v
                legs.append((d, v, 0.0, "straight"))
            elif kind == "turn":
                w = float(rng.choice([-1, 1]) * rng.uniform(0.6, 1.5))
                d = float(rng.uniform(45, 180)) * DEG / abs(w)
                legs.append((d, 0.0, w, "turn"))
            else:
                v = float(rng.uniform(0.25, 0.5))
                r = float(rng.uniform(0.3, 1.5))
                w = float(rng.choice([-1, 1])) * v / r
                d = float(rng.uniform(45, 180)) * DEG / abs(w)
                legs.append((d, v, w, "arc"))
            since_stop += 1
        t += legs[-1][0]
    return legs


def command_profile(c: SimConfig, legs, n: int):
    """Acceleration-limited (v, w) commands at the physics rate."""
    tv = np.zeros(n)
    tw = np.zeros(n)
    t0 = 0.0
    for d, v, w, _ in legs:
        i0, i1 = round(t0 / c.dt), min(n, round((t0 + d) / c.dt))
        tv[i0:i1] = v
        tw[i0:i1] = w
        t0 += d
    av, aw = 0.4 * c.dt, 2.5 * c.dt
    v = np.empty(n)
    w = np.empty(n)
    cv = tv[0] if c.start_moving else 0.0
    cw = tw[0] if c.start_moving else 0.0
    for i in range(n):
        cv += min(av, max(-av, tv[i] - cv))
        cw += min(aw, max(-aw, tw[i] - cw))
        v[i] = cv
        w[i] = cw
    return v, w


def ar1(rng, n, dt, tau, rms):
    """Stationary first-order Gauss-Markov noise with correlation time tau and given RMS."""
    a = math.exp(-dt / tau)
    e = rng.standard_normal(n) * rms * math.sqrt(1 - a * a)
    out = lfilter([1.0], [1.0, -a], e)
    out += rng.standard_normal() * rms * a ** np.arange(n)  # stationary start
    return out


# ----------------------------------------------------------------------------- simulate
def _friction_circle(fx: float, fy: float, limit: float) -> tuple[float, float]:
    """A contact force (N) scaled down onto the friction circle of radius ``limit`` (N)."""
    mag = math.sqrt(fx * fx + fy * fy)
    if mag > limit:
        return fx * limit / mag, fy * limit / mag
    return fx, fy


def simulate(c: SimConfig) -> dict:
    rng = np.random.default_rng(
        c.seed * 7919
        + {"plain": 1, "all": 2, "dead": 3, "moving": 4, "calib_ccw": 5, "calib_cw": 6}[
            c.scenario
        ]
    )
    n = round(c.duration / c.dt) + 1
    t = np.arange(n) * c.dt
    legs = plan_mission(c, rng) if c.legs is None else c.legs
    v_cmd, w_cmd = command_profile(c, legs, n)

    R_nom = c.radius
    R_L = R_nom * (1 + c.radius_mismatch)
    R_R = R_nom * (1 - c.radius_mismatch)
    track_cfg = c.track * (1 + c.track_cfg_error)
    # firmware: wheel rim targets with its configured geometry, regulated on encoder ticks
    tgt_L = (v_cmd - w_cmd * track_cfg / 2) * (R_L / R_nom)
    tgt_R = (v_cmd + w_cmd * track_cfg / 2) * (R_R / R_nom)

    # slip episodes on slippery patches: choose times while driving
    mu_L = np.full(n, c.mu)
    mu_R = np.full(n, c.mu)
    mult_L = np.ones(n)
    mult_R = np.ones(n)
    slip_list = []
    moving = np.abs(v_cmd) > 0.15
    cand = np.flatnonzero(moving & (t > 15) & (t < c.duration - 5))
    for _ in range(c.slip_episodes):
        for _try in range(50):
            i0 = int(rng.choice(cand))
            dur = float(rng.uniform(0.5, 1.5))
            i1 = min(n, i0 + int(dur / c.dt))
            if moving[i0:i1].all() and all(abs(t[i0] - s[0]) > 10 for s in slip_list):
                break
        side = str(rng.choice(["L", "R"]))
        extra = float(rng.uniform(0.2, 0.4))
        ramp = np.ones(i1 - i0)
        m = min(100, (i1 - i0) // 4)  # 0.1 s ramps in and out
        ramp[:m] = np.linspace(0, 1, m)
        ramp[-m:] = np.linspace(1, 0, m)
        if side == "L":
            mult_L[i0:i1] += extra * ramp
            mu_L[i0:i1] = 0.015
        else:
            mult_R[i0:i1] += extra * ramp
            mu_R[i0:i1] = 0.015
        slip_list.append((float(t[i0]), float(t[i1 - 1]), side, extra))
    slip_list.sort()
    tgt_L = tgt_L * mult_L
    tgt_R = tgt_R * mult_R

    # motor speed loop: first-order lag, load ripple proportional to speed
    tau_m = 0.06
    a = math.exp(-c.dt / tau_m)
    rim_L = lfilter([1 - a], [1, -a], tgt_L, zi=[a * tgt_L[0]])[0]
    rim_R = lfilter([1 - a], [1, -a], tgt_R, zi=[a * tgt_R[0]])[0]
    if c.motor_ripple:
        rim_L *= 1 + ar1(rng, n, c.dt, 0.05, c.motor_ripple)
        rim_R *= 1 + ar1(rng, n, c.dt, 0.05, c.motor_ripple)

    # rigid body
    m_, I_ = c.mass, c.inertia
    b2 = c.track / 2
    Nw = m_ * G * (1 - c.caster_load) / 2
    Nc = m_ * G * c.caster_load
    kx, cy = c.k_long, c.c_lat
    cxp = c.caster_x
    crr = c.caster_crr * Nc
    x = y = th = 0.0
    u = float(v_cmd[0])
    vl = 0.0
    r = float(w_cmd[0])
    X = np.empty(n)
    Y = np.empty(n)
    TH = np.empty(n)
    U = np.empty(n)
    VL = np.empty(n)
    RR = np.empty(n)
    AX = np.empty(n)
    AY = np.empty(n)
    RD = np.empty(n)
    dt = c.dt
    sqrt = math.sqrt
    tanh = math.tanh
    cos, sin = math.cos, math.sin
    for i in range(n):
        # contact point velocities (body frame)
        vxl = u - r * b2
        vxr = u + r * b2
        fxl = kx * (rim_L[i] - vxl)
        fyl = -cy * vl
        fxr = kx * (rim_R[i] - vxr)
        fyr = -cy * vl
        fxl, fyl = _friction_circle(fxl, fyl, mu_L[i] * Nw)
        fxr, fyr = _friction_circle(fxr, fyr, mu_R[i] * Nw)
        # caster: rolling resistance opposite its contact velocity
        vcx = u
        vcy = vl + r * cxp
        sp = sqrt(vcx * vcx + vcy * vcy)
        if sp > 1e-9:
            g = crr * tanh(sp / 0.005) / sp
            fcx, fcy = -g * vcx, -g * vcy
        else:
            fcx = fcy = 0.0
        Fx = fxl + fxr + fcx
        Fy = fyl + fyr + fcy
        Mz = b2 * (fxr - fxl) + cxp * fcy
        ax = Fx / m_  # specific force at the base origin, body x
        ay = Fy / m_
        rdot = Mz / I_
        X[i], Y[i], TH[i], U[i], VL[i], RR[i] = x, y, th, u, vl, r
        AX[i], AY[i], RD[i] = ax, ay, rdot
        # semi-implicit Euler
        u_new = u + dt * (ax + r * vl)
        vl_new = vl + dt * (ay - r * u)
        r_new = r + dt * rdot
        ch, sh = cos(th), sin(th)
        x += dt * (u_new * ch - vl_new * sh)
        y += dt * (u_new * sh + vl_new * ch)
        th += dt * r_new
        u, vl, r = u_new, vl_new, r_new

    # ------------------------------------------------------------------ encoders
    ang_L = np.concatenate([[0.0], np.cumsum(rim_L[:-1]) * dt]) / R_L  # wheel angle, rad
    ang_R = np.concatenate([[0.0], np.cumsum(rim_R[:-1]) * dt]) / R_R
    cnt_L = np.floor(ang_L * c.cpr / (2 * math.pi))
    cnt_R = np.floor(ang_R * c.cpr / (2 * math.pi))
    fw_period = c.wheel_period * (1 + (2e-4 if c.scenario != "plain" else 0.0))
    phase = float(rng.uniform(0, c.wheel_period))
    ends = np.arange(phase + fw_period, c.duration - 0.01, fw_period)
    idx_end = np.round(ends / dt).astype(int)
    idx_start = np.round((ends - fw_period) / dt).astype(int)
    idx_start[0] = max(idx_start[0], 0)
    dl = (cnt_L[idx_end] - cnt_L[idx_start]).astype(np.int64)
    dr = (cnt_R[idx_end] - cnt_R[idx_start]).astype(np.int64)
    # host stamps: USB latency 2 ms + jitter (positive-skewed)
    if c.scenario == "plain":
        stamps = ends.copy()
    else:
        stamps = ends + 0.002 + np.abs(rng.normal(0, c.wheel_jitter, len(ends)))
    keep = np.ones(len(ends), bool)
    dead = None
    if c.dead_encoder:
        # 8 s window where the robot keeps driving: |v_cmd| > 0.15 throughout
        mv = np.abs(v_cmd) > 0.15
        win = int(c.dead_encoder / dt)
        ok = np.convolve(mv.astype(float), np.ones(win), "valid") >= win - 0.5
        starts = np.flatnonzero(ok & (t[: len(ok)] > 60) & (t[: len(ok)] < c.duration - 30))
        if len(starts) == 0:
            starts = np.flatnonzero(ok & (t[: len(ok)] > 20))
        if len(starts) == 0:  # relax: 'driving' = wheels turning
            mv = (np.abs(rim_L) + np.abs(rim_R)) > 0.1
            ok = np.convolve(mv.astype(float), np.ones(win), "valid") >= win - 0.5
            starts = np.flatnonzero(ok & (t[: len(ok)] > 20))
        s0 = float(t[int(rng.choice(starts))])
        dead = (s0, s0 + c.dead_encoder)
        sel = (ends > dead[0]) & (ends - fw_period < dead[1])
        dl[sel] = 0
        dr[sel] = 0
    lost = []
    if c.lost_frame_prob:
        drop = rng.random(len(ends)) < c.lost_frame_prob
        # one burst of 3 frames
        j = int(rng.integers(100, len(ends) - 100))
        drop[j : j + 3] = True
        keep &= ~drop
        lost = ends[drop].tolist()
    # stamps strictly increasing
    st = stamps[keep]
    for k in range(1, len(st)):
        if st[k] <= st[k - 1]:
            st[k] = st[k - 1] + 1e-4
    wheels = (st, dl[keep], dr[keep])

    # ------------------------------------------------------------------ IMU
    px, py, _pz = c.imu_lever
    a_imu_x = AX - RD * py - RR**2 * px
    a_imu_y = AY + RD * px - RR**2 * py
    a_imu_z = np.full(n, G)
    roll, pitch = (v * DEG for v in c.mount_tilt_deg)
    # base -> imu frame rotation: IMU frame is tilted by (roll, pitch) w.r.t. base
    cr, sr, cp, sp_ = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp_], [0, 1, 0], [-sp_, 0, cp]])
    R_bi = Ry @ Rx  # imu -> base
    R_ib = R_bi.T  # base -> imu
    f_b = np.stack([a_imu_x, a_imu_y, a_imu_z])
    w_b = np.stack([np.zeros(n), np.zeros(n), RR])
    f_i = R_ib @ f_b
    w_i = R_ib @ w_b
    # errors
    speed = np.clip((np.abs(rim_L) + np.abs(rim_R)) / 2 / 0.2, 0, 1)  # vibration level
    fs = 1 / dt
    gyro = np.empty((3, n))
    acc = np.empty((3, n))
    M = np.eye(3) + c.gyro_cross * rng.uniform(-1, 1, (3, 3)) * (1 - np.eye(3))
    M[2, 2] += c.gyro_scale_z
    if c.gyro_matrix is not None:
        M = np.array(c.gyro_matrix, dtype=float)
    gw = M @ w_i
    bias_all = []
    for k in range(3):
        b = np.full(n, c.gyro_bias_dps[k] * DEG)
        if k == 2:
            b += c.gyro_drift_dps * DEG * (1 - np.exp(-t / c.gyro_drift_tau))
        if c.gyro_rw:
            b += np.cumsum(rng.standard_normal(n)) * c.gyro_rw * DEG * math.sqrt(dt)
        bias_all.append(b)
        noise = rng.standard_normal(n) * c.gyro_nd * DEG * math.sqrt(fs / 2)
        if c.vib_gyro_rms_dps[k]:
            noise += speed * ar1(rng, n, dt, 0.004, c.vib_gyro_rms_dps[k] * DEG * 1.6)
        gyro[k] = gw[k] + b + noise
        an = rng.standard_normal(n) * c.accel_nd * math.sqrt(fs / 2)
        if c.vib_accel_rms:
            an += speed * ar1(rng, n, dt, 0.004, c.vib_accel_rms * 1.6)
        acc[k] = f_i[k] + c.accel_bias[k] + an
    # MPU6050 DLPF_CFG=3 (~42 Hz), 2nd-order Butterworth, causal
    bb, aa = butter(2, 42.0 / (fs / 2))
    gyro = lfilter(bb, aa, gyro - gyro[:, :1], axis=1) + gyro[:, :1]
    acc = lfilter(bb, aa, acc - acc[:, :1], axis=1) + acc[:, :1]
    step = round(1 / c.imu_rate / dt)
    ii = np.arange(round(0.5 / dt) % step, n, step)
    g_s = gyro[:, ii].T
    a_s = acc[:, ii].T
    if c.quantize:
        lsb_g = DEG / 65.5  # +-500 deg/s
        lsb_a = G / 8192.0  # +-4 g
        g_s = np.round(g_s / lsb_g) * lsb_g
        a_s = np.round(a_s / lsb_a) * lsb_a
    imu_t = t[ii] + (np.abs(rng.normal(0, 0.0003, len(ii))) if c.scenario != "plain" else 0.0)
    for k in range(1, len(imu_t)):
        if imu_t[k] <= imu_t[k - 1]:
            imu_t[k] = imu_t[k - 1] + 1e-5

    # true gyro bias about the base vertical (what a planar EKF bias state should converge to)
    B = np.stack(bias_all)[:, ii]
    bias_vert = R_bi[2] @ B
    # truth at 200 Hz
    tt = np.arange(0, n, 5)
    truth = (t[tt], X[tt], Y[tt], TH[tt])
    # true stops: body and wheels at rest
    at_rest = (
        (np.abs(U) < 1e-3) & (np.abs(RR) < 1e-3) & (np.abs(rim_L) < 1e-3) & (np.abs(rim_R) < 1e-3)
    )
    return dict(
        cfg=c,
        legs=legs,
        t=t,
        X=X,
        Y=Y,
        TH=TH,
        U=U,
        VL=VL,
        R=RR,
        rim_L=rim_L,
        rim_R=rim_R,
        v_cmd=v_cmd,
        w_cmd=w_cmd,
        wheels=wheels,
        imu=(imu_t, g_s, a_s),
        truth=truth,
        bias_vert=bias_vert,
        imu_to_base=R_bi,
        gyro_scale_eff=float((R_bi @ M @ R_ib)[2, 2]),
        gyro_matrix=M,
        slips=slip_list,
        dead=dead,
        lost=lost,
        at_rest=at_rest,
        track_cfg=track_cfg,
        speed_ratio=2 * math.pi * R_nom / c.cpr,
    )


def write_run(sim: dict, path: str | Path) -> Path:
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    c = sim["cfg"]
    (path / "robot.toml").write_text(
        "[chassis]\n"
        f"wheel_distance = {sim['track_cfg']!r}\n"
        f"speed_ratio = {sim['speed_ratio']!r}\n"
        f"encode_sampling_time = {c.wheel_period!r}\n"
        "cmd_vel_linear_max = 0.5\n"
        "cmd_vel_angular_max = 2.0\n"
    )
    it, g, a = sim["imu"]
    with open(path / "imu.csv", "w") as fh:
        fh.write("t,gx,gy,gz,ax,ay,az\n")
        for row in zip(it, *g.T, *a.T):
            fh.write(
                ",".join(f"{v:.9f}" if j == 0 else f"{v:.8g}" for j, v in enumerate(row)) + "\n"
            )
    wt, l, r = sim["wheels"]
    with open(path / "wheels.csv", "w") as fh:
        fh.write("t,left,right\n")
        for tt, a1, b1 in zip(wt, l, r):
            fh.write(f"{tt:.9f},{a1:d},{b1:d}\n")
    tt, x, y, th = sim["truth"]
    with open(path / "truth.csv", "w") as fh:
        fh.write("t,x,y,yaw\n")
        for row in zip(tt, x, y, th):
            fh.write("{:.6f},{:.9f},{:.9f},{:.9f}\n".format(*row))
    return path
