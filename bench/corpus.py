"""Random crash tests from models that are not crashnlp's pendulum (no crashnlp import here).

Three generator mechanisms. The first, a planar rigid body (mass m, pitch inertia I about the CG) hits a rigid wall. The front end
touches it at a body point L ahead of and h below the CG. Its crush d is how far that point
has passed the wall; the wall pushes back on it horizontally with the contact force F and
vertically with nu F (nu of either sign), acting at the wall at the point's height, so the
force's line of action misses the CG and pitches the body. The crush force follows a smooth
load curve P(d) (a monotone-cubic PchipInterpolator through random knots) plus c_d times the
crush rate while loading; it unloads along a line of stiffness k_u from the largest crush
to a permanent set and never pulls. Vertical springs and dampers at the axles carry the
static load (preloaded, so rest is an equilibrium). Integrated by scipy's solve_ivp (LSODA).

The second form, `engine_vehicle`, is that body with an engine of 12-20 % of the vehicle's mass
on mounts (a spring and a damper along x): the engine moves forward on its mounts as the body
decelerates, and once its gap to the barrier closes it meets the barrier too, through a stiff,
damped contact that never pulls. The accelerometer, velocity and displacement are the body's;
the barrier force is the sum of both contacts. The engine's load arrives late and at once, which
no single loading curve of the body's crush fitted below the gap foresees.

The third, `rate_vehicle`, is the rigid body with a strain-rate sensitive structure: its loading
force is the quasi-static curve times a Cowper-Symonds factor of the crush rate, the load curve
being the force at the speed it is built for. The force falls as the crush slows within a crash,
and a slower impact meets a softer structure, which a damper linear in the crush rate only
approximates. Unloading is elastic, rate-free: the line of stiffness k_u starts from the
quasi-static force where the loading ended (the loading force at a crush rate of zero).

Each mechanism is drawn with a car's or pickup's dimensions (`random_vehicle`, `engine_vehicle`,
`rate_vehicle`) or a van's or tall SUV's (`tall_vehicle`, `tall_engine_vehicle`, and
`rate_tall_engine_vehicle`, which has all three at once); bench/calibration.py counts each maker
as a generator form.

Measured channels, like the synthetic pickup of the shared data: CG acceleration with
structural ringing (two decaying sines) and white noise, velocity, displacement and pitch
(nose-down positive) with small noise; ground frame, x toward the wall, 10 kHz.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import PchipInterpolator

G0 = 9.80665
DT = 1e-4  # s, 10 kHz
DURATION = 0.2  # s
BAND = 1e-5  # m: the largest crush is still loading within this of it (integration error)
NOISE = {"accel_g": 0.8, "vel_mps": 0.01, "disp_m": 5e-4, "pitch_deg": 0.03}
# knots of the load curve as fractions of the crush the vehicle is made for
KNOT_FRACTIONS = np.array([0.0, 0.08, 0.2, 0.35, 0.5, 0.65, 0.8, 0.95, 1.15, 1.5])


@dataclass(frozen=True)
class Vehicle:
    """Everything the generator needs, SI."""

    name: str
    mass: float
    speed: float
    pitch_inertia: float
    cg_to_impact: float  # L
    cg_above_impact: float  # h
    cg_to_front_axle: float
    cg_to_rear_axle: float
    k_front: float
    k_rear: float
    c_front: float
    c_rear: float
    load_crush: tuple[float, ...]  # knots of the load curve, m
    load_force: tuple[float, ...]  # N
    crush_damping: float  # N s/m while loading
    unloading_stiffness: float  # N/m
    vertical_ratio: float  # nu
    ringing: tuple[tuple[float, float, float], ...]  # (amplitude g, frequency Hz, decay time s)
    seed: int
    engine: Engine | None = None  # the second form: an engine on mounts that meets the barrier late
    rate: RateSensitivity | None = None  # the third: a structure whose crush force grows with the crush rate


@dataclass(frozen=True)
class RateSensitivity:
    """A structure whose loading force is its quasi-static curve times 1 + (rate / reference)^(1/exponent)
    (Cowper-Symonds, the crush rate for the strain rate), the load curve being the force at
    `design_rate`: the force falls as the crush slows, and a slower impact meets a softer structure."""

    reference: float  # m/s
    exponent: float
    design_rate: float  # m/s: the crush rate at which the force is the load curve's

    def factor(self, rate: float) -> float:
        """The loading force over the load curve's at crush rate `rate` (m/s, 0 or more)."""
        return self._raw(rate) / self._raw(self.design_rate)

    def _raw(self, rate: float) -> float:
        return 1.0 + (max(rate, 0.0) / self.reference) ** (1.0 / self.exponent)


@dataclass(frozen=True)
class Engine:
    """An engine on mounts, SI: its share of the vehicle's mass, the mounts' stiffness and damping
    along x, its gap to the barrier (how far it travels before it touches), and the stiffness and
    damping of its contact with the barrier."""

    mass: float
    mount_stiffness: float
    mount_damping: float
    gap: float
    contact_stiffness: float
    contact_damping: float


def random_vehicle(index: int, seed: int, mass: float | None = None, speed: float | None = None) -> Vehicle:
    """One random vehicle: 900-3200 kg, 32-64 km/h (or the mass and speed given), geometry and load curve to match."""
    rng = np.random.default_rng([seed, index])
    mass = rng.uniform(900.0, 3200.0) if mass is None else mass
    speed = rng.uniform(32.0, 64.0) / 3.6 if speed is None else speed
    size = (mass - 900.0) / 2300.0
    wheelbase = 2.35 + 1.1 * size + rng.uniform(-0.1, 0.1)
    front = rng.uniform(0.38, 0.5) * wheelbase
    rear = wheelbase - front
    crush = speed * rng.uniform(0.034, 0.05)  # crush the structure is made for: stop after 70-100 ms
    mean_force = 0.5 * mass * speed**2 / crush
    shape = np.concatenate([[0.0], rng.uniform(0.55, 1.35, 7), [2.0, 4.0]])
    shape[1] *= rng.uniform(0.6, 1.2)  # bumper beam and crash boxes: a first peak of varied height
    load_force = mean_force * shape
    omega = 2 * np.pi * rng.uniform(1.0, 1.5, 2)
    loads = mass * np.array([rear, front]) / wheelbase
    k = loads * omega**2
    zeta = rng.uniform(0.2, 0.35, 2)
    c = 2 * zeta * np.sqrt(k * loads)
    ringing = (
        (rng.uniform(2.0, 6.0), rng.uniform(300.0, 500.0), rng.uniform(0.02, 0.05)),
        (rng.uniform(1.0, 3.0), rng.uniform(600.0, 900.0), rng.uniform(0.01, 0.03)),
    )
    return Vehicle(
        **_plain(
            dict(
                name=f"v{index:02d}",
                mass=mass,
                speed=speed,
                pitch_inertia=mass * (rng.uniform(0.38, 0.5) * wheelbase) ** 2,
                cg_to_impact=front + rng.uniform(0.7, 1.05),
                cg_above_impact=rng.uniform(0.04, 0.16) + 0.1 * size,
                cg_to_front_axle=front,
                cg_to_rear_axle=rear,
                k_front=k[0],
                k_rear=k[1],
                c_front=c[0],
                c_rear=c[1],
                load_crush=tuple(KNOT_FRACTIONS * crush),
                load_force=tuple(load_force),
                crush_damping=rng.uniform(1.0, 3.0) * mass,
                unloading_stiffness=rng.uniform(1.5e7, 6e7),
                vertical_ratio=rng.uniform(-0.02, 0.04),
                ringing=ringing,
                seed=seed,
            )
        )
    )


# The shared data set's synthetic pickup (problems/data/README.md), as this generator's vehicle.
PICKUP = Vehicle(
    name="pickup",
    mass=2550.0,
    speed=56.0 / 3.6,
    pitch_inertia=4800.0,
    cg_to_impact=2.45,
    cg_above_impact=0.18,
    cg_to_front_axle=1.55,
    cg_to_rear_axle=2.10,
    k_front=70e3,
    k_rear=60e3,
    c_front=8e3,
    c_rear=8e3,
    load_crush=(0.0, 0.05, 0.15, 0.25, 0.4, 0.55, 0.7, 0.85),
    load_force=(0.0, 300e3, 450e3, 380e3, 520e3, 700e3, 950e3, 1500e3),
    crush_damping=5e3,
    unloading_stiffness=3.0e7,
    vertical_ratio=0.03,
    ringing=((6.0, 420.0, 0.03), (3.0, 780.0, 0.02)),
    seed=56,
)


def _plain(value):
    """numpy scalars and arrays as Python floats and tuples (YAML and JSON write them)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list, np.ndarray)):
        return tuple(_plain(v) for v in value)
    return float(value) if isinstance(value, np.floating) else value


def tall_vehicle(index: int, seed: int, speed: float | None = None) -> Vehicle:
    """A van or a tall SUV: a random vehicle of 2600-3200 kg with its CG 0.30-0.45 m above the impact
    point, higher than random_vehicle puts it (0.04-0.26 m)."""
    rng = np.random.default_rng([seed, index, 1])
    v = random_vehicle(index, seed, mass=float(rng.uniform(2600.0, 3200.0)), speed=speed)
    return replace(v, cg_above_impact=float(rng.uniform(0.30, 0.45)))


def engine_vehicle(index: int, seed: int, speed: float | None = None) -> Vehicle:
    """A random vehicle of the second form: random_vehicle's body with an engine on mounts (with_engine)."""
    return replace(
        with_engine(random_vehicle(index, seed, speed=speed), np.random.default_rng([seed, index, 2])), name=f"e{index:02d}"
    )


def tall_engine_vehicle(index: int, seed: int, speed: float | None = None) -> Vehicle:
    """A van or a tall SUV (tall_vehicle) with an engine on mounts (with_engine)."""
    v = with_engine(tall_vehicle(index, seed, speed=speed), np.random.default_rng([seed, index, 3]))
    return replace(v, name=f"te{index:02d}")


def rate_vehicle(index: int, seed: int, speed: float | None = None) -> Vehicle:
    """A random vehicle whose structure is strain-rate sensitive (with_rate)."""
    v = with_rate(random_vehicle(index, seed, speed=speed), np.random.default_rng([seed, index, 4]))
    return replace(v, name=f"r{index:02d}")


def rate_tall_engine_vehicle(index: int, seed: int, speed: float | None = None) -> Vehicle:
    """A van or a tall SUV with an engine on mounts (tall_engine_vehicle) and a rate-sensitive structure (with_rate)."""
    v = with_rate(tall_engine_vehicle(index, seed, speed=speed), np.random.default_rng([seed, index, 5]))
    return replace(v, name=f"rte{index:02d}")


def with_rate(v: Vehicle, rng: np.random.Generator) -> Vehicle:
    """The vehicle with a rate-sensitive structure: at the speed it is built for its loading force is
    1.15 to 1.5 times the quasi-static one (the dynamic increase of automotive steels at crash strain
    rates), the exponent 3 to 6; its load curve the force at that speed; the linear crush damping
    halved (the rate sensitivity takes over part of it)."""
    increase, exponent = rng.uniform(0.15, 0.5), rng.uniform(3.0, 6.0)
    rate = RateSensitivity(reference=float(v.speed / increase**exponent), exponent=float(exponent), design_rate=v.speed)
    return replace(v, rate=rate, crush_damping=v.crush_damping / 2)


def with_engine(v: Vehicle, rng: np.random.Generator) -> Vehicle:
    """The vehicle with 12-20 % of its mass in an engine on 8-15 Hz mounts (damping ratio 0.5), whose
    gap to the barrier closes at 55-90 % of the crush the vehicle is built for; the barrier stops
    it over 8-15 cm at about the body's mean crush force, its contact damped at a ratio of 0.4-0.7."""
    mass = v.mass * rng.uniform(0.12, 0.2)
    mount = mass * (2 * np.pi * rng.uniform(8.0, 15.0)) ** 2
    mean_force = float(np.mean(v.load_force[1:8]))
    stop = rng.uniform(0.08, 0.15)  # m over which the barrier stops the engine at the mean force
    engine = Engine(
        mass=float(mass),
        mount_stiffness=float(mount),
        mount_damping=float(2 * 0.5 * np.sqrt(mount * mass)),
        gap=float(v.load_crush[-3] / KNOT_FRACTIONS[-3] * rng.uniform(0.55, 0.9)),
        contact_stiffness=float(2 * mean_force / stop),
        contact_damping=float(rng.uniform(0.4, 0.7) * 2 * np.sqrt(2 * mean_force / stop * mass)),
    )
    return replace(v, engine=engine)


def corpus(count: int = 30, seed: int = 2024) -> list[Vehicle]:
    """`count` random vehicles, the same for the same seed."""
    return [random_vehicle(i, seed) for i in range(count)]


class Body:
    """The generator's equations of motion; state X, Z, phi, Xdot, Zdot, phidot, largest crush, and
    with an engine its travel on the mounts and that travel's rate (x toward the barrier)."""

    def __init__(self, v: Vehicle):
        self.v = v
        self.load = PchipInterpolator(v.load_crush, v.load_force, extrapolate=True)

    def contact(self, X: float, phi: float, Xd: float, phid: float, d_max: float) -> tuple[float, float, float, float]:
        """Crush, crush rate, contact force and the contact point's height offset from the CG."""
        v = self.v
        x_rel = v.cg_to_impact * np.cos(phi) - v.cg_above_impact * np.sin(phi)
        z_rel = -v.cg_to_impact * np.sin(phi) - v.cg_above_impact * np.cos(phi)
        d = X + x_rel - v.cg_to_impact
        rate = Xd + phid * (-v.cg_to_impact * np.sin(phi) - v.cg_above_impact * np.cos(phi))
        if d <= 0.0:
            return d, rate, 0.0, z_rel
        if d >= d_max - BAND and rate > 0.0:
            force = float(self.load(d)) * self.rate_factor(rate) + v.crush_damping * rate
        else:
            static = self.rate_factor(0.0)  # the quasi-static curve's share: no crush rate while unloading
            force = min(static * float(self.load(d)), static * float(self.load(d_max)) - v.unloading_stiffness * (d_max - d))
        return d, rate, max(force, 0.0), z_rel

    def rate_factor(self, rate: float) -> float:
        """The loading force over the load curve's at crush rate `rate` (1 without rate sensitivity)."""
        return 1.0 if self.v.rate is None else self.v.rate.factor(rate)

    def engine_forces(self, s: np.ndarray) -> tuple[float, float]:
        """The mounts' pull on the body (toward the barrier positive) and the barrier's push on
        the engine (>= 0); both zero without an engine."""
        e = self.v.engine
        if e is None:
            return 0.0, 0.0
        X, Xd, travel, rate = s[0], s[3], s[7], s[8]
        mount = e.mount_stiffness * travel + e.mount_damping * rate
        reach = X + travel - e.gap
        push = e.contact_stiffness * reach + e.contact_damping * (Xd + rate) if reach > 0.0 else 0.0
        return mount, max(push, 0.0)

    def body_accel(self, s: np.ndarray) -> tuple[float, float]:
        """The body's x acceleration (where the accelerometer sits) and the barrier's whole force."""
        _, _, F, _ = self.contact(s[0], s[2], s[3], s[5], s[6])
        mount, push = self.engine_forces(s)
        body_mass = self.v.mass - (self.v.engine.mass if self.v.engine else 0.0)
        return (-F + mount) / body_mass, F + push

    def rhs(self, t: float, s: np.ndarray) -> np.ndarray:
        v = self.v
        X, Z, phi, Xd, Zd, phid, d_max = s[:7]
        d, rate, F, z_rel = self.contact(X, phi, Xd, phid, d_max)
        Fx, Fz = -F, v.vertical_ratio * F
        r_x = v.cg_to_impact - d  # the force acts at the wall
        torque = z_rel * Fx - r_x * Fz  # nose-down positive
        Fz_total = Fz
        for a, k, c in ((v.cg_to_front_axle, v.k_front, v.c_front), (-v.cg_to_rear_axle, v.k_rear, v.c_rear)):
            z_axle, zd_axle = Z - a * np.sin(phi), Zd - a * np.cos(phi) * phid
            f = -k * z_axle - c * zd_axle
            Fz_total += f
            torque -= a * np.cos(phi) * f
        growth = max(rate, 0.0) if d >= d_max - BAND else 0.0
        body = [Xd, Zd, phid, self.body_accel(s)[0], Fz_total / v.mass, torque / v.pitch_inertia, growth]
        if v.engine is None:
            return np.array(body)
        mount, push = self.engine_forces(s)
        engine_accel = (-mount - push) / v.engine.mass
        return np.array([*body, s[8], engine_accel - body[3]])


def simulate(v: Vehicle, body_type: type[Body] = Body, duration: float = DURATION) -> dict[str, np.ndarray]:
    """Noise-free response at 10 kHz for `duration`: time, accel, velocity, displacement, pitch,
    barrier force and the part of it that meets the engine (SI), of `body_type`'s equations of motion."""
    body = body_type(v)
    t = DT * np.arange(int(round(duration / DT)) + 1)
    start = [0, 0, 0, v.speed, 0, 0, 0] + ([0, 0] if v.engine else [])
    sol = solve_ivp(body.rhs, (0.0, duration), start, method="LSODA", t_eval=t, rtol=1e-9, atol=1e-11, max_step=5e-5)
    if not sol.success:
        raise RuntimeError(f"{v.name}: {sol.message}")
    X, Z, phi, Xd = sol.y[:4]
    accel, force = np.array([body.body_accel(si) for si in sol.y.T]).T
    engine = np.array([body.engine_forces(si)[1] for si in sol.y.T])
    return {
        "time": t,
        "accel": accel,
        "velocity": Xd,
        "displacement": X,
        "pitch": phi,
        "barrier_force": force,
        "engine_force": engine,
    }


def measured(v: Vehicle, truth: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The channels a test would record: ringing and noise on top of the truth (report units)."""
    rng = np.random.default_rng([v.seed, 99, int("".join(filter(str.isdigit, v.name)) or 0)])
    t = truth["time"]
    ring = sum(a * np.sin(2 * np.pi * f * t) * np.exp(-t / tau) for a, f, tau in v.ringing)
    n = t.size
    return {
        "time_s": t,
        "accel_x_g": truth["accel"] / G0 + ring + NOISE["accel_g"] * rng.standard_normal(n),
        "vel_x_mps": truth["velocity"] + NOISE["vel_mps"] * rng.standard_normal(n),
        "disp_x_m": truth["displacement"] + NOISE["disp_m"] * rng.standard_normal(n),
        "pitch_deg": np.degrees(truth["pitch"]) + NOISE["pitch_deg"] * rng.standard_normal(n),
    }


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(zip(*(np.round(c, 7) for c in columns.values())))
