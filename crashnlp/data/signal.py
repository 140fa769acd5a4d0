"""Signal processing of crash channels: SAE J211-1 / ISO 6487 CFC filters, bias, integration, resampling."""

from __future__ import annotations

import numpy as np

from crashnlp.data.channels import Channel, DataError

CFC_CLASSES = {"CFC60": 60.0, "CFC180": 180.0, "CFC600": 600.0, "CFC1000": 1000.0}


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


def cfc_filter(values: np.ndarray, dt: float, cfc: float | str, pad: float = 0.01) -> np.ndarray:
    """Zero-phase CFC filter of a uniformly sampled signal (sample interval `dt` in s).

    scipy's filtfilt with the J211-1 coefficients: the ends are padded with `pad` seconds of
    the signal reflected about its end values (odd reflection: keeps value and slope, as
    J211-1 suggests to avoid start-up transients), and each pass starts in steady state.
    """
    from scipy.signal import filtfilt  # scipy.signal takes a second to import: only when filtering

    cfc = CFC_CLASSES[cfc] if isinstance(cfc, str) else float(cfc)
    b, a = cfc_coefficients(cfc, dt)
    x = np.asarray(values, dtype=float)
    return filtfilt(b, a, x, padtype="odd", padlen=min(x.size - 1, max(1, int(round(pad / dt)))))


def remove_bias(time: np.ndarray, values: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """Subtract the mean of the samples in `window` (pre-impact: the sensor's zero offset)."""
    inside = (time >= window[0]) & (time <= window[1])
    if not np.any(inside):
        raise ValueError(f"bias window {window[0]:g} s to {window[1]:g} s holds no samples")
    return values - values[inside].mean()


def cumtrapz(time: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral, 0 at the first sample."""
    from scipy.integrate import cumulative_trapezoid

    return cumulative_trapezoid(values, time, initial=0.0)


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
