"""A simulation's plain outcome and its files: the predicted tests (`PredictedTest`), their
intervals part by part (`IntervalParts`), and simulation.json with a response.csv per test,
written and read back (`write_simulation`, `read_simulation`). numpy only at import, as
crashnlp.results.result: a report of a simulation's folder needs no CasADi. The predictions
themselves are crashnlp.analysis.prediction's.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from crashnlp.base.outputs import COLUMNS, OUTPUT, RENAMED_EXTRAPOLATION, current_names
from crashnlp.results.files import claim, run_name
from crashnlp.results.jsonfile import write_json
from crashnlp.results.response import RESPONSE_FIGURE, RESPONSE_FILE, Response, read_columns, response_of, write_response_csv


@dataclass(frozen=True)
class IntervalParts:
    """A metric's 95 % interval, part by part, in the metric's unit: the parameters' half-width,
    the model's miss on the fitted tests, the force past the reach as crashnlp.analysis.prediction
    estimates it, and `unit`, the calibrated form term per unit of q (scale times distance to the
    calibrated power)."""

    value: float
    parameters: float
    fitted: float
    past_the_reach: float
    unit: float

    def form(self, q: float) -> float:
        """The model form's half-width: its miss on the fitted tests and the calibrated out-of-sample term."""
        return math.hypot(self.fitted, q * self.unit)

    def past(self, q: float) -> float:
        """The force past the reach's half-width: its estimate, scaled by q as calibrated."""
        return q * self.past_the_reach

    def half(self, q: float) -> float:
        return math.sqrt(self.parameters**2 + self.form(q) ** 2 + self.past(q) ** 2)

    def interval(self, q: float) -> tuple[float, float]:
        half = self.half(q)
        return self.value - half, self.value + half

    def shares(self, q: float) -> dict[str, float]:
        """Each part's half-width."""
        return {"parameters": self.parameters, "form": self.form(q), "past_the_reach": self.past(q)}

    def score(self, truth: float) -> float:
        """The smallest q whose interval covers `truth` (0 when the parameters and the fitted miss
        do; inf where nothing q scales can)."""
        rest = (truth - self.value) ** 2 - self.parameters**2 - self.fitted**2
        if rest <= 0.0:
            return 0.0
        per_q = math.hypot(self.unit, self.past_the_reach)
        return math.sqrt(rest) / per_q if per_q > 0 else math.inf

    def to_json(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("value", "parameters", "fitted", "past_the_reach", "unit")}

    @classmethod
    def from_json(cls, raw: dict[str, float]) -> IntervalParts:
        return cls(**raw)


@dataclass(frozen=True)
class PredictedTest(Mapping[str, np.ndarray]):
    """One simulated test: output key -> array in SI ("time_s", "crush_m", as crashnlp.base.outputs
    names them), its crash metrics, and with an identified model their 95 % intervals, the
    response bands (output name -> (low, high)), how far it lies past the identified range, each
    metric's interval parts (also where its form term is not calibrated), the calibrated q of each
    form term, and the calibration they came from (crashnlp.analysis.calibration.Calibration.named).
    `source`: the problem and the fit the prediction came from (crashnlp.results.source; empty
    where nobody said, or in a simulation.json written before crashnlp recorded it).
    `data`: the test's measured curves (channel -> (time, values), SI) where it runs at the
    conditions they were recorded at; empty otherwise, with a note saying why."""

    name: str
    speed: float
    mass: float
    response: Response
    metrics: dict[str, float | None]
    intervals: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    bands: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    extrapolation: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    data: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    parts: dict[str, IntervalParts] = field(default_factory=dict)
    form_q: dict[str, float] = field(default_factory=dict)
    calibration: dict[str, Any] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)  # crashnlp.results.source: the problem and the fit it came from

    @cached_property
    def _arrays(self) -> dict[str, np.ndarray]:
        r = self.response
        return {"time_s": r.time, **{OUTPUT[k].key: v for k, v in r.outputs.items() if k in OUTPUT}}

    def __getitem__(self, key: str) -> np.ndarray:
        return self._arrays[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._arrays)

    def __len__(self) -> int:
        return len(self._arrays)

    @property
    def conditions(self) -> str:
        """The speed and mass it was simulated at, as its figure's title and its console line name
        them: "predicted at 64.0 km/h, 2400 kg" (a what-if's `--speed` or `--mass` is not its name's)."""
        return f"predicted at {self.speed * 3.6:.1f} km/h, {self.mass:.0f} kg"

    def shares(self) -> dict[str, dict[str, float | str]]:
        """Per metric with an interval: each part's 95 % half-width, and which part dominates."""
        out: dict[str, dict[str, float | str]] = {}
        for key, q in self.form_q.items():
            shares = self.parts[key].shares(q)
            out[key] = {**shares, "dominant": max(shares, key=lambda k: shares[k])}
        return out


def response_columns(test: PredictedTest) -> dict[str, np.ndarray]:
    """response.csv's columns beyond the response: <column>_low and <column>_high of every band."""
    out = {}
    for o in COLUMNS:
        band = test.bands.get(o.name)
        if band is not None:
            out[f"{o.column}_low"], out[f"{o.column}_high"] = band[0] * o.factor, band[1] * o.factor
    return out


SIMULATION_FILE = "simulation.json"
TEST_FILES = (RESPONSE_FILE, RESPONSE_FIGURE)  # in each test's folder: its response and figure


def simulation_entries(tests: Iterable[str]) -> list[str]:
    """The files a simulation's folder gets (`write_simulation`, its figures), by name within it,
    for the folder's check before the simulation (crashnlp.results.files.check_entries)."""
    return [SIMULATION_FILE, *(f"{test}/{file}" for test in tests for file in TEST_FILES)]


def write_simulation(name: str, tests: dict[str, PredictedTest], out: Path) -> dict:
    """response.csv (with the bands' columns), metrics, intervals and extrapolation of each
    simulated test, and simulation.json (with the tests' source), into a folder that then holds
    this simulation only (crashnlp.results.files.claim); the figures are `simulation_figure_jobs`, drawn by the caller
    (crashnlp.results.drawing)."""
    source = next((test.source for test in tests.values() if test.source), None)
    summary: dict[str, Any] = {"name": name, **({"source": source} if source else {}), "tests": {}}
    with claim(out, run_name("simulate", name), option=None):
        for test in tests.values():
            r = test.response
            write_response_csv(out / test.name / RESPONSE_FILE, r, response_columns(test))
            entry: dict[str, Any] = {"speed_mps": test.speed, "mass_kg": test.mass, "metrics": test.metrics}
            entry["accel_filter"] = r.accel_filter
            if test.intervals:
                entry["intervals"] = {k: None if v is None else list(v) for k, v in test.intervals.items()}
                entry["interval_parts"] = test.shares()
                summary["calibration"] = test.calibration
            if test.intervals or test.extrapolation:
                entry["extrapolation"] = test.extrapolation
            if test.notes:
                entry["notes"] = list(test.notes)
            summary["tests"][test.name] = entry
        write_json(out / SIMULATION_FILE, summary)
    return summary


def read_simulation(folder: Path) -> tuple[str, dict[str, PredictedTest]]:
    """The name and the predicted tests `write_simulation` wrote into `folder`, back in SI: the
    responses and bands from each response.csv, the rest from simulation.json."""
    raw = current_names(json.loads((folder / SIMULATION_FILE).read_text(encoding="utf-8")))
    tests = {}
    for name, entry in raw["tests"].items():
        columns = read_columns(folder / name / RESPONSE_FILE)
        bands = {
            o.name: (columns[f"{o.column}_low"] / o.factor, columns[f"{o.column}_high"] / o.factor)
            for o in COLUMNS
            if f"{o.column}_low" in columns
        }
        intervals = {k: None if v is None else (float(v[0]), float(v[1])) for k, v in entry.get("intervals", {}).items()}
        tests[name] = PredictedTest(
            name,
            float(entry["speed_mps"]),
            float(entry["mass_kg"]),
            response_of(columns, entry.get("accel_filter")),
            entry["metrics"],
            intervals,
            bands,
            current_names(dict(entry.get("extrapolation", {})), RENAMED_EXTRAPOLATION),
            tuple(entry.get("notes", ())),
            source=dict(raw.get("source") or {}),  # none in a simulation.json written before it was recorded
        )
    return str(raw["name"]), tests


def extrapolation_line(beyond: dict[str, float]) -> str:
    """How far a prediction lies past the identified range (`PredictedTest.extrapolation`), in words."""
    parts = []
    if "displacement_m" in beyond:
        travel, rel = beyond["displacement_m"], beyond["displacement_rel"]
        parts.append(f"max displacement {travel * 1e3:.0f} mm ({rel * 100:.0f} %) past the largest fitted")
    if "speed_mps" in beyond:
        side = "above the fastest" if beyond["speed_mps"] > 0 else "below the slowest"
        parts.append(f"speed {abs(beyond['speed_mps']) * 3.6:.1f} km/h {side} fitted test")
    if "mass_kg" in beyond:
        side = "above the heaviest" if beyond["mass_kg"] > 0 else "below the lightest"
        parts.append(f"mass {abs(beyond['mass_kg']):.0f} kg {side} fitted test")
    return "extrapolates: " + "; ".join(parts)
