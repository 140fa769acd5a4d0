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
BENCH = ROOT / "results/bench.json"  # make bench's numbers, read as they are: the benchmarks are not run here
QUOTING = ("README.md", "docs/*.md", "problems/studies/*.yaml")  # the files that quote the runs, as globs from ROOT

BLOCK = re.compile(r"^<!-- numbers: (?P<key>[\w.-]+) -->\n(?P<fence>```[^\n]*\n)(?P<body>.*?)^```", re.MULTILINE | re.DOTALL)
INLINE = re.compile(r"(?P<value>-?[\d.,]+)<!--n:(?P<key>[\w.-]+)-->")

# a prediction of the pickup fitted at 40 and 56 km/h, at 64 km/h (docs/predictions.md's extrapolation)
WHAT_IF = "name: pickup-what-ifs\ntests:\n  - {name: 64kph, speed: 64 km/h, duration: 0.2 s}\n"
PARTS = ("wall", "accelerometers")  # the channels a load-cell barrier's test measures the impact with, each on its own
# the lines of the Camry's fit the README quotes, by how they start (indentation aside)
BRIEF = ("nhtsa-10146: ok", "test ", "max dynamic crush", "time of zero velocity", "peak deceleration", "rebound", "OLC")
BRIEF += ("ISO 18571", "energy balance")


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


def fitted_test(folder: str, test: str) -> dict[str, Any]:
    """One test of a fit's result.json."""
    return dict(json.loads(Path(folder, "result.json").read_text())["tests"][test])


def model_metrics(folder: str, test: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A fit's metrics of one test, model and data, from its result.json."""
    raw = fitted_test(folder, test)["metrics"]
    return raw["model"], raw["data"]


def table_row(prefix: str, test: dict[str, Any]) -> dict[str, str]:
    """A fit's row of docs/barrier.md's table: each channel's ISO 18571 rating, stop, crush, rebound."""
    model = test["metrics"]["model"]
    out = {f"{prefix}.rating.{c}": f"{f['iso18571']['overall']:.3f}" for c, f in test["fit"].items() if f["iso18571"]}
    return out | {
        f"{prefix}.table.max_crush_mm": f"{model['max_crush_m'] * 1e3:.0f}",
        f"{prefix}.table.rebound_mps": f"{model['rebound_velocity_mps']:.2f}",
    }


def channels_apart(consistency: dict[str, Any]) -> dict[str, str]:
    """What the wall and the accelerometers say each on its own (docs/barrier.md): the wall's stop,
    both crushes and rebounds, and how far apart their impulses are."""
    out = {
        "barrier.impulse_apart_pct": f"{(consistency['impulse_ratio'] - 1) * 100:.1f}",
        "barrier.wall.stop_ms": f"{consistency['wall']['time_zero_velocity_s'] * 1e3:.1f}",
    }
    for name in PARTS:
        out[f"barrier.{name}.max_crush_mm"] = f"{consistency[name]['max_crush_m'] * 1e3:.0f}"
        out[f"barrier.{name}.rebound_mps"] = f"{consistency[name]['rebound_velocity_mps']:.1f}"
    return out


def crush_and_stop(prefix: str, metrics: dict[str, Any], digits: Callable[[float], str]) -> dict[str, str]:
    """Max crush (mm) and time of zero velocity (ms) as a page quotes them."""
    return {
        f"{prefix}.max_crush_mm": digits(metrics["max_crush_m"] * 1e3),
        f"{prefix}.stop_ms": digits(metrics["time_zero_velocity_s"] * 1e3),
    }


def console_digits(value: float) -> str:
    """Four significant digits, as the console's metric table prints them."""
    return f"{value:.4g}"


def bench_numbers(bench: dict[str, Any]) -> dict[str, str]:
    """The key numbers of results/bench.json as the README's and the home page's table quote them,
    each as bench/report.py writes it into results/bench.md."""
    ident, sim, whole = bench["identification"], bench["simulation"]["single"], bench["whole_process"]
    shooting, corpus = ident["crashnlp"]["multiple-shooting"], bench["corpus"]["summary"]
    cross, coverage = bench["cross_speed"], bench["self_consistency"]["coverage"]
    joint = next(f for f in cross["fits"] if f["vehicle"] == "pickup-joint.yaml")
    out = {
        "bench.identify_s": f"{shooting['wall_s']:.2f}",
        "bench.identify_iterations": str(shooting["iterations"]),
        "bench.baseline_s": f"{ident['baseline']['wall_s']:.1f}",
        "bench.identify_speedup": f"{ident['ratios']['multiple-shooting']['speedup']:.1f}",
        "bench.process_s": f"{whole['warm']['wall_s']:.2f}",
        "bench.process_mb": f"{max(whole['warm']['peak_rss_mb'], whole['warm_no_figures']['peak_rss_mb']):.0f}",
        "bench.process_no_figures_s": f"{whole['warm_no_figures']['wall_s']:.2f}",
        "bench.baseline_process_s": f"{whole['scipy_baseline']['wall_s']:.2f}",
        "bench.simulation_ms": f"{sim['crashnlp_s'] * 1e3:.1f}",
        "bench.solve_ivp_ms": f"{sim['scipy'][sim['scipy_best']]['wall_s'] * 1e3:.1f}",
        "bench.simulation_speedup": f"{sim['speedup']:.1f}",
        "bench.study_speedup": f"{bench['studies']['speedup_16']['2 workers']:.2f}",
        "bench.corpus_ok": str(corpus["succeeded"]),
        "bench.corpus_vehicles": str(corpus["vehicles"]),
        "bench.corpus_crush_pct": f"{corpus['crush_rel_max'] * 100:.2f}",
        "bench.corpus_stop_ms": f"{corpus['stop_err_max_s'] * 1e3:.2f}",
        "bench.corpus_rating": f"{corpus['force_rating_median']:.3f}",
        "bench.corpus_rating_min": f"{corpus['force_rating_min']:.3f}",
        "bench.corpus_crush_median_pct": f"{corpus['crush_rel_median'] * 100:.2f}",
        "bench.corpus_stop_median_ms": f"{corpus['stop_err_median_s'] * 1e3:.2f}",
        "bench.corpus_iterations": str(max(v["iterations"] for v in bench["corpus"]["vehicles"])),
        "bench.replicates_pct": f"{coverage['coverage_95'] * 100:.0f}",
        "bench.replicates_pairs": str(coverage["pairs"]),
        "bench.joint_crush_pct": f"{joint['crush_rel'] * 100:.1f}",
        "bench.joint_peak_pct": f"{joint['peak_rel'] * 100:.1f}",
        "bench.cross_pct": f"{cross['summary']['coverage'] * 100:.0f}",
        "bench.cross_pairs": str(cross["summary"]["pairs"]),
    }
    for split in ("interpolation", "extrapolation"):
        summary = cross["summary"][split]
        out[f"bench.{split}_within"], out[f"bench.{split}_fits"] = str(summary["within_targets"]), str(summary["fits"])
    grid, speedup = bench["studies"]["grid_16"], bench["studies"]["speedup_16"]
    for name, run_ in (("1", "1 worker"), ("2", "2 workers"), ("dask", "dask LocalCluster, 2 workers")):
        out[f"bench.study_{name}_s"] = f"{grid[run_]['wall_s']:.1f}"
    out["bench.study_dask_speedup"] = f"{speedup['dask LocalCluster, 2 workers']:.2f}"
    consistency = bench["self_consistency"]
    geometry = [e for k, e in consistency["all channels"]["relative_errors"].items() if k.startswith("vehicle.")]
    out["bench.recovery_geometry_pct"] = f"{max(geometry) * 100:.1f}"
    for name, run_ in (("all", "all channels"), ("no_velocity", "without velocity")):
        out[f"bench.recovery_spring_{name}_pct"] = f"{consistency[run_]['relative_errors']['model.spring.values'] * 100:.1f}"
    out["bench.replicates_rms_z"] = f"{coverage['rms_z']:.2f}"
    out["bench.cross_predictions"] = str(sum(cross["summary"][split]["fits"] for split in ("interpolation", "extrapolation")))
    return out


def generate() -> dict[str, dict[str, str]]:
    """Run the shipped problems in a scratch folder; the blocks and numbers the docs quote, with
    make bench's (bench_numbers)."""
    blocks, numbers = {}, bench_numbers(json.loads(BENCH.read_text()))
    with tempfile.TemporaryDirectory(prefix="docs-numbers-") as scratch, chdir(scratch):
        os.symlink(ROOT / "problems", "problems")
        camry = run("identify", "problems/nhtsa-10146.yaml", "--no-figures")
        blocks["identify-nhtsa-10146"] = without_wrote(camry)
        blocks["identify-nhtsa-10146-brief"] = "\n".join(line for line in camry if line.lstrip().startswith(BRIEF))
        model, data = model_metrics("results/nhtsa-10146", "10146")
        numbers |= crush_and_stop("camry", model, console_digits) | crush_and_stop("camry.data", data, console_digits)
        numbers |= table_row("camry", fitted_test("results/nhtsa-10146", "10146"))

        run("identify", "problems/nhtsa-10146-barrier.yaml", "--no-figures")
        barrier = fitted_test("results/nhtsa-10146-barrier", "10146")
        numbers |= table_row("barrier", barrier)
        numbers["barrier.stop_ms"] = console_digits(barrier["metrics"]["model"]["time_zero_velocity_s"] * 1e3)
        numbers |= channels_apart(barrier["consistency"])

        run("identify", "problems/pickup-56kph.yaml", "--no-figures")
        pickup, _ = model_metrics("results/pickup-56kph", "56kph")
        numbers["pickup.max_pitch_deg"] = f"{pickup['max_pitch_deg']:.1f}"
        prediction = run("simulate", "problems/pickup-40kph.yaml", "--params", "results/pickup-56kph/result.json", "--no-figures")
        blocks["simulate-pickup-40kph"] = "\n".join(prediction)
        camry_64 = ("problems/nhtsa-10146.yaml", "--params", "results/nhtsa-10146/result.json", "--speed", "64 km/h")
        faster = run("simulate", *camry_64, "--out", "camry-64", "--no-figures")
        blocks["camry-64-data-not-shown"] = "\n".join(line for line in faster if "data not shown" in line)

        run("identify", "problems/pickup-joint.yaml", "--no-figures")
        Path("what-ifs.yaml").write_text(WHAT_IF)
        joint = run("simulate", "what-ifs.yaml", "--params", "results/pickup-joint/result.json", "--no-figures")
        blocks["pickup-joint-64-extrapolates"] = "\n".join(line for line in joint if "extrapolates" in line)

        run("init", "problems/data/nhtsa-10146/v10146.EV5", "--out", "camry.yaml")
        run("identify", "camry.yaml", "--no-figures")
        init, _ = model_metrics("results/v10146", "v10146")
        numbers |= crush_and_stop("camry.init", init, console_digits)
    if empty := [name for name, text in blocks.items() if not text]:
        raise SystemExit(f"no console line for block {', '.join(empty)}: the command's words changed; change the excerpt")
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
