"""Cross-speed predictions: fit a vehicle at two speeds, predict the third, judge against the generator.

Each vehicle comes from bench/corpus.py (a planar rigid body, not crashnlp's pendulum) and is
tested at 40, 56 and 64 km/h: the same structure at three speeds. The shared synthetic pickup
is the first vehicle (its generator's parameters are those of the shared data set); its shipped
problem, pickup-joint.yaml, whose breakpoints run past the 56 km/h crush, is fitted and
predicted at 64 km/h too. The corpus vehicles come in FAMILIES: a seed and the speed their
structure is built for (56 km/h: the 64 km/h test crushes into the stiffening the generator puts
past the crush a vehicle is built for; 64 km/h: it ends where that stiffening begins; 72 km/h: it
stays inside the built structure), and two of vans and tall SUVs, whose CG sits higher above the
impact point than the corpus's (0.30-0.45 m against 0.04-0.26 m), so that they pitch more. Two
fits per vehicle, from minimal problem files (crashnlp.case.completion fills in the front end):

- extrapolation: fit 40 + 56 km/h, predict 64 km/h (8 km/h past the fastest fitted test);
- interpolation: fit 40 + 64 km/h, predict 56 km/h.

The prediction is `crashnlp.simulate` of a problem that names only the new test's speed and
duration, with the fit's result as `params`; its max displacement, peak deceleration and time of zero
velocity are compared with the generator's noise-free response, and its 95 % intervals are
checked for covering the generator's max displacement and peak deceleration.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import yaml
from scipy.interpolate import PchipInterpolator

import crashnlp
from bench.common import PROBLEMS
from bench.corpus import PICKUP, Vehicle, measured, random_vehicle, simulate, tall_vehicle, write_csv
from bench.robustness import ACCEL_FILTER, WINDOW, minimal_problem
from crashnlp.analysis.summary import values, withheld
from crashnlp.base.outputs import PREDICTED_KEYS
from crashnlp.data.instrument import recorded
from crashnlp.data.signal import CFC_CLASSES

SPEEDS_KMH = (40.0, 56.0, 64.0)
SPLITS = {"extrapolation": ((40.0, 56.0), 64.0), "interpolation": ((40.0, 64.0), 56.0)}
TARGETS = {
    "extrapolation": {"displacement_rel": 0.03, "peak_rel": 0.15},
    "interpolation": {"displacement_rel": 0.02, "peak_rel": 0.10},
    "coverage": 0.85,
    "iterations": 100,
}
COUNT = 6  # corpus vehicles per family


@dataclasses.dataclass(frozen=True)
class Family:
    """Corpus vehicles of one seed, each built for one speed (its structure, tested at any
    speed); `tall`: vans and tall SUVs (bench.corpus.tall_vehicle)."""

    seed: int
    built_kmh: float
    tall: bool = False

    @property
    def label(self) -> str:
        return f"seed {self.seed}, {'tall, ' if self.tall else ''}built for {self.built_kmh:g} km/h"

    def vehicles(self, count: int = COUNT) -> list[Vehicle]:
        make = tall_vehicle if self.tall else random_vehicle
        return [make(i, self.seed, speed=self.built_kmh / 3.6) for i in range(count)]


FAMILIES = (
    Family(2030, 56.0),
    Family(2031, 56.0),
    Family(2041, 64.0),
    Family(2032, 72.0),
    Family(2050, 56.0, tall=True),
    Family(2051, 64.0, tall=True),
)
PICKUP_FAMILY = "the shared pickup"  # its shipped and minimal problems
SHIPPED = (
    PROBLEMS / "pickup-joint.yaml"
)  # the shipped joint fit, its breakpoints past the 56 km/h crush: predicted at 64 km/h too
INTERVAL_METRICS = {"max_displacement_m": "displacement", "peak_decel_g": "peak"}


def at_speed(v: Vehicle, kmh: float) -> Vehicle:
    return dataclasses.replace(v, speed=kmh / 3.6)


def test_entry(kmh: float, data: dict | None = None) -> dict:
    """One test of a problem: its speed, and its data section, or without one the fits' duration."""
    entry: dict = {"name": f"{kmh:.0f}kph", "speed": f"{kmh:g} km/h"}
    return {**entry, "data": data} if data is not None else {**entry, "duration": WINDOW[1]}


def fit_problem(
    v: Vehicle, speeds: tuple[float, ...], folder: Path, transcription: dict | None = None, solver: dict | None = None
) -> Path:
    """The minimal problem of a joint fit at `speeds` (with `transcription`, else the default one;
    with the `solver` section, else none), its CSVs written beside it."""
    problem = minimal_problem(v, "unused.csv", transcription)
    problem["vehicle"].pop("speed")
    problem["name"] = f"{v.name}-{'-'.join(f'{s:.0f}' for s in speeds)}"
    tests = []
    for kmh in speeds:
        name = f"{v.name}-{kmh:.0f}kph.csv"
        write_csv(folder / name, measured(at_speed(v, kmh), simulate(at_speed(v, kmh))))
        tests.append(test_entry(kmh, minimal_problem(v, name)["tests"][0]["data"]))
    problem["tests"] = tests
    if solver is not None:
        problem["solver"] = solver
    path = folder / f"{problem['name']}.yaml"
    path.write_text(yaml.safe_dump(problem, sort_keys=False))
    return path


def prediction_problem(fit_path: Path, kmh: float, folder: Path, mass: float | None = None) -> crashnlp.Problem:
    """The fitted problem with one test at a new speed (and with `mass`, a new mass, kg) and no
    data, written into `folder`: what a user predicts with."""
    raw = yaml.safe_load(fit_path.read_text())
    entry = test_entry(kmh)
    raw["tests"] = [entry if mass is None else {**entry, "mass": f"{mass:.1f} kg"}]
    path = folder / f"{fit_path.stem}-predict-{kmh:.0f}{'' if mass is None else f'-{mass:.0f}kg'}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return crashnlp.load(path)


def given(metrics: Mapping[str, float | None], key: str) -> float:
    """A prediction's metric as a number: NaN where it gives none (crashnlp.analysis.summary.metrics:
    a simulation that ends before its vehicle stops gives no max displacement, stop, peak or pitch)."""
    value = metrics.get(key)
    return math.nan if value is None else float(value)


def errors(metrics: Mapping[str, float | None], real: dict[str, float]) -> dict[str, float]:
    """A prediction's max displacement and peak deceleration relative to the generator's, less one,
    and its stop's error (s); NaN where the prediction or the generator has none (`given`)."""
    return {
        "displacement_rel": given(metrics, "max_displacement_m") / real["max_displacement_m"] - 1.0,
        "peak_rel": given(metrics, "peak_decel_g") / real["peak_decel_g"] - 1.0,
        "stop_err_s": given(metrics, "time_zero_velocity_s") - real["time_zero_velocity_s"],
    }


def truth_metrics(v: Vehicle, kmh: float, as_a_test_gives: bool = False) -> dict[str, float]:
    """The generator's noise-free crash metrics at `kmh`, under the keys predictions report them,
    its acceleration as the fitted tests' accelerometers record it (ACCEL_FILTER), as a
    prediction's is (crashnlp.analysis.prediction.read_through): each its value over the record,
    the curves compared over the same window (NaN: none in it, e.g. no stop). With
    `as_a_test_gives`, NaN too where crashnlp's rule for a record that ends still moving withholds
    it (crashnlp.analysis.summary.withheld), as it reads a model's record: an interval is judged
    against what a record of the prediction's length holds."""
    truth = simulate(at_speed(v, kmh))
    accel = recorded(truth["time"], truth, "accel", CFC_CLASSES[ACCEL_FILTER])
    record = values(truth["time"], accel, truth["velocity"], truth["displacement"], truth["pitch"])
    shown = withheld(record, accel) if as_a_test_gives else record
    return {key: math.nan if shown[key] is None else shown[key] for key in PREDICTED_KEYS}


def judge(v: Vehicle, split: str, folder: Path, shipped: Path | None = None, transcription: dict | None = None) -> dict:
    """Fit one vehicle at two speeds, predict the third, compare with the generator; the fit's
    problem is the minimal one (with `transcription`), or `shipped`."""
    fitted, target = SPLITS[split]
    path = fit_problem(v, fitted, folder, transcription) if shipped is None else shipped
    t0 = time.perf_counter()
    result = crashnlp.identify(path)
    wall = time.perf_counter() - t0
    row: dict = {
        "vehicle": v.name if shipped is None else shipped.name,
        "split": split,
        "status": result.status,
        "iterations": result.solver.iterations,
        "wall_s": wall,
    }
    if not result.ok:
        return row
    pitch_rmse = result.identified.channel_rmse.get("pitch")
    row.update(
        lever_m=result.identified.vehicle["crush_offset"], pitch_rmse_deg=None if pitch_rmse is None else np.degrees(pitch_rmse)
    )
    test = crashnlp.simulate(prediction_problem(path, target, folder), params=result)[f"{target:.0f}kph"]
    real = truth_metrics(v, target)
    row.update(
        **errors(test.metrics, real),
        pitch_err_deg=given(test.metrics, "max_pitch_deg") - real["max_pitch_deg"],
        covered={
            key: bool(test.intervals[key][0] <= real[key] <= test.intervals[key][1]) if test.intervals.get(key) else False
            for key in INTERVAL_METRICS
        },
        intervals={key: test.intervals.get(key) for key in INTERVAL_METRICS},
        truth=real,
        extrapolation=test.extrapolation,
    )
    return {**row, "load_rise": load_rise(v, fitted, target)} if target > max(fitted) else row


def load_rise(v: Vehicle, fitted: tuple[float, ...], target: float) -> float:
    """The generator's load at the predicted test's largest crush over its load at the fitted tests'
    largest: how much the structure stiffens where the prediction goes, which no fit sees (CG travel
    stands for the front end's crush)."""
    crush = {kmh: float(np.max(simulate(at_speed(v, kmh))["displacement"])) for kmh in (*fitted, target)}
    load = PchipInterpolator(v.load_crush, v.load_force)
    return float(load(crush[target]) / load(max(crush[k] for k in fitted)))


def within_targets(row: dict) -> bool:
    target = TARGETS[row["split"]]
    return (
        row["status"] == "ok"
        and row["iterations"] <= TARGETS["iterations"]
        and abs(row["displacement_rel"]) <= target["displacement_rel"]
        and abs(row["peak_rel"]) <= target["peak_rel"]
    )


def worst(rows: list[dict], key: str) -> float:
    """The largest |error| over the rows that have one (a prediction that gives no metric has none)."""
    return float(max((abs(r[key]) for r in rows if np.isfinite(r[key])), default=float("nan")))


def summary(rows: list[dict]) -> dict:
    """Per split: fits within targets, worst errors; over all: the intervals' coverage."""
    out: dict = {}
    for split in SPLITS:
        ok = [r for r in rows if r["split"] == split and r["status"] == "ok"]
        out[split] = {
            "fits": sum(r["split"] == split for r in rows),
            "ok": len(ok),
            "within_targets": sum(within_targets(r) for r in ok),
            "displacement_rel_max": worst(ok, "displacement_rel"),
            "peak_rel_max": worst(ok, "peak_rel"),
            "stop_err_max_s": worst(ok, "stop_err_s"),
            "iterations_max": max((r["iterations"] for r in rows if r["split"] == split), default=0),
        }
    pairs = [c for r in rows if r["status"] == "ok" for c in r["covered"].values()]
    out["coverage"] = float(np.mean(pairs)) if pairs else float("nan")
    out["pairs"] = len(pairs)
    return out


def run(quick: bool = False) -> dict:
    """The bench section: the shipped pickup-joint problem, then the pickup and each family's
    corpus vehicles from minimal problems (the first family's first two with --quick), both
    splits; the summary over all fits and per family."""
    families = FAMILIES[:1] if quick else FAMILIES
    rows = []
    with tempfile.TemporaryDirectory(prefix="crashnlp-cross-speed-") as tmp:
        jobs = [(PICKUP, "extrapolation", SHIPPED, PICKUP_FAMILY)]
        jobs += [(PICKUP, split, None, PICKUP_FAMILY) for split in SPLITS]
        for f in families:
            jobs += [(v, split, None, f.label) for v in f.vehicles(2 if quick else COUNT) for split in SPLITS]
        for v, split, shipped, label in jobs:
            folder = Path(tmp) / re.sub(r"\W+", "-", label)
            folder.mkdir(exist_ok=True)
            rows.append(r := {**judge(v, split, folder, shipped), "family": label})
            line = f"  {r['vehicle']} ({label}) {split}: {r['status']}, {r['iterations']} it"
            if r["status"] == "ok":
                line += (
                    f", displacement {100 * r['displacement_rel']:+.1f} %, peak {100 * r['peak_rel']:+.1f} %, "
                    f"stop {1e3 * r['stop_err_s']:+.2f} ms, covered {sum(r['covered'].values())}/2"
                )
                line += f", load rise {r['load_rise']:.2f}x" if "load_rise" in r else ""
            print(line, flush=True)
    by_family = {label: summary([r for r in rows if r["family"] == label]) for label in dict.fromkeys(r["family"] for r in rows)}
    return {
        "families": [dataclasses.asdict(f) for f in families],
        "speeds_kmh": SPEEDS_KMH,
        "targets": TARGETS,
        "summary": {**summary(rows), "families": by_family},
        "fits": rows,
    }
