"""Units at the edges: pint's conversions, remembered across processes to the bit."""

from __future__ import annotations

import json

import pytest

from crashnlp.base import units
from crashnlp.base.units import G0, UnitError, to_si


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    """An empty cache, and the process's memory of it forgotten (as in a new process)."""
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path))
    units._remembered.cache_clear()
    yield tmp_path
    units._remembered.cache_clear()


def new_process(monkeypatch) -> None:
    """Forget what this process knows, and make pint unusable: only the table can answer."""
    units._remembered.cache_clear()

    def no_pint():
        raise AssertionError("pint was loaded for a remembered conversion")

    monkeypatch.setattr(units, "registry", no_pint)


@pytest.mark.parametrize(
    ("text", "unit", "si"),
    [
        ("56 km/h", "m/s", 56 / 3.6),
        ("30 g", "m/s^2", 30 * G0),  # g of an acceleration is standard gravity, not gram
        ("30 G", "m/s^2", 30 * G0),  # and G, as NHTSA's files write it, not gauss
        ("2550 kg", "kg", 2550.0),
        ("4800 kg*m^2", "kg*m^2", 4800.0),
        ("70 kN/m", "N/m", 70e3),
        ("10 deg", "rad", 0.17453292519943295),
        ("1e6", "N", 1e6),
    ],
)
def test_conversions_into_si(fresh, text, unit, si):
    assert to_si(text, unit) == pytest.approx(si, rel=1e-12)


def test_a_remembered_conversion_is_pints_own_without_loading_pint(fresh, monkeypatch):
    first = [to_si(text, unit) for text, unit in (("56 km/h", "m/s"), ("8 kN*s/m", "N*s/m"), ("0.3 g", "m/s^2"))]
    (table,) = fresh.glob("units-pint-*.json")
    assert len(json.loads(table.read_text())) == 3
    new_process(monkeypatch)
    again = [to_si(text, unit) for text, unit in (("56 km/h", "m/s"), ("8 kN*s/m", "N*s/m"), ("0.3 g", "m/s^2"))]
    assert again == first  # bit for bit


def test_the_same_text_in_another_unit_is_converted_anew(fresh):
    assert to_si("1 km", "m") == 1000.0
    with pytest.raises(UnitError, match="does not convert to s"):
        to_si("1 km", "s")


def test_failures_are_not_remembered(fresh):
    with pytest.raises(UnitError, match="cannot read"):
        to_si("56 furlongs per fortnightz", "m/s")
    with pytest.raises(UnitError, match="does not convert"):
        to_si("3 kg", "m/s")
    assert not list(fresh.glob("units-pint-*.json"))


def test_an_unreadable_table_is_ignored(fresh):
    to_si("56 km/h", "m/s")
    (table,) = fresh.glob("units-pint-*.json")
    table.write_text("{not json")
    units._remembered.cache_clear()
    assert to_si("56 km/h", "m/s") == pytest.approx(56 / 3.6)


@pytest.mark.parametrize(
    ("text", "unit", "expected"),
    [
        ("40,5 km/h", "m/s", "a comma in a number; write 40.5 km/h"),  # pint reads 405 km/h
        ("1719,5 kg", "kg", "a comma in a number; write 1719.5 kg"),
        ("1,000 kg", "kg", "a comma in a number; write 1.000 kg or 1000 kg"),  # a decimal comma or thousands?
        ("1,719.5 kg", "kg", "a comma in a number; write numbers with a decimal point and no thousands separator"),
    ],
)
def test_a_comma_in_a_number_is_refused_and_never_remembered(fresh, monkeypatch, text, unit, expected):
    """pint drops a comma: refused before the table, also where an older table holds pint's reading."""
    with pytest.raises(UnitError, match=f"^{expected}$"):
        to_si(text, unit)
    assert not list(fresh.glob("units-pint-*.json"))
    units._remember({f"{text}\t{unit}": 112.5})  # what a table written before the refusal may hold
    new_process(monkeypatch)
    with pytest.raises(UnitError, match=f"^{expected}$"):
        to_si(text, unit)
