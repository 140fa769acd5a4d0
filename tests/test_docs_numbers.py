"""The README and the docs quote the shipped runs as results/docs-numbers.json says (written by
`make docs-numbers`, scripts/docs_numbers.py), and never by hand: fast, no fit is run here."""

from __future__ import annotations

import importlib.util
import json
import re

import pytest
import yaml
from builders import ROOT

from crashnlp.base.outputs import METRIC, PREDICTED, TABLED
from crashnlp.cli import metric_row, prediction_part
from crashnlp.problem import load_problem, problem_from_dict

spec = importlib.util.spec_from_file_location("docs_numbers", ROOT / "scripts/docs_numbers.py")
assert spec is not None and spec.loader is not None
numbers = importlib.util.module_from_spec(spec)
spec.loader.exec_module(numbers)

QUOTED = numbers.load()
PAGES = {str(p.relative_to(ROOT)): p for p in numbers.quoting()}


@pytest.mark.parametrize("page", sorted(PAGES))
def test_every_marked_block_and_number_is_the_runs(page):
    assert numbers.drift(PAGES[page].read_text(), QUOTED) == []


def test_the_pages_quote_every_block_and_number_the_runs_give():
    text = "".join(p.read_text() for p in PAGES.values())
    used = {m["key"] for m in numbers.BLOCK.finditer(text)} | {m["key"] for m in numbers.INLINE.finditer(text)}
    assert used == set(QUOTED["blocks"]) | set(QUOTED["numbers"])


def test_the_benchmarks_numbers_read_now_are_the_quoted_ones():
    """results/bench.json read as make docs-numbers reads it gives every bench number the pages
    quote, under the same keys (the intervals' scenario and metric names from bench/calibration.py)."""
    quoted = {key: value for key, value in QUOTED["numbers"].items() if key.startswith("bench.")}
    assert numbers.bench_numbers(json.loads(numbers.BENCH.read_text())) == quoted
    scenarios, metrics = numbers.intervals_keys()
    assert scenarios["one test down, 56 -> 40"] == "down40" and metrics["max_displacement_m"] == "displacement"
    assert len(set(scenarios.values())) == len(scenarios) and len(set(metrics.values())) == len(metrics)


def unmarked(text: str) -> str:
    """`text` without its marked blocks and numbers: what was typed by hand."""
    return numbers.INLINE.sub("", numbers.BLOCK.sub("", text))


@pytest.mark.parametrize("page", sorted(PAGES))
def test_no_quoted_number_is_typed_outside_a_marker(page):
    typed = unmarked(PAGES[page].read_text())
    for key, value in QUOTED["numbers"].items():
        if len(re.sub(r"\D", "", value)) >= 4:  # "2.45" may be an input (a CG's height); "745.7" is the Camry's crush
            assert not re.search(rf"(?<![\d.]){re.escape(value)}(?![\d])", typed), f"{key} = {value} typed by hand"


DEFINITIONS = numbers.definitions()
PROSE = sorted(page for page in PAGES if page.endswith(".md") and page not in numbers.EXEMPT)


@pytest.mark.parametrize("page", PROSE)
def test_every_number_of_the_prose_is_marked_generated_or_a_definition(page):
    assert numbers.typed(PAGES[page].read_text(), DEFINITIONS) == []


def test_a_typed_result_is_caught_and_definitions_are_not():
    text = (
        "The fit crushes 745.7 mm in 23 iterations (ISO 18571, CFC 60, issue 41, seed 2030, test 10146).\n"
        "At 56 km/h (a problem's input) and 1e-8 (a tolerance of the code) with 3 workers, exit 2.\n"
        "Marked 745.7<!--n:camry.max_displacement_mm--> and `crashnlp simulate --speed '73.5 km/h'`.\n"
        "<!-- numbers: identify-nhtsa-10146-brief -->\n```\n11 iterations, objective 4.66465\n```\n"
    )
    assert numbers.typed(text, DEFINITIONS) == ["line 1: 745.7", "line 1: 23"]
    assert numbers.typed("the pickup rated 0.955 at 20 kN", frozenset({20e3})) == ["line 1: 0.955"]


def test_a_drifted_number_or_block_is_named_and_refresh_brings_it_back():
    readme = PAGES["README.md"].read_text()
    crush = QUOTED["numbers"]["camry.max_displacement_mm"]
    block = QUOTED["blocks"]["identify-nhtsa-10146-brief"]
    stale = readme.replace(f"{crush}<!--n:camry.max_displacement_mm-->", "745.8<!--n:camry.max_displacement_mm-->")
    stale = stale.replace(block, block.replace("11 iterations", "12 iterations"))
    assert numbers.drift(stale, QUOTED) == [
        "block identify-nhtsa-10146-brief: differs from the run",
        f"camry.max_displacement_mm: 745.8, the run gives {crush}",
    ]
    assert numbers.refresh(stale, QUOTED) == readme
    assert numbers.drift("1.0<!--n:no.such-->", QUOTED) == ["no.such: no such number"]


# what the README's example shows beyond the shipped pickup: more keys, as its text says
SHOWN_BEYOND = ("constraints.bounds", "objective", "solver", "transcription", "reference", "tests.0.speed")


def flat(value, path: str = "") -> dict[str, object]:
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in flat(item, f"{path}.{key}" if path else key).items()}
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return {k: v for i, item in enumerate(value) for k, v in flat(item, f"{path}.{i}").items()}
    return {path: value}


@pytest.mark.parametrize("page", ["README.md", "docs/problem-files.md"])
def test_the_readme_problem_is_the_shipped_pickup_with_more_keys_shown(page):
    """The complete problem the README and the problem-file page show (docs/problem-files.md's
    had drifted: crush offset 0 m, two estimates short) is the shipped file, keys shown beyond."""
    text = (ROOT / page).read_text()
    example = yaml.safe_load(re.search(r"```yaml\n(.*?)```", text, re.DOTALL)[1])
    shipped = load_problem(ROOT / "problems/pickup-56kph.yaml")
    shown = problem_from_dict(example, base_dir=ROOT / "problems")
    a, b = flat(shipped.model_dump()), flat(shown.model_dump())
    differ = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
    assert [k for k in differ if not k.startswith(SHOWN_BEYOND)] == []


def test_the_docs_build_fails_on_a_drifted_page():
    PluginError = pytest.importorskip("mkdocs.exceptions", reason="the docs extra (make docs)").PluginError
    hooks = importlib.util.spec_from_file_location("hooks", ROOT / "docs/hooks.py")
    assert hooks is not None and hooks.loader is not None
    module = importlib.util.module_from_spec(hooks)
    hooks.loader.exec_module(module)

    class Page:  # what the hook reads of mkdocs' page
        class file:
            src_uri = "index.md"

    with pytest.raises(PluginError, match=r"index.md: camry.stop_ms: 1.0, the run gives .*: run make docs-numbers"):
        module.on_page_markdown("stop 1.0<!--n:camry.stop_ms--> ms", Page, None, None)
    with pytest.raises(PluginError, match=r"index.md: typed by hand, not from a build: line 2: 745.7"):
        module.on_page_markdown("The Camry\ncrushes 745.7 mm.", Page, None, None)


ROWS = {m.label: m for m in TABLED}
TABLE_ROW = re.compile(rf"    (?P<label>{'|'.join(map(re.escape, ROWS))}) \([^)]*\)(?P<cells>.*)")
SHORT = {m.short: m for m in PREDICTED if m.short}
NUMBER = r"-?\d+(?:\.\d+)?"
PART = re.compile(
    rf"(?P<short>{'|'.join(map(re.escape, SHORT))}) (?P<value>{NUMBER})(?: \[(?P<low>{NUMBER}), (?P<high>{NUMBER})\])?"
)
PREDICTION_HEAD = r"\S+(?:, [^:]+)?: "  # a prediction line's test, and the speed and mass it ran at
AFTER_PART = ("", ", ", " (95 % intervals)")  # what follows a part of a prediction's line


def labels_unlike_the_consoles(block: str, read_through: str | None) -> list[str]:
    """The lines of a quoted console block whose metric labels differ from those the console
    prints now from the metric registry (crashnlp.base.outputs), accelerations read through
    `read_through`: a fit's metric table's rows (heading and column widths) and each metric of a
    prediction's line, printed again from the line's own values."""
    wrong = []
    for line in block.splitlines():
        if row := TABLE_ROW.fullmatch(line):
            cells = [*row["cells"].split(), "", ""][:2]
            if line.rstrip() != metric_row(ROWS[row["label"]], read_through, *cells).rstrip():
                wrong.append(line)
        elif re.match(rf"{PREDICTION_HEAD}{PART.pattern}", line):
            for part in PART.finditer(line):
                m = SHORT[part["short"]]
                band = None if part["low"] is None else (float(part["low"]) / m.factor, float(part["high"]) / m.factor)
                again = prediction_part(m, float(part["value"]) / m.factor, band, read_through)
                rest = line[part.start() :]
                if not (
                    rest.startswith(again) and any(rest[len(again) :].startswith(a) for a in AFTER_PART[1:]) or rest == again
                ):
                    wrong.append(line)
                    break
    return wrong


@pytest.mark.parametrize("block", sorted(QUOTED["blocks"]))
def test_a_quoted_console_block_names_its_metrics_as_the_console_does_now(block):
    """A fit's metric table or a prediction's line quoted by the pages carries the metric labels
    the registry gives now (results/docs-numbers.json had kept "peak deceleration (g)" after the
    console came to name the CFC class): no fit is run, the block's own values are printed again.
    Every block that holds such a line says what its accelerations were read through."""
    text = QUOTED["blocks"][block]
    labelled = any(TABLE_ROW.fullmatch(line) or re.match(rf"{PREDICTION_HEAD}{PART.pattern}", line) for line in text.splitlines())
    assert labelled == (block in QUOTED["read_through"])
    if labelled:
        assert labels_unlike_the_consoles(text, QUOTED["read_through"][block]) == []


def test_a_stale_label_or_column_width_is_caught():
    table = "  test 1                              model      test\n"
    fresh = metric_row(METRIC["peak_decel_g"], "CFC60", "42.1", "40.94")
    prediction = "40kph, predicted at 40.0 km/h, 2400 kg: max displacement 382.9 [354.9, 410.9] mm, peak decel 19.6 g (CFC60)"
    assert labels_unlike_the_consoles(table + fresh + "\n" + prediction, "CFC60") == []
    stale = [
        "    peak deceleration (g)              42.1     40.94",
        fresh.replace("  42.1", " 42.1"),
        prediction.replace(" (CFC60)", ""),
    ]
    for line in stale:
        assert labels_unlike_the_consoles(line, "CFC60") == [line]
