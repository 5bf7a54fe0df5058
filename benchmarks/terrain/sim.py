"""Outdoor, non-level terrain simulator for a two-wheel (or skid-steer) robot.

Written from physics only (numpy/scipy), independently of the library. The robot follows a
scripted mission over a smooth height map z = h(x, y); its 3-D attitude follows the surface
(body z = surface normal, body x = the heading lifted onto the surface). Everything is computed
on a 1 kHz grid, then the IMU (200 or 30 Hz) and the wheel encoder frames are sampled from it
and written as a log directory (datasets/LOGDIR.md), plus an oracle.npz beside it (true
vertical in the base frame, true biases) for the baselines of run.py.

    python benchmarks/terrain/sim.py OUTDIR --terrain hills --seed 1 [--vibration]
        [--moving-start] [--mount] [--imu-rate 30] [--track-scale 1.5] [--slip] [--bag]

With --bag (write_bag; needs rosbags) also OUTDIR/run.bag, a ROS 1 bag in the shape of issue
11's outdoor robot's, stamped on an epoch clock (t0 = T0 = 1700008765.432109056 s + sim time,
integer ns, so every stamp has a sub-second part), and OUTDIR/run_truth.csv (t on that clock, s;
x, y, m; yaw, rad; 100 Hz):
  /imu/data  sensor_msgs/Imu, every IMU sample (rad/s, m/s^2, in the mounted IMU frame),
             orientation unknown (orientation_covariance[0] = -1), stamp t0 + imu_t
  /odom      nav_msgs/Odometry, 10 Hz: a skid-steer controller's twist from each wheel's
             surface distance over the last period on the encoder's tick grid, v = (vl+vr)/2,
             w = (vr-vl)/wheel_distance with robot.toml's wheel_distance (so w is track_scale
             times too fast, as a skid-steer's own odometry is), pose = its integral
  /gps/fix   sensor_msgs/NavSatFix, 5 Hz: the TRUE horizontal position + N(0, 1 m) per axis,
             on WGS84's tangent plane at 48 N, 11 E (x east, y north), status 0 (fix)
Imperfections: odometry loop jitter N(0, 2 ms) (read times, the twist divided by the actual
interval), its stamps 0.5-3 ms after the read, bag record times 1-4 ms (IMU, odometry) or
20-80 ms (GPS) after the stamps, the tick quantisation (5 mm/s at 10 Hz).

Modelling choices (not tuned against the library):
- The mission is scripted in HORIZONTAL speed u(t) and heading rate about the world vertical
  r(t) (both smoothed by a critically damped 2nd-order lag), so the horizontal path does not
  depend on the terrain; the 3-D position is (x, y, h(x, y)).
- Body rates come from consecutive attitudes (rotation vector of R_k^T R_k+1 per 1 ms), so they
  carry the roll/pitch rates of the terrain and the rate about the surface normal (not psi_dot).
- Specific force f = R^T (a + g_up), a the 3-D acceleration (second difference of positions).
- An IMU sample is the mean over its own sampling period of the 1 kHz values (a box
  anti-alias filter; it preserves the integral of the rate exactly).
- Each wheel counts the distance its contact point rolls ALONG THE SURFACE (body x component of
  its velocity): v -+ w_z * L_eff / 2, w_z the body rate about the surface normal. A skid-steer
  base is modelled by L_eff = track_scale * wheel_distance (its wheels turn more than a true
  differential drive's for the same rotation).
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

G = 9.81
FS = 1000.0          # internal rate, Hz
DT = 1.0 / FS


@dataclass
class Config:
    seed: int = 0
    duration: float = 300.0
    terrain: str = "hills"          # level | hills | ramps
    # hills: the steepest slope on the path, drawn in this range
    max_slope_deg: tuple = (10.0, 15.0)
    vibration: bool = False
    moving_start: bool = False
    mount: bool = False             # IMU rolled +90 deg, yawed -90 deg (said in robot.toml)
    imu_rate: float = 200.0
    wheel_period: float = 0.04      # firmware period (encode_sampling_time)
    wheel_distance: float = 0.45    # m, robot.toml
    track_scale: float = 1.0        # true effective track / robot.toml's (skid-steer: > 1)
    speed_ratio: float = 5e-4       # m per tick
    slip: bool = False              # slip patches on the terrain (wheels over-count)
    n_stops: int = 4


# --------------------------------------------------------------------------- mission
def _smooth(x, tau):
    """Critically damped 2nd-order lag (two 1st-order lags), steady state at x[0]."""
    a = DT / tau
    for _ in range(2):
        x = lfilter([a], [1.0, -(1.0 - a)], x, zi=[x[0] * (1.0 - a)])[0]
    return x


def mission(cfg, rng):
    """Commanded horizontal speed u and vertical yaw rate r at 1 kHz (piecewise, then smoothed)."""
    segs = []
    t = 0.0
    if not cfg.moving_start:
        segs.append((3.0, 0.0, 0.0))
        t = 3.0
    else:   # already driving at t = 0, possibly in an arc
        d = rng.uniform(5, 12)
        segs.append((d, rng.uniform(0.8, 1.3), rng.choice([0.0, rng.uniform(-0.4, 0.4)])))
        t = d
    stops = list(np.sort(cfg.duration * (np.arange(1, cfg.n_stops + 1) / (cfg.n_stops + 1))
                         + rng.uniform(-8, 8, cfg.n_stops)))
    while t < cfg.duration:
        if stops and t >= stops[0]:
            stops.pop(0)
            seg = (rng.uniform(3, 10), 0.0, 0.0)
        else:
            k = rng.choice(["straight", "arc", "turn"], p=[0.45, 0.38, 0.17])
            if k == "straight":
                seg = (rng.uniform(4, 15), rng.uniform(0.6, 1.5), rng.normal(0, 0.02))
            elif k == "arc":
                seg = (rng.uniform(3, 10), rng.uniform(0.5, 1.2),
                       rng.choice([-1, 1]) * rng.uniform(0.15, 0.5))
            else:   # turn in place
                rate = rng.uniform(0.6, 1.2)
                seg = (np.deg2rad(rng.uniform(60, 200)) / rate, 0.0, rng.choice([-1, 1]) * rate)
        segs.append(seg)
        t += seg[0]
    n = round(cfg.duration * FS) + 1
    u = np.zeros(n)
    r = np.zeros(n)
    i = 0
    for d, su, sr in segs:
        j = min(n, i + round(d * FS))
        u[i:j], r[i:j] = su, sr
        i = j
    return _smooth(u, 0.35), _smooth(r, 0.2)


# --------------------------------------------------------------------------- terrain
class Terrain:
    """h(x, y) and its analytic gradient: a sum of sinusoids, mesas (tanh edges) and bumps."""

    def __init__(self):
        self.waves = []   # (A, kx, ky, phase)
        self.mesas = []   # (cx, cy, radius, height, edge width)
        self.bumps = []   # (cx, cy, sigma, height)

    def eval(self, x, y):
        h = np.zeros_like(x)
        hx = np.zeros_like(x)
        hy = np.zeros_like(x)
        for A, kx, ky, ph in self.waves:
            arg = kx * x + ky * y + ph
            h += A * np.sin(arg)
            c = A * np.cos(arg)
            hx += c * kx
            hy += c * ky
        for cx, cy, R, H, w in self.mesas:
            dx, dy = x - cx, y - cy
            rr = np.hypot(dx, dy) + 1e-12
            th = np.tanh((R - rr) / w)
            h += 0.5 * H * (1 + th)
            dhdr = -0.5 * H / w * (1 - th ** 2)     # max slope H / (2 w)
            hx += dhdr * dx / rr
            hy += dhdr * dy / rr
        for cx, cy, s, H in self.bumps:
            dx, dy = x - cx, y - cy
            e = H * np.exp(-(dx ** 2 + dy ** 2) / (2 * s ** 2))
            h += e
            hx += -e * dx / s ** 2
            hy += -e * dy / s ** 2
        return h, hx, hy


def make_terrain(cfg, rng, x, y, moving_idx):
    ter = Terrain()
    if cfg.terrain == "hills":
        for _ in range(4):
            lam = rng.uniform(12, 40)
            a = rng.uniform(0, 2 * np.pi)
            k = 2 * np.pi / lam
            ter.waves.append([lam / (2 * np.pi), k * np.cos(a), k * np.sin(a),
                              rng.uniform(0, 2 * np.pi)])
        _, hx, hy = ter.eval(x, y)
        s = np.tan(np.deg2rad(rng.uniform(*cfg.max_slope_deg))) / np.hypot(hx, hy).max()
        for wv in ter.waves:       # scale so the steepest slope on the path is the drawn one
            wv[0] *= s
    elif cfg.terrain == "ramps":
        # mesas (raised or sunken plateaus whose edges are 10-15 deg ramps) and short bumps,
        # centred near points the robot drives through
        # (features kept apart, so that no two slopes add up)
        def pick(k, clear):
            out = []
            for i in rng.permutation(moving_idx):
                if all(np.hypot(x[i] - cx, y[i] - cy) > clear(cr) for cx, cy, cr in out):
                    out.append((x[i], y[i], 0.0))
                if len(out) == k:
                    break
            return out
        for cx, cy, _ in pick(6, lambda cr: 9.0):
            H = rng.choice([-1, 1]) * rng.uniform(0.3, 0.6)
            w = abs(H) / (2 * np.tan(np.deg2rad(rng.uniform(10, 15))))
            ter.mesas.append((cx + rng.uniform(-1, 1), cy + rng.uniform(-1, 1),
                              rng.uniform(2, 3.5), H, w))
        for _ in range(200):                     # bumps away from the mesas' edges
            i = rng.choice(moving_idx)
            if all(abs(np.hypot(x[i] - m[0], y[i] - m[1]) - m[2]) > 3 * m[4] + 1.0
                   for m in ter.mesas) and all(np.hypot(x[i] - b[0], y[i] - b[1]) > 2.0
                                               for b in ter.bumps):
                ter.bumps.append((x[i] + rng.uniform(-0.2, 0.2), y[i] + rng.uniform(-0.2, 0.2),
                                  rng.uniform(0.18, 0.25), rng.uniform(0.03, 0.05)))
            if len(ter.bumps) == 12:
                break
    elif cfg.terrain != "level":
        raise ValueError(cfg.terrain)
    return ter


# --------------------------------------------------------------------------- simulation
def simulate(cfg: Config):
    # independent streams: the same seed gives the same mission and sensor errors on every
    # terrain, so scenarios are paired
    rng_m, rng_t, rng_s, rng_v = [np.random.default_rng(q)
                                  for q in np.random.SeedSequence(cfg.seed).spawn(4)]
    u, r = mission(cfg, rng_m)
    n = len(u)
    t = np.arange(n) * DT
    # horizontal path (trapezoidal integration); psi = heading about the world vertical
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * DT)])
    vx, vy = u * np.cos(psi), u * np.sin(psi)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * DT)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * DT)])
    moving = np.flatnonzero(u > 0.4)
    ter = make_terrain(cfg, rng_t, x, y, moving)
    z, hx, hy = ter.eval(x, y)
    p = np.stack([x, y, z], 1)

    # attitude from the surface: body z = normal, body x = heading lifted onto the surface
    c, s = np.cos(psi), np.sin(psi)
    slope = hx * c + hy * s
    xb = np.stack([c, s, slope], 1) / np.sqrt(1 + slope ** 2)[:, None]
    zb = np.stack([-hx, -hy, np.ones(n)], 1) / np.sqrt(1 + hx ** 2 + hy ** 2)[:, None]
    yb = np.cross(zb, xb)
    R = np.stack([xb, yb, zb], 2)        # columns: body axes in world (body -> world)

    # body rate per 1 ms interval (exact mean rate of the rotation between samples)
    rot = Rotation.from_matrix(R)
    w_int = (rot[:-1].inv() * rot[1:]).as_rotvec() / DT           # (n-1, 3), body frame
    # acceleration at samples (second difference), specific force in body frame
    a = np.zeros_like(p)
    a[1:-1] = (p[2:] - 2 * p[1:-1] + p[:-2]) / DT ** 2
    a[0], a[-1] = a[1], a[-2]
    f = np.einsum("nji,nj->ni", R, a + np.array([0, 0, G]))     # R^T (a - g)

    # wheels: contact point speed along body x over each interval (along the surface)
    v_int = np.linalg.norm(np.diff(p, axis=0), axis=1) / DT
    L_eff = cfg.wheel_distance * cfg.track_scale
    rad_err = rng_s.normal(0, 0.002, 2)                   # left, right radius errors
    vl = (v_int - w_int[:, 2] * L_eff / 2) * (1 + rad_err[0])
    vr = (v_int + w_int[:, 2] * L_eff / 2) * (1 + rad_err[1])
    slip_info = []
    if cfg.slip:   # 3 patches of 'mud' where one or both wheels over-count by 10-30 %
        xm, ym = 0.5 * (x[1:] + x[:-1]), 0.5 * (y[1:] + y[:-1])
        for i in rng_t.choice(moving[moving < n - 1], 3, replace=False):
            rad = rng_t.uniform(1.5, 3.0)
            inside = np.hypot(xm - x[i], ym - y[i]) < rad
            sl, sr = rng_t.uniform(0.1, 0.3, 2) * rng_t.choice([0, 1], 2, p=[0.3, 0.7])
            vl[inside] *= 1 + sl
            vr[inside] *= 1 + sr
            slip_info.append((float(x[i]), float(y[i]), rad, float(sl), float(sr)))
    Dl = np.concatenate([[0.0], np.cumsum(vl * DT)])
    Dr = np.concatenate([[0.0], np.cumsum(vr * DT)])

    # ---- wheel frames: ticks of each period, quantised on the cumulative count
    kw = round(cfg.wheel_period * FS)
    iw = np.arange(kw, n, kw)
    cl = np.floor(Dl[iw] / cfg.speed_ratio)
    cr = np.floor(Dr[iw] / cfg.speed_ratio)
    ticks = np.stack([np.diff(np.concatenate([[0], cl])), np.diff(np.concatenate([[0], cr]))], 1)
    wheel_t = t[iw]

    # ---- IMU: mean over each sample's period of the 1 kHz values
    m = int(np.floor(cfg.duration * cfg.imu_rate))
    imu_t = np.arange(1, m + 1) / cfg.imu_rate
    i1 = np.minimum(np.round(imu_t * FS).astype(int), n - 1)
    i0 = np.concatenate([[0], i1[:-1]])
    Wc = np.concatenate([np.zeros((1, 3)), np.cumsum(w_int, 0)])
    Fc = np.concatenate([np.zeros((1, 3)), np.cumsum(f[1:], 0)])   # f[1:] ~ interval ends
    span = (i1 - i0)[:, None]
    gyro_true = (Wc[i1] - Wc[i0]) / span
    acc_true = (Fc[i1] - Fc[i0]) / span

    # sensor errors (base frame first; mount applied at the end)
    fs = cfg.imu_rate
    bias = rng_s.choice([-1, 1], 3) * np.deg2rad(rng_s.uniform(0.2, 1.0, 3))
    walk = np.cumsum(rng_s.normal(0, 5e-5 * np.sqrt(1 / fs), (m, 3)), 0)   # 5e-5 rad/s/sqrt(s)
    scale = rng_s.choice([-1, 1], 3) * 0.003
    g_noise = np.deg2rad(0.01) * np.sqrt(fs / 2)          # 0.01 deg/s/sqrt(Hz)
    a_noise = 400e-6 * G * np.sqrt(fs / 2)                # 400 ug/sqrt(Hz)
    acc_bias = rng_s.uniform(-0.1, 0.1, 3)
    gyro = gyro_true * (1 + scale) + bias + walk + rng_s.normal(0, g_noise, (m, 3))
    acc = acc_true + acc_bias + rng_s.normal(0, a_noise, (m, 3))
    vib_rms = 0.0
    if cfg.vibration:
        # broadband (white up to Nyquist) while driving or turning, scaled by activity
        vib_rms = rng_v.uniform(0.5, 1.0)            # m/s^2, vector RMS at full activity
        act = np.clip(np.abs(u[i1]) / 1.0 + np.abs(r[i1]) / 1.0, 0, 1)[:, None]
        shape = np.array([0.5, 0.5, 0.71])         # z strongest; |shape| = 1
        acc += act * vib_rms * shape * rng_v.normal(0, 1, (m, 3))
        gyro += act * np.deg2rad(1.0) * rng_v.normal(0, 1, (m, 3))   # ~1 deg/s per axis
    mount_rpy = [0.0, 0.0, 0.0]
    if cfg.mount:
        mount_rpy = [np.pi / 2, 0.0, -np.pi / 2]
    Rm = Rotation.from_euler("ZYX", mount_rpy[::-1]).as_matrix()   # URDF: Rz(Y) Ry(P) Rx(R)
    gyro_imu = gyro @ Rm          # row-vector form of Rm^T v: base -> IMU frame
    acc_imu = acc @ Rm

    up_base = R[i1, 2, :]         # world vertical expressed in the base frame (third row of R)
    info = dict(config=asdict(cfg), gyro_bias_base=bias.tolist(), gyro_scale=scale.tolist(),
                acc_bias=acc_bias.tolist(), radius_err=rad_err.tolist(), vib_rms=vib_rms,
                slip_patches=slip_info, true_track=L_eff,
                max_slope_path_deg=float(np.degrees(np.arctan(np.hypot(hx, hy).max()))),
                max_surface_speed=float(v_int.max()),
                max_abs_psi_rate=float(np.abs(r).max()),
                path_horizontal=float(np.sum(np.hypot(np.diff(x), np.diff(y)))),
                path_surface=float(np.sum(v_int) * DT),
                climb=float(np.sum(np.abs(np.diff(z)))))
    return dict(t=t, x=x, y=y, z=z, psi=psi, Dl=Dl, Dr=Dr, wheel_t=wheel_t,
                ticks=ticks.astype(int), imu_t=imu_t, gyro=gyro_imu, acc=acc_imu,
                up_base=up_base, gyro_base=gyro, gyro_true=gyro_true,
                mount_rpy=mount_rpy, info=info)


# --------------------------------------------------------------------------- writing
def write(run, cfg: Config, out):
    """out/log: the log directory (LOGDIR.md); out/oracle.npz, out/info.json: for run.py only."""
    log = os.path.join(out, "log")
    os.makedirs(log, exist_ok=True)
    rpy = ", ".join(repr(float(v)) for v in run["mount_rpy"])
    with open(os.path.join(log, "robot.toml"), "w") as fh:
        fh.write(f"""[chassis]
wheel_distance = {cfg.wheel_distance}
speed_ratio = {cfg.speed_ratio}
encode_sampling_time = {cfg.wheel_period}
cmd_vel_linear_max = 1.5
cmd_vel_angular_max = 1.5
wheel_speed_max = 2.5

[frames]
odom = "odom"
base = "base_footprint"
imu_mount_rpy = [{rpy}]
""")
    fmt = "%.17g"
    np.savetxt(os.path.join(log, "imu.csv"),
               np.column_stack([run["imu_t"], run["gyro"], run["acc"]]), delimiter=",",
               fmt=fmt, header="t,gx,gy,gz,ax,ay,az", comments="")
    np.savetxt(os.path.join(log, "wheels.csv"),
               np.column_stack([run["wheel_t"], run["ticks"]]), delimiter=",",
               fmt=["%.17g", "%d", "%d"], header="t,left,right", comments="")
    k = np.arange(0, len(run["t"]), 10)       # truth at 100 Hz
    np.savetxt(os.path.join(log, "truth.csv"),
               np.column_stack([run["t"][k], run["x"][k], run["y"][k], run["psi"][k]]),
               delimiter=",", fmt=fmt, header="t,x,y,yaw", comments="")
    np.savez_compressed(os.path.join(out, "oracle.npz"), imu_t=run["imu_t"],
                        up_base=run["up_base"], gyro_base=run["gyro_base"],
                        gyro_true=run["gyro_true"],
                        truth_t=run["t"][k], truth_x=run["x"][k], truth_y=run["y"][k],
                        truth_yaw=run["psi"][k])
    with open(os.path.join(out, "info.json"), "w") as fh:
        json.dump(run["info"], fh, indent=1)
    return log


# --------------------------------------------------------------------------- ROS 1 bag
T0 = 1_700_000_000.0 + 8765.432109   # s, epoch stamp of sim time 0 in the bag (default)
ORIGIN = (48.0, 11.0, 520.0)         # lat (deg), lon (deg), altitude (m) of sim x = y = 0
WGS84_A, WGS84_E2 = 6378137.0, 6.69437999014e-3


def _radii(lat_deg):
    """WGS84 meridian and prime-vertical radii of curvature at lat_deg (m)."""
    s2 = np.sin(np.deg2rad(lat_deg)) ** 2
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * s2)
    return n * (1 - WGS84_E2) / (1 - WGS84_E2 * s2), n


def to_latlon(east, north):
    """Local tangent plane (sim x = east, y = north, m) -> latitude, longitude (deg)."""
    m, n = _radii(ORIGIN[0])
    return (ORIGIN[0] + np.rad2deg(north / m),
            ORIGIN[1] + np.rad2deg(east / (n * np.cos(np.deg2rad(ORIGIN[0])))))


def from_latlon(lat, lon):
    """Inverse of to_latlon: east, north (m)."""
    m, n = _radii(ORIGIN[0])
    return (np.deg2rad(np.asarray(lon) - ORIGIN[1]) * n * np.cos(np.deg2rad(ORIGIN[0])),
            np.deg2rad(np.asarray(lat) - ORIGIN[0]) * m)


def bag_odometry(run, cfg, odom_rate, rng):
    """What a skid-steer base's controller publishes at odom_rate Hz (see write_bag).

    Returns read times (s, sim clock), stamps (s, sim clock), v (m/s), w (rad/s) and its own
    dead-reckoned pose x, y (m), yaw (rad)."""
    n = len(run["t"])
    k = np.arange(1, int((cfg.duration - 0.006) * odom_rate) + 1)
    jitter = np.clip(rng.normal(0, 0.002, len(k)), -0.006, 0.006)     # loop scheduling, s
    i = np.minimum(np.round((k / odom_rate + jitter) * FS).astype(int), n - 1)
    t_read = i * DT
    q = cfg.speed_ratio                                    # encoder resolution, m per tick
    dl = np.diff(np.floor(np.concatenate([[0.0], run["Dl"][i]]) / q)) * q
    dr = np.diff(np.floor(np.concatenate([[0.0], run["Dr"][i]]) / q)) * q
    dt = np.diff(np.concatenate([[0.0], t_read]))
    v = (dl + dr) / 2 / dt
    w = (dr - dl) / cfg.wheel_distance / dt                # robot.toml's track, not the true one
    yaw = np.cumsum(w * dt)
    mid = yaw - w * dt / 2                                 # 2nd-order Runge-Kutta
    x = np.cumsum(v * dt * np.cos(mid))
    y = np.cumsum(v * dt * np.sin(mid))
    stamp = t_read + rng.uniform(0.0005, 0.003, len(k))    # stamped after reading, computing
    return t_read, stamp, v, w, x, y, yaw


def write_bag(run, cfg: Config, out_path, *, odom_rate=10.0, gps_rate=5.0, gps_std=1.0,
              t0=T0, seed):
    """Write run as a ROS 1 bag (rosbags), shaped like issue 11's outdoor robot's bag.

    Stamps are integer ns on the bag clock: t0 (s, epoch) + sim time.
    - /imu/data sensor_msgs/Imu: every IMU sample of run (rad/s, m/s^2, mounted IMU frame,
      frame imu_link), stamp t0 + imu_t, orientation unknown (orientation_covariance[0] = -1).
    - /odom nav_msgs/Odometry at odom_rate Hz: each wheel's surface distance over the last
      period on the encoder's tick grid (speed_ratio), v = (vl + vr) / 2 (m/s),
      w = (vr - vl) / wheel_distance (rad/s) with robot.toml's wheel_distance, so a skid-steer
      base's (track_scale > 1) twist turns track_scale times too fast; pose = the Runge-Kutta
      integral of the twist (the bag's own dead reckoning).
    - /gps/fix sensor_msgs/NavSatFix at gps_rate Hz from t = 0: the TRUE horizontal position +
      N(0, gps_std) m per axis, as latitude/longitude on WGS84's tangent plane at ORIGIN (sim
      x = east, y = north), altitude ORIGIN + terrain height + N(0, 2 gps_std) m, status 0
      (fix), covariance diagonal (gps_std^2, gps_std^2, (2 gps_std)^2), type 2.
    Imperfections (a real recording's, values judged plausible, not tuned): the odometry loop
    reads the encoders at k / odom_rate + N(0, 2 ms) (clipped to +-6 ms, 1 ms grid) and divides
    by the actual interval; its stamp is 0.5-3 ms after the read; each message is recorded
    (bag time) 1-4 ms (IMU, odometry) or 20-80 ms (GPS) after its stamp; the encoder ticks
    quantise the twist (5e-4 m / 0.1 s = 5 mm/s per tick). seed: the stream of these and of
    the GPS noise (independent of the simulator's). Also writes OUT_truth.csv beside the bag
    (t on the bag clock, s; x, y, m; yaw, rad; 100 Hz). Returns the odometry and the fixes
    written (sim clock) for checks.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    rng = np.random.default_rng(np.random.SeedSequence([seed, 11]))
    t0_ns = round(t0 * 1e9)
    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]

    def header(seq, t, frame):
        ns = t0_ns + round(float(t) * 1e9)
        return Header(seq=seq, stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)

    def diag(*d):
        c = np.zeros((len(d), len(d)))
        c[np.diag_indices(len(d))] = d
        return c.ravel()

    events = []    # (record time ns, topic index, serialized message)
    lag = rng.uniform(0.001, 0.004, len(run["imu_t"]))
    imu_cov = diag(*[np.deg2rad(0.1) ** 2] * 3), diag(*[0.05 ** 2] * 3)
    for j, (t, g, a) in enumerate(zip(run["imu_t"], run["gyro"], run["acc"])):
        msg = T["sensor_msgs/msg/Imu"](
            header=header(j, t, "imu_link"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=diag(-1.0, 0.0, 0.0), angular_velocity=V3(*g),
            angular_velocity_covariance=imu_cov[0], linear_acceleration=V3(*a),
            linear_acceleration_covariance=imu_cov[1])
        events.append((t + lag[j], 0, store.serialize_ros1(msg, "sensor_msgs/msg/Imu")))

    _, stamp, v, w, ox, oy, oyaw = bag_odometry(run, cfg, odom_rate, rng)
    lag = rng.uniform(0.001, 0.004, len(stamp))
    P = T["geometry_msgs/msg/Point"]
    pose_cov = diag(1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2)     # diff_drive_controller-like
    twist_cov = diag(1e-3, 1e-3, 1e6, 1e6, 1e6, 3e-2)
    for j in range(len(stamp)):
        msg = T["nav_msgs/msg/Odometry"](
            header=header(j, stamp[j], "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=P(x=ox[j], y=oy[j], z=0.0),
                    orientation=Q(x=0.0, y=0.0, z=np.sin(oyaw[j] / 2), w=np.cos(oyaw[j] / 2))),
                covariance=pose_cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=V3(x=v[j], y=0.0, z=0.0),
                                                   angular=V3(x=0.0, y=0.0, z=w[j])),
                covariance=twist_cov))
        events.append((stamp[j] + lag[j], 1, store.serialize_ros1(msg, "nav_msgs/msg/Odometry")))

    gps_t = np.arange(0, int(cfg.duration * gps_rate) + 1) / gps_rate
    i = np.round(gps_t * FS).astype(int)
    east = run["x"][i] + rng.normal(0, gps_std, len(i))
    north = run["y"][i] + rng.normal(0, gps_std, len(i))
    alt = ORIGIN[2] + run["z"][i] + rng.normal(0, 2 * gps_std, len(i))
    lat, lon = to_latlon(east, north)
    lag = rng.uniform(0.02, 0.08, len(i))
    for j in range(len(i)):
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=header(j, gps_t[j], "gps"),
            status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=lat[j], longitude=lon[j], altitude=alt[j],
            position_covariance=diag(gps_std ** 2, gps_std ** 2, 4 * gps_std ** 2),
            position_covariance_type=2)
        events.append((gps_t[j] + lag[j], 2,
                       store.serialize_ros1(msg, "sensor_msgs/msg/NavSatFix")))

    if os.path.exists(out_path):
        os.remove(out_path)
    events.sort(key=lambda e: (e[0], e[1]))
    with Writer(out_path) as writer:
        conns = [writer.add_connection(topic, typ, typestore=store) for topic, typ in (
            ("/imu/data", "sensor_msgs/msg/Imu"), ("/odom", "nav_msgs/msg/Odometry"),
            ("/gps/fix", "sensor_msgs/msg/NavSatFix"))]
        for t, c, raw in events:
            writer.write(conns[c], t0_ns + round(t * 1e9), raw)

    with open(os.path.splitext(out_path)[0] + "_truth.csv", "w") as fh:   # 100 Hz, bag clock
        fh.write("t,x,y,yaw\n")
        for k in range(0, len(run["t"]), 10):
            ns = t0_ns + k * 1_000_000
            x, y, psi = (float(run[c][k]) for c in ("x", "y", "psi"))
            fh.write(f"{ns // 10**9}.{ns % 10**9:09d},{x!r},{y!r},{psi!r}\n")
    return dict(t0=t0_ns / 1e9, odom_t=stamp, odom_v=v, odom_w=w, odom_x=ox, odom_y=oy,
                gps_t=gps_t, gps_east=east, gps_north=north)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--terrain", default="hills", choices=["level", "hills", "ramps"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--vibration", action="store_true")
    ap.add_argument("--moving-start", action="store_true")
    ap.add_argument("--mount", action="store_true")
    ap.add_argument("--slip", action="store_true")
    ap.add_argument("--imu-rate", type=float, default=200.0)
    ap.add_argument("--track-scale", type=float, default=1.0)
    ap.add_argument("--bag", action="store_true",
                    help="also write OUTDIR/run.bag (ROS 1: /imu/data, /odom, /gps/fix)")
    a = ap.parse_args()
    cfg = Config(seed=a.seed, duration=a.duration, terrain=a.terrain, vibration=a.vibration,
                 moving_start=a.moving_start, mount=a.mount, imu_rate=a.imu_rate,
                 track_scale=a.track_scale, slip=a.slip)
    run = simulate(cfg)
    log = write(run, cfg, a.out)
    if a.bag:
        write_bag(run, cfg, os.path.join(a.out, "run.bag"), seed=a.seed)
    print(log, json.dumps({k: v for k, v in run["info"].items()
                                              if k not in ("config",)}))


if __name__ == "__main__":
    main()
