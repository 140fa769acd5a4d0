"""A simulated or fitted response: named outputs in SI on a time grid, and its response.csv.

Light (numpy and the outputs registry): a result read back from its files needs no CasADi.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.outputs import COLUMNS, OUTPUT
from crashnlp.results.files import write_columns

# A response's output of the shortening of the front end's line of action, which its crush is while
# the front end touches the barrier; past separation it keeps falling as the vehicle moves away, where
# the crush stays at the permanent set (crashnlp.models.simulation.front_end_crush). The forward
# check compares it, a function of the states as the NLP's are (crashnlp.optimize.verify).
APPROACH = "approach"
RESPONSE_FILE = "response.csv"  # a test's response in its folder of a fit, a design or a simulation
RESPONSE_FIGURE = "response.png"  # its figure, where no data are fitted
NOT_WRITTEN = "not a response crashnlp wrote"  # said of a response.csv that no reader takes
OWN_ACCEL = "model_accel_g"  # response.csv's column of the model's own acceleration, beside the one read through a CFC class


@dataclass
class Response:
    """Named outputs (SI) on a time grid, plus the absorbed energies. `accel_filter`: the CFC
    class its acceleration is read through, as a test's accelerometers record it
    (crashnlp.analysis.summary.as_recorded), and `own_accel` the model's own acceleration then;
    None: the acceleration is the model's own."""

    time: np.ndarray
    outputs: dict[str, np.ndarray]
    states: np.ndarray  # rows: the model's states()[, the ABSORBED works]
    accel_filter: str | None = None
    own_accel: np.ndarray | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.time if name == "time" else self.outputs[name]

    def __iter__(self) -> Iterator[str]:
        """The names it is indexed by: "time", then its outputs."""
        return iter(("time", *self.outputs))

    def keys(self) -> list[str]:
        return list(self)

    @property
    def loading_end(self) -> float:
        """The model's own end of loading: where its crush rate first turns negative (s)."""
        rate = self.outputs["crush_rate"]
        k = int(np.argmax(rate < 0)) if np.any(rate < 0) else 0
        if k == 0:
            return float("nan")
        return float(np.interp(0.0, [-rate[k - 1], -rate[k]], self.time[k - 1 : k + 1]))


def write_response_csv(path: Path, response: Response, extra: dict[str, np.ndarray] | None = None) -> None:
    """response.csv: time and the registry's written outputs, in report units, the model's own
    acceleration where the written one is read through a CFC class (OWN_ACCEL), then `extra`
    columns (already in report units, e.g. a prediction's bands)."""
    written = {str(o.column): response.outputs[o.name] * o.factor for o in COLUMNS}  # COLUMNS: the outputs with a column
    if response.own_accel is not None:
        written[OWN_ACCEL] = response.own_accel * OUTPUT["accel"].factor
    write_columns(path, {"time_s": np.asarray(response.time), **written, **(extra or {})})


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """The columns of a CSV `write_columns` wrote, by name (a response.csv with any extra columns),
    its comment lines skipped (a header line would be read from the first of them). What no such
    table holds (no header or no data row, a row of another length than the header, a cell that
    reads as no number) is an InputError naming the file, and the column and the row: one reader
    for every command that reads a folder back, which all refuse it alike."""
    with path.open(encoding="utf-8") as fh:
        rows = [row for row in csv.reader(line for line in fh if not line.startswith("#")) if row]
    if len(rows) < 2:
        raise InputError(f"{path}: {'empty' if not rows else 'no data row'}: {NOT_WRITTEN}")
    head, data = rows[0], rows[1:]
    for i, row in enumerate(data, 1):
        if len(row) != len(head):
            raise InputError(f"{path}: data row {i} has {len(row)} cells for {len(head)} columns: {NOT_WRITTEN}")
        for column, cell in zip(head, row):
            try:
                float(cell)
            except ValueError:
                raise InputError(f"{path}: {column} is {cell!r} in data row {i}: {NOT_WRITTEN}") from None
    table = np.array(data, dtype=float)
    return {name: table[:, j] for j, name in enumerate(head)}


def response_of(columns: dict[str, np.ndarray], accel_filter: str | None = None) -> Response:
    """The response in a response.csv's columns (`read_columns`), back in SI; its acceleration read
    through CFC class `accel_filter` (as its result or simulation file says)."""
    outputs = {o.name: columns[str(o.column)] / o.factor for o in COLUMNS}
    own = columns[OWN_ACCEL] / OUTPUT["accel"].factor if OWN_ACCEL in columns else None
    return Response(columns["time_s"], outputs, np.zeros((0, columns["time_s"].size)), accel_filter, own)


def read_response(path: Path, accel_filter: str | None = None) -> Response:
    """A response.csv back in SI (the registry's written outputs), its acceleration read through `accel_filter`."""
    return response_of(read_columns(path), accel_filter)
