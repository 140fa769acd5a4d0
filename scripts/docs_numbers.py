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
line after a change of the code moves a number. `typed` lists every other number of a page's
prose that is no definition (docs/development.md gives the rules); the same test and hook
fail on it. Reading and checking the pages imports nothing of crashnlp; only the runs do.
"""

from __future__ import annotations

import ast
import io
import json
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from contextlib import chdir, redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FILE = ROOT / "results/docs-numbers.json"
BENCH = ROOT / "results/bench.json"  # make bench's numbers, read as they are: the benchmarks are not run here
# the files that quote the runs, as globs from ROOT
QUOTING = ("README.md", "docs/*.md", "docs/reference/*.md", "problems/studies/*.yaml")

BLOCK = re.compile(r"^<!-- numbers: (?P<key>[\w.-]+) -->\n(?P<fence>```[^\n]*\n)(?P<body>.*?)^```", re.MULTILINE | re.DOTALL)
INLINE = re.compile(r"(?P<value>[-+]?[\d.,]+(?:e[-+]?\d+)?)<!--n:(?P<key>[\w.-]+)-->")

# a prediction of the pickup fitted at 40 and 56 km/h, at 64 km/h (docs/predictions.md's extrapolation)
WHAT_IF = "name: pickup-what-ifs\ntests:\n  - {name: 64kph, speed: 64 km/h, duration: 0.2 s}\n"
PARTS = ("wall", "accelerometers")  # the channels a load-cell barrier's test measures the impact with, each on its own
# the lines of the Camry's fit the README quotes, by how they start (indentation aside)
BRIEF = ("nhtsa-10146: ok", "test ", "max displacement", "time of zero velocity", "peak deceleration", "rebound", "OLC")
BRIEF += ("ISO 18571", "relative energy balance")


# the blocks that show metric labels (a fit's metric table, a prediction's line), each with the
# run's file and test that say which CFC class its accelerations were read through ("read_through")
LABELLED = {
    "identify-nhtsa-10146": ("results/nhtsa-10146/result.json", "10146"),
    "identify-nhtsa-10146-brief": ("results/nhtsa-10146/result.json", "10146"),
    "simulate-pickup-40kph": ("results/pickup-40kph/simulation/simulation.json", "40kph"),
}


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
    """A fit's row of docs/barrier.md's table: each channel's ISO 18571 rating, stop, max displacement, rebound."""
    model = test["metrics"]["model"]
    out = {f"{prefix}.rating.{c}": f"{f['iso18571']['overall']:.3f}" for c, f in test["fit"].items() if f["iso18571"]}
    return out | {
        f"{prefix}.table.max_displacement_mm": f"{model['max_displacement_m'] * 1e3:.0f}",
        f"{prefix}.table.rebound_mps": f"{model['rebound_velocity_mps']:.2f}",
    }


def channels_apart(consistency: dict[str, Any]) -> dict[str, str]:
    """What the wall and the accelerometers say each on its own (docs/barrier.md): the wall's stop,
    both max displacements and rebounds, and how far apart their impulses are."""
    out = {
        "barrier.impulse_apart_pct": f"{(consistency['impulse_ratio'] - 1) * 100:.1f}",
        "barrier.wall.stop_ms": f"{consistency['wall']['time_zero_velocity_s'] * 1e3:.1f}",
    }
    for name in PARTS:
        out[f"barrier.{name}.max_displacement_mm"] = f"{consistency[name]['max_displacement_m'] * 1e3:.0f}"
        out[f"barrier.{name}.rebound_mps"] = f"{consistency[name]['rebound_velocity_mps']:.1f}"
    return out


def spring_std(prefix: str, folder: str) -> dict[str, str]:
    """The largest finite standard error of a fit's spring values (MN; docs/barrier.md)."""
    std = json.loads(Path(folder, "result.json").read_text())["std_errors"]["model.spring.values"]
    return {f"{prefix}.spring_std_max_mn": f"{max(s for s in std if s is not None) / 1e6:.2g}"}


def displacement_and_stop(prefix: str, metrics: dict[str, Any]) -> dict[str, str]:
    """Max displacement (mm) and time of zero velocity (ms) as the console's metric table prints them."""
    return {
        f"{prefix}.max_displacement_mm": tabled(metrics, "max_displacement_m"),
        f"{prefix}.stop_ms": tabled(metrics, "time_zero_velocity_s"),
    }


def peak(prefix: str, metrics: dict[str, Any]) -> dict[str, str]:
    """Peak deceleration (g) as the console's metric table prints it (the model's as the test
    recorded it)."""
    return {f"{prefix}.peak_g": tabled(metrics, "peak_decel_g")}


def tabled(metrics: dict[str, Any], key: str) -> str:
    """A crash metric of result.json as the console's metric table prints it (Metric.tabled)."""
    from crashnlp.base.outputs import METRIC

    return METRIC[key].tabled(metrics[key])


def bench_numbers(bench: dict[str, Any]) -> dict[str, str]:
    """The numbers of results/bench.json the pages quote ("bench.<name>"), each formatted as the
    pages print it; the sections of make bench one function each."""
    parts = (
        *(_identification, _process, _simulation, _studies, _scale_out, _scaling),
        *(_corpus, _cross_speed, _families, _self_consistency, _intervals, _forms, _choice, _detectors, _truncated),
    )
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
        "transcriptions_apart_pct": f"{abs(collocation['objective'] / shooting['objective'] - 1) * 100:.2f}",
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
    out |= {
        "process_first_s": f"{whole['first_run_fresh_cache']['wall_s']:.1f}",
        "process_speedup": f"{whole['speedup']:.1f}",
        "process_no_figures_speedup": f"{whole['speedup_no_figures']:.1f}",
    }
    out["load"] = f"{bench['machine']['load_average'][0]:.1f}"  # the machine's load average when the run began
    if "new_problem" in whole:  # a new problem's runs and the pickup's, as ratios to the import floor
        new = whole["new_problem"]
        out |= {f"new_problem_run{n}_x": f"{new[f'run_{n}']['vs_floor']:.1f}" for n in (1, 2, 3)}
        out |= {f"new_problem_run{n}_s": f"{new[f'run_{n}']['wall_s']:.2f}" for n in (1, 2, 3)}
        out["new_problem_compile_s"] = f"{new['compile_after_run_2_s']:.0f}"
        out["process_no_figures_x"] = f"{whole['vs_floor']['warm_no_figures']:.1f}"
    return out


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
    out["grid64_iterations"] = str(max(int(row["iterations"]) for row in studies["grid_64_rows"]))
    out["study_dask_speedup"] = f"{studies['speedup_16'][dask]:.2f}"
    if dask in studies["speedup_64"]:
        out["grid64_dask_speedup"] = f"{studies['speedup_64'][dask]:.2f}"
    if "warm_vs_ipopt" in studies["case"]:
        out["study_case_vs_ipopt"] = f"{studies['case']['warm_vs_ipopt']:.2f}"
    return out


PLANS = {"corners": ("corners", (2, 32, 128, 512)), "max_depth 2": ("depth2", (8, 32, 128, 512))}  # the quoted workers


def _scale_out(bench: dict[str, Any]) -> dict[str, str]:
    """A 10,000-case study replayed on a virtual clock (docs/studies.md): what one case ships and
    costs, and the projected wall time and efficiency of two warm-start plans on N workers."""
    studies = bench["studies"]
    case, setup, dask, local = studies["case"], studies["setup"], studies["scheduler"]["dask"], studies["scheduler"]["local"]
    out = {
        "scale_check_s": f"{setup['wall_s']:.1f}",
        "scale_job_kb": f"{case['job_bytes'] / 1e3:.0f}",
        "scale_warm_start_kb": f"{case['warm_start_bytes'] / 1e3:.0f}",
        "scale_result_kb": f"{case['result_bytes'] / 1e3:.0f}",
        "scale_shipped_mb": f"{(case['job_bytes'] + case['result_bytes']) * setup['cases'] / 1e6:.0f}",
        "scale_store_ms": f"{studies['store_ms']:.1f}",
        "scale_dask_ms": f"{dask['per_task_ms']:.0f}",
        "scale_dask_start_s": f"{dask['start_s']:.1f}",
        "scale_local_ms": f"{local['per_task_ms']:.1f}",
        "scale_warm_case_s": f"{case['warm_s']:.2f}",
        "scale_workers_per_scheduler": f"{case['warm_s'] / (studies['store_ms'] * 1e-3):.0f}",
    }
    for row in studies["projection"]:
        plan, lanes = PLANS.get(row["plan"], ("", ()))
        if row["lanes"] not in lanes:
            continue
        out[f"scale_{plan}_seeds"], out[f"scale_{plan}_chain_s"] = str(row["seeds"]), f"{row['chain_s']:.1f}"
        out |= {"scale_corners_depth": str(row["depth"])} if plan == "corners" else {}
        out[f"scale_{plan}_{row['lanes']}_min"] = f"{row['makespan_h'] * 60:.1f}"
        out[f"scale_{plan}_{row['lanes']}_efficiency"] = f"{row['efficiency']:.2f}"
    return out


def _scaling(bench: dict[str, Any]) -> dict[str, str]:
    """Fits at 800 intervals and joint fits of 2 and 4 tests (docs/benchmarks.md's last rows)."""
    scaling, out = bench["scaling"], {}
    for row in scaling["intervals"]:
        if row["intervals"] == max(r["intervals"] for r in scaling["intervals"]):
            out[f"scaling_{row['method']}_s"], out[f"scaling_{row['method']}_iterations"] = (
                f"{row['wall_s']:.2f}",
                str(row["iterations"]),
            )
    for row in scaling["tests"]:
        if row["tests"] > 1:
            out[f"joint{row['tests']}_{row['method']}_s"] = f"{row['wall_s']:.2f}"
            out[f"joint{row['tests']}_{row['method']}_iterations"] = str(row["iterations"])
    for method, slopes in scaling["slopes"].items():
        out[f"scaling_{method}_slope"] = f"{slopes['wall_s']:.2f}"
    return out


def _corpus(bench: dict[str, Any]) -> dict[str, str]:
    corpus, vehicles = bench["corpus"]["summary"], bench["corpus"]["vehicles"]
    return {
        "corpus_ok": str(corpus["succeeded"]),
        "corpus_vehicles": str(corpus["vehicles"]),
        "corpus_displacement_pct": f"{corpus['displacement_rel_max'] * 100:.2f}",
        "corpus_displacement_median_pct": f"{corpus['displacement_rel_median'] * 100:.2f}",
        "corpus_stop_ms": f"{corpus['stop_err_max_s'] * 1e3:.2f}",
        "corpus_stop_median_ms": f"{corpus['stop_err_median_s'] * 1e3:.2f}",
        "corpus_rating": f"{corpus['force_rating_median']:.3f}",
        "corpus_rating_min": f"{corpus['force_rating_min']:.3f}",
        "corpus_iterations": str(max(v["iterations"] for v in vehicles)),
        "corpus_iterations_median": f"{np.median([v['iterations'] for v in vehicles]):.0f}",
        "corpus_stop_rest_ms": f"{sorted(v['stop_err_s'] for v in vehicles)[-2] * 1e3:.1f}",
        "corpus_mass_min_kg": f"{min(v['mass_kg'] for v in vehicles):.0f}",
        "corpus_mass_max_kg": f"{max(v['mass_kg'] for v in vehicles):.0f}",
        "corpus_speed_min_kmh": f"{min(v['speed_kmh'] for v in vehicles):.0f}",
        "corpus_speed_max_kmh": f"{max(v['speed_kmh'] for v in vehicles):.0f}",
        "corpus_displacement_min_mm": f"{min(v['displacement_true_m'] for v in vehicles) * 1e3:.0f}",
        "corpus_displacement_max_mm": f"{max(v['displacement_true_m'] for v in vehicles) * 1e3:.0f}",
    }


def _cross_speed(bench: dict[str, Any]) -> dict[str, str]:
    cross = bench["cross_speed"]
    joint = next(f for f in cross["fits"] if f["vehicle"] == "pickup-joint.yaml")
    out = {
        "joint_displacement_pct": f"{joint['displacement_rel'] * 100:.1f}",
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
            out[f"{group}_{split}_displacement_pct"] = f"{max(p['displacement_rel_max'] for p in parts) * 100:.1f}"
            out[f"{group}_{split}_peak_pct"] = f"{max(p['peak_rel_max'] for p in parts) * 100:.1f}"
            out[f"{group}_{split}_within"] = str(sum(p["within_targets"] for p in parts))
            out[f"{group}_{split}_fits"] = str(sum(p["fits"] for p in parts))
            out[f"{group}_{split}_iterations"] = str(max(p["iterations_max"] for p in parts))
        out[f"{group}_iterations"] = str(
            max(p["iterations_max"] for f in chosen for p in (f["extrapolation"], f["interpolation"]))
        )
    usual = [f for name, f in families.items() if "tall" not in name]
    out["usual_covered"] = str(round(sum(f["coverage"] * f["pairs"] for f in usual)))
    out["usual_pairs"] = str(sum(f["pairs"] for f in usual))
    out["cross_covered"] = str(round(cross["summary"]["coverage"] * cross["summary"]["pairs"]))
    out["family_coverage_lowest_pct"] = f"{min(f['coverage'] for f in families.values()) * 100:.0f}"
    out["family_coverage_highest_pct"] = f"{max(f['coverage'] for f in families.values()) * 100:.0f}"
    minimal = next(f for f in cross["fits"] if f["vehicle"] == "pickup" and f["split"] == "extrapolation")
    out["minimal_displacement_pct"], out["minimal_peak_pct"] = (
        f"{minimal['displacement_rel'] * 100:+.1f}",
        f"{minimal['peak_rel'] * 100:+.1f}",
    )
    return out


def _forms(bench: dict[str, Any]) -> dict[str, str]:
    """The forms on the tall vehicles (bench/forms.py), per form (forms.<form>.<what>): the
    interpolation split, and the extrapolation split's under extrapolation_<what>."""
    out = {}
    for form, s in bench["forms"]["summary"]["interpolation"].items():
        out |= _worst(f"forms.{form}", s) | {
            f"forms.{form}.pitch_median": f"{s['pitch_rmse_median_deg']:.2f}",
            f"forms.{form}.within": str(s["within_targets"]),
            f"forms.{form}.ok": str(s["ok"]),
            f"forms.{form}.fitted_lift_offs": str(s["fitted_lift_offs"]),
            f"forms.{form}.fitted_not_in_truth": str(s["fitted_lift_offs_not_in_truth"]),
        }
    for form, s in bench["forms"]["summary"]["extrapolation"].items():
        out |= {
            f"forms.{form}.extrapolation_within": str(s["within_targets"]),
            f"forms.{form}.extrapolation_ok": str(s["ok"]),
            f"forms.{form}.extrapolation_displacement": f"{s['displacement_rel_max'] * 100:.1f}",
            f"forms.{form}.extrapolation_peak": f"{s['peak_rel_max'] * 100:.1f}",
            f"forms.{form}.extrapolation_lift_offs": str(s["lift_offs"]),
        }
    for split, forms in bench["forms"]["summary"].items():  # the 95 % intervals' coverage (%) and median half-width (%)
        for form, s in forms.items():
            out |= {f"forms.{form}.{split}_{k}": f"{s[k] * 100:.0f}" for k in s if k.endswith(("_covered", "_half_width_median"))}
    hidden = bench["forms"].get("hidden")  # the hidden tall vehicles (forms.hidden.<form>.<what>)
    for form, s in (hidden or {}).get("summary", {}).items():
        out |= _worst(f"forms.hidden.{form}", s) | {
            f"forms.hidden.{form}.within": str(s["within_hidden"]),
            f"forms.hidden.{form}.fits": str(s["fits"]),
            f"forms.hidden.{form}.lift_offs_not_in_truth": str(s["lift_offs_not_in_truth"]),
            f"forms.hidden.{form}.no_stop": str(s["no_stop"]),
            f"forms.hidden.{form}.no_stop_in_truth": str(s["no_stop_in_truth"]),
        }
    rigid = (hidden or {}).get("summary", {}).get("rigid-body", {})
    out |= _unmatched("forms.hidden.rigid-body.unmatched", rigid.get("unmatched_lift_offs", []))
    floor = (hidden or {}).get("pitch_floor")
    return out | (_pitch_floor(floor["summary"]) if floor else {})


def _choice(bench: dict[str, Any]) -> dict[str, str]:
    """compare's choice from one test (bench/choice.py), per population's seed and way of choosing
    (choice.<seed>.<way>.<what>, the way's spaces as dashes, without commas): the vehicles within the tie of the
    better form, those scored, the mean and largest regret (%); and the vehicles, and those for
    which compare chose another form than the default (choice.<seed>.vehicles, .chose_other); and
    the share (%) of a population's predictions that the intervals of the form a way takes cover, of
    the metrics of issue 38's 90 % line (choice.<seed>.covered.<way>.<metric>, bench/choice.py's covered)."""
    from bench.calibration import SHORT, TARGETS

    out = {}
    for seed, ways in bench.get("choice", {}).get("covered", {}).items():
        for way, by in ways.items():
            key = f"choice.{seed}.covered.{way.replace(' ', '-')}"
            out |= {f"{key}.{SHORT[m]}": f"{100 * by[m]['covered'] / by[m]['n']:.0f}" for m in TARGETS["coverage"]}
    for seed, pop in bench.get("choice", {}).get("populations", {}).items():
        s = pop["summary"]
        out |= {f"choice.{seed}.vehicles": str(s["vehicles"]), f"choice.{seed}.chose_other": str(s["chose_other"])}
        for way, w in s["ways"].items():
            key = f"choice.{seed}.{way.replace(',', '').replace(' ', '-')}"
            out |= {f"{key}.within": str(w["within_tie"]), f"{key}.scored": str(w["scored"])}
            if w["scored"]:
                out |= {f"{key}.mean": f"{w['mean_regret'] * 100:.1f}", f"{key}.max": f"{w['max_regret'] * 100:.0f}"}
    return out


def _unmatched(prefix: str, rows: list[dict[str, Any]]) -> dict[str, str]:
    """The fastest of the rigid body's hidden predictions that let go while moving forward where the
    generator does not (bench/forms.py): when (ms) and how fast (m/s) it lets go, when the generator
    lets go and its rebound then (m/s, back from the barrier), its fitted loading curve's miss at its
    largest crush (%)."""
    if not rows:
        return {}
    r = rows[0]
    return {
        f"{prefix}.lift_off_ms": f"{r['lift_off_s'] * 1e3:.1f}",
        f"{prefix}.lift_off_mps": f"{r['lift_off_mps']:.3f}",
        f"{prefix}.truth_release_ms": f"{r['truth_release_s'] * 1e3:.1f}",
        f"{prefix}.truth_rebound_mps": f"{-r['truth_release_mps']:.3f}",
        f"{prefix}.curve_pct": f"{r['curve_at_crush_rel'] * 100:+.0f}",
    }


def _pitch_floor(s: dict[str, Any]) -> dict[str, str]:
    """The engine vans' pitch (bench/forms.py's pitch_floor), forms.hidden.floor.<what>: per fitted
    speed the range of the pitch RMSE of that speed fitted alone (deg), of the engine's share of the
    barrier's impulse (%) and of the pitch its push would add on the front end's line (deg); per
    joint fit the range of its pitch RMSE (deg), and of the best any of them reached."""
    prefix = "forms.hidden.floor"
    out = {f"{prefix}.vans": str(s["vehicles"])}
    for kmh in s["one_speed_deg"]:
        for end in ("min", "max"):
            out[f"{prefix}.one_speed_{kmh}.{end}"] = f"{s['one_speed_deg'][kmh][end]:.2f}"
            out[f"{prefix}.share_{kmh}.{end}"] = f"{s['impulse_share'][kmh][end] * 100:.0f}"
            out[f"{prefix}.engine_pitch_{kmh}.{end}"] = f"{s['engine_pitch_rms_deg'][kmh][end]:.1f}"
    for key, spread in {**s["variants_deg"], "best": s["best_deg"]}.items():
        out |= {f"{prefix}.{key}.{end}": f"{spread[end]:.2f}" for end in ("min", "max")}
    return out


def _worst(prefix: str, s: dict[str, Any]) -> dict[str, str]:
    """A forms summary's worst fitted pitch RMSE, prediction errors and its lift-offs, under `prefix`."""
    return {
        f"{prefix}.pitch_max": f"{s['pitch_rmse_max_deg']:.2f}",
        f"{prefix}.displacement": f"{s['displacement_rel_max'] * 100:.1f}",
        f"{prefix}.peak": f"{s['peak_rel_max'] * 100:.1f}",
        f"{prefix}.stop": f"{s['stop_err_max_s'] * 1e3:.2f}",
        f"{prefix}.lift_offs": str(s["lift_offs"]),
    }


def _detectors(bench: dict[str, Any]) -> dict[str, str]:
    """The watch's rules on the set and the check seed (bench/detectors.py), per seed role:
    detectors.<role>.<rule>.fires (and .false_alarms for the rules that fired), and the role's
    fits, misses (the seeds are bench/detectors.py's SEEDS, named where they are quoted)."""
    d, out = bench["detectors"], {"detectors.count": str(bench["detectors"]["count"])}
    for role in ("set", "check"):
        s = d[role]["summary"]
        out[f"detectors.{role}.fits"] = str(s["fits"])
        out |= {f"detectors.{role}.ok": str(s["ok"]), f"detectors.{role}.misses": str(s["misses"])}
        out[f"detectors.{role}.alone_not_converged"] = str(s["alone_not_converged"])
        out[f"detectors.{role}.apart"] = f"{s['apart_std_max']:.0e}"
        for rule, q in s["rules"].items():  # the fires; the false alarms where a rule can stop a fit it should not
            out[f"detectors.{role}.{rule}.fires"] = str(q["fires"])
            if rule in ("tail", "cycle", "steady", "unsettled"):
                out[f"detectors.{role}.{rule}.false_alarms"] = str(q["false_alarms"])
    return out


def _truncated(bench: dict[str, Any]) -> dict[str, str]:
    """Records cut short (bench/truncated.py): the latest time after impact at which a vehicle held
    whole at a cut, off the barrier after it, met the barrier again (the end of the longest drift)."""
    met = [m["s"] for q in bench["truncated"]["kinds"].values() for m in q["met_again"]]
    return {"truncated.met_again_s": f"{max(met):.2f}"}


def intervals_keys() -> tuple[dict[str, str], dict[str, str]]:
    """The short names of bench/calibration.py's scenarios and metrics in the keys of the intervals'
    numbers: a scenario's, its kind and predicted speed ("down40", "between48", "extrap64": the
    target against its fitted speeds) or its mass ratio in % ("mass120"); a metric's, the last word of
    its name in the calibration's tables, in lower case ("max pitch": "pitch")."""
    if str(ROOT) not in sys.path:  # bench/ is imported as make bench runs it, from the repository root
        sys.path.insert(0, str(ROOT))
    from bench.calibration import MASS_RATIOS, SCENARIOS, SHORT

    scenarios = {}
    for name, (fitted, target) in SCENARIOS.items():
        if name in MASS_RATIOS:
            scenarios[name] = f"mass{MASS_RATIOS[name] * 100:.0f}"
            continue
        beyond = "up" if len(fitted) == 1 else "extrap"
        kind = "down" if target < min(fitted) else "between" if target <= max(fitted) else beyond
        scenarios[name] = f"{kind}{target:.0f}"
    return scenarios, {metric: short.split()[-1].lower() for metric, short in SHORT.items()}


def _intervals(bench: dict[str, Any]) -> dict[str, str]:
    """The calibrated intervals on the check seed, the vehicles their table was not set on: the
    lowest coverage of any scenario and metric, and the half-widths from one test down to 48 km/h;
    and on the check seed and the hidden population, each scenario's coverage and median
    half-width of each metric (iv.<seed: check, hidden>.<scenario>.<metric>.<cov, hw>), and the largest
    miss of the max displacement from one test down to 40 km/h and of the extrapolated peak, and the
    one width for all their predictions that holds 90 % of them (the extrapolated peak's: and 95 %);
    on the hidden population, the lowest coverage and the largest miss of the max displacement one
    test down."""
    intervals = bench["intervals"]
    check = intervals["evaluation"][str(intervals["check_seed"])]["all"]
    down, down40 = check["one test down, 56 -> 48"], check["one test down, 56 -> 40"]
    out = {
        "intervals_vehicles": str(intervals["vehicles"][str(intervals["check_seed"])]),
        "intervals_coverage_lowest_pct": f"{min(m['coverage'] for sc in check.values() for m in sc.values()) * 100:.0f}",
        "intervals_down48_displacement_pct": f"{down['max_displacement_m']['half_width_median'] * 100:.1f}",
        "intervals_down48_peak_pct": f"{down['peak_decel_g']['half_width_median'] * 100:.1f}",
        "intervals_down40_displacement_miss_pct": f"{down40['max_displacement_m']['error_max'] * 100:.0f}",
        "intervals_extrap_peak_miss_pct": f"{check['extrapolation, 40 + 56 -> 64']['peak_decel_g']['error_max'] * 100:.0f}",
        "intervals_down40_displacement_one_width_pct": f"{down40['max_displacement_m']['one_width'] * 100:.1f}",
        "intervals_extrap_peak_one_width_pct": f"{check['extrapolation, 40 + 56 -> 64']['peak_decel_g']['one_width'] * 100:.0f}",
        "intervals_extrap_peak_one_width_level_pct": (
            f"{check['extrapolation, 40 + 56 -> 64']['peak_decel_g']['one_width_level'] * 100:.0f}"
        ),
    }
    hidden = intervals["evaluation"][str(intervals["hidden_seed"])]["all"]
    out["intervals_hidden_coverage_lowest_pct"] = f"{min(m['coverage'] for sc in hidden.values() for m in sc.values()) * 100:.0f}"
    down_misses = [by["max_displacement_m"]["error_max"] for sc, by in hidden.items() if sc.startswith("one test down")]
    out["intervals_hidden_down_displacement_miss_pct"] = f"{max(down_misses) * 100:.0f}"
    calibration = intervals["calibration"]
    corpus = calibration["corpus"]["vehicles"]
    tall = sum(n for form, n in corpus.items() if form.startswith("tall vans"))  # with an engine on mounts or not
    out["iv.corpus.vehicles"], out["iv.corpus.tall"] = str(sum(corpus.values())), str(tall)
    scenario_keys, metric_keys = intervals_keys()
    for metric, short in metric_keys.items():
        out[f"iv.power.{short}"] = f"{calibration['power'][metric]:g}"
    for label, seed in (("check", intervals["check_seed"]), ("hidden", intervals["hidden_seed"])):
        for scenario, by in intervals["evaluation"][str(seed)]["all"].items():
            for metric, e in by.items():
                key = f"iv.{label}.{scenario_keys[scenario]}.{metric_keys[metric]}"
                out[f"{key}.cov"] = f"{e['coverage'] * 100:.0f}"
                out[f"{key}.hw"] = f"{e['half_width_median'] * 100:.{1 if e['half_width_median'] < 0.1 else 0}f}"
    return out | _by_chance(intervals, metric_keys)


def _by_chance(intervals: dict[str, Any], metric_keys: dict[str, str]) -> dict[str, str]:
    """The coverage lines read as counts (bench/calibration.py's by_chance and pooled), per model
    form and population (iv.<form>.<check, hidden>.chance.<below, expected>; the pendulum's without
    the form): the cells below their line and how many an interval that holds 95 % leaves below by
    chance. The pendulum's cells' fewest and most predictions (iv.<check, hidden>.cells.<fewest,
    most>), how often (%) an interval that holds 95 % leaves a hidden-population cell of the
    fewest below the max displacement's 90 % line (iv.hidden.cells.fewest_below_pct), and its pooled
    coverage (%) over every scenario: the lowest and highest of the check seed's metrics
    (iv.check.pooled.<lowest, highest>); the hidden population's, of the metrics of
    issue 38's 90 % line (bench/calibration.py's TARGETS), with its 95 % range
    (iv.hidden.pooled.<metric>.<pct, low, high>), and the covered share of its predictions that
    have an interval, the max displacement's and the stop's (iv.hidden.given.<metric>)."""
    from bench.calibration import TARGETS, by_chance

    out = {}
    for form, section in ((None, intervals), *intervals.get("forms", {}).items()):
        for label, seed in (("check", section["check_seed"]), ("hidden", section["hidden_seed"])):
            cells = section["evaluation"][str(seed)]["all"]
            c = by_chance(cells)
            key = f"iv.{label}" if form is None else f"iv.{form}.{label}"
            out |= {f"{key}.chance.below": str(c["below"]), f"{key}.chance.expected": f"{c['expected_below']:.1f}"}
            if form is not None:
                continue
            sizes = [e["n"] for by in cells.values() for e in by.values() if e["n"]]
            out[f"{key}.cells.fewest"], out[f"{key}.cells.most"] = str(min(sizes)), str(max(sizes))
            pooled = section["pooled"][str(seed)]["all"]
            shares = {m: 100 * e["covered"] / e["n"] for m, e in pooled.items()}
            if label == "check":
                out[f"{key}.pooled.lowest"], out[f"{key}.pooled.highest"] = (f"{f(shares.values()):.0f}" for f in (min, max))
                continue
            fewest = {"max_displacement_m": {"n": min(sizes), "coverage": 1.0}}  # a cell of the fewest, 90 % line
            out[f"{key}.cells.fewest_below_pct"] = f"{100 * by_chance({'s': fewest})['expected_below']:.0f}"
            for metric in ("max_displacement_m", "time_zero_velocity_s"):
                out[f"{key}.given.{metric_keys[metric]}"] = f"{100 * pooled[metric]['covered'] / pooled[metric]['given']:.0f}"
            for metric in TARGETS["coverage"]:
                e, name = pooled[metric], f"{key}.pooled.{metric_keys[metric]}"
                out |= {f"{name}.pct": f"{shares[metric]:.0f}"}
                out |= {f"{name}.{end}": f"{100 * e[end]:.0f}" for end in ("low", "high")}
    return out


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


def code_numbers() -> dict[str, str]:
    """Numbers the pages quote from the code itself: the normal quantile of a 95 % interval, and
    compare's ties (crashnlp.optimize.comparison: TIE of the held-out score in %, BIC_TIE)."""
    from crashnlp.base.outputs import Z95
    from crashnlp.optimize.comparison import BIC_TIE, TIE

    return {"z95": f"{Z95:.2f}", "compare.tie_pct": f"{TIE * 100:g}", "compare.bic_tie": f"{BIC_TIE:g}"}


def generate() -> dict[str, dict[str, Any]]:
    """Run the shipped problems in a scratch folder; the blocks and numbers the docs quote, with
    make bench's (bench_numbers), and the CFC class each labelled block's accelerations were read
    through (LABELLED). The runs go in order: a later one reads an earlier one's result."""
    blocks, numbers = {}, bench_numbers(json.loads(BENCH.read_text())) | code_numbers()
    with tempfile.TemporaryDirectory(prefix="docs-numbers-") as scratch, chdir(scratch):
        os.symlink(ROOT / "problems", "problems")
        for runs in (_camry, _barrier, _pickup, _joint, _init):
            more_blocks, more_numbers = runs()
            blocks |= more_blocks
            numbers |= more_numbers
        read_through = {
            block: json.loads(Path(file).read_text())["tests"][test].get("accel_filter")
            for block, (file, test) in LABELLED.items()
        }
    if empty := [name for name, text in blocks.items() if not text]:
        raise SystemExit(f"no console line for block {', '.join(empty)}: the command's words changed; change the excerpt")
    return {"blocks": blocks, "numbers": numbers, "read_through": read_through}


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
        displacement_and_stop("camry", model)
        | displacement_and_stop("camry.data", data)
        | peak("camry", model)
        | peak("camry.data", data)
    )
    numbers |= {  # as the data set's reference values are given (getting-started)
        "camry.data.stop_rounded_ms": f"{data['time_zero_velocity_s'] * 1e3:.1f}",
        "camry.data.peak_rounded_g": f"{data['peak_decel_g']:.1f}",
        "camry.data.olc_g": f"{data['olc_g']:.1f}",
    }
    return blocks, numbers | table_row("camry", test)


def _barrier() -> Quoted:
    """The Camry fitted to its wall force and accelerometers (the barrier page), after _camry."""
    console = run("identify", "problems/nhtsa-10146-barrier.yaml", "--no-figures")
    test = fitted_test("results/nhtsa-10146-barrier", "10146")
    blocks = {"barrier-consistency": "\n".join(line for line in console if "channel consistency" in line)}
    stop = {"barrier.stop_ms": tabled(test["metrics"]["model"], "time_zero_velocity_s")}
    numbers = table_row("barrier", test) | stop | channels_apart(test["consistency"]) | walls_and_fits()
    return blocks, numbers | spring_std("barrier", BARRIER_FITS["both_fit"]) | spring_std("camry", BARRIER_FITS["accel_fit"])


CRUSH_TABLE = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.65)  # m: the columns of docs/barrier.md's force-crush table
BARRIER_FITS = {"accel_fit": "results/nhtsa-10146", "both_fit": "results/nhtsa-10146-barrier"}


def walls_and_fits() -> dict[str, str]:
    """docs/barrier.md's force against crush (kN): the wall's force and the accelerometers' m|a|,
    each against its own one-mass travel from the impact speed while loading, and each fit's
    loading curve; the wall's and the accelerometers' peaks; and what each fit's simulation rates
    against the channel it was not fitted to (ISO 18571 over the data's window): the accelerometer
    fit's wall force, the barrier fit's displacement."""
    from crashnlp.analysis.rating import iso18571
    from crashnlp.api import load
    from crashnlp.case.testcase import load_tests
    from crashnlp.data.signal import integrate

    problem, (test, *_) = load_tests(load("problems/nhtsa-10146-barrier.yaml"))
    assert test.data is not None  # the problem's test reads its EV5 file
    channels, mass, crush = test.data.channels, problem.vehicle.mass, np.array(CRUSH_TABLE)

    def loading(t: np.ndarray, accel: np.ndarray, force: np.ndarray) -> np.ndarray:
        start = max(0.0, float(t[0]))
        _, travel = integrate(t, accel, test.speed, start)
        k = (t >= start) & (t <= t[np.argmax(travel)])
        return np.interp(crush, travel[k], force[k])

    def rating(folder: str, channel: str, column: str) -> str:
        response, data = np.genfromtxt(f"{folder}/10146/response.csv", delimiter=",", names=True), channels[channel]
        t = data.time[(data.time >= 0) & (data.time <= test.duration)]
        model = np.interp(t, response["time_s"], response[column])
        return f"{iso18571(t, np.interp(t, data.time, data.values), model)['overall']:.3f}"

    wall, accel = channels["barrier_force"], channels["accel"]
    rows = {
        "wall": loading(wall.time, -wall.values / mass, wall.values),
        "accelerometers": loading(accel.time, accel.values, mass * np.abs(accel.values)),
    }
    for row, folder in BARRIER_FITS.items():
        curve = np.genfromtxt(f"{folder}/force_crush.csv", delimiter=",", names=True)
        rows[row] = np.interp(crush, curve["crush_m"], curve["spring_force_N"])
    out = {f"barrier.force.{row}.{c:g}": f"{f / 1e3:.0f}" for row, forces in rows.items() for c, f in zip(CRUSH_TABLE, forces)}
    peaks = {name: float(ch.time[np.argmax(np.abs(ch.values))]) for name, ch in (("wall", wall), ("accelerometers", accel))}
    out |= {f"barrier.{name}.peak_ms": f"{t * 1e3:.0f}" for name, t in peaks.items()}
    out["barrier.wall.peak_kn"] = f"{np.max(np.abs(wall.values)) / 1e3:.0f}"
    out["barrier.peaks_apart_ms"] = f"{(peaks['accelerometers'] - peaks['wall']) * 1e3:.0f}"
    out["barrier.rating.accel_fit.barrier_force"] = rating(BARRIER_FITS["accel_fit"], "barrier_force", "barrier_force_N")
    out["barrier.rating.both_fit.displacement"] = rating(BARRIER_FITS["both_fit"], "displacement", "displacement_m")
    return out


def _pickup() -> Quoted:
    """The pickup's fit (pitch-bound.yaml's comment) and its 40 km/h prediction (getting-started)."""
    run("identify", "problems/pickup-56kph.yaml", "--no-figures")
    test = fitted_test("results/pickup-56kph", "56kph")
    prediction = run("simulate", "problems/pickup-40kph.yaml", "--params", "results/pickup-56kph/result.json", "--no-figures")
    numbers = {"pickup.max_pitch_deg": f"{test['metrics']['model']['max_pitch_deg']:.1f}"} | pickup_fit(test)
    return {"simulate-pickup-40kph": "\n".join(prediction)}, numbers


# a channel's RMSE as docs/identification.md shows it: factor from result.json's unit (g, m/s, m, deg), digits
RMSE_SHOWN = {"accel": (1.0, 2), "velocity": (1.0, 3), "displacement": (1e3, 1), "pitch": (1.0, 2)}
ENERGY = (  # docs/identification.md's energy table, in its order
    "impact_kinetic",
    "impact_loss",
    "front_end_spring",
    "front_end_damper",
    "suspension_damping",
    "final_kinetic",
    "final_potential_change",
    "barrier_work_on_vehicle",
)


def pickup_fit(test: dict[str, Any]) -> dict[str, str]:
    """The pickup's fit at 56 km/h as docs/identification.md gives it: each channel's RMSE and
    rating, the spring values at the breakpoints the data were made with, the pitch lever, and
    where the impact energy goes (kJ)."""
    result = json.loads(Path("results/pickup-56kph/result.json").read_text())
    out = {}
    for channel, fit in test["fit"].items():
        factor, digits = RMSE_SHOWN[channel]
        out[f"pickup.rmse.{channel}"] = f"{fit['rmse'] * factor:.{digits}f}"
        out[f"pickup.rating.{channel}"] = f"{fit['iso18571']['overall']:.3f}"
    values = result["parameters"]["model.spring.values"]
    out |= {f"pickup.spring.{i}_kn": f"{v / 1e3:.0f}" for i, v in enumerate(values[1:-1], start=1)}
    out["pickup.lever_m"] = f"{result['parameters']['vehicle.crush_offset']:.2f}"
    energy = test["energy"]
    out |= {f"pickup.energy.{term}_kj": f"{energy[term] / 1e3:.1f}" for term in ENERGY}
    out["pickup.energy.balance_error_kj"] = f"{energy['balance_error'] / 1e3:.0e}"
    out["pickup.energy.balance_error_relative"] = f"{energy['balance_error_relative']:.0e}"
    return out


def _joint() -> Quoted:
    """The pickup fitted at 40 and 56 km/h, predicted at 64 km/h (predictions' extrapolation line),
    with the identified tail (the trend) and with the law as fitted (`tail: segment`), against
    the generator's 64 km/h test as make bench's cross-speed section recorded it."""
    run("identify", "problems/pickup-joint.yaml", "--no-figures")
    Path("what-ifs.yaml").write_text(WHAT_IF)
    Path("what-ifs-segment.yaml").write_text(WHAT_IF.replace("tests:", "model: {spring: {tail: segment}}\ntests:", 1))
    fitted = ("--params", "results/pickup-joint/result.json", "--no-figures")
    joint = run("simulate", "what-ifs.yaml", *fitted)
    run("simulate", "what-ifs-segment.yaml", *fitted, "--out", "segment")
    identified = json.loads(Path("results/pickup-joint/result.json").read_text())["identified_model"]
    spring, reach = identified["model"]["spring"], identified["range"]["model_crush_m"]
    breakpoints, values = spring["crush_breakpoints"], spring["values"]
    last = max(i for i, c in enumerate(breakpoints) if c <= reach)  # the segment the reach lies in starts here
    segment_slope = (values[last + 1] - values[last]) / (breakpoints[last + 1] - breakpoints[last])
    truth = next(f for f in json.loads(BENCH.read_text())["cross_speed"]["fits"] if f["vehicle"] == "pickup-joint.yaml")["truth"]
    damper = identified["model"]["damper"]["values"]
    numbers = {
        "joint.reach_m": f"{reach:.3f}",
        "joint.reach_mm": f"{reach * 1e3:.0f}",
        "joint.trend_mn_per_m": f"{spring['tail']['slope'] / 1e6:.2f}",
        "joint.damper_low_kns_per_m": f"{damper[0] / 1e3:.1f}",
        "joint.damper_high_kns_per_m": f"{damper[-1] / 1e3:.1f}",
        "joint.reach_past_breakpoint_mm": f"{(reach - breakpoints[last]) * 1e3:.0f}",
        "joint.last_segment_mn_per_m": f"{segment_slope / 1e6:.0f}",
        "joint.generator.peak_g": f"{truth['peak_decel_g']:.1f}",
    }
    predicted = {
        tail: _predicted_64(folder) for tail, folder in (("trend", "results/pickup-what-ifs/simulation"), ("segment", "segment"))
    }
    for tail, test in predicted.items():
        (low, high), peak = test["intervals"]["peak_decel_g"], test["metrics"]["peak_decel_g"]
        numbers[f"joint.{tail}.peak_g"] = f"{peak:.1f}"
        numbers[f"joint.{tail}.peak_low_g"], numbers[f"joint.{tail}.peak_high_g"] = f"{low:.0f}", f"{high:.0f}"
    segment = predicted["segment"]["metrics"]
    numbers["joint.segment.peak_pct"] = f"{(segment['peak_decel_g'] / truth['peak_decel_g'] - 1) * 100:+.1f}"
    numbers["joint.segment.displacement_pct"] = f"{(segment['max_displacement_m'] / truth['max_displacement_m'] - 1) * 100:+.1f}"
    return {"pickup-joint-64-extrapolates": "\n".join(line for line in joint if "extrapolates" in line)}, numbers


def _predicted_64(folder: str) -> dict[str, Any]:
    """The 64 km/h test of a simulation's folder (simulation.json)."""
    return dict(json.loads(Path(folder, "simulation.json").read_text())["tests"]["64kph"])


def _init() -> Quoted:
    """The Camry's problem written by crashnlp init from its EV5 file, then fitted (any-vehicle)."""
    run("init", "problems/data/nhtsa-10146/v10146.EV5", "--out", "camry.yaml")
    run("identify", "camry.yaml", "--no-figures")
    test = fitted_test("results/v10146", "v10146")
    model = test["metrics"]["model"]
    accel = {"camry.init.rating.accel": f"{test['fit']['accel']['iso18571']['overall']:.3f}"}
    return {}, displacement_and_stop("camry.init", model) | peak("camry.init", model) | accel


# --------------------------------------------------------------------------- the pages
EXEMPT = ("docs/design-notes.md",)  # history: what was measured when a choice was made, as the changelog

# what a page shows that is no prose: fenced code and inline code (commands, keys, YAML as typed:
# inputs), link targets, HTML comments, web addresses; marked blocks and values are taken out first
NOT_PROSE = re.compile(r"^```.*?^```|`[^`\n]*`|\]\([^)]*\)|<!--.*?-->|https?://\S+", re.MULTILINE | re.DOTALL)
NUMBER = re.compile(r"(?<![\w.^])[-+]?\d(?:[\d,]*\d)?(?:\.\d+)?(?:e[-+]?\d+)?(?![\w]|\.\d)")
# a number that names something: a standard, a filter class, an equation, a table, an issue, a
# benchmark's seed, a data set's test, a version
NAMED = re.compile(r"(?:ISO(?:/TS)?|J211-|CFC|Eqs?\.|Eq\. \(|\)-\(|Table|issues?|seeds?|test|NHTSA|>=)\s*$")
SCALES = (1e-6, 1e-3, 1e-2, 1.0, 1e2, 1e3, 1e6)  # SI prefixes and percent: 20 kN is 20e3 N


def typed(text: str, definitions: frozenset[float]) -> list[str]:
    """Every number of `text`'s prose and tables that no build writes, as "line N: NUMBER": not
    marked, not in a generated block, not code, and not a definition. A definition is an integer
    below 10 (a count of a setup, an exit code, a formula's coefficient), a year or a benchmark's
    seed (an integer 1900 to 2100), a number naming something (NAMED), or a value of
    `definitions` at any SI prefix or as a percentage (a constant of the code, an input of a
    shipped problem)."""
    text = INLINE.sub(lambda m: " " * len(m[0]), BLOCK.sub(lambda m: "\n" * m[0].count("\n"), text))
    text = NOT_PROSE.sub(lambda m: re.sub(r"[^\n]", " ", m[0]), text)
    out = []
    for number, line in ((m, text.count("\n", 0, m.start()) + 1) for m in NUMBER.finditer(text)):
        value = abs(float(number[0].replace(",", "")))
        if value < 10 and value.is_integer() or 1900 <= value <= 2100 and value.is_integer():
            continue
        if NAMED.search(text[max(0, number.start() - 20) : number.start()]):
            continue
        if any(_key(value * scale) in definitions for scale in SCALES):
            continue
        out.append(f"line {line}: {number[0]}")
    return out


def _key(value: float) -> float:
    return float(f"{value:.10g}")


def definitions() -> frozenset[float]:
    """The numbers the docs may state without a marker: the constants and defaults the crashnlp
    package, the benchmarks and these scripts declare (`constants`: tolerances, limits, a
    benchmark's speeds and seeds) and every number written in a shipped problem or study file
    outside its comments (the inputs a run is given)."""
    code = [p for folder in ("crashnlp", "bench", "scripts") for p in (ROOT / folder).rglob("*.py")]
    values = {_key(v) for path in code for v in constants(ast.parse(path.read_text()))}
    for path in (ROOT / "problems").rglob("*.yaml"):
        for line in path.read_text().splitlines():
            values |= {_key(abs(float(n.replace(",", "")))) for n in NUMBER.findall(INLINE.sub("", line.split(" #")[0]))}
    return frozenset(values)


BOUNDS = ("default", "ge", "gt", "le", "lt")  # a schema Field's default and limits (crashnlp.base.records)


def constants(tree: ast.Module) -> Iterator[float]:
    """The numbers a module declares as definitions: the values of its UPPER_CASE names, its
    functions' defaults, its schema fields' defaults and limits (not the numbers inside its code,
    which may be anything)."""

    def numbers(node: ast.AST | None) -> Iterator[float]:
        for n in ast.walk(node) if node is not None else ():
            if isinstance(n, ast.Constant) and isinstance(n.value, (int, float)) and not isinstance(n.value, bool):
                yield abs(float(n.value))

    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and all(isinstance(t, ast.Name) and t.id.isupper() for t in node.targets):
            yield from numbers(node.value)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            yield from numbers(node.value) if node.target.id.isupper() or isinstance(node.value, ast.Constant) else ()
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for default in (*node.args.defaults, *node.args.kw_defaults):
                yield from numbers(default)
        elif isinstance(node, ast.keyword) and node.arg in BOUNDS:
            yield from numbers(node.value)


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
