"""NHTSA EV5 ASCII X-Y reader: the pipe-delimited .EV5 header and one two-column file per curve.

Header cards used (fields counted from 1, as in the NHTSA Test Reference Guide):
- TEST: 15 closing speed CLSSPD [km/h], 19 total number of curves TOTCRV.
- VEHICLE: 1 vehicle number, 11 test mass VEHTWT [kg], 13 wheelbase [mm], 14 length [mm],
  16 CG behind the front axle VEHCG [mm].
- INSTRUMENTATION: 1 vehicle number, 2 curve number, 3 sensor type, 5 sensor location, 6 axis, 7 x units,
  8 y units, 15 first point NFP, 16 last point NLP, 17 sample interval DELT [us],
  18 data status DASTAT, 19 channel status (P primary, R redundant), 20 comment.
Curve NNN lives next to the header as <stem>.NNN (time [s] TAB value).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.data.channels import Channel, DataError, TestData, check_samples, si_factor, where
from crashnlp.problem.schema import CHANNEL_UNITS, DataSpec

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


def _read_curve(path: Path, header: Path, curve: Curve, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """Time and raw values of one curve, cut to the valid range NFP..NLP the header gives."""
    at = where(path, channel, f"curve {curve.number}")
    if not path.is_file():
        raise DataError(f"{at}: curve file missing (listed in {header.name})")
    if curve.status in NO_DATA:
        raise DataError(f"{at}: header marks the curve as holding no data ({curve.comment or curve.status})")
    try:
        table = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise DataError(f"{at}: cannot read ({str(exc).splitlines()[0]})") from None
    if table.shape[1] < 2:
        raise DataError(f"{at}: expected two columns, time and value")
    time, values = table[:, 0], table[:, 1]
    check_samples(time, values, at)
    if curve.interval > 0:
        dt = float(np.median(np.diff(time)))
        if abs(dt - curve.interval) > 0.01 * curve.interval:
            raise DataError(f"{at}: sample interval {dt:g} s differs from the header's {curve.interval:g} s")
        tol = 0.5 * curve.interval
        valid = (time >= curve.first * curve.interval - tol) & (time <= curve.last * curve.interval + tol)
        time, values = time[valid], values[valid]
        if time.size < 2:
            raise DataError(f"{at}: no samples in the valid range the header gives")
    return time, values


def read_ev5(spec: DataSpec) -> TestData:
    """Channels from the curves `ChannelSpec.curves` (averaged when several), values in SI.

    Units come from the header (G'S is g) unless `ChannelSpec.unit` overrides. A curve whose
    header marks a shorter valid range (NLP, e.g. a channel failed mid-test) is cut to it;
    averaged curves must share sample interval and time range. Meta: 'speed' [m/s] from the
    TEST card, 'mass' [kg] from the VEHICLE card of the vehicle carrying the curves.
    """
    header = spec.file
    cards, curves = read_header(header)
    meta: dict[str, float] = {}
    speed = card_number(cards["TEST"][0], 15)
    if speed is not None and speed > 0:
        meta["speed"] = speed / 3.6
    vehicle = 1
    channels = {}
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        if not ch.curves:
            raise DataError(f"{where(header, name)}: no curves given (an EV5 channel needs `curves`)")
        read = []
        for number in ch.curves:
            if number not in curves:
                raise DataError(f"{where(header, name, f'curve {number}')}: curve not in the INSTRUMENTATION card")
            curve = curves[number]
            vehicle = curve.vehicle
            file = header.with_suffix(f".{number:03d}")
            time, values = _read_curve(file, header, curve, name)
            unit = ch.unit or UNITS.get(curve.unit.upper(), curve.unit)
            values = values * si_factor(unit, name, where(file, name, f"curve {number}"))
            read.append((file, time, values))
        channels[name] = _average(read, name)
    for row in cards.get("VEHICLE", []):
        if row and row[0] == str(vehicle) and (mass := card_number(row, 11)) and mass > 0:
            meta["mass"] = mass
    return TestData(channels, meta)


def _average(read: list[tuple[Path, np.ndarray, np.ndarray]], name: str) -> Channel:
    """Mean of curves on one time base; refuse curves whose sampling or range differ."""
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
    source = "+".join(f.name for f, _, _ in read)
    return Channel(time, total / len(read), CHANNEL_UNITS[name], source)
