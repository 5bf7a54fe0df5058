"""``fusion demo``: the whole live pipeline on a simulated robot, no hardware, no arguments.

What runs (all of it the real code path of ``fusion run`` on a robot):

- the simulated miiboo STM32 firmware (:class:`drivers.sim.stm32.Stm32Sim`: encoders, the
  seed's incremental PID, DC motors) on a pseudo-terminal, stepped on a clock that runs
  ``--speed`` times faster than the wall clock;
- the real :class:`drivers.serial_link.ChassisLink` reading DATA-uart2 frames from that pty and
  sending the wheel targets of a scripted one-minute mission (straights, spins, arcs, stops);
- a simulated MPU6050 on a register-level I2C bus (:class:`drivers.sim.mpu6050.SimulatedMPU6050`)
  driven by the simulated chassis' true motion, read by the real
  :class:`drivers.mpu6050.MPU6050` driver through its FIFO;
- :class:`fusion.pipeline.core.FusionPipeline` (Keel + EKF) publishing to an MCAP file.

The robot is honest about its flaws: ``robot.toml`` says the wheels are 3 % further apart than
they are, the wheel radii differ by 0.5 %, two one-second slip patches make a wheel spin
30 % faster than the ground moves, the IMU sits 2 deg tilted (the mount is configured), and
its gyro has a 0.5 deg/s bias on z that also walks. The report compares the fused odometry
and the wheel-only odometry (seed 000's dead reckoning with the configured parameters)
against the simulator's true pose.

Outputs in ``--out`` (default ``./fusion-demo/``): ``demo.mcap`` (nav_msgs/Odometry, tf,
sensor_msgs/Imu, wheel speeds; open it in Foxglove) and ``demo.png`` (trajectories and yaw
error). Each file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.sim.robot import (
    MISSION,
    ScaledClock,
    SimRobot,
    SimRobotParams,
    mission_command,
    mission_duration,
    send_twist,
)
from fusion.cli import CommandError

__all__ = ["DemoReport", "freeze_heap", "register", "run_demo", "warm_up"]


def nominal_config(sim: SimRobotParams):
    """What the robot's owner wrote in robot.toml: the separation 3 % too large, one
    speed_ratio for both wheels, the measured IMU mount. Returns a RunConfig."""
    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.io.run_config import DEMO_ROBOT, RunConfig
    from fusion.planar.robot import RobotConfig

    chassis = DiffDriveParams(
        wheel_distance=round(sim.wheel_distance * 1.03, 6), speed_ratio=sim.speed_ratio,
        encode_sampling_time=0.04, cmd_vel_linear_max=DEMO_ROBOT.cmd_vel_linear_max,
        cmd_vel_angular_max=DEMO_ROBOT.cmd_vel_angular_max,
        wheel_speed_max=DEMO_ROBOT.wheel_speed_max)
    return RunConfig(robot=RobotConfig(chassis=chassis, imu_mount_rpy=sim.imu_mount_rpy),
                     imu="sim", chassis="sim", publish=())


@dataclass
class DemoReport:
    """Figures of one demo run (SI units; latencies in s of wall-clock time)."""

    distance: float = 0.0
    duration: float = 0.0
    wall_time: float = 0.0
    speed: float = 1.0
    fused_final_error: float = math.nan
    wheel_final_error: float = math.nan
    fused_yaw_rmse: float = math.nan
    wheel_yaw_rmse: float = math.nan
    frames: int = 0
    samples: int = 0
    records: int = 0
    latency_p50: float = math.nan
    latency_p99: float = math.nan
    slips: int = 0
    zupts: int = 0
    gyro_bias_true: float = math.nan
    gyro_bias_est: float = math.nan
    imu_lost: int = 0
    imu_errors: int = 0
    outputs: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    track: dict[str, np.ndarray] = field(default_factory=dict)

    def lines(self) -> list[str]:
        pct = 100.0 / self.distance if self.distance > 0 else math.nan
        return [
            f"mission: {self.distance:.1f} m in {self.duration:.1f} s of robot time "
            f"({self.wall_time:.1f} s wall)",
            "                        fused (EKF)     wheel-only",
            f"final position error  {self.fused_final_error:7.3f} m {'':3}"
            f"{self.wheel_final_error:7.3f} m",
            f"  (% of distance)     {self.fused_final_error * pct:7.2f} % {'':3}"
            f"{self.wheel_final_error * pct:7.2f} %",
            f"yaw RMSE              {math.degrees(self.fused_yaw_rmse):7.2f} deg "
            f"{math.degrees(self.wheel_yaw_rmse):7.2f} deg",
            f"handled: {self.frames} wheel frames, {self.samples} IMU samples, "
            f"{self.records} fused records ({self.slips} slip frames, their yaw rate not fused, "
            f"{self.zupts} zero-velocity updates; {self.imu_lost} IMU samples lost, "
            f"{self.imu_errors} failed I2C reads)",
            f"gyro z bias: true {math.degrees(self.gyro_bias_true):.3f} deg/s, "
            f"estimated {math.degrees(self.gyro_bias_est):.3f} deg/s",
            f"latency frame arrival -> fused record: p50 {self.latency_p50 * 1e3:.1f} ms, "
            f"p99 {self.latency_p99 * 1e3:.1f} ms of wall time at {self.speed:g}x "
            f"(x{self.speed:g} = {self.latency_p50 * self.speed * 1e3:.0f} / "
            f"{self.latency_p99 * self.speed * 1e3:.0f} ms of robot time: a frame waits "
            "for the IMU samples up to the middle of its period, read every 20 ms)",
        ]


def run_demo(out: Path | None, *, speed: float = 6.0, mission=MISSION,
             params: SimRobotParams | None = None, plot: bool = True,
             log=print) -> DemoReport:
    """Run the demo; returns its report (``out`` None: no files)."""
    from drivers.mpu6050 import MPU6050
    from drivers.serial_link import ChassisLink
    from fusion.pipeline.core import FusionPipeline
    from fusion.pipeline.live import LiveRunner
    from fusion.planar.odometry import WheelOdometry
    from fusion.types.samples import WheelTicks

    params = params or SimRobotParams()
    cfg = nominal_config(params)
    chassis = cfg.robot.chassis
    sinks = []
    report = DemoReport()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        try:
            import mcap  # noqa: F401
            import rosbags  # noqa: F401

            from fusion.sinks.bag import McapSink

            sinks.append(McapSink(out / "demo.mcap"))
            report.outputs.append(str(out / "demo.mcap"))
        except ImportError:
            report.notes.append("MCAP skipped: it needs rosbags and mcap "
                                "(python3 -m pip install 'diffbot-fusion[demo]')")

    log("compiling the filters (numba; only the first run takes long) ...")
    t_compile = time.perf_counter()
    warm_up(cfg)
    freeze_heap()
    log(f"  ready in {time.perf_counter() - t_compile:.1f} s")

    clock = ScaledClock(speed)
    robot = SimRobot(clock, params)
    wheel_odo = WheelOdometry(chassis)
    wheel_track: list[tuple[float, float, float, float]] = []
    fused_track: list[tuple[float, float, float, float]] = []

    def on_record(rec) -> None:
        fused_track.append((rec.t, rec.x, rec.y, rec.yaw))

    fifo = 0.02
    pipe = FusionPipeline(cfg.robot, sinks, reorder_window=0.5 * chassis.encode_sampling_time
                          + fifo + 0.02, clock=clock, on_record=on_record)
    end = mission_duration(mission)
    link = None
    imu = None
    runner = None
    wall0 = time.perf_counter()
    complete = False
    switch = sys.getswitchinterval()
    sys.setswitchinterval(0.001)  # threads (firmware, link, FIFO) get the GIL within 1 ms
    log(f"running a {end:.1f} s mission at {speed:g}x real time "
        f"(simulated STM32 on {robot.port}, simulated MPU6050 on I2C) ...")
    try:
        link = ChassisLink(robot.port, period=chassis.encode_sampling_time, clock=clock,
                           command_timeout=0.5, silence_periods=5.0)
        link.start(wait=5.0)
        imu = MPU6050(robot.bus, clock=clock, sample_rate_hz=100.0, gyro_range_dps=500,
                      accel_range_g=4, dlpf=3)
        pipe.open()
        robot.start()
        runner = LiveRunner(pipe, link=link, imu=imu, fifo_interval=fifo).start()
        t_start = clock.monotonic()  # the mission starts now (the robot stood still so far)
        robot.t_origin = t_start
        state = {"cmd": None, "sent": -1.0}

        def on_event(ev) -> None:
            if type(ev) is WheelTicks:
                st = wheel_odo.update(ev.left, ev.right, ev.t)
                wheel_track.append((ev.t, st.x, st.y, st.theta))

        def mission_over() -> bool:
            now = clock.monotonic()
            cmd = mission_command(now - t_start, mission)
            if cmd is None:
                return True
            if cmd != state["cmd"] or now - state["sent"] > 0.2:
                send_twist(link, chassis, *cmd)
                state["cmd"], state["sent"] = cmd, now
            return False

        runner.run(until=mission_over, poll=0.01, on_event=on_event)
        link.stop()
        t_stop = clock.monotonic()  # take the last frames and samples in
        runner.run(until=lambda: clock.monotonic() > t_stop + 0.3, poll=0.01,
                   on_event=on_event)
        complete = True
    finally:
        if runner is not None:
            runner.stop()
        if link is not None:
            link.close()
        robot.close()
        if imu is not None:
            imu.close()
        sys.setswitchinterval(switch)
        import gc

        gc.unfreeze()
        if complete:
            pipe.close()
        else:  # an error or Ctrl-C: no partial demo.mcap (an older complete one stays)
            pipe.abort()
    report.wall_time = time.perf_counter() - wall0
    report.speed = speed
    if robot.late_steps > 0.01 * max(robot.steps, 1):
        report.notes.append(
            f"note: the simulated firmware ran late in {robot.late_steps} of {robot.steps} "
            f"periods (up to {robot.max_lag * 1e3:.0f} ms of robot time, at "
            f"{robot.max_lag_at:.1f} s of the mission): this machine was "
            "busy, frames got late stamps and the figures above suffer; try --speed 3")
    if runner is not None:
        report.imu_lost, report.imu_errors = runner.imu_lost, runner.imu_errors
    stats = pipe.finish_stats()
    report.frames = stats.wheel_frames
    report.samples = stats.imu_samples
    report.records = stats.records
    report.slips, report.zupts = stats.slips, stats.zupts
    p50, p99 = pipe.latency_percentiles(50, 99)
    report.latency_p50, report.latency_p99 = p50 / speed, p99 / speed
    report.gyro_bias_true = math.radians(float(robot.bus.gyro_bias_dps[2]))
    report.gyro_bias_est = pipe.ekf.gyro_bias
    _evaluate(report, robot, np.array(fused_track), np.array(wheel_track))
    report.duration = end  # the mission's length, as announced (not the standing still
    # before it started and while the last frames came in)
    if out is not None and plot:
        png = out / "demo.png"
        msg = _plot(report, png)
        if msg:
            report.notes.append(msg)
        else:
            report.outputs.append(str(png))
    return report


def freeze_heap() -> None:
    """Move everything allocated so far (modules, compiled code) out of the garbage
    collector's view (``gc.freeze``): a full collection then scans only what the run itself
    allocates, instead of pausing every thread for tens of ms while the source threads'
    stamps wait."""
    import gc

    gc.collect()
    gc.freeze()


def warm_up(cfg) -> None:
    """Compile the numba cores before the clock starts (a cold cache takes ~15 s)."""
    from fusion.pipeline.core import FusionPipeline
    from fusion.types.constants import STANDARD_GRAVITY
    from fusion.types.samples import ImuSample, WheelTicks

    pipe = FusionPipeline(cfg.robot)
    with pipe:
        g, a = np.zeros(3), np.array([0.0, 0.0, STANDARD_GRAVITY])
        for k in range(1, 9):
            pipe.push(ImuSample(0.01 * k, g, a))
        pipe.push(WheelTicks(0.04, 0, 0))
        pipe.push(WheelTicks(0.08, 10, 12))


def _evaluate(report: DemoReport, robot: SimRobot, fused: np.ndarray,
              wheel: np.ndarray) -> None:
    from fusion.geometry.angles import wrap_angle

    tr = np.array(robot.truth)
    report.duration = float(tr[-1, 0])
    report.distance = float(np.sum(np.hypot(np.diff(tr[:, 1]), np.diff(tr[:, 2]))))
    frame_t = np.array(robot.frame_times)
    n = wheel.shape[0] if wheel.size else 0
    if n and 0 <= frame_t.size - n <= 3:  # (the last frames may still have been in flight)
        frame_t = frame_t[:n]
        # every frame written arrived: judge the wheel-only odometry at each frame's true
        # time (the end of its period), which spares it any transport delay; the fused
        # records are judged at their own stamps (host clock), delays included
        wheel_eval_t = frame_t
    else:
        wheel_eval_t = wheel[:, 0] if wheel.size else wheel
        report.notes.append(f"{frame_t.size} frames written, {n} received: "
                            "wheel-only judged at arrival times")
    for name, arr in (("fused", fused), ("wheel", wheel)):
        if arr.size == 0:
            continue
        truth = robot.truth_at(arr[:, 0] if name == "fused" else wheel_eval_t)
        err_xy = np.hypot(arr[:, 1] - truth[:, 0], arr[:, 2] - truth[:, 1])
        err_yaw = wrap_angle(arr[:, 3] - truth[:, 2])
        setattr(report, f"{name}_final_error", float(err_xy[-1]))
        setattr(report, f"{name}_yaw_rmse", float(np.sqrt(np.mean(err_yaw ** 2))))
        report.track[name] = arr
        report.track[f"{name}_yaw_error"] = err_yaw
        report.track[f"{name}_t"] = arr[:, 0] if name == "fused" else wheel_eval_t
    report.track["truth"] = tr


def _plot(report: DemoReport, path: Path) -> str | None:
    """Write the PNG (atomically); returns a note when it cannot."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return ("plot skipped: matplotlib is not installed "
                "(python3 -m pip install 'diffbot-fusion[demo]')")
    tr = report.track.get("truth")
    fused, wheel = report.track.get("fused"), report.track.get("wheel")
    if tr is None or fused is None or wheel is None:
        return "plot skipped: no data"
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.5))
    ax1.plot(tr[:, 1], tr[:, 2], "k-", lw=2.5, label="truth (simulator)")
    ax1.plot(wheel[:, 1], wheel[:, 2], "-", color="tab:orange", lw=1.2,
             label=f"wheel-only (final error {report.wheel_final_error:.2f} m)")
    ax1.plot(fused[:, 1], fused[:, 2], "--", color="tab:blue", lw=1.5,
             label=f"fused EKF (final error {report.fused_final_error:.3f} m)")
    ax1.plot([0], [0], "ko")
    ax1.set_xlabel("x in odom (m)")
    ax1.set_ylabel("y in odom (m)")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="best", fontsize=9)
    ax1.set_title(f"Trajectories, {report.distance:.1f} m")
    ax2.plot(report.track["wheel_t"], np.degrees(report.track["wheel_yaw_error"]),
             color="tab:orange",
             label=f"wheel-only (RMSE {math.degrees(report.wheel_yaw_rmse):.2f} deg)")
    ax2.plot(fused[:, 0], np.degrees(report.track["fused_yaw_error"]), color="tab:blue",
             label=f"fused EKF (RMSE {math.degrees(report.fused_yaw_rmse):.2f} deg)")
    ax2.axhline(0.0, color="k", lw=0.8)
    ax2.set_xlabel("robot time (s)")
    ax2.set_ylabel("yaw error (deg)")
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="best", fontsize=9)
    ax2.set_title("Yaw error against the simulator's truth")
    fig.suptitle("fusion demo: simulated miiboo chassis + MPU6050, live pipeline")
    fig.tight_layout()
    from fusion.io.atomic import atomic_write

    try:
        with atomic_write(path, "wb") as fh:
            fig.savefig(fh, dpi=110, format="png")
    finally:
        plt.close(fig)
    return None


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="the live pipeline on a simulated robot (no hardware): report, MCAP and plot",
        description=(
            "Runs a one-minute scripted mission on a simulated miiboo STM32 chassis (on a "
            "pseudo-terminal, through the real serial link) and a simulated MPU6050 (through "
            "the real driver), sped up; fuses it live with the Keel attitude estimator and "
            "the EKF; "
            "prints distance, final position error and yaw RMSE of the fused and the "
            "wheel-only odometry against the simulator's truth, frames and samples handled "
            "and the latency; writes demo.mcap and demo.png."
        ),
    )
    p.add_argument("--out", type=Path, default=Path("fusion-demo"),
                   help="output folder (default ./fusion-demo/)")
    p.add_argument("--speed", type=float, default=6.0,
                   help="robot time per wall-clock second (default 6)")
    p.add_argument("--no-plot", action="store_true", help="do not write demo.png")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not 0.5 <= args.speed <= 20:
        raise CommandError(f"--speed must be within 0.5..20, got {args.speed}")
    report = run_demo(args.out, speed=args.speed, plot=not args.no_plot,
                      log=lambda s: print(s, file=sys.stderr, flush=True))
    for line in report.lines():
        print(line)
    for path in report.outputs:
        print(f"wrote {path}")
    for note in report.notes:
        print(note)
    return 0
