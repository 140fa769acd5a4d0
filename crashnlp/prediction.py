"""Predictions: an identified vehicle simulated at new speeds, masses or durations, with 95 % intervals.

The intervals propagate three sources of error to every crash metric and response curve:

- the parameters: their covariance (the fit's sandwich, with the smoothness prior as the
  information it adds) pushed through the output's sensitivities, taken as central
  differences of the forward simulation over one standard error each way (one-sided at a
  bound), so a metric that bends within that span is not linearised at a point;
- the model's form: on the fitted tests, the model missed each metric of the data by some
  relative amount, root mean square over the tests, scaled to the predicted value; and the
  curve the metric is read from by its RMSE. The fit tunes the metrics it was fitted at (two
  peaks, two crushes), so their miss there understates the miss at another speed, where the
  metric falls on another part of the curve; the curve's RMSE is how far the model's form is
  from the data at any instant. Both are added in quadrature; each channel's band adds its RMSE;
- the force past the crush the model reached in the fitted tests, which no test measured: the
  identified loading curve follows its trend there (crashnlp.model.tail), and how well that
  rule predicts is measured on the identified curve itself, breakpoint by breakpoint inside
  the reach (`trend_misses`). That miss of the force, grown in proportion to the distance past
  the reach over the breakpoint spacing, moves the max crush (by the energy it adds or takes)
  and the peak deceleration (where the peak lies past the reach); and since the force there
  may rise above the peak predicted inside the reach, the peak's interval reaches up to what
  the tail's force may be, 95 %, at the deepest crush.

A metric or curve that no fitted test measured (pitch, without a pitch channel) gets no
interval, nor does anything when an estimated value is not determined by the data: the
prediction says so in `notes`, instead of a band that only looks narrow.

`write_simulation` writes what `crashnlp simulate` writes of the predicted tests, and
`simulation_figure_jobs` are their figures.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.case import Case, TestCase
from crashnlp.errors import InputError
from crashnlp.files import claim, run_name
from crashnlp.identified import INTERVAL_METRICS, Z95, IdentifiedModel, applied
from crashnlp.jsonfile import write_json
from crashnlp.model.tail import spacing, trend_misses
from crashnlp.outputs import COLUMNS, OUTPUT, PANELS, named_test
from crashnlp.problem import Problem
from crashnlp.response import Response, read_columns, response_of, write_response_csv
from crashnlp.result import Result
from crashnlp.summary import data_curves, response_metrics
from crashnlp.units import G0

if TYPE_CHECKING:
    from crashnlp.plots import Job  # not at run time: matplotlib

DRIFT = 0.05  # m/s toward the barrier at the end of a record, without contact: not a stop
# two-sided 95 % quantiles of Student's t for 1 to 30 degrees of freedom
T95 = (
    *(12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131),
    *(2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042),
)
# response columns and the fitted channel whose RMSE measures the model's miss of them
BAND_CHANNEL = {
    "displacement": "displacement",
    "velocity": "velocity",
    "accel": "accel",
    "pitch": "pitch",
    "crush": "displacement",
    "barrier_force": "barrier_force",
}


# the fitted channel each metric is read from (its report unit is the metric's)
METRIC_CHANNEL = {
    "max_crush_m": "displacement",
    "peak_decel_g": "accel",
    "rebound_velocity_mps": "velocity",
    "olc_g": "accel",
    "max_pitch_deg": "pitch",
}


@dataclass(frozen=True)
class PredictedTest(Mapping[str, np.ndarray]):
    """One simulated test: output key -> array in SI ("time_s", "crush_m", as crashnlp.outputs
    names them), its crash metrics, and with an identified model their 95 % intervals, the
    response bands (output name -> (low, high)) and how far it lies past the identified range.
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


def own_tests(result: Result, source: str) -> Problem:
    """The problem a result's own tests make, with its identified vehicle (crashnlp.identified):
    each test at its speed over its fitted window, at the identified vehicle's mass; what
    `crashnlp simulate RESULT_DIR/result.json` simulates. InputError for a result without an
    identified model."""
    if result.identified is None:
        raise InputError(
            f"{source}: identified_model: none (a design's or a hand-written result); give a problem file and --params"
        )
    tests = [{"name": name, "speed": t.speed, "duration": float(t.response.time[-1])} for name, t in result.tests.items()]
    return applied({"name": result.name, "tests": tests}, Path("."), result.identified, source, source)


def predict(case: Case, identified: IdentifiedModel | None = None, dt: float | None = None) -> dict[str, PredictedTest]:
    """Every test of `case` simulated (`case` built from a problem the identified model was
    applied to, crashnlp.identified.apply); with `identified`, intervals and extrapolation too.
    A test's data come with it only where it runs at the speed, mass and duration they were
    recorded at (TestCase.other_conditions); otherwise a note says which test and why."""
    out = {}
    for test in case.tests:
        p = case.test_parameters(test)
        response = case.simulate_test(test, p, dt)
        metrics = response_metrics(response)
        mass = float(p[case.layout.index("vehicle.mass")][0])
        other = test.other_conditions(mass)
        data = data_curves(test) if other is None else {}
        first = (other,) if other is not None else ()
        drift = _drift(test.name, response)
        if identified is None:
            out[test.name] = PredictedTest(test.name, test.speed, mass, response, metrics, notes=first + drift, data=data)
            continue
        intervals, bands, notes = _uncertainty(case, test, p, mass, response, metrics, identified, dt)
        beyond = identified.range.beyond(float(metrics["max_crush_m"] or 0.0), test.speed, mass)
        out[test.name] = PredictedTest(
            test.name, test.speed, mass, response, metrics, intervals, bands, beyond, first + drift + notes, data
        )
    return out


def _drift(name: str, response: Response) -> tuple[str, ...]:
    """A note when the vehicle ends its record still moving toward the barrier without touching
    it: the pendulum's pitch lifted its front end off, and its max crush is its travel at the end,
    not where it stopped."""
    velocity, contact = float(response["velocity"][-1]), float(response["contact_force"][-1])
    if velocity <= DRIFT or contact > 0:
        return ()
    return (
        f"{name}: the vehicle ends still moving toward the barrier at {velocity:.2f} m/s without contact (its pitch "
        "lifted the front end off): its max crush is its travel at the end of the record, not a stop",
    )


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
    past = past_the_reach(case, p, response, identified, mass)
    for i, key in enumerate(INTERVAL_METRICS):
        value, miss = metrics.get(key), identified.discrepancy.get(key)
        if value is None or not np.isfinite(value) or miss is None:
            intervals[key] = None
            why = "no fitted test measured it" if miss is None else "the simulated test does not reach it"
            notes.append(f"{test.name}: no interval for {key}: {why}")
            continue
        form = (miss * value) ** 2 + _curve_miss(identified, key) ** 2
        half = Z95 * np.sqrt(gm[:, i] @ cov @ gm[:, i] + form + past.std.get(key, 0.0) ** 2)
        high = max(value + half, past.peak_ceiling or 0.0) if key == "peak_decel_g" else value + half
        intervals[key] = (float(value - half), float(high))
    bands = {}
    for name, channel in BAND_CHANNEL.items():
        rmse = identified.channel_rmse.get(channel)
        if rmse is None:
            continue
        g = gy.get(name, np.zeros((len(std), response.time.size)))  # values x times
        half = Z95 * np.sqrt(np.einsum("it,ij,jt->t", g, cov, g) + rmse**2)
        bands[name] = (response[name] - half, response[name] + half)
    return intervals, bands, tuple(notes)


def _curve_miss(identified: IdentifiedModel, metric: str) -> float:
    """The fitted tests' RMSE of the channel `metric` is read from, in the metric's unit (0 when
    none is fitted)."""
    channel = METRIC_CHANNEL.get(metric)
    rmse = identified.channel_rmse.get(channel) if channel else None
    return 0.0 if rmse is None or channel is None else rmse * OUTPUT[channel].factor


@dataclass(frozen=True)
class PastTheReach:
    """What the force past the model's reach in the fitted tests adds to a prediction: one
    standard error of max crush (m) and peak deceleration (g), widened to Student's t for the few
    misses it is measured from, and the deceleration (g) the tail's force may reach at the
    deepest crush, 95 % (a faster impact's peak may lie there though the predicted one lies
    inside the reach)."""

    std: dict[str, float] = field(default_factory=dict)
    peak_ceiling: float | None = None


def past_the_reach(case: Case, p: np.ndarray, response: Response, identified: IdentifiedModel, mass: float) -> PastTheReach:
    """The force past the reach is the trend rule's guess: its miss per breakpoint spacing
    (crashnlp.model.tail.trend_misses), times the distance d past the reach, is the force's
    standard error there; the crush moves by the energy that error adds over d, the peak by the
    error where the peak lies. Nothing inside the reach."""
    crush, reach = response["crush"], identified.range.model_crush
    deepest = float(np.max(crush))
    beyond = deepest - reach
    if beyond <= 0:
        return PastTheReach()
    curve = case.loading_curve(p)
    breakpoints = np.asarray(identified.model["spring"]["crush_breakpoints"], float)
    misses = trend_misses(curve, breakpoints, reach)
    if misses.size == 0:
        return PastTheReach()
    quantile = student_t95(misses.size)  # a root mean square of few misses: Student's t, not the normal's 1.96
    rate = float(np.sqrt(np.mean(misses**2))) * quantile / Z95 / spacing(breakpoints)  # N of force error per m past the reach
    at_deepest = max(float(curve(np.array([deepest]))[0]), 1.0)
    std = {"max_crush_m": rate * beyond**2 / 2 / at_deepest}
    peak = int(np.argmax(-response["accel"]))
    if crush[peak] > reach:
        std["peak_decel_g"] = rate * (crush[peak] - reach) / mass / G0
    return PastTheReach(std, (at_deepest + Z95 * rate * beyond) / mass / G0)


def student_t95(dof: int) -> float:
    """The two-sided 95 % quantile of Student's t with `dof` degrees of freedom (the normal's past 30)."""
    return T95[dof - 1] if dof <= len(T95) else Z95


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
    simulated test, and simulation.json, into a folder that then holds this simulation only
    (crashnlp.files.claim); the figures are `simulation_figure_jobs`, drawn by the caller
    (crashnlp.drawing)."""
    summary: dict[str, Any] = {"name": name, "tests": {}}
    with claim(out, run_name("simulate", name), option=None):
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


def read_simulation(folder: Path) -> tuple[str, dict[str, PredictedTest]]:
    """The name and the predicted tests `write_simulation` wrote into `folder`, back in SI: the
    responses and bands from each response.csv, the rest from simulation.json."""
    raw = json.loads((folder / "simulation.json").read_text(encoding="utf-8"))
    tests = {}
    for name, entry in raw["tests"].items():
        columns = read_columns(folder / name / "response.csv")
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
            response_of(columns),
            entry["metrics"],
            intervals,
            bands,
            dict(entry.get("extrapolation", {})),
            tuple(entry.get("notes", ())),
        )
    return str(raw["name"]), tests


def simulation_figure_jobs(name: str, tests: dict[str, PredictedTest], out: Path) -> list[Job]:
    """A response figure per simulated test, with its data behind it where it runs at their
    conditions (PredictedTest.data) and its 95 % band shaded, as crashnlp.plots jobs."""
    jobs: list[Job] = []
    for predicted in tests.values():
        r = predicted.response
        model = {k: (r.time, r[k]) for k in PANELS}
        bands = {k: (r.time, *band) for k, band in predicted.bands.items()}
        at = f"predicted at {predicted.speed * 3.6:.1f} km/h, {predicted.mass:.0f} kg" + (", 95 % band" if bands else "")
        title = f"{named_test(name, predicted.name)}: {at}"
        jobs.append(("response_figure", (out / predicted.name / "response.png", title, model, predicted.data, bands)))
    return jobs


def extrapolation_line(beyond: dict[str, float]) -> str:
    """How far a prediction lies past the identified range (`PredictedTest.extrapolation`), in words."""
    parts = []
    if "crush_m" in beyond:
        parts.append(f"max crush {beyond['crush_m'] * 1e3:.0f} mm ({beyond['crush_rel'] * 100:.0f} %) past the largest fitted")
    if "speed_mps" in beyond:
        side = "above the fastest" if beyond["speed_mps"] > 0 else "below the slowest"
        parts.append(f"speed {abs(beyond['speed_mps']) * 3.6:.1f} km/h {side} fitted test")
    if "mass_kg" in beyond:
        side = "above the heaviest" if beyond["mass_kg"] > 0 else "below the lightest"
        parts.append(f"mass {abs(beyond['mass_kg']):.0f} kg {side} fitted test")
    return "extrapolates: " + "; ".join(parts)
