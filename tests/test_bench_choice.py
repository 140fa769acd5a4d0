"""bench/choice.py's reading of compare's one-test choice: the regret of a way of choosing, what
the summary counts within compare's tie, the coverage of the chosen form's intervals, and the
report's table of it."""

from __future__ import annotations

import pytest

from bench import report
from bench.calibration import CHECK_SEED, held_out_records, pooled
from bench.choice import _covered_by, regret, summary
from crashnlp.analysis.calibration import shipped
from crashnlp.optimize.comparison import BIC_TIE, TIE


def _row(choice: str | None, pendulum: float | None, rigid: float | None, fewer: tuple[float, float] | None = None) -> dict:
    """A vehicle's row: compare's choice, each form's held-out score and, with `fewer`, each form's
    BIC with fewer samples (pendulum, rigid body)."""
    forms = {"pendulum": {"status": "ok", "held_out": pendulum}, "rigid-body": {"status": "ok", "held_out": rigid}}
    if fewer is not None:
        for entry, bic in zip(forms.values(), fewer):
            entry["bic_fewer_samples"] = bic
    return {"vehicle": "v00", "choice": choice, "forms": forms}


def test_the_regret_is_the_chosen_forms_score_over_the_better_ones_and_none_without_both():
    row = _row("rigid-body", 0.10, 0.12)
    assert regret(row, "pendulum") == 0.0
    assert regret(row, "rigid-body") == pytest.approx(0.2)
    assert regret(_row("pendulum", 0.10, None), "pendulum") is None  # a form that failed scores nothing
    assert regret(row, None) is None  # no form's fit converged: no choice


def test_the_summary_counts_choices_within_the_tie_for_every_way_of_choosing():
    rows = [
        _row("rigid-body", 0.10, 0.05),  # compare right, the default twice as bad
        _row("rigid-body", 0.10, 0.10 * (1 + TIE / 2)),  # compare within the tie
        _row("pendulum", 0.10, 0.08),  # compare 25 % worse
        _row("pendulum", None, 0.08),  # unscored
    ]
    s = summary(rows)
    assert s["vehicles"] == 4 and s["chose_other"] == 2
    assert s["ways"]["compare"]["scored"] == 3 and s["ways"]["compare"]["within_tie"] == 2
    assert s["ways"]["compare"]["max_regret"] == pytest.approx(0.25)
    assert s["ways"]["always pendulum"]["within_tie"] == 1 and s["ways"]["always pendulum"]["max_regret"] == pytest.approx(1.0)
    assert s["ways"]["always rigid-body"]["within_tie"] == 3
    assert s["ways"]["BIC, fewer samples"]["scored"] == 0  # no row has it


def test_the_bic_with_fewer_samples_chooses_by_compare_s_rule_with_its_tie():
    lower = _row("rigid-body", 0.10, 0.05, fewer=(-100.0, -100.0 - 3 * BIC_TIE))
    tied = _row("rigid-body", 0.10, 0.05, fewer=(-100.0, -100.0 - BIC_TIE / 2))
    s = summary([lower, tied])
    assert s["ways"]["BIC, fewer samples"]["within_tie"] == 1  # the tie keeps the pendulum, twice as bad
    assert s["ways"]["BIC, fewer samples"]["max_regret"] == pytest.approx(1.0)


def test_a_larger_tie_keeps_the_default_where_compare_s_took_the_other_form():
    row = _row("rigid-body", 0.10, 0.05)
    for entry, bic in zip(row["forms"].values(), (-100.0, -120.0)):
        entry["bic"] = bic
    s = summary([row])
    assert s["ways"]["compare"]["within_tie"] == 1
    assert s["ties"]["BIC, tie 10"]["within_tie"] == 1 and s["ties"]["BIC, tie 50"]["within_tie"] == 0


def test_the_report_gives_a_row_per_generator_form_and_one_for_the_population():
    rows = [_row("rigid-body", 0.10, 0.05, fewer=(-100.0, -200.0)), _row("pendulum", 0.10, 0.08, fewer=(-100.0, -99.0))]
    section = {
        "fitted_kmh": 56.0,
        "predicted_kmh": [40.0, 48.0, 64.0],
        "tie": TIE,
        "populations": {
            "3100": {
                "label": "set seed",
                "kinds": {"rigid body": {"rows": rows, "summary": summary(rows)}},
                "summary": summary(rows),
            }
        },
    }
    table = [line for line in report.choice_md(section) if line.startswith("| set seed")]
    # a row per generator form and the population's, then the population's in the table of ties (no BIC here)
    assert [line.split(" | ")[1] for line in table] == ["rigid body", "all", "none scored"]
    assert "| 1/2 | 1/2, 12.5 % (25 %) | 1/2, 12.5 % (25 %) | 0/2, 62.5 % (100 %) | 2/2, 0.0 % (0 %) |" in table[0]


def test_the_chosen_form_s_coverage_judges_each_vehicle_by_its_form_and_none_without_one():
    """On the shipped check-seed records: every vehicle by one form is the intervals section's
    pooled coverage of that form; a vehicle taken by the rigid body counts its rigid-body predictions, where
    they differ from its pendulum ones; one compare chose no form for counts its predictions as
    misses without an interval."""
    records = {form: rows[str(CHECK_SEED)] for form, rows in held_out_records().items()}
    tables = {form: shipped(form) for form in records}
    vehicles = list(dict.fromkeys((r["form"], r["vehicle"]) for r in records["pendulum"]))
    metric = "time_zero_velocity_s"

    def own(vehicle: tuple[str, str], form: str) -> list[int]:
        e = pooled([r for r in records[form] if (r["form"], r["vehicle"]) == vehicle], tables[form])[metric]
        return [e["covered"], e["n"], e["given"]]

    def counts(pick: dict) -> list[int]:
        e = _covered_by(records, tables, pick)[metric]
        return [e["covered"], e["n"], e["given"]]

    for form in tables:  # every vehicle by one form: that form's records, judged with its own table
        assert _covered_by(records, tables, dict.fromkeys(vehicles, form)) == pooled(records[form], tables[form])
    first = next(v for v in vehicles if own(v, "rigid-body") != own(v, "pendulum"))
    rest = [v for v in vehicles if v != first]
    mixed = counts({first: "rigid-body", **dict.fromkeys(rest, "pendulum")})
    assert mixed == [a + b for a, b in zip(own(first, "rigid-body"), counts(dict.fromkeys(rest, "pendulum")))]
    held = next(v for v in rest if own(v, "pendulum")[0] > 0)
    assert counts({held: None, first: "pendulum"}) == [
        own(first, "pendulum")[0],
        own(held, "pendulum")[1] + own(first, "pendulum")[1],
        own(first, "pendulum")[2],
    ]
