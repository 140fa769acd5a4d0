"""Predictions: an identified vehicle simulated at new speeds, masses or durations, with 95 % intervals.

The intervals propagate two sources of error to every crash metric and response curve:

- the parameters: their covariance (the fit's sandwich, with the smoothness prior as the
  information it adds) pushed through the output's sensitivities, taken as central
  differences of the forward simulation over one standard error each way (one-sided at a
  bound), so a metric that bends within that span is not linearised at a point;
- the model's form: on the fitted tests, the model missed each metric of the data by some
  relative amount, and each channel by its RMSE; that miss, root mean square over the tests,
  is added in quadrature, scaled to the predicted value;
- the force past the fitted crush, which no test measured: the loading curve continues its
  last segment there (crashnlp.model.laws), and how well that rule predicts is
  measured on the identified curve itself, breakpoint by breakpoint inside the data
  (`tail_error`). That relative error of the force, grown in proportion to the distance past
  the fitted crush over the breakpoint spacing, moves the max crush (by the energy it adds or
  takes) and the peak deceleration (where the peak lies past the fitted crush).

A metric or curve that no fitted test measured (pitch, without a pitch channel) gets no
interval, nor does anything when an estimated value is not determined by the data: the
prediction says so in `notes`, instead of a band that only looks narrow.

`write_simulation` writes what `crashnlp simulate` writes of the predicted tests, and
`simulation_figure_jobs` are their figures.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.case import Case, TestCase
from crashnlp.identified import INTERVAL_METRICS, IdentifiedModel
from crashnlp.jsonfile import write_json
from crashnlp.outputs import COLUMNS, MEASURABLE, OUTPUT
from crashnlp.simulation import Response, write_response_csv
from crashnlp.summary import data_curves, response_metrics
from crashnlp.units import G0

if TYPE_CHECKING:
    from crashnlp.plots import Job  # not at run time: matplotlib

Z95 = 1.959964  # two-sided 95 % quantile of the normal distribution
# response columns and the fitted channel whose RMSE measures the model's miss of them
BAND_CHANNEL = {
    "displacement": "displacement",
    "velocity": "velocity",
    "accel": "accel",
    "pitch": "pitch",
    "crush": "displacement",
    "barrier_force": "barrier_force",
}


@dataclass(frozen=True)
class PredictedTest(Mapping[str, np.ndarray]):
    """One simulated test: output key -> array in SI ("time_s", "crush_m", as crashnlp.outputs
    names them), its crash metrics, and with an identified model their 95 % intervals, the
    response bands (output name -> (low, high)) and how far it lies past the identified range."""

    name: str
    speed: float
    mass: float
    response: Response
    metrics: dict[str, float | None]
    intervals: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    bands: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    extrapolation: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

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


def predict(case: Case, identified: IdentifiedModel | None = None, dt: float | None = None) -> dict[str, PredictedTest]:
    """Every test of `case` simulated (`case` built from a problem the identified model was
    applied to, crashnlp.identified.apply); with `identified`, intervals and extrapolation too."""
    out = {}
    for test in case.tests:
        p = case.test_parameters(test)
        response = case.simulate_test(test, p, dt)
        metrics = response_metrics(response)
        mass = float(p[case.layout.index("vehicle.mass")][0])
        if identified is None:
            out[test.name] = PredictedTest(test.name, test.speed, mass, response, metrics)
            continue
        intervals, bands, notes = _uncertainty(case, test, p, mass, response, metrics, identified, dt)
        beyond = identified.range.beyond(float(metrics["max_crush_m"] or 0.0), test.speed, mass)
        out[test.name] = PredictedTest(test.name, test.speed, mass, response, metrics, intervals, bands, beyond, notes)
    return out


def _uncertainty(
    case: Case,
    test: TestCase,
    p: np.ndarray,
    mass: float,
    response: Response,
    metrics: dict[str, float | None],
    identified: IdentifiedModel,
    dt: float | None,
) -> tuple[dict[str, tuple[float, float] | None], dict[str, tuple[np.ndarray, np.ndarray]], tuple[str, ...]]:
    """95 % intervals of the metrics and bands of the response columns (module docstring)."""
    std = identified.std()
    undetermined = [label for label, s in zip(identified.labels, std) if not np.isfinite(s)]
    if undetermined:
        note = f"{test.name}: no intervals: the data do not determine {', '.join(undetermined)}"
        return {k: None for k in INTERVAL_METRICS}, {}, (note,)
    gm, gy = _sensitivities(case, test, p, identified, std, dt)
    cov = identified.covariance if identified.covariance is not None else np.zeros((len(std), len(std)))
    intervals: dict[str, tuple[float, float] | None] = {}
    notes = []
    past = _past_the_fitted_crush(response, identified, mass)
    for i, key in enumerate(INTERVAL_METRICS):
        value, miss = metrics.get(key), identified.discrepancy.get(key)
        if value is None or not np.isfinite(value) or miss is None:
            intervals[key] = None
            why = "no fitted test measured it" if miss is None else "the simulated test does not reach it"
            notes.append(f"{test.name}: no interval for {key}: {why}")
            continue
        half = Z95 * np.sqrt(gm[:, i] @ cov @ gm[:, i] + (miss * value) ** 2 + past.get(key, 0.0) ** 2)
        intervals[key] = (float(value - half), float(value + half))
    bands = {}
    for name, channel in BAND_CHANNEL.items():
        rmse = identified.channel_rmse.get(channel)
        if rmse is None:
            continue
        g = gy.get(name, np.zeros((len(std), response.time.size)))  # values x times
        half = Z95 * np.sqrt(np.einsum("it,ij,jt->t", g, cov, g) + rmse**2)
        bands[name] = (response[name] - half, response[name] + half)
    return intervals, bands, tuple(notes)


def tail_error(breakpoints: np.ndarray, values: np.ndarray) -> float:
    """The relative error of the tail rule on the identified loading curve: at each breakpoint
    from the third on, the force the curve's two breakpoints before it predict (continuing
    their segment) against the curve's own, relative to
    the curve's mean force; root mean square over the breakpoints."""
    x, f = np.asarray(breakpoints, float), np.asarray(values, float)
    if x.size < 3:
        return 0.0
    slope = np.diff(f[:-1]) / np.diff(x[:-1])
    predicted = f[1:-1] + slope * np.diff(x[1:])
    scale = max(float(np.mean(np.abs(f[1:]))), 1.0)
    return float(np.sqrt(np.mean(((f[2:] - predicted) / scale) ** 2)))


def _past_the_fitted_crush(response: Response, identified: IdentifiedModel, mass: float) -> dict[str, float]:
    """One standard error of max crush (m) and peak deceleration (g) from the force past the
    fitted crush: force error u F_R (d / spacing) at a distance d past it (see the module's
    docstring); none inside the fitted crush."""
    spring = identified.model.get("spring") or {}
    if spring.get("law") != "force":
        return {}
    x, f = np.asarray(spring["crush_breakpoints"], float), np.asarray(spring["values"], float)
    crush, reach = response["displacement"], identified.range.max_crush
    beyond = float(np.max(crush)) - reach
    if beyond <= 0 or x.size < 3:
        return {}
    slope = tail_error(x, f) * float(np.mean(np.abs(f[1:]))) / float(np.mean(np.diff(x)))  # N/m of force error
    at_max = max(float(np.interp(np.max(crush), x, f)), 1.0)
    out = {"max_crush_m": slope * beyond**2 / 2 / at_max}
    peak = int(np.argmax(-response["accel"]))
    if crush[peak] > reach:
        out["peak_decel_g"] = slope * (crush[peak] - reach) / mass / G0
    return out


def _sensitivities(
    case: Case, test: TestCase, p: np.ndarray, identified: IdentifiedModel, std: np.ndarray, dt: float | None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """d metric / d value (values x metrics) and d output / d value (output -> values x times):
    central differences over one standard error each way, clipped to the estimate's bounds."""
    slices = case.layout.slices()
    gm = np.zeros((len(identified.labels), len(INTERVAL_METRICS)))
    gy: dict[str, np.ndarray] = {}
    for j, label in enumerate(identified.labels):
        k = _position(slices, label)
        lo, hi = identified.bounds[j]
        up, down = min(p[k] + std[j], hi), max(p[k] - std[j], lo)
        if up <= down:
            continue
        r_up, r_down = (case.simulate_test(test, _with(p, k, value), dt) for value in (up, down))
        m_up, m_down = response_metrics(r_up), response_metrics(r_down)
        gm[j] = [_difference(m_up.get(key), m_down.get(key)) / (up - down) for key in INTERVAL_METRICS]
        for name in BAND_CHANNEL:
            gy.setdefault(name, np.zeros((len(identified.labels), r_up.time.size)))[j] = (r_up[name] - r_down[name]) / (up - down)
    return gm, gy


def _with(p: np.ndarray, k: int, value: float) -> np.ndarray:
    q = p.copy()
    q[k] = value
    return q


def _difference(a: float | None, b: float | None) -> float:
    return 0.0 if a is None or b is None or not (np.isfinite(a) and np.isfinite(b)) else a - b


def _position(slices: dict[str, slice], label: str) -> int:
    """Index in the full parameter vector of a label ("vehicle.mass", "model.spring.values[3]")."""
    path, _, rest = label.partition("[")
    return slices[path].start + (int(rest.rstrip("]")) if rest else 0)


def response_columns(test: PredictedTest) -> dict[str, np.ndarray]:
    """response.csv's columns beyond the response: <column>_low and <column>_high of every band."""
    out = {}
    for o in COLUMNS:
        band = test.bands.get(o.name)
        if band is not None:
            out[f"{o.column}_low"], out[f"{o.column}_high"] = band[0] * o.factor, band[1] * o.factor
    return out


def write_simulation(name: str, tests: dict[str, PredictedTest], out: Path) -> dict:
    """response.csv (with the bands' columns), metrics, intervals and extrapolation of each
    simulated test, and simulation.json; the figures are `simulation_figure_jobs`, drawn by the
    caller (crashnlp.drawing)."""
    summary: dict[str, Any] = {"name": name, "tests": {}}
    for test in tests.values():
        r = test.response
        write_response_csv(out / test.name / "response.csv", r.time, r.outputs, response_columns(test))
        entry: dict[str, Any] = {"speed_mps": test.speed, "mass_kg": test.mass, "metrics": test.metrics}
        if test.intervals:
            entry["intervals"] = {k: None if v is None else list(v) for k, v in test.intervals.items()}
            entry["extrapolation"] = test.extrapolation
        if test.notes:
            entry["notes"] = list(test.notes)
        summary["tests"][test.name] = entry
    write_json(out / "simulation.json", summary)
    return summary


def simulation_figure_jobs(case: Case, tests: dict[str, PredictedTest], out: Path) -> list[Job]:
    """A response figure per simulated test, with its data behind it and its 95 % band shaded,
    as crashnlp.plots jobs."""
    jobs: list[Job] = []
    for test in case.tests:
        predicted = tests[test.name]
        r = predicted.response
        model = {k: (r.time, r[k]) for k in MEASURABLE}
        bands = {k: (r.time, *band) for k, band in predicted.bands.items()}
        title = f"{case.name}: {test.name}"
        jobs.append(("response_figure", (out / test.name / "response.png", title, model, data_curves(test), bands)))
    return jobs
