"""``fusion run``: the live fused-odometry publisher.

Examples::

    fusion run --config robot.toml                          # everything from the file
    fusion run --imu i2c:1 --chassis /dev/ttyUSB0 --publish ros1 --config robot.toml
    fusion run --imu sim --chassis sim --publish foxglove,mcap:run.mcap   # no hardware

Sources: ``--imu i2c:N`` (an MPU6050 on /dev/i2c-N, read through its FIFO), ``sim`` (the
simulated chip, moving with the simulated chassis) or ``none``; ``--chassis`` a serial port
(device path, ``socket://host:port``, anything pyserial's ``serial_for_url`` opens), ``sim``
(the simulated STM32 firmware on a pseudo-terminal) or ``none``. Sinks (``--publish``, comma
separated): ``jsonl[:PATH]``, ``csv:PATH``, ``mcap:PATH``, ``rosbag2:PATH``,
``foxglove[:HOST:PORT]``, ``ros1`` (seed 000's node: /odom, /tf, /imu/data, wheel speeds;
/cmd_vel drives the wheels), ``ros2`` (the same topics for ROS 2 over DDS, domain
``ROS_DOMAIN_ID``; /cmd_vel drives the wheels). The ``jsonl``, ``csv`` and ``mcap`` files are
recorded live: they grow in place and are synced to the disk every second, so a crash or a power
cut loses at most the last second (an MCAP file then lacks its summary section; ``fusion replay``
and :func:`fusion.io.bags.read_bag` read it up to its last complete chunk). A ``rosbag2`` folder
appears only when the run stops cleanly.
A Foxglove client's geometry_msgs/Twist on /cmd_vel (the Teleop panel) drives the wheels too.

Every option can come from the ``--config`` file (:mod:`fusion.io.run_config`, see
:data:`fusion.io.run_config.RUN_OPTIONS`); an option on the command line wins. With ``sim`` for the
chassis the robot drives ``fusion demo``'s mission in a loop (or follows /cmd_vel with
``ros1`` or ``ros2``; with ``foxglove`` until the first /cmd_vel from a client). Runs until Ctrl-C
(or SIGTERM, or ``--duration``): the sources stop, the sinks are closed, and the files are
complete. Status lines go to standard error.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from fusion.cli import CommandError

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "run",
        help="live fused odometry from the IMU and the chassis, published to ROS 1, "
             "ROS 2, Foxglove, MCAP or JSON lines",
        description="The live publisher: MPU6050 (I2C) + chassis (serial) -> Keel + EKF -> "
                    "sinks. Every option can come from --config (TOML, see fusion.io.run_config); "
                    "the command line wins. Ctrl-C stops cleanly (files complete).",
    )
    p.add_argument("--config", type=Path, help="robot configuration file (TOML)")
    p.add_argument("--imu", help="i2c:N (bus number), sim or none (default: sim with "
                                 "--chassis sim, else none)")
    p.add_argument("--address", type=lambda s: int(s, 0), help="MPU6050 address (0x68)")
    p.add_argument("--rate", type=float, metavar="HZ", help="IMU sample rate (default 100)")
    p.add_argument("--calibration", help="IMU calibration JSON (fusion imu-calibrate)")
    p.add_argument("--chassis", metavar="URL",
                   help="chassis DATA-uart2 port (device, socket://, ...), sim or none "
                        "(default sim)")
    p.add_argument("--baudrate", type=int, help="chassis baud rate (115200)")
    p.add_argument("--publish", metavar="SINKS",
                   help="comma-separated sinks: ros1, ros2, foxglove[:HOST:PORT], mcap:PATH, "
                        "rosbag2:PATH, jsonl[:PATH], csv:PATH (default jsonl on stdout); "
                        "jsonl, csv and mcap files are synced every second (a crash loses "
                        "at most the last second)")
    p.add_argument("--publish-rate", type=float, metavar="HZ",
                   help="records per second (0: one per wheel frame, the default)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--speed", type=float,
                   help="with --chassis sim: robot time per wall second (default 1)")
    p.add_argument("--status", type=float, metavar="S",
                   help="seconds between status lines on stderr and {\"status\": ...} "
                        "records in JSON lines outputs: events in, fused, dropped by reason, "
                        "unaccounted, source faults (0: none; default 10)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 3 when the inputs disagree beyond what the model "
                        "explains (most frames slip, an implausible gyro bias, a wheel "
                        "yaw-rate scale beyond 15 %%, odometry and gyro headings diverging); "
                        "the final status says so either way")
    p.set_defaults(func=run)


def _config(args: argparse.Namespace):
    from fusion.io.run_config import RunConfig, _sinks, load_config

    cfg = load_config(args.config) if args.config else RunConfig()
    publish = None
    if args.publish is not None:
        try:
            publish = _sinks(args.publish)
        except ValueError as exc:
            raise CommandError(f"--publish: {exc}") from None
    rate = None
    if args.publish_rate is not None:
        if not args.publish_rate >= 0:
            raise CommandError(f"--publish-rate must be >= 0 Hz, got {args.publish_rate}")
        rate = args.publish_rate
    cfg = cfg.with_overrides(imu=args.imu, imu_address=args.address, imu_rate_hz=args.rate,
                             imu_calibration=args.calibration, chassis=args.chassis,
                             baudrate=args.baudrate, publish=publish, duration=args.duration,
                             speed=args.speed, status=args.status,
                             strict=True if args.strict else None)
    if rate is not None:
        from dataclasses import replace

        cfg = replace(cfg, publish_rate_hz=None if rate == 0 else rate)
    from fusion.io.run_config import _imu_source

    try:
        _imu_source(cfg.imu)
    except ValueError as exc:
        raise CommandError(f"--imu {exc}") from None
    if cfg.imu == "sim" and cfg.chassis != "sim" and args.imu is None:
        # the default IMU is the simulated one, which moves with the simulated chassis only
        from dataclasses import replace

        cfg = replace(cfg, imu="none")
        if cfg.chassis != "none":
            print(f"fusion run: no --imu given: fusing the wheel odometry of {cfg.chassis} "
                  "alone (give --imu i2c:N for an MPU6050 on /dev/i2c-N)", file=sys.stderr)
    if cfg.imu == "none" and cfg.chassis == "none":
        raise CommandError("nothing to fuse: --imu and --chassis are both none (the "
                           "simulated IMU needs --chassis sim)")
    if cfg.chassis not in ("sim", "none") and args.config is None:
        raise CommandError(f"--chassis {cfg.chassis} is a real robot: give --config "
                           "robot.toml with its [chassis] table (wheel_distance, speed_ratio, "
                           "encode_sampling_time), or the odometry would use made-up "
                           "geometry")
    if cfg.chassis not in ("sim", "none") and not cfg.chassis_given:
        # an independent probe's config with only [link] ran a real port on the simulated
        # robot's geometry, which the same command without --config refuses
        raise CommandError(f"{args.config}: has no [chassis] table (wheel_distance, "
                           f"speed_ratio, encode_sampling_time), and --chassis {cfg.chassis} "
                           "is a real robot: without it the odometry would use made-up "
                           "geometry")
    if cfg.imu == "sim" and cfg.chassis != "sim":
        raise CommandError("--imu sim needs --chassis sim (the simulated IMU moves with the "
                           "simulated chassis)")
    if cfg.imu.startswith("i2c:") and cfg.chassis == "sim":
        # it would sit still while the simulated robot drives, its stamps on the host clock
        # and the simulated wheels' on robot time: every sample ahead of that clock
        raise CommandError(f"--imu {cfg.imu} is a real sensor: it does not move with the "
                           "simulated chassis; give a real --chassis PORT, --imu sim, or "
                           "--chassis none to fuse the real IMU alone")
    return cfg


def _sinks_for(cfg, cmd_vel) -> list:
    from fusion.sinks.registry import open_sink
    from fusion.sinks.ros_messages import Topics

    topics = Topics(**cfg.topics)
    sinks = []
    for spec in cfg.publish:
        kind = spec.strip().lower().partition(":")[0]
        if kind == "ros1":
            from fusion.sinks.ros1 import Ros1Sink

            sinks.append(Ros1Sink(topics=topics, cmd_vel_topic=cfg.cmd_vel_topic,
                                  on_cmd_vel=cmd_vel,
                                  frame_id=cfg.robot.odom_frame,
                                  child_frame_id=cfg.robot.base_frame))
        else:
            sink = open_sink(spec, topics=topics, live=True)  # files survive a crash
            if kind in ("foxglove", "ros2"):  # their /cmd_vel drives the robot like ROS 1's
                sink.cmd_vel_topic = cfg.cmd_vel_topic
                sink.on_cmd_vel = cmd_vel
            sinks.append(sink)
    return sinks


#: s a live stamp may be ahead of the host clock before it counts as invalid (a clock jump).
MAX_STAMP_LEAD = 1.0


class _Stop(Exception):
    """A second SIGTERM while the first one's clean stop is under way: stop at once."""


def run(args: argparse.Namespace) -> int:
    from drivers.chassis import WheelFrameParser
    from drivers.serial_link import ChassisLink
    from drivers.sim.robot import LoopingMission, ScaledClock, SimRobot, SimRobotParams, send_twist
    from fusion.cli.demo import freeze_heap, warm_up
    from fusion.pipeline.core import FusionPipeline
    from fusion.pipeline.live import LiveRunner, SourceFailedError

    cfg = _config(args)
    _refuse_options_without_effect(args, cfg)
    if args.duration is not None and not args.duration > 0:
        raise CommandError(f"--duration must be > 0 s, got {args.duration}")
    if not 0.1 <= cfg.speed <= 20:
        raise CommandError(f"--speed must be within 0.1..20, got {cfg.speed}")
    if cfg.speed != 1.0 and cfg.chassis != "sim":
        raise CommandError("--speed only applies to --chassis sim")
    if cfg.status < 0:
        raise CommandError(f"--status must be >= 0 s, got {cfg.status}")
    duration, status = cfg.duration, cfg.status
    chassis = cfg.robot.chassis

    def err(msg: str) -> None:
        print(f"fusion run: {msg}", file=sys.stderr, flush=True)

    warm_up(cfg)  # load (or compile) the numba cores before any source starts
    sim = cfg.chassis == "sim"
    clock = ScaledClock(cfg.speed) if sim else time.monotonic
    link_holder: dict[str, Any] = {}

    def on_cmd_vel(v: float, w: float) -> None:  # a rospy / DDS / Foxglove server thread
        link = link_holder.get("link")
        if link is not None:
            link_holder["external"] = True  # a client drives now: the mission stops
            send_twist(link, chassis, v, w)  # seed 000's command path

    sinks = _sinks_for(cfg, on_cmd_vel)
    window = 0.5 * chassis.encode_sampling_time + cfg.fifo_interval + 0.02
    pipe = FusionPipeline(cfg.robot, sinks, publish_rate_hz=cfg.publish_rate_hz,
                          reorder_window=cfg.reorder_window or window, imu_rate_hz=cfg.imu_rate_hz,
                          tilt=cfg.tilt, clock=clock, max_stamp_lead=MAX_STAMP_LEAD,
                          on_sink_error=lambda sink, exc, text: _sink_failed(sink, exc, text,
                                                                             err),
                          sources=[name for name, on in (("imu", cfg.imu != "none"),
                                                         ("wheels", cfg.chassis != "none"))
                                   if on])
    robot = link = imu = runner = None
    complete = False
    failure: BaseException | None = None
    warnings: list = []
    # Ctrl-C and SIGTERM ask for a clean stop: the consumer finishes the event in hand and
    # stops between events (an exception raised inside a push could leave an event counted
    # in but neither fused nor dropped: "unaccounted" in the final ledger). A second signal
    # stops at once.
    stop_asked: list[int] = []
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    if threading.current_thread() is threading.main_thread():
        def on_signal(signum, frame):
            if stop_asked:
                raise KeyboardInterrupt if signum == signal.SIGINT else _Stop()
            stop_asked.append(signum)

        for s in previous:
            signal.signal(s, on_signal)
    wall0 = time.monotonic()
    freeze_heap()  # keep full garbage collections short (no long pauses of the sources)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(0.001)  # source threads get the GIL within 1 ms
    try:
        try:
            pipe.open()
        except ImportError as exc:
            raise CommandError(str(exc)) from None
        for sink in sinks:
            if hasattr(sink, "host") and hasattr(sink, "port"):
                err(f"Foxglove server: connect to ws://{sink.host}:{sink.port}")
            elif hasattr(sink, "domain_id"):
                err(f"ROS 2 topics on DDS domain {sink.domain_id} (ROS_DOMAIN_ID)")
        if sim:
            robot = SimRobot(clock, SimRobotParams(), keep_truth=False)
        port = robot.port if sim else cfg.chassis
        if cfg.chassis != "none":
            if math.isfinite(chassis.wheel_speed_max):
                def factory():
                    return WheelFrameParser.for_chassis(
                        chassis.wheel_speed_max, chassis.speed_ratio,
                        chassis.encode_sampling_time)
            else:
                factory = WheelFrameParser
            link = ChassisLink(port, baudrate=cfg.baudrate,
                               period=chassis.encode_sampling_time,
                               command_timeout=cfg.command_timeout,
                               silence_periods=cfg.silence_periods, clock=clock,
                               parser_factory=factory,
                               on_event=lambda ev: err(f"link {ev.kind}: {ev.message}"))
            link.start(wait=5.0)
            link_holder["link"] = link
        if cfg.imu != "none":
            imu = _open_imu(cfg, robot, clock)
        if robot is not None:
            robot.start()
        runner = LiveRunner(pipe, link=link, imu=imu, fifo_interval=cfg.fifo_interval,
                            on_fault=lambda name, text: err(text)).start()
        t0 = clock()
        drive = sim and not any(s.strip().lower() in ("ros1", "ros2") for s in cfg.publish)
        state = {"status": time.monotonic()}
        mission = LoopingMission(link, chassis, clock, t0)

        def tick() -> bool:
            if stop_asked:
                return True
            if drive and not link_holder.get("external"):
                mission()
            if status and time.monotonic() - state["status"] >= status:
                state["status"] = time.monotonic()
                _report_status(pipe, runner, err)
            if not pipe.working_sinks and sinks:  # every output failed: nothing to run for
                err("stopping: every output failed")
                return True
            return duration is not None and time.monotonic() - wall0 >= duration

        err(f"running: imu {cfg.imu}, chassis {port if cfg.chassis != 'none' else 'none'}, "
            f"publishing to {', '.join(cfg.publish) or 'nothing'} (Ctrl-C stops)")
        try:
            runner.run(until=tick, poll=0.02)
            if stop_asked:
                err("stopping")
        except (KeyboardInterrupt, _Stop):
            err("stopping")
        except SourceFailedError as exc:  # the files still get what was fused
            err(f"stopping: {exc}")
            failure = exc
        complete = True
    finally:
        try:
            if runner is not None:
                runner.stop()  # pushes what the sources had queued: never suppressed
        except BaseException:
            complete = False
            raise
        finally:
            try:
                for device in (link, robot, imu):
                    if device is not None:
                        device.close()
            finally:
                try:
                    if complete:  # files complete, the final status record last
                        warnings = _close_with_status(pipe, runner)
                    else:
                        pipe.abort()
                finally:
                    if threading.current_thread() is threading.main_thread():
                        for s, handler in previous.items():
                            signal.signal(s, handler)
                    sys.setswitchinterval(switch)
                    import gc

                    gc.unfreeze()
    err(_status(pipe, runner) + f"; done after {time.monotonic() - wall0:.1f} s")
    for w in warnings:
        err(f"warning: inputs disagree ({w.name}): {w.message}")
    if failure is not None:
        raise failure
    from fusion.jobs.status import STRICT_EXIT_STATUS

    return STRICT_EXIT_STATUS if cfg.strict and warnings else 0


def _close_with_status(pipe, runner) -> list:
    """Fuse what the pipeline holds, write the final status record to the JSON lines sinks
    after the last record (counters and trust warnings, :mod:`fusion.jobs.status`, with the
    runner's ledger and sources' health: :meth:`LiveRunner.status`, ``"final": true``),
    close; the warnings."""
    from fusion.jobs.status import pipeline_warnings, status_record, write_status

    try:
        pipe.flush()
        warnings = pipeline_warnings(pipe)
        record = status_record(pipe, warnings)
        if runner is not None:
            record.update(runner.status())
        record["final"] = True
        write_status(pipe, record)
    except BaseException:
        pipe.abort()
        raise
    pipe.close()
    return warnings


def _refuse_options_without_effect(args: argparse.Namespace, cfg) -> None:
    """An option given for a source that does not use it is an error, not silently ignored."""
    real_imu = cfg.imu.startswith("i2c:")
    for given, applies, what in (
            (args.address, real_imu, "--address applies to --imu i2c:N only (the simulated "
                                     "chip answers at 0x68)"),
            (args.baudrate, cfg.chassis not in ("sim", "none"),
             "--baudrate applies to a real --chassis port only"),
            (args.rate, cfg.imu != "none", "--rate sets the IMU sample rate: not with --imu "
                                           "none"),
            (args.calibration, cfg.imu != "none", "--calibration is an IMU calibration: not "
                                                  "with --imu none")):
        if given is not None and not applies:
            raise CommandError(what)


def _open_imu(cfg, robot, clock):
    from drivers.mpu6050 import MPU6050

    calibration = None
    if cfg.imu_calibration:
        from fusion.io.imu_calibration import load_imu_calibration

        calibration = load_imu_calibration(cfg.imu_calibration)
    kw = dict(gyro_range_dps=cfg.gyro_range_dps, accel_range_g=cfg.accel_range_g,
              dlpf=cfg.dlpf, sample_rate_hz=cfg.imu_rate_hz, calibration=calibration)
    if cfg.imu == "sim":
        return MPU6050(robot.bus, 0x68, clock=clock, **kw)  # the simulated chip's address
    return MPU6050(int(cfg.imu.split(":")[1]), cfg.imu_address, **kw)


def _sink_failed(sink, exc: BaseException, text: str, err) -> None:
    """A sink's write failed: say so with the traceback; the run goes on with the others
    (it stops when none is left). Standard output whose reader went away (``fusion run |
    head``) is no error to report: the run ends quietly (exit status 1)."""
    if isinstance(exc, BrokenPipeError):
        return
    if isinstance(exc, OSError):
        # the machine's, not the code's (a full disk, a lost mount): the error names it, a
        # traceback would only bury it (an independent probe's full disk printed three)
        err(f"sink {sink!r} failed: {exc}; the others go on")
        return
    err(f"sink {sink!r} failed; the others go on:\n{text}")


def _report_status(pipe, runner, err) -> None:
    """A status line on stderr and a status record in the JSON lines sinks (the final one:
    :func:`_close_with_status`)."""
    err(_status(pipe, runner))
    if runner is None:
        return
    from fusion.jobs.status import write_status

    write_status(pipe, {**runner.status(), "final": False})


def _ledger_text(led: dict) -> str:
    """``events in N: fused F, held H, queued Q, dropped r1 n1, ...; unaccounted U``."""
    dropped = ", ".join(f"{k} {v}" for k, v in led["dropped"].items() if v) or "none"
    return (f"events in {led['in']}: fused {led['fused']}, held {led['held']}, queued "
            f"{led['queued']}, dropped: {dropped}; unaccounted {led['unaccounted']}")


def _status(pipe, runner) -> str:
    s = pipe.finish_stats()
    p50, p99 = pipe.latency_percentiles(50, 99)
    parts = [f"{s.wheel_frames} frames, {s.imu_samples} IMU samples, {s.records} records",
             f"{s.frames_missing} wheel frames missing ({s.gap_count} gaps), "
             f"{s.attitude_gaps} IMU gaps, {s.speed_resets} speeds forgotten after a gap",
             f"{s.slips} slips, {s.zupts} ZUPTs"]
    if runner is not None:
        parts.append(_ledger_text(runner.ledger()))
        faults = {n: h for n, h in runner.health.items() if h.faults}
        parts.extend(f"source {n}: {h.faults} faults, {h.restarts} restarts"
                     for n, h in faults.items())
    refused = runner.link_parser_counts() if runner is not None else {}
    if any(refused.values()):
        parts.append(f"chassis link: {refused['checksum_failures']} checksum failures, "
                     f"{refused['implausible']} frames refused as implausible, "
                     f"{refused['bytes_skipped']} bytes skipped on this connection")
    if runner is not None and (runner.imu_errors or runner.imu_lost):
        parts.append(f"{runner.imu_errors} failed IMU reads, {runner.imu_lost} samples lost")
    for sink, exc, missed in pipe.sink_failures:
        parts.append(f"sink {sink!r} failed ({type(exc).__name__}: {exc}); {missed} records "
                     "not written to it")
    if p50 == p50:
        parts.append(f"latency p50 {p50 * 1e3:.1f} ms p99 {p99 * 1e3:.1f} ms")
    from fusion.jobs.status import pipeline_warnings

    disagree = [w.name for w in pipeline_warnings(pipe)]
    if disagree:
        parts.append(f"inputs disagree: {', '.join(disagree)}")
    return "; ".join(parts)
