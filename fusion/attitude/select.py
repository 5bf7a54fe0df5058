"""Choose an attitude filter by name, with parameters given by name (``robot.toml``'s
``[attitude]`` table, the pipeline's default filter).

The filters: ``"keel"`` (:class:`fusion.attitude.keel.Keel`, the default) and ``"mahony"``
(:class:`fusion.attitude.mahony.Mahony`, 6-axis preset). Parameters are the fields of the
filter's parameter class (SI units), except ``sample_period``, which the caller sets.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import fields
from typing import Any

from fusion.attitude.keel import Keel, KeelParams
from fusion.attitude.mahony import PRESETS, Mahony, MahonyParams

__all__ = ["FILTER_PARAMS", "build_attitude_filter", "parameter_kinds"]

#: Filter name -> its parameter class.
FILTER_PARAMS: dict[str, type] = {"keel": KeelParams, "mahony": MahonyParams}


def parameter_kinds(name: str) -> dict[str, type]:
    """The parameters a configuration may set for filter ``name``: name -> ``bool`` or
    ``float`` (``sample_period`` is left out: the caller sets it)."""
    if name not in FILTER_PARAMS:
        raise ValueError(f"unknown attitude filter {name!r}; known: {', '.join(FILTER_PARAMS)}")
    defaults = FILTER_PARAMS[name]()
    return {f.name: bool if isinstance(getattr(defaults, f.name), bool) else float
            for f in fields(FILTER_PARAMS[name]) if f.name != "sample_period"}


def build_attitude_filter(name: str, params: Iterable[tuple[str, Any]] = (), *,
                          sample_period: float | None = None) -> Keel | Mahony:
    """A 6-axis filter ``name`` (``"keel"`` or ``"mahony"``) with the given parameters over
    the defaults (Mahony's 6-axis preset) and ``sample_period`` (s, the first step's period).

    Raises:
        ValueError: an unknown filter or parameter name, or a value the filter refuses
            (the message names it).
    """
    kinds = parameter_kinds(name)
    given = dict(params)
    unknown = sorted(set(given) - set(kinds))
    if unknown:
        raise ValueError(f"unknown {name} parameter(s) {unknown}; allowed: {sorted(kinds)}")
    if name == "keel":
        return Keel(axes=6, sample_period=sample_period, **given)
    return Mahony(axes=6, sample_period=sample_period, **{**PRESETS[6], **given})
