"""A clipped accelerometer: one whose pulse ran past its sensor's (or its recorder's) range and was
cut flat at it. Its peak, the crush integrated from it and a fit to it are all wrong, and nothing
downstream sees it: a filter rounds the flat top into a plausible pulse.

A clipped channel holds its extreme, its largest or its smallest value, for a run of identical
samples, and reaches it steeply: it spends almost no time just short of it. A measured one passes
through its peak, and where it is written rounded (a filtered export to 0.1 g) its peak holds one
value for a run too, but it lingers near it: a smooth peak stays within a few of the data's steps
(the gap from the extreme to the nearest other value) about as long again on either side. The
Camry's (NHTSA test 10146) eight vehicle accelerometers hold their extreme for one sample each
(their longest run of identical samples anywhere, near zero before impact, is 4), and so does every
generator record (bench/corpus.py, seeds 3100 and 3200, every form at 40, 56 and 64 km/h), noise on
top of its pulse. A run of CLIP_RUN samples or more that lasts CLIP_SPAN or longer, with fewer
samples than itself within NEAR_STEPS steps of the extreme, is refused. The pickup's pulses at 40
and 56 km/h filtered at CFC 60 and rounded to 0.1 g hold their peak for 21 and 18 samples and
have 3.8 and 4.3 times as many near it; clipped at 20, 25 or 28 g (rounded or not) they hold it for
22 to 397 samples with at most 0.73 times as many near it, and the audit's accelerometers clipped
at 20 g and 25 g held it for 564 and 24. A sensor range in the file's header is not read: EV5
headers give one in no set field, and a recorder clips below the sensor's range as well.
"""

from __future__ import annotations

import numpy as np

from crashnlp.base.units import G0
from crashnlp.data.channels import DataError

CLIP_RUN = 10  # samples in a row at the channel's extreme ...
CLIP_SPAN = 1e-3  # s: ... over this long or longer: clipped
EXTREME_SHARE = 0.1  # a side whose extreme reaches less than this share of the other's is not judged
NEAR_STEPS = 3  # ... with fewer samples than the run within this many of the data's steps of the extreme


def extreme_run(time: np.ndarray, values: np.ndarray) -> tuple[float, int, float]:
    """Of the channel's largest and smallest value (each where its magnitude is at least
    EXTREME_SHARE of the largest: not the zeros a record that never turns positive holds), the one
    held longest, and its longest run of samples in a row: its length and how long it lasts (s)."""
    reach = float(np.max(np.abs(values)))
    runs = [_run(time, values, float(v)) for v in (values.max(), values.min()) if abs(v) >= EXTREME_SHARE * reach > 0]
    return max(runs, key=lambda r: r[1], default=(0.0, 0, 0.0))


def _run(time: np.ndarray, values: np.ndarray, level: float) -> tuple[float, int, float]:
    """`level`, and the longest run of samples in a row equal to it: its length and span (s)."""
    at = np.concatenate(([0], (values == level).astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(at))
    k = int(np.argmax(edges[1::2] - edges[::2]))
    first, last = edges[2 * k], edges[2 * k + 1] - 1
    return level, int(last - first + 1), float(time[last] - time[first])


def near(values: np.ndarray, level: float) -> int:
    """How many samples lie within NEAR_STEPS of the data's steps of `level` but not at it, a step
    being the gap from `level` to the nearest other value."""
    apart = np.abs(values - level)
    off = apart[apart > 0]
    return int(np.sum(off <= NEAR_STEPS * np.min(off))) if off.size else 0


def check_clipped(time: np.ndarray, values: np.ndarray, at: str) -> None:
    """Refuse an accelerometer (`values` in SI, as read) that holds its extreme for CLIP_RUN samples
    or more in a row over CLIP_SPAN or longer, with fewer samples than that near it (`near`),
    naming `at` (file, channel and column or curve) and the level. An averaged channel is checked
    curve by curve: their runs need not line up."""
    extreme, run, span = extreme_run(time, values)
    # a column of one value is flat: check_dead says so
    if run >= CLIP_RUN and span >= CLIP_SPAN and near(values, extreme) < run and np.ptp(values) > 0:
        raise DataError(
            f"{at}: {run} samples in a row ({span * 1e3:.3g} ms) at exactly {extreme / G0:.4g} g, the "
            "furthest it reads that way: the "
            f"accelerometer clipped there (its range, or its recorder's), so its peak, the crush integrated from it and a "
            f"fit to it are all wrong; use an accelerometer that did not clip"
        )
