"""The crash metrics the result files and tables report, for test data and model responses alike."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from crashnlp.analysis.metrics import LET_GO, crash_metrics, let_go_end
from crashnlp.base.outputs import METRIC, METRICS, UNFINISHED, UNSETTLED
from crashnlp.base.units import G0
from crashnlp.case.testcase import TestCase, impulses
from crashnlp.data.instrument import recorded
from crashnlp.data.signal import CFC_CLASSES, integrate, resample
from crashnlp.problem.schema import ChannelSpec
from crashnlp.results.response import Response
from crashnlp.results.result import TestResult

# a record that ends still moving toward the barrier ends mid-crash where its deceleration there is
# at least this share of its peak; below it the pulse is over and the vehicle drifts on without
# contact (its pitch lifted the front end off), and the record holds the pulse whole
MID_CRASH = 0.1
END_SHARE = 0.05  # the last part of a record in which a pitch still rising at its end is read (pitch_rises_at_end)
# A frontal crash pitches a vehicle by degrees: the generator's vehicles by 3 deg or more at 40 to 64
# km/h (docs/design-notes.md). A measured pitch that stays below PITCH_LEAST after impact was most
# likely written in radians and read as degrees (57 times too small: 26 deg reads 0.45). A vehicle
# struck at its CG's height barely pitches, so this is said in the fit's notes, not refused.
PITCH_LEAST = np.radians(0.5)
# the metrics still_moving names where a record does not give them: the predicted and the whole
# crash's ones that the crash's rest would change (the stop is said apart)
_WITHHELD: tuple[str, ...] = tuple(
    m.key for m in METRICS if (m.short or m.whole_crash) and m.whole_pulse and m.key != "time_zero_velocity_s"
)


def metrics(
    t: np.ndarray,
    accel: np.ndarray,
    velocity: np.ndarray,
    displacement: np.ndarray,
    pitch: np.ndarray | None,
    crush: np.ndarray | None = None,
    barrier: np.ndarray | None = None,
) -> dict:
    """The crash metrics result.json reports, in the units their names say; None for a metric the
    record does not hold: one it does not reach (an OLC whose occupant does not travel 300 mm), the
    UNFINISHED ones of a record that ends mid-crash (MID_CRASH), and the UNSETTLED ones of a record
    that ends still moving toward the barrier after the pulse (`still_moving` says where either
    ends). The one rule for test data, fitted models and predictions alike. With the force on the
    barrier (`barrier`: a model's), a record whose loading ends as the vehicle lets go of the barrier
    moving on slowly (`loading_end`) has its stop at that instant (`_ended_at`).

    Max displacement is the crash-test quantity (NHTSA's maximum dynamic crush), the CG's largest
    travel, for data and model alike, so the two compare. A model also reports its largest front-end crush
    (`max_front_end_crush_m`, the `crush` output along the crush force's line of action: what a
    crush bound limits); the two differ by the pitch and the geometry. `record_end_s` and
    `end_velocity_mps` say where the record ends and how fast the vehicle still moves there.
    """
    record = withheld(values(t, accel, velocity, displacement, pitch, crush), accel)
    end = loading_end(t, accel, velocity, barrier)
    return record if end is None else record | _ended_at(end, float(velocity[0]))


def loading_end(t: np.ndarray, accel: np.ndarray, velocity: np.ndarray, barrier: np.ndarray | None) -> float | None:
    """Where a record's loading ends without a stop, as the vehicle lets go of the barrier moving on
    slowly (crashnlp.analysis.metrics.let_go_end); None without the force on the barrier, or where
    the record ends mid-crash (MID_CRASH: it decelerates still, and gives no stop)."""
    return None if barrier is None or _mid_crash(accel) else let_go_end(t, velocity, barrier)


def let_go_words(r: Response) -> str | None:
    """The words for a model response whose loading ends as it lets go of the barrier moving on
    slowly (`loading_end`), as the notes of fits and predictions say them; None for any other."""
    y = r.outputs
    end = loading_end(r.time, y["accel"], y["velocity"], y.get("barrier_force"))
    if end is None:
        return None
    moving = float(np.interp(end, r.time, y["velocity"]))
    return (
        f"lets go of the barrier at {end * 1e3:.1f} ms while its CG still moves toward it at {moving:.3f} m/s, under "
        f"{LET_GO * 100:g} % of the impact speed, and does not touch it again within the record (its pitch lifted the "
        "front end off): its loading ends there, and its stop is that instant; its max displacement is its travel at "
        "the record's end, and as it drifts on and meets the barrier again after the record, it gives no velocity "
        "change, rebound or max pitch"
    )


def _ended_at(end: float, v0: float) -> dict:
    """The stop of a record whose loading ends at `end` without one (the vehicle lets go of the
    barrier while the CG moves on slowly), and the TESW it gives. The rest is the record's as it
    ends drifting: its max displacement its travel at the end, and no velocity change, rebound or
    max pitch (`withheld`): it meets the barrier again after the record."""
    return {"time_zero_velocity_s": end, "tesw_g": v0 / end / G0}


def values(
    t: np.ndarray,
    accel: np.ndarray,
    velocity: np.ndarray,
    displacement: np.ndarray,
    pitch: np.ndarray | None,
    crush: np.ndarray | None = None,
) -> dict:
    """Every crash metric as far as the record goes (None: none in it, a stop or an OLC it does not
    reach), before `withheld`: what the benchmarks compare two curves by over the same record."""
    m = crash_metrics(t, accel, velocity, displacement)
    others = {
        "max_front_end_crush_m": float(np.max(crush)) if crush is not None else None,
        "record_end_s": float(t[-1]),
        "max_pitch_deg": float(np.degrees(np.max(pitch))) if pitch is not None else None,
    }
    out = {k.key: others[k.key] if k.read is None else getattr(m, k.read) / k.per for k in METRICS}
    return {key: None if value is None or not np.isfinite(value) else value for key, value in out.items()}


def withheld(record: dict, accel: np.ndarray) -> dict:
    """A record's `values` without those its crash goes on to change: where it ends before the
    vehicle stops, the UNFINISHED ones mid-crash and the UNSETTLED ones after the pulse; where it
    ends after the stop still decelerating by MID_CRASH of its peak or more, the UNSETTLED ones,
    its rebound not over (`goes_on` says so)."""
    if still_moving(record):
        return {**record, **dict.fromkeys(UNFINISHED if _mid_crash(accel) else UNSETTLED)}
    if record.get("time_zero_velocity_s") is not None and _mid_crash(accel):
        return {**record, **dict.fromkeys(UNSETTLED)}
    return record


def _mid_crash(accel: np.ndarray) -> bool:
    """Whether a record ends while the vehicle still decelerates by MID_CRASH of its peak or more."""
    peak = float(np.max(-accel))
    return peak > 0 and float(-accel[-1]) >= MID_CRASH * peak


def still_moving(metrics: Mapping[str, float | None]) -> str | None:
    """The words for a record that ends before the vehicle stops (no time of zero velocity in
    it), mid-crash or after the pulse, naming the predicted metrics it does not give (`withheld`,
    and for data a drift's max displacement: `data_metrics`); None for one that stops."""
    stop, end, speed = (metrics.get(k) for k in ("time_zero_velocity_s", "record_end_s", "end_velocity_mps"))
    if (stop is not None and np.isfinite(stop)) or end is None or speed is None:
        return None
    moving = f"ends at {end * 1e3:.1f} ms still moving toward the barrier at {speed:.3g} m/s"
    where = "mid-crash" if metrics.get("peak_decel_g") is None else "the crash goes on past it"
    return f"{moving} (no stop: {where}, so no {_listed(_WITHHELD, metrics)} in it)"


def goes_on(metrics: Mapping[str, float | None]) -> str | None:
    """The words for a record whose crash goes on past its end, naming what it does not give: one
    that ends still moving (`still_moving`), or still decelerating after its stop (`_ends_pushed`);
    None otherwise."""
    return still_moving(metrics) or _ends_pushed(metrics)


def _ends_pushed(metrics: Mapping[str, float | None]) -> str | None:
    """The words for a record that stops but ends still decelerating by MID_CRASH of its peak or
    more, its rebound still gathering speed (`withheld`: a stop, and no rebound), naming what it
    does not give; None otherwise, and for a crash that ended as the vehicle let go of the barrier
    moving on (it ends moving toward it: `loading_end`, whose words are `let_go_words`)."""
    stop, end, speed = (metrics.get(k) for k in ("time_zero_velocity_s", "record_end_s", "end_velocity_mps"))
    if stop is None or end is None or metrics.get("rebound_velocity_mps") is not None or (speed is not None and speed > 0):
        return None
    return (
        f"ends at {end * 1e3:.1f} ms after its stop, still decelerating by a tenth of its peak or more (its rebound "
        f"goes on past it, so no {_listed(UNSETTLED, metrics)} in it)"
    )


def _listed(keys: tuple[str, ...], metrics: Mapping[str, float | None]) -> str:
    """The labels of the metrics of `keys` that `metrics` does not give: "a, b or c"."""
    labels = [METRIC[k].label for k in keys if metrics.get(k) is None]
    return ", ".join(labels[:-1]) + f" or {labels[-1]}" if len(labels) > 1 else "".join(labels)


def data_curves(test: TestCase) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    if test.data is None:
        return {}
    return {name: (ch.time, ch.values) for name, ch in test.data.channels.items()}


def pitch_rises_at_end(time: np.ndarray, pitch: np.ndarray | None) -> float | None:
    """The end of a record (s) whose pitch is largest in its last END_SHARE and still rising there
    (a least-squares line through that part slopes up, so that a measured pitch's noise neither
    hides nor fakes it): its max pitch is the record's, and the crash's comes later (a body on its
    suspension pitches for a few hundred ms). None where the pitch peaks before, or there is none."""
    if pitch is None or pitch.size < 2:
        return None
    last = time >= time[-1] - END_SHARE * (time[-1] - time[0])
    if last.sum() < 2 or int(np.argmax(pitch)) < int(np.flatnonzero(last)[0]):
        return None
    return float(time[-1]) if np.polyfit(time[last], pitch[last], 1)[0] > 0 else None


def pitch_words(t: TestResult) -> list[str]:
    """What a fitted test says of its pitch, for its notes and the console: a pitch still rising at
    the window's end (pitch_still_rising), a measured one too small for a crash (pitch_too_small)."""
    return pitch_still_rising(t) + pitch_too_small(t)


def pitch_too_small(t: TestResult) -> list[str]:
    """Where a test's measured pitch stays below PITCH_LEAST after impact: that it may be in radians."""
    if "pitch" not in t.data:
        return []
    time, pitch = (np.asarray(x) for x in t.data["pitch"])
    after = np.abs(pitch[time >= 0.0])
    if not after.size or after.max() >= PITCH_LEAST:
        return []
    return [
        f"the record's max pitch is {np.degrees(after.max()):.2g} deg (channel pitch): a frontal crash pitches a vehicle "
        "by degrees; if the column is in rad, give unit: rad"
    ]


def pitch_still_rising(t: TestResult) -> list[str]:
    """What a fitted test says where its measured pitch, or its model's, still rises at the
    window's end while a max pitch is given (pitch_rises_at_end): that max pitch is the window's."""
    curves = {"model": (t.response.time, t.response["pitch"], t.metrics)}
    if "pitch" in t.data and t.data_metrics is not None:
        curves = {"record": (*t.data["pitch"], t.data_metrics), **curves}
    words = []
    for who, (time, pitch, metrics) in curves.items():
        end = pitch_rises_at_end(np.asarray(time), np.asarray(pitch)) if metrics.get("max_pitch_deg") is not None else None
        if end is not None:
            words.append(
                f"the {who}'s pitch still rises at the window's end, {end * 1e3:.1f} ms: its max pitch is the window's, "
                "and the crash's comes later (a longer window reaches it)"
            )
    return words


def data_metrics(test: TestCase) -> dict | None:
    """Metrics of the measured curves, on the accel channel's time base (`metrics`). A record that
    ends drifting on after the pulse has no max displacement either, and no ESW from it: its last
    sample is not one."""
    ch = test.data.channels if test.data is not None else {}
    if not {"accel", "velocity", "displacement"} <= set(ch):
        return None
    t = ch["accel"].time
    t = t[(t >= max(c.time[0] for c in ch.values())) & (t <= min(c.time[-1] for c in ch.values()))]
    pitch = resample(ch["pitch"], t) if "pitch" in ch else None
    out = metrics(t, resample(ch["accel"], t), resample(ch["velocity"], t), resample(ch["displacement"], t), pitch)
    if still_moving(out):
        out.update(max_displacement_m=None, time_max_displacement_s=None, esw_g=None)
    return out


def response_metrics(r: Response) -> dict:
    """The metrics of a model response, its acceleration as the response carries it: read through
    a test's CFC class where `as_recorded` made it so, so that its peak and pulse compare with the
    test's filtered ones; its force on the barrier tells where a crash ends as it lets go (`metrics`)."""
    y = r.outputs
    return metrics(r.time, y["accel"], y["velocity"], y["displacement"], y["pitch"], y.get("crush"), y.get("barrier_force"))


def as_recorded(r: Response, accel_filter: str | None) -> Response:
    """The response with its acceleration as accelerometers read through CFC class `accel_filter`
    record it (crashnlp.data.instrument.recorded); the response itself for None, or where its
    acceleration is read through that class already (never twice: a second pass filters again)."""
    if accel_filter is None or r.accel_filter == accel_filter:
        return r
    if r.accel_filter is not None:
        raise ValueError(f"a response read through {r.accel_filter} cannot be read through {accel_filter}")
    accel = recorded(r.time, r.outputs, "accel", CFC_CLASSES[accel_filter])
    return replace(r, outputs={**r.outputs, "accel": accel}, accel_filter=accel_filter, own_accel=r.outputs["accel"])


def accel_filter(test: TestCase) -> str | None:
    """The CFC class a test's accelerometers were read through (None: none, or no accel channel)."""
    spec = accel_spec(test)
    return spec.filter if spec is not None and spec.derive is None else None


def accel_spec(test: TestCase) -> ChannelSpec | None:
    """The problem's accel channel of a test, or None where its problem names no accel data."""
    return test.spec.data.channels.get("accel") if test.spec.data is not None else None


def channel_consistency(test: TestCase, mass: float) -> dict | None:
    """What the wall force and the accelerometers each say of the crash, when a test has both.

    Each is integrated as one mass from the impact speed (the wall force as -F / m): its impulse
    m (v0 - v_end) over the data [N s] (crashnlp.case.testcase.impulses, whose ratio check_barrier
    holds within a factor of 2 before the fit), time of zero velocity [s], largest travel [m] and
    rebound [m/s]. A one-mass model meets both only as far as these agree (docs/barrier.md)."""
    data = test.data
    both = impulses(data, mass) if data is not None else None
    if data is None or both is None:
        return None
    wall, accel = data.channels["barrier_force"], data.channels["accel"]
    sets = {
        "wall": {"impulse_Ns": both[0], **_one_mass(wall.time, -wall.values / mass, test.speed)},
        "accelerometers": {"impulse_Ns": both[1], **_one_mass(accel.time, accel.values, test.speed)},
    }
    return {**sets, "impulse_ratio": both[0] / both[1]}


def _one_mass(t: np.ndarray, accel: np.ndarray, v0: float) -> dict[str, float]:
    """Stop time, travel and rebound of one mass decelerated by `accel` from v0."""
    velocity, displacement = integrate(t, accel, v0, max(0.0, float(t[0])))
    m = crash_metrics(t, accel, velocity, displacement)
    return {
        "time_zero_velocity_s": m.t_zero_velocity,
        "max_displacement_m": m.max_displacement,
        "rebound_velocity_mps": m.rebound_velocity,
    }
