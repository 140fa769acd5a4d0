"""The seam between a crash model's form and everything that uses it: `CrashModel`.

A form says how the body moves: its coordinates q, their scales, and its kinetic energy T,
potential V (gravity and the preloaded suspension, zero at rest), Rayleigh function D and the
front end's crush c(q), written once as CasADi expressions (`Mechanics`). The base class forms
Lagrange's equations from them by AD,

    d/dt dL/dqdot - dL/dq + dD/dqdot = Q,   L = T - V,   Q = -F dc/dq,

so the front-end force F does work only through the crush and the barrier none. The front end
(spring law, damper, unloading, tail) and its history state (the largest crush so far, the
last state of every form) are the same element in every form. What the rest of the package
uses is the same for every form: `rhs`, `outputs` (crashnlp.base.outputs' registry, in its order),
`initial_state`, `loading_curve`, `states` and `state_floor`, `pitch_estimate`, the pitch
entries a fit estimates by default, and `check`, what the form refuses to model. A new form is a subclass in one module and one
entry of crashnlp.problem.forms.FORMS.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from crashnlp.base.outputs import NAMES
from crashnlp.models import stored as model_store
from crashnlp.models.laws import (
    SPRING_LAWS,
    UNLOADING_LAWS,
    Expr,
    damper_force,
    engagement,
    hinge,
    never_pulling,
    with_tail,
)
from crashnlp.models.parameters import ParameterLayout
from crashnlp.problem.forms import FORMS
from crashnlp.problem.schema import EstimateSpec, Problem
from crashnlp.problem.schema import Model as ModelSpec
from crashnlp.problem.schema import Tail as TailSpec

HISTORY = "x_max"  # every form's last state: the largest crush so far (m)
ABSORBED = ("barrier_power", "front_damper_power", "damper_power")  # integrated by the simulator
HISTORY_GATE = 5e-3  # m: the largest crush stops following a reloading crush this far below it
# The contact force never pulls: it is the front end's push where positive, zero once the vehicle
# separates. Where the front end unloads, the switch is rounded over a band of SEPARATION crush
# smoothing widths along the unloading stiffness (the unloading switch's width,
# crashnlp.models.laws.plastic_unloading), exact outside it (crashnlp.models.laws.rounded_hinge).
# Unrounded, its slope falls from the unloading stiffness to zero at one instant, and a fit of the
# model as the test records it, whose filtered data read above zero after the pulse, sits on that
# kink at a shooting node, its dual infeasibility held up at any integration step, and the fit
# cycles. At impact the band closes (`_separation_width`): a band there would start contact with a
# jump of force, on which fits cycle instead (measured: docs/design-notes.md, "The end of contact,
# once the model is recorded").
SEPARATION = 0.1
OPEN_AT_IMPACT = 1e-9  # of the band at impact, or before a contact touches (a join of zero width divides by zero)
OUTPUTS = NAMES  # the registry's order (crashnlp.base.outputs)
# CG height above the impact point (bumper beam about 0.45 m, CG 0.45 m to 0.9 m) and radius of
# gyration in pitch (0.9 m for a city car to 1.8 m for a long van; sqrt(I / m)).
CG_ABOVE_IMPACT_BOUNDS = (-0.1, 0.5)  # m
PITCH_GYRATION_BOUNDS = (0.9, 1.8)  # m


@dataclass(frozen=True)
class Structure:
    """What fixes the shape of the symbolic model (not its numbers)."""

    spring_law: str
    unloading_law: str
    n_spring: int
    n_damper: int
    eps_crush: float
    eps_rate: float
    tail: bool = False  # the spring law bends into the line of model.spring.tail

    @classmethod
    def of(cls, spec: ModelSpec) -> Structure:
        return cls(
            spec.spring.law,
            spec.unloading.law,
            len(spec.spring.placed_breakpoints),
            0 if spec.damper is None else len(spec.damper.rate_breakpoints),
            spec.smoothing.crush,
            spec.smoothing.rate,
            isinstance(spec.spring.tail, TailSpec),
        )


@dataclass(frozen=True)
class Mechanics:
    """A form's energies and kinematics, expressions of the coordinates q and their rates.

    The form gives the CG's velocity itself (the node its T is made of) rather than the base
    class differentiating the displacement again: reverse-mode derivatives sum over a node's
    uses in graph order, so a second, equal node would move the NLP's derivatives, and a fit's
    numbers, in their last bits."""

    kinetic: Expr  # T
    potential: Expr  # V: gravity and suspension, zero at rest
    dissipation: Expr  # D: the suspension dampers' Rayleigh function
    displacement: Expr  # the CG's travel toward the barrier since impact
    velocity: Expr  # its rate, of q and qdot (its own rate is the acceleration)
    pitch: Expr  # nose-down positive, zero at rest
    crush: Expr  # the front end's shortening along its line of action
    barrier_share: Expr  # cosine of the line of action to the horizontal: barrier force / contact force


@dataclass(frozen=True)
class Contact:
    """A second body part that meets the barrier besides the front end (an engine on its mounts):
    how far it has passed the barrier's face along x (`reach`, an expression of q, positive once
    it touches), its force on it (>= 0), the elastic part of that force and the energy the elastic
    part stores. Its force enters Lagrange's equations as Q = -force d(reach)/dq, the barrier's
    force and the stored energy as the front end's do; what it does not store it dissipates."""

    reach: Expr
    force: Expr
    elastic: Expr
    stored: Expr


class CrashModel(ABC):
    """Symbolic crash model of one form; CasADi Functions of (state, parameters).

    The state is (q, qdot, x_max): a form's coordinates, their rates and the front end's history."""

    COORDINATES: ClassVar[tuple[str, ...]]
    STATE_FLOOR: ClassVar[tuple[float, ...]]  # smallest scale of each state, in SI (NLP scaling)

    rhs: ca.Function
    outputs: ca.Function
    initial_state: ca.Function
    loading_curve: ca.Function

    def __init__(self, structure: Structure, layout: ParameterLayout, whole: ca.Function | None = None):
        """The model of `structure` and `layout`: derived, or read from `whole`, what `whole()`
        gave of a model of the same form, structure and layout (crashnlp.models.stored)."""
        self.structure = structure
        self.layout = layout
        n = len(self.COORDINATES)
        self.x = ca.SX.sym("x", self.nx) if whole is None else whole.sx_in(0)
        self.q, self.qd = self.x[:n], self.x[n : 2 * n]
        self.p = ca.SX.sym("p", layout.size) if whole is None else whole.sx_in(1)
        self._functions: dict[tuple, Any] = {}
        self._parameters = layout.split(self.p)
        if whole is None:
            self._build()
        else:
            crush, v0 = whole.sx_in(2), whole.sx_in(3)
            self._assign(crush, v0, *whole(self.x, self.p, crush, v0))

    # ---------------------------------------------------------------- what a form says
    @classmethod
    def states(cls) -> tuple[str, ...]:
        """The state's names: the coordinates, their rates, the history."""
        return (*cls.COORDINATES, *(f"{c}dot" for c in cls.COORDINATES), HISTORY)

    @property
    def nx(self) -> int:
        return len(self.states())

    @property
    def state_floor(self) -> np.ndarray:
        return np.asarray(self.STATE_FLOOR, dtype=float)

    @abstractmethod
    def mechanics(self) -> Mechanics:
        """T, V, D, the crush and the kinematics the outputs read, of self.q and self.qd."""

    def contacts(self) -> tuple[Contact, ...]:
        """Body parts that meet the barrier besides the front end; none unless a form has them."""
        return ()

    @abstractmethod
    def initial_state_after_impact(self, v0: Expr) -> Expr:
        """The state just after impact at horizontal speed v0 (a column of length nx)."""

    @classmethod
    def check(cls, problem: Problem) -> None:
        """Refuse (InputError naming the entry) a problem this form cannot model; every form
        models every valid problem unless it says otherwise."""
        return None

    @classmethod
    def pitch_estimate(cls, problem: Problem, several_speeds: bool) -> dict[str, EstimateSpec]:
        """What a fit estimates by default when a test measures pitch: the CG's height above the
        impact point and the pitch inertia, within physical bounds (CG_ABOVE_IMPACT_BOUNDS,
        PITCH_GYRATION_BOUNDS)."""
        mass = problem.vehicle.known_mass
        lo, hi = PITCH_GYRATION_BOUNDS
        return {
            "vehicle.cg_above_impact": EstimateSpec(bounds=CG_ABOVE_IMPACT_BOUNDS),
            "vehicle.pitch_inertia": EstimateSpec(bounds=(mass * lo**2, mass * hi**2)),
        }

    @classmethod
    def complete(cls, problem: Problem, pulses: Sequence[Any]) -> Problem:
        """The problem with the form's own entries it leaves out filled in from the tests'
        measured pulses (crashnlp.case.completion.Pulse); a form without entries of its own
        returns it as it is."""
        return problem

    @classmethod
    def own_estimate(cls, problem: Problem) -> dict[str, EstimateSpec]:
        """What a fit estimates by default of the form's own entries (once `complete` has filled
        them in); none unless a form has entries of its own."""
        return {}

    # ---------------------------------------------------------------- pieces
    def _par(self, path: str) -> ca.SX:
        return self._parameters[path]

    def _front_end(self, crush, rate, x_max):
        """Contact force (never tensile, zero once separated), its damper part, stored energy, and
        the loading force (the law, with its tail) as a function of crush."""
        s = self.structure
        bps = [self._par("model.spring.crush_breakpoints")[i] for i in range(s.n_spring)]
        vals = [self._par("model.spring.values")[i] for i in range(s.n_spring)]
        law = SPRING_LAWS[s.spring_law]
        if s.tail:
            law = with_tail(law, self._par("model.spring.tail.start"), self._par("model.spring.tail.slope"))

        def load(x):
            return law(x, bps, vals, s.eps_crush)[0]

        stiffness = self._par("model.unloading.stiffness")
        spring, stored = UNLOADING_LAWS[s.unloading_law].force(load, crush, x_max, stiffness, s.eps_crush)
        if stored is None:
            stored = law(ca.fmax(crush, 0), bps, vals, s.eps_crush)[1]
        force, damper = spring, 0
        if s.n_damper:
            dbps = [self._par("model.damper.rate_breakpoints")[i] for i in range(s.n_damper)]
            dvals = [self._par("model.damper.values")[i] for i in range(s.n_damper)]
            # the damper engages over the first eps of crush, so the contact force
            # starts from zero at impact instead of jumping to c * v0
            damper = engagement(crush, s.eps_crush) * damper_force(rate, dbps, dvals, s.eps_rate)
        push = force + damper
        separating = never_pulling(push, self._separation_width(crush, x_max, stiffness), s.eps_crush)
        contact = ca.if_else(crush >= 0, separating, 0)
        return contact, contact - ca.if_else(crush >= 0, ca.fmax(spring, 0), 0), ca.if_else(crush >= 0, stored, 0), load

    def _separation_width(self, crush, x_max, stiffness):
        """The band the end of contact is rounded over (SEPARATION above): its full width once
        the front end unloads a crush smoothing width or more below its largest crush, none at
        impact (the crush and the largest crush both zero), so that contact begins without a
        force; a smooth gate in between, never quite zero so that the join stays defined."""
        eps = self.structure.eps_crush
        back = (x_max - crush) ** 2
        return SEPARATION * eps * stiffness * (back / (back + eps * eps) + OPEN_AT_IMPACT)

    def _history_rate(self, crush, rate, x_max):
        """d x_max / dt: the crush rate while loading (a smoothed max(rate, 0)), zero while
        unloading; a reloading crush moves x_max again within HISTORY_GATE of it. No feedback
        acts while the crush follows x_max, so the state adds no stiffness to the ODE.

        The gate acts only where x_max lies above the crush. A simulation never puts it below
        (the rate's hinge is at least the crush rate), but a shooting node's states are free
        variables: there x_max keeps growing with the crush instead of stalling behind it, so
        that the node's defect can close (a gate on both sides holds a node's x_max behind a crush
        a step moved past it, and the fit wanders: docs/design-notes.md, "The largest crush at a
        shooting node")."""
        gap = ca.fmax(x_max - crush, 0) / HISTORY_GATE
        return hinge(rate, self.structure.eps_rate) / (1 + gap**4)

    def _build(self):
        q, qd = self.q, self.qd
        mech = self.mechanics()
        T, V, D = mech.kinetic, mech.potential, mech.dissipation
        Xd = mech.velocity
        crush = mech.crush
        crush_rate = ca.jtimes(crush, q, qd)
        x_max = self.x[self.nx - 1]
        contact, front_damper, stored, load = self._front_end(crush, crush_rate, x_max)
        Q = -contact * ca.jacobian(crush, q).T
        barrier_force, front_damper_power = contact * mech.barrier_share, front_damper * crush_rate
        for other in self.contacts():  # forms with none keep the expressions above unchanged
            rate = ca.jtimes(other.reach, q, qd)
            Q -= other.force * ca.jacobian(other.reach, q).T
            barrier_force += other.force
            front_damper_power += (other.force - other.elastic) * rate
            stored += other.stored

        Lag = T - V
        dL_dqd = ca.gradient(Lag, qd)
        M = ca.jacobian(dL_dqd, qd)
        rhs = ca.gradient(Lag, q) - ca.jacobian(dL_dqd, q) @ qd - ca.gradient(D, qd) + Q
        qdd = ca.solve(M, rhs)
        Xdd = ca.jtimes(Xd, ca.vertcat(q, qd), ca.vertcat(qd, qdd))

        values = {
            "displacement": mech.displacement,
            "velocity": Xd,
            "accel": Xdd,
            "pitch": mech.pitch,
            "crush": crush,
            "crush_rate": crush_rate,
            "barrier_force": barrier_force,
            "contact_force": contact,
            "kinetic": T,
            "potential": V + stored,
            "front_energy": stored,
            "barrier_power": -ca.dot(Q, qd),
            "front_damper_power": front_damper_power,
            "damper_power": 2 * D,
        }
        xdot = ca.vertcat(qd, qdd, self._history_rate(crush, crush_rate, x_max))
        c, v0 = ca.SX.sym("crush"), ca.SX.sym("v0")
        y = ca.vertcat(*[values[k] for k in OUTPUTS])
        self._assign(c, v0, xdot, y, load(c), self.initial_state_after_impact(v0))

    def _assign(self, crush: ca.SX, v0: ca.SX, xdot: ca.SX, y: ca.SX, force: ca.SX, x0: ca.SX) -> None:
        """The model's Functions of its expressions (of self.x, self.p, a crush and an impact speed v0)."""
        args, names = [self.x, self.p], ["x", "p"]
        self.rhs = ca.Function("rhs", args, [xdot], names, ["xdot"])
        self.outputs = ca.Function("outputs", args, [y], names, ["y"])
        self.initial_state = ca.Function("x0", [self.p, v0], [x0], ["p", "v0"], ["x0"])
        self.loading_curve = ca.Function("loading_curve", [crush, self.p], [force], ["crush", "p"], ["force"])

    def whole(self) -> ca.Function:
        """Every expression of the model's Functions in one Function, (x, p, crush, v0) -> (xdot, y,
        force, x0), what crashnlp.models.stored keeps. Each Function is evaluated at its own inputs,
        where CasADi gives back the nodes it holds: the expressions they share stay shared, and
        a model read from it (`__init__`) derives its own Functions (`augmented_rhs`) exactly as the
        derived model does."""
        crush, v0 = self.loading_curve.sx_in(0), self.initial_state.sx_in(1)
        xdot, y = self.rhs(self.x, self.p), self.outputs(self.x, self.p)
        force, x0 = self.loading_curve(crush, self.p), self.initial_state(self.p, v0)
        names = (["x", "p", "crush", "v0"], ["xdot", "y", "force", "x0"])
        return ca.Function("model", [self.x, self.p, crush, v0], [xdot, y, force, x0], *names)

    def unread(self, paths: Sequence[str]) -> list[str]:
        """The entries of `paths` (dotted parameter paths) that none of the form's equations
        reads (its outputs, right-hand side and initial state): a value a fit cannot determine
        and a design cannot move, such as the pendulum's crush offset in a rigid body."""
        v0 = ca.SX.sym("v0")
        reads = ca.vertcat(self.outputs(self.x, self.p), self.rhs(self.x, self.p), self.initial_state(self.p, v0))
        slices = self.layout.slices()
        return [path for path in paths if not ca.depends_on(reads, self.p[slices[path]])]

    def cached(self, key: tuple, build: Callable[[], Any]) -> Any:
        """What `build` makes, built once per model and key: the simulator's integrators and
        compiled functions, which repeat with the same shapes."""
        if key not in self._functions:
            self._functions[key] = build()
        return self._functions[key]

    @cached_property
    def permanent_set(self) -> ca.Function:
        """(x, p) -> the crush the unloading law leaves once its force is zero, from the largest
        crush so far (the history state HISTORY): the law's own (UNLOADING_LAWS), none for the elastic law. Past
        separation the front end's crush stays there (crashnlp.models.simulation.front_end_crush)."""
        largest = self.x[self.nx - 1]
        stiffness = self._par("model.unloading.stiffness")
        at_largest = self.loading_curve(largest, self.p)
        permanent = UNLOADING_LAWS[self.structure.unloading_law].permanent_set(at_largest, largest, stiffness)
        return ca.Function("permanent_set", [self.x, self.p], [permanent], ["x", "p"], ["set"])

    # ---------------------------------------------------------------- simulation form
    @cached_property
    def augmented_rhs(self) -> ca.Function:
        """ODE for simulation: the state followed by the work absorbed by the front end,
        by its damper, and by the suspension dampers (the energy audit's integrals)."""
        x = ca.SX.sym("x", self.nx + len(ABSORBED))
        state = x[: self.nx]
        y = self.outputs(state, self.p)
        work = [y[OUTPUTS.index(name)] for name in ABSORBED]
        ode = ca.vertcat(self.rhs(state, self.p), *work)
        return ca.Function("aug_rhs", [x, self.p], [ode], ["x", "p"], ["xdot"])


def form_class(name: str) -> type[CrashModel]:
    """The class of the form `name` (a key of crashnlp.problem.forms.FORMS)."""
    module, _, cls = FORMS[name].partition(":")
    found: type[CrashModel] = getattr(importlib.import_module(module), cls)
    return found


def build_model(spec: ModelSpec, layout: ParameterLayout) -> CrashModel:
    """The symbolic model of a problem's model section (its `form`) and parameter layout: read
    from the cache where an earlier process derived it (crashnlp.models.stored), else derived
    and kept there."""
    cls, structure = form_class(spec.form), Structure.of(spec)
    path = model_store.path_of(spec.form, (FORMS[spec.form], structure, layout))
    whole = model_store.read(path)
    if whole is not None:
        return cls(structure, layout, whole)
    model = cls(structure, layout)
    model_store.write(path, model.whole())
    return model
