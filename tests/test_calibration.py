"""The calibrated form term of the prediction intervals: classes, scores, the conformal quantile, the shipped table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crashnlp.calibration import Calibration, IntervalParts, conformal_quantile, reach, scale, shipped
from crashnlp.identified import INTERVAL_METRICS, IdentifiedRange


def _range(*tests: tuple[float, float]) -> IdentifiedRange:
    """A fitted range of tests given as (speed m/s, mass kg)."""
    speeds, masses = [s for s, _ in tests], [m for _, m in tests]
    energies = tuple(0.5 * m * s**2 for s, m in tests)
    return IdentifiedRange(0.5, (min(speeds), max(speeds)), (min(masses), max(masses)), 0.45, energies)


def test_a_prediction_s_class_and_distance_follow_its_energy_against_the_fitted_tests():
    one = _range((56 / 3.6, 1500.0))
    assert reach(one, 40 / 3.6, 1500.0) == ("one-down", pytest.approx(2 * math.log(56 / 40)))
    assert reach(one, 64 / 3.6, 1500.0) == ("one-up", pytest.approx(2 * math.log(64 / 56)))
    assert reach(one, 56 / 3.6, 1800.0) == ("one-up", pytest.approx(math.log(1.2)))  # a heavier vehicle: a mass ratio
    assert reach(one, 56 / 3.6, 1500.0)[1] == 0.0  # the fitted test itself
    two = _range((40 / 3.6, 1500.0), (56 / 3.6, 1500.0))
    assert reach(two, 48 / 3.6, 1500.0) == ("between", pytest.approx(2 * math.log(56 / 48)))
    assert reach(two, 64 / 3.6, 1500.0) == ("several-up", pytest.approx(2 * math.log(64 / 56)))
    assert reach(two, 32 / 3.6, 1500.0)[0] == "several-down"


def test_a_result_without_energies_takes_them_from_its_range():
    old = IdentifiedRange(0.5, (56 / 3.6, 56 / 3.6), (1500.0, 1500.0), 0.45)
    assert reach(old, 40 / 3.6, 1500.0) == ("one-down", pytest.approx(2 * math.log(56 / 40)))


def test_the_score_is_the_smallest_q_whose_interval_covers_the_truth():
    parts = IntervalParts(value=10.0, parameters=0.3, fitted=0.4, past_the_reach=0.0, unit=2.0)
    assert parts.score(10.4) == 0.0  # the other parts cover it
    q = parts.score(12.0)
    low, high = parts.interval(q)
    assert high == pytest.approx(12.0) and low == pytest.approx(8.0)
    assert not parts.interval(0.99 * q)[1] >= 12.0
    assert IntervalParts(10.0, 0.0, 0.0, 0.0, unit=0.0).score(11.0) == math.inf  # no form term can cover it


def test_the_parts_add_in_quadrature_and_the_largest_dominates():
    parts = IntervalParts(value=30.0, parameters=1.0, fitted=1.0, past_the_reach=6.0, unit=3.0)
    shares = parts.shares(0.5)
    assert shares["form"] == pytest.approx(math.hypot(1.0, 1.5))
    assert parts.half(0.5) == pytest.approx(math.sqrt(sum(v**2 for v in shares.values())))
    assert max(shares, key=lambda k: shares[k]) == "past_the_reach"
    assert parts.interval(0.0) == pytest.approx((30.0 - math.sqrt(38.0), 30.0 + math.sqrt(38.0)))


def test_the_conformal_quantile_is_the_rank_ceil_n_plus_one_times_the_coverage():
    scores = list(np.arange(1.0, 20.0)[::-1])  # 19 scores: rank ceil(20 * 0.95) = 19, the largest
    assert conformal_quantile(scores, 0.95) == 19.0
    assert conformal_quantile(scores, 0.5) == 10.0
    assert conformal_quantile(scores[:10], 0.95) == math.inf  # too few for 95 %


def test_the_scales_are_the_value_the_impact_speed_for_the_rebound_and_a_floor_for_the_pitch():
    assert scale("max_crush_m", 0.6, 15.0) == 0.6
    assert scale("rebound_velocity_mps", 0.2, 15.0) == 15.0
    assert scale("max_pitch_deg", 0.2, 15.0) == 1.0


def test_the_shipped_table_calibrates_every_metric_of_every_class_and_names_its_corpus():
    cal = shipped()
    for klass in ("one-down", "one-up", "between", "several-up"):
        for metric in INTERVAL_METRICS:
            q = cal.q(klass, metric)
            assert q is not None and np.isfinite(q) and q >= 0, (klass, metric)
    assert cal.q("several-down", "max_crush_m") == cal.q("one-down", "max_crush_m")  # borrowed: one test knows less
    named = cal.named()
    assert named["file"] == "crashnlp/calibration.json" and named["version"] >= 1 and named["corpus"]["seed"]
    assert Calibration.from_json(cal.to_json()) == cal


def test_the_fitted_miss_leaves_out_a_test_where_model_or_data_do_not_reach_the_metric():
    """A fitted test whose model does not stop in its record has no stop time (NaN): its miss is left
    out of the discrepancy, which the prediction's interval is built on, rather than making it NaN."""
    from types import SimpleNamespace

    from crashnlp.optimize.outcome import _discrepancy

    tests = {
        "a": SimpleNamespace(metrics={"time_zero_velocity_s": 0.066}, data_metrics={"time_zero_velocity_s": 0.060}),
        "b": SimpleNamespace(metrics={"time_zero_velocity_s": math.nan}, data_metrics={"time_zero_velocity_s": 0.070}),
    }
    assert _discrepancy(tests)["time_zero_velocity_s"] == pytest.approx(0.1)
