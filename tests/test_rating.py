"""ISO/TS 18571 rating: equal to the objective-rating-metrics package it transcribes; identical
curves rate 1, shifted or scaled curves lower; its compiled time warping takes the numpy one's paths."""

import time
from pathlib import Path

import numpy as np
import pytest

from crashnlp.analysis import rating, warping
from crashnlp.analysis.rating import iso18571, iso18571_each
from crashnlp.numerics.compiled import CACHE_ENV, SWITCH_ENV, cache_dir, compiler

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


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    """The compiled warping as a command gets it: the first rating finds no library, starts its
    compile and rates in numpy; a rating once the compile is done loads it."""
    if compiler() is None:
        pytest.skip("no C compiler")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(CACHE_ENV, str(tmp_path_factory.mktemp("cache")))
        mp.setenv(SWITCH_ENV, "1")
        mp.setattr(warping, "_loaded", [])
        assert warping.kernel() is None, "a library in an empty cache"
        deadline = time.monotonic() + 120
        while (lib := warping.kernel()) is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lib is not None, "the warping's compile did not finish"
        yield lib


def warping_pairs():
    """Pairs of curves for the warping, of 10 to 2001 samples: random, quantised (ties in the
    cumulative costs), constant (ties everywhere), with a nan in either curve (a row or column of
    nan costs) or in one cost only, and curves at a time shift from each other (the path runs
    along the band's edge)."""
    rng = np.random.default_rng(18571)
    for n in (10, 11, 57, 300, 2001):
        x, y = rng.standard_normal(n), rng.standard_normal(n)
        yield pytest.param(x, y, id=f"random {n}")
        yield pytest.param(np.round(2 * x), np.round(2 * y), id=f"quantised {n}")
        yield pytest.param(np.where(np.arange(n) == n // 3, np.nan, x), y, id=f"nan in x {n}")
        yield pytest.param(x, np.where(np.arange(n) == n - 2, np.nan, y), id=f"nan in y {n}")
        if n > 50:  # inf - inf: one cell's cost nan, which np.minimum spreads to every cell after it
            inf_x, inf_y = (np.where(np.arange(n) == k, np.inf, v) for k, v in ((n // 2, x), (n // 2 + 1, y)))
            yield pytest.param(inf_x, inf_y, id=f"one nan cost {n}")
        t = np.linspace(0, 1, n)
        yield pytest.param(np.sin(9 * t), np.sin(9 * (t - 0.08)), id=f"shifted {n}")
    yield pytest.param(np.ones(400), np.ones(400), id="constant")
    yield pytest.param(np.zeros(400), np.ones(400), id="constant apart")


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # nan
@pytest.mark.parametrize(("x", "y"), list(warping_pairs()))
def test_the_compiled_warping_takes_the_numpy_path(kernel, x, y):
    """The compiled warping (crashnlp.analysis.warping) and the numpy recurrence it stands in for
    give the same path, to the last index: ties broken alike, a nan spread alike."""
    band = int(np.ceil(rating.DTW_BAND * x.size)) - 1
    ours = warping.warping_path(kernel, x, y, band)
    numpy = rating._numpy_warping_paths([(x, y)], [band])[0]
    np.testing.assert_array_equal(np.stack(ours), np.stack(numpy))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the constant and nan cases divide by 0
def test_ratings_compiled_and_in_numpy_are_the_same_numbers(kernel, monkeypatch):
    """Every case of the package comparison rated with the compiled warping and without: the same bits."""
    curves = [case.values for case in CASES]
    compiled_ratings = iso18571_each(curves)
    monkeypatch.setattr(warping, "kernel", lambda: None)
    assert repr(iso18571_each(curves)) == repr(compiled_ratings)
