"""BROAD error metrics against scipy and analytic decompositions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.evaluation.orientation import error_angles, orientation_rmse
from fusion.geometry import quaternion as Q

RNG = np.random.default_rng(5)


def test_total_error_matches_scipy_magnitude():
    ref = Rotation.random(300, random_state=RNG)
    est = Rotation.random(300, random_state=RNG)
    total, _, _ = error_angles(Q.from_scipy(est), Q.from_scipy(ref))
    assert np.allclose(total, (est * ref.inv()).magnitude(), atol=1e-7)


@pytest.mark.parametrize("heading, tilt", [(0.3, 0.0), (0.0, 0.2), (-1.1, 0.45), (2.5, -0.7)])
def test_heading_and_inclination_split_an_error(heading, tilt):
    """q_err = Rz(heading) * Rx(tilt) in the earth frame: heading and tilt come back exactly."""
    ref = Rotation.random(50, random_state=RNG)
    err = Rotation.from_euler("z", heading) * Rotation.from_euler("x", tilt)
    est = err * ref
    total, head, incl = error_angles(Q.from_scipy(est), Q.from_scipy(ref))
    assert np.allclose(head, abs(heading), atol=1e-7)
    assert np.allclose(incl, abs(tilt), atol=1e-7)
    assert np.allclose(total, err.magnitude(), atol=1e-7)


def test_rmse_skips_nan_rows_and_applies_mask():
    ref = Q.from_scipy(Rotation.random(10, random_state=RNG))
    est = Q.multiply(Q.from_rotation_vector([0.0, 0.0, np.radians(2.0)]), ref)
    est[3] = np.nan
    ref[4] = np.nan
    mask = np.ones(10, bool)
    mask[0] = False
    e = orientation_rmse(est, ref, mask)
    assert e.samples == 7
    assert e.heading_deg == pytest.approx(2.0)
    assert e.inclination_deg == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="no valid samples"):
        orientation_rmse(est, ref, np.zeros(10, bool))
    with pytest.raises(ValueError, match="mask"):
        orientation_rmse(est, ref, np.ones(9, bool))
