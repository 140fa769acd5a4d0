"""The out-of-sample model-form term of a prediction's intervals, calibrated on held-out predictions.

A fit tunes the metrics of the tests it was fitted at, so the model's miss there says little of
its miss at another speed or mass. That miss is calibrated instead on a corpus of vehicles of
more than one generator form (bench/corpus.py), each fitted as a user would (minimal problem
files) and asked to predict tests it was not fitted at (bench/calibration.py, `make calibrate`).

Each prediction falls into a class by where it goes against the fitted tests' impact energies
(m v^2 / 2): one fitted test and a lower energy (`one-down`) or a higher one (`one-up`); several
and between them (`between`), above them (`several-up`) or below them (`several-down`). Its
distance is |ln(E / E_nearest)|, E_nearest the fitted test's energy closest to its own: a speed
ratio and a mass ratio in one number. The form term's 95 % half-width of a metric is

    q[class][metric] * scale(metric) * distance

where scale is the predicted value (the rebound: the impact speed; the max pitch: at least
1 deg), and q is the split-conformal quantile of the scores of the calibration corpus: the
smallest q with which each held-out interval, its other parts as they were, would have covered
the generator's value (`IntervalParts.score`). At a fitted test's own energy the term is zero,
and the interval is what the fitted tests say of themselves.

The table ships as crashnlp/calibration.json with its method, corpus seeds and version;
simulation.json names it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from crashnlp.identified import IdentifiedRange

FILE = "calibration.json"
PITCH_FLOOR = 1.0  # deg: the max pitch's scale is at least this (a vehicle that barely pitches)
SAME_ENERGY = 1e-3  # relative: fitted tests closer than this in energy count as one
# a class the table lacks borrows one that knows less: a single test in the same direction
FALLBACK = {"several-down": "one-down", "several-up": "one-up"}


@dataclass(frozen=True)
class IntervalParts:
    """A metric's 95 % interval, part by part, in the metric's unit: the parameters' half-width,
    the model's miss on the fitted tests, the force past the reach, and `unit`, the calibrated
    form term per unit of q (scale times distance)."""

    value: float
    parameters: float
    fitted: float
    past_the_reach: float
    unit: float

    def form(self, q: float) -> float:
        """The model form's half-width: its miss on the fitted tests and the calibrated out-of-sample term."""
        return math.hypot(self.fitted, q * self.unit)

    def half(self, q: float) -> float:
        return math.sqrt(self.parameters**2 + self.form(q) ** 2 + self.past_the_reach**2)

    def interval(self, q: float) -> tuple[float, float]:
        half = self.half(q)
        return self.value - half, self.value + half

    def shares(self, q: float) -> dict[str, float]:
        """Each part's half-width."""
        return {"parameters": self.parameters, "form": self.form(q), "past_the_reach": self.past_the_reach}

    def score(self, truth: float) -> float:
        """The smallest q whose interval covers `truth` (0 when the other parts do; inf without a unit)."""
        rest = (truth - self.value) ** 2 - self.parameters**2 - self.fitted**2 - self.past_the_reach**2
        if rest <= 0.0:
            return 0.0
        return math.sqrt(rest) / self.unit if self.unit > 0 else math.inf

    def to_json(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("value", "parameters", "fitted", "past_the_reach", "unit")}

    @classmethod
    def from_json(cls, raw: dict[str, float]) -> IntervalParts:
        return cls(**raw)


def energies(fitted: IdentifiedRange) -> tuple[float, ...]:
    """The fitted tests' impact energies (J), from the range where an older result lacks them."""
    if fitted.energies:
        return fitted.energies
    return tuple(sorted({0.5 * m * v**2 for m, v in zip(fitted.masses, fitted.speeds)}))


def reach(fitted: IdentifiedRange, speed: float, mass: float) -> tuple[str, float]:
    """The class of a prediction at `speed` and `mass` against the fitted tests, and its distance."""
    known = np.asarray(energies(fitted))
    energy = 0.5 * mass * speed**2
    distance = float(np.min(np.abs(np.log(energy / known))))
    several = known.max() > known.min() * (1 + SAME_ENERGY)
    if energy < known.min():
        return ("several-down" if several else "one-down"), distance
    if energy > known.max():
        return ("several-up" if several else "one-up"), distance
    return ("between" if several else "one-down"), distance


def scale(metric: str, value: float, speed: float) -> float:
    """What a metric's form term is relative to: its value, the rebound's impact speed, the max
    pitch's value but at least PITCH_FLOOR degrees."""
    if metric == "rebound_velocity_mps":
        return speed
    if metric == "max_pitch_deg":
        return max(abs(value), PITCH_FLOOR)
    return abs(value)


def conformal_quantile(scores: list[float], coverage: float) -> float:
    """Split-conformal: the ceil((n + 1) coverage)-th smallest score (inf when n is too small)."""
    rank = math.ceil((len(scores) + 1) * coverage)
    return float(np.sort(scores)[rank - 1]) if rank <= len(scores) else math.inf


@dataclass(frozen=True)
class Calibration:
    """The calibrated form term: q per class and metric, and what it was calibrated on."""

    version: int
    method: str
    coverage: float
    corpus: dict[str, Any]
    table: dict[str, dict[str, float]]

    def q(self, klass: str, metric: str) -> float | None:
        """The class's q for a metric, or its fallback's; None where neither was calibrated."""
        row = self.table.get(klass) or self.table.get(FALLBACK.get(klass, ""), {})
        return row.get(metric)

    def named(self) -> dict[str, Any]:
        """What simulation.json says of the calibration its intervals used."""
        return {"file": f"crashnlp/{FILE}", "version": self.version, "method": self.method, "corpus": self.corpus}

    def to_json(self) -> dict[str, Any]:
        return {
            "version": self.version,
            "method": self.method,
            "coverage": self.coverage,
            "corpus": self.corpus,
            "table": self.table,
        }

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> Calibration:
        return cls(int(raw["version"]), raw["method"], float(raw["coverage"]), raw["corpus"], raw["table"])


@cache
def shipped() -> Calibration:
    """The calibration shipped with the package (crashnlp/calibration.json)."""
    return Calibration.from_json(json.loads(resources.files("crashnlp").joinpath(FILE).read_text()))
