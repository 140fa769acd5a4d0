"""Load a test's data as the problem file describes it: read, sign, bias, filter, integrate, window.

A new format is one reader module plus one line in READERS, one in SOURCES and its name in
crashnlp.base.choices.DATA_FORMATS (the schema's choices): a reader takes the DataSpec and
returns the non-derived channels in SI (file sign, unfiltered) and the header meta; its SOURCES
entry lists the files it may read for a DataSpec's `file` (`files_read`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from crashnlp.base.units import G0
from crashnlp.data.channels import Channel, DataError, TestData, check_sampling, of_key, sample_interval, where
from crashnlp.data.clipping import check_clipped
from crashnlp.data.csv_reader import read_csv
from crashnlp.data.iso_mme import mme_files, read_mme
from crashnlp.data.nhtsa_channel import read_channel_files, test_channel_files
from crashnlp.data.nhtsa_ev5 import curve_files, read_ev5
from crashnlp.data.signal import BIAS_LEAST, BIAS_SPAN, CFC_CLASSES, cfc_filter, cut, integrate, remove_bias
from crashnlp.problem.schema import CHANNEL_UNITS, DEFAULT_FILTER, DataSpec

Reader = Callable[[DataSpec], TestData]
READERS: dict[str, Reader] = {
    "csv": read_csv,
    "nhtsa-ev5": read_ev5,
    "nhtsa-channel": read_channel_files,
    "iso-mme": read_mme,
}
SOURCES: dict[str, Callable[[Path], list[Path]]] = {  # the files a reader may read for a DataSpec's `file`
    "csv": lambda path: [path],
    "nhtsa-ev5": curve_files,
    "nhtsa-channel": test_channel_files,
    "iso-mme": mme_files,
}
BIASED = ("accel", "barrier_force")  # transducers whose pre-impact mean is an offset, removed over `bias_window`
# t = 0 is the first contact. By LATE_START after it every generated record has lost more than the
# 5 % of its speed that a measured velocity may part from the test's (docs/design-notes.md, "A record
# that begins after impact"): a record that begins later has lost the pulse's start, which the fit
# needs, and one that begins there at the impact speed runs on another clock (a data system's).
LATE_START = 0.01  # s
# Before impact a vehicle rolls at a steady speed: its accelerometers read their zero offset. NHTSA
# test 10146's eight vehicle accelerometers read at most 0.024 g on average over their 50 ms before
# impact (their noise 0.11 to 0.49 g), a mean the noise moves by under 0.05 g over 5 ms (BIAS_LEAST).
# Past OFFSET_LIMIT, where no bias_window removes it, the offset integrates to a drift (3 g over a
# 0.2 s record: 5.9 m/s, and 145 mm more crush on test 10146): docs/design-notes.md, "An
# accelerometer's offset".
OFFSET_LIMIT = 0.2 * G0  # m/s^2


def _filtered(channel: Channel, cfc: str | None, at: str) -> np.ndarray:
    """A channel's values filtered at CFC class `cfc`: as they are where it is None, or where the
    file's values were filtered at that class before (`Channel.filtered`): not twice."""
    if cfc is None or cfc == channel.filtered:
        return channel.values
    dt = sample_interval(channel.time, at)
    try:
        return cfc_filter(channel.values, dt, CFC_CLASSES[cfc])
    except ValueError as exc:
        raise DataError(f"{at}: {exc}") from None


def _lab_filtered(channel: Channel, lab: str | None, at: str) -> Channel:
    """`channel` as filtered at `lab` before it was read (a channel's `filtered`, for a file that
    cannot say so, as a CSV cannot), so that a filter of that class is not applied twice
    (`_filtered`); a DataError, key `filtered`, where the file says another class (an ISO-MME code)."""
    if lab is None or channel.filtered == lab:
        return channel
    if channel.filtered is not None:
        raise DataError(f"{at}: the file says its values were filtered at {channel.filtered}, not {lab}", "filtered")
    return replace(channel, filtered=lab)


def _filter_note(name: str, cfc: str | None) -> str:
    """What filter a channel with a default class got, said beside SAE J211's class."""
    j211 = DEFAULT_FILTER[name]
    if cfc == j211:
        return f"filtered at {cfc}, the SAE J211 class for {name} and the default"
    return f"filtered at {cfc or 'no CFC'}, where SAE J211 names {j211} for {name}"


def _check_start(spec: DataSpec, name: str, channel: Channel) -> None:
    """Refuse a channel whose record begins more than LATE_START after impact, naming the time
    column (a CSV's, key `time`) or else the channel."""
    begins = float(channel.time[0])
    if begins <= LATE_START:
        return
    at, key = (f"{spec.file}: time column {spec.time.column}", "time") if spec.format == "csv" else (where(spec.file, name), None)
    raise DataError(
        f"{at}: the record begins {begins * 1e3:g} ms after impact (t = 0 is the first contact), past the "
        f"{LATE_START * 1e3:g} ms by which a crash's pulse has taken off more than 5 % of the speed: give the time "
        "from impact on (a data system's clock shifted by its trigger time), or the whole record",
        key,
    )


def _check_offset(at: str, time: np.ndarray, accel: np.ndarray) -> None:
    """Refuse an acceleration whose samples before impact, BIAS_LEAST of them or more, read a mean
    further than OFFSET_LIMIT from zero, naming bias_window and the window that removes it."""
    before = time < 0.0
    span = float(-time[0]) if before.any() else 0.0
    if span < BIAS_LEAST:
        return
    offset = float(np.mean(accel[before]))
    if abs(offset) > OFFSET_LIMIT:
        raise DataError(
            f"{at}: reads {offset / G0:.3g} g on average over the {span * 1e3:g} ms before impact, where the vehicle "
            f"rolls at a steady speed: an offset of the accelerometer, which integrates to a drift (no bias_window "
            f"removes it; bias_window: [{max(-span, -BIAS_SPAN):g} s, 0 s] does), or a pulse that begins before t = 0 "
            "(the record's time origin is off)",
            "bias_window",
        )


def files_read(spec: DataSpec) -> list[Path]:
    """Every file the reader of `spec`'s format may read for it (SOURCES): what the test's data
    come from, so that a study reuses a case only while their contents stay the same."""
    return SOURCES[spec.format](spec.file)


def load_test_data(spec: DataSpec, speed: float | None = None) -> TestData:
    """Channels in SI and the model frame, ready to compare with the model.

    Order: read; multiply by `sign`; remove the mean over `bias_window` from accel and
    barrier_force; filter each read channel at its CFC (barrier_force at CFC 60 unless the
    problem says otherwise, and the notes say so), but not again at the class the file's values were
    filtered at already (`Channel.filtered`); derive channels with `derive: integrate` from the bias-removed
    accel, filtered at the derived channel's own CFC or else accel's, with v(0) = speed (the
    header's speed when `speed` is None) and x(0) = 0; cut every channel to `window` last.
    """
    reader = READERS.get(spec.format)
    if reader is None:
        raise DataError(f"{spec.file}: no reader for format {spec.format!r}")
    raw = reader(spec)
    path = spec.file
    out: dict[str, Channel] = {}
    notes = list(raw.notes)
    accel_unfiltered = None
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        with of_key(f"channels.{name}"):
            c = _lab_filtered(raw.channels[name], ch.filtered, where(path, name))
            check_sampling(c.time, where(path, name))
            _check_start(spec, name, c)
            if name == "accel":
                check_clipped(c.time, c.values, f"{where(path, name)} ({c.source})")
            values = c.values * ch.sign
            if name == "accel" and spec.bias_window is None:
                _check_offset(where(path, name), c.time, values)
            if name in DEFAULT_FILTER:
                notes.append(f"{name}: {_filter_note(name, ch.filter)}")
            if name in BIASED and spec.bias_window is not None:
                try:
                    values = remove_bias(c.time, values, spec.bias_window)
                except ValueError as exc:
                    raise DataError(f"{where(path, name)}: {exc}", "bias_window") from None
            c = replace(c, values=values)
            if name == "accel":
                accel_unfiltered = c
            out[name] = Channel(c.time, _filtered(c, ch.filter, where(path, name)), c.unit, c.source)

    v0 = speed if speed is not None else raw.meta.get("speed")
    for name, ch in spec.channels.items():
        if ch.derive is None:
            continue
        with of_key(f"channels.{name}"):
            at = where(path, name)
            if name not in ("velocity", "displacement"):
                raise DataError(f"{at}: only velocity and displacement can be derived by integration")
            if accel_unfiltered is None:
                raise DataError(f"{at}: integration needs an accel channel read from the file")
            if v0 is None:
                raise DataError(f"{at}: integration needs the impact speed (give the test's speed)")
            cfc = ch.filter or spec.channels["accel"].filter
            accel = _filtered(accel_unfiltered, cfc, where(path, "accel"))
            try:
                velocity, displacement = integrate(accel_unfiltered.time, accel, v0)
            except ValueError as exc:
                raise DataError(f"{at}: {exc}") from None
            values = velocity if name == "velocity" else displacement
            source = f"integral of {accel_unfiltered.source}" + (f" at {cfc}" if cfc else "")
            out[name] = Channel(accel_unfiltered.time, values, CHANNEL_UNITS[name], source)

    if spec.window is not None:
        for channel in out:
            out[channel] = cut(out[channel], spec.window)
            if out[channel].time.size < 2:
                at = where(path, channel)
                raise DataError(f"{at}: window {spec.window[0]:g} s to {spec.window[1]:g} s holds no samples", "window")
    return TestData(out, dict(raw.meta), notes)
