"""Fits that finish: a cycle of Gauss-Newton's iterates is told from a slow convergence, the
shooting fits that cycled at one RK4 step per interval finish once the steps are refined, a cycle
no finer step may take away settles at IPOPT's acceptable level, and joint collocation fits
finish with their constraint block regularized.

The fits are the shipped pickup's, at full size: the cycles come from the crush crossing a kink
of the force laws inside a 1 ms step, which a coarser grid would change. Which IPOPT runs a
cycle leads to is checked on scripted runs."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from builders import ROOT, make_case, small_pickup_problem

from crashnlp.case.case import Case
from crashnlp.optimize import solve as solve_module
from crashnlp.optimize.identify import identify
from crashnlp.optimize.ocp import OptimalControl
from crashnlp.optimize.options import SETTLE_OPTIONS, ipopt_options
from crashnlp.optimize.solved import SolveResult
from crashnlp.optimize.watch import CYCLE_RUN, CYCLE_START, Watch, cycle, followed
from crashnlp.problem import load_problem
from crashnlp.problem.schema import Solver
from crashnlp.transcription.collocation import GAUSS_NEWTON_OPTIONS

PICKUP_56, PICKUP_40 = ROOT / "problems/pickup-56kph.yaml", ROOT / "problems/pickup-40kph.yaml"
ITERATION_LIMIT = 150  # issue 25's acceptance for the joint fits and the 64-case grid


def _returns(iterates: list[np.ndarray]) -> tuple[int, list[float]]:
    """The Watch's bookkeeping over a sequence of iterates: came-back count and step lengths."""
    window: list[np.ndarray] = []
    returns = 0
    for x in iterates:
        window, returns = followed(window, returns, x)
    return returns, [float(np.abs(b - a).max()) for a, b in zip(iterates, iterates[1:])]


def test_a_two_cycle_is_a_cycle():
    centre, offset = np.ones(3), np.array([1e-2, -2e-2, 5e-3])
    iterates = [centre + (offset if k % 2 else -offset) * (1 + 1e-3 * k) for k in range(2 * CYCLE_RUN)]
    assert cycle(*_returns(iterates))


def test_a_four_cycle_is_a_cycle():
    corners = [np.array(c, dtype=float) * 1e-2 for c in ((1, 0), (0, 1), (-1, 0), (0, -1))]
    assert cycle(*_returns([corners[k % 4] for k in range(3 * CYCLE_RUN)]))


def test_a_long_uneven_cycle_is_a_cycle():
    """A loop of 23 iterates with steps of uneven length, as Gauss-Newton ran on a corpus vehicle
    (seed 2032, vehicle 1, 40 + 56 km/h) at 4 RK4 steps per interval: every 23rd iterate repeats."""
    rng = np.random.default_rng(23)
    loop = np.cumsum(rng.normal(size=(23, 4)) * rng.uniform(1e-3, 1.4e-2, (23, 1)), axis=0)
    assert cycle(*_returns([loop[k % 23] for k in range(23 + 3 * CYCLE_RUN)]))


def test_a_cycle_through_a_step_the_line_search_cut_short_is_a_cycle():
    """A loop of three iterates, one reached by a step cut to 1e-3 of a full one, as Gauss-Newton
    ran on a tall van (cross-speed seed 2051, v03, 40 + 56 km/h) at 1 RK4 step per interval: a full
    step, a cut one, a full one back, each lap a little off the last."""
    a, b = np.array([1e-2, -2e-3, 4e-3]), np.array([-5e-3, 3e-3, 1e-3])
    cut = 1e-3 * (b - a)
    loop = [a, a + cut, b]
    iterates = [loop[k % 3] * (1 + 1e-3 * k) for k in range(3 + 3 * CYCLE_RUN)]
    assert cycle(*_returns(iterates))


@pytest.mark.parametrize("ratio", [0.5, 0.9])
def test_a_converging_run_with_steps_cut_short_is_not_a_cycle(ratio):
    """Steps toward a point, every third one cut to 1e-3 by the line search, never come back."""
    direction = np.array([1.0, -0.5, 0.25])
    distance = np.cumsum([ratio**k * (1e-3 if k % 3 == 1 else 1.0) for k in range(4 * CYCLE_RUN)])
    assert not cycle(*_returns([direction * d for d in distance]))


@pytest.mark.parametrize("ratio", [0.5, 0.9, 0.99])
def test_a_converging_run_is_not_a_cycle(ratio):
    """Steady steps toward a point, however slowly, never come back."""
    direction = np.array([1.0, -0.5, 0.25])
    iterates = [direction * (1 - ratio**k) for k in range(4 * CYCLE_RUN)]
    assert not cycle(*_returns(iterates))


def test_an_oscillation_that_closes_in_is_not_a_cycle():
    """Alternating steps that shrink by half each time do come back, but their steps shrink."""
    iterates = [np.array([(-0.5) ** k, 0.0]) for k in range(4 * CYCLE_RUN)]
    assert not cycle(*_returns(iterates))


def _watched_settle(objective_swing: float, violation: float) -> Watch:
    """A Watch on a settle's run (looks: settle) fed a loop of four iterates, as the settle of
    seed 3200's e03 (40 + 64 km/h, 16 RK4 steps) went round: steps of 0.1 to 0.16 in the scaled
    variables, the objective about 15.4 swinging by `objective_swing` (relative) from one
    iterate to the next, each constraint off by `violation`."""
    corners = [np.array(c, dtype=float) * 0.06 for c in ((1, 0), (0, 1), (-1, 0), (0, -1))]
    watch = Watch(2, 1)
    watch.start(np.zeros(1), np.zeros(1), None, frozenset({"settle"}))
    for k in range(2 * CYCLE_START):
        f = 15.4 * (1 + objective_swing * (-1) ** k)
        watch.eval([ca.DM(corners[k % 4]), ca.DM(f), ca.DM([violation]), ca.DM(), ca.DM(), ca.DM()])
        if watch.stopped is not None:
            break
    return watch


@pytest.mark.parametrize("objective_swing, violation", [(5e-3, 1e-8), (1e-7, 3e-4), (0.1, 5e-3)])
def test_a_settles_cycle_that_its_acceptable_level_refuses_is_unsettled(objective_swing, violation):
    """A settle's iterates going round with the objective swinging past SETTLE_OPTIONS' steady
    tolerance, or with the constraints off by more than its own, never settle: the watch sees the
    cycle as soon as the cycle rule would (CYCLE_START), and says it does not settle; also where
    the constraints are off by more than the cycle rule's CYCLE_VIOLATION (the settle of seed
    2062's te00, pendulum, 40 + 64 km/h: the objective swinging by 10 %, the constraints off by
    1e-3 to 1.4e-2)."""
    watch = _watched_settle(objective_swing, violation)
    assert watch.stopped == "unsettled" and watch.count == CYCLE_START


def test_a_settles_cycle_at_a_steady_objective_is_left_to_settle():
    """The same loop with the objective steady to SETTLE_OPTIONS' tolerance and the constraints
    met: the settle's acceptable level ends it, and the watch does not."""
    assert _watched_settle(SETTLE_OPTIONS["acceptable_obj_change_tol"] / 10, 1e-8).stopped is None


def test_a_collocation_nlp_regularizes_its_constraint_block_for_gauss_newton():
    """Collocation asks a Gauss-Newton solve for the permanent constraint regularization; shooting
    asks nothing; the problem's own IPOPT options win over both."""
    method = {
        "collocation": {"method": "collocation", "intervals": 20},
        "shooting": {"method": "multiple-shooting", "intervals": 20},
    }
    asked = {name: OptimalControl(make_case({"transcription": spec})).nlp.gauss_newton_options for name, spec in method.items()}
    assert asked == {"collocation": GAUSS_NEWTON_OPTIONS, "shooting": {}}
    opts = ipopt_options(Solver(ipopt={"perturb_always_cd": "no"}), verbose=False, fit=True, formulation=asked["collocation"])
    assert opts["perturb_always_cd"] == "no"
    assert opts["jacobian_regularization_value"] == GAUSS_NEWTON_OPTIONS["jacobian_regularization_value"]


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.parametrize("intervals", [120, 250])
def test_joint_collocation_fits_of_two_speeds_finish(intervals):
    """pickup-56kph's problem with the 40 km/h test, by collocation: without the constraint block
    regularized, MUMPS misjudges the inertia of these ill-conditioned KKT systems and the fits
    stall (70 and 299 iterations at 120 and 250 intervals); with it they take 21 or fewer
    (Gauss-Newton, then Newton for its tail), within issue 25's line for joint fits."""
    base = load_problem(PICKUP_56)
    problem = base.model_copy(update={"tests": [base.tests[0], load_problem(PICKUP_40).tests[0]]})
    solution = identify(
        Case(problem.with_values({"transcription": {"method": "collocation", "intervals": intervals}})), progress=None
    )
    assert solution.ok, solution.status
    assert solution.result.iterations <= ITERATION_LIMIT


def _pitch_bound_fit(degrees: float, k_front_kn: float):
    problem = load_problem(PICKUP_56).with_values(
        {"constraints.bounds": {"pitch": [None, f"{degrees} deg"]}, "vehicle.suspension.k_front": f"{k_front_kn} kN/m"}
    )
    return identify(Case(problem), progress=None)


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.parametrize("degrees, k_front_kn", [(3, 90), (4, 80)])
def test_the_64_case_grids_neighbours_both_converge(degrees, k_front_kn):
    """3 deg / 90 kN/m converges at one RK4 step per interval; 4 deg / 80 kN/m cycles there and
    finishes refined. Both hold the pitch bound at every node, and the bound is what holds them."""
    solution = _pitch_bound_fit(degrees, k_front_kn)
    assert solution.ok, solution.status
    assert solution.result.iterations <= ITERATION_LIMIT
    pitch = np.concatenate([t["pitch"] for t in solution.tests])
    assert np.max(pitch) <= np.deg2rad(degrees) + 1e-6
    assert abs(np.max(pitch) - np.deg2rad(degrees)) < 1e-4  # the bound is what holds the fit


@pytest.mark.integration
@pytest.mark.slow
def test_a_joint_shooting_fit_of_two_speeds_finishes_refined_at_the_same_optimum():
    """pickup-56kph's problem with the 40 km/h test added (the damper fixed), by multiple
    shooting: it cycles at one RK4 step per interval and finishes refined, where collocation of
    the same problem ends."""
    base = load_problem(PICKUP_56)
    problem = base.model_copy(update={"tests": [base.tests[0], load_problem(PICKUP_40).tests[0]]})
    shooting = identify(Case(problem), progress=None)
    assert shooting.ok, shooting.status
    assert shooting.result.iterations <= ITERATION_LIMIT
    assert any("cycled" in note for note in shooting.notes)
    assert shooting.case.problem.transcription.substeps > 1
    collocation = identify(
        Case(problem.with_values({"transcription": {"method": "collocation", "intervals": 200}})), progress=None
    )
    assert collocation.ok, collocation.status
    scale = np.abs(collocation.theta) + shooting.ocp.free.scale * 1e-3
    assert np.max(np.abs(shooting.theta - collocation.theta) / scale) < 0.02


@pytest.mark.integration
def test_a_fit_whose_forward_check_departs_is_refined_until_it_holds(tmp_path, monkeypatch):
    """Where the forward simulation of a converged fit departs from its NLP trajectory (as the
    hidden population's te01 at 40 + 56 km/h did by 3.5 mm of crush: a stiff bend of its spring
    crossed inside a 1 ms RK4 step), the fit is solved again from there with four times the
    steps, says so, and is judged by the check at those. The departure is stood in for at the
    first grid (the check itself is real at the refined one)."""
    import dataclasses

    from crashnlp.optimize import identify as identifying

    checks, real = [], identifying.verify

    def departing_at_first(case, p, tests):
        check = real(case, p, tests)
        checks.append(case.problem.transcription.substeps)
        if len(checks) > 1:
            return check
        mismatch = {t: {**m, "crush": 2 * check.allowed[t]["crush"]} for t, m in check.mismatch.items()}
        return dataclasses.replace(check, mismatch=mismatch, problem="56kph: the forward simulation departs from the NLP")

    monkeypatch.setattr(identifying, "verify", departing_at_first)
    solution = identify(Case(load_problem(small_pickup_problem(tmp_path))), progress=None)
    assert checks == [2, 8]
    assert solution.ok, solution.status
    (note,) = solution.notes
    assert "departs from the NLP" in note and "at 2 RK4 step(s)" in note and "with 8" in note
    assert solution.case.problem.transcription.substeps == 8 and not solution.verification.departs


def _run(status: str, stopped: str | None = None, tail: float | None = None) -> SolveResult:
    """One IPOPT run's result, as `_solve` returns it."""
    none = np.zeros(0)
    return SolveResult(np.ones(2), 1.0, none, none, none, status, 10, 0.0, 0.0, tail=tail, stopped=stopped)


def _scripted(monkeypatch, runs: list[SolveResult]) -> list[dict]:
    """`solve` on a Gauss-Newton fit whose IPOPT runs return `runs` in turn; the calls it made."""
    calls: list[dict] = []

    def run(nlp, spec, verbose, progress, start=None, looks=frozenset()):
        calls.append({"spec": spec, "start": start, "looks": looks})
        return runs[len(calls) - 1]

    monkeypatch.setattr(solve_module, "_solve", run)
    monkeypatch.setattr(solve_module, "hessian_kind", lambda nlp, spec: "gauss-newton")
    return calls


@pytest.mark.parametrize("refinable", [True, False])
def test_a_cycle_is_refined_where_the_steps_can_be_and_settled_where_not(monkeypatch, refinable):
    """A cycle ends a refinable solve (its caller refines the steps); any other solve settles it:
    Gauss-Newton warm from the cycle's iterate, to IPOPT's acceptable level (SETTLE_OPTIONS)."""
    cycled = _run("User_Requested_Stop", stopped="cycle")
    calls = _scripted(monkeypatch, [cycled, _run("Solved_To_Acceptable_Level")])
    result = solve_module.solve(None, Solver(), progress=None, refinable=refinable)
    assert calls[0]["looks"] == {"tail", "cycle"}
    if refinable:
        assert result.cycling and len(calls) == 1
        return
    assert result.converged and result.settled and result.iterations == 20
    assert calls[1]["start"] is cycled and calls[1]["looks"] == {"settle"}
    assert SETTLE_OPTIONS.items() <= calls[1]["spec"].ipopt.items()


def test_a_cycle_that_does_not_settle_is_finished_by_the_exact_hessian(monkeypatch):
    """Where the settle's own run is seen going round unsettled (crashnlp.optimize.watch), the
    exact Hessian finishes warm from the settle's iterate, every run counted."""
    runs = [
        _run("User_Requested_Stop", stopped="cycle"),
        _run("User_Requested_Stop", stopped="unsettled"),
        _run("Solve_Succeeded"),
    ]
    calls = _scripted(monkeypatch, runs)
    result = solve_module.solve(None, Solver(), progress=None)
    assert result.converged and not result.settled and result.unsettled and result.iterations == 30
    assert calls[1]["looks"] == {"settle"} and SETTLE_OPTIONS.items() <= calls[1]["spec"].ipopt.items()
    assert calls[2]["spec"].hessian == "exact" and calls[2]["start"].z is runs[1].z and len(calls) == 3


def test_gauss_newton_after_a_newton_that_did_not_finish_settles_its_cycle(monkeypatch):
    """Where Newton, started in Gauss-Newton's slow tail, does not finish, Gauss-Newton runs again
    looking for a cycle only (a tail there would hand over to Newton again), and settles it."""
    runs = [
        _run("User_Requested_Stop", tail=0.01),
        _run("Maximum_Iterations_Exceeded"),
        _run("User_Requested_Stop", stopped="cycle"),
        _run("Solved_To_Acceptable_Level"),
    ]
    calls = _scripted(monkeypatch, runs)
    result = solve_module.solve(None, Solver(), progress=None)
    assert result.converged and result.iterations == 40
    assert calls[1]["spec"].hessian == "exact" and calls[1]["start"] is runs[0]
    assert calls[2]["looks"] == {"cycle"} and calls[2]["start"] is None
    assert calls[3]["start"].z is runs[2].z  # warm from the cycle, the runs before it counted
