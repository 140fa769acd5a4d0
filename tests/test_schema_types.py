"""The validated problem holds what its types say: SI floats, frozen sections, unset entries left unset."""

from __future__ import annotations

import pickle

import pytest
import yaml
from builders import ROOT

from crashnlp.base.records import FrozenError, Record
from crashnlp.problem import ProblemError, load_problem, problem_from_dict
from crashnlp.problem.schema import with_fields

PICKUP = ROOT / "problems/pickup-56kph.yaml"


def pickup(**changes) -> dict:
    raw = yaml.safe_load(PICKUP.read_text())
    for path, value in changes.items():
        *parents, leaf = path.split("__")
        node = raw
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
        node[leaf] = value
    return raw


def numbers(node) -> list:
    """Every number under a validated section (its lists and tuples too)."""
    if isinstance(node, Record):
        return [x for name in type(node).model_fields for x in numbers(getattr(node, name))]
    if isinstance(node, (list, tuple)):
        return [x for v in node for x in numbers(v)]
    return [node] if isinstance(node, (int, float)) and not isinstance(node, bool) else []


def test_every_quantity_of_a_validated_problem_is_an_si_float():
    problem = load_problem(PICKUP)
    assert problem.vehicle.speed == pytest.approx(56 / 3.6) and problem.vehicle.suspension.c_front == 8e3
    assert problem.model.spring.values == [0.0] + [500e3] * 6
    assert problem.estimate["model.spring.values"].bounds == (0.0, 3e6)
    assert problem.estimate["vehicle.pitch_inertia"].bounds == (1000.0, 10000.0)
    quantities = numbers(problem.vehicle) + numbers(problem.model) + numbers(problem.estimate["vehicle.crush_offset"])
    assert len(quantities) > 30 and all(type(x) is float for x in quantities), quantities


def test_entries_whose_unit_another_entry_decides_are_converted_in_that_unit():
    secant = pickup(model__spring__law="secant", model__spring__values=["2 MN/m"] * 7, estimate={})
    assert problem_from_dict(secant, PICKUP.parent).model.spring.values == [2e6] * 7
    sigma = pickup(tests__0__data__channels__accel__sigma="0.5 g", constraints__bounds={"pitch": [None, "4 deg"]})
    problem = problem_from_dict(sigma, PICKUP.parent)
    assert problem.tests[0].data.channels["accel"].sigma == pytest.approx(0.5 * 9.80665)
    assert problem.constraints.bounds["pitch"] == pytest.approx((None, 4 * 3.141592653589793 / 180))
    with pytest.raises(ProblemError, match=r"^problem: model\.spring: '2 MN/m' does not convert to N$"):
        problem_from_dict(pickup(model__spring__values=["2 MN/m"] * 7), PICKUP.parent)
    with pytest.raises(ProblemError, match=r"^problem: tests\.0\.data\.channels\.accel\.sigma: Input should be a valid number$"):
        problem_from_dict(pickup(tests__0__data__channels__accel__sigma=[1]), PICKUP.parent)
    with pytest.raises(ProblemError, match=r"^problem: estimate\.vehicle\.crush_offset: '1 kg' does not convert to m$"):
        problem_from_dict(pickup(estimate={"vehicle.crush_offset": {"bounds": [0, "1 kg"]}}), PICKUP.parent)


@pytest.mark.parametrize("section", ["problem", "vehicle", "spring", "estimate"])
def test_a_validated_problem_is_frozen(section):
    problem = load_problem(PICKUP)
    target, field = {
        "problem": (problem, "name"),
        "vehicle": (problem.vehicle, "mass"),
        "spring": (problem.model.spring, "values"),
        "estimate": (problem.estimate["vehicle.crush_offset"], "bounds"),
    }[section]
    with pytest.raises(FrozenError, match="frozen"):
        setattr(target, field, None)


CHANGES_IN_PLACE = {
    "a damper value": lambda p: p.model.damper.values.__setitem__(0, -5e5),
    "a spring value": lambda p: p.model.spring.values.__setitem__(1, -1e9),
    "the breakpoints' order": lambda p: p.model.spring.crush_breakpoints.reverse(),
    "a test more": lambda p: p.tests.append(p.tests[0]),
    "an estimate entry": lambda p: p.estimate.pop("vehicle.crush_offset"),
    "a channel": lambda p: p.tests[0].data.channels.__delitem__("accel"),
    "an IPOPT option": lambda p: p.solver.ipopt.update(max_iter=1),
    "a list the code filled in": lambda p: with_fields(p.model.spring, values=[1.0] * 7).values.sort(),
}


@pytest.mark.parametrize("change", list(CHANGES_IN_PLACE))
def test_a_validated_problem_is_frozen_all_the_way_down(change):
    problem = load_problem(PICKUP)
    with pytest.raises(FrozenError, match="frozen.*with_values"):
        CHANGES_IN_PLACE[change](problem)
    assert problem == load_problem(PICKUP)


def test_a_validated_problem_is_hashable_and_dumps_its_lists_as_lists():
    problem = load_problem(PICKUP)
    assert hash(problem) == hash(load_problem(PICKUP)) and pickle.loads(pickle.dumps(problem)) == problem
    spring = problem.model_dump()["model"]["spring"]
    assert type(spring["values"]) is list and type(spring["crush_breakpoints"]) is list
    assert type(problem.model_dump()["estimate"]) is dict


def test_with_values_makes_a_changed_copy_that_leaves_unset_entries_unset():
    problem = load_problem(PICKUP)
    faster = problem.with_values({"vehicle.speed": "64 km/h", "model.spring.values": [0, *[600e3] * 6]})
    assert faster.vehicle.speed == pytest.approx(64 / 3.6) and faster.model.spring.values[1] == 600e3
    assert problem.vehicle.speed == pytest.approx(56 / 3.6) and problem.model.spring.values[1] == 500e3
    assert faster.vehicle.model_fields_set == problem.vehicle.model_fields_set
    assert "gravity" not in faster.vehicle.model_fields_set and "solver" not in faster.model_fields_set
    assert faster.base_dir == problem.base_dir


@pytest.mark.parametrize("method", ["multiple-shooting", "collocation"])
def test_an_error_inside_the_transcription_names_the_file_s_key_not_its_tag(method):
    """Validation locates an error in a tagged union under the tag ("transcription.collocation.
    intervals"); the file has no such key, so the message names the one it has."""
    with pytest.raises(ProblemError, match=r"^problem: transcription\.intervals: Input should be greater than or equal to 2$"):
        problem_from_dict(pickup(transcription={"method": method, "intervals": 0}), PICKUP.parent)


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        (
            {
                "vehicle__masss": 1,
                "vehicle__cg_to_impact": None,
                "transcription": {"method": "collocation", "intervals": 0, "degree": 12},
            },
            "vehicle.cg_to_impact: missing key; vehicle.masss: unknown key; transcription.intervals: Input should be greater than"
            " or equal to 2; transcription.degree: Input should be less than or equal to 9",
        ),
        (
            {"objective__loss": "l3", "solver__expand": "maybe", "simulation__rtol": 0, "uncertainty__points": "7"},
            "objective.loss: Input should be 'l2' or 'l1'; solver.expand: Input should be a valid boolean, unable to interpret"
            " input; simulation.rtol: Input should be greater than 0",
        ),
        (
            {"uncertainty__points": 7.5, "uncertainty__workers": 0, "simulation__substeps": "x"},
            "simulation.substeps: Input should be a valid integer, unable to parse string as an integer; uncertainty.points:"
            " Input should be a valid integer, got a number with a fractional part; uncertainty.workers: Input should be greater"
            " than or equal to 1",
        ),
    ],
)
def test_every_error_of_a_file_is_said_in_one_line_at_its_key(changes, expected):
    """A file's errors all at once, in the order of the schema's keys, each in the words the schema's
    validation has always used (crashnlp.base.records: pydantic's, kept when pydantic went)."""
    raw = pickup(**{k: v for k, v in changes.items() if v is not None})
    for path in [k for k, v in changes.items() if v is None]:
        *parents, leaf = path.split("__")
        node = raw
        for key in parents:
            node = node[key]
        del node[leaf]
    with pytest.raises(ProblemError) as err:
        problem_from_dict(raw, PICKUP.parent)
    assert str(err.value) == f"problem: {expected}"


@pytest.mark.parametrize(("given", "got"), [(None, "nothing"), ([1, 2], "a list"), ("fast", "a text")])
def test_a_section_given_as_something_else_says_what_it_got_in_a_file_s_words(given, got):
    """`simulation:` left empty, or given a list or a text: the key, what belongs there and what
    came, not a Python class's name."""
    raw = pickup()
    raw["simulation"] = given
    with pytest.raises(ProblemError) as err:
        problem_from_dict(raw, PICKUP.parent)
    assert str(err.value) == f"problem: simulation: Input should be a section of keys (key: value), got {got}"


def test_a_lax_value_is_read_as_its_type():
    """A whole number given as text or as a float, and yes/no for a switch, read as their types."""
    problem = problem_from_dict(
        pickup(
            uncertainty__points="7", transcription={"method": "collocation", "intervals": 40.0}, constraints__monotone_crush="yes"
        ),
        PICKUP.parent,
    )
    assert problem.uncertainty.points == 7 and type(problem.transcription.intervals) is int
    assert problem.constraints.monotone_crush is True
