"""ISO/TS 18571 rating: identical curves rate 1, shifted or scaled curves lower."""

import numpy as np
import pytest

from crashnlp.rating import iso18571

T = np.arange(0, 0.1, 1e-4)


def pulse(t, shift=0.0, scale=1.0):
    s = np.clip(t - shift, 0, 0.06)
    return -30 * scale * np.sin(np.pi * s / 0.06) ** 2


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


def test_mismatched_lengths_refused():
    with pytest.raises(ValueError, match="same length"):
        iso18571(T, pulse(T), pulse(T)[:-1])
