"""Result files: result.json, response and force-crush tables, figures.

Everything here is SI inside and converted to report units (g, deg, ms) only as
it is written.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from crashnlp import plots
from crashnlp.case import Case, TestCase
from crashnlp.data.signal import resample
from crashnlp.jsonfile import write_json
from crashnlp.metrics import crash_metrics
from crashnlp.optimize.identify import Solution, TestSolution
from crashnlp.optimize.verify import TOLERANCE
from crashnlp.rating import iso18571
from crashnlp.simulate import Response, write_response_csv
from crashnlp.transcription.base import DYNAMICS
from crashnlp.units import G0

REPORT_UNITS = {"accel": ("g", 1 / G0), "velocity": ("m/s", 1.0), "displacement": ("m", 1.0), "pitch": ("deg", 180 / math.pi)}
# ignored by reproducibility checks: the only entries that change from run to run
VOLATILE = ("wall_s", "build_s")


def metrics(
    t: np.ndarray,
    accel: np.ndarray,
    velocity: np.ndarray,
    displacement: np.ndarray,
    pitch: np.ndarray | None,
    crush: np.ndarray | None = None,
) -> dict:
    """The crash metrics result.json reports, in the units their names say.

    Max dynamic crush is the largest front-end crush where the crush is known (the model's
    `crush` output: along the pivot-CG line, what a crush bound limits), else the largest CG
    displacement (test data, which have no crush channel); `max_displacement_m` is always the
    latter. The two differ by the pitch: a model pitching nose-down crushes less than it travels.
    """
    m = crash_metrics(t, accel, velocity, displacement)
    t_crush, max_crush = m.t_max_crush, m.max_crush
    if crush is not None:
        after = np.flatnonzero(np.asarray(t) >= 0.0)
        i = after[int(np.argmax(np.asarray(crush)[after]))]
        t_crush, max_crush = float(t[i]), float(crush[i])
    out = {
        "max_crush_m": max_crush,
        "time_max_crush_s": t_crush,
        "max_displacement_m": m.max_crush,
        "time_zero_velocity_s": m.t_zero_velocity,
        "peak_decel_g": m.peak_decel / G0,
        "rebound_velocity_mps": m.rebound_velocity,
        "delta_v_mps": m.delta_v,
        "esw_g": m.esw / G0,
        "tesw_g": m.tesw / G0,
        "olc_g": m.olc / G0,
    }
    out["max_pitch_deg"] = float(np.degrees(np.max(pitch))) if pitch is not None else None
    return out


def data_curves(test: TestCase) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    if test.data is None:
        return {}
    return {name: (ch.time, ch.values) for name, ch in test.data.channels.items()}


def data_metrics(test: TestCase) -> dict | None:
    """Metrics of the measured curves, on the accel channel's time base."""
    ch = test.data.channels if test.data is not None else {}
    if not {"accel", "velocity", "displacement"} <= set(ch):
        return None
    t = ch["accel"].time
    t = t[(t >= max(c.time[0] for c in ch.values())) & (t <= min(c.time[-1] for c in ch.values()))]
    pitch = resample(ch["pitch"], t) if "pitch" in ch else None
    return metrics(t, resample(ch["accel"], t), resample(ch["velocity"], t), resample(ch["displacement"], t), pitch)


def response_metrics(r: Response | TestSolution) -> dict:
    t = r.times if isinstance(r, TestSolution) else r.time
    y = r.outputs
    return metrics(t, y["accel"], y["velocity"], y["displacement"], y["pitch"], y.get("crush"))


def _fit(solution: Solution, ts: TestSolution) -> dict:
    out = {}
    for r in solution.residuals:
        if r.test != ts.name:
            continue
        times = ts.times[r.columns]
        model = ts.outputs[r.channel][r.columns]
        unit, f = REPORT_UNITS[r.channel]
        entry = {"rmse": float(np.sqrt(np.mean((model - r.data) ** 2))) * f, "unit": unit, "sigma": r.sigma * f}
        entry["iso18571"] = iso18571(times, r.data, model) if len(times) >= 10 else None
        out[r.channel] = entry
    return out


def active_constraints(solution: Solution, lam_tol: float = 1e-6, slack_tol: float = 1e-6) -> list[dict]:
    """Inequality constraints at their bound with a nonzero multiplier.

    The multiplier, summed over the block's points, is what a unit of the bound
    is worth: d objective / d bound (objective units per SI unit).
    """
    res, nlp = solution.result, solution.ocp.nlp
    lbg, ubg = nlp.bounds()["lbg"], nlp.bounds()["ubg"]
    out = []
    for c in nlp.constraints:
        if c.name.endswith((*DYNAMICS, ".l1")):
            continue
        rows = slice(c.start, c.start + c.size)
        lam, g, lo, hi = res.lam_g[rows], res.g[rows], lbg[rows], ubg[rows]
        slack = np.minimum(np.abs(g - lo), np.abs(hi - g))
        bound = np.where(np.abs(g - lo) < np.abs(hi - g), lo, hi)
        active = np.flatnonzero((np.abs(lam) > lam_tol) & (slack <= slack_tol * (1 + np.abs(bound))))
        if active.size:
            out.append(
                {
                    "name": c.name,
                    "points": int(active.size),
                    "multiplier": float(np.sum(np.abs(lam[active]))),
                    "max_multiplier": float(np.max(np.abs(lam[active]))),
                }
            )
    return out


def _forward_check(solution: Solution, test: str) -> dict | None:
    """Largest difference between the forward simulation of the optimum and the NLP."""
    v = solution.verification
    if v is None:
        return None
    return {"max_abs_error": v.mismatch[test], "worst_relative": v.worst(test), "tolerance_relative": TOLERANCE}


def _named(solution: Solution, values: np.ndarray) -> dict:
    """Per-entry values of theta by parameter path (a number or a list); inf as None."""
    out = {}
    for e in solution.ocp.free.entries:
        v = [None if not np.isfinite(x) else float(x) for x in values[e.at]]
        out[e.path] = v[0] if e.where.stop - e.where.start == 1 else v
    return out


def parameter_uncertainty(solution: Solution) -> dict:
    """Standard errors (None: not identified), correlation, what is not identified or at a bound."""
    free, cov = solution.ocp.free, solution.covariance
    labels = np.asarray(free.labels())
    out = {"at_bound": labels[solution.at_bound()].tolist()}
    if cov is None:
        return {"std_errors": {}, "correlation": {}, "not_identified": [], **out}
    return {
        "std_errors": _named(solution, cov.std),
        "correlation": {"labels": labels.tolist(), "matrix": np.round(cov.correlation, 6).tolist()},
        "not_identified": labels[~cov.identified].tolist(),
        "profiles": solution.profiles,
        "covariance": {"method": "sandwich, Newey-West over the nodes of each test", "lags": cov.bandwidth},
        **out,
    }


def _bound_constraints(solution: Solution) -> list[dict]:
    """Parameters at a bound, as active constraints (their multiplier is IPOPT's lam_x)."""
    if solution.result is None:
        return []
    theta = solution.ocp.nlp.blocks["theta"]
    lam = np.asarray(solution.result.lam_x).ravel()[theta.offset : theta.offset + theta.shape[0]] / theta.scale.ravel()
    labels = solution.ocp.free.labels()
    return [{"name": f"bound.{labels[i]}", "points": 1, "multiplier": float(abs(lam[i])), "max_multiplier": float(abs(lam[i]))}
            for i in np.flatnonzero(solution.at_bound())]


def force_crush_table(case: Case, p: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """The loading curve from zero to just past the largest crush reached."""
    top = max(reach * 1.05, 1e-3)
    x = np.linspace(0.0, top, 201)
    return x, np.asarray(case.model.loading_curve.map(len(x))(x, p)).ravel()


def write_table(path: Path, columns: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(columns)
    rows = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    with path.open("w") as fh:
        fh.write(",".join(names) + "\n")
        for row in rows:
            fh.write(",".join(f"{v:.9g}" for v in row) + "\n")


def solution_summary(solution: Solution) -> dict:
    """result.json content of an identification or design solve."""
    case, res = solution.case, solution.result
    uncertainty = parameter_uncertainty(solution)
    tests = {}
    for ts, test in zip(solution.tests, case.tests):
        tests[ts.name] = {
            "speed_mps": test.speed,
            "loading_ends_s": ts.loading_end,
            "forward_check": _forward_check(solution, ts.name),
            "energy": solution.verification.energy[ts.name] if solution.verification else None,
            "metrics": {"model": response_metrics(ts), "data": data_metrics(test)},
            "fit": _fit(solution, ts),
        }
    return {
        "name": case.name,
        "kind": case.problem.kind,
        "status": solution.status,
        "solver": {
            "name": "ipopt",
            "return_status": res.return_status if res else None,
            "iterations": res.iterations if res else 0,
            "objective": res.objective if res else None,
            "wall_s": res.wall_s if res else None,
            "build_s": res.build_s if res else None,
        },
        "transcription": case.problem.transcription.model_dump(),
        "parameters": solution.parameters,
        **uncertainty,
        "tests": tests,
        "active_constraints": (active_constraints(solution) if res else []) + _bound_constraints(solution),
    }


def write_solution(solution: Solution, out: Path) -> dict:
    """result.json, per-test responses and figures, force-crush table and figure."""
    case = solution.case
    p = solution.full_parameters()
    summary = solution_summary(solution)
    reach = 0.0
    for ts, test in zip(solution.tests, case.tests):
        write_response_csv(out / ts.name / "response.csv", ts.times, ts.outputs)
        model = {k: (ts.times, ts.outputs[k]) for k, _, _ in plots.PANELS}
        plots.response_figure(out / ts.name / "fit.png", f"{case.name}: {ts.name}", model, data_curves(test))
        res = {
            r.channel: (ts.times[r.columns], ts.outputs[r.channel][r.columns] - r.data)
            for r in solution.residuals
            if r.test == ts.name
        }
        if res:
            plots.residual_figure(out / ts.name / "residuals.png", f"{case.name}: {ts.name} residuals", res)
        reach = max(reach, float(np.max(ts.outputs["crush"])))
    x, f = force_crush_table(case, p, reach)
    write_table(out / "force_crush.csv", {"crush_m": x, "spring_force_N": f})
    bps = p[case.layout.index("model.spring.crush_breakpoints")]
    inside = bps <= x[-1]
    values = np.asarray(case.model.loading_curve.map(int(inside.sum()))(bps[inside], p)).ravel()
    curves = {"identified loading curve": (x, f)}
    known = case.problem.reference.force_crush
    if known is not None:
        curves["reference"] = (np.asarray(known.crush), np.asarray(known.force))
    plots.force_crush_figure(out / "force_crush.png", curves, (bps[inside], values), case.name)
    write_json(out / "result.json", summary)
    return summary


def write_simulation(case: Case, responses: dict[str, Response], out: Path) -> dict:
    """response.csv, a figure and metrics for each simulated test."""
    summary = {"name": case.name, "tests": {}}
    for test in case.tests:
        r = responses[test.name]
        r.write_csv(out / test.name / "response.csv")
        model = {k: (r.time, r[k]) for k, _, _ in plots.PANELS}
        plots.response_figure(out / test.name / "response.png", f"{case.name}: {test.name}", model, data_curves(test))
        summary["tests"][test.name] = {"speed_mps": test.speed, "metrics": response_metrics(r)}
    write_json(out / "simulation.json", summary)
    return summary
