"""A complete physics-simulated run: body trace, sensor streams, ground truth, nominal robot.

:func:`simulate_physics` runs a mission through the 1 kHz body loop and the sensor models;
:func:`physics_scenario` builds the acceptance scenarios (``plain``, ``all``, ``all+dead``).
Deterministic for a seed: the mission, the error magnitudes and the sensor noise each draw
from their own stream of ``numpy.random.default_rng([seed, k])``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import cumulative_trapezoid

from fusion.evaluation.physics_sim.body import BodyParams, ControllerParams
from fusion.evaluation.physics_sim.dynamics import BodyTrace, simulate_body
from fusion.evaluation.physics_sim.mission import Mission, indoor_mission
from fusion.evaluation.physics_sim.sensor_model import SensorModel, all_errors, plain_sensors
from fusion.evaluation.physics_sim.sensors import sample_encoders, sample_imu
from fusion.evaluation.trajectory import yaw_rmse
from fusion.geometry.kinematics import DiffDriveParams
from fusion.geometry.mount import mount_matrix
from fusion.planar.robot import RobotConfig

__all__ = ["SCENARIOS", "PhysicsRun", "driving_window", "physics_scenario", "simulate_physics"]

SCENARIOS = ("plain", "all", "all+dead")


@dataclass
class PhysicsRun:
    """One simulated run.

    Attributes:
        robot: what the owner's robot.toml says (NOMINAL radius and wheel distance, IMU mount
            0 0 0); ``speed_ratio`` m/tick, ``encode_sampling_time`` s.
        imu_t, gyro, accel: host stamps (s), gyro (rad/s) and accelerometer (m/s^2) readings
            (N, 3) in the IMU frame.
        wheel_t, ticks: host stamps (s) of the wheel frames and their (M, 2) int64 counts
            (left, right) per firmware period.
        wheel_dead: (M,) bool, the frame fell in a dead-encoder window.
        imu_t_true, wheel_t_end: the true sample times and period ends behind the stamps, s.
        truth_t: (K,) s at the physics rate.  truth: (K, 3) x, y (m), yaw (rad, continuous)
            of base_footprint in odom.  truth_v: forward speed, m/s.  truth_w: yaw rate,
            rad/s.  truth_gyro_bias: (K, 3) additive gyro bias in the IMU frame, rad/s (the
            g-sensitivity, scale and cross-axis errors come on top).  truth_slip: (K,) bool,
            a tyre slides.
        trace: the full physics trace.  mission, sensors, body: what was simulated.
    """

    robot: RobotConfig
    imu_t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    wheel_t: NDArray[np.float64]
    ticks: NDArray[np.int64]
    wheel_dead: NDArray[np.bool_]
    imu_t_true: NDArray[np.float64]
    wheel_t_end: NDArray[np.float64]
    truth_t: NDArray[np.float64]
    truth: NDArray[np.float64]
    truth_v: NDArray[np.float64]
    truth_w: NDArray[np.float64]
    truth_gyro_bias: NDArray[np.float64]
    truth_slip: NDArray[np.bool_]
    trace: BodyTrace
    mission: Mission
    sensors: SensorModel
    body: BodyParams

    @property
    def duration(self) -> float:
        """Length of the run, s."""
        return float(self.truth_t[-1] - self.truth_t[0])

    @property
    def distance(self) -> float:
        """Path length of the true axle midpoint, m."""
        return float(np.sum(np.hypot(np.diff(self.truth[:, 0]), np.diff(self.truth[:, 1]))))

    def truth_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) true ``x, y, yaw`` (m, m, rad continuous) at times ``t`` (s), linear
        interpolation of the 1 kHz truth."""
        t = np.asarray(t, dtype=float)
        return np.column_stack([np.interp(t, self.truth_t, self.truth[:, j]) for j in range(3)])

    def reference_heading(self) -> NDArray[np.float64]:
        """(N,) heading (rad, continuous) at the IMU samples' TRUE times ``imu_t_true``,
        integrated over those times from the gyro with the TRUE bias removed (its temperature
        drift and the g-sensitivity's share of gravity included) about the TRUE base vertical
        (the real mount), from the true heading at the first sample.

        What is left are the errors nothing on the robot reveals: the gyro's scale and
        cross-axis errors, the rest of its g-sensitivity, vibration and noise. Without an
        absolute heading or a gyro-scale calibration no estimator is expected to do much
        better on yaw (errors can cancel, so it is a reference, not a strict bound).
        """
        s = self.sensors
        R = mount_matrix(s.mount_rpy)  # IMU frame -> base frame
        gravity = R.T @ np.array([0.0, 0.0, self.body.gravity])  # specific force at rest
        g_sens = np.asarray(s.gyro_g_sensitivity, dtype=float).reshape(3, 3)
        t = self.imu_t_true
        rate = (self.gyro - (s.gyro_bias_at(t) + g_sens @ gravity)) @ R[2]  # base vertical
        return self.truth_at(t[:1])[0, 2] + cumulative_trapezoid(rate, t, initial=0.0)

    def reference_yaw_rmse(self) -> float:
        """Yaw RMSE (rad) of :meth:`reference_heading` against the true heading."""
        return yaw_rmse(self.reference_heading(), self.truth_at(self.imu_t_true)[:, 2])

    def dead_windows(self) -> tuple[tuple[float, float], ...]:
        """The dead-encoder windows, ``(start s, duration s)``."""
        return self.sensors.encoder_dead_windows


def nominal_robot(body: BodyParams, sensors: SensorModel) -> RobotConfig:
    """The robot.toml the owner writes: nominal geometry, IMU mount 0 0 0."""
    speed_ratio = 2.0 * math.pi * body.wheel_radius / sensors.encoder_ticks_per_rev
    return RobotConfig(chassis=DiffDriveParams(
        wheel_distance=body.wheel_distance, speed_ratio=speed_ratio,
        encode_sampling_time=sensors.wheel_period))


def driving_window(trace: BodyTrace, duration: float, rng: np.random.Generator,
                   earliest: float = 60.0, min_speed: float = 0.1) -> tuple[float, float]:
    """A ``(start s, duration s)`` window in which the robot drives all the time (true
    ``|u| > min_speed`` m/s throughout), starting at or after ``earliest`` s; picked at random
    among the candidates on a 0.1 s grid.

    Raises:
        ValueError: the trace has no such window.
    """
    step = 0.1
    n_step = round(step / (trace.t[1] - trace.t[0]))
    moving = np.abs(trace.u[::n_step]) > min_speed
    t = trace.t[::n_step]
    span = math.ceil(duration / step) + 1
    run = np.convolve(moving.astype(int), np.ones(span, dtype=int), mode="valid") == span
    ok = np.flatnonzero(run & (t[:run.size] >= earliest))
    if ok.size == 0:
        raise ValueError(f"no {duration} s window of continuous driving after {earliest} s")
    return float(t[int(rng.choice(ok))]), float(duration)


def simulate_physics(
    mission: Mission,
    sensors: SensorModel | None = None,
    seed: int = 0,
    body: BodyParams | None = None,
    controller: ControllerParams | None = None,
    dead_encoder_while_driving: float = 0.0,
) -> PhysicsRun:
    """Simulate ``mission`` at 1 kHz and sample the sensors.

    Args:
        mission: commands and floor.
        sensors: sensor setup and errors (default: ideal sensors).
        seed: seeds the sensor noise, clock phases, losses and the dead window's position.
        body, controller: the robot (defaults of :class:`BodyParams`,
            :class:`ControllerParams`).
        dead_encoder_while_driving: if > 0, a dead-encoder window of this many seconds is
            added where the robot drives throughout (:func:`driving_window`), starting after
            60 s or a fifth of the mission, whichever is earlier.
    """
    sensors = sensors or SensorModel()
    body = body or BodyParams()
    trace = simulate_body(mission, body, controller, sensors.radius_error,
                          sensors.radius_speed_coeff, sensors.separation_error)
    rng = np.random.default_rng([seed, 404])
    if dead_encoder_while_driving > 0:
        window = driving_window(trace, dead_encoder_while_driving, rng,
                                earliest=min(60.0, 0.2 * mission.duration))
        sensors = replace(sensors,
                          encoder_dead_windows=(*sensors.encoder_dead_windows, window))
    imu = sample_imu(trace, body, sensors, np.random.default_rng([seed, 505]))
    enc = sample_encoders(trace, sensors, np.random.default_rng([seed, 606]))
    return PhysicsRun(
        robot=nominal_robot(body, sensors),
        imu_t=imu["t"], gyro=imu["gyro"], accel=imu["accel"],
        wheel_t=enc["t"], ticks=enc["ticks"], wheel_dead=enc["dead"],
        imu_t_true=imu["t_true"], wheel_t_end=enc["t_end"],
        truth_t=trace.t, truth=np.column_stack([trace.x, trace.y, trace.yaw]),
        truth_v=trace.u, truth_w=trace.r, truth_gyro_bias=sensors.gyro_bias_at(trace.t),
        truth_slip=(trace.slip_l > 0) | (trace.slip_r > 0),
        trace=trace, mission=mission, sensors=sensors, body=body,
    )


def physics_scenario(name: str, seed: int = 0, duration: float = 300.0,
                     dead_encoder: float = 8.0, moving_start: bool = False) -> PhysicsRun:
    """An acceptance scenario on :func:`indoor_mission`:

    - ``"plain"``: :func:`plain_sensors`, high friction everywhere;
    - ``"all"``: :func:`all_errors` and three low-friction patches;
    - ``"all+dead"``: as ``"all"`` plus ``dead_encoder`` s of zero ticks on both wheels while
      the robot drives.

    Raises:
        ValueError: an unknown ``name``.
    """
    if name not in SCENARIOS:
        raise ValueError(f"scenario must be one of {SCENARIOS}, got {name!r}")
    plain = name == "plain"
    mission = indoor_mission(seed, duration, moving_start=moving_start, low_friction=not plain)
    sensors = plain_sensors(seed) if plain else all_errors(seed)
    return simulate_physics(mission, sensors, seed,
                            dead_encoder_while_driving=dead_encoder if name == "all+dead" else 0)
