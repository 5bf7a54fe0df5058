"""Replay sources: recorded logs as time-ordered event streams for a
:class:`fusion.pipeline.core.FusionPipeline` (the same object ``fusion run`` uses live).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator
from pathlib import Path

from fusion.pipeline.core import FusionPipeline, PipelineStats
from fusion.planar.robot import RobotConfig
from fusion.types.samples import ImuSample, WheelTicks

__all__ = ["capture_events", "imu_csv_events", "logdir_events", "merge_by_time", "replay"]


def merge_by_time(*streams: Iterable[ImuSample | WheelTicks]) -> Iterator[ImuSample | WheelTicks]:
    """Merge event streams, each in time order, into host time order (ties: the earlier
    stream first), lazily."""
    return heapq.merge(*streams, key=lambda e: e.t)


def replay(pipeline: FusionPipeline, events: Iterable[ImuSample | WheelTicks]) -> PipelineStats:
    """Push every event through ``pipeline`` (opened here if new) and close it.

    On an exception the sinks are aborted (no partial files) and it propagates.
    """
    if pipeline._state == "new":
        pipeline.open()
    try:
        for ev in events:
            pipeline.push(ev)
    except BaseException:
        pipeline.abort()
        raise
    pipeline.close()
    return pipeline.finish_stats()


def imu_csv_events(path: str | Path) -> Iterator[ImuSample]:
    """IMU samples of an IMU CSV (``t,gx,gy,gz,ax,ay,az``; IMU frame, s, rad/s, m/s^2)."""
    from fusion.io.imu_csv import read_imu_csv

    log = read_imu_csv(path)
    t = log.t.tolist()
    for i in range(len(t)):
        yield ImuSample(t[i], log.gyro[i], log.accel[i])


def logdir_events(path: str | Path) -> tuple[RobotConfig, Iterator[ImuSample | WheelTicks]]:
    """``(robot, events)`` of a log directory (``datasets/LOGDIR.md``).

    Read by :func:`fusion.io.logdir.read_logdir`; IMU samples stay in the IMU frame (the
    pipeline applies ``imu_mount_rpy``). The wheel frames come from ``wheels.csv`` or, without
    it, from a DATA-uart2 capture ``wheels.uart2`` (timed or raw, see :func:`capture_events`).
    """
    from fusion.io.logdir import read_logdir

    log = read_logdir(path, imu_frame="imu", truth=False)
    streams: list[Iterable[ImuSample | WheelTicks]] = []
    if log.imu_t is not None:
        t = log.imu_t.tolist()
        streams.append([ImuSample(t[i], log.gyro[i], log.accel[i]) for i in range(len(t))])
    if log.wheel_t is not None:
        streams.append([WheelTicks(t, int(lt), int(rt)) for t, (lt, rt)
                        in zip(log.wheel_t.tolist(), log.ticks.tolist())])
    return log.robot, merge_by_time(*streams)


def capture_events(path: str | Path, period: float, *, t0: float = 0.0,
                   max_ticks: int | None = None) -> tuple[list[WheelTicks], dict[str, int]]:
    """Wheel frames of a DATA-uart2 capture (:func:`fusion.io.uart2.read_uart2_capture`).

    A timed capture (``t,data`` rows, :class:`fusion.io.uart2.Uart2CaptureWriter`) gives each
    frame the stamp the live link would have given it. A raw capture has no clock: frame k
    (0-based, stream order) is stamped ``t0 + (k + 1) * period`` (dropped frames cannot be
    seen). Returns ``(frames, parser_counters)``.
    """
    from fusion.io.uart2 import read_uart2_capture

    cap = read_uart2_capture(path, period=period, max_ticks=max_ticks)
    stamps = cap.frame_times(period, t0).tolist()
    return [WheelTicks(stamps[k], int(cap.left[k]), int(cap.right[k]))
            for k in range(len(cap))], cap.stats
