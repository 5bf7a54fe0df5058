"""Choose a robot's parameters from logs with ground truth, by k-fold cross-validation.

``fusion tune TARGET LOGS/``: every run in ``LOGS/`` is scored with candidate parameters;
:data:`TARGETS` says which runs, which parameters and which score:

- ``odometry``: log directories with a ``truth.csv`` (``datasets/LOGDIR.md``; UMBmark squares
  from ``fusion synth --scenario square`` are such logs too); ``[chassis] wheel_distance``
  (m) and the right/left wheel radius ratio (seed 000's driver has one ``speed_ratio``: it
  goes to the fused EKF as ``[ekf] wheel_rate_per_speed``,
  :func:`fusion.calibration.odometry.radius_mismatch_rate`), scored by the yaw RMSE (deg) of
  the wheel-only dead reckoning against the truth: the separation sets how far the wheels'
  yaw drifts on every turn, the ratio on every straight.
- ``ekf``: the same logs (with imu.csv); ``[ekf] gyro_std``, ``bias_psd``, ``scale_std``,
  scored by the position RMSE (m) of the fused odometry (the replay's pipeline,
  :func:`fusion.jobs.replay.fuse_streams`).
- ``attitude``: BROAD-format trials (``.mat`` or HDF5, :func:`fusion.io.broad.read_broad`);
  Keel's 6-axis ``accel_time_constant``, ``motion_bias_sigma``, ``rest_bias_sigma`` and
  ``bias_drift`` (:class:`fusion.attitude.keel.KeelParams`), scored by the inclination RMSE
  (deg) over the trial's movement phases, as the BROAD paper scores; from the base
  robot.toml's ``[attitude]`` Keel settings if one is given, else Keel's defaults.

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
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.calibration.odometry import (
    ekf_radius_lines,
    radius_mismatch_rate,
    radius_ratio_from_mismatch,
)
from fusion.evaluation.crossval import kfold_splits
from fusion.evaluation.trajectory import position_rmse, yaw_rmse
from fusion.io.logdir import LogDir, read_logdir
from fusion.jobs.engine import run_tasks
from fusion.jobs.imu_lag import choose_imu_lag, shifted
from fusion.jobs.replay import Streams, find_log_dirs, fuse_streams
from fusion.jobs.replay import _truth_at as truth_at  # the replay's truth interpolation
from fusion.jobs.wheel_glitches import glitch_frames
from fusion.planar.odometry import integrate_wheel_travel
from fusion.planar.robot import AttitudeConfig, RobotConfig

__all__ = [
    "BROAD_SUFFIXES",
    "TARGETS",
    "FoldResult",
    "FoldTask",
    "Parameter",
    "Target",
    "TuneResult",
    "apply_parameters",
    "find_tuning_runs",
    "fused_position_rmse",
    "keel_inclination_rmse",
    "odometry_yaw_rmse",
    "run_fold",
    "search",
    "tune",
    "tuned_section",
]


@dataclass(frozen=True)
class Parameter:
    """A tuned value: ``[table] name`` of robot.toml, searched in log space between
    ``low`` and ``high`` times its base value (the base robot's, or the filter's default)."""

    table: str
    name: str
    low: float
    high: float


@dataclass(frozen=True)
class Target:
    """What ``fusion tune TARGET`` tunes: its runs (``load(path)``, found in folders by
    ``find``), parameters, and the score (lower is better) of ``values`` (by parameter name)
    on one run of a robot (``score(robot, values, run)``)."""

    name: str
    parameters: tuple[Parameter, ...]
    score_name: str
    score: Callable[[RobotConfig | None, dict[str, float], Any], float]
    load: Callable[[str], Any]
    find: Callable[[Path], list[Path]]
    needs_robot: bool = True

    def base_values(self, robot: RobotConfig | None) -> dict[str, float]:
        """The parameters' values in ``robot`` (or the filter's defaults)."""
        from fusion.attitude.keel import KeelParams

        tables: dict[str, Any] = {"attitude": KeelParams(**keel_settings(robot)),
                                  "wheels": SimpleNamespace(radius_ratio=1.0)}
        if robot is not None:
            tables |= {"chassis": robot.chassis, "ekf": robot.ekf}
        if robot is not None and any(p.table == "wheels" for p in self.parameters):
            # its radius ratio: the one its EKF's radius mismatch gives
            try:
                ratio = radius_ratio_from_mismatch(robot.ekf.wheel_rate_per_speed,
                                                   robot.chassis.wheel_distance)
            except ValueError as exc:
                raise ValueError(f"the base robot.toml's [ekf] wheel_rate_per_speed: {exc}"
                                 ) from exc
            tables["wheels"] = SimpleNamespace(radius_ratio=ratio)
        return {p.name: float(getattr(tables[p.table], p.name)) for p in self.parameters}


def _truth_at(log: LogDir, t: NDArray[np.float64]) -> NDArray[np.float64]:
    return truth_at(log.truth_t, log.truth, t)


def _inside(log: LogDir, t: NDArray[np.float64]) -> NDArray[np.bool_]:
    return (t >= log.truth_t[0]) & (t <= log.truth_t[-1])


def odometry_yaw_rmse(robot: RobotConfig, log: LogDir, radius_ratio: float = 1.0) -> float:
    """Yaw RMSE (deg) of the wheel-only dead reckoning with ``robot``'s chassis against the
    truth, at the wheel frames inside the truth's span.

    ``radius_ratio``: right over left wheel radius, split evenly so the mean travel per tick
    stays ``speed_ratio`` (1: equal wheels; robot.toml keeps a ratio as its EKF's radius
    mismatch, ``[ekf] wheel_rate_per_speed``, not in the wheel-only dead reckoning).
    """
    sr = robot.chassis.speed_ratio
    wheel_t, ticks = _without_glitches(log, robot)
    dl = ticks[:, 0] * (sr * 2.0 / (1.0 + radius_ratio))
    dr = ticks[:, 1] * (sr * 2.0 * radius_ratio / (1.0 + radius_ratio))
    poses = integrate_wheel_travel(dl, dr, robot.chassis.wheel_distance)
    inside = _inside(log, wheel_t)
    truth = _truth_at(log, wheel_t[inside])
    return math.degrees(yaw_rmse(poses[inside, 2], truth[:, 2]))


def _without_glitches(log: LogDir, robot: RobotConfig):
    """The log's wheel frames (stamps s, ticks) without the glitch frames ``fusion replay``
    leaves out (:mod:`fusion.jobs.wheel_glitches`)."""
    keep = ~glitch_frames(log.wheel_t, log.ticks, robot.chassis.speed_ratio,
                          robot.chassis.encode_sampling_time)
    return log.wheel_t[keep], log.ticks[keep]


def fused_position_rmse(robot: RobotConfig, log: LogDir) -> float:
    """Position RMSE (m) of the fused odometry (the replay's pipeline, no output file, the
    IMU's stamps moved as the replay moves them) against the truth, at the fused rows inside
    the truth's span."""
    streams = Streams(log.imu_t, log.gyro, log.accel, *_without_glitches(log, robot))
    streams = shifted(streams, choose_imu_lag(streams, robot.chassis).lag)
    # the values tried, as given: the walk a log's stops fit would override bias_psd
    table = fuse_streams(robot, streams, None, bias_walk=False)[0]
    t = table[:, 0]
    inside = _inside(log, t)
    truth = _truth_at(log, t[inside])
    return position_rmse(table[inside, 1:3], truth[:, :2])


def keel_settings(robot: RobotConfig | None) -> dict[str, Any]:
    """The KeelParams fields robot.toml's ``[attitude]`` table sets, when its filter is Keel
    (else none: Keel's defaults)."""
    if robot is None or robot.attitude.filter != "keel":
        return {}
    return dict(robot.attitude.params)


def keel_inclination_rmse(values: dict[str, float], trial: Any) -> float:
    """Inclination RMSE (deg) of 6-axis Keel with ``values`` (KeelParams fields) on a BROAD
    trial, over its movement phases."""
    from fusion.attitude.keel import Keel, KeelParams
    from fusion.evaluation.orientation import orientation_rmse

    f = Keel(axes=6, params=KeelParams(**values))
    q = f.update_batch(trial.gyro, trial.accel, dt=1 / trial.rate)
    return orientation_rmse(q, trial.quat_ref, trial.movement).inclination_deg


def _load_log(target: str) -> Callable[[str], LogDir]:
    def load(path: str) -> LogDir:
        """A log directory with what the target needs (truth; wheels; IMU for ``ekf``)."""
        log = read_logdir(path, imu_frame="imu")
        if log.truth_t is None or log.truth_t.size < 2:
            raise ValueError(f"{path}: no truth.csv (tuning needs ground truth)")
        if log.wheel_t is None or log.wheel_t.size == 0:
            raise ValueError(f"{path}: wheels.csv is missing or empty")
        if target == "ekf" and (log.imu_t is None or log.imu_t.size == 0):
            raise ValueError(f"{path}: imu.csv is missing or empty (the ekf target fuses the "
                             "gyro)")
        return log

    return load


def _load_trial(path: str) -> Any:
    from fusion.io.broad import read_broad

    return read_broad(path)


def _find_log_dirs_with_truth(folder: Path) -> list[Path]:
    found = find_log_dirs(folder)
    for p in found:  # refuse a log without truth before any search starts
        if not (p / "truth.csv").is_file():
            raise ValueError(f"{p}: no truth.csv (tuning needs ground truth)")
    return found


#: File suffixes of BROAD trials.
BROAD_SUFFIXES = (".mat", ".h5", ".hdf5")


def _find_trials(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in BROAD_SUFFIXES)


def _odometry_score(robot, values, log) -> float:
    return odometry_yaw_rmse(apply_parameters(robot, values, TARGETS["odometry"]), log,
                             values.get("radius_ratio", 1.0))


def _ekf_score(robot, values, log) -> float:
    return fused_position_rmse(apply_parameters(robot, values, TARGETS["ekf"]), log)


_DEG = math.pi / 180

#: The targets of ``fusion tune``.
TARGETS: dict[str, Target] = {
    # the radius ratio is searched too (a mismatch turns the wheels' yaw on every straight,
    # which the separation alone would absorb on squares); robot.toml keeps it as the EKF's
    # radius mismatch ([ekf] wheel_rate_per_speed)
    "odometry": Target("odometry", (Parameter("chassis", "wheel_distance", 0.8, 1.25),
                                    Parameter("wheels", "radius_ratio", 0.95, 1 / 0.95)),
                       "wheel-only yaw RMSE, deg", _odometry_score,
                       _load_log("odometry"), _find_log_dirs_with_truth),
    "ekf": Target("ekf", (Parameter("ekf", "gyro_std", 0.1, 10.0),
                          Parameter("ekf", "bias_psd", 0.01, 100.0),
                          Parameter("ekf", "scale_std", 0.1, 10.0)),
                  "fused position RMSE, m", _ekf_score,
                  _load_log("ekf"), _find_log_dirs_with_truth),
    "attitude": Target("attitude", (Parameter("attitude", "accel_time_constant", 0.25, 4.0),
                                    Parameter("attitude", "motion_bias_sigma", 0.1, 10.0),
                                    Parameter("attitude", "rest_bias_sigma", 0.1, 10.0),
                                    Parameter("attitude", "bias_drift", 0.1, 10.0)),
                       "6-axis Keel inclination RMSE, deg",
                       lambda robot, values, trial: keel_inclination_rmse(
                           {**keel_settings(robot), **values}, trial),
                       _load_trial, _find_trials, needs_robot=False),
}


def apply_parameters(robot: RobotConfig, values: dict[str, float], target: Target
                     ) -> RobotConfig:
    """``robot`` with ``values`` (by parameter name) in their [chassis], [ekf] and [attitude]
    tables (``[attitude]`` then runs Keel, keeping the Keel settings it had)."""
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
    if "wheels" in changes:  # one speed_ratio: the ratio goes to the EKF's radius mismatch
        c = radius_mismatch_rate(changes["wheels"]["radius_ratio"], out.chassis.wheel_distance)
        out = dataclasses.replace(out, ekf=dataclasses.replace(out.ekf, wheel_rate_per_speed=c))
    if "attitude" in changes:
        keel = out.attitude.filter == "keel"
        params = {**keel_settings(out), **changes["attitude"]}
        out = dataclasses.replace(out, attitude=AttitudeConfig(
            "keel", tuple(params.items()), out.attitude.wheel_knowledge if keel else None))
    return out


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
    """One search: tune ``target`` on ``train`` (run paths) with ``budget`` evaluations,
    starting from ``base`` (parameter values; the robot's for robot targets), then score the
    result and ``base`` on ``test``."""

    target: str
    robot: RobotConfig | None
    base: dict[str, float]
    train: tuple[str, ...]
    test: tuple[str, ...]
    budget: int


@dataclass
class FoldResult:
    """What :func:`run_fold` found: the chosen values (by parameter name), the mean score on
    the training runs (in-sample), per-run scores of the chosen values and of the defaults
    on the test runs, the defaults' mean on the training runs, and evaluations used."""

    values: dict[str, float]
    train_score: float
    default_train_score: float
    test_scores: list[float] = field(default_factory=list)
    default_test_scores: list[float] = field(default_factory=list)
    evaluations: int = 0


def run_fold(task: FoldTask) -> FoldResult:
    """Search on the training runs, score on the test runs (a worker runs this)."""
    target = TARGETS[task.target]
    train = [target.load(p) for p in task.train]
    test = [target.load(p) for p in task.test]

    def values_of(u) -> dict[str, float]:
        return {p.name: task.base[p.name] * math.exp(x) for p, x in zip(target.parameters, u)}

    def mean_score(u) -> float:
        values = values_of(u)
        return float(np.mean([target.score(task.robot, values, run) for run in train]))

    bounds = [(math.log(p.low), math.log(p.high)) for p in target.parameters]
    u, value, n = search(mean_score, bounds, task.budget)
    values = values_of(u)
    return FoldResult(values, value, mean_score(np.zeros(len(bounds))),
                      [target.score(task.robot, values, run) for run in test],
                      [target.score(task.robot, task.base, run) for run in test], n)


@dataclass
class TuneResult:
    """``fusion tune``'s outcome.

    Attributes:
        target: the :class:`Target`.
        runs: the run paths (log directories or trial files); ``folds`` index them.
        folds: per fold, ``(test run indices, FoldResult)``.
        final: the search on every run (its values are the ones to use; its train score is
            in-sample).
        robot: the base robot with the final values (None: the attitude target without a
            base robot).
    """

    target: Target
    runs: list[str]
    folds: list[tuple[list[int], FoldResult]]
    final: FoldResult
    robot: RobotConfig | None

    @property
    def cv_score(self) -> float:
        """Mean over every run of its score with the values chosen without it."""
        return float(np.mean([s for _, f in self.folds for s in f.test_scores]))

    @property
    def default_score(self) -> float:
        """Mean over every run of the defaults' score."""
        return float(np.mean([s for _, f in self.folds for s in f.default_test_scores]))


def tune(target: str, runs: Sequence[str | Path], robot: RobotConfig | None = None, *,
         folds: int = 5, budget: int = 60, jobs: int = 1, client: Any = None,
         on_fold: Callable[[int, FoldResult], None] | None = None) -> TuneResult:
    """Tune ``target``'s parameters on ``runs`` by ``folds``-fold cross-validation.

    ``runs``: log directories (BROAD trial files for ``attitude``), or folders of them;
    ``robot``: the base robot.toml (the search starts from, and bounds around, its values;
    optional for ``attitude``, which otherwise starts from Keel's defaults). Each fold and the final
    search on all runs is one task on the engine (``jobs`` processes, or the Dask
    ``client``). ``on_fold(i, result)`` is called as each fold ends (the final search:
    ``i = -1``).

    Raises:
        ValueError: unknown target, fewer than 2 runs, a bad ``folds`` or ``budget``, or a
            run without what the target needs (named); a failed fold names its error.
    """
    if target not in TARGETS:
        raise ValueError(f"unknown tuning target {target!r}; known: {', '.join(TARGETS)}")
    spec = TARGETS[target]
    if spec.needs_robot and robot is None:
        raise ValueError(f"the {target} target needs a base robot.toml")
    paths = find_tuning_runs(target, runs)
    if len(paths) < 2:
        raise ValueError(f"cross-validation needs at least 2 runs, got {len(paths)}")
    if budget < 1:
        raise ValueError(f"--budget must be >= 1 evaluation, got {budget}")
    base = spec.base_values(robot)
    splits = kfold_splits(len(paths), folds)
    tasks = [FoldTask(target, robot, base, tuple(paths[i] for i in train),
                      tuple(paths[i] for i in test), budget) for train, test in splits]
    tasks.append(FoldTask(target, robot, base, tuple(paths), (), budget))
    results: dict[int, FoldResult] = {}
    for i, ok, value in run_tasks(run_fold, tasks, jobs=jobs, client=client):
        if not ok:
            what = "the search on all runs" if i == len(splits) else f"fold {i + 1}"
            raise ValueError(f"{what} failed: {value}")
        results[i] = value
        if on_fold is not None:
            on_fold(-1 if i == len(splits) else i, value)
    final = results[len(splits)]
    return TuneResult(spec, paths, [(test, results[i]) for i, (_, test) in enumerate(splits)],
                      final, None if robot is None
                      else apply_parameters(robot, final.values, spec))


def find_tuning_runs(target: str, runs: Sequence[str | Path]) -> list[str]:
    """The target's runs given as such or found in folders, in order: log directories
    (with robot.toml and truth.csv), or BROAD trial files for ``attitude``.

    Raises:
        ValueError: a path that is neither, a folder without any, or a log without truth.
    """
    spec = TARGETS[target]
    paths: list[Path] = []
    for p in map(Path, runs):
        if spec.needs_robot and (p / "robot.toml").is_file():
            if not (p / "truth.csv").is_file():
                raise ValueError(f"{p}: no truth.csv (tuning needs ground truth)")
            paths.append(p)
        elif not spec.needs_robot and p.is_file():
            paths.append(p)
        elif p.is_dir():
            found = spec.find(p)
            if not found:
                what = ("log directory (with robot.toml)" if spec.needs_robot
                        else f"BROAD trial ({', '.join(BROAD_SUFFIXES)})")
                raise ValueError(f"{p}: no {what} in it")
            paths += found
        else:
            raise ValueError(f"{p}: no such log directory, trial or folder")
    return [str(p) for p in paths]


def tuned_section(result: TuneResult) -> str:
    """The chosen values as robot.toml table(s), e.g. ``[chassis]\nwheel_distance = ...``
    (the attitude target's ``[attitude]`` table names its filter, ``filter = "keel"``)."""
    lines: list[str] = []
    for table in dict.fromkeys(p.table for p in result.target.parameters):
        if table == "wheels":
            continue
        lines.append(f"[{table}]")
        if table == "attitude":
            lines.append('filter = "keel"')
        for p in result.target.parameters:
            if p.table == table:
                lines.append(f"{p.name} = {result.final.values[p.name]!r}")
    if "radius_ratio" in result.final.values:
        ratio = result.final.values["radius_ratio"]
        lines.append(f"# right/left wheel radius ratio {ratio:.8g} (seed 000's driver has one "
                     "speed_ratio): as the EKF's radius mismatch")
        lines += ["[ekf]", *ekf_radius_lines(radius_mismatch_rate(
            ratio, result.final.values.get("wheel_distance",
                                           result.robot.chassis.wheel_distance)))]
    return "\n".join(lines)
