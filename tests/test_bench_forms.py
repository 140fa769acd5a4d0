"""bench/forms.py's measurements of the engine vans' pitch: the generator with the engine's push
on the front end's line of action (OneLineBody), the engine's share of the barrier's impulse, and
when a front end lets go (release)."""

from __future__ import annotations

import numpy as np

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
