"""Convergence: status, IPOPT iterations and wall time of every fit issue 25 requires to finish.

Four groups, each judged against the issue's acceptance (TARGETS):

- the robustness corpus (30 vehicles, bench/robustness.py): every one ok, median iterations no
  higher than CORPUS_MEDIAN, none above 100;
- joint fits of pickup-56kph + the 40 km/h test (2 tests) and 4 tests by both transcriptions
  (bench/scaling.py's test sweep, 200 intervals): ok within 150 iterations;
- the 64-case grid (bench/studies.py's GRID_64) by `crashnlp study` on 1 and 2 workers: 64 of 64
  ok, none above 150 iterations, the same table on both;
- regularized joint fits: pickup-joint.yaml at each of REGULARIZATION, their iterations and the
  64 km/h prediction's max displacement and peak errors against the generator's pickup.

The first three are solved by the corpus, scaling and studies sections of the same run and only
read here (`summary(results)`, rendered by bench/report.py): solving them again would double the
bench's longest parts on shared cores, and one solve per fit keeps this summary and those
sections' tables from disagreeing. `run()` solves only the regularized fits, which no other
section does.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import crashnlp
from bench.common import PROBLEMS, load
from bench.corpus import PICKUP
from bench.cross_speed import errors, prediction_problem, truth_metrics
from bench.studies import GRID_64, K_FRONT, PITCH

JOINT = PROBLEMS / "pickup-joint.yaml"
REGULARIZATION = (0.0, 1.0, 10.0)
QUICK_INTERVALS = 50
PREDICT_KMH = 64.0
CORPUS_MEDIAN = 12  # the corpus's median iterations in the bench results issue 25 was measured against
GRID_CASES = len(GRID_64["sweep"][PITCH]) * len(GRID_64["sweep"][K_FRONT])
TARGETS = {"corpus_iterations": 100, "joint_iterations": 150, "grid_iterations": 150, "grid_cases": GRID_CASES}


# --------------------------------------------------------------------------- the regularized fits (solved here)
def regularized_fit(weight: float, intervals: int | None) -> dict:
    """pickup-joint.yaml with `objective.regularization` = `weight`, identified, then asked for 64 km/h."""
    problem = load(JOINT, intervals=intervals).with_values({"objective.regularization": weight})
    t0 = time.perf_counter()
    result = crashnlp.identify(problem)
    row = {
        "regularization": weight,
        "intervals": problem.transcription.intervals,
        "status": result.status,
        "iterations": result.solver.iterations,
        "wall_s": time.perf_counter() - t0,
        "compiled": result.solver.compiled,  # the wall time's evaluator; the iterations are the same bits either way
    }
    return {**row, **prediction_errors(result)} if result.ok else row


def prediction_errors(result: crashnlp.Result) -> dict[str, float]:
    """Max displacement and peak deceleration of the fit's PREDICT_KMH prediction (bench/cross_speed.py's
    way: a problem naming only the new speed) relative to the generator's noise-free pickup."""
    with tempfile.TemporaryDirectory(prefix="crashnlp-convergence-") as tmp:
        test = crashnlp.simulate(prediction_problem(JOINT, PREDICT_KMH, Path(tmp)), params=result)[f"{PREDICT_KMH:.0f}kph"]
    real = truth_metrics(PICKUP, PREDICT_KMH)
    return {key: value for key, value in errors(test.metrics, real).items() if key in ("displacement_rel", "peak_rel")}


def run(quick: bool = False) -> dict:
    """The bench section: the regularized fits (at QUICK_INTERVALS with --quick); the other
    groups are read from their own sections' results by `summary`."""
    intervals = QUICK_INTERVALS if quick else None
    rows = []
    for weight in REGULARIZATION:
        rows.append(r := regularized_fit(weight, intervals))
        line = f"  pickup-joint, regularization {weight:g}: {r['status']}, {r['iterations']} it, {r['wall_s']:.1f} s"
        if "displacement_rel" in r:
            line += (
                f"; {PREDICT_KMH:.0f} km/h displacement {100 * r['displacement_rel']:+.1f} %, peak {100 * r['peak_rel']:+.1f} %"
            )
        print(line, flush=True)
    return {"problem": JOINT.name, "predict_kmh": PREDICT_KMH, "targets": TARGETS, "regularized": rows}


# --------------------------------------------------------------------------- the summary over the run's results
def fit_rows(rows: list[dict], label: str, *keys: str) -> list[dict]:
    """Status, iterations and wall time of each fit, named by `label` filled with its row's `keys`
    (a study table's cells are text, empty where a case failed before solving)."""
    return [
        {
            "fit": label.format(*(r[k] for k in keys)),
            "status": r["status"],
            "iterations": int(_number(r.get("iterations"), 0.0)),
            "wall_s": _number(r.get("wall_s"), float("nan")),
        }
        for r in rows
    ]


def _number(cell: str | float | None, empty: float) -> float:
    return float(cell) if cell not in (None, "") else empty


def group(fits: list[dict], limit: int) -> dict:
    """How many fits are ok, their median and largest iterations, and how many ended above `limit`."""
    its = [f["iterations"] for f in fits]
    return {
        "fits": fits,
        "count": len(fits),
        "ok": sum(f["status"] == "ok" for f in fits),
        "median_iterations": float(statistics.median(its)) if its else float("nan"),
        "max_iterations": max(its, default=0),
        "above_limit": sum(i > limit for i in its),
        "limit": limit,
    }


def corpus_group(corpus: dict | None) -> dict | None:
    """The corpus section's vehicles."""
    if not corpus:
        return None
    fits = fit_rows(corpus["vehicles"], "{}", "name")
    return {**group(fits, TARGETS["corpus_iterations"]), "median_target": CORPUS_MEDIAN}


def joint_group(scaling: dict | None) -> dict | None:
    """The scaling section's fits of more than one test (at its `tests_intervals`), both transcriptions."""
    if not scaling:
        return None
    rows = [r for r in scaling["tests"] if r["tests"] > 1]
    fits = fit_rows(rows, "{}, {} tests x {} intervals", "method", "tests", "intervals")
    return {**group(fits, TARGETS["joint_iterations"]), "max_iter": scaling["max_iter"]}


def grid_group(studies: dict | None) -> dict | None:
    """The studies section's 64-case grid: the 1-worker table's cases with their swept values, and
    whether every run's table (1 and 2 workers) equals it but for the solve times."""
    if not studies or "grid_64_rows" not in studies:
        return None
    rows = studies["grid_64_rows"]
    fits = [{**f, "pitch": r[PITCH], "k_front": r[K_FRONT]} for f, r in zip(fit_rows(rows, "{}", "case"), rows)]
    workers = [r["workers"] for r in studies["grid_64"].values()]
    return {**group(fits, TARGETS["grid_iterations"]), "same_table": studies["same_table_64"], "workers": workers}


def regularized_group(convergence: dict | None) -> dict | None:
    """This section's own regularized fits, held to the joint fits' limit (pickup-joint is one)."""
    if not convergence:
        return None
    return group(fit_rows(convergence["regularized"], "regularization {:g}", "regularization"), TARGETS["joint_iterations"])


def summary(results: dict) -> dict[str, dict | None]:
    """Every group of the run's results: None for a group whose section did not run."""
    return {
        "corpus": corpus_group(results.get("corpus")),
        "joint": joint_group(results.get("scaling")),
        "grid": grid_group(results.get("studies")),
        "regularized": regularized_group(results.get("convergence")),
    }
