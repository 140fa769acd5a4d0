"""Records cut short: MID_CRASH on generator vehicles of every kind, from a seed the rule never saw.

A record that ends while the vehicle still moves toward the barrier is mid-crash where its
deceleration at its end is at least MID_CRASH of its peak so far (crashnlp.analysis.summary): it
then gives no peak, stop, rebound or other metric the crash's rest would change. Below that it holds
the pulse whole (a van whose pitch lifted its front end off drifts on without contact) and its
peak stands. The rule fails silently where it holds a record whole whose crash goes on to a larger
peak, an engine that meets the barrier late for one. MID_CRASH was set with the shipped tests cut
short (the pickup, the Camry) and the calibration corpus's tall vans in view; here it is checked on SEED's
vehicles of the four generator kinds (random, engine on mounts, tall, tall with an engine on
mounts), each at SPEEDS_KMH, noise-free, every record cut every STEP from FIRST_CUT to its stop.
Per kind: the cut records the rule held whole, those of them whose peak fell short of the whole
record's by more than SHORT (silent failures), and the cut records it called mid-crash whose peak
was already whole (its caution: a peak not given that was right).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np

from bench.corpus import Vehicle, engine_vehicle, random_vehicle, simulate, tall_engine_vehicle, tall_vehicle
from crashnlp.analysis.summary import MID_CRASH, metrics

SEED = 7777  # never used to set a rule
COUNT = 12  # vehicles of each kind
SPEEDS_KMH = (40.0, 56.0, 64.0)
FIRST_CUT, STEP = 0.010, 0.002  # s
SHORT = 0.01  # a held peak more than this short of the whole record's (relative) is a silent failure
KINDS: dict[str, Callable[[int, int], Vehicle]] = {
    "random": random_vehicle,
    "engine on mounts": engine_vehicle,
    "tall": tall_vehicle,
    "tall, engine on mounts": tall_engine_vehicle,
}


def cuts(v: Vehicle) -> Iterator[tuple[float, bool, float]]:
    """(end, held whole, peak short) of `v`'s noise-free record cut every STEP before its stop, where
    the cut record still moves toward the barrier: whether `metrics` holds its pulse whole, and
    how far the deceleration's peak up to the cut falls short of the whole record's (relative)."""
    truth = simulate(v)
    t, channels = truth["time"], [truth[k] for k in ("accel", "velocity", "displacement", "pitch")]
    decel = -channels[0]
    stop = metrics(t, *channels)["time_zero_velocity_s"]
    for end in np.arange(FIRST_CUT, t[-1] if stop is None else stop, STEP):
        k = int(np.searchsorted(t, end)) + 1
        cut = metrics(t[:k], *(c[:k] for c in channels))
        if cut["time_zero_velocity_s"] is None:
            yield float(end), cut["peak_decel_g"] is not None, 1.0 - float(np.max(decel[:k]) / np.max(decel))


def run(quick: bool = False) -> dict:
    """The bench section: COUNT vehicles of each kind (1 with --quick) at every speed, every cut."""
    count = 1 if quick else COUNT
    out: dict = {"seed": SEED, "count": count, "speeds_kmh": SPEEDS_KMH, "step_s": STEP, "short": SHORT, "mid_crash": MID_CRASH}
    kinds = {}
    for kind, make in KINDS.items():
        held = short = cautious = mid = 0
        failures = []
        for i in range(count):
            for kmh in SPEEDS_KMH:
                v = replace(make(i, SEED), speed=kmh / 3.6)
                for end, whole, shortfall in cuts(v):
                    held += whole
                    mid += not whole
                    short += whole and shortfall > SHORT
                    cautious += not whole and shortfall <= SHORT
                    if whole and shortfall > SHORT:
                        failures.append({"vehicle": v.name, "kmh": kmh, "end_s": end, "short": shortfall})
        kinds[kind] = {"held": held, "held_short": short, "mid_crash": mid, "mid_crash_whole": cautious, "failures": failures}
        print(
            f"  {kind}: {held} cut records held whole, {short} of them short of the peak; {mid} mid-crash, {cautious} of them already whole",
            flush=True,
        )
    out["kinds"] = kinds
    return out
