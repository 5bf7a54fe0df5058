"""Log readers on the bundled BROAD trial and on hand-written CSV files."""

import numpy as np
import pytest

from fusion.io.broad import read_broad
from fusion.io.errors import LogFormatError
from fusion.io.imu_csv import read_imu_csv, write_attitude_csv

TRIAL = "01_undisturbed_slow_rotation_A.mat"


@pytest.fixture(scope="module")
def trial(datasets_dir):
    return read_broad(datasets_dir / "broad" / TRIAL)


def test_broad_mat_contents(trial):
    n = len(trial)
    # The dataset rounds it to 286 Hz in its description; the file stores 1 / 3.5 ms.
    assert n == 56940 and trial.rate == pytest.approx(1 / 0.0035)
    assert trial.gyro.shape == trial.accel.shape == trial.mag.shape == (n, 3)
    assert trial.quat_ref.shape == (n, 4) and trial.movement.dtype == bool
    assert np.allclose(np.diff(trial.t), 0.0035)
    # At rest at the start, the accelerometer measures about 1 g.
    assert np.linalg.norm(trial.accel[:100].mean(0)) == pytest.approx(9.81, abs=0.1)
    good = np.all(np.isfinite(trial.quat_ref), axis=1)
    assert np.allclose(np.linalg.norm(trial.quat_ref[good], axis=1), 1.0, atol=1e-6)


def test_broad_hdf5_reads_the_same(trial, tmp_path):
    h5py = pytest.importorskip("h5py")
    from scipy.io import loadmat

    raw = loadmat(trial.source)
    path = tmp_path / "trial.hdf5"
    with h5py.File(path, "w") as f:
        for key in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement",
                    "sampling_rate"):
            f[key] = raw[key]
    other = read_broad(path)
    for attr in ("gyro", "accel", "mag", "quat_ref", "pos_ref", "movement"):
        assert np.array_equal(getattr(other, attr), getattr(trial, attr), equal_nan=True)
    assert other.rate == trial.rate


def test_broad_errors_name_the_file(tmp_path):
    bad = tmp_path / "x.mat"
    bad.write_bytes(b"not matlab")
    with pytest.raises(LogFormatError, match=r"x\.mat"):
        read_broad(bad)
    with pytest.raises(LogFormatError, match="unknown"):
        read_broad(tmp_path / "x.txt")


def write(tmp_path, text, name="imu.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_imu_csv_with_and_without_magnetometer(tmp_path):
    log = read_imu_csv(write(tmp_path, "t,gx,gy,gz,ax,ay,az\n0,0.1,0.2,0.3,0,0,9.8\n"
                                       "0.01,0.1,0.2,0.3,0,0,9.8\n"))
    assert log.t.tolist() == [0.0, 0.01] and log.mag is None
    assert log.gyro[1].tolist() == [0.1, 0.2, 0.3]
    log = read_imu_csv(write(tmp_path, "t,gx,gy,gz,ax,ay,az,mx,my,mz\n"
                                       "0,0,0,0,0,0,9.8,20,0,-40\n"))
    assert log.mag.tolist() == [[20.0, 0.0, -40.0]]


def test_imu_csv_columns_are_read_by_name_and_others_ignored(tmp_path):
    # what fusion imu writes (temp empty when unknown, attitude columns), in another order
    text = ("ax,ay,az,temp,t,gz,gy,gx,note,roll_deg\n"
            "0.5,0,9.8,,0,0.3,0.2,0.1,still,12\n"
            "0.6,0,9.7,25.1,0.01,0.3,0.2,0.1,x,abc\n")
    log = read_imu_csv(write(tmp_path, text))
    assert log.t.tolist() == [0.0, 0.01] and log.mag is None
    assert log.gyro.tolist() == [[0.1, 0.2, 0.3]] * 2
    assert log.accel.tolist() == [[0.5, 0.0, 9.8], [0.6, 0.0, 9.7]]


@pytest.mark.parametrize(
    "text, where",
    [
        ("time,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,1\n", ":1:"),
        ("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,1\n0.1,0,0,0,0,0\n", ":3: expected 7 fields"),
        ("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,1\n0.1,0,0,x,0,0,1\n", ":3: column 'gz'"),
        ("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,1\n0.1,0,0,0,0,0,1\n0.1,0,0,0,0,0,1\n", ":4: timestamp"),
        # blank lines count as lines: the editor's line number, a plain number in the message
        ("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,1\n\n4.99,0,0,0,0,0,1\n4.99,0,0,0,0,0,1\n",
         ":5: timestamp 4.99 does not increase (previous 4.99)"),
        ("t,gx,gy,gz,ax,ay,az,temp\n0,0,0,0,0,0,1,\n0.1,0,0,0,0,0,1\n", ":3: expected 8 fields"),
        ("t,gx,gy,ax,ay,az\n0,0,0,0,0,1\n", ":1: header has no column 'gz'"),
        ("t,gx,gy,gz,ax,ay,az,mx\n0,0,0,0,0,0,1,3\n", ":1: magnetometer columns"),
        ("t,gx,gy,gz,ax,ay,az,t\n0,0,0,0,0,0,1,3\n", ":1: column 't' appears twice"),
    ],
)
def test_imu_csv_errors_name_file_and_line(tmp_path, text, where):
    path = write(tmp_path, text)
    with pytest.raises(LogFormatError) as info:
        read_imu_csv(path)
    assert str(path) in str(info.value) and where in str(info.value)


def test_gyro_and_accelerometer_columns_exchanged_are_refused(tmp_path):
    # the documented header over rows in t,ax,ay,az,gx,gy,gz order: rates averaging gravity
    rows = "".join(f"{0.01 * i},0.1,-0.2,9.79,0.001,0.002,-0.003\n" for i in range(50))
    with pytest.raises(LogFormatError, match="columns are exchanged") as info:
        read_imu_csv(write(tmp_path, "t,gx,gy,gz,ax,ay,az\n" + rows))
    assert "a magnitude of 9.79" in str(info.value)
    # the right order, and a driver that removed gravity (rates and accelerations small)
    right = "".join(f"{0.01 * i},0.001,0.002,-0.003,0.1,-0.2,9.79\n" for i in range(50))
    assert read_imu_csv(write(tmp_path, "t,gx,gy,gz,ax,ay,az\n" + right)).t.size == 50
    removed = "".join(f"{0.01 * i},0.001,0.002,-0.003,0.1,-0.2,0.05\n" for i in range(50))
    assert read_imu_csv(write(tmp_path, "t,gx,gy,gz,ax,ay,az\n" + removed)).t.size == 50


def test_attitude_csv_is_replaced_atomically(tmp_path):
    out = tmp_path / "att.csv"
    write_attitude_csv(out, [0.0, 0.1], [[1, 0, 0, 0], [0, 1, 0, 0]])
    lines = out.read_text().splitlines()
    assert lines[0] == "t,qw,qx,qy,qz,roll,pitch,yaw"
    assert len(lines) == 3 and not list(tmp_path.glob("*.partial"))
