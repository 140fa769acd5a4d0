"""Read a YAML problem file into a validated `Problem`; bad input becomes one line."""

from __future__ import annotations

import hashlib
import json
from contextlib import suppress
from functools import cache
from pathlib import Path
from typing import Any

from crashnlp.base.cache import cache_dir, installed_version, write_atomic
from crashnlp.problem.errors import ProblemError
from crashnlp.problem.schema import Problem, problem_from_dict


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Parse a YAML file, turning every read, encoding or syntax failure into a ProblemError.

    A file's values are kept in the crashnlp cache under a hash of its text, PyYAML's version and
    the parser's code (`_parsed_file`), as JSON where JSON holds them exactly: a later read of the
    same text loads them without importing PyYAML, whose import and pure-Python parse cost a
    command some 15 ms (docs/design-notes.md, "Reading the problem without PyYAML")."""
    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"{path}: file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ProblemError(f"{path}: not valid UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ProblemError(f"{path}: cannot read ({exc.strerror})") from None
    kept = _parsed_file(text)
    with suppress(OSError, ValueError):
        return json.loads(kept.read_text())
    from crashnlp.problem.parse import parse_yaml  # here, not at the top: only a text not read before needs PyYAML

    raw = parse_yaml(text, path)
    if not _plain(raw):
        return raw
    values = json.dumps(raw)
    with suppress(OSError):
        write_atomic(kept, values)
    return json.loads(values)  # what a later read gets: a copy wherever YAML's aliases shared one value


def _parsed_file(text: str) -> Path:
    """Where the values of the YAML `text` are kept (`read_yaml`)."""
    key = hashlib.sha256("\0".join((text, *_parser())).encode()).hexdigest()[:32]
    return cache_dir() / f"yaml-{key}.json"


@cache
def _parser() -> tuple[str, str]:
    """What else fixes a text's values: the parser's code (crashnlp.problem.parse) and PyYAML's version."""
    return Path(__file__).with_name("parse.py").read_text(), installed_version("yaml", "PyYAML")


def _plain(value: Any) -> bool:
    """Whether JSON gives `value` back as it is: mappings with text keys, lists, text, numbers,
    booleans and nulls (not YAML's dates, sets, binary or other keys)."""
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return value is None or isinstance(value, (str, int, float))


def check_fit_keys(problem: Problem, source: str | Path) -> None:
    """Refuse keys an identification would ignore: a test `duration` that disagrees with its data window.

    identify fits each test over its data window (Case.fit_window); `duration` then only sets
    the horizon of `crashnlp simulate`, so a different value would be silently ignored.
    """
    if problem.kind != "identify":
        return
    for i, test in enumerate(problem.tests):
        window = test.data.window if test.data is not None else None
        if test.duration is not None and window is not None and abs(test.duration - window[1]) > 1e-9:
            raise ProblemError(
                f"{source}: tests.{i}.duration: {test.duration:g} s would be ignored: identify fits the data "
                f"window, which ends at {window[1]:g} s (remove duration or make it {window[1]:g} s)"
            )


def load_problem(path: str | Path) -> Problem:
    """Load and validate a problem file."""
    path = Path(path)
    return problem_from_dict(read_yaml(path), path.resolve().parent, source=str(path))
