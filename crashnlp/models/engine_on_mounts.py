"""The engine-on-mounts crash model: the rigid body with an engine on mounts that meets the barrier late.

Coordinates q = (x, z, phi, u): the rigid body's (crashnlp.models.rigid_body: the CG's travel
toward the barrier, its heave and pitch, nose-down positive) and the engine's travel u toward the
barrier relative to the body, on its mounts (a spring and a damper along x, `vehicle.engine`).
The engine is part of `vehicle.mass` and of the pitch inertia: it heaves with the body's CG and
adds only its fore-aft freedom,

    T = T_rigid - m_e xdot^2 / 2 + m_e (xdot + udot)^2 / 2,   V += k_m u^2 / 2,   D += c_m udot^2 / 2.

The front end is the rigid body's element. The engine meets the barrier once its gap closes: its
reach r = x + u - gap is how far it has passed the barrier's face, and the barrier pushes it back
with k_c r + c_c rdot, compression only (crashnlp.models.form.Contact). The mounts carry that push
to the body along x at the CG's height, without a pitch moment, so the barrier's force is the
front end's and the engine's, while the body's pitch is the front end's doing alone: the part of a
late impulse no single front-end element can carry.

Why the rigid body and not the pendulum: the pendulum's body turns about the impact point, so
every barrier force it takes acts there; an engine that meets the barrier at the CG's height is a
second point of action that form cannot hold. The rigid body's barrier force acts where it meets
the body, so a second contact is one more generalised force.

What a problem leaves out of `vehicle.engine` is filled in (`complete`): the engine's mass a
share ENGINE_SHARE of the vehicle's, mounts at MOUNT_FREQUENCY with damping ratio MOUNT_DAMPING,
the gap from the recorded pulse (`second_rise`), and the contact from the body's mean crush force
(CONTACT_STOP). A fit estimates the gap (`own_estimate`) and none of the others by default: the
gap read from the pulse can be a quarter off its vehicle's, and a gap that far off misfits the
pitch and the peak (measured: docs/design-notes.md, "The engine on its mounts").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import casadi as ca
import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.models.form import OPEN_AT_IMPACT, SEPARATION, Contact, Expr, Mechanics
from crashnlp.models.laws import never_pulling, rounded_hinge, rounded_hinge_integral, smooth_engagement
from crashnlp.models.rigid_body import RigidBodyModel
from crashnlp.problem.schema import Engine, EstimateSpec, Problem, with_fields

# The engine and gearbox's share of the vehicle's mass: a tenth to a fifth of a passenger car's (a
# rule of thumb, assumed: docs/design-notes.md, "The engine on its mounts").
ENGINE_SHARE = 0.15
MOUNT_FREQUENCY = 10.0  # Hz: the powertrain's fore-aft rigid-body mode on its mounts (8 to 15 Hz)
MOUNT_DAMPING = 0.5  # damping ratio of the mounts (hydraulic mounts, large amplitude)
# The contact: the barrier stops the engine at about twice the body's mean crush force (the work
# of the fastest test's impact over its largest travel) within CONTACT_STOP of engine travel, the
# crush space of the radiator and the engine's accessories; damped at CONTACT_DAMPING of critical.
# Assumed, not measured on real tests (docs/design-notes.md, "The engine on its mounts").
CONTACT_STOP = 0.12  # m
CONTACT_DAMPING = 0.5
# The gap: where the recorded loading curve (m |a| against the CG's travel) of the furthest test rises again,
# its force RISE times its trough's after its first peak (`second_rise`); without one, a share
# GAP_SHARE of the largest travel.
RISE = 1.2
GAP_SHARE = 0.7
GAP_BOUNDS = (0.7, 1.4)  # a fit estimates the gap within these times its value from the data
# The contact builds up over CONTACT_WIDTH of reach (the corner of its spring rounded, its damper
# engaged), a switch where model.smoothing.crush is 0: wide enough that an engine at 10 m/s takes
# a 1 ms integration step to cross it, so that a fit does not see its force jump between steps
# (the crush smoothing's 1 mm ran fits out of iterations: docs/design-notes.md).
CONTACT_WIDTH = 0.01  # m


class MeasuredPulse(Protocol):
    """What `complete` reads of a test's recorded pulse (crashnlp.case.completion.Pulse)."""

    @property
    def displacement(self) -> np.ndarray: ...
    @property
    def mass(self) -> float: ...
    @property
    def force(self) -> np.ndarray: ...
    @property
    def speed(self) -> float: ...


class EngineOnMountsModel(RigidBodyModel):
    """Symbolic rigid body with an engine on mounts that meets the barrier through a contact."""

    COORDINATES = ("x", "z", "phi", "u")
    STATE_FLOOR = (0.01, 0.01, 0.01, 0.01, 0.1, 0.1, 0.01, 0.1, 0.01)  # m, m, rad, m; m/s, m/s, rad/s, m/s; m

    def mechanics(self) -> Mechanics:
        body = super().mechanics()
        m_e = self._par("vehicle.engine.mass")
        xd, ud = self.qd[0], self.qd[3]
        T = body.kinetic - 0.5 * m_e * xd**2 + 0.5 * m_e * (xd + ud) ** 2
        V = body.potential + 0.5 * self._par("vehicle.engine.mount_stiffness") * self.q[3] ** 2
        D = body.dissipation + 0.5 * self._par("vehicle.engine.mount_damping") * ud**2
        return Mechanics(T, V, D, body.displacement, body.velocity, body.pitch, body.crush, body.barrier_share)

    def contacts(self) -> tuple[Contact, ...]:
        """The engine's contact with the barrier: elastic k_c r (its corner rounded over
        CONTACT_WIDTH, zero before it: the barrier does not reach out), a damper c_c rdot engaged
        over the first CONTACT_WIDTH, its corners rounded (`smooth_engagement`: the gap, a fitted
        parameter, moves where they are crossed), the push never pulling (its separation rounded as the front
        end's, closed before it touches)."""
        eps = CONTACT_WIDTH if self.structure.eps_crush > 0 else 0.0
        k, c = self._par("vehicle.engine.contact_stiffness"), self._par("vehicle.engine.contact_damping")
        reach = self.q[0] + self.q[3] - self._par("vehicle.engine.gap")
        rate = ca.jtimes(reach, self.q, self.qd)
        if eps > 0:
            elastic, stored = k * rounded_hinge(reach, eps), k * rounded_hinge_integral(reach, eps)
        else:
            elastic, stored = k * ca.fmax(reach, 0), 0.5 * k * ca.fmax(reach, 0) ** 2
        engaged = smooth_engagement(reach, eps)
        push = elastic + engaged * c * rate
        force = never_pulling(push, SEPARATION * eps * k * (engaged + OPEN_AT_IMPACT), eps)
        return (Contact(reach, force, elastic, stored),)

    def initial_state_after_impact(self, v0: Expr) -> Expr:
        """At rest on its suspension and mounts, moving at v0."""
        return ca.vertcat(0, 0, 0, 0, v0, 0, 0, 0, 0)

    @classmethod
    def check(cls, problem: Problem) -> None:
        """The rigid body's, and an engine lighter than the vehicle."""
        super().check(problem)
        engine = problem.vehicle.engine
        if engine is not None and engine.mass is not None and problem.vehicle.mass is not None:
            if engine.mass >= problem.vehicle.mass:
                raise InputError(
                    f"vehicle.engine.mass: {engine.mass:g} kg is not less than vehicle.mass ({problem.vehicle.mass:g} kg); "
                    "the engine is part of the vehicle"
                )

    @classmethod
    def complete(cls, problem: Problem, pulses: Sequence[MeasuredPulse]) -> Problem:
        """`vehicle.engine` with what the problem leaves out filled in (the module's notes)."""
        given = problem.vehicle.engine or Engine()
        mass = given.mass if given.mass is not None else ENGINE_SHARE * problem.vehicle.known_mass
        mount = given.mount_stiffness if given.mount_stiffness is not None else mass * (2 * np.pi * MOUNT_FREQUENCY) ** 2
        gap = given.gap if given.gap is not None else default_gap(pulses)
        stiffness = given.contact_stiffness if given.contact_stiffness is not None else 2 * mean_force(pulses) / CONTACT_STOP
        filled = dict(
            mass=mass,
            mount_stiffness=mount,
            mount_damping=_or(given.mount_damping, 2 * MOUNT_DAMPING * np.sqrt(mount * mass)),
            gap=gap,
            contact_stiffness=stiffness,
            contact_damping=_or(given.contact_damping, 2 * CONTACT_DAMPING * np.sqrt(stiffness * mass)),
        )
        engine = given.model_copy(update={k: float(v) for k, v in filled.items()})
        return with_fields(problem, vehicle=problem.vehicle.model_copy(update={"engine": engine}))

    @classmethod
    def own_estimate(cls, problem: Problem) -> dict[str, EstimateSpec]:
        """The gap, within GAP_BOUNDS times the value the problem gives or the data chose: where the
        engine meets the barrier is what the pulse shows least exactly (`second_rise`), and a gap
        fixed a fifth off misfits the pitch and the peak (docs/design-notes.md)."""
        gap = problem.vehicle.engine.gap if problem.vehicle.engine is not None else None
        if gap is None:
            return {}
        return {"vehicle.engine.gap": EstimateSpec(bounds=(GAP_BOUNDS[0] * gap, GAP_BOUNDS[1] * gap))}


def _or(value: float | None, default: float) -> float:
    return default if value is None else value


def second_rise(displacement: np.ndarray, force: np.ndarray) -> float | None:
    """The CG's travel where a loading curve (force against travel, while loading) rises a second
    time: past its first peak (the largest force of its first third of samples: bumper beam and
    crash boxes), the first travel where the force exceeds both that peak and RISE times its lowest
    since; None where it never does."""
    if force.size < 3:
        return None
    first = int(np.argmax(force[: max(3, force.size // 3)]))
    trough = force[first]
    for i in range(first + 1, force.size):
        trough = min(trough, force[i])
        if force[i] > RISE * trough and force[i] > force[first]:
            return float(displacement[i])
    return None


def default_gap(pulses: Sequence[MeasuredPulse]) -> float:
    """The gap from the pulse of the test that travels furthest: where its loading curve rises a
    second time (`second_rise`), else GAP_SHARE of its largest travel."""
    if not pulses:
        raise InputError("vehicle.engine.gap: not given, and no test has accel or velocity data to derive it from")
    p = max(pulses, key=lambda p: float(np.max(p.displacement)))
    loading = slice(0, int(np.argmax(p.displacement)) + 1)
    found = second_rise(p.displacement[loading], p.force[loading])
    return found if found is not None else GAP_SHARE * float(np.max(p.displacement))


def mean_force(pulses: Sequence[MeasuredPulse]) -> float:
    """The body's mean crush force in the fastest test: its impact energy over its largest travel."""
    if not pulses:
        raise InputError("vehicle.engine.contact_stiffness: not given, and no test has data to derive it from")
    p = max(pulses, key=lambda p: p.speed)
    return 0.5 * p.mass * p.speed**2 / float(np.max(p.displacement))
