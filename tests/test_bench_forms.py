"""bench/forms.py's measurements of the engine vans' pitch: the generator with the engine's push
on the front end's line of action (OneLineBody), the engine's share of the barrier's impulse, and
when a front end lets go (release)."""

from __future__ import annotations

import math

import numpy as np

from bench import report
from bench.corpus import simulate, tall_engine_vehicle, tall_vehicle
from bench.cross_speed import at_speed
from bench.forms import OneLineBody, engine_pitch, release


def test_without_an_engine_the_one_line_body_is_the_generator():
    v = tall_vehicle(0, 7, speed=60 / 3.6)
    a, b = simulate(v), simulate(v, OneLineBody)
    assert np.array_equal(a["pitch"], b["pitch"]) and not a["engine_force"].any()


def test_the_engine_pitches_a_one_force_body_only_once_it_meets_the_barrier():
    """Below the speed at which the engine reaches the barrier it takes none of the impulse and
    adds no pitch; above it, its push on the front end's line pitches the body nose-down further,
    and the generator's own pitch is unchanged before the push starts."""
    v = tall_engine_vehicle(0, 7, speed=60 / 3.6)
    slow, fast = engine_pitch(v, 40.0), engine_pitch(v, 64.0)
    assert slow == {"impulse_share": 0.0, "pitch_rms_deg": 0.0}
    assert 0.1 < fast["impulse_share"] < 0.7 and fast["pitch_rms_deg"] > 1.0
    real, one = simulate(at_speed(v, 64.0)), simulate(at_speed(v, 64.0), OneLineBody)
    before = real["time"] < real["time"][np.flatnonzero(real["engine_force"] > 0)[0]]
    assert np.allclose(real["pitch"][before], one["pitch"][before], atol=1e-9)
    assert np.max(one["pitch"] - real["pitch"]) > 0


def test_release_is_the_last_let_go_and_the_velocity_then():
    t = np.arange(6.0)
    assert release(t, -t, np.array([0, 1, 2, 0, 3, 0.0])) == (5.0, -5.0)
    assert release(t, t, np.array([0, 1, 2, 0, 3, 1.0])) == (None, None)
    assert release(t, t, np.zeros(6)) == (None, None)


def test_the_report_says_how_fast_a_prediction_and_its_generator_let_go():
    f = {"lift_off_s": 0.0984, "lift_off_mps": 0.0856, "truth_prediction_lift_off_s": None}
    f |= {"truth_release_s": 0.0978, "truth_release_mps": -0.0739}
    assert report._lift_off_cell(f) == "98.4 at +0.086 m/s (generator lets go at 97.8 at -0.074 m/s)"
    assert report._lift_off_cell({**f, "truth_prediction_lift_off_s": 0.0721}) == "98.4 at +0.086 m/s (generator 72.1)"
    assert report._lift_off_cell({**f, "lift_off_s": None}) == ""


def test_the_report_gives_a_stop_where_only_the_prediction_has_one():
    """A prediction whose loading ends as it lets go has a stop where its drifting generator has
    none: the cell gives the prediction's, not "no stop"."""
    assert report._stop_cell({"stop_err_s": 0.00425, "stop_s": 0.0984}) == "+4.25"
    assert report._stop_cell({"stop_err_s": math.nan, "stop_s": 0.0715}) == "at 71.5, the generator none"
    assert report._stop_cell({"stop_err_s": math.nan, "stop_s": math.nan}) == "no stop"


def test_the_report_tables_each_engine_vans_pitch_fits():
    fit, failed = {"status": "ok", "pitch_rmse_deg": 1.234}, {"status": "Maximum_Iterations_Exceeded"}
    engine = {"40": {"impulse_share": 0.0, "pitch_rms_deg": 0.0}, "64": {"impulse_share": 0.4, "pitch_rms_deg": 6.0}}
    vans = [
        {"vehicle": f"te0{i}", "engine": engine, "one_speed": {"40": fit, "64": failed}, "variants": {"default": fit}}
        for i in range(2)
    ]
    lines = report._pitch_floor_md({"vans": vans, "summary": {}})
    rows = [line for line in lines if line.startswith("| te0")]
    assert len(rows) == 2 and rows[0] == "| te00 | 0 % / 0.0 | 40 % / 6.0 | 1.23 | Maximum_Iterations_Exceeded | 1.23 |"
    assert report._pitch_floor_md({"vans": [], "summary": {}}) == []
