"""fusion.geometry.mount: IMU mount rotation, vertical rate and heading rate against scipy's
Rotation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.geometry.mount import (
    base_to_imu,
    heading_rate,
    imu_to_base,
    mount_matrix,
    vertical_rate,
)

RPY = [(0.0, 0.0, 0.0), (0.03, -0.02, 0.0), (0.4, -0.3, 1.2), (np.pi, 0.1, -2.0)]


@pytest.mark.parametrize("rpy", RPY)
def test_mount_matrix_is_urdf_rpy(rpy):
    # URDF rpy: fixed axes x, then y, then z = scipy's extrinsic "xyz"
    ref = Rotation.from_euler("xyz", rpy).as_matrix()
    np.testing.assert_allclose(mount_matrix(rpy), ref, rtol=0, atol=1e-15)


@pytest.mark.parametrize("rpy", RPY)
def test_rotations_match_scipy_and_invert(rpy):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(50, 3)) * [1.0, 1.0, 10.0]
    rot = Rotation.from_euler("xyz", rpy)
    R = mount_matrix(rpy)
    np.testing.assert_allclose(imu_to_base(R, v), rot.apply(v), rtol=0, atol=1e-13)
    np.testing.assert_allclose(base_to_imu(R, v), rot.inv().apply(v), rtol=0, atol=1e-13)
    np.testing.assert_allclose(base_to_imu(R, imu_to_base(R, v)), v, rtol=0, atol=1e-13)


@pytest.mark.parametrize("rpy", RPY)
def test_mount_matrix_is_the_robot_config_rotation_bit_for_bit(rpy):
    # the pipeline builds its matrix from RobotConfig.imu_to_base(): swapping it for
    # mount_matrix must not move a bit
    from fusion.geometry import quaternion as quat
    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.planar.robot import RobotConfig

    robot = RobotConfig(chassis=DiffDriveParams(0.3, 1e-4), imu_mount_rpy=tuple(rpy))
    np.testing.assert_array_equal(mount_matrix(rpy), quat.to_matrix(robot.imu_to_base()))


def test_one_vector_and_a_stack_give_the_same_floats():
    R = mount_matrix((0.4, -0.3, 1.2))
    v = np.random.default_rng(2).normal(size=(200, 3))
    stack = imu_to_base(R, v)
    one = np.array([imu_to_base(R, row) for row in v])
    rows = np.array([[R[i][0] * x + R[i][1] * y + R[i][2] * z for i in range(3)]
                     for x, y, z in v.tolist()])  # Python floats, term by term
    np.testing.assert_array_equal(stack, one)
    np.testing.assert_array_equal(stack, rows)
    assert imu_to_base(R.tolist(), v).tolist() == stack.tolist()


def test_vertical_rate_matches_scipy():
    rng = np.random.default_rng(4)
    q = rng.normal(size=(300, 4)) * 3.0  # not normalised: vertical_rate normalises
    g = rng.normal(size=(300, 3))
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]])  # scipy is scalar last
    np.testing.assert_allclose(vertical_rate(g, q), rot.apply(g)[:, 2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(vertical_rate(g), g[:, 2])
    # one sample: the same floats as its row in the batch
    assert vertical_rate(g[5], q[5]) == vertical_rate(g, q)[5]


def test_heading_rate_is_the_rate_of_scipys_zyx_yaw():
    # central difference of scipy's ZYX yaw over a small body rotation at random attitudes
    # (pitch within +-70 deg) and rates
    rng = np.random.default_rng(6)
    euler = np.column_stack([rng.uniform(-np.pi, np.pi, 300), rng.uniform(-1.2, 1.2, 300),
                             rng.uniform(-np.pi, np.pi, 300)])  # yaw, pitch, roll
    rot = Rotation.from_euler("ZYX", euler)
    g = rng.normal(size=(300, 3))
    h = 1e-5
    ahead = (rot * Rotation.from_rotvec(g * h)).as_euler("ZYX")[:, 0]
    back = (rot * Rotation.from_rotvec(-g * h)).as_euler("ZYX")[:, 0]
    expected = np.angle(np.exp(1j * (ahead - back))) / (2 * h)
    q = rot.as_quat()[:, [3, 0, 1, 2]] * 2.0  # scalar first, not normalised
    np.testing.assert_allclose(heading_rate(g, q), expected, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(heading_rate(g), g[:, 2])
    # one sample: the same floats as its row in the batch
    assert heading_rate(g[7], q[7]) == heading_rate(g, q)[7]


def test_heading_rate_integrates_to_the_heading_across_hills_where_the_vertical_rate_drifts():
    # roll and pitch changing together (driving across rolling hills, exaggerated): the
    # integral of the rate about the vertical leaves the heading by degrees, the heading
    # rate's does not
    t = np.linspace(0.0, 20.0, 200_001)
    dt = t[1] - t[0]
    euler = np.column_stack([0.5 * np.sin(0.3 * t) + 0.2 * t, 0.25 * np.sin(0.7 * t + 1.0),
                             0.3 * np.sin(0.5 * t + 2.0)])
    rot = Rotation.from_euler("ZYX", euler)
    step = (rot[:-1].inv() * rot[1:]).as_rotvec()  # body rotation of each step
    mid = (rot[:-1] * Rotation.from_rotvec(step / 2)).as_quat()[:, [3, 0, 1, 2]]
    rates = step / dt
    yaw = euler[:, 0]
    by_heading = yaw[0] + np.concatenate([[0.0], np.cumsum(heading_rate(rates, mid) * dt)])
    by_vertical = yaw[0] + np.concatenate([[0.0], np.cumsum(vertical_rate(rates, mid) * dt)])
    assert np.abs(by_heading - yaw).max() < 1e-6
    assert np.degrees(np.abs(by_vertical - yaw).max()) > 5.0


def test_the_public_ekf_copy_gives_the_same_floats():
    # fusion.planar.ekf.vertical_rate (public) is to delegate here: nothing may move
    from fusion.planar import ekf

    rng = np.random.default_rng(5)
    q, g = rng.normal(size=(500, 4)), rng.normal(size=(500, 3))
    np.testing.assert_array_equal(ekf.vertical_rate(g, q), vertical_rate(g, q))


def test_bad_shapes_name_the_shape():
    with pytest.raises(ValueError, match=r"\(2,\)"):
        vertical_rate(np.zeros(2))
    with pytest.raises(ValueError, match=r"\(3,\)"):
        vertical_rate(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\(2,\)"):
        heading_rate(np.zeros(2))
    with pytest.raises(ValueError, match=r"\(3,\)"):
        heading_rate(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="rpy"):
        mount_matrix((0.0, 0.0))
    with pytest.raises(ValueError, match=r"\(4,\)"):
        imu_to_base(np.eye(3), np.zeros(4))
