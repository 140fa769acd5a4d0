"""Records cut short: MID_CRASH on generator vehicles of every kind, from a seed the rule never saw.

A record that ends while the vehicle still moves toward the barrier is mid-crash where its
deceleration at its end is at least MID_CRASH of its peak so far (crashnlp.analysis.summary): it
then gives no peak, stop, rebound or other metric the crash's rest would change. Below that it is
held whole (a van whose pitch lifted its front end off drifts on without contact) and those
metrics stand. The rule fails silently where a record it holds whole has a crash that goes on and
changes them: a larger peak (an engine that meets the barrier late), more velocity change, a
rebound, more pitch. MID_CRASH was set with the shipped tests cut short (the pickup, the Camry) and
the calibration corpus's tall vans in view; here it is checked on SEED's vehicles of the four
generator kinds (random, engine on mounts, tall, tall with an engine on mounts), each at
SPEEDS_KMH, noise-free, every record cut every STEP from FIRST_CUT to its stop. Per kind: the cut
records held whole, and of them those whose value of each of HELD falls short of the whole
record's by more than SHORT of it (and at least its FLOOR); the cut records called mid-crash, and
of them those whose peak was already whole (the rule's caution: a peak not given that was right).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np

from bench.corpus import DT, Vehicle, engine_vehicle, random_vehicle, simulate, tall_engine_vehicle, tall_vehicle
from crashnlp.analysis.summary import MID_CRASH, metrics
from crashnlp.base.units import G0

SEED = 7777  # never used to set a rule
COUNT = 12  # vehicles of each kind
SPEEDS_KMH = (40.0, 56.0, 64.0)
FIRST_CUT, STEP = 0.010, 0.002  # s
SHORT = 0.01  # a held value more than this short of the whole record's (relative) is a silent failure
HELD = ("peak_decel_g", "delta_v_mps", "rebound_velocity_mps", "max_pitch_deg")  # what a held record gives
FLOOR = {"rebound_velocity_mps": 0.05, "max_pitch_deg": 0.1, "delta_v_mps": 0.05}  # and at least this short
KINDS: dict[str, Callable[[int, int], Vehicle]] = {
    "random": random_vehicle,
    "engine on mounts": engine_vehicle,
    "tall": tall_vehicle,
    "tall, engine on mounts": tall_engine_vehicle,
}


def cuts(v: Vehicle) -> Iterator[tuple[float, bool, dict[str, bool]]]:
    """(end, held whole, short) of `v`'s noise-free record cut every STEP before its stop, where the
    cut record still moves toward the barrier: whether `metrics` holds it whole, and which of HELD
    it then gives short of the whole record's (for one called mid-crash: whether its peak so far
    is short)."""
    truth = simulate(v)
    t, channels = truth["time"], [truth[k] for k in ("accel", "velocity", "displacement", "pitch")]
    whole = metrics(t, *channels)
    stop = whole["time_zero_velocity_s"]
    for end in np.arange(FIRST_CUT, t[-1] if stop is None else stop, STEP):
        k = int(round(end / DT)) + 1
        cut = metrics(t[:k], *(c[:k] for c in channels))
        if cut["time_zero_velocity_s"] is not None:
            continue
        held = cut["peak_decel_g"] is not None
        so_far = cut if held else {"peak_decel_g": float(np.max(-channels[0][:k])) / G0}
        short = {
            key: so_far[key] < whole[key] - max(SHORT * abs(whole[key]), FLOOR.get(key, 0.0))
            for key in (HELD if held else ("peak_decel_g",))
        }
        yield float(t[k - 1]), held, short


def run(quick: bool = False) -> dict:
    """The bench section: COUNT vehicles of each kind (1 with --quick) at every speed, every cut."""
    count = 1 if quick else COUNT
    out: dict = {"seed": SEED, "count": count, "speeds_kmh": SPEEDS_KMH, "step_s": STEP, "short": SHORT, "floor": FLOOR}
    out["mid_crash"] = MID_CRASH
    kinds = {}
    for kind, make in KINDS.items():
        q: dict = {"held": 0, "held_short": dict.fromkeys(HELD, 0), "mid_crash": 0, "mid_crash_whole": 0, "failures": []}
        for i in range(count):
            for kmh in SPEEDS_KMH:
                v = replace(make(i, SEED), speed=kmh / 3.6)
                for end, held, short in cuts(v):
                    if held:
                        q["held"] += 1
                        for key in HELD:
                            q["held_short"][key] += short[key]
                        if any(short.values()):
                            q["failures"].append(
                                {"vehicle": v.name, "kmh": kmh, "end_s": end, "short": [k for k in HELD if short[k]]}
                            )
                    else:
                        q["mid_crash"] += 1
                        q["mid_crash_whole"] += not short["peak_decel_g"]
        kinds[kind] = q
        shorts = ", ".join(f"{key} {n}" for key, n in q["held_short"].items())
        print(
            f"  {kind}: {q['held']} cut records held whole (short: {shorts}); {q['mid_crash']} mid-crash, {q['mid_crash_whole']} of them with the peak",
            flush=True,
        )
    out["kinds"] = kinds
    return out
