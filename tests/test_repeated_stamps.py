"""Messages that share a stamp (fusion.io.repeated_stamps): bursts spread back from their read
stamp, copies left out. Oracle: streams built here from known sample times."""

from __future__ import annotations

import numpy as np
import pytest

from fusion.io.repeated_stamps import spread_repeated_stamps


def _burst_stamped(rate=30.0, burst=3, seconds=10.0, t0=1.7e9):
    """(true sample times, stamps): samples at ``rate`` Hz read ``burst`` at a time, each read
    stamping its samples with the time of its last one."""
    n = int(seconds * rate) // burst * burst
    true = t0 + np.arange(1, n + 1) / rate
    stamps = np.repeat(true[burst - 1::burst], burst)
    return true, stamps


def test_bursts_are_spread_back_onto_the_sample_times():
    true, stamps = _burst_stamped()
    values = np.random.default_rng(0).standard_normal((true.size, 6))
    fix = spread_repeated_stamps(stamps, values, "topic /imu/data")
    assert fix.keep.all() and fix.duplicates == 0
    assert fix.bursts == true.size // 3 and fix.spread == 2 * true.size // 3
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)  # float64 at 1.7e9 s: 2e-7
    assert np.all(np.diff(fix.t) > 0)
    assert fix.note.startswith("topic /imu/data: ") and "spread back" in fix.note


def test_a_burst_after_a_pause_keeps_the_sampling_period():
    # a 2 s pause in the reads: the burst after it is not stretched over the pause
    true, stamps = _burst_stamped(seconds=4.0)
    late = stamps > stamps[30]
    stamps = np.where(late, stamps + 2.0, stamps)
    true = np.where(late, true + 2.0, true)
    fix = spread_repeated_stamps(stamps, np.arange(true.size, dtype=float)[:, None])
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)  # float64 at 1.7e9 s: 2e-7


def test_copies_are_left_out_and_distinct_stamps_untouched():
    t = np.array([0.0, 0.1, 0.1, 0.2, 0.3, 0.3])
    values = np.array([[1.0], [2.0], [2.0], [3.0], [np.nan], [np.nan]])
    fix = spread_repeated_stamps(t, values, "topic /odom")
    assert fix.keep.tolist() == [True, True, False, True, True, False]
    assert fix.duplicates == 2 and fix.spread == 0
    np.testing.assert_array_equal(fix.t, [0.0, 0.1, 0.2, 0.3])
    assert "2 copies of the previous message" in fix.note
    clean = spread_repeated_stamps(np.array([0.0, 0.1]), np.zeros((2, 1)))
    assert clean.note == "" and clean.t.tolist() == [0.0, 0.1]


def test_unsorted_stamps_or_mismatched_values_are_refused():
    with pytest.raises(ValueError, match="non-decreasing"):
        spread_repeated_stamps(np.array([0.0, 0.2, 0.1]), np.zeros((3, 1)))
    with pytest.raises(ValueError, match=r"values \(N, k\)"):
        spread_repeated_stamps(np.array([0.0, 0.1]), np.zeros((3, 1)))


def test_record_times_tell_a_frozen_stamp_from_a_burst():
    # 30 Hz samples recorded 3 ms after they were taken; bursts of 3 published at the read
    # (recorded together) stay bursts; a stamp frozen for 30 samples while they came one by
    # one (recorded 33 ms apart) puts each at its record time less the usual 3 ms.
    true, stamps = _burst_stamped(seconds=6.0)
    record = stamps + 0.003  # a burst is published and recorded at its read
    frozen = slice(60, 90)
    stamps = stamps.copy()
    stamps[frozen] = stamps[60]
    record[frozen] = true[frozen] + 0.003
    values = np.random.default_rng(1).standard_normal((true.size, 6))
    fix = spread_repeated_stamps(stamps, values, "topic /imu/data", record_t=record)
    assert fix.frozen == 30 and fix.bursts == true.size // 3 - 10
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)
    assert "30 messages shared a stamp while they came one by one" in fix.note
    assert "spread back" in fix.note
    # without record times the frozen run reads as one burst, its 0.97 s squeezed into the
    # 0.1 s since the previous stamp
    blind = spread_repeated_stamps(stamps, values, "topic /imu/data")
    assert blind.frozen == 0 and np.ptp(blind.t[frozen]) < 0.11


@pytest.mark.parametrize(("rate", "burst"), [(100.0, 2), (400.0, 4), (30.0, 3)])
def test_bursts_recorded_by_a_busy_recorder_stay_bursts(rate, burst):
    # a burst published at its read, recorded 0-12 ms later message by message (a recorder
    # busy with other topics; review: pairs at 100 Hz were taken for frozen stamps, put at
    # their record times, up to 23 ms off and 40 times out of order)
    true, stamps = _burst_stamped(rate=rate, burst=burst)
    rng = np.random.default_rng(2)
    record = stamps + 0.002 + np.cumsum(rng.uniform(0.0, 0.012 / burst, true.size))
    record -= np.maximum.accumulate(record - stamps - 0.014)  # a bounded, drifting delay
    fix = spread_repeated_stamps(stamps, np.arange(true.size, dtype=float)[:, None],
                                 "topic /imu/data", record_t=record)
    assert fix.frozen == 0 and fix.bursts == true.size // burst
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)


def test_stamps_frozen_for_most_of_a_topic_keep_the_others_delay():
    # two stretches of frozen stamps covering 45 s of 60 (review: with the delay taken over
    # every message, the median was a frozen one's, 7.5 s, and the samples moved by as much)
    rate = 30.0
    true = 1.7e9 + np.arange(1, int(60 * rate) + 1) / rate
    record = true + 0.003
    stamps = true.copy()
    for a, b in ((5.0, 30.0), (35.0, 55.0)):
        run = (true >= 1.7e9 + a) & (true < 1.7e9 + b)
        stamps[run] = true[run][0]
    fix = spread_repeated_stamps(stamps, np.arange(true.size, dtype=float)[:, None],
                                 "topic /imu/data", record_t=record)
    assert fix.frozen == np.count_nonzero(stamps[1:] == stamps[:-1]) + 2
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)
    assert np.all(np.diff(fix.t) > 0)


def test_a_batch_stamped_as_it_is_handled_is_spread_like_one_stamp():
    # ten samples of a 30 Hz FIFO read at once and stamped 0.1 ms apart as a driver handles
    # them: no two stamps equal, but nine of ten steps a 300th of the period
    rate, batch = 30.0, 10
    true = 1.7e9 + np.arange(1, 301) / rate
    read = np.repeat(true[batch - 1::batch], batch)
    stamps = read + np.tile(np.arange(batch) * 1e-4, true.size // batch)
    values = np.random.default_rng(1).standard_normal((true.size, 6))
    fix = spread_repeated_stamps(stamps, values, "topic /imu/data")
    assert fix.keep.all() and fix.near == 270 and fix.bursts == 30
    np.testing.assert_allclose(fix.t, true, rtol=0, atol=1e-6)  # float64 at 1.7e9 s: 2e-7
    # the limit: a tenth of the mean step, from the first read to the last sample's stamp
    limit = 0.1 * (stamps[-1] - stamps[0]) / (stamps.size - 1)
    assert f"270 messages were stamped less than {limit * 1e3:.3g} ms after" in fix.note


@pytest.mark.parametrize("jitter", [0.0, 0.25])
def test_jittered_or_paused_stamps_are_not_batches(jitter):
    # 200 Hz with uniform jitter of +-25 % of the period (no step under half of it) and a
    # 30 s pause in a 60 s log: the pause is left out of the mean, so no step is a batch's
    rng = np.random.default_rng(2)
    t = np.arange(12_000) / 200.0 + rng.uniform(-jitter, jitter, 12_000) / 200.0
    t[6000:] += 30.0
    fix = spread_repeated_stamps(t, rng.standard_normal((t.size, 1)))
    assert fix.note == "" and fix.near == 0
    np.testing.assert_array_equal(fix.t, t)
