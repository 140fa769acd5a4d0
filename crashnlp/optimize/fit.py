"""The fit objective: model outputs against measured channels at the nodes.

Each channel's residuals are divided by its scale sigma and weighted by the
inverse of its sample count, so channels of different units and lengths count
alike. Default scales are the accuracy a crash engineer asks of a fit. A channel
the test filtered (its `filter`) that reads zero before impact is compared as the
test recorded it: the model's samples filtered at the same CFC class, the filter's
two passes variables of the NLP held to its banded equations (crashnlp.data.instrument).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crashnlp.base.units import G0
from crashnlp.case.testcase import TestCase
from crashnlp.data.instrument import AT_REST, RECORDED, Recording, acceleration, from_velocity, recorded, recording
from crashnlp.data.signal import CFC_CLASSES, resample
from crashnlp.numerics.nlp import DYNAMICS, NLPBuilder
from crashnlp.optimize.ocp import OptimalControl, Transcript
from crashnlp.optimize.prior import SmoothnessPrior, smoothness_prior

DEFAULT_SIGMA = {
    "accel": 2.0 * G0,
    "velocity": 0.15,
    "displacement": 0.005,
    "pitch": np.radians(1.0),
    "barrier_force": 20e3,  # N: 3 % of a car's 700 kN peak wall force, about 1.2 g of its mass
}


@dataclass
class Residual:
    """Scaled residuals of one channel of one test (len = fitted nodes)."""

    test: str
    channel: str
    columns: list[int]  # node indices fitted
    data: np.ndarray  # SI, at those nodes
    sigma: float
    weight: float
    model: ca.MX  # model output at those nodes (SI), as the test recorded it
    measured: ca.MX  # the data as an NLP parameter (row)
    cfc: float | None = None  # the class the model's samples are recorded at (None: compared as they are)

    def seen(self, times: np.ndarray, outputs: Mapping[str, np.ndarray]) -> np.ndarray:
        """The model's output at the fitted nodes as this residual compares it with the data, from
        its `outputs` at every node (`times`, SI)."""
        if self.cfc is None:
            return np.asarray(outputs[self.channel], dtype=float)[self.columns]
        return recorded(times, outputs, self.channel, self.cfc)[self.columns]

    @property
    def error(self) -> ca.MX:
        """model - data at the fitted nodes (SI, row)."""
        return self.model - self.measured

    @property
    def factor(self) -> float:
        """sqrt(weight / n) / sigma: the scaled residual is error * factor."""
        return np.sqrt(self.weight / len(self.columns)) / self.sigma


def fitted_channels(test: TestCase) -> list[str]:
    """The channels of a test's data its fit compares with the model: read, and of weight above 0."""
    spec = test.spec.data
    if spec is None or test.data is None:
        return []
    return [name for name, ch in spec.channels.items() if name in test.data.channels and ch.weight > 0]


def channel_residuals(nlp: NLPBuilder, tr: Transcript) -> list[Residual]:
    """Residuals of every fitted channel of a test on the node grid."""
    spec, test_data = tr.test.spec.data, tr.test.data
    if spec is None or test_data is None:
        return []
    out = []
    times = tr.trajectory.times
    for name in fitted_channels(tr.test):
        ch_spec, channel = spec.channels[name], test_data.channels[name]
        cols = np.flatnonzero((times >= channel.time[0] - 1e-12) & (times <= channel.time[-1] + 1e-12))
        sigma = float(ch_spec.sigma) if ch_spec.sigma is not None else DEFAULT_SIGMA[name]  # SI once validated
        cfc = _recorded_class(name, ch_spec.filter if ch_spec.derive is None else None)
        output = (
            tr.output(name) if cfc is None else _recorded(nlp, tr, name, recording(times, cfc), from_velocity(name, times, cfc))
        )
        model = output[:, cols.tolist()]
        data = resample(channel, times[cols])
        measured = nlp.parameter(f"{tr.test.name}.{name}.data", data[None, :])
        out.append(Residual(tr.test.name, name, cols.tolist(), data, sigma, ch_spec.weight, model, measured, cfc))
    return out


def _recorded_class(name: str, cfc: str | None) -> float | None:
    """The CFC class a channel's model samples are recorded at: its filter's, where it reads zero
    before impact; None for the others (their samples compared as they are)."""
    return CFC_CLASSES[cfc] if cfc is not None and name in AT_REST else None


def _recorded(nlp: NLPBuilder, tr: Transcript, name: str, rec: Recording, velocity: bool) -> ca.MX:
    """A model output at every node (row) as the test recorded it: the filter's forward and
    backward passes are variables, started at the passes of the initial guess, and held to the
    filter's banded equations as dynamics (their defects scaled by the guess's largest value). With
    `velocity` (crashnlp.data.instrument.from_velocity) the acceleration is made from the
    velocity's samples (crashnlp.data.instrument.acceleration), linear in the nodes' states."""
    if velocity:
        times = tr.trajectory.times
        rate = _sparse_of(acceleration(np.eye(times.size), float(times[1] - times[0])))
        y = ca.mtimes(rate, tr.output("velocity").T).T
    else:
        y = tr.output(name)
    u0, s0 = rec.solve(np.asarray(nlp.evaluate([y], nlp.bounds()["x0"])[0]).ravel())
    size = max(float(np.max(np.abs(s0))), 1.0)
    u = nlp.variable(f"{tr.test.name}.{name}.forward{RECORDED}", rec.size, u0, scale=size)
    s = nlp.variable(f"{tr.test.name}.{name}.backward{RECORDED}", rec.size, s0, scale=size)
    scale = nlp.parameter(f"{tr.test.name}.{name}.recorded_scale", size)
    a, b = (_sparse_dm(*rec.lower(taps), (rec.size, rec.size)) for taps in (rec.a, rec.b))
    record = ca.mtimes(_sparse_of(rec.extend), y.T)
    nlp.constrain(DYNAMICS, (ca.mtimes(a, u) - ca.mtimes(b, record)) / scale, test=tr.test.name, detail=f"{name}.forward")
    backward = ca.mtimes(a, s) - ca.mtimes(b, u[::-1]) - ca.DM(rec.start) * u[-1]
    nlp.constrain(DYNAMICS, backward / scale, test=tr.test.name, detail=f"{name}.backward")
    return s[rec.at.tolist()].T


def _sparse_dm(rows: np.ndarray, cols: np.ndarray, values: np.ndarray, shape: tuple[int, int]) -> ca.DM:
    """The sparse DM of the nonzeros (rows, cols, values). The indices go to CasADi as lists: SWIG
    converts a numpy integer array element by element, a float array at once (the pickup's three
    matrices, up to 630 nonzeros: 5 to 8 ms of CPU against under 1 ms, measured)."""
    return ca.DM.triplet(rows.tolist(), cols.tolist(), values, *shape)


def _sparse_of(matrix: np.ndarray) -> ca.DM:
    """The sparse DM of a dense matrix's nonzeros (_sparse_dm)."""
    rows, cols = np.nonzero(matrix)
    return _sparse_dm(rows, cols, matrix[rows, cols], matrix.shape)


@dataclass
class FitObjective:
    """What an identification NLP minimizes: the channels' residuals and the smoothness prior
    (None when the spring values are not estimated) at `weight`."""

    residuals: list[Residual]
    prior: SmoothnessPrior | None
    weight: float


def add_fit_objective(ocp: OptimalControl, prior_weight: float | None = None) -> FitObjective:
    """Sum of squares (or the paper's L1 form, through slacks) of all residuals, plus the
    smoothness prior (crashnlp.optimize.prior) at `prior_weight`, else at the problem's
    `objective.regularization`."""
    objective = ocp.case.problem.objective
    residuals = [r for tr in ocp.transcripts for r in channel_residuals(ocp.nlp, tr)]
    for r in residuals:
        if objective.loss == "l2":
            ocp.nlp.least_squares(r.error * ocp.nlp.parameter(f"{r.test}.{r.channel}.factor", r.factor))
        else:  # |e| / sigma through slacks s >= +-e / sigma, mean of s weighted
            normalised = r.error.T / ocp.nlp.parameter(f"{r.test}.{r.channel}.sigma", r.sigma)
            slack = ocp.nlp.variable(f"{r.test}.{r.channel}.slack", len(r.columns), 1.0, 0.0, np.inf)
            ocp.nlp.constrain("l1", slack - normalised, 0.0, np.inf, test=r.test, detail=f"{r.channel}.above")
            ocp.nlp.constrain("l1", slack + normalised, 0.0, np.inf, test=r.test, detail=f"{r.channel}.below")
            ocp.nlp.minimize(r.weight / len(r.columns) * ca.sum1(slack))
    prior = smoothness_prior(ocp.free, ocp.case.base[ocp.case.layout.index("model.spring.crush_breakpoints")])
    weight = prior_weight if prior_weight is not None else objective.regularization
    if prior is None or weight <= 0:
        return FitObjective(residuals, None, 0.0)
    root = ocp.nlp.parameter("prior.weight", np.sqrt(weight / prior.count))
    ocp.nlp.least_squares(root * ca.mtimes(ca.DM(prior.matrix), ocp.theta))
    return FitObjective(residuals, prior, weight)
