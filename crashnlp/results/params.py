"""A fit's result.json given to a simulation: `crashnlp simulate PROBLEM --params FILE` and
`crashnlp.simulate(problem, params=FILE)` read it here, so that both take the same files (a
result.json, another name for one, or a fit's folder) and refuse the same, in the same one line.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from crashnlp.base.errors import InputError
from crashnlp.results.identified import IdentifiedModel, apply, load_applied
from crashnlp.results.result import RESULT_FILE, ResultFile, read_params

if TYPE_CHECKING:
    from crashnlp.problem import Problem


def identified_of(source: str, raw: dict[str, Any]) -> IdentifiedModel | None:
    """The identified vehicle of a result.json's content, or None for one that carries only
    parameters; a fit's result.json (one with an identified vehicle) whose status is not as a fit
    writes it is refused."""
    from crashnlp.results.result import refuse_status

    entry = raw.get("identified_model")
    if entry is None:
        return None
    refuse_status(raw.get("status"), source)
    try:
        return IdentifiedModel.from_json(entry)
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError(f"{source}: identified_model: not the identified model a fit writes") from None


def with_params(problem: Problem | str | Path, path: str | Path) -> tuple[Problem, IdentifiedModel | None, ResultFile]:
    """(problem, identified model, the result.json read) of a problem (a Problem, or its file) and
    the result.json `path` names: its identified vehicle put into the problem (what a problem file
    leaves out of vehicle and model comes from it), or for a result that carries only parameters,
    its values entry by entry, refusing what does not fit (crashnlp.problem.parameters; the
    identified model is then None). Errors name `path`."""
    from crashnlp.problem import Problem, load_problem
    from crashnlp.problem.parameters import with_parameters

    source = str(path)
    read = read_params(path)
    identified = identified_of(source, read.current)
    if identified is not None:
        put_in = apply(problem, identified, source) if isinstance(problem, Problem) else load_applied(problem, identified, source)
        return put_in, identified, read
    loaded = problem if isinstance(problem, Problem) else load_problem(problem)
    return with_parameters(loaded, read.current["parameters"], source), None, read


def given_result(path: str | Path) -> str | None:
    """The result.json a simulation's problem names where it is a fit's (or a design's) result
    itself, its folder or the file (a .json of any name but a problem file written in JSON:
    _problem_in_json); None for a problem file. A folder without result.json is an InputError."""
    folder = Path(path) / RESULT_FILE
    if Path(path).is_dir() and not folder.is_file():
        raise InputError(f"{path}: a folder without result.json; simulate a problem file, or a fit's folder")
    if folder.is_file():
        return str(folder)
    return str(path) if str(path).endswith(".json") and not _problem_in_json(Path(path)) else None


def _problem_in_json(file: Path) -> bool:
    """Whether a .json file is a problem file (JSON is YAML, and identify reads it as one): a
    mapping with the problem's `vehicle` and no result's `parameters`. A file that cannot be read
    or parsed is not: read as a result, it is refused naming the file (read_params)."""
    try:
        document = json.loads(file.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(document, dict) and "vehicle" in document and "parameters" not in document
