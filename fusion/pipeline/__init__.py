"""The fusion pipeline: sources -> attitude -> planar EKF -> records -> sinks.

- :mod:`fusion.pipeline.core`: :class:`FusionPipeline` (event ordering, filter wiring, output).
- :mod:`fusion.pipeline.records`: fused records from the filters' state.
- :mod:`fusion.pipeline.live`: :class:`LiveRunner`, source threads for ``fusion run``.
- :mod:`fusion.pipeline.sources`: recorded logs as event streams for replay.
"""

from fusion.pipeline.core import FusionPipeline, PipelineStats, WheelGap
from fusion.pipeline.live import LiveRunner
from fusion.pipeline.sources import (
    capture_events,
    imu_csv_events,
    logdir_events,
    merge_by_time,
    replay,
)

__all__ = [
    "FusionPipeline",
    "LiveRunner",
    "PipelineStats",
    "WheelGap",
    "capture_events",
    "imu_csv_events",
    "logdir_events",
    "merge_by_time",
    "replay",
]
