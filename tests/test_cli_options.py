"""No option of ``fusion`` is ever ignored (issue 15, Build 1): walking every sub-command's
argparse parser, each option either changes the output for each input kind it is given with,
or is refused there with a message saying where it applies.

The table below is the specification: ``TABLE[command][option]`` lists one row per input kind,
each :func:`changes` (the output differs from the same command without the option) or
:func:`refused` (exit status 2 and the message). ``test_every_option_is_in_the_table`` fails
for an option of the parser that has no row, so a new option needs its row.

Live commands (``run``, ``demo``: their output differs from run to run) also have rows in
``LIVE``: each an :class:`Effect`, a check on the output that must hold with the option and fail
without it (both runs are made), so the option's effect is stated, not just "different".

Adding a command (e.g. ``replay``): remove it from ``NOT_YET`` and add its rows to ``TABLE``
(and its input kinds to ``inputs``).
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from fusion.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]

#: Commands whose rows are still to be written, with the reason (each is a gap, not a pass).
NOT_YET: dict[str, str] = {}


@dataclass(frozen=True)
class Row:
    kind: str  # the input kind (a key of ``inputs``)
    argv: tuple[str, ...]  # the option and its value(s), added to the kind's command line
    refused: str | None = None  # None: the output must change; else the error message
    both: tuple[str, ...] = ()  # arguments for both runs (the option's effect needs them)
    status: int = 0  # the exit status with the option (not refused)


def changes(kind: str, *argv: str, both: tuple[str, ...] = ()) -> Row:
    return Row(kind, argv, both=both)


def refused(kind: str, message: str, *argv: str) -> Row:
    return Row(kind, argv, message)


def exits(kind: str, status: int, *argv: str) -> Row:
    """The option's effect on this input is the exit status (e.g. --strict on data whose
    inputs disagree); the output must still differ (the status is part of it)."""
    return Row(kind, argv, status=status)


MONITOR = ("chassis", "monitor", "--wheel-distance", "1.0", "--speed-ratio", "1e-3")

RUN_FILE = ("run", "--imu", "sim", "--chassis", "sim", "--duration", "1", "--status", "0",
            "--publish", "jsonl:f.jsonl")

#: what `fusion replay` says when a bag's option is given for another input
BAGS_ONLY = "--imu-topic/--odom-topic/--gps-topic/--stamps are for ROS bags"
BAG_TOPICS = ("--imu-topic", "/imu/data", "--odom-topic", "/jackal_velocity_controller/odom")


#: command -> input kind -> the command line without the option under test
BASE = {
    "attitude": {"broad": ["attitude", "trial.mat", "-o", "att.csv"],
                 "csv": ["attitude", "imu.csv", "-o", "att.csv"],
                 "csv+mag": ["attitude", "imu9.csv", "-o", "att.csv"]},
    "imu": {"sim": ["imu", "--sim", "--count", "30", "-o", "stream.csv"],
            "sim raw": ["imu", "--sim", "--count", "30", "--raw", "-o", "raw.csv"]},
    "imu-calibrate": {"raw": ["imu-calibrate", "rest.csv", "-o", "cal.json"]},
    "calibrate odometry": {"logdir": ["calibrate", "odometry", "run1"]},
    "calibrate umbmark": {"squares": ["calibrate", "umbmark", "--cw", "cw", "--ccw", "ccw",
                                      "--side", "2"]},
    "calibrate gyro-scale": {"turns": ["calibrate", "gyro-scale", "turns", "--turns", "3"]},
    "chassis decode": {"capture": ["chassis", "decode", "capture.bin"]},
    "chassis encode": {"ticks": ["chassis", "encode", "100", "-300"]},
    "synth": {"mission": ["synth", "out", "--duration", "12"],
              "square": ["synth", "out", "--scenario", "square"],
              "figure8": ["synth", "out", "--scenario", "figure8"]},
    "tune": {"logs": ["tune", "odometry", "run1", "cw", "ccw", "--budget", "4"],
             "broad": ["tune", "attitude", "trial.mat", "trial.mat", "--budget", "2"]},
    "replay": {"logdir": ["replay", "run1", "-o", "f.csv"],
               "capture": ["replay", "wheels.uart2", "-o", "f.csv", "--robot",
                           "run1/robot.toml"],
               "bag": ["replay", "first8s.bag", *BAG_TOPICS, "-o", "f.csv"],
               "folder": ["replay", "logs", "-o", "out", "--jobs", "1"],
               "moving": ["replay", "moving", "-o", "f.csv"]},
    "demo": {"demo": ["demo", "--out", "d", "--speed", "20"]},
    # the simulated board (fixture ``board``) at inputs/data and inputs/debug, its wheels at
    # 400 and 0 ticks per 0.04 s period while the monitor runs (a tight left turn)
    "chassis monitor": {"board": [*MONITOR, "--port", "data", "--duration", "0.6"],
                        "no port": [*MONITOR, "--port", "nope", "--duration", "0.3",
                                    "--open-timeout", "1"]},
    "chassis pid": {"board": ["chassis", "pid", "get", "--port", "debug"],
                    "no reply": ["chassis", "pid", "get", "--port", "data", "--timeout",
                                 "1"]},
    "chassis step": {"board": ["chassis", "step", "--port", "data", "--ticks", "300",
                               "--duration", "1", "--csv", "s.csv"],
                     "no port": ["chassis", "step", "--port", "nope", "--ticks", "300",
                                 "--duration", "0.5", "--open-timeout", "1"]},
    "run": {"sim": ["run", "--imu", "sim", "--chassis", "sim", "--duration", "1"],
            "sim file": [*RUN_FILE],
            # the IMU's mount configured upside down without tilt compensation: the gyro
            # turns the other way than the wheels (tests/test_trust.py's case, live)
            "flipped": [*RUN_FILE, "--duration", "2", "--speed", "8", "--config",
                        "flipped.toml"],
            "no imu": ["run", "--imu", "none", "--chassis", "sim", "--duration", "1"]},
}

TABLE: dict[str, dict[str, list[Row]]] = {
    "attitude": {
        "--output": [changes(k, "-o", "other.csv") for k in ("broad", "csv", "csv+mag")],
        "--axes": [changes("broad", "--axes", "9"), changes("csv+mag", "--axes", "9"),
                   refused("csv", "--axes 9 needs magnetometer columns", "--axes", "9")],
        "--filter": [changes(k, "--filter", "mahony") for k in ("broad", "csv", "csv+mag")],
        "--offline": [*(changes(k, "--offline") for k in ("broad", "csv", "csv+mag")),
                      refused("csv", "--offline is a Keel mode", "--offline", "--filter",
                              "mahony")],
        "--kp": [*(changes(k, "--kp", "2", both=("--filter", "mahony"))
                   for k in ("broad", "csv", "csv+mag")),
                 refused("csv", "--kp: Mahony-only option(s); add --filter mahony", "--kp", "2")],
        "--ki": [*(changes(k, "--ki", "0.3", both=("--filter", "mahony"))
                   for k in ("broad", "csv", "csv+mag")),
                 refused("csv", "--ki: Mahony-only option(s)", "--ki", "0.3")],
        "--initial-quaternion": [
            *(changes(k, "--initial-quaternion", "0", "0", "0", "1", both=both)
              for k in ("broad", "csv", "csv+mag") for both in ((), ("--filter", "mahony"))),
            refused("csv", "cannot be used with --offline", "--initial-quaternion", "1", "0",
                    "0", "0", "--offline")],
    },
    "imu": {
        # --bus and --sim choose the input kind; --bus needs hardware (tests/test_mpu6050_cli)
        "--bus": [refused("sim", "not allowed with argument --sim", "--bus", "1")],
        "--sim": [changes("sim")],  # the kind itself
        "--address": [refused(k, "no ACK from address 0x69", "--address", "0x69")
                      for k in ("sim", "sim raw")],
        "--rate": [changes(k, "--rate", "200") for k in ("sim", "sim raw")],
        "--gyro-range": [changes(k, "--gyro-range", "2000") for k in ("sim", "sim raw")],
        "--accel-range": [changes(k, "--accel-range", "16") for k in ("sim", "sim raw")],
        # the simulated robot stands still for 5 s, then turns: the filters differ after that
        "--dlpf": [changes(k, "--dlpf", "6", both=("--count", "560")) for k in ("sim",
                                                                              "sim raw")],
        "--calibrate": [changes(k, "--calibrate") for k in ("sim", "sim raw")],
        "--calibrate-seconds": [changes(k, "--calibrate", "--calibrate-seconds", "1")
                                for k in ("sim", "sim raw")],
        "--calibration": [changes("sim", "--calibration", "cal.json"),
                          refused("sim raw", "--calibration does not apply to --raw",
                                  "--calibration", "cal.json")],
        "--save-calibration": [changes(k, "--calibrate", "--save-calibration", "c.json")
                               for k in ("sim", "sim raw")],
        "--no-fifo": [changes("sim", "--no-fifo")],
        "--raw": [changes("sim", "--raw")],
        "--count": [changes(k, "--count", "40") for k in ("sim", "sim raw")],
        "--realtime": [changes("sim", "--realtime", "--count", "3")],
        "--output": [changes(k, "-o", "other.csv") for k in ("sim", "sim raw")],
    },
    "imu-calibrate": {
        "--poses": [changes("raw", "--poses", "poses.csv")],
        "--output": [changes("raw", "-o", "other.json")],
    },
    "calibrate odometry": {
        "--distance": [changes("logdir", "--distance", "20")],
        "--use-truth": [changes("logdir", "--use-truth"),
                        refused("logdir", "give --distance or --use-truth, not both",
                                "--use-truth", "--distance", "20")],
        "--window": [changes("logdir", "--window", "50")],
        "--level": [changes("logdir", "--level")],
        "--imu-lag": [changes("logdir", "--imu-lag", "0.3")],
        # run1's track is a few per cent off robot.toml's: beyond 0.1 % it is refused
        "--max-change": [refused("logdir", "beyond max_change (0.1 %)", "--max-change",
                                 "0.1")],
        "--write": [changes("logdir", "--write", "robot-calibrated.toml")],
    },
    "calibrate umbmark": {
        # the truth says which way each square went, and how long its side was
        "--cw": [refused("squares", "the run belongs under --ccw", "--cw", "cw", "ccw")],
        "--ccw": [refused("squares", "the run belongs under --cw", "--ccw", "ccw", "cw")],
        "--side": [changes("squares", "--side", "2.2"),
                   refused("squares", "a square of side 4 m (--side) is 16 m", "--side",
                           "4")],
    },
    "calibrate gyro-scale": {
        # the last --turns counts: a miscount is refused with both counts
        "--turns": [refused("turns", "but +2 were declared", "--turns", "2")],
        "--mark-std": [changes("turns", "--mark-std", "5")],
        "--write": [changes("turns", "--write", "robot-gyro.toml")],
    },
    "chassis decode": {
        "--output": [changes("capture", "-o", "ticks.csv")],
        "--max-ticks": [changes("capture", "--max-ticks", "200")],
        "--loose-sign": [changes("capture", "--loose-sign")],
    },
    "chassis encode": {},
    "synth": {
        "--scenario": [refused("mission", "--duration applies to --scenario mission only",
                               "--scenario", "square"),
                       changes("square", "--scenario", "figure8"),
                       refused("square", "--scenario turns needs --simulator physics",
                               "--scenario", "turns"),
                       changes("figure8", "--scenario", "square")],
        "--direction": [refused("mission", "--direction applies to --scenario square only",
                                "--direction", "cw"),
                        changes("square", "--direction", "cw"),
                        refused("figure8", "--direction applies to --scenario square only",
                                "--direction", "cw")],
        "--side": [refused("mission", "--side applies to --scenario square only",
                           "--side", "2"),
                   changes("square", "--side", "2"),
                   refused("figure8", "--side applies to --scenario square only", "--side",
                           "2")],
        "--duration": [changes("mission", "--duration", "15"),
                       refused("square", "--duration applies to --scenario mission only",
                               "--duration", "15"),
                       refused("figure8", "--duration applies to --scenario mission only",
                               "--duration", "15")],
        "--seed": [changes(k, "--seed", "7") for k in ("mission", "square", "figure8")],
        # the physics simulator: its own options refused with the kinematic one (the
        # kinematic options under --simulator physics have no rows yet)
        "--simulator": [changes("mission", "--simulator", "physics"),
                        refused("square", "--simulator physics runs --scenario mission or "
                                "turns", "--simulator", "physics"),
                        refused("figure8", "--simulator physics runs --scenario mission or "
                                "turns", "--simulator", "physics")],
        # a gyro-scale calibration run is the physics simulator's
        "--turns": [refused(k, "--turns applies to --scenario turns only", "--turns", "3")
                    for k in ("mission", "square", "figure8")],
        **{opt: [refused(k, f"{opt} applies to --simulator physics only", *argv)
                 for k in ("mission", "square", "figure8")]
           for opt, argv in (("--errors", ("--errors", "plain")),
                             ("--with", ("--with", "vibration")),
                             ("--without", ("--without", "vibration")),
                             ("--dead-encoder", ("--dead-encoder", "8")),
                             ("--moving-start", ("--moving-start",)),
                             ("--truth-rate", ("--truth-rate", "100")))},
        "--separation-error": [changes(k, "--separation-error", "0.1")
                               for k in ("mission", "square", "figure8")],
        "--radius-mismatch": [changes(k, "--radius-mismatch", "0.05")
                              for k in ("mission", "square", "figure8")],
        "--gyro-bias": [changes(k, "--gyro-bias", "2") for k in ("mission", "square",
                                                                  "figure8")],
        # (the first seconds of a mission stand still: the patches fall in the driving)
        "--slip-patches": [changes("mission", "--slip-patches", "0", both=("--duration", "40")),
                           refused("square", "--slip-patches applies to --scenario mission",
                                   "--slip-patches", "1"),
                           refused("figure8", "--slip-patches applies to --scenario mission",
                                   "--slip-patches", "1")],
        "--no-truth": [changes(k, "--no-truth") for k in ("mission", "square", "figure8")],
    },
    "tune": {
        "--robot": [changes("logs", "--robot", "robot-wide.toml"),
                    changes("broad", "--robot", "robot-wide.toml")],
        "--folds": [changes("logs", "--folds", "2")],
        "--budget": [changes("logs", "--budget", "6")],
        "--output": [changes("logs", "-o", "tuned.toml"),
                     refused("broad", "-o for the attitude target needs --robot", "-o",
                             "tuned.toml"),
                     changes("broad", "-o", "tuned.toml", both=("--robot", "robot-wide.toml"))],
        "--jobs": [changes("logs", "--jobs", "2")],
        # (a local cluster's start-up costs seconds: tests/test_cluster_replay.py runs tune
        # on Dask workers)
        "--cluster": [refused("logs", "--cluster and --jobs exclude each other", "--cluster",
                              "local:1", "--jobs", "2")],
    },
    "replay": {
        "--output": [*(changes(k, "-o", "g.csv") for k in ("logdir", "capture", "bag")),
                     changes("folder", "-o", "out2")],
        "--format": [changes("folder", "--format", "jsonl"),
                     *(refused(k, "--format applies to a folder of logs", "--format", "jsonl")
                       for k in ("logdir", "capture", "bag"))],
        "--level": [*(changes(k, "--level") for k in ("logdir", "bag", "folder")),
                    refused("capture", "--level does not apply to a DATA-uart2 capture",
                            "--level")],
        "--plot": [*(changes(k, "--plot", "p.png") for k in ("logdir", "capture", "bag")),
                   changes("folder", "--plot", "plots")],
        # --progress/--no-progress (stderr is no terminal here: the default is quiet)
        "--no-progress": [*(changes(k, "--progress") for k in ("logdir", "capture", "bag",
                                                               "folder")),
                          *(changes(k, "--no-progress", both=("--progress",))
                            for k in ("logdir", "capture", "bag", "folder"))],
        # "moving": run1 from 10 s on, driving from its first row (first stop at 45 s);
        # where the robot starts at rest there is no second pass to leave out
        "--one-pass": [changes("moving", "--one-pass"),
                       refused("capture", "--one-pass does not apply to a DATA-uart2 capture",
                               "--one-pass")],
        # a lag given moves the IMU's stamps (auto, the default, finds none on these inputs)
        "--imu-lag": [*(changes(k, "--imu-lag", "0.3") for k in ("logdir", "bag", "folder")),
                      refused("capture", "--imu-lag does not apply to a DATA-uart2 capture",
                              "--imu-lag", "0.3")],
        # the folder's base runs with --jobs 1: two worker processes say so in the table
        "--jobs": [changes("folder", "--jobs", "2"),
                   *(refused(k, "--jobs applies to a folder of logs only", "--jobs", "2")
                     for k in ("logdir", "capture", "bag"))],
        # other.toml: another wheel_distance and IMU mount than run1/robot.toml's
        "--robot": [*(changes(k, "--robot", "other.toml") for k in ("logdir", "capture",
                                                                    "bag")),
                    refused("folder", "--robot applies to one log directory", "--robot",
                            "other.toml")],
        # its effect is the exit status where the inputs disagree: the bag's first 8 s do
        # (68 % slip; tests/test_trust.py); where they agree it changes nothing by design
        "--strict": [exits("bag", 3, "--strict")],
        **{opt: [*(refused(k, BAGS_ONLY, opt, value) for k in ("logdir", "capture", "folder")),
                 refused("bag", "no topic '/nope'; topics present: /imu/data", opt, "/nope")]
           for opt, value in (("--imu-topic", "/imu/data"),
                              ("--odom-topic", "/jackal_velocity_controller/odom"))},
        # the bundled bag has no GPS: its effect on a bag with one is tests/test_gps_reference.py
        "--gps-topic": [*(refused(k, BAGS_ONLY, "--gps-topic", "/gps/fix")
                          for k in ("logdir", "capture", "folder")),
                        refused("bag", "no topic '/nope'; topics present: /imu/data",
                                "--gps-topic", "/nope"),
                        refused("bag", "--gps-topic /imu/data is also the --imu-topic",
                                "--gps-topic", "/imu/data")],
        # the bag's record times are not its header stamps (tests/test_logs_bags.py: a bag
        # whose driver left every header stamp at zero)
        "--stamps": [changes("bag", "--stamps", "bag"),
                     *(refused(k, BAGS_ONLY, "--stamps", "bag")
                       for k in ("logdir", "capture", "folder"))],
        "--imu-mount-rpy": [
            *(changes(k, "--imu-mount-rpy", "0", "0.1", "0.2") for k in ("logdir", "bag")),
            refused("capture", "--imu-mount-rpy does not apply to a DATA-uart2 capture",
                    "--imu-mount-rpy", "0", "0.1", "0.2"),
            refused("folder", "--imu-mount-rpy applies to one log directory",
                    "--imu-mount-rpy", "0", "0.1", "0.2")],
        # (a local cluster's start-up costs seconds: tests/test_cluster_replay.py replays a
        # folder on Dask workers, byte for byte against the serial replay)
        "--cluster": [refused("folder", "--cluster and --jobs exclude each other",
                              "--cluster", "local:1", "--jobs", "2"),
                      *(refused(k, "--cluster applies to a folder of logs only",
                                "--cluster", "local:1") for k in ("logdir", "capture", "bag"))],
    },
    "run": {  # its refusals (the rows that change the output are to come: NOT_YET)
        "--address": [refused("sim", "--address applies to --imu i2c:N only",
                              "--address", "0x69")],
        "--baudrate": [refused("sim", "--baudrate applies to a real --chassis port only",
                               "--baudrate", "57600")],
        "--rate": [refused("no imu", "--rate sets the IMU sample rate", "--rate", "200")],
        "--calibration": [refused("no imu", "--calibration is an IMU calibration",
                                  "--calibration", "cal.json")],
        "--speed": [refused("sim", "--speed must be >= 0.1 and <= 20.0", "--speed", "50")],
    },
}


def _commands(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, list[str]]:
    """Every (sub-)command's name and its options (long option strings, -h and positionals
    left out), walking nested sub-parsers."""
    out: dict[str, list[str]] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.update(_commands(sub, f"{prefix} {name}".strip()))
    if prefix and not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions):
        out[prefix] = [max(a.option_strings, key=len) for a in parser._actions
                       if a.option_strings and not isinstance(a, argparse._HelpAction)]
    return out


COMMANDS = _commands(build_parser())


def test_every_option_is_in_the_table() -> None:
    missing = [f"{cmd} {opt}" for cmd, opts in COMMANDS.items() for opt in opts
               if cmd not in NOT_YET and opt not in TABLE.get(cmd, {})
               and opt not in LIVE.get(cmd, {})]
    assert missing == [], "options without a row in TABLE: " + ", ".join(missing)
    unknown = [f"{cmd} {opt}" for table in (TABLE, LIVE) for cmd, rows in table.items()
               for opt in rows if opt not in COMMANDS.get(cmd, [])]
    assert unknown == [], "rows for options the parser does not have: " + ", ".join(unknown)
    for cmd in COMMANDS:
        if cmd not in NOT_YET:
            assert cmd in BASE or not COMMANDS[cmd], f"{cmd}: no input kinds in BASE"


def test_the_gaps_are_named() -> None:
    """What is not covered yet is listed (NOT_YET), each a real command of the parser."""
    assert set(NOT_YET) <= set(COMMANDS) | {"replay"}


CASES = [(cmd, opt, row) for cmd, rows in TABLE.items() for opt, rs in rows.items()
         for row in rs]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Every input kind's files, made once: small, from the bundled data or the simulators."""
    from fusion.evaluation.synthetic import degraded_mission, simulate, square
    from fusion.io.logdir import write_synthetic_run

    d = tmp_path_factory.mktemp("inputs")
    (d / "trial.mat").symlink_to(ROOT / "datasets" / "broad" / "24_disturbed_tapping_A.mat")
    rng = np.random.default_rng(3)
    n = 300
    t = np.arange(n) * 0.01
    gyro = rng.normal(0, 0.02, (n, 3)) + np.array([0.0, 0.0, 0.3])
    accel = rng.normal(0, 0.05, (n, 3)) + np.array([0.3, -0.2, 9.8])
    mag = rng.normal(0, 0.5, (n, 3)) + np.array([20.0, 0.0, -40.0])
    np.savetxt(d / "imu.csv", np.column_stack([t, gyro, accel]), delimiter=",", comments="",
               header="t,gx,gy,gz,ax,ay,az")
    np.savetxt(d / "imu9.csv", np.column_stack([t, gyro, accel, mag]), delimiter=",",
               comments="", header="t,gx,gy,gz,ax,ay,az,mx,my,mz")
    raw = ROOT / "datasets" / "mpu6050_raw"
    (d / "rest.csv").symlink_to(raw / "imu_static_test.csv")
    (d / "poses.csv").symlink_to(raw / "example_data_calibration.csv")
    from fusion.calibration.imu import ImuCalibration
    from fusion.io.imu_calibration import save_imu_calibration

    save_imu_calibration(ImuCalibration(gyro_bias=np.array([0.01, -0.02, 0.03])),
                         d / "cal.json")
    write_synthetic_run(d / "run1", degraded_mission(seed=2, duration=120.0))
    assert main(["synth", str(d / "turns"), "--simulator", "physics", "--scenario", "turns",
                 "--turns", "3", "--seed", "1"]) == 0
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT, EncoderModel, ImuModel

    for direction in ("cw", "ccw"):
        run_ = simulate(square(side=2.0, direction=direction), EXAMPLE_ROBOT,
                        ImuModel(), EncoderModel(separation_error=0.03), seed=1)
        write_synthetic_run(d / direction, run_)
    from dataclasses import replace

    from fusion.io.robot_toml import write_robot_toml

    write_robot_toml(d / "robot-wide.toml", replace(EXAMPLE_ROBOT, wheel_distance=0.33))
    # frames with 250 ticks (above --max-ticks 200) and one whose left sign byte is 0x02
    # (only --loose-sign reads it as positive)
    from drivers.chassis import checksum, encode_wheel_frame

    frame = encode_wheel_frame(100, 250)
    loose = bytearray(encode_wheel_frame(-100, 120))
    loose[2] = 0x02  # left sign byte: neither 0 (negative) nor 1 (positive)
    loose[-1] = checksum(loose[:10])  # keep the checksum valid
    (d / "capture.bin").write_bytes(frame + bytes(loose) + frame)
    # replay's inputs: run1's wheel frames as a raw capture, a folder of two logs, another
    # robot.toml, and the bundled bag's first 8 s
    ticks = np.loadtxt(d / "run1" / "wheels.csv", delimiter=",", skiprows=1, usecols=[1, 2],
                       dtype=np.int64)
    (d / "wheels.uart2").write_bytes(b"".join(encode_wheel_frame(int(a), int(b))
                                               for a, b in ticks))
    (d / "moving").mkdir()
    shutil.copy(d / "run1" / "robot.toml", d / "moving")
    for name in ("imu.csv", "wheels.csv"):  # the rows from 10 s on (no truth)
        head, *rows = (d / "run1" / name).read_text().splitlines()
        kept = [r for r in rows if float(r.split(",")[0]) >= 10.0]
        (d / "moving" / name).write_text("\n".join([head, *kept]) + "\n")
    (d / "logs").mkdir()
    for name in ("cw", "ccw"):
        (d / "logs" / name).symlink_to(d / name)
    text = (d / "run1" / "robot.toml").read_text()
    assert "wheel_distance = 0.3 " in text and "imu_mount_rpy = [0.0, 0.0, 0.0]" in text
    (d / "other.toml").write_text(text.replace("wheel_distance = 0.3 ", "wheel_distance = 0.33 ")
                                  .replace("[0.0, 0.0, 0.0]", "[0.0, 0.0, 0.3]"))
    (d / "rate5.toml").write_text("[publish]\nrate_hz = 5.0\n")
    (d / "board.toml").write_text("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\n"
                                  "encode_sampling_time = 0.04\n")
    (d / "flipped.toml").write_text((d / "board.toml").read_text()
                                    + "[imu]\ntilt = false\n[frames]\n"
                                      "imu_mount_rpy = [3.14159, 0.0, 0.0]\n")
    save_imu_calibration(ImuCalibration(gyro_bias=np.array([0.1, 0.0, 0.0])),
                         d / "cal_x.json")
    try:
        _first_seconds(ROOT / "datasets" / "rosbag" / "jackal_sim_test2.bag",
                       d / "first8s.bag", 8.0)
    except ImportError:  # no rosbags (the ros extra): the bag rows skip
        pass
    return d


def _first_seconds(src: Path, dst: Path, seconds: float) -> None:
    """The messages of the ROS 1 bag ``src`` in its first ``seconds``, copied to ``dst``."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(src) as reader, Writer(dst) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                             md5sum=c.digest)
                 for c in reader.connections}
        for conn, stamp, raw in reader.messages():
            if stamp - reader.start_time > seconds * 1e9:
                break
            writer.write(conns[conn.id], stamp, raw)


def _run(argv: list[str], cwd: Path, capsys, monkeypatch) -> tuple[int, str, dict[str, bytes]]:
    monkeypatch.chdir(cwd)
    before = {p.name for p in cwd.iterdir()}
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse refuses (exit status 2, usage on stderr)
        rc = int(exc.code or 0)
    captured = capsys.readouterr()
    written = {str(p.relative_to(cwd)): p.read_bytes() for p in sorted(cwd.rglob("*"))
               if p.is_file() and p.relative_to(cwd).parts[0] not in before}
    for name in list(written):  # the next run starts from the inputs only
        (cwd / name).unlink()
    for p in sorted(cwd.iterdir()):
        if p.name not in before and p.is_dir():
            shutil.rmtree(p)
    return rc, captured.out + "\n--stderr--\n" + captured.err, written


@pytest.mark.parametrize(("cmd", "option", "row"), CASES,
                         ids=[f"{c} {o} [{r.kind}]" for c, o, r in CASES])
def test_option(cmd, option, row, inputs, capsys, monkeypatch) -> None:
    if "first8s.bag" in BASE[cmd][row.kind] and not (inputs / "first8s.bag").exists():
        pytest.skip("reading bags needs rosbags (pip install 'diffbot-fusion[ros]')")
    base = [*BASE[cmd][row.kind], *row.both]
    rc, out, files = _run([*base, *row.argv], inputs, capsys, monkeypatch)
    if row.refused is not None:
        assert rc == 2, out
        assert row.refused in out
        assert files == {}  # refused before writing anything
        return
    assert rc == row.status, out
    if not row.argv:  # the kind itself: it runs
        return
    key = tuple(base)
    if key not in _BASE_RUNS:  # the same command line gives the same output: run it once
        _BASE_RUNS[key] = _run(base, inputs, capsys, monkeypatch)
    rc0, out0, files0 = _BASE_RUNS[key]
    assert rc0 == 0, out0
    assert (rc, out, files) != (rc0, out0, files0), \
        f"{cmd} {' '.join(row.argv)} changed nothing"


#: Output of each base command line (the option-free run), by its arguments.
_BASE_RUNS: dict[tuple[str, ...], tuple[int, str, dict[str, bytes]]] = {}


# -- live commands: an effect each option must have -----------------------------------------


@dataclass(frozen=True)
class Effect:
    kind: str  # the input kind (a key of BASE[command])
    argv: tuple[str, ...]  # the option and its value(s)
    check: Callable[[int, str, dict[str, bytes]], bool]  # (status, output, files) -> holds
    what: str  # the effect, in words


def _records(files: dict[str, bytes], name: str = "f.jsonl") -> tuple[list[dict], dict]:
    """The records and the status record of a JSON lines output."""
    lines = [json.loads(x) for x in files.get(name, b"").decode().splitlines()]
    status = lines.pop()["status"] if lines and "status" in lines[-1] else {}
    return lines, status


def _median_dt(files: dict[str, bytes]) -> float:
    recs, _ = _records(files)
    return float(np.median(np.diff([r["t"] for r in recs]))) if len(recs) > 2 else 0.0


def _span(files: dict[str, bytes]) -> float:
    recs, _ = _records(files)
    return recs[-1]["t"] - recs[0]["t"] if recs else 0.0


def _imu_rate(files: dict[str, bytes]) -> float:
    c = _records(files)[1].get("counters", {})
    return c["imu_samples"] / c["gyro_time"] if c.get("gyro_time") else 0.0


def _mean_gyro_x(files: dict[str, bytes]) -> float:
    recs, _ = _records(files)
    return float(np.mean([r["angular_velocity"][0] for r in recs])) if recs else 0.0


LIVE: dict[str, dict[str, list[Effect]]] = {
    "run": {  # the sim's robot time runs at --speed times the wall clock
        "--config": [Effect("sim file", ("--config", "rate5.toml"),
                            lambda rc, out, f: rc == 0 and 0.15 < _median_dt(f) < 0.25,
                            "[publish] rate_hz = 5 from the file: records 0.2 s apart")],
        "--imu": [Effect("sim file", ("--imu", "none"),
                         lambda rc, out, f: rc == 0 and _records(f)[0] != []
                         and all(r["orientation"] is None for r in _records(f)[0]),
                         "no IMU: records without an attitude")],
        "--rate": [Effect("sim file", ("--rate", "50"),
                          lambda rc, out, f: rc == 0 and 40 < _imu_rate(f) < 60,
                          "the IMU samples at 50 Hz")],
        "--calibration": [Effect("sim file", ("--calibration", "cal_x.json"),
                                 lambda rc, out, f: rc == 0 and _mean_gyro_x(f) < -0.05,
                                 "a 0.1 rad/s x bias taken off the gyro")],
        "--chassis": [Effect("sim file", ("--chassis", "data", "--imu", "none", "--config",
                                          "board.toml"),
                             lambda rc, out, f: rc == 0 and "chassis port data open" in out
                             and len(_records(f)[0]) > 5,
                             "the wheel frames of a (simulated) board on a real pty")],
        "--publish": [Effect("sim file", ("--publish", "csv:g.csv"),
                             lambda rc, out, f: rc == 0 and "g.csv" in f and "f.jsonl" not in f,
                             "a CSV file instead of the JSON lines")],
        "--publish-rate": [Effect("sim file", ("--publish-rate", "5"),
                                  lambda rc, out, f: rc == 0 and 0.15 < _median_dt(f) < 0.25,
                                  "records 0.2 s apart")],
        "--duration": [Effect("sim file", ("--duration", "2.5"),
                              lambda rc, out, f: rc == 0 and _span(f) > 1.6,
                              "runs 2.5 s instead of 1 s")],
        "--speed": [Effect("sim file", ("--speed", "4"),
                           lambda rc, out, f: rc == 0 and _span(f) > 2.0,
                           "4 s of robot time per wall second")],
        "--status": [Effect("sim file", ("--status", "0.3"),
                            lambda rc, out, f: rc == 0
                            and out.count(" IMU samples, ") >= 2,
                            "status lines every 0.3 s, then the final one")],
        "--strict": [Effect("flipped", ("--strict",),
                            lambda rc, out, f: rc == 3 and "heading_divergence" in out,
                            "exit status 3: the gyro turns against the wheels")],
    },
    "demo": {
        "--out": [Effect("demo", ("--out", "e"),
                         lambda rc, out, f: rc == 0 and any(k.startswith("e/") for k in f)
                         and not any(k.startswith("d/") for k in f),
                         "the outputs in e/")],
        "--speed": [Effect("demo", ("--speed", "10"),
                           lambda rc, out, f: rc == 0 and "at 10x real time" in out,
                           "the mission runs at 10x")],
        "--no-plot": [Effect("demo", ("--no-plot",),
                             lambda rc, out, f: rc == 0 and "d/demo.mcap" in f
                             and "d/demo.png" not in f,
                             "no demo.png")],
    },
}

def _rows(out: str) -> NDArray[np.float64]:
    """The monitor's CSV lines (t,left,right,v_left,v_right,x,y,yaw) as an array."""
    lines = out.split("\n--stderr--\n")[0].splitlines()
    rows = [[float(v) for v in x.split(",")] for x in lines[1:] if x and x[0] != "#"]
    return np.array(rows).reshape(-1, 8)


def _speeds_are(out: str, m_per_tick_s: float) -> bool:
    r = _rows(out)
    return bool(len(r) > 3 and np.any(r[:, 1] != 0)
                and np.allclose(r[:, 3], r[:, 1] * m_per_tick_s, atol=1e-3)
                and np.allclose(r[:, 4], r[:, 2] * m_per_tick_s, atol=1e-3))


def _turns_by(out: str, wheel_distance: float) -> bool:
    """Each frame's heading change is (right - left) * 1e-3 m / wheel_distance."""
    r = _rows(out)
    dyaw = np.angle(np.exp(1j * np.diff(r[:, 7])))
    want = (r[1:, 2] - r[1:, 1]) * 1e-3 / wheel_distance
    return bool(len(r) > 3 and np.any(want != 0) and np.allclose(dyaw, want, atol=3e-4))


def _arc_steps(out: str) -> bool:
    """Each frame's step is the chord of an arc, d sin(a)/a with a = dyaw/2 (midpoint: d)."""
    r = _rows(out)
    d = (r[1:, 1] + r[1:, 2]) / 2 * 1e-3
    a = (r[1:, 2] - r[1:, 1]) * 1e-3 / 1.0 / 2
    chord = np.abs(d * np.sinc(a / np.pi))
    step = np.hypot(np.diff(r[:, 5]), np.diff(r[:, 6]))
    return bool(len(r) > 3 and np.any(np.abs(a) > 0.1)
                and np.allclose(step, chord, atol=3e-4))


def _step_csv(files: dict[str, bytes], name: str = "s.csv") -> NDArray[np.float64]:
    if name not in files:
        return np.zeros((0, 3))
    return np.loadtxt(io.StringIO(files[name].decode()), delimiter=",", skiprows=1, ndmin=2)


LIVE["chassis monitor"] = {
    "--port": [Effect("no port", ("--port", "data"),
                      lambda rc, out, f: rc == 0 and len(_rows(out)) > 3, "reads that port")],
    "--period": [Effect("board", ("--period", "0.02"),
                        lambda rc, out, f: rc == 0 and _speeds_are(out, 1e-3 / 0.02),
                        "speeds are ticks * speed_ratio / 0.02 s")],
    "--open-timeout": [Effect("no port", ("--open-timeout", "0.5"),
                              lambda rc, out, f: rc == 2 and " 0.5 s" in out,
                              "gives up on the missing port after 0.5 s")],
    "--wheel-distance": [Effect("board", ("--wheel-distance", "2.0"),
                                lambda rc, out, f: rc == 0 and _turns_by(out, 2.0),
                                "the heading turns by (right - left) travel / 2.0 m")],
    "--speed-ratio": [Effect("board", ("--speed-ratio", "2e-3"),
                             lambda rc, out, f: rc == 0 and _speeds_are(out, 2e-3 / 0.04),
                             "speeds are ticks * 2e-3 m / period")],
    "--duration": [Effect("board", ("--duration", "0.25"),
                          lambda rc, out, f: rc == 0 and 0 < len(_rows(out)) <= 9,
                          "about 0.25 s / 0.04 s frames, not 0.6 s worth")],
    "--interval": [Effect("board", ("--interval", "0.2"),
                          lambda rc, out, f: rc == 0 and len(_rows(out)) > 1
                          and np.diff(_rows(out)[:, 0]).min() > 0.15,
                          "lines 0.2 s apart, not every frame")],
    "--method": [Effect("board", ("--method", "arc"),
                        lambda rc, out, f: rc == 0 and _arc_steps(out),
                        "steps along arcs (0.4 rad per frame: 1.3 mm shorter than midpoint)")],
}
LIVE["chassis pid"] = {
    "--port": [Effect("board", ("--port", "data", "--timeout", "0.5"),
                      lambda rc, out, f: rc == 2 and "no PID reply from data" in out,
                      "asks that port (the data port does not answer)")],
    "--timeout": [Effect("no reply", ("--timeout", "0.5"),
                         lambda rc, out, f: rc == 2 and "within 0.5 s" in out,
                         "gives up after 0.5 s")],
    "--verbose": [Effect("board", ("--verbose",),
                         lambda rc, out, f: rc == 0 and "# [stm32 response:]" in out,
                         "echoes the board's other reply lines")],
}
LIVE["chassis step"] = {
    "--port": [Effect("no port", ("--port", "data"),
                      lambda rc, out, f: rc == 0 and "rise time" in out, "steps that port")],
    "--period": [Effect("board", ("--period", "0.02"),
                        lambda rc, out, f: rc == 0 and "50 expected at --period 0.02 s" in out
                        and "is --period 0.02 s the board's encoder sampling period?" in out,
                        "a 0.04 s board's frame count does not match: says so")],
    "--open-timeout": [Effect("no port", ("--open-timeout", "0.5"),
                              lambda rc, out, f: rc == 2 and " 0.5 s" in out,
                              "gives up on the missing port after 0.5 s")],
    "--ticks": [Effect("board", ("--ticks", "150"),
                       lambda rc, out, f: rc == 0
                       and abs(_step_csv(f)[-5:, 1].mean() - 150) < 5,
                       "the wheels settle at 150 ticks per period")],
    "--wheel": [Effect("board", ("--wheel", "left"),
                       lambda rc, out, f: rc == 0 and len(_step_csv(f)) > 5
                       and not _step_csv(f)[-5:, 2].any() and _step_csv(f)[-5:, 1].all(),
                       "only the left wheel turns (at the end: the right one stops)")],
    "--duration": [Effect("board", ("--duration", "0.5"),
                          lambda rc, out, f: rc == 0 and 4 <= len(_step_csv(f)) <= 16,
                          "about 0.5 s / 0.04 s frames, not 1 s worth")],
    "--csv": [Effect("board", ("--csv", "t.csv"),
                     lambda rc, out, f: rc == 0 and "t.csv" in f and "s.csv" not in f,
                     "the response in t.csv")],
}

LIVE_CASES = [(cmd, opt, e) for cmd, rows in LIVE.items() for opt, es in rows.items()
              for e in es]


@pytest.fixture(scope="module")
def board(inputs):
    """The simulated STM32 firmware on a real pseudo-terminal, its data port linked at
    ``inputs/data`` (a path as a user gives it)."""
    from drivers.sim.stm32 import PtyStm32

    sim = PtyStm32(data_link=str(inputs / "data"), debug_link=str(inputs / "debug")).start()
    yield sim
    sim.close()


@pytest.mark.live  # real time: run alone (pyproject's markers)
@pytest.mark.parametrize(("cmd", "option", "effect"), LIVE_CASES,
                         ids=[f"{c} {o} [{e.kind}]" for c, o, e in LIVE_CASES])
def test_live_option(cmd, option, effect, inputs, board, capsys, monkeypatch) -> None:
    if cmd == "demo":
        pytest.importorskip("matplotlib")  # the base run's demo.png
    if cmd == "chassis monitor":
        _drive(board, (400, 0))
    base = BASE[cmd][effect.kind]
    rc, out, files = _run([*base, *effect.argv], inputs, capsys, monkeypatch)
    assert effect.check(rc, out, files), f"{effect.what}: not seen in\n{out}"
    key = tuple(base)
    if key not in _BASE_RUNS:
        _BASE_RUNS[key] = _run(list(base), inputs, capsys, monkeypatch)
    rc0, out0, files0 = _BASE_RUNS[key]
    assert rc0 == (2 if effect.kind in ("no port", "no reply") else 0), out0
    assert not effect.check(rc0, out0, files0), \
        f"{effect.what}: holds without {option} too, so it shows nothing"


def _drive(board, target: tuple[int, int]) -> None:
    """Set the simulated board's wheel targets and let its PID settle (20 periods)."""
    import time

    board.sim.target = target
    p0 = board.sim.periods
    end = time.monotonic() + 10
    while board.sim.periods < p0 + 20 and time.monotonic() < end:
        time.sleep(0.02)
