"""``fusion replay``: run the fusion pipeline over recorded logs (argument parsing and printing;
the job itself is :mod:`fusion.jobs.replay`).

Inputs: a log directory (``datasets/LOGDIR.md``), a folder whose subfolders are log directories
(every log replayed in a worker process, ``--jobs``, or on Dask workers, ``--cluster``
(:mod:`fusion.jobs.cluster`); one output per log in the ``-o`` folder and a summary table), a
DATA-uart2 capture (``*.uart2``) with ``--robot robot.toml``, or a ROS 1 ``.bag``, a ROS 2 bag
folder or an ``.mcap`` file with ``--imu-topic`` and ``--odom-topic``.

Outputs (``-o``, by suffix): ``.csv`` the fused CSV (:mod:`fusion.io.fused_csv`, the state at
every IMU sample), ``.mcap`` or ``.jsonl`` the pipeline's records. ``--plot out.png`` draws the
tracks and the yaw. Progress goes to standard error when it is a terminal and the input is long
(:data:`AUTO_PROGRESS_MIN_SPAN`, or a folder of logs), or with ``--progress``: a tqdm bar (the
``progress`` extra) or a plain line.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from fusion.cli import CommandError
from fusion.io.fused_csv import FUSED_CSV_COLUMNS

__all__ = ["AUTO_PROGRESS_MIN_SPAN", "register"]

#: Output suffix -> format (as :data:`fusion.jobs.replay.OUTPUT_FORMATS`, without importing
#: the library before a command runs).
OUTPUT_FORMATS = {".csv": "csv", ".mcap": "mcap", ".jsonl": "jsonl"}

CAPTURE_SUFFIXES = (".uart2",)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="fused wheel + gyro odometry (EKF) of recorded logs",
        description=(
            "Run the fusion pipeline (Keel attitude + planar EKF: wheel odometry and the "
            "gyro yaw rate with a gyro-bias state) over a log directory (robot.toml, imu.csv "
            "and/or wheels.csv or wheels.uart2, optional truth.csv; see datasets/LOGDIR.md), "
            "a folder of log directories (in parallel worker processes), a DATA-uart2 "
            "capture (*.uart2, with --robot) or a ROS bag, and write the fused odometry: "
            ".csv (the header " + ",".join(FUSED_CSV_COLUMNS) + ", one row per IMU sample), "
            ".mcap or .jsonl (the pipeline's records, one per wheel frame or bag odometry "
            "message). Prints a "
            "summary; with truth.csv, the errors of the fused and of the wheel-only odometry."
        ),
    )
    p.add_argument("input", type=Path,
                   help="log directory, folder of log directories, *.uart2 capture, or a "
                        "ROS 1 .bag / ROS 2 bag folder / .mcap file")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="fused.csv | fused.mcap | fused.jsonl (format by suffix); for a folder "
                        "of logs, the folder to write one output per log into")
    p.add_argument("--format", choices=sorted(set(OUTPUT_FORMATS.values())), default=None,
                   help="output format of each log of a folder of logs (default csv; a single "
                        "output's format comes from its suffix)")
    p.add_argument("--one-pass", action="store_true",
                   help="fuse as a live run would: where the robot drives off at once, do not "
                        "fuse the log a second time from the gyro bias its first stop taught "
                        "(default: that second pass, said in a 'note: moving start' line)")
    p.add_argument("--imu-lag", type=imu_lag_arg, default=None, metavar="S|auto",
                   help="s by which the IMU's stamps are later than the odometry's (taken off "
                        "them before fusing; 0 leaves them). Default auto: estimated from the "
                        "turns both see, and moved only when clearly off (more than 0.1 s or "
                        "two intervals of the slower stream), with a note")
    p.add_argument("--level", action="store_true",
                   help="take the robot as level: use the gyro's z axis as the yaw rate "
                        "(default: tilt-compensate with the attitude filter's attitude)")
    p.add_argument("--plot", type=Path, metavar="PNG",
                   help="draw fused vs wheel-only (vs truth) trajectories and the yaw error to "
                        "this PNG (for a folder of logs: a folder, one PNG per log); needs "
                        "matplotlib (pip install 'diffbot-fusion[demo]')")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress on stderr (default: when stderr is a terminal, for logs "
                        "of 10 minutes or more and for folders of logs)")
    p.add_argument("-j", "--jobs", type=int, default=None,
                   help="worker processes for a folder of logs (default: the CPU count)")
    p.add_argument("--cluster", nargs="?", const="", default=None, metavar="SPEC",
                   help="replay a folder of logs on Dask (the 'cluster' extra): local[:N] "
                        "starts a local cluster of N one-thread workers (default N: the CPU "
                        "count), tcp://HOST:8786 joins a running scheduler, and --cluster "
                        "alone joins the one in DASK_SCHEDULER_ADDRESS; not with --jobs")
    p.add_argument("--robot", type=Path,
                   help="robot.toml for a capture (required), a bag (wheel_distance and "
                        "[ekf] tuning; optional) or a log directory (instead of its own)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 3 when the inputs disagree beyond what the model "
                        "explains (most frames slip, an implausible gyro bias, a wheel "
                        "yaw-rate scale beyond 15 %%, odometry and gyro headings diverging; "
                        "printed as 'warning: inputs disagree' "
                        "either way)")
    bag = p.add_argument_group("ROS bags")
    bag.add_argument("--imu-topic", help="sensor_msgs/Imu topic (bags only)")
    bag.add_argument("--odom-topic", help="nav_msgs/Odometry topic of the wheel odometry "
                                          "(bags only)")
    bag.add_argument("--gps-topic", help="sensor_msgs/NavSatFix topic (bags only, optional): "
                                         "print the position RMSE of the fused track, the "
                                         "bag's odometry and the gyro-at-stops baseline "
                                         "against the GPS fixes after one SE(2) alignment "
                                         "each, and draw the fixes with --plot")
    bag.add_argument("--stamps", choices=("header", "bag"), default=None,
                     help="message times of a bag: each message's header.stamp (default) or "
                          "the time the bag recorded it (for drivers that leave header "
                          "stamps at zero or on another clock)")
    bag.add_argument("--imu-mount-rpy", type=float, nargs=3, metavar=("R", "P", "Y"),
                     default=None,
                     help="URDF roll pitch yaw (rad) taking IMU-frame vectors into the base "
                          "frame, for a bag or a log directory (default: imu_mount_rpy of "
                          "--robot, else of the log's robot.toml; for a bag, else the "
                          "mount its /tf_static gives, else 0 0 0)")
    p.set_defaults(func=run)


def imu_lag_arg(text: str) -> float | None:
    """--imu-lag (here and in ``fusion calibrate odometry``): "auto" (None) or a finite
    number of s."""
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected s (e.g. 0.25) or 'auto', got {text!r}")
    return value


# -- progress -----------------------------------------------------------------------------------


class _Progress:
    """Progress of one replay on stderr: a tqdm bar if tqdm is installed, else a plain line
    at most every ``interval`` s; nothing when disabled."""

    def __init__(self, total: float, desc: str, unit: str, enabled: bool,
                 interval: float = 1.0) -> None:
        self.total = max(float(total), 0.0)
        self.desc = desc
        self.unit = unit
        self.enabled = enabled
        self.interval = interval
        self._bar = None
        self._done = 0.0
        self._last = -math.inf
        if enabled:
            try:
                from tqdm import tqdm
            except ImportError:
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=math.ceil(self.total), desc=desc, unit=unit,
                                 file=sys.stderr, leave=False, dynamic_ncols=True)

    def update_to(self, done: float) -> None:
        if not self.enabled:
            return
        done = min(max(float(done), self._done), self.total)
        self._done = done
        if self._bar is not None:
            step = int(done) - self._bar.n  # whole units
            if step > 0:
                self._bar.update(step)
            return
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self._line()

    def _line(self) -> None:
        pct = 100.0 * self._done / self.total if self.total > 0 else 100.0
        print(f"{self.desc}: {pct:3.0f}% ({self._done:.1f}/{self.total:.1f} {self.unit})",
              file=sys.stderr, flush=True)

    def discard(self) -> None:
        """Stop showing an unfinished bar (an interrupt): no final line."""
        if self.enabled and self._bar is not None:
            self._bar.close()
        self.enabled = False

    def close(self) -> None:
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
        else:
            self._done = self.total
            self._line()


#: Without --progress/--no-progress, a log of at least this many seconds shows its progress
#: when stderr is a terminal (a shorter one replays in about a second).
AUTO_PROGRESS_MIN_SPAN = 600.0


def _stderr_is_tty() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def _progress_for(flag: bool | None, span: float) -> bool:
    """--progress: True; --no-progress: False; None: a long log on a terminal."""
    if flag is not None:
        return bool(flag)
    return span >= AUTO_PROGRESS_MIN_SPAN and _stderr_is_tty()


def _print_result(r, level_note: bool = True) -> None:
    s = r.stats
    written = (f"{r.rows} rows" if OUTPUT_FORMATS.get(Path(r.output).suffix.lower()) == "csv"
               else f"{r.records} records")
    print(f"{r.source}: {r.span:.1f} s, {r.n_imu} IMU samples, {r.n_wheels} wheel frames "
          f"-> {r.output} ({written})")
    x, y, yaw = r.final
    print(f"final pose: x {x:.3f} m, y {y:.3f} m, yaw {math.degrees(yaw):.2f} deg; path "
          f"{r.distance:.2f} m")
    print(f"gyro bias {math.degrees(r.gyro_bias):+.4f} deg/s; ZUPTs {s['zupts']}, "
          f"slip frames {s['slips']} ({s.get('accel_slips', 0)} seen by the accelerometer), "
          f"turning frames whose yaw rate was not trusted {s['wheel_rate_distrusted']} "
          f"(near-zero ones fused as driving straight {s.get('straight_frames', 0)}), "
          f"wheel yaw-rate scale re-set from its fit {s.get('wheel_scale_refits', 0)}, "
          f"encoder faults (zero ticks while the IMU moved, not "
          f"fused) {s['encoder_faults']} (the next frame catching up their counts "
          f"{s.get('catch_ups', 0)}), gyro bias relearnt at a stop "
          f"{s.get('bias_relearnt', 0)}, gyro spikes not fused {s.get('gyro_spikes', 0)}, "
          f"late inputs fused {s['late_applied']}, dropped "
          f"{s['late_dropped']}, invalid {s['invalid']}; wheel frames missing "
          f"{s['frames_missing']} ({s['gap_count']} gaps), "
          f"IMU gaps {s['attitude_gaps']}, "
          f"speeds forgotten after a gap {s['speed_resets']}")
    for note in r.notes:
        print(f"warning: {note}")
    if r.moving_start is not None:
        print(f"note: {r.moving_start.note}")
    _print_warnings(r.warnings)
    if r.n_imu:
        print(f"wheel yaw-rate calibration seen by the gyro: k {r.k:+.4f} "
              f"(wheel_distance ~ {r.wheel_distance * (1 + r.k) * (1 + r.gyro_scale):.4f} "
              "m with the gyro's scale as configured), "
              f"c {r.c:+.5f} rad/m; see `fusion calibrate odometry` for corrected parameters")
    elif level_note:
        print("no imu.csv: wheel odometry only (no gyro to fuse)")
    if r.truth is not None:
        tr = r.truth
        print(f"truth: {tr['distance']:.2f} m travelled")
        print(f"  fused:      final position error {tr['fused_pct']:.3f} % of distance, "
              f"yaw RMSE {tr['fused_yaw_deg']:.3f} deg")
        print(f"  wheel only: final position error {tr['wheel_pct']:.3f} % of distance, "
              f"yaw RMSE {tr['wheel_yaw_deg']:.3f} deg")


def _print_warnings(warnings) -> None:
    """The trust warnings (:mod:`fusion.evaluation.trust`) of one replay."""
    from fusion.evaluation.trust import imu_units_wrong

    for w in warnings:
        print(f"warning: inputs disagree ({w.name}): {w.message}")
    if not warnings:
        return
    names = {w.name for w in warnings}
    slip = next((w for w in warnings if w.name == "slip"), None)
    gyro_alone = (names <= {"slip", "heading_divergence", "odometry_scale"}
                  and ("odometry_scale" in names or (
                      slip is not None
                      and slip.figures["wheel_rate_distrusted"] > slip.figures["slips"])))
    units = [w.name for w in warnings if imu_units_wrong(w)]
    if units:
        print("warning: the fused odometry above should not be trusted: the IMU's readings "
              f"are in other units ({' and '.join(dict.fromkeys(units))} above), which the "
              "filter takes as SI; convert them (or fix the driver's scale) and replay")
    elif any(w.name == "gyro_axis" and w.figures.get("odometry_rate_slope", 0.0) < 0.0
             for w in warnings):
        print("warning: the fused odometry above should not be trusted: the gyro and the "
              "odometry turn opposite ways (gyro_axis above) and the heading rests on the "
              "gyro; fix the one that is flipped (the IMU's mount or driver, or the "
              "odometry's wheel columns or signs) and replay")
    elif gyro_alone:
        # the EKF already stopped fusing the odometry's yaw rate: say what the heading rests on
        print("warning: the fused odometry above should not be trusted unless the gyro is "
              "right: its heading rests on the gyro alone (the odometry's yaw rate was not "
              "fused in the turns that disagreed, before or after most did; right for a "
              "skid-steer base, whose "
              "odometry turns unlike the robot; "
              "otherwise check the IMU mount and axis signs, --imu-mount-rpy)")
    else:
        print("warning: the fused odometry above should not be trusted")


def _exit_status(args: argparse.Namespace, warnings) -> int:
    from fusion.jobs.status import STRICT_EXIT_STATUS

    if args.strict and warnings:
        print(f"fusion replay: --strict: the inputs disagree (exit status {STRICT_EXIT_STATUS})",
              file=sys.stderr)
        return STRICT_EXIT_STATUS
    return 0


def _print_table(work, results, where: str) -> int:
    head = (f"{'log':<24} {'status':<6} {'time s':>8} {'IMU':>8} {'wheels':>7} "
            f"{'final x':>8} {'final y':>8} {'yaw deg':>8} {'fused %':>8} {'wheel %':>8}  output")
    print(head)
    failed = 0
    for w in work:
        path, output = w.source, w.output
        status, value = results[path]
        name = Path(path).name
        if status != "ok":
            failed += 1
            print(f"{name:<24} {'FAILED':<6} {value}")
            continue
        r = value
        fp = wp = "-"
        if r.truth is not None:
            fp, wp = f"{r.truth['fused_pct']:.3f}", f"{r.truth['wheel_pct']:.3f}"
        print(f"{name:<24} {'ok':<6} {r.span:>8.1f} {r.n_imu:>8} {r.n_wheels:>7} "
              f"{r.final[0]:>8.3f} {r.final[1]:>8.3f} {math.degrees(r.final[2]):>8.2f} "
              f"{fp:>8} {wp:>8}  {output}")
    print(f"{len(work) - failed} of {len(work)} logs replayed ({where}); {failed} failed")
    for w in work:
        status, value = results[w.source]
        if status != "ok":
            print(f"fusion replay: {value}", file=sys.stderr)
    return failed


def run(args: argparse.Namespace) -> int:
    """The command; Ctrl-C (SIGINT) stops it with status 130, saying what was written."""
    outputs = [p for p in (args.output, args.plot) if p is not None]
    before = {p: _file_state(p) for p in outputs}
    started = time.time()
    try:
        return _run(args)
    except KeyboardInterrupt:
        for line in _interrupt_report(before, started):
            print(f"fusion replay: interrupted: {line}", file=sys.stderr, flush=True)
        return 130


def _file_state(path: Path) -> tuple[int, int] | None:
    """(mtime ns, size) of a file, None if there is none (a folder: None)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size) if path.is_file() else None


def _interrupt_report(before: dict[Path, tuple[int, int] | None], started: float
                      ) -> list[str]:
    """What an interrupted replay left: each output written completely before the interrupt,
    or left as it was (outputs are replaced only by complete files, never partly written)."""
    lines = []
    for path, old in before.items():
        if path.is_dir():  # a folder of logs: the outputs finished before the interrupt
            done = sorted(p.name for p in path.iterdir()
                          if p.is_file() and p.stat().st_mtime >= started)
            lines.append(f"{len(done)} output(s) in {path} complete"
                         f"{': ' + ', '.join(done) if done else ''}; the other logs wrote "
                         "nothing")
            continue
        now = _file_state(path)
        if now is not None and now != old:
            lines.append(f"{path} was written completely before the interrupt (kept)")
        elif old is None:
            lines.append(f"{path} not written (nothing partial left)")
        else:
            lines.append(f"{path} left as it was (an existing file is only replaced by a "
                         "complete one)")
    return lines


def _run(args: argparse.Namespace) -> int:
    from fusion.jobs import replay as job

    path: Path = args.input
    if not path.exists():
        raise CommandError(f"{path}: no such log directory or bag")
    bag = job.is_bag(path)
    if not bag and (args.imu_topic or args.odom_topic or args.gps_topic or args.stamps):
        raise CommandError(f"{path}: --imu-topic/--odom-topic/--gps-topic/--stamps are for ROS "
                           "bags; this is not "
                           "a .bag, .mcap or ROS 2 bag folder")
    folder = not bag and path.is_dir() and not (path / "robot.toml").is_file()
    if args.format is not None and not folder:
        fmt = OUTPUT_FORMATS.get(args.output.suffix.lower())
        if fmt != args.format:
            raise CommandError(f"--format applies to a folder of logs; the output "
                               f"{args.output} is {fmt or 'of no known type'} by its suffix")
    if args.jobs is not None and not folder:
        raise CommandError("--jobs applies to a folder of logs only")
    if args.cluster is not None and not folder:
        raise CommandError("--cluster applies to a folder of logs only")
    if args.cluster is not None and args.jobs is not None:
        raise CommandError("--cluster and --jobs exclude each other: --jobs N runs worker "
                           "processes on this machine, --cluster runs on Dask workers")
    if bag:
        return run_bag(args)
    if path.is_file():
        for given, option in ((args.level, "--level"),
                              (args.imu_mount_rpy is not None, "--imu-mount-rpy"),
                              (args.one_pass, "--one-pass"),
                              (args.imu_lag is not None, "--imu-lag")):
            if given:
                raise CommandError(f"{option} does not apply to a DATA-uart2 capture (it has "
                                   "no IMU); it applies to log directories and bags")
        if path.suffix.lower() not in CAPTURE_SUFFIXES:
            raise CommandError(f"{path}: is a file; replay takes a log directory "
                               "(robot.toml, imu.csv, wheels.csv; see datasets/LOGDIR.md), a "
                               "folder of them, a DATA-uart2 capture (.uart2) or a ROS bag "
                               "(.bag, .mcap, ROS 2 folder)")
        if args.robot is None:
            raise CommandError(f"{path}: a capture needs --robot robot.toml (the chassis "
                               "geometry and encode_sampling_time)")
        job.output_format(args.output)
        with _BarContext(args.progress, path.name) as bar:
            r = job.replay_capture(path, args.output, args.robot, plot=args.plot,
                                   progress=bar.callback)
        _print_result(r, level_note=False)
        print("DATA-uart2 capture: wheel odometry only (no gyro to fuse)")
        return _exit_status(args, r.warnings)
    if folder:
        logs = job.find_log_dirs(path)
        if logs:
            for given, option in ((args.robot is not None, "--robot"),
                                  (args.imu_mount_rpy is not None, "--imu-mount-rpy")):
                if given:
                    raise CommandError(f"{option} applies to one log directory, a capture "
                                       "or a bag; each log of a folder uses its own robot.toml")
            return _run_folder(args, logs)
    job.output_format(args.output)
    robot = None
    if args.robot is not None:
        from fusion.io.robot_toml import read_robot_toml

        robot = read_robot_toml(args.robot)
        print(f"robot: {args.robot} (instead of {path / 'robot.toml'})")
    if args.imu_mount_rpy is not None:
        print("IMU mount: roll {:.4f} pitch {:.4f} yaw {:.4f} rad from --imu-mount-rpy "
              "(instead of robot.toml's)".format(*args.imu_mount_rpy))
    with _BarContext(args.progress, path.name) as bar:
        r = job.replay_logdir(path, args.output, tilt=not args.level, plot=args.plot,
                              robot=robot, imu_mount_rpy=args.imu_mount_rpy,
                              progress=bar.callback, load_progress=bar.loading,
                              one_pass=args.one_pass, imu_lag=args.imu_lag)
    _print_result(r)
    return _exit_status(args, r.warnings)


#: Without --progress/--no-progress, loading a file of at least this many bytes shows its
#: progress when stderr is a terminal (a 100 Hz imu.csv of about 10 minutes).
AUTO_LOAD_PROGRESS_MIN_BYTES = 8 << 20


class _BarContext:
    """A progress bar made on the first callback of a job, when the log's span is known;
    before it, one per file being loaded (:meth:`loading`)."""

    def __init__(self, flag: bool | None, desc: str) -> None:
        self.flag = flag
        self.desc = desc
        self.bar: _Progress | None = None
        self._loads: dict[str, _Progress] = {}

    def loading(self, name: str, done: int, total: int) -> None:
        """``done`` of ``total`` bytes of the file ``name`` parsed."""
        bar = self._loads.get(name)
        if bar is None:
            enabled = (self.flag if self.flag is not None
                       else total >= AUTO_LOAD_PROGRESS_MIN_BYTES and _stderr_is_tty())
            bar = self._loads[name] = _Progress(total / 1e6, f"{self.desc}: loading {name}",
                                                "MB", bool(enabled))
        if bar.enabled:
            bar.update_to(done / 1e6)
            if done >= total:
                bar.close()
                bar.enabled = False  # closed: later calls are no-ops

    def callback(self, done: float, total: float) -> None:
        if self.bar is None:
            self.bar = _Progress(total, self.desc, "s", _progress_for(self.flag, total))
        self.bar.update_to(done)

    def __enter__(self) -> _BarContext:
        return self

    def __exit__(self, *exc) -> None:
        for bar in self._loads.values():  # an interrupt while loading
            bar.discard()
        if self.bar is not None:
            self.bar.close()


def _run_folder(args: argparse.Namespace, logs: list[Path]) -> int:
    from fusion.jobs import replay as job

    out_dir: Path = args.output
    if out_dir.suffix.lower() in OUTPUT_FORMATS and not out_dir.is_dir():
        raise CommandError(f"{out_dir}: for a folder of logs, -o is the folder to write one "
                           f"output per log into (choose the type with --format)")
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"{out_dir}: exists and is not a folder")
    if args.plot is not None:
        job.check_plot_output()
        if args.plot.exists() and not args.plot.is_dir():
            raise CommandError(f"{args.plot}: for a folder of logs, --plot is a folder")
    workers = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if workers < 1:
        raise CommandError(f"--jobs must be >= 1, got {workers}")
    workers = min(workers, len(logs))
    cluster = None
    if args.cluster is not None:
        from fusion.jobs import cluster as dask_jobs

        cluster = dask_jobs.parse_cluster(args.cluster)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.plot is not None:
        args.plot.mkdir(parents=True, exist_ok=True)
    ext = {"csv": ".csv", "mcap": ".mcap", "jsonl": ".jsonl"}[args.format or "csv"]
    work = [job.LogJob(str(p), str(out_dir / (p.name + ext)), not args.level,
                       None if args.plot is None else str(args.plot / (p.name + ".png")),
                       one_pass=args.one_pass, imu_lag=args.imu_lag)
            for p in logs]
    bar = _Progress(len(work), f"replay {len(work)} logs", "logs",
                    _stderr_is_tty() if args.progress is None else args.progress,
                    interval=0.0)
    done = [0]

    def on_done(_job, _result) -> None:
        done[0] += 1
        bar.update_to(done[0])

    if cluster is None:
        where = f"{workers} worker process{'es' if workers != 1 else ''}"
        try:
            results = job.replay_logs(work, workers, on_done)
        finally:
            bar.close()
    else:
        where = cluster.describe()
        try:
            with dask_jobs.dask_client(cluster) as client:
                n_workers, threads = dask_jobs.cluster_threads(client)
                if threads > n_workers:
                    print(f"warning: the cluster's {n_workers} workers run {threads} threads; "
                          "replay tasks hold the GIL, start workers with --nthreads 1",
                          file=sys.stderr)
                results = dask_jobs.replay_logs_cluster(work, client, on_done)
        finally:
            bar.close()
    failed = _print_table(work, results, where)
    warned = []
    for w in work:
        status, value = results[w.source]
        for note in value.notes if status == "ok" else ():
            print(f"warning: {Path(w.source).name}: {note}")
        if status == "ok" and value.warnings:
            warned.extend(value.warnings)
            for tw in value.warnings:
                print(f"warning: {Path(w.source).name}: inputs disagree ({tw.name}): "
                      f"{tw.message}")
    if failed:
        return 1
    return _exit_status(args, warned)


#: The tracks a bag's replay compares with GPS (fusion.jobs.replay.replay_bag) and their labels.
_GPS_TRACKS = (("fused", "fused"), ("bag odometry", "the bag's odometry"),
               ("gyro at stops", "gyro at stops"))


def _print_gps(topic: str, fixes, gps) -> None:
    """The tracks' RMSE against the GPS fixes (:class:`fusion.evaluation.gps.GpsComparison`)."""
    from fusion.evaluation.gps import LAG_MAX, OUTLIER_FACTOR, OUTLIER_FLOOR, OUTLIER_WINDOW

    skipped = f", {fixes.no_fix} without a fix left out" if fixes.no_fix else ""
    if fixes.out_of_order:
        print(f"warning: GPS fixes out of order in the bag (sorted): {fixes.out_of_order}")
    first, last = gps.span
    print(f"against GPS ({topic}: {len(fixes)} fixes{skipped}; {gps.compared} compared, "
          f"{first:.3f}-{last:.3f} s), position RMSE after one SE(2) alignment each (the GPS's "
          f"own error included):")
    for name, label in _GPS_TRACKS:
        every = (f"  ({gps.rmse_all[name]:.2f} m with them)" if gps.outliers else "")
        print(f"  {label + ':':<20} {gps.rmse[name]:.2f} m{every}")
    print("  (gyro at stops: the gyro's vertical axis, its bias re-learnt at each stop, with "
          "the odometry's speed)")
    if gps.lag:
        why = ("a receiver's or its driver's latency, or the odometry stamped that much early"
               if gps.lag > 0 else "the odometry stamped that much late, or the fixes on "
               "another clock")
        recorded = ", ".join(f"{label} {gps.rmse_at_stamps[name]:.2f} m"
                             for name, label in _GPS_TRACKS)
        print(f"  (the fixes fit the tracks best, each with its scale fitted, taken as stamped "
              f"{abs(gps.lag):.2f} s {'late' if gps.lag > 0 else 'early'} ({why}), and were "
              f"compared so; at their stamps as recorded: {recorded})")
    if gps.lag_beyond:
        print(f"  (the fixes fit the tracks better {LAG_MAX:g} s off their stamps than on them, "
              "and best further off, beyond the lag searched: the GPS stamped on another "
              "clock? compared at the stamps as recorded)")
    if gps.outliers:
        print(f"  ({gps.outliers} of the {gps.compared} fixes left out: each jumped away "
              f"from every track, its residual more than {OUTLIER_FLOOR:g} m and "
              f"{OUTLIER_FACTOR:g} times the median off its neighbours' within "
              f"{OUTLIER_WINDOW:g} s: multipath or a receiver's jump)")


def run_bag(args: argparse.Namespace) -> int:
    """``fusion replay BAG --imu-topic T --odom-topic T``: the bag's IMU messages and its
    odometry twists through the pipeline (:func:`fusion.jobs.replay.replay_bag`)."""
    from fusion.io.robot_toml import read_robot_toml
    from fusion.jobs import replay as job

    path: Path = args.input
    if not (args.imu_topic and args.odom_topic):
        from fusion.io.bags import bag_topics

        topics = bag_topics(path)
        present = ", ".join(f"{t} ({typ})" for t, (typ, _n) in sorted(topics.items()))
        raise CommandError(f"{path}: a bag needs --imu-topic (sensor_msgs/Imu) and "
                           "--odom-topic (nav_msgs/Odometry); its topics: "
                           f"{present or 'none'}")
    if args.gps_topic in (args.imu_topic, args.odom_topic):
        other = "--imu-topic" if args.gps_topic == args.imu_topic else "--odom-topic"
        raise CommandError(f"--gps-topic {args.gps_topic} is also the {other}; give the "
                           "sensor_msgs/NavSatFix topic")
    robot = read_robot_toml(args.robot) if args.robot is not None else None
    with _BarContext(args.progress, path.name) as bar:
        r = job.replay_bag(path, args.output, imu_topic=args.imu_topic,
                           odom_topic=args.odom_topic, fix_topic=args.gps_topic,
                           stamps=args.stamps or "header", robot=robot,
                           imu_mount_rpy=args.imu_mount_rpy, tilt=not args.level,
                           plot=args.plot, progress=bar.callback, one_pass=args.one_pass,
                           imu_lag=args.imu_lag)
    imu, odom, table, stats, own = r.imu, r.odom, r.table, r.stats, r.own
    written = (f"{table.shape[0]} rows" if args.output.suffix.lower() == ".csv"
               else f"{stats.records} records")
    print(f"{path}: {len(imu)} IMU messages ({imu.frame_id or 'no frame_id'}), {len(odom)} "
          f"odometry messages ({odom.frame_id} -> {odom.child_frame_id}) -> {args.output} "
          f"({written})")
    for note in r.notes:
        print(f"note: {note}")
    if r.motion is not None and r.motion.note:
        print(f"note: {r.motion.note}")
    if r.moving_start is not None:
        print(f"note: {r.moving_start.note}")
    if imu.out_of_order or odom.out_of_order:
        print(f"warning: messages out of order in the bag (sorted): IMU {imu.out_of_order}, "
              f"odometry {odom.out_of_order}")
    for text in r.coverage:
        print(f"warning: {text}")
    dropped = (stats.imu_out_of_order + stats.imu_invalid_stamp, stats.twist_out_of_order
               + stats.twist_invalid_stamp)
    if any(dropped):
        print(f"warning: not fused for a stamp not after the previous one or not finite: "
              f"{dropped[0]} IMU messages, {dropped[1]} odometry twists")
    last = table[-1]
    print(f"final pose: x {last[1]:.3f} m, y {last[2]:.3f} m, yaw {math.degrees(last[3]):.2f}"
          f" deg; path {job.distance_travelled(table):.2f} m")
    ekf = r.pipeline.ekf
    print(f"gyro bias {math.degrees(ekf.gyro_bias):+.4f} deg/s; ZUPTs {stats.zupts}, slip "
          f"(twist/gyro disagreement) {stats.slips}, turning twists whose yaw rate was not "
          f"trusted {stats.wheel_rate_distrusted} (near-zero ones fused as driving straight "
          f"{stats.straight_frames}), encoder faults (zero twist while the IMU "
          f"moved, not fused) {stats.encoder_faults} (the next twist catching up their "
          f"counts {stats.catch_ups}), gyro bias relearnt at a stop "
          f"{stats.bias_relearnt}, gyro spikes not fused {stats.gyro_spikes}, IMU gaps "
          f"{stats.attitude_gaps}, speeds forgotten after a "
          f"gap {stats.speed_resets}, invalid {ekf.stats['invalid']}")
    print(f"the bag's own odometry ({args.odom_topic}) final pose from its start: x "
          f"{own[-1, 0]:.3f} m, y {own[-1, 1]:.3f} m, yaw {math.degrees(own[-1, 2]):.2f} deg")
    if r.gps is not None:
        _print_gps(args.gps_topic, r.fixes, r.gps)
    if r.gps_note:
        print(f"warning: {r.gps_note}")
    _print_warnings(r.warnings)
    return _exit_status(args, r.warnings)
