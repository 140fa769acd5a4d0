"""IPOPT's own options, so that `solver.ipopt` is checked as input before anything is solved.

The list comes from the installed IPOPT itself: one solve of a one-variable NLP with
`print_options_documentation` (about 15 ms), parsed for each option's name, type, valid
range and settings, and kept in the crashnlp cache per CasADi installation, so a problem
file pays a JSON read (which marks the file used: the cache's limit removes the least recently
used kept files first, crashnlp.numerics.compiled). IPOPT leaves a few options out of its documentation ("sb"); a name
missing from the list is asked of IPOPT itself by building a solver with only that option.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path
from typing import Any, Literal, cast

from crashnlp.base.cache import KEPT_IPOPT, cache_dir, used, write_atomic

Kind = Literal["real", "integer", "string"]


@dataclass(frozen=True)
class IpoptOption:
    """One IPOPT option: its type, its range (None: unbounded; `strict`: the end itself is
    outside) and, for a string option, its settings (None: any string, e.g. a file name)."""

    kind: Kind
    lower: float | None = None
    lower_strict: bool = False
    upper: float | None = None
    upper_strict: bool = False
    settings: tuple[str, ...] | None = None

    def problem(self, name: str, value: Any) -> str | None:
        """Why `value` is not a valid setting of this option, or None when it is."""
        if self.kind == "string":
            return self._string_problem(name, value)
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if self.kind == "integer" and not (number and isinstance(value, int)):
            return f"{value!r} is not an integer (IPOPT's {name} is an integer option)"
        if not number or not math.isfinite(value):
            hint = " (YAML reads 1e-6 as text: write 1.0e-6)" if isinstance(value, str) else ""
            return f"{value!r} is not a number{hint}"
        if not self._within(float(value)):
            return f"{value!r} is outside IPOPT's range {self.range(name)}"
        return None

    def _string_problem(self, name: str, value: Any) -> str | None:
        if not isinstance(value, str):
            return f"{value!r} is not text (IPOPT's {name} is a string option)"
        if self.settings is not None and value.lower() not in self.settings:
            return f"{value!r} is none of {', '.join(self.settings)}"
        return None

    def _within(self, v: float) -> bool:
        above = self.lower is None or (v > self.lower if self.lower_strict else v >= self.lower)
        below = self.upper is None or (v < self.upper if self.upper_strict else v <= self.upper)
        return above and below

    def range(self, name: str) -> str:
        """The range as IPOPT documents it ("0 < tol < 1")."""
        lower = f"{self.lower:g} {'<' if self.lower_strict else '<='} " if self.lower is not None else ""
        upper = f" {'<' if self.upper_strict else '<='} {self.upper:g}" if self.upper is not None else ""
        return f"{lower}{name}{upper}"


def check_ipopt(options: Mapping[str, Any]) -> dict[str, str]:
    """Each entry of `options` that IPOPT would refuse -> why (a wrong name, with the closest
    valid one; a value of the wrong type, out of range or not among the settings)."""
    if not options:
        return {}
    known = ipopt_options()
    found = {}
    for name, value in options.items():
        option = known.get(name)
        why = option.problem(name, value) if option is not None else _undocumented(name, value, known)
        if why is not None:
            found[name] = why
    return found


def _undocumented(name: str, value: Any, known: dict[str, IpoptOption]) -> str | None:
    """Ask IPOPT itself about an option its documentation leaves out: a solver with only it."""
    import casadi as ca

    x = ca.MX.sym("x")
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # IPOPT prints what it refuses
            ca.nlpsol("probe", "ipopt", {"x": x, "f": x**2}, {"ipopt": {name: value}, "print_time": False})
    except RuntimeError as exc:
        if "No such IPOPT option" not in str(exc):
            return f"{value!r} is refused by IPOPT (wrong type or value)"
        import difflib  # here, not at the top: only a misspelt option needs it

        close = difflib.get_close_matches(name, list(known), n=1)
        return "no such IPOPT option" + (f" (did you mean {close[0]}?)" if close else "")
    return None


@cache
def ipopt_options() -> dict[str, IpoptOption]:
    """The installed IPOPT's documented options (from the cache, marked used, else read from IPOPT and
    cached)."""
    path = options_file()
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        options = _from_json(json.loads(path.read_text()))
        used(path)
        return options
    options = parse_documentation(ipopt_documentation())
    if not options:
        raise RuntimeError("IPOPT printed no documentation of its options")
    with contextlib.suppress(OSError):  # an unwritable cache: read IPOPT again next time
        write_atomic(path, json.dumps({name: asdict(o) for name, o in options.items()}))
    return options


def options_file() -> Path:
    """Where the installed IPOPT's options are kept in the cache (`ipopt_options`)."""
    return cache_dir() / KEPT_IPOPT.format(key=_installation())


def _installation() -> str:
    """A key of the installed CasADi (and so of the IPOPT it loads): its version and folder."""
    import casadi as ca

    return hashlib.sha256(f"{ca.CasadiMeta.version()}\0{Path(ca.__file__).parent}".encode()).hexdigest()[:16]


def _from_json(raw: dict[str, dict[str, Any]]) -> dict[str, IpoptOption]:
    options = {}
    for name, fields in raw.items():
        settings = fields.pop("settings")
        options[name] = IpoptOption(**fields, settings=None if settings is None else tuple(settings))
    return options


def ipopt_documentation() -> str:
    """IPOPT's documentation of every option (Doxygen markup), printed by one tiny solve."""
    import casadi as ca

    x = ca.MX.sym("x")
    opts = {"print_options_documentation": "yes", "print_options_mode": "doxygen", "print_advanced_options": "yes"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):  # CasADi's solver prints to the sys.stdout it was built under
        solver = ca.nlpsol("doc", "ipopt", {"x": x, "f": x**2}, {"ipopt": {**opts, "max_iter": 0}, "print_time": False})
        solver(x0=1)
    return out.getvalue()


_ENTRY = re.compile(r"<strong>(\w+)</strong>.*?</blockquote>", re.S)
_KIND = re.compile(r"this (real|integer|string) option")
_NUMBER = r"(-?[0-9.]+(?:e[-+]?[0-9]+)?)"
_RANGE = re.compile(rf"option is (?:{_NUMBER} (<|&le;) )?\w+(?: (<|&le;) {_NUMBER})? and its default")
_SETTING = re.compile(r"^ - ([^:\s]+):", re.M)  # one setting a line, with its description
_SETTINGS = re.compile(r"^Possible values: (.+)$", re.M)  # or all on one line ("yes, no")


def parse_documentation(text: str) -> dict[str, IpoptOption]:
    """The options of IPOPT's Doxygen documentation: name, type, range and settings."""
    text = re.sub(r"10<sup>([-+]?\d+)</sup>", r"1e\1", text)
    options = {}
    for entry in _ENTRY.finditer(text):
        kind = _KIND.search(entry.group(0))
        if kind is None:
            continue
        if kind.group(1) == "string":
            inline = _SETTINGS.search(entry.group(0))
            listed = inline.group(1).split(", ") if inline else _SETTING.findall(entry.group(0))
            settings = tuple(s.strip().lower() for s in listed)
            options[entry.group(1)] = IpoptOption("string", settings=None if "*" in settings or not settings else settings)
            continue
        bounds = _RANGE.search(entry.group(0))
        lo, lo_op, hi_op, hi = bounds.groups() if bounds else (None, None, None, None)
        options[entry.group(1)] = IpoptOption(
            cast(Kind, kind.group(1)),  # _KIND matches the kinds only
            lower=None if lo is None else float(lo),
            lower_strict=lo_op == "<",
            upper=None if hi is None else float(hi),
            upper_strict=hi_op == "<",
        )
    return options
