"""A study's table.csv and figures."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.files import atomic_open
from crashnlp.studies.plan import PlannedCase
from crashnlp.studies.spec import Study, SweepEntry

if TYPE_CHECKING:
    pass

PLOTTED = ("max_crush_m", "peak_decel_g", "max_pitch_deg", "olc_g")


def show(value: Any) -> str:
    """A swept value as the user wrote it, in YAML flow style ([null, 4 deg])."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {show(v)}" for k, v in value.items()) + "}"
    return str(value)


def write_table(path: Path, rows: list[dict[str, Any]]) -> None:
    """table.csv: the union of the rows' columns, in first-seen order; missing cells empty."""
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_open(path) as fh:
        writer = csv.DictWriter(fh, columns, restval="")
        writer.writeheader()
        writer.writerows([{k: "" if v is None else v for k, v in r.items()} for r in rows])


def write_figures(folder: Path, study: Study, cases: list[PlannedCase], rows: list[dict]) -> None:
    """Objective, metrics and swept multipliers of the solved cases against each swept entry.

    With several varied entries in a grid, one figure per combination of the others.
    """
    solved = [(c, r) for c, r in zip(cases, rows) if r["status"] == "ok"]
    if not solved:
        return
    names = ["objective"] + [
        k for k in dict.fromkeys(k for _, r in solved for k in r) if k.endswith(PLOTTED) or k.startswith("multiplier.")
    ]
    for i, entry in enumerate(study.entries):
        if len(entry.values) < 2:
            continue
        groups: dict[tuple, list] = {}
        for c, r in solved:
            others = tuple(show(v) for j, v in enumerate(c.values) if j != i)
            groups.setdefault(others, []).append((c, r))
        for k, (others, members) in enumerate(groups.items()):
            suffix = f"-{k}" if len(groups) > 1 else ""
            where = ", ".join(f"{e.path} = {v}" for e, v in zip([e for j, e in enumerate(study.entries) if j != i], others))
            _figure(folder / f"{entry.path}{suffix}.png", entry, i, members, names, f"{study.name} {where}".strip())


def _figure(path: Path, entry: SweepEntry, i: int, members: list, names: list[str], title: str) -> None:
    x = np.array([entry.si(c.values[i]) for c, _ in members])
    xlabel = f"{entry.path} ({entry.unit})" if entry.unit else entry.path
    if np.all(np.isnan(x)):
        x = np.array([float(c.index[0] if len(c.index) == 1 else c.index[i]) for c, _ in members])
        xlabel = f"{entry.path} (value number)"
    order = np.argsort(x, kind="stable")
    series = {n: np.array([_number(r.get(n)) for _, r in members])[order] for n in names}
    from crashnlp import plots  # matplotlib: only once the figures are drawn

    plots.xy_figure(path, x[order], series, xlabel, title)


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
