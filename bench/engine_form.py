"""The engine-on-mounts form on the corpus's engine vehicles, against the pendulum and the rigid body.

Each vehicle (bench.corpus.engine_vehicle, built for 56 km/h, and tall_engine_vehicle, built for
60 km/h) is fitted from the minimal problem `crashnlp init` would write (bench.cross_speed.fit_problem,
model.form set, nothing else: the engine's entries are the form's defaults from the data) at
56 km/h alone, and at 40 + 64 km/h with 56 km/h predicted (bench.forms.judge). Per fit: IPOPT's
status and iterations, the fitted pitch RMSE, and the prediction's max displacement, peak and stop
against the generator's. Not a `make bench` section yet; run as

    python -m bench.engine_form engine 3200 0,1,2,3 engine-on-mounts,rigid-body,pendulum
    python -m bench.engine_form tall 2062 0,1,2 engine-on-mounts

one JSON line per fit on stdout (CHANGELOG.md, Unreleased, quotes a run).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import crashnlp
from bench.corpus import Vehicle, engine_vehicle, tall_engine_vehicle
from bench.cross_speed import fit_problem
from bench.forms import judge, with_form

KINDS = {"engine": (engine_vehicle, 56.0), "tall": (tall_engine_vehicle, 60.0)}  # maker, built-for speed (km/h)
KEPT = ("vehicle", "form", "status", "iterations", "pitch_rmse_deg", "displacement_rel", "peak_rel", "stop_err_s", "lift_off_s")


def one_speed(v: Vehicle, form: str, folder: Path) -> dict:
    """The vehicle fitted at 56 km/h alone with `form`: status, iterations, pitch RMSE (deg)."""
    path = with_form(fit_problem(v, (56.0,), folder), form)
    t0 = time.perf_counter()
    result = crashnlp.identify(path)
    pitch = result.identified.channel_rmse.get("pitch") if result.ok else None
    return {
        "vehicle": v.name,
        "form": form,
        "fitted": "56",
        "status": result.status,
        "iterations": result.solver.iterations,
        "wall_s": time.perf_counter() - t0,
        "pitch_rmse_deg": None if pitch is None else float(np.degrees(pitch)),
    }


def rows(kind: str, seed: int, indices: list[int], forms: list[str]) -> list[dict]:
    """Every vehicle and form: the 56 km/h fit, and the 40 + 64 km/h fit predicting 56 km/h."""
    make, built = KINDS[kind]
    out = []
    for i in indices:
        v = make(i, seed, speed=built / 3.6)
        for form in forms:
            with tempfile.TemporaryDirectory(prefix="crashnlp-engine-form-") as tmp:
                out.append({"seed": seed, **one_speed(v, form, Path(tmp))})
                print(json.dumps(out[-1]), flush=True)
                row = judge(v, form, "interpolation", Path(tmp))
                out.append({"seed": seed, "fitted": "40+64", **{k: row.get(k) for k in KEPT}})
                print(json.dumps(out[-1]), flush=True)
    return out


if __name__ == "__main__":
    rows(sys.argv[1], int(sys.argv[2]), [int(i) for i in sys.argv[3].split(",")], sys.argv[4].split(","))
