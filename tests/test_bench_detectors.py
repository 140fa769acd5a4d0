"""The bench's judgement of the watch's rules (bench/detectors.py) and of the hidden tall vehicles
(bench/forms.py), and bench/report.py's tables of both; on hand-made runs and rows, nothing solved."""

from __future__ import annotations

import math

import numpy as np

from bench import detectors, forms, report
from crashnlp.optimize.options import SETTLE_OPTIONS
from crashnlp.optimize.solved import SolveResult
from crashnlp.problem.schema import Solver


def solved(status: str = "Solve_Succeeded", iterations: int = 10, objective: float = 1.0, z=(0.0,), **kw) -> SolveResult:
    empty = np.zeros(0)
    return SolveResult(np.array(z, float), objective, empty, empty, empty, status, iterations, 1.0, 0.0, **kw)


def run(spec: Solver, result: SolveResult) -> detectors.Run:
    return detectors._run(spec, result)


GN, NEWTON = Solver(), Solver(hessian="exact")


def test_each_run_is_named_by_the_rule_that_stopped_it():
    assert run(GN, solved(tail=0.01)).fired == "tail"
    assert run(GN, solved("User_Requested_Stop", stopped="cycle")).fired == "cycle"
    assert run(GN, solved("User_Requested_Stop", stopped="wander")).fired == "wander"
    assert run(GN, solved("Solved_To_Acceptable_Level")).fired == "steady"
    assert run(NEWTON, solved("Solved_To_Acceptable_Level")).kind == "newton"
    settle = run(Solver(ipopt=dict(SETTLE_OPTIONS)), solved("Solved_To_Acceptable_Level"))
    assert (settle.kind, settle.fired) == ("settle", "settle")
    unsettled = run(Solver(ipopt=dict(SETTLE_OPTIONS)), solved("User_Requested_Stop", stopped="unsettled"))
    assert (unsettled.kind, unsettled.fired) == ("settle", "unsettled")
    assert run(GN, solved()).fired is None and run(GN, solved("Maximum_Iterations_Exceeded")).fired is None


def test_a_tail_is_a_false_alarm_only_where_newton_does_not_finish_the_same_fit():
    tail = run(GN, solved("User_Requested_Stop", objective=2.0, z=(0.0,), tail=0.01))
    home = run(NEWTON, solved(objective=1.0, z=(0.05,)))  # converged lower: the same fit
    elsewhere = run(NEWTON, solved(objective=3.0, z=(5.0,)))  # converged higher and far away
    unfinished = run(NEWTON, solved("Maximum_Iterations_Exceeded", objective=1.0))
    judged = lambda runs: detectors._judged(runs, 0, True, None, None)["false_alarm"]  # noqa: E731
    assert not judged([tail, home])
    assert judged([tail, elsewhere]) and judged([tail, unfinished]) and judged([tail])


def test_a_cycle_is_a_false_alarm_where_the_fit_converged_left_alone():
    cycle = run(GN, solved("User_Requested_Stop", stopped="cycle"))
    assert detectors._judged([cycle], 0, True, None, None) == {"rule": "cycle", "at": 10, "false_alarm": True}
    assert not detectors._judged([cycle], 0, False, None, None)["false_alarm"]


def test_an_unsettled_cycle_is_a_false_alarm_where_the_exact_hessian_does_not_converge():
    unsettled = run(Solver(ipopt=dict(SETTLE_OPTIONS)), solved("User_Requested_Stop", stopped="unsettled"))
    judged = lambda runs: detectors._judged(runs, 0, False, None, None)["false_alarm"]  # noqa: E731
    assert not judged([unsettled, run(NEWTON, solved())])
    assert judged([unsettled, run(NEWTON, solved("Maximum_Iterations_Exceeded"))]) and judged([unsettled])


def test_the_summary_counts_fires_false_alarms_and_runs_that_hit_their_limit_unseen():
    fit = {"status": "ok", "iterations": 30, "alone_iterations": 300, "alone_converged": False, "apart_std": None, "misses": 1}
    fits = [
        {**fit, "fires": [{"rule": "cycle", "at": 20, "false_alarm": False}, {"rule": "settle", "at": 35, "false_alarm": False}]},
        {**fit, "fires": [{"rule": "tail", "at": 12, "false_alarm": True}], "apart_std": 0.1, "misses": 0},
    ]
    s = detectors.summary(fits)
    assert s["rules"]["cycle"] == {"fires": 1, "fits": 1, "false_alarms": 0}
    assert s["rules"]["tail"] == {"fires": 1, "fits": 1, "false_alarms": 1}
    assert s["rules"]["wander"]["fires"] == 0
    assert (s["misses"], s["alone_not_converged"], s["apart_std_max"]) == (1, 2, 0.1)
    lines = report.detectors_md({"count": 1, "joints_kmh": [[40, 56]], "left_alone": {"max_iter": 300},
                                 "set": {"seed": 1, "summary": s}, "check": {"seed": 2, "summary": s}})  # fmt: skip
    assert any("1 on 1 fits, 1 false" in line for line in lines)


def hidden_row(**kw) -> dict:
    row = {"status": "ok", "pitch_rmse_deg": 0.1, "displacement_rel": 0.01, "peak_rel": -0.05, "stop_err_s": 0.001}
    row |= {"stop_s": 0.095, "stop_true_s": 0.094, "lift_off_s": None, "truth_prediction_lift_off_s": None}
    return {**row, **kw}


def test_a_hidden_vehicle_meets_every_target_or_none():
    assert forms.within_hidden(hidden_row())
    for miss in ({"pitch_rmse_deg": 0.6}, {"displacement_rel": -0.03}, {"peak_rel": 0.11}, {"stop_err_s": -0.004}):
        assert not forms.within_hidden(hidden_row(**miss))
    assert not forms.within_hidden(hidden_row(lift_off_s=0.0986))  # in target otherwise, but it lets go while moving on
    assert forms.within_hidden(hidden_row(lift_off_s=0.0986, truth_prediction_lift_off_s=0.097))  # as the vehicle does
    never = {"stop_s": math.nan, "stop_err_s": math.nan}
    assert not forms.within_hidden(hidden_row(**never))  # it never comes to rest where the generator does
    neither = {**never, "stop_true_s": math.nan, "lift_off_s": 0.0717, "truth_prediction_lift_off_s": 0.0721}
    assert forms.within_hidden(hidden_row(**neither))  # it lets go and drifts on as the generator does
    assert not forms.within_hidden(hidden_row(stop_true_s=math.nan, stop_err_s=math.nan))  # it stops, the generator not
    ended = {**neither, "stop_s": 0.0717}  # its loading ends as it lets go (let_go_end), as the generator's does
    assert forms.within_hidden(hidden_row(**ended))
    assert not forms.within_hidden(hidden_row(**{**ended, "stop_s": 0.0760}))  # 3.9 ms after the generator lets go
    assert not forms.within_hidden(hidden_row(status="solver failed", pitch_rmse_deg=None))


def test_coverage_is_the_share_of_intervals_holding_the_generators_value():
    displacement, peak = forms.INTERVAL_METRICS  # the prediction's metric keys, as the bench reads them
    rows = [
        {"covered": {displacement: c, peak: True}, "half_width": {displacement: w, peak: None}}
        for c, w in ((True, 0.02), (False, 0.04), (True, 0.03))
    ]
    out = forms._coverage(rows)
    assert out["displacement_covered"] == 2 / 3 and out["displacement_half_width_median"] == 0.03
    assert out["peak_covered"] == 1.0 and math.isnan(out["peak_half_width_median"])
