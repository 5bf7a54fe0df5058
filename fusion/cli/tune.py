"""``fusion tune``: choose a robot's parameters from logs with ground truth, by k-fold
cross-validation across the logs (argument parsing and printing; the job is
:mod:`fusion.jobs.tune`).

Prints, per fold, the cross-validated score (the held-out logs with the parameters chosen
without them), the in-sample score (the training logs) and the defaults' score (the held-out
logs with the base robot.toml); then the search on every log, whose values it prints as a
robot.toml section and, with ``-o``, writes as a complete robot.toml.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from fusion.cli import CommandError

__all__ = ["register"]

_TARGETS = ("odometry", "ekf", "attitude")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "tune",
        help="choose robot.toml parameters from logs with truth (k-fold cross-validation)",
        description=(
            "Tune a robot's parameters on runs with ground truth, by k-fold "
            "cross-validation across the runs. Targets: odometry ([chassis] wheel_distance "
            "and the wheel radius ratio, scored by the wheel-only yaw RMSE) and ekf ([ekf] "
            "gyro_std, bias_psd, scale_std, scored by the fused position RMSE) on log "
            "directories with truth.csv; attitude (Keel's accel_time_constant, motion_bias_sigma, "
            "rest_bias_sigma, bias_drift, scored by the 6-axis inclination RMSE) on BROAD "
            "trials (.mat, .h5). Prints the cross-validated, in-sample and defaults' scores "
            "per fold, and the chosen values as a robot.toml section."),
    )
    p.add_argument("target", choices=_TARGETS, help="what to tune")
    p.add_argument("logs", type=Path, nargs="+",
                   help="log directories with truth.csv (BROAD trial files for attitude), "
                        "or folders of them")
    p.add_argument("--robot", type=Path,
                   help="base robot.toml, used for every log (default: the first log's; "
                        "attitude: its [attitude] Keel settings, default Keel's defaults)")
    p.add_argument("-k", "--folds", type=int, default=None,
                   help="folds of the cross-validation (default: 5, or the number of logs "
                        "if fewer: leave-one-out)")
    p.add_argument("--budget", type=int, default=60,
                   help="evaluations per search (one: the mean score over the training "
                        "logs; default 60)")
    p.add_argument("-o", "--output", type=Path,
                   help="write the base robot.toml with the chosen values here (attitude: "
                        "needs --robot)")
    p.add_argument("-j", "--jobs", type=int, default=None,
                   help="worker processes (one fold each; default 1)")
    p.add_argument("--cluster", nargs="?", const="", default=None, metavar="SPEC",
                   help="run the folds on Dask: local[:N], tcp://HOST:8786, or alone for "
                        "DASK_SCHEDULER_ADDRESS (the 'cluster' extra); not with --jobs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fusion.io.robot_toml import read_robot_toml, write_robot_toml
    from fusion.jobs import tune as job

    if args.cluster is not None and args.jobs is not None:
        raise CommandError("--cluster and --jobs exclude each other")
    jobs = 1 if args.jobs is None else args.jobs
    if jobs < 1:
        raise CommandError(f"--jobs must be >= 1, got {jobs}")
    target = job.TARGETS[args.target]
    if not target.needs_robot and args.output is not None and args.robot is None:
        raise CommandError("-o for the attitude target needs --robot robot.toml: the robot "
                           "whose [attitude] table gets the chosen values")
    if args.output is not None:
        from fusion.io.atomic import check_target

        check_target(args.output)
    paths = job.find_tuning_runs(args.target, args.logs)
    robot = robot_path = None
    if target.needs_robot or args.robot is not None:
        robot_path = args.robot or Path(paths[0]) / "robot.toml"
        robot = read_robot_toml(robot_path)
    folds = args.folds if args.folds is not None else min(5, len(paths))
    base = f"base {robot_path}" if robot_path else "from Keel's defaults"
    print(f"fusion tune {args.target}: {len(paths)} runs, {folds} folds, budget "
          f"{args.budget} evaluations per search; {base}")
    if args.cluster is None:
        print("folds run " + (f"on {jobs} worker processes" if jobs > 1 else "in this process"))
    print(f"score: {target.score_name} (lower is better), mean over runs")
    names = [p.name for p in target.parameters]

    def on_fold(i: int, r) -> None:
        if i < 0:
            return
        chosen = ", ".join(f"{n} {r.values[n]:.6g}" for n in names)
        print(f"fold {i + 1}: CV {_mean(r.test_scores):.4f}  in-sample {r.train_score:.4f}  "
              f"defaults {_mean(r.default_test_scores):.4f}  ({len(r.test_scores)} held out; "
              f"{r.evaluations} evaluations; {chosen})", flush=True)

    def go(client=None):
        return job.tune(args.target, paths, robot, folds=folds, budget=args.budget,
                        jobs=jobs, client=client, on_fold=on_fold)

    if args.cluster is None:
        result = go()
    else:
        from fusion.jobs import cluster as dask_jobs

        spec = dask_jobs.parse_cluster(args.cluster)
        print(f"folds run on the {spec.describe()}")
        with dask_jobs.dask_client(spec) as client:
            result = go(client)
    final = result.final
    print(f"cross-validated {result.cv_score:.4f}, defaults {result.default_score:.4f} "
          f"(every run scored by values chosen without it)")
    print(f"all runs: in-sample {final.train_score:.4f} (defaults "
          f"{final.default_train_score:.4f}); {final.evaluations} evaluations")
    print("chosen (on every run):")
    print(job.tuned_section(result))
    if args.output is not None and result.robot is not None:
        write_robot_toml(args.output, result.robot)
        print(f"wrote {args.output} ({robot_path} with the chosen values)")
    return 0


def _mean(values) -> float:
    return sum(values) / len(values) if values else math.nan
