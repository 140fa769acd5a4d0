"""CSV reader: one time column and one column per channel, named in the problem file or counted from 1.

`Table` reads any delimited text file of numbers (comma, semicolon, tab or runs of spaces, or the
one Excel's first line "sep=;" names; a header line or none; "#" comment lines and a UTF-8 byte
order mark skipped; decimal commas where the cells are not comma-separated), for this reader, NHTSA channel files
(crashnlp.data.nhtsa_channel) and EV5 curve files (crashnlp.data.nhtsa_ev5) alike.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from crashnlp.base.units import unit_scale
from crashnlp.data.channels import Channel, DataError, TestData, check_samples, of_key, si_factor, where
from crashnlp.problem.schema import CHANNEL_UNITS, DataSpec

DELIMITERS = ",;\t"  # the most frequent on the first line splits the file; with none of them, runs of spaces do


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _delimiter(first: str) -> str:
    """The delimiter the first line has most of, else " " (runs of spaces)."""
    delimiter = max(DELIMITERS, key=first.count)
    return delimiter if delimiter in first else " "


def _separator_line(path: Path, numbered: list[tuple[int, str]]) -> str | None:
    """The delimiter Excel's first line "sep=;" names (a file Excel saved for another locale), or
    None without that line; one naming no single character is refused, naming the line."""
    number, first = numbered[0]
    if not first.lower().startswith("sep="):
        return None
    named = first[4:]
    if len(named) != 1 or named.isalnum() or named in "\"'.":
        raise DataError(f"{path}: line {number} {first!r} names no delimiter (Excel's sep= line names one character)")
    return named


def _header(first: list[str], decimal_comma: bool) -> list[str] | None:
    """The first line's cells as the header; None where every one is a number (no header line)."""
    return None if all(_is_number(c.replace(",", ".") if decimal_comma else c) for c in first) else first


def _split(lines: list[str], delimiter: str, path: Path) -> list[list[str]]:
    """The cells of each line, split on `delimiter` (" ": runs of spaces), each stripped."""
    if delimiter == " ":
        return [line.split() for line in lines]
    try:
        return [[c.strip() for c in row] for row in csv.reader(lines, delimiter=delimiter)]
    except csv.Error as exc:
        raise DataError(f"{path}: cannot read as CSV ({exc})") from None


def _plain(lines: list[str], delimiter: str) -> tuple[list[str] | None, np.ndarray] | None:
    """The header (None without one) and the rows as a matrix, read in one call, where the file is
    plain: no quotes, the same number of cells on every line below the header, every one of them
    a number as numpy reads it (a decimal comma is not); None otherwise, for the cell-by-cell
    reading to read or refuse (a line past the csv module's field limit too, which it refuses).
    A column the header names and the rows lack is left to that reading too (Table.values).
    numpy's reader converts each cell as float() does (the same bits), and refuses some cells
    float() takes (1_000, other scripts' digits), which the cell-by-cell reading then reads."""
    text = "\n".join(lines)
    if '"' in text or max(map(len, lines)) > csv.field_size_limit():
        return None
    first = lines[0].split() if delimiter == " " else [c.strip() for c in lines[0].split(delimiter)]
    header = _header(first, delimiter != ",")
    data = lines[1:] if header is not None else lines
    if not data:
        return None
    try:
        return header, np.loadtxt(data, delimiter=None if delimiter == " " else delimiter, comments=None, ndmin=2)
    except ValueError:
        return None


UTF16_MARKS = (b"\xff\xfe", b"\xfe\xff")  # the byte-order marks of UTF-16, little- and big-endian


@dataclass(frozen=True)
class Table:
    """The cells of a delimited text file: its header (None when the first line is all numbers)
    and its rows, each with its line number in the file (blank and comment lines left out).

    A plain file (see `_plain`) is read in one call into `numbers`, and its rows are split into
    cells only when a message needs them; any other file is read cell by cell."""

    path: Path
    header: list[str] | None
    lines: list[tuple[int, str]]  # the file's lines, numbered, blank and comment lines left out
    decimal_comma: bool = False  # cells not split on commas, so 0,5 is a half
    delimiter: str = ","  # what splits the cells (" ": runs of spaces)
    numbers: np.ndarray | None = field(default=None, compare=False)  # the rows as numbers, a plain file's

    @classmethod
    def read(cls, path: Path) -> Table:
        """The file's cells; a file that cannot be read, is no text, is UTF-16 text, or holds no row of
        data, is refused."""
        try:
            raw = Path(path).read_bytes()
        except OSError as exc:
            raise DataError(f"{path}: cannot read ({exc.strerror})") from None
        if raw.startswith(UTF16_MARKS):  # Excel's "Unicode Text": read as UTF-8, a NUL after every character
            raise DataError(f"{path}: UTF-16 text (its byte-order mark): save it as UTF-8 (Excel: CSV UTF-8)")
        text = raw.decode("utf-8-sig", errors="replace")
        if "\x00" in text:  # a program, an archive, an image: its bytes would be named as its columns
            raise DataError(f"{path}: not a text file (it holds NUL bytes): give the test's data as delimited text")
        lines = text.splitlines()
        numbered = [(n, line) for n, line in enumerate(lines, 1) if (text := line.lstrip()) and text[0] != "#"]
        if not numbered:
            raise DataError(f"{path}: empty file")
        named = _separator_line(path, numbered)
        numbered = numbered[1:] if named is not None else numbered
        if not numbered:
            raise DataError(f"{path}: empty file")
        texts = [line for _, line in numbered]
        delimiter = named or _delimiter(texts[0])
        decimal_comma = delimiter != ","
        plain = _plain(texts, delimiter)
        if plain is not None:
            return cls(Path(path), plain[0], numbered, decimal_comma, delimiter, plain[1])
        cells = _split(texts, delimiter, path)
        header = _header(cells[0], decimal_comma)
        if header is not None and len(cells) == 1:
            raise DataError(f"{path}: no rows of data below the header")
        table = cls(Path(path), header, numbered, decimal_comma, delimiter)
        rows = list(zip((n for n, _ in numbered), cells))
        object.__setattr__(table, "rows", rows[1:] if header is not None else rows)  # the cells split above, not again
        return table

    @cached_property
    def rows(self) -> list[tuple[int, list[str]]]:
        """The rows below the header: each line's number and its cells."""
        texts = [line for _, line in self.lines]
        rows = list(zip((n for n, _ in self.lines), _split(texts, self.delimiter, self.path)))
        return rows[1:] if self.header is not None else rows

    @property
    def width(self) -> int:
        if self.header is not None:
            return len(self.header)
        return self.numbers.shape[1] if self.numbers is not None else len(self.rows[0][1])

    def index(self, column: str | int, channel: str) -> int:
        """Where a column is, 0-based: by its name in the header, else by its number counted from 1."""
        if self.header is not None and str(column) in self.header:
            found = [k + 1 for k, name in enumerate(self.header) if name == str(column)]
            if len(found) > 1:
                raise DataError(
                    f"{where(self.path, channel)}: the header names columns {', '.join(map(str, found))} {column!r}: "
                    "give the one meant by its number"
                )
            return found[0] - 1
        number = int(column) if isinstance(column, int) or column.isdigit() else None
        if number is not None and 1 <= number <= self.width:
            return number - 1
        names = f"columns {', '.join(self.header)}, or" if self.header is not None else "no header line: give"
        raise DataError(f"{where(self.path, channel)}: no column {column!r} ({names} a number from 1 to {self.width})")

    def label(self, k: int) -> str:
        """How a message names column k (0-based): its name, else its number."""
        return self.header[k] if self.header is not None else f"{k + 1}"

    def values(self, k: int, channel: str) -> np.ndarray:
        """Column k (0-based) as numbers; a blank, missing or non-numeric cell is refused, naming
        the column and the line (numpy converts the cells as float() does, in one call)."""
        if self.numbers is not None and k < self.numbers.shape[1]:
            return self.numbers[:, k].copy()
        try:
            column = [cells[k] for _, cells in self.rows]
            return np.array([c.replace(",", ".") for c in column] if self.decimal_comma else column, dtype=float)
        except (IndexError, ValueError):
            raise self._refusal(k, channel) from None

    def _refusal(self, k: int, channel: str) -> DataError:
        """The error naming the first line whose cell of column k is missing or not a number."""
        at = where(self.path, channel, f"column {self.label(k)}")
        for n, cells in self.rows:
            if k >= len(cells):
                return DataError(f"{at}: line {n} ends before this column ({len(cells)} of {self.width} cells)")
            if not _is_number(cells[k].replace(",", ".") if self.decimal_comma else cells[k]):
                return DataError(f"{at}: line {n}: {repr(cells[k]) + ' is not a number' if cells[k] else 'a blank cell'}")
        raise AssertionError("a column numpy refused has a cell float() refuses")


def read_csv(spec: DataSpec) -> TestData:
    """Channels from the columns `ChannelSpec.column`, time from `DataSpec.time`, values in SI.

    A column is named by its header (or counted from 1, as a file without a header line needs).
    A channel without a `unit` is taken as already SI. CSV files carry no header meta.
    """
    path = spec.file
    table = Table.read(path)
    with of_key("time"):
        try:
            scale = unit_scale(spec.time.unit, "s")
        except Exception:
            raise DataError(f"{where(path, 'time')}: unit {spec.time.unit!r} is not a time") from None
        time = table.values(table.index(spec.time.column, "time"), "time") * scale
    channels: dict[str, Channel] = {}
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        with of_key(f"channels.{name}"):
            if ch.column is None:
                raise DataError(f"{where(path, name)}: no column given (a CSV channel needs `column`)")
            k = table.index(ch.column, name)
            at = where(path, name, f"column {table.label(k)}")
            values = table.values(k, name) * (si_factor(ch.unit, name, at) if ch.unit else 1.0)
            check_samples(time, values, at)
            channels[name] = Channel(time.copy(), values, CHANNEL_UNITS[name], f"{path.name}:{table.label(k)}")
    return TestData(channels, {})
