"""No option of ``fusion`` is ever ignored (issue 15, Build 1): walking every sub-command's
argparse parser, each option either changes the output for each input kind it is given with,
or is refused there with a message saying where it applies.

The table below is the specification: ``TABLE[command][option]`` lists one row per input kind,
each :func:`changes` (the output differs from the same command without the option) or
:func:`refused` (exit status 2 and the message). ``test_every_option_is_in_the_table`` fails
for an option of the parser that has no row, so a new option needs its row.

Adding a command (e.g. ``replay``): remove it from ``NOT_YET`` and add its rows to ``TABLE``
(and its input kinds to ``inputs``).
"""

from __future__ import annotations

import argparse
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]

#: Commands whose rows are still to be written, with the reason (each is a gap, not a pass).
NOT_YET = {
    "replay": "the lead's rewrite adds replay's rows",
    "run": "live, seconds per run: only its refusals are rows so far",
    "demo": "about 10 s per run",
    "chassis monitor": "live on a pty: rows to be written",
    "chassis pid": "live on a pty: rows to be written",
    "chassis step": "live on a pty: rows to be written",
}


@dataclass(frozen=True)
class Row:
    kind: str  # the input kind (a key of ``inputs``)
    argv: tuple[str, ...]  # the option and its value(s), added to the kind's command line
    refused: str | None = None  # None: the output must change; else the error message
    both: tuple[str, ...] = ()  # arguments for both runs (the option's effect needs them)


def changes(kind: str, *argv: str, both: tuple[str, ...] = ()) -> Row:
    return Row(kind, argv, both=both)


def refused(kind: str, message: str, *argv: str) -> Row:
    return Row(kind, argv, message)


#: command -> input kind -> the command line without the option under test
BASE = {
    "attitude": {"broad": ["attitude", "trial.mat", "-o", "att.csv"],
                 "csv": ["attitude", "imu.csv", "-o", "att.csv"],
                 "csv+mag": ["attitude", "imu9.csv", "-o", "att.csv"]},
    "imu": {"sim": ["imu", "--sim", "--count", "30", "-o", "stream.csv"],
            "sim raw": ["imu", "--sim", "--count", "30", "--raw", "-o", "raw.csv"]},
    "imu-calibrate": {"raw": ["imu-calibrate", "rest.csv", "-o", "cal.json"]},
    "calibrate odometry": {"logdir": ["calibrate", "odometry", "run1"]},
    "calibrate umbmark": {"squares": ["calibrate", "umbmark", "--cw", "cw", "--ccw", "ccw"]},
    "chassis decode": {"capture": ["chassis", "decode", "capture.bin"]},
    "chassis encode": {"ticks": ["chassis", "encode", "100", "-300"]},
    "synth": {"mission": ["synth", "out", "--duration", "12"],
              "square": ["synth", "out", "--scenario", "square"],
              "figure8": ["synth", "out", "--scenario", "figure8"]},
    "tune": {"logs": ["tune", "odometry", "run1", "cw", "ccw", "--budget", "4"],
             "broad": ["tune", "attitude", "trial.mat", "trial.mat", "--budget", "2"]},
    "run": {"sim": ["run", "--imu", "sim", "--chassis", "sim", "--duration", "1"],
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
        "--write": [changes("logdir", "--write", "robot-calibrated.toml")],
    },
    "calibrate umbmark": {
        "--cw": [changes("squares", "--cw", "cw", "ccw")],
        "--ccw": [changes("squares", "--ccw", "ccw", "cw")],
        "--side": [changes("squares", "--side", "2")],
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
                        refused("square", "--simulator physics runs missions only",
                                "--simulator", "physics"),
                        refused("figure8", "--simulator physics runs missions only",
                                "--simulator", "physics")],
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
               if cmd not in NOT_YET and opt not in TABLE.get(cmd, {})]
    assert missing == [], "options without a row in TABLE: " + ", ".join(missing)
    unknown = [f"{cmd} {opt}" for cmd, rows in TABLE.items() for opt in rows
               if opt not in COMMANDS.get(cmd, [])]
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
    return d


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
    base = [*BASE[cmd][row.kind], *row.both]
    rc, out, files = _run([*base, *row.argv], inputs, capsys, monkeypatch)
    if row.refused is not None:
        assert rc == 2, out
        assert row.refused in out
        assert files == {}  # refused before writing anything
        return
    assert rc == 0, out
    if not row.argv:  # the kind itself: it runs
        return
    rc0, out0, files0 = _run(base, inputs, capsys, monkeypatch)
    assert rc0 == 0, out0
    assert (out, files) != (out0, files0), f"{cmd} {' '.join(row.argv)} changed nothing"
