"""Read a YAML problem file into a validated `Problem`; bad input becomes one line."""

from __future__ import annotations

import hashlib
import json
from contextlib import suppress
from functools import cache
from pathlib import Path
from typing import Any

from crashnlp.base.cache import KEPT_YAML, cache_dir, files_digest, installed_version, used, write_atomic
from crashnlp.problem.errors import ProblemError
from crashnlp.problem.schema import Problem, problem_from_dict

# values kept of a YAML text: at most this many a character of it, and EXPANSION_FLOOR more (aliases
# that share a channel list write it out once more for each test; a flood of them is no problem file)
EXPANSION, EXPANSION_FLOOR = 4, 1000


def read_yaml(path: str | Path, what: str = "a problem file (YAML)") -> Any:
    """The values of a YAML file (`what` it is, which a folder given in its place is told to give),
    every read, encoding or syntax failure a ProblemError.

    A file's values are kept in the crashnlp cache, as JSON, under a hash of its text, PyYAML's
    version and the code that parses and keeps them (`_kept_file`), where JSON gives them back as
    they are (`_as_json`: values aliases point to come back as a copy at each place, on the first
    read as on later ones; a text not kept gives PyYAML's values): a later read of the same text
    loads them without importing PyYAML, whose import and pure-Python parse cost a command some
    15 ms (docs/design-notes.md, "Reading the problem without PyYAML"). Kept files are a few
    times the size of their text; a read marks its file used, and the cache's limit removes the
    least recently used ones with the compiled libraries (crashnlp.numerics.compiled)."""
    path = Path(path)
    if path.is_dir():
        raise ProblemError(f"{path}: a folder; give {what}")
    if not path.is_file():
        raise ProblemError(f"{path}: file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ProblemError(f"{path}: not valid UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ProblemError(f"{path}: cannot read ({exc.strerror})") from None
    kept = _kept_file(text)
    if kept is not None:
        with suppress(OSError, ValueError):
            used(kept)
            return json.loads(kept.read_text())
    from crashnlp.problem.parse import parse_yaml  # here, not at the top: only a text not read before needs PyYAML

    raw = parse_yaml(text, path)
    values = _as_json(raw, len(text))
    if values is None:
        return raw
    if kept is not None:
        with suppress(OSError):
            write_atomic(kept, values)
    return json.loads(values)  # what a later read gets: a copy wherever aliases point to one value


def _kept_file(text: str) -> Path | None:
    """Where the values of the YAML `text` are kept (`read_yaml`); None where the code that parses
    and keeps them cannot be read to key them (an installation without sources)."""
    parser = _parser()
    if parser is None:
        return None
    key = hashlib.sha256("\0".join((text, *parser)).encode()).hexdigest()[:32]
    return cache_dir() / KEPT_YAML.format(key=key)


@cache
def _parser() -> tuple[str, ...] | None:
    """What else fixes a text's kept values: the code that parses (crashnlp.problem.parse) and keeps
    them (this module's), and PyYAML's version; None where the code cannot be read."""
    try:
        code = files_digest(Path(__file__).with_name(name) for name in ("parse.py", "load.py"))
    except OSError:
        return None
    return (code, installed_version("yaml", "PyYAML"))


def _as_json(values: Any, size: int) -> str | None:
    """`values` (of a YAML text of `size` characters) as JSON text, where JSON gives them back as
    they are (`_plain`); else None."""
    if not _plain(values, set(), [EXPANSION * size + EXPANSION_FLOOR]):
        return None
    try:
        return json.dumps(values)
    except ValueError:  # an integer of more digits than Python turns into text
        return None


def _plain(value: Any, ancestors: set[int], budget: list[int]) -> bool:
    """Whether JSON gives `value` back as it is: mappings with text keys, lists, text, numbers,
    booleans and nulls; not YAML's dates, sets, binary data or other keys. A list or mapping that
    aliases reach from several places is written out at each, as a copy, within `budget` values
    in all (EXPANSION): JSON would write out nested aliases 2^n times for n doublings, and for
    ever a list that holds itself (one of its `ancestors`)."""
    budget[0] -= 1
    if budget[0] < 0:
        return False
    if isinstance(value, dict) and not all(isinstance(k, str) for k in value):
        return False
    if isinstance(value, dict | list):
        if id(value) in ancestors:
            return False
        ancestors.add(id(value))
        plain = all(_plain(v, ancestors, budget) for v in (value.values() if isinstance(value, dict) else value))
        ancestors.discard(id(value))
        return plain
    return value is None or isinstance(value, str | int | float)


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
