"""Quaternion helpers against scipy's Rotation (an independent implementation)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.geometry import quaternion as Q

RNG = np.random.default_rng(1234)
N = 500


def random_rotations(n=N):
    return Rotation.random(n, random_state=RNG)


def test_scipy_crossing_round_trip():
    r = random_rotations()
    q = Q.from_scipy(r)
    assert np.allclose(q[:, 1:], r.as_quat()[:, :3]) and np.allclose(q[:, 0], r.as_quat()[:, 3])
    assert np.allclose(Q.to_scipy(q).as_quat(), r.as_quat())


def test_multiply_matches_scipy_composition():
    a, b = random_rotations(), random_rotations()
    got = Q.multiply(Q.from_scipy(a), Q.from_scipy(b))
    want = Q.from_scipy(a * b)
    # q and -q are the same rotation
    assert np.allclose(np.abs(np.sum(got * want, axis=-1)), 1.0)


def test_rotate_and_inverse_match_scipy():
    r = random_rotations()
    v = RNG.normal(size=(N, 3))
    q = Q.from_scipy(r)
    assert np.allclose(Q.rotate(q, v), r.apply(v))
    assert np.allclose(Q.rotate_inverse(q, v), r.apply(v, inverse=True))
    assert np.allclose(Q.rotate(Q.conjugate(q), v), r.inv().apply(v))


def test_matrix_round_trip_and_scipy():
    r = random_rotations()
    q = Q.from_scipy(r)
    assert np.allclose(Q.to_matrix(q), r.as_matrix())
    back = Q.from_matrix(r.as_matrix())
    assert np.all(back[:, 0] >= 0)
    assert np.allclose(np.abs(np.sum(back * q, axis=-1)), 1.0)


@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-9])
def test_from_matrix_near_180_degrees(angle):
    for axis in np.eye(3):
        r = Rotation.from_rotvec(axis * angle)
        q = Q.from_matrix(r.as_matrix())
        assert np.isclose(abs(np.dot(q, Q.from_scipy(r))), 1.0)


def test_euler_matches_scipy_zyx():
    r = random_rotations()
    yaw, pitch, roll = r.as_euler("ZYX").T
    got = Q.to_euler(Q.from_scipy(r))
    assert np.allclose(got, np.stack([roll, pitch, yaw], -1))
    q = Q.from_euler(roll, pitch, yaw)
    assert np.allclose(np.abs(np.sum(q * Q.from_scipy(r), -1)), 1.0)


def test_euler_gimbal_lock_does_not_nan():
    q = Q.from_euler(0.0, np.pi / 2, 0.0) * (1 + 1e-15)
    assert np.all(np.isfinite(Q.to_euler(q)))


def test_rotation_vector_matches_scipy():
    rv = RNG.normal(size=(N, 3)) * 2
    rv[:5] *= 1e-12
    got = Q.from_rotation_vector(rv)
    want = Q.from_scipy(Rotation.from_rotvec(rv))
    assert np.allclose(np.abs(np.sum(got * want, -1)), 1.0, atol=1e-12)


def test_normalize_and_errors():
    q = RNG.normal(size=(N, 4))
    assert np.allclose(np.linalg.norm(Q.normalize(q), axis=-1), 1.0)
    with pytest.raises(ValueError):
        Q.normalize([0, 0, 0, 0])
    with pytest.raises(ValueError, match="shape"):
        Q.multiply([1, 0, 0], [1, 0, 0, 0])


def test_from_accel_recovers_roll_pitch():
    r = random_rotations()
    g_body = r.apply([0, 0, 9.81], inverse=True)  # specific force at rest, body frame
    q = Q.from_accel(g_body)
    roll, pitch, yaw = Q.to_euler(q).T
    _, want_pitch, want_roll = r.as_euler("ZYX").T
    assert np.allclose(yaw, 0.0)
    assert np.allclose(pitch, want_pitch)
    assert np.allclose(roll, want_roll)
    with pytest.raises(ValueError):
        Q.from_accel([0, 0, 0])


def test_from_accel_mag_recovers_full_attitude():
    r = random_rotations()
    field_enu = np.array([0.0, 20.0, -45.0])  # north and down (northern hemisphere), uT
    a = r.apply([0, 0, 9.81], inverse=True)
    m = r.apply(field_enu, inverse=True)
    q = Q.from_accel_mag(a, m)
    assert np.allclose(np.abs(np.sum(q * Q.from_scipy(r), -1)), 1.0)
    with pytest.raises(ValueError):
        Q.from_accel_mag([0, 0, 1], [0, 0, 5])
