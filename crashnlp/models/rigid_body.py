"""The rigid-body crash model: a planar body that pitches about its CG on its suspension.

The classical alternative to the paper's pendulum. Coordinates q = (x, z, phi): the CG's travel
toward the barrier, its heave (up) and the body's pitch (nose-down positive), all zero at rest.
The body rides on the preloaded axle springs and dampers (vehicle.suspension) at
`cg_to_front_axle` ahead of and `cg_to_rear_axle` behind the CG, so rest is an equilibrium.

The front end is the pendulum's element (laws, damper, unloading, tail, history state) between
the barrier and the body point P at the impact point's place in the body: `cg_to_impact` L
ahead of and `cg_above_impact` h below the CG. The barrier's face is frictionless, so the
element's line of action is horizontal through P, and its crush is P's travel toward the barrier,

    c = x + L (cos phi - 1) - h sin phi,

whose force F enters as Q = -F dc/dq: a moment F (L sin phi + h cos phi) nose-down about the CG,
paid for by crush as in the pendulum. There is no impact impulse: the element starts from zero
force, so the state just after impact is the state before it.
"""

from __future__ import annotations

from typing import ClassVar

import casadi as ca

from crashnlp.base.errors import InputError
from crashnlp.models.form import CrashModel, Expr, Mechanics
from crashnlp.problem.schema import Problem


class RigidBodyModel(CrashModel):
    """Symbolic rigid body in travel, heave and pitch about its CG."""

    COORDINATES: ClassVar[tuple[str, ...]] = ("x", "z", "phi")
    STATE_FLOOR: ClassVar[tuple[float, ...]] = (0.01, 0.01, 0.01, 0.1, 0.1, 0.01, 0.01)  # m, m, rad, m/s, m/s, rad/s, m

    def mechanics(self) -> Mechanics:
        q, qd = self.q, self.qd
        m, inertia = self._par("vehicle.mass"), self._par("vehicle.pitch_inertia")
        g = self._par("vehicle.gravity")
        a_f, a_r = self._par("vehicle.cg_to_front_axle"), self._par("vehicle.cg_to_rear_axle")
        L, h = self._par("vehicle.cg_to_impact"), self._par("vehicle.cg_above_impact")
        x, z, phi = q[0], q[1], q[2]
        V = m * g * z
        D: Expr = 0
        for d, share, k, c in (
            (a_f, a_r, self._par("vehicle.suspension.k_front"), self._par("vehicle.suspension.c_front")),
            (-a_r, a_f, self._par("vehicle.suspension.k_rear"), self._par("vehicle.suspension.c_rear")),
        ):
            static = m * g * share / (a_f + a_r)  # the axle's share of the weight, carried at rest
            deflection = d * ca.sin(phi) - z  # compression of the axle's spring
            rate = ca.jtimes(deflection, q, qd)
            V += 0.5 * k * deflection**2 + static * deflection
            D += 0.5 * c * rate**2
        T = 0.5 * m * (qd[0] ** 2 + qd[1] ** 2) + 0.5 * inertia * qd[2] ** 2
        crush = x + L * (ca.cos(phi) - 1) - h * ca.sin(phi)
        return Mechanics(T, V, D, x, qd[0], phi, crush, 1)

    @classmethod
    def check(cls, problem: Problem) -> None:
        """A body that pitches about its CG needs an inertia about it: the paper's point mass
        (pitch_inertia 0) leaves its pitch without one."""
        if problem.vehicle.pitch_inertia <= 0:
            raise InputError(
                f"vehicle.pitch_inertia: 0 (the paper's point mass); model.form {problem.model.form} pitches about the CG "
                "and needs the pitch inertia about it (> 0)"
            )

    def initial_state_after_impact(self, v0: Expr) -> Expr:
        """At rest on its suspension, moving at v0: the element takes no impulse."""
        return ca.vertcat(0, 0, 0, v0, 0, 0, 0)
