"""Messages that share a stamp: a driver that reads a sensor's FIFO in bursts and stamps every
sample of a burst with the read time, or one that published a message twice.

The fusion takes each source's stamps as strictly increasing (a sample not after the previous
one is dropped and counted), so a bag whose 30 Hz IMU is stamped in bursts of three at 10 Hz
lost two thirds of its samples without a word (issue 11's outdoor bag rewritten that way: 9000
messages, 3001 rows). :func:`spread_repeated_stamps` repairs that before the replay:

- a message equal to the previous one in stamp and in every value is a duplicate: left out;
- messages stamped less than :data:`TIGHT_SHARE` of the topic's mean interval apart (a
  driver that stamps each sample of a read as it handles it, microseconds apart) are a run
  as if they shared the run's first stamp (:func:`near_stamp_runs`); spread as below, an
  independent probe's 30 Hz IMU read ten at a time and stamped 0.1 ms apart no longer
  turned its gyro's heading 3217 deg away from the odometry's (GPS RMSE 25.9 -> 1.5 m);
- a run of ``n`` messages that share a stamp but not their values is a burst: its samples
  were taken before the read that stamped them, so they are spread back from the stamp,
  ``stamp - (n - 1 - k) * spacing`` for the k-th, with ``spacing`` the time since the
  previous stamp over ``n`` (the burst filled that interval), at most the sampling period:
  the median of that spacing over all runs (a burst after a pause is not stretched over
  the pause; the first run, with no stamp before it, takes the period);
- unless the messages' record times are known (a bag) and show the run's messages came one
  by one (:data:`FROZEN_MIN_RUN` or more, their record times spanning most of the time the
  samples took, :data:`FROZEN_SHARE`, beyond a busy recorder's jitter): then the stamp froze
  (a driver bug), and each gets its record time less the topic's median record delay (over
  the other messages), kept in order. Spread back, an independent probe's 1 s of frozen IMU stamps
  was squeezed into a millisecond and its turn lost (GPS RMSE 1.55 -> 3.13 m).

Stamps in s; what was done is said in :attr:`StampRepair.note` (empty when nothing was).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["FROZEN_MIN_RUN", "FROZEN_SHARE", "GAP_FACTOR", "RECORD_JITTER", "TIGHT_SHARE",
           "StampRepair", "near_stamp_runs", "spread_repeated_stamps"]

#: A run of equal stamps whose record times span more than this share of the run's sampling
#: time ((n - 1) periods), plus :data:`RECORD_JITTER`, and step by half a period or more (the
#: median step), came one by one: frozen stamps, not a burst read at once (whose messages are
#: recorded together, give or take a busy recorder's delays).
FROZEN_SHARE = 0.8
#: s: what a busy recorder adds to a burst's record times (review: 0-12 ms at 100 Hz).
RECORD_JITTER = 0.015
#: The shortest run taken for frozen stamps (a FIFO read returns a few samples at once).
FROZEN_MIN_RUN = 5
#: A step between two stamps shorter than this share of the topic's mean interval joins a
#: burst: no sensor or driver samples that much faster than it runs on average (a 200 Hz
#: IMU's stamps 0.5 ms apart), so the stamps are a read's, not the samples'. Jitter of a
#: tenth of the period that makes such a step is spread back as well, nearer the sample.
TIGHT_SHARE = 0.1
#: Steps longer than this many times the topic's mean interval are pauses, left out of that
#: mean (a burst of up to this many is still taken for one).
GAP_FACTOR = 20.0
#: Messages outside such runs the topic's record delay is read from, at least (fewer: the
#: stamps are left to the burst rule).
MIN_DELAY_SAMPLES = 10


@dataclass(frozen=True)
class StampRepair:
    """What :func:`spread_repeated_stamps` did.

    Attributes:
        t: (M,) s, the stamps of the messages kept, strictly increasing where the input's
            distinct stamps were.
        keep: (N,) bool, which input messages were kept (False: a duplicate).
        duplicates: messages left out as copies of the previous one.
        spread: messages whose stamp was moved back within a burst.
        bursts: runs of messages that shared a stamp and were spread.
        frozen: messages of runs that came one by one (see the module docstring), put at
            their record times.
        near: messages stamped less than :data:`TIGHT_SHARE` of the mean interval after the
            previous one, taken into its run (:func:`near_stamp_runs`).
        note: one sentence for the user ("" when nothing was done).
    """

    t: NDArray[np.float64]
    keep: NDArray[np.bool_]
    duplicates: int
    spread: int
    bursts: int
    note: str
    frozen: int = 0
    near: int = 0


def near_stamp_runs(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], int, float]:
    """``t`` (s, non-decreasing) with each stamp less than :data:`TIGHT_SHARE` of the mean
    interval after the previous one set to its run's first stamp; the number so set, and that
    limit (s). The mean interval leaves out pauses of more than :data:`GAP_FACTOR` times the
    whole log's mean. Fewer than 3 stamps, or none so close: ``t`` unchanged, 0."""
    if t.size < 3 or not t[-1] > t[0]:
        return t, 0, 0.0
    steps = np.diff(t)
    mean = (t[-1] - t[0]) / steps.size
    mean = float(np.mean(steps[steps <= GAP_FACTOR * mean]))
    limit = TIGHT_SHARE * mean
    near = (steps > 0) & (steps < limit)
    if not near.any():
        return t, 0, limit
    # a run starts at each stamp that is not near its predecessor: take that start's stamp
    starts = np.concatenate([[True], ~(near | (steps == 0))])
    first = np.maximum.accumulate(np.where(starts, np.arange(t.size), 0))
    return t[first], int(np.count_nonzero(near)), limit


def _came_one_by_one(record: NDArray[np.float64], period: float) -> bool:
    """Whether a run of equal stamps was recorded one message after another (frozen stamps)
    rather than at once (a burst): see :data:`FROZEN_SHARE`."""
    n = record.size
    return bool(n >= FROZEN_MIN_RUN
                and record[-1] - record[0] > FROZEN_SHARE * (n - 1) * period + RECORD_JITTER
                and np.median(np.diff(record)) >= 0.5 * period)


def _at_record_times(out: NDArray[np.float64], start: int, n: int,
                     times: NDArray[np.float64]) -> None:
    """Put ``out[start:start + n]`` at ``times``, kept strictly increasing and between the
    stamps before and after the run (a record time's jitter must not reorder the topic)."""
    low = out[start - 1] if start > 0 else -np.inf
    high = out[start + n] if start + n < out.size else np.inf
    step = 1e-6
    times = np.clip(times, low + step, high - step * (n + 1))
    for j in range(1, n):
        times[j] = max(times[j], times[j - 1] + step)
    out[start:start + n] = times


def spread_repeated_stamps(t: NDArray[np.float64], values: NDArray[np.float64],
                           name: str = "messages",
                           record_t: NDArray[np.float64] | None = None) -> StampRepair:
    """Repair stamps shared by consecutive messages (module docstring).

    Args:
        t: (N,) s, non-decreasing (a reader's sorted stamps).
        values: (N, k) each message's values (a duplicate equals the previous in all).
        name: what the messages are, for the note (e.g. ``"topic /imu/data"``).
        record_t: (N,) s, when each message was recorded (a bag's record times), or None.

    Raises:
        ValueError: ``t`` not (N,) and non-decreasing, or ``values`` not (N, k).
    """
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if t.ndim != 1 or values.ndim != 2 or values.shape[0] != t.size:
        raise ValueError(f"t (N,) and values (N, k) expected, got {t.shape} and {values.shape}")
    if np.any(np.diff(t) < 0):
        raise ValueError("t must be non-decreasing (sort the messages first)")
    t, near, near_limit = near_stamp_runs(t)
    same_t = np.concatenate([[False], t[1:] == t[:-1]])
    if not same_t.any():
        return StampRepair(t, np.ones(t.size, dtype=bool), 0, 0, 0, "")
    # equal_nan: a message that repeats a NaN is still a copy
    same_values = np.concatenate([[False], np.all(
        (values[1:] == values[:-1]) | (np.isnan(values[1:]) & np.isnan(values[:-1])),
        axis=1)])
    keep = ~(same_t & same_values)
    kept_t = t[keep]
    duplicates = int(t.size - kept_t.size)
    out = kept_t.copy()
    spread = bursts = frozen = 0
    kept_record = None if record_t is None else np.asarray(record_t, dtype=np.float64)[keep]
    starts = np.flatnonzero(np.concatenate([[True], kept_t[1:] != kept_t[:-1]]))
    lengths = np.diff(np.concatenate([starts, [kept_t.size]]))
    # each run's samples filled the time since the previous stamp: that time over the run's
    # length; the median over the runs is the sampling period (a pause does not move it)
    filled = np.diff(kept_t[starts]) / lengths[1:]
    if filled.size:
        period = float(np.median(filled))
        runs = list(zip(starts.tolist(), lengths.tolist(), strict=True))
        one_by_one = [kept_record is not None and n >= 2
                      and _came_one_by_one(kept_record[start:start + n], period)
                      for start, n in runs]
        # the topic's usual record delay, from the messages outside such runs
        usual = ~np.repeat(np.array(one_by_one, dtype=bool), lengths)
        known = kept_record is not None and np.count_nonzero(usual) >= MIN_DELAY_SAMPLES
        delay = float(np.median(kept_record[usual] - kept_t[usual])) if known else 0.0
        for i, (start, n) in enumerate(runs):
            if n < 2:
                continue
            if known and one_by_one[i]:
                _at_record_times(out, start, n, kept_record[start:start + n] - delay)
                frozen += n
                continue
            spacing = min(filled[i - 1], period) if i > 0 else period
            out[start:start + n] = kept_t[start] - (n - 1 - np.arange(n)) * spacing
            spread += n - 1
            bursts += 1
    parts = []
    if frozen:
        parts.append(f"{frozen} messages shared a stamp while they came one by one (their "
                     "record times spread as the samples did: a stamp that froze): each put "
                     "at its record time less the topic's usual record delay "
                     f"({delay * 1e3:.1f} ms)")
    if near:
        parts.append(f"{near} messages were stamped less than {near_limit * 1e3:.3g} ms after "
                     f"the previous one (a tenth of the topic's mean interval: when a driver "
                     "handled a batch read at once, not when each was sampled): each batch "
                     "taken as stamped at its first")
    if bursts:
        parts.append(f"{spread} messages carried the stamp of a later one ({bursts} runs of "
                     "equal stamps: a batch stamped at one time, a driver's read or a "
                     "recorder's receipt): spread back from it over the time since the "
                     "previous stamp")
    if duplicates:
        parts.append(f"{duplicates} copies of the previous message (same stamp and values) "
                     "left out")
    note = f"{name}: " + "; ".join(parts) if parts else ""
    return StampRepair(out, keep, duplicates, spread, bursts, note, frozen, near)
