"""The numbers the documentation quotes, from the shipped problems run now (`make docs-numbers`).

`python scripts/docs_numbers.py` runs the shipped problems through the command line in a scratch
folder, as a user runs them from the repository root, reads results/bench.json as `make bench`
left it, and writes results/docs-numbers.json: `blocks`, console excerpts by name, and `numbers`,
values as the pages print them by dotted name. Then it rewrites every place of QUOTING that
quotes them, through two markers:

    <!-- numbers: BLOCK -->     the line before a fenced block: the block's lines are blocks[BLOCK]
    VALUE<!--n:KEY-->           an inline value (in prose, a table, a YAML comment): VALUE is numbers[KEY]

Nothing here is typed by hand: a page quotes a run only through a marker, `drift` lists every
marker whose text differs from the file (tests/test_docs_numbers.py holds every quoting file
to it; docs/hooks.py fails `make docs` on it), and `make docs-numbers` brings the pages back in
line after a change of the code moves a number. Reading and checking the pages imports nothing
of crashnlp; only the runs do.
"""

from __future__ import annotations

import io
import json
import os
import re
import tempfile
from collections.abc import Iterator
from contextlib import chdir, redirect_stdout
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
FILE = ROOT / "results/docs-numbers.json"
BENCH = ROOT / "results/bench.json"  # make bench's numbers, read as they are: the benchmarks are not run here
QUOTING = ("README.md", "docs/*.md", "problems/studies/*.yaml")  # the files that quote the runs, as globs from ROOT

BLOCK = re.compile(r"^<!-- numbers: (?P<key>[\w.-]+) -->\n(?P<fence>```[^\n]*\n)(?P<body>.*?)^```", re.MULTILINE | re.DOTALL)
INLINE = re.compile(r"(?P<value>[-+]?[\d.,]+)<!--n:(?P<key>[\w.-]+)-->")

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


def crush_and_stop(prefix: str, metrics: dict[str, Any]) -> dict[str, str]:
    """Max crush (mm) and time of zero velocity (ms) as the console's metric table prints them."""
    return {
        f"{prefix}.max_crush_mm": console_digits(metrics["max_crush_m"] * 1e3),
        f"{prefix}.stop_ms": console_digits(metrics["time_zero_velocity_s"] * 1e3),
    }


def peak(prefix: str, metrics: dict[str, Any]) -> dict[str, str]:
    """Peak deceleration (g) as the console's metric table prints it (the model's as the test
    recorded it)."""
    return {f"{prefix}.peak_g": console_digits(metrics["peak_decel_g"])}


def console_digits(value: float) -> str:
    """Four significant digits, as the console's metric table prints them."""
    return f"{value:.4g}"


def bench_numbers(bench: dict[str, Any]) -> dict[str, str]:
    """The numbers of results/bench.json the pages quote ("bench.<name>"), each formatted as the
    pages print it; the sections of make bench one function each."""
    parts = (_identification, _process, _simulation, _studies, _corpus, _cross_speed, _families, _self_consistency, _intervals)
    return {f"bench.{name}": text for part in parts for name, text in part(bench).items()}


def _identification(bench: dict[str, Any]) -> dict[str, str]:
    ident = bench["identification"]
    shooting, collocation = ident["crashnlp"]["multiple-shooting"], ident["crashnlp"]["collocation"]
    vm, baseline, ratios = ident["virtual_machine"]["multiple-shooting"], ident["baseline"], ident["ratios"]
    data, data_baseline = ident["from_data"]["crashnlp"], ident["from_data"]["baseline"]
    return {
        "identify_s": f"{shooting['wall_s']:.2f}",
        "identify_iterations": str(shooting["iterations"]),
        "identify_ms_per_iteration": f"{shooting['ms_per_iteration']:.1f}",
        "identify_objective": f"{shooting['objective']:.5g}",
        "identify_speedup": f"{ratios['multiple-shooting']['speedup']:.1f}",
        "baseline_s": f"{baseline['wall_s']:.1f}",
        "baseline_simulations": str(baseline["simulations"]),
        "baseline_objective": f"{baseline['objective']:.4g}",
        "vm_s": f"{vm['wall_s']:.2f}",
        "vm_ms_per_iteration": f"{vm['ms_per_iteration']:.0f}",
        "vm_speedup": f"{baseline['wall_s'] / vm['wall_s']:.1f}",
        "collocation_s": f"{collocation['wall_s']:.2f}",
        "collocation_iterations": str(collocation["iterations"]),
        "collocation_ms_per_iteration": f"{collocation['ms_per_iteration']:.1f}",
        "collocation_speedup": f"{ratios['collocation']['speedup']:.1f}",
        "from_data_s": f"{data['wall_s']:.2f}",
        "from_data_iterations": str(data["iterations"]),
        "from_data_objective": f"{data['objective']:.5g}",
        "from_data_baseline_s": f"{data_baseline['wall_s']:.1f}",
        "from_data_baseline_iterations": str(data_baseline["iterations"]),
        "from_data_baseline_simulations": str(data_baseline["simulations"]),
        "from_data_baseline_objective": f"{data_baseline['objective']:.4g}",
        "from_data_speedup": f"{ident['from_data']['speedup']:.0f}",
    }


def _process(bench: dict[str, Any]) -> dict[str, str]:
    whole = bench["whole_process"]
    runs = {
        "process": "warm",
        "process_no_figures": "warm_no_figures",
        "baseline_process": "scipy_baseline",
        "simulate": "simulate_warm",
        "simulate_no_figures": "simulate_no_figures",
        "import": "python_numpy_casadi",
    }
    out = {f"{name}_s": f"{whole[run]['wall_s']:.2f}" for name, run in runs.items()}
    out |= {f"{name}_mb": f"{whole[run]['peak_rss_mb']:.0f}" for name, run in runs.items()}
    return out | {
        "process_first_s": f"{whole['first_run_fresh_cache']['wall_s']:.1f}",
        "process_speedup": f"{whole['speedup']:.1f}",
        "process_no_figures_speedup": f"{whole['speedup_no_figures']:.1f}",
    }


def _simulation(bench: dict[str, Any]) -> dict[str, str]:
    single, batch = bench["simulation"]["single"], bench["simulation"]["batch"]
    return {
        "simulation_ms": f"{single['crashnlp_s'] * 1e3:.1f}",
        "simulation_call_ms": f"{single['crashnlp_call_only_s'] * 1e3:.1f}",
        "solve_ivp_ms": f"{single['scipy'][single['scipy_best']]['wall_s'] * 1e3:.1f}",
        "simulation_speedup": f"{single['speedup']:.1f}",
        "batch_compiled_s": f"{batch['compiled']['wall_s']:.2f}",
        "batch_vm_s": f"{batch['vm']['wall_s']:.1f}",
    }


def _studies(bench: dict[str, Any]) -> dict[str, str]:
    studies, out = bench["studies"], {}
    for study, name in (("pitch_bound", "pitch_bound"), ("grid_16", "study"), ("grid_64", "grid64")):
        speedup = studies[f"speedup_{study.removeprefix('grid_')}"]
        out[f"{name}_speedup"] = f"{speedup['2 workers']:.2f}"
        for workers, run in (("1", "1 worker"), ("2", "2 workers")):
            out[f"{name}_{workers}_s"] = f"{studies[study][run]['wall_s']:.1f}"
    for workers, run in (("1", "1 worker"), ("2", "2 workers")):  # the 16-case grid runs three times
        walls = studies["grid_16"][run]["walls_s"]
        out[f"study_{workers}_fastest_s"], out[f"study_{workers}_slowest_s"] = f"{min(walls):.1f}", f"{max(walls):.1f}"
    one = studies["grid_16"]["1 worker"]
    out["study_solves_s"], out["study_chain_s"] = f"{one['solves_s']:.1f}", f"{one['longest_chain_s']:.1f}"
    dask = "dask LocalCluster, 2 workers"
    out["study_dask_s"] = f"{studies['grid_16'][dask]['wall_s']:.1f}"
    out["study_dask_speedup"] = f"{studies['speedup_16'][dask]:.2f}"
    return out


def _corpus(bench: dict[str, Any]) -> dict[str, str]:
    corpus = bench["corpus"]["summary"]
    return {
        "corpus_ok": str(corpus["succeeded"]),
        "corpus_vehicles": str(corpus["vehicles"]),
        "corpus_crush_pct": f"{corpus['crush_rel_max'] * 100:.2f}",
        "corpus_crush_median_pct": f"{corpus['crush_rel_median'] * 100:.2f}",
        "corpus_stop_ms": f"{corpus['stop_err_max_s'] * 1e3:.2f}",
        "corpus_stop_median_ms": f"{corpus['stop_err_median_s'] * 1e3:.2f}",
        "corpus_rating": f"{corpus['force_rating_median']:.3f}",
        "corpus_rating_min": f"{corpus['force_rating_min']:.3f}",
        "corpus_iterations": str(max(v["iterations"] for v in bench["corpus"]["vehicles"])),
    }


def _cross_speed(bench: dict[str, Any]) -> dict[str, str]:
    cross = bench["cross_speed"]
    joint = next(f for f in cross["fits"] if f["vehicle"] == "pickup-joint.yaml")
    out = {
        "joint_crush_pct": f"{joint['crush_rel'] * 100:.1f}",
        "joint_peak_pct": f"{joint['peak_rel'] * 100:.1f}",
        "cross_pct": f"{cross['summary']['coverage'] * 100:.0f}",
        "cross_pairs": str(cross["summary"]["pairs"]),
    }
    for split in ("interpolation", "extrapolation"):
        summary = cross["summary"][split]
        out[f"{split}_within"], out[f"{split}_fits"] = str(summary["within_targets"]), str(summary["fits"])
    return out | {"cross_predictions": str(int(out["interpolation_fits"]) + int(out["extrapolation_fits"]))}


def _families(bench: dict[str, Any]) -> dict[str, str]:
    """The cross-speed benchmark by family (family<seed>, family_pickup for the shared pickup), and
    over the usual families (the shared pickup's included) against the tall vans and SUVs."""
    cross, out = bench["cross_speed"], {}
    families = cross["summary"]["families"]
    for name, family in families.items():
        i = seed[1] if (seed := re.search(r"seed (\d+)", name)) else "_pickup"
        for split in ("extrapolation", "interpolation"):
            out[f"family{i}_{split}_within"] = str(family[split]["within_targets"])
            out[f"family{i}_{split}_fits"] = str(family[split]["fits"])
        out[f"family{i}_covered"], out[f"family{i}_pairs"] = (
            str(round(family["coverage"] * family["pairs"])),
            str(family["pairs"]),
        )
    for group in ("usual", "tall"):
        chosen = [f for name, f in families.items() if ("tall" in name) == (group == "tall")]
        for split in ("extrapolation", "interpolation"):
            parts = [f[split] for f in chosen]
            out[f"{group}_{split}_crush_pct"] = f"{max(p['crush_rel_max'] for p in parts) * 100:.1f}"
            out[f"{group}_{split}_peak_pct"] = f"{max(p['peak_rel_max'] for p in parts) * 100:.1f}"
            out[f"{group}_{split}_within"] = str(sum(p["within_targets"] for p in parts))
            out[f"{group}_{split}_fits"] = str(sum(p["fits"] for p in parts))
            out[f"{group}_{split}_iterations"] = str(max(p["iterations_max"] for p in parts))
    usual = [f for name, f in families.items() if "tall" not in name]
    out["usual_covered"] = str(round(sum(f["coverage"] * f["pairs"] for f in usual)))
    out["usual_pairs"] = str(sum(f["pairs"] for f in usual))
    out["cross_covered"] = str(round(cross["summary"]["coverage"] * cross["summary"]["pairs"]))
    out["family_coverage_lowest_pct"] = f"{min(f['coverage'] for f in families.values()) * 100:.0f}"
    out["family_coverage_highest_pct"] = f"{max(f['coverage'] for f in families.values()) * 100:.0f}"
    minimal = next(f for f in cross["fits"] if f["vehicle"] == "pickup" and f["split"] == "extrapolation")
    out["minimal_crush_pct"], out["minimal_peak_pct"] = f"{minimal['crush_rel'] * 100:+.1f}", f"{minimal['peak_rel'] * 100:+.1f}"
    return out


def _intervals(bench: dict[str, Any]) -> dict[str, str]:
    """The calibrated intervals on the check seed, the vehicles their table was not set on: the
    lowest coverage of any scenario and metric, and the half-widths from one test down to 48 km/h."""
    intervals = bench["intervals"]
    check = intervals["evaluation"][str(intervals["check_seed"])]["all"]
    down = check["one test down, 56 -> 48"]
    return {
        "intervals_vehicles": str(down["max_crush_m"]["n"]),
        "intervals_coverage_lowest_pct": f"{min(m['coverage'] for sc in check.values() for m in sc.values()) * 100:.0f}",
        "intervals_down48_crush_pct": f"{down['max_crush_m']['half_width_median'] * 100:.1f}",
        "intervals_down48_peak_pct": f"{down['peak_decel_g']['half_width_median'] * 100:.1f}",
    }


def _self_consistency(bench: dict[str, Any]) -> dict[str, str]:
    consistency = bench["self_consistency"]
    coverage = consistency["coverage"]
    geometry = [e for k, e in consistency["all channels"]["relative_errors"].items() if k.startswith("vehicle.")]
    out = {
        "replicates_pct": f"{coverage['coverage_95'] * 100:.0f}",
        "replicates_pairs": str(coverage["pairs"]),
        "replicates_rms_z": f"{coverage['rms_z']:.2f}",
        "recovery_geometry_pct": f"{max(geometry) * 100:.1f}",
    }
    for name, run in (("all", "all channels"), ("no_velocity", "without velocity")):
        out[f"recovery_spring_{name}_pct"] = f"{consistency[run]['relative_errors']['model.spring.values'] * 100:.1f}"
    return out


Quoted = tuple[dict[str, str], dict[str, str]]  # blocks, numbers


def generate() -> dict[str, dict[str, str]]:
    """Run the shipped problems in a scratch folder; the blocks and numbers the docs quote, with
    make bench's (bench_numbers). The runs go in order: a later one reads an earlier one's result."""
    blocks, numbers = {}, bench_numbers(json.loads(BENCH.read_text()))
    with tempfile.TemporaryDirectory(prefix="docs-numbers-") as scratch, chdir(scratch):
        os.symlink(ROOT / "problems", "problems")
        for runs in (_camry, _barrier, _pickup, _joint, _init):
            more_blocks, more_numbers = runs()
            blocks |= more_blocks
            numbers |= more_numbers
    if empty := [name for name, text in blocks.items() if not text]:
        raise SystemExit(f"no console line for block {', '.join(empty)}: the command's words changed; change the excerpt")
    return {"blocks": blocks, "numbers": numbers}


def _camry() -> Quoted:
    """The Camry's fit (getting-started, the README, the barrier page), and at 64 km/h (predictions)."""
    camry = run("identify", "problems/nhtsa-10146.yaml", "--no-figures")
    test = fitted_test("results/nhtsa-10146", "10146")
    fitted = ("--params", "results/nhtsa-10146/result.json")
    faster = run("simulate", "problems/nhtsa-10146.yaml", *fitted, "--speed", "64 km/h", "--out", "camry-64", "--no-figures")
    blocks = {
        "identify-nhtsa-10146": without_wrote(camry),
        "identify-nhtsa-10146-brief": "\n".join(line for line in camry if line.lstrip().startswith(BRIEF)),
        "camry-64-data-not-shown": "\n".join(line for line in faster if "data not shown" in line),
    }
    model, data = test["metrics"]["model"], test["metrics"]["data"]
    numbers = (
        crush_and_stop("camry", model) | crush_and_stop("camry.data", data) | peak("camry", model) | peak("camry.data", data)
    )
    return blocks, numbers | table_row("camry", test)


def _barrier() -> Quoted:
    """The Camry fitted to its wall force and accelerometers (the barrier page)."""
    run("identify", "problems/nhtsa-10146-barrier.yaml", "--no-figures")
    test = fitted_test("results/nhtsa-10146-barrier", "10146")
    stop = {"barrier.stop_ms": console_digits(test["metrics"]["model"]["time_zero_velocity_s"] * 1e3)}
    return {}, table_row("barrier", test) | stop | channels_apart(test["consistency"])


def _pickup() -> Quoted:
    """The pickup's fit (pitch-bound.yaml's comment) and its 40 km/h prediction (getting-started)."""
    run("identify", "problems/pickup-56kph.yaml", "--no-figures")
    pitch = fitted_test("results/pickup-56kph", "56kph")["metrics"]["model"]["max_pitch_deg"]
    prediction = run("simulate", "problems/pickup-40kph.yaml", "--params", "results/pickup-56kph/result.json", "--no-figures")
    return {"simulate-pickup-40kph": "\n".join(prediction)}, {"pickup.max_pitch_deg": f"{pitch:.1f}"}


def _joint() -> Quoted:
    """The pickup fitted at 40 and 56 km/h, predicted at 64 km/h (predictions' extrapolation line)."""
    run("identify", "problems/pickup-joint.yaml", "--no-figures")
    Path("what-ifs.yaml").write_text(WHAT_IF)
    joint = run("simulate", "what-ifs.yaml", "--params", "results/pickup-joint/result.json", "--no-figures")
    return {"pickup-joint-64-extrapolates": "\n".join(line for line in joint if "extrapolates" in line)}, {}


def _init() -> Quoted:
    """The Camry's problem written by crashnlp init from its EV5 file, then fitted (any-vehicle)."""
    run("init", "problems/data/nhtsa-10146/v10146.EV5", "--out", "camry.yaml")
    run("identify", "camry.yaml", "--no-figures")
    test = fitted_test("results/v10146", "v10146")
    model = test["metrics"]["model"]
    accel = {"camry.init.rating.accel": f"{test['fit']['accel']['iso18571']['overall']:.3f}"}
    return {}, crush_and_stop("camry.init", model) | peak("camry.init", model) | accel


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
    main()
