"""A whole simulated robot for demos and tests: the simulated STM32 chassis (on a pty) and the
simulated MPU6050 (an I2C bus object) driven by one true motion on one scaled clock, and a
scripted mission to drive it.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from fusion.geometry.mount import base_to_imu, mount_matrix
from fusion.types.constants import STANDARD_GRAVITY

__all__ = [
    "MISSION",
    "LoopingMission",
    "ScaledClock",
    "SimRobot",
    "SimRobotParams",
    "mission_command",
    "mission_duration",
]


#: The scripted mission: (duration s, forward speed m/s, yaw rate rad/s), about 60 s.
MISSION: tuple[tuple[float, float, float], ...] = (
    (3.0, 0.0, 0.0),          # rest: the filter learns the gyro bias
    (5.0, 0.4, 0.0),          # 2 m straight (a slip patch on the left wheel)
    (1.0, 0.0, 0.0),
    (1.571, 0.0, 1.0),        # 90 deg left on the spot
    (4.0, 0.4, 0.0),
    (6.0, 0.35, 0.5),         # arc, 172 deg left
    (1.5, 0.0, 0.0),
    (4.0, 0.5, 0.0),
    (2.618, 0.0, -1.2),       # 180 deg right on the spot
    (5.0, 0.3, -0.6),         # arc right
    (5.0, 0.4, 0.0),          # (a slip patch on the right wheel)
    (2.0, 0.0, 0.0),
    (7.854, 0.4, 0.8),        # a full circle of 0.5 m radius
    (3.0, 0.3, 0.0),
    (4.0, 0.0, 0.0),          # rest at the end
)


def mission_command(t: float, mission=MISSION) -> tuple[float, float] | None:
    """Commanded ``(v m/s, w rad/s)`` at mission time ``t`` s, None after the end."""
    if t < 0:
        return 0.0, 0.0
    for duration, v, w in mission:
        if t < duration:
            return v, w
        t -= duration
    return None


def mission_duration(mission=MISSION) -> float:
    """Length of a mission, s."""
    return float(sum(d for d, _, _ in mission))


class ScaledClock:
    """Robot time that runs ``speed`` times faster than the wall clock, s.

    ``monotonic()`` (also the instance itself, called) reads it, from ``start`` s on (a host's
    monotonic clock reads the time since boot: ``start=1000.0`` is one that has been up a
    while); ``sleep(s)`` sleeps ``s`` robot seconds. It has no ``advance``: the simulated
    MPU6050 then follows it without adding wire time.
    """

    def __init__(self, speed: float = 1.0, start: float = 0.0) -> None:
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be > 0, got {speed!r}")
        if not (math.isfinite(start) and start >= 0):
            raise ValueError(f"start must be >= 0 s (a host clock's), got {start!r}")
        self.speed = float(speed)
        self.start = float(start)
        self._t0 = time.monotonic()

    def monotonic(self) -> float:
        return self.start + (time.monotonic() - self._t0) * self.speed

    __call__ = monotonic

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self.speed)


@dataclass(frozen=True)
class SimRobotParams:
    """The simulated robot's *true* properties (what ``robot.toml`` gets slightly wrong).

    Attributes:
        wheel_distance: true wheel separation, m.
        speed_ratio: true m of rim travel per tick (both wheels).
        radius_mismatch: relative ground-travel difference right - left (0.005: the right
            wheel covers 0.5 % more ground per tick than the left).
        slip_patches: ``(t0, t1, wheel, slip)`` windows (s after :attr:`SimRobot.t_origin`,
            the mission start) in which ``wheel``
            (0 left, 1 right) loses ``slip`` of its travel (0.3: the wheel turns 1/0.7 times
            as far as the robot moves).
        gyro_bias_dps: constant gyro bias (x, y, z), deg/s.
        gyro_bias_walk_dps: random walk of the z bias, deg/s per sqrt(s).
        gyro_noise_dps, accel_noise_g: white noise per sample (deg/s, g).
        imu_mount_rpy: how the IMU sits on the robot (URDF rpy, rad).
        slip_noise: random extra slip per period (floor texture).
        seed: seed of every random draw.
    """

    wheel_distance: float = 0.3
    speed_ratio: float = 5e-5
    radius_mismatch: float = 0.005
    slip_patches: tuple[tuple[float, float, int, float], ...] = (
        (10.5, 11.5, 0, 0.3), (39.0, 40.0, 1, 0.3))
    gyro_bias_dps: tuple[float, float, float] = (0.1, -0.1, 0.5)
    gyro_bias_walk_dps: float = 0.002
    gyro_noise_dps: float = 0.04
    accel_noise_g: float = 0.004
    imu_mount_rpy: tuple[float, float, float] = (math.radians(2.0), math.radians(-1.5), 0.0)
    slip_noise: float = 0.001
    seed: int = 7


@dataclass
class _Segment:
    t0: float
    w: float
    v: float
    a: float


class SimRobot:
    """The simulated STM32 (on a pty, in a thread) and MPU6050 (an I2C bus object), sharing
    one :class:`ScaledClock` and one true motion.

    Args:
        clock: the robot clock.
        params: the true robot (:class:`SimRobotParams`).
        data_link: a symlink path for the data port (needed for :meth:`unplug`/:meth:`replug`).
        keep_truth: keep the whole true trajectory (for a report; bounded runs only). Without
            it only the last 10 s of motion are kept (indefinite runs).

    Attributes:
        port: the path the host opens (the symlink if given).
        bus: the simulated MPU6050, an SMBus-like object for :class:`drivers.mpu6050.MPU6050`.
        truth: list of ``(t, x, y, yaw)`` at every period (with ``keep_truth``).
    """

    def __init__(self, clock: ScaledClock, params: SimRobotParams | None = None, *,
                 data_link: str | None = None, keep_truth: bool = True) -> None:
        from drivers.sim.mpu6050 import SimulatedMPU6050
        from drivers.sim.stm32 import Stm32Sim, Stm32SimParams

        self.clock = clock
        self.params = p = params or SimRobotParams()
        half = 0.5 * p.radius_mismatch
        self._base_slip = (half, -half)  # left covers less ground per tick, right more
        self.sim = Stm32Sim(Stm32SimParams(wheel_distance=p.wheel_distance,
                                           speed_ratio=p.speed_ratio, slip=self._base_slip,
                                           slip_noise=p.slip_noise, seed=p.seed,
                                           substeps=10, history=100))
        self.period = self.sim.params.period
        self._mount = mount_matrix(p.imu_mount_rpy)
        # the last 2 s of true motion, as arrays rebuilt once per period (the IMU reads only
        # recent instants; older ones are held at the oldest value)
        self._segments: deque[_Segment] = deque(maxlen=50)
        self._seg_arrays = (np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
        self._seg_lock = threading.Lock()
        self.keep_truth = keep_truth
        self.truth: list[tuple[float, float, float, float]] = [(0.0, 0.0, 0.0, 0.0)]
        self._last_v = 0.0
        self._rng = np.random.default_rng(p.seed)
        self.bus = SimulatedMPU6050(self._motion, clock=clock, gyro_bias_dps=p.gyro_bias_dps,
                                    gyro_noise_dps=p.gyro_noise_dps,
                                    accel_noise_g=p.accel_noise_g, seed=p.seed)
        self._data_link = data_link
        self._io = threading.Lock()
        self._master, self._slave, name = self._pty()
        if data_link:
            self._point(name)
        self.port = data_link or name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.steps = 0
        self.frames_written = 0
        self.frame_times: list[float] = []  # robot time of each frame written (keep_truth)
        self.t_origin = 0.0  # robot time the slip patches are counted from
        self.late_steps = 0  # periods the firmware ran more than a period late (busy host)
        self.max_lag = 0.0  # s of robot time
        self.max_lag_at = 0.0  # mission time of the worst lag, s

    # -- pty ---------------------------------------------------------------------------------
    @staticmethod
    def _pty() -> tuple[int, int, str]:
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        return master, slave, os.ttyname(slave)

    def _point(self, target: str) -> None:
        assert self._data_link is not None
        tmp = f"{self._data_link}.{os.getpid()}.tmp"
        os.symlink(target, tmp)
        os.replace(tmp, self._data_link)

    def unplug(self) -> None:
        """The USB serial adapter is pulled: the port and its symlink vanish."""
        with self._io:
            if self._data_link and os.path.islink(self._data_link):
                os.unlink(self._data_link)
            for fd in (self._master, self._slave):
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._master = self._slave = -1

    def replug(self) -> None:
        """The adapter is plugged back in: a new pty behind the same symlink."""
        if not self._data_link:
            raise ValueError("replug needs data_link (a stable path the host reopens)")
        with self._io:
            self._master, self._slave, name = self._pty()
            self._point(name)

    # -- truth -------------------------------------------------------------------------------
    def _motion(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True body rates (rad/s) and specific force (m/s^2) in the IMU frame at times t:
        each period's mean yaw rate and speed, so the gyro integrates to the true yaw."""
        with self._seg_lock:
            t0, ws, vs, acc = self._seg_arrays
        n = len(t)
        rate = np.zeros((n, 3))
        force = np.zeros((n, 3))
        force[:, 2] = STANDARD_GRAVITY
        if t0.size:
            i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, t0.size - 1)
            w, v, a = ws[i], vs[i], acc[i]
            rate[:, 2] = w
            force[:, 0] = a
            force[:, 1] = v * w
        return base_to_imu(self._mount, rate), base_to_imu(self._mount, force)

    # -- firmware loop -----------------------------------------------------------------------
    def _slip_at(self, t: float) -> tuple[float, float]:
        slip = list(self._base_slip)
        t -= self.t_origin
        for t0, t1, wheel, s in self.params.slip_patches:
            if t0 <= t < t1:
                slip[wheel] += s
        return slip[0], slip[1]

    def _step(self, k: int) -> None:
        sim = self.sim
        t = k * self.period
        lag = self.clock.monotonic() - t
        if lag > self.max_lag:
            self.max_lag, self.max_lag_at = lag, t - self.t_origin
        if lag > self.period:
            self.late_steps += 1
        # host commands that arrived
        with self._io:
            fd = self._master
            if fd >= 0:
                with contextlib.suppress(OSError, ValueError):
                    while select.select([fd], [], [], 0)[0]:
                        data = os.read(fd, 4096)
                        if not data:
                            break
                        sim.command_bytes(data)
        sim.params.slip = self._slip_at(t)
        pose0 = sim.pose.copy()
        out = sim.step()  # counts of [t - T, t], then the physics of [t, t + T]
        pose1 = sim.pose.copy()
        # mean motion over the next period, for the IMU
        d = float(np.hypot(*(pose1[:2] - pose0[:2])))
        heading = math.atan2(pose1[1] - pose0[1], pose1[0] - pose0[0]) if d > 0 else pose0[2]
        sign = 1.0 if math.cos(heading - pose0[2] - 0.5 * (pose1[2] - pose0[2])) >= 0 else -1.0
        v = sign * d / self.period
        w = float(pose1[2] - pose0[2]) / self.period
        seg = _Segment(t, w, v, (v - self._last_v) / self.period)
        self._last_v = v
        segs = self._segments
        segs.append(seg)
        arrays = (np.array([x.t0 for x in segs]), np.array([x.w for x in segs]),
                  np.array([x.v for x in segs]), np.array([x.a for x in segs]))
        with self._seg_lock:
            self._seg_arrays = arrays
        if self.keep_truth:
            self.truth.append((t + self.period, float(pose1[0]), float(pose1[1]),
                               float(pose1[2])))
        # the gyro bias walks
        walk = self.params.gyro_bias_walk_dps
        if walk:
            self.bus.gyro_bias_dps = self.bus.gyro_bias_dps + np.array(
                [0.0, 0.0, walk * math.sqrt(self.period) * self._rng.normal()])
        if out:
            with self._io:
                if self._master >= 0:
                    with contextlib.suppress(OSError):
                        os.write(self._master, out)
                        self.frames_written += 1
                        if self.keep_truth:
                            self.frame_times.append(t)
        self.steps += 1

    def _run(self, k: int) -> None:
        while not self._stop.is_set():
            wait = k * self.period - self.clock.monotonic()
            if wait > 0:
                self._stop.wait(min(wait / self.clock.speed, 0.05))
                continue
            self._step(k)
            k += 1

    def start(self) -> SimRobot:
        """Start the firmware at the next period boundary (the robot stands still there)."""
        k0 = math.ceil(self.clock.monotonic() / self.period)
        self.truth = [(k0 * self.period, 0.0, 0.0, 0.0)]
        self._thread = threading.Thread(target=self._run, args=(k0,), name="sim-stm32",
                                        daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._io:
            for fd in (self._master, self._slave):
                if fd >= 0:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = -1
        if self._data_link and os.path.islink(self._data_link):
            with contextlib.suppress(OSError):
                os.unlink(self._data_link)

    def truth_at(self, t: np.ndarray) -> np.ndarray:
        """True ``(x, y, yaw)`` at robot times ``t`` (linear interpolation; yaw continuous)."""
        tr = np.array(self.truth)
        t = np.asarray(t, dtype=float)
        return np.column_stack([np.interp(t, tr[:, 0], tr[:, i]) for i in (1, 2, 3)])


def send_twist(link: Any, chassis: Any, v: float, w: float) -> bool:
    """Seed 000's command path (:meth:`drivers.serial_link.ChassisLink.send_twist`: clamp
    (v m/s, w rad/s), keep the curvature within the wheel limit, target ticks per period)."""
    return link.send_twist(v, w, chassis)


class LoopingMission:
    """Drives the scripted mission in a loop through a chassis link: call it from a run loop.

    A command is (re)sent when it changes or every ``resend`` s (robot time), so the link's
    stale-command stop never fires while the mission runs.
    """

    def __init__(self, link: Any, chassis: Any, clock, t0: float, mission=MISSION,
                 resend: float = 0.2) -> None:
        self.link, self.chassis, self.clock, self.t0 = link, chassis, clock, t0
        self.mission, self.resend = mission, resend
        self.period = mission_duration(mission)
        self._cmd: tuple[float, float] | None = None
        self._sent = -math.inf

    def __call__(self) -> float:
        """Send the mission's command for now if due; returns the robot time now, s."""
        now = self.clock()
        cmd = mission_command((now - self.t0) % self.period, self.mission)
        if cmd != self._cmd or now - self._sent > self.resend:
            send_twist(self.link, self.chassis, *cmd)
            self._cmd, self._sent = cmd, now
        return now
