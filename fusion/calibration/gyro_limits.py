"""What a gyro log cannot be: beyond every MPU6050 full scale (other units), or clipped at one.

Both calibrations (:mod:`fusion.calibration.gyro_scale`, :mod:`fusion.calibration.odometry`)
take the gyro as their reference, so a rate in deg/s or a rate held at the sensor's limit
gives a confident wrong answer rather than an error. These checks name them.

Units: rad/s.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["GYRO_FULL_SCALES", "GYRO_FULL_SCALE_MAX", "check_gyro_units", "saturated_samples"]

#: rad/s: the MPU6050's full-scale ranges (FS_SEL 0-3: 250, 500, 1000, 2000 deg/s)
GYRO_FULL_SCALES = tuple(math.radians(d) for d in (250.0, 500.0, 1000.0, 2000.0))
#: rad/s: the largest of them. A reading beyond it is in other units (deg/s: a turn at
#: 1 rad/s reads 57.3).
GYRO_FULL_SCALE_MAX = GYRO_FULL_SCALES[-1]
#: A clipped reading lies within this share of a full scale: the driver takes the bias off
#: the chip's limit (an MPU6050's zero-rate output is within 20 deg/s, 8 % of 250 deg/s).
CLIP_SHARE = 0.1


def check_gyro_units(gyro: ArrayLike, where: str = "the gyro") -> None:
    """Raise ``ValueError`` if an axis of ``gyro`` ((N, 3) rad/s) reads beyond
    :data:`GYRO_FULL_SCALE_MAX`, naming the reading and the likely units."""
    g = np.abs(np.asarray(gyro, dtype=float).reshape(-1, 3))
    peak = float(g.max(initial=0.0))
    if peak > GYRO_FULL_SCALE_MAX:
        raise ValueError(
            f"{where} reads up to {peak:.3g} rad/s on one axis, beyond an MPU6050's largest "
            f"full scale ({GYRO_FULL_SCALE_MAX:.3g} rad/s = 2000 deg/s): the rates are in "
            "other units (deg/s?); the gyro columns are in rad/s")


def saturated_samples(gyro: ArrayLike, least_run: int = 3) -> NDArray[np.bool_]:
    """(N,) bool: samples at which some axis of ``gyro`` ((N, 3) rad/s, in the IMU's own
    axes: a mount rotation mixes a clipped axis with others) is held at its limit.

    A limit is the axis's most positive (or most negative) reading, held for ``least_run``
    samples in a row or more, and within :data:`CLIP_SHARE` of a full scale
    (:data:`GYRO_FULL_SCALES`): a clipped sensor repeats its limit, a real peak does not, and
    a smooth, finely quantised peak far from any full scale is no clip. Each sign has its
    own limit (a 16-bit reading clips at +32767 and -32768, and a driver that takes the bias
    off moves the two apart).
    """
    g = np.asarray(gyro, dtype=float).reshape(-1, 3)
    out = np.zeros(g.shape[0], dtype=bool)
    for axis in range(3):
        for sign in (1.0, -1.0):
            values = sign * g[:, axis]
            top = float(values.max(initial=0.0))
            if top <= 0.0 or not any(abs(top / fs - 1.0) <= CLIP_SHARE
                                     for fs in GYRO_FULL_SCALES):
                continue
            at = values >= top * (1.0 - 1e-9)
            edges = np.flatnonzero(np.diff(np.concatenate(([0], at.astype(int), [0]))))
            for start, stop in zip(edges[::2], edges[1::2], strict=True):
                if stop - start >= least_run:
                    out[start:stop] = True
    return out
