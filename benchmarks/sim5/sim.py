"""sim5: an independent differential-drive robot + MPU6050 + encoder simulator.

Written from scratch (numpy/scipy only) without reading the library's estimator or simulators.
Writes log directories per datasets/LOGDIR.md:  robot.toml (NOMINAL geometry), imu.csv,
wheels.csv, truth.csv, plus sim_meta.json / sim_aux.npz (truth-side info for scoring only).

Usage: python sim.py OUTDIR --scenario all|dead|moving|glitch --seed N

Design (magnitudes in the module constants below and in REPORT.md):
  * 1 kHz planar rigid body (x, y, yaw; body velocities u forward, vl lateral, r yaw rate),
    mass 8 kg, Iz 0.25 kg m^2, two driven wheels on the axle (the base_footprint origin),
    a trailing castor (swivel at x=-0.20 m, trail 3 cm, kinematic swivel, rolling drag).
  * Tyres: longitudinal force = C_s * slip (slip velocity / max(|u|,0.2)), C_s = 400 N per unit
    slip, lateral force = -C_alpha * slip angle (C_alpha 250 N/rad per wheel), both capped by a
    friction ellipse mu*N (mu 0.7; two low-friction patches with mu 0.12 per run).  Sideslip in
    turns is therefore real: the body's velocity is not along its heading.
  * Each wheel: equivalent mass 0.6 kg (gear-reflected rotor), viscous + Coulomb gear loss,
    firmware PI speed loop on the speed it believes (ticks x NOMINAL speed_ratio), force limit,
    following (v, w) commands ramped at 0.8 m/s^2 / 4 rad/s^2 and mixed with NOMINAL
    wheel_distance.
  * Suspension: pitch and roll are 2nd-order (6 Hz, zeta 0.25) following -0.6 deg per m/s^2 of
    longitudinal acceleration and +0.8 deg per m/s^2 of lateral acceleration.
  * IMU at lever arm (0.12, 0.04, 0.06) m, mount tilt drawn 0.5-2 deg (roll, pitch, plus a
    small yaw), unknown to robot.toml (imu_mount_rpy = 0).
  * MPU6050: see imu_errors().  Chip sample clock 200 Hz nominal, off by U(-0.5, 0.5) %;
    host reads the FIFO every 50 ms (+-2 ms jitter) and stamps sample i of an n-sample burst
    t_read - (n-1-i) * 5 ms (nominal period), then forces strictly increasing stamps
    (a stamp not after the previous one is put 0.5 ms after it).  FIFO of 85 samples: a longer
    stall overflows, the driver resets the FIFO and the queued samples are lost.
  * Encoders on the motor shaft: backlash 0.4 mm of rim travel, integer counts latched at the
    firmware's own clock (40 ms nominal, off by U(-0.3,0.3) %), speed-dependent effective
    radius, host stamps = latch + 1.5 ms + lognormal jitter + 1 % of frames delayed 10-30 ms,
    0.3 % lost frames plus one burst of 3 lost, a few EMI glitch frames (absurd counts).
"""

import argparse
import json
import math
import os

import numpy as np
from scipy import signal

# ---------------------------------------------------------------- nominal (what the user believes)
NOM_L = 0.30  # m wheel distance in robot.toml
NOM_SR = 1.0e-4  # m per tick in robot.toml
NOM_T = 0.04  # s encode_sampling_time
V_MAX = 0.5
W_MAX = 2.0
WHEEL_SPEED_MAX = 0.8

DT = 1e-3
G = 9.81
T_OFFSET = 1000.0  # host monotonic clock = true time + this


# ---------------------------------------------------------------- mission / commands
def build_mission(rng, scenario, duration=300.0):
    """List of (duration, v, w_fn) segments.  w may be a callable of segment-local time."""
    segs = []

    def stop(d):
        segs.append((d, 0.0, 0.0, "stop"))

    def corridor():
        d = rng.uniform(10, 25)
        v = rng.uniform(0.38, 0.5) * rng.choice([1, 1, 1, -0.5])
        a, f = rng.uniform(0.02, 0.06), rng.uniform(0.05, 0.15)
        ph = rng.uniform(0, 6.28)
        segs.append(
            (d, v, lambda t, a=a, f=f, ph=ph: a * math.sin(2 * math.pi * f * t + ph), "corridor")
        )

    def figure8():
        v = rng.uniform(0.25, 0.35)
        w = rng.uniform(0.7, 1.0)
        loop = 2 * math.pi / w
        n = int(rng.integers(1, 3))
        for _ in range(n):
            segs.append((loop, v, w, "fig8a"))
            segs.append((loop, v, -w, "fig8b"))

    def spin():
        w = rng.uniform(1.2, 2.0) * rng.choice([-1, 1])
        turns = rng.uniform(0.75, 2.5)
        segs.append((2 * math.pi * turns / abs(w), 0.0, w, "spin"))

    def dock():
        # back in, short pause, creep forward, back again: several direction reversals
        for _ in range(int(rng.integers(2, 4))):
            segs.append(
                (rng.uniform(2, 4), -rng.uniform(0.1, 0.2), rng.uniform(-0.3, 0.3), "dock_rev")
            )
            segs.append((rng.uniform(0.2, 0.6), 0.0, 0.0, "dock_pause"))
            segs.append(
                (rng.uniform(1, 2.5), rng.uniform(0.08, 0.15), rng.uniform(-0.4, 0.4), "dock_fwd")
            )

    def arc():
        segs.append((rng.uniform(5, 12), rng.uniform(0.2, 0.45), rng.uniform(-0.6, 0.6), "arc"))

    def slalom():
        v, a, per = rng.uniform(0.3, 0.45), rng.uniform(0.5, 1.0), rng.uniform(3, 6)
        segs.append(
            (
                rng.uniform(10, 20),
                v,
                lambda t, a=a, per=per: a * math.sin(2 * math.pi * t / per),
                "slalom",
            )
        )

    def stop_random():
        k = rng.random()
        if k < 0.35:
            stop(rng.uniform(0.3, 0.9))  # under 1 s
        elif k < 0.65:
            stop(rng.uniform(1.5, 4.0))
        else:
            stop(rng.uniform(5.0, 20.0))

    moves = [corridor, figure8, spin, dock, arc, slalom]
    if scenario == "moving":
        # already driving at the first sample; no stop (and no reversal) before 60-90 s
        first_stop = rng.uniform(60, 90)
        t = 0.0
        while t < first_stop:
            f = [corridor, figure8, arc, slalom, spin][int(rng.integers(0, 5))]
            n0 = len(segs)
            f()
            # no reversing in the first minute (a reversal passes through v = 0)
            for i in range(n0, len(segs)):
                d, v, w, name = segs[i]
                if v < 0:
                    segs[i] = (d, -v, w, name)
            t = sum(s[0] for s in segs)
        # cut the segments so the stop comes at first_stop
        cut, acc = [], 0.0
        for d, v, w, name in segs:
            if acc + d >= first_stop:
                cut.append((first_stop - acc, v, w, name))
                break
            cut.append((d, v, w, name))
            acc += d
        segs[:] = cut
        stop(rng.uniform(3.0, 8.0))
    else:
        stop(rng.uniform(3.0, 5.0))  # starts at rest, a few seconds still
    while sum(s[0] for s in segs) < duration + 5:
        f = moves[int(rng.integers(0, len(moves)))]
        f()
        if rng.random() < 0.45:
            stop_random()
    return segs


def command_profile(segs, n, scenario):
    v = np.zeros(n)
    w = np.zeros(n)
    label = np.empty(n, dtype=object)
    t0 = 0.0
    for d, vv, ww, name in segs:
        i0, i1 = int(round(t0 / DT)), min(n, int(round((t0 + d) / DT)))
        if i0 >= n:
            break
        tl = (np.arange(i0, i1) - i0) * DT
        v[i0:i1] = vv
        w[i0:i1] = np.array([ww(x) for x in tl]) if callable(ww) else ww
        label[i0:i1] = name
        t0 += d
    return v, w, label


# ---------------------------------------------------------------- dynamics
def simulate_body(rng, scenario, duration):
    n = int(round(duration / DT)) + 1
    segs = build_mission(rng, scenario, duration)
    vcmd, wcmd, label = command_profile(segs, n, scenario)

    # true robot (unknown to the user)
    L = NOM_L * (1 + rng.uniform(-0.03, 0.03))
    common = rng.uniform(-0.004, 0.004)
    mism = rng.uniform(-0.003, 0.003)
    srL = NOM_SR * (1 + common - mism / 2)  # true m per tick (at zero speed)
    srR = NOM_SR * (1 + common + mism / 2)
    kappa = rng.uniform(0.002, 0.006)  # effective radius grows kappa per (m/s)^2
    m, Iz, mw = 8.0, 0.25, 0.6
    Nw = 0.4 * m * G
    Nc = 0.2 * m * G
    Cs, Ca = 400.0, 250.0
    mu_nom = 0.7
    # two low friction patches (time windows while driving)
    patches = []
    for _ in range(2):
        ts = rng.uniform(30, duration - 20)
        patches.append((ts, ts + rng.uniform(3, 6)))
    mu_low = 0.12
    xc, trail = -0.20, 0.03
    mu_rr_w, mu_rr_c = 0.015, 0.03
    Kp, Ki, Fmax = 60.0, 600.0, 25.0
    visc, coul = 2.0, 0.4
    # suspension
    wn, zeta = 2 * math.pi * 6.0, 0.25
    kp_pitch = math.radians(0.6)
    kr_roll = math.radians(0.8)
    amax, alpmax = 0.8, 4.0

    # state
    X = Y = psi = 0.0
    u = vl = r = 0.0
    sL = sR = 0.0
    iL = iR = 0.0
    th = thd = ph = phd = 0.0
    phic = 0.0
    vr = wr = 0.0
    if scenario == "moving":
        u, r = vcmd[0], wcmd[0]
        vr, wr = u, r
        sL, sR = u - r * L / 2, u + r * L / 2
        # integrators to the steady drive force (rolling drag) so the start is smooth
        iL = iR = (mu_rr_w * Nw + 0.5 * mu_rr_c * Nc + visc * abs(u) + coul) * np.sign(u) / Ki
        phic = 0.0

    out = np.zeros((n, 14))
    ua_prev, vla_prev = 0.0, 0.0
    cL = srL / NOM_SR  # firmware believed speed = s * NOM_SR / sr_true
    cR = srR / NOM_SR
    p0 = [(int(a / DT), int(b / DT)) for a, b in patches]
    mu_arr = np.full(n, mu_nom)
    for a, b in p0:
        mu_arr[a:b] = mu_low
    tanh = math.tanh
    sqrt = math.sqrt
    cos, sin = math.cos, math.sin
    hL, hR = L / 2, -L / 2
    for k in range(n):
        mu = mu_arr[k]
        # ramped commands (firmware)
        dv = vcmd[k] - vr
        vr += max(-amax * DT, min(amax * DT, dv))
        dw = wcmd[k] - wr
        wr += max(-alpmax * DT, min(alpmax * DT, dw))
        tL = vr - wr * NOM_L / 2
        tR = vr + wr * NOM_L / 2
        # firmware PI on the believed wheel speed
        eL = tL - sL / cL
        eR = tR - sR / cR
        FmL = Kp * eL + Ki * iL
        FmR = Kp * eR + Ki * iR
        if abs(FmL) < Fmax:
            iL += eL * DT
        if abs(FmR) < Fmax:
            iR += eR * DT
        FmL = max(-Fmax, min(Fmax, FmL))
        FmR = max(-Fmax, min(Fmax, FmR))
        if (
            tL == 0.0
            and tR == 0.0
            and abs(sL) < 1e-3
            and abs(sR) < 1e-3
            and vcmd[k] == 0
            and wcmd[k] == 0
        ):
            # firmware brake at standstill (holds, integrators bleed)
            iL *= 0.99
            iR *= 0.99
        # tyre lateral: slip angle
        Fy = []
        Fx = []
        sn = []
        for s, h, Fm in ((sL, hL, FmL), (sR, hR, FmR)):
            uc = u - r * h
            slat = vl
            den = max(abs(uc), 0.15)
            fy = -Ca * slat / den
            lim = mu * Nw
            fy = max(-lim, min(lim, fy))
            # longitudinal, implicit in the (light) wheel
            cx = Cs / max(abs(uc), 0.2)
            loss = visc * s + coul * tanh(s / 0.005) + mu_rr_w * Nw * tanh(s / 0.005)
            s_new = (s + DT / mw * (Fm - loss + cx * uc)) / (1 + DT * cx / mw)
            fx = cx * (s_new - uc)
            flim = sqrt(max(lim * lim - fy * fy, 0.05 * lim * lim))
            if abs(fx) > flim:
                fx = flim if fx > 0 else -flim
                s_new = s + DT / mw * (Fm - loss - fx)
            Fx.append(fx)
            Fy.append(fy)
            sn.append(s_new)
        sL, sR = sn
        # castor (kinematic swivel, rolling drag along its heading)
        vsx, vsy = u, vl + r * xc
        ch, shh = cos(phic), sin(phic)
        vperp = -vsx * shh + vsy * ch
        phic += DT * (-r + vperp / trail)
        vroll = vsx * ch + vsy * shh
        fc = -mu_rr_c * Nc * tanh(vroll / 0.01)
        Fcx, Fcy = fc * ch, fc * shh
        # body
        Fxs = Fx[0] + Fx[1] + Fcx
        Fys = Fy[0] + Fy[1] + Fcy
        Mz = -(hL * Fx[0] + hR * Fx[1]) + xc * Fcy
        ua = Fxs / m + vl * r
        vla = Fys / m - u * r
        u += DT * ua
        vl += DT * vla
        r += DT * Mz / Iz
        # longitudinal / lateral acceleration of the origin (body axes, inertial)
        along = ua - vl * r
        alat = vla + u * r
        # suspension
        the = -kp_pitch * along
        phe = kr_roll * alat
        thd += DT * (-wn * wn * (th - the) - 2 * zeta * wn * thd)
        th += DT * thd
        phd += DT * (-wn * wn * (ph - phe) - 2 * zeta * wn * phd)
        ph += DT * phd
        c, s_ = cos(psi), sin(psi)
        X += DT * (u * c - vl * s_)
        Y += DT * (u * s_ + vl * c)
        psi += DT * r
        out[k] = (X, Y, psi, u, vl, r, th, ph, thd, phd, sL, sR, along, alat)
    t = np.arange(n) * DT
    geo = dict(
        L=L, srL=srL, srR=srR, kappa=kappa, common=common, mism=mism, patches=patches, mu_low=mu_low
    )
    return t, out, geo, segs, vcmd, wcmd, label


# ---------------------------------------------------------------- helpers
def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def body_kinematics(t, out):
    """True body angular rate and specific force at the IMU point, body axes (n x 3)."""
    X, Y, psi, u, vl, r, th, ph, thd, phd = [out[:, i] for i in range(10)]
    # ZYX Euler rates -> body rates
    psid = r
    wx = phd - psid * np.sin(th)
    wy = thd * np.cos(ph) + psid * np.cos(th) * np.sin(ph)
    wz = -thd * np.sin(ph) + psid * np.cos(th) * np.cos(ph)
    w = np.stack([wx, wy, wz], 1)
    # world acceleration of the origin (horizontal plane)
    vxw = np.gradient(X, DT)
    vyw = np.gradient(Y, DT)
    axw = np.gradient(vxw, DT)
    ayw = np.gradient(vyw, DT)
    aw = np.stack([axw, ayw, np.full_like(axw, G)], 1)  # a + g_up  (specific force, world)
    # into body: R = Rz(psi) Ry(th) Rx(ph);  f_b = R^T f_w
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(th), np.sin(th)
    cph, sph = np.cos(ph), np.sin(ph)
    # R^T rows
    R = np.empty((len(t), 3, 3))
    R[:, 0, 0] = cps * cth
    R[:, 0, 1] = cps * sth * sph - sps * cph
    R[:, 0, 2] = cps * sth * cph + sps * sph
    R[:, 1, 0] = sps * cth
    R[:, 1, 1] = sps * sth * sph + cps * cph
    R[:, 1, 2] = sps * sth * cph - cps * sph
    R[:, 2, 0] = -sth
    R[:, 2, 1] = cth * sph
    R[:, 2, 2] = cth * cph
    fb = np.einsum("nji,nj->ni", R, aw)
    # lever arm
    p = np.array([0.12, 0.04, 0.06])
    al = np.gradient(w, DT, axis=0)
    fb = fb + np.cross(al, p) + np.cross(w, np.cross(w, p))
    up_b = R[:, 2, :]  # world z in body axes
    return w, fb, up_b


def bandnoise(rng, n, lo, hi, fs=1000.0):
    b, a = signal.butter(2, [lo, hi], btype="band", fs=fs)
    x = signal.lfilter(b, a, rng.standard_normal(n))
    return x / np.std(x)


# ---------------------------------------------------------------- IMU
def imu_errors(rng, t, w_b, f_b, moving_speed):
    """MPU6050 chip-frame outputs at 1 kHz (before DLPF/sampling) + the true additive gyro bias."""
    n = len(t)
    dps = math.pi / 180
    # mount tilt (chip frame -> body), unknown to the user
    mr = rng.uniform(0.5, 2.0) * rng.choice([-1, 1])
    mp = rng.uniform(0.5, 2.0) * rng.choice([-1, 1])
    my = rng.uniform(-0.5, 0.5)
    Rm = rot_z(math.radians(my)) @ rot_y(math.radians(mp)) @ rot_x(math.radians(mr))
    w_c = w_b @ Rm  # = (Rm^T w_b^T)^T
    f_c = f_b @ Rm
    # temperature profile (deg C): warm-up + slow HVAC wobble
    T = 28 + 10 * (1 - np.exp(-t / 200.0)) + 0.6 * np.sin(2 * math.pi * t / 137.0)
    dT = T - T[0]
    # gyro
    b0 = rng.uniform(0.5, 2.0, 3) * rng.choice([-1, 1], 3) * dps
    bw = rng.uniform(0.1, 0.4, 3) * rng.choice([-1, 1], 3) * dps
    tw = rng.uniform(60, 150)
    warm = np.outer(np.exp(-t / tw) - 1.0, bw)  # drifts by bw over the first minutes
    rw = np.cumsum(rng.standard_normal((n, 3)), 0) * (0.004 * dps * math.sqrt(DT))
    btc = rng.normal(0, 0.015, 3) * dps  # bias per deg C
    scale = rng.uniform(0.003, 0.015, 3) * rng.choice([-1, 1], 3)
    stc = rng.normal(0, 1e-4, 3)  # scale per deg C (0.01 %/C)
    cross = rng.uniform(-0.005, 0.005, (3, 3))
    np.fill_diagonal(cross, 0)
    gsens = rng.normal(0, 0.1 * dps / G, (3, 3))  # rad/s per m/s^2 (0.1 deg/s/g)
    bias = b0 + warm + rw + dT[:, None] * btc + f_c @ gsens.T
    M = np.eye(3) + cross
    scl = 1 + scale[None, :] + dT[:, None] * stc[None, :]
    gyro = (w_c @ M.T) * scl + bias
    gyro += rng.standard_normal((n, 3)) * (0.005 * dps * math.sqrt(500))
    env = moving_speed
    vibg = (
        np.stack([bandnoise(rng, n, 12, 90) for _ in range(3)], 1)
        * np.array([0.4, 0.4, 0.15])
        * dps
    )
    gyro += vibg * env[:, None]
    # accel
    ab = rng.uniform(0.1, 0.4, 3) * rng.choice([-1, 1], 3)
    asc = rng.uniform(0.005, 0.02, 3) * rng.choice([-1, 1], 3)
    across = rng.uniform(-0.005, 0.005, (3, 3))
    np.fill_diagonal(across, 0)
    atc = rng.normal(0, 0.003, 3)
    acc = (f_c @ (np.eye(3) + across).T) * (1 + asc) + ab + dT[:, None] * atc
    acc += rng.standard_normal((n, 3)) * (400e-6 * G * math.sqrt(500))
    viba = np.stack([bandnoise(rng, n, 12, 90) for _ in range(3)], 1) * np.array([1.0, 1.0, 2.0])
    acc += viba * env[:, None]
    true_bias_c = bias  # additive part (incl. g-sensitivity on the true specific force)
    pars = dict(
        mount_rpy_deg=[mr, mp, my],
        b0_dps=(b0 / dps).tolist(),
        warm_dps=(bw / dps).tolist(),
        warm_tau=tw,
        scale=scale.tolist(),
        bias_tc_dps_per_C=(btc / dps).tolist(),
        accel_bias=ab.tolist(),
        accel_scale=asc.tolist(),
    )
    return gyro, acc, true_bias_c, Rm, pars


def sample_imu(rng, t, gyro, acc, scenario, duration):
    """DLPF, chip clock, FIFO bursts, host stamps, quantisation."""
    b, a = signal.butter(2, 42.0, fs=1000.0)
    zi = signal.lfilter_zi(b, a)
    gf = signal.lfilter(b, a, gyro, axis=0, zi=zi[:, None] * gyro[0][None, :])[0]
    af = signal.lfilter(b, a, acc, axis=0, zi=zi[:, None] * acc[0][None, :])[0]
    delta = rng.uniform(-0.005, 0.005)
    P = 0.005 * (1 + delta)
    tc = np.arange(rng.uniform(0.01, 0.02), duration - 0.02, P)  # true sample times
    gs = np.stack([np.interp(tc, t, gf[:, i]) for i in range(3)], 1)
    as_ = np.stack([np.interp(tc, t, af[:, i]) for i in range(3)], 1)
    # quantisation / range: +-250 dps (131 LSB per dps), +-2 g (16384 LSB per g)
    glsb = math.radians(1 / 131.0)
    alsb = G / 16384.0
    gs = np.clip(np.round(gs / glsb), -32768, 32767) * glsb
    as_ = np.clip(np.round(as_ / alsb), -32768, 32767) * alsb
    # host FIFO reads
    reads = []
    tr = 0.05
    stalls = []
    if scenario == "glitch":
        ts = 8.0
        while ts < duration - 5:
            ts += rng.uniform(5, 15)
            stalls.append(
                (ts, rng.choice([rng.uniform(0.1, 0.4), rng.uniform(0.45, 0.7)], p=[0.85, 0.15]))
            )
    si = 0
    while tr < duration + 0.06:
        reads.append(tr)
        step = 0.05 + rng.normal(0, 0.002)
        if si < len(stalls) and tr + step >= stalls[si][0]:
            step += stalls[si][1]
            si += 1
        tr += step
    reads = np.array(reads)
    avail = tc + 0.0003  # in the FIFO shortly after the sample
    idx = np.searchsorted(avail, reads, side="right")
    stamps, keep = [], []
    prev = -1.0
    lost = 0
    j0 = 0
    for tr, j1 in zip(reads, idx):
        nq = j1 - j0
        if nq <= 0:
            continue
        if nq > 85:  # overflow: driver resets the FIFO, queue lost
            lost += nq
            j0 = j1
            continue
        rt = tr + 0.0008  # read transaction time
        for i in range(nq):
            s = rt - (nq - 1 - i) * 0.005
            if s <= prev:
                s = prev + 0.0005
            stamps.append(s)
            keep.append(j0 + i)
            prev = s
        j0 = j1
    keep = np.array(keep)
    sample_imu.full = (tc, gs)  # every chip sample (before FIFO loss), for the reference
    return (
        np.array(stamps),
        gs[keep],
        as_[keep],
        tc[keep],
        dict(
            chip_rate_err=delta,
            fifo_lost=int(lost),
            stalls=[(float(a), float(b)) for a, b in stalls],
        ),
    )


# ---------------------------------------------------------------- encoders
def encoders(rng, t, out, geo, scenario, duration, label):
    sL, sR, u = out[:, 10], out[:, 11], out[:, 3]
    k = geo["kappa"]
    cntL = np.cumsum(sL / (geo["srL"] * (1 + k * sL**2))) * DT
    cntR = np.cumsum(sR / (geo["srR"] * (1 + k * sR**2))) * DT
    # backlash: the motor (encoder) leads the wheel by +-b/2 in the drive direction
    b = 0.0004
    offs = []
    for s in (sL, sR):
        o = np.zeros(len(s))
        cur = b / 2 * (1 if s[0] >= 0 else -1)
        for i in range(len(s)):
            if s[i] > 1e-3:
                tgt = b / 2
            elif s[i] < -1e-3:
                tgt = -b / 2
            else:
                tgt = cur
            d = tgt - cur
            cur += max(-0.1 * DT, min(0.1 * DT, d))
            o[i] = cur
        offs.append(o)
    cntL = cntL + (offs[0] - offs[0][0]) / geo["srL"]
    cntR = cntR + (offs[1] - offs[1][0]) / geo["srR"]
    eps = rng.uniform(-0.003, 0.003)
    Tfw = NOM_T * (1 + eps)
    lat = rng.uniform(0.0, Tfw)
    tau = np.arange(lat, duration - 0.05, Tfw)
    tau = tau + 2e-4 * np.sin(2 * np.pi * tau / 90.0)  # slow firmware clock wander
    L = np.floor(np.interp(tau, t, cntL)).astype(np.int64)
    R = np.floor(np.interp(tau, t, cntR)).astype(np.int64)
    dL = np.diff(L)
    dR = np.diff(R)
    tau = tau[1:]
    nfr = len(tau)
    host = tau + 0.0015 + rng.lognormal(math.log(0.0008), 0.6, nfr)
    dl = rng.random(nfr) < 0.01
    host[dl] += rng.uniform(0.01, 0.03, dl.sum())
    for i in range(1, nfr):
        if host[i] <= host[i - 1]:
            host[i] = host[i - 1] + 0.0002
    keep = rng.random(nfr) > 0.003
    j = int(rng.integers(100, nfr - 100))
    keep[j : j + 3] = False
    info = dict(fw_clock_err=eps, lost=int((~keep).sum()), glitches=[], dead=None)
    # dead encoder feed: 8 s of zero ticks while the robot keeps driving
    if scenario == "dead":
        speed = np.abs(u)
        drive = np.interp(tau, t, (speed > 0.15).astype(float)) > 0.99
        best = None
        run = 0
        for i in range(nfr):
            run = run + 1 if drive[i] and tau[i] > 60 else 0
            if run * Tfw >= 8.0:
                best = i - run + 1
                break
        if best is None:  # fall back: the longest drive window after 60 s
            best = int(np.searchsorted(tau, 150.0))
        n8 = int(round(8.0 / Tfw))
        dL[best : best + n8] = 0
        dR[best : best + n8] = 0
        info["dead"] = [float(tau[best] + T_OFFSET), float(tau[min(best + n8, nfr - 1)] + T_OFFSET)]
    # EMI glitches: single frames with absurd counts
    ng = int(rng.integers(3, 6)) if scenario != "glitch" else int(rng.integers(20, 31))
    cand = np.where(keep)[0]
    cand = cand[(cand > 20) & (cand < nfr - 20)]
    for i in rng.choice(cand, ng, replace=False):
        kind = rng.integers(0, 3)
        which = rng.integers(0, 3)  # left, right, both
        if kind == 0:
            val = int(rng.integers(20000, 2_000_000)) * int(rng.choice([-1, 1]))
            vals = (val, val)
        elif kind == 1:
            bit = int(rng.integers(12, 23))
            vals = (int(dL[i]) ^ (1 << bit), int(dR[i]) ^ (1 << bit))
        else:
            vals = (
                int(rng.integers(-8_000_000, 8_000_000)),
                int(rng.integers(-8_000_000, 8_000_000)),
            )
        if which in (0, 2):
            dL[i] = vals[0]
        if which in (1, 2):
            dR[i] = vals[1]
        info["glitches"].append([float(host[i] + T_OFFSET), int(dL[i]), int(dR[i])])
    host, dL, dR = host[keep], dL[keep], dR[keep]
    return host, dL, dR, info


# ---------------------------------------------------------------- writing
def write_run(outdir, scenario, seed, duration=300.0):
    logdir = os.path.join(outdir, "log")
    os.makedirs(logdir, exist_ok=True)
    rng_body = np.random.default_rng([seed, 11, {"moving": 1}.get(scenario, 0)])
    t, out, geo, segs, vcmd, wcmd, label = simulate_body(rng_body, scenario, duration)
    w_b, f_b, up_b = body_kinematics(t, out)
    speed = np.abs(out[:, 3]) + 0.15 * np.abs(out[:, 5])
    env = np.clip(0.3 + 1.6 * speed / 0.5, 0, 2.5) * (speed > 0.01)
    env = signal.lfilter([0.02], [1, -0.98], env)  # smooth onset
    rng_imu = np.random.default_rng([seed, 22])
    gyro, acc, bias_c, Rm, ipars = imu_errors(rng_imu, t, w_b, f_b, env)
    rng_s = np.random.default_rng([seed, 33, {"glitch": 1}.get(scenario, 0)])
    it, g, a, itrue, sinfo = sample_imu(rng_s, t, gyro, acc, scenario, duration)
    rng_e = np.random.default_rng([seed, 44, {"glitch": 1, "dead": 2}.get(scenario, 0)])
    wt, dL, dR, einfo = encoders(rng_e, t, out, geo, scenario, duration, label)

    with open(os.path.join(logdir, "robot.toml"), "w") as f:
        f.write(f"""[chassis]
wheel_distance = {NOM_L}
speed_ratio = {NOM_SR}
encode_sampling_time = {NOM_T}
cmd_vel_linear_max = {V_MAX}
cmd_vel_angular_max = {W_MAX}
wheel_speed_max = {WHEEL_SPEED_MAX}

[frames]
imu_mount_rpy = [0.0, 0.0, 0.0]
""")
    with open(os.path.join(logdir, "imu.csv"), "w") as f:
        f.write("t,gx,gy,gz,ax,ay,az\n")
        arr = np.column_stack([it + T_OFFSET, g, a])
        np.savetxt(f, arr, fmt="%.17g", delimiter=",")
    with open(os.path.join(logdir, "wheels.csv"), "w") as f:
        f.write("t,left,right\n")
        for tt, l, r in zip(wt + T_OFFSET, dL, dR):
            f.write(f"{tt:.17g},{int(l)},{int(r)}\n")
    sel = slice(0, len(t), 5)  # truth at 200 Hz
    with open(os.path.join(logdir, "truth.csv"), "w") as f:
        f.write("t,x,y,yaw\n")
        np.savetxt(
            f,
            np.column_stack([t[sel] + T_OFFSET, out[sel, 0], out[sel, 1], out[sel, 2]]),
            fmt="%.17g",
            delimiter=",",
        )
    # truth-side info for scoring: the reference heading (gyro about the true vertical, true
    # additive bias removed), evaluated at the IMU rows (true sample times -> host stamps)
    b, a_ = signal.butter(2, 42.0, fs=1000.0)
    up_c = up_b @ Rm  # true vertical in chip axes
    # the same quantised samples: measured minus (DLPF-filtered) true bias, projected
    zi = signal.lfilter_zi(b, a_)
    bias_f = signal.lfilter(b, a_, bias_c, axis=0, zi=zi[:, None] * bias_c[0][None, :])[0]
    bias_s = np.stack([np.interp(itrue, t, bias_f[:, i]) for i in range(3)], 1)
    up_s = np.stack([np.interp(itrue, t, up_c[:, i]) for i in range(3)], 1)
    rate_ref = np.sum((g - bias_s) * up_s, 1)
    np.savez_compressed(
        os.path.join(outdir, "sim_aux.npz"),
        imu_t=it + T_OFFSET,
        imu_true_t=itrue + T_OFFSET,
        rate_ref=rate_ref,
        bias_z_true=np.sum(bias_s * up_s, 1),
        t1k=t[::10] + T_OFFSET,
        u=out[::10, 3],
        r=out[::10, 5],
    )
    dist = float(np.sum(np.hypot(np.diff(out[:, 0]), np.diff(out[:, 1]))))
    turn = float(np.sum(np.abs(np.diff(out[:, 2]))))
    meta = dict(
        scenario=scenario,
        seed=seed,
        duration=duration,
        T_OFFSET=T_OFFSET,
        true_L=geo["L"],
        L_err_pct=100 * (geo["L"] / NOM_L - 1),
        sr_common_pct=100 * geo["common"],
        sr_mismatch_pct=100 * geo["mism"],
        kappa=geo["kappa"],
        low_mu_patches=[[a + T_OFFSET, b + T_OFFSET] for a, b in geo["patches"]],
        imu=ipars,
        imu_sampling=sinfo,
        encoders=einfo,
        distance_m=dist,
        total_turn_deg=math.degrees(turn),
        max_sideslip_deg=float(
            np.degrees(np.max(np.abs(np.arctan2(out[:, 4], np.maximum(np.abs(out[:, 3]), 0.05)))))
        ),
        segments=[
            (float(d), float(v) if not callable(v) else None, s[3])
            for s in segs
            for d, v in [(s[0], s[1])]
        ],
    )
    with open(os.path.join(outdir, "sim_meta.json"), "w") as f:
        json.dump(meta, f, indent=1)
    return meta


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("outdir")
    ap.add_argument("--scenario", default="all", choices=["all", "dead", "moving", "glitch"])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=300.0)
    a = ap.parse_args()
    import time

    t0 = time.time()
    m = write_run(a.outdir, a.scenario, a.seed, a.duration)
    print(
        f"{a.outdir}: {m['distance_m']:.1f} m, {m['total_turn_deg']:.0f} deg turned, "
        f"L err {m['L_err_pct']:+.2f} %, glitches {len(m['encoders']['glitches'])}, "
        f"dead {m['encoders']['dead']}, {time.time() - t0:.1f} s"
    )
