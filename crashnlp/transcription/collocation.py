"""Direct collocation: Lagrange polynomials through Radau or Legendre points."""

from __future__ import annotations

import casadi as ca
import numpy as np

from crashnlp.model.pendulum import NX
from crashnlp.nlp import DYNAMICS
from crashnlp.transcription.base import Transcription, per_row


class Collocation(Transcription):
    def _interval(self, h: float, rhs: ca.Function) -> ca.Function:
        """Collocation defects and end state of one interval as an SX Function."""
        d = self.spec.degree
        tau = ca.collocation_points(d, self.spec.scheme)
        C, D, _ = ca.collocation_coeff(tau)
        x0, xc = ca.SX.sym("x0", NX), ca.SX.sym("xc", NX, d)
        p = rhs.sx_in(1)
        Z = ca.horzcat(x0, xc)
        slopes = ca.horzcat(*[rhs(xc[:, j], p) for j in range(d)])
        return ca.Function("interval", [x0, xc, p], [Z @ C - h * slopes, Z @ D])

    def _add_dynamics(self, nlp, name, X, theta, times, scale, scale_values, guess, rhs):
        n, d = X.shape[1] - 1, self.spec.degree
        h = float(times[1] - times[0])
        tau = np.asarray(ca.collocation_points(d, self.spec.scheme))
        inner = (times[:-1, None] + h * tau[None, :]).ravel()
        Xc = nlp.variable(f"{name}.xc", (NX, n * d), guess(inner), scale=scale_values[:, None])
        defects, end = nlp.mapped(self._interval(h, rhs), n, X[:, :-1], Xc, theta)
        nlp.constrain(DYNAMICS, defects / per_row(scale, n * d), test=name, detail="collocation")
        nlp.constrain(DYNAMICS, (end - X[:, 1:]) / per_row(scale, n), test=name, detail="continuity")
