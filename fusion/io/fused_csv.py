"""The fused-odometry CSV: one format for every CSV the library writes of the fused state.

``fusion replay -o fused.csv`` writes the EKF state after every IMU sample (or wheel frame
without an IMU); ``fusion run --publish csv:PATH`` (:class:`fusion.sinks.text.CsvSink`) one row
per published record. Both use these columns, in this order:

==========================  =====================================================================
``t``                       s, host clock (a record's stamp; a state row's effective time)
``x``, ``y``, ``yaw``       pose of base_footprint in odom: m, m, rad wrapped to (-pi, pi]
``v``, ``w``                forward speed m/s, yaw rate rad/s
``gyro_bias_z``             the EKF's gyro bias about the vertical, rad/s
``wheel_rate_scale``        its wheel yaw-rate scale state k (1)
``wheel_rate_per_speed``    its wheel yaw-rate per speed state c, rad/m
``var_x`` .. ``cov_y_yaw``  pose covariance: m^2, m^2, rad^2, m^2, m*rad, m*rad
``var_v``, ``var_w``        (m/s)^2, (rad/s)^2
``wheel_left_speed``, ..    rim speed of each wheel in the last wheel frame, m/s
``zupt``, ``slip``,         1 or 0: what the EKF made of the last wheel frame (or odometry twist):
``encoder_fault``           a zero-velocity update, a slip (yaw rate not fused), an encoder fault
                            (zero speed while the IMU moved; not fused)
==========================  =====================================================================

Files written before the flag columns existed (the first 19 columns only) still read: their
flags come back as NaN (unknown).

An empty cell is a value the row does not have (a record carries no bias states; no wheel
frame yet). Numbers are written with Python's shortest round-trip repr: every bit of the value,
so epoch stamps keep their sub-second part and equal states give identical bytes. Files are
replaced atomically (:mod:`fusion.io.atomic`).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.atomic import atomic_write
from fusion.io.errors import LogFormatError

__all__ = ["FLAG_COLUMNS", "FUSED_CSV_COLUMNS", "format_fused_row", "read_fused_csv",
           "write_fused_csv"]

FUSED_CSV_COLUMNS = (
    "t", "x", "y", "yaw", "v", "w", "gyro_bias_z", "wheel_rate_scale", "wheel_rate_per_speed",
    "var_x", "var_y", "var_yaw", "cov_xy", "cov_x_yaw", "cov_y_yaw", "var_v", "var_w",
    "wheel_left_speed", "wheel_right_speed", "zupt", "slip", "encoder_fault",
)
#: The columns of fused CSVs written before the per-record flags (still read).
FLAG_COLUMNS = ("zupt", "slip", "encoder_fault")
_OLD_COLUMNS = FUSED_CSV_COLUMNS[:-len(FLAG_COLUMNS)]

_HEADER = ",".join(FUSED_CSV_COLUMNS) + "\n"


def format_fused_row(values: Sequence[float | None]) -> str:
    """One CSV line (with its newline) of :data:`FUSED_CSV_COLUMNS` values; None or NaN give
    an empty cell."""
    if len(values) != len(FUSED_CSV_COLUMNS):
        raise ValueError(f"a fused CSV row has {len(FUSED_CSV_COLUMNS)} values, got "
                         f"{len(values)}")
    return ",".join("" if v is None or v != v else repr(float(v)) for v in values) + "\n"


def write_fused_csv(path: str | Path, rows: NDArray[np.float64] | Iterable[Sequence[float]]
                    ) -> None:
    """Write ``rows`` ((N, 22) in :data:`FUSED_CSV_COLUMNS` order; NaN = empty) to ``path``,
    atomically (an existing file is replaced only by a complete one)."""
    table = np.asarray(rows, dtype=np.float64).reshape(-1, len(FUSED_CSV_COLUMNS))
    with atomic_write(Path(path), encoding="ascii", newline="") as fh:
        fh.write(_HEADER)
        fh.writelines(format_fused_row(r) for r in table.tolist())


def read_fused_csv(path: str | Path) -> dict[str, NDArray[np.float64]]:
    """Columns of a fused CSV by name (empty cells NaN; every one of
    :data:`FUSED_CSV_COLUMNS`, the flags NaN in a file written before they existed).

    Raises:
        LogFormatError: the header is neither :data:`FUSED_CSV_COLUMNS` nor the older one
            without the flags, or a cell is not a number (naming ``file:line``).
    """
    path = Path(path)
    with path.open(newline="", encoding="ascii") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or tuple(header) not in (FUSED_CSV_COLUMNS, _OLD_COLUMNS):
            raise LogFormatError(f"{path}:1: not a fused CSV (expected the header "
                                 f"{','.join(FUSED_CSV_COLUMNS)})")
        width = len(header)
        rows = []
        for line, row in enumerate(reader, start=2):
            if len(row) != width:
                raise LogFormatError(f"{path}:{line}: {len(row)} cells, expected {width}")
            try:
                rows.append([float(c) if c else math.nan for c in row])
            except ValueError:
                raise LogFormatError(f"{path}:{line}: a cell is not a number: {row}") from None
    table = np.array(rows, dtype=np.float64).reshape(-1, width)
    out = {name: table[:, i].copy() for i, name in enumerate(header)}
    for name in FUSED_CSV_COLUMNS[width:]:
        out[name] = np.full(table.shape[0], math.nan)
    return out
