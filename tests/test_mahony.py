"""Mahony filter: analytic cases, streaming/batch equivalence, state, bad input."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion._jit import HAVE_NUMBA
from fusion.attitude.mahony import Mahony, MahonyParams
from fusion.geometry import quaternion as Q

G = 9.80665


def level_accel(n, roll=0.0, pitch=0.0):
    r = Rotation.from_euler("ZYX", [0.0, pitch, roll])
    return np.tile(r.apply([0.0, 0.0, G], inverse=True), (n, 1))


def test_static_tilt_converges_to_true_roll_pitch():
    roll, pitch = 0.3, -0.2
    n, dt = 3000, 0.01
    f = Mahony(kp=1.0, ki=0.0, sample_period=dt, initial_quaternion=[1, 0, 0, 0],
               rest_detection=False)
    f.update_batch(np.zeros((n, 3)), level_accel(n, roll, pitch))
    got_roll, got_pitch, _ = f.euler
    assert got_roll == pytest.approx(roll, abs=1e-6)
    assert got_pitch == pytest.approx(pitch, abs=1e-6)


def test_constant_rate_matches_closed_form_within_rk1_error():
    """With no feedback, each RK1 step + normalisation turns by 2*atan(|w|dt/2) about w."""
    w = np.array([0.3, -0.5, 0.8])
    n, dt = 2000, 0.01
    f = Mahony(kp=0.0, ki=0.0, sample_period=dt, initial_quaternion=[1, 0, 0, 0],
               rest_detection=False)
    out = f.update_batch(np.tile(w, (n, 1)), level_accel(n))
    rate = np.linalg.norm(w)
    exact = Q.from_rotation_vector(np.outer(np.arange(1, n + 1) * dt, w))
    err = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(out * exact, 1)), 0, 1)))
    # Closed form of the RK1 angle deficit after k steps, and its leading-order bound.
    per_step = rate * dt - 2 * math.atan(rate * dt / 2)
    k = np.arange(1, n + 1)
    predicted = np.degrees(k * per_step)
    # err is acos-limited near zero (~1e-6 deg); compare where it is resolvable.
    assert np.allclose(err[100:], predicted[100:], rtol=1e-3)
    assert np.all(predicted <= np.degrees(k * (rate * dt) ** 3 / 12) + 1e-15)
    # The rotation axis is exactly preserved.
    axis = out[-1, 1:] / np.linalg.norm(out[-1, 1:])
    assert abs(np.dot(axis, w / rate)) == pytest.approx(1.0, abs=1e-12)


def test_constant_gyro_bias_is_estimated_in_observable_axes():
    bias = np.array([0.02, -0.01, 0.015])  # rad/s
    n, dt = 20000, 0.01
    f = Mahony(kp=0.5, ki=0.05, sample_period=dt, initial_quaternion=[1, 0, 0, 0],
               rest_detection=False)
    f.update_batch(np.tile(bias, (n, 1)), level_accel(n))
    est = f.gyro_bias
    assert est[:2] == pytest.approx(bias[:2], abs=1e-5)
    # Level and 6-axis: the bias about gravity is not observable from the accelerometer.
    assert abs(est[2]) < 1e-6
    roll, pitch, _ = f.euler
    assert abs(roll) < 1e-5 and abs(pitch) < 1e-5


def test_rest_detection_estimates_all_three_bias_axes():
    bias = np.array([0.02, -0.01, 0.015])
    n, dt = 6000, 0.01
    rng = np.random.default_rng(3)
    gyro = bias + rng.normal(0, 0.002, (n, 3))
    accel = level_accel(n, 0.4, 0.1) + rng.normal(0, 0.02, (n, 3))
    f = Mahony(kp=0.5, ki=0.0, sample_period=dt, rest_detection=True)
    f.update_batch(gyro, accel)
    assert f.gyro_bias == pytest.approx(bias, abs=5e-4)
    assert f.counters.rest_samples > n // 2


def test_nine_axis_estimates_yaw_bias():
    bias = np.array([0.0, 0.0, 0.01])
    n, dt = 40000, 0.01
    field = np.array([0.0, 20.0, -40.0])
    f = Mahony(kp=0.5, ki=0.05, axes=9, sample_period=dt)
    f.update_batch(np.tile(bias, (n, 1)), level_accel(n), np.tile(field, (n, 1)))
    assert f.gyro_bias == pytest.approx(bias, abs=1e-5)
    assert f.euler[2] == pytest.approx(0.0, abs=1e-4)  # body x faces east: yaw 0


def test_nine_axis_initialises_heading_from_magnetometer():
    r = Rotation.from_euler("ZYX", [1.1, 0.2, -0.3])
    field = np.array([0.0, 20.0, -40.0])
    f = Mahony(axes=9, sample_period=0.01)
    f.update(np.zeros(3), r.apply([0, 0, G], inverse=True), r.apply(field, inverse=True))
    assert abs(np.dot(f.quaternion, Q.from_scipy(r))) == pytest.approx(1.0, abs=1e-6)


def test_steady_spin_is_not_learnt_as_bias():
    """A robot spinning in place at 30 deg/s: constant gyro and accelerometer, not rest."""
    n, dt = 3000, 0.01
    f = Mahony(sample_period=dt)  # 6-axis defaults, rest detection on
    f.update_batch(np.tile([0.0, 0.0, math.radians(30)], (n, 1)), level_accel(n))
    assert f.counters.rest_samples == 0
    assert np.allclose(f.gyro_bias, 0.0, atol=1e-9)


def messy_inputs(n=3000, seed=7):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.016, n))
    gyro = rng.normal(0, 0.5, (n, 3))
    accel = level_accel(n, 0.2, -0.1) + rng.normal(0, 1.5, (n, 3))
    mag = np.tile([0.0, 20.0, -40.0], (n, 1)) + rng.normal(0, 2, (n, 3))
    gyro[100:110] = 0.0
    gyro[200] = np.nan
    accel[300] = 0.0
    accel[301, 1] = np.inf
    mag[400] = 0.0
    mag[401, 0] = np.nan
    # corrupt values (skipped and counted, never a poisoned state) and a gap (the gap policy)
    k = n // 5
    gyro[k, 2] = 1e200
    accel[k + 50, 0] = -1e150
    t[n // 2:] += 2.0
    return t, gyro, accel, mag


OPTIONS = [
    {},
    {"rest_detection": True, "accel_rejection": 1.5, "ramp_time": 1.0},
]


@pytest.mark.parametrize("axes", [6, 9])
@pytest.mark.parametrize("options", OPTIONS)
def test_streaming_equals_batch_exactly(axes, options):
    t, gyro, accel, mag = messy_inputs()
    m = mag if axes == 9 else None
    batch = Mahony(axes=axes, **options)
    out_b = batch.update_batch(gyro, accel, m, timestamps=t)
    stream = Mahony(axes=axes, **options)
    dts = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    out_s = np.array([
        stream.update(gyro[i], accel[i], None if m is None else m[i], dt=dts[i])
        for i in range(len(t))
    ])
    assert np.array_equal(out_b, out_s)
    assert np.array_equal(batch.gyro_bias, stream.gyro_bias)
    assert batch.counters == stream.counters
    assert batch.counters.gyro_skipped == 2 and batch.counters.accel_skipped == 3
    assert batch.counters.gaps == 1
    if axes == 9:
        assert batch.counters.mag_skipped >= 1
    assert np.all(np.isfinite(out_b))


@pytest.mark.parametrize("options", OPTIONS)
def test_split_run_equals_single_run(options):
    t, gyro, accel, mag = messy_inputs()
    whole = Mahony(axes=9, **options).update_batch(gyro, accel, mag, timestamps=t)
    f = Mahony(axes=9, **options)
    a = f.update_batch(gyro[:1234], accel[:1234], mag[:1234], timestamps=t[:1234])
    saved = f.get_state()
    b = f.update_batch(gyro[1234:], accel[1234:], mag[1234:], timestamps=t[1234:])
    assert np.array_equal(np.vstack([a, b]), whole)
    g = Mahony(axes=9, **options)
    g.set_state(saved)
    c = g.update_batch(gyro[1234:], accel[1234:], mag[1234:], timestamps=t[1234:])
    assert np.array_equal(c, b)


def test_per_sample_dt_equals_timestamps():
    t, gyro, accel, _ = messy_inputs()
    f1 = Mahony(sample_period=0.01)
    out1 = f1.update_batch(gyro, accel, timestamps=t)
    dts = np.diff(t, prepend=t[0] - 0.01)
    out2 = Mahony().update_batch(gyro, accel, dt=dts)
    assert np.array_equal(out1, out2)


def test_nan_gyro_row_holds_attitude_and_reset_forgets():
    f = Mahony(sample_period=0.01)
    q1 = f.update([0.1, 0.0, 0.0], [0, 0, G])
    q2 = f.update([np.nan, 0.0, 0.0], [0, 0, G])
    assert np.array_equal(q1, q2)
    assert f.counters.gyro_skipped == 1
    f.reset()
    assert f.counters.gyro_skipped == 0 and f.get_state().quaternion is None


def test_zero_accel_before_initialisation_is_counted_not_used():
    f = Mahony(sample_period=0.01)
    out = f.update_batch(np.zeros((3, 3)), [[0, 0, 0], [0, 0, 0], [0, G, 0]])
    assert np.array_equal(out[0], [1, 0, 0, 0]) and f.counters.accel_skipped == 2
    assert f.euler[0] == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda f: f.update([0, 0, 0], [0, 0, G], dt=0.0), "dt"),
        (lambda f: f.update([0, 0, 0], [0, 0, G], dt=-0.01), "dt"),
        (lambda f: f.update([0, 0, 0], [0, 0, G], dt=float("nan")), "dt"),
        (lambda f: f.update([0, 0], [0, 0, G], dt=0.01), "gyro must have 3"),
        (lambda f: f.update([0, 0, 0], [0, 0, G]), "no dt"),
        (lambda f: f.update_batch(np.zeros((4, 3)), np.zeros((3, 3)), dt=0.01), "accel has 3"),
        (lambda f: f.update_batch(np.zeros((4, 2)), np.zeros((4, 3)), dt=0.01), r"\(N, 3\)"),
        (lambda f: f.update_batch(np.zeros((3, 3)), np.zeros((3, 3)),
                                  timestamps=[0.0, 0.1, 0.1]), "index 2"),
        (lambda f: f.update_batch(np.zeros((3, 3)), np.zeros((3, 3)),
                                  dt=[0.1, -1, 0.1]), "index 1"),
    ],
)
def test_bad_input_raises_clear_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call(Mahony())


def test_bad_params_raise():
    with pytest.raises(ValueError, match="kp"):
        MahonyParams(kp=-1)
    with pytest.raises(ValueError, match="axes"):
        Mahony(axes=7)
    with pytest.raises(ValueError, match="initial_quaternion"):
        Mahony(initial_quaternion=[1, 0, 0])


def seed_mahony_fixed(gyro, accel, kp, seed_ki, half_t):
    """Seed 001's READ_DMP2 written out with its defects fixed (cross product present,
    integral added once, rad/s input) and its per-sample Ki kept: the reference for the
    gain mapping seed_Ki = Ki * dt."""
    q0, q1, q2, q3 = 1.0, 0.0, 0.0, 0.0
    ex_int = ey_int = ez_int = 0.0
    out = []
    for (gx, gy, gz), (ax, ay, az) in zip(gyro, accel):
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / norm, ay / norm, az / norm
        vx = 2 * (q1 * q3 - q0 * q2)
        vy = 2 * (q0 * q1 + q2 * q3)
        vz = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
        ex, ey, ez = ay * vz - az * vy, az * vx - ax * vz, ax * vy - ay * vx
        ex_int += ex * seed_ki
        ey_int += ey * seed_ki
        ez_int += ez * seed_ki
        gx, gy, gz = gx + kp * ex + ex_int, gy + kp * ey + ey_int, gz + kp * ez + ez_int
        q0, q1, q2, q3 = (
            q0 + (-q1 * gx - q2 * gy - q3 * gz) * half_t,
            q1 + (q0 * gx + q2 * gz - q3 * gy) * half_t,
            q2 + (q0 * gy - q1 * gz + q3 * gx) * half_t,
            q3 + (q0 * gz + q1 * gy - q2 * gx) * half_t,
        )
        norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        q0, q1, q2, q3 = q0 / norm, q1 / norm, q2 / norm, q3 / norm
        out.append((q0, q1, q2, q3))
    return np.array(out)


def test_seed_gain_mapping():
    """Our Ki per second equals the seed's per-sample Ki divided by dt."""
    _, gyro, accel, _ = messy_inputs(1500)
    gyro = np.nan_to_num(gyro)
    accel[300:302] = [0, 0, G]
    gyro[300], accel[350] = 0.0, [0, 0, G]  # corrupt rows: the filter skips them, the seed not
    dt, kp, seed_ki = 0.005, 2.0, 0.01
    ref = seed_mahony_fixed(gyro, accel, kp, seed_ki, dt / 2)
    f = Mahony(kp=kp, ki=seed_ki / dt, sample_period=dt, initial_quaternion=[1, 0, 0, 0],
               rest_detection=False)
    assert np.allclose(f.update_batch(gyro, accel), ref, atol=1e-12)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed: only one path exists")
def test_interpreted_path_equals_compiled(tmp_path):
    """The same Python source runs interpreted (no numba) with bit-identical results."""
    t, gyro, accel, mag = messy_inputs(800)
    opts = dict(rest_detection=True, accel_rejection=1.5, ramp_time=1.0)
    compiled = Mahony(axes=9, **opts).update_batch(gyro, accel, mag, timestamps=t)
    np.savez(tmp_path / "in.npz", t=t, gyro=gyro, accel=accel, mag=mag)
    code = (
        "import numpy as np, sys\n"
        "from fusion._jit import HAVE_NUMBA\n"
        "assert not HAVE_NUMBA\n"
        "from fusion.attitude.mahony import Mahony\n"
        f"d = np.load(r'{tmp_path / 'in.npz'}')\n"
        f"q = Mahony(axes=9, **{opts!r}).update_batch(d['gyro'], d['accel'], d['mag'],"
        " timestamps=d['t'])\n"
        f"np.save(r'{tmp_path / 'out.npy'}', q)\n"
    )
    env = {"FUSION_DISABLE_JIT": "1", "PATH": "/usr/bin:/bin"}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    assert np.array_equal(np.load(tmp_path / "out.npy"), compiled)


def test_hot_path_equals_batch_and_survives_reset_and_params():
    """update() without dt/mag (the compiled hot path) gives the batch result bit for bit."""
    _, gyro, accel, _ = messy_inputs(600)
    want = Mahony(sample_period=0.01).update_batch(gyro, accel)
    f = Mahony(sample_period=0.01)
    got = np.array([f.update(g, a) for g, a in zip(gyro, accel)])
    assert np.array_equal(got, want)
    f.reset()
    assert np.array_equal(np.array([f.update(g, a) for g, a in zip(gyro, accel)]), want)
    # int64 rows would be misread by compiled code: they must take the converting path
    g_int = np.zeros(3, dtype=np.int64)
    f2, f3 = Mahony(sample_period=0.01), Mahony(sample_period=0.01)
    for g, a in zip(gyro[:10], accel[:10]):
        f2.update(g, a)
        f3.update(g, a)
    assert np.array_equal(f2.update(g_int, accel[10]), f3.update(np.zeros(3), accel[10]))
    # a new sample period takes effect on the hot path too
    f2.params = MahonyParams(kp=0.15, ki=0.0005, sample_period=0.02)
    f3.params = MahonyParams(kp=0.15, ki=0.0005, sample_period=0.02)
    assert np.array_equal(f2.update(gyro[11], accel[11]),
                          f3.update(gyro[11], accel[11], dt=0.02))
