"""Predictions: an identified vehicle simulated at new speeds, masses or durations, with 95 % intervals.

Each crash metric's interval adds, in quadrature, 95 % half-widths of (crashnlp.results.simulation.IntervalParts):

- the parameters: their covariance (the fit's sandwich, with the smoothness prior as the
  information it adds) pushed through the output's sensitivities, taken as central
  differences of the forward simulation over one standard error each way (one-sided at a
  bound), so a metric that bends within that span is not linearised at a point;
- the model's form: its miss on the fitted tests (each metric's relative miss, root mean square
  over the tests, scaled to the predicted value, and the RMSE of the curve the metric is read
  from), and the out-of-sample term calibrated on held-out predictions of a corpus of vehicles
  of five generator forms, one table per model form (crashnlp.analysis.calibration): the fit
  tunes the metrics of the tests it was fitted at, so their miss there understates the miss at
  another speed or mass. The calibrated
  term grows with the distance in impact energy from the nearest fitted test (to a power the
  calibration sets per metric), and is zero at a fitted test's own;
- the force past the crush the model reached in the fitted tests, which no test measured: the
  identified loading curve follows its trend there (crashnlp.models.tail), and how well that
  rule predicts is measured on the identified curve itself, breakpoint by breakpoint over the
  reach's second half (`trend_misses`). That miss of the force, grown in proportion to the distance past
  the reach over the breakpoint spacing, moves the max displacement (by the energy it adds or takes),
  the stop with it, and the peak deceleration where the peak lies past the reach. That is a
  rule's guess, so the calibrated q scales it as it scales the form term; a peak the force past
  the reach raises beyond the predicted one is the calibrated form term's to cover.

Each interval reports its parts, and the dominant one; an interval the force past the reach
dominates says so in a note. The response bands are pointwise 95 %: at each instant the
parameters' half-width of the curve, and the non-parameter half-width of the metric read from
that curve (the peak deceleration for the acceleration and the barrier force, the max displacement for
displacement and crush, the rebound for the velocity, the max pitch for the pitch) in proportion
to how far the curve has moved from what the model knows exactly (zero force, the initial
state): so the band at a metric's instant is that metric's interval, and there is no band after
the vehicle has left the barrier or at t = 0. Intervals and bands are cut to what is physically
certain (crashnlp.analysis.limits), with a note for each interval cut.

A simulated test that ends mid-crash, before its vehicle stops and while it still decelerates
(crashnlp.analysis.summary.MID_CRASH), gives no metric its record does not hold (no max
displacement, stop, peak deceleration, rebound or max pitch), nor their intervals or the bands
scaled to them, and a note says where it ends and how fast it still moves; one that ends drifting
on after the pulse says so, gives no velocity change, rebound or max pitch (the vehicle meets the
barrier again: UNSETTLED), and its max displacement is its travel at the end. A metric whose fitted
tests' records end before it (the same rule) has no miss of the fit's own: where the curve it is
read from was fitted, its interval holds the curves' miss and the calibrated form term, and a note
says so. A metric or curve that no fitted test measured (pitch, without a pitch channel) gets no
interval, nor does anything when an estimated value is not determined by the data: the prediction
says so in `notes`, instead of a band that only looks narrow.

The predicted tests are crashnlp.results.simulation's `PredictedTest`s, and its `write_simulation`
writes what `crashnlp simulate` writes of them; `simulation_figure_jobs` are their figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.analysis.calibration import SAME_ENERGY, Calibration, reach, shipped
from crashnlp.analysis.limits import limited_band, limited_interval
from crashnlp.analysis.metrics import DRIFT, lift_off, zero_crossing
from crashnlp.analysis.summary import (
    accel_filter,
    accel_spec,
    as_recorded,
    data_curves,
    goes_on,
    let_go_words,
    pitch_rises_at_end,
    response_metrics,
)
from crashnlp.base.errors import InputError
from crashnlp.base.outputs import METRIC, METRICS, OUTPUT, PANELS, PREDICTED_KEYS, UNFINISHED, UNSETTLED, Z95, named_test
from crashnlp.base.units import G0, UnitError, to_si
from crashnlp.case.case import Case, TestCase
from crashnlp.models.tail import spacing, tail_start, trend_misses
from crashnlp.problem import Problem
from crashnlp.results.identified import UNLOADING_STIFFNESS, IdentifiedModel, applied, shaping_nothing_short_of, without_entries
from crashnlp.results.response import RESPONSE_FIGURE, Response
from crashnlp.results.result import Result, unconverged_mark
from crashnlp.results.simulation import IntervalParts, PredictedTest

if TYPE_CHECKING:
    from crashnlp.results.plots import Job  # not at run time: matplotlib

# the fitted channels that determine the CG's motion, and with it every metric but the pitch
MOTION = ("accel", "velocity", "displacement")
# response columns and the metric whose non-parameter half-width their band carries: each channel
# a metric is one instant of (Metric.extreme), and the outputs that move with one of those channels
# (the front end's crush with the CG's travel, the barrier force with the deceleration)
_AT_EXTREME = {str(m.channel): m.key for m in METRICS if m.extreme}
MOVES_WITH = {"crush": "displacement", "barrier_force": "accel"}
BAND_METRIC = _AT_EXTREME | {name: _AT_EXTREME[channel] for name, channel in MOVES_WITH.items()}


def own_tests(result: Result, source: str) -> Problem:
    """The problem a result's own tests make, with its identified vehicle (crashnlp.results.identified):
    each test at its speed over its fitted window, at the identified vehicle's mass; what
    `crashnlp simulate RESULT_DIR/result.json` simulates. InputError for a result without an
    identified model."""
    if result.identified is None:
        raise InputError(
            f"{source}: identified_model: none (a design's or a hand-written result); give a problem file and --params"
        )
    tests = [{"name": name, "speed": t.speed, "duration": float(t.response.time[-1])} for name, t in result.tests.items()]
    return applied({"name": result.name, "tests": tests}, Path("."), result.identified, source, source)


MAX_STEPS = 1_000_000  # output steps a simulation may ask for
# output steps each test needs: its metrics are read from the samples (a peak at one, a stop or the
# OLC's instants between two); two fits' predictions at 50 steps are within 4.2 % of those at 5000,
# at 20 the peak deceleration is 5 % off, at 5 several metrics 3 to 23 % (docs/design-notes.md)
MIN_STEPS = 50


def output_step(dt: float | str | None, name: str = "dt") -> float | None:
    """An output step given outside a problem file (`crashnlp.simulate(dt=...)`, `--dt`; called
    `name` in its errors): "0.1 ms", or a number, or a number written as text, in s; in SI and
    refused where it is not a positive number of seconds (check_steps), one line naming `name`."""
    if dt is None:
        return None
    try:
        step = to_si(dt, "s")
    except UnitError as exc:
        raise InputError(f"{name} {dt}: {exc}") from None
    check_steps(None, step, name)
    return step


def check_steps(case: Case | None, dt: float | None, name: str = "dt", source: str = "simulate") -> None:
    """Refuse an output step `dt` (called `name` where the user gave it) that is not a positive
    number of seconds, or a simulation of `case` (with `dt`, or the problem's simulation.dt from
    `source`) that asks for more than MAX_STEPS output steps, or for fewer than MIN_STEPS over a
    test. No case: `dt` alone."""
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise InputError(f"{name} {dt:g}: must be a positive number of seconds")
    if case is None:
        return
    longest, shortest = max(t.duration for t in case.tests), min(t.duration for t in case.tests)
    step, where = (dt, name) if dt is not None else (case.problem.simulation.dt, f"{source}: simulation.dt")
    if longest / step > MAX_STEPS:
        raise InputError(f"{where} {step:g} s: more than {MAX_STEPS:,} output steps over {longest:g} s (tests' duration)")
    if shortest / step < MIN_STEPS:
        raise InputError(
            f"{where} {step:g} s: {shortest / step:.3g} output steps over {shortest:g} s (the shortest test's duration); "
            f"a prediction reads its metrics from {MIN_STEPS} or more (a step of at most {shortest / MIN_STEPS:g} s)"
        )


def predict(
    case: Case,
    identified: IdentifiedModel | None = None,
    dt: float | None = None,
    calibration: Calibration | None = None,
    status: str = "ok",
) -> dict[str, PredictedTest]:
    """Every test of `case` simulated (`case` built from a problem the identified model was
    applied to, crashnlp.results.identified.apply); with `identified`, intervals and extrapolation too,
    their form terms from `calibration` (by default the shipped table of the problem's model
    form). A fit whose `status` is not ok (it did not converge) gives its values simulated as they
    are, without intervals or bands: its covariance and its misses are not a converged fit's; a
    note says so. A test's data come with it only where it runs at the speed, mass and duration they
    were recorded at (TestCase.other_conditions); otherwise a note says which test and why. A `dt` that is not a
    positive step, or too many steps, is refused (check_steps), as is, in a problem simulated with
    its own values (no `identified`), an engine or a crush offset the model form does not read
    (Case.refuse_unread_given; a fit's vehicle is simulated as it was fitted)."""
    check_steps(case, dt)
    if identified is None:
        case.refuse_unread_given()
    out = {}
    for test in case.tests:
        p = case.test_parameters(test)
        cfc = read_through(test, identified)
        response = _simulated(case, test, p, dt, cfc)
        metrics = response_metrics(response)
        mass = float(p[case.layout.index("vehicle.mass")][0])
        other = test.other_conditions(mass)
        data = data_curves(test) if other is None else {}
        first = (other,) if other is not None else ()
        drift = ending_notes(test.name, response, metrics)
        if identified is None:
            out[test.name] = PredictedTest(test.name, test.speed, mass, response, metrics, notes=first + drift, data=data)
            continue
        beyond = identified.range.beyond(float(np.max(response["displacement"])), test.speed, mass)
        chosen = calibration or shipped(case.problem.model.form)
        if chosen is None or status != "ok":
            note = uncalibrated(test.name, case.problem.model.form) if status == "ok" else unconverged(test.name, status)
            none: dict[str, tuple[float, float] | None] = {k: None for k in PREDICTED_KEYS}
            notes = first + drift + (note,)
            out[test.name] = PredictedTest(test.name, test.speed, mass, response, metrics, none, {}, beyond, notes, data)
            continue
        u = _uncertainty(case, test, p, mass, response, metrics, identified, dt, chosen, cfc)
        out[test.name] = PredictedTest(
            test.name,
            test.speed,
            mass,
            response,
            metrics,
            u.intervals,
            u.bands,
            beyond,
            first + drift + u.notes,
            data,
            u.parts,
            u.q,
            chosen.named(),
        )
    return out


def _simulated(case: Case, test: TestCase, p: np.ndarray, dt: float | None, cfc: str | None) -> Response:
    """A test simulated at the full parameters `p`, its acceleration read through CFC class `cfc`."""
    return as_recorded(case.simulate_test(test, p, dt), cfc)


def read_through(test: TestCase, identified: IdentifiedModel | None) -> str | None:
    """The CFC class a prediction reads its acceleration through: its own test's accelerometers'
    where its problem names accel data, else the fitted tests' (IdentifiedModel.accel_filter), so
    that a predicted peak is the kind of peak the fit reports, at the fitted tests' own conditions
    the same number; None: the model's own acceleration."""
    if accel_spec(test) is not None or identified is None:
        return accel_filter(test)
    return identified.accel_filter


def uncalibrated(name: str, form: str) -> str:
    """The note of a prediction whose model form has no calibration table: no intervals, and why."""
    return (
        f"{name}: no intervals: model form {form} has no calibration table (crashnlp/analysis/calibration.json, "
        "make calibrate), and another form's misses are not its own"
    )


def ending_notes(name: str, response: Response, metrics: dict[str, float | None]) -> tuple[str, ...]:
    """The notes on how a simulated test ends: a crash whose loading ends as the vehicle lets go of
    the barrier while it moves on slowly (crashnlp.analysis.summary.let_go_words), else a drift
    without contact whose travel at the end is its max displacement (`_drift`), or a front end
    that lets go while the CG moves on (`_let_go`); and where it ends still moving, what its record
    does not give (`_moving`); a pitch still rising at its end (`_pitch_rising`)."""
    words = let_go_words(response)
    if words is not None:
        first: tuple[str, ...] = (f"{name}: the vehicle {words}",)
    else:
        first = (_drift(name, response) if metrics.get("max_displacement_m") is not None else ()) or _let_go(name, response)
    return first + _moving(name, metrics) + _pitch_rising(name, response, metrics)


def _pitch_rising(name: str, response: Response, metrics: dict[str, float | None]) -> tuple[str, ...]:
    """A note when the pitch is largest at the simulation's last instant: the max pitch it gives
    is the record's, and the crash's comes later (a body on its suspension pitches for a few
    hundred ms); a longer duration reaches it."""
    end = pitch_rises_at_end(response.time, response["pitch"]) if metrics.get("max_pitch_deg") is not None else None
    if end is None:
        return ()
    return (
        f"{name}: the pitch still rises as the simulation ends at {end * 1e3:.1f} ms: its max pitch is "
        "the record's, and the crash's comes later (a longer duration reaches it)",
    )


def _moving(name: str, metrics: dict[str, float | None]) -> tuple[str, ...]:
    """A note when the simulation ends before its crash does (crashnlp.analysis.summary.goes_on):
    which metrics it does not give, where it ends and how fast the vehicle still moves there."""
    words = goes_on(metrics)
    return (f"{name}: the simulation {words}",) if words else ()


def _drift(name: str, response: Response) -> tuple[str, ...]:
    """A note when the vehicle ends its record still moving toward the barrier without touching
    it: the model's pitch lifted its front end off (crashnlp.analysis.metrics.lift_off), and its
    max displacement is its travel at the end, not where it stopped."""
    velocity, contact = float(response["velocity"][-1]), float(response["contact_force"][-1])
    if velocity <= DRIFT or contact > 0:
        return ()
    return (
        f"{name}: the vehicle drifts on without contact (its pitch lifted the front end off): its max displacement "
        "is its travel at the end of the record, not a stop",
    )


def _let_go(name: str, response: Response) -> tuple[str, ...]:
    """A note when the front end lets go of the barrier while the CG still moves toward it, however
    slowly (crashnlp.analysis.metrics.lift_off): what the response does from then on is the pitch's,
    not the structure's. A creep of a few cm/s matters most: the time of zero velocity is then when
    the creep ends, tens of ms after the structure let go."""
    t = lift_off(response.time, response["velocity"], response["contact_force"], faster_than=0.0)
    if t is None:
        return ()
    v = float(np.interp(t, response.time, response["velocity"]))
    stop = zero_crossing(response.time, response["velocity"])
    drift = f"; its time of zero velocity ({stop * 1e3:.1f} ms) is when that drift ends" if stop > t else ""
    return (
        f"{name}: the front end lets go of the barrier at {t * 1e3:.1f} ms while the CG still moves toward it at "
        f"{v:.3f} m/s (its pitch lifted it off): its crush and stop from then on are the pitch's{drift}",
    )


@dataclass(frozen=True)
class Uncertainty:
    """A predicted test's intervals, their parts and form q, its bands and notes."""

    intervals: dict[str, tuple[float, float] | None]
    parts: dict[str, IntervalParts] = field(default_factory=dict)
    q: dict[str, float] = field(default_factory=dict)
    bands: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def _uncertainty(
    case: Case,
    test: TestCase,
    p: np.ndarray,
    mass: float,
    response: Response,
    metrics: dict[str, float | None],
    identified: IdentifiedModel,
    dt: float | None,
    calibration: Calibration,
    cfc: str | None,
) -> Uncertainty:
    """95 % intervals of the metrics and bands of the response columns (module docstring), the
    acceleration read through CFC class `cfc` as the response's is."""
    std, unused = identified.std(), _left_out(case, identified, response)
    unseen = ", ".join(label for label, s, out in zip(identified.labels, std, unused) if out and not np.isfinite(s))
    # an unloading line no fitted test went along shapes nothing up to the stop: left out of every
    # interval, it withholds those of the metrics read after the stop (UNSETTLED)
    unloading = np.array([label == UNLOADING_STIFFNESS and not np.isfinite(s) for label, s in zip(identified.labels, std)])
    unused = unused | unloading
    undetermined = [label for label, s, out in zip(identified.labels, std, unused) if not (np.isfinite(s) or out)]
    if undetermined:
        why = (
            "a design's values are chosen for its goal, fitted to no data, so nothing measures how uncertain they are"
            if identified.designed
            else f"the data do not determine {', '.join(undetermined)}"
        )
        return Uncertainty({k: None for k in PREDICTED_KEYS}, notes=(f"{test.name}: no intervals: {why}",))
    notes = [f"{test.name}: {unseen}, which the data do not determine, shape no force it goes through"] if unseen else []
    gm, gy = _sensitivities(case, test, p, identified, np.where(unused, 0.0, std), dt, cfc, metrics)
    cov = without_entries(identified.covariance, unused) if identified.covariance is not None else np.zeros((len(std), len(std)))
    past = past_the_reach(case, p, response, identified, mass, metrics)
    klass, distance = reach(identified.range, test.speed, mass)
    notes += _uncalibrated_distance(test.name, klass, distance, calibration)
    intervals: dict[str, tuple[float, float] | None] = {}
    parts, qs = {}, {}
    for i, key in enumerate(PREDICTED_KEYS):
        value, (miss, unreached) = metrics.get(key), _fitted_miss(identified, key)
        q = calibration.q(klass, key) if distance > 0 else 0.0
        intervals[key] = None
        if unloading.any() and key in UNSETTLED:
            why = f"the data do not determine {UNLOADING_STIFFNESS}, which it goes through"
            notes.append(f"{test.name}: no interval for {METRIC[key].label}: {why}")
            continue
        if miss is None or value is None or not np.isfinite(value):
            if value is None and key in UNFINISHED and goes_on(metrics):
                continue  # the simulation's still-moving note says so (_moving)
            why = "no fitted test measured it" if miss is None else "the simulated test does not reach it"
            notes.append(f"{test.name}: no interval for {METRIC[key].label}: {why}")
            continue
        if unreached:
            notes.append(_unreached(test.name, key, distance))
        parts[key] = IntervalParts(
            value,
            _parameter_half(key, gm[:, i], gy, cov, response),
            Z95 * float(np.hypot(miss * value, _curve_miss(identified, key))),
            past.get(key, 0.0),
            calibration.unit(key, value, test.speed, distance),
        )
        if q is None or not np.isfinite(q):
            notes.append(
                f"{test.name}: no interval for {METRIC[key].label}: its form term is not calibrated for a prediction"
                f" of class {klass}"
            )
            continue
        qs[key] = q
        intervals[key], cut = limited_interval(test.name, key, parts[key].interval(q), float(response.time[-1]))
        notes += cut
    notes += _dominated(test.name, parts, qs)
    bands = _bands(response, test.speed, gy, cov, parts, qs)
    return Uncertainty(intervals, parts, qs, _rebound_cut(response, bands, intervals), tuple(notes))


def _unreached(name: str, key: str, distance: float) -> str:
    """The note of a metric the fitted tests' records end before: its interval holds no miss of
    the fit's own; away from the fitted tests the calibrated form term stands in, and at their
    speed and mass (a distance within SAME_ENERGY) nothing does, since the corpus holds no
    prediction past the end of a fitted record."""
    ended = f"{name}: {METRIC[key].label}: the fitted tests' records end before it; its interval holds the fitted curves' miss"
    if distance > SAME_ENERGY:
        return f"{ended} and the calibrated form term, not the fit's own miss of it"
    return (
        f"{ended} and the parameters' only: at the fitted speed and mass there is no calibrated form term, and"
        " nothing measures how far the model misses past the end of a fitted record"
    )


def _uncalibrated_distance(name: str, klass: str, distance: float, calibration: Calibration) -> list[str]:
    """A note where a prediction goes further from the fitted tests than the calibration corpus's
    predictions of its class went: its intervals' form term is carried on, not calibrated."""
    farthest = calibration.farthest(klass)
    if farthest is None or distance <= farthest * (1 + SAME_ENERGY):
        return []
    return [
        f"{name}: it goes {distance:.2f} from the fitted tests (|ln| of the impact energy ratio), past the {farthest:.2f} "
        f"the calibration corpus's predictions of its class ({klass}) went: its intervals' form term is carried on "
        "by the power of the distance, not calibrated"
    ]


def _left_out(case: Case, identified: IdentifiedModel, response: Response) -> np.ndarray:
    """Per estimate, whether the prediction leaves it out: a spring value that shapes no force
    short of the crush the prediction goes through (with the tail's clearance,
    crashnlp.models.tail.tail_start), or short of the start of the line its tail follows. A fit's
    own tail starts just past the crush its tests reached, where the data stop determining the
    values; a value left out neither widens nor withholds the prediction's intervals."""
    spring = case.problem.model.spring
    start = tail_start(float(np.max(response["crush"])), case.problem.model.smoothing.crush)
    if not isinstance(spring.tail, str):
        start = min(start, spring.tail.start)
    return shaping_nothing_short_of(identified.labels, spring.placed_breakpoints, start)


def _fitted_miss(identified: IdentifiedModel, key: str) -> tuple[float | None, bool]:
    """The fitted tests' relative miss of a metric (None where no fitted test measured its curve),
    and whether their records end before it. A record that ends with the vehicle still moving has
    no stop, rebound or max displacement in it, so the fit has no miss of them; where the curve
    they are read from was fitted (the CG's motion, or the pitch for the pitch), the fit's own miss
    is taken as zero and the interval holds the curves' miss and the calibrated form term."""
    miss = identified.discrepancy.get(key)
    if miss is not None:
        return miss, False
    curves = ("pitch",) if METRIC[key].channel == "pitch" else MOTION
    return (0.0, True) if any(c in identified.channel_rmse for c in curves) else (None, False)


def _parameter_half(key: str, gm: np.ndarray, gy: dict[str, np.ndarray], cov: np.ndarray, response: Response) -> float:
    """The parameters' 95 % half-width of a metric: from its own sensitivities, or from its curve's
    at the metric's instant where that is wider (a central difference of an extreme moves its
    instant), so that the band there lies within the interval."""
    var = float(gm @ cov @ gm)
    metric = METRIC[key]
    column = metric.channel if metric.extreme else None
    if column is not None and column in gy:
        g = gy[column][:, int(np.argmax(metric.extreme * response[column]))] * OUTPUT[column].factor
        var = max(var, float(g @ cov @ g))
    return Z95 * float(np.sqrt(var))


def _dominated(name: str, parts: dict[str, IntervalParts], qs: dict[str, float]) -> list[str]:
    """A note for each interval that the force past the reach dominates."""
    notes = []
    for key, q in qs.items():
        shares = parts[key].shares(q)
        if shares["past_the_reach"] > max(shares["parameters"], shares["form"]):
            notes.append(
                f"{name}: {METRIC[key].label}'s interval is mostly the force past the crush the fitted tests reached"
                " (no test measured it)"
            )
    return notes


def _bands(
    response: Response,
    speed: float,
    gy: dict[str, np.ndarray],
    cov: np.ndarray,
    parts: dict[str, IntervalParts],
    qs: dict[str, float],
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pointwise 95 % bands: the parameters' half-width of the curve at each instant, and its
    metric's non-parameter half-width in proportion to how far the curve has moved from what
    the model knows exactly (zero, or for the velocity the impact speed), the displacement's
    after its max with the velocity's carried on (`_carried_back`); cut to what is physically
    certain (crashnlp.analysis.limits: the barrier force only pushes, and at impact, `speed`,
    nothing has moved yet)."""
    v0 = float(response["velocity"][0])
    rest = {}
    for name, key in BAND_METRIC.items():
        part = parts.get(key)
        if part is None or key not in qs:
            continue
        y = response[name]
        moved = np.abs(v0 - y) if name == "velocity" else np.abs(y)
        reference = v0 + part.value if name == "velocity" else abs(part.value)
        share = np.hypot(part.form(qs[key]), part.past(qs[key])) / reference if reference > 0 else 0.0
        rest[name] = share * moved
    if "displacement" in rest and "velocity" in rest:
        rest["displacement"] = np.hypot(rest["displacement"], _carried_back(response, rest["velocity"]))
    bands = {}
    for name, half_rest in rest.items():
        y = response[name]
        g = gy.get(name, np.zeros((cov.shape[0], y.size)))  # values x times
        half = np.sqrt(Z95**2 * np.einsum("it,ij,jt->t", g, cov, g) + half_rest**2)
        bands[name] = limited_band(name, response.time, y, (y - half, y + half), speed)
    return bands


def _rebound_cut(
    response: Response, bands: dict[str, tuple[np.ndarray, np.ndarray]], intervals: dict[str, tuple[float, float] | None]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """`bands` with the velocity band's top, from where the front end leaves the barrier for good
    (or the rebound's instant, the velocity's least, where that is earlier) on, no higher than minus
    the rebound interval's low end, nor below the curve: with no force on it the vehicle moves
    back at its rebound (the pitch and the suspension change it by mm/s), so a rebound interval
    cut at zero (crashnlp.analysis.limits) cuts the band at zero too, and the band at the
    rebound's instant is its interval."""
    rebound = intervals.get("rebound_velocity_mps")
    if rebound is None or "velocity" not in bands:
        return bands
    v = response["velocity"]
    low, high = bands["velocity"]
    pushed = np.flatnonzero(response["contact_force"] > 0)
    top = min(int(np.argmin(v)), int(pushed[-1]) + 1 if pushed.size else v.size)
    high = high.copy()
    high[top:] = np.maximum(v[top:], np.minimum(high[top:], -rebound[0]))
    return {**bands, "velocity": (low, high)}


def _carried_back(response: Response, velocity_rest: np.ndarray) -> np.ndarray:
    """The displacement's non-parameter half-width after its max: the velocity band's
    (`velocity_rest`, the rebound's miss) integrated from the max on, since how fast the vehicle
    comes back off the barrier decides how far back it is; zero up to the max, where the max
    displacement's interval holds."""
    time, top = response.time, int(np.argmax(response["displacement"]))
    steps = 0.5 * (velocity_rest[top + 1 :] + velocity_rest[top:-1]) * np.diff(time[top:])
    return np.concatenate([np.zeros(top + 1), np.cumsum(steps)])


def _curve_miss(identified: IdentifiedModel, metric: str) -> float:
    """The fitted tests' RMSE of the channel `metric` is read from, in the metric's unit (0 when
    none is fitted)."""
    channel = METRIC[metric].channel
    rmse = identified.channel_rmse.get(channel) if channel else None
    return 0.0 if rmse is None or channel is None else rmse * OUTPUT[channel].factor


def past_the_reach(
    case: Case, p: np.ndarray, response: Response, identified: IdentifiedModel, mass: float, metrics: dict[str, float | None]
) -> dict[str, float]:
    """The 95 % half-widths the force past the model's reach in the fitted tests adds to max
    displacement (m), time of zero velocity (s) and peak deceleration (g); nothing inside the reach.

    The force there is the trend rule's guess: its miss per breakpoint spacing
    (crashnlp.models.tail.trend_misses), with Student's t for the few misses it is measured from,
    times the distance d past the reach, is the force's error there. The max displacement moves by the
    energy that error adds over d, the stop in proportion to it (the mean speed to the stop
    unchanged), and the peak by the error where the peak lies, if past the reach."""
    crush, reach_m = response["crush"], identified.range.model_crush
    deepest = float(np.max(crush))
    beyond = deepest - reach_m
    if beyond <= 0:
        return {}
    curve = case.loading_curve(p)
    breakpoints = np.asarray(identified.model["spring"]["crush_breakpoints"], float)
    misses = trend_misses(curve, breakpoints, reach_m)
    if misses.size == 0:
        return {}
    from scipy.stats import t as student  # only past the reach: scipy.stats costs every simulate 0.3 s to import

    quantile = float(student.ppf(0.975, misses.size))  # a root mean square of few misses: Student's t
    rate = float(np.sqrt(np.mean(misses**2))) * quantile / spacing(breakpoints)  # N of force error per m past the reach, 95 %
    at_deepest = max(float(curve(np.array([deepest]))[0]), 1.0)
    half = {"max_displacement_m": rate * beyond**2 / 2 / at_deepest}
    stop, travel = metrics.get("time_zero_velocity_s"), metrics.get("max_displacement_m")
    if stop is not None and np.isfinite(stop) and travel:
        half["time_zero_velocity_s"] = stop * half["max_displacement_m"] / travel
    peak = int(np.argmax(-response["accel"]))
    if crush[peak] > reach_m:
        half["peak_decel_g"] = rate * (float(crush[peak]) - reach_m) / mass / G0
    return half


def _sensitivities(
    case: Case,
    test: TestCase,
    p: np.ndarray,
    identified: IdentifiedModel,
    std: np.ndarray,
    dt: float | None,
    cfc: str | None,
    metrics: dict[str, float | None],
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """d metric / d value (values x metrics) and d output / d value (output -> values x times):
    central differences over one standard error each way, clipped to the estimate's bounds, the
    acceleration read through CFC class `cfc`; one-sided from `metrics`, the estimate's, where one
    end's record does not give a metric (`_slope`)."""
    slices = case.layout.slices()
    gm = np.zeros((len(identified.labels), len(PREDICTED_KEYS)))
    gy: dict[str, np.ndarray] = {}
    for j, label in enumerate(identified.labels):
        k = _position(slices, label)
        lo, hi = identified.bounds[j]
        up, down = min(p[k] + std[j], hi), max(p[k] - std[j], lo)
        if up <= down:
            continue
        r_up, r_down = (_simulated(case, test, _with(p, k, value), dt, cfc) for value in (up, down))
        m_up, m_down = response_metrics(r_up), response_metrics(r_down)
        ends = (up, down, float(p[k]))
        gm[j] = [_slope(m_up.get(key), m_down.get(key), metrics.get(key), ends) for key in PREDICTED_KEYS]
        for name in BAND_METRIC:
            gy.setdefault(name, np.zeros((len(identified.labels), r_up.time.size)))[j] = (r_up[name] - r_down[name]) / (up - down)
    return gm, gy


def _with(p: np.ndarray, k: int, value: float) -> np.ndarray:
    q = p.copy()
    q[k] = value
    return q


def _slope(high: float | None, low: float | None, here: float | None, ends: tuple[float, float, float]) -> float:
    """A metric's change per unit of a value, from the metric at the value's two ends and at the
    estimate (`ends`: the value up, down and estimated): central where both ends give the metric;
    one-sided where one does and the estimate does (a record that ends drifting, or mid-crash, at
    one end withholds what the crash goes on to change: crashnlp.analysis.summary.withheld); 0
    where neither end does, the estimate does not, or the one end is the estimate (at its bound)."""
    up, down, estimate = ends
    given = [(x, m) for x, m in ((up, high), (down, low)) if m is not None and np.isfinite(m)]
    if len(given) == 2:
        return (given[0][1] - given[1][1]) / (up - down)
    if len(given) == 1 and here is not None and np.isfinite(here) and given[0][0] != estimate:
        x, m = given[0]
        return (m - here) / (x - estimate)
    return 0.0


def _position(slices: dict[str, slice], label: str) -> int:
    """Index in the full parameter vector of a label ("vehicle.mass", "model.spring.values[3]")."""
    path, _, rest = label.partition("[")
    return slices[path].start + (int(rest.rstrip("]")) if rest else 0)


def traced(case: Case, identified: IdentifiedModel | None, dt: float | None, source: dict[str, Any]) -> dict[str, PredictedTest]:
    """`predict`'s tests, each with the `source` it came from (crashnlp.results.source), with
    intervals where that source's fit converged (its status ok, or no fit named)."""
    status = (source.get("result") or {}).get("status") or "ok"
    return {name: replace(test, source=source) for name, test in predict(case, identified, dt, status=status).items()}


def unconverged(name: str, status: str) -> str:
    """The note of a test predicted from a fit that did not converge."""
    return f"{name}: no intervals: the fit ended {status}, not converged; its values are simulated as they are"


def simulation_figure_jobs(name: str, tests: dict[str, PredictedTest], out: Path) -> list[Job]:
    """A response figure per simulated test, with its data behind it where it runs at their
    conditions (PredictedTest.data) and its 95 % band shaded, as crashnlp.results.plots jobs."""
    jobs: list[Job] = []
    for predicted in tests.values():
        r = predicted.response
        model = {k: (r.time, r[k]) for k in PANELS}
        bands = {k: (r.time, *band) for k, band in predicted.bands.items()}
        status = (predicted.source.get("result") or {}).get("status") or "ok"
        at = predicted.conditions + (", 95 % band" if bands else "")
        at += unconverged_mark(status)
        title = f"{named_test(name, predicted.name)}: {at}"
        figure = (out / predicted.name / RESPONSE_FIGURE, title, model, predicted.data, bands, None, None, r.accel_filter)
        jobs.append(("response_figure", figure))
    return jobs
