"""CFC filters against J211-1 response and an independent scipy design; bias, integration, resampling."""

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from crashnlp.data import Channel, DataError
from crashnlp.data.signal import cfc_coefficients, cfc_filter, integrate, remove_bias, resample

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
