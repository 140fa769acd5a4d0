"""Crash-pulse metrics from time, acceleration, velocity and displacement (SI, model frame).

Model frame: x toward the barrier, impact at t = 0, so accel < 0 while crushing, velocity starts
at +v0 and displacement (CG travel since impact) is positive. Works for test data and model
output alike. Definitions:
- max displacement: the CG's largest travel since impact, and its time (NHTSA's "maximum dynamic
  crush"; not the front end's crush, which the model reports apart);
- time of zero velocity: first downward crossing of v = 1e-6 v0 after impact (so a vehicle that stops
  without rebound counts as stopped), linearly interpolated;
- delta-V: v0 - min(v) (includes the rebound); rebound velocity: -min(v) (>= 0);
- peak deceleration: max(-a);
- ESW (equivalent square wave, displacement based): v0^2 / (2 C), C the max displacement;
  TESW (time based): v0 / t_m, t_m the time of zero velocity; both as in M. Huang,
  "Vehicle Crash Mechanics", CRC Press 2002, ch. 2 (constant decelerations that stop the
  vehicle in the same crush, resp. the same time);
- OLC (Occupant Load Criterion; Kuebler, Gargallo, Elsaesser, "Characterization and evaluation
  of frontal crash pulses with respect to occupant safety", Airbag 2008 / ESV): a virtual occupant
  moves freely at v0 until it has travelled 65 mm relative to the vehicle (t1), then decelerates
  at a constant rate, reaching the vehicle velocity after a further 235 mm (t2); OLC is that rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OLC_FREE = 0.065  # m, free flight of the virtual occupant
OLC_RESTRAINED = 0.235  # m, restrained travel until it moves with the vehicle
STOPPED = 1e-6  # fraction of v0 below which the vehicle counts as stopped
DRIFT = 0.05  # m/s toward the barrier without contact: still moving, not stopped
# A model whose front end lets go of the barrier for the last time within its record while its CG
# still moves toward it, slower than LET_GO of the impact speed, has ended its loading
# there: what follows is a drift on the suspension without contact (the pitch lifted the front end
# off), at a speed within the rebound's own error (the calibration's rebound scale is at least this
# share of the impact speed). Its stop is that instant (`let_go_end`); set and checked on the
# corpus (docs/design-notes.md, "A crash that ends as the front end lets go").
LET_GO = 0.05
# a force on the barrier below this share of its largest is none: a model's smoothed switches leave
# a residue where a contact has opened (an engine's contact, 1e-6 N after a 500 kN crash)
NO_FORCE = 1e-9


@dataclass(frozen=True)
class CrashMetrics:
    """Metrics in SI: m, s, m/s, m/s^2. NaN where a metric is not reached in the record."""

    v0: float
    max_displacement: float
    t_max_displacement: float
    t_zero_velocity: float
    delta_v: float
    rebound_velocity: float
    end_velocity: float
    peak_decel: float
    t_peak_decel: float
    esw: float
    tesw: float
    olc: float


def lift_off(t: np.ndarray, velocity: np.ndarray, contact: np.ndarray, faster_than: float = DRIFT) -> float | None:
    """The first time the front end lets go of the barrier (contact force back to zero, `touching`,
    after it was positive) while the CG still moves toward it faster than `faster_than` (m/s); None when it
    never does. A model whose pitch lifts the front end off stops late or not at all: its crush and
    stop are then the pitch's, not the structure's."""
    pushing = touching(contact)
    touched = np.cumsum(pushing) > 0
    off = np.flatnonzero(touched & ~pushing & (velocity > faster_than))
    return float(t[off[0]]) if off.size else None


def touching(contact: np.ndarray) -> np.ndarray:
    """Where a contact force pushes: above NO_FORCE of its largest."""
    contact = np.asarray(contact, float)
    return contact > NO_FORCE * float(np.max(contact, initial=0.0))


def let_go_end(t: np.ndarray, velocity: np.ndarray, contact: np.ndarray) -> float | None:
    """The instant a model's crash ends without a stop in its record: where the force on the
    barrier (`contact`: every contact's, an engine's too) falls to zero for the last time
    (`touching`), the CG moving on toward it slower than LET_GO of the impact speed; None where the
    velocity reaches zero in the record, the barrier still pushes at its end, or the CG moves on
    faster as it lets go. A vehicle that lets go, touches the barrier again and lets go once more
    ends its loading at the last let-go."""
    if np.isfinite(zero_crossing(t, velocity, STOPPED * abs(float(velocity[0])))):
        return None
    pushing = touching(contact)
    if not pushing.any() or pushing[-1]:
        return None
    off = int(np.flatnonzero(pushing)[-1]) + 1
    return float(t[off]) if float(velocity[off]) <= LET_GO * abs(float(velocity[0])) else None


def zero_crossing(t: np.ndarray, v: np.ndarray, level: float = 0.0) -> float:
    """First time v falls from above `level` to at or below it, linearly interpolated; NaN if never."""
    idx = np.flatnonzero((v[:-1] > level) & (v[1:] <= level))
    if idx.size == 0:
        return float("nan")
    i = idx[0]
    return float(t[i] + (t[i + 1] - t[i]) * (v[i] - level) / (v[i] - v[i + 1]))


def olc(t: np.ndarray, velocity: np.ndarray, displacement: np.ndarray) -> float:
    """Occupant Load Criterion [m/s^2] of a vehicle pulse starting at impact (t[0], v0 = velocity[0]).

    Relative occupant travel in free flight is v0 (t - t0) - x(t) (x from impact); t1 is where it
    reaches 65 mm. For t2 > t1 the constant-deceleration phase gives OLC = (v0 - v(t2)) / (t2 - t1)
    and a relative travel of v0 (t1 - t0) + (v0 + v(t2)) / 2 (t2 - t1) - x(t2); t2 is the first time this
    reaches 300 mm. Linear interpolation between samples; NaN if the occupant never gets there.
    """
    t = np.asarray(t, float) - t[0]
    v0 = velocity[0]
    x = np.asarray(displacement, float) - displacement[0]
    free = v0 * t - x
    k = np.flatnonzero(free >= OLC_FREE)
    if k.size == 0:
        return float("nan")
    k = k[0]
    t1 = float(np.interp(OLC_FREE, free[k - 1 : k + 1], t[k - 1 : k + 1])) if k > 0 else float(t[0])
    later = t > t1
    tt, vv, xx = t[later], velocity[later], x[later]
    travel = v0 * t1 + 0.5 * (v0 + vv) * (tt - t1) - xx
    j = np.flatnonzero(travel >= OLC_FREE + OLC_RESTRAINED)
    if j.size == 0:
        return float("nan")
    j = j[0]
    if j > 0:
        w = (OLC_FREE + OLC_RESTRAINED - travel[j - 1]) / (travel[j] - travel[j - 1])
        t2 = tt[j - 1] + w * (tt[j] - tt[j - 1])
        v2 = vv[j - 1] + w * (vv[j] - vv[j - 1])
    else:
        t2, v2 = tt[0], vv[0]
    return float((v0 - v2) / (t2 - t1))


def crash_metrics(t: np.ndarray, accel: np.ndarray, velocity: np.ndarray, displacement: np.ndarray) -> CrashMetrics:
    """Metrics of one frontal-crash response; samples before t = 0 (pre-impact) are ignored.

    `displacement` is the CG travel since impact (0 at t = 0); v0 is the velocity at t = 0
    (or at the first sample when the record starts later).
    """
    t, a, v, x = (np.asarray(arr, float) for arr in (t, accel, velocity, displacement))
    if t[0] < 0.0 < t[-1] and not np.any(t == 0.0):  # add the impact instant itself
        k = int(np.searchsorted(t, 0.0))
        t, a, v, x = (np.insert(arr, k, np.interp(0.0, t, arr)) for arr in (t, a, v, x))
    after = t >= 0.0
    t, a, v, x = t[after], a[after], v[after], x[after]
    v0 = float(v[0])
    i_travel = int(np.argmax(x))
    i_peak = int(np.argmax(-a))
    t_stop = zero_crossing(t, v, STOPPED * abs(v0))
    max_displacement = float(x[i_travel])
    return CrashMetrics(
        v0=v0,
        max_displacement=max_displacement,
        t_max_displacement=float(t[i_travel]),
        t_zero_velocity=t_stop,
        delta_v=float(v0 - v.min()),
        rebound_velocity=float(max(0.0, -v.min())),
        end_velocity=float(v[-1]),
        peak_decel=float(-a[i_peak]),
        t_peak_decel=float(t[i_peak]),
        esw=v0**2 / (2.0 * max_displacement) if max_displacement > 0 else float("nan"),
        tesw=v0 / t_stop if t_stop > 0 else float("nan"),
        olc=olc(t, v, x),
    )
