"""What a newcomer meets on the command line (issue 15): output paths refused before any work,
one clear error for a missing serial port, messages that name the user's input.

Every command runs as a real subprocess (``python -m fusion``) in a scratch folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BROAD = ROOT / "datasets" / "broad" / "24_disturbed_tapping_A.mat"
LOGDIR = ROOT / "tests" / "data" / "golden_replay"


def fusion(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fusion", *args], cwd=cwd, timeout=timeout,
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


# (command line, what would show the work had started). Each names missing/OUT as output.
OUTPUT_CASES = {
    "attitude": (["attitude", str(BROAD), "-o", "missing/att.csv"], "samples over"),
    "imu --save-calibration": (["imu", "--sim", "--calibrate", "--count", "5",
                                "--save-calibration", "missing/c.json"], "calibrating"),
    "imu -o": (["imu", "--sim", "--count", "5", "-o", "missing/imu.csv"], "t,gx"),
    "calibrate odometry --write": (["calibrate", "odometry", str(LOGDIR), "--write",
                                    "missing/robot.toml"], "odometry calibration"),
    "synth": (["synth", "missing/run1", "--duration", "20"], "IMU samples"),
    "run --publish": (["run", "--duration", "5", "--publish", "csv:missing/fused.csv"],
                      "running:"),
    "chassis decode -o": (["chassis", "decode", "capture.bin", "-o", "missing/ticks.csv"],
                          "bytes,"),
    # the port does not exist either: the path is refused first, before the wheels turn
    "chassis step --csv": (["chassis", "step", "--port", "/nonexistent/tty", "--ticks", "100",
                            "--csv", "missing/step.csv"], "target"),
}


@pytest.mark.parametrize("case", sorted(OUTPUT_CASES))
def test_a_bad_output_path_is_refused_before_any_work(tmp_path: Path, case: str) -> None:
    argv, work = OUTPUT_CASES[case]
    (tmp_path / "capture.bin").write_bytes(bytes.fromhex("ff ff 01 00 00 64 00 00 01 2c 90"))
    r = fusion(*argv, cwd=tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 2, out
    target = next(a.split(":", 1)[-1] for a in argv if "missing/" in a)
    assert f"{target}: cannot write it, the folder missing does not exist" in r.stderr, out
    assert work not in out  # nothing was computed (or moved) before the refusal
    assert ".partial" not in out  # the user's path, never an internal temporary name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["capture.bin"]


def test_demo_into_a_file_names_the_path(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("")
    r = fusion("demo", "--out", "afile/demo", cwd=tmp_path)
    assert r.returncode == 2 and "afile/demo" in r.stderr and "compiling" not in r.stdout


def test_a_missing_serial_port_is_one_clear_error(tmp_path: Path) -> None:
    r = fusion("chassis", "monitor", "--port", "/dev/ttyUSB-absent", "--wheel-distance", "0.3",
               "--speed-ratio", "5e-5", "--open-timeout", "1", cwd=tmp_path)
    assert r.returncode == 2
    assert r.stdout == ""  # no CSV header for data that never comes
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr  # not one "# open_failed" line per retry
    assert lines[0].startswith("fusion chassis: error: chassis port /dev/ttyUSB-absent did "
                               "not open within 1 s")
    assert "No such file or directory" in lines[0]


@pytest.mark.live  # real time: run alone (pyproject's markers)
def test_run_on_a_real_chassis_without_imu_fuses_the_wheels_and_says_so(tmp_path: Path) -> None:
    from drivers.sim.stm32 import PtyStm32

    cfg = tmp_path / "robot.toml"
    cfg.write_text("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\n"
                   "encode_sampling_time = 0.04\n")
    with PtyStm32() as board:  # the simulated firmware on a real pseudo-terminal
        r = fusion("run", "--config", str(cfg), "--chassis", board.data_port, "--duration",
                   "1.5", "--status", "0", "--publish", "jsonl:fused.jsonl", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "--imu sim needs --chassis sim" not in r.stderr
    assert f"no --imu given: fusing the wheel odometry of {board.data_port} alone" in r.stderr
    recs = [json.loads(line) for line in (tmp_path / "fused.jsonl").read_text().splitlines()]
    assert "status" in recs.pop()  # the status record after the records
    assert len(recs) > 10 and all(r["orientation"] is None for r in recs)  # no IMU


def test_run_with_an_explicit_simulated_imu_on_a_real_chassis_is_refused(tmp_path) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\n"
                   "encode_sampling_time = 0.04\n")
    r = fusion("run", "--config", str(cfg), "--chassis", "/dev/ttyUSB0", "--imu", "sim",
               cwd=tmp_path)
    assert r.returncode == 2 and "--imu sim needs --chassis sim" in r.stderr


def test_run_on_a_real_chassis_with_a_config_without_its_geometry_is_refused(tmp_path) -> None:
    # an independent probe's config with only [link] ran a real port on the simulated robot's
    # geometry; without --config the same command is refused for that
    cfg = tmp_path / "run.toml"
    cfg.write_text("[link]\nbaudrate = 115200\n")
    r = fusion("run", "--config", str(cfg), "--chassis", "/dev/ttyUSB0", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert f"{cfg}: has no [chassis] table" in r.stderr and "made-up geometry" in r.stderr


def test_a_bad_robot_toml_is_named_with_its_line(tmp_path: Path) -> None:
    from fusion.io.errors import LogFormatError
    from fusion.io.robot_toml import read_robot_toml

    path = tmp_path / "robot.toml"
    path.write_text("# a robot\n[chassis]\nwheel_distance = 0.3\nspeed_ratio = 'fast'\n"
                    "encode_sampling_time = 0.04\n")
    with pytest.raises(LogFormatError, match=f"^{path}:4: \\[chassis\\] speed_ratio must be"):
        read_robot_toml(path)
    path.write_text("[chassis]\nwheel_distance = 0.3\nspeed_ratio = 5e-5\n"
                    "encode_sampling_time = 0.04\n\n[ekf]\ngyro_noise = 1\n")
    with pytest.raises(LogFormatError, match=f"^{path}:7: \\[ekf\\] unknown key"):
        read_robot_toml(path)


def test_robot_toml_from_numpy_numbers_is_plain_toml(tmp_path: Path) -> None:
    import numpy as np

    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.io.robot_toml import read_robot_toml, write_robot_toml

    path = tmp_path / "robot.toml"
    write_robot_toml(path, DiffDriveParams(wheel_distance=np.float64(0.31),
                                           speed_ratio=np.float64(5e-5),
                                           encode_sampling_time=0.04))
    assert "np.float64" not in path.read_text()
    assert read_robot_toml(path).chassis.wheel_distance == 0.31


def test_attitude_names_the_lines_of_the_rows_it_skips(tmp_path: Path) -> None:
    (tmp_path / "imu.csv").write_text(
        "t,gx,gy,gz,ax,ay,az,temp\n0,0,0,0,0,0,9.8,\n0.01,0,0,0,0,0,9.8,\n\n"
        "0.02,nan,0,0,0,0,9.8,\n0.03,0,0,0,0,0,nan,\n0.04,0,0,0,0,0,0,\n0.05,0,0,0,0,0,9.8,\n")
    r = fusion("attitude", "imu.csv", "-o", "att.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "1 gyro rows skipped" in r.stdout and "imu.csv line 5\n" in r.stdout
    assert "2 accelerometer rows unusable" in r.stdout and "imu.csv lines 6, 7\n" in r.stdout


def test_replay_names_the_lines_of_the_imu_rows_it_skips(tmp_path: Path) -> None:
    log = tmp_path / "log"
    log.mkdir()
    (log / "robot.toml").write_text((LOGDIR / "robot.toml").read_text())
    (log / "wheels.csv").write_text("t,left,right\n0.04,0,0\n0.08,0,0\n0.12,0,0\n")
    (log / "imu.csv").write_text(
        "t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,0,0,0,9.8\n\n"
        "0.02,nan,0,0,0,0,9.8\n0.03,0,0,0,0,0,inf\n0.04,0,0,0,0,0,9.8\n")
    r = fusion("replay", "log", "-o", "f.mcap", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert ("warning: log/imu.csv: 2 sample(s) with a NaN or infinite value skipped: "
            "line(s) 5, 6\n") in r.stdout
    assert "3 IMU samples" in r.stdout
    assert "-> f.mcap (3 records)" in r.stdout  # an MCAP output has records, not rows


def test_a_bag_without_topics_lists_its_topics(tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    bag = ROOT / "datasets" / "rosbag" / "jackal_sim_test2.bag"
    r = fusion("replay", str(bag), "-o", "f.csv", cwd=tmp_path)
    assert r.returncode == 2
    assert ("a bag needs --imu-topic (sensor_msgs/Imu) and --odom-topic (nav_msgs/Odometry); "
            "its topics: /imu/data (sensor_msgs/Imu), /jackal_velocity_controller/odom "
            "(nav_msgs/Odometry)") in r.stderr
    # bag-only runs refuse the options of a folder of logs, as for any single input
    r = fusion("replay", str(bag), "-o", "f.csv", "--imu-topic", "/imu/data", "--odom-topic",
               "/jackal_velocity_controller/odom", "--format", "mcap", cwd=tmp_path)
    assert r.returncode == 2 and "--format applies to a folder of logs" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.live  # real time: run alone (pyproject's markers)
def test_output_into_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    # `fusion run | head -c 100`: the reader goes away while records are still written
    proc = subprocess.Popen([sys.executable, "-m", "fusion", "run", "--duration", "3",
                             "--status", "0"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.stdout.read(100).startswith(b'{"t":')
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert "Traceback" not in err and "Broken pipe" not in err, err


def test_version(tmp_path: Path) -> None:
    from importlib.metadata import version

    r = fusion("--version", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.strip() == f"fusion {version('diffbot-fusion')}"


def test_help_texts_are_plain_and_complete(tmp_path: Path) -> None:
    r = fusion("chassis", "--help", cwd=tmp_path)
    assert "``" not in r.stdout and "::" not in r.stdout  # no reStructuredText markup
    r = fusion("run", "--help", cwd=tmp_path)
    assert "csv:PATH" in " ".join(r.stdout.split())


@pytest.mark.live  # real time: run alone (pyproject's markers)
def test_simulated_stm32_removes_its_links_on_sigterm(tmp_path: Path) -> None:
    links = tmp_path / "chassis"
    proc = subprocess.Popen([sys.executable, "-m", "drivers.sim.stm32", "--link-dir",
                             str(links)], stdout=subprocess.PIPE, text=True, cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout.readline().startswith("data (DATA-uart2):")
        assert proc.stdout.readline().startswith("debug (DEBUG-uart1):")
        assert (links / "data").is_symlink() and (links / "debug").is_symlink()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 5
    while any(links.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(links.iterdir()) == []  # no dead links left behind


README = (ROOT / "README.md").read_text(encoding="utf-8")


def _readme_commands() -> list[str]:
    """The README's shell lines (backslash continuations joined), in order."""
    return README.replace("\\\n", " ").splitlines()


@pytest.mark.parametrize("name", ["imu.csv", "uart2.bin", "chassis.uart2"])
def test_readme_inputs_are_produced_before_they_are_used(name: str) -> None:
    first = next(line for line in _readme_commands() if name in line.split("#")[0])
    produces = (f"-o {name}", f"> {name}", f" {name}  ")  # -o, a redirect, cp's target
    assert any(p in first.split("#")[0] + "  " for p in produces), first


def test_readme_bag_examples_use_topics_the_bundled_bag_has() -> None:
    from fusion.io.bags import bag_topics

    lines = [line for line in _readme_commands() if "datasets/rosbag/" in line
             and "--" in line and "fusion replay" in line]
    assert lines
    for line in lines:
        words = line.split()
        bag = next(w for w in words if w.startswith("datasets/rosbag/"))
        topics = bag_topics(ROOT / bag)
        for opt in ("--imu-topic", "--odom-topic"):
            if opt in words:
                assert words[words.index(opt) + 1] in topics, (line, sorted(topics))
