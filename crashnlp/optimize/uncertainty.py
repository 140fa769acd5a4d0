"""Sensitivity of the fit to the parameters, and Gauss-Newton standard errors.

The states of a transcription are tied to the parameters by the dynamics
constraints G(theta, X) = 0, so dX/dtheta = -G_X^-1 G_theta; the residual
sensitivity is then dR/dtheta = R_theta + R_X dX/dtheta. This serves every
transcription alike, and the same Jacobian tells before a solve whether some
parameter cannot move the fit at all.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse.linalg as spla

from crashnlp.optimize.fit import Residual
from crashnlp.optimize.problem import OptimalControl
from crashnlp.transcription.base import DYNAMICS



@dataclass
class Sensitivity:
    jacobian: np.ndarray  # d residual (SI) / d theta (SI), rows by channel
    raw: np.ndarray  # residuals (SI)
    rows: list[slice]  # rows of each channel

    def dead(self, rtol: float = 1e-10) -> np.ndarray:
        """Parameters whose column is zero: they cannot change the fit."""
        norms = np.zeros(self.jacobian.shape[1])
        for rows in self.rows:  # per channel, relative to the channel's own scale
            block = self.jacobian[rows]
            scale = max(np.abs(block).max(), 1e-300)
            norms = np.maximum(norms, np.abs(block).max(axis=0) / scale)
        return norms <= rtol

    def covariance(self) -> np.ndarray:
        """Gauss-Newton covariance with each channel's noise level estimated from its residuals."""
        J, e = [], []
        for rows in self.rows:
            s = np.sqrt(np.mean(self.raw[rows] ** 2)) or 1.0
            J.append(self.jacobian[rows] / s)
            e.append(self.raw[rows] / s)
        J, e = np.vstack(J), np.concatenate(e)
        dof = max(len(e) - J.shape[1], 1)
        return np.linalg.pinv(J.T @ J) * float(e @ e) / dof


class SensitivityEvaluator:
    """Built once per NLP; evaluated at any solution vector."""

    def __init__(self, ocp: OptimalControl, residuals: list[Residual]):
        nlp = ocp.nlp
        d = nlp.derivatives()
        dyn = [g for g, c in zip(nlp.g, nlp.constraints) if c.name.endswith(DYNAMICS)]
        R = ca.vertcat(*[ca.vec(r.model - ca.DM(r.data).T) for r in residuals])
        self.f = ca.Function("sens", [d.z], [d.jacobian(ca.vertcat(*dyn)), d.jacobian(R), R])
        theta = nlp.blocks["theta"]
        self.theta = np.arange(theta.offset, theta.offset + theta.shape[0])
        self.theta_scale = theta.scale
        self.states = np.concatenate(
            [np.arange(b.offset, b.offset + b.shape[0] * b.shape[1]) for n, b in nlp.blocks.items() if n.endswith((".x", ".xc"))]
        )
        sizes = [len(r.columns) for r in residuals]
        ends = np.cumsum(sizes)
        self.rows = [slice(e - n, e) for e, n in zip(ends, sizes)]

    def __call__(self, z: np.ndarray) -> Sensitivity:
        G, Rz, R = self.f(z)
        G, Rz = G.sparse().tocsc(), Rz.sparse().tocsc()
        dx = -spla.spsolve(G[:, self.states].tocsc(), G[:, self.theta].toarray())
        dx = dx.reshape(len(self.states), len(self.theta))
        J = Rz[:, self.theta].toarray() + Rz[:, self.states] @ dx
        return Sensitivity(np.asarray(J) / self.theta_scale, np.asarray(R).ravel(), self.rows)
