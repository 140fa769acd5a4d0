"""compare's choice from one test: does the form it chooses predict the vehicle's other speeds best?

With one test, `crashnlp compare` has no test to hold out and chooses by the BIC of each form's
fit (crashnlp.optimize.comparison). Here each vehicle of the intervals' corpus (bench/calibration.py's
populations: the set seed, the check seed and the hidden population of a form the corpus does not
hold) is tested at FITTED_KMH and its forms fitted and scored from that test alone, as compare
does it (score_form, choose), its minimal problem as `crashnlp init` writes it; each form's fit
then predicts the vehicle at PREDICTED_KMH, scored as compare's held-out score is (each measured
channel's RMSE over its data's RMS, averaged over the channels and the speeds:
crashnlp.optimize.comparison.held_out_prediction).

Per population and generator form: how often each way of choosing predicts within compare's TIE of
the better form, and the mean and largest regret (the chosen form's score over the better form's,
less one). The ways: compare's choice; compare's rule on a BIC whose samples are counted as fewer
for the residuals' lag-one correlation (the fitted nodes are not independent: a form's miss is
smooth in time); always the default form; always the other form. Beside them compare's rule with
the larger ties OTHER_TIES. Nothing is set on these vehicles: BIC_TIE is Kass and Raftery's, so
every population judges the rule.

What the choice does for the intervals (`covered`): on the populations whose held-out records
bench/calibration.py keeps (the check seed and the hidden population, CHECK_RECORDS), every
prediction of each vehicle by the form compare chose from its one test, against the generator's
value with that form's shipped table, beside each form always (engine-on-mounts too, which compare
fits when named).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

import crashnlp
from bench.calibration import CHECK_RECORDS, LABELS, POPULATIONS, held_out_records, shares, vehicle_counts, vehicles
from bench.corpus import Vehicle
from bench.cross_speed import fit_problem
from crashnlp.analysis.calibration import shipped
from crashnlp.base.outputs import PREDICTED_KEYS
from crashnlp.optimize.comparison import (
    BIC_TIE,
    TIE,
    FormScore,
    choose,
    held_out_prediction,
    information_criteria,
    score_form,
    with_form,
)
from crashnlp.problem.forms import COMPARED, DEFAULT_FORM

FITTED_KMH = 56.0
PREDICTED_KMH = (40.0, 48.0, 64.0)
QUICK_COUNT = 1  # vehicles of each generator form with --quick
OTHER_TIES = (10.0, 50.0, 100.0, 400.0)  # BIC ties tried beside compare's BIC_TIE


def judge(v: Vehicle, folder: Path) -> dict:
    """One vehicle: compare's choice from its FITTED_KMH test (its fits as compare makes and scores
    them, crashnlp.optimize.comparison.score_form), the BIC with the samples counted as fewer
    (`fewer_samples_bic`), and each form's held-out score at PREDICTED_KMH."""
    whole = crashnlp.load(fit_problem(v, (FITTED_KMH, *PREDICTED_KMH), folder))
    one = whole.model_copy(update={"tests": whole.tests[:1]})
    scored = {form: score_form(one, form, None, "bic") for form in COMPARED}
    row: dict = {"vehicle": v.name, "choice": choose([score for score, _ in scored.values()], "bic")[0], "forms": {}}
    for form, (score, fit) in scored.items():
        entry: dict = {"status": score.status, "bic": score.bic}
        if fit is not None and fit.ok and fit.identified is not None and score.parameters is not None:
            held = [held_out_prediction(with_form(whole, form), t.name, fit.identified) for t in whole.tests[1:]]
            scores = [h.score for h in held]
            entry["held_out"] = None if None in scores else float(np.mean(scores))  # type: ignore[arg-type]
            entry |= fewer_samples_bic(fit, score.parameters)
        row["forms"][form] = entry
    return row


def fewer_samples_bic(fit: crashnlp.Result, k: int) -> dict:
    """The fit's BIC with each channel's n samples counted as n (1 - r) / (1 + r), r the lag-one
    correlation of its residuals (floored at 0): a smooth miss is fewer independent samples than
    nodes. Beside it each fitted channel's r ("test/channel")."""
    fitted = {f"{name}/{c.channel}": c for name, t in fit.tests.items() for c in (t.fit or {}).values()}
    lag = {key: _lag_one(c.model - c.data) for key, c in fitted.items()}
    counted = [c.data.size * (1 - lag[key]) / (1 + lag[key]) for key, c in fitted.items()]
    _, bic = information_criteria(list(fitted.values()), k, counted)
    return {"bic_fewer_samples": bic, "lag_one": lag}


def _lag_one(residual: np.ndarray) -> float:
    """The lag-one correlation of a residual, within [0, 0.999]."""
    r = residual - residual.mean()
    denominator = float(r @ r)
    return min(max(float(r[:-1] @ r[1:]) / denominator if denominator > 0 else 0.0, 0.0), 0.999)


def regret(row: dict, form: str | None) -> float | None:
    """The chosen form's held-out score over the better form's, less one; None where a form has no score."""
    scores = {f: e.get("held_out") for f, e in row["forms"].items()}
    if form is None or None in scores.values():
        return None
    return scores[form] / min(scores.values()) - 1.0  # type: ignore[operator, type-var]


def ways(row: dict) -> dict[str, str | None]:
    """The form each way of choosing takes for `row`: compare's, compare's rule on the BIC with
    fewer samples, and each form always."""
    return {
        "compare": row["choice"],
        "BIC, fewer samples": _by_bic(row, "bic_fewer_samples"),
        **{f"always {form}": form for form in COMPARED},
    }


def ties(row: dict) -> dict[str, str | None]:
    """The form compare's rule takes for `row` with each of OTHER_TIES."""
    return {f"BIC, tie {tie:g}": _by_bic(row, "bic", tie) for tie in OTHER_TIES}


def _by_bic(row: dict, key: str, tie: float = BIC_TIE) -> str | None:
    """The form compare's rule chooses by each form's `key` (a BIC) with the tie `tie`."""
    scores = [FormScore(form, e["status"], bic=e.get(key)) for form, e in row["forms"].items()]
    return choose(scores, "bic", tie)[0]


def summary(rows: list[dict]) -> dict:
    """The vehicles, how many compare gave another form than the default, the fitted channels'
    residual lag-one correlations (5th percentile, median, 95th), and per way of choosing (`ways`)
    and per other tie (`ties`): vehicles scored, within TIE of the better form, mean and largest
    regret."""
    out: dict = {"vehicles": len(rows), "chose_other": sum(row["choice"] not in (None, DEFAULT_FORM) for row in rows)}
    lags = [r for row in rows for e in row["forms"].values() for r in e.get("lag_one", {}).values()]
    if lags:  # the fitted channels' residual lag-one correlations, every form's
        out["lag_one"] = dict(zip(("p05", "median", "p95"), (float(x) for x in np.quantile(lags, [0.05, 0.5, 0.95]))))
    for part, pick in (("ways", ways), ("ties", ties)):
        out[part] = {way: _tally([regret(row, pick(row)[way]) for row in rows]) for way in (pick(rows[0]) if rows else ())}
    return out


def _tally(regrets: list[float | None]) -> dict:
    values = [r for r in regrets if r is not None]
    return {
        "scored": len(values),
        "within_tie": sum(r <= TIE for r in values),
        "mean_regret": float(np.mean(values)) if values else None,
        "max_regret": float(np.max(values)) if values else None,
    }


def covered(populations: dict) -> dict:
    """Per population with held-out records (CHECK_RECORDS), per way of choosing (compare's, and
    each form with records always: engine-on-mounts too, which compare fits when named) and per
    metric: how many of the population's predictions (every scenario of bench/calibration.py, each
    vehicle's by the way's form, judged with that form's shipped table) cover the generator's
    value, with the share's range over whole vehicles (bench/calibration.py's `shares`); a vehicle
    compare chose no form for has no interval."""
    held = held_out_records() if CHECK_RECORDS.exists() else {}
    tables = {form: shipped(form) for form in held}
    out: dict = {}
    for seed, pop in populations.items():
        if any(seed not in held.get(form, {}) for form in COMPARED):
            continue
        chosen = {(kind, row["vehicle"]): row["choice"] for kind, g in pop["kinds"].items() for row in g["rows"]}
        picks = {"compare": chosen, **{f"always {form}": dict.fromkeys(chosen, form) for form in held}}
        records = {form: held[form][seed] for form in held}
        out[seed] = {way: _covered_by(records, tables, pick) for way, pick in picks.items()}
    return out


def _covered_by(records: dict[str, list[dict]], tables: dict, pick: dict[tuple[str, str], str | None]) -> dict:
    """`covered` of one population (`records`: form -> its held-out records) and one way (`pick`:
    (generator form, vehicle) -> the form it takes, None for none)."""
    out = {}
    for metric in PREDICTED_KEYS:
        per: dict[tuple[str, str], list[int]] = {}
        for vehicle, form in pick.items():
            rows = [r for r in records[form or DEFAULT_FORM] if (r["form"], r["vehicle"]) == vehicle]
            per |= vehicle_counts(rows, metric, tables[form] if form else None)
        if per:
            out[metric] = shares(per)
    return out


def run(quick: bool = False) -> dict:
    """The bench section: every population's vehicles (QUICK_COUNT of each generator form with --quick)."""
    out: dict = {"fitted_kmh": FITTED_KMH, "predicted_kmh": PREDICTED_KMH, "tie": TIE, "populations": {}}
    for seed, (makers, counts) in POPULATIONS.items():
        if quick:
            counts = dict.fromkeys(counts, QUICK_COUNT)
        groups: dict[str, list[dict]] = {}
        with tempfile.TemporaryDirectory() as tmp:
            for kind, v in vehicles(seed, counts, makers):
                folder = Path(tmp) / f"{kind.replace(' ', '-')}-{v.name}"
                folder.mkdir()
                groups.setdefault(kind, []).append(judge(v, folder))
                print(f"  seed {seed} {kind} {v.name}: {groups[kind][-1]['choice']}", flush=True)
        out["populations"][str(seed)] = {
            "label": LABELS[seed],
            "kinds": {kind: {"rows": rows, "summary": summary(rows)} for kind, rows in groups.items()},
            "summary": summary([r for rows in groups.values() for r in rows]),
        }
    out["covered"] = covered(out["populations"])
    return out
