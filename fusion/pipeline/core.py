"""One fusion pipeline for live data and replay: sources -> Mahony -> planar EKF -> sinks.

Data flow (one :class:`FusionPipeline` object; only the sources differ between live and
replay)::

    ImuSample (IMU frame) --mount rotation--> Mahony (attitude) --vertical rate--\
                                                                                  ReorderBuffer
    WheelTicks (DATA-uart2 frame, ticks per period) ----------------------------/      |
                                                           PlanarEKF <-----------------+
                                                               |
                                      FusedOdometry records -> sinks (fusion.sinks)

Event-time model, stated once:

- Every input is a time-stamped event on one host clock (s): :class:`fusion.types.samples.ImuSample`
  (the sample instant) or :class:`fusion.types.samples.WheelTicks` (the end of the firmware period,
  as stamped by :class:`drivers.serial_link.ChassisLink`), or an external odometry twist
  (:meth:`FusionPipeline.push_twist`: a ROS bag's nav_msgs/Odometry, at its stamp). Callers
  push events in *arrival* order, which for a replay is host time order (:func:`merge_by_time`).
- IMU samples go through the Mahony filter on arrival (they must increase in time; a sample
  that does not is dropped and counted), which gives the attitude and the yaw rate about the
  world vertical (:func:`fusion.planar.ekf.vertical_rate`, tilt compensation).
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
import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.attitude.mahony import Mahony
from fusion.geometry import quaternion as quat
from fusion.pipeline.records import _fast_record, _record_fields
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import PlanarEKF, ReorderBuffer
from fusion.planar.robot import RobotConfig
from fusion.types.fused import FusedOdometry
from fusion.types.samples import ImuSample, WheelTicks

__all__ = ["FusionPipeline", "PipelineStats", "WheelGap"]


_EV_GYRO = core.EV_GYRO


_EV_WHEELS = core.EV_WHEELS


_EV_TWIST = core.EV_TWIST


_SOURCES = ("imu", "wheels", "twist")


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
        imu_samples: IMU samples accepted (pushed in time order).
        imu_out_of_order: IMU samples dropped because their stamp did not increase.
        wheel_frames: wheel frames accepted.
        wheel_out_of_order: wheel frames dropped because their stamp did not increase.
        twist_messages: external odometry twists accepted (:meth:`FusionPipeline.push_twist`).
        twist_out_of_order: twists dropped because their stamp did not increase.
        records: records published.
        late_dropped, late_applied: inputs the EKF dropped as too late / fused at its own time.
        slips, zupts: wheel frames down-weighted as slip; zero-velocity updates.
        gaps: wheel-frame gaps longer than ``gap_periods`` periods (bounded list, the newest).
        gap_count: gaps seen in total; frames_missing: frames missing in them.
    """

    imu_samples: int = 0
    imu_out_of_order: int = 0
    wheel_frames: int = 0
    wheel_out_of_order: int = 0
    twist_messages: int = 0
    twist_out_of_order: int = 0
    records: int = 0
    late_dropped: int = 0
    late_applied: int = 0
    slips: int = 0
    zupts: int = 0
    gap_count: int = 0
    frames_missing: int = 0
    gaps: collections.deque = field(default_factory=lambda: collections.deque(maxlen=100))

    def as_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "gaps"}
        d["gaps"] = [g.__dict__ for g in self.gaps]
        return d


def _matrix_or_none(q: NDArray[np.float64]) -> list[list[float]] | None:
    R = quat.to_matrix(q)
    return None if np.array_equal(R, np.eye(3)) else R.tolist()


class FusionPipeline:
    """Mahony attitude + planar EKF over time-stamped IMU and wheel events, into sinks.

    Args:
        robot: chassis geometry, frames (with the IMU mount rotation) and EKF tuning
            (:class:`fusion.planar.robot.RobotConfig`, e.g. from
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
        imu_rate_hz: nominal IMU rate, Hz (the Mahony filter's first step).
        tilt: tilt-compensate the gyro with the Mahony attitude (False: the gyro's z axis is
            the yaw rate, a level robot).
        mahony: a configured :class:`fusion.attitude.mahony.Mahony` (default: the 6-axis preset).
        clock: host clock (s) used only to measure latency from a wheel frame's stamp to its
            record; None disables latency measurement.
        gap_periods: a wheel-frame interval longer than this many periods is a gap.
        on_record: ``callback(record)`` after each record is written to the sinks.
        latency_window: latencies kept (the newest) for :meth:`latency_percentiles`.

    The pipeline is not thread safe: feed it from one thread (live sources put their events
    on a queue, see ``fusion/cli/run.py``).
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
        mahony: Mahony | None = None,
        clock: Callable[[], float] | None = None,
        gap_periods: float = 2.5,
        on_record: Callable[[FusedOdometry], None] | None = None,
        latency_window: int = 100_000,
    ) -> None:
        if publish_rate_hz is not None and not (
            math.isfinite(publish_rate_hz) and publish_rate_hz > 0
        ):
            raise ValueError(f"publish_rate_hz must be > 0 Hz or None, got {publish_rate_hz!r}")
        if not (math.isfinite(imu_rate_hz) and imu_rate_hz > 0):
            raise ValueError(f"imu_rate_hz must be > 0 Hz, got {imu_rate_hz!r}")
        if not gap_periods > 1:
            raise ValueError(f"gap_periods must be > 1, got {gap_periods!r}")
        self.robot = robot
        chassis = robot.chassis
        self.period = chassis.encode_sampling_time
        if reorder_window is None:
            reorder_window = 0.5 * self.period + robot.ekf.wheel_latency
        if not (math.isfinite(reorder_window) and reorder_window >= 0):
            raise ValueError(f"reorder_window must be >= 0 s, got {reorder_window!r}")
        self.reorder_window = float(reorder_window)
        self.sinks = list(sinks)
        self.publish_rate_hz = publish_rate_hz
        self.tilt = bool(tilt)
        self.ekf = PlanarEKF(chassis, robot.ekf)
        self.mahony = mahony if mahony is not None else Mahony(axes=6,
                                                               sample_period=1.0 / imu_rate_hz)
        self._mount = _matrix_or_none(robot.imu_to_base())
        self._buffer = _WatermarkBuffer(self.reorder_window)
        bad = set(sources) - set(_SOURCES)
        if bad or not sources:
            raise ValueError(f"sources must be some of {list(_SOURCES)}, got {list(sources)}")
        self._marks = {name: -math.inf for name in sources}
        self._watermark = -math.inf
        self._clock = clock
        self._gap_periods = float(gap_periods)
        self._on_record = on_record
        self.stats = PipelineStats()
        self.latencies: collections.deque[float] = collections.deque(maxlen=latency_window)
        self._last_imu_t = -math.inf
        self._last_wheel_t: float | None = None
        self._last_twist_t = -math.inf
        self._q: NDArray[np.float64] | None = None  # attitude of the last fused IMU sample
        self._gyro = None
        self._accel = None
        self._wheel_speeds: tuple[float, float] | None = None
        self._next_tick: float | None = None
        self._state = "new"
        self._m_per_s = chassis.speed_ratio / self.period

    # -- lifecycle --------------------------------------------------------------------------
    def open(self) -> FusionPipeline:
        """Open the sinks (a sink that fails to open closes the ones already open)."""
        if self._state != "new":
            raise RuntimeError("the pipeline was already opened")
        opened = []
        try:
            for sink in self.sinks:
                sink.open()
                opened.append(sink)
        except BaseException:
            for sink in opened:
                sink.abort()
            raise
        self._state = "open"
        return self

    def close(self) -> None:
        """Fuse what the reorder buffer still holds, publish, and close the sinks."""
        if self._state != "open":
            return
        try:
            self.flush()
        except BaseException:
            self.abort()
            raise
        self._state = "closed"
        errors = []
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as exc:  # close every sink, then report
                errors.append(exc)
        if errors:
            raise errors[0]

    def abort(self) -> None:
        """Stop without finishing: sinks are aborted (file sinks discard partial output)."""
        if self._state != "open":
            return
        self._state = "aborted"
        for sink in self.sinks:
            try:
                sink.abort()
            except Exception:  # aborting: keep going
                continue

    def __enter__(self) -> FusionPipeline:
        if self._state == "new":
            self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- inputs -----------------------------------------------------------------------------
    def push(self, event: ImuSample | WheelTicks) -> None:
        """Feed one event (in arrival order); records are published as they become due."""
        if self._state != "open":
            raise RuntimeError("the pipeline is not open: call open() or use 'with'")
        if type(event) is WheelTicks:
            self.push_wheels(event)
        elif type(event) is ImuSample:
            self.push_imu(event)
        else:
            raise TypeError(f"events are ImuSample or WheelTicks, got {type(event).__name__}")

    def push_imu(self, sample: ImuSample) -> None:
        """One IMU sample: gyro rad/s and specific force m/s^2 in the IMU frame, stamp s."""
        t = float(sample.t)
        if not t > self._last_imu_t:
            self.stats.imu_out_of_order += 1
            return
        R = self._mount
        if R is None:
            g = np.asarray(sample.gyro, dtype=np.float64).reshape(3)
            a = np.asarray(sample.accel, dtype=np.float64).reshape(3)
        else:  # written out so that push_arrays computes the very same floats
            gx, gy, gz = np.asarray(sample.gyro, dtype=np.float64).reshape(3).tolist()
            ax, ay, az = np.asarray(sample.accel, dtype=np.float64).reshape(3).tolist()
            g = np.array([R[0][0] * gx + R[0][1] * gy + R[0][2] * gz,
                          R[1][0] * gx + R[1][1] * gy + R[1][2] * gz,
                          R[2][0] * gx + R[2][1] * gy + R[2][2] * gz])
            a = np.array([R[0][0] * ax + R[0][1] * ay + R[0][2] * az,
                          R[1][0] * ax + R[1][1] * ay + R[1][2] * az,
                          R[2][0] * ax + R[2][1] * ay + R[2][2] * az])
        self._last_imu_t = t
        self.stats.imu_samples += 1
        q = self.mahony.update(g, a, timestamp=t)
        if self.tilt:
            w, x, y, z = q.tolist()
            gx, gy, gz = g.tolist()
            n2 = w * w + x * x + y * y + z * z
            r20 = 2.0 * (x * z - w * y) / n2
            r21 = 2.0 * (y * z + w * x) / n2
            r22 = 1.0 - 2.0 * (x * x + y * y) / n2
            rate = r20 * gx + r21 * gy + r22 * gz
        else:
            rate = float(g[2])
        self._buffer.push(t, (_EV_GYRO, t, rate, q, g, a))
        if "imu" in self._marks:
            self._marks["imu"] = t
            self._watermark = min(self._marks.values())
        self._release()

    def push_wheels(self, frame: WheelTicks) -> None:
        """One DATA-uart2 frame: ticks counted in the period ending at ``frame.t`` (s)."""
        t = float(frame.t)
        last = self._last_wheel_t
        if last is not None:
            if not t > last:
                self.stats.wheel_out_of_order += 1
                return
            if t - last > self._gap_periods * self.period:
                missing = max(1, round((t - last) / self.period) - 1)
                self.stats.gaps.append(WheelGap(last, t, missing))
                self.stats.gap_count += 1
                self.stats.frames_missing += missing
        self._last_wheel_t = t
        self.stats.wheel_frames += 1
        t_eff = t - 0.5 * self.period - self.ekf.noise.wheel_latency
        self._buffer.push(t_eff, (_EV_WHEELS, t, int(frame.left), int(frame.right)))
        if "wheels" in self._marks:
            self._marks["wheels"] = t_eff
            self._watermark = min(self._marks.values())
        self._release()

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
        if self._state != "open":
            raise RuntimeError("the pipeline is not open: call open() or use 'with'")
        t = float(t)
        if not t > self._last_twist_t:
            self.stats.twist_out_of_order += 1
            return
        self._last_twist_t = t
        self.stats.twist_messages += 1
        self._buffer.push(t, (_EV_TWIST, t, float(v), float(w)))
        if "twist" in self._marks:
            self._marks["twist"] = t
            self._watermark = min(self._marks.values())
        self._release()

    def flush(self) -> None:
        """Fuse every held event now (end of a replay, or before a pause)."""
        for _t, ev in self._buffer.flush():
            self._apply(ev)

    # -- core -------------------------------------------------------------------------------
    def _release(self) -> None:
        buf = self._buffer
        for _t, ev in buf.pop_through(self._watermark):
            self._apply(ev)
        for _t, ev in buf.pop_ready():
            self._apply(ev)

    def _apply(self, ev: tuple) -> None:
        ekf = self.ekf
        if ev[0] == _EV_GYRO:
            _, t, rate, q, g, a = ev
            ekf.update_gyro(t, rate)
            self._q, self._gyro, self._accel = q, g, a
            if self.publish_rate_hz is not None:
                self._tick()
            return
        if ev[0] == _EV_TWIST:
            _, t, v, w = ev
            ekf.update_twist(t, v, w)
        else:
            _, t, left, right = ev
            ekf.update_wheels(t, left, right)
            self._wheel_speeds = (left * self._m_per_s, right * self._m_per_s)
        if self.publish_rate_hz is None:
            self._publish(t)
        else:
            self._tick()

    def _tick(self) -> None:
        t = self.ekf.t
        if t is None:
            return
        if self._next_tick is None:
            self._next_tick = t
        if t >= self._next_tick:
            self._publish(None)
            rate = self.publish_rate_hz
            self._next_tick = (math.floor(t * rate + 1e-9) + 1) / rate

    def _publish(self, wheel_stamp: float | None) -> None:
        if self._state != "open":
            raise RuntimeError("the pipeline is not open: call open() or use 'with'")
        rec = self.current_record()
        for sink in self.sinks:
            sink.write(rec)
        self.stats.records += 1
        if self._clock is not None and wheel_stamp is not None:
            self.latencies.append(self._clock() - wheel_stamp)
        if self._on_record is not None:
            self._on_record(rec)

    def current_record(self) -> FusedOdometry:
        """The fused state now as a :class:`FusedOdometry` (frames from the config).

        ``angular_velocity`` is the last base-frame gyro sample's x and y with the EKF's
        yaw rate as z (so /odom's twist carries the fused rate); ``orientation`` the Mahony
        attitude of that sample; wheel speeds are the last frame's rim speeds (m/s).
        """
        ekf = self.ekf
        g = self._gyro
        ws = self._wheel_speeds
        return _fast_record(_record_fields(
            ekf.t if ekf.t is not None else 0.0, ekf.x, ekf.P, self._q,
            None if g is None else (float(g[0]), float(g[1])), self._accel,
            ws, self.robot.odom_frame, self.robot.base_frame,
        ))

    # -- batch entry point --------------------------------------------------------------------
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
    ) -> None:
        """Whole recorded streams at once, then :meth:`flush` (for replay of long logs).

        Exactly equivalent to pushing ``merge_by_time(imu_samples, wheel_frames, twists)``
        one event at a time (:meth:`push_imu`, :meth:`push_wheels`, :meth:`push_twist`) into
        this (fresh) pipeline and flushing: the same records, bit for bit
        (tests/test_pipeline.py), computed with the Mahony filter's and the EKF's batch
        entry points. The pipeline must not have received events before.

        Args:
            imu_t, gyro, accel: (N,) stamps s, (N, 3) rad/s and m/s^2 in the IMU frame.
            wheel_t, ticks: (M,) frame stamps s (end of period) and (M, 2) ticks per period.
            twist_t, twist_v, twist_w: (K,) external odometry twists (a nav_msgs/Odometry
                twist): stamps s, forward speed m/s, yaw rate rad/s (see :meth:`push_twist`).
        """
        if self._state != "open":
            raise RuntimeError("the pipeline is not open: call open() or use 'with'")
        if (self.stats.imu_samples or self.stats.wheel_frames or self.stats.twist_messages
                or len(self._buffer)):
            raise ValueError("push_arrays needs a pipeline that has received no events")
        it = np.zeros(0) if imu_t is None else np.asarray(imu_t, dtype=np.float64).reshape(-1)
        n_imu = it.size
        G = np.asarray(gyro, dtype=np.float64).reshape(n_imu, 3) if n_imu else np.zeros((0, 3))
        A = np.asarray(accel, dtype=np.float64).reshape(n_imu, 3) if n_imu else np.zeros((0, 3))
        wt = np.zeros(0) if wheel_t is None else np.asarray(wheel_t, dtype=np.float64).reshape(-1)
        TK = (np.zeros((0, 2), np.int64) if wt.size == 0
              else np.asarray(ticks).reshape(wt.size, 2).astype(np.int64))
        tt = np.zeros(0) if twist_t is None else np.asarray(twist_t, dtype=np.float64).reshape(-1)
        TV = np.zeros(0) if twist_v is None else np.asarray(twist_v, dtype=np.float64).reshape(-1)
        TW = np.zeros(0) if twist_w is None else np.asarray(twist_w, dtype=np.float64).reshape(-1)
        if not TV.size == TW.size == tt.size:
            raise ValueError(f"{tt.size} twist stamps but {TV.size} v and {TW.size} w values")

        keep = _increasing(it)
        self.stats.imu_out_of_order += int(n_imu - keep.sum())
        it, G, A = it[keep], G[keep], A[keep]
        R = self._mount
        if R is not None and it.size:
            G = _rotate_rows(R, G)
            A = _rotate_rows(R, A)
        if it.size:
            Q = self.mahony.update_batch(G, A, timestamps=it)
            if self.tilt:
                w, x, y, z = Q[:, 0], Q[:, 1], Q[:, 2], Q[:, 3]
                n2 = w * w + x * x + y * y + z * z
                r20 = 2.0 * (x * z - w * y) / n2
                r21 = 2.0 * (y * z + w * x) / n2
                r22 = 1.0 - 2.0 * (x * x + y * y) / n2
                rate = r20 * G[:, 0] + r21 * G[:, 1] + r22 * G[:, 2]
            else:
                rate = G[:, 2].copy()
            self._last_imu_t = float(it[-1])
        else:
            Q = np.zeros((0, 4))
            rate = np.zeros(0)
        self.stats.imu_samples += int(it.size)

        keep = _increasing(wt)
        self.stats.wheel_out_of_order += int(wt.size - keep.sum())
        wt, TK = wt[keep], TK[keep]
        if wt.size:
            dts = np.diff(wt)
            for i in np.flatnonzero(dts > self._gap_periods * self.period).tolist():
                missing = max(1, round(float(dts[i]) / self.period) - 1)
                self.stats.gaps.append(WheelGap(float(wt[i]), float(wt[i + 1]), missing))
                self.stats.gap_count += 1
                self.stats.frames_missing += missing
            self._last_wheel_t = float(wt[-1])
        self.stats.wheel_frames += int(wt.size)

        keep = _increasing(tt)
        self.stats.twist_out_of_order += int(tt.size - keep.sum())
        tt, TV, TW = tt[keep], TV[keep], TW[keep]
        if tt.size:
            self._last_twist_t = float(tt[-1])
        self.stats.twist_messages += int(tt.size)

        # arrival order (host time; at equal stamps IMU, then wheels, then twists, as
        # merge_by_time with the streams in that order), then the reorder buffer's release
        # order: by effective time, ties in arrival order
        n_w = wt.size
        stamp = np.concatenate([it, wt, tt])
        kind = np.concatenate([np.full(it.size, _EV_GYRO, np.int64),
                               np.full(n_w, _EV_WHEELS, np.int64),
                               np.full(tt.size, _EV_TWIST, np.int64)])
        src = np.concatenate([np.arange(it.size), np.arange(n_w), np.arange(tt.size)])
        t_eff = np.concatenate([it, wt - 0.5 * self.period - self.ekf.noise.wheel_latency, tt])
        arrival = np.argsort(stamp, kind="stable")
        order = arrival[np.argsort(t_eff[arrival], kind="stable")]
        kind, src, t_eff = kind[order], src[order], t_eff[order]
        a = np.where(kind == _EV_GYRO, rate[np.minimum(src, max(it.size - 1, 0))]
                     if it.size else 0.0, 0.0)
        b = np.zeros(kind.size)
        is_w = kind == _EV_WHEELS
        a[is_w] = TK[src[is_w], 0]
        b[is_w] = TK[src[is_w], 1]
        is_t = kind == _EV_TWIST
        a[is_t] = TV[src[is_t]]
        b[is_t] = TW[src[is_t]]
        # the wheel frame's own stamp goes to the filter: update_wheels() subtracts the same
        # half period and latency, process_batch() takes effective times (a twist's is its
        # stamp)
        if self.publish_rate_hz is None:
            points = np.flatnonzero(is_w | is_t)
        else:
            points = self._tick_points(t_eff, a, b)
        pos = np.arange(kind.size)
        last_gyro = np.maximum.accumulate(np.where(kind == _EV_GYRO, pos, -1)) if kind.size \
            else pos
        last_wheel = np.maximum.accumulate(np.where(is_w, pos, -1)) if kind.size else pos
        ekf = self.ekf
        start = 0
        for p in points.tolist():
            ekf.process_batch(kind[start:p + 1], t_eff[start:p + 1], a[start:p + 1],
                              b[start:p + 1])
            start = p + 1
            self._set_last(last_gyro[p], last_wheel[p], src, G, A, Q, TK)
            kp = kind[p]
            self._publish(float(wt[src[p]]) if kp == _EV_WHEELS
                          else float(tt[src[p]]) if kp == _EV_TWIST else None)
        if start < kind.size:
            ekf.process_batch(kind[start:], t_eff[start:], a[start:], b[start:])
            self._set_last(last_gyro[-1], last_wheel[-1], src, G, A, Q, TK)
        self.flush()

    def _set_last(self, gi: int, wi: int, src, G, A, Q, TK) -> None:
        if gi >= 0:
            k = src[gi]
            self._q, self._gyro, self._accel = Q[k], G[k], A[k]  # views; records copy
        if wi >= 0:
            k = src[wi]
            self._wheel_speeds = (int(TK[k, 0]) * self._m_per_s, int(TK[k, 1]) * self._m_per_s)

    def _tick_points(self, t_eff, a, b) -> NDArray[np.int64]:
        """Indices after which :meth:`_tick` publishes (the filter's time is the running
        maximum of the valid events' effective times)."""
        valid = np.isfinite(t_eff) & np.isfinite(a) & np.isfinite(b)
        t_after = np.fmax.accumulate(np.where(valid, t_eff, np.nan)) if t_eff.size else t_eff
        rate = self.publish_rate_hz
        nxt = self._next_tick
        out = []
        for k, t in enumerate(t_after.tolist()):
            if t != t:  # no valid event yet: the filter has no time
                continue
            if nxt is None:
                nxt = t
            if t >= nxt:
                out.append(k)
                nxt = (math.floor(t * rate + 1e-9) + 1) / rate
        self._next_tick = nxt
        return np.array(out, dtype=np.int64)

    def finish_stats(self) -> PipelineStats:
        """The counters, with the EKF's late/slip/ZUPT counters copied in."""
        s = self.ekf.stats
        self.stats.late_dropped = s["late_dropped"]
        self.stats.late_applied = s["late_applied"]
        self.stats.slips = s["slips"]
        self.stats.zupts = s["zupts"]
        return self.stats

    def latency_percentiles(self, *qs: float) -> list[float]:
        """Percentiles (0..100) of the measured wheel-frame -> record latencies, s (NaN if
        none were measured)."""
        if not self.latencies:
            return [math.nan for _ in qs]
        a = np.fromiter(self.latencies, dtype=float)
        return [float(v) for v in np.percentile(a, qs)]


class _WatermarkBuffer(ReorderBuffer):
    """The EKF's :class:`fusion.planar.ekf.ReorderBuffer` with one more way out: :meth:`pop_through`
    releases, in order, everything not newer than a time every source has passed."""

    def pop_through(self, t: float) -> list:
        out = []
        heap = self._heap
        while heap and heap[0][0] <= t:
            tt, _, ev = heapq.heappop(heap)
            out.append((tt, ev))
        return out


def _increasing(t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Mask of the stamps that are greater than every earlier one (NaN never is)."""
    if t.size == 0:
        return np.zeros(0, dtype=bool)
    prev = np.concatenate([[-np.inf], np.fmax.accumulate(t)[:-1]])
    return t > prev


def _rotate_rows(R: list[list[float]], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R @ v[i]`` for every row, with the very operations of :meth:`FusionPipeline.push_imu`."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return np.column_stack([R[0][0] * x + R[0][1] * y + R[0][2] * z,
                            R[1][0] * x + R[1][1] * y + R[1][2] * z,
                            R[2][0] * x + R[2][1] * y + R[2][2] * z])
