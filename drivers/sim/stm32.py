"""Simulated miiboo STM32 chassis firmware (seed 000 section 2) on the far end of two ptys.

What is modelled, per wheel, every sampling period ``T`` (TIM1 interrupt, 40 ms by default),
in the firmware's order:

1. read the encoder count of the last period (TIM2/TIM3 in encoder mode: integer ticks; the
   fractional part of the rotation carries over, so counts are quantised but never lost);
2. send both counts on DATA-uart2 (unless a dropped frame is simulated);
3. run the incremental PID of seed 000 section 2.4 on (target, count):
   ``e = target - current``; ``u += Ka*(Kp*(e - e1) + Ki*e + Kd*(e - 2*e1 + e2))``, stored in an
   ``int`` as the C code does (truncation toward zero), clamped to +-``pwm_limit`` (30000 of
   TIM4's 35999); a zero target brakes: ``u = 0`` and the error history is cleared;
4. apply the PWM to a first-order DC motor: the wheel rim speed tends to
   ``u / pwm_max * wheel_speed_full`` (m/s) with time constant ``motor_tau`` s, integrated
   exactly over ``substeps`` sub-steps.

The ground moves by the wheel travel times ``1 - slip`` (optional slip per wheel, plus random
slip noise); the encoder sees the full rotation. The true pose (x, y, theta in the odom frame,
m and rad) integrates the ground travel with exact arcs per sub-step, so odometry computed
from the feedback can be compared with it.

DEBUG-uart1: a welcome banner and the firmware version at start; 15-byte commands are
answered with printf text like the firmware: ``[stm32 response:]``, ``firmware version:a.b.c``
(for the request), and ``kp_set:%f``, ``ki_set:%f``, ``kd_set:%f``.

Use :class:`Stm32Sim` directly (``step()`` advances one period, no I/O, no clock) or run it in
real time on ptys with :class:`PtyStm32` (a thread), or from a shell::

    python -m drivers.sim.stm32 --link-dir /tmp/chassis     # prints the two port paths
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import math
import os
import select
import signal
import sys
import threading
import time
import tty
from dataclasses import dataclass, field

import numpy as np

from drivers.chassis import DebugCommandParser, WheelFrameParser, encode_wheel_frame
from fusion.geometry.dead_reckoning import step, wheel_motion
from fusion.types.constants import TICKS_MAX

__all__ = ["PtyStm32", "Stm32Sim", "Stm32SimParams", "main"]

BANNER = "\r\n###welcome to use miiboo in stm32!!###\r\n"


def _version_line(v: tuple[int, int, int]) -> str:
    return f"firmware version:{v[0]}.{v[1]}.{v[2]}\r\n"


@dataclass
class Stm32SimParams:
    """Simulated chassis and firmware parameters (SI units).

    Attributes:
        period: firmware sampling period T, s.
        wheel_distance: wheel separation, m.
        speed_ratio: m of wheel rim travel per encoder tick.
        wheel_speed_full: rim speed at full PWM (pwm_max), m/s.
        motor_tau: first-order motor time constant, s.
        pwm_max: PWM counter top (TIM4 arr + 1 = 36000 on the board; 35999 used as scale).
        pwm_limit: PID output clamp, PWM counts.
        kp, ki, kd, ka: default gains of the incremental PID (PWM counts per tick).
        slip: fraction of wheel travel lost to slip (left, right), 0..1.
        slip_noise: standard deviation of a random extra slip fraction per period.
        drop_prob: probability that a feedback frame is not sent.
        substeps: motor integration sub-steps per period.
        firmware_version: reported by the version request.
        echo_targets: print ``enc1_target:%d``/``enc2_target:%d`` on DEBUG-uart1 for every
            speed command (the seed's listing has these printf lines near a commented block).
        seed: random seed for slip noise and dropped frames.
        history: periods kept in the per-period records of :class:`Stm32Sim`
            (``ticks_counted``, ``targets``, ...; the newest), and frame times kept by
            :class:`PtyStm32`; None keeps everything (memory grows with the run).
    """

    period: float = 0.04
    wheel_distance: float = 0.3
    speed_ratio: float = 5e-5
    wheel_speed_full: float = 1.2
    motor_tau: float = 0.1
    pwm_max: int = 35999
    pwm_limit: int = 30000
    kp: float = 30.0
    ki: float = 15.0
    kd: float = 5.0
    ka: float = 1.0
    slip: tuple[float, float] = (0.0, 0.0)
    slip_noise: float = 0.0
    drop_prob: float = 0.0
    substeps: int = 20
    firmware_version: tuple[int, int, int] = (1, 0, 0)
    echo_targets: bool = False
    seed: int = 0
    history: int | None = 10_000

    def __post_init__(self) -> None:
        if self.history is not None and (isinstance(self.history, bool)
                                         or not isinstance(self.history, int)
                                         or self.history < 1):
            raise ValueError(f"history must be a positive number of periods or None, got "
                             f"{self.history!r}")


@dataclass
class _Pid:
    """The seed's incremental PID for one motor (C semantics: int output)."""

    u: int = 0
    e1: int = 0
    e2: int = 0

    def step(self, target: int, current: int, kp: float, ki: float, kd: float, ka: float,
             limit: int) -> int:
        err = target - current
        u = self.u + ka * (kp * (err - self.e1) + ki * err + kd * (err - 2 * self.e1 + self.e2))
        u = int(u)  # C assignment of a float expression to int: truncation toward zero
        u = max(-limit, min(limit, u))
        self.e2 = self.e1
        self.e1 = err
        if target == 0:  # brake stop
            u = 0
            self.e1 = 0
            self.e2 = 0
        self.u = u
        return u


@dataclass
class _Wheel:
    speed: float = 0.0  # rim speed, m/s
    enc: float = 0.0  # encoder position, ticks (continuous)
    enc_read: int = 0  # floor(enc) at the last read
    pid: _Pid = field(default_factory=_Pid)


class Stm32Sim:
    """The firmware and the chassis physics, without I/O or a clock (call :meth:`step`).

    Commands go in with :meth:`command_bytes` (DATA-uart2 bytes) and :meth:`debug_bytes`
    (DEBUG-uart1 bytes); :meth:`step` returns the DATA-uart2 bytes to send, and
    :meth:`take_debug_output` the pending DEBUG-uart1 text.

    The per-period records (``ticks_sent``, ``ticks_counted``, ``pose_at_read``,
    ``pose_at_sent``, ``targets``) are deques of the newest ``params.history`` periods, so a
    simulator running for hours keeps flat memory.
    """

    def __init__(self, params: Stm32SimParams | None = None) -> None:
        self.params = params if params is not None else Stm32SimParams()
        p = self.params
        self.gains = (p.kp, p.ki, p.kd)
        self.left = _Wheel()
        self.right = _Wheel()
        self.target = (0, 0)
        self.pose = np.zeros(3)  # true x, y, theta (odom frame), m, m, rad
        n = p.history
        # the newest n periods (a ring buffer each)
        self.ticks_sent: collections.deque[tuple[int, int]] = collections.deque(maxlen=n)
        self.ticks_counted: collections.deque[tuple[int, int]] = collections.deque(maxlen=n)
        self.pose_at_read: collections.deque[np.ndarray] = collections.deque(maxlen=n)
        self.pose_at_sent: collections.deque[np.ndarray] = collections.deque(maxlen=n)
        self.targets: collections.deque[tuple[int, int]] = collections.deque(maxlen=n)
        self.pwm = (0, 0)
        self.periods = 0
        self.dropped = 0
        self._rng = np.random.default_rng(p.seed)
        self._cmd_parser = WheelFrameParser(max_ticks=TICKS_MAX, strict_sign=False)
        self._dbg_parser = DebugCommandParser()
        self._debug_out: list[str] = [BANNER, _version_line(p.firmware_version)]
        self._lock = threading.Lock()

    # -- inputs --
    def command_bytes(self, data: bytes) -> None:
        """DATA-uart2 bytes from the host (speed control frames: target ticks per period)."""
        with self._lock:
            frames = self._cmd_parser.feed(data) + self._cmd_parser.flush()
            for f in frames:
                self.target = (f.left, f.right)
                if self.params.echo_targets:
                    self._debug_out.append(
                        f"\r\nenc1_target:{f.left}\r\nenc2_target:{f.right}\r\n"
                    )

    def debug_bytes(self, data: bytes) -> None:
        """DEBUG-uart1 bytes from the host (15-byte PID commands)."""
        with self._lock:
            for cmd in self._dbg_parser.feed(data):
                p = self.params
                lines = ["\r\n[stm32 response:]\r\n"]
                if cmd.kind == "request":
                    lines.append(_version_line(p.firmware_version))
                elif cmd.kind == "reset":
                    self.gains = (p.kp, p.ki, p.kd)
                else:
                    self.gains = (cmd.kp, cmd.ki, cmd.kd)
                kp, ki, kd = self.gains
                lines.append(f"kp_set:{kp:f}\r\nki_set:{ki:f}\r\nkd_set:{kd:f}\r\n")
                self._debug_out.append("".join(lines))

    def take_debug_output(self) -> bytes:
        with self._lock:
            out = "".join(self._debug_out).encode()
            self._debug_out.clear()
            return out

    # -- one TIM1 period --
    def step(self) -> bytes:
        """Advance one period; returns the feedback frame (b"" when dropped)."""
        p = self.params
        with self._lock:
            # 1. read the encoders first
            counts = []
            for w in (self.left, self.right):
                now = math.floor(w.enc)
                counts.append(now - w.enc_read)
                w.enc_read = now
            c_l, c_r = counts
            self.ticks_counted.append((c_l, c_r))
            self.pose_at_read.append(self.pose.copy())
            self.targets.append(self.target)
            # 2. send them on uart2
            out = b""
            if p.drop_prob and self._rng.random() < p.drop_prob:
                self.dropped += 1
            else:
                out = encode_wheel_frame(max(-TICKS_MAX, min(TICKS_MAX, c_l)),
                                         max(-TICKS_MAX, min(TICKS_MAX, c_r)))
                self.ticks_sent.append((c_l, c_r))
                self.pose_at_sent.append(self.pose.copy())
            # 3. PID per motor
            kp, ki, kd = self.gains
            u_l = self.left.pid.step(self.target[0], c_l, kp, ki, kd, p.ka, p.pwm_limit)
            u_r = self.right.pid.step(self.target[1], c_r, kp, ki, kd, p.ka, p.pwm_limit)
            self.pwm = (u_l, u_r)
            # 4. motors and ground over the next period
            self._physics(u_l, u_r)
            self.periods += 1
            return out

    def _physics(self, u_l: int, u_r: int) -> None:
        p = self.params
        dt = p.period / p.substeps
        decay = math.exp(-dt / p.motor_tau)
        slip = [p.slip[0], p.slip[1]]
        if p.slip_noise:
            slip = [s + abs(self._rng.normal(0.0, p.slip_noise)) for s in slip]
        for _ in range(p.substeps):
            travel = []
            for w, u in ((self.left, u_l), (self.right, u_r)):
                ss = u / p.pwm_max * p.wheel_speed_full
                d = ss * dt + (w.speed - ss) * p.motor_tau * (1.0 - decay)
                w.speed = ss + (w.speed - ss) * decay
                w.enc += d / p.speed_ratio
                travel.append(d)
            dl = travel[0] * (1.0 - slip[0])
            dr = travel[1] * (1.0 - slip[1])
            x, y, th = self.pose.tolist()
            self.pose[:] = step(x, y, th, *wheel_motion(dl, dr, p.wheel_distance), rule="arc")

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        """True rim speeds (left, right), m/s."""
        return self.left.speed, self.right.speed


def _make_pty() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo or line discipline on the far end
    tty.setraw(master)
    return master, slave, os.ttyname(slave)


def _point(link: str | None, target: str) -> None:
    if link is None:
        return
    tmp = f"{link}.{os.getpid()}.tmp"
    os.symlink(target, tmp)
    os.replace(tmp, link)


class PtyStm32:
    """Runs a :class:`Stm32Sim` in real time in a thread, on two pseudo-terminals.

    Args:
        sim: the simulated firmware (default parameters if None).
        data_link, debug_link: optional symlink paths that point at the pty slaves (stable
            names, like udev's); needed to unplug and replug the data port.

    Attributes:
        data_port, debug_port: the paths a host opens (the symlinks if given, else /dev/pts/N).
    """

    def __init__(
        self,
        sim: Stm32Sim | None = None,
        data_link: str | None = None,
        debug_link: str | None = None,
    ) -> None:
        self.sim = sim if sim is not None else Stm32Sim()
        self._data_link = data_link
        self._debug_link = debug_link
        self._dm, self._ds, data_name = _make_pty()
        self._gm, self._gs, debug_name = _make_pty()
        _point(data_link, data_name)
        _point(debug_link, debug_name)
        self.data_port = data_link or data_name
        self.debug_port = debug_link or debug_name
        self._stop = threading.Event()
        self._io = threading.Lock()
        self._thread: threading.Thread | None = None
        # monotonic time each frame was written (the newest params.history)
        self.frame_times: collections.deque[float] = collections.deque(
            maxlen=self.sim.params.history)

    def start(self) -> PtyStm32:
        self._thread = threading.Thread(target=self._run, name="PtyStm32", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the firmware (no more frames); the ports stay open until :meth:`close`."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def close(self) -> None:
        """Stop and close both ptys (the host sees the ports vanish)."""
        self.stop()
        with self._io:
            for fd in (self._dm, self._ds, self._gm, self._gs):
                if fd >= 0:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._dm = self._ds = self._gm = self._gs = -1
        for link in (self._data_link, self._debug_link):
            if link and os.path.islink(link):
                with contextlib.suppress(OSError):
                    os.unlink(link)

    def __enter__(self) -> PtyStm32:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- cable --
    def unplug(self) -> None:
        """The data port vanishes (USB adapter pulled): pty closed, symlink removed."""
        with self._io:
            if self._data_link and os.path.islink(self._data_link):
                os.unlink(self._data_link)
            for fd in (self._dm, self._ds):
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._dm = self._ds = -1

    def replug(self) -> None:
        """The data port comes back (a new pty behind the same symlink)."""
        if not self._data_link:
            raise ValueError("replug needs data_link (a stable path the host reopens)")
        with self._io:
            self._dm, self._ds, name = _make_pty()
            _point(self._data_link, name)

    # -- loop --
    def _run(self) -> None:
        T = self.sim.params.period
        next_t = time.monotonic() + T
        while not self._stop.is_set():
            # service input until the next period
            while True:
                wait = next_t - time.monotonic()
                if wait <= 0:
                    break
                with self._io:
                    fds = [fd for fd in (self._dm, self._gm) if fd >= 0]
                try:
                    ready, _, _ = select.select(fds, [], [], min(wait, 0.01))
                except (OSError, ValueError):
                    time.sleep(min(wait, 0.01))
                    continue
                for fd in ready:
                    try:
                        data = os.read(fd, 4096)
                    except OSError:
                        continue
                    if fd == self._dm:
                        self.sim.command_bytes(data)
                    elif fd == self._gm:
                        self.sim.debug_bytes(data)
            out = self.sim.step()
            next_t += T
            if next_t < time.monotonic():  # fell behind (slow machine): skip, keep cadence
                next_t = time.monotonic() + T
            with self._io:
                if out and self._dm >= 0:
                    with contextlib.suppress(OSError):
                        os.write(self._dm, out)
                        self.frame_times.append(time.monotonic())
                dbg = self.sim.take_debug_output()
                if dbg and self._gm >= 0:
                    with contextlib.suppress(OSError):
                        os.write(self._gm, dbg)


def main(argv: list[str] | None = None) -> int:
    """``python -m drivers.sim.stm32``: run the simulated chassis until Ctrl-C or SIGTERM
    (either closes the ptys and removes the ``--link-dir`` symlinks)."""
    ap = argparse.ArgumentParser(prog="python -m drivers.sim.stm32",
                                 description="Simulated miiboo STM32 chassis on two ptys.")
    ap.add_argument("--link-dir", help="create stable symlinks data and debug in this folder")
    ap.add_argument("--period", type=float, default=0.04, help="sampling period, s")
    ap.add_argument("--slip", type=float, nargs=2, default=(0.0, 0.0), metavar=("LEFT", "RIGHT"))
    ap.add_argument("--drop", type=float, default=0.0, help="probability of a dropped frame")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many s")
    args = ap.parse_args(argv)
    params = Stm32SimParams(period=args.period, slip=tuple(args.slip), drop_prob=args.drop)
    data_link = debug_link = None
    if args.link_dir:
        os.makedirs(args.link_dir, exist_ok=True)
        data_link = os.path.join(args.link_dir, "data")
        debug_link = os.path.join(args.link_dir, "debug")

    def on_term(signum, frame):  # SIGTERM (kill, systemd) stops like Ctrl-C: links removed
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    sim = PtyStm32(Stm32Sim(params), data_link=data_link, debug_link=debug_link).start()
    try:  # a SIGTERM may come as soon as the ports are printed
        print(f"data (DATA-uart2):   {sim.data_port}", flush=True)
        print(f"debug (DEBUG-uart1): {sim.debug_port}", flush=True)
        end = None if args.duration is None else time.monotonic() + args.duration
        while end is None or time.monotonic() < end:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        sim.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
