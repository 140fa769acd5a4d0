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
- M is the long-run covariance of the score, sum_t s_t with s_t the weighted
  residual times the Jacobian row of all channels at node t: residuals of a
  filtered accelerometer or an integrated channel are autocorrelated, and
  velocity and displacement integrated from the same accelerometer carry the
  same noise, so neither a per-channel noise level nor a sample count is
  right. M is the Newey-West (Bartlett) estimate over the nodes of each test,
  with the bandwidth of Andrews (1991) from the score's lag-1
  autocorrelation; tests are independent. This is the standard HAC estimator
  of econometrics; it needs no assumption on the noise levels.
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
    bandwidth: dict[str, int]  # Newey-West lags used per test

    @property
    def std(self) -> np.ndarray:
        return np.where(self.identified, np.sqrt(np.maximum(np.diag(self.matrix), 0.0)), np.inf)

    @property
    def correlation(self) -> np.ndarray:
        std = np.where(self.identified, self.std, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = self.matrix / np.outer(std, std)
        return np.nan_to_num(corr, nan=0.0, posinf=0.0, neginf=0.0)


def bartlett_bandwidth(scores: np.ndarray) -> int:
    """Andrews' (1991) AR(1) plug-in bandwidth for the Bartlett kernel (nodes x params)."""
    n = scores.shape[0]
    a, b = scores[1:], scores[:-1]
    denom = np.sum(b * b, axis=0)
    used = denom > 0
    if n < 4 or not used.any():
        return 0
    rho = np.clip(np.sum(a * b, axis=0)[used] / denom[used], -0.97, 0.97)
    sigma4 = np.sum(b * b, axis=0)[used] ** 2
    alpha = np.sum(4 * rho**2 * sigma4 / (1 - rho) ** 6 / (1 + rho) ** 2) / np.sum(sigma4 / (1 - rho) ** 4)
    return int(min(np.ceil(1.1447 * (alpha * n) ** (1 / 3)), n // 2))


def long_run_covariance(scores: np.ndarray, lags: int) -> np.ndarray:
    """Newey-West estimate of the covariance of sum_t s_t (scores: nodes x params)."""
    M = scores.T @ scores
    for lag in range(1, lags + 1):
        gamma = scores[lag:].T @ scores[:-lag]
        M += (1 - lag / (lags + 1)) * (gamma + gamma.T)
    return M


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
        M, bandwidth = np.zeros((n, n)) if prior is None else prior.copy(), {}
        for test, scores in self._scores(weights).items():
            bandwidth[test] = bartlett_bandwidth(scores)
            M += long_run_covariance(scores, bandwidth[test])
        cov = H_inv @ M @ H_inv
        cov[~identified, :] = np.inf
        cov[:, ~identified] = np.inf
        return Covariance(cov, H_inv, identified, bandwidth)

    def _scores(self, weights: np.ndarray) -> dict[str, np.ndarray]:
        """Per test, the score of every node: sum over channels of w e J_row (nodes x params)."""
        out: dict[str, np.ndarray] = {}
        g = self.jacobian * (weights * self.raw)[:, None]
        for rows, res in zip(self.rows, self.residuals):
            nodes = np.asarray(res.columns)
            current = out.get(res.test)
            size = max(nodes.max() + 1, 0 if current is None else current.shape[0])
            grown = np.zeros((size, g.shape[1]))
            if current is not None:
                grown[: current.shape[0]] = current
            np.add.at(grown, nodes, g[rows])
            out[res.test] = grown
        return out


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
