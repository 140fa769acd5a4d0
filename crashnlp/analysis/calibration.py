"""The out-of-sample model-form term of a prediction's intervals, calibrated on held-out predictions.

A fit tunes the metrics of the tests it was fitted at, so the model's miss there says little of
its miss at another speed or mass. That miss is calibrated instead on a corpus of vehicles of
more than one generator form (bench/corpus.py), each fitted as a user would (minimal problem
files) and asked to predict tests it was not fitted at (bench/calibration.py, `make calibrate`).

Each prediction falls into a class by where it goes against the fitted tests: a lighter vehicle,
further below the fitted masses than beside the fitted speeds, is `mass-down` (ballast out,
another trim: its crush stays within the fitted one at the fitted speed); any other by its impact
energy (m v^2 / 2) against theirs, `down`, `between` or `up`. A heavier vehicle (a payload) is
`up`: its crush goes past the fitted tests' as a faster vehicle's does, and so do its misses. Its
distance is |ln(E / E_nearest)|, E_nearest the fitted test's energy closest to its own: a speed
ratio and a mass ratio in one number; or, where larger, how far its speed (twice, its share of
the energy) or its mass lies outside the fitted ones (|ln| of the ratio): a what-if that trades
speed for mass at a fitted energy still goes somewhere. A metric's 95 % half-width adds in quadrature the
parameters' half-width, the model's miss on the fitted tests, and what q scales:

    q[class][metric] * scale(metric) * distance ** power[metric]    (the out-of-sample form term)
    q[class][metric] * past_the_reach                                (the force past the reach)

scale is the predicted value (the rebound: at least the table's share of the impact speed; the max pitch: at least 1 deg);
past_the_reach is crashnlp.analysis.prediction's estimate of what the force past the crush the fitted
tests reached adds, a rule's guess that the calibration scales like the form term. q is the
split-conformal quantile of the scores of the calibration corpus: the smallest q with which each
held-out interval, its other parts as they were, would have covered the generator's value
(`crashnlp.results.simulation.IntervalParts.score`), its rank from the number of vehicles (one vehicle's predictions of a
class miss alike); and at least the score that 95 % of each generator form's predictions do not
exceed: a vehicle's form is not known when it is predicted, so the interval must hold for every
form the corpus has, not only for their mix. The power says how the miss grows with the
distance, set from the corpus per metric, and the rebound's floor is the share of the impact
speed whose table gives the corpus's rebounds the narrowest intervals (bench/calibration.py). At
a fitted test's own energy the terms are zero, and the interval is what the fitted tests say of
themselves.

Each model form has its own table, calibrated on that form's fits of the corpus: a form's miss
is its own. The tables ship as crashnlp/analysis/calibration.json (model form -> table, each with
its method, corpus seeds and version); a prediction takes its form's (`shipped`), and
simulation.json names the table it used. A form without a table of its own gives no intervals.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from crashnlp.problem.forms import DEFAULT_FORM
from crashnlp.results.identified import IdentifiedRange

FILE = "calibration.json"  # model form -> its table
PITCH_FLOOR = 1.0  # deg: the max pitch's scale is at least this (a vehicle that barely pitches)
# the rebound's scale is at least its table's `rebound_floor` share of the impact speed (a front end
# that gives back little still misses); 1, the impact speed itself, is the rule of the tables before it
IMPACT_SPEED = 1.0
SAME_ENERGY = 1e-3  # relative: fitted tests closer than this in energy count as one
Reach = Literal["down", "between", "up", "mass-down"]  # a prediction's class against the fitted tests (`reach`)
CLASSES: tuple[Reach, ...] = get_args(Reach)


def energies(fitted: IdentifiedRange) -> tuple[float, ...]:
    """The fitted tests' impact energies (J), from the range where an older result lacks them."""
    if fitted.energies:
        return fitted.energies
    return tuple(sorted({0.5 * m * v**2 for m, v in zip(fitted.masses, fitted.speeds)}))


def _outside(value: float, bounds: tuple[float, float]) -> float:
    """|ln| of how far `value` lies outside [low, high] (0 inside)."""
    low, high = bounds
    return abs(math.log(value / min(max(value, low), high)))


def reach(fitted: IdentifiedRange, speed: float, mass: float) -> tuple[Reach, float]:
    """The class of a prediction at `speed` and `mass` against the fitted tests, and its distance
    (module docstring): |ln(E / E_nearest)|, or twice how far its speed, or how far its mass, lies
    outside the fitted ones where larger. A lighter vehicle that goes further below the fitted masses than beside
    the fitted speeds (|ln| of the mass ratio against twice the speed ratio's) is `mass-down`; any
    other is `down`, `between` or `up` by its energy against the fitted tests' (a heavier vehicle
    `up`: its crush goes past theirs)."""
    known = np.asarray(energies(fitted))
    energy = 0.5 * mass * speed**2
    apart = float(np.min(np.abs(np.log(energy / known))))
    distance = max(apart, 2 * _outside(speed, fitted.speeds), _outside(mass, fitted.masses))
    if mass < fitted.masses[0] and _outside(mass, fitted.masses) > 2 * _outside(speed, fitted.speeds):
        return "mass-down", distance
    if energy < known.min() * (1 - SAME_ENERGY):
        return "down", distance
    if energy > known.max() * (1 + SAME_ENERGY):
        return "up", distance
    return "between", distance


def scale(metric: str, value: float, speed: float, rebound_floor: float = IMPACT_SPEED) -> float:
    """What a metric's form term is relative to: its value; the rebound's value but at least
    `rebound_floor` of the impact speed (its miss grows with the energy the front end gives back,
    and a rebound near zero still has one); the max pitch's value but at least PITCH_FLOOR degrees."""
    if metric == "rebound_velocity_mps":
        return max(abs(value), rebound_floor * speed)
    if metric == "max_pitch_deg":
        return max(abs(value), PITCH_FLOOR)
    return abs(value)


def form_unit(metric: str, value: float, speed: float, distance: float, power: float, rebound_floor: float) -> float:
    """The form term per unit of q: the metric's scale (`scale`) times the distance to `power`;
    zero at a fitted test's own energy."""
    return scale(metric, value, speed, rebound_floor) * distance**power if distance > 0 else 0.0


def share_quantile(scores: list[float], share: float) -> float:
    """The smallest score that at least `share` of the scores do not exceed: the ceil(n share)-th
    smallest of n, n share rounded to 9 digits first (35 x (29 / 35) is 29.000000000000004 in
    floating point, and must rank 29); inf where no score is (a share past 1, or a rank below 1)."""
    rank = math.ceil(round(len(scores) * share, 9))
    return float(np.sort(scores)[rank - 1]) if share <= 1 and rank >= 1 else math.inf


def conformal_quantile(scores: list[float], coverage: float, units: int | None = None) -> float:
    """Split-conformal: of n scores from `units` exchangeable units (each unit's scores alike: one
    vehicle's predictions; n units by default), the score at the share ceil((units + 1) coverage)
    / units of them, the ceil((n + 1) coverage)-th smallest for n units (inf when too few)."""
    units = units or len(scores)
    return share_quantile(scores, math.ceil((units + 1) * coverage) / units)


@dataclass(frozen=True)
class Calibration:
    """The calibrated form term of one model form: q per class and metric, per metric the power of
    the distance in the form term's unit, the rebound's floor (`scale`), and what it was
    calibrated on."""

    form: str
    version: int
    method: str
    coverage: float
    corpus: dict[str, Any]
    table: dict[str, dict[str, float]]
    power: dict[str, float]
    rebound_floor: float = IMPACT_SPEED

    def q(self, klass: str, metric: str) -> float | None:
        """The class's q for a metric; None where it was not calibrated."""
        return self.table.get(klass, {}).get(metric)

    def unit(self, metric: str, value: float, speed: float, distance: float) -> float:
        """The form term per unit of q with this table's power and rebound floor (`form_unit`)."""
        return form_unit(metric, value, speed, distance, self.power[metric], self.rebound_floor)

    def scale(self, metric: str, value: float, speed: float) -> float:
        """The metric's scale (`scale`) with this table's rebound floor."""
        return scale(metric, value, speed, self.rebound_floor)

    def farthest(self, klass: str) -> float | None:
        """The largest distance the corpus's predictions of class `klass` went (its scenarios: one
        vehicle at the fitted speeds, the predicted speed and mass ratio); past it the form term
        is the power of the distance carried on, not calibrated. None where no scenario is of it."""
        out: dict[str, float] = {}
        for scenario in self.corpus.get("scenarios", {}).values():
            speeds = [kmh / 3.6 for kmh in scenario["fitted_kmh"]]
            fitted = IdentifiedRange(0.0, (min(speeds), max(speeds)), (1.0, 1.0), 0.0, tuple(0.5 * v**2 for v in speeds))
            k, distance = reach(fitted, scenario["predicted_kmh"] / 3.6, scenario["mass_ratio"])
            out[k] = max(out.get(k, 0.0), distance)
        return out.get(klass)

    def named(self) -> dict[str, Any]:
        """What simulation.json says of the calibration its intervals used."""
        return {
            "file": f"crashnlp/analysis/{FILE}",
            "form": self.form,
            "version": self.version,
            "method": self.method,
            "corpus": self.corpus,
        }

    def to_json(self) -> dict[str, Any]:
        return {
            "form": self.form,
            "version": self.version,
            "method": self.method,
            "coverage": self.coverage,
            "corpus": self.corpus,
            "table": self.table,
            "power": self.power,
            "rebound_floor": self.rebound_floor,
        }

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> Calibration:
        return cls(
            raw["form"],
            int(raw["version"]),
            raw["method"],
            float(raw["coverage"]),
            raw["corpus"],
            raw["table"],
            {k: float(v) for k, v in raw["power"].items()},
            float(raw.get("rebound_floor", IMPACT_SPEED)),  # a table before version 11: the impact speed
        )


@cache
def tables() -> dict[str, Calibration]:
    """The tables shipped with the package (crashnlp/analysis/calibration.json, beside this module), by
    model form."""
    raw = json.loads(Path(__file__).with_name(FILE).read_text())
    return {form: Calibration.from_json(table) for form, table in raw.items()}


def shipped(form: str = DEFAULT_FORM) -> Calibration | None:
    """The shipped table of model form `form`; None where it has none: another form's misses are
    not its own, so its predictions get no intervals (crashnlp.analysis.prediction says so)."""
    return tables().get(form)
