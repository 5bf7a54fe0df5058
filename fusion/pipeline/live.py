"""Live operation: source threads (the chassis link, the MPU6050, any :class:`Source`) feeding
one :class:`fusion.pipeline.core.FusionPipeline` through one bounded queue.

Nothing is lost without a count (issue 12):

- **Queue**: at most ``max_queue`` events wait. When producers outrun the consumer the
  overflow policy decides which event goes: ``"drop_oldest"`` (default: live data, the newest
  matters) or ``"drop_newest"``; either way it is counted in
  :attr:`LiveRunner.queue_overflow` (per source in :attr:`LiveRunner.overflow_by_source`).
  Events leave the queue in the order they were put (a burst of any size keeps its order;
  the consumer never puts an event back and never blocks on the queue).
- **Source faults**: an unexpected exception in a source thread is reported with its
  traceback (``on_fault(name, text)``; by default the ``fusion.live`` logger), the source
  is restarted after a backoff (``backoff`` s of wall time, doubling up to
  ``max_backoff``), and after ``max_restarts`` consecutive failed tries :meth:`LiveRunner.run`
  raises :class:`SourceFailedError`: the run never goes on silently without a source.
- **Conservation**: :meth:`LiveRunner.ledger` gives events in (per source) = fused + held +
  counted by reason (the pipeline's reasons plus ``queue_overflow``, plus what still waits in
  the queue), with ``unaccounted`` that must be 0.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from fusion.pipeline.core import FusionPipeline

__all__ = ["OVERFLOW_POLICIES", "ImuFifoSource", "LinkSource", "LiveRunner", "Source",
           "SourceFailedError", "SourceHealth"]

#: What a full queue drops: the oldest waiting event, or the one being put.
OVERFLOW_POLICIES = ("drop_oldest", "drop_newest")
_log = logging.getLogger("fusion.live")


class Source(Protocol):
    """An event source run in its own thread by :class:`LiveRunner`.

    ``read()`` returns the events available now (blocking at most a fraction of a second),
    oldest first; ``restart()`` is called after ``read()`` raised, before reading again. An
    optional ``start()`` is called by :meth:`LiveRunner.start` before the threads start; a
    source that wraps another has it as ``inner`` (so its counters are found).
    """

    name: str

    def read(self) -> Iterable[Any]: ...

    def restart(self) -> None: ...


class SourceFailedError(RuntimeError):
    """A source kept failing: it was restarted ``max_restarts`` times without success. The
    message names the source and its last error; ``__cause__`` is that exception."""


@dataclass
class SourceHealth:
    """A source's counters.

    Attributes:
        name: the source's name (``"imu"``, ``"wheels"``, ...).
        events: events it put on the queue (accepted or dropped there).
        overflow: its events the full queue dropped.
        faults: unexpected exceptions its thread caught (each reported with its traceback).
        restarts: restarts after a fault.
        failed: it failed ``max_restarts`` consecutive tries; the run stops.
        last_error: the traceback text of the newest fault (None: none yet).
    """

    name: str
    events: int = 0
    overflow: int = 0
    faults: int = 0
    restarts: int = 0
    failed: bool = False
    last_error: str | None = None


class ImuFifoSource:
    """An MPU6050's FIFO (:class:`drivers.mpu6050.MPU6050`), read every ``interval`` s of its
    clock. A read the driver's retries could not save (:class:`drivers.mpu6050.MPU6050Error`)
    is counted in :attr:`errors` (``last_error`` its message) and the loop goes on; the
    samples the driver reports lost (FIFO overflow, failed reads) are counted in :attr:`lost`
    (missing upstream: they never reach the queue)."""

    name = "imu"

    def __init__(self, imu: Any, interval: float = 0.02) -> None:
        self.imu, self.interval = imu, float(interval)
        self.errors = 0
        self.lost = 0
        self.overflows = 0
        self.last_error: str | None = None

    def start(self) -> None:
        self.imu.enable_fifo()

    def read(self) -> list[Any]:
        from drivers.mpu6050 import MPU6050Error

        self.imu.clock.sleep(self.interval)
        try:
            r = self.imu.read_fifo()
        except MPU6050Error as exc:  # retried by the driver already: reported and counted
            self.errors += 1
            self.last_error = str(exc)
            return []
        self.lost += r.lost
        self.overflows += int(r.overflow)
        return r.samples

    def restart(self) -> None:
        self.imu.enable_fifo()  # resets the FIFO and its clock


class LinkSource:
    """A chassis link's frames (:class:`drivers.serial_link.ChassisLink`, which reconnects
    a vanished port by itself)."""

    name = "wheels"

    def __init__(self, link: Any) -> None:
        self.link = link

    def read(self) -> list[Any]:
        frame = self.link.get(timeout=0.05)
        return [] if frame is None else [frame]

    def restart(self) -> None:
        pass


class LiveRunner:
    """Feeds a :class:`FusionPipeline` from live sources in arrival order.

    Each source has a thread that puts its events on one bounded queue; :meth:`run` (in the
    calling thread) takes them off in order and pushes them into the pipeline, so the
    pipeline itself stays single-threaded.

    Args:
        pipeline: an open pipeline.
        link: a started :class:`drivers.serial_link.ChassisLink` (its frames are forwarded),
            or None.
        imu: a :class:`drivers.mpu6050.MPU6050` (its FIFO is enabled here and read every
            ``fifo_interval`` s of its clock), or None.
        sources: further :class:`Source` objects.
        fifo_interval: s between FIFO reads (the 1024-byte FIFO holds 85 samples).
        max_queue: events kept waiting at most.
        overflow: what a full queue drops, one of :data:`OVERFLOW_POLICIES`.
        max_restarts: consecutive failed tries of a source before the run stops.
        backoff, max_backoff: wall s before the first restart, doubling up to ``max_backoff``.
        on_fault: ``callback(source_name, traceback_text)`` in the source's thread (default:
            an error on the ``fusion.live`` logger).

    Attributes:
        imu_errors: FIFO reads that failed after the driver's retries (the loop goes on);
            ``last_imu_error`` the newest message (of every :class:`ImuFifoSource`).
        imu_lost: IMU samples the driver reported lost (overflow, failed reads): known missing
            upstream, never queued.
        queue_overflow: events the full queue dropped (``dropped`` is the same count).
        events_pushed: events handed to the pipeline.
        health: :class:`SourceHealth` per source name.
    """

    def __init__(self, pipeline: FusionPipeline, *, link: Any = None, imu: Any = None,
                 sources: Iterable[Source] = (), fifo_interval: float = 0.02,
                 max_queue: int = 100_000, overflow: str = "drop_oldest",
                 max_restarts: int = 5, backoff: float = 0.05, max_backoff: float = 2.0,
                 on_fault: Callable[[str, str], None] | None = None) -> None:
        if not fifo_interval > 0:
            raise ValueError(f"fifo_interval must be > 0 s, got {fifo_interval!r}")
        if not (isinstance(max_queue, int) and max_queue >= 1):
            raise ValueError(f"max_queue must be an integer >= 1, got {max_queue!r}")
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        if not (isinstance(max_restarts, int) and max_restarts >= 0):
            raise ValueError(f"max_restarts must be an integer >= 0, got {max_restarts!r}")
        if not (0 <= backoff <= max_backoff):
            raise ValueError(f"need 0 <= backoff <= max_backoff s, got {backoff!r}, "
                             f"{max_backoff!r}")
        self.pipeline = pipeline
        self.link = link
        self.imu = imu
        self.fifo_interval = float(fifo_interval)
        self.max_queue = max_queue
        self.overflow = overflow
        self.max_restarts = max_restarts
        self.backoff, self.max_backoff = float(backoff), float(max_backoff)
        self._on_fault = on_fault
        srcs: list[Any] = []
        if imu is not None:
            srcs.append(ImuFifoSource(imu, self.fifo_interval))
        if link is not None:
            srcs.append(LinkSource(link))
        srcs.extend(sources)
        names = [s.name for s in srcs]
        if len(set(names)) != len(names):
            raise ValueError(f"source names must be unique, got {names}")
        self._sources = srcs
        self.health = {s.name: SourceHealth(s.name) for s in srcs}
        self._q: collections.deque = collections.deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._failure: SourceFailedError | None = None
        self.queue_overflow = 0
        self.events_pushed = 0

    # -- counters -----------------------------------------------------------------------------
    def _unwrapped(self, kind: type) -> list[Any]:
        """The sources of type ``kind``, found through wrappers' ``inner``."""
        found = []
        for src in self._sources:
            while not isinstance(src, kind) and hasattr(src, "inner"):
                src = src.inner
            if isinstance(src, kind):
                found.append(src)
        return found

    def _imu_sources(self) -> list[ImuFifoSource]:
        return self._unwrapped(ImuFifoSource)

    @property
    def imu_errors(self) -> int:
        return sum(s.errors for s in self._imu_sources())

    @property
    def imu_lost(self) -> int:
        return sum(s.lost for s in self._imu_sources())

    @property
    def imu_overflows(self) -> int:
        return sum(s.overflows for s in self._imu_sources())

    @property
    def last_imu_error(self) -> str | None:
        return next((s.last_error for s in self._imu_sources() if s.last_error), None)

    @property
    def dropped(self) -> int:
        """Events the full queue dropped (:attr:`queue_overflow`)."""
        return self.queue_overflow

    @property
    def queued(self) -> int:
        """Events waiting in the queue now."""
        return len(self._q)

    @property
    def events_in(self) -> int:
        """Events the sources put on the queue."""
        return sum(h.events for h in self.health.values())

    def ledger(self) -> dict[str, Any]:
        """Where every event the sources delivered went: ``{"in", "fused", "held",
        "queued", "dropped": {reason: n}, "unaccounted"}`` (see
        :meth:`fusion.pipeline.core.FusionPipeline.ledger`; ``queued`` still waits here,
        ``dropped["queue_overflow"]`` was dropped here). ``unaccounted`` is
        ``in - fused - held - queued - sum(dropped)`` and must be 0. Events handed to the
        pipeline outside this runner are not counted in ``in`` (push nothing else into it)."""
        with self._cond:
            queued = len(self._q)
            events_in = self.events_in
            overflow = self.queue_overflow
        p = self.pipeline.ledger()
        dropped = {**p["dropped"], "queue_overflow": overflow}
        unaccounted = events_in - p["fused"] - p["held"] - queued - sum(dropped.values())
        return {"in": events_in, "fused": p["fused"], "held": p["held"], "queued": queued,
                "dropped": dropped, "unaccounted": unaccounted}

    # -- producers ------------------------------------------------------------------------------
    def _put_all(self, name: str, events: Iterable[Any]) -> None:
        health = self.health[name]
        q = self._q
        with self._cond:
            for ev in events:
                health.events += 1
                if len(q) >= self.max_queue:
                    self.queue_overflow += 1
                    if self.overflow == "drop_newest":
                        health.overflow += 1
                        continue
                    old_name, _ = q.popleft()
                    self.health[old_name].overflow += 1
                q.append((name, ev))
            self._cond.notify()

    def _source_loop(self, src: Any) -> None:
        health = self.health[src.name]
        tries = 0  # consecutive failed tries
        restart_due = False
        while not self._stop.is_set():
            try:
                if restart_due:
                    health.restarts += 1
                    src.restart()
                    restart_due = False
                events = src.read()
                if events:
                    self._put_all(src.name, events)
                tries = 0
            except Exception as exc:
                tries += 1
                health.faults += 1
                health.last_error = traceback.format_exc()
                self._report(src.name, f"source {src.name!r} raised (try {tries} of "
                                       f"{self.max_restarts + 1}):\n{health.last_error}")
                if tries > self.max_restarts:
                    health.failed = True
                    err = SourceFailedError(
                        f"source {src.name!r} failed {tries} times in a row, last: "
                        f"{type(exc).__name__}: {exc}")
                    err.__cause__ = exc
                    with self._cond:
                        self._failure = self._failure or err
                        self._cond.notify()
                    return
                self._stop.wait(min(self.backoff * 2 ** (tries - 1), self.max_backoff))
                restart_due = True

    def _report(self, name: str, text: str) -> None:
        if self._on_fault is not None:
            self._on_fault(name, text)
        else:
            _log.error("%s", text)

    def start(self) -> LiveRunner:
        """Start the sources (the IMU's FIFO is enabled) and their threads."""
        for src in self._sources:
            start = getattr(src, "start", None)
            if start is not None:
                start()
        for src in self._sources:
            self._threads.append(threading.Thread(target=self._source_loop, args=(src,),
                                                  name=f"source-{src.name}", daemon=True))
        for th in self._threads:
            th.start()
        return self

    # -- consumer -------------------------------------------------------------------------------
    def _take(self, limit: int, timeout: float) -> list[tuple[str, Any]]:
        """Up to ``limit`` events, oldest first (waits up to ``timeout`` s for the first)."""
        q = self._q
        with self._cond:
            if not q and timeout > 0 and self._failure is None:
                self._cond.wait(timeout)
            n = min(limit, len(q))
            return [q.popleft() for _ in range(n)]

    def _check_sources(self) -> None:
        if self._failure is not None:
            raise self._failure

    def run(self, until: Callable[[], bool] | None = None, poll: float = 0.05,
            on_event: Callable[[Any], None] | None = None, batch: int = 1000) -> None:
        """Push events into the pipeline until ``until()`` is true or :meth:`stop` is
        called. ``until`` is called after each batch of at most ``batch`` events and at least
        every ``poll`` wall seconds (a place to send commands); ``on_event(ev)`` sees each
        event before the pipeline does. Ctrl-C (KeyboardInterrupt) propagates; the events of
        the batch in hand that the pipeline had not yet counted go back to the front of the
        queue (:meth:`stop` pushes them), so the ledger loses none. An event interrupted
        inside the pipeline's own push may still show as unaccounted: to stop without that,
        let ``until`` return True (``fusion run`` turns Ctrl-C and SIGTERM into that).

        Raises:
            SourceFailedError: a source failed ``max_restarts + 1`` times in a row (the
                events it delivered before are in the pipeline; call :meth:`stop` to push
                the rest and close the pipeline).
        """
        push = self.pipeline.push
        stats = self.pipeline.stats
        while not self._stop.is_set() and not (until is not None and until()):
            self._check_sources()
            taken = self._take(batch, poll)
            done = 0  # events of ``taken`` the pipeline has counted
            try:
                for _name, ev in taken:
                    if on_event is not None:
                        on_event(ev)
                    before = stats.events_in
                    try:
                        push(ev)
                    finally:
                        done += stats.events_in != before
                    self.events_pushed += 1
            except BaseException:
                with self._cond:  # not lost: the front of the queue again
                    self._q.extendleft(reversed(taken[done:]))
                raise
        self._check_sources()

    def stop(self) -> None:
        """Stop the source threads and push what they had queued (errors propagate)."""
        self._stop.set()
        for th in self._threads:
            th.join(timeout=5.0)
        self._threads.clear()
        while True:
            taken = self._take(10_000, 0.0)
            if not taken:
                break
            if self.pipeline.is_open:
                for _name, ev in taken:
                    self.pipeline.push(ev)
                    self.events_pushed += 1
            else:  # put back: the ledger still counts them as queued
                with self._cond:
                    self._q.extendleft(reversed(taken))
                break

    def link_parser_counts(self) -> dict[str, int]:
        """What the chassis link's frame parser refused on the current connection (bytes,
        :class:`drivers.chassis.ParserStats`): ``checksum_failures``, ``implausible``
        (checksum-valid frames beyond its bound or with a sign byte other than 0/1) and
        ``bytes_skipped``; empty without a link. Frames refused mid-run were said nowhere
        but the missing count (an independent probe's frames of 0xFFFFFF ticks)."""
        parser = getattr(self.link, "parser", None)
        st = getattr(parser, "stats", None)
        if st is None:
            return {}
        return {"checksum_failures": int(st.checksum_failures),
                "implausible": int(st.implausible), "bytes_skipped": int(st.bytes_skipped)}

    def status(self) -> dict[str, Any]:
        """A status record: the ledger, per-source health, what is known missing upstream
        (IMU samples the driver lost, wheel frames missing, singly or in gaps, frames the
        link's own queue dropped), latency percentiles (s, robot time)."""
        p50, p99 = self.pipeline.latency_percentiles(50, 99)
        return {"ledger": self.ledger(),
                "sources": {n: dict(h.__dict__, last_error=None if h.last_error is None
                                    else h.last_error.strip().splitlines()[-1])
                            for n, h in self.health.items()},
                "imu_errors": self.imu_errors, "imu_lost_upstream": self.imu_lost,
                "wheel_frames_missing_upstream": self.pipeline.stats.frames_missing,
                "link_queue_dropped_upstream": sum(
                    getattr(s.link, "frames_dropped", 0) for s in self._unwrapped(LinkSource)),
                "link_parser": self.link_parser_counts(),
                "latency_p50": p50, "latency_p99": p99, "wall_time": time.time()}
