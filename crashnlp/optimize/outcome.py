"""The one place a solved NLP becomes a plain `Result` (crashnlp.results.result).

Everything that needs the NLP (multipliers, constraint blocks, the parameter
layout) is read here, once; nothing downstream touches the optimizer.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from crashnlp.analysis.limits import FORCE_RANGE, within
from crashnlp.analysis.rating import iso18571_each
from crashnlp.analysis.summary import (
    accel_filter,
    accel_spec,
    as_recorded,
    channel_consistency,
    data_metrics,
    goes_on,
    let_go_words,
    pitch_words,
    response_metrics,
)
from crashnlp.base.outputs import PREDICTED_KEYS, Z95
from crashnlp.case.case import Case, TestCase
from crashnlp.case.completion import measured_pulse, measured_pulses
from crashnlp.models.tail import trend_tail
from crashnlp.numerics.nlp import NOT_REPORTED
from crashnlp.optimize.identify import Solution
from crashnlp.problem.forms import DEFAULT_FORM
from crashnlp.results.identified import (
    IdentifiedModel,
    IdentifiedRange,
    shaping_nothing_short_of,
    takes_in_zero_note,
    without_entries,
)
from crashnlp.results.response import Response
from crashnlp.results.result import ActiveConstraint, ChannelFit, LoadingCurve, Result, SolverStats, TestResult

COVARIANCE_METHOD = "sandwich, Newey-West over the nodes of each test"


def result_of(solution: Solution, ratings: bool = True) -> Result:
    """The plain result of a solve; `ratings`: rate each channel fit by ISO/TS 18571 (most of the
    time of a warm-started study case, and no column of a study's table). Its notes name the values
    whose 95 % interval takes in zero (Result.takes_in_zero), as the console and the report do."""
    case, res = solution.case, solution.result
    solver = SolverStats(
        res.return_status if res else None,
        res.iterations if res else 0,
        res.objective if res else None,
        res.wall_s if res else None,
        res.build_s if res else None,
        res.compiled if res else None,
    )
    tests = {test.name: _test(solution, ts, test, ratings) for ts, test in zip(solution.tests, case.tests)}
    labels = solution.ocp.free.labels()
    identified = identified_model(solution, tests)
    cov, pull, at_bound = solution.covariance, solution.bound_pull(), solution.at_bound()
    result = Result(
        name=case.name,
        kind=case.problem.kind,
        status=solution.status,
        solver=solver,
        transcription=case.problem.transcription.model_dump(),
        parameters=solution.parameters,
        std_errors=_named(solution, cov.std) if cov is not None else {},
        correlation={"labels": labels, "matrix": np.round(cov.correlation, 6).tolist()} if cov is not None else {},
        not_identified=tuple(np.asarray(labels)[~cov.identified].tolist()) if cov is not None else (),
        at_bound={label: _finite_rounded(pull[i]) for i, label in enumerate(labels) if at_bound[i]},
        active_constraints=tuple(active_constraints(solution)) + tuple(_parameter_bounds(solution)),
        tests=tests,
        force_crush=_force_crush(solution, identified),
        profiles=solution.profiles,
        covariance={"method": COVARIANCE_METHOD, "lags": cov.bandwidth} if cov is not None else {},
        inequalities=tuple(c.name for c in solution.ocp.nlp.constraints if c.kind not in NOT_REPORTED),
        z=res.z if res else None,
        notes=tuple(solution.notes) + _data_notes(case) + _moving_notes(tests) + _pitch_notes(tests) + identified.tail_notes(),
        identified=identified,
        regularization=solution.regularization,
        output_bounds={str(name): ends for name, ends in case.problem.constraints.bounds.items()},
        resolution=case.resolution.to_json() if case.resolution is not None else {},
    )
    loose = result.takes_in_zero()
    return replace(result, notes=result.notes + (takes_in_zero_note(loose),)) if loose else result


def identified_model(solution: Solution, tests: dict[str, TestResult]) -> IdentifiedModel:
    """The fitted vehicle, complete, with what a prediction needs (crashnlp.results.identified); a fit's
    loading curve bends into its trend just past the crush the model reached (crashnlp.models.tail)."""
    case, free, cov = solution.case, solution.ocp.free, solution.covariance
    fitted = case.problem.with_values(solution.parameters)
    mass = float(fitted.vehicle.mass or 0.0)  # Case fills it in
    masses = [float(t.overrides.get("vehicle.mass", mass)) for t in case.tests]
    pulses = measured_pulses(case.problem, case.tests)
    measured = (
        max(p.max_displacement for p in pulses)
        if pulses
        else max(float(t.metrics["max_displacement_m"] or 0.0) for t in tests.values())
    )
    reach = solution.reach
    # a result names its form where it is not the default one: the pendulum's files carry no form entry
    model = fitted.model.model_dump(mode="json", exclude={"form"} if fitted.model.form == DEFAULT_FORM else None)
    if case.problem.kind == "identify" and fitted.model.spring.tail == "trend":
        curve = case.loading_curve(solution.full_parameters())
        breakpoints = np.asarray(fitted.model.spring.placed_breakpoints)
        start, slope = trend_tail(curve, breakpoints, reach, fitted.model.smoothing.crush)
        model["spring"]["tail"] = {"start": start, "slope": slope}
    return IdentifiedModel(
        vehicle=fitted.vehicle.model_dump(mode="json"),
        model=model,
        parameters=solution.parameters,
        labels=tuple(free.labels()),
        covariance=None if cov is None else cov.matrix,
        bounds=tuple(zip(free.lower.tolist(), free.upper.tolist())),
        range=IdentifiedRange(
            measured,
            _span([t.speed for t in case.tests]),
            _span(masses),
            reach,
            tuple(0.5 * m * t.speed**2 for m, t in zip(masses, case.tests)),
        ),
        discrepancy=_discrepancy(tests),
        channel_rmse=_channel_rmse(tests),
        accel_filter=_accel_filter(case),
        designed=case.problem.kind == "design",
    )


def _accel_filter(case: Case) -> str | None:
    """The CFC class the fitted tests' accelerometers were read through, where they have accel
    data and agree on it (None otherwise: a prediction then reports the model's own acceleration)."""
    filters = {accel_filter(t) for t in case.tests if accel_spec(t) is not None}
    return filters.pop() if len(filters) == 1 else None


def _finite_rounded(x: float) -> float | None:
    """`x` to three decimals; None where it is not a number (a value the data do not determine)."""
    return round(float(x), 3) if np.isfinite(x) else None


def _span(values: list[float]) -> tuple[float, float]:
    return float(min(values)), float(max(values))


def _discrepancy(tests: dict[str, TestResult]) -> dict[str, float]:
    """Per metric, the root mean square over tests of the model's relative miss of the data's value,
    over the tests where both reach it (a model that does not stop in the record has no stop time)."""
    out = {}
    for key in PREDICTED_KEYS:
        pairs = [(t.metrics.get(key), (t.data_metrics or {}).get(key)) for t in tests.values()]
        misses = [model / data - 1.0 for model, data in pairs if model is not None and data and np.isfinite(model / data)]
        if misses:
            out[key] = float(np.sqrt(np.mean(np.square(misses))))
    return out


def _channel_rmse(tests: dict[str, TestResult]) -> dict[str, float]:
    """Per fitted channel, the root mean square over tests of the fit's RMSE (SI)."""
    channels = {c for t in tests.values() for c in t.fit}
    return {c: float(np.sqrt(np.mean([t.fit[c].rmse ** 2 for t in tests.values() if c in t.fit]))) for c in sorted(channels)}


def _data_notes(case: Case) -> tuple[str, ...]:
    """What the readers chose from each test's data, one line each, naming the test."""
    return tuple(f"test {t.name}: {n}" for t in case.tests if t.data is not None for n in t.data.notes)


def _moving_notes(tests: dict[str, TestResult]) -> tuple[str, ...]:
    """A test whose record (or whose model over it) ends before the vehicle stops, or whose model's
    loading ends as it lets go of the barrier moving on (let_go_words), said so."""
    notes = []
    for name, t in tests.items():
        for who, metrics in (("record", t.data_metrics), ("model", t.metrics)):
            text = goes_on(metrics) if metrics is not None else None
            notes += [f"test {name}: the {who} {text}"] if text else []
        words = let_go_words(t.response)
        notes += [f"test {name}: the model {words}"] if words else []
    return tuple(notes)


def _pitch_notes(tests: dict[str, TestResult]) -> tuple[str, ...]:
    """Each test whose measured or fitted pitch still rises at the window's end, or whose measured
    pitch is too small for a crash, said so (summary.pitch_words)."""
    return tuple(f"test {name}: {words}" for name, t in tests.items() for words in pitch_words(t))


def _test(solution: Solution, ts: Response, test: TestCase, ratings: bool) -> TestResult:
    v = solution.verification
    check = None
    if v is not None:
        check = {"max_abs_error": v.mismatch[test.name], "allowed": v.allowed[test.name], "worst_relative": v.worst(test.name)}
    data = {name: (ch.time, ch.values) for name, ch in test.data.channels.items()} if test.data is not None else {}
    seen = as_recorded(ts, accel_filter(test))  # as the test's accelerometers record it: what its fit is rated on
    return TestResult(
        test.name,
        test.speed,
        seen,
        data,
        _fits(solution, ts, test.name, ratings),
        response_metrics(seen),
        data_metrics(test),
        ts.loading_end,
        v.energy[test.name] if v is not None else None,
        check,
        channel_consistency(test, _mass(solution, test)),
    )


def _mass(solution: Solution, test: TestCase) -> float:
    """The vehicle mass [kg] of a test at the solution."""
    case = solution.case
    return float(case.test_parameters(test, solution.full_parameters())[case.layout.index("vehicle.mass")][0])


def _fits(solution: Solution, ts: Response, test: str, ratings: bool) -> dict[str, ChannelFit]:
    """Each fitted channel of a test: model and data at its nodes, RMSE and ISO 18571 ratings
    (rated together: crashnlp.analysis.rating.iso18571_each; none under 10 nodes)."""
    fitted = [r for r in solution.residuals if r.test == test]
    curves = [(ts.time[r.columns], r.data, r.seen(ts.time, ts.outputs)) for r in fitted]
    rated = [i for i, (times, _, _) in enumerate(curves) if ratings and len(times) >= 10]
    rating = dict(zip(rated, iso18571_each([curves[i] for i in rated])))
    out = {}
    for i, (r, (times, data, model)) in enumerate(zip(fitted, curves)):
        rmse = float(np.sqrt(np.mean((model - data) ** 2)))
        out[r.channel] = ChannelFit(r.channel, times, data, model, r.sigma, rmse, rating.get(i))
    return out


def _named(solution: Solution, values: np.ndarray) -> dict:
    """Per-entry values of theta by parameter path (a number or a list); inf as None."""
    out = {}
    for e in solution.ocp.free.entries:
        v = [None if not np.isfinite(x) else float(x) for x in values[e.at]]
        out[e.path] = v[0] if e.where.stop - e.where.start == 1 else v
    return out


def active_constraints(solution: Solution, lam_tol: float = 1e-6, slack_tol: float = 1e-6) -> list[ActiveConstraint]:
    """Inequality blocks with points at their bound and a nonzero multiplier.

    The multiplier, summed over the block's points, is what a unit of the bound is worth:
    d objective / d bound (objective units per SI unit), -lambda in IPOPT's sign (lambda >= 0 at an
    upper bound, <= 0 at a lower): negative where raising the bound lowers the objective (an
    upper bound that holds the optimum back), positive at a lower bound."""
    res, nlp = solution.result, solution.ocp.nlp
    if res is None:
        return []
    bounds = nlp.bounds()
    out = []
    for c in nlp.constraints:
        if c.kind in NOT_REPORTED:
            continue
        rows = slice(c.start, c.start + c.size)
        lam, g, lo, hi = res.lam_g[rows], res.g[rows], bounds["lbg"][rows], bounds["ubg"][rows]
        slack = np.minimum(np.abs(g - lo), np.abs(hi - g))
        bound = np.where(np.abs(g - lo) < np.abs(hi - g), lo, hi)
        active = np.flatnonzero((np.abs(lam) > lam_tol) & (slack <= slack_tol * (1 + np.abs(bound))))
        if active.size:
            worth = -lam[active]
            out.append(ActiveConstraint(c.kind, c.name, c.test, int(active.size), float(worth.sum()), _largest(worth)))
    return out


def _largest(worth: np.ndarray) -> float:
    """The entry of largest magnitude, with its sign."""
    return float(worth[np.argmax(np.abs(worth))])


def _parameter_bounds(solution: Solution) -> list[ActiveConstraint]:
    """Parameters at a bound, as active constraints: d objective / d bound, -lam_x in SI."""
    if solution.result is None:
        return []
    block = solution.ocp.nlp.blocks["theta"]
    worth = 0.0 - solution.result.lam_x[block.offset : block.offset + block.shape[0]] / block.scale.ravel()  # no -0.0
    labels = solution.ocp.free.labels()
    return [
        ActiveConstraint("parameter_bound", f"bound.{labels[i]}", None, 1, float(worth[i]), float(worth[i]))
        for i in np.flatnonzero(solution.at_bound())
    ]


def _force_crush(solution: Solution, identified: IdentifiedModel) -> LoadingCurve:
    """The loading curve from zero to just past the largest crush reached, its breakpoints and 95 %
    band, and each test's measured m |a| against CG travel while loading. A tail starting short
    of the curve's end (`identified`'s) gets a crush of its own at its start, where the table
    force_crush.csv takes the tail's line from (crashnlp.results.result.along_the_tail): the
    table read back gives the same line."""
    case, p = solution.case, solution.full_parameters()
    end = max(solution.reach * 1.05, 1e-3)
    x = np.linspace(0.0, end, 201)
    tail = identified.tail_line
    if tail is not None and tail["start"] < end:
        x = np.insert(x, np.searchsorted(x, tail["start"]), tail["start"])  # not union1d: it imports numpy.ma
    curve = case.loading_curve(p)
    bps = solution.breakpoints
    inside = bps[bps <= x[-1]]
    f, values = curve(x), curve(inside) if inside.size else np.zeros(0)
    known = case.problem.reference.force_crush
    reference = (np.asarray(known.crush), np.asarray(known.force)) if known is not None else None
    pulses = {test.name: measured_pulse(case.problem, test) for test in case.tests}
    measured = {name: (p.displacement[p.loading], p.force[p.loading]) for name, p in pulses.items() if p is not None}
    return LoadingCurve(x, f, inside, values, reference, measured, _curve_band(solution, x, f, bps))


def _curve_band(
    solution: Solution, x: np.ndarray, f: np.ndarray, breakpoints: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The loading curve's 95 % band at the crushes `x` (N): the estimates' covariance pushed
    through the curve's sensitivities, central differences over one standard error each way;
    None without a covariance or where the data do not determine an estimate that shapes the
    curve over `x`, and for a fit that did not converge (a last iterate's covariance, which its
    report and its predictions do not take either). Cut at zero force: a front end only pushes
    (crashnlp.analysis.limits)."""
    cov = solution.covariance
    if cov is None or not solution.ok:
        return None
    free, theta = solution.ocp.free, solution.theta
    outside = shaping_nothing_short_of(free.labels(), breakpoints, float(x[-1]))
    if not np.all(np.isfinite(cov.std) | outside):
        return None
    g = np.zeros((theta.size, x.size))
    for j, step in enumerate(cov.std):
        if step > 0 and not outside[j]:
            up, down = (theta + s * step * np.eye(theta.size)[j] for s in (1.0, -1.0))
            g[j] = (solution.case.loading_curve(free.full(up))(x) - solution.case.loading_curve(free.full(down))(x)) / (2 * step)
    matrix = without_entries(cov.matrix, outside)
    half = Z95 * np.sqrt(np.maximum(np.einsum("it,ij,jt->t", g, matrix, g), 0.0))
    return within(f - half, f + half, f, *FORCE_RANGE)
