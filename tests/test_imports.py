"""The package's layers: every module of crashnlp sits in a layer of the import-linter contract in
pyproject.toml, few modules sit directly in crashnlp/, and no import among crashnlp's modules
runs in a cycle.

`make lint` holds the imports to the contract (lint-imports): a lower layer never imports a
higher one, and crashnlp.api, the second layer from the top, is imported by nothing inside the
package but the command line (and the package's __init__, which is no layer). A module the
contract does not name is not checked by it at all; hence the first test here. Nor does the
contract see a cycle inside one layer; hence the cycle test, where every import counts, those
inside functions too, but not those under `if TYPE_CHECKING:` (they never run). `from crashnlp.x
import y` is an edge to crashnlp.x.y when that is a module, else to crashnlp.x; a package's
__init__ is the package's module.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "crashnlp"
TOP_MODULES = 6  # at most this many modules directly in crashnlp/ (its __init__ among them)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of a module, at any depth, but none under `if TYPE_CHECKING:`."""
    found: list[ast.Import | ast.ImportFrom] = []
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        stack.extend(ast.iter_child_nodes(node))
    return found


def imported(name: str, path: Path, known: set[str]) -> set[str]:
    """The crashnlp modules one module imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in _imports(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        out |= {t for t in targets if t in known and t != name}
    return out


def import_graph() -> dict[str, set[str]]:
    found = modules()
    return {name: imported(name, path, set(found)) for name, path in found.items()}


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan), each a cycle or several."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle():
    found = [sorted(c) for c in cycles(import_graph())]
    assert not found, f"import cycles in crashnlp: {found}"


def layers() -> list[str]:
    """The layers of the contract, each side-by-side name on its own."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (contract,) = (c for c in config["contracts"] if c["type"] == "layers")
    return [name.strip() for layer in contract["layers"] for name in layer.split("|")]


def test_every_module_sits_in_a_layer():
    named = layers()
    outside = sorted(m for m in modules() if m != "crashnlp" and not any(m == n or m.startswith(n + ".") for n in named))
    assert not outside, f"modules in no layer of pyproject.toml's [tool.importlinter] (place them): {outside}"


def test_few_modules_directly_in_the_package():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= TOP_MODULES, f"{len(top)} modules directly in crashnlp/: {top}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from crashnlp.lower import Case\n", {"crashnlp.lower"}),
        ("def f():\n    from crashnlp import lower\n", {"crashnlp.lower"}),
        ("import crashnlp.lower as c\n", {"crashnlp.lower"}),
        ("from .lower import Case\n", {"crashnlp.lower"}),
        ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from crashnlp.lower import Case\n", set()),
    ],
)
def test_the_graph_sees_every_kind_of_import(tmp_path, source, expected):
    path = tmp_path / "mod.py"
    path.write_text(source)
    assert imported("crashnlp.mod", path, {"crashnlp", "crashnlp.lower", "crashnlp.mod"}) == expected


def test_a_cycle_is_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def plain_imports(code: str) -> set[str]:
    """The top-level packages a fresh process loads to run `code`; none of CasADi, pydantic,
    matplotlib or PyYAML may be among them (asserted here), crashnlp and numpy must."""
    measured = (
        f"import sys; before = set(sys.modules); {code};"
        " print(sorted({m.partition('.')[0] for m in set(sys.modules) - before}))"
    )
    printed = subprocess.run([sys.executable, "-c", measured], capture_output=True, text=True, check=True).stdout
    loaded = set(ast.literal_eval(printed))
    assert "crashnlp" in loaded and "numpy" in loaded
    assert not loaded & {"casadi", "pydantic", "matplotlib", "yaml"}, sorted(loaded)
    return loaded


@pytest.mark.integration  # a process of its own
def test_a_result_imports_with_numpy_alone():
    """`crashnlp.Result` and the plain types in it load without CasADi, pydantic or matplotlib: a
    result read back, a report or a table of results pays for none of them."""
    plain_imports("import crashnlp; from crashnlp import Result; Result.load")


@pytest.mark.integration  # a process of its own
def test_a_simulation_folder_reads_with_numpy_alone(tmp_path):
    """A simulation's folder is written, read back and its page rendered (as `crashnlp report` does)
    without CasADi, pydantic or matplotlib, a test past the identified range too: its predicted
    tests are plain results (crashnlp.results.simulation)."""
    plain_imports(
        "from pathlib import Path; import numpy as np;"
        " from crashnlp.base.outputs import COLUMNS; from crashnlp.report.folders import read_simulation;"
        " from crashnlp.report import simulation_page; from crashnlp.results.response import Response;"
        " from crashnlp.results.simulation import PredictedTest, write_simulation;"
        " t = np.linspace(0.0, 0.1, 5); r = Response(t, {o.name: t for o in COLUMNS}, np.zeros((0, 5)));"
        f" out = Path({str(tmp_path / 'sim')!r});"
        " past = {'t1': PredictedTest('t1', 15.0, 2000.0, r, {'peak_decel_g': 30.0}, extrapolation={'speed_mps': 2.0})};"
        " write_simulation('x', past, out);"
        " name, tests = read_simulation(out); assert name == 'x' and tests['t1'].metrics == {'peak_decel_g': 30.0};"
        " assert 'extrapolates: speed 7.2 km/h above the fastest' in simulation_page(name, past, out)"
    )


UNUSED_ON_A_RUN = ("matplotlib", "numpy.ma", "scipy", "yaml", "tempfile", "statistics", "zipfile", "difflib")


@pytest.mark.integration  # processes of their own, and fits or simulations
@pytest.mark.parametrize("command", ["identify", "simulate"])
def test_a_command_without_figures_imports_no_library_it_does_not_use(tmp_path, command):
    """`crashnlp identify` and `simulate` with `--no-figures`, run after a `simulate` of the same
    problem, load neither matplotlib nor scipy nor numpy.ma (which np.median and np.percentile
    import on their first call: a third of numpy's own import), nor PyYAML (the problem's values
    come from the cache once read), nor the standard library's
    tempfile, statistics, zipfile and difflib (milliseconds each, with what they import, for what
    a run of a shipped problem never does). The first run may: pint, reading a
    unit the cache's table has not seen yet, imports scipy. The runs have a cache of their own: the
    table is written whole, so a process of another test may drop what the first run wrote."""
    env = {**os.environ, "CRASHNLP_CACHE": str(tmp_path / "cache")}  # its own: no other test's process rewrites the units
    for run in ("simulate", command):  # the first fills the cache (units, the model's functions), for less than a fit
        code = (
            "import sys; from crashnlp.cli import main;"
            f" code = main([{run!r}, {str(ROOT / 'problems/pickup-56kph.yaml')!r}, '--out', {str(tmp_path / run)!r},"
            f" '--no-figures']); print(code, sorted(m for m in {UNUSED_ON_A_RUN!r} if m in sys.modules))"
        )
        printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert printed.splitlines()[-1] == "0 []", printed


@pytest.mark.integration  # a process of its own
def test_reading_a_problem_loads_no_validation_library():
    """Reading and validating a problem (units from the cache's table) loads neither pydantic nor
    importlib.metadata: each cost more than the rest of reading it (docs/design-notes.md, "The
    problem schema's cost"). The first read fills the table; the second is the one measured."""
    code = (
        "import sys; from crashnlp.problem import load_problem;"
        f" load_problem({str(ROOT / 'problems/pickup-56kph.yaml')!r});"
        " print(sorted(m for m in ('pydantic', 'pydantic_core', 'importlib.metadata') if m in sys.modules))"
    )
    for _ in range(2):
        printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert printed.split() == ["[]"], printed
