"""ISO/TS 18571 rating: equal to the objective-rating-metrics package it transcribes; identical
curves rate 1, shifted or scaled curves lower."""

from pathlib import Path

import numpy as np
import pytest

from crashnlp.analysis import rating
from crashnlp.analysis.rating import iso18571, iso18571_each
from crashnlp.numerics.compiled import cache_dir

T = np.arange(0, 0.1, 1e-4)
SHIPPED = Path(__file__).parents[1] / "problems/data/synthetic-pickup/pickup-56kph.csv"
NAMES = ("corridor", "phase", "magnitude", "slope", "overall")


def pulse(t, shift=0.0, scale=1.0):
    s = np.clip(t - shift, 0, 0.06)
    return -30 * scale * np.sin(np.pi * s / 0.06) ** 2


def square(t):
    return np.sign(np.sin(2 * np.pi * t / 0.01 + 0.1))


def noise(t, size, seed):
    return size * np.random.default_rng(seed).standard_normal(t.size)


def shipped_cases():
    """The shipped test's four channels over 0.15 s against a model-like curve: smoother,
    1.5 ms late, 4 % larger."""
    data = np.loadtxt(SHIPPED, delimiter=",", skiprows=1)[:1500]
    t = data[:, 0]
    for k, name in enumerate(("accel", "velocity", "displacement", "pitch"), start=1):
        smooth = np.convolve(data[:, k], np.ones(25) / 25, mode="same")
        yield pytest.param(t, data[:, k], 1.04 * np.interp(t - 0.0015, t, smooth), id=f"shipped {name}")


T20 = np.arange(0, 0.15, 5e-5)
UNEVEN = np.sort(np.random.default_rng(3).uniform(0, 0.1, 700))
CASES = [
    pytest.param(T, pulse(T), pulse(T), id="identical"),
    pytest.param(T, pulse(T), pulse(T, scale=1.2), id="scaled"),
    pytest.param(T, pulse(T), pulse(T, shift=0.005), id="later"),
    pytest.param(T, pulse(T, shift=0.01), pulse(T, shift=0.003), id="earlier"),
    pytest.param(T, pulse(T), pulse(T, 0.002, 0.9) + noise(T, 1.0, 1), id="shifted scaled noisy"),
    pytest.param(T, pulse(T) + noise(T, 0.5, 2), pulse(T, -0.001, 1.1), id="noisy reference"),
    pytest.param(T, np.round(pulse(T) / 10), np.round(pulse(T, 0.001, 1.1) / 7), id="quantised (warping ties)"),
    pytest.param(T, square(T), square(T - 0.003), id="square wave (correlation ties)"),
    pytest.param(T[:12], np.sin(np.arange(12) / 3), np.cos(np.arange(12) / 3), id="12 samples"),
    pytest.param(T20, pulse(T20, 0.03), pulse(T20, 0.02, 0.8) + noise(T20, 0.3, 4), id="20 kHz, 0.15 s"),
    pytest.param(T[::5], pulse(T[::5]), pulse(T[::5], 0.004, 1.05), id="2 kHz"),
    pytest.param(UNEVEN, pulse(UNEVEN), pulse(UNEVEN, 0.001, 0.95), id="uneven sampling"),
    pytest.param(T, pulse(T), np.zeros_like(T), id="constant model"),
    pytest.param(T, pulse(T), np.where(T == T[500], np.nan, pulse(T)), id="nan in the model"),
    *shipped_cases(),
]


@pytest.fixture(scope="module")
def package_ratings(request):
    """The package's ratings of two 10 kHz curves; its numba functions are cached on disk, in
    pytest's cache (the run's crashnlp cache is new every run, and they compile for 7 s)."""
    cache = getattr(request.config, "cache", None)  # None with -p no:cacheprovider
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NUMBA_CACHE_DIR", str(cache.mkdir("numba") if cache is not None else cache_dir() / "numba"))
        dtwalign = pytest.importorskip("dtwalign")
        ISO18571 = pytest.importorskip("objective_rating_metrics.rating").ISO18571
    for module in (dtwalign.backtrack, dtwalign.cost, dtwalign.window):
        for value in vars(module).values():
            if hasattr(value, "enable_caching") and hasattr(value, "py_func"):
                value.enable_caching()

    def ratings(ref, mod):
        t = rating.ISO_DT * np.arange(ref.size)
        r = ISO18571(np.column_stack([t, ref]), np.column_stack([t, mod]), dt=rating.ISO_DT)
        return {name: float(getattr(r, f"{name}_rating")(ndigits=-1)) for name in NAMES}

    return ratings


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the constant and nan cases divide by 0
@pytest.mark.parametrize(("t", "reference", "model"), CASES)
def test_equals_the_package(package_ratings, monkeypatch, t, reference, model):
    ours = iso18571(t, reference, model)
    monkeypatch.setattr(rating, "_ratings_each", lambda curves: [package_ratings(*c) for c in curves])  # the package's
    theirs = iso18571(t, reference, model)
    np.testing.assert_allclose([ours[k] for k in NAMES], [theirs[k] for k in NAMES], rtol=0, atol=1e-6, equal_nan=True)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the nan case divides by nan
def test_curves_rated_together_get_each_its_own_numbers():
    """Rated together, curves of other lengths and warping bands share one cost array: each gets,
    to the bit, the ratings it gets alone, and a curve with a nan spoils no other's."""
    short = T[:700]
    curves = [
        (T, pulse(T), pulse(T, 0.001, 0.95)),
        (short, pulse(short), pulse(short, 0.002, 1.1)),
        (T, pulse(T), np.where(T == T[500], np.nan, pulse(T))),
        (UNEVEN, pulse(UNEVEN), pulse(UNEVEN, 0.001, 0.95)),
        (T20, pulse(T20), pulse(T20, 0.003)),
    ]
    together = [[r[k] for k in NAMES] for r in iso18571_each(curves)]
    np.testing.assert_array_equal(together, [[iso18571(*c)[k] for k in NAMES] for c in curves])


def test_identical_scaled_shifted_and_resampled():
    ref = pulse(T)
    same = iso18571(T, ref, ref)
    assert same == {"corridor": 1.0, "phase": 1.0, "magnitude": 1.0, "slope": 1.0, "overall": 1.0}
    scaled = iso18571(T, ref, pulse(T, scale=1.2))
    assert scaled["phase"] == 1.0 and scaled["magnitude"] < 0.95 and scaled["corridor"] < 0.95
    shifted = iso18571(T, ref, pulse(T, shift=0.005))
    assert shifted["phase"] < 0.9 and shifted["overall"] < 0.95
    worse = iso18571(T, ref, pulse(T, shift=0.01, scale=1.3))
    assert worse["overall"] < min(scaled["overall"], shifted["overall"])
    coarse = T[::5]  # 2 kHz grid is resampled to 10 kHz
    assert iso18571(coarse, pulse(coarse), pulse(coarse))["overall"] == pytest.approx(1.0)


@pytest.mark.parametrize("delay", [0.001, 0.005, 0.012])
def test_a_pure_delay_costs_phase_in_proportion(delay):
    """A pulse delayed within a quiet record is found exactly: phase falls linearly, to 0 at
    a fifth of the record, and the overlapped curves are equal (magnitude and slope 1, to rounding)."""
    r = iso18571(T, pulse(T, 0.02), pulse(T, 0.02 + delay))
    assert r["phase"] == pytest.approx(1 - delay / (0.2 * T.size * rating.ISO_DT))
    assert r["magnitude"] == pytest.approx(1.0, abs=1e-12) and r["slope"] == pytest.approx(1.0, abs=1e-12)


def test_mismatched_lengths_refused():
    with pytest.raises(ValueError, match="same length"):
        iso18571(T, pulse(T), pulse(T)[:-1])
