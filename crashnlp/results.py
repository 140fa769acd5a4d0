"""Result files: result.json, response and force-crush tables, figures, from a plain Result.

Everything here is SI inside and converted to report units (g, deg, ms) only as
it is written. Figures are drawn after the result files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from crashnlp import plots
from crashnlp.case import Case, TestCase
from crashnlp.data.signal import resample
from crashnlp.files import write_columns
from crashnlp.jsonfile import write_json
from crashnlp.metrics import crash_metrics
from crashnlp.outputs import COLUMNS
from crashnlp.result import Result
from crashnlp.simulation import Response, write_response_csv
from crashnlp.units import G0

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

    Max dynamic crush is the crash-test quantity, the CG's largest displacement, for data and
    model alike, so the two compare. A model also reports its largest front-end crush
    (`max_front_end_crush_m`, the `crush` output along the crush force's line of action: what a
    crush bound limits); the two differ by the pitch and the geometry.
    """
    m = crash_metrics(t, accel, velocity, displacement)
    out = {
        "max_crush_m": m.max_crush,
        "time_max_crush_s": m.t_max_crush,
        "max_front_end_crush_m": float(np.max(crush)) if crush is not None else None,
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


def response_metrics(r: Response) -> dict:
    y = r.outputs
    return metrics(r.time, y["accel"], y["velocity"], y["displacement"], y["pitch"], y.get("crush"))


def read_response(path: Path) -> Response:
    """A response.csv back in SI (the registry's written outputs)."""
    table = np.genfromtxt(path, delimiter=",", names=True)
    outputs = {o.name: table[o.column] / o.factor for o in COLUMNS}
    return Response(np.asarray(table["time_s"]), outputs, np.zeros((0, table.size)))


def write_result(result: Result, out: Path, figures: bool = True) -> None:
    """result.json, per-test responses, the force-crush table, and the figures after them."""
    for name, t in result.tests.items():
        write_response_csv(out / name / "response.csv", t.response.time, t.response.outputs)
    fc = result.force_crush
    if fc is not None:
        write_columns(out / "force_crush.csv", {"crush_m": fc.crush, "spring_force_N": fc.force})
    write_json(out / "result.json", result.to_json())
    if figures:
        write_figures(result, out)


def write_figures(result: Result, out: Path) -> None:
    """Fit and residual figures per test, and the force-crush figure."""
    for name, t in result.tests.items():
        model = {k: (t.response.time, t.response[k]) for k in plots.PANELS}
        plots.response_figure(out / name / "fit.png", f"{result.name}: {name}", model, t.data)
        residuals = {c: (f.times, f.model - f.data) for c, f in t.fit.items()}
        if residuals:
            plots.residual_figure(out / name / "residuals.png", f"{result.name}: {name} residuals", residuals)
    fc = result.force_crush
    if fc is not None:
        curves = {"identified loading curve": (fc.crush, fc.force)}
        if fc.reference is not None:
            curves["reference"] = fc.reference
        plots.force_crush_figure(out / "force_crush.png", curves, (fc.breakpoints, fc.values), result.name)


def write_simulation(case: Case, responses: dict[str, Response], out: Path, figures: bool = True) -> dict:
    """response.csv, a figure and metrics for each simulated test."""
    summary: dict[str, Any] = {"name": case.name, "tests": {}}
    for test in case.tests:
        r = responses[test.name]
        r.write_csv(out / test.name / "response.csv")
        summary["tests"][test.name] = {"speed_mps": test.speed, "metrics": response_metrics(r)}
    write_json(out / "simulation.json", summary)
    if figures:
        for test in case.tests:
            r = responses[test.name]
            model = {k: (r.time, r[k]) for k in plots.PANELS}
            plots.response_figure(out / test.name / "response.png", f"{case.name}: {test.name}", model, data_curves(test))
    return summary
