"""``fusion chassis`` end to end: files, and the simulated firmware over ptys."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from drivers.chassis import encode_wheel_frame
from drivers.sim.stm32 import PtyStm32, Stm32Sim, Stm32SimParams
from fusion.cli import main
from fusion.cli.chassis import step_metrics

pytestmark = pytest.mark.live  # real time: run alone (pyproject's markers)


def test_encode_prints_golden_hex(capsys):
    assert main(["chassis", "encode", "100", "-300"]) == 0
    # FF FF | 01 00 00 64 (+100) | 00 00 01 2C (-300) | checksum 0x290 -> 90
    assert capsys.readouterr().out.strip() == "ff ff 01 00 00 64 00 00 01 2c 90"
    assert main(["chassis", "encode", str(1 << 24), "0"]) == 2
    assert "24-bit" in capsys.readouterr().err


def test_decode_capture_to_csv(tmp_path, capsys):
    values = [(1, -1), (255, 65535), (-300, 100)]
    cap = tmp_path / "uart2.bin"
    cap.write_bytes(b"\x42\xff" + b"".join(encode_wheel_frame(a, b) for a, b in values) + b"\xff")
    out = tmp_path / "out.csv"
    assert main(["chassis", "decode", str(cap), "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("left,right")
    assert lines[1:] == ["1,-1,2", "255,65535,13", "-300,100,24"]
    report = capsys.readouterr().out
    assert "3 frames" in report and "3 bytes skipped" in report
    # missing file: exit 2 and the path in the message
    assert main(["chassis", "decode", str(tmp_path / "nope.bin")]) == 2
    assert "nope.bin" in capsys.readouterr().err


def test_step_metrics_first_order_analytic():
    tau, A = 0.1, 400.0
    t = np.arange(0, 2.0, 0.001)
    y = A * (1 - np.exp(-t / tau))
    m = step_metrics(t, y, A)
    assert m.rise_time == pytest.approx(tau * math.log(9), rel=1e-3)  # 10 % -> 90 %
    assert m.overshoot == 0.0
    assert abs(m.steady_state_error) < 1e-3
    # mirrored for a negative step
    assert step_metrics(t, -y, -A).rise_time == pytest.approx(m.rise_time)


def test_step_metrics_second_order_overshoot():
    zeta, wn = 0.3, 20.0
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(0, 3.0, 1e-4)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2)
                                      * np.sin(wd * t))
    m = step_metrics(t, 250 * y, 250)
    expected = 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))  # 37.2 %
    assert m.overshoot == pytest.approx(expected, rel=1e-3)


@pytest.fixture
def chassis(tmp_path):
    sim = PtyStm32(Stm32Sim(Stm32SimParams(period=0.02)), data_link=str(tmp_path / "data"),
                   debug_link=str(tmp_path / "debug")).start()
    yield sim
    sim.close()


def test_pid_get_set_reset(chassis, capsys):
    assert main(["chassis", "pid", "get", "--port", chassis.debug_port]) == 0
    out = capsys.readouterr().out
    d = Stm32SimParams()
    assert "firmware version: 1.0.0" in out
    assert f"kp={d.kp:g} ki={d.ki:g} kd={d.kd:g}" in out
    assert main(["chassis", "pid", "set", "12.5", "-0.25", "0.0001",
                 "--port", chassis.debug_port]) == 0
    assert "kp=12.5 ki=-0.25 kd=0.0001" in capsys.readouterr().out
    assert chassis.sim.gains == (12.5, -0.25, 0.0001)
    assert main(["chassis", "pid", "reset", "--port", chassis.debug_port]) == 0
    assert chassis.sim.gains == (d.kp, d.ki, d.kd)
    capsys.readouterr()
    assert main(["chassis", "pid", "set", "0.00001", "1", "1", "--port",
                 chassis.debug_port]) == 2
    assert "finer" in capsys.readouterr().err


def test_monitor_prints_speeds_and_odometry(chassis, capsys):
    p = chassis.sim.params
    chassis.sim.target = (200, 200)  # straight ahead: 200 ticks per period
    p0 = chassis.sim.periods
    end = time.monotonic() + 10
    while chassis.sim.periods < p0 + 30 and time.monotonic() < end:  # let the PID settle
        time.sleep(0.02)
    assert main(["chassis", "monitor", "--port", chassis.data_port, "--period", str(p.period),
                 "--wheel-distance", str(p.wheel_distance), "--speed-ratio",
                 str(p.speed_ratio), "--duration", "0.6"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "t,left,right,v_left,v_right,x,y,yaw"
    rows = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    assert len(rows) >= 5
    ticks = [(int(a), int(b)) for a, b in rows[:, 1:3]]
    # the printed ticks are a contiguous run of what the firmware sent
    sent = list(chassis.sim.ticks_sent)
    k = next(i for i in range(len(sent)) if sent[i : i + len(ticks)] == ticks)
    assert k > 0
    # speeds: ticks * speed_ratio / period (printed to 4 decimals)
    np.testing.assert_allclose(rows[:, 3], rows[:, 1] * p.speed_ratio / p.period, atol=5e-5)
    np.testing.assert_allclose(rows[:, 4], rows[:, 2] * p.speed_ratio / p.period, atol=5e-5)
    # straight line: x is the running sum of the mean wheel travel, yaw stays 0
    x = np.cumsum((rows[:, 1] + rows[:, 2]) / 2 * p.speed_ratio)
    np.testing.assert_allclose(rows[:, 5], x, atol=5e-5)
    assert np.all(np.abs(rows[:, 7]) < 1e-3)
    # and the wheels settle on the commanded 200 ticks per period (+-1 tick of quantisation)
    assert np.all(np.abs(rows[-8:, 1:3] - 200) <= 1)


def test_step_response_against_the_simulator(chassis, capsys, tmp_path):
    p = chassis.sim.params
    csv_path = tmp_path / "step.csv"
    assert main(["chassis", "step", "--port", chassis.data_port, "--period", str(p.period),
                 "--ticks", "300", "--duration", "1.5", "--csv", str(csv_path)]) == 0
    out = capsys.readouterr().out
    assert "rise time" in out and "overshoot" in out
    got = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    m = step_metrics(got[:, 0], got[:, 1], 300)
    # the oracle: the same firmware and motor stepped offline, period by period. The
    # response depends only on the period in which the command landed, so after the leading
    # zeros the recorded counts must equal the offline ones exactly, whatever the host load.
    ref = Stm32Sim(Stm32SimParams(period=p.period))
    ref.target = (300, 300)
    for _ in range(len(got)):
        ref.step()
    y_ref = [c[0] for c in ref.ticks_counted]
    y = [int(v) for v in got[:, 1]]
    first = next(i for i, v in enumerate(y) if v != 0)
    first_ref = next(i for i, v in enumerate(y_ref) if v != 0)
    n = len(y) - first
    assert n > 30
    assert y[first:] == y_ref[first_ref : first_ref + n]
    assert [int(v) for v in got[:, 2]] == y  # both wheels stepped alike
    r = step_metrics(p.period * np.arange(len(y_ref)), y_ref, 300)
    assert m.overshoot == pytest.approx(r.overshoot, abs=1e-9)
    assert 0 < m.rise_time < 1.0
    assert abs(m.steady_state_error) <= 1.0
    assert f"overshoot: {m.overshoot:.1f} %" in out
