"""Shared builders for test problems (plain dicts, so each test states what it changes) and checks."""

from __future__ import annotations

import copy
import csv
import os
import signal
import sys
from pathlib import Path

import numpy as np
import yaml

from crashnlp.case.case import Case
from crashnlp.problem import problem_from_dict

ROOT = Path(__file__).resolve().parents[1]

BASE = {
    "name": "unit",
    "vehicle": {
        "mass": "2550 kg",
        "speed": "56 km/h",
        "pitch_inertia": "4800 kg*m^2",
        "cg_to_impact": "2.45 m",
        "cg_above_impact": "0.18 m",
        "cg_to_front_axle": "1.55 m",
        "cg_to_rear_axle": "2.10 m",
        "suspension": {"k_front": "70 kN/m", "k_rear": "60 kN/m", "c_front": "8 kN*s/m", "c_rear": "8 kN*s/m"},
        "crush_offset": "0.1 m",
    },
    "model": {
        "spring": {
            "law": "force",
            "crush_breakpoints": [0, 0.05, 0.15, 0.25, 0.4, 0.55, 0.7, 0.85],
            "values": ["0 kN", "300 kN", "450 kN", "380 kN", "520 kN", "700 kN", "950 kN", "1500 kN"],
        },
        "damper": {"rate_breakpoints": [0, 16], "values": ["5 kN*s/m", "5 kN*s/m"]},
        "unloading": {"law": "plastic", "stiffness": "30 MN/m"},
    },
    "tests": [{"name": "t56", "duration": "0.2 s"}],
}


def merge(base: dict, changes: dict) -> dict:
    """Deep-merge `changes` into a copy of `base`; None deletes a key."""
    out = copy.deepcopy(base)
    for key, value in changes.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def small_pickup_problem(folder: Path) -> Path:
    """A short fit of the shipped pickup data (60 ms, 40 intervals): two spring values and the
    crush offset, written as a problem file into `folder`."""
    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    raw["tests"][0]["data"]["window"] = ["0 s", "0.06 s"]
    raw["model"]["spring"] = {"law": "force", "crush_breakpoints": [0, 0.25, 0.6], "values": ["0 kN", "400 kN", "500 kN"]}
    raw["estimate"] = {"model.spring.values": {"bounds": [0, "3 MN"]}, "vehicle.crush_offset": {"bounds": [-0.3, 0.5]}}
    raw.pop("reference")
    raw["transcription"] = {"method": "multiple-shooting", "intervals": 40, "substeps": 2}
    path = folder / "small.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def write_channels(path: Path, r, names: tuple[str, str, str, str] = ("accel_g", "vel_mps", "disp_m", "pitch_deg")) -> None:
    """A simulated response `r` written as a test's CSV: time, then acceleration (g), velocity,
    displacement and pitch (deg) under the column `names`."""
    columns = {"time_s": r.time, names[0]: r["accel"] / 9.80665, names[1]: r["velocity"]}
    columns |= {names[2]: r["displacement"], names[3]: np.degrees(r["pitch"])}
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows([list(columns), *zip(*columns.values())])


def make_case(changes: dict | None = None, base_dir: Path = ROOT / "problems") -> Case:
    return Case(problem_from_dict(merge(BASE, changes or {}), base_dir))


def assert_monotone_crush(ts) -> None:
    """At every grid point: the crush rises to its largest value, then only falls while in contact."""
    crush, peak = ts.outputs["crush"], int(np.argmax(ts.outputs["crush"]))
    assert np.all(np.diff(crush[: peak + 1]) >= -1e-4)  # MONOTONE_TOLERANCE
    contact = ts.outputs["contact_force"][peak:] > 0
    assert np.all(np.diff(crush[peak:])[contact[1:]] <= 1e-4)


def assert_exact_hessian_is_casadis(nlp, z: np.ndarray, lam_f: float, seed: int) -> None:
    """The structured exact Hessian of an NLP (crashnlp.numerics.derivatives) against CasADi's own Hessian
    of the whole Lagrangian, at z with random constraint multipliers (every constraint's
    curvature counts): the same values, and a pattern that holds every nonzero CasADi finds."""
    import casadi as ca

    p, values = nlp.problem(), nlp.bounds()["p"]
    ng = p["g"].numel()
    lam_g = np.random.default_rng(seed).standard_normal(ng)
    H = nlp.derivatives().hessian(p["f"], p["g"])(z, values, lam_f, lam_g)
    lf, lg = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ng)
    lagrangian = ca.hessian(lf * p["f"] + ca.dot(lg, p["g"]), p["x"])[0]
    reference = ca.Function("ref", [p["x"], p["p"], lf, lg], [ca.triu(lagrangian)])
    expected = reference(z, values, lam_f, lam_g).full()
    assert np.abs(expected).max() > 0
    assert np.max(np.abs(H.full() - expected)) <= 1e-9 * np.abs(expected).max()
    assert set(zip(*reference.sparsity_out(0).get_triplet())) <= set(zip(*H.sparsity().get_triplet()))


def parents() -> dict[int, int]:
    """Every process's parent, from /proc (Linux)."""
    found: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            found[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    return found


def command(pid: int) -> str:
    """A process's command line, from /proc (Linux); empty for one that has ended."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def descendants(pid: int) -> set[int]:
    """Every process below `pid`, from /proc (Linux)."""
    parent = parents()
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier} - found
        found |= frontier
    return found


def die_once(marker: str) -> int:
    """A task whose worker is killed (SIGKILL) the first time it runs, as by the kernel's OOM
    killer or a user's kill; `marker` is the file that remembers it ran. Returns the pid."""
    path = Path(marker)
    if not path.exists():
        path.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


def die_always(tally: str) -> int:
    """A task whose worker is killed every time it runs; each run adds a line to the file `tally`."""
    with open(tally, "a") as fh:
        fh.write("ran\n")
    os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


def worker_pid(_) -> int:
    """A task that says which process ran it."""
    return os.getpid()


def worker_state() -> tuple[bool, bool]:
    """Whether this worker has the solver stack loaded, and ignores SIGINT."""
    return "crashnlp.optimize.pipeline" in sys.modules, signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def _linear(x: np.ndarray, bps: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """The piecewise-linear curve through (bps, vals), its end segments continued."""
    i = np.clip(np.searchsorted(bps, x) - 1, 0, len(bps) - 2)
    return vals[i] + (vals[i + 1] - vals[i]) / (bps[i + 1] - bps[i]) * (x - bps[i])


def assert_contact_force_is_the_front_ends(case: Case, r, p: np.ndarray) -> None:
    """The contact force of response `r` (test parameters `p`) at every point, against the
    front-end law written here again in numpy:

    - zero, exactly, wherever the crush is negative (the vehicle has left the barrier);
    - wherever the damper is engaged (crush past the smoothing width), max(spring + damper, 0):
      zero exactly where the unloading spring and the rebounding damper pull, the sum
      otherwise. The spring is the loading curve, or for plastic unloading the smaller of it
      and the unloading line from the largest crush (the history state). The smoothed hinges
      depart from the exact kinks by at most eps / 2 times each slope change, the smoothed
      switch to unloading by 0.05 eps times the unloading stiffness;
    - the force the dynamics feel: the power the vehicle loses to the barrier is the contact
      force times the crush rate.
    """
    value = {path: np.asarray(p[s], dtype=float) for path, s in case.layout.slices().items()}
    spec = case.problem.model
    crush, rate, force, x_max = r["crush"], r["crush_rate"], r["contact_force"], r.states[case.model.nx - 1]
    peak = np.max(np.abs(force))
    assert peak > 0, "the front end never touched the barrier"
    separated = crush < 0
    assert np.all(force[separated] == 0), np.max(np.abs(force[separated]))
    np.testing.assert_allclose(r["barrier_power"], force * rate, rtol=0, atol=1e-9 * np.max(np.abs(force * rate)))

    eps = spec.smoothing.crush
    bps, vals = value["model.spring.crush_breakpoints"], value["model.spring.values"]
    slopes = np.diff(vals) / np.diff(bps)

    def load(x):
        return _linear(x, bps, vals) * (x if spec.spring.law == "secant" else 1)  # secant: F = k(x) x

    spring, tolerance = load(crush), 0.5 * eps * np.sum(np.abs(np.diff(slopes))) * (bps[-1] if spec.spring.law == "secant" else 1)
    if spec.unloading.law == "plastic":
        stiffness = value["model.unloading.stiffness"][0]
        spring = np.minimum(spring, load(x_max) - stiffness * (x_max - crush))
        tolerance += 0.05 * eps * stiffness
    damper = 0.0
    if spec.damper is not None:
        damper = _linear(np.abs(rate), value["model.damper.rate_breakpoints"], value["model.damper.values"]) * rate
    expected = np.maximum(spring + damper, 0)
    engaged = crush > eps
    loading = engaged & (rate > 0.1) & (x_max - crush < 1e-6)
    assert np.count_nonzero(loading) >= 5, "no point of the response is loading"
    error = np.abs(force - expected)[engaged]
    assert np.max(error) <= tolerance + 1e-6 * peak, (np.max(error), tolerance)
