"""Multiple shooting: a state at every node, M RK4 sub-steps per interval, mapped."""
from __future__ import annotations

import casadi as ca

from crashnlp.model.pendulum import NX
from crashnlp.transcription.base import Transcription, per_row


class MultipleShooting(Transcription):
    def _step(self, h: float, rhs: ca.Function) -> ca.Function:
        """One interval of `substeps` RK4 steps as an SX Function (CasADi's sysid pattern)."""
        x, xm = ca.SX.sym("x", NX), ca.SX.sym("xm")
        p, dt = self.theta, h / self.spec.substeps
        xk = x
        for _ in range(self.spec.substeps):
            k1 = rhs(xk, p, xm)
            k2 = rhs(xk + dt / 2 * k1, p, xm)
            k3 = rhs(xk + dt / 2 * k2, p, xm)
            k4 = rhs(xk + dt * k3, p, xm)
            xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return ca.Function("step", [x, p, xm], [xk])

    def _add_dynamics(self, nlp, name, X, theta, x_max, times, scale, guess, rhs):
        n = X.shape[1] - 1
        (end,) = nlp.mapped(self._step(float(times[1] - times[0]), rhs), n, X[:, :-1], theta, x_max)
        nlp.constrain(f"{name}.continuity", (end - X[:, 1:]) / per_row(scale, n))
