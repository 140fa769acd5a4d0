"""The model's outputs as a crash test's instrumentation records them: CFC filtered.

A test's accelerometers (and load cells) are filtered to SAE J211 over the whole record, from
before impact on; the data a fit compares with, and the metrics reported of them (peak, OLC,
ISO 18571), are of the filtered signal. The model's samples are not filtered by anything, so a
fit that compares them with the data asks an unfiltered pulse to match a filtered one: even a
fit of the model's own data then misses its parameters, and the model's peak is compared with a
rounded one. `cfc_recorded` applies to the model's samples what the data went through:

- before impact the channel reads zero (the vehicle at rest in its own frame: no deceleration,
  no wall force, no pitch), so the record the filter sees starts PRE_IMPACT seconds earlier at
  zero, and the model's value at impact is a step from it, as the accelerometer's is;
- between the samples the signal is linear, on a grid RATE_FACTOR times finer than needed for
  the filter class to be sampled well (at least ten samples per period of the class's -3 dB
  frequency; the model's own grid where that is fine enough already);
- then `crashnlp.data.signal.cfc_filter`, the same zero-phase two-pass J211 Butterworth the
  data get, and the result is read at the model's samples.

Where the filter runs on the model's grid itself (`from_velocity`), the acceleration is given to it
as the velocity's rate (`rate`), not as the model's acceleration at the samples: the two agree to
fourth order where the pulse is smooth, but a sample of the acceleration jumps in slope, as a
function of the parameters, whenever an event of the pulse (the end of contact, a spring
breakpoint, the force at zero crush on its bound) crosses it, and a fit whose recorded residuals
hang on such a sample steps the event across it and back without end. The velocity's samples are
the NLP's states: the rate is linear in them, and the events act only through the integration
between the nodes (at impact too, where the rate, one sided, is the step from rest that the front
end's first millimetre makes within tens of microseconds; the sample there holds half of it,
`acceleration`).

Every step is linear in the samples, so on a fixed grid it is a matrix, but a dense one (the
filter's response lasts tens of samples each way), and a fit's Gauss-Newton Hessian would
couple every node through it. A fit instead holds the filter's two passes to their own
equations, banded (`Recording`, crashnlp.optimize.fit): the same numbers, a few nonzeros a row.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from crashnlp.data.signal import cfc_coefficients, cfc_filter, from_rest

AT_REST = ("accel", "barrier_force", "pitch")  # channels that read zero before impact
PRE_IMPACT = 0.02  # s of zero record before impact (the CFC 60 filter's response lasts about 10 ms)
CORNER = 5.0 / 3.0  # the -3 dB frequency of a CFC class, per unit of its class number
SAMPLES_PER_PERIOD = 10  # of the -3 dB frequency, at least, where the filter runs
PAD = 0.01  # s of odd reflection past the record's end (cfc_filter's `pad`)
RECORDED = ".recorded"  # the ending of the NLP's blocks of a recording's passes (states of the sensitivities)


def _steps(dt: float, cfc: float) -> int:
    """Filter steps per sample interval: the fewest that put SAMPLES_PER_PERIOD samples in a
    period of the class's -3 dB frequency."""
    return max(1, math.ceil(dt * SAMPLES_PER_PERIOD * CORNER * cfc - 1e-9))


def _grid(time: np.ndarray, cfc: float) -> tuple[int, float, int]:
    """Filter steps per sample interval, the filter's sample interval and the zero record's length."""
    steps = _steps(float(time[1] - time[0]), cfc)
    fine_dt = float(time[1] - time[0]) / steps
    return steps, fine_dt, math.ceil(PRE_IMPACT / fine_dt)


def cfc_recorded(time: np.ndarray, values: np.ndarray, cfc: float) -> np.ndarray:
    """A model output sampled on a uniform grid from impact (`time[0] = 0`, zero before), filtered
    at CFC `cfc` as the test's record of it is, at the same samples."""
    time, values = np.asarray(time, dtype=float), np.asarray(values, dtype=float)
    steps, fine_dt, before = _grid(time, cfc)
    fine = np.arange((time.size - 1) * steps + 1) * fine_dt + time[0]
    record = np.concatenate([np.zeros(before), np.interp(fine, time, values)])
    return cfc_filter(record, fine_dt, cfc, PAD)[before::steps]


def rate(values: np.ndarray, dt: float) -> np.ndarray:
    """The rate of samples (along the first axis, `dt` apart): fourth-order central differences,
    second order where a side has fewer than two samples (one sided at the ends, so that no
    stencil reaches across the step at impact); first order of two samples. Of the identity, its
    matrix."""
    v = np.asarray(values, dtype=float)
    if v.shape[0] < 3:
        return np.broadcast_to((v[-1] - v[0]) / dt, v.shape).copy()
    out = np.empty_like(v)
    out[0] = (-3.0 * v[0] + 4.0 * v[1] - v[2]) / (2.0 * dt)
    out[-1] = (v[-3] - 4.0 * v[-2] + 3.0 * v[-1]) / (2.0 * dt)
    out[1:-1] = (v[2:] - v[:-2]) / (2.0 * dt)
    out[2:-2] = (v[:-4] - 8.0 * v[1:-3] + 8.0 * v[3:-1] - v[4:]) / (12.0 * dt)
    return out


def acceleration(velocity: np.ndarray, dt: float) -> np.ndarray:
    """The acceleration samples a record is made of, from the velocity's samples on a uniform grid
    from impact (along the first axis): the velocity's `rate`, and at impact half of it, since a
    sample stands for the interval about it and half of that lies before impact, at rest (the
    step half a sample late or early otherwise; 0.4 g off at impact on the pickup's fitted pulse,
    0.1 g so)."""
    out = rate(velocity, dt)
    out[0] *= 0.5
    return out


def from_velocity(name: str, time: np.ndarray, cfc: float) -> bool:
    """Whether the output `name` on `time` is recorded from the velocity's samples (`acceleration`):
    the acceleration, where the filter runs on the grid itself (`_steps`). On a coarser grid a
    step's quadrature error where it crosses a bend of the force law (its velocity a few mm/s off,
    over a few ms) would be read as acceleration: the acceleration's own samples are recorded there."""
    return name == "accel" and _steps(float(time[1] - time[0]), cfc) == 1


def recorded(time: np.ndarray, outputs: Mapping[str, np.ndarray], name: str, cfc: float) -> np.ndarray:
    """The model's output `name` on a uniform grid from impact as the test records it at CFC `cfc`:
    `cfc_recorded` of its samples, the acceleration's made from the velocity's where `from_velocity`."""
    values = acceleration(outputs["velocity"], float(time[1] - time[0])) if from_velocity(name, time, cfc) else outputs[name]
    return cfc_recorded(time, np.asarray(values, dtype=float), cfc)


@dataclass(frozen=True)
class Recording:
    """`cfc_recorded` on a fixed grid as the filter's own equations, linear and banded, for an NLP.

    The record the filter passes over is `extend @ y` (y the samples: joined linearly onto the
    filter's grid from impact on, then cfc_filter's odd reflection past the end); the forward
    pass u solves `lower(a) u = lower(b) record` from rest (before impact the record is zero, and
    so is the pass); the backward pass s, over u reversed, solves `lower(a) s = lower(b) u[::-1] +
    start * u[-1]` (cfc_filter starts each pass in steady state); the recorded samples are
    `s[at]`. Equal to `cfc_recorded` (tested), with a few nonzeros a row where its matrix is dense.
    """

    extend: np.ndarray  # record samples x y samples
    a: np.ndarray  # the biquad's denominator (a[0] = 1)
    b: np.ndarray  # its numerator
    start: np.ndarray  # the backward pass's first rows, per unit of u's last sample
    at: np.ndarray  # the samples of s (reversed time) at the grid's

    @property
    def size(self) -> int:
        return self.extend.shape[0]

    def lower(self, taps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The banded lower-triangular Toeplitz matrix of a biquad's three taps, as the rows,
        columns and values of its nonzeros (size x size)."""
        n = self.size
        parts = [(np.arange(k, n), np.arange(n - k), np.full(n - k, taps[k])) for k in range(3) if taps[k]]
        rows, cols, values = (np.concatenate(column) for column in zip(*parts))
        return rows, cols, values

    def solve(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The forward and backward passes (u, s) of `values` at the grid's samples, each by the
        biquad's recursion from rest (a dense solve of the same equations waits on the BLAS
        threads of a busy machine: 80 ms a fit, measured)."""
        u = from_rest(self._numerator(self.extend @ np.asarray(values, dtype=float)), self.a)
        return u, from_rest(self._numerator(u[::-1]) + self.start * u[-1], self.a)

    def _numerator(self, x: np.ndarray) -> np.ndarray:
        """lower(b) @ x: the numerator's taps over x, zero before its start."""
        return np.convolve(x, self.b)[: x.size]


def recording(time: np.ndarray, cfc: float) -> Recording:
    """The Recording of samples on `time` (uniform, from impact) at CFC `cfc`."""
    steps, fine_dt, before = _grid(time, cfc)
    fine = np.arange((time.size - 1) * steps + 1) * fine_dt
    interp = np.column_stack([np.interp(fine, time - time[0], unit) for unit in np.eye(time.size)])
    record = np.vstack([np.zeros((before, time.size)), interp])  # what cfc_filter gets
    pad = min(record.shape[0] - 1, max(1, int(round(PAD / fine_dt))))
    reflected = 2.0 * record[-1] - record[-2 : -pad - 2 : -1]
    b, a = cfc_coefficients(cfc, fine_dt)
    gain = b.sum() / math.fsum(a)  # the steady state's output per unit input
    start = np.zeros(interp.shape[0] + pad)
    start[0] = b[1] + b[2] - (a[1] + a[2]) * gain
    start[1] = b[2] - a[2] * gain
    at = start.size - 1 - steps * np.arange(time.size)
    return Recording(np.vstack([interp, reflected]), a, b, start, at)
