"""Serial transport for the miiboo chassis (DATA-uart2), on pyserial.

:class:`ChassisLink` opens the port with ``serial.serial_for_url`` (a device path such as
``/dev/ttyUSB0`` or a stable udev symlink, ``socket://host:port``, ``loop://``), runs one reader
thread that feeds :class:`drivers.chassis.WheelFrameParser`, and delivers every accepted frame
as a :class:`fusion.types.samples.WheelTicks` stamped on the host clock (``time.monotonic`` by
default, s). The stamp is the estimated arrival time of the frame's last byte: the read's
return time minus the transmission time (10 bits per byte at ``baudrate``) of the bytes that
came after it in the same read, but never earlier than the previous read's return
(:class:`drivers.chassis.FrameStamper`, the rule :func:`fusion.io.uart2.read_uart2_capture` applies
to a recorded capture). ``on_read(t, data)`` sees every read (empty ones too), so a live
session can be recorded with :class:`fusion.io.uart2.Uart2CaptureWriter` and replayed to the same
frames and stamps.

Robustness (a robot runs for hours):

- **Liveness**: no frame for ``silence_periods`` sampling periods since the last frame (or
  for :data:`STARTUP_SILENCE` s since the port opened) raises a ``"silent"`` event saying
  what came instead (nothing, or bytes that make no frame); the next frame raises
  ``"alive"``.
- **Frame period**: frames whose median interval over the first :data:`PERIOD_CHECK_SPAN` s
  of a connection is more than :data:`PERIOD_TOLERANCE` off ``period`` raise ``"period"``
  once per connection: the ticks of a frame are per the board's period, and the host
  divides by ``period``.
- **Stale commands**: when no wheel target has been sent for ``command_timeout`` s and the last
  target was not zero, the link sends a stop frame (0, 0) and raises ``"command_stale"``; the
  firmware would otherwise keep driving at the last target for ever.
- **Reconnect**: when the port vanishes (USB unplugged: the read fails) the link raises
  ``"disconnected"``, retries every ``reconnect_interval`` s, raises ``"connected"`` when the
  port is back, and resumes (a fresh parser; the current target is re-sent if not stale).
- **Clean close**: :meth:`ChassisLink.close` stops the thread, sends a stop frame if asked,
  and closes the port. The link is a context manager.

Events are :class:`LinkEvent` objects, delivered to ``on_event`` (called in the reader thread)
and kept in :attr:`ChassisLink.events` (a bounded deque).
"""

from __future__ import annotations

import collections
import contextlib
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import serial

from drivers.chassis import FRAME_LEN, FrameStamper, WheelFrameParser, encode_wheel_frame
from fusion.types.samples import WheelTicks

try:  # POSIX: pyserial's flush (tcdrain) raises termios.error, no OSError, on a dead port
    from termios import error as _TermiosError
except ImportError:  # Windows
    class _TermiosError(Exception):  # type: ignore[no-redef]
        """Never raised: no termios here."""

#: What a port that went away raises (an independent probe's pty closed and reopened: the
#: stop frame written at shutdown raised termios.error from tcdrain and ended the run with a
#: traceback).
PORT_ERRORS = (serial.SerialException, OSError, _TermiosError)
#: s of frames over which a connection's frame period is measured (after its first read,
#: which may bring a backlog).
PERIOD_CHECK_SPAN = 2.0
#: s a new connection may wait for its first frame before ``"silent"``: boards that reset
#: when the port opens (a USB adapter's DTR) start sending a second or so later.
STARTUP_SILENCE = 2.0
#: Share of ``period`` the measured frame period may be off before ``"period"`` is raised (an
#: independent probe's board at 20 and 80 ms against 40 configured: speeds read at half and
#: twice, nothing said).
PERIOD_TOLERANCE = 0.25

__all__ = ["ChassisLink", "LinkEvent"]


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """Something that happened on the link.

    Attributes:
        t: host time, s (the link's clock).
        kind: ``"connected"``, ``"disconnected"``, ``"open_failed"``, ``"silent"``, ``"alive"``,
            ``"command_stale"``, ``"write_failed"``, ``"closed"``.
        message: human-readable detail naming the port.
    """

    t: float
    kind: str
    message: str


class ChassisLink:
    """Reader thread + command writer for the DATA-uart2 serial port.

    Args:
        url: anything ``serial.serial_for_url`` accepts (device path, ``socket://``, ``loop://``).
        baudrate: 115200 on the miiboo board.
        period: firmware sampling period ``encode_sampling_time``, s.
        silence_periods: frames missing for this many periods -> ``"silent"``.
        command_timeout: s without a new wheel target before a non-zero target is stopped
            (``None``: never).
        reconnect_interval: s between attempts to reopen a vanished port.
        parser_factory: builds the frame parser (e.g. with a bound from the robot's geometry).
        on_frame: callback ``f(WheelTicks)`` in the reader thread (keep it short).
        on_event: callback ``f(LinkEvent)`` in the reader thread.
        on_read: callback ``f(t, data)`` in the reader thread for every read of the port,
            before its frames are delivered: the read's return time (s, the link's clock)
            and its bytes (``b""`` for a read that timed out). ``Uart2CaptureWriter.write``
            fits: the capture replays to the frames and stamps the link delivered.
        clock: the host clock, s.
        queue_size: frames kept for :meth:`get` (the oldest are dropped and counted beyond);
            0 keeps none (use ``on_frame`` alone).
    """

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 115200,
        period: float = 0.04,
        silence_periods: float = 5.0,
        command_timeout: float | None = 0.5,
        reconnect_interval: float = 0.2,
        parser_factory: Callable[[], WheelFrameParser] = WheelFrameParser,
        on_frame: Callable[[WheelTicks], None] | None = None,
        on_event: Callable[[LinkEvent], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        queue_size: int = 100_000,
        on_read: Callable[[float, bytes], None] | None = None,
    ) -> None:
        positive = {"period": period, "silence_periods": silence_periods,
                    "reconnect_interval": reconnect_interval}
        if command_timeout is not None:
            positive["command_timeout"] = command_timeout
        for name, value in positive.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{url}: {name} must be finite and > 0, got {value!r}")
        if isinstance(baudrate, bool) or not (isinstance(baudrate, int) and baudrate > 0):
            raise ValueError(f"{url}: baudrate must be a whole number > 0, got {baudrate!r}")
        self.url = url
        self.baudrate = int(baudrate)
        self.period = float(period)
        self.silence_periods = float(silence_periods)
        self.command_timeout = command_timeout
        self.reconnect_interval = float(reconnect_interval)
        self._parser_factory = parser_factory
        self.parser = parser_factory()
        self._on_frame = on_frame
        self._on_event = on_event
        self._on_read = on_read
        self._clock = clock
        if queue_size < 0:
            raise ValueError(f"queue_size must be >= 0, got {queue_size!r}")
        self._queue_size = int(queue_size)
        self._frames: queue.Queue[WheelTicks] = queue.Queue(maxsize=max(1, queue_size))
        self.events: collections.deque[LinkEvent] = collections.deque(maxlen=1000)
        self.frames_dropped = 0
        self.frames_received = 0
        self.reconnects = 0
        self._port: serial.SerialBase | None = None
        self._lock = threading.Lock()  # guards _port for writes
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = threading.Event()
        self._target = (0, 0)
        self._target_time: float | None = None
        self._stale_sent = False
        self._last_frame_time: float | None = None
        self._new_connection_checks(None)
        self._ever_connected = False
        self._stamper = FrameStamper(self.parser, baudrate=self.baudrate, period=self.period)

    # -- lifecycle --
    def start(self, wait: float | None = 2.0) -> ChassisLink:
        """Start the reader thread; wait up to ``wait`` s for the port to open.

        Raises:
            OSError: the port could not be opened within ``wait`` s (the thread keeps trying).
        """
        if self._thread is not None:
            raise RuntimeError("ChassisLink already started")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"ChassisLink({self.url})",
                                        daemon=True)
        self._thread.start()
        if wait is not None and not self._connected.wait(wait):
            last = next((e for e in reversed(self.events) if e.kind == "open_failed"), None)
            detail = f": {last.message}" if last else ""
            raise OSError(f"chassis port {self.url} did not open within {wait} s{detail}")
        return self

    def close(self, stop: bool = True) -> None:
        """Stop the reader, send a stop frame (if ``stop`` and connected), close the port."""
        if stop:
            self._write(encode_wheel_frame(0, 0))
        self._stop.set()
        port = self._port
        if port is not None:
            with contextlib.suppress(Exception):
                port.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            if self._port is not None:
                with contextlib.suppress(Exception):
                    self._port.close()
                self._port = None
        self._connected.clear()
        self._emit("closed", f"{self.url} closed")

    def __enter__(self) -> ChassisLink:
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- status --
    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._connected.is_set()

    @property
    def alive(self) -> bool:
        """True when a frame arrived within the last ``silence_periods`` periods."""
        t = self._last_frame_time
        return t is not None and self._clock() - t <= self.silence_periods * self.period

    @property
    def last_frame_time(self) -> float | None:
        return self._last_frame_time

    # -- commands --
    def send_ticks(self, left: int, right: int) -> bool:
        """Send target ticks per period (left, right). Returns False if the port is down
        (the target is kept and sent when the port comes back, unless it is stale by then).

        Raises:
            ValueError: a target outside the 24-bit wire range.
        """
        frame = encode_wheel_frame(left, right)
        self._target = (int(left), int(right))
        self._target_time = self._clock()
        self._stale_sent = False
        return self._write(frame)

    def send_twist(self, v: float, w: float, params, rounding: str = "truncate") -> bool:
        """Send a body twist as seed 000's ``base_controller`` does: clamp to the
        ``cmd_vel_*_max`` limits, scale to ``wheel_speed_max`` keeping the curvature, convert to
        target ticks per period (:func:`fusion.geometry.kinematics.twist_to_ticks`).

        Args:
            v: forward speed, m/s. w: yaw rate, rad/s (CCW). params: a
                :class:`fusion.geometry.kinematics.DiffDriveParams`. rounding: ``"truncate"``
                (seed) or ``"nearest"``.
        """
        from fusion.geometry.kinematics import twist_to_ticks

        left, right = twist_to_ticks(v, w, params, rounding=rounding)
        return self.send_ticks(left, right)

    def stop(self) -> bool:
        """Send zero targets (the firmware brakes on a zero target)."""
        return self.send_ticks(0, 0)

    def _write(self, frame: bytes) -> bool:
        with self._lock:
            port = self._port
            if port is None:
                return False
            try:
                port.write(frame)
                port.flush()
            except PORT_ERRORS as exc:
                self._emit("write_failed", f"write to {self.url} failed: {exc}")
                return False
        return True

    # -- frames --
    def get(self, timeout: float | None = None) -> WheelTicks | None:
        """Next received frame (oldest first), or None after ``timeout`` s."""
        try:
            return self._frames.get(timeout=timeout)
        except queue.Empty:
            return None

    def drain(self) -> list[WheelTicks]:
        """All frames received and not yet taken."""
        out = []
        while True:
            try:
                out.append(self._frames.get_nowait())
            except queue.Empty:
                return out

    # -- reader thread --
    def _emit(self, kind: str, message: str) -> None:
        ev = LinkEvent(self._clock(), kind, message)
        self.events.append(ev)
        if self._on_event is not None:
            self._on_event(ev)

    def _open(self) -> bool:
        try:
            port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.period)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._emit("open_failed", f"cannot open chassis port {self.url}: {exc}")
            return False
        with self._lock:
            self._port = port
        self.parser = self._parser_factory()
        self._stamper = FrameStamper(self.parser, baudrate=self.baudrate, period=self.period)
        self._new_connection_checks(self._clock())
        if self._ever_connected:
            self.reconnects += 1
        self._ever_connected = True
        self._emit("connected", f"chassis port {self.url} open")  # event first, then the flag
        self._connected.set()
        # resume the current target if it is still fresh
        if self._target != (0, 0) and not self._command_is_stale(self._clock()):
            self._write(encode_wheel_frame(*self._target))
        return True

    def _new_connection_checks(self, opened: float | None) -> None:
        """Start the liveness and period checks afresh for a connection opened at ``opened``
        (None: none yet): it is silent, or off its period, only by its own frames."""
        self._opened_time = opened
        self._bytes_at_last_frame = 0
        self._silent = False
        self._period_stamps: list[float] | None = None  # frames of the period check
        self._period_checked = False

    def _drop_port(self, reason: str) -> None:
        with self._lock:
            port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self._emit("disconnected", f"chassis port {self.url} lost: {reason}")
        self._connected.clear()

    def _command_is_stale(self, now: float) -> bool:
        return (
            self.command_timeout is not None
            and self._target_time is not None
            and now - self._target_time > self.command_timeout
        )

    def _deliver(self, stamped) -> None:
        t_arr, left, right, _off = stamped
        for t, lft, rgt in zip(t_arr.tolist(), left.tolist(), right.tolist()):
            sample = WheelTicks(t, int(lft), int(rgt))
            self.frames_received += 1
            self._last_frame_time = sample.t
            self._bytes_at_last_frame = self.parser.stats.bytes_in
            if self._queue_size:
                if self._frames.full():
                    with contextlib.suppress(queue.Empty):
                        self._frames.get_nowait()
                        self.frames_dropped += 1
                self._frames.put_nowait(sample)
            if self._on_frame is not None:
                self._on_frame(sample)
        if t_arr.size and self._silent:
            self._silent = False
            self._emit("alive", f"frames from {self.url} again")
        if t_arr.size:
            self._check_period(t_arr.tolist())

    def _check_period(self, stamps: list[float]) -> None:
        """Raise ``"period"`` once per connection when the median interval of its frames
        over :data:`PERIOD_CHECK_SPAN` s (from the second read on: the first may bring a
        backlog) is more than :data:`PERIOD_TOLERANCE` off ``period`` (module docstring).
        The median, not the mean: a stall and the burst that follows it move it little."""
        if self._period_checked:
            return
        if self._period_stamps is None:
            self._period_stamps = []  # after the first read
            return
        self._period_stamps.extend(stamps)
        window = self._period_stamps
        if window[-1] - window[0] < PERIOD_CHECK_SPAN:
            return
        self._period_checked = True
        measured = float(np.median(np.diff(window)))
        if abs(measured / self.period - 1.0) <= PERIOD_TOLERANCE:
            return
        st = self.parser.stats
        broken = st.checksum_failures + st.resyncs + st.implausible
        said = (f"frames from {self.url} come every {measured:.3f} s (median), the configured "
                f"period (encode_sampling_time) is {self.period:g} s")
        misread = ("a frame's ticks are counted over the board's period and divided by the "
                   f"configured one, so speeds read {measured / self.period:.2g} times their "
                   "true value")
        if measured > self.period and broken > 0.05 * len(window):
            self._emit("period", f"{said}: {broken} frames were broken, refused as "
                       "implausible or skipped on this connection, which lengthens it; if the "
                       f"board does send every {self.period:g} s they are the cause, if not "
                       f"{misread}")
        else:
            self._emit("period", f"{said}: {misread}; set encode_sampling_time to the "
                       "board's period")

    def _housekeeping(self, now: float) -> None:
        # liveness
        ref = self._last_frame_time
        limit = self.silence_periods * self.period
        if ref is None or (self._opened_time is not None and self._opened_time > ref):
            # none yet on this connection: silent since it opened, after a board's start-up
            # (many reset when the port opens)
            ref = self._opened_time
            limit = max(limit, STARTUP_SILENCE)
        if ref is not None and not self._silent and now - ref > limit:
            self._silent = True
            since = ("since it opened" if self._last_frame_time is None
                     or self._last_frame_time < ref else "")
            self._emit("silent", f"no frame from {self.url} for {now - ref:.3f} s"
                       + (f" {since}" if since else "") + self._what_came())
        # a lone deferred frame on a quiet line
        self._deliver(self._stamper.poll(now))
        # stale command
        if (
            not self._stale_sent
            and self._target != (0, 0)
            and self._command_is_stale(now)
        ):
            self._stale_sent = True
            self._target = (0, 0)
            self._write(encode_wheel_frame(0, 0))
            self._emit(
                "command_stale",
                f"no wheel target for {self.command_timeout} s: sent stop to {self.url}",
            )

    def _what_came(self) -> str:
        """What the port delivered since the last frame, for a ``"silent"`` event: nothing,
        or bytes that are no DATA-uart2 frame (an independent probe's wrong-baud-rate
        garbage, sign bytes of 2 and 5,000,000-tick frames had all gone unsaid)."""
        st = self.parser.stats
        got = st.bytes_in - self._bytes_at_last_frame
        if got <= 0:
            return ": nothing received (check the wiring and that the board is on)"
        if got < FRAME_LEN and self._last_frame_time is not None:
            return f": {got} bytes received since, a frame cut short (the board stopped)"
        parts = []
        if st.implausible:
            parts.append(f"{st.implausible} checksum-valid frames refused as implausible "
                         f"(more than {self.parser.max_ticks} ticks per period, or a sign "
                         "byte other than 0 or 1)")
        if st.checksum_failures:
            parts.append(f"{st.checksum_failures} failed the checksum")
        detail = "; ".join(parts) if parts else "no frame header FF FF with a valid checksum"
        return (f": {got} bytes received, none a frame ({detail} on this connection): the "
                "wrong --baudrate, another protocol on this port, or a board sending other "
                "frames")

    def _run(self) -> None:
        while not self._stop.is_set():
            port = self._port
            if port is None:
                if not self._open():
                    self._stop.wait(self.reconnect_interval)
                continue
            try:
                data = port.read(1)
                if data and port.in_waiting:
                    data += port.read(port.in_waiting)
            except (*PORT_ERRORS, TypeError, AttributeError) as exc:
                # TypeError/AttributeError: pyserial racing a concurrent close()
                if self._stop.is_set():
                    break
                self._drop_port(str(exc))
                continue
            now = self._clock()
            if self._on_read is not None:
                self._on_read(now, data)
            self._deliver(self._stamper.feed(now, data))
            self._housekeeping(now)
