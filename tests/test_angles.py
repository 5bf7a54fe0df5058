"""fusion.geometry.angles: one wrapping to (-pi, pi], array and scalar forms.

Oracles: the exact seam values stated in the module's convention, and numpy's
``arctan2(sin a, cos a)`` (an independent definition of the wrapped angle) away from the seam.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import fusion.evaluation.trajectory
import fusion.planar.odometry
from fusion._jit import HAVE_NUMBA, njit
from fusion.geometry.angles import wrap_angle, wrap_angle_scalar

PI = math.pi
ABOVE_PI = math.nextafter(PI, 4.0)  # the double just above pi: past the true seam
ABOVE_MINUS_PI = math.nextafter(-PI, 0.0)  # the double just above -pi

# (input, exact output) of the documented convention
SEAM = [
    (PI, PI), (-PI, PI), (3 * PI, PI), (-3 * PI, PI),
    (0.0, 0.0), (-0.0, 0.0), (2 * PI, 0.0), (-2 * PI, 0.0),
    (ABOVE_PI, -PI), (ABOVE_MINUS_PI, PI),
    (math.nextafter(PI, 0.0), math.nextafter(PI, 0.0)),
    (PI / 2, PI / 2), (-PI / 2, -PI / 2), (1.5 * PI, -PI / 2),
]


def _scalar_forms():
    forms = [wrap_angle_scalar]
    if HAVE_NUMBA:
        forms.append(wrap_angle_scalar.py_func)  # the interpreted source of the compiled one
    return forms


@pytest.mark.parametrize(("a", "expected"), SEAM)
def test_seam_values_exactly(a, expected):
    for f in (wrap_angle, *_scalar_forms()):
        got = f(a)
        assert got == expected and math.copysign(1.0, got) == math.copysign(1.0, expected), f
    assert wrap_angle(np.array([a]))[0] == expected


def test_matches_arctan2_of_sin_cos_away_from_the_seam():
    rng = np.random.default_rng(7)
    a = np.concatenate([rng.uniform(-4 * PI, 4 * PI, 20000), rng.uniform(-1e3, 1e3, 20000)])
    ref = np.arctan2(np.sin(a), np.cos(a))
    away = np.abs(np.abs(ref) - PI) > 1e-9
    # both sides carry the rounding of |a| (ulp(1e3) = 1.1e-13) and of sin/cos/arctan2
    np.testing.assert_allclose(wrap_angle(a)[away], ref[away], rtol=0, atol=1e-12)
    w = wrap_angle(a)
    assert np.all((w >= -PI) & (w <= PI))


def test_scalar_and_array_forms_agree_bit_for_bit():
    rng = np.random.default_rng(3)
    k = np.arange(-2000, 2000)
    seams = (2 * k + 1) * np.pi
    a = np.concatenate([rng.uniform(-1e6, 1e6, 5000), rng.uniform(-10, 10, 5000), seams,
                        np.nextafter(seams, np.inf), np.nextafter(seams, -np.inf), [0.0, -0.0]])
    arr = wrap_angle(a)
    for f in _scalar_forms():
        sc = np.array([f(float(x)) for x in a])
        np.testing.assert_array_equal(sc.view(np.int64), arr.view(np.int64))
    assert np.all((arr >= -PI) & (arr <= PI))  # also at the seams of large angles


def test_non_finite_gives_nan():
    for f in (wrap_angle, *_scalar_forms()):
        for a in (math.nan, math.inf, -math.inf):
            with np.errstate(invalid="ignore"):
                assert math.isnan(f(a))


def test_array_shape_and_scalar_type():
    assert isinstance(wrap_angle(4.0), float)
    assert wrap_angle(np.zeros((2, 3))).shape == (2, 3)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_scalar_form_is_callable_from_a_compiled_core():
    @njit(cache=False)
    def core(values):
        out = np.empty_like(values)
        for i in range(values.size):
            out[i] = wrap_angle_scalar(values[i])
        return out

    a = np.linspace(-20.0, 20.0, 1001)
    np.testing.assert_array_equal(core(a), wrap_angle(a))


def test_public_names_are_the_canonical_function():
    assert fusion.planar.odometry.wrap_angle is wrap_angle
    assert fusion.evaluation.trajectory.wrap_angle is wrap_angle
