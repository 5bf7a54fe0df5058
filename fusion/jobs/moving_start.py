"""A moving start in an offline replay: the gyro bias the robot's first stop teaches, taken
back to the start of the log.

A robot that drives off at once gives the EKF nothing that tells its gyro's bias until the
first stop: a skid-steer base in gentle arcs never reads as driving straight (its twist's
yaw rate overstates turns by its skid factor), so the heading drifts by the whole bias until
then (a terrain benchmark bag: 21 deg after a minute) and the stop's correction comes too
late for the track already driven. Live, nothing better can be done. A replay has the whole
log: when the first zero-velocity update comes more than :data:`MOVING_START_DELAY` after the
first row, :func:`first_stop` takes the bias over the first stop of at least
:data:`MIN_STOP` and its uncertainty, grown by the bias's random walk (``EkfNoise.bias_psd``)
over the time back to the start, and the log is fused again from a prior of that mean and
standard deviation (``EkfNoise.initial_bias``, ``initial_bias_std``;
:func:`fusion.jobs.replay.fuse_streams`). The bias is the gyro's reading over the stop (the
filter's rate plus bias), not the filter's bias state, which can lag there: on a terrain
bag with the twist stamped 0.2 s late, a 0.2 s pause before a turn in place let the turn's
start into the bias state (1 deg/s off), which the filter relearns only after a few of the
stop's ZUPTs (:func:`fusion.planar._ekf_core._relearn_bias_at_stop`); the readings over the
stop were within 0.01 deg/s of the on-time bag's throughout. :data:`MIN_STOP` and
:data:`STOP_EDGE` keep pauses and stop edges out.

A moving start that never stops for :data:`MIN_STOP` has no such stop: :func:`last_estimate`
takes the bias the filter ended with instead (learnt from straight driving; its variance
grown over the whole run). The terrain test bag's first 40 s with a +3 deg/s gyro bias
ended 7.3 m from the unbiased replay's end fused once, 0.04 m fused again (2026-11-29).

The wheels' yaw-rate calibration (``k``, ``c``: the EKF's ``wheel_rate_scale`` and
``wheel_rate_per_speed``) is taken from the first pass's end (:func:`wheel_prior`): it is
constant, and a whole run with its stops knows it best. Started from 0 instead, the radius
mismatch ``c`` (rad/m) soaks up the bias's error while the robot drives straight at a steady
speed (``c * v`` and the bias read alike on the wheels' yaw rate), so before the first stop
the straight driving taught the bias little: an independent simulator's moving start whose
gyro warmed up by 0.38 deg/s over the 82 s before its first stop (benchmarks/sim5 s7) kept the
bias within 0.07 deg/s of the stop's, 0.24 deg/s off the truth at 20 s, and reached the stop
13.5 deg off (with the prior: 0.10 deg/s, 8.8 deg; yaw RMSE 10.3 -> 8.6 deg;
tests/test_sim5_replay.py). Held out (2026-12-08, fresh seeds, yaw RMSE deg, before -> after):
sim5's moving starts, seeds 17-20, 4.99 3.08 8.79 4.14 -> 4.96 2.74 8.43 2.69 (its reference,
the gyro less its true bias: 4.76 3.08 6.33 1.38); the black-box simulator's, seeds 447-450,
3.61 2.57 4.27 2.80 -> 3.59 2.54 4.26 2.80; the terrain simulator's (seeds 70-71) hills and
level moving starts 2.50 2.79 2.31 3.47 -> 2.41 2.77 2.25 3.45, its skid-steer bags within
0.01 deg and 0.01 m of GPS RMSE (their twists' yaw rate is not fused, so nothing learns ``k``
or ``c``). Without the doubled variance (below): 8.2 deg on s7, 8.35 and 2.43 on s19 and s20,
the rest within 0.03. Nothing is carried where the calibration is beyond the trust checks'
limits, was not learnt, or comes with wheel scale refits (``EkfNoise.wheel_scale_refit``), nor
from a run that never stopped (its ``c`` and bias were learnt together), and the prior's
variance is twice the end's (the data is fused twice; review).

Measured on data none of this was chosen on (2026-11-28; yaw RMSE, deg, one pass -> two):
the independent black-box simulator's moving starts (benchmarks/blackbox), seeds 201-204,
4.86 5.45 5.16 1.59 -> 4.64 1.76 1.80 0.93 (bias error RMS 0.04-0.09 -> 0.007-0.019 deg/s);
the terrain simulator's bags (benchmarks/terrain: skid-steer, 30 Hz IMU, 10 Hz twists,
first full stop after 65-71 s), seeds 21-23, outdoor-bag 12.1 6.0 2.8 -> 1.3 2.7 1.9 and
hills-bag 13.4 6.7 3.1 -> 2.1 2.1 2.0, position RMSE against GPS (mean) 2.30 -> 1.50 and
2.37 -> 1.53 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.evaluation.trust import RADIUS_MISMATCH_LIMIT, WHEEL_SCALE_LIMIT

__all__ = ["LEARNT_SHARE", "MIN_STOP", "MOVING_START_DELAY", "STOP_EDGE", "STOP_MERGE_GAP",
           "MovingStart", "WheelPrior", "first_stop", "last_estimate", "wheel_prior"]

#: s: a first zero-velocity update later than this after the first row is a moving start (a
#: robot at rest gets its first within a few wheel frames).
MOVING_START_DELAY = 2.0
#: s: zero-velocity updates less than this apart belong to one stop.
STOP_MERGE_GAP = 1.0
#: s: the shortest stop whose bias is taken back (a pause of a few frames, e.g. before a turn
#: in place, teaches little and is where a late twist lets the turn's start in).
MIN_STOP = 1.0
#: A wheel calibration state whose standard deviation is still above this share of its
#: prior's was not learnt (:func:`wheel_prior`).
LEARNT_SHARE = 0.9
#: s: left out of the stop's readings at either end: where a twist stamped late still says
#: "still" while the robot has started moving, the gyro's first motion is in them.
STOP_EDGE = 0.5


@dataclass(frozen=True)
class WheelPrior:
    """The wheels' yaw-rate calibration a run ended with, as the prior of its second pass:
    ``k`` (1) and ``c`` (rad/m) with their standard deviations (``EkfNoise.wheel_rate_scale``,
    ``calib_k_std``, ``wheel_rate_per_speed``, ``calib_c_std``)."""

    k: float
    k_std: float
    c: float
    c_std: float

    def describe(self) -> str:
        return (f"the wheels' yaw-rate scale {self.k:+.4f} +- {self.k_std:.4f} and radius "
                f"mismatch {self.c:+.5f} +- {self.c_std:.5f} rad/m it ended with")


@dataclass(frozen=True)
class MovingStart:
    """A moving start and what its first stop tells: times in s on the log's clock, ``bias``
    and ``bias_std`` in rad/s (the prior for the start of the log); ``never_stopped``: the
    run has no stop, and the bias is the filter's at its end (:func:`last_estimate`; the
    "stop" is then the last row). ``prior``: rad/s, the bias the run was fused from first
    (``EkfNoise.initial_bias``); ``fused_again``: False where ``--one-pass`` kept that first
    pass (as a live run), whose start was then fused with the bias still being learnt."""

    start: float
    stop_begin: float
    stop_end: float
    bias: float
    bias_std: float
    never_stopped: bool = False
    prior: float = 0.0
    fused_again: bool = True
    wheels: WheelPrior | None = None

    @property
    def note(self) -> str:
        """One line for the user: what the replay did, and how to have it as live."""
        if not self.fused_again:
            where = ("the filter ended with" if self.never_stopped
                     else f"its first stop taught (after {self.stop_begin - self.start:.1f} s)")
            off = math.degrees(self.bias - self.prior)
            drive = self.stop_begin - self.start
            return (f"moving start fused once (--one-pass, as a live run): the gyro bias "
                    f"{where}, {math.degrees(self.bias):+.3f} +- "
                    f"{math.degrees(self.bias_std):.3f} deg/s, is {off:+.3f} deg/s off the "
                    f"prior the run started from; over {drive:.1f} s of driving that turns "
                    f"the heading by up to {abs(off) * drive:.0f} deg, less what the wheels "
                    "taught the filter on the way (without --one-pass the run is fused again "
                    "from that bias)")
        if self.never_stopped:
            return (f"moving start: the robot never stopped (for {MIN_STOP:g} s) in "
                    f"{self.stop_end - self.start:.1f} s; the gyro bias the filter ended with, "
                    f"{math.degrees(self.bias):+.3f} +- {math.degrees(self.bias_std):.3f} deg/s "
                    "(its random walk back to the start included), is the prior from the "
                    f"start {self._with_wheels}(a second pass; --one-pass fuses as a live run "
                    "would)")
        return (f"moving start: the robot drove {self.stop_begin - self.start:.1f} s before "
                f"its first stop; the gyro bias learnt there, "
                f"{math.degrees(self.bias):+.3f} +- {math.degrees(self.bias_std):.3f} deg/s "
                "(its random walk back to the start included), is the prior from the start "
                f"{self._with_wheels}(a second pass; --one-pass fuses as a live run would)")

    @property
    def _with_wheels(self) -> str:
        """The second pass's wheel prior, for the note ("" where it had none)."""
        return "" if self.wheels is None else f"with {self.wheels.describe()} "


def first_stop(t: NDArray[np.float64], rate: NDArray[np.float64], bias: NDArray[np.float64],
               bias_var: NDArray[np.float64], zupt: NDArray[np.bool_],
               bias_psd: float) -> MovingStart | None:
    """The moving start in a fused run's rows (``t`` s, the yaw rate and gyro bias states
    rad/s, the bias's variance (rad/s)^2, the zero-velocity-update flag), or None: the first
    row is a stop's (or comes within :data:`MOVING_START_DELAY` of one), or the run never
    stops for :data:`MIN_STOP` (updates less than :data:`STOP_MERGE_GAP` apart are one stop).

    The bias is what the gyro read over the first such stop, less :data:`STOP_EDGE` at either
    end: the median of rate + bias (the filter's gyro reading, in its scale; at rest the rate
    is 0, and where the filter's own bias is off and it takes the stop's readings for motion,
    the rate state carries the difference). Its variance: the filter's over the stop, the
    readings' spread over their number, and ``bias_psd`` ((rad/s)^2/s, the bias's random walk)
    over the time back to the start."""
    rows = np.flatnonzero(zupt)
    if rows.size == 0 or t[rows[0]] - t[0] <= MOVING_START_DELAY:
        return None
    apart = np.flatnonzero(np.diff(t[rows]) > STOP_MERGE_GAP)
    begins = rows[np.concatenate([[0], apart + 1])]
    ends = rows[np.concatenate([apart, [rows.size - 1]])]
    long_enough = np.flatnonzero(t[ends] - t[begins] >= MIN_STOP)
    if long_enough.size == 0:
        return None
    begin, end = begins[long_enough[0]], ends[long_enough[0]]
    inner = np.flatnonzero((t >= t[begin] + STOP_EDGE) & (t <= t[end] - STOP_EDGE))
    if inner.size == 0:  # rows sparser than the stop's interior: its middle one
        inner = np.array([(begin + end) // 2])
    reading = rate[inner] + bias[inner]
    mid = float(np.median(t[inner]))
    var = (float(np.median(bias_var[inner])) + float(np.var(reading)) / inner.size
           + bias_psd * (mid - float(t[0])))
    return MovingStart(start=float(t[0]), stop_begin=float(t[begin]), stop_end=float(t[end]),
                       bias=float(np.median(reading)), bias_std=math.sqrt(max(var, 0.0)))


def last_estimate(t: NDArray[np.float64], bias: NDArray[np.float64],
                  bias_var: NDArray[np.float64], zupt: NDArray[np.bool_],
                  bias_psd: float) -> MovingStart | None:
    """For a moving start that never stops for :data:`MIN_STOP` (where :func:`first_stop`
    finds nothing; pauses of a few frames do not count): the gyro bias the filter ended with
    (learnt from the wheels' straight driving and any pauses), its variance grown by
    ``bias_psd`` over the whole run back to the start, as a :class:`MovingStart`
    (``never_stopped``); None when the run starts at rest (a zero-velocity update within
    :data:`MOVING_START_DELAY` of its first row) or has fewer than 2 rows. A run that never stops
    gets the bias only once it has been driven: a 60 s drive with a +3 deg/s gyro bias was
    fused with its heading 180 deg off (9.6 m of GPS RMSE) while the filter ended at +3.25."""
    rows = np.flatnonzero(zupt)
    if t.size < 2 or (rows.size and t[rows[0]] - t[0] <= MOVING_START_DELAY):
        return None
    var = float(bias_var[-1]) + bias_psd * float(t[-1] - t[0])
    return MovingStart(start=float(t[0]), stop_begin=float(t[-1]), stop_end=float(t[-1]),
                       bias=float(bias[-1]), bias_std=math.sqrt(max(var, 0.0)),
                       never_stopped=True)


def wheel_prior(t: NDArray[np.float64], k: NDArray[np.float64], k_var: NDArray[np.float64],
                c: NDArray[np.float64], c_var: NDArray[np.float64], k_std: float,
                c_std: float, k_psd: float, c_psd: float) -> WheelPrior | None:
    """The wheels' yaw-rate scale ``k`` (1) and radius mismatch ``c`` (rad/m) of a fused run's
    last row (``t`` s; the states and their variances per row) as the prior of its second
    pass: each variance grown by its random walk (``k_psd`` 1/s, ``c_psd`` (rad/m)^2/s) over
    the run back to its start, then doubled (the second pass fuses the same data again: half
    the information is the prior's). None where it says nothing or is no calibration: not
    finite; ``|k|`` or ``|c|`` beyond the trust checks' limits
    (:data:`fusion.evaluation.trust.WHEEL_SCALE_LIMIT`, ``RADIUS_MISMATCH_LIMIT``: wheels
    and gyro in other units or geometry, a fault those checks name); or neither learnt
    (both standard deviations still above :data:`LEARNT_SHARE` of their priors ``k_std``
    and ``c_std``: odometry whose yaw rate was never fused). A state not learnt keeps its
    prior (``k_std`` or ``c_std``, the first row's mean), and a learnt one's standard
    deviation is at most its prior's (review)."""
    span = float(t[-1] - t[0])
    k_end, c_end = float(k[-1]), float(c[-1])
    k_var_end = float(k_var[-1]) + k_psd * span
    c_var_end = float(c_var[-1]) + c_psd * span
    if not (np.isfinite([k_end, c_end, k_var_end, c_var_end]).all() and k_var_end >= 0.0
            and c_var_end >= 0.0):
        return None
    if abs(k_end) > WHEEL_SCALE_LIMIT or abs(c_end) > RADIUS_MISMATCH_LIMIT:
        return None
    k_learnt = not k_var_end > (LEARNT_SHARE * k_std) ** 2
    c_learnt = not c_var_end > (LEARNT_SHARE * c_std) ** 2
    if not (k_learnt or c_learnt):
        return None
    # a state not learnt keeps the robot's own prior (its mean: the run's first row's); a
    # learnt one never gets looser than that prior
    return WheelPrior(k=k_end if k_learnt else float(k[0]),
                      k_std=min(math.sqrt(2.0 * k_var_end), k_std) if k_learnt else k_std,
                      c=c_end if c_learnt else float(c[0]),
                      c_std=min(math.sqrt(2.0 * c_var_end), c_std) if c_learnt else c_std)
