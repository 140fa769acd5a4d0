"""The numbers the documentation quotes, from the shipped problems run now (`make docs-numbers`).

`python scripts/docs_numbers.py` runs the shipped problems through the command line in a scratch
folder, as a user runs them from the repository root, and writes results/docs-numbers.json:
`blocks`, console excerpts by name, and `numbers`, values as the pages print them by dotted
name. Then it rewrites every place of QUOTING that quotes them, through two markers:

    <!-- numbers: BLOCK -->     the line before a fenced block: the block's lines are blocks[BLOCK]
    VALUE<!--n:KEY-->           an inline value (in prose, a table, a YAML comment): VALUE is numbers[KEY]

Nothing here is typed by hand: a page quotes a run only through a marker, `drift` lists every
marker whose text differs from the file (tests/test_docs_numbers.py holds every quoting file
to it; docs/hooks.py fails `make docs` on it), and `make docs-numbers` brings the pages back in
line after a change of the code moves a number.
"""

from __future__ import annotations

import io
import json
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import chdir, redirect_stdout
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
FILE = ROOT / "results/docs-numbers.json"
QUOTING = ("README.md", "docs/*.md", "problems/studies/*.yaml")  # the files that quote the runs, as globs from ROOT

BLOCK = re.compile(r"^<!-- numbers: (?P<key>[\w.-]+) -->\n(?P<fence>```[^\n]*\n)(?P<body>.*?)^```", re.MULTILINE | re.DOTALL)
INLINE = re.compile(r"(?P<value>-?[\d.,]+)<!--n:(?P<key>[\w.-]+)-->")

# a prediction of the pickup fitted at 40 and 56 km/h, at 64 km/h (docs/predictions.md's extrapolation)
WHAT_IF = "name: pickup-what-ifs\ntests:\n  - {name: 64kph, speed: 64 km/h, duration: 0.2 s}\n"
BRIEF = ("nhtsa-10146: ok", "  test ", "max dynamic crush", "time of zero velocity", "peak deceleration", "rebound", "OLC")
BRIEF += ("    ISO 18571", "    energy balance")


# --------------------------------------------------------------------------- the runs
def run(*argv: str) -> list[str]:
    """The console lines of one crashnlp command run in the current folder; it must succeed."""
    from crashnlp.cli import main

    out = io.StringIO()
    with redirect_stdout(out):
        code = main(list(argv))
    if code != 0:
        raise SystemExit(f"crashnlp {' '.join(argv)}: exit {code}\n{out.getvalue()}")
    return out.getvalue().splitlines()


def without_wrote(lines: list[str]) -> str:
    """A fit's console as the docs show it: without its closing line naming the folder it wrote."""
    return "\n".join(line for line in lines if not line.startswith("wrote "))


def model_metrics(folder: str, test: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A fit's metrics of one test, model and data, from its result.json."""
    raw = json.loads(Path(folder, "result.json").read_text())["tests"][test]["metrics"]
    return raw["model"], raw["data"]


def crush_and_stop(prefix: str, metrics: dict[str, Any], digits: Callable[[float], str]) -> dict[str, str]:
    """Max crush (mm) and time of zero velocity (ms) as a page quotes them."""
    return {
        f"{prefix}.max_crush_mm": digits(metrics["max_crush_m"] * 1e3),
        f"{prefix}.stop_ms": digits(metrics["time_zero_velocity_s"] * 1e3),
    }


def console_digits(value: float) -> str:
    """Four significant digits, as the console's metric table prints them."""
    return f"{value:.4g}"


def generate() -> dict[str, dict[str, str]]:
    """Run the shipped problems in a scratch folder; the blocks and numbers the docs quote."""
    blocks, numbers = {}, {}
    with tempfile.TemporaryDirectory(prefix="docs-numbers-") as scratch, chdir(scratch):
        os.symlink(ROOT / "problems", "problems")
        camry = run("identify", "problems/nhtsa-10146.yaml", "--no-figures")
        blocks["identify-nhtsa-10146"] = without_wrote(camry)
        blocks["identify-nhtsa-10146-brief"] = "\n".join(line for line in camry if line.lstrip().startswith(BRIEF))
        model, data = model_metrics("results/nhtsa-10146", "10146")
        numbers |= crush_and_stop("camry", model, console_digits) | crush_and_stop("camry.data", data, console_digits)

        run("identify", "problems/pickup-56kph.yaml", "--no-figures")
        pickup, _ = model_metrics("results/pickup-56kph", "56kph")
        numbers["pickup.max_pitch_deg"] = f"{pickup['max_pitch_deg']:.1f}"
        prediction = run("simulate", "problems/pickup-40kph.yaml", "--params", "results/pickup-56kph/result.json", "--no-figures")
        blocks["simulate-pickup-40kph"] = "\n".join(prediction)
        faster = run("simulate", "results/nhtsa-10146", "--speed", "64 km/h", "--out", "camry-64", "--no-figures")
        blocks["camry-64-data-not-shown"] = "\n".join(line for line in faster if "data not shown" in line)

        run("identify", "problems/pickup-joint.yaml", "--no-figures")
        Path("what-ifs.yaml").write_text(WHAT_IF)
        joint = run("simulate", "what-ifs.yaml", "--params", "results/pickup-joint/result.json", "--no-figures")
        blocks["pickup-joint-64-extrapolates"] = "\n".join(line for line in joint if "extrapolates" in line)

        run("init", "problems/data/nhtsa-10146/v10146.EV5", "--out", "camry.yaml")
        run("identify", "camry.yaml", "--no-figures")
        init, _ = model_metrics("results/camry", "10146")
        numbers |= crush_and_stop("camry.init", init, console_digits)
    return {"blocks": blocks, "numbers": numbers}


# --------------------------------------------------------------------------- the pages
def quoting() -> Iterator[Path]:
    """The files that quote the runs."""
    for pattern in QUOTING:
        yield from sorted(ROOT.glob(pattern))


def load() -> dict[str, dict[str, str]]:
    """The committed results/docs-numbers.json."""
    return dict(json.loads(FILE.read_text()))


def drift(text: str, quoted: dict[str, dict[str, str]]) -> list[str]:
    """Every marker of `text` whose text differs from `quoted` (or names nothing in it), in words."""
    out = []
    for m in BLOCK.finditer(text):
        want = quoted["blocks"].get(m["key"])
        if want is None or m["body"] != want + "\n":
            out.append(f"block {m['key']}: " + ("no such block" if want is None else "differs from the run"))
    for m in INLINE.finditer(text):
        want = quoted["numbers"].get(m["key"])
        if want != m["value"]:
            out.append(f"{m['key']}: {m['value']}, the run gives {want}" if want else f"{m['key']}: no such number")
    return out


def refresh(text: str, quoted: dict[str, dict[str, str]]) -> str:
    """`text` with every marker's text replaced by what `quoted` says (a marker naming nothing kept)."""
    blocks, numbers = quoted["blocks"], quoted["numbers"]

    def block(m: re.Match) -> str:
        body = blocks[m["key"]] + "\n" if m["key"] in blocks else m["body"]
        return f"<!-- numbers: {m['key']} -->\n{m['fence']}{body}```"

    text = BLOCK.sub(block, text)
    return INLINE.sub(lambda m: f"{numbers.get(m['key'], m['value'])}<!--n:{m['key']}-->", text)


def main() -> None:
    quoted = generate()
    FILE.write_text(json.dumps(quoted, indent=2, sort_keys=True) + "\n")
    print(f"wrote {FILE.relative_to(ROOT)}")
    for path in quoting():
        text = path.read_text()
        if (new := refresh(text, quoted)) != text:
            path.write_text(new)
            print(f"updated {path.relative_to(ROOT)}")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    main()
