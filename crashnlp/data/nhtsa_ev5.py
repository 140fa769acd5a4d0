"""NHTSA EV5 ASCII X-Y reader: the pipe-delimited .EV5 header and one two-column file per curve.

Header cards used (fields counted from 1, as in the NHTSA Test Reference Guide):
- TEST: 15 closing speed CLSSPD [km/h], 19 total number of curves TOTCRV.
- VEHICLE: 1 vehicle number, 11 test mass VEHTWT [kg], 13 wheelbase [mm], 14 length [mm],
  16 CG behind the front axle VEHCG [mm].
- INSTRUMENTATION: 1 vehicle number, 2 curve number, 3 sensor type, 5 sensor location, 6 axis, 7 x units,
  8 y units, 15 first point NFP, 16 last point NLP, 17 sample interval DELT [us],
  18 data status DASTAT, 19 channel status (P primary, R redundant), 20 comment.
Curve NNN lives next to the header as <stem>.NNN (time [s] TAB value).

A curve is read only as far as the header says its data are valid (`valid_until`): status NO
(not installed) or CF ("No valid data") never, "No valid data after 67ms" up to 67 ms. A curve
file that ends before that (by more than END_TOLERANCE samples) is cut short, and refused. A
barrier load cell whose curve is flat after impact (`flat_after_impact`) is dead whatever the
header says: left out of `all-valid-barrier-fx`, refused where a problem names it.
"""

from __future__ import annotations

import glob
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.data.channels import (
    END_TOLERANCE,
    Channel,
    DataError,
    TestData,
    check_samples,
    median_interval,
    of_key,
    si_factor,
    where,
)
from crashnlp.data.clipping import check_clipped
from crashnlp.data.csv_reader import Table
from crashnlp.problem.schema import ALL_BARRIER_FX, CHANNEL_UNITS, SUMMED, ChannelSpec, DataSpec

# EV5 unit codes -> pint units
UNITS = {
    "G'S": "g",
    "G": "g",
    "NWT": "N",
    "NWM": "N*m",
    "MM": "mm",
    "M": "m",
    "CM": "cm",
    "DEG": "deg",
    "RAD": "rad",
    "DPS": "deg/s",
    "RPS": "rad/s",
    "MPS": "m/s",
    "KPH": "km/h",
    "M/S": "m/s",
    "KM/H": "km/h",
    "SEC": "s",
    "MS": "ms",
}
NO_DATA = {"NO"}  # data status meaning the channel holds no data (e.g. sensor not installed)
FAILED = {"CF"}  # data status of a failed channel: valid only as far as its comment says
NEVER_VALID = ("NO VALID DATA", "NOT INSTALLED")  # comments, upper case, of a curve holding no data
VALID_UNTIL = re.compile(r"NO VALID DATA AFTER\s*([0-9.]+)\s*MS")  # a comment giving the end of the valid data
# at most this many distinct values after impact: a load cell's converter flickering between a few
# counts, or one value held, not a cell the impact loaded (design-notes.md, "Dead load cells")
FLAT_LEVELS = 8
# Accelerometers averaged into one channel take one velocity change: the Camry's (test 10146) six
# vehicle X accelerometers change it from impact on within 10 % of each other. Curves further apart
# than CURVES_APART times were read in different units: a curve in m/s^2 under a G'S header takes
# 9.81 times the change, and its mean with a curve in g stops the vehicle 5.4 times over.
CURVES_APART = 2.0
# a curve that changes the velocity by less than this share of the curve that changes it most reads
# no pulse: dead (a unit slip takes a ninth, m/s^2 read as g, or a thousandth and more of mm/s^2;
# a dead sensor's noise integrates to a hundredth of the change or less)
DEAD_SHARE = 0.05


@dataclass
class Curve:
    """One INSTRUMENTATION line."""

    number: int
    vehicle: int
    location: str
    axis: str
    unit: str
    first: int
    last: int
    interval: float  # s
    status: str
    comment: str
    sensor: str = ""  # field 3, e.g. AC (accelerometer)
    primary: bool = True  # field 19: P primary, R redundant


def curve_files(header: Path) -> list[Path]:
    """The files a test's curves may be read from: the header and every <stem>.NNN beside it."""
    return [header, *sorted(header.parent.glob(f"{glob.escape(header.stem)}.[0-9][0-9][0-9]"))]


def _cards(path: Path) -> dict[str, list[list[str]]]:
    """Header lines by card name, each split on '|'."""
    cards: dict[str, list[list[str]]] = {}
    current = None
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    for line in lines:
        text = line.strip()
        if text.startswith("-----") and text.endswith("-----"):
            current = text.strip("- ").upper()
            cards.setdefault(current, [])
        elif text and current is not None and not text.startswith("#"):
            cards[current].append([f.strip() for f in text.split("|")])
    for name in ("TEST", "INSTRUMENTATION"):
        if not cards.get(name):
            raise DataError(f"{path}: no {name} card (not an EV5 header?)")
    return cards


def card_number(fields: list[str], index: int) -> float | None:
    """Field `index` (counted from 1) as a float, or None when absent or not a number."""
    try:
        return float(fields[index - 1])
    except (IndexError, ValueError):
        return None


def _curves(path: Path, rows: list[list[str]]) -> dict[int, Curve]:
    curves = {}
    for row in rows:
        try:
            number = int(row[1])
            curves[number] = Curve(
                number=number,
                vehicle=int(row[0]),
                location=row[4],
                axis=row[5],
                unit=row[7],
                first=int(row[14]),
                last=int(row[15]),
                interval=float(row[16]) * 1e-6,
                status=row[17].upper() if len(row) > 17 else "",
                comment="|".join(row[19:]),
                sensor=row[2].upper(),
                primary=len(row) <= 18 or row[18].upper() != "R",
            )
        except (IndexError, ValueError):
            raise DataError(f"{path}: INSTRUMENTATION line {'|'.join(row)[:40]!r} is malformed") from None
    return curves


def read_header(path: Path) -> tuple[dict[str, list[list[str]]], dict[int, Curve]]:
    """The header's cards (lines split on '|') and its INSTRUMENTATION curves by number."""
    cards = _cards(path)
    return cards, _curves(path, cards["INSTRUMENTATION"])


def valid_until(curve: Curve) -> float | None:
    """The last time [s] the header says a curve's data are valid: inf throughout, None never.

    Status NO, or a comment "No valid data" or "Not installed", is never valid; a comment "No
    valid data after 67ms" is valid up to 67 ms; status CF (channel failed) without one, never."""
    comment = curve.comment.upper()
    until = VALID_UNTIL.search(comment)
    if until and curve.status not in NO_DATA:
        return float(until.group(1)) * 1e-3
    if curve.status in NO_DATA | FAILED or any(text in comment for text in NEVER_VALID):
        return None
    return math.inf


def _read_curve(path: Path, header: Path, curve: Curve, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """Time and raw values of one curve, cut to the valid range NFP..NLP and to `valid_until`."""
    at = where(path, channel, f"curve {curve.number}")
    until = valid_until(curve)
    if until is None:
        raise DataError(f"{at}: the header marks the curve's data as not valid ({curve.status}: {curve.comment})")
    if not path.is_file():
        raise DataError(f"{at}: curve file missing (listed in {header.name})")
    table = Table.read(path)
    time, values = table.values(0, channel), table.values(1, channel)
    check_samples(time, values, at)
    if curve.interval > 0:
        dt = median_interval(time)
        if abs(dt - curve.interval) > 0.01 * curve.interval:
            raise DataError(f"{at}: sample interval {dt:g} s differs from the header's {curve.interval:g} s")
        tol = 0.5 * curve.interval
        end = min(curve.last * curve.interval, until)
        if time[-1] < end - END_TOLERANCE * curve.interval:
            raise DataError(
                f"{at}: the file ends at {time[-1] * 1e3:g} ms, but the header says the curve runs to {end * 1e3:g} ms"
                f" (NLP {curve.last}): the file is cut short"
            )
        valid = (time >= curve.first * curve.interval - tol) & (time <= end + tol)
        time, values = time[valid], values[valid]
    else:
        time, values = time[time <= until], values[time <= until]
    if time.size < 2:
        raise DataError(f"{at}: no samples in the valid range the header gives")
    return time, values


def is_barrier_cell(curve: Curve) -> bool:
    """Whether a curve is one of the barrier's Fx load cells (sensor LC, axis XG, a force unit)."""
    return curve.sensor == "LC" and curve.axis == "XG" and UNITS.get(curve.unit.upper()) == "N"


def barrier_cells(header: Path, curves: dict[int, Curve]) -> tuple[list[int], list[Curve]]:
    """The barrier's Fx load cells: the numbers of those the header marks valid throughout, and
    the curves of those it marks invalid for some or all of the test."""
    cells = [c for c in curves.values() if is_barrier_cell(c)]
    if not cells:
        raise DataError(f"{header}: no barrier Fx load cell (sensor LC, axis XG, unit NWT) in the INSTRUMENTATION card")
    kept = [c.number for c in cells if valid_until(c) == math.inf]
    if not kept:
        raise DataError(f"{header}: the header marks every barrier Fx load cell as not valid")
    return kept, [c for c in cells if valid_until(c) != math.inf]


def flat_after_impact(curve: Curve, time: np.ndarray, values: np.ndarray) -> str | None:
    """Why a barrier load cell is dead though its header may not say so: after impact (t = 0) its
    curve takes no more than FLAT_LEVELS distinct values. None for a live cell and for any other
    curve (a coarse pitch or a quiet sensor elsewhere may hold few values and still be measured)."""
    levels = np.unique(values[time >= 0]).size
    if not is_barrier_cell(curve) or levels > FLAT_LEVELS:
        return None
    return f"flat after impact, {levels} distinct value{'' if levels == 1 else 's'}"


Read = tuple[Curve, Path, np.ndarray, np.ndarray]  # a curve, its file, its time and raw values


def _read_numbered(header: Path, curves: dict[int, Curve], number: int, name: str) -> Read:
    """Curve `number` of the header, read as far as it is valid (`_read_curve`)."""
    if number not in curves:
        raise DataError(f"{where(header, name, f'curve {number}')}: curve not in the INSTRUMENTATION card")
    curve = curves[number]
    file = header.with_suffix(f".{number:03d}")
    return (curve, file, *_read_curve(file, header, curve, name))


def _read_named(header: Path, curves: dict[int, Curve], numbers: list[int], name: str) -> list[Read]:
    """The curves a problem names, each read; a barrier load cell flat after impact is refused
    as one the header marks not valid is."""
    read = [_read_numbered(header, curves, number, name) for number in numbers]
    for curve, file, time, values in read:
        if why := flat_after_impact(curve, time, values):
            raise DataError(
                f"{where(file, name, f'curve {curve.number}')}: the load cell is dead ({why}), though the header"
                f" marks it valid ({curve.status}: {curve.comment})"
            )
    return read


def live_barrier_cells(
    header: Path, curves: dict[int, Curve], name: str
) -> tuple[list[Read], list[Curve], list[tuple[Curve, str]]]:
    """Every barrier Fx load cell the header marks valid and whose curve is not flat after impact,
    read; the cells the header marks not valid; and the flat ones, each with why."""
    kept, marked = barrier_cells(header, curves)
    live, flat = [], []
    for number in kept:
        curve, file, time, values = _read_numbered(header, curves, number, name)
        why = flat_after_impact(curve, time, values)
        if why:
            flat.append((curve, why))
        else:
            live.append((curve, file, time, values))
    if not live:
        raise DataError(f"{header}: every barrier Fx load cell is marked not valid or flat after impact")
    return live, marked, flat


def _read_curves(header: Path, curves: dict[int, Curve], name: str, ch: ChannelSpec) -> tuple[list[Read], str | None]:
    """The curves a channel reads, and a note of what `all-valid-barrier-fx` summed and left out."""
    if ch.curves == ALL_BARRIER_FX:
        live, marked, flat = live_barrier_cells(header, curves, name)
        left_out = [f"{c.number:03d} ({c.status}: {c.comment})" for c in marked]
        left_out += [f"{c.number:03d} ({why}: {c.comment})" for c, why in flat]
        dropped = "; ".join(left_out) or "none"
        return live, f"{name}: {len(live)} barrier Fx load cells summed; dropped as not valid: {dropped}"
    if not isinstance(ch.curves, tuple) or not ch.curves:
        raise DataError(f"{where(header, name)}: no curves given (an EV5 channel needs `curves`)")
    return _read_named(header, curves, list(ch.curves), name), None


def read_ev5(spec: DataSpec) -> TestData:
    """Channels from the curves `ChannelSpec.curves` (averaged when several, summed for a
    force), values in SI.

    Units come from the header (G'S is g) unless `ChannelSpec.unit` overrides. A curve whose
    header marks a shorter valid range (NLP, or a comment "No valid data after ...") is cut to
    it, and one it marks not valid is refused, as is a barrier load cell flat after impact;
    combined curves must share sample interval and time range. Meta: 'speed' [m/s] from the TEST
    card, 'mass' [kg] from the VEHICLE card of the vehicle carrying the curves (the barrier's are
    vehicle 0).
    """
    header = spec.file
    cards, curves = read_header(header)
    meta: dict[str, float] = {}
    speed = card_number(cards["TEST"][0], 15)
    if speed is not None and speed > 0:
        meta["speed"] = speed / 3.6
    vehicle = 1
    channels: dict[str, Channel] = {}
    notes: list[str] = []
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        with of_key(f"channels.{name}"):
            read, note = _read_curves(header, curves, name, ch)
            notes += [note] if note else []
            in_si = []
            for curve, file, time, values in read:
                vehicle = curve.vehicle or vehicle
                unit = ch.unit or UNITS.get(curve.unit.upper(), curve.unit)
                in_si.append((file, time, values * si_factor(unit, name, where(file, name, f"curve {curve.number}"))))
            channels[name] = combine(in_si, name)
    for row in cards.get("VEHICLE", []):
        if row and row[0] == str(vehicle) and (mass := card_number(row, 11)) and mass > 0:
            meta["mass"] = mass
    return TestData(channels, meta, notes)


def combine(read: list[tuple[Path, np.ndarray, np.ndarray]], name: str) -> Channel:
    """Sum (a force, `SUMMED`) or mean of curves on one time base; refuse curves whose sampling
    or range differ."""
    file0, time, total = read[0]
    dt0 = (time[-1] - time[0]) / (time.size - 1)
    for file, t, v in read[1:]:
        dt = (t[-1] - t[0]) / (t.size - 1)
        if abs(dt - dt0) > 1e-3 * dt0:
            raise DataError(f"{where(file, name)}: sample interval {dt:g} s differs from {file0.name}'s {dt0:g} s")
        if t.size != time.size or np.max(np.abs(t - time)) > 0.01 * dt0:
            raise DataError(
                f"{where(file, name)}: time range {t[0]:g} s to {t[-1]:g} s differs from "
                f"{file0.name}'s {time[0]:g} s to {time[-1]:g} s"
            )
        total = total + v
    if name == "accel":
        for file, t, v in read:
            check_clipped(t, v, where(file, name))
        _check_apart(read)
    source = "+".join(f.name for f, _, _ in read)
    return Channel(time, total if name in SUMMED else total / len(read), CHANNEL_UNITS[name], source)


def _check_apart(read: list[tuple[Path, np.ndarray, np.ndarray]]) -> None:
    """Refuse accelerometer curves to be averaged whose velocity changes from impact on (t >= 0)
    part by more than CURVES_APART times, or go opposite ways: read in different units or signs,
    or one of them dead, their mean is neither's. Names the curve furthest from the one that
    changes the velocity most."""
    changes = [float(np.trapezoid(v[t >= 0], t[t >= 0])) for _, t, v in read]
    ref = max(range(len(changes)), key=lambda j: abs(changes[j]))
    if changes[ref] == 0.0:
        return  # every curve flat: the channel is dead, which the fit's checks say
    ratios = [change / changes[ref] for change in changes]
    k = max(range(len(ratios)), key=lambda j: abs(np.log(abs(ratios[j]))) if ratios[j] else np.inf)
    if 1 / CURVES_APART <= ratios[k] <= CURVES_APART:
        return
    if abs(ratios[k]) < DEAD_SHARE:
        apart, why = "next to nothing", "the curve is dead (it reads no pulse); leave it out of the curves"
    elif ratios[k] < 0.0:
        apart, why = "the other way", "the curves are read with different signs"
    else:
        apart = f"{ratios[k]:.3g} times as much"
        why = "the curves are read in different units (one in m/s^2 under a G'S header takes a ninth of the change)"
    raise DataError(
        f"{where(read[k][0], 'accel')}: the curve changes the velocity by {changes[k]:.3g} m/s from impact on, "
        f"{read[ref][0].name} by {changes[ref]:.3g} m/s ({apart}): {why}, and their mean is neither's"
    )
