"""Sensitivity of the fit to the parameters, and their standard errors.

The states of a transcription are tied to the parameters by the dynamics
constraints G(theta, X) = 0, so dX/dtheta = -G_X^-1 G_theta; the residual
sensitivity is then dR/dtheta = R_theta + R_X dX/dtheta. This serves every
transcription alike.

The covariance is a sandwich, H^-1 M H^-1, built to mean what it says:
- H = J^T W J, the Gauss-Newton Hessian of the weighted fit, is inverted by an
  SVD of the weighted Jacobian with equilibrated columns, never by forming
  J^T J in SI units (whose condition number squares that of J); directions
  whose singular value is below RANK_RTOL of the largest are not identified,
  and every parameter with a share in them gets an infinite std. Entries the
  fitted tests never reach (spring values past the crush the model went
  through) are left out first (`Sensitivity.without`): their columns hold only
  the smoothing's faint leak, which the SVD would pair with the values the
  data do reach, inflating their errors many times over.
- M is the long-run covariance of the score sum_t s_t, s_t the weighted residual
  times the Jacobian row of all channels at node t, for residuals that are
  coloured noise: a filtered accelerometer's, an integrated channel's and the
  model form's miss are correlated over tens of ms, and velocity and
  displacement integrated from the same accelerometer carry the same noise, so
  neither a per-channel noise level nor a sample count is right. Per test, M is
  the sum over t, u of x_t gamma(t - u) x_u^T (an output-error fit whose
  disturbance is not white: L. Ljung, System Identification, 2nd ed., 1999,
  ch. 9), x_t the weighted Jacobian rows of the channels at
  node t and gamma the channels' residual cross-covariance at every lag, the
  biased (divide-by-n) estimate from the residuals themselves, which keeps M
  positive semi-definite. Summed over every lag it is computed as R^T R, R(v)
  the channels' cross-correlation of x with the residual at lag v (`_meat`).
  It needs no bandwidth, so it does not change as the grid is refined. Tests
  are independent.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from crashnlp.data.instrument import RECORDED
from crashnlp.numerics.nlp import DYNAMICS, NLPBuilder
from crashnlp.optimize.fit import Residual
from crashnlp.optimize.ocp import OptimalControl

RANK_RTOL = 1e-7  # singular values below this fraction of the largest are not identified
NULL_SHARE = 1e-3  # a parameter with this share of a null direction is not identified


@dataclass
class Covariance:
    matrix: np.ndarray  # SI, inf on the rows/columns of parameters not identified
    hessian_inverse: np.ndarray  # (J^T W J)^+, SI: the curvature of the objective the profiles see
    identified: np.ndarray  # bool per parameter

    @property
    def std(self) -> np.ndarray:
        return np.where(self.identified, np.sqrt(np.maximum(np.diag(self.matrix), 0.0)), np.inf)

    @property
    def correlation(self) -> np.ndarray:
        std = np.where(self.identified, self.std, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = self.matrix / np.outer(std, std)
        return np.nan_to_num(corr, nan=0.0, posinf=0.0, neginf=0.0)


@dataclass
class Sensitivity:
    jacobian: np.ndarray  # d residual (SI) / d theta (SI), rows by channel
    raw: np.ndarray  # residuals (SI)
    rows: list[slice]  # rows of each channel
    residuals: list[Residual]

    def without(self, unreached: np.ndarray) -> Sensitivity:
        """This sensitivity with the columns of `unreached` entries set to zero: entries that the
        fitted tests never reach (their columns hold only the smoothing's leak past the crush the
        model went through). They are then not identified, and the rank of the others is theirs."""
        return replace(self, jacobian=np.where(unreached, 0.0, self.jacobian))

    def weights(self) -> np.ndarray:
        """Each residual row's weight in the objective: weight / (n sigma^2) of its channel."""
        return np.concatenate(
            [
                np.full(r.stop - r.start, res.weight / (len(res.columns) * res.sigma**2))
                for r, res in zip(self.rows, self.residuals)
            ]
        )

    def covariance(self, prior: np.ndarray | None = None) -> Covariance:
        """Sandwich covariance of the parameters (see the module's docstring). `prior`: the
        information a prior adds (crashnlp.optimize.prior, SmoothnessPrior.information), to the
        Hessian and, as the prior's own score variance, to the meat: a value the prior alone
        holds gets the prior's width, not none."""
        n = self.jacobian.shape[1]
        weights = self.weights()
        Jw = self.jacobian * np.sqrt(weights)[:, None]
        if prior is not None:
            Jw = np.vstack([Jw, _root(prior)])
        d = np.linalg.norm(Jw, axis=0)
        d = np.where(d > 0, d, 1.0)
        U, s, Vt = np.linalg.svd(Jw / d, full_matrices=False)
        keep = s > RANK_RTOL * (s[0] if s.size and s[0] > 0 else 1.0)
        null = Vt[~keep]
        identified = np.ones(n, bool) if not null.size else np.max(np.abs(null), axis=0) < NULL_SHARE
        H_inv = (Vt[keep].T / s[keep] ** 2) @ Vt[keep] / np.outer(d, d)  # pseudo-inverse of J^T W J (+ prior)
        M = np.zeros((n, n)) if prior is None else prior.copy()
        for channels in self._channels(weights).values():
            M += _meat(channels)
        cov = H_inv @ M @ H_inv
        cov[~identified, :] = np.inf
        cov[:, ~identified] = np.inf
        return Covariance(cov, H_inv, identified)

    def _channels(self, weights: np.ndarray) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
        """Per test, each channel's fitted nodes, residuals and weighted Jacobian rows (w J)."""
        out: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
        weighted = self.jacobian * weights[:, None]
        for rows, res in zip(self.rows, self.residuals):
            out.setdefault(res.test, []).append((np.asarray(res.columns), self.raw[rows], weighted[rows]))
        return out


def _meat(channels: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """One test's M (the module's docstring): R^T R, R(v) = sum over channels of
    sum_t x_t e_(t+v) / sqrt(n) at every lag v, each channel's nodes, residuals e and
    weighted Jacobian rows x placed on the test's node grid (n: its fitted nodes). With
    white residuals of variance s^2 its mean is s^2 sum_t x_t x_t^T, the least-squares
    meat."""
    size = max(int(nodes.max()) + 1 for nodes, _, _ in channels)
    length = 1 << int(np.ceil(np.log2(2 * size)))  # zero-padded: the correlation is not circular
    params = channels[0][2].shape[1]
    R = np.zeros((length, params))
    for nodes, e, x in channels:
        on_grid_e, on_grid_x = np.zeros(size), np.zeros((size, params))
        on_grid_e[nodes], on_grid_x[nodes] = e, x
        spectrum = np.conj(np.fft.rfft(on_grid_x, length, axis=0)) * np.fft.rfft(on_grid_e, length)[:, None]
        R += np.fft.irfft(spectrum, length, axis=0) / np.sqrt(nodes.size)
    return R.T @ R


def _root(information: np.ndarray) -> np.ndarray:
    """Rows R with R^T R = `information` (symmetric, positive semi-definite)."""
    values, vectors = np.linalg.eigh(information)
    return (vectors * np.sqrt(np.maximum(values, 0.0))).T


def sensitivity_function(nlp: NLPBuilder, residuals: list[Residual]) -> ca.Function:
    """(x, p) -> d dynamics / dz, d residuals / dz, residuals (model - data, SI)."""
    d = nlp.derivatives()
    dyn = [g for g, c in zip(nlp.g, nlp.constraints) if c.kind == DYNAMICS]
    R = ca.vertcat(*[ca.vec(r.error) for r in residuals])
    return nlp.function("sens", [d.jacobian(ca.vertcat(*dyn)), d.jacobian(R), R])


class SensitivityEvaluator:
    """Built once per NLP; evaluated at any solution vector. The function comes compiled with
    the solver's (identify registers it as an extra of the NLP) when the solve was compiled."""

    def __init__(self, ocp: OptimalControl, residuals: list[Residual]):
        nlp = ocp.nlp
        self.f = nlp.functions.get("sens") or sensitivity_function(nlp, residuals)
        self.p = nlp.bounds()["p"]
        theta = nlp.blocks["theta"]
        self.theta = list(range(theta.offset, theta.offset + theta.shape[0]))  # columns of z
        self.theta_scale = theta.scale
        states = [b for n, b in nlp.blocks.items() if n.endswith((".x", ".xc", RECORDED))]  # held by the dynamics
        self.states = np.concatenate([np.arange(b.offset, b.offset + b.shape[0] * b.shape[1]) for b in states]).tolist()
        sizes = [len(r.columns) for r in residuals]
        ends = np.cumsum(sizes)
        self.rows = [slice(e - n, e) for e, n in zip(ends, sizes)]
        self.residuals = residuals

    def __call__(self, z: np.ndarray) -> Sensitivity:
        G, Rz, R = self.f(z, self.p)
        # CasADi's sparse QR: on a collocation NLP's state block, CSparse's LU fills in (19 s against
        # 0.04 s at 250 intervals and two tests); no scipy.sparse import
        dx = -ca.solve(G[:, self.states], ca.densify(G[:, self.theta]), "qr")
        J = ca.densify(Rz[:, self.theta]) + ca.mtimes(Rz[:, self.states], dx)
        return Sensitivity(J.full() / self.theta_scale, R.full().ravel(), self.rows, self.residuals)
