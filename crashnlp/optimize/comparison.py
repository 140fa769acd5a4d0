"""Which model form the data choose: every form fitted, and scored on what its fit did not see.

`compare(problem)` fits the problem once with every form it is given (`compared`, unless told) and
reports per form the objective, the fitted pitch and max displacement misfit, the number of identified
parameters, and a held-out score:

- with two or more tests, leave-one-test-out: each test predicted by the form fitted to the
  others (crashnlp.results.identified.apply, crashnlp.analysis.prediction.predict: the trend tail, as any
  prediction). The score is the prediction's relative RMSE, each measured channel's RMSE over
  the RMS of its data on the test's duration, averaged over channels and held-out tests; with
  the errors of max displacement, peak deceleration and stop time beside it;
- with one test, the Bayesian information criterion of the fit's Gaussian likelihood, each
  channel with its own variance: BIC = sum_c n_c ln(RSS_c / n_c) + k ln n, k the identified
  parameters (the estimated entries less those the fit leaves unidentified). AIC beside it.

The choice is the form with the lowest held-out score (BIC) among the forms whose fit converged.
A form whose fit converged but that has no score (a held-out fit failed) is named beside the
choice, left out of it: where it is the default form, its tie did not apply.
The default form (the paper's pendulum) stays the choice unless another is better by more than a
tie: TIE relative in the held-out score, BIC_TIE in BIC (a difference below 2 is not worth more
than a mention: Kass and Raftery, 1995). A fit alone never chooses: a form with more freedom fits
at least as well. A held-out prediction that lets the front end go while the CG still moves
toward the barrier (crashnlp.analysis.metrics.lift_off), where the measured test was still being
decelerated then, is named beside the choice, but does not pass a form over: its cost is in the
score already, and passing a form over for it would choose by one symptom against the whole
held-out error (measured: docs/design-notes.md, "Which form: the score, not the lift-off").

`forms` names the forms to fit (default `compared`: COMPARED, the pendulum and the rigid body,
and the problem's own `model.form`; the engine-on-mounts form is fitted when named, there or in
`forms`, since its fits cost many times the others').

An estimate entry that a form's equations do not read (the pendulum's `vehicle.crush_offset` in
the rigid body) is left out of that form's fit, so that it counts no parameter it does not have.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import TextIO

import numpy as np

from crashnlp.analysis.metrics import lift_off
from crashnlp.analysis.prediction import predict
from crashnlp.analysis.summary import data_metrics
from crashnlp.base.errors import InputError, RunError
from crashnlp.base.units import G0
from crashnlp.case.case import case_of
from crashnlp.case.checks import check_keys
from crashnlp.optimize.pipeline import prepare_case, solve_problem
from crashnlp.problem import Problem
from crashnlp.problem.forms import COMPARED, DEFAULT_FORM, FORMS
from crashnlp.results.identified import IdentifiedModel, apply
from crashnlp.results.response import Response
from crashnlp.results.result import ChannelFit, Result

HELD_OUT_TESTS = 2  # tests from which on a form is scored by leave-one-test-out prediction
TIE = 0.05  # relative difference of held-out scores within which the default form stays
BIC_TIE = 2.0  # BIC difference within which the default form stays
PUSHED = G0  # m/s^2: a measured deceleration above this says the front end still pushed on the barrier
LIFT_WINDOW = 2e-3  # s: the measured deceleration's median over this either side of a predicted lift-off
COMPARE_FILE = "compare.json"  # what `crashnlp compare` writes in its folder, checked before any fit (check_entries)


@dataclass(frozen=True)
class HeldOut:
    """One test predicted by a form fitted to the other tests (SI; errors relative where named)."""

    test: str
    status: str
    score: float | None = None  # relative RMSE, mean over the measured channels
    channels: dict[str, float] = field(default_factory=dict)  # relative RMSE per channel
    max_displacement_error_rel: float | None = None
    peak_decel_error_rel: float | None = None
    stop_error_s: float | None = None
    lift_off_s: float | None = None  # the front end lets go while the CG moves on, and the data say it did not


@dataclass(frozen=True)
class FormScore:
    """One form's fit of every test and its held-out score."""

    form: str
    status: str
    objective: float | None = None
    pitch_rmse_rad: float | None = None  # over the fitted tests' pitch channels
    displacement_error_m: float | None = None  # worst |model - measured| max displacement (the CG's travel)
    parameters: int | None = None  # identified; None without a fit
    samples: int | None = None  # fitted data points; None without a fit
    aic: float | None = None
    bic: float | None = None
    held_out: tuple[HeldOut, ...] = ()
    lift_off_s: float | None = None  # the first held-out prediction's lift-off the measured test does not show

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def held_out_score(self) -> float | None:
        """The mean held-out score, None unless every held-out prediction has one."""
        scores = [h.score for h in self.held_out if h.score is not None]
        return float(np.mean(scores)) if self.held_out and len(scores) == len(self.held_out) else None


@dataclass(frozen=True)
class Comparison:
    """Every form's score, the criterion the choice used, the choice and why."""

    name: str
    criterion: str  # "held-out" or "bic"
    forms: tuple[FormScore, ...]
    choice: str | None
    reason: str

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "criterion": self.criterion,
            "choice": self.choice,
            "reason": self.reason,
            "forms": {f.form: {**asdict(f), "held_out_score": f.held_out_score} for f in self.forms},
        }


def with_form(problem: Problem, form: str, source: str | None = None) -> Problem:
    """The problem with `model.form` set to `form`, less the estimate entries the form's
    equations do not read (its outputs, right-hand side and initial state) and the vehicle
    entries it does not read (an engine, a crush offset: Case.unread_given), back at their
    defaults; its input errors naming `source`."""
    changed = problem.model_copy(update={"model": problem.model.model_copy(update={"form": form})})
    case = case_of(changed, source)  # refuses a problem the form cannot model
    unread = case.model.unread(list(changed.estimate))
    defaults = {key: type(changed.vehicle).model_fields[key].default for key in case.unread_given()}
    vehicle = changed.vehicle.model_copy(update=defaults)
    return changed.model_copy(
        update={"estimate": {k: v for k, v in changed.estimate.items() if k not in unread}, "vehicle": vehicle}
    )


def compared(problem: Problem) -> tuple[str, ...]:
    """The forms `compare` fits unless told: COMPARED and the problem's own `model.form`, which
    a user who names it (with an engine for it) means to be among them."""
    return tuple(dict.fromkeys((*COMPARED, problem.model.form)))


def compare(
    problem: Problem,
    source: str | None = None,
    progress: TextIO | None = None,
    forms: str | Sequence[str] | None = None,
) -> Comparison:
    """Every one of `forms` (default `compared`; a name alone is one form, as `--forms pendulum`
    gives it) fitted to the problem's tests and scored (see the module notes); `source` the file
    its input errors name, `progress` a stream for a line per fit."""
    forms = compared(problem) if forms is None else (forms,) if isinstance(forms, str) else tuple(forms)
    check_comparable(problem, source, forms)
    criterion = "held-out" if len(problem.tests) >= HELD_OUT_TESTS else "bic"
    scores = [score_form(problem, form, source, criterion, progress)[0] for form in dict.fromkeys(forms)]
    choice, reason = choose(scores, criterion)
    return Comparison(problem.name, criterion, tuple(scores), choice, reason)


def check_comparable(problem: Problem, source: str | None, forms: Sequence[str], where: str = "forms") -> None:
    """What `compare` refuses before it fits anything, as an InputError: a problem that is not an
    identify problem, `forms` (given as `where`) naming none, the first of them that is no model
    form, and the problem's own errors (`source` the file they name), before any form's: a vehicle
    entry its own form does not read (an engine, a crush offset: Case.refuse_unread_given) as
    identify refuses it; the other forms' problems leave it out (with_form)."""
    if problem.kind != "identify":
        raise InputError(f"{source or problem.name}: kind is {problem.kind!r}; compare fits an identify problem's forms")
    if not forms:
        raise InputError(f"{where}: names no model form; give one or more of {', '.join(FORMS)}")
    unknown = [form for form in forms if form not in FORMS]
    if unknown:
        raise InputError(f"{where}: {unknown[0]!r} is none of {', '.join(FORMS)}")
    check_keys(problem, source)
    case_of(problem, source).refuse_unread_given(source or problem.name)
    prepare_case(with_form(problem, problem.model.form, source), source)  # as its own form fits it


def _say(progress: TextIO | None, line: str) -> None:
    if progress is not None:
        print(line, file=progress, flush=True)


def score_form(
    problem: Problem, form: str, source: str | None, criterion: str, progress: TextIO | None = None
) -> tuple[FormScore, Result | None]:
    """The problem fitted with `form` and scored by `criterion` ("held-out" or "bic"), and the fit
    (None where the form refuses the problem or the fit raised: the score's status says which)."""
    _say(progress, f"{problem.name}: fitting {form}")
    # the profiles the problem asks for are its chosen form's business, not the comparison's
    problem = problem.model_copy(update={"uncertainty": problem.uncertainty.model_copy(update={"profile": []})})
    try:
        formed = with_form(problem, form, source)
    except InputError as exc:  # a problem this form cannot model (CrashModel.check)
        return FormScore(form, f"refused: {exc}"), None
    fit, status = _fit(formed, source)
    return (FormScore(form, status) if fit is None else _score(formed, fit, source, criterion, progress)), fit


def _fit(problem: Problem, source: str | None) -> tuple[Result | None, str]:
    """The problem's fit and its status; a fit that raised a run error has its one line as status."""
    try:
        result = solve_problem(problem, source, ratings=False)
    except (RunError, RuntimeError) as exc:
        return None, f"failed: {exc}"
    return result, result.status


def information_criteria(
    channels: Sequence[ChannelFit], k: int, counted: Sequence[float] | None = None
) -> tuple[float | None, float | None]:
    """AIC and BIC of a fit's Gaussian likelihood, each channel with its own variance, estimated
    (constants dropped): sum_c n_c ln(RSS_c / n_c) + 2 k, and + k ln(sum_c n_c), `k` the identified
    parameters; n_c a channel's samples, or as many as `counted` takes them for, channel by
    channel; None without samples."""
    n = [c.data.size for c in channels] if counted is None else list(counted)
    if sum(n) <= 0:
        return None, None
    deviance = sum(nc * math.log(max(float(np.mean((c.model - c.data) ** 2)), 1e-300)) for nc, c in zip(n, channels))
    return deviance + 2 * k, deviance + k * math.log(sum(n))


def _score(problem: Problem, fit: Result, source: str | None, criterion: str, progress: TextIO | None) -> FormScore:
    """`fit`'s score (the problem's form's, as `score_form` gives it)."""
    fitted = [t for t in fit.tests.values() if t.fit]
    channels = [c for t in fitted for c in t.fit.values()]
    k = int(sum(np.size(v) for v in fit.parameters.values()) - len(fit.not_identified))  # the identified parameters
    aic, bic = information_criteria(channels, k)
    held = (
        tuple(_held_out(problem, name, source, progress) for name in (t.name for t in problem.tests))
        if criterion == "held-out"
        else ()
    )
    offs = [h.lift_off_s for h in held if h.lift_off_s is not None]
    return FormScore(
        problem.model.form,
        fit.status,
        fit.solver.objective,
        _pitch_rmse(fitted),
        _displacement_error(fit),
        k,
        int(sum(c.data.size for c in channels)),
        aic,
        bic,
        held,
        min(offs) if offs else None,
    )


def _pitch_rmse(tests: list) -> float | None:
    """The fitted pitch's RMSE over every test's pitch samples (rad); None without pitch data."""
    fits = [t.fit["pitch"] for t in tests if "pitch" in t.fit]
    if not fits:
        return None
    return float(np.sqrt(np.sum([np.sum((f.model - f.data) ** 2) for f in fits]) / np.sum([f.data.size for f in fits])))


def _displacement_error(fit: Result) -> float | None:
    """The worst |model - measured| max displacement (the CG's travel) over the tests that measure it (m)."""
    errors = [
        abs(t.metrics["max_displacement_m"] - t.data_metrics["max_displacement_m"])  # type: ignore[operator]
        for t in fit.tests.values()
        if t.data_metrics
        and t.data_metrics.get("max_displacement_m") is not None
        and t.metrics.get("max_displacement_m") is not None
    ]
    return max(errors) if errors else None


def _lift_off(response: Response, data: dict[str, tuple[np.ndarray, np.ndarray]]) -> float | None:
    """The time the response's front end lets go of the barrier while the CG still moves toward
    it (crashnlp.analysis.metrics.lift_off), where the measured test was still being decelerated then (by
    more than PUSHED over LIFT_WINDOW): a vehicle whose front end really comes free (its pitch
    outruns its travel) is no model's fault. None without such a time, or without data to say."""
    t = lift_off(response.time, response["velocity"], response["contact_force"])
    if t is None:
        return None
    if "accel" in data:
        time, accel = data["accel"]
    elif "velocity" in data:
        time, velocity = data["velocity"]
        accel = np.gradient(velocity, time)
    else:
        return None
    near = np.abs(time - t) <= LIFT_WINDOW
    return t if near.any() and -float(np.median(accel[near])) > PUSHED else None


def _held_out(problem: Problem, name: str, source: str | None, progress: TextIO | None) -> HeldOut:
    """Test `name` predicted by the problem's form fitted to the other tests."""
    _say(progress, f"  {problem.model.form}: predicting {name} from the other tests")
    others = problem.model_copy(update={"tests": [t for t in problem.tests if t.name != name]})
    fit, status = _fit(others, source)
    if fit is None or not fit.ok or fit.identified is None:
        return HeldOut(name, status)
    return held_out_prediction(problem, name, fit.identified, source)


def held_out_prediction(problem: Problem, name: str, identified: IdentifiedModel, source: str | None = None) -> HeldOut:
    """Test `name` of the problem predicted by a fit's identified model (`identified`, of the
    problem's form; the trend tail, as any prediction), scored against its data."""
    alone = problem.model_copy(update={"tests": [t for t in problem.tests if t.name == name], "estimate": {}})
    case = case_of(apply(alone, identified, source or problem.name), source)
    (predicted,) = predict(case).values()
    response, data = predicted.response, predicted.data
    channels = {}
    for channel, (t, values) in data.items():
        inside = (t >= 0.0) & (t <= response.time[-1])
        if channel not in response.outputs or np.count_nonzero(inside) < 2:
            continue
        model = np.interp(t[inside], response.time, response[channel])
        scale = float(np.sqrt(np.mean(values[inside] ** 2)))
        if scale > 0:
            channels[channel] = float(np.sqrt(np.mean((model - values[inside]) ** 2)) / scale)
    measured = data_metrics(case.tests[0]) or {}

    def error(key: str, relative: bool) -> float | None:
        mine, theirs = predicted.metrics.get(key), measured.get(key)
        if mine is None or theirs is None or (relative and theirs == 0):
            return None
        return (mine - theirs) / abs(theirs) if relative else mine - theirs

    return HeldOut(
        name,
        "ok",
        float(np.mean(list(channels.values()))) if channels else None,
        channels,
        error("max_displacement_m", True),
        error("peak_decel_g", True),
        error("time_zero_velocity_s", False),
        _lift_off(response, data),
    )


def choose(scores: list[FormScore], criterion: str, bic_tie: float = BIC_TIE) -> tuple[str | None, str]:
    """The chosen form and why (see the module notes); `bic_tie` the BIC difference within which
    the default form stays (BIC_TIE; bench/choice.py tries others)."""
    value: dict[str, float] = {}
    for f in scores:
        v = f.held_out_score if criterion == "held-out" else f.bic
        if f.ok and v is not None:
            value[f.form] = v
    what = "held-out relative RMSE" if criterion == "held-out" else "BIC"
    if not value:
        return None, _no_score(scores, criterion)
    best = min(value, key=lambda form: value[form])
    choice, reason = best, f"{best}: the lowest {what}"
    if DEFAULT_FORM in value and best != DEFAULT_FORM:
        margin = value[DEFAULT_FORM] - value[best]
        if margin <= (TIE * abs(value[best]) if criterion == "held-out" else bic_tie):
            choice, reason = DEFAULT_FORM, f"{DEFAULT_FORM}: the default, within a tie of {best}'s {what}"
    reason += _unscored(scores, value, what)
    lifted = _of(scores, choice).lift_off_s
    if lifted is not None:
        reason += f"; its held-out prediction lets the front end go at {lifted * 1e3:.1f} ms while the data still push"
    if criterion == "bic":
        reason += "; with one test nothing is held out: a second test at another speed lets compare choose by held-out prediction"
    if choice != DEFAULT_FORM and all(f.pitch_rmse_rad is None for f in scores if f.ok):
        reason += "; no test measures pitch, where the forms differ most: the choice rests on the other channels alone"
    return choice, reason


def _no_score(scores: list[FormScore], criterion: str) -> str:
    """Why no form has a score by `criterion`: no fit converged, or those that did lack the score
    (a held-out fit that failed: the table's lines under it say which)."""
    converged = [f.form for f in scores if f.ok]
    if not converged:
        return "no form's fit converged"
    if criterion == "held-out":
        return (
            f"no form has a held-out score: the fit of {', '.join(converged)} converged, "
            "but a held-out prediction of each failed or has no score"
        )
    return f"no form has a BIC: the fit of {', '.join(converged)} converged, but with no fitted samples"


def _unscored(scores: list[FormScore], value: dict[str, float], what: str) -> str:
    """The note on the forms whose fit converged but that have no score, left out of the choice,
    the default form's tie rule not applied where it is one of them; empty without such forms."""
    unscored = [f.form for f in scores if f.ok and f.form not in value]
    if not unscored:
        return ""
    tie = " (the default: its tie rule was not applied)" if DEFAULT_FORM in unscored else ""
    return f"; left out for want of a {what}: {', '.join(unscored)}{tie}"


def _of(scores: list[FormScore], form: str) -> FormScore:
    return next(f for f in scores if f.form == form)
