"""The problem file schema: what a YAML problem may say, validated and converted to SI.

Every quantity field accepts a plain number (SI) or a string with units. Fields
tagged with `Unit` know their SI unit, which also lets `estimate` and `sweep`
entries name them by dotted path and give bounds with units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    WithJsonSchema,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from crashnlp.outputs import MEASURABLE, OUTPUT
from crashnlp.problem.ipopt import check_ipopt
from crashnlp.units import to_si

QuantityIn = float | str
LARGEST = 1e12  # no quantity of this model comes near it in SI; beyond it is a typo or an attack


def si(value: Any, unit: str) -> float:
    """`to_si`, refusing values the model cannot integrate: NaN, infinite or absurdly large."""
    v = to_si(value, unit)
    if not math.isfinite(v):
        raise ValueError(f"{value!r} is not a finite number")
    if abs(v) > LARGEST:
        raise ValueError(f"{value!r} is beyond any physical value here (|value| <= {LARGEST:g} in SI)")
    return v


def _positive(v: float | None) -> float | None:
    if v is not None and v <= 0:
        raise ValueError("must be positive")
    return v


def _not_negative(v: float | None) -> float | None:
    if v is not None and v < 0:
        raise ValueError("must not be negative")
    return v


def folder_name(v: str) -> str:
    """A name that becomes a folder of the results: one path segment, printable, at most 100 characters."""
    if not v or v.strip() != v or v in (".", "..") or len(v) > 100:
        raise ValueError("must be 1 to 100 characters, without surrounding spaces, and not . or ..")
    if any(c in v for c in "/\\") or not v.isprintable():
        raise ValueError("must not contain / or \\ or control characters (it names a results folder)")
    return v


FolderName = Annotated[str, AfterValidator(folder_name)]


MASSES = (1.0, 1e6)  # kg: from a scale model to a loaded truck; outside is a unit mistake
MAX_SPEED = 150.0  # m/s (540 km/h): no crash test comes near it


def _mass(v: float | None) -> float | None:
    if v is not None and not MASSES[0] <= v <= MASSES[1]:
        raise ValueError(f"{v:g} kg is no vehicle's mass ({MASSES[0]:g} kg to {MASSES[1]:g} kg)")
    return v


def _speed(v: float | None) -> float | None:
    _not_negative(v)
    if v is not None and v > MAX_SPEED:
        raise ValueError(f"{v:g} m/s is faster than any crash test (at most {MAX_SPEED:g} m/s)")
    return v


@dataclass(frozen=True)
class Unit:
    """Marks a field as a physical quantity stored in SI `unit`."""

    si: str


@dataclass(frozen=True)
class Structural:
    """Marks a numeric field that shapes the model and is never a free parameter."""


def Q(unit: str):
    """A float field in SI `unit` that also accepts strings with units."""
    return Annotated[
        float,
        BeforeValidator(lambda v: si(v, unit)),
        WithJsonSchema({"anyOf": [{"type": "number"}, {"type": "string"}], "description": f"SI unit {unit}"}),
        Unit(unit),
    ]


def QList(unit: str):
    return Annotated[list[Q(unit)], Unit(unit)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=False, allow_inf_nan=False)

    def unit_of(self, field: str) -> str | None:
        """SI unit of a field, or None for a field that is not a quantity."""
        info = type(self).model_fields.get(field)
        if info is None:
            return None
        if any(isinstance(m, Structural) for m in info.metadata):
            return None
        return _find_unit([info.annotation, *info.metadata])


def _find_unit(items: list[Any]) -> str | None:
    """Unit marker in a field's annotation, looking through Optional and Annotated."""
    for item in items:
        if isinstance(item, Structural):
            return None
        if isinstance(item, Unit):
            return item.si
        args = get_args(item)
        if args:
            found = _find_unit(list(args) + list(getattr(item, "__metadata__", ())))
            if found is not None:
                return found
    return None


def _increasing(values: list[float], what: str) -> list[float]:
    if len(values) < 2:
        raise ValueError(f"{what} needs at least two breakpoints")
    if any(b <= a for a, b in zip(values, values[1:])):
        raise ValueError(f"{what} must be strictly increasing")
    return values


# --------------------------------------------------------------------------- vehicle
class Suspension(Strict):
    k_front: Q("N/m") = 0.0
    k_rear: Q("N/m") = 0.0
    c_front: Q("N*s/m") = 0.0
    c_rear: Q("N*s/m") = 0.0

    _not_negative = field_validator("k_front", "k_rear", "c_front", "c_rear")(lambda v: _not_negative(v))


class Vehicle(Strict):
    mass: Q("kg") | None = Field(None, description="test mass; may come from the data header")
    speed: Annotated[Q("m/s") | None, Structural()] = Field(None, description="impact speed (a test may override)")
    pitch_inertia: Q("kg*m^2") = Field(0.0, description="about the CG; 0 is the paper's point mass")
    cg_to_impact: Q("m") = Field(description="horizontal distance CG to the impact point")
    cg_above_impact: Q("m") = 0.0
    cg_to_front_axle: Q("m")
    cg_to_rear_axle: Q("m")
    suspension: Suspension = Suspension()
    crush_offset: Q("m") = Field(
        0.0,
        description="distance of the crush force's line of action from the pivot-CG line; > 0 pitches nose-down",
    )
    gravity: Q("m/s^2") = 9.80665

    @field_validator("mass", "cg_to_impact", "cg_to_front_axle", "cg_to_rear_axle", "gravity")
    @classmethod
    def _positive(cls, v):
        return _positive(v)

    @field_validator("pitch_inertia")
    @classmethod
    def _not_negative(cls, v):
        return _not_negative(v)

    _check_mass = field_validator("mass")(lambda v: _mass(v))
    _check_speed = field_validator("speed")(lambda v: _speed(v))  # 0: a vehicle at rest


# --------------------------------------------------------------------------- model
SPRING_UNITS = {"force": "N", "secant": "N/m"}


class BreakpointCount(Strict):
    """Breakpoints to be placed over the data's crush range (crashnlp.autoinit)."""

    count: int = Field(ge=2, le=30, description="number of breakpoints, 0 included")


class Spring(Strict):
    law: Literal["force", "secant"] = Field(
        "force", description="force: F(x) piecewise linear; secant: F = k(x) x, k piecewise linear (paper Eq. 1)"
    )
    crush_breakpoints: QList("m") | BreakpointCount | None = Field(
        None, description="crush at the breakpoints; omitted or {count: N}: placed over the data's crush range"
    )
    values: list[QuantityIn] | None = Field(
        None, description="forces (law force) or secant stiffnesses (law secant); omitted: from the measured force-crush curve"
    )

    @field_validator("crush_breakpoints")
    @classmethod
    def _bp(cls, v):
        return _increasing(v, "crush_breakpoints") if isinstance(v, list) else v

    @model_validator(mode="after")
    def _values(self):
        if self.values is None:
            return self
        if not isinstance(self.crush_breakpoints, list):
            raise ValueError("values need crush_breakpoints given as a list")
        self.values = [si(v, SPRING_UNITS[self.law]) for v in self.values]
        if len(self.values) != len(self.crush_breakpoints):
            raise ValueError(f"values has {len(self.values)} entries but crush_breakpoints has {len(self.crush_breakpoints)}")
        return self

    def unit_of(self, field: str) -> str | None:
        return SPRING_UNITS[self.law] if field == "values" else super().unit_of(field)


class Damper(Strict):
    rate_breakpoints: QList("m/s")
    values: QList("N*s/m")

    @field_validator("rate_breakpoints")
    @classmethod
    def _bp(cls, v):
        return _increasing(v, "rate_breakpoints")

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.values) != len(self.rate_breakpoints):
            raise ValueError(f"values has {len(self.values)} entries but rate_breakpoints has {len(self.rate_breakpoints)}")
        return self


class Unloading(Strict):
    law: Literal["elastic", "plastic"] = "elastic"
    stiffness: Q("N/m") | None = Field(
        None, description="unloading stiffness of the plastic law; omitted: from the data's rebound"
    )

    @field_validator("stiffness")
    @classmethod
    def _positive(cls, v):
        if v is not None and v <= 0:
            raise ValueError("must be positive")
        return v


class Smoothing(Strict):
    """Width of the smoothed hinges at breakpoints (keeps IPOPT away from kinks); 0 = exact kinks."""

    crush: Annotated[Q("m"), Structural()] = 1e-3
    rate: Annotated[Q("m/s"), Structural()] = 1e-3

    _not_negative = field_validator("crush", "rate")(lambda v: _not_negative(v))


class Model(Strict):
    spring: Spring = Spring()
    damper: Damper | None = Field(None, description="omitted: none, or a nominal one when the spring values come from the data")
    unloading: Unloading = Unloading()
    smoothing: Smoothing = Smoothing()


# --------------------------------------------------------------------------- data
CHANNEL_UNITS = {name: OUTPUT[name].unit for name in MEASURABLE}
ChannelName = Literal["accel", "velocity", "displacement", "pitch", "barrier_force"]
assert set(get_args(ChannelName)) == set(MEASURABLE), "the channels a problem names are the measurable outputs"
CFC = Literal["CFC60", "CFC180", "CFC600", "CFC1000"]
DEFAULT_FILTER: dict[str, CFC] = {"barrier_force": "CFC60"}  # SAE J211 for barrier load cells; `filter: null`: raw
SUMMED = ("barrier_force",)  # the curves of a force are cells of one wall, summed; other channels' are averaged
AllBarrierFx = Literal["all-valid-barrier-fx"]  # EV5: every load cell (sensor LC, axis XG, a force) the header marks valid
ALL_BARRIER_FX: str = get_args(AllBarrierFx)[0]


class TimeColumn(Strict):
    column: str
    unit: str = "s"


class ChannelSpec(Strict):
    column: str | None = Field(None, description="CSV column")
    curves: list[int] | AllBarrierFx | None = Field(
        None,
        description="NHTSA EV5 curve numbers, averaged (barrier_force: summed); all-valid-barrier-fx: every valid"
        " barrier Fx load cell of the test",
    )
    code: str | None = Field(None, description="ISO-MME channel code")
    unit: str | None = Field(None, description="unit of the stored values; EV5 and MME files carry their own")
    filter: CFC | None = Field(None, description="SAE J211 filter class; barrier_force: CFC60 unless given (null: none)")
    sign: Literal[1, -1] = Field(
        1,
        description="multiplies the stored values into the model frame (x toward the barrier; barrier_force: compression"
        " positive, so -1 for NHTSA load cells)",
    )
    derive: Literal["integrate"] | None = Field(None, description="integrate the accel channel from the impact speed")
    sigma: QuantityIn | None = Field(None, description="scale of the residuals; default per channel")
    weight: float = Field(1.0, ge=0.0)


class DataSpec(Strict):
    file: Path
    format: Literal["csv", "nhtsa-ev5", "iso-mme"] = "csv"
    time: TimeColumn = TimeColumn(column="time_s")
    window: tuple[Q("s"), Q("s")] | None = None
    bias_window: tuple[Q("s"), Q("s")] | None = Field(None, description="pre-impact samples whose mean is removed")
    channels: dict[ChannelName, ChannelSpec]

    @field_validator("file")
    @classmethod
    def _exists(cls, v: Path, info: ValidationInfo):
        base = Path((info.context or {}).get("base_dir", "."))
        path = v if v.is_absolute() else base / v
        if not path.exists():
            raise ValueError(f"file not found: {path}")
        return path.resolve()

    @field_validator("window", "bias_window")
    @classmethod
    def _ordered(cls, v):
        if v is not None and v[1] <= v[0]:
            raise ValueError("window end must be after its start")
        return v

    @model_validator(mode="after")
    def _channels(self):
        """Default filters, curve lists that fit their channel, and sigmas in SI."""
        for name, ch in self.channels.items():
            if name in DEFAULT_FILTER and "filter" not in ch.model_fields_set:
                ch.filter = DEFAULT_FILTER[name]
            if ch.curves == ALL_BARRIER_FX and name != "barrier_force":
                raise ValueError(f"channels.{name}: curves {ALL_BARRIER_FX} are barrier forces, a barrier_force channel")
            if ch.sigma is not None:
                ch.sigma = _positive(si(ch.sigma, CHANNEL_UNITS[name]))
        return self


class Test(Strict):
    name: FolderName
    speed: Q("m/s") | None = None
    mass: Q("kg") | None = None
    duration: Q("s") | None = None
    data: DataSpec | None = None

    _positive = field_validator("duration")(lambda v: _positive(v))
    _check_mass = field_validator("mass")(lambda v: _mass(_positive(v)))
    _check_speed = field_validator("speed")(lambda v: _speed(v))


# --------------------------------------------------------------------------- identification
OUTPUT_UNITS = {
    "displacement": "m",
    "velocity": "m/s",
    "accel": "m/s^2",
    "pitch": "rad",
    "crush": "m",
    "barrier_force": "N",
}
OutputName = Literal["displacement", "velocity", "accel", "pitch", "crush", "barrier_force"]
Bound = tuple[QuantityIn | None, QuantityIn | None]


class EstimateSpec(Strict):
    initial: QuantityIn | list[QuantityIn] | None = Field(None, description="default: the value in the problem")
    bounds: Bound | None = None
    prior_scale: QuantityIn | None = Field(None, description="scale of the decision variable; default from bounds")


class Constraints(Strict):
    monotone_crush: bool = Field(False, description="crush does not decrease until its maximum")
    monotone_spring: bool = Field(False, description="spring values non-decreasing")
    bounds: dict[OutputName, Bound] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _convert(self):
        self.bounds = {k: tuple(None if b is None else si(b, OUTPUT_UNITS[k]) for b in v) for k, v in self.bounds.items()}
        for k, (lo, hi) in self.bounds.items():
            if lo is not None and hi is not None and lo > hi:
                raise ValueError(f"bounds.{k}: lower bound above upper bound")
        return self


class Objective(Strict):
    loss: Literal["l2", "l1"] = "l2"
    regularization: float = Field(
        0.0, ge=0.0, description="weight of the smoothness prior on the spring values' slope changes (crashnlp.optimize.prior)"
    )


MAX_INTERVALS = 10_000  # beyond this the NLP does not fit in memory, let alone solve


class MultipleShootingSpec(Strict):
    method: Literal["multiple-shooting"]
    intervals: int = Field(200, ge=2, le=MAX_INTERVALS)
    substeps: int = Field(1, ge=1, le=100)


class CollocationSpec(Strict):
    method: Literal["collocation"]
    intervals: int = Field(200, ge=2, le=MAX_INTERVALS)
    degree: int = Field(3, ge=1, le=9)
    scheme: Literal["radau", "legendre"] = "radau"


TranscriptionSpec = Annotated[MultipleShootingSpec | CollocationSpec, Field(discriminator="method")]


class Solver(Strict):
    ipopt: dict[str, Any] = Field(default_factory=dict, description="options passed to IPOPT")
    hessian: Literal["auto", "exact", "gauss-newton", "limited-memory"] = Field(
        "auto", description="auto: Gauss-Newton for a least-squares fit (loss l2), exact otherwise"
    )
    expand: bool = Field(False, description="expand the NLP's functions to SX when they run in CasADi's virtual machine")
    compile: Literal["auto", "now", "never"] = Field(
        "auto",
        description="the NLP's functions in C, cached per problem shape: auto uses a cached library and else compiles"
        " one in the background for the next run; now compiles before solving; never stays in CasADi's virtual machine",
    )

    @field_validator("ipopt")
    @classmethod
    def _ipopt(cls, v: dict[str, Any]) -> dict[str, Any]:
        """Refuse what IPOPT would refuse, each error at its key (solver.ipopt.max_itr)."""
        errors = [
            InitErrorDetails(type=PydanticCustomError("ipopt_option", "{why}", {"why": why}), loc=(name,), input=v[name])
            for name, why in check_ipopt(v).items()
        ]
        if errors:
            raise ValidationError.from_exception_data("ipopt", errors)
        return v


class Uncertainty(Strict):
    """Profile-likelihood intervals, beyond the sandwich standard errors, for chosen parameters."""

    profile: list[str] = Field(
        default_factory=list, description="estimated entries to profile, e.g. vehicle.cg_above_impact or model.spring.values[2]"
    )
    points: int = Field(4, ge=2, le=20, description="re-optimisations on each side, 0.75 std apart")
    executor: Literal["local", "dask"] = Field("local", description="where the profiles run in parallel (the study executors)")
    workers: int | None = Field(None, ge=1)


class Simulation(Strict):
    integrator: Literal["cvodes", "rk"] = "cvodes"
    substeps: int = Field(4, ge=1, le=1000, description="rk sub-steps per output step")
    rtol: float = Field(1e-8, gt=0.0, lt=1.0)
    atol: float = Field(1e-10, gt=0.0, lt=1.0)
    dt: Q("s") = Field(1e-4, description="output step")
    duration: Q("s") = Field(0.25, description="when a test gives neither duration nor data")

    _positive = field_validator("dt", "duration")(lambda v: _positive(v))


class Design(Strict):
    minimize: Literal["peak_decel", "olc", "crush"] = "peak_decel"


class ForceCrush(Strict):
    crush: QList("m")
    force: QList("N")

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.crush) != len(self.force):
            raise ValueError("crush and force need the same number of entries")
        return self


class Reference(Strict):
    """Known curves drawn beside the identified ones (FE load-cell data, or a synthetic truth)."""

    force_crush: ForceCrush | None = None


class Problem(Strict):
    name: FolderName
    kind: Literal["identify", "design"] = "identify"
    vehicle: Vehicle
    model: Model
    tests: list[Test] = Field(min_length=1)
    estimate: dict[str, EstimateSpec] = Field(default_factory=dict)
    constraints: Constraints = Constraints()
    objective: Objective = Objective()
    transcription: TranscriptionSpec = Field(default_factory=lambda: MultipleShootingSpec(method="multiple-shooting"))
    solver: Solver = Solver()
    simulation: Simulation = Simulation()
    uncertainty: Uncertainty = Uncertainty()
    design: Design | None = None
    reference: Reference = Reference()
    base_dir: Annotated[Path, WithJsonSchema({"type": "null"})] = Field(Path("."), exclude=True)

    @model_validator(mode="after")
    def _check(self):
        names = [t.name for t in self.tests]
        if len(set(names)) != len(names):
            raise ValueError("tests: names must be unique")
        for path, spec in self.estimate.items():
            unit = self.unit_at(path)
            try:
                if spec.initial is not None:
                    spec.initial = (
                        [si(v, unit) for v in spec.initial] if isinstance(spec.initial, list) else si(spec.initial, unit)
                    )
                if spec.bounds is not None:
                    spec.bounds = tuple(None if b is None else si(b, unit) for b in spec.bounds)
                if spec.prior_scale is not None:
                    spec.prior_scale = si(spec.prior_scale, unit)
            except ValueError as exc:
                raise ValueError(f"estimate.{path}: {exc}") from None
            self._initial_within_bounds(path, spec)
        return self

    def _initial_within_bounds(self, path: str, spec: EstimateSpec) -> None:
        """Refuse an initial value (given, or the problem's own) outside the entry's estimate bounds."""
        if spec.bounds is None:
            return
        lo = -math.inf if spec.bounds[0] is None else spec.bounds[0]
        hi = math.inf if spec.bounds[1] is None else spec.bounds[1]
        if lo > hi:
            raise ValueError(f"estimate.{path}.bounds: lower bound above upper bound")
        given = spec.initial is not None
        value = spec.initial if given else self.value_at(path)
        values = value if isinstance(value, list) else [value]
        outside = [v for v in values if isinstance(v, (int, float)) and not lo <= v <= hi]
        if outside:
            where = "initial" if given else f"the problem's value of {path}"
            raise ValueError(f"estimate.{path}: {where} {outside[0]:g} is outside the bounds [{lo:g}, {hi:g}] (SI)")

    def value_at(self, path: str) -> Any:
        """The value of an entry named by dotted path, or None when the problem has none there."""
        node: Any = self
        for key in path.split("."):
            node = getattr(node, key, None) if isinstance(node, BaseModel) else None
        return node

    def speed(self, test: Test) -> float | None:
        return test.speed if test.speed is not None else self.vehicle.speed

    def with_values(self, values: dict[str, Any]) -> Problem:
        """A new validated problem with entries replaced by dotted path ("vehicle.speed": "64 km/h",
        "model.spring.values": [...], "tests.0.speed": ...); this one is left as it is. What the
        problem left out stays left out (`model_fields_set`), so that the new problem is still
        completed from its data, and a result's identified vehicle still fills it in."""
        from crashnlp.problem.load import problem_from_dict

        full = self.model_dump(mode="python", exclude_none=False)
        raw = self.model_dump(mode="python", exclude_unset=True)
        for path, value in values.items():
            *parents, leaf = path.split(".")
            node: Any = full
            try:
                for key in parents:
                    node = node[int(key)] if isinstance(node, list) else node[key]
                if isinstance(node, list) or leaf not in node:
                    raise KeyError(path)
            except (KeyError, IndexError, ValueError, TypeError):
                raise KeyError(path) from None
            node = raw
            for key in parents:
                node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
            node[leaf] = value
        return problem_from_dict(raw, self.base_dir, "with_values")

    def unit_at(self, path: str) -> str:
        """SI unit of a numeric entry named by dotted path ("model.spring.values")."""
        *parents, leaf = path.split(".")
        node: Any = self
        for key in parents:
            node = getattr(node, key, None) if isinstance(node, BaseModel) else None
            if node is None:
                break
        unit = node.unit_of(leaf) if isinstance(node, Strict) else None
        if unit is None:
            raise ValueError(f"estimate.{path}: not a numeric entry of the problem")
        return unit
