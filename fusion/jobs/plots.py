"""The replay's PNG: trajectories (fused, reference, truth) and yaw against time.

Needs matplotlib (the ``demo`` extra). The PNG is written atomically with the umask's
permissions.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.atomic import create_temp_file

__all__ = ["FUSED_LABEL", "WHEEL_LABEL", "plot_replay"]

#: Trace names: what each line is.
FUSED_LABEL = "fused (EKF: wheel odometry + gyro)"
WHEEL_LABEL = "wheel odometry alone (dead reckoning)"


def plot_replay(path: Path, title: str, t: NDArray[np.float64], pose: NDArray[np.float64],
                ref_t: NDArray[np.float64], ref: NDArray[np.float64],
                truth_t: NDArray[np.float64] | None, truth: NDArray[np.float64] | None,
                ref_label: str = WHEEL_LABEL,
                more_yaw: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64]]] = (),
                more_xy: Sequence[tuple[str, NDArray[np.float64]]] = ()) -> None:
    """Draw the fused track ``pose`` ((N, 3) x m, y m, yaw rad at ``t`` s) beside a
    reference track ``ref`` at ``ref_t`` (named ``ref_label``) and, when given, the truth;
    right: the yaw error against the truth, or without it the yaws (unwrapped, deg, each from
    its start), with ``more_yaw`` traces ``(label, t s, yaw rad)`` (e.g. a bag's own IMU
    orientation); ``more_xy``: points ``(label, (K, 2) x m, y m)`` on the trajectory (e.g. GPS
    fixes moved into the fused track's frame)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.5))
    try:
        if truth is not None:
            ax1.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="truth")
        ax1.plot(ref[:, 0], ref[:, 1], "-", color="tab:orange", lw=1, label=ref_label)
        ax1.plot(pose[:, 0], pose[:, 1], "-", color="tab:blue", lw=1, label=FUSED_LABEL)
        for label, xy in more_xy:
            ax1.plot(xy[:, 0], xy[:, 1], ".", color="tab:green", ms=3, label=label)
        ax1.set_aspect("equal", adjustable="datalim")
        ax1.set_xlabel("x (m)")
        ax1.set_ylabel("y (m)")
        ax1.grid(True, alpha=0.3)
        ax1.legend(loc="best", fontsize=9)
        ax1.set_title("Trajectory in odom")
        if truth is not None:
            def err(ts, yaw):
                want = np.interp(ts, truth_t, np.unwrap(truth[:, 2]))
                return np.degrees(np.angle(np.exp(1j * (yaw - want))))

            inside = (t >= truth_t[0]) & (t <= truth_t[-1])
            r_in = (ref_t >= truth_t[0]) & (ref_t <= truth_t[-1])
            ax2.plot(ref_t[r_in], err(ref_t[r_in], ref[r_in, 2]), color="tab:orange", lw=1,
                     label=ref_label)
            ax2.plot(t[inside], err(t[inside], pose[inside, 2]), color="tab:blue", lw=1,
                     label=FUSED_LABEL)
            ax2.axhline(0.0, color="k", lw=0.8)
            ax2.set_ylabel("yaw error (deg)")
            ax2.set_title("Yaw error against the truth")
        else:
            ax2.plot(ref_t, np.degrees(np.unwrap(ref[:, 2])), color="tab:orange", lw=1,
                     label=ref_label)
            ax2.plot(t, np.degrees(np.unwrap(pose[:, 2])), color="tab:blue", lw=1,
                     label=FUSED_LABEL)
            for (label, ts, yaw), color in zip(more_yaw, ("tab:green", "tab:red",
                                                           "tab:purple")):
                ok = np.isfinite(yaw)
                y = np.unwrap(yaw[ok])
                ax2.plot(ts[ok], np.degrees(y - y[0]), color=color, lw=1, label=label)
            ax2.set_ylabel("yaw, unwrapped (deg)")
            ax2.set_title("Yaw (no truth in the log)")
        ax2.set_xlabel("t (s)")
        ax2.grid(True, alpha=0.3)
        ax2.legend(loc="best", fontsize=9)
        fig.suptitle(f"fusion replay: {title}")
        fig.tight_layout()
        tmp = create_temp_file(path)
        try:
            fig.savefig(tmp, dpi=100, format="png")
            tmp.replace(path)
        finally:
            tmp.unlink(missing_ok=True)
    finally:
        plt.close(fig)
