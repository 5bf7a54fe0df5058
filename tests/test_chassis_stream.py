"""The million-frame test: a realistic DATA-uart2 feedback stream with bursts of line noise
between frames must decode to exactly the frames sent, in order (none lost, none invented)."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from drivers.chassis import WheelFrameParser, encode_wheel_frame
from fusion.geometry.kinematics import DiffDriveParams, twist_to_ticks

N = 1_000_000


def robot_ticks(n: int, rng: np.random.Generator) -> np.ndarray:
    """Ticks per 40 ms period of a robot that accelerates, cruises, turns, reverses and stops.

    Wheel d = 65 mm, 4096 ticks/rev (5e-5 m/tick), L = 0.3 m; speeds up to 1.5 m/s give up to
    about 1600 ticks per period, so low bytes 0xFF and checksums 0xFF occur all the time.
    """
    p = DiffDriveParams(wheel_distance=0.3, speed_ratio=np.pi * 0.065 / 4096)
    seg_len = rng.integers(25, 750, n // 25 + 1)
    starts = np.cumsum(seg_len)
    seg = np.searchsorted(starts, np.arange(n), side="right")
    v_t = rng.uniform(-0.6, 1.5, seg.max() + 1)
    w_t = rng.uniform(-3.0, 3.0, seg.max() + 1)
    stop = rng.random(seg.max() + 1) < 0.2
    v_t[stop] = 0.0
    w_t[stop] = 0.0
    # first-order response of the chassis to the segment targets (tau = 0.3 s)
    a = 1 - np.exp(-0.04 / 0.3)
    v = lfilter([a], [1, a - 1], v_t[seg])  # y[i] = y[i-1] + a*(x[i] - y[i-1])
    w = lfilter([a], [1, a - 1], w_t[seg])
    left, right = twist_to_ticks(v, w, p, rounding="nearest")
    left = left + rng.integers(-1, 2, n) * (left != 0)  # encoder quantisation jitter
    right = right + rng.integers(-1, 2, n) * (right != 0)
    ticks = np.column_stack([left, right]).astype(np.int64)
    # sprinkle the 0xFF-rich values a fast wheel or a spike can produce (within the bound)
    special = np.array([255, -255, 65535, -65535, 0xFFFF, 0x00FFFF, 511, 99999, -99999, 0])
    idx = rng.choice(n, 2000, replace=False)
    ticks[idx, rng.integers(0, 2, idx.size)] = rng.choice(special, idx.size)
    return ticks


def encode_all(ticks: np.ndarray) -> np.ndarray:
    """Vectorised encoder written from the protocol table (checked against the codec below)."""
    n = ticks.shape[0]
    out = np.empty((n, 11), dtype=np.uint8)
    out[:, 0] = out[:, 1] = 0xFF
    for col, (s, b) in enumerate(((2, 3), (6, 7))):
        val = ticks[:, col]
        mag = np.abs(val)
        out[:, s] = (val >= 0).astype(np.uint8)
        out[:, b] = mag >> 16
        out[:, b + 1] = (mag >> 8) & 0xFF
        out[:, b + 2] = mag & 0xFF
    out[:, 10] = out[:, :10].sum(axis=1, dtype=np.uint32) & 0xFF
    return out


def noise_bursts(count: int, rng: np.random.Generator, frames: np.ndarray) -> list[bytes]:
    bursts = []
    for _ in range(count):
        kind = rng.integers(0, 5)
        if kind == 0:  # plain random line noise
            b = rng.integers(0, 256, rng.integers(1, 40), dtype=np.uint8).tobytes()
        elif kind == 1:  # noise ending in 0xFF / 0xFF 0xFF just before a frame header
            b = rng.integers(0, 256, rng.integers(0, 20), dtype=np.uint8).tobytes()
            b += b"\xff" * int(rng.integers(1, 3))
        elif kind == 2:  # a frame cut short (dropout): its first 1..10 bytes
            f = frames[rng.integers(0, frames.shape[0])].tobytes()
            b = f[: rng.integers(1, 11)]
        elif kind == 3:  # noise, then a truncated frame
            f = frames[rng.integers(0, frames.shape[0])].tobytes()
            b = rng.integers(0, 256, rng.integers(1, 12), dtype=np.uint8).tobytes()
            b += f[: rng.integers(2, 11)]
        else:  # a frame with a corrupted byte (bad checksum): noise to the parser
            f = bytearray(frames[rng.integers(0, frames.shape[0])].tobytes())
            k = int(rng.integers(2, 11))
            f[k] ^= 1 << int(rng.integers(0, 8))
            b = bytes(f)
        bursts.append(b)
    return bursts


def build_stream(seed: int, n: int = N, n_bursts: int = 20_000):
    """(stream bytes, ticks (n, 2), frame offsets (n,), noise byte count)."""
    rng = np.random.default_rng(seed)
    ticks = robot_ticks(n, rng)
    frames = encode_all(ticks)
    gaps = np.sort(rng.choice(np.arange(1, n), n_bursts, replace=False))
    bursts = noise_bursts(n_bursts, rng, frames)
    pieces = []
    offsets = np.empty(n, dtype=np.int64)
    flat = frames.reshape(-1)
    prev = pos = noise_bytes = 0
    for g, b in zip(gaps, bursts):
        chunk = flat[prev * 11 : g * 11].tobytes()
        offsets[prev:g] = pos + 11 * np.arange(g - prev)
        pieces += [chunk, b]
        pos += len(chunk) + len(b)
        noise_bytes += len(b)
        prev = g
    offsets[prev:] = pos + 11 * np.arange(n - prev)
    pieces.append(flat[prev * 11 :].tobytes())
    return b"".join(pieces), ticks, offsets, noise_bytes


def decode_in_chunks(stream: bytes, seed: int, parser: WheelFrameParser):
    rng = np.random.default_rng(seed)
    got_off, got_l, got_r = [], [], []
    i = 0
    while i < len(stream):  # chunks as a serial read would deliver them
        k = int(rng.integers(1, 8192))
        o, lft, rgt = parser.feed_arrays(stream[i : i + k])
        got_off.append(o)
        got_l.append(lft)
        got_r.append(rgt)
        i += k
    last = parser.finish()
    got_off = np.concatenate([*got_off, [f.offset for f in last]]).astype(np.int64)
    got_l = np.concatenate([*got_l, [f.left for f in last]]).astype(np.int64)
    got_r = np.concatenate([*got_r, [f.right for f in last]]).astype(np.int64)
    return got_off, got_l, got_r


def test_million_frames_with_noise_exact():
    seed = 20261122
    stream, ticks, offsets, noise_bytes = build_stream(seed)
    frames = encode_all(ticks)
    rng = np.random.default_rng(1)
    # the vectorised encoder agrees with the codec (whose golden vectors are hand-checked)
    for i in rng.choice(N, 500, replace=False):
        assert frames[i].tobytes() == encode_wheel_frame(int(ticks[i, 0]), int(ticks[i, 1]))
    assert np.count_nonzero(frames[:, 10] == 0xFF) > 1000  # checksum 0xFF is common
    assert np.count_nonzero((frames[:, 8] == 0xFF) & (frames[:, 9] == 0xFF)) > 100
    assert len(stream) == 11 * N + noise_bytes

    parser = WheelFrameParser()
    got_off, got_l, got_r = decode_in_chunks(stream, seed, parser)

    assert got_off.size == N, f"{got_off.size - N:+d} frames"
    np.testing.assert_array_equal(got_off, offsets)
    np.testing.assert_array_equal(got_l, ticks[:, 0])
    np.testing.assert_array_equal(got_r, ticks[:, 1])
    s = parser.stats
    assert s.frames == N
    assert s.bytes_skipped == noise_bytes
    assert s.resyncs == 20_000  # exactly one per noise burst
    assert s.deferred > 0  # the lookahead rule was exercised
