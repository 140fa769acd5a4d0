"""The model's samples as the test records them: the J211 filter as a matrix on the model's grid."""

import numpy as np
import pytest
from scipy.signal import filtfilt

from crashnlp.base.units import G0
from crashnlp.data.instrument import PRE_IMPACT, acceleration, cfc_recorded, rate, recorded, recording
from crashnlp.data.signal import cfc_coefficients, cfc_filter


def pulse(t: np.ndarray) -> np.ndarray:
    """A crash pulse (m/s^2): a step at impact, a sharp peak at 30 ms, the stop at 80 ms."""
    return -(30.0 + 150.0 * np.sin(np.pi * t / 0.08) ** 2 + 200.0 * np.maximum(0.0, 1.0 - np.abs(t - 0.03) / 0.006)) * (t < 0.08)


def test_cfc_recorded_is_the_j211_filter_of_a_record_at_rest_before_impact():
    """At 10 kHz: scipy's filtfilt of the J211 biquad over 20 ms of zeros and the pulse, padded by
    odd reflection as cfc_filter pads, read from impact on."""
    dt = 1e-4
    t = np.arange(0.0, 0.15 + dt / 2, dt)
    before = round(PRE_IMPACT / dt)
    b, a = cfc_coefficients(60.0, dt)
    ref = filtfilt(b, a, np.concatenate([np.zeros(before), pulse(t)]), padtype="odd", padlen=round(0.01 / dt))[before:]
    np.testing.assert_allclose(cfc_recorded(t, pulse(t), 60.0), ref, atol=1e-9 * 380.0)


@pytest.mark.parametrize(("cfc", "size"), [(60.0, 151), (180.0, 151), (60.0, 8)])
def test_the_filters_banded_equations_record_every_signal_as_the_filter_does(cfc, size):
    """The forward and backward passes solved from their banded equations give cfc_recorded's
    samples (CFC 180 on a 1 ms grid filters between the samples; 7 ms: the end's reflection
    reaches into the record's zeros), and the equations have at most three nonzeros a row."""
    t = np.linspace(0.0, 0.001 * (size - 1), size)
    signal = pulse(t) + np.random.default_rng(0).normal(0.0, 20.0, t.size)
    rec = recording(t, cfc)
    _, backward = rec.solve(signal)
    np.testing.assert_allclose(backward[rec.at], cfc_recorded(t, signal, cfc), atol=1e-9 * 400.0)
    assert np.bincount(rec.lower(rec.a)[0]).max() == 3


def test_on_a_coarse_grid_the_recording_is_the_fine_records_at_its_samples():
    """The model's samples at 1 ms, filtered at CFC 60, against the pulse sampled and filtered at
    10 kHz as a test records it: within 2 % of the peak, of which the filter takes 9 % off."""
    fine = np.arange(0.0, 0.15 + 5e-5, 1e-4)
    coarse = fine[::10]
    truth = cfc_filter(np.concatenate([np.zeros(200), pulse(fine)]), 1e-4, 60.0)[200:][::10]
    seen = cfc_recorded(coarse, pulse(coarse), 60.0)
    peak = np.max(np.abs(pulse(fine)))
    assert np.max(np.abs(seen - truth)) < 0.02 * peak
    assert np.max(np.abs(truth)) < 0.93 * peak  # the filter rounds the peak: what the fit must see


def test_a_class_the_model_grid_cannot_carry_is_filtered_on_a_finer_one():
    """CFC 180 needs 3 kHz for ten samples a period of its -3 dB frequency (300 Hz): on a 1 ms grid
    the signal is filtered between the samples, not refused."""
    t = np.linspace(0.0, 0.15, 151)
    seen = cfc_recorded(t, pulse(t), 180.0)
    assert np.all(np.isfinite(seen)) and np.max(np.abs(seen - pulse(t))) < 0.2 * 380.0


def test_the_exported_pulse_is_recorded_from_rest_as_the_fit_compares_it():
    """A pulse that steps to 20 g at impact is exported as an accelerometer at rest before impact
    records it (half the step at impact: the zero-phase filter's), not as the step held back into
    negative time; and it is the fit's recording of the same samples."""
    from crashnlp.report.export import pulse
    from crashnlp.results.response import Response

    time = np.arange(0.0, 0.1 + 1e-9, 1e-4)
    step = -20.0 * G0 * (time < 0.05)
    velocity = 15.0 + np.concatenate([[0.0], np.cumsum(0.5 * (step[1:] + step[:-1]) * np.diff(time))])
    p = pulse(Response(time, {"accel": step, "velocity": velocity}, np.zeros((1, time.size))), 15.0, 1e4, 60.0)
    assert p.accel[0] == pytest.approx(0.5 * step[0], rel=0.05)  # the step is half a sample before it
    assert np.allclose(p.accel, cfc_recorded(time, step, 60.0))


@pytest.mark.parametrize("size", [2, 3, 4, 5, 151])
def test_the_velocitys_rate_is_exact_for_polynomials_of_its_stencils_order(size):
    """Fourth-order central differences inside (exact for quartics), second order at the ends
    and their neighbours (exact for quadratics), first order on two samples; its matrix (the
    rate of the identity) is the same operator."""
    t = np.linspace(0.0, 0.001 * (size - 1), size)
    quadratic = (2.0 - 3.0 * t + 40.0 * t**2, -3.0 + 80.0 * t)
    expected = quadratic if size > 2 else (2.0 - 3.0 * t, np.full(size, -3.0))
    np.testing.assert_allclose(rate(expected[0], 0.001), expected[1], rtol=1e-9, atol=1e-9)
    quartic = (t**4 - 0.1 * t**3, 4.0 * t**3 - 0.3 * t**2)
    inside = slice(2, size - 2)
    np.testing.assert_allclose(rate(quartic[0], 0.001)[inside], quartic[1][inside], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rate(np.eye(size), 0.001) @ quartic[0], rate(quartic[0], 0.001), atol=1e-12)
    assert acceleration(quadratic[0], 0.001)[0] == pytest.approx(0.5 * rate(quadratic[0], 0.001)[0])


def _unloading(end: float, t: np.ndarray) -> dict[str, np.ndarray]:
    """A pulse whose force unloads linearly to zero at `end` and stays zero: its acceleration
    and its velocity (from 15 m/s), exact."""
    slope = 40_000.0  # m/s^3: 40 g less every millisecond
    accel = -slope * np.maximum(end - t, 0.0)
    velocity = 15.0 - slope * (end * np.minimum(t, end) - 0.5 * np.minimum(t, end) ** 2)
    return {"accel": accel, "velocity": velocity}


def test_the_recorded_acceleration_moves_smoothly_as_the_end_of_contact_crosses_a_sample():
    """The end of contact crossing the sample at 72 ms: the recorded acceleration, taken as the
    velocity's rate, has the same slope in the end's time on either side; a sample of the
    acceleration itself jumps in slope there (what made the fits step the end across a node and
    back, seed 3200's e02 at 56 km/h), by a quarter of the slope."""
    t = np.linspace(0.0, 0.15, 151)
    node, step = 0.072, 1e-6

    def slopes(seen):
        before, at, after = (seen(node + k * step) for k in (-1, 0, 1))
        return (at - before) / step, (after - at) / step

    left, right = slopes(lambda end: recorded(t, _unloading(end, t), "accel", 60.0))
    assert np.max(np.abs(right - left)) < 1e-3 * np.max(np.abs(left))
    left, right = slopes(lambda end: cfc_recorded(t, _unloading(end, t)["accel"], 60.0))
    assert np.max(np.abs(right - left)) > 0.2 * np.max(np.abs(left))


def test_the_recorded_acceleration_is_the_fine_records_on_a_coarse_grid():
    """The acceleration recorded from the velocity's samples at 1 ms against the pulse sampled
    and filtered at 10 kHz as a test records it: as close as the acceleration's own samples are
    (test_on_a_coarse_grid_the_recording_is_the_fine_records_at_its_samples)."""
    fine = np.arange(0.0, 0.15 + 5e-5, 1e-4)
    coarse = fine[::10]
    truth = cfc_filter(np.concatenate([np.zeros(200), pulse(fine)]), 1e-4, 60.0)[200:][::10]
    dense = np.arange(0.0, 0.15 + 5e-7, 1e-6)
    velocity = 15.0 + np.concatenate([[0.0], np.cumsum(0.5 * (pulse(dense)[1:] + pulse(dense)[:-1]) * 1e-6)])
    seen = recorded(coarse, {"accel": pulse(coarse), "velocity": velocity[::1000]}, "accel", 60.0)
    assert np.max(np.abs(seen - truth)) < 0.02 * np.max(np.abs(pulse(fine)))


def test_the_fit_compares_the_acceleration_the_report_reads(tmp_path):
    """The fit's recorded acceleration (its filter's passes, from the velocity's rate at the
    nodes) is what the residual reports as the model seen through the filter, at the NLP's start,
    where the passes are the filter's of the start."""
    from builders import small_pickup_problem

    from crashnlp.case.case import Case
    from crashnlp.optimize.identify import evaluate, fit_ocp
    from crashnlp.problem import load_problem

    problem = load_problem(small_pickup_problem(tmp_path))
    spec = {"method": "multiple-shooting", "intervals": 60, "substeps": 2}  # 1 ms: the filter runs on the nodes
    ocp, fit = fit_ocp(Case(problem.with_values({"transcription": spec})))
    start = ocp.nlp.bounds()["x0"]
    (accel,) = [r for r in fit.residuals if r.channel == "accel"]
    response = evaluate(ocp, start)[0]
    model = np.asarray(ocp.nlp.evaluate([accel.model], start)[0]).ravel()
    np.testing.assert_allclose(model, accel.seen(response.time, response.outputs), rtol=1e-9, atol=1e-9 * G0)
    assert not np.allclose(model, cfc_recorded(response.time, response.outputs["accel"], 60.0)[accel.columns], atol=1e-3 * G0)
