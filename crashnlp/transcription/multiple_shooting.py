"""Multiple shooting: a state at every node, M RK4 sub-steps per interval, mapped."""
from __future__ import annotations

import casadi as ca
import numpy as np

from crashnlp.model.pendulum import NX
from crashnlp.transcription.base import Transcription, per_row
from crashnlp.runtime import mapped


class MultipleShooting(Transcription):
    def _step(self, h: float) -> ca.Function:
        """One interval of `substeps` RK4 steps as an SX Function (CasADi's sysid pattern)."""
        x, xm, lo = ca.SX.sym("x", NX), ca.SX.sym("xm"), ca.SX.sym("lo")
        p, f, dt = self.theta, self.phase_rhs, h / self.spec.substeps
        xk = x
        for _ in range(self.spec.substeps):
            k1 = f(xk, p, xm, lo)
            k2 = f(xk + dt / 2 * k1, p, xm, lo)
            k3 = f(xk + dt / 2 * k2, p, xm, lo)
            k4 = f(xk + dt * k3, p, xm, lo)
            xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return ca.Function("step", [x, p, xm, lo], [xk])

    def _add_dynamics(self, nlp, name, X, theta, xm, loading, times, scale, guess):
        n = self.intervals
        step = mapped(self._step(float(times[1] - times[0])), n)
        end = step(X[:, :-1], ca.repmat(theta, 1, n), xm, ca.DM(loading).T)
        nlp.constrain(f"{name}.continuity", (end - X[:, 1:]) / per_row(scale, n))
