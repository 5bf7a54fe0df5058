"""One fusion pipeline for live data and replay: sources -> Keel -> planar EKF -> sinks.

Data flow (one :class:`FusionPipeline` object; only the sources differ between live and
replay)::

    ImuSample (IMU frame) --mount rotation--> Keel (attitude) --heading rate----\
                wheels: v*w, dv/dt, stillness --^                                 ReorderBuffer
    WheelTicks (DATA-uart2 frame, ticks per period) ----------------------------/      |
                                                           PlanarEKF <-----------------+
                                                               |
                                      FusedOdometry records -> sinks (fusion.sinks)

The attitude filter is Keel (:class:`fusion.attitude.keel.Keel`) unless ``robot.toml``'s
``[attitude]`` table (:class:`fusion.planar.robot.AttitudeConfig`) chooses the Mahony port or
the constructor is given a configured filter (``attitude=``). Keel is told what the wheels
know (:meth:`FusionPipeline._wheel_knowledge`): the centripetal acceleration ``v*w`` and the
forward acceleration dv/dt of the newest wheel frame (or twist) that arrived before the IMU
sample, removed from the accelerometer (without them Keel leans into sustained turns and
after starts and stops), and stillness (wheels stopped and the IMU quiet: the gyro bias is
refined; wheels turning: no rest, even in a slow steady turn that an IMU alone cannot tell
from bias). A wheel frame or twist older than ``gap_periods`` wheel periods tells nothing.

Event-time model, stated once:

- Every input is a time-stamped event on one host clock (s): :class:`fusion.types.samples.ImuSample`
  (the sample instant) or :class:`fusion.types.samples.WheelTicks` (the end of the firmware period,
  as stamped by :class:`drivers.serial_link.ChassisLink`), or an external odometry twist
  (:meth:`FusionPipeline.push_twist`: a ROS bag's nav_msgs/Odometry, at its stamp). Callers
  push events in *arrival* order, which for a replay is host time order (:func:`merge_by_time`).
- IMU samples go through the attitude filter on arrival (they must increase in time; a sample
  that does not is dropped and counted), which gives the attitude and the heading rate (the
  rate of the ZYX yaw that the pose integrates: the rate about the world vertical,
  :func:`fusion.geometry.mount.vertical_rate`, plus ``roll_dot * sin(pitch)``,
  :meth:`FusionPipeline._roll_term`; tilt compensation). What the
  filter is told about the wheels depends only on the events that arrived before the sample,
  so replaying the same events in one call or one at a time gives the same attitude. The
  horizontal gyro bias learnt over the samples at which the robot stood still is taken off
  the gyro the attitude filter sees (:meth:`FusionPipeline._rest_gyro_bias`) and, projected
  by the estimated tilt, off the vertical rate (:meth:`FusionPipeline._bias_leak`), so the
  bias the EKF learns at a stop holds while driving; before the first stop a robot with
  odometry fuses its gyro's own z axis (no leak of the unknown x, y biases). With tilt
  compensation, each wheel frame or twist that is not a standstill reaches the EKF in the
  pose's own terms (:mod:`fusion.pipeline.heading_frame`): its speed times the mean
  ``cos(pitch)`` over its period (the wheels count along a slope, the pose moves on the
  horizontal), its yaw rate plus the mean difference between that heading rate and the
  gyro's z rate (the wheels turn about the surface normal).
- The EKF's own policy orders the inputs: each event is keyed by its *effective* time (a wheel
  frame's is ``stamp - encode_sampling_time/2 - wheel_latency``, the middle of its period; an
  IMU sample's and a twist's is its stamp) and held in a :class:`fusion.planar.ekf.ReorderBuffer`
  until it is ``reorder_window`` s older than the newest event, or earlier, as soon as every
  source has delivered an event at least as new (the *watermark*: each source is in time order, so
  nothing older can still come); what is released still late is handled by the EKF's
  late-input policy (fused at the filter time within ``late_tolerance``, else dropped and
  counted in :attr:`PipelineStats.late_dropped`). The default window,
  ``encode_sampling_time/2 + wheel_latency``, is exactly enough for host-ordered replay; live
  sources that deliver in batches (the MPU6050 FIFO) need their batch interval on top. The
  window only matters when a source stalls: with both sources flowing, the watermark releases
  a wheel frame as soon as the IMU samples up to the middle of its period are in.
- Output: with ``publish_rate_hz=None`` one record per wheel frame (or twist), stamped with
  the filter time after that frame (the middle of its period; a twist's stamp); with a rate,
  one record each time the filter time crosses a multiple of ``1/publish_rate_hz`` (seed
  000 publishes at 10 Hz).

Gaps and bad values: a wheel-frame interval longer than ``gap_periods`` periods is recorded
(:class:`WheelGap`, ``stats.gap_count``); the attitude filter's and the EKF's gap policies
(their module docstrings) bound the cost of any silence and the pose's extrapolation, counted
in ``stats.attitude_gaps`` and ``stats.speed_resets``; a non-finite or implausible value is
skipped by the attitude filter (its counters) and refused by the EKF (``stats.invalid``).

Determinism: nothing here reads a clock except to measure latency (``clock``), so replaying
the same events gives the same records bit for bit (tests/test_pipeline_golden.py).

Replay sources: :func:`logdir_events` (a log directory, ``datasets/LOGDIR.md``),
:func:`capture_events` (a DATA-uart2 capture through :func:`fusion.io.uart2.read_uart2_capture`,
stamped as the live link stamps), :func:`imu_csv_events`. Live sources are
:class:`drivers.serial_link.ChassisLink` and :class:`drivers.mpu6050.MPU6050` (see
``fusion/cli/run.py``).
"""

from __future__ import annotations

import collections
import logging
import math
import traceback
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from fusion.attitude.keel import Keel
from fusion.attitude.mahony import Mahony
from fusion.attitude.select import build_attitude_filter
from fusion.geometry import quaternion as quat
from fusion.geometry.kinematics import ticks_to_twist
from fusion.geometry.mount import imu_to_base, vertical_rate
from fusion.io.stamp_units import MAX_IMU_RATE_HZ, MIN_IMU_RATE_HZ
from fusion.pipeline import _event_core as ev_core
from fusion.pipeline.heading_frame import HeadingFrame
from fusion.pipeline.records import _fast_record, _record_fields
from fusion.planar import _ekf_core as core
from fusion.planar.accel_slip import AccelSlipDetector, AccelSlipParams
from fusion.planar.ekf import PlanarEKF
from fusion.planar.imu_motion import MOTION_STILL, ImuMotionDetector
from fusion.planar.robot import AttitudeConfig, RobotConfig
from fusion.types.fused import FusedOdometry
from fusion.types.lifecycle import Lifecycle
from fusion.types.samples import ImuSample, WheelTicks

__all__ = ["DROP_REASONS", "FusionPipeline", "PipelineStats", "SinkFailures", "WheelGap"]

_log = logging.getLogger("fusion.pipeline")

#: Why an input event was not fused (the keys of :meth:`FusionPipeline.ledger`'s
#: ``dropped``): too late for the EKF; a stamp not after its source's previous one; a stamp
#: that is NaN, infinite or, live, below 0 or ahead of the host clock by more than
#: ``max_stamp_lead``; a NaN or infinite value; a gyro sample at full scale (saturated: not
#: the rate); a gyro spike (a reading further from the predicted rate than any robot turns;
#: a glitch); a wheel frame or twist with zero speed while the IMU shows motion (an encoder
#: fault: flagged, not fused).
#: A gap drops no event: the EKF's gap policy forgets speeds (``speed_resets``), the attitude
#: filters count theirs (``attitude_gaps``), and every event after a gap is fused.
DROP_REASONS = ("late", "out_of_order", "invalid_stamp", "invalid_value", "gyro_saturated",
                "gyro_spike", "encoder_fault")


class SinkFailures(Exception):
    """Several sinks failed (writes or close); the message names each sink and its error,
    :attr:`errors` holds ``(sink, exception)`` pairs (each exception keeps its traceback)."""

    def __init__(self, errors: list[tuple[Any, BaseException]]) -> None:
        self.errors = errors
        super().__init__(f"{len(errors)} sink errors: " + "; ".join(
            f"{sink!r}: {type(exc).__name__}: {exc}" for sink, exc in errors))


_EV_GYRO = core.EV_GYRO
_EV_WHEELS = core.EV_WHEELS
_EV_TWIST = core.EV_TWIST
#: Watermark sources, in the order of :func:`fusion.pipeline._event_core.source_of`.
_SOURCES = ("imu", "wheels", "twist")
#: Kinds whose state rows :attr:`FusionPipeline.state_rows` can keep.
TRACE_KINDS = {"imu": _EV_GYRO, "wheels": _EV_WHEELS, "twist": _EV_TWIST}
#: Events per call of the compiled core in :meth:`FusionPipeline.push_arrays` (bounds the
#: memory of its outputs and sets how often ``on_progress`` is called).
BATCH_CHUNK = 1 << 16
#: Share of each interval of about one period by which the missing-frame count's period
#: estimate moves toward it (:meth:`FusionPipeline._count_missing`): 50 frames to follow a
#: board a few % off its nominal period.
PERIOD_PULL = 0.02


@dataclass(frozen=True)
class WheelGap:
    """Wheel frames missing between two received ones (a pulled cable, a dropped frame).

    Attributes:
        t_start, t_end: stamps of the frames on either side of the gap, s.
        missing: frames that should have arrived in between (``round(dt/T) - 1``).
    """

    t_start: float
    t_end: float
    missing: int


@dataclass
class PipelineStats:
    """Counters of a :class:`FusionPipeline` (monotonic).

    Attributes:
        events_in: events handed to the pipeline (every push, every row of push_arrays).
        imu_samples: IMU samples accepted (pushed in time order).
        imu_out_of_order: IMU samples dropped because their stamp did not increase.
        imu_invalid_stamp, wheel_invalid_stamp, twist_invalid_stamp: events dropped because
            their stamp was NaN, infinite or (with ``max_stamp_lead``) below 0 or ahead of the
            host clock by more than ``max_stamp_lead`` s.
        invalid_values: IMU samples and twists dropped for a NaN or infinite value.
        wheel_frames: wheel frames accepted.
        wheel_out_of_order: wheel frames dropped because their stamp did not increase.
        twist_messages: external odometry twists accepted (:meth:`FusionPipeline.push_twist`).
        twist_out_of_order: twists dropped because their stamp did not increase.
        records: records published.
        late_dropped, late_applied: inputs the EKF dropped as too late / fused at its own time.
        slips, zupts: wheel frames fused as slipping (yaw rate not fused; see the EKF's
            ``stats``); zero-velocity updates.
        accel_slips: of the slips, the wheel frames the accelerometer flagged
            (:mod:`fusion.planar.accel_slip`).
        wheel_rate_distrusted: turning wheel frames (or twists) whose yaw rate was not fused
            because most turns disagreed with the gyro (a skid-steer base, a wrong
            wheel_distance; :class:`fusion.planar.ekf.EkfNoise` ``max_slip_share``), or
            twists that disagreed before the external odometry was proven in turns.
        odometry_rate_slope, odometry_rate_correlation: the slope and correlation of the
            odometry's yaw rate against the gyro's over every moving frame (the EKF's
            ``odometry_rate_fit``; None until the gyro's rates spread): a slope far from 1 is
            an odometry that turns unlike the robot (a skid-steer base's).
        straight_frames: of the frames whose yaw rate was not trusted, those whose near-zero
            yaw rate was fused as driving straight (the EKF's ``straight_rate``: what teaches
            the gyro bias before the first stop when the odometry is a skid-steer's).
        wheel_scale_refits: times the EKF's wheel yaw-rate scale restarted at the slope of the
            wheel ticks' yaw rate fitted against the gyro's (opt-in, ``EkfNoise.
            wheel_scale_refit``: a skid-steer base or a wrong wheel_distance in robot.toml).
        encoder_faults: wheel frames (or twists) with zero speed while the IMU showed motion
            (or the stop would have been impossibly hard): flagged and not fused.
        catch_ups: frames right after 1-3 encoder faults that carried their counts too (a
            read that came back empty, then one that caught up): fused as the periods they
            cover (the EKF's ``_catch_up``).
        fault_turn: rad, the EKF's yaw rate state (the gyro's, bias removed) integrated
            over those frames' intervals: the turn the odometry, dead, could not see (the
            EKF's ``fault_turn``;
            :mod:`fusion.evaluation.trust` leaves it out of the headings it compares).
        gyro_spikes: gyro samples further from the predicted rate than any robot turns (a
            glitch on the bus; not fused; the EKF's ``gyro_spikes``).
        bias_relearnt: stops at which the gyro bias was relearnt because every zero-velocity
            update of 0.5 s with the IMU still found the same yaw rate beyond the bias's
            variance (the bias had gone wrong while driving; the EKF's ``bias_relearnt``).
        gaps: wheel-frame gaps longer than ``gap_periods`` periods (bounded list, the newest).
        gap_count: gaps seen in total. frames_missing: wheel frames missing in all (each
            interval counts ``round(interval/period) - 1`` against the frames' own period,
            one under half a period -1: single lost frames too, not only those in gaps; a
            late frame followed by one right behind it counts none).
        accel_sum: m/s^2, the accelerometer's readings in the base frame (the configured
            mount applied) summed over the accepted IMU samples (x, y, z): divided by
            ``imu_samples``, the mean specific force, which points up when the mount is right
            (:mod:`fusion.evaluation.trust`'s ``mount`` check).
        gyro_turn: rad, the gyro's heading rate (as fused, bias included)
            integrated over the accepted IMU samples; gyro_time: s it spans (intervals longer
            than the EKF's ``max_extrapolation`` left out of both: gaps).
        wheel_turn: rad, the heading change of the wheel frames ((right - left) travel /
            wheel_distance); twist_turn: rad, the twists' yaw rate integrated (not over
            intervals longer than ``max_extrapolation``); both only where the IMU has samples
            (not before its first, nor in its gaps longer than ``max_extrapolation``: a 30 s
            IMU gap while turning had made heading_divergence fire on a good track).
        (The two turns let :mod:`fusion.evaluation.trust` see the sources disagree.)
        wheel_travel, twist_travel: m, signed, the wheel frames' and the twists' travel
            over the same frames (what a wheel radius mismatch turns the odometry by, ``c``
            rad/m; apart, as the turns, so that the sums do not depend on how the two
            sources interleave).
        attitude_gaps: IMU periods longer than the attitude filter's ``max_gap`` (integrated
            over one regular period, inclination re-initialised from the accelerometer).
        speed_resets: the EKF's speeds forgotten after ``max_extrapolation`` s without a
            measurement (its gap policy: the pose stops extrapolating).
        invalid: inputs the EKF refused as non-finite or implausible (a corrupt value).
    """

    events_in: int = 0
    imu_samples: int = 0
    imu_out_of_order: int = 0
    imu_invalid_stamp: int = 0
    wheel_invalid_stamp: int = 0
    twist_invalid_stamp: int = 0
    invalid_values: int = 0
    wheel_frames: int = 0
    wheel_out_of_order: int = 0
    twist_messages: int = 0
    twist_out_of_order: int = 0
    records: int = 0
    late_dropped: int = 0
    late_applied: int = 0
    slips: int = 0
    accel_slips: int = 0
    wheel_rate_distrusted: int = 0
    straight_frames: int = 0
    wheel_scale_refits: int = 0
    odometry_rate_slope: float | None = None
    odometry_rate_correlation: float | None = None
    zupts: int = 0
    encoder_faults: int = 0
    catch_ups: int = 0
    fault_turn: float = 0.0
    bias_relearnt: int = 0
    gyro_spikes: int = 0
    gap_count: int = 0
    frames_missing: int = 0
    accel_sum: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_turn: float = 0.0
    gyro_time: float = 0.0
    wheel_turn: float = 0.0
    twist_turn: float = 0.0
    wheel_travel: float = 0.0
    twist_travel: float = 0.0
    attitude_gaps: int = 0
    speed_resets: int = 0
    invalid: int = 0
    gaps: collections.deque = field(default_factory=lambda: collections.deque(maxlen=100))

    def as_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "gaps"}
        d["gaps"] = [g.__dict__ for g in self.gaps]
        return d


def _matrix_or_none(q: NDArray[np.float64]) -> list[list[float]] | None:
    R = quat.to_matrix(q)
    return None if np.array_equal(R, np.eye(3)) else R.tolist()


class FusionPipeline(Lifecycle):
    """Keel (or Mahony) attitude + planar EKF over time-stamped IMU and wheel events, into sinks.

    Args:
        robot: chassis geometry, frames (with the IMU mount rotation), EKF tuning and the
            attitude filter's choice (:class:`fusion.planar.robot.RobotConfig`, e.g. from
            :func:`fusion.io.robot_toml.read_robot_toml` or
            :func:`fusion.io.run_config.load_config`).
        sinks: :class:`fusion.sinks.base.Sink` objects; the pipeline opens them in
            :meth:`open` (or ``with``) and closes them in :meth:`close` (aborts them when the
            block raises, so file sinks leave no partial output).
        publish_rate_hz: None: one record per wheel frame or twist; else records at this rate of
            filter time (Hz).
        reorder_window: s an event is held for reordering at most (default: half a wheel
            period plus the EKF's ``wheel_latency``, enough for host-ordered replay; add the
            largest batch delay of live sources).
        sources: the sources whose watermark releases events early: ``"imu"``,
            ``"wheels"``, ``"twist"`` (default ``("imu", "wheels")``; give only the ones
            that will deliver, e.g. ``("wheels",)`` without an IMU or ``("imu", "twist")``
            for a ROS bag's odometry, else only the window releases).
        imu_rate_hz: nominal IMU rate, Hz (the attitude filter's first step), 4 .. 10,000.
        tilt: tilt-compensate the gyro with the filter's attitude from the first stop on
            (the horizontal gyro bias learnt at rest taken off, :meth:`_bias_leak`; before it
            the gyro's z axis if there is odometry); False: the gyro's z axis is the yaw rate,
            a level robot.
        attitude: a configured :class:`fusion.attitude.keel.Keel` or
            :class:`fusion.attitude.mahony.Mahony` (default: the one ``robot.attitude``
            describes, Keel with its defaults unless ``[attitude]`` says otherwise; giving both
            a filter and a non-default ``robot.attitude`` filter or parameters is refused).
            A Keel is told the wheels' knowledge unless ``robot.attitude.wheel_knowledge`` is
            False.
        mahony: the old name of ``attitude`` (deprecated; warns).
        clock: host clock (s) used only to measure latency from a wheel frame's stamp to its
            record; None disables latency measurement.
        gap_periods: a wheel-frame interval longer than this many periods is a gap.
        on_record: ``callback(record)`` after each record is written to the sinks.
        latency_window: latencies kept (the newest) for :meth:`latency_percentiles`.
        state_rows: event kinds (``"imu"``, ``"wheels"``, ``"twist"``) after which the EKF
            state is kept for :attr:`state_rows` (the replay CSV: after every IMU sample).
        on_progress: ``callback(t)`` with the filter's effective time (s) after each chunk of
            :data:`BATCH_CHUNK` events of :meth:`push_arrays` (progress bars).
        max_stamp_lead: with a ``clock``: an event stamped more than this many s after
            ``clock()``, or before 0, is dropped as an invalid stamp (a live stamp cannot be
            in the future, and no host clock reads below 0, nor can ROS time: a clock jump
            or a corrupt stamp); None (default) checks nothing.
        accel_slip: the accelerometer slip test (:mod:`fusion.planar.accel_slip`) on every
            wheel frame: True with :class:`AccelSlipParams`' noise figures and the EKF's
            ``tick_std`` and ``wheel_latency``, an :class:`AccelSlipParams`, or False
            (default: the gyro gate alone decides). Off by default: on the physics
            simulator it finds about a third of the slipping frames with no false alarm but
            changes no figure measurably (benchmarks/accel_slip.py), and on a slope of more
            than about one degree it would take the robot for slipping (see
            :meth:`_slip_detector`). It takes the base-frame specific force (the
            mount rotation applied; gravity leaking through a tilt is removed as the
            offset learnt at rest) and the yaw rate the EKF gets; a flagged frame goes to
            the EKF as a slip (``EV_WHEELS_SLIP``).
        on_sink_error: ``callback(sink, exception, traceback_text)`` when a sink's ``write``
            raises
            (default: an error on the ``fusion.pipeline`` logger). That sink is aborted (a
            file sink leaves the old file, or none) and gets no more records; the others go
            on; :meth:`close` raises its error at the end.

    Nothing is dropped silently: :meth:`ledger` accounts for every event handed in (fused,
    held for reordering, or dropped for one of :data:`DROP_REASONS`).

    One path for every input: :meth:`push` (and :meth:`push_imu`, :meth:`push_wheels`,
    :meth:`push_twist`) hand one event, :meth:`push_arrays` whole streams, to the same
    array code (order checks, mount rotation, the attitude filter's batch step, the heading
    rate, gap detection), and then to one compiled function,
    :func:`fusion.pipeline._event_core.run_events`, that orders, fuses and decides the
    records event by event. Both entry points therefore give the same records bit for bit.

    The pipeline is not thread safe: feed it from one thread (live sources put their events
    on a queue, see :mod:`fusion.pipeline.live`).
    """

    def __init__(
        self,
        robot: RobotConfig,
        sinks: Sequence[Any] = (),
        *,
        publish_rate_hz: float | None = None,
        reorder_window: float | None = None,
        sources: Sequence[str] = ("imu", "wheels"),
        imu_rate_hz: float = 100.0,
        tilt: bool = True,
        attitude: Keel | Mahony | None = None,
        mahony: Mahony | None = None,
        clock: Callable[[], float] | None = None,
        gap_periods: float = 2.5,
        on_record: Callable[[FusedOdometry], None] | None = None,
        latency_window: int = 100_000,
        state_rows: Sequence[str] = (),
        on_progress: Callable[[float], None] | None = None,
        max_stamp_lead: float | None = None,
        on_sink_error: Callable[[Any, BaseException, str], None] | None = None,
        accel_slip: AccelSlipParams | bool = False,
    ) -> None:
        if publish_rate_hz is not None and not (
            math.isfinite(publish_rate_hz) and publish_rate_hz > 0
        ):
            raise ValueError(f"publish_rate_hz must be > 0 Hz or None, got {publish_rate_hz!r}")
        if not (math.isfinite(imu_rate_hz) and MIN_IMU_RATE_HZ <= imu_rate_hz <= MAX_IMU_RATE_HZ):
            raise ValueError(f"imu_rate_hz must be {MIN_IMU_RATE_HZ} .. {MAX_IMU_RATE_HZ} Hz, "
                             f"got {imu_rate_hz!r}")
        if not (math.isfinite(gap_periods) and gap_periods > 1):
            raise ValueError(f"gap_periods must be finite and > 1, got {gap_periods!r}")
        if isinstance(latency_window, bool) or not (isinstance(latency_window, int)
                                                    and latency_window >= 1):
            raise ValueError(f"latency_window must be a whole number >= 1, got "
                             f"{latency_window!r}")
        if not isinstance(robot, RobotConfig):
            raise ValueError(f"robot must be a RobotConfig, got {type(robot).__name__}")
        self.robot = robot
        chassis = robot.chassis
        self.period = chassis.encode_sampling_time
        if reorder_window is None:
            reorder_window = 0.5 * self.period + robot.ekf.wheel_latency
        if not (math.isfinite(reorder_window) and reorder_window >= 0):
            raise ValueError(f"reorder_window must be >= 0 s, got {reorder_window!r}")
        self.reorder_window = float(reorder_window)
        bad = set(sources) - set(_SOURCES)
        if bad or not sources:
            raise ValueError(f"sources must be some of {list(_SOURCES)}, got {list(sources)}")
        bad = set(state_rows) - set(TRACE_KINDS)
        if bad:
            raise ValueError(f"state_rows must be some of {list(TRACE_KINDS)}, got "
                             f"{list(state_rows)}")
        if max_stamp_lead is not None and not max_stamp_lead >= 0:
            raise ValueError(f"max_stamp_lead must be >= 0 s or None, got {max_stamp_lead!r}")
        self.max_stamp_lead = max_stamp_lead
        self.sinks = list(sinks)
        self._active_sinks = list(self.sinks)  # minus those whose write failed
        #: sinks whose write failed: ``(sink, exception, records not written to it)``
        self.sink_failures: list[list[Any]] = []
        self._on_sink_error = on_sink_error
        self.publish_rate_hz = publish_rate_hz
        self.tilt = bool(tilt)
        self.ekf = PlanarEKF(chassis, robot.ekf)
        self.attitude = self._attitude_filter(robot.attitude, attitude, mahony, imu_rate_hz)
        self._knows_wheels = robot.attitude.uses_wheels and isinstance(self.attitude, Keel)
        self._quiet = (0.0, 0.0, 0.0)
        if self._knows_wheels:
            par = self.attitude.params
            self._quiet = (par.bias_clip + par.rest_gyro_threshold, par.gravity,
                           par.rest_accel_threshold)
        # the newest motion known from the wheels (or twists): stamp s, v m/s, w rad/s,
        # forward acceleration m/s^2; and each source's last (stamp, v) for the acceleration
        self._known_motion = (-math.inf, math.nan, math.nan, math.nan)
        self._last_speed = {"wheels": (-math.inf, 0.0), "twist": (-math.inf, 0.0)}
        # still / moving per IMU sample, for the EKF's ZUPT and encoder-fault decisions
        self._imu_motion = ImuMotionDetector(robot.imu_motion)
        # sums over the still IMU samples of the base x, y gyro rates (_rest_gyro_bias), and
        # their number
        self._rest_gyro_sum = (0.0, 0.0)
        # (stamp s, roll rad, sin(pitch)) of the previous IMU sample's attitude, and the sum
        # of sin(pitch) over the still samples (_roll_term)
        self._last_roll = (math.nan, math.nan, math.nan)
        self._rest_sin_pitch_sum = 0.0
        self._rest_count = 0
        self._slip = self._slip_detector(accel_slip)
        self._mount = _matrix_or_none(robot.imu_to_base())
        self._sched = ev_core.new_sched(*(name in sources for name in _SOURCES))
        self._heap_f = np.empty((256, 4))
        self._heap_i = np.empty((256, 3), dtype=np.int64)
        self._pub = np.empty((256, ev_core.PUB_WIDTH))  # output rows of one core call
        self._trace = np.empty((256 if state_rows else 0, ev_core.TRACE_WIDTH))
        self._rate = 0.0 if publish_rate_hz is None else float(publish_rate_hz)
        self._trace_mask = sum(1 << TRACE_KINDS[name] for name in set(state_rows))
        if "wheels" in state_rows:  # wheel frames flagged as slipping are wheel frames too
            self._trace_mask |= 1 << core.EV_WHEELS_SLIP
        self._trace_chunks: list[NDArray[np.float64]] = []
        self._clock = clock
        self._gap_periods = float(gap_periods)
        self._on_record = on_record
        self._on_progress = on_progress
        self.stats = PipelineStats()
        self.latencies: collections.deque[float] = collections.deque(maxlen=latency_window)
        self._last_imu_t = -math.inf
        self._first_imu_t = math.inf
        # spans with no IMU sample (a gap's start plus max_extrapolation, its end), in time
        # order: the odometry's turns there are not counted against the gyro's
        self._imu_gaps: tuple[list[float], list[float]] = ([], [])
        self._expects_imu = "imu" in sources
        self._last_wheel_t = -math.inf
        self._frame_period = self.period  # _count_missing: the frames' own period, s
        self._missing_sum = 0
        self._last_twist_t = -math.inf
        # payloads of accepted events by ref (per source): the IMU's (attitude, base-frame
        # gyro, accel) rows and the wheel frames' ticks, kept until superseded
        self._imu_rows = _RowStore()
        self._wheel_rows = _RowStore()
        self._n_twists = 0
        self._state = "new"
        self._m_per_s = chassis.speed_ratio / self.period
        self._m_per_turn = chassis.speed_ratio / chassis.wheel_distance  # rad per tick
        self._m_per_tick = chassis.speed_ratio
        self._wheel_shift = 0.5 * self.period  # a frame's effective time: stamp - this - latency
        # wheel frames and twists into the EKF's horizontal, heading-rate terms (tilt only)
        self._heading_frame = HeadingFrame(self.period, chassis.speed_ratio,
                                           chassis.wheel_distance)

    @staticmethod
    def _attitude_filter(config: AttitudeConfig, attitude: Keel | Mahony | None,
                         mahony: Mahony | None, imu_rate_hz: float) -> Keel | Mahony:
        """The attitude filter: ``attitude`` (or the old name ``mahony``) if given, else the
        one ``robot.attitude`` describes."""
        if mahony is not None:
            if attitude is not None:
                raise ValueError("give attitude= (mahony= is its old name), not both")
            warnings.warn("FusionPipeline(mahony=) is deprecated: pass attitude=",
                          DeprecationWarning, stacklevel=3)
            attitude = mahony
        if attitude is None:
            return build_attitude_filter(config.filter, config.params,
                                         sample_period=1.0 / imu_rate_hz)
        if not isinstance(attitude, (Keel, Mahony)):
            raise TypeError(f"attitude must be a Keel or a Mahony filter, got "
                            f"{type(attitude).__name__}")
        if (config.filter, config.params) != (AttitudeConfig.filter, AttitudeConfig.params):
            raise ValueError(f"robot.attitude chooses the {config.filter} filter "
                             f"{dict(config.params)} and attitude= passes a filter: give one")
        if config.wheel_knowledge and not isinstance(attitude, Keel):
            raise ValueError("robot.attitude.wheel_knowledge is a Keel input: the "
                             f"{type(attitude).__name__} filter cannot use it")
        return attitude

    def _slip_detector(self, accel_slip: AccelSlipParams | bool) -> AccelSlipDetector | None:
        """The accelerometer slip test the constructor's ``accel_slip`` asks for.

        It is fed the specific force as measured, not with gravity removed by the attitude
        filter: Keel is told the wheels' dv/dt and v*w, so during a slip its attitude leans
        toward what the wheels claim and the gravity-free force follows them, hiding the
        slip (physics simulator, "all" runs of seeds 100-102: 0, 0 and 47 frames flagged
        where the force as measured gives 16, 16 and 73; and 2 false alarms on a "plain"
        run where this gives none). The price: on a slope the gravity leak differs from
        the one learnt at rest by about 0.17 m/s^2 per degree along the track; above
        about one degree the test takes that for a slip while the robot is on the slope.
        """
        if accel_slip is False:
            return None
        if accel_slip is True:
            noise = self.robot.ekf
            accel_slip = AccelSlipParams(tick_std=noise.tick_std,
                                         wheel_latency=noise.wheel_latency)
        if not isinstance(accel_slip, AccelSlipParams):
            raise ValueError(f"accel_slip must be True, False or an AccelSlipParams, got "
                             f"{accel_slip!r}")
        chassis = self.robot.chassis
        return AccelSlipDetector(chassis.speed_ratio, chassis.encode_sampling_time, accel_slip)

    # -- lifecycle (fusion.types.lifecycle.Lifecycle: open, close, abort, with) -------------
    def _reuse_error(self) -> Exception:
        return RuntimeError("the pipeline was already opened")

    def _open(self) -> None:
        """Open the sinks (a sink that fails to open aborts the ones already open)."""
        opened = []
        try:
            for sink in self.sinks:
                sink.open()
                opened.append(sink)
        except BaseException:
            for sink in opened:
                sink.abort()
            raise

    def _finish(self) -> None:
        """At close: fuse what the reorder buffer still holds and publish it."""
        self.flush()

    def _close(self) -> None:
        """Close every sink still working, then report every sink error: the write errors
        (sinks aborted on the way) and the close errors. One error is raised as itself;
        several as :class:`SinkFailures` naming each."""
        errors: list[tuple[Any, BaseException]] = [(sink, exc)
                                                    for sink, exc, _ in self.sink_failures]
        for sink in self._active_sinks:
            try:
                sink.close()
            except Exception as exc:  # close every sink, then report
                errors.append((sink, exc))
        if len(errors) == 1:
            sink, exc = errors[0]
            path = getattr(sink, "path", None)
            if isinstance(exc, OSError) and exc.errno and exc.filename is None and path:
                # a full disk's flush names no file: the user's output path is the one
                raise type(exc)(exc.errno, exc.strerror, str(path)) from exc
            raise exc
        if errors:
            raise SinkFailures(errors) from errors[0][1]

    def _abort(self) -> None:
        """Abort every sink (file sinks discard partial output)."""
        for sink in self.sinks:
            try:
                sink.abort()
            except Exception:  # aborting: report and keep going
                _log.error("aborting %r failed:\n%s", sink, traceback.format_exc())

    def _check_open(self) -> None:
        if self._state != "open":
            raise RuntimeError("the pipeline is not open: call open() or use 'with'")

    # -- inputs -----------------------------------------------------------------------------
    def push(self, event: ImuSample | WheelTicks) -> None:
        """Feed one event (in arrival order); records are published as they become due."""
        if type(event) is WheelTicks:
            self.push_wheels(event)
        elif type(event) is ImuSample:
            self.push_imu(event)
        else:
            raise TypeError(f"events are ImuSample or WheelTicks, got {type(event).__name__}")

    def push_imu(self, sample: ImuSample) -> None:
        """One IMU sample: gyro rad/s and specific force m/s^2 in the IMU frame, stamp s.

        Samples must increase in time: one that does not (or has a non-finite stamp) is
        dropped and counted in :attr:`PipelineStats.imu_out_of_order`."""
        self._check_open()
        self._ingest(imu_t=np.array([sample.t], dtype=np.float64),
                     gyro=np.asarray(sample.gyro, dtype=np.float64).reshape(1, 3),
                     accel=np.asarray(sample.accel, dtype=np.float64).reshape(1, 3))

    def push_wheels(self, frame: WheelTicks) -> None:
        """One DATA-uart2 frame: ticks counted in the period ending at ``frame.t`` (s).

        Frames must increase in time (else dropped and counted in
        :attr:`PipelineStats.wheel_out_of_order`); a longer interval than ``gap_periods``
        periods is recorded as a :class:`WheelGap`."""
        self._check_open()
        self._ingest(wheel_t=np.array([frame.t], dtype=np.float64),
                     ticks=np.array([[int(frame.left), int(frame.right)]], dtype=np.int64))

    def push_twist(self, t: float, v: float, w: float) -> None:
        """One external wheel-odometry twist, e.g. a nav_msgs/Odometry message of a ROS bag:
        forward speed ``v`` (m/s, base frame x) and yaw rate ``w`` (rad/s, about the base
        frame's z) at stamp ``t`` (s, host clock), fused at ``t`` by the EKF's twist update
        (:meth:`fusion.planar.ekf.PlanarEKF.update_twist`: noise ``twist_v_std``/``twist_w_std``,
        the wheel gate and ZUPT logic).

        Twists must increase in time (one that does not is dropped and counted in
        :attr:`PipelineStats.twist_out_of_order`); they go through the same reorder buffer
        as IMU samples and wheel frames, keyed by their stamp (their effective time), and the
        ``"twist"`` source's watermark. Without a publish rate, each twist gives one record
        (like a wheel frame); the record's wheel speeds stay those of the last wheel frame
        (None without one): a twist carries no wheel speeds.
        """
        self._check_open()
        self._ingest(twist_t=np.array([t], dtype=np.float64),
                     twist_v=np.array([v], dtype=np.float64),
                     twist_w=np.array([w], dtype=np.float64))

    def push_arrays(
        self,
        imu_t: NDArray[np.float64] | None = None,
        gyro: NDArray[np.float64] | None = None,
        accel: NDArray[np.float64] | None = None,
        wheel_t: NDArray[np.float64] | None = None,
        ticks: NDArray[np.int64] | None = None,
        twist_t: NDArray[np.float64] | None = None,
        twist_v: NDArray[np.float64] | None = None,
        twist_w: NDArray[np.float64] | None = None,
        *,
        flush: bool = True,
    ) -> None:
        """Whole recorded streams at once (replay of long logs), then :meth:`flush` unless
        ``flush=False``.

        The events arrive in host time order (at equal stamps IMU, then wheels, then twists):
        exactly equivalent to pushing ``merge_by_time(imu_samples, wheel_frames, twists)`` one
        event at a time with :meth:`push_imu`, :meth:`push_wheels` and :meth:`push_twist`, the
        same records bit for bit (the same code runs; tests/test_pipeline.py).

        Args:
            imu_t, gyro, accel: (N,) stamps s, (N, 3) rad/s and m/s^2 in the IMU frame.
            wheel_t, ticks: (M,) frame stamps s (end of period) and (M, 2) ticks per period.
            twist_t, twist_v, twist_w: (K,) external odometry twists (a nav_msgs/Odometry
                twist): stamps s, forward speed m/s, yaw rate rad/s (see :meth:`push_twist`).
            flush: fuse what the reorder buffer holds at the end (the end of a replay).
        """
        self._check_open()
        it = _floats(imu_t)
        n = it.size
        wt = _floats(wheel_t)
        tt = _floats(twist_t)
        tv, tw = _floats(twist_v), _floats(twist_w)
        if not tv.size == tw.size == tt.size:
            raise ValueError(f"{tt.size} twist stamps but {tv.size} v and {tw.size} w values")
        self._ingest(
            imu_t=it,
            gyro=np.asarray(gyro, dtype=np.float64).reshape(n, 3) if n else None,
            accel=np.asarray(accel, dtype=np.float64).reshape(n, 3) if n else None,
            wheel_t=wt,
            ticks=np.asarray(ticks).reshape(wt.size, 2).astype(np.int64) if wt.size else None,
            twist_t=tt,
            twist_v=tv,
            twist_w=tw,
            flush=flush,
        )

    def flush(self) -> None:
        """Fuse every held event now (end of a replay, or before a pause)."""
        self._ingest(flush=True)

    # -- the one path -----------------------------------------------------------------------
    def _ingest(self, imu_t=None, gyro=None, accel=None, wheel_t=None, ticks=None,
                twist_t=None, twist_v=None, twist_w=None, flush: bool = False) -> None:
        """Events of each source in their arrival order -> the compiled event core."""
        stats = self.stats
        limit, floor = math.inf, -math.inf
        if self._clock is not None and self.max_stamp_lead is not None:
            limit, floor = self._clock() + self.max_stamp_lead, 0.0
        parts = []  # (stamp, kind, t_eff, a, b, ref) per source with events
        # the other sources' accepted events first: the attitude filter is told what the
        # wheels (or twists) that arrived before each IMU sample knew
        if wheel_t is not None and wheel_t.size:
            stats.events_in += wheel_t.size
            bad, dropped, wheel_t, (ticks,) = _in_order(wheel_t, self._last_wheel_t,
                                                        (floor, limit), ticks)
            stats.wheel_invalid_stamp += bad
            stats.wheel_out_of_order += dropped
        if twist_t is not None and twist_t.size:
            stats.events_in += twist_t.size
            twist_t, (twist_v, twist_w) = self._finite_values(twist_t, twist_v, twist_w)
            bad, dropped, twist_t, (twist_v, twist_w) = _in_order(
                twist_t, self._last_twist_t, (floor, limit), twist_v, twist_w)
            stats.twist_invalid_stamp += bad
            stats.twist_out_of_order += dropped
        motion = self._motion(wheel_t, ticks, twist_t, twist_v, twist_w)
        slip_imu = None  # the IMU's part of the accelerometer slip test
        if imu_t is not None and imu_t.size:
            stats.events_in += imu_t.size
            imu_t, (gyro, accel) = self._finite_values(imu_t, gyro, accel)
            bad, dropped, imu_t, (gyro, accel) = _in_order(imu_t, self._last_imu_t,
                                                           (floor, limit), gyro, accel)
            stats.imu_invalid_stamp += bad
            stats.imu_out_of_order += dropped
            if imu_t.size:
                R = self._mount
                if R is not None:
                    gyro, accel = imu_to_base(R, gyro), imu_to_base(R, accel)
                imu_codes = self._imu_motion.update_batch(imu_t, gyro, accel)
                rest = self._rest_gyro_bias(imu_t, gyro, imu_codes, motion)
                q = self._attitude(imu_t, gyro - rest.bias, accel,
                                   motion if self._knows_wheels else None)
                if self.tilt:
                    rate = (vertical_rate(gyro, q) - self._bias_leak(rest, q)
                            + self._roll_term(imu_t, q, rest))
                    # before the first stop of a robot with odometry: the gyro's own z axis
                    # (_bias_leak says why); an element-wise choice, the same bits either way
                    rate = np.where(rest.odometry & (rest.count == 0), gyro[:, 2], rate)
                else:
                    rate = gyro[:, 2].copy()
                if self._slip is not None:
                    # the base-frame specific force as measured (see _slip_detector)
                    slip_imu = (imu_t, accel[:, 0], accel[:, 1], rate, imu_codes)
                dt = _steps(imu_t, self._last_imu_t, self.ekf.noise.max_extrapolation)
                self._note_imu_gaps(imu_t)
                stats.accel_sum = _add_up_columns(stats.accel_sum, accel)
                stats.gyro_turn = _add_up(stats.gyro_turn, rate * dt)
                stats.gyro_time = _add_up(stats.gyro_time, dt)
                self._last_imu_t = float(imu_t[-1])
                stats.imu_samples += imu_t.size
                ref0 = self._imu_rows.append(q, gyro, accel)
                if self.tilt:
                    self._heading_frame.add_imu(imu_t, q, rate - gyro[:, 2])
                parts.append((imu_t, _EV_GYRO, imu_t, rate, imu_codes,
                              np.arange(ref0, ref0 + imu_t.size)))
                if self.ekf.noise.accel_speed_psd > 0.0:
                    # the forward specific force drives the EKF's speed (EkfNoise), right
                    # after each gyro sample as fusion.planar.ekf.merge_events orders it
                    parts.append((imu_t, core.EV_ACCEL, imu_t, accel[:, 0].copy(),
                                  np.zeros(imu_t.size), np.arange(ref0, ref0 + imu_t.size)))
        if motion[0].size:
            self._known_motion = tuple(float(m[-1]) for m in motion)
        wheel_slip = self._slip_flags(slip_imu, wheel_t, ticks)
        if wheel_t is not None and wheel_t.size:
            self._note_gaps(wheel_t)
            self._last_wheel_t = float(wheel_t[-1])
            stats.wheel_frames += wheel_t.size
            # frames the EKF refuses as implausible (a corrupt frame: either wheel faster
            # than max_speed) are no turn: one frame of 100000 ticks had 'turned' the
            # odometry by -8498 deg and made heading_divergence call a good track untrustworthy
            covered = self._imu_covers(wheel_t) & (
                np.max(np.abs(ticks), axis=1) * self._m_per_s
                <= self.ekf.noise.max_speed)
            stats.wheel_turn = _add_up(stats.wheel_turn, np.where(
                covered, (ticks[:, 1] - ticks[:, 0]) * self._m_per_turn, 0.0))
            stats.wheel_travel = _add_up(stats.wheel_travel, np.where(
                covered, 0.5 * (ticks[:, 1] + ticks[:, 0]) * self._m_per_tick, 0.0))
            ref0 = self._wheel_rows.append(ticks)
            t_eff = wheel_t - self._wheel_shift - self.ekf.noise.wheel_latency
            kind = _EV_WHEELS if wheel_slip is None else np.where(
                wheel_slip, core.EV_WHEELS_SLIP, _EV_WHEELS)
            left, right = self._heading_frame.ticks(wheel_t, ticks)
            parts.append((wheel_t, kind, t_eff, left, right,
                          np.arange(ref0, ref0 + wheel_t.size)))
        if twist_t is not None and twist_t.size:
            covered = self._imu_covers(twist_t) * _steps(
                twist_t, self._last_twist_t, self.ekf.noise.max_extrapolation)
            sane = ((np.abs(twist_v) <= self.ekf.noise.max_speed)
                    & (np.abs(twist_w) <= self.ekf.noise.max_rate))  # as the EKF's
            stats.twist_turn = _add_up(stats.twist_turn, np.where(sane, twist_w * covered, 0.0))
            stats.twist_travel = _add_up(stats.twist_travel,
                                         np.where(sane, twist_v * covered, 0.0))
            self._last_twist_t = float(twist_t[-1])
            stats.twist_messages += twist_t.size
            ref0 = self._n_twists
            self._n_twists += twist_t.size
            noise = self.ekf.noise
            twist_v, twist_w = self._heading_frame.twists(twist_t, twist_v, twist_w,
                                                          noise.twist_zero_v, noise.twist_zero_w)
            parts.append((twist_t, _EV_TWIST, twist_t, twist_v, twist_w,
                          np.arange(ref0, ref0 + twist_t.size)))
        self._heading_frame.forget_old()
        if not parts:
            if flush:
                self._run(*_NO_EVENTS, flush=True)
            return
        if len(parts) == 1:
            stamp, kind, t_eff, a, b, refs = parts[0]
            self._run(np.broadcast_to(kind, stamp.shape).astype(np.int64), t_eff, a, b, stamp,
                      refs, flush=flush)
            return
        # arrival order: host time, ties in source order (IMU, wheels, twist) as merge_by_time
        stamp = np.concatenate([p[0] for p in parts])
        order = np.argsort(stamp, kind="stable")
        kinds = np.concatenate([np.broadcast_to(p[1], p[0].shape).astype(np.int64)
                                for p in parts])
        self._run(kinds[order], *(np.concatenate([p[i] for p in parts])[order]
                                  for i in (2, 3, 4)),
                  stamp[order], np.concatenate([p[5] for p in parts])[order], flush=flush)

    def _slip_flags(self, imu, wheel_t, ticks) -> NDArray[np.bool_] | None:
        """The accelerometer slip test over one call's accepted IMU samples (``imu``:
        stamps, specific force x, y, yaw rate, motion codes; or None) and wheel frames, in
        arrival order (at equal stamps the IMU sample first, as :meth:`_ingest` orders
        them); the wheel frames' flags, or None (no test or no frames)."""
        has_wheels = wheel_t is not None and wheel_t.size > 0
        if self._slip is None or (imu is None and not has_wheels):
            return None
        cols = [np.zeros(0, dtype=np.int64), *(np.zeros(0) for _ in range(5))]
        if imu is not None:
            cols = [np.zeros(imu[0].size, dtype=np.int64), *imu]
        if has_wheels:
            m = wheel_t.size
            zeros = np.zeros(m)
            wheel = [np.ones(m, dtype=np.int64), wheel_t, ticks[:, 0].astype(np.float64),
                     ticks[:, 1].astype(np.float64), zeros, zeros]
            cols = [np.concatenate([c, w]) for c, w in zip(cols, wheel)]
        order = np.argsort(cols[1], kind="stable")
        out = self._slip.update_batch(*(c[order] for c in cols))
        if not has_wheels:
            return None
        flags = np.empty(order.size, dtype=bool)
        flags[order] = out[:, 0] == 1.0
        return flags[flags.size - wheel_t.size:]

    def _finite_values(self, t: NDArray[np.float64], *cols: NDArray) -> tuple[NDArray, tuple]:
        """Drop (and count) the events with a NaN or infinite value in any column (they
        would poison the attitude filter or the EKF)."""
        ok = np.ones(t.size, dtype=bool)
        for c in cols:
            ok &= np.isfinite(c).reshape(t.size, -1).all(axis=1)
        if ok.all():
            return t, cols
        self.stats.invalid_values += int(t.size - ok.sum())
        return t[ok], tuple(c[ok] for c in cols)

    def _motion(self, wheel_t, ticks, twist_t, twist_v, twist_w):
        """``(stamp, v, w, a)`` arrays of the accepted wheel frames and twists of one call in
        arrival order (at equal stamps wheels first). A frame's v (m/s) and w (rad/s) are its
        ticks over its period with the nominal geometry; ``a`` (m/s^2) is the change of v
        from the source's previous event over the wheel period (a twist: over the stamp
        difference), 0 after a gap longer than ``gap_periods`` periods or for the first
        event."""
        streams = []
        if wheel_t is not None and wheel_t.size:
            v, w = ticks_to_twist(ticks[:, 0], ticks[:, 1], self.robot.chassis)
            streams.append((wheel_t, v, w, self._forward_accel("wheels", wheel_t, v)))
        if twist_t is not None and twist_t.size:
            streams.append((twist_t, twist_v, twist_w,
                            self._forward_accel("twist", twist_t, twist_v)))
        if len(streams) < 2:
            return streams[0] if streams else _NO_MOTION
        stamp = np.concatenate([streams[0][0], streams[1][0]])
        order = np.argsort(stamp, kind="stable")
        return tuple(np.concatenate([streams[0][i], streams[1][i]])[order] for i in range(4))

    def _forward_accel(self, source: str, t: NDArray[np.float64],
                       v: NDArray[np.float64]) -> NDArray[np.float64]:
        """dv/dt (m/s^2) of one source's accepted events (see :meth:`_motion`); remembers
        the last (stamp, v)."""
        t_prev, v_prev = self._last_speed[source]
        self._last_speed[source] = (float(t[-1]), float(v[-1]))
        tp = np.concatenate([[t_prev], t[:-1]])
        dv = v - np.concatenate([[v_prev], v[:-1]])
        dt = t - tp
        a = dv / self.period if source == "wheels" else dv / dt
        a[~(dt <= self._gap_periods * self.period)] = 0.0
        return a

    def _rest_gyro_bias(self, t, gyro, imu_codes, motion) -> _RestBias:
        """The horizontal gyro bias learnt at rest, per IMU sample (stamps ``t`` s, base-frame
        ``gyro`` rad/s): the mean of the base x and y rates over every sample so far (this one
        included) at which the robot stood still: the IMU still (:data:`MOTION_STILL`) and the
        newest wheel frame or twist at most ``gap_periods`` periods old with ``|v|`` and
        ``|w|`` at most ``EkfNoise.twist_zero_v`` and ``twist_zero_w`` (the EKF's own test of
        a twist at rest; a frame of a tick or two on a fine encoder may pass it too, which
        does no harm: creeping at a millimetre per second with the IMU quiet leaves the x, y
        rates and the tilt as at rest). 0 until the first stop; the mean never forgets (the
        x, y biases' warm-up drift is left to the attitude filter).

        It is taken off the gyro the attitude filter sees: an MPU6050's x and y biases are up
        to +-20 deg/s before calibration, far beyond what Keel's own bias estimate may reach
        (``bias_clip``, 2 deg/s), and the rest would tilt its attitude by degrees (with 15 and
        -10 deg/s the fused yaw RMSE on benchmarks/blackbox's "all" seed 101 was 107 deg).
        Stillness here needs the wheels, not the attitude, so the estimate comes first."""
        if t.size == 1 and not motion[0].size:
            still = self._still_one(float(t[0]), int(imu_codes[0]))
            sx, sy = self._rest_gyro_sum
            if still:
                gx, gy = gyro[0, :2].tolist()
                sx, sy = sx + gx, sy + gy
                self._rest_gyro_sum = (sx, sy)
                self._rest_count += 1
            c = self._rest_count
            bias = [[sx / c, sy / c, 0.0]] if c else [[0.0, 0.0, 0.0]]
            return _RestBias(np.array([still]), np.array([c]), np.array(bias),
                             np.array([self._known_motion[0] > -math.inf]))
        idx = np.searchsorted(motion[0], t, side="left") - 1
        inside = idx >= 0
        src_t, v, w = (np.where(inside, m[idx], last) if m.size else np.full(t.size, last)
                       for m, last in zip(motion[:3], self._known_motion[:3]))
        n = self.ekf.noise
        still = ((imu_codes == MOTION_STILL) & (t - src_t <= self._gap_periods * self.period)
                 & (np.abs(v) <= n.twist_zero_v) & (np.abs(w) <= n.twist_zero_w))
        # running sums in sample order (cumsum adds one row at a time, so one call with many
        # samples and many calls with one give the same bits); a non-still row adds nothing
        sums = np.cumsum(np.vstack([self._rest_gyro_sum,
                                    np.where(still[:, None], gyro[:, :2], 0.0)]), axis=0)[1:]
        count = self._rest_count + np.cumsum(still)
        self._rest_gyro_sum = tuple(sums[-1].tolist())
        self._rest_count = int(count[-1])
        means = np.zeros((t.size, 3))
        means[:, :2] = np.where(count[:, None] > 0, sums / np.maximum(count, 1)[:, None], 0.0)
        return _RestBias(still, count, means, src_t > -math.inf)

    def _still_one(self, t: float, code: int) -> bool:
        """:meth:`_rest_gyro_bias`'s stillness of one IMU sample with no wheel frame or twist
        in the same call, in scalars."""
        src_t, v, w, _ = self._known_motion
        n = self.ekf.noise
        return bool(code == MOTION_STILL and t - src_t <= self._gap_periods * self.period
                    and abs(v) <= n.twist_zero_v and abs(w) <= n.twist_zero_w)

    def _bias_leak(self, rest: _RestBias, q) -> NDArray[np.float64]:
        """(N,) rad/s to take off the rate about the vertical: the gyro's horizontal bias
        learnt at rest (:meth:`_rest_gyro_bias`) as the attitude ``q`` projects it,
        ``bx*r20 + by*r21`` with ``(r20, r21)`` the base x, y components of the world vertical
        (``q``'s third row). 0 until the first stop.

        Why: the projection ``R[2, :] @ gyro`` mixes the x and y rates into the vertical one
        by the estimated tilt, biases included, and that tilt is not the same at rest and
        while driving (vibration, lever arm, skid, an accelerometer bias: a degree or so;
        slopes: many): a bias of 1 deg/s and a 0.6 deg change leave 0.01 deg/s, about 2 deg of
        heading over 200 s of driving. Until the first stop the x, y biases are unknown, so
        a robot with odometry (wheel frames or twists) fuses its gyro's own z axis instead:
        no leak at all, and on a level floor with a small tilt the same rate within
        ``1 - cos(tilt)``. With the whole leak removed from then on, the rate at that first
        stop is the z bias as before it (times ``cos(tilt)``): the stop brings no step, and
        the heading the EKF corrects back to the start holds. Before (the vertical rate from
        the first sample, its leak held at its value at rest from the first stop on), the
        leak's change over the drive before the first stop fell on the heading: moving
        starts on benchmarks/blackbox 3.88 deg yaw RMSE (seeds 101-106 and 301-308; now
        3.58), on benchmarks/terrain's hills 6.47 (now 3.46). Without odometry (an IMU alone)
        there is no stop to learn from, and the vertical rate is kept."""
        if q.shape[0] == 1:
            # one sample: the same operations on Python floats (same bits, less overhead)
            if not rest.count[0]:
                return np.zeros(1)
            qw, qx, qy, qz = q[0].tolist()
            n2 = qw * qw + qx * qx + qy * qy + qz * qz
            u0 = 2.0 * (qx * qz - qw * qy) / n2
            u1 = 2.0 * (qy * qz + qw * qx) / n2
            bx, by = rest.bias[0, :2].tolist()
            return np.array([bx * u0 + by * u1])
        qw, qx, qy, qz = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        n2 = qw * qw + qx * qx + qy * qy + qz * qz
        up0 = 2.0 * (qx * qz - qw * qy) / n2
        up1 = 2.0 * (qy * qz + qw * qx) / n2
        leak = rest.bias[:, 0] * up0 + rest.bias[:, 1] * up1
        return np.where(rest.count > 0, leak, 0.0)

    def _roll_term(self, t: NDArray[np.float64], q: NDArray[np.float64],
                   rest: _RestBias) -> NDArray[np.float64]:
        """(N,) rad/s: ``roll_dot * (sin(pitch) - sin_pitch_rest)`` of the attitudes ``q`` at
        stamps ``t`` (s), from each sample's roll change since the previous sample, with
        ``sin_pitch_rest`` the mean of ``sin(pitch)`` over the samples at which the robot
        stood still (``rest``, :meth:`_rest_gyro_bias`); 0 until the first stop.

        Not before the first stop: until then the gyro's horizontal bias is unknown and the
        attitude unproven. From a moving start the attitude filter's first samples swing by
        degrees within milliseconds, and that swing, fed as a rate, became a gyro bias of
        9 deg/s and 72 deg of yaw RMSE (black-box simulator, moving start, seed 303).

        The heading (the ZYX yaw: the direction of the body x axis on the horizontal plane,
        what the pose integrates) changes at the rate about the world vertical plus
        ``roll_dot * sin(pitch)``. That term vanishes on a level floor and at a constant
        tilt, but not where roll and pitch change together (driving across hills: about
        1.5 deg RMS of heading over 300 s on 10-15 deg slopes, benchmarks/terrain).

        Taken from the attitude's roll change, not from the gyro rates
        (:func:`fusion.geometry.mount.heading_rate`, the same on exact inputs): its integral
        is bounded by the attitude's own error, where the rate formula turns a tilt error
        into a scale error of every turn. The pitch at rest is taken off, as the gyro bias's
        leak is (:meth:`_bias_leak`): on a level floor it is the IMU's unstated mount pitch,
        and ``roll_dot`` times it is only the attitude's roll noise times a constant, which
        the EKF took for a bias wandering against the wheels (the black-box simulator with a
        real MPU6050's horizontal biases, tests/test_blackbox_replay.py, seed 101: 2.8 deg
        yaw RMSE with the full term, 2.3 without any, 2.2 with this one). The mean at rest
        also holds the pitch of the slopes the robot stopped on: on hills the term keeps the
        pitch relative to the stops' average, and a robot that stopped only on a 12 deg ramp
        then rolls by 10 deg gets about 2 deg of heading offset from it (bounded, not a
        drift). One loop on Python floats for one sample or many: the same
        bits."""
        out = np.zeros(t.size)
        t_prev, roll_prev, s_prev = self._last_roll
        s_sum = self._rest_sin_pitch_sum
        for i, (ti, (qw, qx, qy, qz), still, count) in enumerate(
                zip(t.tolist(), q.tolist(), rest.still.tolist(), rest.count.tolist())):
            n2 = qw * qw + qx * qx + qy * qy + qz * qz
            r20 = 2.0 * (qx * qz - qw * qy) / n2
            r21 = 2.0 * (qy * qz + qw * qx) / n2
            r22 = 1.0 - 2.0 * (qx * qx + qy * qy) / n2
            roll, sin_pitch = math.atan2(r21, r22), -r20
            if not (math.isfinite(roll) and math.isfinite(sin_pitch)):
                continue  # no attitude: no term, and the previous one stays the reference
            if still:
                s_sum += sin_pitch
            dt = ti - t_prev
            if count and dt > 0.0:  # not before the first stop; dt NaN at the first sample
                d = math.remainder(roll - roll_prev, 2.0 * math.pi)  # through +-180 deg
                out[i] = d * (0.5 * (sin_pitch + s_prev) - s_sum / count) / dt
            t_prev, roll_prev, s_prev = ti, roll, sin_pitch
        self._last_roll = (t_prev, roll_prev, s_prev)
        self._rest_sin_pitch_sum = s_sum
        return out

    @property
    def horizontal_gyro_bias(self) -> tuple[float, float, int]:
        """``(bx, by, samples)``: the base-frame x and y gyro bias learnt at rest, rad/s
        (:meth:`_rest_gyro_bias`: taken off the gyro the attitude filter sees and, through
        the tilt projection, off the vertical rate, :meth:`_bias_leak`; 0 before
        the first stop, and always without a wheel or twist source), and the number of
        still IMU samples it is the mean of."""
        if self._rest_count == 0:
            return 0.0, 0.0, 0
        bx, by = (s / self._rest_count for s in self._rest_gyro_sum)
        return bx, by, self._rest_count

    def _wheel_knowledge(self, t, gyro, accel, motion):
        """What the wheels tell the attitude filter at each IMU sample (stamps ``t`` s,
        base-frame ``gyro`` rad/s and ``accel`` m/s^2), from the newest wheel frame or twist
        that arrived before it (an IMU sample arrives before a wheel frame of the same stamp),
        if not older than ``gap_periods`` wheel periods:

        - known acceleration (N, 3), m/s^2, base frame: the forward acceleration dv/dt along x
          and the centripetal ``v*w`` along +y (to the left when turning left while driving
          forward), with ``w`` the gyro's rate about the base z axis, not the wheels' (a
          skid-steer base's odometry turns several times as fast as the robot: on the
          bundled Jackal bag the wheels' ``w`` tilted the attitude and leaked 6 deg out of
          the heading); the IMU's lever arm is left out (an IMU off the axle centre feels
          ``w^2 r`` more); NaN rows where nothing is known;
        - stillness (N,): 0 moving (v or w not zero), 1 known still (v = w = 0 and the IMU
          quiet: ``|gyro|`` below Keel's ``bias_clip + rest_gyro_threshold`` and ``|accel|``
          within ``rest_accel_threshold`` of gravity), NaN unknown (the filter's own rest
          detector decides).
        """
        idx = np.searchsorted(motion[0], t, side="left") - 1
        inside = idx >= 0
        src_t, v, w, a = (np.where(inside, m[idx], last) if m.size else np.full(t.size, last)
                          for m, last in zip(motion, self._known_motion))
        fresh = t - src_t <= self._gap_periods * self.period
        # the same operations as _knowledge_now, so one sample gets the same bits either way
        v = np.where(fresh, v, math.nan)
        w = np.where(fresh, w, math.nan)
        known = np.zeros((t.size, 3))
        known[:, 0] = a
        known[:, 1] = v * gyro[:, 2]
        known[~fresh] = math.nan
        gyro_max, gravity, accel_tol = self._quiet
        gx, gy, gz = gyro[:, 0], gyro[:, 1], gyro[:, 2]
        ax, ay, az = accel[:, 0], accel[:, 1], accel[:, 2]
        quiet = ((gx * gx + gy * gy + gz * gz < gyro_max * gyro_max)
                 & (np.abs(np.sqrt(ax * ax + ay * ay + az * az) - gravity) < accel_tol))
        moving = (v != 0.0) | (w != 0.0)
        still = np.where(moving, 0.0, np.where(quiet, 1.0, math.nan))
        still[~fresh] = math.nan
        return still, known

    def _knowledge_now(self, t: float, gyro: NDArray[np.float64], accel: NDArray[np.float64]):
        """:meth:`_wheel_knowledge` of one IMU sample with no wheel frame or twist in the same
        call (the streaming case), in scalars: ``(still, known_accel)`` as
        :meth:`fusion.attitude.keel.Keel.update` takes them."""
        src_t, v, w, a = self._known_motion
        if not t - src_t <= self._gap_periods * self.period:
            return None, None
        if v != 0.0 or w != 0.0:
            still = False
        else:
            gyro_max, gravity, accel_tol = self._quiet
            gx, gy, gz = gyro.tolist()
            ax, ay, az = accel.tolist()
            still = ((gx * gx + gy * gy + gz * gz < gyro_max * gyro_max)
                     and abs(math.sqrt(ax * ax + ay * ay + az * az) - gravity) < accel_tol)
            still = True if still else None
        return still, np.array([a, v * float(gyro[2]), 0.0])

    def _attitude(self, t: NDArray[np.float64], gyro: NDArray[np.float64],
                  accel: NDArray[np.float64], motion) -> NDArray[np.float64]:
        """(N, 4) attitudes after each sample. One sample goes through the filter's streaming
        call, which costs a fraction of a batch call's set-up; both run the same compiled step
        and give the same bits (the attitude filters' contract, tests/test_mahony.py,
        tests/test_keel.py), with the same wheel knowledge (:meth:`_wheel_knowledge`, computed
        from the events that arrived before each sample in both paths)."""
        f = self.attitude
        if motion is None:
            if t.size == 1:
                return f.update(gyro[0], accel[0], timestamp=float(t[0]))[None, :]
            return f.update_batch(gyro, accel, timestamps=t)
        if t.size == 1 and not motion[0].size:
            still, known = self._knowledge_now(float(t[0]), gyro[0], accel[0])
            return f.update(gyro[0], accel[0], timestamp=float(t[0]), still=still,
                            known_accel=known)[None, :]
        still, known = self._wheel_knowledge(t, gyro, accel, motion)
        if t.size == 1:
            s = still[0]
            return f.update(gyro[0], accel[0], timestamp=float(t[0]),
                            still=None if s != s else bool(s), known_accel=known[0])[None, :]
        return f.update_batch(gyro, accel, timestamps=t, still=still, known_accel=known)

    def _note_imu_gaps(self, imu_t: NDArray[np.float64]) -> None:
        """Record the IMU's first stamp and the spans of its gaps longer than the EKF's
        ``max_extrapolation`` (before the samples ``imu_t``, not yet the last seen), each
        from the gap's start plus that to its end: :meth:`_imu_covers`."""
        longest = self.ekf.noise.max_extrapolation
        self._first_imu_t = min(self._first_imu_t, float(imu_t[0]))
        prev = np.concatenate([[self._last_imu_t], imu_t[:-1]])
        for i in np.flatnonzero(np.isfinite(prev) & (imu_t - prev > longest)).tolist():
            self._imu_gaps[0].append(float(prev[i]) + longest)
            self._imu_gaps[1].append(float(imu_t[i]))

    def _imu_covers(self, t: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which odometry stamps ``t`` (s) the IMU covers, so their turns count against the
        gyro's (``wheel_turn``, ``twist_turn``): from its first sample to ``max_extrapolation``
        after its last so far, outside its gaps; all of them in a run without an IMU. The
        same whether the IMU came before (a replay's batch) or is still to come (live: a
        stamp past the last sample by more than that is in a gap, or before the first)."""
        if not self._expects_imu:
            return np.ones(t.size, dtype=bool)
        covered = (t >= self._first_imu_t) & (
            t <= self._last_imu_t + self.ekf.noise.max_extrapolation)
        starts, ends = self._imu_gaps
        if starts:
            k = np.searchsorted(np.asarray(starts), t, side="right") - 1
            inside = (k >= 0) & (t < np.asarray(ends)[np.maximum(k, 0)])
            covered &= ~inside
        return covered

    def _note_gaps(self, wheel_t: NDArray[np.float64]) -> None:
        """Count the wheel frames missing (:meth:`_count_missing`) and record the gaps longer
        than ``gap_periods`` periods (the first frame has none)."""
        self._count_missing(wheel_t)
        prev = np.concatenate([[self._last_wheel_t], wheel_t[:-1]])
        dt = wheel_t - prev
        # before the first frame prev is -inf: dt is inf, nothing missing
        finite = np.isfinite(dt)
        limit = self._gap_periods * self.period
        for i in np.flatnonzero((dt > limit) & finite).tolist():
            missing = max(1, round(float(dt[i]) / self.period) - 1)
            self.stats.gaps.append(WheelGap(float(prev[i]), float(wheel_t[i]), missing))
            self.stats.gap_count += 1

    def _count_missing(self, wheel_t: NDArray[np.float64]) -> None:
        """Wheel frames missing so far: each interval counts ``round(dt/T) - 1`` frames,
        ``T`` the frames' own period (the configured one, followed by :data:`PERIOD_PULL`
        of each interval within 25 % of it: a board a few % off its nominal period), and an
        interval under half a period counts -1 (a frame that came late, or a backlog read in
        one burst, and the next that arrived right behind it: frames that all came). The
        total is never below 0. An independent probe's frames split in two writes 50 ms
        apart, none lost, had counted 80 missing; counting against a fixed grid instead had
        taken a board 3 % slow for 42 lost frames in 2000 (a review)."""
        period, missing = self._frame_period, self._missing_sum
        prev = self._last_wheel_t
        for t in wheel_t.tolist():
            if math.isfinite(prev):
                dt = t - prev
                r = dt / period
                missing += round(r) - 1
                if 0.75 <= r <= 1.25:
                    period += PERIOD_PULL * (dt - period)
            prev = t
        self._frame_period, self._missing_sum = period, missing
        self.stats.frames_missing = max(0, missing)

    def _run(self, kinds, t_eff, a, b, stamps, refs, flush: bool) -> None:
        """Feed arrival-ordered events to the compiled core in chunks and publish."""
        self._check_open()
        n = kinds.size
        step = BATCH_CHUNK
        start = 0
        while True:
            stop = min(start + step, n)
            last = stop >= n
            held = int(self._sched[ev_core.S_HEAP_N])
            room = held + (stop - start)
            if room > self._heap_f.shape[0]:
                size = max(room, 2 * self._heap_f.shape[0])
                self._heap_f = np.resize(self._heap_f, (size, 4))
                self._heap_i = np.resize(self._heap_i, (size, 3))
            if room > self._pub.shape[0]:
                self._pub = np.empty((room, ev_core.PUB_WIDTH))
                if self._trace_mask:
                    self._trace = np.empty((room, ev_core.TRACE_WIDTH))
            pub, trace = self._pub, self._trace
            ekf = self.ekf
            if not (type(ekf.x) is np.ndarray and ekf.x.flags.c_contiguous
                    and ekf.x.dtype == np.float64 and ekf.P.flags.c_contiguous):
                # a user may have set x or P through filterpy's API
                ekf.x = np.ascontiguousarray(ekf.x, dtype=np.float64).reshape(-1)
                ekf.P = np.ascontiguousarray(ekf.P, dtype=np.float64)
            n_pub, n_trace = ev_core.run_events(
                kinds[start:stop], t_eff[start:stop], a[start:stop], b[start:stop],
                stamps[start:stop], refs[start:stop], flush and last, self._heap_f,
                self._heap_i, self._sched, ekf.x, ekf.P, ekf._aux, ekf._par,
                self.reorder_window, self._rate, self._trace_mask, pub, trace)
            if n_trace:
                self._trace_chunks.append(trace[:n_trace].copy())
            if n_pub:
                self._publish_rows(pub[:n_pub])
            if self._on_progress is not None and stop > start:
                self._on_progress(float(t_eff[stop - 1]))
            start = stop
            if last:
                break
        # payloads older than the last applied ones are no longer needed
        self._imu_rows.prune(int(self._sched[ev_core.S_LAST_GYRO]))
        self._wheel_rows.prune(int(self._sched[ev_core.S_LAST_WHEEL]))

    # -- output -----------------------------------------------------------------------------
    def _publish_rows(self, pub: NDArray[np.float64]) -> None:
        sinks = self._active_sinks
        clock = self._clock
        on_record = self._on_record
        stats = self.stats
        for row in pub.tolist():
            rec = self._record(row)
            for sink in sinks:
                try:
                    sink.write(rec)
                except Exception as exc:
                    self._sink_failed(sink, exc)
                    sinks = self._active_sinks
            for failure in self.sink_failures:
                failure[2] += 1
            stats.records += 1
            stamp = row[ev_core.U_STAMP]
            if clock is not None and stamp == stamp:
                self.latencies.append(clock() - stamp)
            if on_record is not None:
                on_record(rec)

    @property
    def working_sinks(self) -> list[Any]:
        """The sinks still getting records (all but those whose write failed)."""
        return list(self._active_sinks)

    def _sink_failed(self, sink: Any, exc: BaseException) -> None:
        """A sink's write raised: report it with its traceback, abort that sink (a file
        sink keeps the old file), and publish to the others only."""
        text = traceback.format_exc()
        self._active_sinks = [s for s in self._active_sinks if s is not sink]
        self.sink_failures.append([sink, exc, 0])
        try:
            sink.abort()
        except Exception:
            text += f"\nand aborting it failed:\n{traceback.format_exc()}"
        if self._on_sink_error is not None:
            self._on_sink_error(sink, exc, text)
        else:
            _log.error("sink %r failed; it gets no more records:\n%s", sink, text)

    def _record(self, row: list[float]) -> FusedOdometry:
        gi = int(row[ev_core.U_LAST_GYRO])
        if gi >= 0:
            q, g, accel = self._imu_rows.get(gi)
            gyro_xy = (float(g[0]), float(g[1]))
        else:
            q = gyro_xy = accel = None
        wi = int(row[ev_core.U_LAST_WHEEL])
        if wi >= 0:
            (left, right), = self._wheel_rows.get(wi)
            speeds = (int(left) * self._m_per_s, int(right) * self._m_per_s)
        else:
            speeds = None
        t = row[ev_core.U_T]
        if t != t:  # no event has set the filter time yet
            t = 0.0
        x0 = ev_core.U_X
        p0 = ev_core.U_P
        return _fast_record(_record_fields(t, row[x0:x0 + 8], row[p0:p0 + 25], q, gyro_xy,
                                           accel, speeds, self.robot.odom_frame,
                                           self.robot.base_frame, int(row[ev_core.U_FLAGS])))

    def current_record(self) -> FusedOdometry:
        """The fused state now as a :class:`FusedOdometry` (frames from the config).

        ``angular_velocity`` is the last base-frame gyro sample's x and y with the EKF's
        yaw rate as z (so /odom's twist carries the fused rate); ``orientation`` the attitude
        filter's attitude of that sample; wheel speeds are the last frame's rim speeds (m/s).
        """
        ekf = self.ekf
        row = np.empty((1, ev_core.PUB_WIDTH))
        ev_core.write_pub_row(row, 0, np.asarray(ekf.x, dtype=np.float64),
                              np.asarray(ekf.P, dtype=np.float64), ekf._aux, self._sched,
                              math.nan, -1)
        return self._record(row[0].tolist())

    @property
    def state_rows(self) -> NDArray[np.float64]:
        """(N, TRACE_WIDTH) EKF state after each event of the ``state_rows`` kinds so far: the
        event's effective time (s), the state row of
        :meth:`fusion.planar.ekf.PlanarEKF.process_batch` (state with continuous yaw,
        diag(P), pose cross terms), the left and right ticks of the last wheel frame
        fused (NaN before the first) and the EKF's flags of the last wheel frame or twist
        (bits 1 ZUPT, 2 slip, 4 encoder fault); column indices
        :data:`fusion.pipeline._event_core.T_LEFT`, ``T_RIGHT``, ``T_FLAGS``."""
        if not self._trace_chunks:
            return np.zeros((0, ev_core.TRACE_WIDTH))
        if len(self._trace_chunks) > 1:
            self._trace_chunks = [np.concatenate(self._trace_chunks)]
        return self._trace_chunks[0]

    def finish_stats(self) -> PipelineStats:
        """The counters, with the EKF's (late, slip, ZUPT, speed reset, invalid) and the
        attitude filter's (gaps) counters copied in."""
        s = self.ekf.stats
        self.stats.late_dropped = s["late_dropped"]
        self.stats.late_applied = s["late_applied"]
        self.stats.slips = s["slips"]
        self.stats.accel_slips = s["accel_slips"]
        self.stats.wheel_rate_distrusted = s["wheel_rate_distrusted"]
        self.stats.straight_frames = s["straight_frames"]
        self.stats.wheel_scale_refits = s["wheel_scale_refits"]
        fit = self.ekf.odometry_rate_fit
        if fit is not None:
            self.stats.odometry_rate_slope = fit[1]
            # None (JSON null), not NaN, while the odometry's rate has not varied
            self.stats.odometry_rate_correlation = None if math.isnan(fit[2]) else fit[2]
        self.stats.zupts = s["zupts"]
        self.stats.encoder_faults = s["encoder_faults"]
        self.stats.catch_ups = s["catch_ups"]
        self.stats.fault_turn = s["fault_turn"]
        self.stats.bias_relearnt = s["bias_relearnt"]
        self.stats.gyro_spikes = s["gyro_spikes"]
        self.stats.speed_resets = s["speed_resets"]
        self.stats.invalid = s["invalid"]
        self.stats.attitude_gaps = self.attitude.counters.gaps
        return self.stats

    def ledger(self) -> dict[str, Any]:
        """Where every event handed in went: ``{"in", "fused", "held", "dropped":
        {reason: n}, "unaccounted"}``. ``held`` waits in the reorder buffer (0 after
        :meth:`flush` or :meth:`close`); ``dropped`` counts each of :data:`DROP_REASONS`;
        ``fused`` is what the EKF applied (its own count of updates; IMU samples also went
        through the attitude filter); ``unaccounted = in - fused - held - sum(dropped)`` is
        0 unless a count is missing (tests/test_live_faults.py)."""
        s = self.stats
        e = self.ekf.stats
        dropped = {
            "late": e["late_dropped"],
            "out_of_order": s.imu_out_of_order + s.wheel_out_of_order + s.twist_out_of_order,
            "invalid_stamp": s.imu_invalid_stamp + s.wheel_invalid_stamp
            + s.twist_invalid_stamp,
            "invalid_value": s.invalid_values + e["invalid"],
            "gyro_saturated": e["gyro_saturated"],
            "gyro_spike": e["gyro_spikes"],
            # zero ticks while the IMU shows motion: flagged, not fused (the pose coasts)
            "encoder_fault": e["encoder_faults"],
        }
        held = int(self._sched[ev_core.S_HEAP_N])
        fused = e["updates"]  # counted by the EKF core itself, independently of the above
        unaccounted = s.events_in - fused - held - sum(dropped.values())
        return {"in": s.events_in, "fused": fused, "held": held, "dropped": dropped,
                "unaccounted": unaccounted}

    def latency_percentiles(self, *qs: float) -> list[float]:
        """Percentiles (0..100) of the measured wheel-frame -> record latencies, s (NaN if
        none were measured)."""
        if not self.latencies:
            return [math.nan for _ in qs]
        a = np.fromiter(self.latencies, dtype=float)
        return [float(v) for v in np.percentile(a, qs)]


_NO_MOTION = (np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))


class _RestBias(NamedTuple):
    """Per IMU sample of one call: stood still (bool), still samples so far (int), the
    horizontal gyro bias learnt at rest (N, 3), rad/s, base frame (z 0), and whether a wheel
    frame or twist arrived before it (bool)."""

    still: NDArray[np.bool_]
    count: NDArray[np.int64]
    bias: NDArray[np.float64]
    odometry: NDArray[np.bool_]
_NO_EVENTS = (np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0),
              np.zeros(0, dtype=np.int64))


class _RowStore:
    """Rows of per-event payload arrays addressed by a running index (``ref``), appended in
    chunks and dropped once superseded."""

    def __init__(self) -> None:
        self._chunks: collections.deque = collections.deque()  # (first ref, arrays)
        self._next = 0

    def append(self, *arrays: NDArray) -> int:
        """Store rows (equal length); returns the ref of the first."""
        first = self._next
        self._chunks.append((first, arrays))
        self._next += arrays[0].shape[0]
        return first

    def get(self, ref: int) -> tuple:
        for first, arrays in reversed(self._chunks):
            if ref >= first:
                return tuple(a[ref - first] for a in arrays)
        raise KeyError(ref)

    def prune(self, keep_from: int) -> None:
        """Drop the chunks whose rows are all older than ``keep_from``."""
        chunks = self._chunks
        while len(chunks) > 1 and chunks[1][0] <= keep_from:
            chunks.popleft()


def _floats(values) -> NDArray[np.float64]:
    """``values`` as a 1-D float64 array (None: empty)."""
    return np.zeros(0) if values is None else np.asarray(values, dtype=np.float64).reshape(-1)


def _steps(t: NDArray[np.float64], last: float, longest: float) -> NDArray[np.float64]:
    """Intervals before each stamp of ``t`` (s), the first from ``last`` (0 when ``last`` is
    -inf: the first event of a source has no interval), and 0 for an interval longer than
    ``longest`` s: a gap, over which a rate says nothing (the EKF forgets its speeds after
    ``max_extrapolation``; a rate times a 20 s gap was a turn of hundreds of degrees in the
    turn counters)."""
    dt = np.diff(t, prepend=last if math.isfinite(last) else t[0])
    return np.where(dt > longest, 0.0, dt)


def _add_up(total: float, values: NDArray[np.float64]) -> float:
    """``total`` plus ``values`` added one at a time, left to right (a cumulative sum, not
    numpy's pairwise one): the same bits whether the events come one by one or in a batch."""
    return float(np.cumsum(np.concatenate(([total], values)))[-1])


def _add_up_columns(totals: tuple[float, ...], rows: NDArray[np.float64]) -> tuple[float, ...]:
    """:func:`_add_up` of each column of ``rows`` (N, k) onto ``totals`` (k); one row on
    Python floats (the same bits, less overhead for a live sample)."""
    if rows.shape[0] == 1:
        return tuple(a + b for a, b in zip(totals, rows[0].tolist(), strict=True))
    return tuple(_add_up(a, rows[:, j]) for j, a in enumerate(totals))


def _in_order(t: NDArray[np.float64], last: float, bounds: tuple[float, float],
              *cols: NDArray) -> tuple[int, int, NDArray, tuple]:
    """``(invalid, out_of_order, t, cols)``: the events of one source that pushing them one
    at a time accepts (:func:`_increasing`), with their columns, and how many were dropped
    for an invalid stamp (NaN, infinite, outside ``bounds``: (first, last) s allowed) and for
    not increasing."""
    finite = np.isfinite(t) & (t >= bounds[0]) & (t <= bounds[1])
    keep = _increasing(t, last, finite)
    if keep.all():
        return 0, 0, t, cols
    invalid = int(t.size - finite.sum())
    return invalid, int(t.size - keep.sum()) - invalid, t[keep], tuple(c[keep] for c in cols)


def _increasing(t: NDArray[np.float64], last: float,
                finite: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Mask of the stamps accepted in arrival order: valid (``finite``) and greater than
    ``last`` and every earlier accepted one (what pushing them one at a time accepts)."""
    if t.size == 1:
        return finite & (t > last)
    prev = np.fmax.accumulate(np.concatenate([[last], np.where(finite, t, -np.inf)[:-1]]))
    return finite & (t > prev)
