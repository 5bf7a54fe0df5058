"""The IMU's mount from a bag's ``/tf_static`` (fusion.io.bag_tf) and its use by ``fusion replay``.

Oracle: scipy's rotations (URDF roll-pitch-yaw is scipy's extrinsic "xyz": ``R = Rz Ry Rx``),
composed independently of the library's quaternions; and a replay of the same bag with the
mount given by hand (``--imu-mount-rpy``, issue 11's real bag's mount).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from reshaped_bag import (
    IMU_TOPIC,
    MOUNT_RPY,
    ODOM_TOPIC,
    reshape_jackal_bag,
    with_static_transforms,
)
from scipy.spatial.transform import Rotation

from fusion.cli import main
from fusion.io.bag_tf import mount_angle, static_chain


def _wxyz(rot: Rotation) -> np.ndarray:
    x, y, z, w = rot.as_quat()
    return np.array([w, x, y, z])


def _xyzw(rpy) -> tuple[float, float, float, float]:
    return tuple(float(v) for v in Rotation.from_euler("xyz", rpy).as_quat())


def test_a_chain_of_static_transforms_composes_as_scipy_does() -> None:
    # base_footprint -> base_link -> plate, and imu_link stored as the plate's PARENT (a
    # tree published the other way round): the chain is walked either way
    a = Rotation.from_euler("xyz", (0.0, 0.0, 0.2))
    b = Rotation.from_euler("xyz", (0.1, -0.3, 1.2))
    c = Rotation.from_euler("xyz", (2.0, 0.4, -0.7))  # plate in imu_link
    edges = {("base_footprint", "base_link"): _wxyz(a), ("base_link", "plate"): _wxyz(b),
             ("imu_link", "plate"): _wxyz(c), ("odom", "gps"): _wxyz(a)}
    q, chain = static_chain(edges, "base_footprint", "/imu_link")
    assert chain == ("base_footprint", "base_link", "plate", "imu_link")
    expected = a * b * c.inv()
    got = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    assert (got.inv() * expected).magnitude() < 1e-12
    # unjoined frames, an unknown frame: no chain
    assert static_chain(edges, "base_link", "gps") is None
    assert static_chain(edges, "base_link", "camera") is None


def test_mount_angle_is_the_rotation_between_two_mounts() -> None:
    a, b = (0.3, -0.2, 1.0), (1.5708, 0.0, -1.5708)
    expected = (Rotation.from_euler("xyz", a).inv() * Rotation.from_euler("xyz", b)).magnitude()
    assert mount_angle(a, b) == pytest.approx(expected, abs=1e-9)
    assert mount_angle(b, b) == pytest.approx(0.0, abs=1e-6)


@pytest.fixture(scope="module")
def bags(datasets_dir, tmp_path_factory):
    """The Jackal bag in issue 11's real bag's shape (IMU rolled +90, yawed -90 deg), without
    and with a /tf_static that puts imu_link in base_link through a mount plate."""
    pytest.importorskip("rosbags")
    root = tmp_path_factory.mktemp("bag_tf")
    plain = root / "plain.bag"
    reshape_jackal_bag(datasets_dir / "rosbag" / "jackal_sim_test2.bag", plain)
    tf = root / "tf.bag"
    with_static_transforms(plain, tf, [
        ("/base_link", "plate", _xyzw((0.0, 0.0, MOUNT_RPY[2]))),
        ("plate", "imu_link", _xyzw((MOUNT_RPY[0], MOUNT_RPY[1], 0.0)))])
    return plain, tf


def _replay(bag, out, capsys, *extra):
    code = main(["replay", str(bag), "--imu-topic", IMU_TOPIC, "--odom-topic", ODOM_TOPIC,
                 "-o", str(out), *extra])
    return code, capsys.readouterr().out, np.loadtxt(out, delimiter=",", skiprows=1,
                                                    usecols=range(4))


def test_a_bag_with_its_mount_on_tf_static_needs_no_mount_flag(bags, tmp_path, capsys) -> None:
    plain, tf = bags
    code, printed, by_hand = _replay(plain, tmp_path / "hand.csv", capsys,
                                     "--imu-mount-rpy", *map(str, MOUNT_RPY))
    assert code == 0 and "/tf_static" not in printed
    code, printed, from_tf = _replay(tf, tmp_path / "tf.csv", capsys)
    assert code == 0, printed
    (note,) = [ln for ln in printed.splitlines() if "IMU mount from the bag's" in ln]
    assert "base_link -> plate -> imu_link" in note
    r, p, y = (float(v) for v in note.split("roll ")[1].split(" rad")[0].replace(
        "pitch ", "").replace("yaw ", "").split())
    assert (r, p, y) == pytest.approx(MOUNT_RPY, abs=1e-4)
    assert "(mount)" not in printed  # the accelerometer agrees with it
    # the same track as with the mount given by hand (to the 4 decimals the note prints)
    np.testing.assert_allclose(from_tf[:, 1:4], by_hand[:, 1:4], atol=1e-3)


def test_a_mount_given_against_tf_static_is_said_and_used(bags, tmp_path, capsys) -> None:
    _, tf = bags
    # the flag wins; the bag's tree is named, 120 deg away; the accelerometer sides with the
    # tree (the mount check names the mount to set)
    code, printed, _ = _replay(tf, tmp_path / "flag.csv", capsys,
                               "--imu-mount-rpy", "0", "0", "0")
    (note,) = [ln for ln in printed.splitlines() if "/tf_static" in ln]
    apart = math.degrees(Rotation.from_euler("xyz", MOUNT_RPY).magnitude())
    assert f"is {apart:.1f} deg from --imu-mount-rpy" in note and "which was used" in note
    assert "inputs disagree (mount)" in printed
    # within the tolerance: nothing said
    close = (MOUNT_RPY[0] + math.radians(2.0), MOUNT_RPY[1], MOUNT_RPY[2])
    code, printed, _ = _replay(tf, tmp_path / "close.csv", capsys,
                               "--imu-mount-rpy", *map(str, close))
    assert code == 0 and "/tf_static" not in printed
