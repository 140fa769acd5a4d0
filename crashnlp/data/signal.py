"""Signal processing of crash channels: SAE J211-1 / ISO 6487 CFC filters, bias, integration, resampling."""

from __future__ import annotations

import math

import numpy as np

from crashnlp.base.choices import CFC_CLASSES
from crashnlp.data.channels import Channel, DataError


def cfc_coefficients(cfc: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Numerator b and denominator a of one pass of the J211-1 Appendix C 2-pole Butterworth.

    wd = 2 pi CFC 2.0775, wa = tan(wd T / 2), a0 = wa^2 / (1 + sqrt2 wa + wa^2), a1 = 2 a0, a2 = a0,
    b1 = -2 (wa^2 - 1) / (1 + sqrt2 wa + wa^2), b2 = (-1 + sqrt2 wa - wa^2) / (1 + sqrt2 wa + wa^2),
    Y[t] = a0 X[t] + a1 X[t-1] + a2 X[t-2] + b1 Y[t-1] + b2 Y[t-2].
    Run forward and backward this gives -3 dB at 1.667 CFC (100 Hz for CFC 60).
    """
    wd = 2.0 * np.pi * cfc * 2.0775
    if wd * dt / 2.0 >= np.pi / 2.0:
        raise ValueError(f"CFC {cfc:g} needs a sample rate above {2 * 2.0775 * cfc:g} Hz")
    wa = np.tan(wd * dt / 2.0)
    den = 1.0 + np.sqrt(2.0) * wa + wa**2
    a0 = wa**2 / den
    b1 = -2.0 * (wa**2 - 1.0) / den
    b2 = (-1.0 + np.sqrt(2.0) * wa - wa**2) / den
    # lfilter form: a[0] y[n] = sum b x - a[1] y[n-1] - a[2] y[n-2]
    return np.array([a0, 2.0 * a0, a0]), np.array([1.0, -b1, -b2])


def _recurse(inputs: np.ndarray, s: float, a2: float, y: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The all-pole recursion in delta form down the rows of `inputs` (L x columns), all columns at once.

    y[i] = v[i] - a1 y[i-1] - a2 y[i-2] written as d[i] = v[i] - s y[i-1] + a2 d[i-1],
    y[i] = y[i-1] + d[i] with s = 1 + a1 + a2 and d the step: with poles near 1 (low CFC,
    high sample rate) the direct form loses digits to cancellation, this form does not.
    Starts from y[-1] = `y`, d[-1] = `d` (one per column); returns y (L x columns) and the last d.
    """
    ys = np.empty(inputs.shape)
    for i, row in enumerate(inputs):
        d = row - s * y + a2 * d
        y = np.add(y, d, out=ys[i])
    return ys, d


def _carried(ends: tuple[np.ndarray, np.ndarray], free_ends: np.ndarray, y_before: float) -> np.ndarray:
    """The state (y, d) before each block (2 x blocks), carried from the steady state (y_before, 0).

    A block's end state is its forced end state plus its free response to the state before it
    (`free_ends`: rows y and d at the block's end, columns the response to unit y and unit d).
    """
    (yy, yd), (dy, dd) = free_ends.tolist()
    y, d = y_before, 0.0
    states = []
    for y_end, d_end in zip(ends[0].tolist(), ends[1].tolist()):
        states.append((y, d))
        y, d = y_end + yy * y + yd * d, d_end + dy * y + dd * d
    return np.array(states).T


def _all_pole(v: np.ndarray, s: float, a2: float, y_before: float) -> np.ndarray:
    """y[n] = v[n] - a1 y[n-1] - a2 y[n-2] (s = 1 + a1 + a2) from y[-1] = y[-2] = `y_before`: exact, no loop per sample.

    The signal is cut into ~2 sqrt(n) blocks of L ~ sqrt(n) / 2 samples, the columns of an
    L x blocks array (more blocks than rows: a step down the rows costs more than one from
    block to block). The recursion runs down the rows for all blocks at once, each block from
    rest, and for the two free responses to a unit state; the state before each block is then
    carried block to block, and each block gets its free response to it. ~2.5 sqrt(n) Python
    steps, and no matrix product (no BLAS threads to stall when the cores are busy).
    """
    blocks = max(1, int(2 * np.sqrt(v.size)))
    length = -(-v.size // blocks)
    inputs = np.zeros(blocks * length)
    inputs[: v.size] = v
    out, d_end = _recurse(inputs.reshape(blocks, length).T, s, a2, np.zeros(blocks), np.zeros(blocks))
    free, free_d_end = _recurse(np.zeros((length, 2)), s, a2, np.array([1.0, 0.0]), np.array([0.0, 1.0]))
    states = _carried((out[-1], d_end), np.array([free[-1], free_d_end]), y_before)
    out += np.outer(free[:, 0], states[0])
    out += np.outer(free[:, 1], states[1])
    return out.T.ravel()[: v.size]


def from_rest(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """y[n] = v[n] - a1 y[n-1] - a2 y[n-2] (a = [1, a1, a2]) from rest: a biquad's denominator
    alone, as `_all_pole` runs it (no loop per sample, no dense solve)."""
    return _all_pole(np.asarray(v, dtype=float), math.fsum(a), a[2], 0.0)


def _steady_pass(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """One causal pass of the biquad (b, a with a0 = 1) over `x`, started in steady state for x[0]:
    as if x had always been x[0] before (scipy's lfilter with zi = lfilter_zi(b, a) x[0])."""
    past = np.concatenate((np.full(2, x[0]), x))
    v = b[0] * past[2:] + b[1] * past[1:-1] + b[2] * past[:-2]
    s = math.fsum(a)  # 1 + a1 + a2 rounded once: it is small, the DC gain is sum(b) / s
    return _all_pole(v, s, a[2], x[0] * b.sum() / s)


def _odd_extension(x: np.ndarray, n: int) -> np.ndarray:
    """`x` with `n` samples added at each end, reflected about the end values (keeps value and slope)."""
    if n == 0:
        return x
    return np.concatenate((2 * x[0] - x[n:0:-1], x, 2 * x[-1] - x[-2 : -n - 2 : -1]))


def cfc_filter(values: np.ndarray, dt: float, cfc: float | str, pad: float = 0.01) -> np.ndarray:
    """Zero-phase CFC filter of a uniformly sampled signal (sample interval `dt` in s).

    The J211-1 biquad run forward then backward, as scipy's filtfilt(padtype="odd") does it: the
    ends are padded with `pad` seconds of the signal reflected about its end values (odd
    reflection: keeps value and slope, as J211-1 suggests to avoid start-up transients), and each
    pass starts in steady state. Pure numpy, so loading data does not import scipy.signal.
    """
    cfc = CFC_CLASSES[cfc] if isinstance(cfc, str) else float(cfc)
    b, a = cfc_coefficients(cfc, dt)
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        raise ValueError("cannot filter an empty signal")
    padlen = min(x.size - 1, max(1, int(round(pad / dt))))
    forward = _steady_pass(b, a, _odd_extension(x, padlen))
    both = _steady_pass(b, a, forward[::-1])[::-1]
    return both[padlen : padlen + x.size]


# A bias window's mean is the sensor's zero offset only where the record covers the window (it begins
# no later than a sample after the window does) and the window holds BIAS_LEAST of record: the mean
# of 50 samples at 10 kHz has a seventh of the noise of one (the generator's 0.8 g white noise: 0.11 g),
# while a single sample at impact may read a spike of g's and shift the whole record by it.
BIAS_LEAST = 0.005  # s; `crashnlp init` writes a window wherever this much pre-impact record exists
BIAS_SPAN = 0.05  # s of pre-impact record whose mean is the accelerometer's offset: the window init writes


def remove_bias(time: np.ndarray, values: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """Subtract the mean of the samples in `window` (pre-impact: the sensor's zero offset); refuse a
    window the record does not cover, or that holds less than BIAS_LEAST of it."""
    inside = (time >= window[0]) & (time <= window[1])
    held = time[inside]
    said = f"bias window {window[0]:g} s to {window[1]:g} s"
    if held.size == 0:
        raise ValueError(f"{said} holds no samples")
    span = float(held[-1] - held[0])
    if window[0] < time[0] - (time[1] - time[0]) or span < BIAS_LEAST - 1e-9:
        raise ValueError(
            f"{said} holds {held.size} sample(s), {span * 1e3:g} ms of a record that begins at {time[0]:g} s: "
            f"the mean of a window the record does not cover, or of less than {BIAS_LEAST * 1e3:g} ms, is no "
            "offset (leave bias_window out where the record has no pre-impact samples)"
        )
    return values - values[inside].mean()


def cumtrapz(time: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral, 0 at the first sample."""
    out = np.zeros(np.shape(values))
    np.cumsum(np.diff(time) * (values[1:] + values[:-1]) / 2.0, out=out[1:])
    return out


def integrate(time: np.ndarray, accel: np.ndarray, v0: float, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement from acceleration by trapezoid rule, with v(t0) = v0 and x(t0) = 0.

    Samples before t0 are integrated too (backwards from t0), so a pre-impact record shows
    v ~ v0 and x ~ v0 (t - t0) < 0.
    """
    if not time[0] <= t0 <= time[-1]:
        raise ValueError(f"impact time {t0:g} s is outside the record {time[0]:g} s to {time[-1]:g} s")
    velocity = cumtrapz(time, accel)
    velocity += v0 - np.interp(t0, time, velocity)
    displacement = cumtrapz(time, velocity)
    displacement -= np.interp(t0, time, displacement)
    return velocity, displacement


def cut(channel: Channel, window: tuple[float, float]) -> Channel:
    """The part of a channel with window[0] <= t <= window[1] (a small tolerance keeps grid ends)."""
    tol = 1e-9 * max(1.0, abs(window[1]))
    keep = (channel.time >= window[0] - tol) & (channel.time <= window[1] + tol)
    return Channel(channel.time[keep], channel.values[keep], channel.unit, channel.source)


def resample(channel: Channel, t: np.ndarray) -> np.ndarray:
    """Channel values at times `t` by linear interpolation; `t` must lie within the record."""
    t = np.asarray(t, dtype=float)
    tol = 1e-9 * max(1.0, abs(channel.time[-1]))
    if t.min() < channel.time[0] - tol or t.max() > channel.time[-1] + tol:
        raise DataError(
            f"{channel.source}: grid {t.min():g} s to {t.max():g} s runs outside the record "
            f"{channel.time[0]:g} s to {channel.time[-1]:g} s"
        )
    return np.interp(t, channel.time, channel.values)
