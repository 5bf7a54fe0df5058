"""Compiled event core of :class:`fusion.pipeline.core.FusionPipeline` (private).

One function, :func:`run_events`, takes events in *arrival* order and does, per event, what the
pipeline promises (its module docstring states the policy): hold the event in a reorder heap
keyed by its effective time, release what the sources' watermark or the reorder window allows,
apply each released event to the planar EKF (:func:`fusion.planar._ekf_core.step_core`, which
also applies the EKF's gap policy and refuses implausible values), and note where a record is
due. Streaming (one event per call) and batch (all events in one call)
run this very function, so the two paths agree bit for bit by construction for any reorder
window and set of sources (tests/test_pipeline.py).

Numba compiles it when installed (``fast`` extra); otherwise the same code runs interpreted.

State lives in caller-owned arrays so that a pipeline can be fed across calls:

- the heap: parallel arrays ``heap_f`` (float64 rows ``[t_eff, a, b, stamp]``) and ``heap_i``
  (int64 rows ``[seq, kind, ref]``), ``sched[S_HEAP_N]`` entries in use; ``ref`` is the
  caller's index of the event's payload within its source (IMU sample, wheel frame, twist);
- ``sched`` (float64): heap size, arrival counter, newest effective time, each source's mark
  and whether it takes part in the watermark, the next publish tick, the refs of the last
  applied IMU sample and wheel frame;
- the EKF's ``x``, ``P``, ``aux``, ``par`` (:mod:`fusion.planar._ekf_core`).

Outputs (preallocated by the caller, at least as many rows as events can be applied in the
call: the heap size plus the new events):

- ``pub`` rows, one per record due (:data:`PUB_WIDTH` columns, indices ``U_*``): the filter
  time, ``x`` (8), ``P[:5, :5]`` row major (25; its pose block that of the held pose,
  :func:`fusion.planar._ekf_core.reported_pose_covariance`), the refs of the last applied
  IMU sample and wheel frame (-1: none yet), the stamp of the wheel frame or twist that
  triggered the record (NaN for a rate tick), the EKF status of the triggering event and the
  flags of the last wheel frame or twist (:data:`fusion.planar._ekf_core.FLAG_ZUPT`,
  ``FLAG_SLIP``, ``FLAG_FAULT``);
- ``trace`` rows for every applied event whose kind is in ``trace_mask`` (bit ``1 << kind``):
  the event's effective time, the state row of
  :meth:`fusion.planar.ekf.PlanarEKF.process_batch` (state, diag(P), pose cross terms;
  :data:`fusion.planar._ekf_core.ROW_WIDTH` columns) and
  the left and right ticks of the last applied wheel frame (NaN before the first) and the
  flags of the last wheel frame or twist.
"""

from __future__ import annotations

import math

import numpy as np

from fusion._jit import njit
from fusion.planar._ekf_core import (
    A_FLAGS,
    A_T,
    EV_ACCEL,
    EV_GYRO,
    EV_TWIST,
    EV_WHEELS,
    EV_WHEELS_SLIP,
    NX,
    ROW_WIDTH,
    reported_pose_covariance,
    step_core,
    write_state_row,
)

__all__ = ["PUB_WIDTH", "SCHED_SIZE", "TRACE_WIDTH", "T_FLAGS", "T_LEFT", "T_RIGHT", "new_sched",
           "run_events", "source_of", "write_pub_row"]

# sched indices
S_HEAP_N = 0
S_SEQ = 1
S_NEWEST = 2
S_MARK = 3  # 3 sources: imu, wheels, twist
S_USE = 6  # 1.0 when the source takes part in the watermark
S_NEXT_TICK = 9  # NaN: not set yet
S_LAST_GYRO = 10
S_LAST_WHEEL = 11
S_LAST_LEFT = 12  # ticks of the last applied wheel frame (NaN: none yet)
S_LAST_RIGHT = 13
SCHED_SIZE = 14

# heap columns
H_T = 0
H_A = 1
H_B = 2
H_STAMP = 3
H_SEQ = 0
H_KIND = 1
H_REF = 2

# pub columns
U_T = 0
U_X = 1
U_P = U_X + NX
U_LAST_GYRO = U_P + 25
U_LAST_WHEEL = U_LAST_GYRO + 1
U_STAMP = U_LAST_WHEEL + 1
U_STATUS = U_STAMP + 1
U_FLAGS = U_STATUS + 1
PUB_WIDTH = U_FLAGS + 1

# trace columns: effective time, the state row, left and right ticks, flags
T_LEFT = 1 + ROW_WIDTH
T_RIGHT = T_LEFT + 1
T_FLAGS = T_RIGHT + 1
TRACE_WIDTH = T_FLAGS + 1


def new_sched(use_imu: bool, use_wheels: bool, use_twist: bool) -> np.ndarray:
    """A fresh ``sched`` vector for the given watermark sources."""
    s = np.zeros(SCHED_SIZE)
    s[S_NEWEST] = -math.inf
    s[S_MARK:S_MARK + 3] = -math.inf
    s[S_USE:S_USE + 3] = (float(use_imu), float(use_wheels), float(use_twist))
    s[S_NEXT_TICK] = math.nan
    s[S_LAST_GYRO] = -1.0
    s[S_LAST_WHEEL] = -1.0
    s[S_LAST_LEFT] = math.nan
    s[S_LAST_RIGHT] = math.nan
    return s


@njit
def source_of(kind):
    """Watermark source of an event kind: 0 IMU (gyro, forward specific force), 1 wheels,
    2 twist."""
    if kind == EV_GYRO or kind == EV_ACCEL:
        return 0
    if kind == EV_WHEELS or kind == EV_WHEELS_SLIP:
        return 1
    return 2


@njit
def _before(heap_f, heap_i, i, j):
    """Heap order: effective time, then arrival."""
    ti = heap_f[i, H_T]
    tj = heap_f[j, H_T]
    if ti < tj:
        return True
    if ti > tj:
        return False
    return heap_i[i, H_SEQ] < heap_i[j, H_SEQ]


@njit
def _swap(heap_f, heap_i, i, j):
    for c in range(heap_f.shape[1]):
        v = heap_f[i, c]
        heap_f[i, c] = heap_f[j, c]
        heap_f[j, c] = v
    for c in range(heap_i.shape[1]):
        w = heap_i[i, c]
        heap_i[i, c] = heap_i[j, c]
        heap_i[j, c] = w


@njit
def _heap_push(heap_f, heap_i, n, t, a, b, stamp, seq, kind, ref):
    heap_f[n, H_T] = t
    heap_f[n, H_A] = a
    heap_f[n, H_B] = b
    heap_f[n, H_STAMP] = stamp
    heap_i[n, H_SEQ] = seq
    heap_i[n, H_KIND] = kind
    heap_i[n, H_REF] = ref
    i = n
    while i > 0:
        parent = (i - 1) // 2
        if _before(heap_f, heap_i, i, parent):
            _swap(heap_f, heap_i, i, parent)
            i = parent
        else:
            break


@njit
def _heap_pop(heap_f, heap_i, n):
    """Move the top to row ``n - 1`` (the caller reads it there) and restore the heap."""
    last = n - 1
    _swap(heap_f, heap_i, 0, last)
    i = 0
    while True:
        left = 2 * i + 1
        if left >= last:
            break
        child = left
        right = left + 1
        if right < last and _before(heap_f, heap_i, right, left):
            child = right
        if _before(heap_f, heap_i, child, i):
            _swap(heap_f, heap_i, child, i)
            i = child
        else:
            break


@njit
def write_pub_row(pub, n_pub, x, P, aux, sched, stamp, status):
    row = pub[n_pub]
    row[U_T] = aux[A_T]
    for i in range(NX):
        row[U_X + i] = x[i]
    for i in range(5):
        for j in range(5):
            if i < 3 and j < 3:  # the held pose's (fusion.planar._ekf_core.held_pose_offset)
                row[U_P + 5 * i + j] = reported_pose_covariance(P, aux, i, j)
            else:
                row[U_P + 5 * i + j] = P[i, j]
    row[U_LAST_GYRO] = sched[S_LAST_GYRO]
    row[U_LAST_WHEEL] = sched[S_LAST_WHEEL]
    row[U_STAMP] = stamp
    row[U_STATUS] = status
    row[U_FLAGS] = aux[A_FLAGS]
    return n_pub + 1


@njit
def _tick(pub, n_pub, x, P, aux, sched, rate, status):
    """A record when the filter time has crossed the next multiple of ``1/rate``."""
    t = aux[A_T]
    if math.isnan(t):
        return n_pub
    if math.isnan(sched[S_NEXT_TICK]):
        sched[S_NEXT_TICK] = t
    if t >= sched[S_NEXT_TICK]:
        n_pub = write_pub_row(pub, n_pub, x, P, aux, sched, math.nan, status)
        sched[S_NEXT_TICK] = (math.floor(t * rate + 1e-9) + 1) / rate
    return n_pub


@njit
def _apply(heap_f, heap_i, row, x, P, aux, par, sched, rate, trace_mask, pub, n_pub, trace,
           n_trace):
    """Apply the released event stored at heap row ``row``; returns ``(n_pub, n_trace)``."""
    kind = heap_i[row, H_KIND]
    t = heap_f[row, H_T]
    status = step_core(x, P, aux, par, kind, t, heap_f[row, H_A], heap_f[row, H_B])
    if kind == EV_GYRO:
        sched[S_LAST_GYRO] = heap_i[row, H_REF]
        if rate > 0.0:
            n_pub = _tick(pub, n_pub, x, P, aux, sched, rate, status)
    elif kind == EV_WHEELS or kind == EV_WHEELS_SLIP or kind == EV_TWIST:
        if kind != EV_TWIST:
            sched[S_LAST_WHEEL] = heap_i[row, H_REF]
            sched[S_LAST_LEFT] = heap_f[row, H_A]
            sched[S_LAST_RIGHT] = heap_f[row, H_B]
        if rate > 0.0:
            n_pub = _tick(pub, n_pub, x, P, aux, sched, rate, status)
        else:
            n_pub = write_pub_row(pub, n_pub, x, P, aux, sched, heap_f[row, H_STAMP], status)
    if (trace_mask >> kind) & 1:
        out = trace[n_trace]
        out[0] = t
        write_state_row(out, 1, x, P, aux)
        out[T_LEFT] = sched[S_LAST_LEFT]
        out[T_RIGHT] = sched[S_LAST_RIGHT]
        out[T_FLAGS] = aux[A_FLAGS]
        n_trace += 1
    return n_pub, n_trace


@njit
def run_events(kinds, t_eff, aa, bb, stamps, refs, flush, heap_f, heap_i, sched, x, P, aux,
               par, window, rate, trace_mask, pub, trace):
    """Push events (arrival order) through the reorder heap into the EKF; see the module
    docstring. ``flush``: release everything held at the end. ``rate`` <= 0: a record per
    wheel frame or twist, else at this rate of filter time (Hz).

    Returns ``(n_pub, n_trace)``: rows written to ``pub`` and ``trace``.
    """
    n_pub = 0
    n_trace = 0
    n = int(sched[S_HEAP_N])
    for k in range(kinds.shape[0]):
        kind = kinds[k]
        t = t_eff[k]
        _heap_push(heap_f, heap_i, n, t, aa[k], bb[k], stamps[k], int(sched[S_SEQ]), kind,
                   refs[k])
        n += 1
        sched[S_SEQ] += 1.0
        if t > sched[S_NEWEST]:
            sched[S_NEWEST] = t
        src = source_of(kind)
        if sched[S_USE + src] != 0.0:
            sched[S_MARK + src] = t
        watermark = math.inf
        for s in range(3):
            if sched[S_USE + s] != 0.0 and sched[S_MARK + s] < watermark:
                watermark = sched[S_MARK + s]
        # released by the watermark (nothing older can still come), then by the window
        while n > 0 and heap_f[0, H_T] <= watermark:
            _heap_pop(heap_f, heap_i, n)
            n -= 1
            n_pub, n_trace = _apply(heap_f, heap_i, n, x, P, aux, par, sched, rate, trace_mask,
                                    pub, n_pub, trace, n_trace)
        while n > 0 and heap_f[0, H_T] <= sched[S_NEWEST] - window:
            _heap_pop(heap_f, heap_i, n)
            n -= 1
            n_pub, n_trace = _apply(heap_f, heap_i, n, x, P, aux, par, sched, rate, trace_mask,
                                    pub, n_pub, trace, n_trace)
    if flush:
        while n > 0:
            _heap_pop(heap_f, heap_i, n)
            n -= 1
            n_pub, n_trace = _apply(heap_f, heap_i, n, x, P, aux, par, sched, rate, trace_mask,
                                    pub, n_pub, trace, n_trace)
    sched[S_HEAP_N] = n
    return n_pub, n_trace
