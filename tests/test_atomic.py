"""fusion.io.atomic: the one atomic-output helper, checked with real files.

References are independent of the helper: the bytes written, what a plain ``open(path, "w")``
gives (permissions) under the same umask, the folder listing (no temporary left), and a real
crash (SIGKILL of a writing process).
"""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fusion.io.atomic import AtomicDirectory, AtomicFile, atomic_write, create_temp_file


def _plain_open_mode(path: Path, existing_mode: int | None = None) -> int:
    """The mode a plain ``open(path, "w")`` leaves (on a new file, or on one of this mode)."""
    if existing_mode is not None:
        path.write_text("old")
        path.chmod(existing_mode)
    with open(path, "w") as fh:
        fh.write("x")
    mode = stat.S_IMODE(path.stat().st_mode)
    path.unlink()
    return mode


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_success_writes_the_bytes_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    with atomic_write(target, newline="") as fh:
        fh.write("a,b\r\n1,2\n")
        assert not target.exists()  # not visible before the block ends
    assert target.read_bytes() == b"a,b\r\n1,2\n"
    assert _names(tmp_path) == ["out.csv"]
    with atomic_write(tmp_path / "b.bin", "wb") as fh:
        fh.write(bytes(range(256)))
    assert (tmp_path / "b.bin").read_bytes() == bytes(range(256))


def test_replaces_an_existing_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old contents, longer than the new ones\n")
    with atomic_write(target) as fh:
        fh.write("new\n")
        assert target.read_text() == "old contents, longer than the new ones\n"
    assert target.read_text() == "new\n"
    assert _names(tmp_path) == ["out.txt"]


@pytest.mark.parametrize("exc_type", [RuntimeError, KeyboardInterrupt])
def test_exception_inside_the_block_keeps_the_old_file(tmp_path: Path, exc_type) -> None:
    target = tmp_path / "out.txt"
    target.write_bytes(b"old\n")
    with pytest.raises(exc_type):
        with atomic_write(target) as fh:
            fh.write("half of the new" * 1000)
            fh.flush()
            raise exc_type("stop")
    assert target.read_bytes() == b"old\n"
    assert _names(tmp_path) == ["out.txt"]
    # no old file: none appears
    with pytest.raises(exc_type):
        with atomic_write(tmp_path / "new.txt") as fh:
            fh.write("x")
            raise exc_type("stop")
    assert _names(tmp_path) == ["out.txt"]


@pytest.mark.parametrize("mode", ["w", "wb"])
def test_new_file_has_the_permissions_of_a_plain_open(tmp_path: Path, umask: int,
                                                      mode: str) -> None:
    expected = _plain_open_mode(tmp_path / "reference")
    assert expected == 0o666 & ~umask  # the reference itself
    with atomic_write(tmp_path / "out", mode) as fh:
        fh.write(b"x" if "b" in mode else "x")
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == expected


def test_replaced_file_keeps_its_permissions_like_a_plain_open(tmp_path: Path,
                                                               umask: int) -> None:
    for old_mode in (0o600, 0o640, 0o664):
        expected = _plain_open_mode(tmp_path / "reference", existing_mode=old_mode)
        assert expected == old_mode  # open("w") keeps an existing file's mode
        target = tmp_path / "out"
        target.write_text("old")
        target.chmod(old_mode)
        with atomic_write(target) as fh:
            fh.write("new")
        assert stat.S_IMODE(target.stat().st_mode) == expected
        assert target.read_text() == "new"


def test_missing_folder_is_refused_naming_the_users_path(tmp_path: Path) -> None:
    target = tmp_path / "nope" / "out.csv"
    with pytest.raises(FileNotFoundError) as info:
        with atomic_write(target):
            pytest.fail("the block must not run")
    msg = str(info.value)
    assert str(target) in msg and "does not exist" in msg and ".partial" not in msg
    with pytest.raises(FileNotFoundError, match="does not exist"):
        AtomicDirectory(target)
    assert _names(tmp_path) == []


def test_folder_that_is_a_file_or_target_that_is_a_folder(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("")
    with pytest.raises(NotADirectoryError, match=str(tmp_path / "f" / "out")):
        AtomicFile(tmp_path / "f" / "out")
    (tmp_path / "d").mkdir()
    with pytest.raises(IsADirectoryError, match=str(tmp_path / "d")):
        AtomicFile(tmp_path / "d")
    assert _names(tmp_path) == ["d", "f"]


def _refuses_unwritable(target: Path) -> None:
    with pytest.raises(PermissionError) as info:
        with atomic_write(target):
            pytest.fail("the block must not run")
    msg = str(info.value)
    assert msg.startswith(f"{target}:") and "not writable" in msg and ".partial" not in msg
    assert _names(target.parent) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only folder")
def test_unwritable_folder_is_refused_naming_the_users_path(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    try:
        _refuses_unwritable(ro / "out.csv")
    finally:
        ro.chmod(0o755)


def test_folder_the_os_calls_unwritable_is_refused(tmp_path: Path, monkeypatch) -> None:
    # the same check where the test runs as root: the folder is what os.access denies
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p).name != "ro" and real_access(p, m))
    (tmp_path / "ro").mkdir()
    _refuses_unwritable(tmp_path / "ro" / "out.csv")


def test_overwrite_false_refuses_an_existing_file(tmp_path: Path) -> None:
    target = tmp_path / "cap.txt"
    target.write_text("keep")
    with pytest.raises(FileExistsError, match=str(target)):
        AtomicFile(target, overwrite=False)
    # a file that appears while writing is not clobbered either
    out = AtomicFile(tmp_path / "late.txt", overwrite=False)
    out.file.write("mine")
    (tmp_path / "late.txt").write_text("theirs")
    with pytest.raises(FileExistsError):
        out.commit()
    assert (tmp_path / "late.txt").read_text() == "theirs"
    assert target.read_text() == "keep"
    assert _names(tmp_path) == ["cap.txt", "late.txt"]


def test_the_file_is_fsynced_before_the_rename(tmp_path: Path, monkeypatch) -> None:
    events: list[str] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append("fsync-dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "fsync-file")
        real_fsync(fd)

    def replace(a, b):
        events.append("replace")
        real_replace(a, b)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    with atomic_write(tmp_path / "out") as fh:
        fh.write("x")
    assert events == ["fsync-file", "replace", "fsync-dir"]


def test_a_killed_writer_leaves_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old\n")
    code = textwrap.dedent(f"""
        import sys, time
        from fusion.io.atomic import AtomicFile
        out = AtomicFile({str(target)!r})
        out.file.write("new line\\n" * 100000)
        out.file.flush()
        print("written", flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "written"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
        proc.stdout.close()
    assert target.read_text() == "old\n"
    left = [n for n in _names(tmp_path) if n != "out.txt"]
    assert len(left) == 1 and left[0].startswith(".out.txt.") and left[0].endswith(".partial")


def test_create_temp_file_is_fresh_and_has_the_umask_mode(tmp_path: Path, umask: int) -> None:
    a, b = create_temp_file(tmp_path / "x"), create_temp_file(tmp_path / "x")
    assert a != b and a.name.startswith(".x.") and a.name.endswith(".partial")
    assert stat.S_IMODE(a.stat().st_mode) == 0o666 & ~umask


def test_directory_commit_replace_and_discard(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    staged = AtomicDirectory(bag)
    assert staged.staging.parent == tmp_path and staged.staging.name.startswith(".bag.")
    assert stat.S_IMODE(staged.staging.stat().st_mode) == 0o700  # private while built
    (staged.staging / "bag").mkdir()
    (staged.staging / "bag" / "a.txt").write_text("one")
    staged.commit(staged.staging / "bag")
    assert _names(tmp_path) == ["bag"] and (bag / "a.txt").read_text() == "one"
    # a failed build leaves the old folder as it was
    staged = AtomicDirectory(bag)
    (staged.staging / "bag").mkdir()
    staged.discard()
    assert _names(tmp_path) == ["bag"] and _names(bag) == ["a.txt"]
    # a new folder replaces the old one whole (its old files do not survive)
    staged = AtomicDirectory(bag)
    (staged.staging / "bag").mkdir()
    (staged.staging / "bag" / "b.txt").write_text("two")
    staged.commit(staged.staging / "bag")
    assert _names(tmp_path) == ["bag"] and _names(bag) == ["b.txt"]
    with pytest.raises(FileExistsError, match=str(bag)):
        AtomicDirectory(bag, overwrite=False)
    # a file built in the staging folder replaces a file
    staged = AtomicDirectory(tmp_path / "f.mcap")
    (staged.staging / "f.mcap").write_bytes(b"\x89MCAP")
    staged.commit(staged.staging / "f.mcap")
    assert (tmp_path / "f.mcap").read_bytes() == b"\x89MCAP"
    assert _names(tmp_path) == ["bag", "f.mcap"]


# -- the library's writers ----------------------------------------------------------------
def test_write_logdir_failing_part_way_keeps_the_old_table(tmp_path: Path) -> None:
    from fusion.evaluation.synthetic import EXAMPLE_ROBOT
    from fusion.io.logdir import read_wheels_csv, write_logdir

    log = write_logdir(tmp_path / "log", EXAMPLE_ROBOT, wheel_t=[0.04, 0.08],
                       ticks=[[1, 2], [3, 4]])
    before = (log / "wheels.csv").read_bytes()
    with pytest.raises(ValueError):  # 3 times, 2 tick rows: found while writing the rows
        write_logdir(log, EXAMPLE_ROBOT, wheel_t=[0.04, 0.08, 0.12], ticks=[[5, 6], [7, 8]])
    assert (log / "wheels.csv").read_bytes() == before
    assert _names(log) == ["robot.toml", "wheels.csv"]
    t, ticks = read_wheels_csv(log / "wheels.csv")
    assert t.tolist() == [0.04, 0.08] and ticks.tolist() == [[1, 2], [3, 4]]


def test_capture_writer_keeps_a_recording_stopped_by_an_exception(tmp_path: Path) -> None:
    from fusion.io.uart2 import Uart2CaptureWriter

    cap = tmp_path / "wheels.uart2"
    with pytest.raises(KeyboardInterrupt):
        with Uart2CaptureWriter(cap) as w:
            w.write(0.5, b"\xff\xff")
            assert not cap.exists()  # hidden while recording
            raise KeyboardInterrupt
    assert cap.read_text() == "t,data\n0.5,ffff\n"
    assert _names(tmp_path) == ["wheels.uart2"]


def test_calibration_save_to_a_missing_folder_names_it(tmp_path: Path) -> None:
    from fusion.calibration.imu import ImuCalibration
    from fusion.io.imu_calibration import save_imu_calibration

    cal = ImuCalibration(np.zeros(3), np.zeros(3), np.ones(3))
    target = tmp_path / "nope" / "cal.json"
    with pytest.raises(FileNotFoundError, match=str(target)):
        save_imu_calibration(cal, target)


def test_cli_output_in_a_missing_folder_is_named(tmp_path: Path, capsys) -> None:
    from drivers.chassis import encode_wheel_frame
    from fusion.cli import main

    cap = tmp_path / "uart2.bin"
    cap.write_bytes(encode_wheel_frame(1, 2))
    target = tmp_path / "nope" / "out.csv"
    assert main(["chassis", "decode", str(cap), "-o", str(target)]) == 2
    err = capsys.readouterr().err
    assert f"{target}: cannot write it" in err and ".partial" not in err


def test_a_device_or_fifo_is_refused_not_replaced(tmp_path: Path, capsys) -> None:
    # an independent probe's `fusion run --publish csv:/dev/full` replaced the machine's
    # /dev/full with a regular file (the output is renamed over its path)
    from fusion.cli import main
    from fusion.io.atomic import check_target

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for open_it in (lambda: AtomicFile(fifo, "w"), lambda: create_temp_file(fifo),
                    lambda: check_target(fifo), lambda: AtomicDirectory(fifo)):
        with pytest.raises(FileExistsError, match=r"pipe: is a FIFO; .* would replace it"):
            open_it()
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and _names(tmp_path) == ["pipe"]
    with pytest.raises(FileExistsError, match="/dev/null: is a character device"):
        check_target("/dev/null")
    # the live command refuses it before the robot moves
    assert main(["run", "--publish", f"csv:{fifo}", "--duration", "1"]) == 2
    assert f"{fifo}: is a FIFO" in capsys.readouterr().err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
