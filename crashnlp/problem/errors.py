"""Bad input in a problem: the error type, and a validation's errors as the one line the user sees."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from crashnlp.errors import InputError


class ProblemError(InputError):
    """Bad input: the message is the one line the user sees (exit status 2)."""


def _loc(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(p) for p in loc if p not in ("function-after", "function-before"))


def _message(err: Any) -> str:
    msg = err["msg"].removeprefix("Value error, ")
    loc = _loc(err["loc"])
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "missing":
        msg = "missing key"
    return f"{loc}: {msg}" if loc else msg


def all_errors(exc: ValidationError) -> str:
    """Every error of a validation in one line ("a: missing key; b.c: unknown key"), one per key.

    A value that fits no member of a union gets an error per member; the first stands for all.
    """
    seen: dict[str, str] = {}
    for err in exc.errors():
        seen.setdefault(_loc(err["loc"]), _message(err))
    return "; ".join(seen.values())
