"""Direct collocation: Lagrange polynomials through Radau or Legendre points."""

from __future__ import annotations

import casadi as ca
import numpy as np

from crashnlp.numerics.nlp import DYNAMICS
from crashnlp.transcription.base import Transcription, per_row

# The KKT systems of a collocation fit are ill-conditioned: large Gauss-Newton entries beside a near
# null space of the dynamics' multipliers. MUMPS's pivoting then can report a wrong inertia although
# the Gauss-Newton Hessian is positive semi-definite; IPOPT regularizes the Hessian heavily and the
# steps stall. A small permanent regularization of the constraint block (delta_c = 1e-10 mu^0.25:
# IPOPT's `perturb_always_cd`) removes the near null space. Shooting fits do not need it, and their
# iterations move with it, so only collocation asks for it (measured: docs/design-notes.md, "A
# regularized constraint block for collocation").
GAUSS_NEWTON_OPTIONS = {"perturb_always_cd": "yes", "jacobian_regularization_value": 1e-10}


class Collocation(Transcription):
    def _interval(self, h: float, rhs: ca.Function) -> ca.Function:
        """Collocation defects and end state of one interval as an SX Function."""
        d = self.spec.degree
        tau = ca.collocation_points(d, self.spec.scheme)
        C, D, _ = ca.collocation_coeff(tau)
        nx = self.model.nx
        x0, xc = ca.SX.sym("x0", nx), ca.SX.sym("xc", nx, d)
        p = rhs.sx_in(1)
        Z = ca.horzcat(x0, xc)
        slopes = ca.horzcat(*[rhs(xc[:, j], p) for j in range(d)])
        return ca.Function("interval", [x0, xc, p], [Z @ C - h * slopes, Z @ D])

    def _add_dynamics(self, nlp, name, X, theta, times, scale, scale_values, guess, rhs):
        n, d = X.shape[1] - 1, self.spec.degree
        h = float(times[1] - times[0])
        tau = np.asarray(ca.collocation_points(d, self.spec.scheme))
        inner = (times[:-1, None] + h * tau[None, :]).ravel()
        Xc = nlp.variable(f"{name}.xc", (self.model.nx, n * d), guess(inner), scale=scale_values[:, None])
        defects, end = nlp.mapped(self._interval(h, rhs), n, X[:, :-1], Xc, theta)
        nlp.constrain(DYNAMICS, defects / per_row(scale, n * d), test=name, detail="collocation")
        nlp.constrain(DYNAMICS, (end - X[:, 1:]) / per_row(scale, n), test=name, detail="continuity")
        nlp.gauss_newton_options.update(GAUSS_NEWTON_OPTIONS)
