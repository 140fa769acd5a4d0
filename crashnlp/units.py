"""Unit conversion at the edges: strings such as "56 km/h" become SI floats.

Plain numbers are taken as SI. In crash work "g" next to an acceleration means
standard gravity, not gram, so that one case is resolved by the dimension asked for.
"""

from __future__ import annotations

import re
from functools import cache, lru_cache
from typing import Any

import pint

ureg: pint.UnitRegistry = pint.UnitRegistry()
G0 = 9.80665  # standard gravity, m/s^2

_G_TOKEN = re.compile(r"(?<![A-Za-z_])g(?![A-Za-z_0-9])")


class UnitError(ValueError):
    """A quantity that cannot be read or converted."""


@cache
def _dimensionality(unit: str):
    return ureg.parse_units(unit).dimensionality if unit else ureg.dimensionless.dimensionality


def to_si(value: float | int | str, unit: str) -> float:
    """Convert a number (already SI) or a string with units into SI `unit`."""
    if isinstance(value, bool):
        raise UnitError(f"expected a quantity in {unit or 'no unit'}, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if not isinstance(value, str):
        raise UnitError(f"expected a number or a string with units, got {value!r}")
    return _string_to_si(value, unit)


@lru_cache(maxsize=4096)
def _string_to_si(value: str, unit: str) -> float:
    """A quantity written as text in SI `unit`. Cached: pint's parser is slow and a study
    validates the same strings in every case (30 ms a case uncached, 4 ms cached)."""
    text = value.strip()
    try:  # a plain number written as a string (YAML reads 1e6 as text) is SI too
        return float(text)
    except ValueError:
        pass
    target = ureg.parse_units(unit) if unit else ureg.dimensionless
    if _dimensionality(unit) == _dimensionality("m/s^2"):
        text = _G_TOKEN.sub("g_0", text)
    try:
        quantity: Any = ureg.Quantity(text)
    except Exception as exc:  # pint raises several unrelated types
        raise UnitError(f"cannot read {value!r} as a quantity") from exc
    if not isinstance(quantity, ureg.Quantity):
        return float(quantity)
    try:
        return float(quantity.to(target).magnitude)
    except pint.DimensionalityError:
        raise UnitError(f"{value!r} does not convert to {unit or 'a plain number'}") from None


def unit_scale(unit: str, si_unit: str) -> float:
    """Factor that turns a value in `unit` into `si_unit` (e.g. 'g' -> 'm/s^2': 9.80665)."""
    return to_si(f"1 {unit}", si_unit)
