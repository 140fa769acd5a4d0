"""The identified vehicle a fit hands on: its complete model, its uncertainty and its range.

A fit completes its problem from the data (crashnlp.case.completion) and then estimates some of its
entries. `IdentifiedModel` keeps all of it: every vehicle and model entry in SI with the
fitted values in place, the covariance of the estimated ones, the range of crush, speed and
mass the fitted tests covered, and how far the model's own crash metrics missed the data's on
those tests. result.json stores it under `identified_model`; `apply` puts it into another
problem of the same vehicle (a new speed, mass or duration), so that a prediction needs no
more than the fit's result and a problem that names what is new.

The dataclasses need numpy only, as a Result read back does (crashnlp.results); the functions
that make problems import the problem schema when they are called.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.base.choices import CFC_CLASSES
from crashnlp.base.errors import InputError
from crashnlp.base.outputs import OUTPUT, OUTPUTS, Z95

if TYPE_CHECKING:
    from crashnlp.problem.schema import Problem

# the vehicle's geometry: a problem that gives other values describes another vehicle
GEOMETRY = ("cg_to_impact", "cg_to_front_axle", "cg_to_rear_axle")
# relative: geometry this close is the same vehicle, given in other units (8.0381 ft for 2.45 m is 5e-6
# apart, five significant digits of feet); 0.1 mm in a metre is finer than a vehicle is measured
SAME_GEOMETRY = 1e-4
# the model's structure (section, field): given otherwise by a problem, it is another model
STRUCTURE = (("spring", "law"), ("spring", "crush_breakpoints"), ("damper", "rate_breakpoints"), ("unloading", "law"))
SAME = 1e-9  # relative: values closer than this are the same
SPRING_VALUES = "model.spring.values"
DAMPER_VALUES = "model.damper.values"
UNLOADING_STIFFNESS = "model.unloading.stiffness"
# what a Case fills in from its own data when a problem leaves it out (crashnlp.case.completion): a
# fit writes the value it used, so a null here is an edited file, and a prediction would read it from
# the predicted test's data
FROM_DATA = ("vehicle.mass", SPRING_VALUES, UNLOADING_STIFFNESS)
# the estimates whose zero means none (no force): a 95 % interval that takes it in does not tell them from none
NONE_AT_ZERO = (SPRING_VALUES, DAMPER_VALUES, UNLOADING_STIFFNESS)
TAKES_IN_ZERO = "95 % interval takes in zero (the data do not tell the value from none)"
EDITED = "(a result.json edited by hand?)"  # the likeliest cause of a result.json crashnlp would not have written


@dataclass(frozen=True)
class IdentifiedRange:
    """What the fitted tests covered: the largest measured displacement (the CG's travel), the speeds and
    masses of the tests, the largest front-end crush the model went through in them, how far
    the data determine its loading curve, and each test's impact energy, m v^2 / 2 (SI; none in
    a result written before they were kept). A prediction beyond it extrapolates."""

    max_displacement: float
    speeds: tuple[float, float]
    masses: tuple[float, float]
    model_crush: float
    energies: tuple[float, ...] = ()

    def beyond(self, max_displacement: float, speed: float, mass: float) -> dict[str, float]:
        """How far a simulated test lies past the range: max displacement in m and relative, speed in m/s,
        mass in kg, each only where it is past; empty inside the range."""
        out: dict[str, float] = {}
        if max_displacement > self.max_displacement * (1 + 1e-3):
            out["displacement_m"] = max_displacement - self.max_displacement
            out["displacement_rel"] = max_displacement / self.max_displacement - 1.0
        for key, value, (lo, hi) in (("speed_mps", speed, self.speeds), ("mass_kg", mass, self.masses)):
            past = value - hi if value > hi * (1 + 1e-6) else value - lo if value < lo * (1 - 1e-6) else 0.0
            if past:
                out[key] = past
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "max_displacement_m": self.max_displacement,
            "speeds_mps": list(self.speeds),
            "masses_kg": list(self.masses),
            "model_crush_m": self.model_crush,
            "energies_j": list(self.energies),
        }

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> IdentifiedRange:
        energies = tuple(float(e) for e in raw.get("energies_j", ()))
        travel, model_crush = float(raw["max_displacement_m"]), float(raw["model_crush_m"])
        return cls(travel, _pair(raw["speeds_mps"]), _pair(raw["masses_kg"]), model_crush, energies)


def _pair(values: Any) -> tuple[float, float]:
    lo, hi = (float(v) for v in values)
    return lo, hi


@dataclass(frozen=True)
class IdentifiedModel:
    """A fitted vehicle, complete (see the module's docstring). SI throughout.

    `labels` name the estimated entries one number each ("model.spring.values[3]"), in the
    order of `covariance` (None where the data do not determine a value) and `bounds`.
    `discrepancy`: per crash metric, the root mean square over the fitted tests of the model's
    relative miss of the data's value; a metric no fitted test measured is absent.
    `accel_filter`: the CFC class the fitted tests' accelerometers were read through, where they
    name one and agree (None: unfiltered); a prediction reads its acceleration through it, so
    that its peak is the fitted tests' kind of peak (crashnlp.analysis.prediction). `designed`: a
    design's vehicle (crashnlp design), its values chosen for a goal, fitted to no data."""

    vehicle: dict[str, Any]
    model: dict[str, Any]
    parameters: dict[str, float | list[float]]
    labels: tuple[str, ...]
    covariance: np.ndarray | None
    bounds: tuple[tuple[float, float], ...]
    range: IdentifiedRange
    discrepancy: dict[str, float] = field(default_factory=dict)
    channel_rmse: dict[str, float] = field(default_factory=dict)
    accel_filter: str | None = None
    designed: bool = False

    def to_json(self) -> dict[str, Any]:
        cov = None if self.covariance is None else [[_finite(x) for x in row] for row in self.covariance]
        return {
            "vehicle": self.vehicle,
            "model": self.model,
            "parameters": self.parameters,
            "labels": list(self.labels),
            "covariance": cov,
            "bounds": [[_finite(lo), _finite(hi)] for lo, hi in self.bounds],
            "range": self.range.to_json(),
            "discrepancy": self.discrepancy,
            "channel_rmse": {OUTPUT[c].key: v for c, v in self.channel_rmse.items()},  # the SI unit in the key
            "accel_filter": self.accel_filter,
        } | ({"designed": True} if self.designed else {})

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> IdentifiedModel:
        cov = raw.get("covariance")
        matrix = None if cov is None else np.array([[np.inf if x is None else x for x in row] for row in cov], dtype=float)
        bounds = tuple((-np.inf if lo is None else lo, np.inf if hi is None else hi) for lo, hi in raw["bounds"])
        return cls(
            raw["vehicle"],
            raw["model"],
            raw["parameters"],
            tuple(raw["labels"]),
            matrix,
            bounds,
            IdentifiedRange.from_json(raw["range"]),
            dict(raw.get("discrepancy", {})),
            _by_channel(raw.get("channel_rmse", {})),
            raw.get("accel_filter"),
            raw.get("designed") is True,
        )

    @property
    def tail_line(self) -> dict[str, float] | None:
        """The line its loading curve bends into past the fitted tests' crush (`start`, m, and
        `slope`, N/m); None where its law continues its segments (`segment`, or a design's `trend`,
        which no fit has put in place)."""
        tail = self.model["spring"].get("tail")
        return tail if isinstance(tail, dict) else None

    def tail_notes(self) -> tuple[str, ...]:
        """What a prediction's loading curve does past the crush the fit reached, and which fitted
        values lie past it (none without a tail)."""
        tail = self.tail_line
        if tail is None:
            return ()
        note = (
            f"past {1e3 * tail['start']:.0f} mm of crush (the model reached {1e3 * self.range.model_crush:.0f} mm in the"
            f" fitted tests) a prediction's loading curve follows its trend, {1e-3 * tail['slope']:.0f} kN/m"
        )
        shaping = shaping_nothing_short_of(self.labels, self.model["spring"]["crush_breakpoints"], tail["start"])
        past = [label for label, out in zip(self.labels, shaping) if out]
        if past:
            note += f"; past it, no test determines {', '.join(past)}, and predictions follow the trend instead"
        return (note,)

    def as_problem(self, name: str, source: str | None = None) -> Problem:
        """The identified vehicle as a problem of one data-free test at its speed: what reads the
        model without its data (the units of its entries, its model's functions) takes this. It is
        validated as a problem file is, and what a prediction reads beside it as a fit writes it
        (`refuse_out_of_shape`): an entry out of shape (a result.json edited by hand) is an
        InputError naming `source` (the file it came from; `name` without one) and the entry."""
        from crashnlp.problem.schema import problem_from_dict  # the schema: not for a result read back

        self.refuse_unfilled(source or name)
        self.refuse_out_of_shape(source or name)
        raw = {"name": name, "vehicle": self.vehicle, "model": self.model, "tests": [{"name": "identified"}]}
        return problem_from_dict(raw, Path("."), source or name)

    def refuse_unfilled(self, source: str) -> None:
        """An InputError naming `source` and the entry where an entry of FROM_DATA is missing or null."""
        for path in FROM_DATA:
            section, *keys = path.split(".")
            node: Any = {"vehicle": self.vehicle, "model": self.model}[section]
            for key in keys:
                node = node.get(key) if isinstance(node, dict) else None
            if node is None:
                raise InputError(
                    f"{source}: identified_model.{path} is missing or null: a fit writes the value it used, and a prediction "
                    f"would take it from its own test's data instead {EDITED}"
                )

    def refuse_out_of_shape(self, source: str) -> None:
        """An InputError naming `source` and the entry where what a prediction reads beside the
        vehicle and the model is not as a fit writes it: bounds or a covariance that are not one
        entry, or one row and column, per label; a covariance holding nan (a fit writes null, read as
        infinite, where the data do not determine a value) or a variance below zero; a range,
        discrepancy or channel RMSE below zero or not a number; an accelerometer filter that is no
        CFC class. Each would shift or break a prediction's intervals and notes without a word."""
        n = len(self.labels)
        if len(self.bounds) != n:
            raise InputError(f"{source}: identified_model.bounds has {len(self.bounds)} entries for {n} labels {EDITED}")
        if self.covariance is not None:
            if self.covariance.shape != (n, n):
                rows = "x".join(map(str, self.covariance.shape))
                raise InputError(f"{source}: identified_model.covariance is {rows} for {n} labels {EDITED}")
            for i, row in enumerate(self.covariance):
                if np.isnan(row).any() or row[i] < 0:
                    what = "holds a value that is not a number" if np.isnan(row).any() else f"has the variance {row[i]:g}"
                    raise InputError(f"{source}: identified_model.covariance row {i} ({self.labels[i]}) {what} {EDITED}")
        for entry, value in self._not_negative():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < math.inf:
                raise InputError(f"{source}: identified_model.{entry} is {value}: must be a number, not negative {EDITED}")
        if self.accel_filter is not None and (not isinstance(self.accel_filter, str) or self.accel_filter not in CFC_CLASSES):
            classes = ", ".join(CFC_CLASSES)
            raise InputError(
                f"{source}: identified_model.accel_filter is {self.accel_filter!r}: one of {classes}, or null {EDITED}"
            )

    def _not_negative(self) -> list[tuple[str, Any]]:
        """(entry, value) of each number result.json keeps beside the model that is zero or above."""
        r = self.range
        spans = [("range.speeds_mps", r.speeds), ("range.masses_kg", r.masses), ("range.energies_j", r.energies)]
        return [
            ("range.max_displacement_m", r.max_displacement),
            ("range.model_crush_m", r.model_crush),
            *((f"{entry}[{i}]", v) for entry, values in spans for i, v in enumerate(values)),
            *((f"discrepancy.{key}", v) for key, v in self.discrepancy.items()),
            *((f"channel_rmse.{OUTPUT[c].key if c in OUTPUT else c}", v) for c, v in self.channel_rmse.items()),
        ]

    def std(self) -> np.ndarray:
        """Standard error of each labelled value; inf where the data do not determine it."""
        if self.covariance is None:
            return np.full(len(self.labels), np.inf)
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def takes_in_zero(self, profiles: Mapping[str, Mapping[str, Any]]) -> tuple[str, ...]:
        """The labels of the estimated values whose zero means none (NONE_AT_ZERO: the spring's and
        damper's values, the unloading stiffness) and whose 95 % interval takes in zero
        (TAKES_IN_ZERO): the lower end of the profile's interval where `profiles` (Result.profiles)
        has one, else value - Z95 std with a finite standard error, cut at the lower bound as the
        report's interval is (one above zero keeps the interval off it). Only values off their
        bounds count: one at a bound is said to be there, and one the data do not determine at all
        (an infinite standard error) is not identified instead. An offset or a height, whose zero
        means nothing (at a bound's lower end or not), never is."""
        values = self._labelled_values()
        return tuple(
            label
            for label, s, (lo, hi) in zip(self.labels, self.std(), self.bounds)
            if label.partition("[")[0] in NONE_AT_ZERO
            and label in values
            and lo < values[label] < hi
            and max(_lower_end(profiles.get(label), values[label], s), lo) <= 0
        )

    def _labelled_values(self) -> dict[str, float]:
        """The estimated values by label, as `labels` names them (an entry of one value by its path)."""
        out: dict[str, float] = {}
        for path, value in self.parameters.items():
            values = value if isinstance(value, list) else [value]
            out |= {path: values[0]} if len(values) == 1 else {f"{path}[{k}]": v for k, v in enumerate(values)}
        return out


def takes_in_zero_note(values: Collection[str]) -> str:
    """The line that says which values' 95 % interval takes in zero (TAKES_IN_ZERO), each as
    `values` gives it (a label, or a label with its value and where it stands), "none" for none:
    the console, the report, the export's curve notes and result.json's notes word it alike."""
    return f"{TAKES_IN_ZERO}: {', '.join(values) or 'none'}"


def _lower_end(profile: Mapping[str, Any] | None, value: float, std: float) -> float:
    """The lower end of a value's 95 % interval, before its bound cuts it: its profile's where it
    has one (-inf where the profile did not close below: it ran to the bound, or runs on past the
    values profiled, for all it says to the bound), else value - Z95 std (inf without a finite
    standard error: no interval to speak of)."""
    if profile and profile.get("points"):
        return -math.inf if profile.get("lower") is None else float(profile["lower"])
    return value - Z95 * std if np.isfinite(std) else math.inf


def shaping_nothing_short_of(labels: tuple[str, ...] | list[str], breakpoints: Any, crush: float) -> np.ndarray:
    """Per labelled estimate, whether it shapes no loading force short of `crush` (m): a spring
    value whose breakpoint and the one before it lie at or past that crush (the value at the first
    breakpoint shapes the curve from zero). Tests that stop short of the crush cannot determine
    such a value, and a loading curve that follows its trend from there leaves it out."""
    x = np.asarray(breakpoints, float)
    past = np.concatenate([[False], x[:-1] >= crush]) if x.size else np.zeros(0, bool)
    out = np.zeros(len(labels), bool)
    for j, label in enumerate(labels):
        path, _, index = label.partition("[")
        if path == SPRING_VALUES and index:
            out[j] = past[int(index.rstrip("]"))]
    return out


def without_entries(covariance: np.ndarray, left_out: np.ndarray) -> np.ndarray:
    """`covariance` with the rows and columns of the `left_out` entries zero: what it says of the
    others, for a quantity those entries do not shape (their own may be infinite)."""
    return np.where(left_out[:, None] | left_out[None, :], 0.0, covariance)


def _by_channel(rmse: dict[str, float]) -> dict[str, float]:
    """`channel_rmse` as result.json keeps it, by the channel's key with its SI unit ("accel_mps2"),
    keyed by channel name; files written before the key said the unit have the name alone."""
    names = {o.key: o.name for o in OUTPUTS}
    return {names.get(key, key): value for key, value in rmse.items()}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def load_applied(path: str | Path, identified: IdentifiedModel, source: str) -> Problem:
    """A problem file with the identified vehicle in it (`applied`)."""
    from crashnlp.problem.load import read_yaml

    path = Path(path)
    return applied(read_yaml(path), path.resolve().parent, identified, source, str(path))


def applied(raw: Any, base_dir: Path, identified: IdentifiedModel, source: str, name: str) -> Problem:
    """A problem given as a plain dict (`name` its file, which its errors name) with the identified
    vehicle in it (`apply`). What it leaves out comes from the identified vehicle before it is
    validated: every vehicle entry, and every section of the model (spring, damper, ...; a section
    it gives is its own, whole), so that a prediction of only `name` and `tests` is a problem."""
    from crashnlp.problem.schema import problem_from_dict

    identified.as_problem("identified", source)  # an entry it brings out of shape names `source`, not the file
    if isinstance(raw, dict):
        vehicle, model = ({} if raw.get(key) is None else raw[key] for key in ("vehicle", "model"))
        raw = {**raw, "vehicle": _filled(vehicle, identified.vehicle), "model": _filled(model, identified.model, deep=False)}
    return _put_in(problem_from_dict(raw, base_dir, source=name), identified, source)


def _filled(given: Any, theirs: dict[str, Any], deep: bool = True) -> Any:
    """A section of a problem file with the entries it leaves out taken from `theirs`, and with
    `deep`, those of the mappings inside it too (what the file gives wins; a section that is not a
    mapping is left for the schema to refuse)."""
    if not isinstance(given, dict):
        return given
    inner = {k: _filled(v, theirs[k]) for k, v in given.items() if deep and isinstance(theirs.get(k), dict)}
    return {**theirs, **given, **inner}


def apply(problem: Problem, identified: IdentifiedModel, source: str) -> Problem:
    """`problem` with the identified vehicle in it: the whole model section (but a tail the
    problem gives), the estimated vehicle entries, and every vehicle entry the problem leaves out.
    The problem's own speeds, masses, durations and tests stay; a problem whose geometry or model
    structure differs from the identified vehicle's, or an identified model out of shape (a
    result.json edited by hand: `IdentifiedModel.as_problem`), is refused (InputError naming
    `source` and the entry)."""
    identified.as_problem(problem.name, source)
    return _put_in(problem, identified, source)


def _put_in(problem: Problem, identified: IdentifiedModel, source: str) -> Problem:
    """`apply` of an identified model already validated."""
    from crashnlp.problem.schema import problem_from_dict

    _refuse_another_vehicle(problem, identified, source)
    raw = problem.model_dump(mode="python", exclude_unset=True)
    given = problem.vehicle.model_fields_set
    vehicle = dict(raw.get("vehicle", {}))
    for key, value in identified.vehicle.items():
        if key not in given or _estimated(identified, f"vehicle.{key}"):
            vehicle[key] = value
    raw["vehicle"] = vehicle
    raw["model"] = _model(problem, identified)
    raw["estimate"] = {}
    return problem_from_dict(raw, problem.base_dir, source)


def _model(problem: Problem, identified: IdentifiedModel) -> dict[str, Any]:
    """The identified model section, with the problem's own `model.spring.tail` where it gives a
    line or `segment`: the user's word on the force past the fitted crush wins (`trend` is what
    the identified model holds already)."""
    spring = problem.model.spring
    if "tail" not in spring.model_fields_set or spring.tail == "trend":
        return identified.model
    tail = spring.tail if isinstance(spring.tail, str) else spring.tail.model_dump()
    return {**identified.model, "spring": {**identified.model["spring"], "tail": tail}}


def _estimated(identified: IdentifiedModel, path: str) -> bool:
    """Whether the fit estimated the entry at `path` or one inside it (vehicle.suspension.k_front)."""
    return any(p == path or p.startswith(path + ".") for p in identified.parameters)


def _refuse_another_vehicle(problem: Problem, identified: IdentifiedModel, source: str) -> None:
    from crashnlp.problem.forms import DEFAULT_FORM  # the problem layer: not for a result read back

    given = problem.vehicle.model_fields_set
    for key in GEOMETRY:
        mine, theirs = getattr(problem.vehicle, key), identified.vehicle.get(key)
        if key in given and theirs is not None and not same(mine, theirs, SAME_GEOMETRY):
            raise InputError(
                f"{source}: vehicle.{key}: the problem's is {mine:g} m, the identified vehicle's {theirs:g} m: "
                "another vehicle (a result predicts the vehicle it was fitted to)"
            )
    theirs_form = identified.model.get("form", DEFAULT_FORM)
    if "form" in problem.model.model_fields_set and problem.model.form != theirs_form:
        raise InputError(
            f"{source}: model.form: the problem's is {problem.model.form}, the identified vehicle's {theirs_form}: "
            "another model (a result predicts the model it was fitted with)"
        )
    for section, key in STRUCTURE:
        node = getattr(problem.model, section)
        theirs = (identified.model.get(section) or {}).get(key)
        if node is None or key not in node.model_fields_set or theirs is None:
            continue
        mine = getattr(node, key)
        if _differs(mine, theirs):
            raise InputError(
                f"{source}: model.{section}.{key}: the problem's is {mine}, the identified vehicle's {theirs}: "
                "another model (a result predicts the model it was fitted with)"
            )


def _differs(mine: Any, theirs: Any) -> bool:
    """Whether the problem's structure entry names another model than the identified one's: a list
    differs in length or a value, a count (`{count: N}`, which the fit placed as N breakpoints) in N."""
    from crashnlp.problem.schema import BreakpointCount

    if isinstance(mine, BreakpointCount):
        return not isinstance(theirs, list) or mine.count != len(theirs)
    if isinstance(mine, tuple) or isinstance(theirs, list):
        return not isinstance(mine, tuple) or len(mine) != len(theirs) or not all(map(same, mine, theirs))
    return mine != theirs


def same(a: float, b: float, tolerance: float = SAME) -> bool:
    """Whether two values are the same to a relative `tolerance` (a number written to result.json
    and read back is the same as itself)."""
    return abs(a - b) <= tolerance * max(abs(a), abs(b), 1e-12)
