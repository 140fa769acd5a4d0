"""The bench's convergence summary (bench/convergence.py) judges the other sections' fits as
issue 25's acceptance does, and bench/report.py renders it; on hand-made results, nothing solved."""

from __future__ import annotations

from bench import convergence, report
from bench.studies import K_FRONT, PITCH


def fit(status: str = "ok", iterations: int = 20) -> dict:
    return {"status": status, "iterations": iterations, "wall_s": 1.0}


def results(corpus_its: list[int], joint_its: list[int], grid_status: list[str], same_table: bool = True) -> dict:
    """A results dict with the four groups' sources, the grid's cells text as in a study table."""
    grid = [
        {"case": f"case-{i:03d}", PITCH: f"[null, {3 + i} deg]", K_FRONT: "80 kN/m", **fit(s), "iterations": "21", "wall_s": ""}
        for i, s in enumerate(grid_status)
    ]
    return {
        "corpus": {"vehicles": [{"name": f"v{i:02d}", **fit(iterations=n)} for i, n in enumerate(corpus_its)]},
        "scaling": {
            "max_iter": 300,
            "tests": [
                {"method": m, "tests": k, "intervals": 200, **fit(iterations=n)}
                for (m, k), n in zip([(m, k) for m in ("multiple-shooting", "collocation") for k in (1, 2, 4)], joint_its)
            ],
        },
        "studies": {
            "grid_64_rows": grid,
            "same_table_64": same_table,
            "grid_64": {"1 worker": {"workers": 1}, "2 workers": {"workers": 2}},
        },
        "convergence": {
            "problem": "pickup-joint.yaml",
            "predict_kmh": 64.0,
            "regularized": [
                {"regularization": w, "intervals": 200, **fit(iterations=n), "displacement_rel": 0.01, "peak_rel": -0.05}
                for w, n in ((0.0, 20), (10.0, 377))
            ],
        },
    }


def test_groups_take_only_the_fits_the_acceptance_names():
    groups = convergence.summary(results([9, 12, 130], [16, 36, 37, 17, 17, 24], ["ok"] * 63 + ["solver failed"]))
    assert groups["corpus"]["median_iterations"] == 12 and groups["corpus"]["above_limit"] == 1
    assert groups["joint"]["count"] == 4  # the 1-test fits are not joint fits
    assert groups["grid"]["ok"] == 63 and groups["grid"]["fits"][0]["iterations"] == 21
    assert groups["regularized"]["max_iterations"] == 377


def test_targets_met_and_missed():
    good = report.convergence_targets(convergence.summary(results([9, 12, 14], [16, 36, 37, 17, 17, 24], ["ok"] * 64)))
    assert [met for _, _, met in good] == [True, True, True, False]  # the regularized fit at 377 iterations
    bad = report.convergence_targets(convergence.summary(results([9, 12, 14], [36] * 6, ["ok"] * 64, same_table=False)))
    assert bad[2][2] is False


def test_sections_not_run_are_not_applicable_and_render():
    r = results([9], [16] * 6, ["ok"] * 4)
    del r["studies"], r["corpus"], r["scaling"]
    assert [met for _, _, met in report.convergence_targets(convergence.summary(r))] == [None, None, None, False]
    text = report.markdown(r)
    assert "## Convergence" in text and "not run" in text
