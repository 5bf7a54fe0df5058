"""``fusion replay`` through the pipeline: outputs by suffix, captures, folders of logs in
worker processes, progress, plots, and outputs that are never left partial.

Oracles: the pipeline fed one event at a time from :func:`fusion.pipeline.sources.logdir_events`
(the streaming path; tests/test_pipeline.py shows it equals the filters composed by hand),
independent readers of the outputs (the mcap package, json), and the replay of the same
ticks written as a log directory.
"""

from __future__ import annotations

import fcntl
import io
import json
import os
import stat
import struct
import subprocess
import sys
import termios

import numpy as np
import pytest

from drivers.chassis import encode_wheel_frame
from fusion.cli import main
from fusion.evaluation.synthetic import EXAMPLE_ROBOT, degraded_mission
from fusion.io.fused_csv import read_fused_csv
from fusion.io.logdir import write_logdir, write_synthetic_run
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.sources import logdir_events, replay
from fusion.sinks.text import JsonLinesSink


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Three short synthetic logs (20 s each) in one folder, and one robot.toml."""
    root = tmp_path_factory.mktemp("fleet")
    for seed in (1, 2, 3):
        write_synthetic_run(root / f"run{seed}", degraded_mission(seed=seed, duration=20.0))
    return root


def _cli(*argv: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fusion", "replay", *argv],
                          capture_output=True, text=True, timeout=300, **kw)


def _py(code: str, *argv: str) -> subprocess.CompletedProcess:
    """A real interpreter running ``code`` then fusion's main with ``argv``."""
    script = f"{code}\nimport sys\nfrom fusion.cli import main\nsys.exit(main({list(argv)!r}))"
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)


def test_jsonl_output_is_the_pipeline_fed_event_by_event(logs, tmp_path):
    log = logs / "run1"
    out = tmp_path / "fused.jsonl"
    assert main(["replay", str(log), "-o", str(out)]) == 0
    robot, events = logdir_events(log)
    buf = io.StringIO()
    replay(FusionPipeline(robot, [JsonLinesSink(buf, flush=False)], imu_rate_hz=100.0), events)
    lines = out.read_text().splitlines(keepends=True)
    assert "".join(lines[:-1]) == buf.getvalue()  # byte for byte
    assert json.loads(lines[-1])["status"]["warnings"] == []  # then the status record
    recs = [json.loads(x) for x in buf.getvalue().splitlines()]
    wheels = np.loadtxt(log / "wheels.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(recs) == wheels.shape[0]  # one record per wheel frame


def test_csv_and_records_come_from_one_filter(logs, tmp_path):
    # the CSV (state at each IMU sample) and the records (state after each wheel frame) are
    # two views of one filter run: the synthetic missions end standing still, where both
    # must hold the same final pose (the filter only predicts between them, at zero speed)
    log = logs / "run2"
    assert main(["replay", str(log), "-o", str(tmp_path / "f.csv")]) == 0
    assert main(["replay", str(log), "-o", str(tmp_path / "f.jsonl")]) == 0
    csv = read_fused_csv(tmp_path / "f.csv")
    last = json.loads((tmp_path / "f.jsonl").read_text().splitlines()[-2])  # [-1]: status
    assert abs(last["v"]) < 1e-3 and abs(csv["v"][-1]) < 1e-3
    np.testing.assert_allclose([csv["x"][-1], csv["y"][-1], csv["yaw"][-1]],
                               [last["x"], last["y"], last["yaw"]], atol=1e-6)
    # the wheel speeds of the rows are those of the last frame, as in the records
    assert csv["wheel_left_speed"][-1] == last["wheel_left_speed"]


def test_mcap_output_reads_back(logs, tmp_path):
    pytest.importorskip("rosbags")
    from mcap.reader import make_reader

    out = tmp_path / "fused.mcap"
    assert main(["replay", str(logs / "run3"), "-o", str(out)]) == 0
    counts: dict[str, int] = {}
    with open(out, "rb") as fh:
        for _s, channel, _m in make_reader(fh).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    n = np.loadtxt(logs / "run3" / "wheels.csv", delimiter=",", skiprows=1).shape[0]
    assert counts["/odom"] == counts["/tf"] == n
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~_umask()


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".mcap"])
def test_a_failing_replay_leaves_an_existing_output_untouched(tmp_path, capsys, suffix):
    run = degraded_mission(seed=6, duration=10.0)
    d = write_synthetic_run(tmp_path / "bad", run)
    lines = (d / "wheels.csv").read_text().splitlines()
    lines[40] = "12.5,3,notanumber"
    (d / "wheels.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / f"out{suffix}"
    out.write_bytes(b"the previous, complete output")
    assert main(["replay", str(d), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "wheels.csv:41" in err
    assert out.read_bytes() == b"the previous, complete output"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", out.name]


def test_output_errors_name_the_path(logs, tmp_path, capsys):
    assert main(["replay", str(logs / "run1"), "-o", str(tmp_path / "f.txt")]) == 2
    assert "f.txt: unknown output type '.txt'" in capsys.readouterr().err
    assert main(["replay", str(logs / "run1"), "-o", str(tmp_path / "no" / "f.csv")]) == 2
    assert "the folder" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_raw_capture_replays_like_its_ticks(tmp_path, capsys):
    # the frames of a raw DATA-uart2 capture are stamped (k+1)*period; replaying the capture
    # must give the wheel-only replay of the same ticks at those stamps, byte for byte
    run = degraded_mission(seed=7, duration=15.0)
    T = EXAMPLE_ROBOT.encode_sampling_time
    ticks = run.ticks
    cap = tmp_path / "chassis.uart2"
    cap.write_bytes(b"\x00\x13garbage" + b"".join(encode_wheel_frame(int(a), int(b))
                                                   for a, b in ticks.tolist()))
    d = write_logdir(tmp_path / "ref", EXAMPLE_ROBOT, wheel_t=(np.arange(len(ticks)) + 1) * T,
                     ticks=ticks)
    assert main(["replay", str(cap), "--robot", str(d / "robot.toml"),
                 "-o", str(tmp_path / "cap.csv")]) == 0
    text = capsys.readouterr().out
    assert f"{len(ticks)} wheel frames" in text and "wheel odometry only" in text
    assert main(["replay", str(d), "-o", str(tmp_path / "ref.csv")]) == 0
    assert (tmp_path / "cap.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
    assert main(["replay", str(cap), "-o", str(tmp_path / "x.csv")]) == 2
    assert "a capture needs --robot robot.toml" in capsys.readouterr().err


def test_a_folder_of_logs_in_worker_processes(logs, tmp_path):
    fleet = tmp_path / "fleet"
    fleet.mkdir()
    for name in ("run1", "run2"):
        (fleet / name).symlink_to(logs / name, target_is_directory=True)
    broken = fleet / "run9"
    broken.mkdir()
    (broken / "robot.toml").write_text((logs / "run1" / "robot.toml").read_text())
    (broken / "wheels.csv").write_text("t,left,right\n0.04,1,2\n0.08,1\n")
    (fleet / "notes").mkdir()  # not a log directory: ignored
    out = tmp_path / "out"
    proc = _cli(str(fleet), "-o", str(out), "--jobs", "2")
    assert proc.returncode == 1, proc.stderr
    # the good logs: each output equals the single replay of that log
    assert sorted(p.name for p in out.iterdir()) == ["run1.csv", "run2.csv"]
    for name in ("run1", "run2"):
        single = tmp_path / f"{name}-single.csv"
        assert main(["replay", str(logs / name), "-o", str(single)]) == 0
        assert (out / f"{name}.csv").read_bytes() == single.read_bytes()
    rows = {line.split()[0]: line for line in proc.stdout.splitlines()[1:4]}
    assert rows["run1"].split()[1] == rows["run2"].split()[1] == "ok"
    assert rows["run9"].split()[1] == "FAILED"
    assert "wheels.csv:3" in rows["run9"]  # the error names the file and line
    assert "2 of 3 logs replayed (2 worker processes); 1 failed" in proc.stdout
    assert "wheels.csv:3" in proc.stderr
    # all good: exit 0, other formats, one PNG per log
    import shutil

    shutil.rmtree(broken)
    proc = _cli(str(fleet), "-o", str(tmp_path / "out2"), "--format", "jsonl", "-j", "2",
                "--plot", str(tmp_path / "plots"))
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "out2").iterdir()) == ["run1.jsonl", "run2.jsonl"]
    for name in ("run1", "run2"):
        assert (tmp_path / "plots" / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_progress_only_on_a_terminal_or_when_asked(logs, tmp_path):
    pytest.importorskip("tqdm")
    log = str(logs / "run1")
    quiet = _cli(log, "-o", str(tmp_path / "a.csv"))  # stderr is a pipe: no progress
    assert quiet.returncode == 0 and quiet.stderr == ""
    bar = _cli(log, "-o", str(tmp_path / "b.csv"), "--progress")
    assert bar.returncode == 0 and "run1:" in bar.stderr and "%|" in bar.stderr  # tqdm
    # without tqdm: a plain line
    plain = _py("import sys; sys.modules['tqdm'] = None", "replay", log, "-o",
                str(tmp_path / "c.csv"), "--progress")
    assert plain.returncode == 0, plain.stderr
    assert "run1: 100% (20.0/20.0 s)" in plain.stderr
    # a terminal on stderr (a real pty): by default a long log shows progress and a short one
    # stays quiet (the threshold, AUTO_PROGRESS_MIN_SPAN = 600 s, is lowered here around the
    # 20 s logs to keep the test fast); --no-progress silences, --progress forces
    cases = ((15.0, (), True), (30.0, (), False), (15.0, ("--no-progress",), False),
             (30.0, ("--progress",), True))
    for span, extra, expect in cases:
        code = ("import sys\nimport fusion.cli.replay as r\n"
                f"r.AUTO_PROGRESS_MIN_SPAN = {span}\nfrom fusion.cli import main\n"
                f"sys.exit(main({['replay', log, '-o', str(tmp_path / 'd.csv'), *extra]!r}))")
        seen = _on_a_terminal([sys.executable, "-c", code])
        assert (b"run1:" in seen and b"%|" in seen) is expect, (span, extra, seen)


def _on_a_terminal(argv: list[str]) -> bytes:
    """Run with stderr on a real pty of 24 x 100 characters; returns what it wrote there."""
    master, slave = os.openpty()
    # a fresh pty is 0 x 0 characters, where tqdm draws nothing
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    seen = b""
    try:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=slave)
        os.close(slave)
        slave = -1
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # EIO: the child closed the terminal
                break
            if not chunk:
                break
            seen += chunk
        assert proc.wait(timeout=120) == 0, seen
    finally:
        os.close(master)
        if slave >= 0:
            os.close(slave)
    return seen


def test_plot_and_its_missing_dependency(logs, tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "p.png"
    assert main(["replay", str(logs / "run2"), "-o", str(tmp_path / "f.csv"),
                 "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert stat.S_IMODE(png.stat().st_mode) == 0o666 & ~_umask()
    proc = _py("import sys; sys.modules['matplotlib'] = None", "replay", str(logs / "run2"),
               "-o", str(tmp_path / "g.csv"), "--plot", str(tmp_path / "q.png"))
    assert proc.returncode == 2
    assert "--plot needs matplotlib: pip install 'diffbot-fusion[demo]'" in proc.stderr
    assert not (tmp_path / "g.csv").exists() and not (tmp_path / "q.png").exists()


def test_replay_options_act_on_a_log_directory_or_are_refused(logs, tmp_path, capsys):
    """--robot and --imu-mount-rpy change a log directory's output (and say so); --format,
    --jobs, --level and --imu-mount-rpy are refused where they do not apply."""
    import dataclasses

    from fusion.io.robot_toml import read_robot_toml, write_robot_toml

    log = logs / "run2"
    base = tmp_path / "base.csv"
    assert main(["replay", str(log), "-o", str(base)]) == 0
    robot = read_robot_toml(log / "robot.toml")
    other = tmp_path / "other.toml"
    write_robot_toml(other, dataclasses.replace(
        robot, chassis=dataclasses.replace(robot.chassis,
                                           wheel_distance=robot.chassis.wheel_distance * 1.1)))
    capsys.readouterr()
    assert main(["replay", str(log), "-o", str(tmp_path / "r.csv"), "--robot", str(other)]) == 0
    assert f"robot: {other}" in capsys.readouterr().out
    assert (tmp_path / "r.csv").read_bytes() != base.read_bytes()
    assert main(["replay", str(log), "-o", str(tmp_path / "m.csv"), "--imu-mount-rpy",
                 "3.14159", "0", "0"]) == 0
    assert "from --imu-mount-rpy" in capsys.readouterr().out
    assert (tmp_path / "m.csv").read_bytes() != base.read_bytes()
    assert main(["replay", str(log), "--robot", str(tmp_path / "nope.toml"), "-o",
                 str(tmp_path / "n.csv")]) == 2
    assert "nope.toml" in capsys.readouterr().err
    refusals = [
        (["--format", "mcap", "-o", str(tmp_path / "f.csv")], "--format applies to a folder"),
        (["--jobs", "2", "-o", str(tmp_path / "f.csv")], "--jobs applies to a folder"),
    ]
    for extra, message in refusals:
        assert main(["replay", str(log), *extra]) == 2
        assert message in capsys.readouterr().err
    assert main(["replay", str(logs), "-o", str(tmp_path / "out"), "--robot", str(other)]) == 2
    assert "--robot applies to one log directory" in capsys.readouterr().err
