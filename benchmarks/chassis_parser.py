"""DATA-uart2 parser throughput and link latency.

1. Throughput (MB/s) of :class:`drivers.chassis.WheelFrameParser` on a clean stream and on a
   noisy one (a burst of line noise every 50 frames), beside two peers written here from the
   seed's description: the seed's byte-by-byte sliding window (the ``base_controller`` loop,
   in Python) and a ``bytes.find`` scanner that accepts the first checksum match. Frames lost
   and invented (by stream offset) are counted for each.
   "speed" is each parser's MB/s relative to ours with 4 KiB reads (the size of a serial
   read); "1 MiB" is the bulk case (decoding a capture file).
2. Latency over a real pty (os.openpty): from the moment the frame's last byte is written on
   the far end to the moment :class:`fusion.planar.odometry.WheelOdometry` has integrated it,
   through
   :class:`drivers.serial_link.ChassisLink` (reader thread, parser, callback); p50/p99/max.
   Frames that rule 3 defers (checksum byte 0xFF and the like, 1 in ~200) wait for the next
   frame; they are reported separately.

Run: python benchmarks/chassis_parser.py [--frames N] [--latency-frames N] [--period S]
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
import tty

import numpy as np

from drivers.chassis import WheelFrameParser, encode_wheel_frame
from drivers.serial_link import ChassisLink
from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.odometry import WheelOdometry


def make_frames(n: int, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(n) * 0.04
    left = np.round(600 * np.sin(0.3 * t) + rng.normal(0, 3, n)).astype(np.int64)
    right = np.round(600 * np.sin(0.3 * t + 0.4) + rng.normal(0, 3, n)).astype(np.int64)
    out = np.empty((n, 11), dtype=np.uint8)
    out[:, 0] = out[:, 1] = 0xFF
    for col, val in ((2, left), (6, right)):
        mag = np.abs(val)
        out[:, col] = val >= 0
        out[:, col + 1] = mag >> 16
        out[:, col + 2] = (mag >> 8) & 0xFF
        out[:, col + 3] = mag & 0xFF
    out[:, 10] = out[:, :10].sum(axis=1, dtype=np.uint32) & 0xFF
    return out


def noisy(frames: np.ndarray, rng: np.random.Generator, every: int = 50):
    """Frames with a burst every ``every`` frames: random bytes or a frame cut short (a
    dropout). Returns the stream and the offsets of the real frames."""
    pieces = []
    offsets = []
    pos = 0
    for i in range(0, frames.shape[0], every):
        chunk = frames[i : i + every]
        offsets.extend(range(pos, pos + 11 * chunk.shape[0], 11))
        pieces.append(chunk.tobytes())
        pos += 11 * chunk.shape[0]
        if rng.random() < 0.5:
            burst = rng.integers(0, 256, rng.integers(1, 30), dtype=np.uint8).tobytes()
        else:
            burst = frames[rng.integers(0, frames.shape[0])].tobytes()[: rng.integers(2, 11)]
        pieces.append(burst)
        pos += len(burst)
    return b"".join(pieces), np.array(offsets)


def seed_sliding_window(data: bytes) -> list[int]:
    """The seed's host loop: shift an 11-byte window per byte, accept any checksum match."""
    win = [0] * 11
    found = []
    for i, byte in enumerate(data):
        win.pop(0)
        win.append(byte)
        if win[0] == 0xFF and win[1] == 0xFF and (sum(win[:10]) & 0xFF) == win[10]:
            found.append(i - 10)
    return found


def find_scanner(data: bytes) -> list[int]:
    """First checksum match after each header found with bytes.find (no plausibility)."""
    found = []
    i = data.find(b"\xff\xff")
    n = len(data)
    while 0 <= i <= n - 11:
        w = data[i : i + 11]
        if sum(w[:10]) & 0xFF == w[10]:
            found.append(i)
            i = data.find(b"\xff\xff", i + 11)
        else:
            i = data.find(b"\xff\xff", i + 1)
    return found


def ours(data: bytes, chunk: int = 4096) -> list[int]:
    p = WheelFrameParser()
    found = []
    for i in range(0, len(data), chunk):
        found.extend(p.feed_arrays(data[i : i + chunk])[0].tolist())
    return found + [f.offset for f in p.finish()]


def timed(fn, data: bytes) -> tuple[float, list[int]]:
    t0 = time.perf_counter()
    found = fn(data)
    dt = time.perf_counter() - t0
    return len(data) / dt / 1e6, found


def throughput(n_frames: int) -> None:
    rng = np.random.default_rng(0)
    frames = make_frames(n_frames, rng)
    clean = frames.tobytes()
    dirty, dirty_offsets = noisy(frames, rng)
    print(f"throughput, {n_frames} frames ({len(clean) / 1e6:.1f} MB clean, "
          f"{len(dirty) / 1e6:.1f} MB with a burst of noise or a cut frame every 50 frames)")
    print(f"{'parser':<32}{'stream':<7}{'MB/s':>8}{'speed':>8}{'frames':>9}{'lost':>7}"
          f"{'invented':>9}")
    for name, data, truth in (("clean", clean, np.arange(n_frames) * 11),
                              ("noisy", dirty, dirty_offsets)):
        base = None
        for label, fn in (("ours (WheelFrameParser, 4 KiB)", ours),
                          ("ours (WheelFrameParser, 1 MiB)", lambda d: ours(d, 1 << 20)),
                          ("seed sliding window (Python)", seed_sliding_window),
                          ("bytes.find + checksum", find_scanner)):
            mbps, found = timed(fn, data)
            base = base or mbps
            got = set(found)
            want = set(truth.tolist())
            print(f"{label:<32}{name:<7}{mbps:>8.2f}{mbps / base:>7.2f}x{len(found):>9}"
                  f"{len(want - got):>7}{len(got - want):>9}")


def latency(n: int, period: float) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    name = os.ttyname(slave)
    geo = DiffDriveParams(wheel_distance=0.3, speed_ratio=5e-5, encode_sampling_time=period)
    odo = WheelOdometry(geo)
    done: list[tuple[int, float]] = []

    def on_frame(sample) -> None:
        odo.update(sample.left, sample.right, t=sample.t)
        done.append((odo.state.updates, time.monotonic()))

    rng = np.random.default_rng(1)
    values = [(int(a), int(b)) for a, b in rng.integers(-900, 900, (n, 2))]
    for i in range(0, n, 20):  # every 20th frame has checksum 0xFF: rule 3 defers it
        a, b = values[i]
        while encode_wheel_frame(a, b)[10] != 0xFF:
            a += 1
        values[i] = (a, b)
    frames = [encode_wheel_frame(a, b) for a, b in values]
    deferred = {i for i, f in enumerate(frames) if f[10] == 0xFF or b"\xff\xff" in f[1:]}
    written: list[float] = []
    link = ChassisLink(name, period=period, command_timeout=None, on_frame=on_frame).start()
    try:
        time.sleep(0.1)

        def writer() -> None:
            nxt = time.monotonic()
            for f in frames:
                nxt += period
                while time.monotonic() < nxt:
                    time.sleep(min(0.001, max(0.0, nxt - time.monotonic())))
                os.write(master, f)
                written.append(time.monotonic())

        th = threading.Thread(target=writer)
        th.start()
        th.join()
        end = time.monotonic() + 2.0
        while len(done) < n and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        link.close(stop=False)
        os.close(master)
        os.close(slave)
    lat = np.array([t_done - written[k - 1] for k, t_done in done[:n]]) * 1e3
    idx = np.arange(lat.size)
    normal = lat[[i not in deferred for i in idx]]
    late = lat[[i in deferred for i in idx]]
    print(f"\nlatency over a pty, frame last byte written -> odometry updated "
          f"({lat.size}/{n} frames at {1 / period:.0f} Hz)")
    for label, arr in (("immediate frames", normal), ("deferred frames (rule 3)", late)):
        if arr.size:
            print(f"  {label:<26} n={arr.size:<5} p50 {np.percentile(arr, 50):7.3f} ms   "
                  f"p99 {np.percentile(arr, 99):7.3f} ms   max {arr.max():7.3f} ms")
    print(f"  {'all':<26} n={lat.size:<5} p50 {np.percentile(lat, 50):7.3f} ms   "
          f"p99 {np.percentile(lat, 99):7.3f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--latency-frames", type=int, default=1000)
    ap.add_argument("--period", type=float, default=0.01, help="s between frames (latency)")
    args = ap.parse_args()
    throughput(args.frames)
    latency(args.latency_frames, args.period)
    return 0


if __name__ == "__main__":
    sys.exit(main())
