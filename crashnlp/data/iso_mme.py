"""ISO/TS 13499 (ISO-MME) reader: a test folder or .zip with <test>.mme, Channel/<test>.chn and
channel files Channel/<test>.001, .002, ...

All three are text files of "Name  :value" lines. The .mme file gives test-object data
("Velocity test object 1", "Mass test object 1"); the .chn file lists "Name of channel 001 :CODE / text";
a channel file gives "Unit", "Time of first sample", "Sampling interval", "Number of samples"
and then the samples, one per line. A code's 16th character is its filter class: 0 unfiltered,
A to D filtered by the lab at CFC 1000, 600, 180 and 60 (`LAB_FILTERS`), others another filter.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath

import numpy as np

from crashnlp.base.units import to_si
from crashnlp.data.channels import Channel, DataError, TestData, check_samples, of_key, si_factor, where
from crashnlp.problem.schema import CHANNEL_UNITS, DataSpec

_CHANNEL_LINE = re.compile(r"name of channel\s+(\d+)", re.IGNORECASE)
UNFILTERED = "0"  # the filter class (a code's 16th character) of data no filter has touched
LAB_FILTERS = {"A": "CFC1000", "B": "CFC600", "C": "CFC180", "D": "CFC60"}  # filter classes that are SAE J211 CFC classes


def filter_class(code: str) -> str:
    """An ISO channel code's filter class, its 16th character ('' for a shorter code)."""
    return code[15:16]


def filter_said(code: str, cfc: str | None) -> str | None:
    """What a channel code's filter class says of its data, and what a problem's filter `cfc` does
    over it, for a note or a comment; None where the code says unfiltered (class 0) or nothing."""
    letter = filter_class(code)
    if letter in ("", UNFILTERED):
        return None
    lab = LAB_FILTERS.get(letter)
    said = f"filtered by the lab, ISO filter class {letter} ({lab})" if lab else f"ISO filter class {letter}, not a CFC class"
    if cfc is None:
        return said
    return f"{said}: not filtered at {cfc} again" if cfc == lab else f"{said}; filtered at {cfc} over it"


class _Store:
    """Files of one test (folder or zip) by relative path, looked up case-insensitively."""

    def __init__(self, path: Path):
        import zipfile  # here, not at the top: every command imports this reader, few read a zip

        self.path = path
        self.zipped = path.is_file() and zipfile.is_zipfile(path)
        self.base = path if path.is_dir() or self.zipped else path.parent
        if self.zipped:
            with zipfile.ZipFile(path) as archive:
                names = [n for n in archive.namelist() if not n.endswith("/")]
        else:
            names = [p.relative_to(self.base).as_posix() for p in self.base.rglob("*") if p.is_file()]
        self.names = {n.lower(): n for n in names}

    def name(self, name: str) -> str | None:
        """The stored spelling of a relative path, or None."""
        return self.names.get(name.lower())

    def label(self, name: str) -> str:
        """How error messages name a stored file."""
        return f"{self.base}/{name}"

    def text(self, name: str) -> str:
        if self.zipped:
            import zipfile

            with zipfile.ZipFile(self.path) as archive:
                return archive.read(name).decode("latin-1")
        return (self.base / name).read_text(encoding="latin-1")

    def find(self, suffix: str) -> list[str]:
        return sorted(n for low, n in self.names.items() if low.endswith(suffix))


def _pairs(text: str) -> tuple[dict[str, str], list[str]]:
    """'Name :value' lines (keys lower-cased) up to the first line without a colon, and the rest."""
    pairs: dict[str, str] = {}
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if ":" not in line:
            if line.strip():
                return pairs, lines[i:]
            continue
        key, value = line.split(":", 1)
        pairs.setdefault(" ".join(key.split()).lower(), value.strip())
    return pairs, []


META_KEYS = {"speed": ("velocity test object {}", "m/s"), "mass": ("mass test object {}", "kg")}  # .mme entries by meta key
_DECIMAL_COMMA = re.compile(r"[+-]?\d+,\d+(\s*\D.*)?")  # a number with a decimal comma, as European labs write 2550,0
_THOUSANDS = re.compile(r",\d{3}(?!\d)")  # a comma that may separate thousands: 2,550 is 2550 or 2.55
# what a vehicle's crash test can hold, in SI: of a number that reads two ways (2,550), the one
# reading that falls here is the header's (the two readings are a factor 1000 apart, wider than
# either range, so at most one does)
VEHICLE_RANGE = {"speed": (1.0, 50.0), "mass": (100.0, 100_000.0)}


def header_meta(header: dict[str, str], obj: str, label: str) -> dict[str, float]:
    """'speed' and 'mass' of test object `obj` in SI from the .mme entries (plain numbers are SI, as
    ISO-MME stores them); an entry absent or NOVALUE is left out. A decimal comma reads as a point;
    one before exactly three digits (2,550: 2550 or 2.55) reads the way that is a vehicle's
    (VEHICLE_RANGE). An entry present but unreadable, or a vehicle's neither way, is refused
    naming the file `label` and the line: left out, it would silently drop the problem's mass and
    speed checks or leave them to a misleading "no header gives it"."""
    meta: dict[str, float] = {}
    for meta_key, (pattern, unit) in META_KEYS.items():
        key = pattern.format(obj)
        text = header.get(key, "")
        if not text or text.upper() == "NOVALUE":
            continue
        readings = _readings(text, unit)
        low, high = VEHICLE_RANGE[meta_key]
        plausible = [value for value in readings if low <= value <= high] if len(readings) > 1 else readings
        if len(plausible) != 1:
            line = f"'{key} :{text}'"
            raise DataError(f"{label}: header line {line} is not a quantity in {unit} (write it with a decimal point)")
        if plausible[0]:
            meta[meta_key] = plausible[0]
    return meta


def _readings(text: str, unit: str) -> list[float]:
    """The values in `unit` (SI) an .mme entry reads as: a number with a decimal point, a quantity
    with its unit, or a decimal comma; one with a comma before exactly three digits both ways (a
    decimal comma, a thousands separator); none where it is no number."""
    if not _DECIMAL_COMMA.fullmatch(text):
        candidates = [text]
    elif _THOUSANDS.search(text):
        candidates = [text.replace(",", "."), text.replace(",", "")]
    else:
        candidates = [text.replace(",", ".")]
    out = []
    for number in candidates:
        try:
            out.append(float(to_si(number if re.search(r"[A-Za-z]", number) else float(number), unit)))
        except ValueError:
            continue
    return out


def mme_files(path: Path) -> list[Path]:
    """The files of the test `path` names: a zip itself, else every file of its folder (`_Store`)."""
    store = _Store(path)
    return [path] if store.zipped else [store.base / name for name in sorted(store.names.values())]


def _open(path: Path) -> tuple[_Store, str, str, dict[str, str]]:
    """The test's files, its .mme and .chn names, and its channel numbers by code."""
    store = _Store(path)
    mme_files = [path.name] if path.suffix.lower() == ".mme" else store.find(".mme")
    if not mme_files:
        held = sorted(p.name for p in path.iterdir()) if path.is_dir() else []
        names = ", ".join(held[:4]) + (", ..." if len(held) > 4 else "")
        hint = f"; it holds {names}: name the data file" if held else ""
        raise DataError(f"{path}: no .mme file (not an ISO-MME test?){hint}")
    mme_name = mme_files[0]
    root = str(PurePosixPath(mme_name).parent)
    prefix = "" if root == "." else root + "/"
    chn_files = [n for n in store.find(".chn") if n.lower().startswith(prefix.lower() + "channel/")]
    if not chn_files:
        raise DataError(f"{path}: no Channel/*.chn file")
    chn_name = chn_files[0]
    listing, _ = _pairs(store.text(chn_name))
    codes: dict[str, str] = {}
    for key, value in listing.items():
        match = _CHANNEL_LINE.fullmatch(key)
        if match:
            codes.setdefault(value.split("/")[0].strip().upper(), match.group(1))
    return store, mme_name, chn_name, codes


def read_header(path: Path) -> tuple[dict[str, float], list[str]]:
    """Speed and mass of test object 1 (`header_meta`) and the channel codes of the test."""
    store, mme_name, _, codes = _open(path)
    return header_meta(_pairs(store.text(mme_name))[0], "1", store.label(mme_name)), list(codes)


def read_mme(spec: DataSpec) -> TestData:
    """Channels chosen by `ChannelSpec.code` (16-character ISO code), values in SI.

    The unit is the channel file's "Unit" unless `ChannelSpec.unit` overrides. A code's filter
    class A to D is the channel's `filtered` (a filter of that class is not applied again), and a
    note says what any class but 0 is. Meta: 'speed' and 'mass' of the test object numbered by the
    first character of the first code (default 1).
    """
    path = spec.file
    store, mme_name, chn_name, codes = _open(path)
    channels: dict[str, Channel] = {}
    notes: list[str] = []
    obj = None
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        with of_key(f"channels.{name}"):
            if not ch.code:
                raise DataError(f"{where(path, name)}: no code given (an ISO-MME channel needs `code`)")
            code = ch.code.strip().upper()
            if code not in codes:
                raise DataError(f"{where(store.label(chn_name), name, f'code {code}')}: code not in the channel list")
            obj = obj or (code[0] if code[0].isdigit() and code[0] != "0" else "1")
            wanted = f"{chn_name.rsplit('.', 1)[0]}.{codes[code]}"
            file = store.name(wanted)
            at = where(store.label(file or wanted), name, f"code {code}")
            if file is None:
                raise DataError(f"{at}: channel file missing")
            source = f"{PurePosixPath(file).name}:{code}"
            channels[name] = _channel(store.text(file), ch.unit, name, at, source, LAB_FILTERS.get(filter_class(code)))
            if said := filter_said(code, ch.filter):
                notes.append(f"{name}: code {code}: {said}")

    header, _ = _pairs(store.text(mme_name))
    return TestData(channels, header_meta(header, obj or "1", store.label(mme_name)), notes)


def _channel(text: str, unit: str | None, name: str, at: str, source: str, filtered: str | None) -> Channel:
    """One channel file's samples in SI; `filtered`: the CFC class its code says the lab filtered it at."""
    header, rows = _pairs(text)
    try:
        t0 = float(header["time of first sample"])
        dt = float(header["sampling interval"])
        count = int(float(header["number of samples"]))
    except KeyError as exc:
        raise DataError(f"{at}: header lacks {exc.args[0]!r}") from None
    except ValueError:
        raise DataError(f"{at}: time of first sample, sampling interval or number of samples is not a number") from None
    try:
        values = np.array([float(r) for r in rows if r.strip()])
    except ValueError as exc:
        raise DataError(f"{at}: bad sample ({exc})") from None
    if values.size != count:
        ends = f"the data end at {(t0 + dt * (values.size - 1)) * 1e3:g} ms, the header's at {(t0 + dt * (count - 1)) * 1e3:g} ms"
        raise DataError(f"{at}: {values.size} samples but the header says {count} ({ends})")
    unit = unit or header.get("unit", "")
    if not unit or unit.upper() == "NOVALUE":
        raise DataError(f"{at}: no unit in the channel file (give `unit`)")
    values = values * si_factor(unit.replace("**", "^"), name, at)
    time = t0 + dt * np.arange(count)
    check_samples(time, values, at)
    return Channel(time, values, CHANNEL_UNITS[name], source, filtered)
