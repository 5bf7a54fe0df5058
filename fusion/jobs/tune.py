"""Choose a robot's parameters from logs with ground truth, by k-fold cross-validation.

``fusion tune TARGET LOGS/``: every log directory of ``LOGS/`` with a ``truth.csv``
(``datasets/LOGDIR.md``; UMBmark squares from ``fusion synth --scenario square`` are such logs
too) is scored with candidate parameters; :data:`TARGETS` says which parameters and which
score:

- ``odometry``: ``[chassis] wheel_distance`` (m), scored by the yaw RMSE (deg) of the
  wheel-only dead reckoning against the truth: the separation sets how far the wheels' yaw
  drifts on every turn.
- ``ekf``: ``[ekf] gyro_std``, ``bias_psd``, ``scale_std``, scored by the position RMSE (m) of
  the fused odometry (the replay's pipeline, :func:`fusion.jobs.replay.fuse_streams`).

The logs are split into k folds (:func:`fusion.evaluation.crossval.kfold_splits`). For each
fold, parameters are searched on the other folds' logs (in-sample score) and then scored on
the held-out fold (the cross-validated score, beside the defaults' score on the same logs).
Finally the parameters are searched once more on every log: those are the ones to use, and
the CV score is the honest estimate of what they give on logs they were not tuned on.

The search runs in log space between bounds relative to the base robot's values, with
:func:`scipy.optimize.minimize_scalar` (one parameter) or Nelder-Mead (several), and stops
after ``budget`` evaluations (one evaluation: the mean score over the training logs); the
defaults are always the first evaluation, so a search never ends worse, in-sample, than them.
Each fold (and the final search) is one coarse task on the engine
(:func:`fusion.jobs.engine.run_tasks`: this process, ``--jobs`` processes or a Dask cluster);
workers read the logs by path.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.evaluation.crossval import kfold_splits
from fusion.evaluation.trajectory import position_rmse, yaw_rmse
from fusion.io.logdir import LogDir, read_logdir
from fusion.jobs.engine import run_tasks
from fusion.jobs.replay import Streams, find_log_dirs, fuse_streams
from fusion.planar.odometry import WheelOdometry
from fusion.planar.robot import RobotConfig

__all__ = [
    "TARGETS",
    "FoldResult",
    "FoldTask",
    "Parameter",
    "Target",
    "TuneResult",
    "apply_parameters",
    "find_tuning_logs",
    "load_tuning_log",
    "run_fold",
    "search",
    "tune",
    "tuned_section",
]


@dataclass(frozen=True)
class Parameter:
    """A tuned value: ``[table] name`` of robot.toml, searched in log space between
    ``low`` and ``high`` times the base robot's value."""

    table: str
    name: str
    low: float
    high: float

    def base_value(self, robot: RobotConfig) -> float:
        return float(getattr(_table(robot, self.table), self.name))


def _table(robot: RobotConfig, table: str) -> Any:
    if table == "chassis":
        return robot.chassis
    if table == "ekf":
        return robot.ekf
    raise ValueError(f"unknown robot.toml table {table!r}")


@dataclass(frozen=True)
class Target:
    """What ``fusion tune TARGET`` tunes, and the score (lower is better) it minimises."""

    name: str
    parameters: tuple[Parameter, ...]
    score_name: str
    score: Callable[[RobotConfig, LogDir], float]


def _truth_at(log: LogDir, t: NDArray[np.float64]) -> NDArray[np.float64]:
    yaw = np.unwrap(log.truth[:, 2])
    return np.column_stack([np.interp(t, log.truth_t, log.truth[:, 0]),
                            np.interp(t, log.truth_t, log.truth[:, 1]),
                            np.interp(t, log.truth_t, yaw)])


def _inside(log: LogDir, t: NDArray[np.float64]) -> NDArray[np.bool_]:
    return (t >= log.truth_t[0]) & (t <= log.truth_t[-1])


def odometry_yaw_rmse(robot: RobotConfig, log: LogDir) -> float:
    """Yaw RMSE (deg) of the wheel-only dead reckoning with ``robot``'s chassis against the
    truth, at the wheel frames inside the truth's span."""
    poses = WheelOdometry(robot.chassis).update_batch(log.ticks[:, 0], log.ticks[:, 1])
    inside = _inside(log, log.wheel_t)
    truth = _truth_at(log, log.wheel_t[inside])
    return math.degrees(yaw_rmse(poses[inside, 2], truth[:, 2]))


def fused_position_rmse(robot: RobotConfig, log: LogDir) -> float:
    """Position RMSE (m) of the fused odometry (the replay's pipeline, no output file)
    against the truth, at the fused rows inside the truth's span."""
    streams = Streams(log.imu_t, log.gyro, log.accel, log.wheel_t, log.ticks)
    table, _, _ = fuse_streams(robot, streams, None)
    t = table[:, 0]
    inside = _inside(log, t)
    truth = _truth_at(log, t[inside])
    return position_rmse(table[inside, 1:3], truth[:, :2])


#: The targets of ``fusion tune``.
TARGETS: dict[str, Target] = {
    "odometry": Target("odometry", (Parameter("chassis", "wheel_distance", 0.8, 1.25),),
                       "wheel-only yaw RMSE, deg", odometry_yaw_rmse),
    "ekf": Target("ekf", (Parameter("ekf", "gyro_std", 0.1, 10.0),
                          Parameter("ekf", "bias_psd", 0.01, 100.0),
                          Parameter("ekf", "scale_std", 0.1, 10.0)),
                  "fused position RMSE, m", fused_position_rmse),
}


def apply_parameters(robot: RobotConfig, values: dict[str, float], target: Target
                     ) -> RobotConfig:
    """``robot`` with ``values`` (by parameter name) in their tables."""
    changes: dict[str, dict[str, float]] = {}
    for p in target.parameters:
        if p.name in values:
            changes.setdefault(p.table, {})[p.name] = float(values[p.name])
    out = robot
    if "chassis" in changes:
        out = dataclasses.replace(out, chassis=dataclasses.replace(out.chassis,
                                                                   **changes["chassis"]))
    if "ekf" in changes:
        out = dataclasses.replace(out, ekf=dataclasses.replace(out.ekf, **changes["ekf"]))
    return out


def load_tuning_log(path: str | Path, target: Target) -> LogDir:
    """A log directory with what ``target`` needs (truth; wheels; IMU for ``ekf``).

    Raises:
        ValueError: naming the log and the missing file.
    """
    log = read_logdir(path, imu_frame="imu")
    if log.truth_t is None or log.truth_t.size < 2:
        raise ValueError(f"{path}: no truth.csv (tuning needs ground truth)")
    if log.wheel_t is None or log.wheel_t.size == 0:
        raise ValueError(f"{path}: wheels.csv is missing or empty")
    if target.name == "ekf" and (log.imu_t is None or log.imu_t.size == 0):
        raise ValueError(f"{path}: imu.csv is missing or empty (the ekf target fuses the gyro)")
    return log


class _BudgetSpent(Exception):
    pass


def search(objective: Callable[[NDArray[np.float64]], float], bounds: Sequence[tuple[float,
           float]], budget: int) -> tuple[NDArray[np.float64], float, int]:
    """Minimise ``objective(u)`` over the box ``bounds`` (containing 0: the defaults) within
    ``budget`` evaluations; returns ``(u, value, evaluations)`` of the best point seen.

    ``u = 0`` is evaluated first; then :func:`scipy.optimize.minimize_scalar` (bounded Brent)
    for one dimension, Nelder-Mead (with a simplex spanning a fifth of each bound) for more.
    """
    from scipy import optimize

    if budget < 1:
        raise ValueError(f"budget must be >= 1 evaluation, got {budget}")
    lo = np.array([b[0] for b in bounds], dtype=float)
    hi = np.array([b[1] for b in bounds], dtype=float)
    best: list[Any] = [None, math.inf]
    count = [0]

    def f(u) -> float:
        if count[0] >= budget:
            raise _BudgetSpent
        u = np.clip(np.atleast_1d(np.asarray(u, dtype=float)), lo, hi)
        count[0] += 1
        value = float(objective(u))
        if not math.isfinite(value):
            value = math.inf
        if value < best[1]:
            best[0], best[1] = u.copy(), value
        return value

    try:
        f(np.zeros(lo.size))
        if lo.size == 1:
            optimize.minimize_scalar(lambda u: f([u]), bounds=(lo[0], hi[0]), method="bounded",
                                     options={"maxiter": budget, "xatol": 1e-5})
        else:
            step = 0.2 * (hi - lo)
            simplex = np.vstack([np.zeros(lo.size), np.diag(step)])
            optimize.minimize(f, np.zeros(lo.size), method="Nelder-Mead",
                              bounds=list(zip(lo, hi)),
                              options={"initial_simplex": simplex, "maxfev": budget,
                                       "xatol": 1e-4, "fatol": 1e-9})
    except _BudgetSpent:
        pass
    return best[0], best[1], count[0]


@dataclass(frozen=True)
class FoldTask:
    """One search: tune ``target`` on ``train`` (log paths) with ``budget`` evaluations,
    then score the result and the base robot's defaults on ``test``."""

    target: str
    robot: RobotConfig
    train: tuple[str, ...]
    test: tuple[str, ...]
    budget: int


@dataclass
class FoldResult:
    """What :func:`run_fold` found: the chosen values (by parameter name), the mean score on
    the training logs (in-sample), per-log scores of the chosen values and of the defaults
    on the test logs, the defaults' mean on the training logs, and evaluations used."""

    values: dict[str, float]
    train_score: float
    default_train_score: float
    test_scores: list[float] = field(default_factory=list)
    default_test_scores: list[float] = field(default_factory=list)
    evaluations: int = 0


def run_fold(task: FoldTask) -> FoldResult:
    """Search on the training logs, score on the test logs (a worker runs this)."""
    target = TARGETS[task.target]
    train = [load_tuning_log(p, target) for p in task.train]
    test = [load_tuning_log(p, target) for p in task.test]
    base = {p.name: p.base_value(task.robot) for p in target.parameters}

    def values_of(u) -> dict[str, float]:
        return {p.name: base[p.name] * math.exp(x) for p, x in zip(target.parameters, u)}

    def mean_score(u) -> float:
        robot = apply_parameters(task.robot, values_of(u), target)
        return float(np.mean([target.score(robot, log) for log in train]))

    bounds = [(math.log(p.low), math.log(p.high)) for p in target.parameters]
    u, value, n = search(mean_score, bounds, task.budget)
    values = values_of(u)
    default_train = mean_score(np.zeros(len(bounds)))
    tuned = apply_parameters(task.robot, values, target)
    return FoldResult(values, value, default_train,
                      [target.score(tuned, log) for log in test],
                      [target.score(task.robot, log) for log in test], n)


@dataclass
class TuneResult:
    """``fusion tune``'s outcome.

    Attributes:
        target: the :class:`Target`.
        logs: the log paths, in fold order of ``folds``.
        folds: per fold, ``(test log indices, FoldResult)``.
        final: the search on every log (its values are the ones to use; its train score is
            in-sample).
        robot: the base robot with the final values.
    """

    target: Target
    logs: list[str]
    folds: list[tuple[list[int], FoldResult]]
    final: FoldResult
    robot: RobotConfig

    @property
    def cv_score(self) -> float:
        """Mean over every log of its score with the values chosen without it."""
        return float(np.mean([s for _, f in self.folds for s in f.test_scores]))

    @property
    def default_score(self) -> float:
        """Mean over every log of the defaults' score."""
        return float(np.mean([s for _, f in self.folds for s in f.default_test_scores]))


def tune(target: str, logs: Sequence[str | Path], robot: RobotConfig, *, folds: int = 5,
         budget: int = 30, jobs: int = 1, client: Any = None,
         on_fold: Callable[[int, FoldResult], None] | None = None) -> TuneResult:
    """Tune ``target``'s parameters of ``robot`` on ``logs`` by ``folds``-fold CV.

    ``logs``: log directories, or one folder of them. Each fold and the final search on all
    logs is one task on the engine (``jobs`` processes, or the Dask ``client``).
    ``on_fold(i, result)`` is called as each fold ends (the final search: ``i = -1``).

    Raises:
        ValueError: unknown target, fewer than 2 logs, a bad ``folds`` or ``budget``, or a
            log without what the target needs (named); a failed fold names its logs.
    """
    if target not in TARGETS:
        raise ValueError(f"unknown tuning target {target!r}; known: {', '.join(TARGETS)}")
    paths = find_tuning_logs(logs)
    if len(paths) < 2:
        raise ValueError(f"cross-validation needs at least 2 logs with truth, got {len(paths)}")
    if budget < 1:
        raise ValueError(f"--budget must be >= 1 evaluation, got {budget}")
    for p in paths:  # refuse a log without truth before any search starts
        if not (Path(p) / "truth.csv").is_file():
            raise ValueError(f"{p}: no truth.csv (tuning needs ground truth)")
    splits = kfold_splits(len(paths), folds)
    tasks = [FoldTask(target, robot, tuple(paths[i] for i in train),
                      tuple(paths[i] for i in test), budget) for train, test in splits]
    tasks.append(FoldTask(target, robot, tuple(paths), (), budget))
    results: dict[int, FoldResult] = {}
    for i, ok, value in run_tasks(run_fold, tasks, jobs=jobs, client=client):
        if not ok:
            what = "the search on all logs" if i == len(splits) else f"fold {i + 1}"
            raise ValueError(f"{what} failed: {value}")
        results[i] = value
        if on_fold is not None:
            on_fold(-1 if i == len(splits) else i, value)
    final = results[len(splits)]
    return TuneResult(TARGETS[target], paths,
                      [(test, results[i]) for i, (_, test) in enumerate(splits)], final,
                      apply_parameters(robot, final.values, TARGETS[target]))


def find_tuning_logs(logs: Sequence[str | Path]) -> list[str]:
    """Log directories given as such or found in folders (:func:`find_log_dirs`), in order.

    Raises:
        ValueError: a path that is neither, or a folder without any.
    """
    paths: list[str] = []
    for p in map(Path, logs):
        if p.is_dir() and not (p / "robot.toml").is_file():
            found = find_log_dirs(p)
            if not found:
                raise ValueError(f"{p}: no log directory (with robot.toml) in it")
            paths += [str(q) for q in found]
        elif (p / "robot.toml").is_file():
            paths.append(str(p))
        else:
            raise ValueError(f"{p}: not a log directory (robot.toml, wheels.csv, truth.csv) "
                             "or a folder of them")
    return paths


def tuned_section(result: TuneResult) -> str:
    """The chosen values as robot.toml table(s), e.g. ``[chassis]\\nwheel_distance = ...``."""
    lines: list[str] = []
    for table in dict.fromkeys(p.table for p in result.target.parameters):
        lines.append(f"[{table}]")
        for p in result.target.parameters:
            if p.table == table:
                lines.append(f"{p.name} = {result.final.values[p.name]!r}")
    return "\n".join(lines)
