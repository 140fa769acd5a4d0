"""Bad input in a problem: the error type, and a validation's errors as the one line the user sees."""

from __future__ import annotations

from typing import Any

from crashnlp.base.errors import InputError
from crashnlp.base.records import ValidationError

# What a key of several forms (a union in crashnlp.problem.schema) accepts, in plain words: said in
# place of the error per form, which names the forms by their types.
UNION_FORMS = {
    "crush_breakpoints": "a list of crush values, or {count: N} with N from 2 to 30",
    "tail": "trend, segment, or {start: a crush, slope: a stiffness}",
    "curves": "a list of curve numbers, or all-valid-barrier-fx",
    "column": "a column's name, or its number counted from 1",
    "initial": "a number, or a list of numbers",
}
# error types (crashnlp.base.records) that say a value is not of a form at all (rather than wrong inside it)
NOT_THIS_FORM = frozenset(
    {"list_type", "dict_type", "model_type", "model_attributes_type", "literal_error", "string_type", "int_type"}
    | {"int_from_float", "int_parsing", "float_type", "float_parsing", "tuple_type", "union_tag_invalid"}
)


class ProblemError(InputError):
    """Bad input: the message is the one line the user sees (exit status 2)."""


def _loc(loc: tuple[int | str, ...]) -> str:
    """An error's location as the file's keys, dotted."""
    return ".".join(map(str, loc))


def _text(err: Any) -> str:
    if err["type"] == "extra_forbidden":
        return "unknown key"
    if err["type"] == "missing":
        return "missing key"
    return str(err["msg"])


def _message(err: Any) -> str:
    loc = _loc(err["loc"])
    return f"{loc}: {_text(err)}" if loc else _text(err)


def _union_split(loc: tuple[int | str, ...]) -> tuple[tuple[int | str, ...], tuple[int | str, ...] | None]:
    """(the key, what follows its form's name) of an error inside a form of a UNION_FORMS key;
    (loc, None) for any other error."""
    for i, part in enumerate(loc[:-1]):
        if part in UNION_FORMS:
            return loc[: i + 1], loc[i + 2 :]
    return loc, None


def _union_message(key: str, errors: list[tuple[tuple[int | str, ...], Any]]) -> str:
    """A union key's errors as one: what it accepts, and what is wrong inside the form the value has."""
    accepts = f"{key}: {UNION_FORMS[key.rsplit('.', 1)[-1]]}"
    inside = [(rest, err) for rest, err in errors if rest or err["type"] not in NOT_THIS_FORM]
    if not inside:
        return accepts
    rest, err = inside[0]
    return f"{accepts} ({_loc(rest) + ': ' if rest else ''}{_text(err)})"


def all_errors(exc: ValidationError) -> str:
    """Every error of a validation in one line ("a: missing key; b.c: unknown key"), one per key.

    A value that fits no form of a key of several forms (UNION_FORMS) says what the key accepts,
    and what is wrong inside the form it has, if any; another union's first error stands for all.
    """
    seen: dict[str, str] = {}
    unions: dict[str, list[tuple[tuple[int | str, ...], Any]]] = {}
    for err in exc.errors():
        key, rest = _union_split(err["loc"])
        if rest is None:
            seen.setdefault(_loc(key), _message(err))
        else:
            unions.setdefault(_loc(key), []).append((rest, err))
            seen.setdefault(_loc(key), "")
    for union, errors in unions.items():
        seen[union] = _union_message(union, errors)
    return "; ".join(seen.values())
