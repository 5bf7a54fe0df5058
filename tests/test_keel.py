"""Keel estimator: analytic cases, external knowledge, gaps, streaming/batch/split equality."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion._jit import HAVE_NUMBA
from fusion.attitude.keel import Keel, KeelParams
from fusion.attitude.keel_offline import keel_offline
from fusion.attitude.mahony import Mahony
from fusion.geometry import quaternion as Q

G = 9.80665
DEG = math.pi / 180
UP = np.array([0.0, 0.0, G])
FIELD = np.array([0.0, 20.0, -40.0])  # uT, ENU: north along +y, dipping down


def body(rot: Rotation, world_vectors):
    """World vectors seen in the body frame of the body -> world rotations ``rot``."""
    return rot.apply(world_vectors, inverse=True)


def errors_deg(q, rot: Rotation):
    """Total, heading, inclination errors (deg) of ``q`` against the scipy truth, in the
    atan2 form (exact near zero, where the acos form of the BROAD metric loses digits)."""
    ref = np.broadcast_to(Q.from_scipy(rot), np.shape(q))
    e = Q.multiply(q, Q.conjugate(ref))
    w, x, y, z = np.abs(e).T
    total = 2 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)
    heading = 2 * np.arctan2(z, w)
    inclination = 2 * np.arctan2(np.hypot(x, y), np.hypot(w, z))
    return np.degrees(total), np.degrees(heading), np.degrees(inclination)


def inclination_deg(q, rot: Rotation):
    return errors_deg(q, rot)[2]


def test_static_tilt_gives_roll_and_pitch():
    """Oracle: scipy's rotation of gravity. The first sample levels the gyro frame; the
    estimator then holds the exact tilt, with and without noise."""
    rot = Rotation.from_euler("ZYX", [0.0, -0.2, 0.3])
    n, dt = 2000, 0.01
    f = Keel(sample_period=dt)
    q = f.update_batch(np.zeros((n, 3)), np.tile(body(rot, UP), (n, 1)))
    assert np.max(inclination_deg(q, rot)) < 1e-9
    roll, pitch, _ = f.euler
    assert roll == pytest.approx(0.3, abs=1e-12) and pitch == pytest.approx(-0.2, abs=1e-12)

    rng = np.random.default_rng(1)
    acc = np.tile(body(rot, UP), (n, 1)) + rng.normal(0, 0.1, (n, 3))
    q = Keel(sample_period=dt).update_batch(rng.normal(0, 0.002, (n, 3)), acc)
    # Averaging (running mean, then a 3 s low-pass) of 0.1 m/s^2 noise: well below 0.1 deg.
    assert np.max(inclination_deg(q[500:], rot)) < 0.1


@pytest.mark.parametrize("jitter", [False, True])
def test_constant_rate_matches_closed_form(jitter):
    """Rotation at a constant rate about a tilted axis, accelerometer = gravity seen by the
    true attitude (scipy). Gyro integration is exact for a constant rate, so the attitude
    equals the closed form exp(w t) at every sample, for jittered periods too."""
    w = np.array([0.3, -0.5, 0.8])
    n = 3000
    rng = np.random.default_rng(2)
    dts = rng.uniform(0.004, 0.016, n) if jitter else np.full(n, 0.01)
    t = np.cumsum(dts) - dts[0]
    rot = Rotation.from_rotvec(np.outer(t, w))
    f = Keel()
    q = f.update_batch(np.tile(w, (n, 1)), body(rot, UP), timestamps=t)
    err = errors_deg(q, rot)[0]
    assert np.max(err) < 1e-8
    assert np.max(np.abs(f.gyro_bias)) < 1e-12  # nothing to learn: no bias


def test_gyro_bias_step_at_rest_is_recovered_within_three_seconds():
    """A bias step of 0.5 deg/s per axis at rest: within 3 s the estimate is within
    0.05 deg/s of the truth on every axis (gyro noise 0.1 deg/s)."""
    dt, n, step_at = 0.01, 6000, 3000
    rng = np.random.default_rng(0)
    rot = Rotation.from_euler("ZYX", [0.0, 0.2, 0.3])
    acc = np.tile(body(rot, UP), (n, 1)) + rng.normal(0, 0.05, (n, 3))
    bias = np.array([0.5, -0.4, 0.3]) * DEG
    gyro = rng.normal(0, 0.1 * DEG, (n, 3))
    gyro[step_at:] += bias
    _, diag = Keel(sample_period=dt).update_batch(gyro, acc, diagnostics=True)
    after = step_at + int(3.0 / dt)
    assert np.all(diag.rest[step_at - 100:])
    assert np.max(np.abs(diag.gyro_bias[after:] - bias)) < 0.05 * DEG
    assert np.all(diag.gyro_bias_sigma[after:] < 0.05 * DEG)


def test_gyro_bias_in_motion_is_learnt_in_the_horizontal_axes():
    """A sensor swinging about two axes, never at rest: the inclination correction reveals
    the horizontal bias (0.4 deg/s x, -0.3 deg/s y) within 60 s to 0.05 deg/s; without bias
    estimation the inclination error grows instead."""
    dt, n = 0.01, 12000
    t = np.arange(n) * dt
    angles = np.column_stack([0.5 * np.sin(0.7 * t), 0.4 * np.sin(0.45 * t + 1), 0 * t])
    rot = Rotation.from_euler("ZYX", angles[:, ::-1])
    # Body rates of this motion from the scipy rotations (finite differences, exact enough).
    rates = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt
    rates = np.vstack([rates, rates[-1]])
    bias = np.array([0.4, -0.3, 0.0]) * DEG
    f = Keel(sample_period=dt)
    still = np.zeros(n)  # the host knows it is moving
    q, diag = f.update_batch(rates + bias, body(rot, UP), dt=dt, still=still, diagnostics=True)
    assert not np.any(diag.rest)
    assert np.max(np.abs(diag.gyro_bias[6000:, :2] - bias[:2])) < 0.05 * DEG
    with_bias = np.sqrt(np.mean(inclination_deg(q[6000:], rot[6000:]) ** 2))
    q0 = Keel(sample_period=dt, motion_bias_estimation=False).update_batch(
        rates + bias, body(rot, UP), still=still)
    without = np.sqrt(np.mean(inclination_deg(q0[6000:], rot[6000:]) ** 2))
    assert with_bias < 0.5 * without


def butterworth_step_response(t, tau):
    """Step response of y'' + (2/tau) y' + (2/tau^2) y = (2/tau^2) u, from rest."""
    x = t / tau
    return 1.0 - np.exp(-x) * (np.cos(x) + np.sin(x))


def test_sustained_acceleration_tilts_as_the_lowpass_predicts_and_known_accel_removes_it():
    """Level sensor, forward acceleration 2 m/s^2 from t = 10 s. Without knowledge the tilt
    error follows atan(2 s(t) / g), s the continuous filter's step response (the steps hold
    the input constant, so the exact discretisation equals it at every sample). Given
    known_accel the error stays zero."""
    dt, n, start = 0.01, 2500, 1000
    acc = np.tile(UP, (n, 1))
    acc[start:, 0] += 2.0
    gyro = np.zeros((n, 3))
    f = Keel(sample_period=dt, motion_bias_estimation=False)
    q = f.update_batch(gyro, acc)
    level = Rotation.identity(n)
    t = (np.arange(n) - start + 1) * dt
    predicted = np.degrees(np.arctan(2.0 * butterworth_step_response(np.maximum(t, 0), 3.0) / G))
    assert np.allclose(inclination_deg(q, level), predicted, atol=1e-9)
    assert inclination_deg(q, level)[-1] > 5.0  # a real error: the sustained case is hard

    known = np.zeros((n, 3))
    known[start:, 0] = 2.0
    q = Keel(sample_period=dt).update_batch(gyro, acc, known_accel=known)
    assert np.max(inclination_deg(q, level)) < 1e-9


def test_centripetal_acceleration_of_a_turning_robot():
    """Robot driving a circle: v = 1 m/s, yaw rate w = 0.5 rad/s, so the body feels v*w =
    0.5 m/s^2 towards the centre (+y, left). In the gyro frame that vector turns at w and the
    low-pass attenuates it by |H(jw)| = 1/sqrt(1 + (w tau / sqrt 2)^4) (Butterworth); given
    known_accel = (0, v*w, 0) the error vanishes. (Without it the error is about 1.9 deg
    here: a host that knows v*w should pass it.)"""
    dt, n, v, w = 0.01, 6000, 1.0, 0.5
    t = np.arange(n) * dt
    rot = Rotation.from_euler("Z", (w * t)[:, None])
    gyro = np.tile([0.0, 0.0, w], (n, 1))
    acc = np.tile(UP + np.array([0.0, v * w, 0.0]), (n, 1))
    q = Keel(sample_period=dt, motion_bias_estimation=False).update_batch(gyro, acc)
    gain = 1.0 / math.sqrt(1.0 + (w * 3.0 / math.sqrt(2)) ** 4)
    predicted = math.degrees(math.atan(gain * v * w / G))
    steady = inclination_deg(q[3000:], rot[3000:])
    assert steady.mean() == pytest.approx(predicted, rel=0.02)

    known = np.tile([0.0, v * w, 0.0], (n, 1))
    q = Keel(sample_period=dt).update_batch(gyro, acc, known_accel=known)
    assert np.max(inclination_deg(q, rot)) < 1e-9


def test_uncorrected_gyro_bias_lags_by_the_lowpass_phase_through_many_folds():
    """Static level sensor, gyro bias 5 deg/s about x, bias estimation off: the gyro frame
    turns 600 deg in 120 s (folded back every 45 deg), gravity circles in it, and the
    low-passed vector lags by the Butterworth phase atan2(sqrt2 w wn, wn^2 - w^2),
    wn = sqrt2 / tau, less the half-sample advance w dt / 2 of the held-input discretisation."""
    dt, n, w = 0.01, 12000, 5 * DEG
    f = Keel(sample_period=dt, motion_bias_estimation=False, rest_bias_estimation=False)
    q = f.update_batch(np.tile([w, 0.0, 0.0], (n, 1)), np.tile(UP, (n, 1)))
    wn = math.sqrt(2) / 3.0
    lag = math.degrees(math.atan2(math.sqrt(2) * w * wn, wn * wn - w * w) - w * dt / 2)
    steady = inclination_deg(q[6000:], Rotation.identity(n - 6000))
    assert np.max(np.abs(steady - lag)) < 1e-6


def test_magnet_passing_by_holds_heading_and_leaves_inclination_untouched():
    """9-axis, sensor tilted and turning at 10 deg/s; a magnet passes (40 uT along world x,
    a 10 s bump). The heading error stays below 2 deg (Mahony's 9-axis filter: over 20 deg);
    the inclination is the 6-axis one (the heading offset turns about up only)."""
    dt, n = 0.01, 9000
    t = np.arange(n) * dt
    rot = Rotation.from_euler("ZYX", np.column_stack([10 * DEG * t, np.full(n, 0.15),
                                                     np.full(n, -0.1)]))
    gyro = np.tile([0.0, 0.0, 0.0], (n, 1))
    gyro[:] = (rot[:-1].inv() * rot[1:]).as_rotvec()[[0]] / dt  # constant body rate
    acc = body(rot, UP)
    bump = np.exp(-0.5 * ((t - 50.0) / 2.5) ** 2)
    world_field = FIELD + np.outer(40.0 * bump, [1.0, 0.0, 0.0])
    mag = body(rot, world_field)
    f = Keel(axes=9, sample_period=dt)
    q9, diag = f.update_batch(gyro, acc, mag, diagnostics=True)
    _, heading, incl = errors_deg(q9, rot)
    assert np.any(diag.mag_disturbed[(t > 45) & (t < 55)])
    assert np.max(heading) < 2.0
    q6 = Keel(sample_period=dt).update_batch(gyro, acc)
    assert np.allclose(incl, inclination_deg(q6, rot), atol=1e-9)
    # The test is not trivial: Mahony's 9-axis filter follows the magnet.
    m = Mahony(axes=9, sample_period=dt).update_batch(gyro, acc, mag)
    assert np.max(errors_deg(m, rot)[1]) > 20.0


def test_heading_from_the_first_magnetometer_sample():
    rot = Rotation.from_euler("ZYX", [1.1, 0.2, -0.3])
    f = Keel(axes=9, sample_period=0.01)
    f.update(np.zeros(3), body(rot, UP), body(rot, FIELD))
    assert abs(np.dot(f.quaternion, Q.from_scipy(rot))) == pytest.approx(1.0, abs=1e-9)


def test_slow_spin_is_rest_to_the_imu_but_not_when_the_wheels_say_moving():
    """A robot turning in place at 1 deg/s: constant gyro and accelerometer, below the rest
    rate bound, so the IMU alone learns the spin as bias; still=False (wheels turning)
    prevents it."""
    dt, n = 0.01, 3000
    gyro = np.tile([0.0, 0.0, 1.0 * DEG], (n, 1))
    acc = np.tile(UP, (n, 1))
    alone = Keel(sample_period=dt)
    alone.update_batch(gyro, acc)
    assert alone.gyro_bias[2] == pytest.approx(1.0 * DEG, rel=0.05)
    told = Keel(sample_period=dt)
    told.update_batch(gyro, acc, still=np.zeros(n))
    assert told.counters.rest_samples == 0 and told.gyro_bias[2] == 0.0


def test_gap_is_not_integrated_as_one_step_and_inclination_is_reacquired():
    """5 s without data while the robot was tipped by 20 deg: the sample after the gap is
    integrated over the last regular period only and the accelerometer gives the new
    inclination at once."""
    dt = 0.01
    before = Rotation.identity()
    after = Rotation.from_euler("X", 20 * DEG)
    t = np.concatenate([np.arange(500) * dt, 10.0 + np.arange(500) * dt])
    acc = np.vstack([np.tile(body(before, UP), (500, 1)), np.tile(body(after, UP), (500, 1))])
    gyro = np.zeros((1000, 3))
    gyro[500] = [0.0, 0.0, 1.0]  # a fast yaw rate right after the gap
    f = Keel()
    q = f.update_batch(gyro, acc, timestamps=t)
    assert f.counters.gaps == 1
    yaw_turn = Q.to_euler(q[500])[2] - Q.to_euler(q[499])[2]
    assert yaw_turn == pytest.approx(1.0 * dt, abs=1e-9)  # not 1 rad/s * 5.5 s
    assert inclination_deg(q[500:501], after)[0] < 1e-6
    # Same gap, streaming: identical.
    g = Keel()
    qs = np.array([g.update(gyro[i], acc[i], timestamp=t[i]) for i in range(1000)])
    assert np.array_equal(qs, q)


def messy_inputs(n=3000, seed=7):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.016, n))
    t[1700:] += 0.7  # a gap
    gyro = rng.normal(0, 0.5, (n, 3))
    accel = body(Rotation.from_euler("ZYX", [0, -0.1, 0.2]), UP) + rng.normal(0, 1.5, (n, 3))
    mag = np.tile(FIELD, (n, 1)) + rng.normal(0, 2, (n, 3))
    gyro[100:110] = 0.0
    gyro[200] = np.nan
    accel[300] = 0.0
    accel[301, 1] = np.inf
    mag[400] = 0.0
    mag[401, 0] = np.nan
    gyro[450, 1] = 1e200  # corrupt values: skipped and counted, never a poisoned state
    accel[460, 2] = 1e150
    still = np.full(n, np.nan)
    still[500:800] = 1.0
    still[900:1000] = 0.0
    known = np.zeros((n, 3))
    known[1000:1200, 1] = 0.8
    known[1300] = np.nan
    return t, gyro, accel, mag, still, known


@pytest.mark.parametrize("axes", [6, 9])
def test_streaming_equals_batch_exactly(axes):
    t, gyro, accel, mag, still, known = messy_inputs()
    m = mag if axes == 9 else None
    batch = Keel(axes=axes)
    out_b = batch.update_batch(gyro, accel, m, timestamps=t, still=still, known_accel=known)
    stream = Keel(axes=axes)
    out_s = np.array([
        stream.update(gyro[i], accel[i], None if m is None else m[i], timestamp=t[i],
                      still=None if np.isnan(still[i]) else bool(still[i]),
                      known_accel=known[i])
        for i in range(len(t))
    ])
    assert np.array_equal(out_b, out_s)
    assert batch.counters == stream.counters
    c = batch.counters
    assert c.gyro_skipped == 2 and c.accel_skipped == 3 and c.gaps == 1 and c.rest_samples > 0
    if axes == 9:
        assert c.mag_skipped >= 2
    assert np.all(np.isfinite(out_b))
    assert np.array_equal(batch.get_state().core, stream.get_state().core)


def test_hot_path_equals_batch():
    """update(g, a) with float64 arrays and a default period takes the compiled fast path."""
    _, gyro, accel, *_ = messy_inputs()
    gyro, accel = gyro[:600], accel[:600]
    want = Keel(sample_period=0.01).update_batch(gyro, accel)
    f = Keel(sample_period=0.01)
    assert np.array_equal(np.array([f.update(g, a) for g, a in zip(gyro, accel)]), want)
    f.reset()
    got = np.array([f.update(list(g), tuple(a)) for g, a in zip(gyro, accel)])
    assert np.array_equal(got, want)
    # Timestamps (Python floats and numpy scalars) take the fast path after the first sample.
    t = 0.01 * np.arange(600) + 100.0
    want = Keel().update_batch(gyro, accel, timestamps=t)
    for stamps in (t.tolist(), list(t)):
        f = Keel()
        got = np.array([f.update(g, a, timestamp=s) for g, a, s in zip(gyro, accel, stamps)])
        assert np.array_equal(got, want)


def test_split_run_equals_single_run_and_state_restores():
    t, gyro, accel, mag, still, known = messy_inputs()
    kw = dict(axes=9)
    whole = Keel(**kw).update_batch(gyro, accel, mag, timestamps=t, still=still,
                                    known_accel=known)
    f = Keel(**kw)
    cut = 1234
    a = f.update_batch(gyro[:cut], accel[:cut], mag[:cut], timestamps=t[:cut],
                       still=still[:cut], known_accel=known[:cut])
    saved = f.get_state()
    b = f.update_batch(gyro[cut:], accel[cut:], mag[cut:], timestamps=t[cut:],
                       still=still[cut:], known_accel=known[cut:])
    assert np.array_equal(np.vstack([a, b]), whole)
    g = Keel(**kw)
    g.set_state(saved)
    c = g.update_batch(gyro[cut:], accel[cut:], mag[cut:], timestamps=t[cut:],
                       still=still[cut:], known_accel=known[cut:])
    assert np.array_equal(c, b)
    assert saved.bias_covariance.shape == (3, 3)
    assert np.all(np.linalg.eigvalsh(saved.bias_covariance) > 0)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed: only one path exists")
def test_interpreted_path_equals_compiled(tmp_path):
    """The same Python source runs interpreted (no numba) with bit-identical results."""
    t, gyro, accel, mag, still, known = (x[:1500] for x in messy_inputs())
    compiled = Keel(axes=9).update_batch(gyro, accel, mag, timestamps=t, still=still,
                                         known_accel=known)
    offline = keel_offline(gyro, accel, mag, timestamps=t, axes=9)
    np.savez(tmp_path / "in.npz", t=t, gyro=gyro, accel=accel, mag=mag, still=still,
             known=known)
    code = (
        "import numpy as np\n"
        "from fusion._jit import HAVE_NUMBA\n"
        "assert not HAVE_NUMBA\n"
        "from fusion.attitude.keel import Keel\n"
        "from fusion.attitude.keel_offline import keel_offline\n"
        f"d = np.load(r'{tmp_path / 'in.npz'}')\n"
        "q = Keel(axes=9).update_batch(d['gyro'], d['accel'], d['mag'], timestamps=d['t'],"
        " still=d['still'], known_accel=d['known'])\n"
        "o = keel_offline(d['gyro'], d['accel'], d['mag'], timestamps=d['t'], axes=9)\n"
        f"np.save(r'{tmp_path / 'out.npy'}', q)\n"
        f"np.save(r'{tmp_path / 'off.npy'}', o)\n"
    )
    env = {"FUSION_DISABLE_JIT": "1", "PATH": "/usr/bin:/bin"}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    assert np.array_equal(np.load(tmp_path / "out.npy"), compiled)
    assert np.array_equal(np.load(tmp_path / "off.npy"), offline)


def test_offline_matches_closed_form_and_beats_online_on_a_bias_step():
    """Constant-rate case: offline equals the closed form too. With a gyro bias present
    from the start, the offline pass (which knows the bias from the whole recording) has a
    smaller inclination error than the causal one."""
    w = np.array([0.2, -0.1, 0.4])
    n, dt = 2000, 0.01
    t = np.arange(n) * dt
    rot = Rotation.from_rotvec(np.outer(t, w))
    q = keel_offline(np.tile(w, (n, 1)), body(rot, UP), sample_period=dt)
    assert np.max(errors_deg(q, rot)[0]) < 1e-8

    n = 12000
    t = np.arange(n) * dt
    angles = np.column_stack([0.5 * np.sin(0.7 * t), 0.4 * np.sin(0.45 * t + 1)])
    rot = Rotation.from_euler("YX", angles)
    rates = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt
    gyro = np.vstack([rates, rates[-1]]) + np.array([0.4, -0.3, 0.0]) * DEG
    online = Keel(sample_period=dt).update_batch(gyro, body(rot, UP))
    offline = keel_offline(gyro, body(rot, UP), sample_period=dt)
    rms = [np.sqrt(np.mean(inclination_deg(x, rot) ** 2)) for x in (online, offline)]
    assert rms[1] < 0.5 * rms[0]


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda f: f.update([0, 0, 0], [0, 0, G], dt=0.0), "dt"),
        (lambda f: f.update([0, 0, 0], [0, 0, G], dt=float("nan")), "dt"),
        (lambda f: f.update([0, 0], [0, 0, G], dt=0.01), "gyro must have 3"),
        (lambda f: f.update_batch(np.zeros((4, 3)), np.zeros((3, 3)), dt=0.01), "accel has 3"),
        (lambda f: f.update_batch(np.zeros((3, 3)), np.zeros((3, 3)),
                                  timestamps=[0.0, 0.1, 0.1]), "index 2"),
        (lambda f: f.update_batch(np.zeros((3, 3)), np.zeros((3, 3)), dt=0.01,
                                  still=[1, 0]), "still must have shape"),
        (lambda f: f.update_batch(np.zeros((3, 3)), np.zeros((3, 3)), dt=0.01,
                                  known_accel=np.zeros((3, 2))), "known_accel"),
    ],
)
def test_bad_input_raises_clear_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call(Keel())


def test_second_sample_without_period_raises_and_bad_params_raise():
    f = Keel()
    f.update([0, 0, 0], [0, 0, G])  # the first sample only initialises
    with pytest.raises(ValueError, match="no dt"):
        f.update([0, 0, 0], [0, 0, G])
    with pytest.raises(ValueError, match="accel_time_constant"):
        KeelParams(accel_time_constant=0.0)
    with pytest.raises(ValueError, match="axes"):
        Keel(axes=7)
    with pytest.raises(ValueError, match="initial_quaternion"):
        Keel(initial_quaternion=[1, 0, 0])
