"""Every optimum checked by the forward simulator, with the energy audit it gives.

The NLP integrates the model by its transcription; the separate CVODES
integrator simulates the same model at the optimum. Where the two disagree by
more than a tenth of a channel's fit scale and more than half a percent of the
channel's largest value somewhere, the NLP's trajectory is not the model's, and
the solve is not `ok`. Where the data stop (velocity
crosses zero) but the model neither does within the window nor ends its crash
by letting go of the barrier while it moves on slowly, the fit misses the test's
defining event and is not `ok` either; so is a design whose vehicle does not stop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crashnlp.analysis.energy import energy_audit
from crashnlp.analysis.summary import loading_end
from crashnlp.case.case import Case
from crashnlp.models.simulation import simulate
from crashnlp.optimize.fit import DEFAULT_SIGMA
from crashnlp.problem.schema import CollocationSpec
from crashnlp.results.response import APPROACH

CHECKED = ("displacement", "velocity", "pitch", "crush")  # states; the acceleration jumps at separation
# what a check compares: the output itself, but for the crush the shortening of the front end's line
# of action, a function of the states alone (the crush stays at the permanent set past separation)
COMPARED = {"crush": APPROACH}
SCALE = {**DEFAULT_SIGMA, "crush": DEFAULT_SIGMA["displacement"]}
TOLERANCE = 0.1  # of a channel's fit scale...
RELATIVE_TOLERANCE = 0.005  # ...or of its largest value, whichever is larger
ENERGY_TOLERANCE = 5e-3  # of the impact energy


@dataclass
class Verification:
    mismatch: dict[str, dict[str, float]]  # test -> output -> max |simulated - NLP| (SI)
    allowed: dict[str, dict[str, float]]  # test -> output -> the tolerance (SI)
    energy: dict[str, dict[str, float]]  # test -> energy audit (J)
    problem: str | None  # why the solve is not ok, if it is not

    def worst(self, test: str) -> float:
        """Largest mismatch of a test relative to its tolerance (above 1 fails)."""
        return max(v / self.allowed[test][k] for k, v in self.mismatch[test].items())

    @property
    def departs(self) -> bool:
        """Whether the forward simulation of some test departs from the NLP beyond its tolerance."""
        return any(self.worst(test) > 1 for test in self.mismatch)


def _stops(test, time: np.ndarray, outputs: dict[str, np.ndarray], designed: bool) -> str | None:
    """Why the model misses the data's stop, if it does: its velocity never reaches zero, nor does
    its loading end as it lets go of the barrier moving on slowly (loading_end). A design
    (`designed`), which has no data, must stop its vehicle so within the window: one that goes on
    meets no crash goal (a crush bound given in mm read as m let the vehicle through the barrier)."""
    velocity = test.data.channels.get("velocity") if test.data is not None else None
    data_stop = velocity is not None and np.any(velocity.values <= 0)
    if not (data_stop or designed):
        return None
    ended = loading_end(time, outputs["accel"], outputs["velocity"], outputs.get("barrier_force"))
    if np.any(outputs["velocity"] <= 0) or ended is not None:
        return None
    if velocity is not None and data_stop:
        t = float(velocity.time[np.argmax(velocity.values <= 0)])
        return f"{test.name}: the model does not stop within the window (the data stop at {t * 1e3:.1f} ms)"
    return (
        f"{test.name}: the designed vehicle does not stop within the window (it still moves toward the barrier at "
        f"{float(outputs['velocity'][-1]):.3g} m/s at {float(time[-1]) * 1e3:.1f} ms): a design that does not stop "
        "its vehicle meets no crash goal"
    )


def _coarse(case: Case) -> str:
    """What a collocation whose optimum the forward simulation departs from can change: its grid
    is too coarse for the check. Radau of degree 1 (implicit Euler, first order) misses the
    pickup's crush by 51 times the tolerance on 100 intervals, halving with each doubling, and
    passes only at 6400; degree 3 passes at 50. Multiple shooting refines its steps itself
    (crashnlp.optimize.identify)."""
    spec = case.problem.transcription
    if not isinstance(spec, CollocationSpec):
        return ""
    return (
        f": collocation of degree {spec.degree} on {spec.intervals} intervals is too coarse for it,"
        " give more intervals or a higher degree"
    )


def verify(case: Case, p: np.ndarray, tests) -> Verification:
    """Forward-simulate every test at parameters p on its NLP grid and compare."""
    mismatch, allowed, energy, problems = {}, {}, {}, []
    for ts, test in zip(tests, case.tests):
        pt = case.test_parameters(test, p)
        sim = simulate(case.model, pt, test.speed, ts.time, case.problem.simulation)
        pairs = {k: (sim[COMPARED.get(k, k)], ts[COMPARED.get(k, k)]) for k in CHECKED}
        mismatch[test.name] = {k: float(np.max(np.abs(a - b))) for k, (a, b) in pairs.items()}
        allowed[test.name] = {
            k: max(TOLERANCE * SCALE[k], RELATIVE_TOLERANCE * float(np.max(np.abs(a)))) for k, (a, _) in pairs.items()
        }
        mass = float(pt[case.layout.index("vehicle.mass")][0])
        energy[test.name] = energy_audit(sim, mass, test.speed)
        if not np.all(np.isfinite(sim["velocity"])):
            problems.append(f"{test.name}: the forward simulation failed")
            continue
        worst = max(mismatch[test.name], key=lambda k: mismatch[test.name][k] / allowed[test.name][k])
        if mismatch[test.name][worst] > allowed[test.name][worst]:
            problems.append(
                f"{test.name}: the forward simulation departs from the NLP "
                f"({worst} by {mismatch[test.name][worst]:.3g} SI{_coarse(case)})"
            )
        if abs(energy[test.name]["balance_error_relative"]) > ENERGY_TOLERANCE:
            problems.append(f"{test.name}: the energy balance misses by {energy[test.name]['balance_error_relative']:.2%}")
        stop = _stops(test, ts.time, ts.outputs, case.problem.kind == "design")
        if stop:
            problems.append(stop)
    return Verification(mismatch, allowed, energy, "; ".join(problems) or None)
