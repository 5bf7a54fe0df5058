"""FusedOdometry: the record every sink consumes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.types.fused import FusedOdometry, yaw_quaternion


def _pose_cov() -> np.ndarray:
    c = np.zeros((6, 6))
    c[0, 0], c[1, 1], c[5, 5] = 0.04, 0.09, 0.0025
    c[0, 1] = c[1, 0] = 0.01
    c[0, 5] = c[5, 0] = -0.002
    c[2, 2] = c[3, 3] = c[4, 4] = 99999.0
    return c


@pytest.mark.parametrize("yaw", [0.0, 0.3, -2.0, math.pi, 7.5])
def test_yaw_quaternion_matches_scipy(yaw: float) -> None:
    x, y, z, w = Rotation.from_euler("z", yaw).as_quat()  # scipy is scalar last
    q = yaw_quaternion(yaw)
    # q and -q are the same rotation: compare up to sign
    sign = np.sign(np.dot(q, [w, x, y, z]))
    np.testing.assert_allclose(sign * q, [w, x, y, z], atol=1e-15)


def test_covariance_accepts_row_major_36_and_6x6() -> None:
    c = _pose_cov()
    a = FusedOdometry(t=1.0, x=0, y=0, yaw=0, v=0, w=0, pose_covariance=c.reshape(36))
    b = FusedOdometry(t=1.0, x=0, y=0, yaw=0, v=0, w=0, pose_covariance=c)
    assert a.pose_covariance.shape == (6, 6)
    # row-major: element (0, 5) is index 5, (5, 0) is index 30
    assert a.pose_covariance[0, 5] == c.reshape(36)[5] == -0.002
    assert a.pose_covariance[5, 0] == c.reshape(36)[30]
    assert a == b


def test_defaults_and_frames() -> None:
    r = FusedOdometry(t=2.5, x=1, y=2, yaw=0.5, v=0.3, w=-0.1)
    assert (r.frame_id, r.child_frame_id, r.imu_frame_id) == ("odom", "base_footprint",
                                                             "base_footprint")
    # unobserved components carry seed 000's 99999, observed ones 0
    assert np.diag(r.pose_covariance).tolist() == [0, 0, 99999, 99999, 99999, 0]
    assert np.diag(r.twist_covariance).tolist() == [0, 99999, 99999, 99999, 99999, 0]
    assert r.angular_velocity.tolist() == [0.0, 0.0, -0.1]
    assert r.orientation is None and r.linear_acceleration is None
    np.testing.assert_array_equal(r.orientation_or_yaw, yaw_quaternion(0.5))


def test_orientation_is_normalised_and_preferred() -> None:
    q = np.array([0.9, 0.1, -0.05, 0.4])
    q /= np.linalg.norm(q)
    r = FusedOdometry(t=0, x=0, y=0, yaw=0.1, v=0, w=0, orientation=q * (1 + 5e-4))
    np.testing.assert_allclose(r.orientation, q, atol=1e-15)
    np.testing.assert_allclose(r.orientation_or_yaw, q, atol=1e-15)
    np.testing.assert_array_equal(r.yaw_quaternion, yaw_quaternion(0.1))


def test_record_is_immutable() -> None:
    r = FusedOdometry(t=0, x=0, y=0, yaw=0, v=0, w=0, pose_covariance=_pose_cov())
    with pytest.raises(AttributeError):
        r.x = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        r.pose_covariance[0, 0] = 5.0


def test_json_round_trip() -> None:
    r = FusedOdometry(
        t=12.34, x=1.5, y=-0.25, yaw=3.0, v=0.2, w=0.05, pose_covariance=_pose_cov(),
        orientation=[1, 0, 0, 0], angular_velocity=[0.01, -0.02, 0.05],
        linear_acceleration=[0.1, 0.0, 9.81], wheel_left_speed=0.19, wheel_right_speed=0.21,
        frame_id="odom2", child_frame_id="base_link", imu_frame_id="imu_link",
    )
    d = json.loads(json.dumps(r.to_dict()))
    assert len(d["pose_covariance"]) == 36
    assert d["pose_covariance"][5] == -0.002
    assert FusedOdometry.from_dict(d) == r


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x": float("nan")}, "x must be finite"),
        ({"t": float("inf"), "w": -float("inf")}, "t must be finite"),
        ({"pose_covariance": np.eye(5)}, "6x6 or 36"),
        ({"pose_covariance": np.triu(np.ones((6, 6)))}, "symmetric"),
        ({"twist_covariance": np.full(36, np.inf)}, "finite"),
        ({"orientation": [1, 1, 0, 0]}, "unit quaternion"),
        ({"orientation": [1, 0, 0]}, r"\[w, x, y, z\]"),
        ({"angular_velocity": [0, 0]}, "3 elements"),
        ({"wheel_left_speed": float("inf")}, "wheel_left_speed"),
        ({"frame_id": ""}, "frame_id"),
    ],
)
def test_bad_values_are_named(kwargs: dict, match: str) -> None:
    base = {"t": 0.0, "x": 0.0, "y": 0.0, "yaw": 0.0, "v": 0.0, "w": 0.0}
    with pytest.raises(ValueError, match=match):
        FusedOdometry(**{**base, **kwargs})


def test_from_dict_rejects_unknown_keys() -> None:
    with pytest.raises(ValueError, match="unknown FusedOdometry fields: speed"):
        FusedOdometry.from_dict({"t": 0, "x": 0, "y": 0, "yaw": 0, "v": 0, "w": 0, "speed": 1})
