"""The Mahony filter on the real BROAD trials against the dataset's published results."""

import json

import numpy as np
import pytest

from fusion.attitude.mahony import Mahony
from fusion.evaluation.orientation import orientation_rmse
from fusion.io.broad import read_broad


@pytest.fixture(scope="module")
def broad_dir(datasets_dir):
    return datasets_dir / "broad"


@pytest.fixture(scope="module")
def trials(broad_dir):
    paths = sorted(broad_dir.glob("*.mat"))
    assert len(paths) == 10
    return [read_broad(p) for p in paths]


@pytest.fixture(scope="module")
def published(broad_dir):
    with open(broad_dir / "published_mahony_average_rmse.json") as fh:
        return json.load(fh)


def test_nine_axis_reproduces_published_table(trials, published):
    """Kp 0.74, Ki 0.0012 from the dataset's own initial state: every trial within 0.01 deg.

    Measured on this port: largest deviation 0.0005 deg (trial 14), most below 0.0002 deg.
    """
    assert published["tagp_parameters"] == {"Kp": 0.74, "Ki": 0.0012}
    worst = 0.0
    for tr in trials:
        f = Mahony(0.74, 0.0012, axes=9, sample_period=1 / tr.rate,
                   initial_quaternion=tr.reference_initial_quaternion())
        q = f.update_batch(tr.gyro, tr.accel, tr.mag)
        got = orientation_rmse(q, tr.quat_ref, tr.movement)
        want = published["trials"][tr.name]["tagp_parameters"]
        for key, value in (("total_rmse_deg", got.total_deg),
                           ("heading_rmse_deg", got.heading_deg),
                           ("inclination_rmse_deg", got.inclination_deg)):
            assert value == pytest.approx(want[key], abs=0.01), (tr.name, key)
        worst = max(worst, abs(got.total_deg - want["total_rmse_deg"]))
    assert worst < 0.002  # a float64 port lands within about 0.001 deg


def test_physically_correct_start_differs_from_quirk(trials):
    """The library's own initialisation is the correct attitude, not the dataset's quirk."""
    tr = trials[0]
    f = Mahony(0.74, 0.0012, axes=9, sample_period=1 / tr.rate)
    f.update_batch(tr.gyro[:1], tr.accel[:1], tr.mag[:1])
    quirk = tr.reference_initial_quaternion()
    # The correct start is close to the optical ground truth at rest; the quirk is not.
    ref0 = tr.quat_ref[np.flatnonzero(np.all(np.isfinite(tr.quat_ref), axis=1))[0]]
    def angle(a, b):
        return np.degrees(2 * np.arccos(min(1.0, abs(float(np.dot(a, b))))))
    assert angle(f.quaternion, ref0) < angle(quirk, ref0)


def test_six_axis_defaults_inclination(trials):
    """The 6-axis defaults reach a mean inclination RMSE <= 2.0 deg over the ten trials."""
    errs = []
    for tr in trials:
        f = Mahony(sample_period=1 / tr.rate)
        q = f.update_batch(tr.gyro, tr.accel)
        errs.append(orientation_rmse(q, tr.quat_ref, tr.movement).inclination_deg)
    assert np.mean(errs) <= 2.0, errs
