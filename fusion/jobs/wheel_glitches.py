"""Wheel frames that no wheel can produce: a count that jumps away and back within two frames.

An independent probe (2026-12-07, its own simulator: encoder frames hit by EMI, 4096-18613
ticks in one frame of a robot whose wheels reach 0.8 m/s) found such frames under the EKF's
absolute bound (``EkfNoise.max_speed``, 50 m/s, which a corrupt frame of 10-46 m/s passes):
one was fused (the speed state jumped 0.12 -> 0.44 m/s for a frame), and the replay's wheel
checks and its printed wheel-only figures took them at face value ("speeds not in m/s",
"headings diverge", a wheel-only error of 51-1630 %) on runs whose fused track was fine.

A replay has the frames on both sides of each one: :func:`glitch_frames` marks a run of at
most :data:`MAX_GLITCH_FRAMES` frames in which one wheel's count departs from the frames
just before and just after it by more than that wheel could change its speed in the time
between (:data:`MAX_WHEEL_ACCEL`), while those two frames agree with each other. A counter
read once wrong gives +X then -X in consecutive frames, hence two. Slip, a wheel spinning
up, a stop or a dropped frame change a count for good or within what a wheel can do; they
are never marked. Units: s, ticks, m/tick.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.kinematics import DiffDriveParams
from fusion.io.logdir import wheels_csv_lines
from fusion.jobs.streams import Streams

__all__ = ["MAX_GLITCH_FRAMES", "MAX_WHEEL_ACCEL", "QUANTUM_TICKS", "glitch_frames", "in_log",
           "stamped", "without_glitches"]

#: m/s^2: no wheel's ground speed changes faster (5 g; a motor spinning a lifted wheel up
#: reaches a few times less), so a count further from its neighbours' than this allows over
#: the time between them is not the wheel's.
MAX_WHEEL_ACCEL = 50.0
#: The longest run of frames that can be a glitch (longer is the wheel's own motion).
MAX_GLITCH_FRAMES = 2
#: ticks: the quantisation and a frame boundary's share, never taken for a departure.
QUANTUM_TICKS = 2.0


def glitch_frames(wheel_t: NDArray[np.float64], ticks: NDArray, speed_ratio: float,
                  period: float) -> NDArray[np.bool_]:
    """(M,) bool: the wheel frames (stamps ``wheel_t`` s, sorted; ``ticks`` (M, 2) per
    period; ``speed_ratio`` m/tick; ``period`` s) that are a short glitch (module docstring).
    The first and last frame are never marked (one side is unknown)."""
    t = np.asarray(wheel_t, dtype=np.float64)
    n = np.asarray(ticks, dtype=np.float64).reshape(-1, 2)
    marked = np.zeros(t.size, dtype=bool)
    per_second = MAX_WHEEL_ACCEL * period / speed_ratio  # ticks per period, per s between

    def bound(dt: NDArray[np.float64]) -> NDArray[np.float64]:
        return (per_second * np.maximum(dt, period) + QUANTUM_TICKS)[:, None]

    for length in range(1, MAX_GLITCH_FRAMES + 1):
        if t.size < length + 2:
            break
        before = np.arange(t.size - length - 1)
        after = before + length + 1
        # the frames around the run agree: the wheel's own speed carried on across it
        glitch = np.all(np.abs(n[after] - n[before]) <= bound(t[after] - t[before]), axis=1)
        for k in range(1, length + 1):
            inner = before + k
            # each frame of the run departs from both sides on the same wheel
            departs = ((np.abs(n[inner] - n[before]) > bound(t[inner] - t[before]))
                       & (np.abs(n[inner] - n[after]) > bound(t[after] - t[inner])))
            glitch &= np.any(departs, axis=1) & ~marked[inner]
        for k in range(1, length + 1):
            marked[before[glitch] + k] = True
    return marked


def without_glitches(streams: Streams, chassis: DiffDriveParams,
                     where: Callable[[list[int]], str]) -> tuple[Streams, str | None]:
    """``streams`` without its glitch frames (:func:`glitch_frames`), and a note for the user
    (None when there was none): how many, the largest speed one claimed, and ``where(first
    indices)`` (e.g. "wheels.csv line(s) 12, 40"). Left out, a glitch frame's period counts
    as a missing frame, its ticks as lost."""
    if not streams.has_wheels:
        return streams, None
    marked = glitch_frames(streams.wheel_t, streams.ticks, chassis.speed_ratio,
                           chassis.encode_sampling_time)
    if not marked.any():
        return streams, None
    idx = np.flatnonzero(marked)
    fastest = float(np.abs(streams.ticks[idx]).max()) * chassis.speed_ratio \
        / chassis.encode_sampling_time
    more = f" and {idx.size - 5} more" if idx.size > 5 else ""
    note = (f"{idx.size} wheel frame(s) left out as glitches (a wheel's speed away from the "
            f"frames' on either side and back faster than {MAX_WHEEL_ACCEL:g} m/s^2, up to "
            f"{fastest:.3g} m/s; EMI or a counter read wrong: if frequent, check the encoder "
            f"wiring and its shielding): {where(idx[:5].tolist())}{more}")
    keep = ~marked
    return dataclasses.replace(streams, wheel_t=streams.wheel_t[keep],
                               ticks=streams.ticks[keep]), note


def in_log(path: Path, wheel_t: NDArray[np.float64]) -> Callable[[list[int]], str]:
    """For :func:`without_glitches`: where a log directory's wheel frames are, in words:
    wheels.csv's lines, or a capture's frames by their stamps ``wheel_t`` (s; the parser's
    frame count leaves out what it refused)."""

    def where(indices: list[int]) -> str:
        csv = path / "wheels.csv"
        if csv.is_file():
            lines = wheels_csv_lines(csv)
            return f"{csv} line(s) {', '.join(str(lines[i]) for i in indices)}"
        return f"{path / 'wheels.uart2'} {stamped(wheel_t[indices])}"

    return where


def stamped(t: NDArray[np.float64]) -> str:
    """Frames named by their stamps ``t`` (s)."""
    return f"frame(s) stamped {', '.join(f'{x:.3f}' for x in t)} s"
