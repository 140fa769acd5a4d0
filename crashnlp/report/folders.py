"""What a folder crashnlp wrote holds, read back through the loaders that wrote it.

A fit or a design (result.json: `Result.load`), a simulation (simulation.json:
crashnlp.results.simulation.read_simulation) or a study (cases/: crashnlp.studies.store.CaseStore).
The report and the exports read folders here; a folder that is none of these, or whose files
do not read as crashnlp writes them, is an InputError naming it (one line, exit 2).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from crashnlp.base.errors import InputError, unreadable
from crashnlp.results import simulation
from crashnlp.results.result import RESULT_FILE, Result, ResultFile, refuse_edited
from crashnlp.results.simulation import PredictedTest

if TYPE_CHECKING:
    from crashnlp.problem.schema import Problem
    from crashnlp.results.identified import IdentifiedModel
from crashnlp.studies.store import CaseStore

Kind = Literal["result", "simulation", "study"]
MARKERS: tuple[tuple[Kind, str], ...] = (("result", "result.json"), ("simulation", "simulation.json"), ("study", "cases"))


def folder_kind(folder: Path) -> Kind:
    """Which of crashnlp's folders `folder` is, by the file that marks it."""
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder" if folder.exists() else f"{folder}: no such folder")
    for kind, marker in MARKERS:
        if (folder / marker).exists():
            return kind
    raise InputError(f"{folder}: holds no result.json, simulation.json or cases/: not a folder crashnlp wrote")


def read_result(folder: Path, file: ResultFile | None = None) -> Result:
    """The fit or design in `folder` (`file`: its result.json where the caller has read it
    already), refused where it was edited out of what crashnlp writes (refuse_edited): what a
    prediction, an export or a report of it reads is checked here, once."""
    path = folder / RESULT_FILE
    with reading(path):
        return refuse_edited(Result.load(folder, file), str(path))


def result_alone(path: str, params: object | None, given_as: str) -> tuple[Problem, IdentifiedModel | None, ResultFile]:
    """(problem, identified model, the result.json read) of a result.json given in place of a
    problem (crashnlp.results.params.given_result): its own tests with its identified vehicle
    (crashnlp.analysis.prediction.own_tests); an InputError where `params` (named `given_as`) is
    given too."""
    from crashnlp.analysis.prediction import own_tests
    from crashnlp.results.result import fit_folder, read_params

    if params is not None:
        raise InputError(
            f"{given_as} {params}: {path} is a result already; give a problem file with {given_as}, or the result alone"
        )
    read = read_params(path)  # one line for a file that is not a result.json
    result = read_result(fit_folder(path), read)
    return own_tests(result, path), result.identified, read


def read_simulation(folder: Path) -> tuple[str, dict[str, PredictedTest]]:
    """The name and the predicted tests of the simulation in `folder`."""
    with reading(folder / "simulation.json"):
        return simulation.read_simulation(folder)


def read_study(folder: Path) -> list[dict]:
    """The rows of the study's finished cases in `folder`, in case order."""
    rows = CaseStore(folder / "cases").rows()
    if not rows:
        raise InputError(f"{folder / 'cases'}: no finished case")
    return rows


@contextmanager
def reading(path: Path) -> Iterator[None]:
    """Any failure to read a folder's files, or what they hold, becomes one line naming `path`,
    the file that marks it (crashnlp.base.errors.unreadable); an InputError is that line already."""
    try:
        yield
    except InputError:
        raise  # one line already, naming the file and the entry
    except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
        raise unreadable(path, exc) from None
