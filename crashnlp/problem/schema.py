"""The problem file schema: what a YAML problem may say, validated and converted to SI.

Two types meet in every quantity. What a file may give is a `QuantityIn`: a plain number
(SI) or a string with units ("56 km/h"). What a validated `Problem` holds is a float in SI.
A field of a fixed unit says so in its type (`Length`, `Speed`, ...: a float marked with its
`Unit`, which converts the file's value); a field whose unit another entry decides (spring
values by the law, a channel's sigma by the channel, bounds by what they bound) is an
`SIValue`, converted by its model's validator before the fields are checked. The unit
markers also let `estimate` and `sweep` entries name fields by dotted path and give bounds
with units. A validated problem is frozen: `Problem.with_values` makes a changed copy.

The sections are records of crashnlp.base.records, which reads their annotations as the classes
are defined: objects, not strings (no `from __future__ import annotations`).
"""

import copy
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Self, TypeVar, get_args

from crashnlp.base.choices import CFC_CLASSES, DATA_FORMATS, DESIGN_OBJECTIVES, EXECUTORS, SPRING_LAWS, UNLOADING_LAWS
from crashnlp.base.outputs import BOUNDED, MEASURABLE, OUTPUT
from crashnlp.base.records import (
    AfterValidator,
    BeforeValidator,
    Conversion,
    CustomError,
    Discriminator,
    Field,
    Record,
    Tag,
    ValidationError,
    ValidationInfo,
    WithJsonSchema,
    error,
    field_validator,
    model_validator,
)
from crashnlp.base.units import G0, UnitError, to_si
from crashnlp.problem.errors import ProblemError, all_errors
from crashnlp.problem.forms import DEFAULT_FORM, FORMS
from crashnlp.problem.ipopt import check_ipopt

QuantityIn = float | str  # what a file may give for a quantity: a number (SI) or a string with units
QUANTITY_IN_SCHEMA: dict[str, Any] = {"anyOf": [{"type": "number"}, {"type": "string"}]}
LARGEST = 1e12  # no quantity of this model comes near it in SI; beyond it is a typo or an attack


def si(value: Any, unit: str) -> float:
    """`to_si`, refusing values the model cannot integrate: NaN, infinite or absurdly large."""
    v = to_si(value, unit)
    if not math.isfinite(v):
        raise ValueError(f"{value!r} is not a finite number")
    if abs(v) > LARGEST:
        raise ValueError(f"{value!r} is beyond any physical value here (|value| <= {LARGEST:g} in SI)")
    return v


def _quantity_in_si(value: Any, unit: str) -> Any:
    """A file's number or text in SI `unit`. Any other value, and a number that is not finite, stay as
    they are: the field's own check refuses them at their key."""
    if isinstance(value, float) and not math.isfinite(value):
        return value
    return si(value, unit) if isinstance(value, (int, float, str)) else value


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


def _impact_speed(v: float | None) -> float | None:
    """A what-if's speed: a crash's, so above 0."""
    if v == 0:
        raise ValueError("0 m/s is no impact")
    return _speed(v)


def stated_speed(value: QuantityIn) -> QuantityIn:
    """An impact speed, refused (UnitError) as text without a unit: a plain "64" would be 64 m/s
    (230 km/h), and no data stand against it in a simulation (a fit's data do,
    crashnlp.case.testcase): a what-if's speed, init's, and a problem's own (`ImpactSpeed`: a file's
    `speed: "64"`, with_values' "64"). A number (a Python one, or a YAML one unquoted) stays SI."""
    if not isinstance(value, str):
        return value
    try:
        number = float(value)
    except ValueError:
        return value
    if not math.isfinite(number):
        return value
    raise UnitError(f'give its unit, e.g. "{number:g} km/h" or "{number:g} m/s"')


def what_if(speed: QuantityIn | None, mass: QuantityIn | None, prefix: str = "") -> tuple[float | None, float | None]:
    """A speed and a mass given outside a problem file ("64 km/h", "1650 kg"; a Python number is
    SI, a speed's text needs its unit: stated_speed), in SI and checked as a file's are; a
    ProblemError names `prefix` + speed or mass."""
    out = []
    for name, value, unit, check in (("speed", speed, "m/s", _impact_speed), ("mass", mass, "kg", _mass)):
        try:
            given = stated_speed(value) if name == "speed" and value is not None else value
            si = None if given is None else to_si(given, unit)
            if si is not None and not math.isfinite(si):
                raise ValueError("not a finite number")
            out.append(check(si))
        except ValueError as exc:
            raise ProblemError(f"{prefix}{name} {value}: {exc}") from None
    return out[0], out[1]


@dataclass(frozen=True)
class Unit(Conversion):
    """Marks a float field as a physical quantity in SI `si`: the file gives a `QuantityIn`,
    which validation converts (`si`), and the field holds the SI float."""

    si: str

    def before(self, value: Any) -> float:
        return si(value, self.si)

    def json_schema(self) -> dict[str, Any]:
        return {**QUANTITY_IN_SCHEMA, "description": f"SI unit {self.si}"}


@dataclass(frozen=True)
class Structural:
    """Marks a numeric field that shapes the model and is never a free parameter."""


Length = Annotated[float, Unit("m")]
Speed = Annotated[float, Unit("m/s")]
ImpactSpeed = Annotated[float, BeforeValidator(stated_speed), Unit("m/s")]  # its text needs a unit: stated_speed
Acceleration = Annotated[float, Unit("m/s^2")]
Time = Annotated[float, Unit("s")]
Mass = Annotated[float, Unit("kg")]
Inertia = Annotated[float, Unit("kg*m^2")]
Force = Annotated[float, Unit("N")]
Stiffness = Annotated[float, Unit("N/m")]
Damping = Annotated[float, Unit("N*s/m")]
SIValue = Annotated[float, WithJsonSchema(QUANTITY_IN_SCHEMA)]  # a float in SI; its model's validator converts the file's
Bound = tuple[SIValue | None, SIValue | None]


class Strict(Record):
    """A section of a problem: unknown keys refused, and frozen once validated."""

    def unit_of(self, field: str) -> str | None:
        """SI unit of a field, or None for a field that is not a quantity."""
        return _field_unit(type(self), field)


def _field_unit(section: type[Record], field: str, structural: bool = False) -> str | None:
    """SI unit of a field the type `section` declares, or None for one that is not a quantity; a
    quantity that shapes the model (`Structural`: vehicle.speed) counts only where `structural`."""
    info = section.model_fields.get(field)
    if info is None or (not structural and any(isinstance(m, Structural) for m in info.metadata)):
        return None
    return _find_unit([info.annotation, *info.metadata], structural)


_S = TypeVar("_S", bound=Strict)
_T = TypeVar("_T")


def _filled_in(value: _T | None, path: str) -> _T:
    """A value a Case fills in from the data when the file leaves it out (crashnlp.case.completion), once filled in."""
    if value is None:
        raise RuntimeError(f"{path}: not filled in from the data yet (a Case does that)")
    return value


def with_fields(section: _S, **values: Any) -> _S:
    """A copy of a validated section with fields replaced, that leaves what the file gave
    (`model_fields_set`) as it was: a section filled in from the data is not given by the file."""
    return section.replaced(values, section.model_fields_set)


def _find_unit(items: list[Any], structural: bool = False) -> str | None:
    """Unit marker in a field's annotation, looking through Optional and Annotated; None under a
    `Structural` marker unless `structural`."""
    for item in items:
        if isinstance(item, Structural) and not structural:
            return None
        if isinstance(item, Unit):
            return item.si
        args = get_args(item)
        if args:
            found = _find_unit(list(args) + list(getattr(item, "__metadata__", ())), structural)
            if found is not None:
                return found
    return None


def _increasing(values: tuple[float, ...], what: str) -> tuple[float, ...]:
    if len(values) < 2:
        raise ValueError(f"{what} needs at least two breakpoints")
    if any(b <= a for a, b in zip(values, values[1:])):
        raise ValueError(f"{what} must be strictly increasing")
    return values


# --------------------------------------------------------------------------- vehicle
class Suspension(Strict):
    k_front: Stiffness = 0.0
    k_rear: Stiffness = 0.0
    c_front: Damping = 0.0
    c_rear: Damping = 0.0

    _not_negative = field_validator("k_front", "k_rear", "c_front", "c_rear")(lambda v: _not_negative(v))


class Engine(Strict):
    """An engine on mounts that meets the barrier once its gap closes (model.form engine-on-mounts;
    other forms leave it out). Omitted entries are filled in by the form (crashnlp.models.engine_on_mounts)."""

    mass: Mass | None = Field(None, description="part of vehicle.mass; omitted: a share of it")
    mount_stiffness: Stiffness | None = Field(None, description="the mounts along x; omitted: from a nominal frequency")
    mount_damping: Damping | None = Field(None, description="the mounts along x; omitted: from a nominal damping ratio")
    gap: Length | None = Field(None, description="the engine's travel toward the barrier before it touches; omitted: from data")
    contact_stiffness: Stiffness | None = Field(None, description="of its contact with the barrier (compression only)")
    contact_damping: Damping | None = Field(None, description="of its contact with the barrier")

    _positive = field_validator("mass", "gap", "contact_stiffness")(lambda v: _positive(v))
    _not_negative = field_validator("mount_stiffness", "mount_damping", "contact_damping")(lambda v: _not_negative(v))


class Vehicle(Strict):
    mass: Mass | None = Field(None, description="test mass; may come from the data header")
    speed: Annotated[ImpactSpeed | None, Structural()] = Field(None, description="impact speed (a test may override)")
    pitch_inertia: Inertia = Field(0.0, description="about the CG; 0 is the paper's point mass")
    cg_to_impact: Length = Field(description="horizontal distance CG to the impact point")
    cg_above_impact: Length = 0.0
    cg_to_front_axle: Length
    cg_to_rear_axle: Length
    suspension: Suspension = Suspension()
    crush_offset: Length = Field(
        0.0,
        description="distance of the crush force's line of action from the pivot-CG line; > 0 pitches nose-down",
    )
    gravity: Acceleration = G0
    engine: Engine | None = Field(None, description="an engine on mounts (model.form engine-on-mounts)")

    @field_validator("mass", "cg_to_impact", "cg_to_front_axle", "cg_to_rear_axle", "gravity")
    @classmethod
    def _positive(cls, v: float | None) -> float | None:
        return _positive(v)

    @field_validator("pitch_inertia")
    @classmethod
    def _not_negative(cls, v: float) -> float | None:
        return _not_negative(v)

    _check_mass = field_validator("mass")(lambda v: _mass(v))
    _check_speed = field_validator("speed")(lambda v: _speed(v))  # 0: a vehicle at rest

    @property
    def known_mass(self) -> float:
        """The mass, once known: a Case takes it from a test or a data header when the file leaves it out."""
        return _filled_in(self.mass, "vehicle.mass")


# --------------------------------------------------------------------------- model


class BreakpointCount(Strict):
    """Breakpoints to be placed over the data's crush range (crashnlp.case.completion)."""

    count: int = Field(ge=2, le=30, description="number of breakpoints, 0 included")


class Tail(Strict):
    """The loading curve past `start`: the straight line from the law's force there, rising at `slope`."""

    start: Length = Field(description="crush from which the line replaces the law")
    slope: Stiffness = Field(
        description="the line's rise of force per crush (not negative: a crushed front end does not weaken without end)"
    )

    _not_negative = field_validator("start", "slope")(lambda v: _not_negative(v))


TailRule = Literal["trend", "segment"]

SpringLawName = Literal[tuple(SPRING_LAWS)]  # type: ignore[valid-type]  # crashnlp.base.choices


class Spring(Strict):
    law: SpringLawName = Field(  # type: ignore[valid-type]
        "force", description="force: F(x) piecewise linear; secant: F = k(x) x, k piecewise linear (paper Eq. 1)"
    )
    crush_breakpoints: tuple[Length, ...] | BreakpointCount | None = Field(
        None, description="crush at the breakpoints; omitted or {count: N}: placed over the data's crush range"
    )
    values: tuple[Annotated[SIValue, AfterValidator(_not_negative)], ...] | None = Field(
        None, description="forces (law force) or secant stiffnesses (law secant); omitted: from the measured force-crush curve"
    )
    tail: Annotated[
        Annotated[Tail, Tag("line")] | Annotated[TailRule, Tag("rule")],
        Discriminator(lambda v: "rule" if isinstance(v, str) else "line"),
    ] = Field(
        "trend",
        description="past the last breakpoint the law continues its last segment; {start, slope}: a straight line from"
        " start on, in fits and simulations alike; trend: a fit's identified model gets that line from the largest crush"
        " the model reached in the fitted tests, along the curve's trend there (crashnlp.models.tail); segment: it keeps"
        " the law as fitted",
    )

    @model_validator(mode="before")
    @classmethod
    def _values_in_si(cls, data: Any) -> Any:
        """The values in the law's unit. Without a valid law their unit is unknown: they are left
        out, and the law's error stands for them."""
        if not isinstance(data, dict) or not isinstance(data.get("values"), list):
            return data
        law = data.get("law", "force")
        if not isinstance(law, str) or law not in SPRING_LAWS:
            return {k: v for k, v in data.items() if k != "values"}
        return {**data, "values": [_quantity_in_si(v, SPRING_LAWS[law]) for v in data["values"]]}

    @field_validator("crush_breakpoints")
    @classmethod
    def _bp(cls, v: tuple[float, ...] | BreakpointCount | None) -> tuple[float, ...] | BreakpointCount | None:
        return _increasing(v, "crush_breakpoints") if isinstance(v, tuple) else v

    @model_validator(mode="after")
    def _values(self) -> Self:
        if self.values is None:
            return self
        if not isinstance(self.crush_breakpoints, tuple):
            raise ValueError("values need crush_breakpoints given as a list")
        if len(self.values) != len(self.crush_breakpoints):
            raise ValueError(f"values has {len(self.values)} entries but crush_breakpoints has {len(self.crush_breakpoints)}")
        return self

    def unit_of(self, field: str) -> str | None:
        return SPRING_LAWS[self.law] if field == "values" else super().unit_of(field)

    @property
    def placed_breakpoints(self) -> tuple[float, ...]:
        """The crush breakpoints, once placed: a Case places them over the data's crush range when the
        file gives none or a count (crashnlp.case.completion)."""
        if not isinstance(self.crush_breakpoints, tuple):
            raise RuntimeError("model.spring.crush_breakpoints: not placed yet (a Case places them from the data)")
        return self.crush_breakpoints

    @property
    def known_values(self) -> tuple[float, ...]:
        """The spring values, once known: a Case takes them from the measured force-crush curve when the file leaves them out."""
        return _filled_in(self.values, "model.spring.values")


class Damper(Strict):
    rate_breakpoints: tuple[Speed, ...]
    values: tuple[Annotated[Damping, AfterValidator(_not_negative)], ...]

    @field_validator("rate_breakpoints")
    @classmethod
    def _bp(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        return _increasing(v, "rate_breakpoints")

    @model_validator(mode="after")
    def _same_length(self) -> Self:
        if len(self.values) != len(self.rate_breakpoints):
            raise ValueError(f"values has {len(self.values)} entries but rate_breakpoints has {len(self.rate_breakpoints)}")
        return self


UnloadingLawName = Literal[UNLOADING_LAWS]  # type: ignore[valid-type]


class Unloading(Strict):
    law: UnloadingLawName = "elastic"
    stiffness: Stiffness | None = Field(
        None, description="unloading stiffness of the plastic law; omitted: from the data's rebound"
    )

    @field_validator("stiffness")
    @classmethod
    def _positive(cls, v: float | None) -> float | None:
        return _positive(v)

    @property
    def known_stiffness(self) -> float:
        """The unloading stiffness, once known: a Case takes it from the data's rebound when the file leaves it out."""
        return _filled_in(self.stiffness, "model.unloading.stiffness")


class Smoothing(Strict):
    """Width of the smoothed hinges at breakpoints (keeps IPOPT away from kinks); 0 = exact kinks."""

    crush: Annotated[Length, Structural()] = 1e-3
    rate: Annotated[Speed, Structural()] = 1e-3

    _not_negative = field_validator("crush", "rate")(lambda v: _not_negative(v))


FormName = Literal[tuple(FORMS)]  # type: ignore[valid-type]  # the registry's keys (crashnlp.problem.forms)


class Model(Strict):
    form: FormName = Field(DEFAULT_FORM, description="the model's form: " + ", ".join(FORMS))  # type: ignore[valid-type]
    spring: Spring = Spring()
    damper: Damper | None = Field(None, description="omitted: none, or a nominal one when the spring values come from the data")
    unloading: Unloading = Unloading()
    smoothing: Smoothing = Smoothing()


# --------------------------------------------------------------------------- data
CHANNEL_UNITS = {name: OUTPUT[name].unit for name in MEASURABLE}
ChannelName = Literal[MEASURABLE]  # type: ignore[valid-type]  # the channels a problem names: the measurable outputs
DataFormat = Literal[DATA_FORMATS]  # type: ignore[valid-type]  # crashnlp.base.choices
FILTER_CLASSES = tuple(CFC_CLASSES)  # their names, a filter a channel may give
CFC = Literal[FILTER_CLASSES]  # type: ignore[valid-type]  # crashnlp.base.choices
# SAE J211's classes for vehicle structure (total vehicle comparison) and barrier load cells; `filter: null`: raw
DEFAULT_FILTER: dict[str, CFC] = {"accel": "CFC60", "barrier_force": "CFC60"}
SUMMED = ("barrier_force",)  # the curves of a force are cells of one wall, summed; other channels' are averaged


def _not_bool(v: Any) -> Any:
    """Refuse true and false where a number counts: the lax conversion of an int (crashnlp.base.records)
    would read them as 1 and 0."""
    if isinstance(v, bool):
        raise CustomError("int_type", "Input should be a number, not true or false")
    return v


Index = Annotated[int, BeforeValidator(_not_bool)]  # a column's or a curve's number
AllBarrierFx = Literal["all-valid-barrier-fx"]  # EV5: every load cell (sensor LC, axis XG, a force) the header marks valid
ALL_BARRIER_FX: str = get_args(AllBarrierFx)[0]


class TimeColumn(Strict):
    column: str | Index = Field(description="CSV column: its name in the header, or its number counted from 1")
    unit: str = "s"


class ChannelSpec(Strict):
    column: str | Index | None = Field(None, description="CSV column: its name in the header, or its number counted from 1")
    curves: tuple[Index, ...] | AllBarrierFx | None = Field(
        None,
        description="NHTSA EV5 curve numbers, or the numbers CCC of NHTSA channel files vNNNNNtsv.CCC, averaged"
        " (barrier_force: summed); all-valid-barrier-fx: every valid barrier Fx load cell of an EV5 test",
    )
    code: str | None = Field(None, description="ISO-MME channel code")
    unit: str | None = Field(
        None, description="unit of the stored values; EV5 and MME files carry their own, NHTSA channel files none"
    )
    filter: CFC | None = Field(
        None, description="SAE J211 filter class; accel and barrier_force: CFC60 unless given (null: none)"
    )
    filtered: CFC | None = Field(
        None,
        description="the class the file's values were filtered at before (a lab's): a filter of that class is not applied"
        " again, and the model is still read through it (an ISO-MME code says its own)",
    )
    sign: Literal[1, -1] = Field(
        1,
        description="multiplies the stored values into the model frame (x toward the barrier; barrier_force: compression"
        " positive, so -1 for NHTSA load cells)",
    )
    derive: Literal["integrate"] | None = Field(None, description="integrate the accel channel from the impact speed")
    sigma: SIValue | None = Field(None, description="scale of the residuals; default per channel")
    weight: float = Field(1.0, ge=0.0)

    _positive = field_validator("sigma")(lambda v: _positive(v))


CHANNEL_FILE = re.compile(r"v(\d+)tsv\.(\d{3})", re.IGNORECASE)  # an NHTSA channel file: test NNNNN, curve CCC


def format_of(path: Path) -> str:
    """The data format a path's name says: nhtsa-ev5 for .EV5; nhtsa-channel for a channel file
    vNNNNNtsv.CCC, or a folder of them and no .mme; iso-mme for .mme, another folder or a .zip;
    csv otherwise."""
    suffix = path.suffix.lower()
    if suffix == ".ev5":
        return "nhtsa-ev5"
    if CHANNEL_FILE.fullmatch(path.name) or (
        path.is_dir() and any(CHANNEL_FILE.fullmatch(p.name) for p in path.iterdir()) and not any(path.glob("*.mme"))
    ):
        return "nhtsa-channel"
    if suffix in (".mme", ".zip") or path.is_dir():
        return "iso-mme"
    return "csv"


def located(path: Path) -> Path:
    """A data file's absolute path as the user put it: its folder resolved (symlinks and `..` as the
    system follows them), its own name kept where it is a symlink. A reader looks beside the file
    (an EV5's curves, an ISO-MME test's Channel folder, an NHTSA test's other channels): beside the
    link, where the user put it, not beside its target."""
    path = path.absolute()
    return path.parent.resolve() / path.name if path.is_symlink() else path.resolve()


class DataSpec(Strict):
    file: Path
    format: DataFormat = Field(
        "csv", description="omitted: from the file's name (crashnlp.problem.schema.format_of), csv for a name no other format has"
    )
    time: TimeColumn = TimeColumn(column="time_s")
    window: tuple[Time, Time] | None = None
    bias_window: tuple[Time, Time] | None = Field(
        None, description="pre-impact samples (ending at t = 0 or before), their mean removed"
    )
    channels: Mapping[ChannelName, ChannelSpec]

    @model_validator(mode="before")
    @classmethod
    def _format_from_name(cls, data: Any, info: ValidationInfo) -> Any:
        """A format the file's name says, where the problem names none."""
        if not isinstance(data, dict) or "format" in data or not isinstance(data.get("file"), (str, Path)):
            return data
        path = Path(data["file"])
        return {
            **data,
            "format": format_of(path if path.is_absolute() else Path((info.context or {}).get("base_dir", ".")) / path),
        }

    @model_validator(mode="before")
    @classmethod
    def _channels_in_si(cls, data: Any) -> Any:
        """Default filters, and sigmas in their channel's unit."""
        if not isinstance(data, dict) or not isinstance(data.get("channels"), dict):
            return data
        return {**data, "channels": {name: _channel_in_si(name, ch) for name, ch in data["channels"].items()}}

    @field_validator("file")
    @classmethod
    def _exists(cls, v: Path, info: ValidationInfo) -> Path:
        base = Path((info.context or {}).get("base_dir", "."))
        path = v if v.is_absolute() else base / v
        if not path.exists():
            raise ValueError(f"file not found: {path}")
        return located(path)

    @field_validator("window", "bias_window")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and v[1] <= v[0]:
            raise ValueError("window end must be after its start")
        return v

    @field_validator("bias_window")
    @classmethod
    def _pre_impact(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        """A bias window before impact (t = 0): a mean taken over the crash pulse is no sensor offset."""
        if v is not None and v[1] > 0:
            raise ValueError(f"ends at {v[1]:g} s, after impact (t = 0): the bias is the mean of pre-impact samples")
        return v

    @model_validator(mode="after")
    def _curves(self) -> Self:
        """Curve lists that fit their channel."""
        for name, ch in self.channels.items():
            if ch.curves == ALL_BARRIER_FX and name != "barrier_force":
                raise ValueError(f"channels.{name}: curves {ALL_BARRIER_FX} are barrier forces, a barrier_force channel")
        return self


def _channel_in_si(name: Any, channel: Any) -> Any:
    """A channel as given, with its default filter when it names none and its sigma in SI."""
    if not isinstance(channel, dict) or name not in CHANNEL_UNITS:
        return channel
    out = dict(channel)
    if name in DEFAULT_FILTER and "filter" not in out:
        out["filter"] = DEFAULT_FILTER[name]
    if out.get("sigma") is not None:
        out["sigma"] = _quantity_in_si(out["sigma"], CHANNEL_UNITS[name])
    return out


class Test(Strict):
    name: FolderName
    speed: ImpactSpeed | None = None
    mass: Mass | None = None
    duration: Time | None = None
    data: DataSpec | None = None

    _positive = field_validator("duration")(lambda v: _positive(v))
    _check_mass = field_validator("mass")(lambda v: _mass(_positive(v)))
    _check_speed = field_validator("speed")(lambda v: _speed(v))


# --------------------------------------------------------------------------- identification
OUTPUT_UNITS = {name: OUTPUT[name].unit for name in BOUNDED}  # the outputs a bound may limit, and their SI units
OutputName = Literal[BOUNDED]  # type: ignore[valid-type]


class EstimateSpec(Strict):
    """How an entry is estimated: its start, bounds and scale, in the unit of the entry it names."""

    initial: SIValue | tuple[SIValue, ...] | None = Field(None, description="default: the value in the problem")
    bounds: Bound | None = None
    prior_scale: SIValue | None = Field(None, description="scale of the decision variable; default from bounds")


def _bound_in_si(bound: Any, unit: str | None) -> Any:
    """(lower, upper) in SI `unit` (None: no bound). A key that names no output has no unit: its error
    stands for its bounds, which are not read."""
    if unit is None:
        return (None, None)
    return [None if b is None else _quantity_in_si(b, unit) for b in bound] if isinstance(bound, (list, tuple)) else bound


class Constraints(Strict):
    monotone_crush: bool = Field(False, description="crush does not decrease until its maximum")
    monotone_spring: bool = Field(False, description="spring values non-decreasing")
    bounds: Mapping[OutputName, Bound] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _bounds_in_si(cls, data: Any) -> Any:
        """Each output's bounds in its unit."""
        if not isinstance(data, dict) or not isinstance(data.get("bounds"), dict):
            return data
        return {**data, "bounds": {k: _bound_in_si(v, OUTPUT_UNITS.get(k)) for k, v in data["bounds"].items()}}

    @model_validator(mode="after")
    def _ordered(self) -> Self:
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
    ipopt: Mapping[str, Any] = Field(default_factory=dict, description="options passed to IPOPT")
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
    def _ipopt(cls, v: Mapping[str, Any]) -> Mapping[str, Any]:
        """Refuse what IPOPT would refuse, each error at its key (solver.ipopt.max_itr)."""
        errors = [error("ipopt_option", (name,), why, v[name]) for name, why in check_ipopt(v).items()]
        if errors:
            raise ValidationError("ipopt", errors)
        return v


Executor = Literal[EXECUTORS]  # type: ignore[valid-type]  # crashnlp.base.choices


class Uncertainty(Strict):
    """Profile-likelihood intervals, beyond the sandwich standard errors, for chosen parameters."""

    profile: tuple[str, ...] = Field(
        default_factory=list,
        description="estimated entries to profile, e.g. vehicle.cg_above_impact or model.spring.values[2]",
    )
    points: int = Field(4, ge=2, le=20, description="re-optimisations on each side, 0.75 std apart")
    executor: Executor = Field("local", description="where the profiles run in parallel (the study executors)")
    workers: int | None = Field(None, ge=1)


class Simulation(Strict):
    integrator: Literal["cvodes", "rk"] = "cvodes"
    substeps: int = Field(4, ge=1, le=1000, description="rk sub-steps per output step")
    rtol: float = Field(1e-8, gt=0.0, lt=1.0)
    atol: float = Field(1e-10, gt=0.0, lt=1.0)
    dt: Time = Field(1e-4, description="output step")
    duration: Time = Field(0.25, description="when a test gives neither duration nor data")

    _positive = field_validator("dt", "duration")(lambda v: _positive(v))


DesignObjective = Literal[DESIGN_OBJECTIVES]  # type: ignore[valid-type]  # crashnlp.base.choices


class Design(Strict):
    minimize: DesignObjective = DESIGN_OBJECTIVES[0]


class ForceCrush(Strict):
    crush: tuple[Length, ...]
    force: tuple[Force, ...]

    @model_validator(mode="after")
    def _same_length(self) -> Self:
        if len(self.crush) != len(self.force):
            raise ValueError("crush and force need the same number of entries")
        return self


class Reference(Strict):
    """Known curves drawn beside the identified ones (FE load-cell data, or a synthetic truth)."""

    force_crush: ForceCrush | None = None


class Problem(Strict):
    """A problem file: the vehicle, its model, its tests and what to estimate. Validated, every
    quantity is in SI and the problem is frozen: `with_values` makes a changed copy."""

    name: FolderName
    kind: Literal["identify", "design"] = "identify"
    vehicle: Vehicle
    model: Model
    tests: tuple[Test, ...] = Field(min_length=1)
    constraints: Constraints = Constraints()
    objective: Objective = Objective()
    transcription: TranscriptionSpec = Field(default_factory=lambda: MultipleShootingSpec(method="multiple-shooting"))
    solver: Solver = Solver()
    simulation: Simulation = Simulation()
    uncertainty: Uncertainty = Uncertainty()
    design: Design | None = None
    reference: Reference = Reference()
    base_dir: Path = Field(Path("."), exclude=True)  # where its relative paths start: problem_from_dict's, never a file's
    estimate: Mapping[str, EstimateSpec] = Field(default_factory=dict)  # last: it takes the units of the entries it names

    @field_validator("estimate", mode="before")
    @classmethod
    def _estimate_in_si(cls, value: Any, info: ValidationInfo) -> Any:
        """Each entry's initial value, bounds and scale in the unit of the entry it names, each error at
        its entry (estimate.vehicle.mass: ...). An entry in a section that failed its own validation
        is left out: that section's error stands for it."""
        if not isinstance(value, dict):
            return value
        converted, errors = {}, []
        for path, spec in value.items():
            if not isinstance(path, str):
                converted[path] = spec  # the key's own check refuses it
            elif path.split(".")[0] not in cls.model_fields or path.split(".")[0] in info.data:
                try:
                    converted[path] = _estimate_in_si(spec, _unit_at(info.data, path))
                except ValueError as exc:
                    errors.append(error("estimate", (path,), str(exc), spec))
        if errors:
            raise ValidationError("estimate", errors)
        return converted

    @model_validator(mode="after")
    def _check(self) -> Self:
        names = [t.name for t in self.tests]
        if len(set(names)) != len(names):
            raise ValueError("tests: names must be unique")
        for path, spec in self.estimate.items():
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
        values = value if isinstance(value, tuple) else [value]
        outside = [v for v in values if isinstance(v, (int, float)) and not lo <= v <= hi]
        if outside:
            where = "initial" if given else f"the problem's value of {path}"
            raise ValueError(f"estimate.{path}: {where} {outside[0]:g} is outside the bounds [{lo:g}, {hi:g}] (SI)")

    def value_at(self, path: str) -> Any:
        """The value of an entry named by dotted path, or None when the problem has none there."""
        node: Any = self
        for key in path.split("."):
            node = getattr(node, key, None) if isinstance(node, Record) else None
        return node

    def speed(self, test: Test) -> float | None:
        return test.speed if test.speed is not None else self.vehicle.speed

    def with_values(self, values: Mapping[str, Any]) -> "Problem":
        """A new validated problem with entries replaced by dotted path ("vehicle.speed": "64 km/h",
        "model.spring.values": [...], "tests.0.speed": ...); this one is left as it is. What the
        problem left out stays left out (`model_fields_set`), so that the new problem is still
        completed from its data, and a result's identified vehicle still fills it in. A path that
        names no entry of the problem is a ProblemError naming it (TypeError: `values` is no mapping)."""
        if not isinstance(values, Mapping):
            raise TypeError(f"with_values: expected a mapping of dotted paths to values, got {type(values).__name__}")
        full = self.model_dump(mode="python", exclude_none=False)
        raw = self.model_dump(mode="python", exclude_unset=True)
        for path, value in values.items():
            if not isinstance(path, str) or not self._has_entry(full, path):
                raise self._no_entry(path)
            *parents, leaf = path.split(".")
            node: Any = raw
            for key in parents:
                node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
            node[leaf] = value
        return problem_from_dict(raw, self.base_dir, "with_values")

    @staticmethod
    def _has_entry(full: dict[str, Any], path: str) -> bool:
        """Whether the dotted `path` names an entry of a problem's dump with every entry (`full`)."""
        *parents, leaf = path.split(".")
        node: Any = full
        try:
            for key in parents:
                node = node[int(key)] if isinstance(node, list) else node[key]
        except (KeyError, IndexError, ValueError, TypeError):
            return False
        return isinstance(node, dict) and leaf in node

    def _no_entry(self, path: object) -> ProblemError:
        """The one line for a with_values path that names no entry of the problem; a new key of a
        mapping with free keys (solver.ipopt) is given with the mapping whole."""
        parent = path.rpartition(".")[0] if isinstance(path, str) else ""
        whole = f"; give {parent} whole to add a key to it" if isinstance(self.value_at(parent), dict) else ""
        return ProblemError(f"with_values: {path}: {self.name} has no such entry{whole}")

    def unit_at(self, path: str) -> str:
        """SI unit of a numeric entry named by dotted path ("model.spring.values")."""
        unit = _unit_at(dict(self), path)
        if unit is None:
            raise ValueError(f"estimate.{path}: not a numeric entry of the problem")
        return unit

    def quantity_unit(self, path: str) -> str | None:
        """SI unit of any quantity the problem file may give at a dotted path, or None for an entry
        that is no quantity: a parameter's (`unit_at`), and also one that shapes the model
        (vehicle.speed) or a test's (tests.0.speed), which no estimate names. A study's swept
        entry is plotted in it."""
        return _unit_at(dict(self), path, quantity=True)


def _unit_at(sections: Mapping[str, Any], path: str, quantity: bool = False) -> str | None:
    """SI unit of the numeric entry at a dotted path into a problem's validated sections, or None;
    through a section the problem leaves out (an engine the pendulum's file does not give) by the
    section's declared type, so that a study may sweep an entry of it with its unit. `quantity`:
    any quantity (`Problem.quantity_unit`), through the problem's lists of tests too; else a parameter's."""
    first, _, rest = path.partition(".")
    *parents, leaf = rest.split(".")
    node: Any = sections.get(first)
    for key in parents:
        if isinstance(node, type):
            node = _declared(node, key)
            continue
        if quantity and isinstance(node, tuple):
            node = node[int(key)] if key.isdigit() and int(key) < len(node) else None
            continue
        child = getattr(node, key, None) if isinstance(node, Record) else None
        node = child if child is not None or not isinstance(node, Record) else _declared(type(node), key)
    if isinstance(node, type):
        return _field_unit(node, leaf, quantity)
    if not isinstance(node, Strict):
        return None
    unit = node.unit_of(leaf)
    return unit if unit is not None or not quantity else _field_unit(type(node), leaf, structural=True)


def _declared(section: type[Record], key: str) -> type[Strict] | None:
    """The section type that the type `section` declares its field `key` to hold (None where it
    declares no section there)."""
    info = section.model_fields.get(key)
    kinds = (get_args(info.annotation) or (info.annotation,)) if info is not None else ()
    return next((kind for kind in kinds if isinstance(kind, type) and issubclass(kind, Strict)), None)


def _estimate_in_si(spec: Any, unit: str | None) -> Any:
    """An estimate entry as given, with its quantities in SI `unit` (ValueError: the entry names no
    numeric entry, or a quantity does not convert)."""
    if unit is None:
        raise ValueError("not a numeric entry of the problem")
    if not isinstance(spec, dict):
        return spec
    out = dict(spec)
    initial = out.get("initial")
    if isinstance(initial, list):
        out["initial"] = [_quantity_in_si(v, unit) for v in initial]
    elif initial is not None:
        out["initial"] = _quantity_in_si(initial, unit)
    if out.get("bounds") is not None:
        out["bounds"] = _bound_in_si(out["bounds"], unit)
    if out.get("prior_scale") is not None:
        out["prior_scale"] = _quantity_in_si(out["prior_scale"], unit)
    return out


def problem_from_dict(raw: dict[str, Any], base_dir: Path, source: str = "problem") -> Problem:
    """Validate a problem given as a plain dict (paths relative to `base_dir`)."""
    if not isinstance(raw, dict):
        raise ProblemError(f"{source}: expected a mapping at the top level")
    try:
        problem = Problem.model_validate(copy.deepcopy(raw), context={"base_dir": base_dir})
    except ValidationError as exc:
        raise ProblemError(f"{source}: {all_errors(exc)}") from None
    return problem.model_copy(update={"base_dir": base_dir})
