"""Unit conversion at the edges: strings such as "56 km/h" become SI floats.

Plain numbers are taken as SI. In crash work "g" (or "G") next to an acceleration means
standard gravity, not gram (nor gauss), so that one case is resolved by the dimension asked for.
A comma is refused: pint drops it ("40,5 km/h" would be 405 km/h), and a decimal comma
and a thousands separator cannot be told apart.

pint converts. Building its registry costs a quarter of a second in every process,
more than the rest of reading a problem, so each conversion pint has made is
remembered in the crashnlp cache (units-pint-<version>.json: text and target unit
-> SI value), and pint is loaded only for a text it has not converted before. The
remembered value is pint's own, to the last bit; failures are never remembered. A read marks
the table used: the cache's limit removes the least recently used kept files first
(crashnlp.numerics.compiled).
"""

from __future__ import annotations

import json
import re
from contextlib import suppress
from functools import cache
from pathlib import Path
from typing import Any

from crashnlp.base.cache import KEPT_UNITS, cache_dir, installed_version, used, write_atomic

G0 = 9.80665  # standard gravity, m/s^2

_G_TOKEN = re.compile(r"(?<![A-Za-z_])[gG](?![A-Za-z_0-9])")  # g, or G as NHTSA's files and init write it


class UnitError(ValueError):
    """A quantity that cannot be read or converted."""


@cache
def registry() -> Any:
    """pint's unit registry, built on first use."""
    import pint

    return pint.UnitRegistry()


@cache
def _dimensionality(unit: str):
    ureg = registry()
    return ureg.parse_units(unit).dimensionality if unit else ureg.dimensionless.dimensionality


def to_si(value: float | int | str, unit: str) -> float:
    """Convert a number (already SI) or a string with units into SI `unit`."""
    if isinstance(value, bool):
        raise UnitError(f"expected a quantity in {unit or 'no unit'}, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if not isinstance(value, str):
        raise UnitError(f"expected a number or a string with units, got {value!r}")
    text = value.strip()
    try:  # a plain number written as a string (YAML reads 1e6 as text) is SI too
        return float(text)
    except ValueError:
        pass
    if "," in text:  # before the table: a refused text is never looked up nor remembered
        raise UnitError(_comma(text))
    known = _remembered()
    key = f"{text}\t{unit}"
    if key not in known:
        known[key] = _convert(value, text, unit)
        _remember(known)
    return known[key]


def _comma(text: str) -> str:
    """Why a text with a comma is refused, and the text to write: for a single comma between
    digits and no point, the comma as a decimal point (and without it too where three digits
    follow, as in a thousands separator)."""
    if text.count(",") != 1 or "." in text or not re.search(r"\d,\d", text):
        return "a comma in a number; write numbers with a decimal point and no thousands separator"
    thousands = f" or {text.replace(',', '')}" if re.search(r",\d{3}(?!\d)", text) else ""
    return f"a comma in a number; write {text.replace(',', '.')}{thousands}"


def _convert(value: str, text: str, unit: str) -> float:
    """pint's conversion of `text` into `unit`."""
    import pint

    ureg = registry()
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


def _table() -> Path:
    return cache_dir() / KEPT_UNITS.format(version=installed_version("pint", "pint"))


@cache
def _remembered() -> dict[str, float]:
    """The conversions pint made in earlier processes (empty when the table is unreadable), the
    table marked used."""
    table = _table()
    try:
        known = json.loads(table.read_text())
    except (OSError, ValueError):
        return {}
    used(table)
    return {k: float(v) for k, v in known.items()} if isinstance(known, dict) else {}


def _remember(known: dict[str, float]) -> None:
    """Write the table (whole, atomically; a lost race only costs a conversion later)."""
    with suppress(OSError):
        write_atomic(_table(), json.dumps(known, sort_keys=True))


def unit_scale(unit: str, si_unit: str) -> float:
    """Factor that turns a value in `unit` into `si_unit` (e.g. 'g' -> 'm/s^2': 9.80665)."""
    return to_si(f"1 {unit}", si_unit)
