"""A gyro-scale calibration run on the physics simulator: turns in place back to a mark.

What a robot owner does once (:mod:`fusion.calibration.gyro_scale`): the robot rests on a
mark, turns in place a counted number of times, stops back on the mark and rests again. The
firmware only knows the nominal geometry, so a commanded spin does not land on the mark by
itself; the owner nudges it there, by eye. Here the spin's length is adjusted (by re-running
the deterministic physics) until the TRUE turn equals the declared turns plus the owner's
alignment error, drawn from ``mark_std``.
"""

from __future__ import annotations

import math

import numpy as np

from fusion.evaluation.physics_sim.body import BodyParams
from fusion.evaluation.physics_sim.dynamics import simulate_body
from fusion.evaluation.physics_sim.mission import Mission, Segment
from fusion.evaluation.physics_sim.run import PhysicsRun, simulate_physics
from fusion.evaluation.physics_sim.sensor_model import SensorModel

__all__ = ["gyro_calibration_run"]


def _turns_mission(rest: float, spin: float, rate: float) -> Mission:
    return Mission((Segment("stop", rest, 0.0, 0.0), Segment("spin", spin, 0.0, rate),
                    Segment("stop", rest, 0.0, 0.0)))


def gyro_calibration_run(
    sensors: SensorModel,
    seed: int = 0,
    turns: int = 10,
    rate: float = 1.0,
    rest: float = 5.0,
    mark_std: float = math.radians(1.0),
    body: BodyParams | None = None,
) -> tuple[PhysicsRun, float]:
    """Simulate ``turns`` full turns in place (signed: CCW positive) at ``rate`` rad/s with
    ``rest`` s at rest before and after.

    Returns:
        ``(run, alignment_error)``: the run, whose true yaw turned ``2*pi*turns +
        alignment_error`` (rad; the owner's error putting the robot back on the mark, drawn
        from ``N(0, mark_std)`` with ``rng([seed, 707])``).

    Raises:
        ValueError: ``turns`` not a non-zero whole number, ``rate`` not > 0.
    """
    if int(turns) != turns or turns == 0:
        raise ValueError(f"turns must be a non-zero whole number, got {turns!r}")
    if not rate > 0:
        raise ValueError(f"rate must be > 0 rad/s, got {rate!r}")
    alignment = float(np.random.default_rng([seed, 707]).normal(0.0, mark_std))
    target = 2.0 * math.pi * turns + alignment
    w = math.copysign(rate, turns)
    spin = abs(target) / rate
    for _ in range(6):  # the true turn is nearly linear in the spin's length
        trace = simulate_body(_turns_mission(rest, spin, w), body, None, sensors.radius_error,
                              sensors.radius_speed_coeff, sensors.separation_error)
        miss = target - trace.yaw[-1]
        if abs(miss) < 1e-5:
            break
        spin += miss / w
    run = simulate_physics(_turns_mission(rest, spin, w), sensors, seed, body=body)
    return run, float(run.truth[-1, 2] - 2.0 * math.pi * turns)
