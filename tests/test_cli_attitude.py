"""``fusion attitude`` end to end on real files."""

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.attitude.keel import Keel
from fusion.attitude.keel_offline import keel_offline
from fusion.attitude.mahony import Mahony
from fusion.cli import main
from fusion.io.broad import read_broad

TRIAL = "24_disturbed_tapping_A.mat"


@pytest.fixture(scope="module")
def trial_path(datasets_dir):
    return datasets_dir / "broad" / TRIAL


def read_out(path):
    lines = path.read_text().splitlines()
    assert lines[0] == "t,qw,qx,qy,qz,roll,pitch,yaw"
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_broad_trial_nine_axis_with_initial_quaternion(trial_path, tmp_path, capsys):
    tr = read_broad(trial_path)
    q0 = tr.reference_initial_quaternion()
    out = tmp_path / "att.csv"
    code = main(["attitude", str(trial_path), "-o", str(out), "--axes", "9", "--filter",
                 "mahony", "--kp", "0.74", "--ki", "0.0012", "--initial-quaternion",
                 *map(str, q0)])
    assert code == 0
    table = read_out(out)
    assert table.shape == (len(tr), 8)
    ref = Mahony(0.74, 0.0012, axes=9, sample_period=1 / tr.rate, initial_quaternion=q0)
    assert np.allclose(table[:, 1:5], ref.update_batch(tr.gyro, tr.accel, tr.mag), atol=1e-9)
    # Euler columns: roll, pitch, yaw of the ZYX sequence (scipy as the reference).
    yaw, pitch, roll = Rotation.from_quat(table[:, [2, 3, 4, 1]]).as_euler("ZYX").T
    assert np.allclose(table[:, 5:8], np.column_stack([roll, pitch, yaw]), atol=1e-7)
    printed = capsys.readouterr().out
    # The published total RMSE of this trial is 2.1462 deg.
    assert "total 2.146 deg" in printed


@pytest.mark.parametrize("filt", ["keel", "mahony"])
def test_imu_csv_input_uses_timestamps(trial_path, tmp_path, filt):
    tr = read_broad(trial_path)
    n = 3000
    t = np.cumsum(np.full(n, 0.0035))
    t[1000:] += 0.01  # a gap: per-sample periods must follow the timestamps
    csv = tmp_path / "imu.csv"
    np.savetxt(csv, np.column_stack([t, tr.gyro[:n], tr.accel[:n], tr.mag[:n]]),
               delimiter=",", header="t,gx,gy,gz,ax,ay,az,mx,my,mz", comments="", fmt="%.17g")
    out = tmp_path / "att.csv"
    assert main(["attitude", str(csv), "-o", str(out), "--axes", "9", "--filter", filt]) == 0
    est = Keel(axes=9) if filt == "keel" else Mahony(axes=9)
    ref = est.update_batch(tr.gyro[:n], tr.accel[:n], tr.mag[:n], timestamps=t)
    assert np.allclose(read_out(out)[:, 1:5], ref, atol=1e-9)


def test_errors_exit_2_with_a_message(tmp_path, capsys):
    csv = tmp_path / "imu.csv"
    csv.write_text("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,0,0,0,9.8\n")
    assert main(["attitude", str(csv), "-o", str(tmp_path / "o.csv"), "--axes", "9"]) == 2
    assert "mx,my,mz" in capsys.readouterr().err
    assert main(["attitude", str(tmp_path / "missing.csv"), "-o", str(tmp_path / "o.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_default_is_keel_and_offline_runs_on_broad(trial_path, tmp_path, capsys):
    tr = read_broad(trial_path)
    for extra, ref in (([], Keel().update_batch(tr.gyro, tr.accel, dt=1 / tr.rate)),
                       (["--offline"], keel_offline(tr.gyro, tr.accel, dt=1 / tr.rate))):
        out = tmp_path / "att.csv"
        assert main(["attitude", str(trial_path), "-o", str(out), *extra]) == 0
        assert np.allclose(read_out(out)[:, 1:5], ref, atol=1e-9)
        printed = capsys.readouterr().out
        assert "Keel" in printed and "inclination" in printed


@pytest.mark.parametrize(
    "args, message",
    [
        (["--kp", "1"], "--kp: Mahony-only option(s); add --filter mahony"),
        (["--kp", "1", "--ki", "0.1"], "--kp, --ki: Mahony-only"),
        (["--filter", "mahony", "--offline"], "--offline is a Keel mode"),
        (["--offline", "--initial-quaternion", "1", "0", "0", "0"], "cannot be used with"),
    ],
)
def test_options_of_the_other_filter_are_refused(trial_path, tmp_path, capsys, args, message):
    out = tmp_path / "o.csv"
    assert main(["attitude", str(trial_path), "-o", str(out), *args]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_console_entry_point_runs():
    """`python -m fusion` reaches the same CLI (the `fusion` script wraps the same main)."""
    res = subprocess.run([sys.executable, "-m", "fusion", "attitude", "--help"],
                         capture_output=True, text=True, check=True)
    assert "--initial-quaternion" in res.stdout and "--filter" in res.stdout
