"""Results of the benchmarks: all numbers to JSON, the tables and targets to Markdown."""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

from bench import calibration, convergence
from crashnlp.base.outputs import METRIC


def _met(ok: bool | None) -> str:
    return "n/a" if ok is None else ("met" if ok else "**missed**")


def _signed(error: float, factor: float = 1.0, digits: int = 1) -> str:
    """An error in a table, signed; "none" where the prediction or the generator gives no value (NaN)."""
    return f"{error * factor:+.{digits}f}" if math.isfinite(error) else "none"


def targets(results: dict) -> list[tuple[str, str, bool | None]]:
    """(target, measured, met) for every target of the issue; None when the section did not run."""
    rows = []
    ident = results.get("identification")
    for method, r in (ident or {}).get("crashnlp", {}).items():
        q, b = ident["ratios"][method], ident["baseline"]
        rows.append((f"identification {method}: >= 50x faster than the baseline", f"{q['speedup']:.1f}x", q["speedup"] >= 50))
        rows.append(
            (
                f"identification {method}: objective <= baseline's",
                f"{r['objective']:.5g} vs {b['objective']:.5g}",
                r["objective"] <= b["objective"],
            )
        )
        rows.append(
            (f"identification {method}: < 1 s wall", f"{r['wall_s']:.2f} s ({r['ipopt_s']:.2f} s IPOPT)", r["wall_s"] < 1.0)
        )
    sim = results.get("simulation")
    if sim:
        s, b = sim["single"], sim["batch"]
        rows.append(
            (
                "forward simulation >= 20x faster than solve_ivp",
                f"{s['speedup']:.1f}x ({s['speedup_call_only']:.1f}x integrator call only)",
                s["speedup"] >= 20,
            )
        )
        best = min(b["vm"]["wall_s"], b["compiled"]["wall_s"])
        rows.append((f"{b['n']} batched simulations < 1 s", f"{best:.2f} s", best < 1.0 if b["n"] >= 1000 else None))
    st = results.get("studies")
    if st and "grid_16" in st:
        g = st["speedup_16"]
        rows.append(
            (
                "study, 16-case grid: 2 workers >= 1.7x faster than 1, same table",
                f"{g['2 workers']:.2f}x (dask LocalCluster {g['dask LocalCluster, 2 workers']:.2f}x); "
                f"tables {'identical' if st['same_table_16'] else '**differ**'}",
                g["2 workers"] >= 1.7 and st["same_table_16"],
            )
        )
        big = st["speedup_64"]
        if "dask LocalCluster, 2 workers" in big:
            rows.append(
                (
                    "study, 64-case grid: 2 workers >= 1.8x faster than 1, a dask LocalCluster of 2 >= 1.6x",
                    f"{big['2 workers']:.2f}x, dask {big['dask LocalCluster, 2 workers']:.2f}x",
                    big["2 workers"] >= 1.8 and big["dask LocalCluster, 2 workers"] >= 1.6,
                )
            )
        if "warm_vs_ipopt" in st["case"]:
            ratio = st["case"]["warm_vs_ipopt"]
            rows.append(("study: a warm case's whole cost <= 1.5x IPOPT's time", f"{ratio:.2f}x", ratio <= 1.5))
        p = st["speedup_pitch_bound"]
        rows.append(
            (
                "study, pitch-bound (4 cases): 2 workers >= 1.8x faster than 1",
                f"{p['2 workers']:.2f}x (serial maps in both runs: {p['2 workers, serial maps'] / p['1 worker, serial maps']:.2f}x)",
                p["2 workers"] >= 1.8,
            )
        )
    sc = results.get("scaling")
    for method, s in (sc or {}).get("slopes", {}).items():
        detail = (
            f"; {s['ipopt_per_iteration']:.2f} per IPOPT iteration, steepest step {s['steepest_step']:.2f}"
            if "steepest_step" in s
            else ""
        )
        rows.append(
            (
                f"scaling {method}: time no faster than linear in intervals (slope <= 1)",
                f"slope {s['wall_s']:.2f} ({s['ipopt_s']:.2f} IPOPT only{detail})",
                s["wall_s"] <= 1.0,
            )
        )
    co = results.get("corpus")
    if co:
        c, t = co["summary"], co["targets"]
        rows.append(("corpus: every vehicle identified", f"{c['succeeded']} of {c['vehicles']}", c["success_rate"] == 1.0))
        rows.append(
            (
                f"corpus: max displacement within {100 * t['displacement_rel']:g} %",
                f"largest error {100 * c['displacement_rel_max']:.2f} %",
                c["displacement_rel_max"] <= t["displacement_rel"],
            )
        )
        rows.append(
            (
                f"corpus: stop time within {1e3 * t['stop_s']:g} ms",
                f"largest error {1e3 * c['stop_err_max_s']:.2f} ms",
                c["stop_err_max_s"] <= t["stop_s"],
            )
        )
        rows.append(
            (
                f"corpus: median barrier-force ISO 18571 >= {t['force_rating_median']}",
                f"{c['force_rating_median']:.3f} (lowest {c['force_rating_min']:.3f})",
                c["force_rating_median"] >= t["force_rating_median"],
            )
        )
    rows += cross_speed_targets(results.get("cross_speed"))
    rows += calibration.targets(results.get("intervals"))
    if "convergence" in results:
        rows += convergence_targets(convergence.summary(results))
    wp = results.get("whole_process")
    if wp and "second_run_fresh_cache" in wp:
        warm, bare = wp["warm"], wp["warm_no_figures"]
        rows.append(
            (
                "whole process: `crashnlp identify` >= 20x faster than the scipy fit as a process",
                f"{wp['speedup']:.1f}x ({warm['wall_s']:.2f} s against {wp['scipy_baseline']['wall_s']:.2f} s; "
                f"{wp['speedup_no_figures']:.1f}x with --no-figures)",
                wp["speedup"] >= 20,
            )
        )
        peak = max(warm["peak_rss_mb"], bare["peak_rss_mb"])
        rows.append(("whole process: peak RSS <= 400 MB", f"{peak:.0f} MB", peak <= 400))
    if wp and "new_problem" in wp:
        third = wp["new_problem"]["run_3"]["vs_floor"]
        rows.append(
            ("whole process: a new problem (init), empty cache, run 3 <= 4x the import floor", f"{third:.1f}x", third <= 4)
        )
        bare = wp["vs_floor"]["warm_no_figures"]
        rows.append(("whole process: the pickup warm, --no-figures, <= 3.5x the import floor", f"{bare:.1f}x", bare <= 3.5))
    return rows


SPLITS = ("extrapolation", "interpolation")  # the cross-speed section's


def cross_speed_targets(xs: dict | None) -> list[tuple[str, str, bool | None]]:
    """The cross-speed section's targets: errors per split, interval coverage, iterations."""
    if not xs:
        return []
    s, t = xs["summary"], xs["targets"]
    rows: list[tuple[str, str, bool | None]] = []
    for split in SPLITS:
        r, goal = s[split], t[split]
        rows.append(
            (
                f"cross-speed {split}: max displacement within {100 * goal['displacement_rel']:g} %, peak within {100 * goal['peak_rel']:g} %",
                f"{r['within_targets']} of {r['fits']} (largest {100 * r['displacement_rel_max']:.1f} % and {100 * r['peak_rel_max']:.1f} %)",
                r["within_targets"] == r["fits"],
            )
        )
    rows.append(
        (
            f"cross-speed: 95 % intervals cover the generator's max displacement and peak in >= {100 * t['coverage']:g} % of pairs",
            f"{100 * s['coverage']:.0f} % of {s['pairs']}",
            s["coverage"] >= t["coverage"],
        )
    )
    worst = max(s[split]["iterations_max"] for split in SPLITS)
    rows.append(
        (f"cross-speed: every fit within {t['iterations']} IPOPT iterations", f"largest {worst}", worst <= t["iterations"])
    )
    return rows


def convergence_targets(groups: dict[str, dict | None]) -> list[tuple[str, str, bool | None]]:
    """Issue 25's acceptance per group of fits (bench/convergence.py); n/a where its section did not run."""
    c, j, g, r = groups["corpus"], groups["joint"], groups["grid"], groups["regularized"]
    limits = convergence.TARGETS
    return [
        (
            f"convergence, corpus: every vehicle ok, median iterations <= {convergence.CORPUS_MEDIAN}, "
            f"none above {limits['corpus_iterations']}",
            _iterations(c),
            None if c is None else _all_ok(c) and c["median_iterations"] <= c["median_target"],
        ),
        (
            f"convergence, joint fits of 2 and 4 tests by both transcriptions: ok within {limits['joint_iterations']} iterations",
            _iterations(j),
            None if j is None else _all_ok(j),
        ),
        (
            f"convergence, {limits['grid_cases']}-case grid: every case ok within {limits['grid_iterations']} iterations, "
            "the same table on 1 and 2 workers",
            "n/a" if g is None else f"{_iterations(g)}; tables {'identical' if g['same_table'] else '**differ**'}",
            None if g is None else _all_ok(g) and g["count"] == limits["grid_cases"] and g["same_table"],
        ),
        (
            f"convergence, regularized joint fits: ok within {limits['joint_iterations']} iterations",
            _iterations(r),
            None if r is None else _all_ok(r),
        ),
    ]


def _all_ok(g: dict) -> bool:
    return g["ok"] == g["count"] and g["above_limit"] == 0


def _iterations(g: dict | None) -> str:
    if g is None:
        return "n/a"
    above = f", {g['above_limit']} above {g['limit']}" if g["above_limit"] else ""
    return f"{g['ok']} of {g['count']} ok; iterations median {g['median_iterations']:g}, largest {g['max_iterations']}{above}"


def convergence_md(results: dict) -> list[str]:
    """The convergence summary over the run's corpus, scaling, studies and convergence results."""
    groups = convergence.summary(results)
    sources = {"corpus": "corpus", "joint": "scaling", "grid": "studies", "regularized": "convergence"}
    labels = {"corpus": "robustness corpus", "joint": "joint fits", "grid": "64-case grid", "regularized": "regularized fits"}
    rows = [[labels[k], sources[k], *(["not run", "", "", "", ""] if g is None else _group_cells(g))] for k, g in groups.items()]
    return [
        "## Convergence",
        "",
        "Status, IPOPT iterations and wall time of the fits issue 25 requires to finish. The corpus, joint fits and grid "
        "are those of the corpus, scaling and studies sections of this results file, read rather than solved again. "
        "Iterations count every IPOPT run of a fit (Gauss-Newton, its hand-over to Newton, restarts); a grid case's "
        "time is its solve's, the others' the whole identification's.",
        "",
        *_table(["fits", "section", "ok", "median iterations", "largest", "above limit", "wall (s), median"], rows),
        "",
        *_slow_fits_md(groups["corpus"], "Corpus vehicles"),
        *_fits_md(
            groups["joint"],
            f"Joint fits (scaling section, each IPOPT run capped at {(groups['joint'] or {}).get('max_iter')} iterations):",
        ),
        *_regularized_md(results.get("convergence")),
        *_grid_md(groups["grid"]),
    ]


def _group_cells(g: dict) -> list:
    wall = statistics.median(f["wall_s"] for f in g["fits"]) if g["fits"] else float("nan")
    return [
        f"{g['ok']} of {g['count']}",
        f"{g['median_iterations']:g}",
        g["max_iterations"],
        f"{g['above_limit']} above {g['limit']}",
        f"{wall:.2f}",
    ]


def _fit_table(fits: list[dict]) -> list[str]:
    return _table(
        ["fit", "status", "iterations", "wall (s)"],
        [[f["fit"], f["status"], f["iterations"], f"{f['wall_s']:.2f}"] for f in fits],
    )


def _fits_md(g: dict | None, title: str) -> list[str]:
    return [] if g is None else [title, "", *_fit_table(g["fits"]), ""]


def _slow_fits_md(g: dict | None, title: str) -> list[str]:
    """A group's fits that failed or ended above its limit (every fit's row is in its own section)."""
    if g is None:
        return []
    slow = [f for f in g["fits"] if f["status"] != "ok" or f["iterations"] > g["limit"]]
    if not slow:
        return [f"{title}: every one ok within {g['limit']} iterations.", ""]
    return [f"{title} that failed or took more than {g['limit']} iterations:", "", *_fit_table(slow), ""]


def _regularized_md(r: dict | None) -> list[str]:
    if not r:
        return []
    ok = lambda x: "displacement_rel" in x  # noqa: E731
    rows = [
        [
            f"{x['regularization']:g}",
            x["intervals"],
            x["status"],
            x["iterations"],
            f"{x['wall_s']:.2f} ({'compiled' if x.get('compiled') else 'VM'})",
            _signed(x["displacement_rel"], 100) if ok(x) else "",
            _signed(x["peak_rel"], 100) if ok(x) else "",
        ]
        for x in r["regularized"]
    ]
    kmh = f"{r['predict_kmh']:.0f} km/h"
    return [
        f"{r['problem']} with `objective.regularization` set, identified; its {kmh} prediction (a problem naming only that "
        "speed, as in the cross-speed section) against the generator's noise-free pickup:",
        "",
        *_table(
            ["regularization", "intervals", "status", "iterations", "wall (s)", f"{kmh} displacement (%)", f"{kmh} peak (%)"],
            rows,
        ),
        "",
    ]


def _grid_md(g: dict | None) -> list[str]:
    """The grid's iterations as a matrix: pitch bound down, front suspension across; failed cases marked."""
    if g is None:
        return []
    pitch = list(dict.fromkeys(f["pitch"] for f in g["fits"]))
    k_front = list(dict.fromkeys(f["k_front"] for f in g["fits"]))
    cell = {(f["pitch"], f["k_front"]): f for f in g["fits"]}
    show = lambda f: f["iterations"] if f["status"] == "ok" else f"**{f['iterations']}, {f['status']}**"  # noqa: E731
    matrix = [[p, *(show(cell[p, k]) if (p, k) in cell else "" for k in k_front)] for p in pitch]
    same = "identical but for solve times" if g["same_table"] else "**differ**"
    return [
        f"64-case grid (studies section, pickup-56kph): IPOPT iterations of each case in the 1-worker table; the tables of "
        f"{' and '.join(str(w) for w in g['workers'])} workers are {same}.",
        "",
        *_table(["pitch bound, front suspension", *k_front], matrix),
        "",
    ]


def _goal(target: dict) -> str:
    return f"{100 * target['displacement_rel']:g} % / {100 * target['peak_rel']:g} %"


def cross_speed_md(r: dict) -> list[str]:
    ok = lambda x: x["status"] == "ok"  # noqa: E731
    rows = [
        [
            x["vehicle"],
            x["family"],
            x["split"],
            x["status"],
            x["iterations"],
            _signed(x["displacement_rel"], 100) if ok(x) else "",
            _signed(x["peak_rel"], 100) if ok(x) else "",
            _signed(x["stop_err_s"], 1e3, 2) if ok(x) else "",
            f"{sum(x['covered'].values())} of {len(x['covered'])}" if ok(x) else "",
            f"{x['load_rise']:.2f}" if "load_rise" in x else "",
            _signed(x["pitch_err_deg"]) if ok(x) else "",
            f"{x['pitch_rmse_deg']:.2f}" if x.get("pitch_rmse_deg") is not None else "",
        ]
        for x in r["fits"]
    ]
    families = [
        [
            name,
            *(f"{f[split]['within_targets']} of {f[split]['fits']}" for split in SPLITS),
            f"{100 * f['coverage']:.0f} % of {f['pairs']}",
            max(f[split]["iterations_max"] for split in SPLITS),
        ]
        for name, f in r["summary"]["families"].items()
    ]
    return [
        "## Cross-speed predictions",
        "",
        "The shipped `pickup-joint.yaml` (its breakpoints past the 56 km/h crush), then the shared synthetic pickup and "
        "the corpus vehicles of each family (a seed, and the speed each vehicle's structure is built for) from minimal "
        "problem files, each the same structure at 40, 56 and 64 km/h. Extrapolation fits 40 + 56 km/h and predicts "
        "64 km/h; interpolation fits 40 + 64 km/h and predicts 56 km/h, with `crashnlp.simulate` "
        "of a problem that names only the new speed. Errors against the generator's noise-free response; covered: "
        "whether the 95 % intervals hold the generator's max displacement and peak deceleration; load rise: the generator's "
        "load at the predicted test's largest crush over its load at the fitted tests' largest, how much the structure "
        "stiffens where only the prediction goes (the corpus's load curves double at 1.15 times the crush each vehicle "
        "was built for: built for 56 km/h, the 64 km/h test crushes into that rise); max pitch: the predicted test's max pitch less the "
        "generator's; pitch RMSE: the fit's miss of the measured pitch on its own tests. The targets above count every fit.",
        "",
        *_table(
            ["family", *(f"{split}s within {_goal(r['targets'][split])}" for split in SPLITS), "covered", "iterations, largest"],
            families,
        ),
        "",
        *_table(
            [
                "vehicle",
                "family",
                "split",
                "status",
                "iterations",
                "displacement (%)",
                "peak (%)",
                "stop (ms)",
                "covered",
                "load rise (x)",
                METRIC["max_pitch_deg"].heading,
                "pitch RMSE, fitted (deg)",
            ],
            rows,
        ),
        "",
    ]


def _table(head: list[str], rows: list[list]) -> list[str]:
    return [
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
        *("| " + " | ".join(str(c) for c in r) + " |" for r in rows),
    ]


PROFILED = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")


def identification_md(r: dict) -> list[str]:
    b = r["baseline"]
    b_wall = b["wall_s"]
    runs = [(m, "compiled", c) for m, c in r["crashnlp"].items()]
    runs += [(m, "CasADi's VM", c) for m, c in r.get("virtual_machine", {}).items()]
    rows = [
        [
            f"{m}, {how}",
            c["status"],
            f"{c['wall_s']:.3f}",
            f"{c['ipopt_s']:.3f}",
            f"{c['iterations']} it, {c.get('ms_per_iteration', float('nan')):.1f} ms/it",
            f"{c['objective']:.5g}",
            f"{b_wall / c['wall_s']:.1f}x",
        ]
        for m, how, c in runs
    ]
    rows.append(
        [
            "scipy baseline",
            "converged" if b["converged"] else f"not converged ({b['message']})",
            f"{b['wall_s']:.1f}",
            "",
            f"{b['iterations']} it, {b['simulations']} simulations",
            f"{b['objective']:.5g}",
            "1x",
        ]
    )
    channels = list(b["rmse"])
    rmse = [
        [m, *(f"{c['rmse'][k]['rmse']:.4g} {c['rmse'][k]['unit']}" for k in channels)]
        for m, c in {**r["crashnlp"], "scipy baseline": b}.items()
    ]
    prof = [
        [
            m,
            *(f"{1e3 * c['profile'][f][1] / max(c['profile'][f][0], 1):.2f} ms x {c['profile'][f][0]}" for f in PROFILED),
            f"{c['ipopt_s'] - sum(c['profile'][f][1] for f in PROFILED):.2f} s",
        ]
        for m, c in r["crashnlp"].items()
        if c.get("profile")
    ]
    profile = (
        [
            "Inside IPOPT (CasADi's timing statistics): time per call x calls of each function, and what is left for "
            "IPOPT itself (MUMPS, line search):",
            "",
            *_table(["method", *PROFILED, "IPOPT itself"], prof),
            "",
        ]
        if prof
        else []
    )
    return [
        f"## Identification ({r['problem']}, {next(iter(r['crashnlp'].values()))['intervals']} intervals)",
        "",
        "Objective: every final parameter set judged by one CVODES forward simulation at the node times.",
        "",
        *_table(["method", "status", "wall (s)", "IPOPT (s)", "work", "objective", "speed-up"], rows),
        "",
        "RMSE per channel (same evaluator):",
        "",
        *_table(["method", *channels], rmse),
        "",
        *_from_data_md(r.get("from_data")),
        *profile,
    ]


def _from_data_md(d: dict | None) -> list[str]:
    """Both fits from the measured force-crush curve: time to a fit, not to the baseline's stop."""
    if not d:
        return []
    c, b = d["crashnlp"], d["baseline"]
    return [
        "From the measured force-crush curve instead (the spring values left to crashnlp.case.completion, for both): "
        f"crashnlp {d['method']} {c['wall_s']:.2f} s, {c['iterations']} it, objective {c['objective']:.5g}; "
        f"the baseline {b['wall_s']:.1f} s, {b['iterations']} it, {b['simulations']} simulations, objective "
        f"{b['objective']:.5g} ({'converged' if b['converged'] else 'not converged'}): {d['speedup']:.1f}x. From the "
        "problem's flat guess the baseline stops early at a worse fit, which is what the targets above time.",
        "",
    ]


def simulation_md(r: dict) -> list[str]:
    s, b = r["single"], r["batch"]
    rows = [
        ["crashnlp simulate (states and outputs)", f"{1e3 * s['crashnlp_s']:.1f}", ""],
        ["crashnlp integrator call only", f"{1e3 * s['crashnlp_call_only_s']:.1f}", ""],
    ]
    rows += [
        [f"solve_ivp {m}", f"{1e3 * v['wall_s']:.1f}", f"{v['max_crush_diff_mm']:.1e} mm, {v['max_accel_diff_g']:.1e} g"]
        for m, v in s["scipy"].items()
    ]
    checks = [[c["member"], f"{c['max_diff_vs_alone']:.1e}", f"{c['max_crush_diff_vs_cvodes_mm']:.3g}"] for c in b["checks"]]
    return [
        "## Forward simulation",
        "",
        f"One 56 km/h simulation, {s['grid_points']} output points, rtol {s['rtol']:g}, atol {s['atol']:g} (best of repeats):",
        "",
        *_table(["method", "wall (ms)", "max difference to crashnlp"], rows),
        "",
        f"Speed-up against the fastest solve_ivp ({s['scipy_best']}): {s['speedup']:.1f}x end-to-end, {s['speedup_call_only']:.1f}x integrator call only.",
        "",
        f"Batch of {b['n']} ({b['integrator']}, dt {b['dt']:g} s, {b['steps']} steps):",
        "",
        *_table(
            ["evaluation", "first call (s)", "run (s)", "per simulation (ms)"],
            [
                [m, f"{b[m]['first_call_s']:.2f}", f"{b[m]['wall_s']:.2f}", f"{b[m]['per_simulation_ms']:.2f}"]
                for m in ("vm", "compiled")
            ],
        ),
        "",
        *_table(["member", "max abs(batch - alone)", "crush vs CVODES (mm)"], checks),
        "",
    ]


def studies_md(r: dict) -> list[str]:
    if "grid_16" not in r:
        return ["## Studies", "", r.get("skipped", "(no 16-case grid in these results)"), ""]
    c, g = r["case"], r["grid_16"]["1 worker, serial maps"]
    return [
        "## Studies",
        "",
        "`crashnlp study` as a process, into a fresh folder each run; median of the runs given, the variants taking turns. "
        "A lone worker's solve uses the threaded maps on both cores (as shipped); serial maps: CRASHNLP_THREADS=1. "
        "The load average (1 minute) before and after each study's runs says what else shared the cores: a speed-up "
        "measured beside other work is not the machine's.",
        "",
        *_table(
            ["study", "run", "wall (s)", "runs (s)", "speed-up", "table as the first", "exit", "load average (before, after)"],
            _study_rows(r),
        ),
        "",
        f"On the 16-case grid the solves themselves (IPOPT) take {g['solves_s']:.1f} s in all and the longest warm-start chain "
        f"{g['longest_chain_s']:.1f} s of it: two workers can be at most {g['two_worker_bound']:.2f}x faster on the solves. "
        f"IPOPT per case: cold median {r['cold_ipopt_s']['median']:.2f} s (largest {r['cold_ipopt_s']['max']:.1f} s), "
        f"warm median {r['warm_ipopt_s']['median']:.2f} s (largest {r['warm_ipopt_s']['max']:.1f} s), over the 16- and 64-case grids.",
        "",
        *_table(["per case", "measured"], _case_rows(r)),
        "",
        "### 10,000 cases",
        "",
        _ten_thousand(r),
        "",
        "The real plan and scheduler on a virtual clock: a 100 x 100 grid of the same entries, each case's cost drawn from the "
        f"cold and warm IPOPT times measured above plus {c['overhead_s']:.2f} s outside IPOPT, and the main process's "
        f"{r['store_ms'] + r['scheduler']['local']['per_task_ms']:.1f} ms per case (storing it, starting the next) serial. "
        "Efficiency: the work over workers x wall time.",
        "",
        *_table(["plan", "cold seeds", "depth", "workers", "wall (min)", "efficiency"], _projection_rows(r["projection"])),
        "",
    ]


def _study_rows(r: dict) -> list[list]:
    rows = []
    for key, label in (("pitch_bound", "pitch-bound (4 cases)"), ("grid_16", "16-case grid"), ("grid_64", "64-case grid")):
        for name, x in r[key].items():
            rows.append(
                [
                    label,
                    name,
                    f"{x['wall_s']:.1f}",
                    ", ".join(f"{w:.1f}" for w in x["walls_s"]),
                    f"{r[key]['1 worker']['wall_s'] / x['wall_s']:.2f}x",
                    "yes" if x["same_table"] else "**no**",
                    x["exit"],
                    ", ".join(f"{a:.1f}" for a in x.get("load_average", ())),  # runs before the load was recorded: none
                ]
            )
    return rows


def _case_rows(r: dict) -> list[list]:
    c, local, dask, s = r["case"], r["scheduler"]["local"], r["scheduler"]["dask"], r["setup"]
    return [
        ["cold seed of the grid, in one process", f"{c['cold_s']:.2f} s ({c['cold_ipopt_s']:.2f} s IPOPT)"],
        ["warm case of the grid, in one process", f"{c['warm_s']:.2f} s ({c['warm_ipopt_s']:.2f} s IPOPT)"],
        [
            "job shipped to a worker (problem + warm start)",
            f"{c['job_bytes'] / 1e3:.1f} kB ({c['warm_start_bytes'] / 1e3:.1f} kB warm start)",
        ],
        ["result shipped back (row + solution)", f"{c['result_bytes'] / 1e3:.1f} kB ({c['columns']} columns)"],
        ["scheduler per case, process pool", f"{local['per_task_ms']:.2f} ms (workers up in {local['start_s']:.1f} s)"],
        ["scheduler per case, dask LocalCluster", f"{dask['per_task_ms']:.2f} ms (cluster up in {dask['start_s']:.1f} s)"],
        ["main process storing a case", f"{r['store_ms']:.2f} ms"],
        [f"checking a {s['cases']:,}-case study before any solve", f"{s['wall_s']:.1f} s ({s['per_case_ms']:.1f} ms a case)"],
    ]


def _ten_thousand(r: dict) -> str:
    """What the per-case numbers say about a 10,000-case study."""
    c, s = r["case"], r["setup"]
    main_ms = r["store_ms"] + r["scheduler"]["local"]["per_task_ms"]
    case_s = r["warm_ipopt_s"]["median"] + c["overhead_s"]
    return (
        f"Before any solve the main process checks every case: {s['per_case_ms'] * 10:.0f} s for 10,000. Each case ships "
        f"{c['job_bytes'] / 1e3:.0f} kB to its worker and {c['result_bytes'] / 1e3:.0f} kB back "
        f"({(c['job_bytes'] + c['result_bytes']) * 1e4 / 1e6:.0f} MB in all), nothing a network notices. The main process "
        f"handles the finished cases one at a time, {main_ms:.1f} ms each (dask adds "
        f"{r['scheduler']['dask']['per_task_ms']:.0f} ms of round trip per case, spread over its workers): at the median "
        f"warm case ({case_s:.2f} s) it keeps about {case_s / (1e-3 * main_ms):.0f} workers busy before it is the bottleneck. "
        "What limits many workers sooner is the plan: at first only the seeds can run, and a chain of warm starts "
        f"runs one case after another, so a slow case deep in a chain (the slowest warm case here: {r['warm_ipopt_s']['max']:.0f} s "
        "of IPOPT) sets the wall time."
    )


def _projection_rows(projection: list[dict]) -> list[list]:
    return [
        [x["plan"], x["seeds"], x["depth"], x["lanes"], f"{60 * x['makespan_h']:.1f}", f"{x['efficiency']:.2f}"]
        for x in projection
    ]


def scaling_md(r: dict) -> list[str]:
    fmt = lambda x: [
        x["method"],
        x["intervals"],
        x["tests"],
        f"{x['wall_s']:.2f}",
        f"{x['ipopt_s']:.2f}",
        x["iterations"],
        x["status"] + (" (capped)" if x["capped"] else ""),
    ]
    head = ["method", "intervals", "tests", "wall (s)", "IPOPT (s)", "iterations", "status"]
    slopes = [
        [
            m,
            f"{s['wall_s']:.2f}",
            f"{s['ipopt_s']:.2f}",
            f"{s.get('ipopt_per_iteration', float('nan')):.2f}",
            f"{s.get('steepest_step', float('nan')):.2f}",
        ]
        for m, s in r["slopes"].items()
    ]
    return [
        "## Scaling",
        "",
        f"IPOPT capped at {r['max_iter']} iterations. Figure: `{r['figure']}`.",
        "",
        *_table(head, [fmt(x) for x in r["intervals"]]),
        "",
        *_table(head, [fmt(x) for x in r["tests"]]),
        "",
        "Log-log slope of time against intervals, over the converged solves:",
        "",
        *_table(["method", "end-to-end", "IPOPT only", "IPOPT per iteration", "steepest step (end-to-end)"], slopes),
        "",
    ]


def corpus_md(r: dict) -> list[str]:
    c = r["summary"]
    ok = lambda x: x["status"] == "ok"  # noqa: E731
    rows = [
        [
            x["name"],
            f"{x['mass_kg']:.0f}",
            f"{x['speed_kmh']:.1f}",
            x["status"],
            METRIC["max_displacement_m"].shown(x["displacement_true_m"], 0) if ok(x) else "",
            _signed(x["displacement_rel"], 100, 2) if ok(x) else "",
            METRIC["time_zero_velocity_s"].shown(x["stop_true_s"], 1) if ok(x) else "",
            _signed(x["stop_err_s"], 1e3, 2) if ok(x) else "",
            f"{x['force_rating']:.3f}" if ok(x) else "",
            x["iterations"],
            f"{x['wall_s']:.2f}",
        ]
        for x in r["vehicles"]
    ]
    return [
        "## Robustness corpus",
        "",
        f"{c['vehicles']} random vehicles from `bench/corpus.py` (a planar rigid body with an eccentric contact force, "
        f"not the pendulum; seed {r['seed']}), each identified from a minimal problem file (vehicle and test only). "
        "Judged against the generator's noise-free response; the force rating is ISO/TS 18571 of the barrier force "
        "from impact to separation.",
        "",
        f"Identified {c['succeeded']} of {c['vehicles']}; within 2 % max displacement and 2 ms stop time: {c['within_targets']}. "
        f"Max displacement error median {100 * c['displacement_rel_median']:.2f} %, largest {100 * c['displacement_rel_max']:.2f} %; stop-time error "
        f"median {1e3 * c['stop_err_median_s']:.2f} ms, largest {1e3 * c['stop_err_max_s']:.2f} ms; force rating median "
        f"{c['force_rating_median']:.3f}, lowest {c['force_rating_min']:.3f}; median wall time {c['wall_median_s']:.2f} s.",
        "",
        *_table(
            [
                "vehicle",
                "mass (kg)",
                "speed (km/h)",
                "status",
                METRIC["max_displacement_m"].heading,
                "displacement error (%)",
                "stop (ms)",
                "stop error (ms)",
                "force ISO 18571",
                "iterations",
                "wall (s)",
            ],
            rows,
        ),
        "",
    ]


def self_consistency_md(r: dict) -> list[str]:
    rows = [
        [
            label,
            r[label]["status"],
            r[label]["iterations"],
            *(f"{100 * r[label]['relative_errors'][p]:.2f}" for p in r["truth"]),
            f"{r[label]['forward_check_worst']:.3f}",
        ]
        for label in ("all channels", "without velocity")
    ]
    c = r["coverage"]
    return [
        "## Self-consistency of the shipped pickup identification",
        "",
        "The shipped pickup fit is the truth; crashnlp's simulator makes data from it at 0.1 ms in the shipped CSV's "
        "columns, and the shipped problem fits them back (largest error per parameter: spring values relative to "
        "the largest force, the rest to their truth; the forward check relative to its tolerance).",
        "",
        *_table(["data", "status", "iterations", *r["truth"], "forward check"], rows),
        "",
        f"{c['replicates']} replicates with white noise (1 g filtered at CFC 60, 0.02 m/s, 1 mm, 0.1 deg): the 95 % "
        f"intervals cover the truth in {100 * c['coverage_95']:.0f} % of {c['pairs']} (parameter, replicate) pairs, "
        f"RMS z {c['rms_z']:.2f} (parameters whose truth sits on a bound left out).",
        "",
    ]


def new_problem_md(r: dict | None) -> list[str]:
    if r is None:
        return []
    runs = [r[f"run_{n}"] for n in (1, 2, 3)]
    rows = [
        [f"run {n}", f"{x['wall_s']:.2f}", f"{x['vs_floor']:.1f}x", f"{x['cpu_s']:.2f}", f"{x['cpu_vs_floor']:.1f}x", x["exit"]]
        for n, x in enumerate(runs, 1)
    ]
    return [
        "## A new problem, as a user gets it",
        "",
        "`crashnlp init` on the Camry's EV5 file, then `crashnlp identify --no-figures` from an empty cache with no "
        "crashnlp variable set, each run followed by three runs of the floor (`python -c 'import numpy, casadi'` "
        "with one OpenBLAS thread, as the command runs; median "
        f"{r['floor_s']:.2f} s, CPU {r['floor_cpu_s']:.2f} s):",
        "",
        *_table(["run", "wall (s)", "against the floor", "CPU (s)", "CPU against the floor's", "exit"], rows),
        "",
        f"The NLP's library, compiled after run 1 at nice 19, was ready {r['compile_after_run_2_s']:.1f} s after run 2 ended; "
        "run 3 started then.",
        "",
    ]


def whole_process_md(r: dict) -> list[str]:
    labels = {
        "first_run_fresh_cache": "crashnlp, first run on a fresh cache (VM solve, NLP compiled behind)",
        "second_run_fresh_cache": "crashnlp, second run (compiled NLP)",
        "warm": "crashnlp, warm caches",
        "warm_no_figures": "crashnlp --no-figures, warm caches",
        "simulate_warm": "`crashnlp simulate` of the same problem, warm caches",
        "simulate_no_figures": "`crashnlp simulate --no-figures`, warm caches",
        "python_numpy_casadi": "python -c 'import numpy, casadi' (the floor: one OpenBLAS thread, run after each command)",
        "scipy_baseline": "scipy least_squares + solve_ivp fit (same model), as a process",
    }
    rows = [[label, f"{r[k]['wall_s']:.2f}", f"{r[k]['peak_rss_mb']:.0f}", r[k]["exit"]] for k, label in labels.items() if k in r]
    return [
        *new_problem_md(r.get("new_problem")),
        "## Whole process",
        "",
        f"`{r['command']}` as a process (median of {r['repeats']} runs, the commands taking turns), what a user waits for:",
        "",
        *_table(["run", "wall (s)", "peak RSS (MB)", "exit"], rows),
        "",
        f"The scipy fit takes {r['speedup']:.1f}x as long as the crashnlp command ({r['speedup_no_figures']:.1f}x without figures).",
        f"The NLP's library compiled in the background in {r.get('background_compile_s', float('nan')):.1f} s after the first run "
        "returned (once per problem shape and machine).",
        "",
    ]


def forms_md(r: dict) -> list[str]:
    """Every model form on the tall vehicles, both splits (bench/forms.py)."""
    rows = [
        [
            split,
            form,
            f"{s['ok']}/{s['fits']}",
            f"{s['within_targets']}/{s['ok']}",
            f"{s['pitch_rmse_median_deg']:.2f}",
            f"{s['pitch_rmse_max_deg']:.2f}",
            f"{100 * s['displacement_rel_max']:.1f} %",
            f"{100 * s['peak_rel_max']:.1f} %",
            f"{1e3 * s['stop_err_max_s']:.2f}",
            s["lift_offs"],
            f"{s['fitted_lift_offs']} ({s['fitted_lift_offs_not_in_truth']})",
            *_interval_cells(s),
        ]
        for split, forms in r["summary"].items()
        for form, s in forms.items()
    ]
    head = ["split", "form", "converged", "within targets", "pitch RMSE median (deg)", "worst (deg)", "worst displacement"]
    head += ["worst peak", "worst stop (ms)", "predictions lifting off", "fits lifting off (not in the generator)"]
    head += ["displacement covered (half-width)", "peak covered (half-width)"]
    goals = "; ".join(f"{split} {_goal(t)}" for split, t in r["targets"].items())
    return [
        "## Model forms on tall vehicles",
        "",
        "Vans and tall SUVs fitted with each form at 40 + 64 km/h, 56 predicted (interpolation), and at 40 + 56, "
        f"64 predicted (extrapolation); targets, displacement / peak: {goals}. Covered: the share of predictions whose 95 % "
        "interval holds the generator's value; half-width: the median, relative to the prediction.",
        "",
        *_table(head, rows),
        "",
        *_hidden_md(r.get("hidden")),
    ]


def _interval_cells(s: dict) -> list[str]:
    return [f"{100 * s[f'{m}_covered']:.0f} % ({100 * s[f'{m}_half_width_median']:.1f} %)" for m in ("displacement", "peak")]


def _lift_off_cell(f: dict) -> str:
    """A prediction's lift-off (ms; and the CG's speed then, where the row has it), and the
    generator's own at that speed, or where it has none when it lets go and how fast it moves then."""
    if f["lift_off_s"] is None:
        return ""
    cell = f"{1e3 * f['lift_off_s']:.1f}" + ("" if f.get("lift_off_mps") is None else f" at {f['lift_off_mps']:+.3f} m/s")
    truth = f["truth_prediction_lift_off_s"]
    if truth is not None:
        return cell + f" (generator {1e3 * truth:.1f})"
    if f.get("truth_release_s") is None:
        return cell
    return cell + f" (generator lets go at {1e3 * f['truth_release_s']:.1f} at {f['truth_release_mps']:+.3f} m/s)"


def _stop_cell(f: dict) -> str:
    """A hidden fit's stop against the generator's (ms); where the generator never comes to rest,
    the prediction's own stop (its loading's end as it lets go), or none."""
    if math.isfinite(f["stop_err_s"]):
        return f"{1e3 * f['stop_err_s']:+.2f}"
    return f"at {1e3 * f['stop_s']:.1f}, the generator none" if math.isfinite(f["stop_s"]) else "no stop"


def _hidden_md(h: dict | None) -> list[str]:
    """The hidden tall vehicles, one row a fit, held to the issue's targets for them."""
    if not h:
        return []
    t = h["targets"]
    rows = [
        [
            f"{f['vehicle']} ({f['family']})",
            f["form"],
            f["status"],
            f["iterations"],
            *(
                [
                    f"{f['pitch_rmse_deg']:.2f}",
                    _signed(f["displacement_rel"], 100),
                    _signed(f["peak_rel"], 100),
                    _stop_cell(f),
                    _lift_off_cell(f),
                    _met(f["within_hidden"]),
                ]
                if f["status"] == "ok"
                else ["", "", "", "", "", _met(False)]
            ),
        ]
        for f in h["fits"]
    ]
    kinds = "; ".join(f"{label}: {k['maker']}, seed {k['seed']}" for label, k in h["kinds"].items())
    return [
        f"Hidden tall vehicles ({kinds}; built for {h['built_kmh']:g} km/h), fitted at 40 + 64 km/h, 56 predicted; "
        f"targets: fitted pitch RMSE <= {t['pitch_rmse_deg']:g} deg, displacement {100 * t['displacement_rel']:g} %, "
        f"peak {100 * t['peak_rel']:g} %, stop {1e3 * t['stop_s']:g} ms, no lift-off while the CG moves on that the "
        "generator does not have at 56 km/h too.",
        "",
        *_table(
            [
                "vehicle",
                "form",
                "status",
                "iterations",
                "pitch RMSE (deg)",
                "displacement (%)",
                "peak (%)",
                "stop (ms)",
                "lift-off (ms)",
                "met",
            ],
            rows,
        ),
        "",
        *_pitch_floor_md(h.get("pitch_floor")),
    ]


def _pitch_floor_md(floor: dict | None) -> list[str]:
    """The engine vans' pitch under the rigid body's fits (bench/forms.py's pitch_floor), one row a van."""
    if not floor or not floor["vans"]:
        return []
    vans = floor["vans"]
    speeds, variants = list(vans[0]["one_speed"]), list(vans[0]["variants"])
    rows = [
        [
            v["vehicle"],
            *(f"{100 * v['engine'][k]['impulse_share']:.0f} % / {v['engine'][k]['pitch_rms_deg']:.1f}" for k in speeds),
            *(_pitch_cell(v["one_speed"][k]) for k in speeds),
            *(_pitch_cell(v["variants"][k]) for k in variants),
        ]
        for v in vans
    ]
    head = [
        "van",
        *(f"{k} km/h: engine's impulse share / its pitch on the front end's line (deg)" for k in speeds),
        *(f"{k} km/h fitted alone (deg)" for k in speeds),
        *(f"joint, {k.replace('_', ' ')} (deg)" for k in variants),
    ]
    return [
        "The engine vans' pitch under the rigid body: the engine's share of the barrier's impulse and the RMS pitch its "
        "push would add if it acted on the front end's line of action, as in a form with one front-end force; the fitted "
        "pitch RMSE of each speed fitted alone, and of the joint fit as made above, with the pitch weighted up, with the "
        "suspension estimated, with the CG's height and the pitch inertia free.",
        "",
        *_table(head, rows),
        "",
    ]


def _pitch_cell(fit: dict) -> str:
    return f"{fit['pitch_rmse_deg']:.2f}" if "pitch_rmse_deg" in fit else fit["status"]


def detectors_md(r: dict) -> list[str]:
    """The watch's rules on the set seed's and the check seed's corpus fits (bench/detectors.py)."""
    rows = []
    for role in ("set", "check"):
        s = r[role]["summary"]
        cells = [f"{q['fires']} on {q['fits']} fits, {q['false_alarms']} false" for q in s["rules"].values()]
        apart = "" if math.isnan(s["apart_std_max"]) else f"{s['apart_std_max']:.1e}"
        rows.append([f"{role} (seed {r[role]['seed']})", f"{s['ok']} of {s['fits']}", *cells, s["misses"]])
        rows[-1] += [f"{s['iterations_median']:g} / {s['alone_iterations_median']:g}", s["alone_not_converged"], apart]
    rules = list(r["set"]["summary"]["rules"])
    head = ["seed", "ok", *rules, "misses", "iterations median, watched / left alone", "left alone not converged"]
    return [
        "## The watch's rules, set on one seed and checked on another",
        "",
        f"{r['count']} corpus vehicles a seed, each fitted on its own test and at "
        f"{' and at '.join(' + '.join(f'{k:g}' for k in j) for j in r['joints_kmh'])} km/h, watched (as crashnlp fits) and left alone (Gauss-Newton, no "
        f"watch, IPOPT's own termination, at most {r['left_alone']['max_iter']} iterations). Per rule: fires, the fits it "
        "fired on, false alarms (a tail whose Newton did not finish the same fit; a cycle on a fit that converged left "
        "alone; a steady stop away from the fit left alone; an unsettled cycle whose exact Hessian did not converge). Misses: runs that reached their limit with no rule firing. "
        "Apart: the largest parameter difference between the watched fit and the fit left alone, in standard errors.",
        "",
        *_table([*head, "apart (std)"], rows),
        "",
    ]


def truncated_md(r: dict) -> list[str]:
    """MID_CRASH on records cut short, vehicles of every generator kind (bench/truncated.py)."""
    first = next(iter(r["kinds"].values()))
    judged, withheld = list(first["held_short"]), list(first["held_withheld"])
    rows = [
        [
            kind,
            q["held"],
            *(q["held_short"][k] for k in judged),
            *(q["held_withheld"][k] for k in withheld),
            q["mid_crash"],
            q["mid_crash_whole"],
        ]
        for kind, q in r["kinds"].items()
    ]
    head = [
        "kind",
        "held whole",
        *(f"of them giving {METRIC[k].label} short" for k in judged),
        *(f"of them without {METRIC[k].label}, whole already" for k in withheld),
        "mid-crash",
        "of them with the peak in the record",
    ]
    floors = ", ".join(f"{v:g} {METRIC[k].unit} of {METRIC[k].label}" for k, v in r["floor"].items())
    met = sorted(m["s"] for q in r["kinds"].values() for m in q["met_again"])
    vehicles = f"{r['count']} vehicle{'s' if r['count'] != 1 else ''}"
    return [
        "## Records cut short: the mid-crash rule on a seed it was not set on",
        "",
        f"{vehicles} of each generator kind (seed {r['seed']}), noise-free at "
        f"{', '.join(f'{k:g}' for k in r['speeds_kmh'])} km/h, each record cut every {r['step_s'] * 1e3:g} ms before "
        f"its stop while still moving toward the barrier. Held whole: the deceleration at the cut below "
        f"{r['mid_crash']:g} of the peak so far, so the record gives its peak, and no velocity change, rebound or max "
        f"pitch (the vehicle meets the barrier again). Giving the peak short: more than {r['short']:.0%} below the "
        "whole record's, a silent failure. Without one, whole already: no more than that (or "
        f"{floors}, where more) below the whole record's, the caution's cost. Mid-crash: none of them given; of "
        "them with the peak in the record: the caution's cost.",
        "",
        *_table(head, rows),
        "",
        f"Vehicles held whole at a cut that left the barrier after it and met it again before they stopped: "
        f"{len(met)}, {met[0]:.2f} to {met[-1]:.2f} s after impact."
        if met
        else "No vehicle held whole at a cut left the barrier after it and met it again before it stopped.",
        "",
    ]


def choice_md(r: dict) -> list[str]:
    """compare's choice from one test against each form's prediction of the other speeds (bench/choice.py)."""
    rows = []
    for pop in r["populations"].values():
        for kind, s in [*((k, g["summary"]) for k, g in pop["kinds"].items()), ("all", pop["summary"])]:
            rows.append([pop["label"], kind, f"{s['chose_other']}/{s['vehicles']}", *map(_choice_cell, s["ways"].values())])
    ways = list(next(iter(r["populations"].values()))["summary"]["ways"])
    head = ["population", "generator form", "compare chose another form than the default", *ways]
    speeds = ", ".join(f"{k:g}" for k in r["predicted_kmh"])
    return [
        "## One test: compare's choice against the other speeds",
        "",
        f"Each vehicle of the intervals' populations tested at {r['fitted_kmh']:g} km/h; `crashnlp compare` chooses "
        "between its default forms from that test alone (BIC). Each form's fit of it then predicts the vehicle at "
        f"{speeds} km/h, scored as compare's held-out score is. The ways of choosing: compare's; compare's rule on a BIC "
        "whose samples are counted as fewer for the residuals' lag-one correlation, r (n (1 - r) / (1 + r) a channel); "
        "each form always. Per way: the vehicles whose chosen "
        f"form predicts within {100 * r['tie']:.0f} % of the better form's score, of those both forms scored; the mean and "
        "(in brackets) largest regret, the chosen form's score over the better one's, less one.",
        "",
        *_table(head, rows),
        "",
        "compare's rule with larger BIC ties than its 2, on every population's vehicles together (the same counts):",
        "",
        *_table(
            ["population", *next(iter(r["populations"].values()))["summary"]["ties"]],
            [[pop["label"], *(_choice_cell(w) for w in pop["summary"]["ties"].values())] for pop in r["populations"].values()],
        ),
        "",
        *_chosen_coverage_md(r),
    ]


def _chosen_coverage_md(r: dict) -> list[str]:
    """The intervals of the form each way chose (bench/choice.py's `covered`): per population and
    metric, the share covered over every scenario, with its range over whole vehicles."""
    covered = r.get("covered")
    if not covered:
        return []
    metrics = list(next(iter(next(iter(covered.values())).values())))
    rows = [
        [r["populations"][seed]["label"], way, *(calibration.share_text(by[m]) for m in metrics)]
        for seed, ways in covered.items()
        for way, by in ways.items()
    ]
    return [
        "The intervals of the form each way takes, on the populations whose held-out records the intervals' section "
        "keeps: every scenario's prediction of each vehicle by that form, judged with the form's shipped table; per "
        "metric the share that holds the generator's value, and in brackets its 95 % range over whole vehicles resampled "
        "and, where some predictions have no interval (a failed fit, no value, or a vehicle compare chose no form for), "
        "the share of those that have one:",
        "",
        *_table(["population", "way", *(calibration.SHORT[m] for m in metrics)], rows),
        "",
    ]


def _choice_cell(w: dict) -> str:
    """One way of choosing's tally (bench/choice.py's summary): within the tie of those scored, the mean and largest regret."""
    if not w["scored"]:
        return "none scored"
    return f"{w['within_tie']}/{w['scored']}, {100 * w['mean_regret']:.1f} % ({100 * w['max_regret']:.0f} %)"


SECTIONS = {
    "identification": identification_md,
    "simulation": simulation_md,
    "studies": studies_md,
    "scaling": scaling_md,
    "corpus": corpus_md,
    "self_consistency": self_consistency_md,
    "cross_speed": cross_speed_md,
    "forms": forms_md,
    "choice": choice_md,
    "intervals": calibration.markdown,
    "whole_process": whole_process_md,
    "detectors": detectors_md,
    "truncated": truncated_md,
}


def markdown(results: dict) -> str:
    m = results.get("machine", {})
    lines = [
        "# crashnlp benchmarks",
        "",
        f"Machine: {m.get('cpus')} CPUs, load average at start {m.get('load_average')} (other jobs share it), "
        f"CasADi {m.get('casadi')}, SciPy {m.get('scipy')}.{' QUICK smoke run: reduced sizes.' if results.get('quick') else ''}",
        "",
        "## Targets",
        "",
        *_table(["target", "measured", "result"], [[t, v, _met(ok)] for t, v, ok in targets(results)]),
        "",
    ]
    for name, fn in SECTIONS.items():
        if name in results:
            lines += fn(results[name])
    if "convergence" in results:
        lines += convergence_md(results)
    return "\n".join(lines)


def write(results: dict, json_path: Path, md_path: Path) -> None:
    """All numbers to `json_path`, the targets and tables of this run to `md_path` (how the numbers moved
    from round to round is CHANGELOG.md's)."""
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(results, indent=2, default=float))
    md_path.write_text(markdown(results))
