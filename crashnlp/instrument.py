"""The model's outputs as a crash test's instrumentation records them: CFC filtered.

A test's accelerometers (and load cells) are filtered to SAE J211 over the whole record, from
before impact on; the data a fit compares with, and the metrics reported of them (peak, OLC,
ISO 18571), are of the filtered signal. The model's samples are not filtered by anything, so a
fit that compares them with the data asks an unfiltered pulse to match a filtered one: even a
fit of the model's own data then misses its parameters, and the model's peak is compared with a
rounded one. `as_recorded` applies to the model's samples what the data went through:

- before impact the channel reads zero (the vehicle at rest in its own frame: no deceleration,
  no wall force, no pitch), so the record the filter sees starts PRE_IMPACT seconds earlier at
  zero, and the model's value at impact is a step from it, as the accelerometer's is;
- between the samples the signal is linear, on a grid RATE_FACTOR times finer than needed for
  the filter class to be sampled well (at least ten samples per period of the class's -3 dB
  frequency; the model's own grid where that is fine enough already);
- then `crashnlp.data.signal.cfc_filter`, the same zero-phase two-pass J211 Butterworth the
  data get, and the result is read at the model's samples.

Every step is linear in the samples, so on a fixed grid it is a matrix (`recording_matrix`):
the fit's objective multiplies the model's samples by it (crashnlp.optimize.fit).
"""

from __future__ import annotations

import math

import numpy as np

from crashnlp.data.signal import cfc_filter

AT_REST = ("accel", "barrier_force", "pitch")  # channels that read zero before impact
PRE_IMPACT = 0.02  # s of zero record before impact (the CFC 60 filter's response lasts about 10 ms)
CORNER = 5.0 / 3.0  # the -3 dB frequency of a CFC class, per unit of its class number
SAMPLES_PER_PERIOD = 10  # of the -3 dB frequency, at least, where the filter runs


def _steps(dt: float, cfc: float) -> int:
    """Filter steps per sample interval: the fewest that put SAMPLES_PER_PERIOD samples in a
    period of the class's -3 dB frequency."""
    return max(1, math.ceil(dt * SAMPLES_PER_PERIOD * CORNER * cfc - 1e-9))


def as_recorded(time: np.ndarray, values: np.ndarray, cfc: float) -> np.ndarray:
    """A model output sampled on a uniform grid from impact (`time[0] = 0`, zero before), filtered
    at CFC `cfc` as the test's record of it is, at the same samples."""
    time, values = np.asarray(time, dtype=float), np.asarray(values, dtype=float)
    dt = float(time[1] - time[0])
    steps = _steps(dt, cfc)
    fine_dt = dt / steps
    before = math.ceil(PRE_IMPACT / fine_dt)
    fine = np.arange((time.size - 1) * steps + 1) * fine_dt + time[0]
    record = np.concatenate([np.zeros(before), np.interp(fine, time, values)])
    return cfc_filter(record, fine_dt, cfc)[before::steps]


def recording_matrix(time: np.ndarray, cfc: float) -> np.ndarray:
    """The matrix R with R @ values = as_recorded(time, values, cfc) for every `values` on `time`:
    `as_recorded` of each unit sample (it is linear)."""
    return np.column_stack([as_recorded(time, unit, cfc) for unit in np.eye(len(time))])
