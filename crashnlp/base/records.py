"""Frozen records validated from plain data: what the problem and study schemas are built of.

A `Record` subclass declares its fields as annotated class attributes, as pydantic's models do,
and takes the part of pydantic's API the schemas use (`Field`, `field_validator`,
`model_validator`, `Annotated` validators, tagged unions, `model_validate`, `model_copy`,
`model_dump`, `model_fields_set`, `model_json_schema`), with pydantic's lax conversions and its
error types and messages, each at the file's key: a file's errors read as they did. It is plain Python, read
as a class is defined: pydantic's import and the building of its validators were most of a
warm command's time beyond numpy and CasADi (docs/design-notes.md, "The problem schema's cost").

Unknown keys are refused and a validated record is frozen all the way down: a field declared
`tuple[X, ...]` holds the data's list as a FrozenList, one declared `Mapping[K, V]` its mapping as a
FrozenDict, and each dumps as the list or dict it was. The problem's and the study's records declare
their lists and mappings so; a field declared `list[X]` or `dict[K, V]` would be validated into a
plain, changeable one.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, NoReturn, Self, Union, get_args, get_origin

REQUIRED: Any = object()  # a field's default when the file must give it
INVALID: Any = object()  # what a value that failed validation becomes (its errors are recorded)


# --------------------------------------------------------------------------- errors
class ValidationError(ValueError):
    """A validation's errors, each a dict with `type`, `loc` (keys into the data), `msg` and `input`."""

    def __init__(self, title: str, errors: list[dict[str, Any]]) -> None:
        super().__init__(f"{len(errors)} validation error(s) for {title}: " + "; ".join(e["msg"] for e in errors))
        self.title = title
        self._errors = errors

    def errors(self) -> list[dict[str, Any]]:
        return self._errors


class CustomError(ValueError):
    """A validator's error of a given type (pydantic's PydanticCustomError) and message."""

    def __init__(self, type: str, message: str) -> None:
        self.type = type
        self.message = message
        super().__init__(message)


def error(type: str, loc: tuple[int | str, ...], msg: str, value: Any) -> dict[str, Any]:
    """One error of a ValidationError, at `loc` (keys into the data)."""
    return {"type": type, "loc": loc, "msg": msg, "input": value}


class FrozenError(AttributeError, TypeError):
    """An attempt to change a validated record, or a list or mapping of one in place."""


FROZEN = "a validated record is frozen (a problem's with_values makes a changed copy)"
LIST_CHANGES = frozenset(("append", "extend", "insert", "pop", "remove", "clear", "sort", "reverse"))


class FrozenList(tuple[Any, ...]):
    """A list of the data's in a validated record (a field declared `tuple[X, ...]`): a tuple, equal
    to the list of its items, shown and dumped as the list it was; a list's changes in place are
    refused as the record's are."""

    def __setitem__(self, index: Any, value: Any) -> NoReturn:
        raise FrozenError(f"{FROZEN}: its lists are tuples")

    def __delitem__(self, index: Any) -> NoReturn:
        raise FrozenError(f"{FROZEN}: its lists are tuples")

    def __eq__(self, other: object) -> bool:
        return tuple.__eq__(self, tuple(other) if isinstance(other, list) else other)

    def __ne__(self, other: object) -> bool:
        return not self == other

    __hash__ = tuple.__hash__

    def __repr__(self) -> str:
        return repr(list(self))  # as the file gave it, in messages that show it

    def __getattr__(self, name: str) -> NoReturn:
        if name in LIST_CHANGES:
            raise FrozenError(f"{FROZEN}: its lists are tuples, with no {name}")
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


class FrozenDict(dict[Any, Any]):
    """A mapping of the data's in a validated record (a field declared `Mapping[K, V]`): a dict, so
    that JSON, IPOPT's options and `isinstance(..., dict)` take it as one, whose changes are refused."""

    def _refuse(self, *args: Any, **kwargs: Any) -> NoReturn:
        raise FrozenError(f"{FROZEN}: its mappings are read-only")

    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self) -> tuple[Any, ...]:
        return type(self), (dict(self),)  # a pickle or a copy filled in as it is made, not key by key

    def __hash__(self) -> int:  # type: ignore[override]  # dict is unhashable, a frozen one is not
        return hash(frozenset(self.items()))


def frozen(value: Any) -> Any:
    """`value` with its lists as FrozenLists and its dicts as FrozenDicts, all the way down: a record's
    field as the code replaces it (`Record.replaced`), frozen as a validated one is."""
    if isinstance(value, list):
        return FrozenList(frozen(v) for v in value)
    if isinstance(value, dict) and not isinstance(value, FrozenDict):
        return FrozenDict({k: frozen(v) for k, v in value.items()})
    return value


class _Errors:
    """The errors of one validation, each at its location."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def add(self, loc: tuple[int | str, ...], type: str, msg: str, value: Any) -> Any:
        self.items.append(error(type, loc, msg, value))
        return INVALID

    def raised(self, loc: tuple[int | str, ...], exc: Exception, value: Any) -> Any:
        """The error a validator raised, at `loc` (a nested validation's errors each under it)."""
        if isinstance(exc, ValidationError):
            for e in exc.errors():
                self.items.append({**e, "loc": (*loc, *e["loc"])})
            return INVALID
        if isinstance(exc, CustomError):
            return self.add(loc, exc.type, exc.message, value)
        return self.add(loc, "value_error", str(exc), value)


# --------------------------------------------------------------------------- declarations
class FieldInfo:
    """A field's declaration: its type (Annotated's metadata apart), default, limits and description.
    An `exclude`d field is the code's, not the data's: set from its default (and by model_copy),
    a key of that name in the data is refused as unknown, and it is in no dump and no JSON Schema."""

    def __init__(
        self,
        default: Any = REQUIRED,
        *,
        default_factory: Callable[[], Any] | None = None,
        description: str | None = None,
        ge: float | None = None,
        gt: float | None = None,
        le: float | None = None,
        lt: float | None = None,
        min_length: int | None = None,
        discriminator: str | None = None,
        exclude: bool = False,
    ) -> None:
        self.annotation: Any = Any
        self.metadata: list[Any] = []
        self.default = default
        self.default_factory = default_factory
        self.description = description
        self.limits = {k: v for k, v in (("ge", ge), ("gt", gt), ("le", le), ("lt", lt)) if v is not None}
        self.min_length = min_length
        self.discriminator = discriminator
        self.exclude = exclude

    def is_required(self) -> bool:
        return self.default is REQUIRED and self.default_factory is None

    def get_default(self) -> Any:
        return self.default_factory() if self.default_factory is not None else self.default


def Field(default: Any = REQUIRED, **declared: Any) -> Any:  # noqa: N802  # pydantic's spelling, for the callers' reading
    """A field's declaration (FieldInfo), typed as its value would be, so that it stands as the default."""
    return FieldInfo(default, **declared)


class AfterValidator:
    """Annotated metadata: a function of the value once its type is checked."""

    def __init__(self, func: Callable[[Any], Any]) -> None:
        self.func = func


class BeforeValidator:
    """Annotated metadata: a function of the value as given, before its type is checked."""

    def __init__(self, func: Callable[[Any], Any]) -> None:
        self.func = func


class WithJsonSchema:
    """Annotated metadata: the JSON Schema of the value, in place of its type's."""

    def __init__(self, schema: dict[str, Any]) -> None:
        self.schema = schema


class Tag:
    """Annotated metadata: the tag of a form of a union that a `Discriminator` picks by."""

    def __init__(self, tag: str) -> None:
        self.tag = tag


class Discriminator:
    """Annotated metadata: the function that names the form (its `Tag`) a value of a union has."""

    def __init__(self, func: Callable[[Any], str | None]) -> None:
        self.func = func


class Conversion:
    """Annotated metadata that converts the value as given, before its type is checked, and states
    the JSON Schema of what it takes (a quantity's unit: crashnlp.problem.schema.Unit)."""

    def before(self, value: Any) -> Any:
        return value

    def json_schema(self) -> dict[str, Any]:
        return {}


class _Validator:
    """A field or model validator as declared: which fields, when, and its function."""

    def __init__(self, func: Any, mode: str, fields: tuple[str, ...] = ()) -> None:
        self.func: Callable[..., Any] = func.__func__ if isinstance(func, classmethod) else func
        self.bound = isinstance(func, classmethod)  # called with the class first
        self.mode = mode
        self.fields = fields
        self.takes_info = self.func.__code__.co_argcount - self.bound > 1

    def __call__(self, cls: type, value: Any, info: ValidationInfo) -> Any:
        args = (cls, value) if self.bound else (value,)
        return self.func(*args, info) if self.takes_info else self.func(*args)


def field_validator(*fields: str, mode: Literal["after", "before"] = "after") -> Callable[[Any], _Validator]:
    """A validator of the named fields: a function (or classmethod) of the value, and optionally a `ValidationInfo`."""
    return lambda func: _Validator(func, mode, fields)


def model_validator(*, mode: Literal["after", "before"]) -> Callable[[Any], _Validator]:
    """A validator of a whole record: before, a classmethod of the data as given; after, a method of the record."""
    return lambda func: _Validator(func, mode)


class ValidationInfo:
    """What a validator may read: the validation's `context` and the fields validated so far (`data`)."""

    def __init__(self, context: dict[str, Any] | None, data: dict[str, Any]) -> None:
        self.context = context
        self.data = data


# --------------------------------------------------------------------------- records
def _split(annotation: Any) -> tuple[Any, list[Any]]:
    """(type, metadata) of a field's annotation: Annotated's metadata apart, its Field merged in."""
    if get_origin(annotation) is Annotated:
        return get_args(annotation)[0], list(annotation.__metadata__)
    return annotation, []


class Record:
    """A section of a file: unknown keys refused, no number that is not finite, frozen once validated
    (its lists and mappings too, as the code's replacements of them: `replaced`)."""

    model_fields: ClassVar[dict[str, FieldInfo]] = {}
    _field_validators: ClassVar[dict[str, list[_Validator]]] = {}
    _model_before: ClassVar[list[_Validator]] = []
    _model_after: ClassVar[list[_Validator]] = []

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        fields = dict(cls.model_fields)
        validators: dict[str, list[_Validator]] = {k: list(v) for k, v in cls._field_validators.items()}
        before, after = list(cls._model_before), list(cls._model_after)
        for name, annotation in vars(cls).get("__annotations__", {}).items():
            if isinstance(annotation, str):  # `from __future__ import annotations` in the record's module
                raise TypeError(f"{cls.__name__}.{name}: a record's annotations are read as objects, not strings")
            if get_origin(annotation) is ClassVar:
                continue
            value = vars(cls).get(name, REQUIRED)
            info = value if isinstance(value, FieldInfo) else FieldInfo(value)
            info.annotation, info.metadata = _split(annotation)
            for m in [m for m in info.metadata if isinstance(m, FieldInfo)]:
                info.limits.update(m.limits)
                info.min_length = m.min_length if m.min_length is not None else info.min_length
                info.discriminator = m.discriminator or info.discriminator
                info.metadata.remove(m)
            fields[name] = info
            if name in vars(cls):
                delattr(cls, name)
        for value in list(vars(cls).values()):
            if isinstance(value, _Validator) and value.fields:
                for name in value.fields:
                    validators.setdefault(name, []).append(value)
            elif isinstance(value, _Validator):
                (before if value.mode == "before" else after).append(value)
        cls.model_fields, cls._field_validators, cls._model_before, cls._model_after = fields, validators, before, after

    def __init__(self, **values: Any) -> None:
        """A record validated from keyword values (ValidationError: every error)."""
        errors = _Errors()
        _record(type(self), values, (), errors, None, self)
        if errors.items:
            raise ValidationError(type(self).__name__, errors.items)

    # ---- pydantic's API, as the schemas' callers use it
    @classmethod
    def model_validate(cls, data: Any, *, context: dict[str, Any] | None = None) -> Self:
        """A validated record from plain data; ValidationError holds every error."""
        errors = _Errors()
        record = _validate_model(cls, data, (), errors, context)
        if errors.items:
            raise ValidationError(cls.__name__, errors.items)
        return record

    def replaced(self, update: dict[str, Any], given: set[str]) -> Self:
        """A copy with the fields of `update` replaced, unvalidated but frozen (their lists and dicts
        as a validated record's); `given`: the fields that count as given by the data (model_fields_set)."""
        record = type(self).__new__(type(self))
        record.__dict__.update({**self.__dict__, **{name: frozen(value) for name, value in update.items()}})
        object.__setattr__(record, "__fields_set__", set(given))
        return record

    @property
    def model_fields_set(self) -> set[str]:
        """The fields the data gave (or a copy's update set): the rest are defaults."""
        return set(self.__dict__["__fields_set__"])

    def model_copy(self, *, update: dict[str, Any] | None = None) -> Self:
        """A copy with fields replaced, unvalidated; the replaced ones count as given."""
        return self.replaced(update or {}, self.model_fields_set | set(update or ()))

    def model_dump(
        self,
        *,
        mode: Literal["python", "json"] = "python",
        exclude_none: bool = False,
        exclude_unset: bool = False,
        exclude: set[str] | None = None,
    ) -> dict[str, Any]:
        """The record as plain data (mode json: paths as text, tuples as lists), without excluded fields."""
        out = {}
        for name, info in type(self).model_fields.items():
            value = self.__dict__[name]
            if info.exclude or name in (exclude or ()) or (exclude_unset and name not in self.__dict__["__fields_set__"]):
                continue
            if exclude_none and value is None:
                continue
            out[name] = _dump(value, mode, exclude_none, exclude_unset)
        return out

    @classmethod
    def model_json_schema(cls) -> dict[str, Any]:
        """The JSON Schema of the data a record is validated from (docs/reference/problem-file.md is made from it)."""
        defs: dict[str, Any] = {}
        top = _record_schema(cls, defs)
        return {**({"$defs": dict(sorted(defs.items()))} if defs else {}), **top}

    def __iter__(self) -> Iterator[tuple[str, Any]]:
        return ((name, self.__dict__[name]) for name in type(self).model_fields)

    def __setattr__(self, name: str, value: Any) -> None:
        raise FrozenError(f"{type(self).__name__}.{name}: Instance is frozen")

    def __delattr__(self, name: str) -> None:
        raise FrozenError(f"{type(self).__name__}.{name}: Instance is frozen")

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return dict(self) == dict(other)

    def __hash__(self) -> int:
        return hash((type(self), *(v for _, v in self)))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self)})"


def _dump(value: Any, mode: str, exclude_none: bool, exclude_unset: bool) -> Any:
    if isinstance(value, Record):
        return value.model_dump(mode=mode, exclude_none=exclude_none, exclude_unset=exclude_unset)  # type: ignore[arg-type]
    if isinstance(value, dict):
        return {k: _dump(v, mode, exclude_none, exclude_unset) for k, v in value.items()}
    if isinstance(value, list | tuple):
        items = [_dump(v, mode, exclude_none, exclude_unset) for v in value]
        return items if isinstance(value, list | FrozenList) or mode == "json" else tuple(items)
    if isinstance(value, Path) and mode == "json":
        return str(value)
    return value


# --------------------------------------------------------------------------- validation
def _kind(value: Any) -> str:
    """What a file gave where a section of keys belongs, in a file's words (not a Python class's)."""
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return "true or false"
    return {list: "a list", str: "a text", int: "a number", float: "a number"}.get(type(value), type(value).__name__)


def _validate_model(cls: type[Record], data: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    """A record of `cls` from `data` (a record of it as it is), its errors recorded."""
    if isinstance(data, cls):
        return data
    return _record(cls, data, loc, errors, context, None)


def _record(cls: type[Record], data: Any, loc: tuple, errors: _Errors, context: Any, into: Record | None) -> Any:
    """The record of `cls` from `data` (filled into `into` when given, for a direct construction),
    or INVALID with its errors recorded."""
    for v in cls._model_before:
        try:
            data = v(cls, data, ValidationInfo(context, {}))
        except ValueError as exc:
            return errors.raised(loc, exc, data)
    if not isinstance(data, dict):
        return errors.add(loc, "model_type", f"Input should be a section of keys (key: value), got {_kind(data)}", data)
    n_before = len(errors.items)
    values: dict[str, Any] = {}
    for name, info in cls.model_fields.items():
        if name in data and not info.exclude:
            value = _field(cls, name, info, data[name], (*loc, name), errors, context, values)
            if value is not INVALID:
                values[name] = value
        elif info.is_required():
            errors.add((*loc, name), "missing", "Field required", data)
        else:
            values[name] = frozen(info.get_default())
    for key in data:
        if key not in cls.model_fields or cls.model_fields[key].exclude:
            errors.add((*loc, key), "extra_forbidden", "Extra inputs are not permitted", data[key])
    if len(errors.items) > n_before:
        return INVALID
    record = into if into is not None else object.__new__(cls)
    record.__dict__.update(values)
    object.__setattr__(record, "__fields_set__", {k for k in data if k in cls.model_fields})
    for v in cls._model_after:
        try:
            v.func(record)
        except ValueError as exc:
            return errors.raised(loc, exc, data)
    return record


def _field(
    cls: type[Record], name: str, info: FieldInfo, value: Any, loc: tuple, errors: _Errors, context: Any, data: dict
) -> Any:
    """A field's value: its before validators, its type, its after validators; INVALID at the first that fails."""
    validators = cls._field_validators.get(name, ())
    vinfo = ValidationInfo(context, data)
    value = _run(cls, [v for v in validators if v.mode == "before"], value, vinfo, loc, errors)
    if value is INVALID:
        return INVALID
    value = _value(info.annotation, info.metadata, value, loc, errors, context, info)
    if value is INVALID:
        return INVALID
    return _run(cls, [v for v in validators if v.mode == "after"], value, vinfo, loc, errors)


def _run(cls: type[Record], validators: list[_Validator], value: Any, info: ValidationInfo, loc: tuple, errors: _Errors) -> Any:
    """`value` through field validators in turn, or INVALID with the error the first raised."""
    try:
        for v in validators:
            value = v(cls, value, info)
    except ValueError as exc:
        return errors.raised(loc, exc, value)
    return value


def _value(
    tp: Any, metadata: list[Any], value: Any, loc: tuple, errors: _Errors, context: Any, info: FieldInfo | None = None
) -> Any:
    """`value` as type `tp` with its Annotated `metadata` (and a field's limits) says, or INVALID."""
    try:
        for m in metadata:
            if isinstance(m, BeforeValidator):
                value = m.func(value)
            elif isinstance(m, Conversion):
                value = m.before(value)
    except ValueError as exc:
        return errors.raised(loc, exc, value)
    discriminator = next((m for m in metadata if isinstance(m, Discriminator)), None)
    if discriminator is not None:
        value = _tagged_by(discriminator, tp, value, loc, errors, context)
    elif info is not None and info.discriminator is not None:
        value = _tagged(info.discriminator, tp, value, loc, errors, context)
    else:
        value = _typed(tp, value, loc, errors, context)
    if value is INVALID:
        return INVALID
    declared = [m for m in (info, *metadata) if isinstance(m, FieldInfo)]  # a field's, and an Annotated Field's
    if not all(_within(d, value, loc, errors) for d in declared):
        return INVALID
    try:
        for m in metadata:
            if isinstance(m, AfterValidator):
                value = m.func(value)
    except ValueError as exc:
        return errors.raised(loc, exc, value)
    return value


LIMITS = {
    "ge": ("greater_than_equal", "greater than or equal to", lambda v, b: v >= b),
    "gt": ("greater_than", "greater than", lambda v, b: v > b),
    "le": ("less_than_equal", "less than or equal to", lambda v, b: v <= b),
    "lt": ("less_than", "less than", lambda v, b: v < b),
}


def _within(info: FieldInfo, value: Any, loc: tuple, errors: _Errors) -> bool:
    """A field's limits: its numbers' bounds, its collections' least length."""
    if info.min_length is not None and isinstance(value, list | dict | tuple) and len(value) < info.min_length:
        kind = "List" if isinstance(value, list | FrozenList) else "Dictionary" if isinstance(value, dict) else "Tuple"
        items = "item" if info.min_length == 1 else "items"
        msg = f"{kind} should have at least {info.min_length} {items} after validation, not {len(value)}"
        errors.add(loc, "too_short", msg, value)
        return False
    if isinstance(value, int | float) and not isinstance(value, bool):
        for key, bound in info.limits.items():
            kind, words, holds = LIMITS[key]
            if not holds(value, bound):
                shown = (
                    int(bound) if isinstance(bound, float) and bound.is_integer() else bound
                )  # 0.0 as 0, as pydantic-core says
                errors.add(loc, kind, f"Input should be {words} {shown}", value)
                return False
    return True


def _typed(tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    """`value` as type `tp`, converted as pydantic's lax mode does, or INVALID with its error."""
    if tp is Any:
        return value
    origin = get_origin(tp)
    if origin is Annotated:
        inner, metadata = _split(tp)
        return _value(inner, metadata, value, loc, errors, context)
    if origin in (Union, types.UnionType):
        return _union(tp, value, loc, errors, context)
    if origin is Literal:
        return _literal(tp, value, loc, errors)
    if origin is list or _listed(tp):
        if not isinstance(value, list | tuple):
            return errors.add(loc, "list_type", "Input should be a valid list", value)
        kind = list if origin is list else FrozenList
        return _items([get_args(tp)[0]] * len(value), value, loc, errors, context, kind)
    if origin is tuple:
        return _tuple(tp, value, loc, errors, context)
    if origin in (dict, Mapping):
        return _dict(tp, value, loc, errors, context)
    if tp is type(None):
        return value if value is None else errors.add(loc, "none_required", "Input should be None", value)
    if isinstance(tp, type) and issubclass(tp, Record):
        return _validate_model(tp, value, loc, errors, context)
    return SCALARS[tp](value, loc, errors)


def _listed(tp: Any) -> bool:
    """Whether `tp` is `tuple[X, ...]`: a record's frozen list of the data's (FrozenList)."""
    return get_origin(tp) is tuple and get_args(tp)[1:] == (Ellipsis,)


def _items(types_: list[Any], value: Any, loc: tuple, errors: _Errors, context: Any, kind: type) -> Any:
    out = [_typed(t, v, (*loc, i), errors, context) for i, (t, v) in enumerate(zip(types_, value))]
    return INVALID if any(v is INVALID for v in out) else kind(out)


def _tuple(tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    if not isinstance(value, list | tuple):
        return errors.add(loc, "tuple_type", "Input should be a valid tuple", value)
    args = get_args(tp)
    if len(value) < len(args):
        for i in range(len(value), len(args)):
            errors.add((*loc, i), "missing", "Field required", value)
        return INVALID
    if len(value) > len(args):
        msg = f"Tuple should have at most {len(args)} items after validation, not {len(value)}"
        return errors.add(loc, "too_long", msg, value)
    return _items(list(args), value, loc, errors, context, tuple)


def _dict(tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    if not isinstance(value, dict):
        return errors.add(loc, "dict_type", "Input should be a valid dictionary", value)
    key_type, value_type = get_args(tp)
    out, bad = {}, False
    for k, v in value.items():
        key = _typed(key_type, k, (*loc, k, "[key]"), errors, context)
        item = _typed(value_type, v, (*loc, k), errors, context)
        bad = bad or key is INVALID or item is INVALID
        out[key] = item
    return INVALID if bad else out if get_origin(tp) is dict else FrozenDict(out)


def _union(tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    """The first form of a union `value` fits; an Optional's None as it is. A union of several forms
    locates each form's errors under the form's name, as pydantic does."""
    forms = [a for a in get_args(tp) if a is not type(None)]
    if len(forms) < len(get_args(tp)) and value is None:
        return None
    if len(forms) == 1:
        return _typed(forms[0], value, loc, errors, context)
    tried: list[dict[str, Any]] = []
    for form in _by_strictness(forms, value):
        attempt = _Errors()
        out = _typed(form, value, (*loc, _form_name(form)), attempt, context)
        if out is not INVALID:
            return out
        tried += attempt.items
    order = {_form_name(f): i for i, f in enumerate(forms)}
    errors.items.extend(sorted(tried, key=lambda e: order.get(e["loc"][len(loc)], 0)))
    return INVALID


def _by_strictness(forms: list[Any], value: Any) -> list[Any]:
    """The forms a value matches exactly first (pydantic's smart union: a strict match wins)."""
    exact = [f for f in forms if isinstance(f, type) and type(value) is f]
    return exact + [f for f in forms if f not in exact]


def _form_name(form: Any) -> str:
    if get_origin(form) is Annotated:
        form = get_args(form)[0]
    return getattr(form, "__name__", None) if isinstance(form, type) else str(form).replace("typing.", "")  # type: ignore[return-value]


def _tagged(key: str, tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    """A union of records picked by the value of their field `key` (a Literal of one tag each)."""
    forms = {get_args(f.model_fields[key].annotation)[0]: f for f in get_args(tp)}
    if not isinstance(value, dict) and not isinstance(value, tuple(forms.values())):
        return errors.add(
            loc, "model_attributes_type", "Input should be a valid dictionary or object to extract fields from", value
        )
    if isinstance(value, dict) and key not in value:
        return errors.add(loc, "union_tag_not_found", f"Unable to extract tag using discriminator '{key}'", value)
    tag = value[key] if isinstance(value, dict) else getattr(value, key)
    # the tag is a value of the file's, not a key: the form's errors are the union's own
    return _form_tagged(forms, tag, f" found using '{key}'", value, loc, loc, errors, context)


def _tagged_by(discriminator: Discriminator, tp: Any, value: Any, loc: tuple, errors: _Errors, context: Any) -> Any:
    """A union whose forms carry a `Tag`, picked by the discriminator's function of the value."""
    forms = {next(m.tag for m in f.__metadata__ if isinstance(m, Tag)): f for f in get_args(tp)}
    tag = discriminator.func(value)
    return _form_tagged(forms, tag, "", value, loc, (*loc, tag), errors, context)


def _form_tagged(
    forms: dict[Any, Any], tag: Any, found: str, value: Any, loc: tuple, inside: tuple, errors: _Errors, context: Any
) -> Any:
    """`value` as the form of a tagged union (tag -> form) its `tag` picks, that form's errors located
    at `inside`; where no form has the tag, the union's error at `loc` (`found`: how the tag was got)."""
    if tag not in forms:
        expected = ", ".join(f"'{t}'" for t in forms)
        msg = f"Input tag '{tag}'{found} does not match any of the expected tags: {expected}"
        return errors.add(loc, "union_tag_invalid", msg, value)
    return _typed(forms[tag], value, inside, errors, context)


def _literal(tp: Any, value: Any, loc: tuple, errors: _Errors) -> Any:
    allowed = get_args(tp)
    for a in allowed:
        if value == a and type(value) is type(a) or (type(a) is int and type(value) is float and value == a):
            return a
    words = [repr(a) for a in allowed]
    expected = words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"
    return errors.add(loc, "literal_error", f"Input should be {expected}", value)


def _float(value: Any, loc: tuple, errors: _Errors) -> Any:
    if isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            return errors.add(loc, "float_parsing", "Input should be a valid number, unable to parse string as a number", value)
    elif isinstance(value, int | float):
        number = float(value)
    else:
        return errors.add(loc, "float_type", "Input should be a valid number", value)
    if not math.isfinite(number):
        return errors.add(loc, "finite_number", "Input should be a finite number", value)
    return number


def _int(value: Any, loc: tuple, errors: _Errors) -> Any:
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return errors.add(loc, "finite_number", "Input should be a finite number", value)
        if value != int(value):
            return errors.add(
                loc, "int_from_float", "Input should be a valid integer, got a number with a fractional part", value
            )
        return int(value)
    if isinstance(value, str):
        try:
            return int(value.strip())
        except ValueError:
            return errors.add(loc, "int_parsing", "Input should be a valid integer, unable to parse string as an integer", value)
    return errors.add(loc, "int_type", "Input should be a valid integer", value)


BOOL_WORDS = {"0": False, "off": False, "f": False, "false": False, "n": False, "no": False}
BOOL_WORDS |= {"1": True, "on": True, "t": True, "true": True, "y": True, "yes": True}


def _bool(value: Any, loc: tuple, errors: _Errors) -> Any:
    if isinstance(value, bool):
        return value
    if isinstance(value, int | float) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in BOOL_WORDS:
        return BOOL_WORDS[value.strip().lower()]
    kind = "bool_parsing" if isinstance(value, str | int | float) else "bool_type"
    return errors.add(
        loc, kind, "Input should be a valid boolean" + (", unable to interpret input" if kind == "bool_parsing" else ""), value
    )


def _str(value: Any, loc: tuple, errors: _Errors) -> Any:
    return value if isinstance(value, str) else errors.add(loc, "string_type", "Input should be a valid string", value)


def _path(value: Any, loc: tuple, errors: _Errors) -> Any:
    return Path(value) if isinstance(value, str | Path) else errors.add(loc, "path_type", "Input is not a valid path", value)


SCALARS: dict[Any, Callable[[Any, tuple, _Errors], Any]] = {float: _float, int: _int, bool: _bool, str: _str, Path: _path}


# --------------------------------------------------------------------------- JSON Schema
JSON_TYPES = {float: "number", int: "integer", bool: "boolean", str: "string", type(None): "null"}


JSON_LIMITS = {"ge": "minimum", "gt": "exclusiveMinimum", "le": "maximum", "lt": "exclusiveMaximum"}


def _record_schema(cls: type[Record], defs: dict[str, Any]) -> dict[str, Any]:
    import inspect  # a docstring's indentation taken off as pydantic's schema did; only when a schema is asked for

    properties, required = {}, []
    for name, info in [(name, info) for name, info in cls.model_fields.items() if not info.exclude]:
        properties[name] = _field_schema(name, info, defs)
        if info.is_required():
            required.append(name)
    out: dict[str, Any] = {"additionalProperties": False, "properties": properties}
    if required:
        out["required"] = required
    out |= {"title": cls.__name__, "type": "object"}
    if cls.__doc__:
        out["description"] = inspect.cleandoc(cls.__doc__)
    return dict(sorted(out.items()))


def _field_schema(name: str, info: FieldInfo, defs: dict[str, Any]) -> dict[str, Any]:
    """A field's JSON Schema: its type's, its limits (on the form that is not None), title, default and description."""
    node = _schema(info.annotation, info.metadata, defs)
    if info.discriminator is not None:
        forms = [get_args(f.model_fields[info.discriminator].annotation)[0] for f in get_args(info.annotation)]
        mapping = {tag: ref["$ref"] for tag, ref in zip(forms, node["anyOf"])}
        node = {
            "discriminator": {"mapping": dict(sorted(mapping.items())), "propertyName": info.discriminator},
            "oneOf": node["anyOf"],
        }
    forms = node.get("anyOf", [node])
    limited = next((f for f in forms if f.get("type") != "null"), node)
    limits = {JSON_LIMITS[key]: bound for key, bound in info.limits.items()}
    if info.min_length:
        limits["minItems" if limited.get("type") == "array" else "minProperties"] = info.min_length
    if limited is node:
        node = {**node, **limits}
    else:
        forms[forms.index(limited)] = dict(sorted({**limited, **limits}.items()))
    refs = [f for f in forms if f.get("type") != "null"]
    if not (len(refs) == 1 and "$ref" in refs[0]):  # a section's own title stands for it
        node["title"] = name.replace("_", " ").title()
    if info.description:
        node["description"] = info.description
    if not info.is_required() and info.default_factory is None:
        node["default"] = _dump(info.default, "json", False, False)
    return dict(sorted(node.items()))


def _schema(tp: Any, metadata: list[Any], defs: dict[str, Any]) -> dict[str, Any]:
    """The JSON Schema of type `tp` with its Annotated `metadata`; records go to `defs`."""
    for m in metadata:
        if isinstance(m, WithJsonSchema):
            return dict(m.schema)
        if isinstance(m, Conversion):
            return dict(m.json_schema())
    origin = get_origin(tp)
    if origin is Annotated:
        inner, more = _split(tp)
        return _schema(inner, more, defs)
    if origin in (Union, types.UnionType):
        forms = [_schema(a, [], defs) for a in get_args(tp)]
        flat = [f for form in forms for f in (form["anyOf"] if list(form) == ["anyOf"] else [form])]
        return {"oneOf" if any(isinstance(m, Discriminator) for m in metadata) else "anyOf": flat}
    if origin is Literal:
        values = list(get_args(tp))
        kinds = {JSON_TYPES.get(type(v)) for v in values}
        kind = {"type": kinds.pop()} if len(kinds) == 1 else {}
        return {"const": values[0], **kind} if len(values) == 1 else {"enum": values, **kind}
    if origin is list or _listed(tp):
        return {"items": _schema(get_args(tp)[0], [], defs), "type": "array"}
    if origin is tuple:
        args = get_args(tp)
        return {
            "maxItems": len(args),
            "minItems": len(args),
            "prefixItems": [_schema(a, [], defs) for a in args],
            "type": "array",
        }
    if origin in (dict, Mapping):
        key, value = get_args(tp)
        names = {"propertyNames": {"enum": list(get_args(key))}} if get_origin(key) is Literal else {}
        return {"additionalProperties": True if value is Any else _schema(value, [], defs), **names, "type": "object"}
    if isinstance(tp, type) and issubclass(tp, Record):
        if tp.__name__ not in defs:
            defs[tp.__name__] = {}
            defs[tp.__name__] = _record_schema(tp, defs)
        return {"$ref": f"#/$defs/{tp.__name__}"}
    if tp is Path:
        return {"format": "path", "type": "string"}
    return {"type": JSON_TYPES[tp]} if tp in JSON_TYPES else {}
