"""The sandwich's meat (crashnlp.optimize.uncertainty._meat) against what it estimates: the
least-squares meat for white residuals, the Toeplitz form for coloured ones, and channels that
carry the same noise."""

from __future__ import annotations

import numpy as np

from crashnlp.optimize.uncertainty import _meat

N, DRAWS = 300, 300
T = np.linspace(0.0, 1.0, N)
X = np.column_stack([np.sin(3.0 * T), T, np.exp(-5.0 * T)])  # weighted Jacobian rows of one channel
NODES = np.arange(N)


def _mean_meat(residuals, rows=X) -> np.ndarray:
    return np.mean([_meat([(NODES, e, rows)]) for e in residuals], axis=0)


def _close(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _ar1(rng: np.random.Generator, rho: float, sigma: float) -> np.ndarray:
    """A stationary AR(1) series of innovation sigma."""
    e = np.empty(N)
    e[0] = rng.standard_normal() * sigma / np.sqrt(1 - rho**2)
    for k in range(1, N):
        e[k] = rho * e[k - 1] + sigma * rng.standard_normal()
    return e


def test_white_residuals_give_the_least_squares_meat():
    rng = np.random.default_rng(1)
    sigma = 0.7
    mean = _mean_meat(sigma * rng.standard_normal(N) for _ in range(DRAWS))
    assert _close(mean, sigma**2 * X.T @ X) < 0.1


def test_coloured_residuals_give_the_meat_of_their_autocovariance():
    """AR(1) residuals correlated over 20 nodes: the meat is x^T Gamma x, Gamma their
    autocovariance (tapered by 1 - |k|/n, as the biased estimate is), several times the meat of
    white residuals of the same variance, which the errors would be too small by."""
    rng = np.random.default_rng(2)
    rho, sigma = 0.95, 0.3
    lag = np.abs(NODES[:, None] - NODES[None, :])
    gamma = sigma**2 / (1 - rho**2) * rho**lag * (1 - lag / N)
    mean = _mean_meat(_ar1(rng, rho, sigma) for _ in range(DRAWS))
    assert _close(mean, X.T @ gamma @ X) < 0.15
    white = sigma**2 / (1 - rho**2) * X.T @ X
    assert np.trace(mean) > 5 * np.trace(white)


def test_two_channels_of_the_same_noise_count_it_once_in_each():
    """Velocity and its copy read from the same accelerometer: one noise, so the meat of the two
    channels is the one channel's with the rows added, not the sum of two independent meats."""
    rng = np.random.default_rng(3)
    noise = [rng.standard_normal(N) for _ in range(DRAWS)]
    other = X[:, ::-1]
    both = np.mean([_meat([(NODES, e, X), (NODES, e, other)]) for e in noise], axis=0)
    assert _close(both, (X + other).T @ (X + other)) < 0.1
