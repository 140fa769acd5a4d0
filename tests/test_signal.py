"""CFC filters against J211-1 response, scipy's filtfilt and an independent scipy design; bias, integration, resampling."""

from decimal import Decimal, localcontext

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid
from scipy.signal import butter, filtfilt

from crashnlp.data import Channel, DataError
from crashnlp.data.signal import cfc_coefficients, cfc_filter, cumtrapz, integrate, remove_bias, resample

DT = 1e-4  # 10 kHz


def gain_db(cfc: float, freq: float, dt: float) -> float:
    """Steady-state gain of the forward-backward filter at `freq`, measured in the record's middle."""
    t = np.arange(0, 0.5, dt)
    y = cfc_filter(np.sin(2 * np.pi * freq * t), dt, cfc)
    mid = slice(t.size // 4, 3 * t.size // 4)
    return 20 * np.log10(np.sqrt(2) * np.std(y[mid]))


@pytest.mark.parametrize("cfc", [60, 180, 600, 1000])
def test_cfc_response_meets_j211_corridor(cfc):
    dt = 1 / (40 * cfc)  # well above the J211 minimum rate, so the bilinear warp stays small
    assert abs(gain_db(cfc, 0.1 * cfc, dt)) < 0.1  # flat pass band
    assert -1.0 < gain_db(cfc, cfc, dt) < 0.5  # J211-1 corridor at F_H = CFC
    assert gain_db(cfc, 5 / 3 * cfc, dt) == pytest.approx(-3.0, abs=0.3)  # -3 dB at 1.667 CFC
    assert gain_db(cfc, 10 * cfc, dt) < -45  # 2+2 poles: -40 dB/decade


@pytest.mark.parametrize("cfc", [60, 180, 1000])
def test_cfc_matches_scipy_butterworth_with_prewarped_cutoff(cfc):
    b, a = butter(2, 2.0775 * cfc, fs=1 / DT)
    b_j, a_j = cfc_coefficients(cfc, DT)
    np.testing.assert_allclose(b_j, b, rtol=1e-10)
    np.testing.assert_allclose(a_j, a, rtol=1e-10, atol=1e-14)
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=4000)) + 20 * np.sin(2 * np.pi * 50 * np.arange(4000) * DT)
    ours = cfc_filter(x, DT, f"CFC{cfc}")
    ref = filtfilt(b, a, x, padtype="odd", padlen=100)
    interior = slice(400, -400)
    assert np.max(np.abs(ours[interior] - ref[interior])) < 1e-6 * np.max(np.abs(x))


def signal(kind: str, size: int, dt: float) -> np.ndarray:
    """Test inputs: a noisy random walk, a step, a noisy crash pulse (haversine deceleration, offset)."""
    rng = np.random.default_rng(size)
    t = np.arange(size) * dt
    if kind == "random":
        return np.cumsum(rng.normal(size=size)) + 5 * rng.normal(size=size)
    if kind == "step":
        return np.where(np.arange(size) > size // 3, 100.0, -3.0)
    pulse = -300 * np.sin(np.pi * t / (size * dt)) ** 2
    return 2.0 + pulse + 10 * rng.normal(size=size)


def scipy_cfc(x: np.ndarray, dt: float, cfc: float, pad: float = 0.01) -> np.ndarray:
    """The J211-1 biquad through scipy's filtfilt, padded as cfc_filter pads."""
    b, a = cfc_coefficients(cfc, dt)
    return filtfilt(b, a, x, padtype="odd", padlen=min(x.size - 1, max(1, round(pad / dt))))


def fastest_dt(cfc: float) -> float:
    """A sample interval near the coarsest J211-1 allows (wd T / 2 at 0.9 pi / 2): poles far from 1."""
    return 0.9 / (2 * 2.0775 * cfc)


@pytest.mark.parametrize("kind", ["random", "step", "pulse"])
@pytest.mark.parametrize("size", [1, 2, 7, 150, 3000, 20001])  # up to 150: the pad is capped by the length
@pytest.mark.parametrize("dt", [1e-5, 1e-4, "fastest"])
@pytest.mark.parametrize("cfc", [60, 180, 600, 1000])
def test_cfc_filter_equals_scipy_filtfilt(cfc, dt, size, kind):
    dt = fastest_dt(cfc) if dt == "fastest" else dt
    x = signal(kind, size, dt)
    ours = cfc_filter(x, dt, cfc)
    assert ours.shape == x.shape
    assert np.max(np.abs(ours - scipy_cfc(x, dt, cfc))) <= 1e-10 * np.max(np.abs(x))


def exact_cfc(x: np.ndarray, dt: float, cfc: float, pad: float = 0.01) -> np.ndarray:
    """The same filter (odd padding, steady start, forward then backward) in 40-digit decimal arithmetic."""
    b, a = (list(map(Decimal, map(float, c))) for c in cfc_coefficients(cfc, dt))
    pad_n = min(x.size - 1, max(1, round(pad / dt)))
    with localcontext() as context:
        context.prec = 40
        u = list(map(Decimal, map(float, x)))
        ext = [2 * u[0] - v for v in u[pad_n:0:-1]] + u + [2 * u[-1] - v for v in u[-2 : -pad_n - 2 : -1]]
        for _ in range(2):
            x1 = x2 = ext[0]
            y1 = y2 = ext[0] * sum(b) / sum(a)
            out = []
            for v in ext:
                y1, y2 = b[0] * v + b[1] * x1 + b[2] * x2 - a[1] * y1 - a[2] * y2, y1
                x1, x2 = v, x1
                out.append(y1)
            ext = out[::-1]
        return np.array([float(v) for v in ext[pad_n : pad_n + x.size]])


def test_poles_near_one_lose_no_digits():
    # CFC 60 at 1 MHz: poles 6e-4 from 1, a DC gain of 1e6 in the all-pole part; the direct form
    # (scipy's lfilter) is off by 1e-12 to 1e-10 of the peak here
    dt, x = 1e-6, signal("pulse", 400, 1e-6)
    assert np.max(np.abs(cfc_filter(x, dt, 60) - exact_cfc(x, dt, 60))) < 1e-13 * np.max(np.abs(x))


def sine_gain(cfc: float, freq: float, dt: float) -> float:
    """Amplitude ratio of a sine through the filter, by least squares on the record's middle half."""
    t = np.arange(0, max(0.2, 10 / freq), dt)
    y = cfc_filter(np.sin(2 * np.pi * freq * t), dt, cfc)
    mid = slice(t.size // 4, 3 * t.size // 4)
    basis = np.stack([np.sin(2 * np.pi * freq * t[mid]), np.cos(2 * np.pi * freq * t[mid])], axis=1)
    return float(np.hypot(*np.linalg.lstsq(basis, y[mid], rcond=None)[0]))


def biquad_power(cfc: float, freq: float, dt: float) -> float:
    """|H(e^jwT)|^2 of one pass: the amplitude ratio of the forward-backward pair."""
    b, a = cfc_coefficients(cfc, dt)
    z = np.exp(-2j * np.pi * freq * dt * np.arange(3))
    return float(abs(b @ z / (a @ z)) ** 2)


@pytest.mark.parametrize("cfc", [60, 180, 600, 1000])
def test_sine_gain_is_the_squared_biquad_response(cfc):
    dt = 1 / (40 * cfc)
    for ratio in (0.1, 1.0, 5 / 3, 10.0):
        assert sine_gain(cfc, ratio * cfc, dt) == pytest.approx(biquad_power(cfc, ratio * cfc, dt), rel=1e-6, abs=1e-9)
    assert sine_gain(cfc, 0.1 * cfc, dt) == pytest.approx(1.0, abs=1e-4)  # pass band
    assert sine_gain(cfc, 5 / 3 * cfc, dt) ** 2 == pytest.approx(0.5, rel=0.01)  # -3 dB at 1.667 CFC
    assert sine_gain(cfc, 10 * cfc, dt) < 1e-3  # 2 + 2 poles: -40 dB/decade and more


def test_dc_passes_unchanged_at_every_length():
    for size in (1, 2, 5, 1000, 30000):
        # CFC 60 at 100 kHz: the rounded coefficients' DC gain is 1 - 2e-13 per pass (scipy's filtfilt too)
        np.testing.assert_allclose(cfc_filter(np.full(size, -7.25), 1e-5, 60), -7.25, rtol=1e-11)


def test_filter_refuses_an_empty_signal():
    with pytest.raises(ValueError, match="empty"):
        cfc_filter(np.zeros(0), DT, 60)


def test_cumtrapz_equals_scipy_on_an_uneven_grid():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(1e-5, 1e-3, size=500))
    v = rng.normal(size=500)
    np.testing.assert_allclose(cumtrapz(t, v), cumulative_trapezoid(v, t, initial=0.0), rtol=1e-13, atol=1e-15)
    assert cumtrapz(t[:1], v[:1]).tolist() == [0.0]


def test_filter_keeps_constant_and_ramp_to_the_ends():
    t = np.arange(0, 0.1, DT)
    np.testing.assert_allclose(cfc_filter(np.full(t.size, 3.0), DT, 60), 3.0, rtol=1e-9)
    ramp = 5.0 + 40.0 * t
    np.testing.assert_allclose(cfc_filter(ramp, DT, 60), ramp, atol=1e-3)  # start-up transient decays in the pad


def test_filter_refuses_too_low_sample_rate():
    with pytest.raises(ValueError, match="sample rate"):
        cfc_filter(np.zeros(100), 1e-2, 60)


def test_bias_removal_uses_only_the_window():
    t = np.arange(-0.01, 0.05, DT)
    x = 0.7 + np.where(t > 0, -100 * t, 0.0)
    y = remove_bias(t, x, (-0.01, 0.0))
    assert abs(y[t <= 0]).max() < 1e-12
    assert y[-1] == pytest.approx(x[-1] - 0.7)
    with pytest.raises(ValueError, match="no samples"):
        remove_bias(t, x, (1.0, 2.0))


def test_integration_of_half_sine_pulse_is_exact_to_discretisation():
    # a = -A sin(pi t / T) on [0, T]: v = v0 - A T/pi (1 - cos), x = v0 t - A T/pi (t - T/pi sin)
    A, T, v0 = 300.0, 0.08, 15.0
    t = np.arange(-0.01, T + 1e-12, 1e-5)
    on = t >= 0
    a = np.where(on, -A * np.sin(np.pi * t / T), 0.0)
    v, x = integrate(t, a, v0)
    v_true = np.where(on, v0 - A * T / np.pi * (1 - np.cos(np.pi * t / T)), v0)
    x_true = np.where(on, v0 * t - A * T / np.pi * (t - T / np.pi * np.sin(np.pi * t / T)), v0 * t)
    np.testing.assert_allclose(v, v_true, atol=1e-5)
    np.testing.assert_allclose(x, x_true, atol=1e-6)
    with pytest.raises(ValueError, match="outside the record"):
        integrate(t[t > 0.01], a[t > 0.01], v0)


def test_resample_interpolates_and_refuses_extrapolation():
    ch = Channel(np.array([0.0, 1.0, 2.0]), np.array([0.0, 10.0, 0.0]), "m", "test.csv:x")
    np.testing.assert_allclose(resample(ch, np.array([0.0, 0.5, 1.5, 2.0])), [0, 5, 5, 0])
    with pytest.raises(DataError, match="test.csv:x"):
        resample(ch, np.array([0.0, 2.5]))
