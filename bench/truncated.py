"""Records cut short: MID_CRASH on generator vehicles of every kind, from a seed the rule never saw.

A record that ends while the vehicle still moves toward the barrier is mid-crash where its
deceleration at its end is at least MID_CRASH of its peak so far (crashnlp.analysis.summary): it
then gives no peak, stop, rebound or other metric the crash's rest would change. Below that it is
held whole (a van whose pitch lifted its front end off drifts on without contact): its peak
stands, and it gives none of the UNSETTLED metrics (velocity change, rebound, max pitch), since the
vehicle meets the barrier again. The rule fails silently where a record gives a value the crash's
rest changes: a larger peak (an engine that meets the barrier late), more velocity change, a
rebound, more pitch. MID_CRASH was set with the shipped tests cut short (the pickup, the Camry) and
the calibration corpus's tall vans in view; here it is checked on SEED's vehicles of the four
generator kinds (random, engine on mounts, tall, tall with an engine on mounts), each at
SPEEDS_KMH, noise-free, every record cut every STEP from FIRST_CUT to its stop. Per kind: the cut
records held whole that give their peak short of the whole record's by more than SHORT of it, and
per UNSETTLED metric those that withhold it though it was whole already (within SHORT of it, or
its FLOOR: the rule's caution); of the cut records called mid-crash, those with the peak already;
and when the vehicles held whole at a cut, off the barrier after it, meet it again before they stop
(`met_again`: where their drift ends).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from bench.corpus import DT, Vehicle, engine_vehicle, random_vehicle, simulate, tall_engine_vehicle, tall_vehicle
from crashnlp.analysis.summary import MID_CRASH, metrics, values, withheld
from crashnlp.base.outputs import UNSETTLED

SEED = 7777  # never used to set a rule
COUNT = 12  # vehicles of each kind
SPEEDS_KMH = (40.0, 56.0, 64.0)
FIRST_CUT, STEP = 0.010, 0.002  # s
# the whole record's length: every vehicle of SEED stops within it (a tall van that lifts its front
# end off drifts on past the corpus's 0.2 s, and stops after it meets the barrier again: `met_again`)
WHOLE = 0.5  # s
SHORT = 0.01  # a given value more than this short of the whole record's (relative) is a silent failure
JUDGED = ("peak_decel_g", *UNSETTLED)  # the extremes a cut record could give short
HELD_GIVES = tuple(key for key in JUDGED if key not in UNSETTLED)  # those a record held whole gives: its peak
FLOOR = {"rebound_velocity_mps": 0.05, "max_pitch_deg": 0.1, "delta_v_mps": 0.05}  # and at least this short
KINDS: dict[str, Callable[[int, int], Vehicle]] = {
    "random": random_vehicle,
    "engine on mounts": engine_vehicle,
    "tall": tall_vehicle,
    "tall, engine on mounts": tall_engine_vehicle,
}


@dataclass(frozen=True)
class Cut:
    """A record cut at `end` while still moving toward the barrier: whether `metrics` holds it
    whole, which of JUDGED it gives, which of them its pulse so far has short of the whole
    record's (None: the whole record does not give it either), and when the vehicle next meets the
    barrier after the cut, off it meanwhile (None: not before it stops)."""

    end: float
    held: bool
    given: frozenset[str]
    short: dict[str, bool | None]
    meets_again: float | None


def cuts(v: Vehicle) -> Iterator[Cut]:
    """`v`'s noise-free record cut every STEP before its stop, where the cut record still moves
    toward the barrier."""
    truth = simulate(v, duration=WHOLE)
    t, channels = truth["time"], [truth[k] for k in ("accel", "velocity", "displacement", "pitch")]
    whole = metrics(t, *channels)
    stop = whole["time_zero_velocity_s"]
    if stop is None:
        raise ValueError(f"{v.name} at {v.speed * 3.6:g} km/h does not stop within {WHOLE:g} s: no whole record to judge by")
    force = truth["barrier_force"]
    contacts = t[1:][(force[:-1] <= 0) & (force[1:] > 0)]  # when the barrier force rises from zero
    for end in np.arange(FIRST_CUT, stop, STEP):
        k = int(round(end / DT)) + 1
        so_far = values(t[:k], *(c[:k] for c in channels))
        cut = withheld(so_far, channels[0][:k])
        if cut["time_zero_velocity_s"] is not None:
            continue
        short = {
            key: None
            if whole[key] is None
            else bool(so_far[key] < whole[key] - max(SHORT * abs(whole[key]), FLOOR.get(key, 0.0)))
            for key in JUDGED
        }
        given = frozenset(key for key in JUDGED if cut[key] is not None)
        again = contacts[(contacts > t[k - 1]) & (contacts < stop)]
        meets_again = float(again[0]) if again.size else None
        yield Cut(float(t[k - 1]), cut["peak_decel_g"] is not None, given, short, meets_again)


def run(quick: bool = False) -> dict:
    """The bench section: COUNT vehicles of each kind (1 with --quick) at every speed, every cut."""
    count = 1 if quick else COUNT
    out: dict = {"seed": SEED, "count": count, "speeds_kmh": SPEEDS_KMH, "step_s": STEP, "short": SHORT, "floor": FLOOR}
    out["mid_crash"] = MID_CRASH
    kinds = {}
    for kind, make in KINDS.items():
        q: dict = {"held": 0, "held_short": dict.fromkeys(HELD_GIVES, 0), "held_withheld": dict.fromkeys(UNSETTLED, 0)}
        q |= {"mid_crash": 0, "mid_crash_whole": 0, "failures": [], "met_again": []}
        for i in range(count):
            for kmh in SPEEDS_KMH:
                _count(q, replace(make(i, SEED), speed=kmh / 3.6), kmh)
        kinds[kind] = q
        shorts, cautious = (", ".join(f"{key} {n}" for key, n in q[part].items()) for part in ("held_short", "held_withheld"))
        print(
            f"  {kind}: {q['held']} cut records held whole (given short: {shorts}; withheld, whole already: {cautious}); "
            f"{q['mid_crash']} mid-crash, {q['mid_crash_whole']} of them with the peak; "
            f"{len(q['met_again'])} held whole meet the barrier again",
            flush=True,
        )
    out["kinds"] = kinds
    return out


def _count(q: dict, v: Vehicle, kmh: float) -> None:
    """`v`'s cuts into its kind's counts, and, where a cut held whole is off the barrier before `v`
    meets it again and stops, the time after impact `v` meets it again (listed: its drift's end)."""
    again = []
    for c in cuts(v):
        if not c.held:
            q["mid_crash"] += 1
            q["mid_crash_whole"] += c.short["peak_decel_g"] is False
            continue
        _count_held(q, v, kmh, c)
        if c.meets_again is not None:
            again.append(c.meets_again)
    if again:
        q["met_again"].append({"vehicle": v.name, "kmh": kmh, "s": max(again)})


def _count_held(q: dict, v: Vehicle, kmh: float, c: Cut) -> None:
    """A held cut into its kind's counts: each of HELD_GIVES it gives short (a silent failure,
    listed), and each UNSETTLED metric it withholds (as every held cut does: the vehicle meets the
    barrier again) though its pulse so far had it whole (the caution's cost)."""
    q["held"] += 1
    wrong = [key for key in HELD_GIVES if key in c.given and c.short[key]]
    for key in HELD_GIVES:
        q["held_short"][key] += key in wrong
    for key in UNSETTLED:
        q["held_withheld"][key] += key not in c.given and c.short[key] is False
    if wrong:
        q["failures"].append({"vehicle": v.name, "kmh": kmh, "end_s": c.end, "short": wrong})
