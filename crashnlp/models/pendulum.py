"""The elastic-pendulum crash model: equations of motion from T, V and D by AD.

Coordinates q = (r, theta): r is the change of the pivot-CG distance, theta the
angle of the pivot-CG line above the horizontal. The pivot is the impact point
on the barrier, x points toward the barrier, z up:

    X = -(l0 + r) cos(theta),   Z = (l0 + r) sin(theta)

T, V and the Rayleigh function D are written once; Lagrange's equations

    d/dt dL/dqdot - dL/dq + dD/dqdot = Q

are formed with CasADi jacobians by crashnlp.models.form.CrashModel (docs/model.md
says why the paper's printed equations are not used). The suspension carries the static load (preload), so
the vehicle at rest stays at rest.

The front end is one element between the barrier and the body. Its crush is
the shortening along its line of action, which runs at `crush_offset` e from
the pivot-CG line: c = -r - e (theta - theta0). Its force F >= 0 enters as
the generalised force Q = -F dc/dq, so the pitch moment e F is paid for by
crush: the vehicle loses exactly the power F dc/dt the element absorbs, and the
barrier itself does no work. The element's history is the fifth state, the
largest crush so far, integrated alike by the simulator and the NLP, so the
switch from loading to unloading is the model's own event.
"""

from __future__ import annotations

import casadi as ca

from crashnlp.models.form import CrashModel, Expr, Mechanics
from crashnlp.problem.schema import EstimateSpec, Problem

# The pitch lever: the offset of the crush force's line of action from the pivot-CG line (m),
# positive nose-down; its moment about the CG is the lever times the force. The bounds of an
# effective lever (PITCH_LEVER_BOUNDS): the pendulum's body pitches with the pivot-CG line, so it
# needs a larger lever than the rails' height below the CG; fitted at several speeds, the
# physical one (`pitch_lever_bounds`).
PITCH_LEVER = "vehicle.crush_offset"
PITCH_LEVER_BOUNDS = (-0.5, 1.0)  # m


def pitch_lever_bounds(problem: Problem, several_speeds: bool) -> tuple[float, float]:
    """The estimated pitch lever's bounds (m): PITCH_LEVER_BOUNDS, but with tests at several speeds
    up to the CG's height above the impact point as the problem gives it (not below zero).

    The wall pushes the front end back where it meets the barrier, so the crush force's moment
    about the CG is at most the force times that height; the lever's moment is the lever times the
    force. The pendulum's body turns about the impact point, with inertia m l0^2 + I, not about
    its CG, so a larger lever fits the measured pitch closer (about h m l0^2 / I, two to four
    times h), and the crush pays for the lever's moment: the model's front end gives up that many
    times the crush a real one gives up to the same pitch. A fit of one test absorbs that into its
    loading curve and predicts other speeds as well with either bound. Fitted at two speeds, one
    curve has to serve two pitches, and with the larger lever it predicts a third speed wrong
    (docs/design-notes.md, "The pitch lever")."""
    if not several_speeds:
        return PITCH_LEVER_BOUNDS
    return PITCH_LEVER_BOUNDS[0], max(float(problem.vehicle.cg_above_impact), 0.0)


class PendulumModel(CrashModel):
    """Symbolic elastic pendulum: the paper's form, pitching about the impact point."""

    COORDINATES = ("r", "theta")
    STATE_FLOOR = (0.01, 0.01, 0.1, 0.01, 0.01)  # m, rad, m/s, rad/s, m

    def _geometry(self):
        L, h = self._par("vehicle.cg_to_impact"), self._par("vehicle.cg_above_impact")
        return ca.sqrt(L * L + h * h), ca.atan2(h, L)

    def mechanics(self) -> Mechanics:
        q, qd = self.q, self.qd
        m, inertia = self._par("vehicle.mass"), self._par("vehicle.pitch_inertia")
        g = self._par("vehicle.gravity")
        a_f, a_r = self._par("vehicle.cg_to_front_axle"), self._par("vehicle.cg_to_rear_axle")
        l0, theta0 = self._geometry()
        h = self._par("vehicle.cg_above_impact")
        r, theta = q[0], q[1]
        rho = l0 + r
        X, Z = -rho * ca.cos(theta), rho * ca.sin(theta)
        Xd, Zd = ca.jtimes(X, q, qd), ca.jtimes(Z, q, qd)

        # Suspension: body points at the axles move with Z and the pitch; the
        # static load is carried as a preload, so rest is an equilibrium.
        susp = self._par
        pitch = theta - theta0
        V = m * g * (Z - h)
        D: Expr = 0
        for d, share, k, c in (
            (a_f, a_r, susp("vehicle.suspension.k_front"), susp("vehicle.suspension.c_front")),
            (-a_r, a_f, susp("vehicle.suspension.k_rear"), susp("vehicle.suspension.c_rear")),
        ):
            static = m * g * share / (a_f + a_r)
            deflection = h - (Z - d * ca.sin(pitch))
            rate = ca.jtimes(deflection, q, qd)
            V += 0.5 * k * deflection**2 + static * deflection
            D += 0.5 * c * rate**2
        T = 0.5 * m * (Xd**2 + Zd**2) + 0.5 * inertia * qd[1] ** 2
        crush = -r - self._par("vehicle.crush_offset") * pitch
        displacement = X + self._par("vehicle.cg_to_impact")
        # the line of action is parallel to pivot-CG
        return Mechanics(T, V, D, displacement, Xd, pitch, crush, ca.cos(theta))

    def initial_state_after_impact(self, v0: Expr) -> Expr:
        """State just after impact at horizontal speed v0.

        The radial spring takes no impulse, so the radial velocity is the
        component of v0; the pivot stops the tangential motion impulsively,
        which conserves the angular momentum about the pivot.
        """
        m, inertia = self._par("vehicle.mass"), self._par("vehicle.pitch_inertia")
        l0, theta0 = self._geometry()
        thetad = m * v0 * l0 * ca.sin(theta0) / (m * l0**2 + inertia)
        return ca.vertcat(0, theta0, -v0 * ca.cos(theta0), thetad, 0)

    @classmethod
    def pitch_estimate(cls, problem: Problem, several_speeds: bool) -> dict[str, EstimateSpec]:
        """The CG height and pitch inertia (CrashModel's), and the pitch lever within
        `pitch_lever_bounds`."""
        out = super().pitch_estimate(problem, several_speeds)
        out[PITCH_LEVER] = EstimateSpec(bounds=pitch_lever_bounds(problem, several_speeds))
        return out
