"""CSV reader: one time column and one column per channel, named in the problem file or counted from 1.

`Table` reads any delimited text file of numbers (comma, semicolon or tab; a header line or
none), for this reader and for NHTSA channel files (crashnlp.data.nhtsa_channel) alike.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.data.channels import Channel, DataError, TestData, check_samples, si_factor, where
from crashnlp.problem.schema import CHANNEL_UNITS, DataSpec
from crashnlp.units import unit_scale

DELIMITERS = ",;\t"  # the most frequent on the first line splits the file


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Table:
    """The cells of a delimited text file: its header (None when the first line is all numbers)
    and its rows, each with its line number in the file (blank lines left out)."""

    path: Path
    header: list[str] | None
    rows: list[tuple[int, list[str]]]

    @classmethod
    def read(cls, path: Path) -> Table:
        """The file's cells; a file that cannot be read, or holds no row of data, is refused."""
        try:
            lines = Path(path).read_text(errors="replace").splitlines()
        except OSError as exc:
            raise DataError(f"{path}: cannot read ({exc.strerror})") from None
        numbered = [(n, line) for n, line in enumerate(lines, 1) if line.strip()]
        if not numbered:
            raise DataError(f"{path}: empty file")
        delimiter = max(DELIMITERS, key=numbered[0][1].count)
        cells = csv.reader((line for _, line in numbered), delimiter=delimiter)
        try:
            rows = [(n, [c.strip() for c in row]) for (n, _), row in zip(numbered, cells)]
        except csv.Error as exc:
            raise DataError(f"{path}: cannot read as CSV ({exc})") from None
        header = None if all(_is_number(c) for c in rows[0][1]) else rows.pop(0)[1]
        if not rows:
            raise DataError(f"{path}: no rows of data below the header")
        return cls(Path(path), header, rows)

    @property
    def width(self) -> int:
        return len(self.header) if self.header is not None else len(self.rows[0][1])

    def index(self, column: str | int, channel: str) -> int:
        """Where a column is, 0-based: by its name in the header, else by its number counted from 1."""
        if self.header is not None and str(column) in self.header:
            return self.header.index(str(column))
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
        the column and the line."""
        at = where(self.path, channel, f"column {self.label(k)}")
        for n, cells in self.rows:
            if k >= len(cells):
                raise DataError(f"{at}: line {n} ends before this column ({len(cells)} of {self.width} cells)")
            if not _is_number(cells[k]):
                raise DataError(f"{at}: line {n}: {repr(cells[k]) + ' is not a number' if cells[k] else 'a blank cell'}")
        return np.array([cells[k] for _, cells in self.rows], dtype=float)


def read_csv(spec: DataSpec) -> TestData:
    """Channels from the columns `ChannelSpec.column`, time from `DataSpec.time`, values in SI.

    A column is named by its header (or counted from 1, as a file without a header line needs).
    A channel without a `unit` is taken as already SI. CSV files carry no header meta.
    """
    path = spec.file
    table = Table.read(path)
    try:
        scale = unit_scale(spec.time.unit, "s")
    except Exception:
        raise DataError(f"{where(path, 'time')}: unit {spec.time.unit!r} is not a time") from None
    time = table.values(table.index(spec.time.column, "time"), "time") * scale
    channels: dict[str, Channel] = {}
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        if ch.column is None:
            raise DataError(f"{where(path, name)}: no column given (a CSV channel needs `column`)")
        k = table.index(ch.column, name)
        at = where(path, name, f"column {table.label(k)}")
        values = table.values(k, name) * (si_factor(ch.unit, name, at) if ch.unit else 1.0)
        check_samples(time, values, at)
        channels[name] = Channel(time.copy(), values, CHANNEL_UNITS[name], f"{path.name}:{table.label(k)}")
    return TestData(channels, {})
