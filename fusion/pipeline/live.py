"""Live operation: source threads (the chassis link, the MPU6050) feeding one
:class:`fusion.pipeline.core.FusionPipeline` through a queue.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

from fusion.pipeline.core import FusionPipeline

__all__ = ["LiveRunner"]


class LiveRunner:
    """Feeds a :class:`FusionPipeline` from live sources in arrival order.

    Each source has a thread that puts its events on one queue; :meth:`run` (in the calling
    thread) takes them off in order and pushes them into the pipeline, so the pipeline
    itself stays single-threaded.

    Args:
        pipeline: an open pipeline.
        link: a started :class:`drivers.serial_link.ChassisLink` (its frames are forwarded),
            or None.
        imu: a :class:`drivers.mpu6050.MPU6050` (its FIFO is enabled here and read every
            ``fifo_interval`` s of its clock), or None.
        fifo_interval: s between FIFO reads (the 1024-byte FIFO holds 85 samples).
        max_queue: events kept waiting at most (beyond, the oldest are dropped and counted).

    Attributes:
        imu_errors: FIFO reads that failed after the driver's retries (the loop goes on);
            ``last_imu_error`` the newest message.
        imu_lost: IMU samples the driver reported lost (overflow, failed reads).
        dropped: events dropped because the queue was full.
    """

    def __init__(self, pipeline: FusionPipeline, *, link: Any = None, imu: Any = None,
                 fifo_interval: float = 0.02, max_queue: int = 100_000) -> None:
        if not fifo_interval > 0:
            raise ValueError(f"fifo_interval must be > 0 s, got {fifo_interval!r}")
        self.pipeline = pipeline
        self.link = link
        self.imu = imu
        self.fifo_interval = float(fifo_interval)
        self._q: queue.Queue = queue.Queue(maxsize=max_queue)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.imu_errors = 0
        self.imu_lost = 0
        self.imu_overflows = 0
        self.last_imu_error: str | None = None
        self.dropped = 0
        self.events_pushed = 0

    def _put(self, ev: Any) -> None:
        try:
            self._q.put_nowait(ev)
        except queue.Full:
            try:
                self._q.get_nowait()
                self.dropped += 1
            except queue.Empty:
                pass
            self._q.put_nowait(ev)

    def _imu_loop(self) -> None:
        from drivers.mpu6050 import MPU6050Error

        imu = self.imu
        while not self._stop.is_set():
            imu.clock.sleep(self.fifo_interval)
            try:
                r = imu.read_fifo()
            except MPU6050Error as exc:  # retried by the driver already: report, go on
                self.imu_errors += 1
                self.last_imu_error = str(exc)
                continue
            self.imu_lost += r.lost
            self.imu_overflows += int(r.overflow)
            for sample in r.samples:
                self._put(sample)

    def _link_loop(self) -> None:
        link = self.link
        while not self._stop.is_set():
            frame = link.get(timeout=0.05)
            if frame is not None:
                self._put(frame)

    def start(self) -> LiveRunner:
        """Enable the IMU FIFO and start the source threads."""
        if self.imu is not None:
            self.imu.enable_fifo()
            self._threads.append(threading.Thread(target=self._imu_loop, name="imu-fifo",
                                                  daemon=True))
        if self.link is not None:
            self._threads.append(threading.Thread(target=self._link_loop, name="link-frames",
                                                  daemon=True))
        for th in self._threads:
            th.start()
        return self

    def run(self, until: Callable[[], bool] | None = None, poll: float = 0.05,
            on_event: Callable[[Any], None] | None = None) -> None:
        """Push events into the pipeline until ``until()`` is true or :meth:`stop` is
        called. ``until`` is called after each batch of events and at least every ``poll``
        wall seconds (a place to send commands); ``on_event(ev)`` sees each event before the
        pipeline does. Ctrl-C (KeyboardInterrupt) propagates."""
        q = self._q
        push = self.pipeline.push
        while not self._stop.is_set() and not (until is not None and until()):
            try:
                ev = q.get(timeout=poll)
            except queue.Empty:
                continue
            for _ in range(1000):  # this one and whatever else waits, without blocking
                if on_event is not None:
                    on_event(ev)
                push(ev)
                self.events_pushed += 1
                try:
                    ev = q.get_nowait()
                except queue.Empty:
                    break
            else:
                self._q.put(ev)  # keep the one taken; give until() a turn

    def stop(self) -> None:
        """Stop the source threads and push what they had queued."""
        self._stop.set()
        for th in self._threads:
            th.join(timeout=5.0)
        self._threads.clear()
        while True:
            try:
                ev = self._q.get_nowait()
            except queue.Empty:
                break
            if self.pipeline._state == "open":
                self.pipeline.push(ev)
                self.events_pushed += 1
