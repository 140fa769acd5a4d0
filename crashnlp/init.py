"""`crashnlp init`: a complete, commented problem file from one test's data.

What the data's header gives (EV5: VEHTWT, closing speed, wheelbase, VEHCG; ISO-MME: mass and
speed of test object 1; CSV and NHTSA channel files: nothing) is used and said so; options
(--mass, --speed) win over the header, and are refused where the data contradict them as a fit
would refuse them (crashnlp.case.testcase). An existing file is written over only with --force,
a data file never.
Geometry no source gives takes typical values for the mass class (VEHICLE_CLASSES), each
marked as an estimate:

- impact point: the front bumper, a front overhang ahead of the front axle;
- CG behind the front axle: CG_SHARE (0.44) of the wheelbase (EV5 VEHCG when given);
- CG above the impact point: bumper beam about 0.45 m above ground, CG height by class;
- pitch inertia: m (0.44 wheelbase)^2 (radius of gyration 1.24 m for a 2.8 m wheelbase);
- suspension: each axle's static load at a ride frequency of 1.2 Hz, damping ratio 0.25.

The breakpoints, spring values, damper, unloading stiffness and estimate are then filled in
from the data (crashnlp.case.completion) and written out, so the file identifies as it stands and
every entry can be edited.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from crashnlp.analysis.metrics import STOPPED, zero_crossing
from crashnlp.base.choices import DATA_FORMATS
from crashnlp.base.errors import InputError
from crashnlp.base.records import ValidationError
from crashnlp.base.units import unit_scale
from crashnlp.case.testcase import PITCH_SWING, nose_up
from crashnlp.data.channels import Channel
from crashnlp.data.csv_reader import Table
from crashnlp.data.load import READERS, load_test_data
from crashnlp.data.nhtsa_channel import channel_files
from crashnlp.data.signal import BIAS_LEAST, BIAS_SPAN
from crashnlp.models.pendulum import PITCH_LEVER
from crashnlp.problem import Problem, problem_from_dict
from crashnlp.problem.errors import all_errors
from crashnlp.problem.schema import CHANNEL_FILE, CHANNEL_UNITS, DEFAULT_FILTER, DataSpec, format_of, located
from crashnlp.results.files import atomic_open, check_writable_file

if TYPE_CHECKING:
    from crashnlp.case.case import Case

ACCEL_FILTER = DEFAULT_FILTER["accel"]  # a drafted accelerometer's filter, written out: the default, SAE J211's class
UNFRAMED = ("csv", "nhtsa-channel")  # formats whose files say nothing of their sign convention: read from the data
# upper test mass (kg), class, wheelbase (m), front overhang (m), CG above the impact point (m)
VEHICLE_CLASSES = (
    (1200.0, "city car", 2.45, 0.70, 0.08),
    (1550.0, "compact car", 2.65, 0.85, 0.10),
    (1900.0, "mid-size car", 2.80, 0.95, 0.10),
    (2400.0, "SUV", 2.90, 0.95, 0.15),
    (math.inf, "pickup or van", 3.40, 1.00, 0.20),
)
CG_SHARE = 0.44  # CG behind the front axle, fraction of the wheelbase
GYRATION_SHARE = 0.44  # pitch radius of gyration, fraction of the wheelbase
RIDE_FREQUENCY, DAMPING_RATIO = 1.2, 0.25  # Hz, -
OVERHANG_SHARE = 0.47  # front overhang, fraction of length minus wheelbase (EV5 gives both)
WINDOW_FACTOR, WINDOW_MIN = 2.0, 0.1  # fit window: twice the stop time, at least 0.1 s...
PITCH_MARGIN = 0.01  # s: ...and this past a measured pitch's peak (a body pitches for a few hundred ms)


@dataclass
class Draft:
    """What init has found out; every value (SI) with the comment that says where it came from."""

    name: str
    data: dict
    vehicle: dict[str, tuple[float, str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    comments: dict[str, str] = field(default_factory=dict)  # per channel
    optional: dict[str, dict] = field(default_factory=dict)  # channels written commented out, for the user to add


@dataclass
class Options:
    """The command line's choices."""

    format: str | None = None
    mass: float | None = None
    speed: float | None = None
    columns: dict[str, str] = field(default_factory=dict)  # channel -> NAME[:UNIT]
    name: str | None = None
    force: bool = False  # write over an existing --out (never over a data file)


# ------------------------------------------------------------------ EV5
ACCEL_PLACES = (("REAR SEAT", "rear seat crossmember"), ("CG", "vehicle CG"), ("FLOOR", "floor"), ("SILL", "sill"))


def _ev5_accelerometers(curves: dict) -> tuple[list[int], str]:
    """Primary longitudinal accelerometers of vehicle 1 at the rear seat (else CG, floor, sill), not the engine's."""
    from crashnlp.data.nhtsa_ev5 import NO_DATA

    usable = [
        c
        for c in curves.values()
        if c.vehicle == 1
        and c.sensor == "AC"
        and c.axis.startswith("X")
        and c.primary
        and c.status not in NO_DATA
        and "ENGINE" not in c.comment.upper()
    ]
    for key, place in ACCEL_PLACES:
        chosen = [c for c in usable if key in c.comment.upper() or key in c.location.upper()]
        if chosen:
            names = "; ".join(f"{c.number:03d} {c.comment}" for c in chosen)
            return [c.number for c in chosen], f"mean of the primary {place} X accelerometers ({names})"
    raise InputError("no longitudinal vehicle accelerometer (rear seat, CG, floor or sill) in the INSTRUMENTATION card")


def _ev5_barrier(path: Path, curves: dict, draft: Draft) -> None:
    """The wall force of a load-cell barrier, offered commented out: a one-mass model does not
    meet it and the accelerometers at once unless the user weighs them (docs/barrier.md). The
    cells are read, as the fit would read them, to count the dead ones the header does not mark."""
    from crashnlp.data.channels import DataError
    from crashnlp.data.nhtsa_ev5 import live_barrier_cells

    try:
        live, marked, flat = live_barrier_cells(path, curves, "barrier_force")
    except DataError:
        return
    draft.optional["barrier_force"] = {"curves": "all-valid-barrier-fx", "sign": -1}
    dead = [f"{n} {why}" for n, why in ((len(marked), "marked not valid"), (len(flat), "flat after impact")) if n]
    left_out = f", {' and '.join(dead)} left out" if dead else ""
    draft.comments["barrier_force"] = (
        f"wall force: sum of the {len(live)} valid load cells{left_out}, CFC 60; to fit it too, see docs/barrier.md"
    )


def _accel_draft(name: str, accel: dict, why: str) -> Draft:
    """A draft whose data are one accelerometer channel (`accel`: which curves of the file, `why`
    its comment) read through ACCEL_FILTER, with the velocity and displacement integrated from it."""
    channels = {
        "accel": {**accel, "filter": ACCEL_FILTER},
        **{ch: {"derive": "integrate"} for ch in ("velocity", "displacement")},
    }
    draft = Draft(name, {"channels": channels})
    draft.comments = {"accel": why, "velocity": "integrated from the impact speed", "displacement": "integrated twice"}
    return draft


def ev5_draft(path: Path) -> Draft:
    """Mass, speed, wheelbase, CG and overhang from the TEST and VEHICLE cards; the accelerometers."""
    from crashnlp.data.nhtsa_ev5 import card_number, read_header

    cards, curves = read_header(path)
    numbers, why = _ev5_accelerometers(curves)
    draft = _accel_draft(path.stem, {"curves": numbers}, why)
    _ev5_barrier(path, curves, draft)
    speed = card_number(cards["TEST"][0], 15)
    if speed:
        draft.vehicle["speed"] = (speed / 3.6, "TEST card closing speed")
    row = next((r for r in cards.get("VEHICLE", []) if r and r[0] == "1"), [])
    mass, wheelbase, length, cg = (card_number(row, i) for i in (11, 13, 14, 16))
    if mass:
        draft.vehicle["mass"] = (mass, "VEHICLE card VEHTWT (test mass)")
    if wheelbase and cg:
        draft.vehicle["cg_to_front_axle"] = (cg / 1e3, "VEHCG, CG behind the front axle")
        draft.vehicle["cg_to_rear_axle"] = ((wheelbase - cg) / 1e3, f"wheelbase {wheelbase:g} mm - VEHCG")
        if length:
            overhang = OVERHANG_SHARE * (length - wheelbase) / 1e3
            draft.vehicle["cg_to_impact"] = (
                cg / 1e3 + overhang,
                f"estimate: VEHCG + front overhang {overhang:.3f} m ({OVERHANG_SHARE} of length {length:g} mm - wheelbase)",
            )
    return draft


# ------------------------------------------------------------------ ISO-MME
def _least_filtered(codes: list[str]) -> str:
    """Of several codes of the accelerometer to read, the unfiltered one (filter class 0), which the
    draft filters at ACCEL_FILTER; else one the lab filtered at ACCEL_FILTER already, which the
    reader does not filter again; else the first listed."""
    from crashnlp.data.iso_mme import LAB_FILTERS, UNFILTERED, filter_class

    def rank(code: str) -> int:
        letter = filter_class(code)
        return 0 if letter == UNFILTERED else 1 if LAB_FILTERS.get(letter) == ACCEL_FILTER else 2

    return min(codes, key=rank)


def _mme_accel_why(code: str, at_cg: bool) -> str:
    """The comment of the accelerometer read: where it is, and what the lab's filter left to do."""
    from crashnlp.data.iso_mme import filter_said

    said = filter_said(code, ACCEL_FILTER) or "unfiltered (ISO filter class 0)"
    return f"vehicle X accelerometer {'at the CG' if at_cg else 'of test object 1'}, {said}"


def mme_draft(path: Path) -> Draft:
    """Mass and speed of test object 1; its vehicle X accelerometer, at the CG if there is one, the
    unfiltered code where the test holds it and a filtered one (`_least_filtered`)."""
    from crashnlp.data.iso_mme import META_KEYS, read_header

    meta, codes = read_header(path)
    accels = [c for c in codes if len(c) == 16 and c[0] == "1" and c[2:6] == "VEHC" and c[12:15] == "ACX"]
    if not accels:
        raise InputError(f"{path}: no vehicle X accelerometer of test object 1 (code 1?VEHC??????ACX?)")
    at_cg = [c for c in accels if "CG" in c[6:12]]
    code = _least_filtered(at_cg or accels)
    draft = _accel_draft(path.stem, {"code": code}, _mme_accel_why(code, bool(at_cg)))
    for entry in ("mass", "speed"):
        if entry in meta:
            draft.vehicle[entry] = (meta[entry], f".mme header '{META_KEYS[entry][0].format(1)}'")
    return draft


# ------------------------------------------------------------------ CSV
CSV_PATTERNS = {
    "time": r"^(time|t)($|[^a-z])",
    "accel": r"acc|decel",
    "velocity": r"(?<!tra)vel|speed",  # not "travel"
    "displacement": r"disp|travel",
    "pitch": r"pitch",
}
UNIT_WORDS = {
    "mps2": "m/s^2",
    "ms2": "m/s^2",
    "m/s2": "m/s^2",
    "m/s^2": "m/s^2",
    "m/s²": "m/s^2",
    "g": "g",
    "gs": "g",
    "g's": "g",
    "ft/s2": "ft/s^2",
    "ft/s^2": "ft/s^2",
    "ft/s²": "ft/s^2",
    "fps2": "ft/s^2",
    "mps": "m/s",
    "m/s": "m/s",
    "kph": "km/h",
    "kmh": "km/h",
    "km/h": "km/h",
    "km/hr": "km/h",
    "mph": "mph",
    "ft/s": "ft/s",
    "fps": "ft/s",
    "m": "m",
    "mm": "mm",
    "cm": "cm",
    "in": "in",
    "inch": "in",
    "inches": "in",
    "ft": "ft",
    "s": "s",
    "ms": "ms",
    "sec": "s",
    "msec": "ms",
    "deg": "deg",
    "rad": "rad",
}
# what a column holds when only its unit says so, by SI unit (an angle may be any rotation: pitch is found by its name)
UNIT_CHANNELS = {"time": "s", **{ch: CHANNEL_UNITS[ch] for ch in ("accel", "velocity", "displacement")}}
CHANNEL_SIGNS = {
    "accel": "the pulse decelerates",
    "velocity": "the impact speed is positive",
    "displacement": "the travel toward the barrier is positive",
    "pitch": "the nose-down pitch is positive",
}


def unit_in_name(name: str) -> str | None:
    """The unit a column name carries: "[g]", "(km/h)" or a last "_g" / "_mps" part."""
    bracket = re.search(r"[\[(]([^\])]+)[\])]", name)
    token = bracket.group(1) if bracket else name.rsplit("_", 1)[-1] if "_" in name else ""
    return UNIT_WORDS.get(token.strip().lower())


def _measures(unit: str) -> str | None:
    """The channel (or time) a unit alone says a column holds (UNIT_CHANNELS); None for any other quantity."""
    return next((ch for ch, si in UNIT_CHANNELS.items() if _converts(unit, si)), None)


def _converts(unit: str, si: str) -> bool:
    try:
        unit_scale(unit, si)
    except Exception:  # pint and UnitError both land here
        return False
    return True


def _recognised(name: str) -> str | None:
    """The channel (or time) a column's name says it holds: by its words, else by its unit."""
    by_name = next((ch for ch, pattern in CSV_PATTERNS.items() if re.search(pattern, name.lower())), None)
    unit = unit_in_name(name)
    return by_name or (_measures(unit) if unit else None)


def _given(table: Table, channel: str, given: str) -> tuple[str | int, str | None]:
    """(column, unit) of the option NAME[:UNIT], NAME a column's name or its number counted from 1."""
    name, _, unit = given.partition(":")
    k = table.index(name, channel)
    column = table.header[k] if table.header is not None else k + 1
    return column, unit or (unit_in_name(str(column)) if table.header is not None else None)


def _csv_columns(table: Table, columns: dict[str, str]) -> tuple[dict[str, tuple[str | int, str]], list[str]]:
    """(column, unit) of time and each channel found, and the header's columns none reads.

    Given columns first; then, per channel, the first column whose name fits it. Every column
    that fits a channel but has no unit in its name is named in one message."""
    chosen = {ch: _given(table, ch, given) for ch, given in columns.items()}
    unread = []
    taken = {str(column) for column, _ in chosen.values()}
    for name in [h for h in table.header or [] if h and h not in taken]:  # a blank name: a trailing delimiter
        channel = _recognised(name)
        if channel is not None and channel not in chosen:
            chosen[channel] = (name, unit_in_name(name))
        else:
            unread.append(name)
    no_unit = [f"{column!r} ({ch})" for ch, (column, unit) in chosen.items() if not unit]
    if no_unit:
        options = " ".join(f"--column {ch}={column}:UNIT" for ch, (column, unit) in chosen.items() if not unit)
        raise InputError(f"{table.path}: no unit in the column names {', '.join(no_unit)}; give {options}")
    return {ch: (column, str(unit)) for ch, (column, unit) in chosen.items()}, unread


def csv_draft(path: Path, columns: dict[str, str]) -> Draft:
    """Columns recognised by name or unit (or given), units from the names (or given), signs from
    the data; a file without a header line needs its columns given by number."""
    table = Table.read(path)
    if table.header is None and "time" not in columns:
        raise InputError(f"{path}: no header line; give the columns by number, e.g. --column time=1:s --column accel=2:g")
    found, unread = _csv_columns(table, columns)
    listed = f" among {', '.join(map(repr, unread))}" if unread else ""
    if "time" not in found:
        raise InputError(f"{path}: no time column{listed} (give --column time=NAME:UNIT)")
    if "accel" not in found and "velocity" not in found:
        raise InputError(f"{path}: no accel or velocity column{listed} (give --column accel=NAME:UNIT)")
    time = found.pop("time")
    channels: dict[str, dict] = {ch: {"column": name, "unit": unit} for ch, (name, unit) in found.items()}
    if "accel" in channels:
        channels["accel"]["filter"] = ACCEL_FILTER
    draft = Draft(path.stem, {"time": {"column": time[0], "unit": time[1]}, "channels": channels})
    draft.comments = {ch: f"column {name!r} in {unit}" for ch, (name, unit) in found.items()}
    if unread:
        draft.notes.append(f"Columns not read: {', '.join(map(repr, unread))} (--column CHANNEL=NAME:UNIT reads one).")
    _integrated(draft, "the accel column")
    return draft


def _integrated(draft: Draft, accel: str) -> None:
    """Velocity and displacement integrated from the accelerometers where the data give neither."""
    channels = draft.data["channels"]
    for ch in ("velocity", "displacement"):
        if ch not in channels and "accel" in channels:
            channels[ch] = {"derive": "integrate"}
            draft.comments[ch] = f"integrated from {accel}"


# ------------------------------------------------------------------ NHTSA channel files
def _curve_numbers(given: str, option: str) -> list[int]:
    """Channel files named by number (93) or by name (v10146tsv.093), comma-separated."""
    numbers = []
    for item in given.split(","):
        named = CHANNEL_FILE.fullmatch(Path(item.strip()).name)
        if not (item.strip().isdigit() or named):
            raise InputError(f"{option}: name channel files by their number CCC or their name vNNNNNtsv.CCC, not {item!r}")
        numbers.append(int(named.group(2)) if named else int(item))
    return numbers


def channel_draft(paths: list[Path], columns: dict[str, str]) -> Draft:
    """Channel files of one test: the channels --column names (CCC[,CCC][:UNIT]), else the files
    given, taken as the vehicle's longitudinal accelerometers in g (the database's unit for them)."""
    test, files = channel_files(paths[0])
    named = [CHANNEL_FILE.fullmatch(p.name) for p in paths]
    if len(paths) > 1 and any(m is None or m.group(1) != test or p.parent != paths[0].parent for p, m in zip(paths, named)):
        raise InputError(
            f"{', '.join(map(str, paths))}: give one folder, or channel files vNNNNNtsv.CCC of one test in one folder"
        )
    if not columns and paths[0].is_dir():
        listed = ", ".join(f"{n:03d}" for n in files)
        raise InputError(f"{paths[0]}: name its channels, e.g. --column accel=CCC,CCC:g (channel files {listed})")
    chosen = {ch: given.partition(":") for ch, given in columns.items()}
    if not chosen:
        chosen = {"accel": (",".join(p.name for p in paths), ":", "g")}
    channels, comments = {}, {}
    for ch, (names, _, unit) in chosen.items():
        option = f"--column {ch}={names}"
        numbers = _curve_numbers(names, option)
        if not unit:
            raise InputError(f"{option}: an NHTSA channel file carries no unit; give {option}:UNIT")
        missing = [f"{n:03d}" for n in numbers if n not in files]
        if missing:
            raise InputError(f"{option}: no channel file {', '.join(missing)} of the test beside {paths[0]}")
        channels[ch] = {"curves": numbers, "unit": unit, **({"filter": ACCEL_FILTER} if ch == "accel" else {})}
        comments[ch] = f"channel files {', '.join(files[n].name for n in numbers)} in {unit}" + (
            ", averaged" if len(numbers) > 1 else ""
        )
    if not columns:
        comments["accel"] += ", taken as the vehicle's X accelerometers (--column accel=CCC:UNIT says otherwise)"
    draft = Draft(f"v{test}", {"channels": channels})
    draft.comments = comments
    _integrated(draft, "the accelerometers")
    return draft


def _direction(name: str, values: np.ndarray) -> float:
    """> 0 when a channel reads in the model frame: decelerating, impact speed positive, travel
    positive, a pitch that does not swing nose-up past its nose-down swing and PITCH_SWING
    (crashnlp.case.testcase.nose_up: a frontal crash pitches the nose down)."""
    if name == "accel":
        return -float(np.sum(values))
    if name == "velocity":
        return float(values[0])
    if name == "pitch":
        return -1.0 if nose_up(values) else 1.0
    return float(values[np.argmax(np.abs(values))])


def _signs(draft: Draft, path: Path) -> None:
    """Flip channels read in the opposite frame (x toward the barrier), for files that declare none."""
    data = load_test_data(_data_spec(draft, path), 1.0)
    for name, ch in data.channels.items():
        if name in CHANNEL_SIGNS and "derive" not in draft.data["channels"][name]:
            if _direction(name, ch.values[ch.time >= 0.0]) < 0:
                draft.data["channels"][name]["sign"] = -1
                draft.comments[name] += f", sign flipped so that {CHANNEL_SIGNS[name]}"
            elif name == "pitch":
                draft.comments[name] += ", taken as nose-down positive (its largest swing is)"


# ------------------------------------------------------------------ the rest, common to all formats
def _data_spec(draft: Draft, path: Path) -> DataSpec:
    try:
        return DataSpec.model_validate({"file": str(path), **draft.data})
    except ValidationError as exc:
        raise InputError(f"{path}: {all_errors(exc)}") from None


def _bias_window(draft: Draft, path: Path) -> None:
    """A bias window over the last BIAS_SPAN before impact where every channel read holds at least
    BIAS_LEAST of pre-impact record (the least a window may hold, and the least over which the
    data refuse an offset no window removes) and an accel channel is read: set before the data are
    loaded, which refuse such an offset."""
    spec = _data_spec(draft, path)
    raw = READERS[spec.format](spec).channels
    read = [raw[name] for name, ch in spec.channels.items() if ch.derive is None]
    start = max(c.time[0] for c in read)
    if start <= -BIAS_LEAST and "accel" in raw:
        draft.data["bias_window"] = [max(float(start), -BIAS_SPAN), 0.0]


def _timing(draft: Draft, path: Path, speed: float) -> None:
    """A fit window of twice the stop time, or to PITCH_MARGIN past a measured pitch's peak where
    that is later (so the max pitch is the crash's, not the window's), within the record."""
    data = load_test_data(_data_spec(draft, path), speed)
    end = min(c.time[-1] for c in data.channels.values())
    v = data.channels["velocity"]
    after = v.time >= 0.0
    stop = zero_crossing(v.time[after], v.values[after], STOPPED * speed)
    if math.isnan(stop):
        draft.data["window"] = [0.0, float(end)]
        draft.notes.append("Fit window: the whole record after impact (the vehicle does not stop in it).")
        return
    fit = max(WINDOW_MIN, math.ceil(WINDOW_FACTOR * stop / 0.01) * 0.01)
    peak, pitch = _pitch_peak(data.channels.get("pitch")), ""
    if peak is not None and peak + PITCH_MARGIN > fit:
        fit = math.ceil(round((peak + PITCH_MARGIN) / 0.01, 6)) * 0.01
        pitch = f", and past the pitch's peak at {peak * 1e3:.0f} ms"
    draft.data["window"] = [0.0, round(min(end, fit), 4)]
    draft.notes.append(
        f"Fit window: from impact to {draft.data['window'][1] * 1e3:.0f} ms (about twice the stop time, "
        f"{stop * 1e3:.1f} ms{pitch})."
    )


def _pitch_peak(pitch: Channel | None) -> float | None:
    """When a measured pitch is largest after impact (s); None without one, or where it never
    swings past PITCH_SWING (a vehicle that barely pitches: noise or drift would set the window)."""
    if pitch is None:
        return None
    after = pitch.time >= 0.0
    if not after.any() or np.max(pitch.values[after]) < PITCH_SWING:
        return None
    return float(pitch.time[after][np.argmax(pitch.values[after])])


def vehicle_class(mass: float) -> tuple[float, str, float, float, float]:
    """The VEHICLE_CLASSES row of a test mass."""
    return next(c for c in VEHICLE_CLASSES if mass <= c[0])


def fill_geometry(draft: Draft) -> dict[str, tuple[float, str]]:
    """Typical geometry for the mass class where no source gives it; returns the suspension."""
    v, mass = draft.vehicle, draft.vehicle["mass"][0]
    _, kind, wheelbase, overhang, above = vehicle_class(mass)
    est = f"estimate for a {mass:.0f} kg {kind}"
    if "cg_to_front_axle" not in v:
        v["cg_to_front_axle"] = (CG_SHARE * wheelbase, f"{est}: {CG_SHARE} of a {wheelbase} m wheelbase")
        v["cg_to_rear_axle"] = ((1 - CG_SHARE) * wheelbase, f"{est}: the rest of the wheelbase")
    front, rear = v["cg_to_front_axle"][0], v["cg_to_rear_axle"][0]
    wheelbase = front + rear
    v.setdefault("cg_to_impact", (front + overhang, f"{est}: CG to front axle + a front overhang of {overhang} m"))
    v.setdefault("cg_above_impact", (above, f"{est}: CG height above a bumper beam about 0.45 m high"))
    gyration = GYRATION_SHARE * wheelbase
    v.setdefault(
        "pitch_inertia", (mass * gyration**2, f"{est}: radius of gyration {gyration:.2f} m ({GYRATION_SHARE} x wheelbase)")
    )
    omega = 2 * math.pi * RIDE_FREQUENCY
    loads = {"front": mass * rear / wheelbase, "rear": mass * front / wheelbase}
    out = {}
    for axle, load in loads.items():
        k = load * omega**2
        out[f"k_{axle}"] = (k, "")
        out[f"c_{axle}"] = (2 * DAMPING_RATIO * math.sqrt(k * load), "")
    return out


def _resolve(draft: Draft, options: Options, path: Path) -> None:
    """Mass and speed from the options, else the header, else (speed) the velocity channel."""
    for key, value in (("mass", options.mass), ("speed", options.speed)):
        if value is not None:
            draft.vehicle[key] = (value, "given (--" + key + ")")
    velocity = draft.data["channels"].get("velocity")
    if "speed" not in draft.vehicle and velocity is not None and "derive" not in velocity:
        v = load_test_data(_data_spec(draft, path), 1.0).channels["velocity"]  # any speed: the channel is measured
        draft.vehicle["speed"] = (float(np.interp(0.0, v.time, v.values)), "the velocity data at t = 0")
    for key in ("mass", "speed"):
        if key not in draft.vehicle:
            raise InputError(f"{path}: no {key} in the data; give --{key}")


def _draft(fmt: str, paths: list[Path], columns: dict[str, str]) -> Draft:
    """The format's draft: several data paths are channel files of one test, other formats read one."""
    if fmt == "nhtsa-channel":
        return channel_draft(paths, columns)
    if len(paths) > 1:
        raise InputError(f"{', '.join(map(str, paths))}: {fmt} reads one data set (several paths are NHTSA channel files)")
    return csv_draft(paths[0], columns) if fmt == "csv" else {"nhtsa-ev5": ev5_draft, "iso-mme": mme_draft}[fmt](paths[0])


def _check_columns(fmt: str, columns: dict[str, str]) -> None:
    """--column names channels of the formats whose files do not say what they hold."""
    known = {"csv": ("time", *CHANNEL_UNITS), "nhtsa-channel": tuple(CHANNEL_UNITS)}.get(fmt, ())
    for channel, given in columns.items():
        if channel not in known:
            what = f"{fmt} channels are {', '.join(known)}" if known else f"{fmt} data say what their channels hold"
            raise InputError(f"--column {channel}={given}: {what}")


def draft_for(paths: list[Path], options: Options) -> tuple[Draft, dict]:
    """The draft of a data set (format, channels, vehicle values and comments) and its suspension;
    `paths[0]` is the file the problem names."""
    path = paths[0]
    fmt = options.format or format_of(path)
    if fmt not in DATA_FORMATS:
        raise InputError(f"--format {fmt}: one of {', '.join(DATA_FORMATS)}")
    _check_columns(fmt, options.columns)
    draft = _draft(fmt, paths, options.columns)
    draft.data = {"format": fmt, **draft.data}
    if options.name:
        draft.name = options.name
    _bias_window(draft, path)
    if fmt in UNFRAMED:
        _signs(draft, path)
    _resolve(draft, options, path)
    _timing(draft, path, draft.vehicle["speed"][0])
    suspension = fill_geometry(draft)
    return draft, suspension


# ------------------------------------------------------------------ the problem file
VEHICLE_UNITS = {
    "mass": ("kg", 1.0, ".0f"),
    "speed": ("km/h", 3.6, ".2f"),
    "pitch_inertia": ("kg*m^2", 1.0, ".0f"),
    "cg_to_impact": ("m", 1.0, ".3f"),
    "cg_above_impact": ("m", 1.0, ".3f"),
    "cg_to_front_axle": ("m", 1.0, ".3f"),
    "cg_to_rear_axle": ("m", 1.0, ".3f"),
}
ESTIMATE_UNITS = {
    "model.spring.values": ("kN", 1e-3, ".0f"),
    "model.unloading.stiffness": ("MN/m", 1e-6, ".0f"),
    "vehicle.cg_above_impact": ("m", 1.0, ".2f"),
    "vehicle.pitch_inertia": ("kg*m^2", 1.0, ".0f"),
    "vehicle.crush_offset": ("m", 1.0, ".2f"),
    "vehicle.vertical_force_ratio": ("", 1.0, ".2f"),
}
STEP = 1e-3  # s per transcription interval


def _q(value: float, unit: str, scale: float, fmt: str) -> str:
    return f"{value * scale:{fmt}} {unit}".strip()


def _line(indent: int, text: str, comment: str = "") -> str:
    body = " " * indent + text
    return f"{body:<43} # {comment}" if comment else body


def _flow(values: dict | list) -> str:
    return yaml.safe_dump(values, default_flow_style=True, sort_keys=False, width=1000).strip()


def problem_dict(draft: Draft, suspension: dict, path: Path) -> dict:
    """The problem as init writes it before the data fill in the front end (SI numbers)."""
    window = draft.data["window"][1]
    return {
        "name": draft.name,
        "vehicle": {**{k: v for k, (v, _) in draft.vehicle.items()}, "suspension": {k: v for k, (v, _) in suspension.items()}},
        "model": {"spring": {"law": "force"}, "unloading": {"law": "plastic"}},
        "tests": [{"name": draft.name, "data": {"file": str(located(path)), **draft.data}}],
        "constraints": {"monotone_crush": True},
        "transcription": {"method": "multiple-shooting", "intervals": max(50, round(window / STEP)), "substeps": 1},
    }


def render(draft: Draft, problem: Problem, data_file: str) -> str:
    """The commented YAML text of a completed problem."""
    v, m = problem.vehicle, problem.model
    lines = [
        f"# Written by `crashnlp init` from {data_file} ({draft.data['format']}).",
        *(f"# {n}" for n in draft.notes),
        "# Front end: breakpoints over the data's crush range, values from the measured force-crush curve",
        "# (m |a| while loading), unloading stiffness from the rebound, nominal damper (crashnlp/case/completion.py).",
        f"name: {json.dumps(draft.name)}",
        "vehicle:",
    ]
    for key, (unit, scale, fmt) in VEHICLE_UNITS.items():
        lines.append(_line(2, f"{key}: {_q(getattr(v, key), unit, scale, fmt)}", draft.vehicle[key][1]))
    s = v.suspension
    susp = {f"k_{a}": _q(getattr(s, f"k_{a}"), "kN/m", 1e-3, ".1f") for a in ("front", "rear")}
    susp.update({f"c_{a}": _q(getattr(s, f"c_{a}"), "kN*s/m", 1e-3, ".2f") for a in ("front", "rear")})
    lines.append(
        _line(
            2,
            f"suspension: {_flow(susp)}",
            f"estimate: axle loads at {RIDE_FREQUENCY} Hz ride frequency, damping ratio {DAMPING_RATIO}",
        )
    )
    bps = [round(b, 4) for b in m.spring.placed_breakpoints]
    assert m.damper is not None  # spring values from the data come with a nominal damper (crashnlp.case.completion.complete)
    lines += [
        "model:",
        "  spring:",
        "    law: force",
        _line(4, f"crush_breakpoints: {_flow(bps)}", f"m; to {bps[-1] * 1e3:.0f} mm, the largest crush; at its bends"),
        _line(4, f"values: [{', '.join(_q(x, 'kN', 1e-3, '.0f') for x in m.spring.known_values)}]", "measured force-crush curve"),
        _line(
            2,
            "damper: "
            + _flow(
                {
                    "rate_breakpoints": [round(b, 2) for b in m.damper.rate_breakpoints],
                    "values": [_q(c, "kN*s/m", 1e-3, ".2f") for c in m.damper.values],
                }
            ),
            "nominal",
        ),
        _line(
            2,
            f"unloading: {{law: plastic, stiffness: {_q(m.unloading.known_stiffness, 'MN/m', 1e-6, '.1f')}}}",
            "from the rebound",
        ),
    ]
    lines += _test_lines(draft, data_file)
    lines.append("estimate:")
    for path, spec in problem.estimate.items():
        unit, scale, fmt = ESTIMATE_UNITS[path]
        lo, hi = spec.bounds or (None, None)
        assert lo is not None and hi is not None  # crashnlp.case.completion.default_estimate bounds each entry on both sides
        bounds = ", ".join(_q(b, unit, scale, fmt) for b in (lo, hi))
        lines.append(_line(2, f"{path}: {{bounds: [{bounds}]}}", "pitch lever" if path == PITCH_LEVER else ""))
    lines += ["constraints:", "  monotone_crush: true", "transcription: " + _flow(problem.transcription.model_dump())]
    return "\n".join(lines) + "\n"


def _test_lines(draft: Draft, data_file: str) -> list[str]:
    d = draft.data
    lines = [
        "tests:",
        f"  - name: {json.dumps(draft.name)}",
        "    data:",
        f"      file: {data_file}",
        f"      format: {d['format']}",
    ]
    if "time" in d:
        lines.append(f"      time: {_flow(d['time'])}")
    for key in ("bias_window", "window"):
        if key in d:
            lines.append(
                _line(6, f"{key}: [{d[key][0]:g} s, {d[key][1]:g} s]", "pre-impact mean removed" if key == "bias_window" else "")
            )
    lines.append("      channels:")
    for name, ch in d["channels"].items():
        lines.append(_line(8, f"{name}: {_flow(ch)}", draft.comments.get(name, "")))
    for name, ch in draft.optional.items():
        lines.append(_line(8, f"# {name}: {_flow(ch)}", draft.comments.get(name, "")))
    return lines


def init_problem(data: Path | list[Path], out: Path, options: Options) -> tuple[Problem, list[str]]:
    """Write a complete, commented problem file for the data set `data` (a path; or several NHTSA
    channel files of one test) to `out`; return its problem and the notes the file's head gives."""
    from crashnlp.case.case import Case

    paths = [data] if isinstance(data, Path) else data
    for path in paths:
        if not path.exists():
            raise InputError(f"{path}: file not found")
    _check_out(Path(out), paths, options)
    draft, suspension = draft_for(paths, options)
    out_dir = Path(out).resolve().parent
    drafted = problem_from_dict(problem_dict(draft, suspension, paths[0]), out_dir, source=str(paths[0]))
    case = Case(drafted)
    _check_given(case, options)
    problem = case.problem
    if case.resolution is not None:
        draft.notes.append(f"Spring: {case.resolution.note}.")
    text = render(draft, problem, os.path.relpath(located(paths[0]), out_dir))
    out_dir.mkdir(parents=True, exist_ok=True)  # the data file is named from here
    written = problem_from_dict(yaml.safe_load(text), out_dir, source=f"{out} (as written)")
    with atomic_open(Path(out)) as fh:
        fh.write(text)
    return written, draft.notes


def _check_out(out: Path, paths: list[Path], options: Options) -> None:
    """Refuse, before any work, an --out that cannot be written, that is one of the test's data
    files (even with --force), or that exists without --force: a problem file holds its user's edits."""
    check_writable_file(out)
    if not out.exists():
        return
    if out.resolve() in _data_files(paths, options.format or format_of(paths[0])):
        raise InputError(f"--out {out}: is one of the test's data files; name the problem file to write")
    if not options.force:
        raise InputError(f"--out {out}: exists; give --force to write over it, or name another file")


def _data_files(paths: list[Path], fmt: str) -> set[Path]:
    """The files of the test's data set, resolved: the paths given; the curve files its EV5 header
    lists; every channel file of an NHTSA test; an ISO-MME test's .mme and Channel files. A
    problem may read any of them (init offers a barrier's commented out)."""
    from crashnlp.data.nhtsa_ev5 import read_header

    files = set(paths)
    path = paths[0]
    if fmt == "nhtsa-ev5":
        files.update(path.with_suffix(f".{number:03d}") for number in read_header(path)[1])
    elif fmt == "nhtsa-channel":
        files.update(channel_files(path)[1].values())
    elif fmt == "iso-mme" and (path.is_dir() or path.suffix.lower() == ".mme"):  # a zip is one file
        base = path if path.is_dir() else path.parent
        for p in base.rglob("*"):
            if p.suffix.lower() == ".mme" or "channel" in (part.lower() for part in p.relative_to(base).parts[:-1]):
                files.add(p)
    return {p.resolve() for p in files}


def _check_given(case: Case, options: Options) -> None:
    """Refuse data identify would refuse (Case.check_data: a dead channel, a speed, units or signs
    they contradict), as identify would (crashnlp.case.testcase), and a --speed or --mass the test's
    data (as the case read them) contradict: the file written would not be fitted. A dead channel
    comes first: a velocity column of zeros is no speed to set --speed against."""
    from crashnlp.case.checks import named
    from crashnlp.case.testcase import check_dead, mass_contradicted, speed_contradicted

    test = case.tests[0]
    assert test.data is not None  # init writes the test with its data
    as_read = f"{test.spec.data.file if test.spec.data else case.name}: as read for the problem file"
    with named(as_read):
        check_dead(0, test.speed, test.spec, test.data)
    given = (("--speed", options.speed, speed_contradicted), ("--mass", options.mass, mass_contradicted))
    for option, value, contradicted in given:
        why = None if value is None else contradicted(value, test.spec, test.data)
        if why is not None:
            raise InputError(f"{option}: {why}")
    with named(as_read):
        case.check_data()  # what identify refuses in the data (their units, signs, speed), before the file is written
