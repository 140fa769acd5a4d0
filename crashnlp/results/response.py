"""A simulated or fitted response: named outputs in SI on a time grid, and its response.csv.

Light (numpy and the outputs registry): a result read back from its files needs no CasADi.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.base.outputs import COLUMNS
from crashnlp.results.files import write_columns


@dataclass
class Response:
    """Named outputs (SI) on a time grid, plus the absorbed energies."""

    time: np.ndarray
    outputs: dict[str, np.ndarray]
    states: np.ndarray  # rows: the model's states()[, the ABSORBED works]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.time if name == "time" else self.outputs[name]

    @property
    def loading_end(self) -> float:
        """The model's own end of loading: where its crush rate first turns negative (s)."""
        rate = self.outputs["crush_rate"]
        k = int(np.argmax(rate < 0)) if np.any(rate < 0) else 0
        if k == 0:
            return float("nan")
        return float(np.interp(0.0, [-rate[k - 1], -rate[k]], self.time[k - 1 : k + 1]))


def write_response_csv(
    path: Path, time: np.ndarray, outputs: dict[str, np.ndarray], extra: dict[str, np.ndarray] | None = None
) -> None:
    """response.csv: time and the registry's written outputs, in report units, then `extra`
    columns (already in report units, e.g. a prediction's bands)."""
    written = {str(o.column): outputs[o.name] * o.factor for o in COLUMNS}  # COLUMNS: the outputs with a column
    write_columns(path, {"time_s": np.asarray(time), **written, **(extra or {})})


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """The columns of a CSV `write_columns` wrote, by name (a response.csv with any extra columns)."""
    table = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
    return {name: np.asarray(table[name], dtype=float) for name in table.dtype.names or ()}


def response_of(columns: dict[str, np.ndarray]) -> Response:
    """The response in a response.csv's columns (`read_columns`), back in SI."""
    outputs = {o.name: columns[str(o.column)] / o.factor for o in COLUMNS}
    return Response(columns["time_s"], outputs, np.zeros((0, columns["time_s"].size)))


def read_response(path: Path) -> Response:
    """A response.csv back in SI (the registry's written outputs)."""
    return response_of(read_columns(path))
