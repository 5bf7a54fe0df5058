"""A second robot simulator for acceptance tests, independent of the estimator's model.

Unlike :mod:`fusion.evaluation.synthetic` (a kinematic sampler), this one integrates the
physics of a two-wheel robot at 1 kHz (:mod:`.dynamics`: mass and inertia, a firmware PI
speed loop on each wheel, traction-limited tyre forces so wheels slip when asked for more than
friction gives) and samples sensors from that state at their own clocks (:mod:`.sensors`),
with errors the estimator has no state for (:mod:`.sensor_model`): speed-dependent effective
wheel radius, a wrong wheel distance, gyro scale, cross-axis and g-sensitivity, temperature-
driven bias drift, vibration while driving, IMU mount tilt, encoder quantisation, dead encoder
feeds, lost frames, stamp latency and jitter, clock errors. Missions: :mod:`.mission`.

Quick use::

    from fusion.evaluation.physics_sim import physics_scenario
    run = physics_scenario("all", seed=3)          # 300 s, every error on
    run.imu_t, run.gyro, run.wheel_t, run.ticks     # what the robot logs
    run.truth_at(run.wheel_t)                      # true x, y, yaw there
"""

from fusion.evaluation.physics_sim.body import BodyParams, ControllerParams
from fusion.evaluation.physics_sim.dynamics import PHYSICS_RATE, BodyTrace, simulate_body
from fusion.evaluation.physics_sim.mission import (
    Mission,
    Segment,
    circle_mission,
    indoor_mission,
)
from fusion.evaluation.physics_sim.run import (
    SCENARIOS,
    PhysicsRun,
    driving_window,
    physics_scenario,
    simulate_physics,
)
from fusion.evaluation.physics_sim.sensor_model import (
    ERROR_GROUPS,
    SensorModel,
    all_errors,
    plain_sensors,
    with_errors,
)

__all__ = [
    "ERROR_GROUPS",
    "PHYSICS_RATE",
    "SCENARIOS",
    "BodyParams",
    "BodyTrace",
    "ControllerParams",
    "Mission",
    "PhysicsRun",
    "Segment",
    "SensorModel",
    "all_errors",
    "circle_mission",
    "driving_window",
    "indoor_mission",
    "physics_scenario",
    "plain_sensors",
    "simulate_body",
    "simulate_physics",
    "with_errors",
]
