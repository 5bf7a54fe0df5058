"""``fusion run --publish ros2``: a ROS 2 peer process's /cmd_vel drives the simulated robot and
its /odom comes back over DDS (loopback only, a fresh ROS_DOMAIN_ID).

The peer (``tests/ros2_peer.py``) declares its types from rosbags' definitions and imports
nothing of ``fusion``. Needs the ``ros2`` extra: skipped without it, except under CI (``CI``
set), where the import fails the module.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

if importlib.util.find_spec("cyclonedds") is None and not os.environ.get("CI"):
    pytest.skip("the ros2 extra (cyclonedds) is not installed", allow_module_level=True)

import cyclonedds  # noqa: F401  (under CI: a missing ros2 extra fails here)

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

PEER = Path(__file__).with_name("ros2_peer.py")


def test_ros2_cmd_vel_drives_the_simulated_chassis_and_odom_comes_back(tmp_path, ros2_env):
    jsonl = tmp_path / "run.jsonl"
    node = subprocess.Popen(
        [sys.executable, "-m", "fusion", "run", "--imu", "sim", "--chassis", "sim",
         "--publish", f"ros2,jsonl:{jsonl}", "--status", "0"],
        env=ros2_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peer = None
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # the pipeline and the DDS participant are up
            line = node.stderr.readline()
            lines.append(line)
            if "running:" in line or not line:
                break
        assert "publishing to ros2" in "".join(lines), "".join(lines)
        domain = ros2_env["ROS_DOMAIN_ID"]
        assert f"ROS 2 topics on DDS domain {domain} (ROS_DOMAIN_ID)" in "".join(lines)
        time.sleep(1.0)  # the robot stands still: with ros2 only /cmd_vel moves it
        # 0.3 m/s for 3 s, then 1 s of zero command
        peer = subprocess.run([sys.executable, str(PEER), "drive", "--cmd-vel", "0.3", "0.0",
                               "--seconds", "3"], env=ros2_env, capture_output=True, text=True,
                              timeout=150)
        assert peer.returncode == 0, peer.stderr
        node.send_signal(signal.SIGINT)
        _out, err = node.communicate(timeout=60)
        lines.append(err)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait(timeout=10)
    assert node.returncode == 0, "".join(lines)
    res = json.loads(peer.stdout.strip().splitlines()[-1])
    frame, child, x_before, _y = res["before"]
    _f, _c, x, y = res["last"]
    assert (frame, child) == ("odom", "base_footprint")
    assert res["n"] > res["n_before"] + 50 and res["tf"] > 50  # /odom, /tf at the wheel rate
    assert res["vmax"] > 0.2  # the fused forward speed followed the command
    # 0.3 m/s for 3 s, minus the ramp: the robot drove forward ~0.9 m, not sideways
    assert 0.5 < x - x_before < 1.2 and abs(y) < 0.1

    recs = [json.loads(r) for r in jsonl.read_text().splitlines()]
    assert "status" in recs.pop()  # the status record after the records
    x0 = recs[0]["x"]
    moved = [r["t"] for r in recs if abs(r["x"] - x0) > 0.01]
    assert moved, "the fused odometry never moved"
    # before the command the robot stood still (no mission with ros2): the first second of
    # records did not move; and the file's last pose is the one the peer saw last
    assert moved[0] - recs[0]["t"] > 1.0
    assert abs(recs[-1]["x"] - x) < 0.05
