"""What is physically certain of a frontal barrier crash, whatever the data: the range each
predicted metric can take, the range of the barrier force, and the state at the instant of impact.
A prediction's 95 % intervals and bands (crashnlp.analysis.prediction), and the identified loading
curve's band (crashnlp.optimize.outcome), are limited to them here.

A limit holds the truth for certain, so an interval or band cut at it covers the truth whenever
the uncut one did: the cut never lowers coverage. An interval or band that reaches a limit says
only that the data say nothing beyond it.

- **Metrics** (model frame, crashnlp.analysis.metrics: x toward the barrier, impact at t = 0; their
  ranges are the metric registry's, crashnlp.base.outputs.METRIC_RANGE):
  max displacement and max pitch are the largest of curves that start at zero, peak deceleration
  is max(-a) over a record that starts with no force, rebound velocity is max(0, -min v) (a speed
  away from the barrier), and OLC is the constant deceleration that brings the occupant, free at
  the impact speed, to the vehicle's velocity, which the barrier slows: each is >= 0. The time of
  zero velocity is read from the record, so it lies within [0, the record's end]; an interval
  that would pass the end is cut there, and a note says so (a stop after the end is not in the
  record).
- **The barrier force** is >= 0: a barrier only pushes (the model's contact is never tensile,
  crashnlp.models.form). So is the loading curve's force.
- **At impact** (t = 0) nothing is crushed yet: the barrier force is zero, and with it the
  acceleration; the displacement, crush and pitch are zero, and the velocity is the impact speed.
  A band there spans the model's own value and that one: zero wide where they agree. (The model's
  force at zero crush is the loading curve's first value, a fitted one; a value at its bound of
  zero with the covariance the data give it would otherwise band the force at impact by its
  standard error. The pendulum's velocity just after impact is the impact speed less the part
  its pivot takes.)

Not limited: the acceleration to <= 0 during contact (the pendulum's body, turning with its
pivot line, and a body pushed by its engine on mounts accelerate without a barrier force, and a
measured accelerometer rings), and the displacement, crush, velocity and pitch after impact (a
rebound carries the CG back, the front end separates, the body pitches either way)."""

from __future__ import annotations

import math

import numpy as np

from crashnlp.base.outputs import METRIC, METRIC_RANGE

FORCE_RANGE = (0.0, math.inf)  # N: a barrier, and a front end, only push
BAND_RANGE: dict[str, tuple[float, float]] = {"barrier_force": FORCE_RANGE}
AT_IMPACT = {"barrier_force": 0.0, "accel": 0.0, "displacement": 0.0, "crush": 0.0, "pitch": 0.0}  # and the impact speed


def limited_interval(name: str, key: str, interval: tuple[float, float], end: float) -> tuple[tuple[float, float], list[str]]:
    """A metric's 95 % interval cut to the metric's physical range (the time of zero velocity's
    ends at the record's `end`, s), and a note where it is cut: the data say nothing beyond a
    limit, nor anything at all of a metric whose interval spans its whole range (only the time
    of zero velocity's range is finite). An interval inside the range comes back as it was."""
    low_limit, high_limit = METRIC_RANGE.get(key, (-math.inf, math.inf))
    high_limit = end if high_limit is None else high_limit
    low, high = interval
    metric, notes = METRIC[key], []
    shown = lambda v: f"{metric.shown(v)} {metric.unit}"
    if low < low_limit and high > high_limit:
        notes.append(
            f"{name}: {metric.label}'s interval spans every value it can take ({shown(low_limit)} to the record's end,"
            f" {shown(high_limit)}): the data do not determine it"
        )
    elif low < low_limit:
        notes.append(
            f"{name}: {metric.label}'s interval is cut at {shown(low_limit)}, the least it can be: the data say nothing below it"
        )
    elif high > high_limit:
        notes.append(
            f"{name}: {metric.label}'s interval passes the record's end ({shown(high_limit)}) and is cut there:"
            " the record says nothing of a stop after it"
        )
    return (max(low, low_limit), min(high, high_limit)), notes


def limited_band(
    name: str, time: np.ndarray, curve: np.ndarray, band: tuple[np.ndarray, np.ndarray], speed: float
) -> tuple[np.ndarray, np.ndarray]:
    """A response column's band cut to its physical range (BAND_RANGE), and at impact (t = 0)
    spanning the model's value and the one certain there (AT_IMPACT; the velocity's is the impact
    `speed`). The curve stays within its band."""
    low, high = within(*band, curve, *BAND_RANGE.get(name, (-math.inf, math.inf)))
    known = speed if name == "velocity" else AT_IMPACT.get(name)
    impact = time == 0.0
    if known is not None and np.any(impact):
        low = np.where(impact, np.minimum(curve, known), low)
        high = np.where(impact, np.maximum(curve, known), high)
    return low, high


def within(
    low: np.ndarray, high: np.ndarray, curve: np.ndarray, low_limit: float, high_limit: float
) -> tuple[np.ndarray, np.ndarray]:
    """A band (low, high) about `curve` cut to [low_limit, high_limit], never past the curve itself."""
    return np.maximum(low, np.minimum(low_limit, curve)), np.minimum(high, np.maximum(high_limit, curve))
