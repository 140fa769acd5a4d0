"""mkdocs hooks of the crashnlp site (mkdocs.yml `hooks:`).

- The problem-file reference (`reference/problem-file.md`) gets its table at each build, from the
  JSON Schema of problem files (what `crashnlp schema` prints: the schema of the top-level
  `crashnlp.problem.Problem`): every key by dotted path, its type, SI unit, default and
  description. Only the JSON Schema is read, never the schema module's class names, so the page
  follows any refactoring of the schema's records.
- The numbers a page quotes from the shipped runs (console blocks, a fit's crush and stop time)
  are those of results/docs-numbers.json, which `make docs-numbers` writes
  (scripts/docs_numbers.py): a page whose marked block or number differs from the file, or that
  types a number that is neither marked nor a definition, fails the build, naming it.
- The crash-metric reference (`reference/metrics.md`) gets its table at each build, from the metric
  registry (crashnlp.base.outputs: METRICS, and RENAMED for the keys older files used).
  Both pages are in docs/ with their prose, so that a link to them resolves in the repository
  too, where they say how to see the table without a build (TABLES).
- The figures under results/readme/ and results/bench-scaling.png, CHANGELOG.md and
  results/bench.md live outside docs/; they are added to the site as generated files, so the
  pages link them by their site paths (figures/..., changelog.md, bench-results.md).
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

ROOT = Path(__file__).resolve().parent.parent

# outside docs/ -> site path
COPIED = {
    **{f"figures/{p.name}": p for p in sorted((ROOT / "results/readme").glob("*.png"))},
    "figures/bench-scaling.png": ROOT / "results/bench-scaling.png",
}
PAGES = {
    "changelog.md": ROOT / "CHANGELOG.md",
    "bench-results.md": ROOT / "results/bench.md",
}


def on_files(files: Files, config: Any) -> Files:
    for uri, path in COPIED.items():
        if path.exists():
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    for uri, path in PAGES.items():
        files.append(File.generated(config, uri, content=_page(path)))
    return files


def _docs_numbers() -> ModuleType:
    """scripts/docs_numbers.py, which writes the quoted numbers and reads the pages' markers."""
    spec = importlib.util.spec_from_file_location("docs_numbers", ROOT / "scripts/docs_numbers.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


NUMBERS = _docs_numbers()


DEFINITIONS = NUMBERS.definitions()
# the guide's own pages, history aside, by their site paths; generated pages (the changelog, bench results) are not held to it
GUIDE = [p.relative_to(ROOT) for p in NUMBERS.quoting() if p.suffix == ".md"]
PROSE = {p.relative_to("docs").as_posix() for p in GUIDE if p.parts[0] == "docs"}
PROSE -= {Path(p).relative_to("docs").as_posix() for p in NUMBERS.EXEMPT}


def on_page_markdown(markdown: str, page: Page, config: Any, files: Files) -> str:
    """A page quotes the shipped runs as results/docs-numbers.json says, and types no other
    number than a definition (docs/development.md), or the build fails."""
    drift = NUMBERS.drift(markdown, NUMBERS.load())
    if drift:
        raise PluginError(f"{page.file.src_uri}: {'; '.join(drift)}: run make docs-numbers")
    if page.file.src_uri in PROSE and (typed := NUMBERS.typed(markdown, DEFINITIONS)):
        raise PluginError(f"{page.file.src_uri}: typed by hand, not from a build: {'; '.join(typed)}")
    if (table := TABLES.get(page.file.src_uri)) is not None:
        return markdown.rstrip("\n") + "\n\n" + table()
    return markdown


def _page(path: Path) -> str:
    """A Markdown file from outside docs/, its links to repository files made plain code."""
    text = path.read_text()
    # [text](path) to a file of the repository that the site does not carry: keep the text and name the path
    return re.sub(r"\[([^\]]+)\]\((?!https?:|#)([^)]+)\)", r"\1 (`\2`)", text)


# --------------------------------------------------------------------------- problem-file reference
def file_schema() -> dict:
    """The JSON Schema of problem files: what `crashnlp schema` prints, else the schema of
    `crashnlp.problem.Problem` it is made from."""
    command = Path(sys.executable).with_name("crashnlp")
    if command.exists():
        run = subprocess.run([str(command), "schema"], capture_output=True, text=True, check=False)
        if run.returncode == 0:
            return dict(json.loads(run.stdout))
    from crashnlp.problem import Problem

    return Problem.model_json_schema()


def problem_reference() -> str:
    """The table of docs/reference/problem-file.md: every key of a problem file."""
    schema = file_schema()
    rows: list[list[str]] = []
    _walk(schema, schema, "", rows, set(), _shipped_units())
    lines = [
        "| key | type | unit (SI) | default | description |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- crash-metric reference
def metrics_reference() -> str:
    """The table of docs/reference/metrics.md: the crash metrics as result.json, simulation.json, a
    study's table and compare-results' metrics.csv name them, and the keys files written before a
    rename used: the registry's own."""
    from crashnlp.base.outputs import METRICS, RENAMED, RENAMED_EXTRAPOLATION

    before = {new: old for old, new in RENAMED.items()}
    lines = [
        "| key | what | shown in | CSV column | key in older files |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [f"| `{m.key}` | {m.label} | {m.unit} | `{m.column}` | {_old(before.get(m.key))} |" for m in METRICS]
    lines += [
        "",
        "Files written before the CG's travel was named displacement read as written now: every reader of",
        "`result.json`, `simulation.json` and a study's cases maps the older keys above (`RENAMED`), and a",
        "prediction's `extrapolation` "
        + ", ".join(f"`{old}` to `{new}`" for old, new in RENAMED_EXTRAPOLATION.items())
        + " (`RENAMED_EXTRAPOLATION`).",
    ]
    return "\n".join(lines) + "\n"


TABLES: dict[str, Callable[[], str]] = {  # page -> its generated table, put after the page's own text
    "reference/problem-file.md": problem_reference,
    "reference/metrics.md": metrics_reference,
}


def _old(key: str | None) -> str:
    return f"`{key}`" if key else ""


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _resolve(node: dict, root: dict) -> dict:
    while "$ref" in node:
        name = node["$ref"].split("/")[-1]
        node = {**root["$defs"][name], **{k: v for k, v in node.items() if k != "$ref"}}
    return node


def _variants(node: dict, root: dict) -> list[dict]:
    """The alternatives of a union (anyOf / oneOf), resolved; a plain node is its own one."""
    node = _resolve(node, root)
    for key in ("anyOf", "oneOf"):
        if key in node:
            out: list[dict] = []
            for v in node[key]:
                out += _variants(v, root)
            return out
    return [node]


SI_UNIT = re.compile(r"SI unit (\S+)")


def _unit(node: dict, root: dict) -> str:
    """The SI unit a quantity (or a list of quantities) is stored in, from its schema's description."""
    node = _resolve(node, root)
    for key in ("unit", "x-unit"):  # a schema that states the unit as a key of its own
        if isinstance(node.get(key), str):
            return str(node[key])
    m = SI_UNIT.search(node.get("description", ""))
    if m:
        return m.group(1)
    inner = [*node.get("anyOf", ()), *node.get("oneOf", ())]
    if node.get("type") == "array":
        inner += [node.get("items") or {}, *node.get("prefixItems", ())]
    for v in inner:
        u = _unit(v, root)
        if u:
            return u
    return ""


def _type(node: dict, root: dict) -> str:
    names: list[str] = []
    for v in _variants(node, root):
        if "const" in v:
            name = json.dumps(v["const"])
        elif "enum" in v:
            name = " | ".join(json.dumps(e) for e in v["enum"])
        elif v.get("type") == "array":
            if "prefixItems" in v:
                name = "[" + ", ".join(_type(i, root) for i in v["prefixItems"]) + "]"
            else:
                name = f"list of {_type(v.get('items', {}), root)}"
        elif v.get("type") == "object" or "properties" in v:
            name = "mapping" if not v.get("properties") else "section"
        elif "type" in v:
            t = v["type"]
            name = " or ".join(t) if isinstance(t, list) else str(t)
            if v.get("minimum") is not None or v.get("maximum") is not None:
                name += f" ({v.get('minimum', '')}..{v.get('maximum', '')})"
        else:
            name = "any"
        if name not in names:
            names.append(name)
    quantity = {"number", "string"} <= set(names) and _unit(node, root)
    if quantity:
        names = ["quantity" if n == "number" else n for n in names if n != "string"]
    return " or ".join(names)


def _description(node: dict, root: dict) -> str:
    text = node.get("description") or _resolve(node, root).get("description") or ""
    text = SI_UNIT.sub("", text).strip(" ;,")
    if not text:
        for v in _variants(node, root):
            d = SI_UNIT.sub("", v.get("description", "")).strip(" ;,")
            if d:
                return d
    return text


def _default(node: dict) -> str:
    if "default" not in node or isinstance(node["default"], dict) and node["default"]:
        return ""  # a section's default is its keys' defaults
    return "`" + json.dumps(node["default"]) + "`"


def _shipped_units() -> Callable[[str], str]:
    """The SI unit of a dotted path as a loaded problem tells it (`Problem.unit_at`), for the
    quantities whose JSON Schema carries a description of its own instead of the unit."""
    try:
        from crashnlp.problem import load_problem

        problem = load_problem(ROOT / "problems/pickup-56kph.yaml")
    except Exception:  # the reference is still written, without these units
        return lambda path: ""

    def unit(path: str) -> str:
        try:
            return str(problem.unit_at(path))
        except Exception:
            return ""

    return unit


def _walk(
    node: dict, root: dict, path: str, rows: list[list[str]], seen: set[str], units: Callable[[str], str], note: str = ""
) -> None:
    """Rows for the properties of `node`, then for the sections and lists of sections inside it."""
    node = _resolve(node, root)
    required = set(node.get("required", ()))
    for key, child in node.get("properties", {}).items():
        if all(v.get("type") == "null" for v in _variants(child, root)):
            continue  # set by the loader, never by a file
        dotted = f"{path}.{key}" if path else key
        mark = " (required)" if key in required else ""
        unit = _unit(child, root) or units(dotted)
        kind = _type(child, root)
        if unit and "number or string" in kind:
            kind = kind.replace("number or string", "quantity")
        description = "; ".join(d for d in (_description(child, root), note) if d)
        rows.append([f"`{dotted}`{mark}", kind, unit, _default(child), description])
        variants = _variants(child, root)
        sections = [v for v in variants if v.get("properties")]
        tag = child.get("discriminator", {}).get("propertyName") if len(sections) > 1 else None
        for v in variants:
            if v.get("properties"):
                const = _resolve(v["properties"].get(tag, {}), root).get("const") if tag else None
                _walk(v, root, dotted, rows, seen, units, f"with {tag}: {const}" if const else note)
            elif v.get("type") == "array" and _resolve(v.get("items", {}), root).get("properties"):
                _walk(v["items"], root, f"{dotted}[]", rows, seen, units)
            elif v.get("type") == "object" and isinstance(v.get("additionalProperties"), dict):
                inner = _resolve(v["additionalProperties"], root)
                if inner.get("properties") and f"{dotted}.<name>" not in seen:
                    seen.add(f"{dotted}.<name>")
                    _walk(inner, root, f"{dotted}.<name>", rows, seen, units)
