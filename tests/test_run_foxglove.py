"""``fusion run --publish foxglove``: a Foxglove client's /cmd_vel drives the (simulated) robot.

A real ``fusion run`` process (simulated STM32 on a pty and simulated MPU6050), a real WebSocket
client speaking the Foxglove protocol as the Teleop panel does (advertise a JSON channel
/cmd_vel of geometry_msgs/Twist, publish on it). Before the first command the simulator drives
the demo's mission; once the client commands "turn in place at 1 rad/s", the published
odometry must show the robot turning in place.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import struct
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)

websockets = pytest.importorskip("websockets")
pytest.importorskip("foxglove")


def _twist(vx: float, wz: float) -> bytes:
    return json.dumps({"linear": {"x": vx, "y": 0.0, "z": 0.0},
                       "angular": {"x": 0.0, "y": 0.0, "z": wz}}).encode()


async def _teleop(port: int, seconds: float, vx: float, wz: float) -> None:
    async with websockets.connect(f"ws://127.0.0.1:{port}",
                                  subprotocols=["foxglove.sdk.v1"]) as ws:
        info = json.loads(await asyncio.wait_for(ws.recv(), 30))
        assert "clientPublish" in info["capabilities"]
        await ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": 3, "topic": "/cmd_vel", "encoding": "json",
             "schemaName": "geometry_msgs/Twist"}]}))
        end = time.monotonic() + seconds
        while time.monotonic() < end:  # 10 Hz, like a teleop panel held down
            # client message data: opcode 0x01, client channel id u32 LE, payload
            await ws.send(struct.pack("<BI", 1, 3) + _twist(vx, wz))
            await asyncio.sleep(0.1)


def test_foxglove_cmd_vel_drives_the_simulated_chassis(tmp_path):
    jsonl = tmp_path / "run.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "fusion", "run", "--imu", "sim", "--chassis", "sim",
         "--publish", f"foxglove:0,jsonl:{jsonl}", "--status", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    try:
        port = None
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and port is None:
            line = proc.stderr.readline()
            if not line:
                break
            lines.append(line)
            if "Foxglove server: connect to ws://" in line:
                port = int(line.rsplit(":", 1)[1])
        assert port is not None, "".join(lines)
        while time.monotonic() < deadline:  # let the pipeline run a little first
            line = proc.stderr.readline()
            lines.append(line)
            if "running:" in line:
                break
        time.sleep(1.0)
        t_cmd = time.monotonic()
        asyncio.run(_teleop(port, 4.0, 0.0, 1.0))
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
        lines.append(err)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 0, "".join(lines)
    recs = [json.loads(x) for x in jsonl.read_text().splitlines()]
    assert "status" in recs.pop()  # the status record after the records
    assert t_cmd > 0 and len(recs) > 100
    # the last 1.5 s of robot time are under the command (4 s of it, minus the ramp):
    # turning in place at ~1 rad/s, not driving the mission
    t_end = recs[-1]["t"]
    tail = [r for r in recs if r["t"] > t_end - 1.5]
    assert len(tail) > 20
    w = sorted(r["w"] for r in tail)
    v = sorted(abs(r["v"]) for r in tail)
    assert 0.8 < w[len(w) // 2] < 1.2, (w[0], w[-1])
    assert v[len(v) // 2] < 0.05
