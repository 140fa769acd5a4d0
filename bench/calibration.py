"""Held-out predictions: the calibration of the intervals' form term, and the benchmark of the intervals.

`make calibrate` (bench/calibrate.py) writes crashnlp/analysis/calibration.json and the bench section
`intervals` from its records; `make bench` runs the section too.

Each vehicle comes from bench/corpus.py in one of five generator forms (FORMS), none of them
crashnlp's pendulum: a rigid body (random_vehicle), that body with an engine on mounts that meets
the barrier late (engine_vehicle), vans and tall SUVs (tall_vehicle), those with an engine on
mounts (tall_engine_vehicle), and the rigid body with a structure whose force grows with the crush
rate (rate_vehicle); each is built for 56, 64 or 72 km/h in turn. It is fitted from minimal
problem files, as a user would, at 56 km/h alone, at 40 + 56 and at 40 + 64 km/h, and each fit
predicts the speeds it was not fitted at, and the 56 km/h fit the same vehicle heavier and
lighter (SCENARIOS, MASS_RATIOS). A prediction's interval parts
(crashnlp.results.simulation.IntervalParts), its fit's range and the generator's noise-free metrics make
one record. The corpus of one seed (SET_SEED) sets the calibration: per metric the power of the
distance (power), then per class of prediction and metric the split-conformal quantile (LEVEL)
of the records' scores, its rank from the number of vehicles, or where larger the share LEVEL of any
one generator form's scores (a vehicle's form is not known when it is predicted); the corpus of
another (CHECK_SEED), whose records set no q, checks it: coverage, median half-width and accuracy
per scenario and metric, and per form; and so does a population of a form no table or rule was
set on (HIDDEN, HIDDEN_SEED: tall vans with an engine on mounts and a rate-sensitive structure,
three mechanisms no vehicle of the corpus has together). The tall vans with
an engine on mounts were that population up to version 9, and helped choose between candidate
rules for version 8 (docs/design-notes.md); since version 10 they are a form of the corpus. The records hold what a model form's fits and predictions give: each model form
(MODEL_FORMS) is fitted to the same vehicles and gets its own table, set and checked the same way
(`make calibrate`, bench/calibrate.py, whose `--forms FORM ...` makes the named forms' tables only:
the other forms' tables, held-out records and parts of the bench section stay as they were).
"""

from __future__ import annotations

import gzip
import json
import math
import re
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import binom

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import crashnlp  # noqa: E402
from bench.common import ROOT  # noqa: E402
from bench.corpus import (  # noqa: E402
    Vehicle,
    engine_vehicle,
    random_vehicle,
    rate_tall_engine_vehicle,
    rate_vehicle,
    tall_engine_vehicle,
    tall_vehicle,
)
from bench.cross_speed import fit_problem, prediction_problem, truth_metrics  # noqa: E402
from crashnlp.analysis.calibration import (  # noqa: E402
    IMPACT_SPEED,
    PITCH_FLOOR,
    Calibration,
    conformal_quantile,
    form_unit,
    reach,
    share_quantile,
    shipped,
)
from crashnlp.analysis.prediction import predict  # noqa: E402
from crashnlp.base.outputs import PREDICTED_KEYS  # noqa: E402
from crashnlp.case.case import case_of  # noqa: E402
from crashnlp.problem.forms import DEFAULT_FORM  # noqa: E402
from crashnlp.results.identified import IdentifiedRange, apply  # noqa: E402
from crashnlp.results.simulation import IntervalParts, PredictedTest  # noqa: E402

VERSION = 13
# the conformal level: 95 % intervals; the rank counts vehicles, not predictions (one vehicle's two
# predictions of a class, 56 -> 64 and 40 + 56 -> 64, miss alike): docs/design-notes.md
LEVEL = 0.95
BOOTSTRAP = 2000  # whole-vehicle resamples of a pooled coverage's range (`pooled`)
POWER_STEP, POWER_RANGE = 0.05, (0.25, 1.5)  # the power of the distance in the form term's unit (power)
# the rebound's floors tried (shares of the impact speed; IMPACT_SPEED: the impact speed itself, the rule before version 11)
REBOUND_FLOORS = (0.02, 0.05, 0.1, 0.2, IMPACT_SPEED)
SET_SEED, CHECK_SEED, HIDDEN_SEED = 3100, 3200, 3300
BUILT_KMH = (56.0, 64.0, 72.0)  # the speed vehicle i's structure is built for: BUILT_KMH[i % 3]
# the corpus's forms: a rigid body, one with an engine on mounts, vans and tall SUVs, rigid bodies of
# 2600-3200 kg whose CG sits 0.30-0.45 m above the impact point (the others': 0.04-0.26 m), which pitch more,
# those vans with an engine on mounts, and rigid bodies whose structure's force grows with the crush rate
FORMS: dict[str, Callable[..., Vehicle]] = {
    "rigid body": random_vehicle,
    "engine on mounts": engine_vehicle,
    "tall vans and SUVs": tall_vehicle,
    "tall vans with an engine on mounts": tall_engine_vehicle,
    "rate-sensitive structures": rate_vehicle,
}
# a population of a form the calibration never saw: tall vans with an engine on mounts and a rate-sensitive structure
HIDDEN: dict[str, Callable[..., Vehicle]] = {"rate-sensitive tall vans with an engine on mounts": rate_tall_engine_vehicle}
# seed -> (forms, vehicles of each form)
POPULATIONS: dict[int, tuple[dict[str, Callable[..., Vehicle]], dict[str, int]]] = {
    SET_SEED: (FORMS, dict(zip(FORMS, (20, 20, 8, 8, 10)))),
    CHECK_SEED: (FORMS, dict(zip(FORMS, (12, 12, 8, 8, 8)))),
    HIDDEN_SEED: (HIDDEN, {"rate-sensitive tall vans with an engine on mounts": 10}),
}
# model form -> seed -> vehicles of each generator form its table is set and checked on (None: POPULATIONS');
# each form's fits make its own table (crashnlp.analysis.calibration.shipped)
MODEL_FORMS: dict[str, dict[int, dict[str, int]] | None] = {
    DEFAULT_FORM: None,
    "rigid-body": None,
    "engine-on-mounts": None,
}
CHECK_RECORDS = ROOT / "tests" / "data" / "calibration-held-out.json.gz"  # written by make calibrate
LABELS = {SET_SEED: "set seed", CHECK_SEED: "check seed (unseen)", HIDDEN_SEED: "hidden population (unseen form)"}
# scenario -> (fitted speeds, predicted speed), km/h
SCENARIOS: dict[str, tuple[tuple[float, ...], float]] = {
    "one test down, 56 -> 40": ((56.0,), 40.0),
    "one test down, 56 -> 48": ((56.0,), 48.0),
    "one test up, 56 -> 64": ((56.0,), 64.0),
    "interpolation, 40 + 56 -> 48": ((40.0, 56.0), 48.0),
    "interpolation, 40 + 64 -> 56": ((40.0, 64.0), 56.0),
    "extrapolation, 40 + 56 -> 64": ((40.0, 56.0), 64.0),
    "one test, mass +20 %, 56 -> 56": ((56.0,), 56.0),
    "one test, mass -15 %, 56 -> 56": ((56.0,), 56.0),
}
# scenario -> the predicted test's mass over the fitted tests' (payload or ballast at the CG: with_payload)
MASS_RATIOS = {"one test, mass +20 %, 56 -> 56": 1.2, "one test, mass -15 %, 56 -> 56": 0.85}
# issue 38's acceptance: coverage per metric; median half-width (relative) per scenario kind and metric
TARGETS = {
    "coverage": {"max_displacement_m": 0.9, "peak_decel_g": 0.9, "time_zero_velocity_s": 0.9},
    "coverage_other": 0.85,
    "half_width": {
        "one test down": {"max_displacement_m": 0.03, "peak_decel_g": 0.15},
        "interpolation": {"max_displacement_m": 0.03, "peak_decel_g": 0.15},
        "extrapolation": {"peak_decel_g": 0.30},
    },
}
SHARPNESS = {metric for widths in TARGETS["half_width"].values() for metric in widths}  # the metrics with a width line
METHOD = (
    f"split-conformal: per class of prediction and metric, the ceil((n + 1) {LEVEL})-th smallest score of n held-out "
    "predictions (the rank's n the class's vehicles, its quantile over their predictions), or where larger the "
    f"ceil(n {LEVEL})-th smallest of the n predictions of any one generator form, a score the smallest q "
    "whose interval covers the generator's value; q scales the form term (the metric's scale times the distance to "
    "a power, the slope of the log root mean square miss against the log distance within the classes; the "
    "rebound's scale at least the floor share of the impact speed whose intervals on the corpus are narrowest) and "
    "the force past the reach"
)


def vehicles(seed: int, counts: dict[str, int], forms: dict[str, Callable[..., Vehicle]] = FORMS) -> list[tuple[str, Vehicle]]:
    """`counts[form]` vehicles of each form, the same for the same seed."""
    return [(form, make(i, seed, speed=BUILT_KMH[i % 3] / 3.6)) for form, make in forms.items() for i in range(counts[form])]


def held_out(
    form: str,
    v: Vehicle,
    folder: Path,
    transcription: dict | None = None,
    scenarios: tuple[str, ...] = tuple(SCENARIOS),
    model_form: str = DEFAULT_FORM,
) -> list[dict]:
    """One record per scenario (of `scenarios`): each fit once (minimal problem of `model_form`, with
    `transcription`, and IPOPT's options as a user's file leaves them), each of its predictions'
    interval parts, class and the fit's own tests, and the generator's metrics as a record of the
    predicted test holds them (a failed fit's too)."""
    out = []
    for fitted in dict.fromkeys(SCENARIOS[s][0] for s in scenarios):
        path = with_form(fit_problem(v, fitted, folder, transcription), model_form)
        result = crashnlp.identify(path)
        for scenario in scenarios:
            speeds, target = SCENARIOS[scenario]
            if speeds != fitted:
                continue
            ratio = MASS_RATIOS.get(scenario, 1.0)
            row = {"vehicle": v.name, "form": form, "scenario": scenario, "status": result.status}
            row["truth"] = truth_metrics(with_payload(v, ratio), target, as_a_test_gives=True)
            if result.ok:
                problem = prediction_problem(path, target, folder, v.mass * ratio if ratio != 1.0 else None)
                predicted = prediction(problem, result, model_form)[f"{target:.0f}kph"]
                klass, distance = reach(result.identified.range, predicted.speed, predicted.mass)
                row |= {
                    "class": klass,
                    "distance": distance,
                    "speed_mps": predicted.speed,
                    "mass_kg": predicted.mass,
                    "extrapolation": predicted.extrapolation,
                    "parts": {k: p.to_json() for k, p in predicted.parts.items()},
                    "fit": _fit_record(result),
                }
            out.append(row)
    return out


def prediction(problem: crashnlp.Problem, result: crashnlp.Result, model_form: str) -> dict[str, PredictedTest]:
    """`crashnlp.simulate(problem, params=result)`, the intervals' parts of a model form without a
    table of its own made with the default form's: a record keeps of the table only the form
    term's unit, which `_parts` makes again with the power being calibrated, so a form's first
    table is made from its own fits as its next ones are."""
    case = case_of(apply(problem, result.identified, problem.name))
    return predict(case, result.identified, calibration=shipped(model_form) or shipped())


def with_form(path: Path, model_form: str) -> Path:
    """The problem file at `path` with `model.form: model_form` (the default form's file as it is)."""
    if model_form != DEFAULT_FORM:
        raw = yaml.safe_load(path.read_text())
        raw["model"]["form"] = model_form
        path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def _fit_record(result: crashnlp.Result) -> dict:
    """What a record keeps of its fit: the range, the model's miss on the fitted tests (per metric,
    and per channel the root mean square over the curve), and each fitted test's metrics, model's
    and data's."""
    ident = result.identified
    return {
        "range": ident.range.to_json(),
        "discrepancy": ident.discrepancy,
        "channel_rmse": ident.channel_rmse,
        "tests": {name: {"model": t.metrics, "data": t.data_metrics} for name, t in result.tests.items()},
    }


def with_payload(v: Vehicle, ratio: float) -> Vehicle:
    """The vehicle with its mass times `ratio`, the change carried at the CG (payload or ballast):
    its pitch inertia in proportion, its structure, suspension and engine as they were."""
    if ratio == 1.0:
        return v
    return replace(v, mass=v.mass * ratio, pitch_inertia=v.pitch_inertia * ratio)


def collect(
    seed: int,
    counts: dict[str, int],
    forms: dict[str, Callable[..., Vehicle]] = FORMS,
    transcription: dict | None = None,
    cache: Path | None = None,
    model_form: str = DEFAULT_FORM,
) -> list[dict]:
    """Every scenario's record for every vehicle of `seed`, fitted in `model_form`; with `cache`, a
    vehicle's records are read from (and written to) a file there, so that a rerun refits none."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="crashnlp-calibration-") as tmp:
        for form, v in vehicles(seed, counts, forms):
            fitted_as = "" if model_form == DEFAULT_FORM else f"{model_form}-"
            stem = re.sub(r"\W+", "-", f"{fitted_as}{seed}-{form}-{v.name}")
            stored = cache / f"{stem}.json" if cache is not None else None
            kept = json.loads(stored.read_text()) if stored is not None and stored.exists() else []
            if kept and all("truth" in row for row in kept):  # a record made before every row had its truth is made again
                rows += kept
                continue
            folder = Path(tmp) / stem
            folder.mkdir()
            mine = held_out(form, v, folder, transcription, model_form=model_form)
            if stored is not None:
                stored.write_text(json.dumps(mine))
            rows += mine
            print(f"  {model_form} seed {seed} {form} {v.name}: {', '.join(r['status'] for r in mine)}", flush=True)
    return rows


def _parts(row: dict, metric: str, power: float = 1.0, floor: float = IMPACT_SPEED) -> IntervalParts | None:
    """A record's interval parts of `metric`, its form term's unit the metric's scale (the rebound's
    with `floor`) times the distance to `power`."""
    raw = row.get("parts", {}).get(metric)
    if raw is None:
        return None
    unit = form_unit(metric, raw["value"], row["speed_mps"], row["distance"], power, floor)
    return IntervalParts(raw["value"], raw["parameters"], raw["fitted"], raw["past_the_reach"], unit)


def klass(row: dict) -> str:
    """A record's class, from its fit's range as crashnlp.analysis.calibration.reach finds it now."""
    return reach(IdentifiedRange.from_json(row["fit"]["range"]), row["speed_mps"], row["mass_kg"])[0]


def _scored(
    rows: list[dict], metric: str, power: float = 1.0, floor: float = IMPACT_SPEED
) -> list[tuple[dict, IntervalParts, float]]:
    """The records that go somewhere (a distance above zero) whose prediction and generator both
    have `metric`, with its parts (`_parts`) and its truth."""
    out = []
    for row in rows:
        parts, truth = _parts(row, metric, power, floor), row["truth"][metric]
        if parts is not None and np.isfinite(truth) and row["distance"] > 0:
            out.append((row, parts, truth))
    return out


def power(rows: list[dict], metric: str, floor: float = IMPACT_SPEED) -> float:
    """How the miss of `metric` grows with the distance: within each class, the root mean square
    of the relative miss (|miss| / scale) of each distance the class's records go to; the slope of
    its logarithm against the distance's, each class about its own mean (least squares, weighted
    by the records), to POWER_STEP within POWER_RANGE (1 where no class goes to two distances)."""
    groups: dict[tuple[str, float], list[float]] = {}
    for row, parts, truth in _scored(rows, metric, floor=floor):
        groups.setdefault((klass(row), round(row["distance"], 3)), []).append(
            abs(truth - parts.value) / (parts.unit / row["distance"])
        )
    by: dict[str, list[tuple[float, float, int]]] = {}
    for (k, distance), misses in groups.items():
        rms = math.sqrt(np.mean(np.square(misses)))
        if rms > 0:
            by.setdefault(k, []).append((math.log(distance), math.log(rms), len(misses)))
    spread = [_about_mean(points) for points in by.values() if len(points) > 1]
    if not spread:
        return 1.0
    x, y, w = (np.concatenate(c) for c in zip(*spread))
    slope = float(np.sum(w * x * y) / np.sum(w * x * x))
    return float(np.clip(round(slope / POWER_STEP) * POWER_STEP, *POWER_RANGE))


def _about_mean(points: list[tuple[float, float, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x and y about their weighted means, and the weights."""
    x, y, w = (np.array(c, float) for c in zip(*points))
    return x - np.average(x, weights=w), y - np.average(y, weights=w), w


def _table(rows: list[dict], metric: str, grown: float, floor: float = IMPACT_SPEED) -> dict[str, tuple[float, int]]:
    """q per class of one metric, and the records it came from: the conformal quantile of the
    class's scores, its rank from the number of vehicles (crashnlp.analysis.calibration.conformal_quantile),
    or, where larger, one generator form's own share (_form_quantile): a pooled quantile covers the
    mix of forms, and a form whose misses are larger than the mix's less."""
    scores: dict[str, list[float]] = {}
    by_form: dict[str, dict[str, list[float]]] = {}
    units: dict[str, set[tuple[str, str]]] = {}
    for row, parts, truth in _scored(rows, metric, grown, floor):
        score, k = parts.score(truth), klass(row)
        scores.setdefault(k, []).append(score)
        by_form.setdefault(k, {}).setdefault(row["form"], []).append(score)
        units.setdefault(k, set()).add((row["form"], row["vehicle"]))
    return {
        k: (max(conformal_quantile(s, LEVEL, len(units[k])), *map(_form_quantile, by_form[k].values())), len(s))
        for k, s in scores.items()
    }


def _form_quantile(scores: list[float]) -> float:
    """The smallest score that at least LEVEL of one generator form's predictions do not exceed (the
    ceil(n LEVEL)-th smallest of n): the form's own coverage on the corpus, without the finite-sample
    rank, which would be its largest score (20 vehicles: ceil(21 * 0.95) = 20) and let one vehicle's
    miss set a class's width (docs/design-notes.md, "Made again (version 8)")."""
    return share_quantile(scores, LEVEL)


def calibrate(rows: list[dict], seed: int, model_form: str = DEFAULT_FORM) -> Calibration:
    """The calibration of `model_form` from its records of one seed: the rebound's floor
    (`rebound_floor`), per metric the power of the distance (power), then q per class (_table)."""
    floor = rebound_floor(rows)
    grown = {m: power(rows, m, floor) for m in PREDICTED_KEYS}
    per_metric = {m: _table(rows, m, grown[m], floor) for m in PREDICTED_KEYS}
    classes = sorted({k for t in per_metric.values() for k in t})
    table = {k: {m: per_metric[m][k][0] for m in PREDICTED_KEYS if k in per_metric[m]} for k in classes}
    corpus = {
        "seed": seed,
        "vehicles": {
            form: len({r["vehicle"] for r in rows if r["form"] == form}) for form in dict.fromkeys(r["form"] for r in rows)
        },
        "forms": {form: make.__name__ for form, make in FORMS.items()},
        "built_kmh": list(BUILT_KMH),
        "scenarios": {
            name: {"fitted_kmh": list(f), "predicted_kmh": t, "mass_ratio": MASS_RATIOS.get(name, 1.0)}
            for name, (f, t) in SCENARIOS.items()
        },
        "records": {k: {m: per_metric[m][k][1] for m in PREDICTED_KEYS if k in per_metric[m]} for k in classes},
    }
    return Calibration(model_form, VERSION, METHOD, LEVEL, corpus, table, grown, floor)


def rebound_floor(rows: list[dict]) -> float:
    """Of REBOUND_FLOORS, the one whose rebound intervals, set on `rows` (power, _table), are the
    narrowest on them: the median half-width in m/s, every floor's coverage being the conformal one."""
    return min(REBOUND_FLOORS, key=lambda floor: _rebound_half_width(rows, floor))


def _rebound_half_width(rows: list[dict], floor: float) -> float:
    """The median rebound half-width (m/s) of the records' intervals, the table set on them with `floor`."""
    metric = "rebound_velocity_mps"
    grown = power(rows, metric, floor)
    table = _table(rows, metric, grown, floor)
    halves = []
    for row, parts, _ in _scored(rows, metric, grown, floor):
        low, high = parts.interval(table[klass(row)][0])
        halves.append((high - low) / 2)
    return float(np.median(halves)) if halves else math.inf


def judged(row: dict, metric: str, calibration: Calibration) -> dict | None:
    """One prediction's metric against the generator: covered, and the half-width and the error
    relative to the metric's scale (crashnlp.analysis.calibration.scale: the rebound's is at least a
    share of the impact speed, so that a rebound of zero has an error too); None where the fit
    failed or the prediction has no value."""
    if "parts" not in row:
        return None
    parts = _parts(row, metric, calibration.power[metric], calibration.rebound_floor)
    truth = row["truth"][metric]
    q = calibration.q(klass(row), metric) if row["distance"] > 0 else 0.0
    if parts is None or not np.isfinite(truth) or q is None or not np.isfinite(q):
        return None
    low, high = parts.interval(q)
    per = calibration.scale(metric, parts.value, row["speed_mps"])
    return {
        "covered": bool(low <= truth <= high),
        "half_rel": (high - low) / 2 / per if per else float("inf"),
        "error_rel": (parts.value - truth) / per if per else float("inf"),
    }


def evaluate(rows: list[dict], calibration: Calibration) -> dict:
    """Per scenario and metric: predictions, coverage, median half-width, median and largest error
    (relative); a failed fit or a prediction without a value or an interval counts as not covered,
    a prediction whose generator's record does not hold the metric (NaN: no stop, or a record that
    ends still moving withholds it, crashnlp.analysis.summary.withheld) not at all.
    `coverage_given` is the coverage of the predictions that have an interval: the calibration's
    part, without the fits' failures. `one_width` is the narrowest half-width, one relative width
    for every prediction of the scenario, that would hold the generator's value as often as issue
    38's coverage line asks (`needed`), and `one_width_level` as often as LEVEL (a failed fit, or
    a prediction without a value or an interval, is held by none), for the metrics with a sharpness
    line in some scenario (SHARPNESS), in every scenario: what an interval's median half-width
    cannot go below without knowing which predictions miss most."""
    out: dict = {}
    for scenario in SCENARIOS:
        out[scenario] = {}
        for metric in PREDICTED_KEYS:
            mine = [r for r in rows if r["scenario"] == scenario and np.isfinite(r["truth"][metric])]
            got = [judged(r, metric, calibration) for r in mine]
            seen = [g for g in got if g is not None]
            misses = [abs(g["error_rel"]) if g is not None else math.inf for g in got]
            out[scenario][metric] = {
                "n": len(mine),
                "coverage": sum(g["covered"] for g in seen) / len(mine) if mine else float("nan"),
                "coverage_given": sum(g["covered"] for g in seen) / len(seen) if seen else float("nan"),
                "half_width_median": float(np.median([g["half_rel"] for g in seen])) if seen else float("nan"),
                "error_median": float(np.median([abs(g["error_rel"]) for g in seen])) if seen else float("nan"),
                "error_max": float(np.max([abs(g["error_rel"]) for g in seen])) if seen else float("nan"),
            }
            if mine and metric in SHARPNESS:
                out[scenario][metric] |= {
                    "one_width": share_quantile(misses, needed(metric)),
                    "one_width_level": share_quantile(misses, LEVEL),
                }
    return out


def by_chance(evaluation: dict) -> dict:
    """A population's coverage lines read as counts (`evaluate`'s cells): how many fall below their
    line, and how many an interval that holds LEVEL of the time would leave below theirs by chance
    (the sum over the cells of the binomial chance of fewer covered than the line needs: each
    vehicle gives a cell one prediction, so a cell's are independent draws)."""
    below = expected = 0.0
    lines = 0
    for by in evaluation.values():
        for metric, e in by.items():
            n = e["n"]
            if not n:
                continue
            need = math.ceil(needed(metric) * n - 1e-9)
            lines += 1
            below += round(e["coverage"] * n) < need
            expected += float(binom.cdf(need - 1, n, LEVEL))
    return {"lines": lines, "below": int(below), "expected_below": expected}


def pooled(rows: list[dict], calibration: Calibration) -> dict:
    """Per metric, every scenario's predictions together (`shares` of `vehicle_counts`)."""
    return {metric: shares(per) for metric in PREDICTED_KEYS if (per := vehicle_counts(rows, metric, calibration))}


def vehicle_counts(rows: list[dict], metric: str, calibration: Calibration | None) -> dict[tuple[str, str], list[int]]:
    """Per vehicle (generator form, name), of its predictions whose generator's record holds
    `metric`: how many the interval covers, how many there are, and how many have an interval
    (none without a `calibration`: a vehicle no form's fit gave a result for)."""
    per: dict[tuple[str, str], list[int]] = {}
    for row in rows:
        if np.isfinite(row["truth"][metric]):
            got = judged(row, metric, calibration) if calibration is not None else None
            counts = per.setdefault((row["form"], row["vehicle"]), [0, 0, 0])
            counts[0] += bool(got and got["covered"])
            counts[1] += 1
            counts[2] += got is not None
    return per


def shares(per: dict[tuple[str, str], list[int]]) -> dict:
    """How many predictions the intervals cover, of those the generator's record holds the metric
    for (n) and of those with an interval (given), and the 95 % range of the covered share from
    resampling whole vehicles (BOOTSTRAP draws, a fixed seed): a vehicle's predictions miss alike,
    so they are not independent draws."""
    vehicles = np.array(list(per.values()))  # covered, n, given
    low, high = vehicle_range(vehicles[:, :2])
    covered, n, given = (int(x) for x in vehicles.sum(axis=0))
    return {"covered": covered, "n": n, "given": given, "low": low, "high": high}


def vehicle_range(vehicles: np.ndarray) -> tuple[float, float]:
    """The 95 % range of the covered share of predictions, each row one vehicle's (covered, n),
    from BOOTSTRAP resamples of whole vehicles with a fixed seed."""
    draws = vehicles[np.random.default_rng(0).integers(0, len(vehicles), (BOOTSTRAP, len(vehicles)))].sum(axis=1)
    low, high = np.quantile(draws[:, 0] / draws[:, 1], [0.025, 0.975])
    return float(low), float(high)


def _chance_line(evaluation: dict, shares: dict | None) -> str:
    """`by_chance` and `pooled` (`shares`, none in a section made before it) in a sentence under a
    population's table."""
    c = by_chance(evaluation)
    line = (
        f"Cells below their coverage line: {c['below']} of {c['lines']}; an interval that holds {100 * LEVEL:.0f} % of the "
        f"time leaves {c['expected_below']:.1f} below by chance, on cells of these sizes."
    )
    if not shares:
        return line
    pooled_shares = "; ".join(f"{SHORT[m]} {share_text(e)}" for m, e in shares.items())
    return (
        f"{line} Covered over every scenario: {pooled_shares} (in brackets the share's 95 % range, whole vehicles "
        "resampled, and where some predictions have no interval, a failed fit or no value, the share of those that have one)."
    )


def share_text(e: dict) -> str:
    """A `shares` entry as text: the covered share, and in brackets its range over whole vehicles
    and, where some predictions have no interval, how many of those with one it covers."""
    given = f"; {e['covered']} of the {e['given']} with an interval" if e["given"] < e["n"] else ""
    return f"{100 * e['covered'] / e['n']:.0f} % ({100 * e['low']:.0f} to {100 * e['high']:.0f} %{given})"


def needed(metric: str) -> float:
    """Issue 38's coverage line of `metric`."""
    return TARGETS["coverage"].get(metric, TARGETS["coverage_other"])


def run(quick: bool = False) -> dict:
    """The bench section from records of every population of every model form (two vehicles per
    generator form with --quick)."""
    return sections({form: records(form, 2 if quick else None) for form in MODEL_FORMS})


def records(model_form: str = DEFAULT_FORM, count: int | None = None, cache: Path | None = None) -> dict[int, list[dict]]:
    """Every population's records of `model_form`'s fits (`count` vehicles of each generator form,
    or MODEL_FORMS' numbers, or POPULATIONS'), each vehicle's kept in `cache` if given (collect)."""
    chosen = MODEL_FORMS[model_form] or {}
    return {
        seed: collect(
            seed,
            {form: count or n for form, n in chosen.get(seed, counts).items()},
            forms,
            cache=cache,
            model_form=model_form,
        )
        for seed, (forms, counts) in POPULATIONS.items()
    }


def compact(rows: list[dict]) -> list[dict]:
    """What judging a record needs (judged), its numbers to 7 significant digits: the held-out
    records tests/test_calibration.py checks the shipped table on."""

    def short(value):
        if isinstance(value, dict):
            return {k: short(v) for k, v in value.items()}
        if isinstance(value, list):
            return [short(v) for v in value]
        return float(f"{value:.7g}") if isinstance(value, float) and math.isfinite(value) else value

    keep = ("vehicle", "form", "scenario", "status", "speed_mps", "mass_kg", "distance", "parts", "truth")
    return [
        short({k: r[k] for k in keep if k in r} | ({"fit": {"range": r["fit"]["range"]}} if "fit" in r else {})) for r in rows
    ]


def held_out_records() -> dict[str, dict[str, list[dict]]]:
    """Per model form, the check seed's and the hidden population's records as make calibrate left
    them (CHECK_RECORDS)."""
    return json.loads(gzip.decompress(CHECK_RECORDS.read_bytes()))


def sections(by_form: dict[str, dict[int, list[dict]]]) -> dict:
    """The bench section: the default form's (section), and every other form's under "forms"."""
    return merged({}, {form: section(rows, form) for form, rows in by_form.items()})


def section(records: dict[int, list[dict]], model_form: str = DEFAULT_FORM) -> dict:
    """`model_form`'s table set on SET_SEED's records (and whether it is the shipped one), evaluated
    on every population's records, over all and per generator form."""
    calibration = calibrate(records[SET_SEED], SET_SEED, model_form)
    return {
        "model_form": model_form,
        "calibration": calibration.to_json(),
        "shipped": (table := shipped(model_form)) is not None and calibration.to_json() == table.to_json(),
        "set_seed": SET_SEED,
        "check_seed": CHECK_SEED,
        "hidden_seed": HIDDEN_SEED,
        "vehicles": {str(seed): len({(r["form"], r["vehicle"]) for r in rows}) for seed, rows in records.items()},
        "targets": TARGETS,
        "evaluation": _by_group(records, lambda rows: evaluate(rows, calibration)),
        "pooled": _by_group(records, lambda rows: pooled(rows, calibration)),
    }


def _by_group(records: dict[int, list[dict]], read: Callable[[list[dict]], dict]) -> dict:
    """`read` of every population's records (seed -> rows), over all and per generator form."""
    return {
        str(seed): {
            "all": read(rows),
            **{form: read([r for r in rows if r["form"] == form]) for form in dict.fromkeys(r["form"] for r in rows)},
        }
        for seed, rows in records.items()
    }


def scenario_kind(scenario: str) -> str:
    return scenario.split(",")[0]


def targets(section: dict | None) -> list[tuple[str, str, bool | None]]:
    """Issue 38's acceptance, for every model form's table: coverage per scenario and metric on
    the check seed and the hidden population, median half-widths on the check seed."""
    if not section:
        return []
    return [row for s in (section, *section.get("forms", {}).values()) for row in _form_targets(s)]


def _form_targets(section: dict) -> list[tuple[str, str, bool | None]]:
    form = section.get("model_form", DEFAULT_FORM)
    rows = []
    for seed in (CHECK_SEED, HIDDEN_SEED):
        for scenario, by in section["evaluation"].get(str(seed), {}).get("all", {}).items():
            for metric, e in by.items():
                rows += _coverage_target(f"{form}: {LABELS[seed]}, {scenario}, {metric}", metric, e)
                width = TARGETS["half_width"].get(scenario_kind(scenario), {}).get(metric)
                if width is not None and seed == CHECK_SEED:
                    rows.append(
                        (
                            f"intervals {form}: {scenario}, {metric}: median half-width <= {width:.0%}",
                            f"{e['half_width_median']:.1%} (one width for all holds {needed(metric):.0%} at "
                            f"{e['one_width']:.1%}, {LEVEL:.0%} at {e['one_width_level']:.1%})",
                            e["half_width_median"] <= width,
                        )
                    )
    return rows


def _coverage_target(what: str, metric: str, e: dict) -> list[tuple[str, str, bool | None]]:
    need = needed(metric)
    return [(f"intervals {what}: cover >= {need:.0%}", f"{e['coverage']:.0%} of {e['n']}", e["coverage"] >= need)]


SHORT = {
    "max_displacement_m": "displacement",
    "time_zero_velocity_s": "stop",
    "peak_decel_g": "peak",
    "rebound_velocity_mps": "rebound",
    "olc_g": "OLC",
    "max_pitch_deg": "max pitch",
}


def _evaluation_table(evaluation: dict) -> list[str]:
    """Per scenario and metric: covered (of those with an interval, where a fit failed or gave none),
    median half-width, median and largest error."""
    head = ["scenario", *(f"{SHORT[m]}: covered / half-width / error median, max" for m in PREDICTED_KEYS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for scenario, by in evaluation.items():
        cells = [
            f"{_covered(e)} / {e['half_width_median']:.1%} / {e['error_median']:.1%}, {e['error_max']:.1%}" for e in by.values()
        ]
        lines.append("| " + " | ".join([f"{scenario} ({next(iter(by.values()))['n']})", *cells]) + " |")
    return lines


def _covered(e: dict) -> str:
    given = e.get("coverage_given", e["coverage"])
    return f"{e['coverage']:.0%}" + (f" ({given:.0%} with one)" if given != e["coverage"] else "")


def markdown(section: dict) -> list[str]:
    """The section of results/bench.md: the method, then per model form its table, and coverage,
    sharpness and accuracy on every population."""
    cal = section["calibration"]
    checked, hidden = (section["vehicles"][str(section[seed])] for seed in ("check_seed", "hidden_seed"))
    lines = [
        "## Prediction intervals on vehicles no one tuned for",
        "",
        f"{len(FORMS)} generator forms ({', '.join(FORMS)}): on the set seed "
        f"{', '.join(f'{n} {form}' for form, n in cal['corpus']['vehicles'].items())}; on the check seed {checked} vehicles. "
        "Each is fitted from minimal problem files at 56 km/h, at 40 + 56 and at 40 + 64 km/h, and predicts the speeds "
        "it was not fitted at, and at 56 km/h with 20 % more and 15 % less mass. Each model form's table "
        f"(crashnlp/analysis/calibration.json, version {cal['version']}) is set on its own fits of seed {section['set_seed']} "
        f"(conformal level {cal['coverage']}) and checked on seed {section['check_seed']}, whose records set no q, and on "
        f"{hidden} vehicles of a form the corpus does not hold, {', '.join(HIDDEN)} (seed {HIDDEN_SEED}). Per metric: the "
        "share of predictions whose 95 % interval holds the generator's value (a failed fit, or one that gives no "
        "interval, counts as a miss; in brackets the share of those with an interval), the median half-width and the "
        "median and largest error, relative to the value (the rebound's to at least its table's floor share of the impact "
        f"speed, the max pitch's to at least {PITCH_FLOOR:g} deg, as the form term's scale is).",
        "",
    ]
    for s in (section, *section.get("forms", {}).values()):
        lines += _form_markdown(s)
    return lines


def _form_markdown(section: dict) -> list[str]:
    """One model form's part of the section: its table, then its evaluation on every population."""
    cal, form = section["calibration"], section.get("model_form", DEFAULT_FORM)
    lines = [
        f"### Model form {form}",
        "",
        f"Set on {', '.join(f'{n} {generator}' for generator, n in cal['corpus']['vehicles'].items())} of seed "
        f"{section['set_seed']}.",
        "",
        *(
            []
            if section["shipped"]
            else [
                f"**This run's {form} table is not the shipped one (crashnlp/analysis/calibration.json): `make calibrate`.**",
                "",
            ]
        ),
        "q per class and metric, and per metric the power of the distance in the form term's unit:",
        "",
        "| class | " + " | ".join(SHORT[m] for m in PREDICTED_KEYS) + " |",
        "|---|" + "---|" * len(PREDICTED_KEYS),
        *(
            f"| {k} | " + " | ".join(f"{row.get(m, float('nan')):.3g}" for m in PREDICTED_KEYS) + " |"
            for k, row in cal["table"].items()
        ),
        "| power of the distance | " + " | ".join(f"{cal['power'][m]:g}" for m in PREDICTED_KEYS) + " |",
        "",
        f"The rebound's scale: its value, but at least {cal.get('rebound_floor', IMPACT_SPEED):g} of the impact speed.",
        "",
    ]
    for seed in (CHECK_SEED, HIDDEN_SEED, SET_SEED):
        for group, evaluation in section["evaluation"].get(str(seed), {}).items():
            lines += [f"#### {form}: seed {seed}, {LABELS[seed]}: {group}", "", *_evaluation_table(evaluation), ""]
            lines += [_chance_line(evaluation, section.get("pooled", {}).get(str(seed), {}).get(group)), ""]
    return lines


def merged(old: dict, made: dict[str, dict]) -> dict:
    """The bench section (sections' layout) with the parts of the model forms in `made` (form ->
    section) in place of `old`'s, every other form's part as `old` has it."""
    main = made.get(DEFAULT_FORM) or {k: v for k, v in old.items() if k != "forms"}
    return {**main, "forms": old.get("forms", {}) | {form: s for form, s in made.items() if form != DEFAULT_FORM}}
