"""A black-box check of `fusion replay` on a third, independent simulator (issue 11).

`sim.py` was written on 2026-11-26 by a helper who was not shown the estimator's code nor the
project's two simulators (only the log-directory format, the README and `fusion replay
--help`): a 1 kHz planar rigid body with friction-circle wheel contacts (skid in fast arcs
and slip on low-friction patches come out of the physics), a firmware driving the wheels with
its configured (wrong) geometry, encoders with quantisation, firmware clock drift, host stamp
latency and jitter, lost frames and a dead-encoder window, and an MPU6050 with bias, warm-up
drift, random walk, scale and cross-axis errors, a small mount tilt that robot.toml does not
mention, vibration while driving, a 42 Hz DLPF and LSB quantisation. This script writes each
run as a log directory, replays it with ``python -m fusion replay`` exactly as a user would
(a subprocess on this checkout), and scores the fused CSV, wheel-only dead reckoning and a
gyro-at-stops baseline (its own, written from the logs alone) against the truth.

It imports nothing of the library (its own CSV reading, angle wrapping and baselines): what
it scores comes from the files alone, as an outside check should.

Scenarios: plain (white noise, constant bias), all (every error), dead (all + 8 s of zero ticks
while driving), moving (all, driving from the first sample, first stop after ~70 s).

usage: python benchmarks/blackbox/run_all.py [--seeds N] [--first-seed S]
    [--scenarios plain,all,dead,moving] [--out DIR] [--calibrate]
Results: DIR/<scenario>_<seed>/{robot.toml,imu.csv,wheels.csv,truth.csv,fused.csv,
replay.txt,metrics.json} (~30 MB a run) and the table DIR/RESULTS_table.md (default DIR:
./blackbox-runs). 6 seeds x 4 scenarios take about 15 min. With --calibrate also
calib_ccw/, calib_cw/, robot-gyro.toml, fused_cal.csv per run and DIR/RESULTS_calibrated.md.

Measured on 2026-11-26 (seeds 1-6; final error % of distance / yaw RMSE deg, means): fused
0.07/0.20, 1.20/2.68, 1.03/2.06, 1.16/3.09; gyro at stops 0.07/0.24, 1.10/2.58, 2.57/2.71,
15.2/37.0; wheel only 0.28/0.81, 17.4/61.0, 31.9/77.2, 16.7/50.6. On "all" the fused odometry
was worse than gyro-at-stops on 4 of 6 seeds; in "moving" seed 4 the first stop moved the
heading by +9 deg over 14 s (3 deg of it at rest) while the bias changed by 0.13 deg/s.

The "reference" yaw RMSE column (reference_yaw_rmse in metrics.json): the heading integrated from
the gyro about the TRUE base vertical minus the TRUE bias there, i.e. what an estimator that
knew the mount tilt and the bias exactly would still get from the gyro's scale (0.3-1 %) and
cross-axis errors, noise and vibration; nothing here tells the gyro's scale (no absolute
heading), so it is about the best a fused estimate can do on yaw, not a strict bound (errors
can cancel).

Held out, 2026-11-27 (seeds 101-106, which nothing was chosen or looked at on before; means,
worst in brackets):

| scenario | fused final % / yaw deg | gyro at stops | wheel only | reference yaw |
|---|---|---|---|---|
| plain | 0.08 / 0.22 (0.11 / 0.29) | 0.11 / 0.28 | 0.3 / 0.9 | 0.12 |
| all | 1.13 / 2.32 (2.08 / 3.37) | 1.32 / 2.85 | 28.0 / 73.7 | 2.59 |
| dead | 0.68 / 1.70 (2.30 / 2.31) | 3.35 / 1.50 | 10.7 / 55.4 | 1.69 |
| moving | 1.21 / 3.34 (3.79 / 5.71) | 16.5 / 41.0 | 23.9 / 62.9 | 2.16 |

Fused better than gyro at stops on final error / yaw: all 5/5 of 6, dead 6/1, moving 6/6,
plain 4/4. Its yaw RMSE is within 0.5 deg of the reference on 17 of the 18 plain, all and
dead runs (all seed 105: 2.44 against 1.87): there the yaw is limited by the gyro's
unobservable scale, not by the filter. On "moving"
(driving from the first sample, first stop after 64-74 s) it is 0.5-4 deg above it on five
of six: before the first stop the bias is learnt only from the wheels (confounded with their
left/right radius mismatch), and the first stop's retroactive heading correction applies the
bias at the stop to the whole drive, while the simulated warm-up drift changed it by
0.04-0.1 deg/s over that minute (the filter's covariance covers it: NEES inside on 87 % of
moving seed 4's rows).

Held out again after the pipeline began holding the horizontal gyro bias's leak through the
tilt projection at its value at rest (FusionPipeline._bias_leak, 2026-11-27; seeds 101-106,
means, worst in brackets):

| scenario | fused final % / yaw deg | gyro at stops | wheel only | reference yaw |
|---|---|---|---|---|
| plain | 0.09 / 0.22 (0.14 / 0.28) | 0.11 / 0.28 | 0.3 / 0.9 | 0.12 |
| all | 1.31 / 2.85 (2.54 / 4.26) | 1.32 / 2.85 | 28.0 / 73.7 | 2.59 |
| dead | 0.63 / 1.80 (2.22 / 3.32) | 3.35 / 1.50 | 10.7 / 55.4 | 1.69 |
| moving | 1.37 / 3.48 (3.62 / 5.54) | 16.5 / 41.0 | 23.9 / 62.9 | 2.16 |

The yaw is within 0.5 deg of the reference on 16 of the 18 plain, all and dead runs (all 102:
4.26 against 3.57; dead 102: 3.32 against 2.61), but its mean on "all" rose 2.32 -> 2.85 and
fused beats gyro at stops on yaw on 4 of 6 "all" runs (5 before): the leak had made errors of
up to +-3 deg (on seeds 301-308), which on these seeds happened to cancel part of the gyro's
scale error (all 101: 1.20 before, reference 2.18, now 2.36). With the x/y gyro biases of the
bundled real MPU6050 (-3.3, +1.1 deg/s; this simulator draws 0.2-2) the fix is a clear gain:
all + dead 101-106, mean yaw 3.08 -> 2.38 deg (reference 2.14, worst 6.23 -> 5.08;
tests/test_blackbox_replay.py).

Held out once more after the EKF's wheel yaw-rate model took the frame's measured speed for the
radius mismatch's c*v and the persistent-disagreement slip test came in (EkfNoise.slip_window,
2026-11-27; found on long straight drives without a stop, tests/test_ekf_slip.py): plain, all
and dead within 0.01 of the table above (means and worst runs); moving 1.46 / 3.65 (worst
yaw 5.80) against 1.37 / 3.48 (5.54), mostly moving 104 (3.83 -> 4.71 deg: its bias before
the first stop, learnt from the wheels alone, now lands 0.1 deg/s further from the truth). On
the tuning seeds 301-308 moving went 4.17 -> 4.06 deg and on the physics
simulator's moving starts (benchmarks/ekf_accuracy.py, seeds 0-7) 4.24 -> 4.05 deg (calibrated
1.42 -> 1.12, worst 5.9 -> 3.6): a draw on this simulator's held-out moving starts, a gain on
the others.

Again after the pipeline added the heading's roll_dot * (sin(pitch) - its value at rest) to
the rate about the vertical once the robot has stopped (FusionPipeline._roll_term, found on the
hills of benchmarks/terrain; 2026-11-27), yaw RMSE means (worst), held out 101-106: plain 0.22
(0.27) unchanged, all 2.86 -> 2.81 (4.27 -> 4.13), dead 1.81 -> 1.80 (3.32 -> 3.02), moving
3.65 -> 3.69 (5.80 -> 5.90); tuning 301-308: plain 0.19, all 3.64 -> 3.63, dead 4.32 -> 4.26,
moving 4.06 -> 4.02. On this level floor the term is the attitude's noise: a draw. Then the
gyro's own z axis before the first stop (the unknown x, y biases no longer leak through the
tilt; the whole leak learnt at rest removed from the first stop on): moving starts, 101-106
and 301-308 together, 3.88 -> 3.58 deg (moving 303: 5.05 -> 2.47); all 3.28 and dead 3.21
unchanged.

With the gyro's scale calibrated as README says (``--calibrate``, 2026-11-29): for each run,
the same simulated robot and IMU (scale, cross-axis matrix, tilt, biases, vibration) turn 10
times in place each way back to a mark, stopped within a random 0.5 deg of it; ``fusion
calibrate gyro-scale ... --write`` on those two logs, then ``fusion replay --robot`` with the
written robot.toml, and the gyro-at-stops baseline with the same scale. Nothing was chosen on
these runs. Seeds 417-424, never run before; mean (range over the 8 seeds):

| yaw RMSE, deg | fused, calibrated | gyro at stops, calibrated | fused, uncalibrated |
|---|---|---|---|
| all | 0.50 (0.22-0.95) | 0.95 (0.36-1.92) | 1.86 (0.94-4.01) |
| dead | 0.57 (0.18-0.94) | 0.97 (0.21-1.83) | 1.78 (0.53-4.58) |
| moving | 1.38 (0.42-2.75) | 38.6 (16.2-58.5) | 3.01 (0.88-6.75) |

| final error, % | fused, calibrated | gyro at stops, calibrated | fused, uncalibrated |
|---|---|---|---|
| all | 0.20 (0.02-0.77) | 0.35 (0.12-0.69) | 0.55 (0.01-0.92) |
| dead | 0.49 (0.20-0.68) | 3.13 (2.09-4.89) | 1.13 (0.46-3.87) |
| moving | 0.47 (0.01-1.16) | 13.7 (2.8-21.9) | 1.09 (0.07-2.44) |

Issue 11's bound of 1.5 deg yaw RMSE holds on all 16 runs that start at rest, and 0.5 % of
the distance on 11 of them ("all" 422 0.77 %; "dead" 418, 420, 421, 424 0.55-0.68 %); not on
three of the eight moving starts (2.0-2.8 deg: the bias before the first stop is learnt from
the wheels alone). The calibrated baseline is better on yaw on 3 of the 8 "all" runs and 1
of the 8 "dead" runs, by 0.2-0.5 deg. ``fusion calibrate gyro-scale`` measures the scale
about the vertical the accelerometer shows (the one the pipeline projects the gyro on,
tilted by the accelerometer's bias: 2-3 deg here): there its error is within 0.4 of its
stated standard deviation (0.021-0.030 %) on all 24 runs; about the base's true vertical it
is 0.00-0.15 % lower. Pose NEES inside its 95 % bounds on 57-99 % of the rows (at least 85 %
on 19 of 24).

After the calibration commands were hardened (their rest, saturation and agreement checks,
the same day), seeds 425-428, never run before: calibrated fused yaw RMSE "all" 0.53 0.30
0.27 1.35 deg, "dead" 0.35 0.39 0.78 0.53 (uncalibrated 2.14 3.52 2.04 1.47, 1.83 1.06 4.51
1.81); final error 0.18 0.08 0.15 0.53 %, 0.09 0.32 0.11 1.96 %; the calibrated baseline
better on yaw on "all" 428 (0.45) and "dead" 428 (0.44). No calibration run was refused.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import sim
from scipy.integrate import cumulative_trapezoid
from scipy.stats import chi2

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent  # the checkout whose `fusion` is replayed
RUNS = Path.cwd() / "blackbox-runs"  # --out


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def read_csv_cols(path):
    with open(path, newline="") as fh:
        rd = csv.reader(fh)
        head = next(rd)
        rows = [[float(c) if c != "" else np.nan for c in r] for r in rd if r]
    arr = np.array(rows, dtype=float)
    return {h: arr[:, i] for i, h in enumerate(head)}


def read_robot(path):
    import tomllib

    d = tomllib.loads(Path(path).read_text())["chassis"]
    return d["wheel_distance"], d["speed_ratio"], d["encode_sampling_time"]


# ------------------------------------------------------------------ baselines (from files only)
def wheel_only(wheels, L, sr, period):
    t, l, r = wheels["t"], wheels["left"], wheels["right"]
    x = y = th = 0.0
    out = np.empty((len(t), 3))
    for k in range(len(t)):
        dl, dr = l[k] * sr, r[k] * sr
        ds, dth = (dl + dr) / 2, (dr - dl) / L
        x += ds * math.cos(th + dth / 2)
        y += ds * math.sin(th + dth / 2)
        th += dth
        out[k] = x, y, th
    return t, out


def find_stops(wheels, imu, min_len=1.0, gyro_std_max=0.15 * math.pi / 180 * 3, acc_std_max=0.15):
    """Stop windows: consecutive zero-tick frames lasting >= min_len s AND a quiet IMU
    (gz std and |accel| std small) over the window (its first 0.4 s and last 0.1 s cut)."""
    t, l, r = wheels["t"], wheels["left"], wheels["right"]
    zero = (l == 0) & (r == 0)
    wins = []
    k = 0
    n = len(t)
    while k < n:
        if not zero[k]:
            k += 1
            continue
        j = k
        while j + 1 < n and zero[j + 1]:
            j += 1
        t0, t1 = t[k] - 0.0, t[j]
        if t1 - t0 >= min_len:
            a, b = t0 + 0.4, t1 - 0.1
            sel = (imu["t"] >= a) & (imu["t"] <= b)
            if sel.sum() >= 20:
                gz = imu["gz"][sel]
                an = np.sqrt(imu["ax"][sel] ** 2 + imu["ay"][sel] ** 2 + imu["az"][sel] ** 2)
                quiet = gz.std() < gyro_std_max and an.std() < acc_std_max
                wins.append(
                    dict(
                        t0=float(t0),
                        t1=float(t1),
                        a=float(a),
                        b=float(b),
                        quiet=bool(quiet),
                        bias=float(gz.mean()),
                        gz_std=float(gz.std()),
                        acc_std=float(an.std()),
                    )
                )
        k = j + 1
    return wins


def gyro_at_stops(wheels, imu, sr, period, wins):
    it, gz = imu["t"], imu["gz"]
    quiet = [w for w in wins if w["quiet"]]
    bias_t = np.array([w["b"] for w in quiet])
    bias_v = np.array([w["bias"] for w in quiet])
    # bias in force at each sample: last window finished before it (causal); 0 before any
    k = np.searchsorted(bias_t, it, side="right") - 1
    b = np.where(k >= 0, bias_v[np.clip(k, 0, None)] if len(bias_v) else 0.0, 0.0)
    rate = gz - b
    hold = np.zeros(len(it), bool)
    for w in quiet:
        hold |= (it >= w["a"]) & (it <= w["t1"])
    rate[hold] = 0.0
    head = cumulative_trapezoid(rate, it, initial=0.0)
    t = wheels["t"]
    ds = (wheels["left"] + wheels["right"]) / 2 * sr
    hmid = np.interp(t - period / 2, it, head)
    x = np.cumsum(ds * np.cos(hmid))
    y = np.cumsum(ds * np.sin(hmid))
    th = np.interp(t, it, head)
    return (t, np.stack([x, y, th], 1)), (it, head, b)


# ------------------------------------------------------------------ metrics
def reference_yaw_rmse(sm):
    """Yaw RMSE (deg) of the heading integrated from the gyro about the true base vertical
    minus the true bias there: what an estimator that knew the mount tilt and the bias
    exactly would still get from the gyro's scale and cross-axis errors, noise and vibration
    (no absolute heading tells the scale). Evaluated at the IMU samples."""
    it, g, _ = sm["imu"]
    rate = g @ sm["imu_to_base"][2] - sm["bias_vert"]
    th = np.unwrap(sm["TH"])
    truth = np.interp(it, sm["t"], th)
    err = wrap(truth[0] + cumulative_trapezoid(rate, it, initial=0.0) - truth)
    return float(np.degrees(np.sqrt(np.mean(err**2))))


def path_length(truth):
    return float(np.sum(np.hypot(np.diff(truth["x"]), np.diff(truth["y"]))))


def errors(t, pose, truth, dist):
    """final position error % of distance; yaw RMSE deg (wrapped) over rows t."""
    tt = truth["t"]
    sel = (t >= tt[0]) & (t <= tt[-1])
    t, pose = t[sel], pose[sel]
    xt = np.interp(t, tt, truth["x"])
    yt = np.interp(t, tt, truth["y"])
    th_t = np.interp(t, tt, np.unwrap(truth["yaw"]))
    fe = math.hypot(pose[-1, 0] - xt[-1], pose[-1, 1] - yt[-1])
    dy = wrap(pose[:, 2] - th_t)
    return 100 * fe / dist, float(np.degrees(np.sqrt(np.mean(dy**2)))), dy


def fused_metrics(f, truth, dist, sm):
    keep = (f["t"] >= truth["t"][0]) & (f["t"] <= truth["t"][-1])
    f = {k: v[keep] for k, v in f.items()}
    t = f["t"]
    pose = np.stack([f["x"], f["y"], f["yaw"]], 1)
    fe, yr, dy = errors(t, pose, truth, dist)
    steps = np.hypot(np.diff(f["x"]), np.diff(f["y"]))
    ystep = np.abs(wrap(np.diff(f["yaw"])))
    tt = truth["t"]
    ex = f["x"] - np.interp(t, tt, truth["x"])
    ey = f["y"] - np.interp(t, tt, truth["y"])
    e = np.stack([ex, ey, dy], 1)
    P = np.empty((len(t), 3, 3))
    P[:, 0, 0], P[:, 1, 1], P[:, 2, 2] = f["var_x"], f["var_y"], f["var_yaw"]
    P[:, 0, 1] = P[:, 1, 0] = f["cov_xy"]
    P[:, 0, 2] = P[:, 2, 0] = f["cov_x_yaw"]
    P[:, 1, 2] = P[:, 2, 1] = f["cov_y_yaw"]
    ok = np.all(np.isfinite(P.reshape(len(t), -1)), 1) & (np.linalg.det(P) > 0)
    nees = np.full(len(t), np.nan)
    nees[ok] = np.einsum("ni,ni->n", e[ok], np.linalg.solve(P[ok], e[ok][:, :, None])[:, :, 0])
    lo, hi = chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)
    valid = nees[ok]
    nan_rows = int(np.sum(~np.isfinite(np.stack([f["x"], f["y"], f["yaw"]]))))
    # flags vs truth
    dtr = np.diff(t, append=t[-1])
    rest = np.interp(t, sm["t"], sm["at_rest"].astype(float)) > 0.5
    in_slip = np.zeros(len(t), bool)
    for a, b, *_ in sm["slips"]:
        in_slip |= (t >= a - 0.1) & (t <= b + 0.3)
    in_dead = np.zeros(len(t), bool)
    if sm["dead"]:
        in_dead = (t >= sm["dead"][0]) & (t <= sm["dead"][1] + 0.1)
    z = f["zupt"] == 1
    s = f["slip"] == 1
    ef = f["encoder_fault"] == 1
    bias_err = np.degrees(f["gyro_bias_z"] - np.interp(t, sm["imu"][0], sm["bias_vert"]))
    return dict(
        final_pct=fe,
        yaw_rmse=yr,
        max_step=float(np.nanmax(steps)),
        max_step_t=float(t[1:][np.nanargmax(steps)]),
        max_yaw_step_deg=float(np.degrees(np.nanmax(ystep))),
        nees_in95=float(np.mean((valid >= lo) & (valid <= hi))) if len(valid) else float("nan"),
        nees_above=float(np.mean(valid > hi)) if len(valid) else float("nan"),
        nees_below=float(np.mean(valid < lo)) if len(valid) else float("nan"),
        nees_median=float(np.median(valid)) if len(valid) else float("nan"),
        nees_max=float(np.max(valid)) if len(valid) else float("nan"),
        nan_rows=nan_rows,
        max_abs_yaw_err=float(np.degrees(np.max(np.abs(dy)))),
        t_max_abs_yaw_err=float(t[np.argmax(np.abs(dy))]),
        zupt_s_true_rest=float(np.sum(dtr[z & rest])),
        zupt_s_moving=float(np.sum(dtr[z & ~rest])),
        rest_s=float(np.sum(dtr[rest])),
        rest_s_no_zupt=float(np.sum(dtr[rest & ~z])),
        slip_s_in_true=float(np.sum(dtr[s & in_slip])),
        slip_s_outside=float(np.sum(dtr[s & ~in_slip])),
        slip_true_s=float(np.sum(dtr[in_slip])),
        slip_episodes_flagged=int(
            sum(np.any(s & (t >= a - 0.1) & (t <= b + 0.3)) for a, b, *_ in sm["slips"])
        ),
        encfault_s_in_dead=float(np.sum(dtr[ef & in_dead])),
        encfault_s_outside=float(np.sum(dtr[ef & ~in_dead])),
        bias_err_final_dps=float(bias_err[-1]),
        bias_err_rms_dps=float(np.sqrt(np.nanmean(bias_err[t > 30] ** 2))),
        bias_err_max_dps=float(np.nanmax(np.abs(bias_err))),
    )


def parse_replay(text):
    d = {}
    for key, pat in [
        ("zupts", r"ZUPTs (\d+)"),
        ("slip_frames", r"slip frames (\d+)"),
        ("enc_faults", r"encoder faults[^)]*\) (\d+)"),
        ("wheel_gaps", r"wheel frames missing \d+ \((\d+) gaps"),
        ("gaps_missing", r"wheel frames missing (\d+)"),
        ("untrusted_turn", r"not trusted (\d+)"),
        ("dropped", r"dropped (\d+)"),
        ("invalid", r"invalid (\d+)"),
        ("late", r"late inputs fused (\d+)"),
        ("wheel_scale_refits", r"wheel yaw-rate scale re-set from its fit (\d+)"),
    ]:
        m = re.search(pat, text)
        d[key] = int(m.group(1)) if m else None
    m = re.search(r"gyro bias ([-+0-9.e]+) deg/s", text)
    d["bias_dps"] = float(m.group(1)) if m else None
    m = re.search(
        r"fused:\s+final position error ([0-9.]+) % of distance, yaw RMSE ([0-9.]+)", text
    )
    d["tool_fused"] = (float(m.group(1)), float(m.group(2))) if m else None
    m = re.search(
        r"wheel only: final position error ([0-9.]+) % of distance, yaw RMSE ([0-9.]+)", text
    )
    d["tool_wheel"] = (float(m.group(1)), float(m.group(2))) if m else None
    d["warnings"] = [
        ln
        for ln in text.splitlines()
        if "warn" in ln.lower() or ("error" in ln.lower() and "position error" not in ln)
    ]
    return d


def _fusion(*args):
    """``python -m fusion ARGS`` on this checkout, as a user runs it."""
    return subprocess.run(
        [sys.executable, "-m", "fusion", *args],
        cwd=REPO,
        env={
            **os.environ,
            "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        },
        capture_output=True,
        text=True,
    )


def run_one(scenario, seed, calibrate=False):
    rd = RUNS / f"{scenario}_{seed}"
    t0 = time.time()
    cfg = sim.make_config(scenario, seed)
    sm = sim.simulate(cfg)
    sim.write_run(sm, rd)
    t_sim = time.time() - t0
    t0 = time.time()
    p = _fusion("replay", str(rd), "-o", str(rd / "fused.csv"))
    t_rep = time.time() - t0
    text = p.stdout + ("\n[stderr]\n" + p.stderr if p.stderr.strip() else "")
    (rd / "replay.txt").write_text(f"returncode {p.returncode}\n" + text)
    rep = parse_replay(text)
    rep["returncode"] = p.returncode
    L, sr, period = read_robot(rd / "robot.toml")
    truth = read_csv_cols(rd / "truth.csv")
    wheels = read_csv_cols(rd / "wheels.csv")
    imu = read_csv_cols(rd / "imu.csv")
    dist = path_length(truth)
    res = dict(
        scenario=scenario,
        seed=seed,
        dist=dist,
        replay=rep,
        t_sim=t_sim,
        t_replay=t_rep,
        cfg=dict(
            radius=cfg.radius,
            track=cfg.track,
            track_cfg=sm["track_cfg"],
            cpr=cfg.cpr,
            period=cfg.wheel_period,
            imu_rate=cfg.imu_rate,
            bias_z_dps=cfg.gyro_bias_dps[2],
            drift_dps=cfg.gyro_drift_dps,
            scale_z=cfg.gyro_scale_z,
            scale_eff=sm["gyro_scale_eff"],
        ),
        slips=sm["slips"],
        dead=sm["dead"],
        n_lost=len(sm["lost"]),
        reference_yaw_rmse=reference_yaw_rmse(sm),
        true_bias_vert_start_end=[
            float(np.degrees(sm["bias_vert"][0])),
            float(np.degrees(sm["bias_vert"][-1])),
        ],
    )
    wt, wpose = wheel_only(wheels, L, sr, period)
    res["wheel"] = dict(zip(("final_pct", "yaw_rmse"), errors(wt, wpose, truth, dist)[:2]))
    wins = find_stops(wheels, imu)
    (gt, gpose), (_it, _head, _b) = gyro_at_stops(wheels, imu, sr, period, wins)
    res["gyro_stops"] = dict(zip(("final_pct", "yaw_rmse"), errors(gt, gpose, truth, dist)[:2]))
    res["gyro_stops"]["n_windows"] = sum(w["quiet"] for w in wins)
    res["gyro_stops"]["n_rejected"] = sum(not w["quiet"] for w in wins)
    res["gyro_stops"]["first_bias_t"] = next((w["b"] for w in wins if w["quiet"]), None)
    if p.returncode == 0 and (rd / "fused.csv").exists():
        f = read_csv_cols(rd / "fused.csv")
        res["fused"] = fused_metrics(f, truth, dist, sm)
    else:
        res["fused"] = None
    if calibrate and scenario != "plain":  # plain's gyro has no scale error
        res["calibrated"] = calibrate_and_replay(rd, cfg, sm, truth, wheels, imu, dist, sr,
                                                 period)
    (rd / "metrics.json").write_text(json.dumps(res, indent=1))
    return res


# ------------------------------------------------------------------ gyro-scale calibration
CAL_TURNS = 10  # full turns in place each way, as README's "Calibrating the gyro's scale"
CAL_RATE = 1.0  # rad/s commanded
CAL_REST = 5.0  # s still on the mark before and after
CAL_MARK_STD = 0.5  # deg: how far from the mark the robot really stops (a careful user)


def calibration_run(cfg, gyro_matrix, turns, rng):
    """The README's calibration on the mission's robot and IMU (same scale, cross-axis matrix,
    tilt, biases, vibration; a fresh warm-up): rest, ``turns`` full turns in place, rest. The
    commanded rate is raised or lowered until the robot (whose firmware turns with
    the wrong wheel distance, on skidding tyres) ends within 0.01 deg of the mark plus a
    random mark error, as a user stops it by eye. Returns the simulation and the true angle
    turned minus ``turns`` * 360, deg."""
    target = turns * 2 * math.pi + math.radians(rng.normal(0.0, CAL_MARK_STD))
    turn_time = round(abs(target) / CAL_RATE, 3)  # the physics' 1 ms step
    rate = math.copysign(CAL_RATE, turns)  # then adjusted: continuous, unlike the time
    for _ in range(6):
        legs = [(CAL_REST, 0.0, 0.0, "stop"), (turn_time, 0.0, rate, "turn"),
                (CAL_REST + 1.0, 0.0, 0.0, "stop")]
        c = dataclasses.replace(
            cfg, scenario="calib_ccw" if turns > 0 else "calib_cw", legs=legs,
            duration=sum(leg[0] for leg in legs), gyro_matrix=gyro_matrix, slip_episodes=0,
            dead_encoder=0.0, start_moving=False)
        sm = sim.simulate(c)
        turned = float(np.unwrap(sm["TH"])[-1] - sm["TH"][0])
        if abs(turned - target) < math.radians(0.01):
            break
        rate *= target / turned
    else:
        raise RuntimeError(f"calibration turn of seed {cfg.seed} did not reach its mark "
                           f"({math.degrees(turned - target):+.3f} deg off)")
    return sm, math.degrees(turned - turns * 2 * math.pi)


def scale_about_accel_vertical(csm):
    """The gyro's true scale error about the vertical its accelerometer shows at the
    calibration's first rest (``g``, 1): what ``fusion calibrate gyro-scale`` measures, and the
    vertical the pipeline projects the gyro on. It differs from the scale about the base's
    true vertical (``gyro_scale_eff``) by about ``-tilt^2/2`` for the accelerometer bias's
    tilt of that vertical (this simulator: up to 3.3 deg, 0.17 %), which the pipeline's rate
    carries alike."""
    it, _, acc = csm["imu"]
    up = acc[it < CAL_REST - 1.0].mean(axis=0)
    up /= np.linalg.norm(up)
    unit_turn = csm["imu_to_base"].T @ np.array([0.0, 0.0, 1.0])  # in the IMU frame
    return float((csm["gyro_matrix"] @ unit_turn) @ up - 1.0)


def read_gyro_scale(toml_path):
    import tomllib

    ekf = tomllib.loads(Path(toml_path).read_text())["ekf"]
    return ekf["gyro_scale"], ekf["gyro_scale_std"]


def calibrate_and_replay(rd, cfg, sm, truth, wheels, imu, dist, sr, period):
    """Both calibration runs into rd/calib_ccw, rd/calib_cw; ``fusion calibrate gyro-scale``
    on them as a user would (``--write``); the mission replayed with that robot.toml, and the
    gyro-at-stops baseline with the same calibrated scale."""
    rng = np.random.default_rng(20_000 + cfg.seed)
    mark_err = {}
    for name, turns in (("calib_ccw", CAL_TURNS), ("calib_cw", -CAL_TURNS)):
        csm, mark_err[name] = calibration_run(cfg, sm["gyro_matrix"], turns, rng)
        sim.write_run(csm, rd / name)
    toml = rd / "robot-gyro.toml"
    p = _fusion("calibrate", "gyro-scale", str(rd / "calib_ccw"), str(rd / "calib_cw"),
                "--turns", str(CAL_TURNS), str(-CAL_TURNS), "--write", str(toml))
    (rd / "calibrate.txt").write_text(f"returncode {p.returncode}\n{p.stdout}{p.stderr}")
    out = dict(true_g=sm["gyro_scale_eff"] - 1.0, true_g_accel=scale_about_accel_vertical(csm),
               mark_error_deg=mark_err, returncode=p.returncode)
    if p.returncode != 0:
        return out
    g, g_std = read_gyro_scale(toml)
    out.update(g=g, g_std=g_std)
    p = _fusion("replay", str(rd), "--robot", str(toml), "-o", str(rd / "fused_cal.csv"))
    (rd / "replay_cal.txt").write_text(f"returncode {p.returncode}\n{p.stdout}{p.stderr}")
    out["replay_returncode"] = p.returncode
    if p.returncode == 0:
        out["fused"] = fused_metrics(read_csv_cols(rd / "fused_cal.csv"), truth, dist, sm)
    imu_cal = dict(imu, gz=imu["gz"] / (1.0 + g))
    (gt, gpose), _ = gyro_at_stops(wheels, imu_cal, sr, period, find_stops(wheels, imu_cal))
    out["gyro_stops"] = dict(zip(("final_pct", "yaw_rmse"), errors(gt, gpose, truth, dist)[:2]))
    return out


def calibrated_table(results):
    lines = [
        "| scen | seed | true g % about the base's vertical (the accel's) | calibrated g % (std) | "
        "fused fin% | fused yawRMSE | gyro@stops fin% | gyro@stops yawRMSE | "
        "uncalibrated fused yawRMSE | NEES in95 (above) |",
        "|" + "---|" * 10,
    ]
    for r in results:
        cal = r.get("calibrated")
        if not cal:
            continue
        f = cal.get("fused") or {}
        gs = cal.get("gyro_stops") or {}
        g = cal.get("g")
        lines.append(
            f"| {r['scenario']} | {r['seed']} | {100 * cal['true_g']:.3f} "
            f"({100 * cal['true_g_accel']:.3f}) | "
            + (f"{100 * g:.3f} ({100 * cal['g_std']:.3f})" if g is not None else "failed")
            + f" | {fmt(f.get('final_pct'))} | {fmt(f.get('yaw_rmse'))} | "
            f"{fmt(gs.get('final_pct'))} | {fmt(gs.get('yaw_rmse'))} | "
            f"{fmt((r['fused'] or {}).get('yaw_rmse'))} | {fmt(f.get('nees_in95'))} "
            f"({fmt(f.get('nees_above'))}) |"
        )
    return "\n".join(lines)


def fmt(v, n=2):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{n}f}"


def table(results):
    lines = [
        "| scen | seed | dist m | fused fin% | fused yawRMSE | wheel fin% | wheel yawRMSE | "
        "gyro@stops fin% | gyro@stops yawRMSE | reference yawRMSE | fused max step m | "
        "NEES in95 (above) | ZUPT/slip/encflt (tool) | slip eps flagged | bias err rms dps | "
        "rc/warn |",
        "|" + "---|" * 16,
    ]
    for r in results:
        f = r["fused"] or {}
        rp = r["replay"]
        lines.append(
            f"| {r['scenario']} | {r['seed']} | {r['dist']:.1f} | {fmt(f.get('final_pct'))} | "
            f"{fmt(f.get('yaw_rmse'))} | {fmt(r['wheel']['final_pct'])} | "
            f"{fmt(r['wheel']['yaw_rmse'])} | "
            f"{fmt(r['gyro_stops']['final_pct'])} | {fmt(r['gyro_stops']['yaw_rmse'])} | "
            f"{fmt(r.get('reference_yaw_rmse'))} | "
            f"{fmt(f.get('max_step'), 4)} | {fmt(f.get('nees_in95'))} "
            f"({fmt(f.get('nees_above'))}) | "
            f"{rp['zupts']}/{rp['slip_frames']}/{rp['enc_faults']} | "
            f"{f.get('slip_episodes_flagged', '-')}/{len(r['slips'])} | "
            f"{fmt(f.get('bias_err_rms_dps'), 3)} | "
            f"{rp['returncode']}/{len(rp['warnings'])} |"
        )
    return "\n".join(lines)


def main():
    global RUNS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=RUNS, help="folder of the runs and the table")
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--scenarios", default="plain,all,dead,moving")
    ap.add_argument("--calibrate", action="store_true",
                    help="also calibrate each run's gyro scale as README says (10 turns each "
                         "way back to a mark, `fusion calibrate gyro-scale`) and replay with "
                         "it: DIR/RESULTS_calibrated.md")
    a = ap.parse_args()
    RUNS = a.out
    RUNS.mkdir(parents=True, exist_ok=True)
    results = []
    for sc in a.scenarios.split(","):
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            r = run_one(sc, seed, calibrate=a.calibrate)
            results.append(r)
            f = r["fused"] or {}
            print(
                f"{sc} {seed}: fused {fmt(f.get('final_pct'))}% {fmt(f.get('yaw_rmse'))}deg | "
                f"wheel "
                f"{fmt(r['wheel']['final_pct'])}% {fmt(r['wheel']['yaw_rmse'])}deg | gyro@stops "
                f"{fmt(r['gyro_stops']['final_pct'])}% {fmt(r['gyro_stops']['yaw_rmse'])}deg | "
                f"reference {fmt(r['reference_yaw_rmse'])}deg | tool {r['replay']['tool_fused']} | "
                f"sim {r['t_sim']:.0f}s replay {r['t_replay']:.0f}s",
                flush=True,
            )
            cal = r.get("calibrated")
            if cal:
                fc, gc = cal.get("fused") or {}, cal.get("gyro_stops") or {}
                print(
                    f"  calibrated g {100 * cal.get('g', math.nan):.3f} % (true "
                    f"{100 * cal['true_g_accel']:.3f} % about the accelerometer's vertical, "
                    f"{100 * cal['true_g']:.3f} % about the base's): fused "
                    f"{fmt(fc.get('final_pct'))}% "
                    f"{fmt(fc.get('yaw_rmse'))}deg | gyro@stops {fmt(gc.get('final_pct'))}% "
                    f"{fmt(gc.get('yaw_rmse'))}deg",
                    flush=True,
                )
    # merge with all metrics.json present
    allres = [
        json.loads(p.read_text())
        for p in sorted(RUNS.glob("*/metrics.json"))
        if not p.parent.name.startswith("test")
    ]
    order = {"plain": 0, "all": 1, "dead": 2, "moving": 3}
    allres.sort(key=lambda r: (order.get(r["scenario"], 9), r["seed"]))
    (RUNS / "RESULTS_table.md").write_text(table(allres) + "\n")
    print(table(allres))
    if any(r.get("calibrated") for r in allres):
        (RUNS / "RESULTS_calibrated.md").write_text(calibrated_table(allres) + "\n")
        print(calibrated_table(allres))


if __name__ == "__main__":
    main()
