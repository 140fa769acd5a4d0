"""Where a simulation came from: the problem it simulated and the fit whose parameters it took.

A prediction handed on is traced to its fit by this record (simulation.json's "source", the
console's line under `crashnlp simulate`, the simulation's report): the problem as given, and
for a fit its result.json as given (a file or its folder), its name, the sha256 of its bytes,
its status and its model form. A Result given in memory (the API) has no file: its record holds
the sha256 of its JSON form (the bytes `Result.save` would write as result.json) and says so.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from crashnlp.results.jsonfile import json_text
from crashnlp.results.result import Result, ResultFile, result_file

IN_MEMORY = "a Result in memory, no file: sha256 of its JSON form"
UNRECORDED = "not recorded (written before crashnlp kept it)"  # what is said in place of `source_line` where it is ''


def simulation_source(
    problem: str | Path | None,
    result: Result | str | Path | None,
    values: dict[str, Any] | None = None,
    file: ResultFile | None = None,
) -> dict[str, Any]:
    """The source of a simulation of `problem` (a file as given; None: a Problem in memory) with
    the parameters of `result` (a Result, a result.json or its folder as given; None: none), or
    the `values` given in their place (dotted path -> value, kept as given). `file`: the result.json
    `result` names where the caller has read it already, not read again."""
    source: dict[str, Any] = {"problem": None if problem is None else str(problem)}
    if values:
        source["values"] = values
    if isinstance(result, Result):
        raw = result.to_json()
        source["result"] = {"path": None, **_fit(raw, json_text(raw).encode()), "note": IN_MEMORY}
    elif result is not None:
        file = file or ResultFile.read(result_file(result))
        source["result"] = {"path": str(result), **_fit(file.document, file.data)}
    return source


def _fit(raw: dict[str, Any], data: bytes) -> dict[str, Any]:
    """A result.json's name, the sha256 of its bytes, its status and model form (None where it
    keeps no identified model: a design's, or one carrying only parameters)."""
    model = (raw.get("identified_model") or {}).get("model")
    form = None
    if isinstance(model, dict):
        from crashnlp.problem.forms import DEFAULT_FORM  # a model that names no form is the default's

        form = model.get("form", DEFAULT_FORM)
    return {"name": raw.get("name"), "sha256": hashlib.sha256(data).hexdigest(), "status": raw.get("status"), "form": form}


def source_line(source: dict[str, Any]) -> str:
    """The source in one line, as the console and the report give it ('' for none: a simulation
    written before crashnlp recorded its source)."""
    if not source:
        return ""
    problem = source.get("problem") or "a problem in memory"
    fit = source.get("result")
    if not fit:
        given = source.get("values")
        return f"from {problem}, with " + (f"{len(given)} values given in memory" if given else "its own values")
    where = fit.get("path") or "a Result in memory (no file; sha256 of its JSON form)"
    head = f"{where}, its own tests" if fit.get("path") == source.get("problem") else f"{problem}, with the parameters of {where}"
    return (
        f"from {head}: {fit.get('name')}, status {fit.get('status')},"
        f" form {fit.get('form') or 'not recorded'}, sha256 {fit.get('sha256')}"
    )
