"""Measured channels in SI and the model frame, and the one error type of bad data."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.units import unit_scale
from crashnlp.problem.schema import CHANNEL_UNITS


class DataError(InputError):
    """Bad test data: the message is one line naming the file and the channel; `key` is the key of
    the test's data (DataSpec) that led there, e.g. 'channels.accel' (None: the file as a whole)."""

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


@contextmanager
def of_key(key: str) -> Iterator[None]:
    """A DataError raised inside came of `key` of the test's data (DataSpec), e.g. 'channels.accel'."""
    try:
        yield
    except DataError as exc:
        exc.key = exc.key or key
        raise


@dataclass
class Channel:
    """One signal: time [s], values in SI `unit`, and where it came from (files, curves, codes).
    `filtered`: the CFC class the file's values were filtered at before they were read (an ISO-MME
    code's filter class), which a problem's filter of that class is not applied again over; None
    where the file says none."""

    time: np.ndarray
    values: np.ndarray
    unit: str
    source: str
    filtered: str | None = None


@dataclass
class TestData:
    """Channels by name (the measurable outputs) and header values in SI.

    `meta` may hold 'mass' [kg] and 'speed' [m/s] when the file header gives them; `notes` say
    what a reader chose from the data (one line each, e.g. the load cells it summed and left out).
    """

    __test__ = False  # not a pytest test class

    channels: Mapping[str, Channel]
    meta: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def where(path: object, channel: str, detail: str = "") -> str:
    """The prefix of every data error: file, channel and (optionally) curve, column or code."""
    extra = f" ({detail})" if detail else ""
    return f"{path}: channel {channel}{extra}"


def si_factor(unit: str, channel: str, at: str) -> float:
    """Factor from `unit` into the SI unit of `channel`; 'g' on an acceleration is standard gravity."""
    try:
        return unit_scale(unit, CHANNEL_UNITS[channel])
    except Exception:  # pint and UnitError both land here
        raise DataError(f"{at}: unit {unit!r} does not convert to {CHANNEL_UNITS[channel]}") from None


def check_samples(time: np.ndarray, values: np.ndarray, at: str) -> None:
    """Refuse empty, non-finite or non-increasing samples (they would poison filters and integrals)."""
    if time.size < 2 or time.shape != values.shape:
        raise DataError(f"{at}: fewer than two samples")
    if not np.all(np.isfinite(time)):
        raise DataError(f"{at}: time has NaN or infinite samples")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise DataError(f"{at}: NaN or infinite value at t = {time[bad[0]]:g} s")
    steps = np.diff(time)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        raise DataError(f"{at}: time not increasing at t = {time[i + 1]:g} s")


# A record's sample intervals may part from their mean by UNIFORM of it: times written to 1 us with a
# 100 us interval round each by up to 1 %. A gap of missing rows or a jittered clock parts them by far
# more; filters and the fit's resampling both take the record for one of even steps.
UNIFORM = 0.01


def sample_interval(time: np.ndarray, at: str) -> float:
    """Mean sample interval of a uniformly sampled record; refuse a record whose intervals part from
    it by more than UNIFORM of it (a gap, a jittered clock), naming where."""
    dt = (time[-1] - time[0]) / (time.size - 1)
    off = np.abs(np.diff(time) - dt)
    worst = int(np.argmax(off))
    if off[worst] > UNIFORM * dt:
        raise DataError(
            f"{at}: sampling is not uniform: the interval after t = {time[worst]:.6g} s is "
            f"{time[worst + 1] - time[worst]:.3g} s, the record's mean {dt:.3g} s (a gap, or a jittered clock)"
        )
    return float(dt)


END_TOLERANCE = 2  # samples by which a record may end before the end it is to reach (a window rounded, a header's NLP)
SAMPLE_INTERVALS = (5e-7, 5e-3)  # s: 2 MHz to 200 Hz; crash data are sampled at about 10 kHz
RECORD_SPANS = (1e-3, 100.0)  # s: a crash lasts about 0.1 s


def median_interval(time: np.ndarray) -> float:
    """The median interval between the samples of a time base that `check_samples` passed:
    np.median(np.diff(time)), the same number, without the import of numpy.ma that np.median
    makes on its first call (45 ms of CPU in every command that reads data)."""
    steps = np.diff(np.asarray(time, dtype=float))
    half = steps.size // 2
    if steps.size % 2:
        return float(np.partition(steps, half)[half])
    low, high = np.partition(steps, (half - 1, half))[half - 1 : half + 1]
    return float((low + high) / 2)


def check_sampling(time: np.ndarray, at: str) -> None:
    """Refuse a time base no crash record has: usually a wrong time unit (ms read as s, or s as ms);
    then one whose sampling is not uniform (`sample_interval`), filtered or not."""
    dt = median_interval(time)
    span = float(time[-1] - time[0])
    lo, hi = SAMPLE_INTERVALS
    if not lo <= dt <= hi:
        raise DataError(
            f"{at}: sample interval {dt:g} s ({1 / dt:.3g} Hz) is not a crash record's "
            f"({lo:g} s to {hi:g} s): is the time unit right?"
        )
    if not RECORD_SPANS[0] <= span <= RECORD_SPANS[1]:
        raise DataError(f"{at}: the record lasts {span:g} s, not a crash record's: is the time unit right?")
    sample_interval(time, at)
