"""How ``fusion`` reports errors (issue 12): one line for errors a user can act on, the
traceback for internal errors (or for any error with ``--debug``), every sink's close error."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from drivers.sim.robot import SimRobotParams
from fusion.cli import CommandError, is_user_error, main
from fusion.cli.demo import nominal_config
from fusion.io.errors import LogFormatError
from fusion.pipeline.core import FusionPipeline, SinkFailures
from fusion.sinks.base import Sink
from fusion.types.samples import ImuSample, WheelTicks


def _fail_with(monkeypatch, exc: BaseException) -> None:
    """``fusion synth`` raises ``exc`` (its handler replaced; parsing stays real)."""
    import fusion.cli.synth as synth

    def boom(args: argparse.Namespace) -> int:
        raise exc

    monkeypatch.setattr(synth, "run", boom)


def test_user_errors_are_one_line(monkeypatch, capsys, tmp_path):
    _fail_with(monkeypatch, LogFormatError(f"{tmp_path}/imu.csv:7: expected 7 columns, got 3"))
    assert main(["synth", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err == f"fusion synth: error: {tmp_path}/imu.csv:7: expected 7 columns, got 3\n"


def test_internal_errors_keep_their_traceback(monkeypatch, capsys, tmp_path):
    _fail_with(monkeypatch, KeyError("x_state"))
    assert main(["synth", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in boom" in err
    assert "internal error: KeyError: 'x_state'" in err


def test_debug_prints_the_traceback_of_user_errors_too(monkeypatch, capsys, tmp_path):
    _fail_with(monkeypatch, CommandError("--duration must be > 0 s, got -1"))
    assert main(["--debug", "synth", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "CommandError: --duration must be > 0 s" in err


def test_a_value_error_from_inside_numpy_is_internal_one_from_the_project_is_not():
    with pytest.raises(ValueError) as numpy_error:
        np.zeros(3) + np.zeros(4)
    assert not is_user_error(numpy_error.value)
    with pytest.raises(ValueError) as ours:
        FusionPipeline(nominal_config(SimRobotParams()).robot, imu_rate_hz=-5)
    assert is_user_error(ours.value)
    assert is_user_error(OSError(2, "No such file or directory", "/dev/ttyUSB9"))


class _CloseFails(Sink):
    def __init__(self, name: str) -> None:
        super().__init__()
        self.name = name

    def __repr__(self) -> str:
        return f"_CloseFails({self.name})"

    def _write(self, record) -> None:
        pass

    def _close(self) -> None:
        raise OSError(28, f"No space left on device: {self.name}")


class _Fine(Sink):
    closed = False

    def _write(self, record) -> None:
        pass

    def _close(self) -> None:
        self.closed = True


def test_every_sinks_close_error_is_reported():
    fine = _Fine()
    pipe = FusionPipeline(nominal_config(SimRobotParams()).robot,
                          [_CloseFails("a"), fine, _CloseFails("b")])
    pipe.open()
    pipe.push(ImuSample(0.01, np.zeros(3), np.array([0.0, 0.0, 9.81])))
    pipe.push(WheelTicks(0.04, 0, 0))
    with pytest.raises(SinkFailures) as info:
        pipe.close()
    msg = str(info.value)
    assert "_CloseFails(a)" in msg and "_CloseFails(b)" in msg and "No space left" in msg
    assert fine.closed  # the others are closed all the same
    assert [s.name for s, _ in info.value.errors] == ["a", "b"]
    assert is_user_error(info.value)  # disk full: one line, naming both


@pytest.mark.live  # a run on a sped-up clock: run alone (pyproject's markers)
def test_a_full_disk_is_one_line_naming_the_output(tmp_path):
    # a real write error with no file name (the kernel's EFBIG at a file-size limit, as ENOSPC
    # at a full disk): an independent probe's full disk printed three tracebacks and a final
    # "error: [Errno 28] No space left on device" naming no file
    import os
    import subprocess
    import sys
    import textwrap

    out = tmp_path / "fused.csv"
    script = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
        from fusion.cli import main
        sys.exit(main(["run", "--duration", "30", "--speed", "10", "--status", "0",
                       "--publish", "csv:{out}"]))
    """)
    # interpreted: no compiled core to cache (its files would hit the limit on a cold cache)
    env = {**os.environ, "FUSION_DISABLE_JIT": "1"}
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=300, env=env)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    assert f"sink CsvSink('{out}') failed: [Errno 27] File too large; the others go on" \
        in r.stderr, r.stderr
    assert f"error: [Errno 27] File too large: '{out}'" in r.stderr, r.stderr
