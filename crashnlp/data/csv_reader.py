"""CSV reader: one time column and one column per channel, named in the problem file."""

from __future__ import annotations

import csv

import numpy as np

from crashnlp.data.channels import Channel, DataError, TestData, check_samples, si_factor, where
from crashnlp.problem.schema import CHANNEL_UNITS, DataSpec
from crashnlp.units import unit_scale


def read_csv(spec: DataSpec) -> TestData:
    """Channels from the columns `ChannelSpec.column`, time from `DataSpec.time`, values in SI.

    A channel without a `unit` is taken as already SI. CSV files carry no header meta.
    """
    path = spec.file
    try:
        with open(path, newline="") as fh:
            first = fh.readline()
            delimiter = max(",;\t", key=first.count)
            header = [h.strip() for h in next(csv.reader([first], delimiter=delimiter))]
            table = np.loadtxt(fh, delimiter=delimiter, ndmin=2)
    except (OSError, ValueError, StopIteration) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{path}: cannot read as CSV ({reason})") from None
    if table.shape[1] != len(header):
        raise DataError(f"{path}: {len(header)} column names but {table.shape[1]} columns of data")

    def column(name: str, channel: str) -> np.ndarray:
        if name not in header:
            raise DataError(f"{where(path, channel)}: no column {name!r} (columns: {', '.join(header)})")
        return table[:, header.index(name)]

    time = column(spec.time.column, "time")
    try:
        time = time * unit_scale(spec.time.unit, "s")
    except Exception:
        raise DataError(f"{where(path, 'time')}: unit {spec.time.unit!r} is not a time") from None
    channels: dict[str, Channel] = {}
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        if ch.column is None:
            raise DataError(f"{where(path, name)}: no column given (a CSV channel needs `column`)")
        at = where(path, name, f"column {ch.column}")
        values = column(ch.column, name) * (si_factor(ch.unit, name, at) if ch.unit else 1.0)
        check_samples(time, values, at)
        channels[name] = Channel(time.copy(), values, CHANNEL_UNITS[name], f"{path.name}:{ch.column}")
    return TestData(channels, {})
