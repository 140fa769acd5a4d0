"""Multiple shooting: a state at every node, M RK4 sub-steps per interval, mapped."""

from __future__ import annotations

from crashnlp.numerics.integrators import rk4
from crashnlp.numerics.nlp import DYNAMICS
from crashnlp.transcription.base import Transcription, per_row


class MultipleShooting(Transcription):
    def _add_dynamics(self, nlp, name, X, theta, times, scale, scale_values, guess, rhs):
        n = X.shape[1] - 1
        step = rk4(rhs, float(times[1] - times[0]), self.spec.substeps)
        (end,) = nlp.mapped(step, n, X[:, :-1], theta)
        nlp.constrain(DYNAMICS, (end - X[:, 1:]) / per_row(scale, n), test=name, detail="continuity")
