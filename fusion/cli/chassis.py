"""``fusion chassis``: the miiboo STM32 chassis from the command line: decode, encode,
monitor, pid, step (the usage is in ``_DESCRIPTION``, what ``fusion chassis --help`` prints).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fusion.cli import CommandError

__all__ = ["StepMetrics", "register", "step_metrics"]


# -- step response metrics --
@dataclass(frozen=True)
class StepMetrics:
    """Step response of one wheel.

    Attributes:
        target: commanded ticks per period.
        rise_time: s from 10 % to 90 % of the target (linear interpolation), nan if never.
        overshoot: peak beyond the target, % of the target (0 if none).
        steady_state_error: target minus the mean of the last ``tail`` of the record, ticks.
        steady_state_value: that mean, ticks per period.
    """

    target: float
    rise_time: float
    overshoot: float
    steady_state_error: float
    steady_state_value: float


def _crossing(t: np.ndarray, y: np.ndarray, level: float) -> float:
    above = np.flatnonzero(y >= level)
    if above.size == 0:
        return math.nan
    k = int(above[0])
    if k == 0:
        return float(t[0])
    t0, t1, y0, y1 = t[k - 1], t[k], y[k - 1], y[k]
    return float(t0 + (level - y0) * (t1 - t0) / (y1 - y0))


def step_metrics(t, y, target: float, tail: float = 0.25) -> StepMetrics:
    """Rise time (10-90 %), overshoot (%) and steady-state error of a step response.

    Args:
        t: sample times, s, from the step (t=0 at the command), increasing.
        y: response samples (ticks per period).
        target: commanded value (non-zero); a negative step is mirrored.
        tail: fraction of the record, at its end, averaged as the steady state.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.shape != y.shape or t.size < 4:
        raise ValueError(f"need matching t and y with >= 4 samples, got {t.shape}, {y.shape}")
    if target == 0:
        raise ValueError("a step response needs a non-zero target")
    if not 0 < tail <= 1:
        raise ValueError(f"tail must be in (0, 1], got {tail!r}")
    sgn = 1.0 if target > 0 else -1.0
    ys = sgn * y
    tg = abs(target)
    rise = _crossing(t, ys, 0.9 * tg) - _crossing(t, ys, 0.1 * tg)
    peak = float(ys.max())
    overshoot = max(0.0, (peak - tg) / tg * 100.0)
    n_tail = max(1, round(tail * y.size))
    ss = float(y[-n_tail:].mean())
    return StepMetrics(float(target), rise, overshoot, float(target - ss), ss)


# -- commands --
def _csv_rows(fh: Any, header: list[str], rows: Iterable[Sequence[Any]]) -> None:
    w = csv.writer(fh, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)


def _write_csv(path: str, header: list[str], rows: Iterable[Sequence[Any]]) -> None:
    """``header`` and ``rows`` as a CSV file, written atomically (replaced only when complete)."""
    from fusion.io.atomic import atomic_write

    try:
        with atomic_write(path, newline="") as fh:
            _csv_rows(fh, header, rows)
    except OSError as exc:
        if str(path) in str(exc):  # the error names the file already
            raise
        raise CommandError(f"cannot write {path}: {exc.strerror or exc}") from exc


def _cmd_decode(args) -> int:
    from drivers.chassis import WheelFrameParser
    from fusion.io.atomic import check_target

    if args.output not in (None, "-"):
        check_target(args.output)
    try:
        with open(args.capture, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise CommandError(f"cannot read capture {args.capture}: {exc.strerror}") from exc
    parser = WheelFrameParser(max_ticks=args.max_ticks, strict_sign=not args.loose_sign)
    off, left, right = parser.feed_arrays(data)
    tail = parser.finish()
    rows = [(int(a), int(b), int(c)) for a, b, c in zip(left, right, off)]
    rows += [(f.left, f.right, f.offset) for f in tail]
    out = sys.stdout if args.output in (None, "-") else None
    if out is not None:
        _csv_rows(out, ["left", "right", "offset"], rows)
    else:
        _write_csv(args.output, ["left", "right", "offset"], rows)
    s = parser.stats
    report = sys.stderr if out is not None else sys.stdout
    print(
        f"{args.capture}: {s.bytes_in} bytes, {s.frames} frames, {s.bytes_skipped} bytes "
        f"skipped, {s.checksum_failures} checksum failures, {s.implausible} implausible, "
        f"{s.resyncs} resyncs, {s.deferred} deferred, {s.ambiguous} ambiguous",
        file=report,
    )
    return 0


def _cmd_encode(args) -> int:
    from drivers.chassis import encode_wheel_frame

    print(encode_wheel_frame(args.left, args.right).hex(" "))
    return 0


def _geometry(args):
    from fusion.geometry.kinematics import DiffDriveParams

    return DiffDriveParams(
        wheel_distance=args.wheel_distance, speed_ratio=args.speed_ratio,
        encode_sampling_time=args.period,
    )


def _start_link(args, *, report_events: bool) -> Any:
    """Open the chassis port (up to ``--open-timeout`` s): one clear error if it does not
    open; link events (reconnects, silences) go to stderr once it is open."""
    import threading

    from drivers.serial_link import ChassisLink

    opened = threading.Event()

    def on_event(e) -> None:
        if report_events and opened.is_set():  # the retries while opening are not news
            print(f"# {e.kind}: {e.message}", file=sys.stderr, flush=True)

    link = ChassisLink(args.port, period=args.period, command_timeout=None, on_event=on_event)
    try:
        link.start(wait=args.open_timeout)
    except OSError as exc:
        link.close(stop=False)
        last = next((e for e in reversed(link.events) if e.kind == "open_failed"), None)
        why = f" ({last.message.split(': ', 1)[-1]})" if last else ""
        raise CommandError(f"chassis port {args.port} did not open within "
                           f"{args.open_timeout:g} s{why}") from exc
    opened.set()
    return link


def _cmd_monitor(args) -> int:
    from fusion.planar.odometry import WheelOdometry

    geo = _geometry(args)
    odo = WheelOdometry(geo, method=args.method)
    out = sys.stdout
    link = _start_link(args, report_events=True)
    print("t,left,right,v_left,v_right,x,y,yaw", file=out, flush=True)
    t_end = None if args.duration is None else time.monotonic() + args.duration
    count = 0
    last_print = -math.inf
    try:
        while t_end is None or time.monotonic() < t_end:
            f = link.get(timeout=0.1)
            if f is None:
                continue
            st = odo.update(f.left, f.right, t=f.t)
            count += 1
            if f.t - last_print >= args.interval:
                last_print = f.t
                print(f"{f.t:.3f},{f.left},{f.right},{st.vl:.4f},{st.vr:.4f},"
                      f"{st.x:.4f},{st.y:.4f},{st.yaw:.4f}", file=out, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        link.close(stop=False)
    s = link.parser.stats
    print(f"# {count} frames, {s.bytes_skipped} bytes skipped, {s.checksum_failures} checksum "
          f"failures, {s.implausible} implausible, {link.reconnects} reconnects", file=sys.stderr)
    return 0


def _cmd_pid(args) -> int:
    import serial

    from drivers.chassis import (
        DebugReplyParser,
        encode_pid_request,
        encode_pid_reset,
        encode_pid_set,
    )

    if args.action == "set":
        if args.gains is None or len(args.gains) != 3:
            raise CommandError("pid set needs three gains: KP KI KD")
        frame = encode_pid_set(*args.gains)
    elif args.gains:
        raise CommandError(f"pid {args.action} takes no gains")
    else:
        frame = encode_pid_request() if args.action == "get" else encode_pid_reset()
    try:
        port = serial.serial_for_url(args.port, baudrate=115200, timeout=0.05)
    except (serial.SerialException, ValueError) as exc:
        raise CommandError(f"cannot open debug port {args.port}: {exc}") from exc
    parser = DebugReplyParser()
    try:
        port.reset_input_buffer()
        port.write(frame)
        port.flush()
        end = time.monotonic() + args.timeout
        gains = None
        while time.monotonic() < end and gains is None:
            for ev in parser.feed(port.read(256)):
                if ev.kind == "gains":
                    gains = ev.values
                elif args.verbose:
                    print(f"# {ev.line}", file=sys.stderr)
    finally:
        port.close()
    if gains is None:
        raise CommandError(f"no PID reply from {args.port} within {args.timeout} s")
    if parser.version is not None:
        print("firmware version: {}.{}.{}".format(*parser.version))
    print(f"kp={gains[0]:g} ki={gains[1]:g} kd={gains[2]:g}")
    return 0


def _cmd_step(args) -> int:
    from fusion.io.atomic import check_target

    if args.ticks == 0:
        raise CommandError("--ticks must be non-zero")
    if args.csv:
        check_target(args.csv)  # before the wheels turn, not after
    link = _start_link(args, report_events=False)
    left = args.ticks if args.wheel in ("left", "both") else 0
    right = args.ticks if args.wheel in ("right", "both") else 0
    try:
        link.drain()
        t0 = time.monotonic()
        link.send_ticks(left, right)
        samples = []
        while time.monotonic() - t0 < args.duration:
            f = link.get(timeout=0.1)
            if f is not None and f.t >= t0:
                samples.append(f)
    finally:
        link.close(stop=True)
    if len(samples) < 4:
        raise CommandError(f"only {len(samples)} frames from {args.port} in {args.duration} s")
    # sample k holds the ticks counted over the period ending at its stamp
    t = np.array([f.t - t0 for f in samples])
    wheel = "right" if args.wheel == "right" else "left"
    y = np.array([getattr(f, wheel) for f in samples], dtype=float)
    m = step_metrics(t, y, args.ticks)
    expected = args.duration / args.period
    print(f"target {m.target:g} ticks/period ({wheel} wheel), {len(samples)} frames "
          f"({expected:.0f} expected at --period {args.period:g} s)")
    if not 0.8 * expected <= len(samples) <= 1.2 * expected:
        print(f"warning: {len(samples)} frames in {args.duration:g} s is one per "
              f"{args.duration / len(samples):.3f} s: is --period {args.period:g} s the "
              "board's encoder sampling period? (the rise time is in s either way)")
    print(f"rise time (10-90 %): {m.rise_time:.3f} s")
    print(f"overshoot: {m.overshoot:.1f} %")
    print(f"steady-state value: {m.steady_state_value:.2f} ticks/period, "
          f"error {m.steady_state_error:+.2f}", flush=True)
    if args.csv:  # after the results: a failure here loses nothing already printed
        _write_csv(args.csv, ["t", "left", "right"],
                   [(f"{f.t - t0:.4f}", f.left, f.right) for f in samples])
    return 0


_DESCRIPTION = """\
The miiboo STM32 chassis from the command line:

  fusion chassis decode CAPTURE [-o OUT.csv]     raw DATA-uart2 bytes -> CSV (left,right,offset)
  fusion chassis encode LEFT RIGHT               one DATA-uart2 frame in hex
  fusion chassis monitor --port URL --wheel-distance M --speed-ratio M_PER_TICK
                                                 live wheel speeds and odometry
  fusion chassis pid get|reset|set [KP KI KD] --port URL    DEBUG-uart1 PID commands
  fusion chassis step --port URL --ticks N       wheel step response: rise time, overshoot,
                                                 steady-state error (seed 000 section 5)

Units: ticks per sampling period on the wire, m/s and m, rad for odometry, s for time.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("chassis", help="miiboo STM32 chassis: decode, encode, monitor, "
                              "PID, step response", description=_DESCRIPTION,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="chassis_command", metavar="ACTION", required=True)

    d = sub.add_parser("decode", help="raw DATA-uart2 capture -> CSV (left,right,offset)")
    d.add_argument("capture", help="file of raw bytes read from the chassis port")
    d.add_argument("-o", "--output", help="CSV to write (default: stdout)")
    d.add_argument("--max-ticks", type=int, default=100_000,
                   help="plausibility bound, ticks per period (default 100000)")
    d.add_argument("--loose-sign", action="store_true",
                   help="accept any non-zero sign byte as positive (the seed's decoder)")
    d.set_defaults(func=_cmd_decode)

    e = sub.add_parser("encode", help="print one DATA-uart2 frame in hex")
    e.add_argument("left", type=int, help="left wheel ticks per period")
    e.add_argument("right", type=int, help="right wheel ticks per period")
    e.set_defaults(func=_cmd_encode)

    def link_args(q, geometry: bool) -> None:
        q.add_argument("--port", required=True, help="serial port or pyserial URL")
        q.add_argument("--period", type=float, default=0.04, metavar="S",
                       help="the board's encoder sampling period, s (default 0.04)")
        q.add_argument("--open-timeout", type=float, default=3.0, metavar="S",
                       help="s to wait for the port to open (default 3)")
        if geometry:
            q.add_argument("--wheel-distance", type=float, required=True, help="m")
            q.add_argument("--speed-ratio", type=float, required=True, help="m per tick")

    m = sub.add_parser("monitor", help="live wheel speeds and odometry (CSV lines)")
    link_args(m, geometry=True)
    m.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after this many s (default: until Ctrl-C)")
    m.add_argument("--interval", type=float, default=0.0, metavar="S",
                   help="s between printed lines (default 0: every frame)")
    m.add_argument("--method", choices=("midpoint", "arc"), default="midpoint",
                   help="odometry integration: midpoint (second order, default) or arc "
                        "(exact for constant speeds)")
    m.set_defaults(func=_cmd_monitor)

    q = sub.add_parser("pid", help="DEBUG-uart1: get, reset or set the PID gains")
    q.add_argument("action", choices=("get", "reset", "set"))
    q.add_argument("gains", type=float, nargs="*", metavar="K", help="KP KI KD for set")
    q.add_argument("--port", required=True, help="DEBUG-uart1 port or pyserial URL")
    q.add_argument("--timeout", type=float, default=2.0, metavar="S",
                   help="s to wait for the reply (default 2)")
    q.add_argument("-v", "--verbose", action="store_true", help="echo the other reply lines")
    q.set_defaults(func=_cmd_pid)

    s = sub.add_parser("step", help="wheel step response: rise time, overshoot, error")
    link_args(s, geometry=False)
    s.add_argument("--ticks", type=int, required=True, help="target ticks per period")
    s.add_argument("--wheel", choices=("left", "right", "both"), default="both",
                   help="wheel(s) to command; the metrics are of the left one unless 'right' "
                        "(default both)")
    s.add_argument("--duration", type=float, default=2.0, metavar="S",
                   help="s to record (default 2)")
    s.add_argument("--csv", help="also write the response to this CSV (t,left,right)")
    s.set_defaults(func=_cmd_step)
