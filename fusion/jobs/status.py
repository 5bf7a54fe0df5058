"""The end-of-run status of a :class:`fusion.pipeline.core.FusionPipeline`: its counters and
the trust warnings (:mod:`fusion.evaluation.trust`), as ``fusion replay`` and ``fusion run``
print them and write them as the JSON lines status record.
"""

from __future__ import annotations

from typing import Any

from fusion.evaluation.trust import TrustWarning, trust_warnings
from fusion.pipeline.core import FusionPipeline

__all__ = ["STRICT_EXIT_STATUS", "pipeline_warnings", "status_record", "write_status"]

#: Exit status of ``fusion replay``/``fusion run --strict`` when a trust check failed.
STRICT_EXIT_STATUS = 3


def pipeline_warnings(pipe: FusionPipeline) -> list[TrustWarning]:
    """The trust checks over ``pipe``'s counters and its EKF's gyro bias and wheel
    calibration estimates (yaw-rate scale, radius mismatch; none without an IMU sample)."""
    stats = pipe.finish_stats()
    bias = float(pipe.ekf.gyro_bias) if stats.imu_samples else None
    k = float(pipe.ekf.x[6]) if stats.imu_samples else None  # the gyro is its reference
    c = float(pipe.ekf.x[7]) if stats.imu_samples else None
    return trust_warnings(stats.as_dict(), bias, k, c)


def status_record(pipe: FusionPipeline, warnings: list[TrustWarning]) -> dict[str, Any]:
    """``{"t": filter time s, "counters": {...}, "gyro_bias": rad/s, "warnings": [...]}``
    (JSON-ready; the counters of :meth:`PipelineStats.as_dict` without the gap list)."""
    counters = {k: v for k, v in pipe.finish_stats().as_dict().items() if k != "gaps"}
    t = float(pipe.ekf.t) if pipe.ekf.t is not None else None
    return {"t": t, "counters": counters, "gyro_bias": float(pipe.ekf.gyro_bias),
            "warnings": [w.to_dict() for w in warnings]}


def write_status(pipe: FusionPipeline, status: dict[str, Any]) -> None:
    """Write ``status`` to every sink of ``pipe`` that takes status records (the JSON lines
    sink); call after the last record (:meth:`FusionPipeline.flush`) and before closing."""
    for sink in pipe.sinks:
        write = getattr(sink, "write_status", None)
        if write is not None and sink.is_open:  # not a sink whose write failed (aborted)
            write(status)
