"""A fifth, independent check of `fusion replay` (issue 11): generate, replay and score sim5 runs.

`sim.py` was written on 2026-12-07 by a helper shown only README.md, datasets/LOGDIR.md and
`fusion replay --help` (not the estimator, the other simulators, benchmarks or tests): a 1 kHz
rigid body with tyre slip and sideslip, a castor, suspension pitch and roll, an IMU on a lever
arm with an unknown tilt, an MPU6050 with warm-up and temperature drift, scale and cross-axis
errors, vibration, a drifting chip clock read in FIFO bursts, encoders with backlash, lost and
late frames and EMI glitch frames (sim.py's docstring has the magnitudes). Each run is replayed
as a user would (`python -m fusion replay LOGDIR -o fused.csv`, a subprocess on this
checkout), and scored with this folder's own code (common.py: CSV reading, wheel-only and
gyro-at-stops baselines, a reference: the gyro with the TRUE bias removed, integrated about
the true vertical; what the unobservable scale error leaves).

usage: python benchmarks/sim5/run_all.py [--out DIR] [--seeds 1-8]
           [--scenarios all,dead,moving,glitch]      -> DIR/runs/<sc>_s<seed>/
       python benchmarks/sim5/run_all.py --out DIR --table   -> DIR/results.md
(default DIR ./sim5-runs; a run takes 10-20 s, 32 runs about 8 min.)

Measured at 22bf279 (2026-12-07, seeds 1-8, nothing of the library chosen on them before;
means, final error % / yaw RMSE deg):

| scenario | fused | reference yaw | gyro at stops | wheel only | fused within 0.5 deg of ref |
|---|---|---|---|---|---|
| all | 1.15 / 4.29 | 3.89 | 3.77 / 9.78 | 5.49 / 17.39 | 5/8 (worst +2.77, s7) |
| dead | 1.10 / 4.31 | 3.89 | 4.27 / 9.91 | 16.50 / 49.44 | 5/8 (+2.58, s7) |
| moving | 2.14 / 5.45 | 4.22 | 36.5 / 93.0 | 3.59 / 11.35 | 4/8 (+8.83, s7) |
| glitch | 1.22 / 4.44 | 3.87 | 3.06 / 9.26 | 6.05 / 17.29 | 5/8 (+2.86, s7) |

Fused beat both baselines on both figures on 7/8 all, 7/8 dead, 4/8 moving, 5/8 glitch runs;
issue 11's 1.5 deg held on 1 of 32 (the reference itself is above 1.5 deg on 28 of 32: the
gyro's 0.3-1.5 % scale error, which nothing here makes observable). No NaN, no step above 0.56
of 3 v_max dt. What it found and what changed (the baselines here refuse frames faster than
2 x wheel_speed_max; the replay took them):
- EMI glitch frames of 10-46 m/s passed the EKF's 50 m/s bound (one was fused) and the
  whole-log checks took every glitch at face value: false speed_scale (4 runs) and
  heading_divergence (3 glitch runs) warnings, wheel-only figures of 51-1630 % printed.
  Now left out with a note (fusion/jobs/wheel_glitches.py): exactly the 3-30 glitches per
  run are marked, nothing else; the fused figures did not move (within 0.03 % / 0.01 deg).
- An 8 s dead feed during a spin read as heading_divergence ("should not be trusted") on 5 of
  8 dead runs, and nothing else said when or how long. Now said with its start and length
  (fusion/jobs/dead_feed.py) and its turn left out of the heading check (EKF fault_turn).
- Re-run after both (the same 32 runs, so in-sample for these two changes): fused means
  within 0.01 of the table (all 1.16 / 4.29, dead 1.10 / 4.31, moving 2.15 / 5.45, glitch
  1.23 / 4.43), beating both baselines on 6/8 glitch runs; replays ending in "should not be
  trusted" 12 -> 0 of 32 (8 heading_divergence and 4 speed_scale warnings before, none after).
- Not changed: seed 7 (+2.6-2.9 deg above the reference at rest starts, +8.8 on the moving
  start) has a warm-up drift of 0.37 deg/s with a 60 s time constant; the EKF's bias walk
  (bias_psd 1e-8 (rad/s)^2/s) follows 0.04 deg/s a minute, which the bundled real MPU6050's
  100 s at rest (datasets/mpu6050_raw/imu_static_test.csv: -0.511 -> -0.495 deg/s) fits and
  this warm-up does not. Widening it for one simulator's warm-up would be tuning on it.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import sim
from common import (
    gyro_at_stops_yaw,
    load_log,
    read_csv,
    sane_frames,
    score_track,
    truth_interp,
    wheel_dr,
)

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))  # the checkout whose `fusion` is replayed
ROOT = os.path.join(os.getcwd(), "sim5-runs")  # --out
ENV = dict(os.environ, PYTHONPATH=REPO)


def one(sc, seed):
    rd = os.path.join(ROOT, "runs", f"{sc}_s{seed}")
    logdir = os.path.join(rd, "log")
    if not os.path.exists(os.path.join(rd, "sim_meta.json")):
        sim.write_run(rd, sc, seed, 300.0)
    meta = json.load(open(os.path.join(rd, "sim_meta.json")))
    fused = os.path.join(rd, "fused.csv")
    if not os.path.exists(fused):
        t0 = time.time()
        p = subprocess.run(
            [sys.executable, "-m", "fusion", "replay", logdir, "-o", fused, "--no-progress"],
            cwd=ROOT,
            env=ENV,
            capture_output=True,
            text=True,
        )
        open(os.path.join(rd, "replay.txt"), "w").write(
            f"$ python -m fusion replay {logdir} -o {fused} --no-progress\n# exit {p.returncode}, "
            f"{time.time() - t0:.0f} s\n--- stdout\n{p.stdout}--- stderr\n{p.stderr}"
        )
    out = open(os.path.join(rd, "replay.txt")).read()
    robot, imu, wh, tr = load_log(logdir)
    aux = np.load(os.path.join(rd, "sim_aux.npz"))
    dist = meta["distance_m"]
    res = dict(sc=sc, seed=seed, dist=dist)
    if os.path.exists(fused):
        f = read_csv(fused)
        nan = int(sum(np.isnan(f[k]).sum() for k in ("t", "x", "y", "yaw")))
        s = score_track(tr, f["t"], f["x"], f["y"], f["yaw"], dist)
        step = np.hypot(np.diff(f["x"]), np.diff(f["y"]))
        dt = np.diff(f["t"])
        bound = 3 * robot["chassis"]["cmd_vel_linear_max"] * dt
        ratio = step / np.maximum(bound, 1e-9)
        i = int(np.argmax(ratio))
        res["fused"] = s
        res["fused"].update(
            nan=nan,
            rows=len(f["t"]),
            max_step_m=float(step.max()),
            max_step_ratio=float(ratio[i]),
            max_step_t=float(f["t"][i + 1]),
            steps_over=int((ratio > 1).sum()),
        )
        # bias estimate against truth (vertical-projected true bias) at the end
        bz = np.interp(f["t"], aux["imu_t"], aux["bias_z_true"])
        res["fused"]["bias_err_dps_rms"] = float(
            np.degrees(np.sqrt(np.mean((f["gyro_bias_z"] - bz) ** 2)))
        )
        # yaw error during the dead window
        if meta["encoders"]["dead"]:
            a, b = meta["encoders"]["dead"]
            m = (f["t"] >= a) & (f["t"] <= b + 2)
            tx, ty, tyaw = truth_interp(tr, f["t"][m])
            res["fused"]["dead_pos_err_growth_m"] = float(
                np.hypot(f["x"][m][-1] - tx[-1], f["y"][m][-1] - ty[-1])
                - np.hypot(f["x"][m][0] - tx[0], f["y"][m][0] - ty[0])
            )
            res["fused"]["dead_dist_fused_m"] = float(
                np.sum(np.hypot(np.diff(f["x"][m]), np.diff(f["y"][m])))
            )
            res["fused"]["dead_dist_true_m"] = float(np.sum(np.hypot(np.diff(tx), np.diff(ty))))
    else:
        res["fused"] = None
    t, x, y, yaw = wheel_dr(robot, wh)
    res["wheel"] = score_track(tr, t, x, y, yaw, dist)
    ti, yg, stops = gyro_at_stops_yaw(robot, imu, wh)
    res["n_stops"] = len(stops)
    res["first_stop"] = float(stops[0][0] - meta["T_OFFSET"]) if stops else None
    t, x, y, yaw = wheel_dr(robot, wh, lambda q: np.interp(q, ti, yg))
    res["gyro_stops"] = score_track(tr, t, x, y, yaw, dist)
    rr, tt = aux["rate_ref"], aux["imu_t"]
    cont = os.path.join(rd, "sim_aux_cont.npz")
    if os.path.exists(cont):  # every chip sample (the host's FIFO losses put back)
        c = np.load(cont)
        rr, tt = c["rate_ref"], c["t"]
    yr = np.concatenate([[0.0], np.cumsum(0.5 * (rr[1:] + rr[:-1]) * np.diff(tt))])
    res["reference_yaw_rmse"] = score_track(tr, tt, np.zeros_like(tt), np.zeros_like(tt), yr, dist)[
        "yaw_rmse"
    ]
    res["glitches"] = len(meta["encoders"]["glitches"])
    res["insane_frames"] = int((~sane_frames(robot, wh)).sum())
    res["replay_lines"] = [
        l
        for l in out.splitlines()
        if (
            "warning" in l
            or "note" in l
            or "fused:" in l
            or "wheel only" in l
            or "invalid" in l
            or "exit" in l
        )
    ]
    json.dump(res, open(os.path.join(rd, "score.json"), "w"), indent=1)
    return res


def table():
    import glob

    rows = [
        json.load(open(p))
        for p in sorted(glob.glob(os.path.join(ROOT, "runs", "*_s*", "score.json")))
    ]
    out = []
    for sc in ["all", "dead", "moving", "glitch"]:
        rs = sorted([r for r in rows if r["sc"] == sc], key=lambda r: r["seed"])
        if not rs:
            continue
        out.append(f"\n### {sc}\n")
        out.append(
            "| seed | dist m | fused final % | fused yaw RMSE | ref yaw RMSE | fused-ref | gyro@stops final % / yaw | wheel-only final % / yaw | max step / bound | NaN |"
        )
        out.append("|---|---|---|---|---|---|---|---|---|---|")
        cnt = dict(fin=0, yaw=0, beat=0, all=0, n=0)
        for r in rs:
            f = r["fused"]
            if f is None:
                out.append(f"| {r['seed']} | {r['dist']:.0f} | FAILED | | | | | | | |")
                cnt["n"] += 1
                continue
            g, w = r["gyro_stops"], r["wheel"]
            ok_f = f["final_pct"] <= 0.5
            ok_y = f["yaw_rmse"] <= 1.5
            beat = f["final_pct"] < min(g["final_pct"], w["final_pct"]) and f["yaw_rmse"] < min(
                g["yaw_rmse"], w["yaw_rmse"]
            )
            cnt["fin"] += ok_f
            cnt["yaw"] += ok_y
            cnt["beat"] += beat
            cnt["all"] += ok_f and ok_y and beat
            cnt["n"] += 1
            out.append(
                f"| {r['seed']} | {r['dist']:.0f} | {f['final_pct']:.2f} | {f['yaw_rmse']:.2f} | {r['reference_yaw_rmse']:.2f} | "
                f"{f['yaw_rmse'] - r['reference_yaw_rmse']:+.2f} | {g['final_pct']:.2f} / {g['yaw_rmse']:.2f} | "
                f"{w['final_pct']:.2f} / {w['yaw_rmse']:.2f} | {f['max_step_ratio']:.2f} | {f['nan']} |"
            )
        ff = [r["fused"] for r in rs if r["fused"]]
        out.append(
            f"\nmeans: fused {np.mean([f['final_pct'] for f in ff]):.2f} % / {np.mean([f['yaw_rmse'] for f in ff]):.2f} deg, "
            f"reference {np.mean([r['reference_yaw_rmse'] for r in rs]):.2f} deg, "
            f"gyro@stops {np.mean([r['gyro_stops']['final_pct'] for r in rs]):.2f} % / {np.mean([r['gyro_stops']['yaw_rmse'] for r in rs]):.2f} deg, "
            f"wheel-only {np.mean([r['wheel']['final_pct'] for r in rs]):.2f} % / {np.mean([r['wheel']['yaw_rmse'] for r in rs]):.2f} deg"
        )
        out.append(
            f"issue 11 counts: final <= 0.5 %: {cnt['fin']}/{cnt['n']}; yaw RMSE <= 1.5 deg: {cnt['yaw']}/{cnt['n']}; "
            f"beats both baselines on both: {cnt['beat']}/{cnt['n']}; all three: {cnt['all']}/{cnt['n']}"
        )
    txt = "\n".join(out)
    open(os.path.join(ROOT, "results.md"), "w").write(txt)
    print(txt)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=ROOT, help="folder of the runs (default ./sim5-runs)")
    ap.add_argument("--seeds", default="1-8")
    ap.add_argument("--scenarios", default="all,dead,moving,glitch")
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--rescore", action="store_true")
    a = ap.parse_args()
    ROOT = os.path.abspath(a.out)
    os.makedirs(ROOT, exist_ok=True)
    if a.rescore:
        import glob

        for p in sorted(glob.glob(os.path.join(ROOT, "runs", "*_s*"))):
            sc, sd = os.path.basename(p).rsplit("_s", 1)
            one(sc, int(sd))
        table()
        sys.exit()
    if a.table:
        table()
        sys.exit()
    lo, hi = map(int, a.seeds.split("-"))
    for seed in range(lo, hi + 1):
        for sc in a.scenarios.split(","):
            t0 = time.time()
            r = one(sc, seed)
            f = r["fused"]
            print(
                f"{sc} s{seed}: fused {f['final_pct']:.2f} % {f['yaw_rmse']:.2f} deg | ref {r['reference_yaw_rmse']:.2f} | "
                f"stops {r['gyro_stops']['final_pct']:.2f} % {r['gyro_stops']['yaw_rmse']:.2f} | wheel {r['wheel']['final_pct']:.2f} % "
                f"{r['wheel']['yaw_rmse']:.2f} | step {f['max_step_ratio']:.2f} ({time.time() - t0:.0f} s)",
                flush=True,
            )
