"""``fusion replay``: run the fused-odometry EKF over a log directory or a ROS bag.

Inputs:

- a log directory (``datasets/LOGDIR.md``): wheel ticks + IMU (+ truth);
- a ROS 1 ``.bag``, a ROS 2 bag folder or an ``.mcap`` file with ``--imu-topic``
  (sensor_msgs/Imu) and ``--odom-topic`` (nav_msgs/Odometry, whose twist is the wheel
  odometry, fused as an external twist), ``--imu-mount-rpy`` taking IMU-frame vectors into the
  base frame (URDF rpy, rad). Needs the ``ros`` extra (``rosbags``).

Output CSV (one row per IMU sample, or per wheel frame when the log has no IMU), header::

    t,x,y,yaw,v,w,gyro_bias_z,wheel_rate_scale,wheel_rate_per_speed,
    var_x,var_y,var_yaw,cov_xy,cov_x_yaw,cov_y_yaw

``t`` s (host clock), pose of base_footprint in odom (m, m, rad wrapped to (-pi, pi]), v m/s,
w rad/s, gyro bias rad/s, the wheel calibration states k (1) and c (rad/m) of
:mod:`fusion.ekf`, and the pose covariance (m^2, m*rad, rad^2).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.cli import CommandError

__all__ = ["FUSED_CSV_COLUMNS", "fuse_logdir", "register", "write_fused_csv"]

FUSED_CSV_COLUMNS = (
    "t", "x", "y", "yaw", "v", "w", "gyro_bias_z", "wheel_rate_scale", "wheel_rate_per_speed",
    "var_x", "var_y", "var_yaw", "cov_xy", "cov_x_yaw", "cov_y_yaw",
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="fused wheel + gyro odometry (EKF) of a log directory",
        description=(
            "Run the planar EKF (wheel odometry + gyro yaw rate with a gyro-bias state) over a "
            "log directory (robot.toml, imu.csv and/or wheels.csv, optional truth.csv; see "
            "datasets/LOGDIR.md) and write the fused odometry as CSV with the header "
            + ",".join(FUSED_CSV_COLUMNS)
            + ". Prints a summary; with truth.csv, the errors of the fused and of the "
            "wheel-only odometry."
        ),
    )
    p.add_argument("input", type=Path,
                   help="log directory, or a ROS 1 .bag / ROS 2 bag folder / .mcap file")
    p.add_argument("-o", "--output", type=Path, required=True, help="fused CSV to write")
    p.add_argument("--level", action="store_true",
                   help="take the robot as level: use the gyro's z axis as the yaw rate "
                        "(default: tilt-compensate with the Mahony attitude)")
    bag = p.add_argument_group("ROS bags")
    bag.add_argument("--imu-topic", help="sensor_msgs/Imu topic (bags only)")
    bag.add_argument("--odom-topic", help="nav_msgs/Odometry topic of the wheel odometry "
                                          "(bags only)")
    bag.add_argument("--imu-mount-rpy", type=float, nargs=3, metavar=("R", "P", "Y"),
                     default=(0.0, 0.0, 0.0),
                     help="URDF roll pitch yaw (rad) taking IMU-frame vectors into the base "
                          "frame (bags only; a log directory has it in robot.toml)")
    bag.add_argument("--robot", type=Path,
                     help="robot.toml for a bag (wheel_distance and [ekf] tuning; optional)")
    p.set_defaults(func=run)


def fuse_logdir(log, tilt: bool = True):
    """Fuse a :class:`fusion.logdir.LogDir`; returns ``(track, filter, rows)``.

    With ``tilt`` and an IMU, the yaw rate is the gyro rate about the world vertical, using
    the Mahony filter's attitude (6-axis); otherwise the gyro's z axis. ``rows`` is the mask of
    :meth:`fusion.ekf.FusedTrack.output_rows`.
    """
    from fusion.ekf import fuse, vertical_rate

    gyro_z = None
    if log.imu_t is not None and log.imu_t.size:
        if tilt and log.imu_t.size >= 2:
            from fusion.mahony import Mahony

            q = Mahony(axes=6).update_batch(log.gyro, log.accel, timestamps=log.imu_t)
            gyro_z = vertical_rate(log.gyro, q)
        else:
            gyro_z = log.gyro[:, 2].copy()
    track, ekf = fuse(log.robot.chassis, log.imu_t if gyro_z is not None else None, gyro_z,
                      log.wheel_t, log.ticks, log.robot.ekf)
    return track, ekf, track.output_rows()


def write_fused_csv(path: Path, t: NDArray[np.float64], states: NDArray[np.float64]) -> None:
    """Write the rows of :func:`fuse_logdir` (``states``: process_batch rows) atomically."""
    yaw = np.pi - np.mod(np.pi - states[:, 2], 2 * np.pi)
    table = np.column_stack([t, states[:, 0:2], yaw, states[:, 3:8], states[:, 8:11],
                             states[:, 16:19]])
    tmp = path.with_name(path.name + ".partial")
    try:
        np.savetxt(tmp, table, delimiter=",", header=",".join(FUSED_CSV_COLUMNS), comments="",
                   fmt="%.10g")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def run(args: argparse.Namespace) -> int:
    from fusion.logdir import read_logdir
    from fusion.odometry import WheelOdometry
    from fusion.trajectory_metrics import (
        final_position_error_percent,
        path_length,
        yaw_rmse,
    )

    path: Path = args.input
    if not path.exists():
        raise CommandError(f"{path}: no such log directory or bag")
    if _is_bag(path):
        return run_bag(args)
    if args.imu_topic or args.odom_topic:
        raise CommandError(f"{path}: --imu-topic/--odom-topic are for ROS bags; this is not "
                           "a .bag, .mcap or ROS 2 bag folder")
    if path.is_file():
        raise CommandError(f"{path}: is a file; replay takes a log directory "
                           "(robot.toml, imu.csv, wheels.csv; see datasets/LOGDIR.md) or a "
                           "ROS bag (.bag, .mcap, ROS 2 folder)")
    log = read_logdir(path)
    if log.wheel_t is None or log.wheel_t.size == 0:
        raise CommandError(f"{path}: wheels.csv is missing or empty; the fused odometry needs "
                           "the wheel encoder frames")
    track, ekf, rows = fuse_logdir(log, tilt=not args.level)
    gyro_rows = track.kind[rows] == 0
    t_out = np.where(gyro_rows, track.t[rows], track.t_filter[rows])
    states = track.states[rows]
    write_fused_csv(args.output, t_out, states)

    chassis = log.robot.chassis
    t0, t1 = log.time_span
    n_imu = 0 if log.imu_t is None else log.imu_t.size
    print(f"{path}: {t1 - t0:.1f} s, {n_imu} IMU samples, {log.wheel_t.size} wheel frames "
          f"-> {args.output} ({len(t_out)} rows)")
    x, y, yaw = states[-1, 0], states[-1, 1], math.degrees(math.remainder(states[-1, 2],
                                                                          2 * math.pi))
    print(f"final pose: x {x:.3f} m, y {y:.3f} m, yaw {yaw:.2f} deg; path "
          f"{_distance(t_out, states):.2f} m")
    s = ekf.stats
    print(f"gyro bias {math.degrees(ekf.gyro_bias):+.4f} deg/s; ZUPTs {s['zupts']}, "
          f"slip frames {s['slips']}, late inputs fused {s['late_applied']}, dropped "
          f"{s['late_dropped']}, invalid {s['invalid']}")
    if n_imu and (log.wheel_t[-1] > log.imu_t[-1] + chassis.encode_sampling_time
                  or log.wheel_t[0] < log.imu_t[0] - chassis.encode_sampling_time):
        print(f"warning: wheel frames span {log.wheel_t[0]:.3f}-{log.wheel_t[-1]:.3f} s, the "
              f"IMU {log.imu_t[0]:.3f}-{log.imu_t[-1]:.3f} s; rows are written at IMU samples "
              "only, so the output covers the IMU's span")
    if n_imu:
        k, c = ekf.x[6], ekf.x[7]
        print(f"wheel yaw-rate calibration seen by the gyro: k {k:+.4f} "
              f"(wheel_distance ~ {chassis.wheel_distance * (1 + k):.4f} m), "
              f"c {c:+.5f} rad/m; see `fusion calibrate odometry` for corrected parameters")
    else:
        print("no imu.csv: wheel odometry only (no gyro to fuse)")
    if log.truth_t is not None and log.truth_t.size:
        truth = _truth_at(log.truth_t, log.truth, t_out)
        dist = path_length(log.truth)
        inside = (t_out >= log.truth_t[0]) & (t_out <= log.truth_t[-1])
        fused_pct = final_position_error_percent(states[inside, :2], truth[inside], dist)
        fused_yaw = math.degrees(yaw_rmse(states[inside, 2], truth[inside, 2]))
        wheel = WheelOdometry(chassis).update_batch(log.ticks[:, 0], log.ticks[:, 1])
        wtruth = _truth_at(log.truth_t, log.truth, log.wheel_t)
        w_in = (log.wheel_t >= log.truth_t[0]) & (log.wheel_t <= log.truth_t[-1])
        wheel_pct = final_position_error_percent(wheel[w_in, :2], wtruth[w_in], dist)
        wheel_yaw = math.degrees(yaw_rmse(wheel[w_in, 2], wtruth[w_in, 2]))
        print(f"truth: {dist:.2f} m travelled")
        print(f"  fused:      final position error {fused_pct:.3f} % of distance, "
              f"yaw RMSE {fused_yaw:.3f} deg")
        print(f"  wheel only: final position error {wheel_pct:.3f} % of distance, "
              f"yaw RMSE {wheel_yaw:.3f} deg")
    return 0


def _distance(t: NDArray[np.float64], states: NDArray[np.float64]) -> float:
    """Distance travelled, m: the integral of the fused |v| (the polyline through 100 Hz
    position estimates would add their noise)."""
    v = np.abs(states[:, 3])
    return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)))


def _is_bag(path: Path) -> bool:
    if path.is_file():
        return path.suffix.lower() in (".bag", ".mcap")
    return (path / "metadata.yaml").is_file()


def run_bag(args: argparse.Namespace) -> int:
    """``fusion replay BAG --imu-topic T --odom-topic T``."""
    from fusion import quaternion as quat
    from fusion.ekf import fuse, vertical_rate
    from fusion.kinematics import DiffDriveParams
    from fusion.logdir import RobotConfig, read_robot_toml
    from fusion.logs import read_bag

    path: Path = args.input
    if not (args.imu_topic and args.odom_topic):
        raise CommandError(f"{path}: a bag needs --imu-topic (sensor_msgs/Imu) and "
                           "--odom-topic (nav_msgs/Odometry)")
    if args.robot is not None:
        robot = read_robot_toml(args.robot)
    else:
        # wheel_distance only enters the tiny radius-mismatch term of the speed; the period
        # only the motion-onset logic: neutral values
        robot = RobotConfig(DiffDriveParams(wheel_distance=0.5, speed_ratio=1e-4,
                                            encode_sampling_time=0.02))
    bag = read_bag(path, imu_topic=args.imu_topic, odom_topic=args.odom_topic)
    imu, odom = bag.imu, bag.odometry
    q_mount = quat.from_euler(*args.imu_mount_rpy)
    gyro = quat.rotate(q_mount, imu.gyro)
    accel = quat.rotate(q_mount, imu.accel)
    if args.level or len(imu) < 2:
        gyro_z = gyro[:, 2].copy()
    else:
        from fusion.mahony import Mahony

        q = Mahony(axes=6).update_batch(gyro, accel, timestamps=imu.t)
        gyro_z = vertical_rate(gyro, q)
    track, ekf = fuse(robot.chassis, imu.t, gyro_z, noise=robot.ekf, twist_t=odom.t,
                      twist_v=odom.v, twist_w=odom.w)
    rows = track.output_rows()
    t_out = track.t[rows]
    states = track.states[rows]
    write_fused_csv(args.output, t_out, states)
    print(f"{path}: {len(imu)} IMU messages ({imu.frame_id or 'no frame_id'}), {len(odom)} "
          f"odometry messages ({odom.frame_id} -> {odom.child_frame_id}) -> {args.output} "
          f"({len(t_out)} rows)")
    if imu.out_of_order or odom.out_of_order:
        print(f"warning: messages out of order in the bag (sorted): IMU {imu.out_of_order}, "
              f"odometry {odom.out_of_order}")
    yaw = math.degrees(math.remainder(states[-1, 2], 2 * math.pi))
    print(f"final pose: x {states[-1, 0]:.3f} m, y {states[-1, 1]:.3f} m, yaw {yaw:.2f} deg; "
          f"path {_distance(t_out, states):.2f} m")
    s = ekf.stats
    print(f"gyro bias {math.degrees(ekf.gyro_bias):+.4f} deg/s; ZUPTs {s['zupts']}, slip "
          f"(twist/gyro disagreement) {s['slips']}, invalid {s['invalid']}")
    # the bag's own wheel odometry pose, moved to start at the origin like the fused track
    x0, y0, th0 = odom.x[0], odom.y[0], odom.yaw[0]
    dx, dy = odom.x[-1] - x0, odom.y[-1] - y0
    c, sn = math.cos(th0), math.sin(th0)
    oyaw = math.degrees(math.remainder(odom.yaw[-1] - th0, 2 * math.pi))
    print(f"bag odometry ({args.odom_topic}) final pose from its start: x {c * dx + sn * dy:.3f}"
          f" m, y {-sn * dx + c * dy:.3f} m, yaw {oyaw:.2f} deg")
    return 0


def _truth_at(truth_t, truth, t) -> NDArray[np.float64]:
    yaw = np.unwrap(truth[:, 2])
    return np.column_stack([np.interp(t, truth_t, truth[:, 0]),
                            np.interp(t, truth_t, truth[:, 1]),
                            np.interp(t, truth_t, yaw)])
