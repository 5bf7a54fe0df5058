"""The simulated robot with the real link and driver, and I2C error bursts on a schedule of
robot time (shared by the live pipeline's tests)."""

from __future__ import annotations

import errno

from drivers.mpu6050 import MPU6050
from drivers.serial_link import ChassisLink
from drivers.sim.robot import SimRobot

__all__ = ["NackBursts", "sim_hardware"]


def sim_hardware(clock, params, cfg, *, link_path: str | None = None,
                 keep_truth: bool = True) -> tuple[SimRobot, ChassisLink, MPU6050]:
    """``(robot, link, imu)``: the simulated STM32 on a real pty (behind ``link_path`` if
    given) read by a started ChassisLink, and the simulated chip behind the real driver
    (100 Hz, +-500 deg/s, +-4 g). The robot is not started."""
    robot = SimRobot(clock, params, data_link=link_path, keep_truth=keep_truth)
    link = ChassisLink(robot.port, period=cfg.robot.chassis.encode_sampling_time, clock=clock,
                       command_timeout=0.5, reconnect_interval=0.02)
    link.start(wait=5.0)
    imu = MPU6050(robot.bus, clock=clock, sample_rate_hz=100.0, gyro_range_dps=500,
                  accel_range_g=4)
    return robot, link, imu


class NackBursts:
    """Call with the time ``t`` (s) from a run loop: from 1 s on, every 0.5 s a burst of 2
    NACKs (within the driver's 3 retries); once, at ``long_at`` s, 12 in a row (EIO: the
    retries run out, the FIFO read fails).

    Attributes:
        short: short bursts injected; long_t: when the long one was (None: not yet).
    """

    def __init__(self, bus, long_at: float) -> None:
        self.bus, self.long_at = bus, long_at
        self.short = 0
        self.long_t: float | None = None

    def __call__(self, t: float) -> None:
        if t > 1.0 and int(t * 2) > self.short + 2:
            self.bus.inject_nack(2)
            self.short += 1
        if t > self.long_at and self.long_t is None:
            self.bus.inject_nack(12, errno=errno.EIO)
            self.long_t = t
