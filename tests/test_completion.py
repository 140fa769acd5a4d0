"""What a problem leaves out, filled in from the data: breakpoints, spring values, unloading, estimate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from builders import ROOT, merge
from scipy.interpolate import PchipInterpolator

from crashnlp.case.case import Case
from crashnlp.case.completion import (
    DEFAULT_COUNT,
    LEVEL,
    MAX_COUNT,
    REACH,
    complete,
    measured_pulses,
    repaired_start,
    resolution,
    several_speeds,
    spring_values,
    unloading_stiffness,
)
from crashnlp.case.segmentation import MIN_SPACING
from crashnlp.models.pendulum import PITCH_LEVER, PITCH_LEVER_BOUNDS, pitch_lever_bounds
from crashnlp.optimize.identify import repair_start
from crashnlp.problem import ProblemError, load_problem, problem_from_dict
from crashnlp.problem.load import read_yaml

PICKUP = ROOT / "problems" / "pickup-56kph.yaml"


def pickup(**changes) -> dict:
    """The shipped pickup problem as a dict, with `changes` merged in (None deletes)."""
    return merge(read_yaml(PICKUP), changes)


@pytest.fixture(scope="module")
def pickup_case() -> Case:
    return Case(load_problem(PICKUP))


def test_breakpoints_span_the_measured_crush_where_the_curve_bends(pickup_case):
    """From 0 to the largest crush, none closer than the shortest segment allows, one at the
    bumper's first peak (0.05 m in the load curve the pickup's data were made with), and the
    piecewise-linear curve through them follows that load curve closer than through even ones."""
    pulses = measured_pulses(pickup_case.problem, pickup_case.tests)
    crush = max(p.max_displacement for p in pulses)
    assert crush == pytest.approx(0.593, abs=0.002)  # the data set's truth
    bps = np.array(resolution(pulses, DEFAULT_COUNT)[0])
    assert bps.size == DEFAULT_COUNT and bps[0] == 0.0
    assert bps[-1] == pytest.approx(REACH * crush)
    assert np.min(np.diff(bps)) >= MIN_SPACING * bps[-1] / (DEFAULT_COUNT - 1) - 1e-12
    assert np.min(np.abs(bps - 0.05)) < 0.005
    ref = pickup_case.problem.reference.force_crush
    truth = PchipInterpolator(ref.crush, ref.force)
    x = np.linspace(0.0, crush, 500)
    misses = [np.sqrt(np.mean((np.interp(x, b, truth(b)) - truth(x)) ** 2)) for b in (bps, np.linspace(0.0, crush, bps.size))]
    assert misses[0] < 0.7 * misses[1]


def test_the_data_choose_the_fewest_breakpoints_whose_curve_follows_their_loading_curve(pickup_case):
    """The Camry's loading curve (NHTSA 10146: its peaks and folds) asks for 14 breakpoints: 13
    leave more than LEVEL per unit of mass, 14 less. The synthetic pickup's smooth one is followed
    within a fifth of LEVEL by DEFAULT_COUNT already. A count or a list the problem gives is kept,
    and the data's choice is said beside it."""
    camry = Case(load_problem(ROOT / "problems" / "nhtsa-10146.yaml"))
    pulses = measured_pulses(camry.problem, camry.tests)
    placed, chosen = resolution(pulses)
    assert (chosen.count, chosen.chosen, len(placed)) == (14, "data", 14) and chosen.misfit <= LEVEL
    assert resolution(pulses, 13)[1].misfit > LEVEL
    assert chosen.misfit < resolution(pulses, DEFAULT_COUNT)[1].misfit / 3
    pickup = measured_pulses(pickup_case.problem, pickup_case.tests)
    placed, chosen = resolution(pickup)
    assert chosen.count == DEFAULT_COUNT < MAX_COUNT and chosen.misfit < LEVEL / 5
    given = resolution(pulses, [0.0, 0.4, 0.8])[1]
    assert (given.count, given.chosen, given.data_count) == (3, "list", 14) and given.misfit > LEVEL
    assert "the data would choose 14" in given.note


def test_spring_values_follow_the_true_load_curve(pickup_case):
    """m|a| against crush while loading recovers the generator's load curve within 3 % inside the
    crush range, at breakpoints apart from its first peak (a band around a peak averages it down)."""
    pulses = measured_pulses(pickup_case.problem, pickup_case.tests)
    bps = list(np.linspace(0.0, max(p.max_displacement for p in pulses), DEFAULT_COUNT))
    ref = pickup_case.problem.reference.force_crush
    truth = PchipInterpolator(ref.crush, ref.force)(bps)
    values = np.array(spring_values(bps, pulses, "force", pickup_case.problem.model.damper))
    inside = slice(1, -1)  # 0 and the breakpoint past the largest crush are not measured at a point
    assert np.allclose(values[inside], truth[inside], rtol=0.03)


def test_unloading_stiffness_from_the_rebound_is_of_the_right_order(pickup_case):
    k = unloading_stiffness(measured_pulses(pickup_case.problem, pickup_case.tests))
    assert 0.5 * 3e7 < k < 2 * 3e7  # the data were made with 30 MN/m


def test_minimal_problem_is_completed_without_changing_the_given_one():
    raw = pickup(
        model={"spring": {"crush_breakpoints": {"count": 6}, "values": None}, "damper": None, "unloading": {"stiffness": None}},
        estimate=None,
    )
    given = problem_from_dict(raw, PICKUP.parent)
    case = Case(given)
    filled = case.problem
    assert given.model.spring.values is None and given.estimate == {}  # the given problem stays as it was
    assert len(filled.model.spring.crush_breakpoints) == 6 == len(filled.model.spring.values)
    assert filled.model.damper.values == pytest.approx([2.0 * 2550] * 2)  # nominal: 2 /s times the mass
    assert 1e7 < filled.model.unloading.stiffness < 1e8
    bounds = {path: spec.bounds for path, spec in filled.estimate.items()}
    assert set(bounds) == {
        "model.spring.values",
        "model.unloading.stiffness",
        "vehicle.cg_above_impact",
        "vehicle.pitch_inertia",
        PITCH_LEVER,
    }
    lo, hi = bounds["vehicle.pitch_inertia"]
    assert lo < 4800 < hi and bounds["vehicle.cg_above_impact"][0] < 0.18 < bounds["vehicle.cg_above_impact"][1]
    assert bounds[PITCH_LEVER] == PITCH_LEVER_BOUNDS  # one test: an effective lever's bounds
    assert bounds["model.spring.values"][1] >= 2 * max(filled.model.spring.values)


@pytest.mark.parametrize(("height", "top"), [("0.42 m", 0.42), ("0 m", 0.0), ("-0.05 m", 0.0)])
def test_at_several_speeds_the_pitch_lever_reaches_up_to_the_cg_height_above_the_impact_point(height, top, pickup_case):
    """The wall's force acts where the front end meets it, so its moment about the CG is at most the
    force times the CG's height above the impact point; a CG at or below it gets no nose-down lever.
    A fit of one test keeps the effective lever's bounds."""
    problem = problem_from_dict(pickup(vehicle={"cg_above_impact": height}, estimate=None), PICKUP.parent)
    (measured,) = measured_pulses(pickup_case.problem, pickup_case.tests)
    slower = dataclasses.replace(measured, speed=40 / 3.6)
    assert pitch_lever_bounds(problem, several_speeds([measured, slower])) == (PITCH_LEVER_BOUNDS[0], pytest.approx(top))
    assert (
        pitch_lever_bounds(problem, several_speeds([measured, dataclasses.replace(measured, speed=0.95 * measured.speed)]))
        == PITCH_LEVER_BOUNDS
    )
    assert pitch_lever_bounds(problem, several_speeds([measured])) == PITCH_LEVER_BOUNDS


def test_no_pitch_channel_estimates_the_front_end_only():
    raw = pickup(model={"spring": {"crush_breakpoints": None, "values": None}}, estimate=None)
    del raw["tests"][0]["data"]["channels"]["pitch"]
    filled = Case(problem_from_dict(raw, PICKUP.parent)).problem
    assert set(filled.estimate) == {"model.spring.values", "model.unloading.stiffness"}


def test_values_need_listed_breakpoints():
    raw = pickup(model={"spring": {"crush_breakpoints": {"count": 7}}})
    with pytest.raises(ProblemError, match="model.spring: values need crush_breakpoints given as a list"):
        problem_from_dict(raw, PICKUP.parent)


def test_breakpoints_without_data_are_refused():
    raw = pickup(model={"spring": {"crush_breakpoints": None, "values": None}}, estimate=None)
    raw["tests"] = [{"name": "t", "duration": 0.1}]
    with pytest.raises(Exception, match="model.spring.crush_breakpoints: not given, and no test has accel or velocity data"):
        Case(problem_from_dict(raw, PICKUP.parent))


def test_complete_keeps_what_the_problem_gives(pickup_case):
    """A complete problem comes back equal (the shipped problems do not change)."""
    problem = load_problem(PICKUP)
    assert complete(problem, measured_pulses(pickup_case.problem, pickup_case.tests))[0].model_dump() == problem.model_dump()


def test_repaired_start_reaches_the_measured_crush():
    """A stiff start at the pickup's own breakpoints, repaired from the data, crushes as far as the data."""
    raw = pickup(model={"spring": {"values": ["1500 kN"] * 7}})  # stops far short of the measured 0.593 m
    case = Case(problem_from_dict(raw, PICKUP.parent))
    short = np.max(case.simulate()["56kph"]["displacement"])
    start = case.layout.with_values(case.base, repaired_start(case.problem, case.tests))
    reached = np.max(case.simulate(start)["56kph"]["displacement"])
    assert short < 0.4 and reached == pytest.approx(0.593, rel=0.05)
    original = case.base.copy()
    repaired, note = repair_start(case)
    assert note.startswith(
        f"pickup-56kph: the initial values stop test 56kph at a max displacement of {short * 1e3:.0f} mm, the data's is 594 mm"
    )
    assert np.array_equal(repaired.base, start) and np.array_equal(case.base, original)  # a copy; the case is kept
    assert repair_start(repaired) == (repaired, None)  # repaired once, then it reaches


def test_a_start_that_moves_every_value_is_left_alone():
    """500 kN everywhere stops the pickup at about 0.56 m, past every breakpoint but the last,
    whose value moves the force from 0.55 m on: no value has a zero derivative, nothing to repair."""
    case = Case(problem_from_dict(pickup(), PICKUP.parent))
    assert repair_start(case) == (case, None)


def test_crush_from_acceleration_alone_matches_the_displacement_channel(pickup_case):
    """Without displacement or velocity channels the crush is the acceleration integrated twice from the impact speed."""
    raw = pickup(model={"spring": {"crush_breakpoints": None, "values": None}}, estimate=None)
    channels = raw["tests"][0]["data"]["channels"]
    for name in ("velocity", "displacement", "pitch"):
        del channels[name]
    accel_only = Case(problem_from_dict(raw, PICKUP.parent))
    (measured,) = measured_pulses(pickup_case.problem, pickup_case.tests)
    (integrated,) = measured_pulses(accel_only.problem, accel_only.tests)
    assert integrated.max_displacement == pytest.approx(measured.max_displacement, rel=0.01)
    assert accel_only.problem.model.spring.crush_breakpoints[-1] == pytest.approx(REACH * measured.max_displacement, rel=0.01)


def test_tests_at_two_speeds_estimate_the_damper_one_speed_does_not(tmp_path):
    from bench.corpus import measured, random_vehicle, simulate, write_csv
    from bench.robustness import minimal_problem

    v = random_vehicle(1, 2030)
    raw = minimal_problem(v, "a.csv")
    write_csv(tmp_path / "a.csv", measured(v, simulate(v)))
    one = Case(problem_from_dict(raw, tmp_path)).problem
    assert "model.damper.values" not in one.estimate
    faster = dataclasses.replace(v, speed=1.3 * v.speed)
    write_csv(tmp_path / "b.csv", measured(faster, simulate(faster)))
    second = merge(raw["tests"][0], {"name": "t2", "speed": faster.speed, "data": {"file": "b.csv"}})
    two = Case(
        problem_from_dict({**raw, "vehicle": {**raw["vehicle"], "speed": None}, "tests": [raw["tests"][0], second]}, tmp_path)
    )
    lo, hi = two.problem.estimate["model.damper.values"].bounds
    assert lo == 0.0 and hi > two.problem.model.damper.values[0] > 0.0  # the nominal damper inside its bounds
