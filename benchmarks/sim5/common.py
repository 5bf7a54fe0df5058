"""Own CSV reading, baselines and scoring for sim5 (numpy only; does not import fusion)."""

import math
import os

import numpy as np
import tomllib


def read_csv(path):
    with open(path) as f:
        header = f.readline().strip().split(",")
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError:  # empty fields (e.g. fused.csv wheel speeds before the first frame)
        data = np.genfromtxt(path, delimiter=",", skip_header=1, filling_values=np.nan, ndmin=2)
    return {h: data[:, i] for i, h in enumerate(header)}


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def load_log(logdir):
    with open(os.path.join(logdir, "robot.toml"), "rb") as f:
        robot = tomllib.load(f)
    imu = read_csv(os.path.join(logdir, "imu.csv"))
    wh = read_csv(os.path.join(logdir, "wheels.csv"))
    tr = read_csv(os.path.join(logdir, "truth.csv"))
    return robot, imu, wh, tr


def sane_frames(robot, wh):
    """Frames whose implied wheel speed is within 2x wheel_speed_max (a simple sanity gate)."""
    ch = robot["chassis"]
    vmax = 2 * ch.get("wheel_speed_max", 1.0)
    lim = vmax * ch["encode_sampling_time"] / ch["speed_ratio"]
    return (np.abs(wh["left"]) <= lim) & (np.abs(wh["right"]) <= lim)


def wheel_dr(robot, wh, yaw_rate_fn=None):
    """Dead reckoning at the wheel frames' stamps.  Heading from the ticks (wheel-only) or from a
    given yaw series (yaw_at(t)) for the gyro baseline; distance from the ticks."""
    ch = robot["chassis"]
    sr, L = ch["speed_ratio"], ch["wheel_distance"]
    ok = sane_frames(robot, wh)
    t = wh["t"]
    l = np.where(ok, wh["left"], 0.0) * sr
    r = np.where(ok, wh["right"], 0.0) * sr
    ds = (l + r) / 2
    if yaw_rate_fn is None:
        dth = (r - l) / L
        yaw_end = np.cumsum(dth)
        yaw_mid = yaw_end - dth / 2
    else:
        yaw_end = yaw_rate_fn(t)
        yaw_mid = yaw_rate_fn(t - ch["encode_sampling_time"] / 2)
    x = np.cumsum(ds * np.cos(yaw_mid))
    y = np.cumsum(ds * np.sin(yaw_mid))
    return t, x, y, yaw_end


def find_stops(robot, imu, wh, min_len=1.0, edge=0.2):
    """Stops: runs of frames with zero ticks >= min_len s where the IMU is quiet; returns
    (t0, t1) trimmed by `edge` on both ends."""
    t = wh["t"]
    zero = (wh["left"] == 0) & (wh["right"] == 0)
    stops = []
    i = 0
    n = len(t)
    while i < n:
        if zero[i]:
            j = i
            while j + 1 < n and zero[j + 1]:
                j += 1
            # a zero frame covers (t - T, t]
            t0 = t[i] - robot["chassis"]["encode_sampling_time"] + edge
            t1 = t[j] - edge
            if t1 - t0 >= min_len - 2 * edge:
                m = (imu["t"] >= t0) & (imu["t"] <= t1)
                if m.sum() > 20:
                    a = np.stack([imu["ax"][m], imu["ay"][m], imu["az"][m]], 1)
                    g = np.stack([imu["gx"][m], imu["gy"][m], imu["gz"][m]], 1)
                    quiet = np.max(np.std(a, 0)) < 0.15 and np.max(np.std(g, 0)) < math.radians(0.5)
                    if quiet:
                        stops.append((t0, t1))
            i = j + 1
        else:
            i += 1
    return stops


def gyro_at_stops_yaw(robot, imu, wh):
    stops = find_stops(robot, imu, wh)
    t = imu["t"]
    gz = imu["gz"].copy()
    bias = np.zeros_like(gz)
    for t0, t1 in stops:
        m = (t >= t0) & (t <= t1)
        bias[t > t1] = np.mean(gz[m])  # used from that stop on
    rate = gz - bias
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    return t, yaw, stops


def truth_interp(tr, tq):
    yaw_u = np.unwrap(tr["yaw"])
    return (
        np.interp(tq, tr["t"], tr["x"]),
        np.interp(tq, tr["t"], tr["y"]),
        np.interp(tq, tr["t"], yaw_u),
    )


def score_track(tr, t, x, y, yaw, dist):
    m = (t >= tr["t"][0]) & (t <= tr["t"][-1])
    t, x, y, yaw = t[m], x[m], y[m], yaw[m]
    tx, ty, tyaw = truth_interp(tr, t)
    e = wrap(yaw - tyaw)
    fin = math.hypot(x[-1] - tx[-1], y[-1] - ty[-1])
    return dict(
        final_pct=100 * fin / dist,
        final_m=fin,
        yaw_rmse=math.degrees(math.sqrt(np.mean(e**2))),
        yaw_max=math.degrees(np.max(np.abs(e))),
        yaw_final=math.degrees(e[-1]),
    )
