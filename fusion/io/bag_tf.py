"""The IMU's mount from a bag's static transforms (``/tf_static``).

A robot's description (URDF through robot_state_publisher, or static_transform_publisher)
puts the IMU's frame in the base's on ``/tf_static`` (tf2_msgs/TFMessage), and a bag recorded
with it holds that tree. The IMU's messages name their frame (``header.frame_id``) and the
odometry names the base (``child_frame_id``), so the rotation taking IMU-frame vectors into the
base frame is the chain of static transforms between the two, whichever way each is stored.

Frames are compared without a leading "/" (ROS 1's tf allowed "/base_link"). A transform
published twice on ``/tf_static`` keeps its last value (tf2's static buffer does the same).
Only ``/tf_static`` is read: ``/tf`` carries the moving frames (odom -> base), and a mount
published there by an old static_transform_publisher is not told apart from motion here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.geometry import quaternion as quat

__all__ = ["TF_STATIC_TOPIC", "StaticMount", "mount_angle", "read_static_mount",
           "static_chain"]

TF_STATIC_TOPIC = "/tf_static"


@dataclass(frozen=True)
class StaticMount:
    """The IMU's mount found in a bag: ``rpy`` URDF roll, pitch, yaw (rad) of the IMU frame
    in the base frame (as robot.toml's ``imu_mount_rpy``), ``chain`` the frames from the base
    to the IMU, ``source`` the file."""

    rpy: tuple[float, float, float]
    chain: tuple[str, ...]
    source: str

    def describe(self) -> str:
        r, p, y = (round(a, 4) + 0.0 for a in self.rpy)  # no "-0.0000" for a rounding error
        return (f"{TF_STATIC_TOPIC} {' -> '.join(self.chain)}: roll {r:.4f} pitch {p:.4f} "
                f"yaw {y:.4f} rad")


def _frame(name: str) -> str:
    return name.lstrip("/")


def static_chain(edges: dict[tuple[str, str], NDArray[np.float64]], base: str,
                 imu: str) -> tuple[NDArray[np.float64], tuple[str, ...]] | None:
    """The rotation of frame ``imu`` in frame ``base`` as a unit quaternion ``[w, x, y, z]``
    (it takes ``imu``-frame vectors into ``base``) and the frames between, from ``edges``
    ``{(parent, child): q}`` (``q`` the child's orientation in the parent, as a
    geometry_msgs/Transform's rotation); None when no chain of edges joins them."""
    base, imu = _frame(base), _frame(imu)
    links: dict[str, list[tuple[str, NDArray[np.float64]]]] = {}
    for (parent, child), q in edges.items():
        links.setdefault(parent, []).append((child, q))
        links.setdefault(child, []).append((parent, quat.conjugate(q)))
    if base not in links or imu not in links:
        return None
    found: dict[str, tuple[NDArray[np.float64], tuple[str, ...]]] = {
        base: (np.array([1.0, 0.0, 0.0, 0.0]), (base,))}
    queue = deque([base])
    while queue:
        frame = queue.popleft()
        q_frame, path = found[frame]
        for nxt, q in links[frame]:
            if nxt not in found:
                found[nxt] = (quat.normalize(quat.multiply(q_frame, q)), (*path, nxt))
                queue.append(nxt)
    return found.get(imu)


def read_static_mount(path: str | Path, base: str, imu: str) -> StaticMount | None:
    """The IMU's mount from the ``/tf_static`` of the bag or MCAP file at ``path``: the chain
    of static transforms from frame ``base`` (the odometry's ``child_frame_id``) to ``imu``
    (the IMU messages' ``frame_id``); None when the file has no ``/tf_static``
    (tf2_msgs/TFMessage), either frame is unnamed, they are the same frame, or no chain joins
    them. Needs the ``ros`` extra (rosbags), as any bag."""
    from fusion.io.bags import open_bag

    if not base or not imu or _frame(base) == _frame(imu):
        return None
    edges: dict[tuple[str, str], NDArray[np.float64]] = {}
    with open_bag(Path(path)) as bag:
        if bag.topics.get(TF_STATIC_TOPIC, ("", 0))[0] != "tf2_msgs/TFMessage":
            return None
        for _topic, _ns, msg, _pub in bag.messages([TF_STATIC_TOPIC]):
            for tf in msg.transforms:
                r = tf.transform.rotation
                q = np.array([r.w, r.x, r.y, r.z], dtype=float)
                if np.isfinite(q).all() and np.linalg.norm(q) > 0.5:
                    edges[_frame(tf.header.frame_id), _frame(tf.child_frame_id)] = (
                        quat.normalize(q))
    chain = static_chain(edges, base, imu)
    if chain is None:
        return None
    q, frames = chain
    roll, pitch, yaw = (float(a) for a in quat.to_euler(q))
    return StaticMount((roll, pitch, yaw), frames, str(path))


def mount_angle(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """rad: the angle of the rotation between two mounts given as URDF roll, pitch, yaw."""
    from fusion.geometry.mount import mount_matrix

    rel = mount_matrix(a).T @ mount_matrix(b)
    return math.acos(max(-1.0, min(1.0, (float(np.trace(rel)) - 1.0) / 2.0)))
