"""Front-end force laws: piecewise-linear spring and damper characteristics, unloading.

Piecewise-linear functions are written as a sum of hinges, not with
casadi.interpolant: an interpolant with symbolic values has no derivative with
respect to those values unless inlined, the hinge form has exact ones. Each hinge
may be smoothed, max(z, 0) ~ (z + sqrt(z^2 + eps^2)) / 2, which keeps IPOPT
away from kinks at the breakpoints.

A new spring law is a function (x, breakpoints, values, eps) -> (force, energy)
added to SPRING_LAWS; a new unloading law one entry of UNLOADING_LAWS, its force and its permanent
set; either's name also goes into crashnlp.base.choices, where the schema reads it. Past the last
breakpoint a law continues its last segment, unless `with_tail` bends it into a line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca

Expr = Any  # a CasADi SX or MX expression (their stubs do not mix the two in arithmetic)


def hinge(z: Expr, eps: float) -> Expr:
    """max(z, 0), smoothed over a width eps when eps > 0."""
    return ca.fmax(z, 0) if eps == 0 else 0.5 * (z + ca.sqrt(z * z + eps * eps))


def rounded_hinge(z: Expr, width: Expr) -> Expr:
    """max(z, 0) with its corner rounded by a parabola over |z| < width / 2: once differentiable,
    and exact outside that band (zero below it, z above), so that a force clamped by it is zero
    past the band, not a tail."""
    half = 0.5 * width
    return ca.if_else(z >= half, z, ca.if_else(z <= -half, 0, (z + half) ** 2 / (2 * width)))


def engagement(z: Expr, eps: float) -> Expr:
    """0 below z = 0, rising to 1 over the first eps of z: a contact's damper engages as the contact
    begins, so that its force starts from zero instead of jumping to c * v; a step where eps is 0."""
    return ca.fmin(ca.fmax(z / eps, 0), 1) if eps > 0 else z > 0


def smooth_engagement(z: Expr, eps: float) -> Expr:
    """`engagement` with its two corners rounded: 3 s^2 - 2 s^3 of s = clamp(z / eps, 0, 1), once
    differentiable, so that a damper engaging where a parameter moves the contact's start (an
    engine's gap) does not put a kink of c * v / eps into the force; a step where eps is 0."""
    s = engagement(z, eps)
    return s * s * (3 - 2 * s) if eps > 0 else s


def never_pulling(push: Expr, width: Expr, eps: float) -> Expr:
    """A contact's force from what pushes it: max(push, 0), its corner rounded over `width`
    (`rounded_hinge`) where the contact is smoothed (eps > 0), so that a contact lets go smoothly."""
    return rounded_hinge(push, width) if eps > 0 else ca.fmax(push, 0)


def rounded_hinge_integral(z: Expr, width: Expr) -> Expr:
    """Antiderivative of `rounded_hinge` in z, zero below its band."""
    half = 0.5 * width
    return ca.if_else(z >= half, 0.5 * z * z + width * width / 24, ca.if_else(z <= -half, 0, (z + half) ** 3 / (6 * width)))


def hinge_integral(z: Expr, eps: float) -> Expr:
    """Antiderivative of `hinge` in z, zero far left."""
    if eps == 0:
        return 0.5 * ca.fmax(z, 0) ** 2
    r = ca.sqrt(z * z + eps * eps)
    return 0.25 * (z * z + z * r + eps * eps * ca.log((z + r) / eps))


def _pieces(bps, vals):
    """Slopes of the segments and their changes at interior breakpoints."""
    n = len(bps)
    slopes = [(vals[i + 1] - vals[i]) / (bps[i + 1] - bps[i]) for i in range(n - 1)]
    kinks = [slopes[i] - slopes[i - 1] for i in range(1, n - 1)]
    return slopes, kinks


def piecewise_linear(x: Expr, bps, vals, eps: float) -> Expr:
    """Interpolant through (bps, vals), extrapolated linearly, exact at bps[0]."""
    slopes, kinks = _pieces(bps, vals)
    f = vals[0] + slopes[0] * (x - bps[0])
    for b, dk in zip(bps[1:-1], kinks):
        f += dk * (hinge(x - b, eps) - hinge(bps[0] - b, eps))
    return f


def piecewise_linear_integral(x: Expr, bps, vals, eps: float) -> Expr:
    """Integral of `piecewise_linear` from bps[0] to x."""
    slopes, kinks = _pieces(bps, vals)
    dx = x - bps[0]
    f = vals[0] * dx + 0.5 * slopes[0] * dx * dx
    for b, dk in zip(bps[1:-1], kinks):
        f += dk * (hinge_integral(x - b, eps) - hinge_integral(bps[0] - b, eps) - hinge(bps[0] - b, eps) * dx)
    return f


def force_law(x: Expr, bps, vals, eps: float) -> tuple[Expr, Expr]:
    """F(x) piecewise linear over crush breakpoints; strain energy is its integral."""
    return piecewise_linear(x, bps, vals, eps), piecewise_linear_integral(x, bps, vals, eps)


def secant_law(x: Expr, bps, vals, eps: float) -> tuple[Expr, Expr]:
    """Paper Eq. (1): F = k(x) x with k piecewise linear (secant stiffness).

    The energy integral int k(s) s ds is exact for eps = 0 and uses the same
    hinge integrals otherwise (first order in eps).
    """
    k = piecewise_linear(x, bps, vals, eps)
    slopes, kinks = _pieces(bps, vals)
    k0 = vals[0] - slopes[0] * bps[0]
    energy = 0.5 * k0 * x * x + slopes[0] * x**3 / 3
    for b, dk in zip(bps[1:-1], kinks):
        h = ca.fmax(x - b, 0)
        energy += dk * (h**3 / 3 + 0.5 * b * h * h - hinge(bps[0] - b, eps) * 0.5 * x * x)
    return k * x, energy


SpringLaw = Callable[[Expr, list, list, float], tuple[Expr, Expr]]
SPRING_LAWS: dict[str, SpringLaw] = {"force": force_law, "secant": secant_law}


def with_tail(law: SpringLaw, start: Expr, slope: Expr) -> SpringLaw:
    """`law` up to the crush `start`; past it the straight line from the law's force at `start`
    rising at `slope` (a hinge smoothed as the law's own). The energy is the law's up to `start`
    plus the line's trapezoid, exact for eps = 0."""

    def tailed(x: Expr, bps: list, vals: list, eps: float) -> tuple[Expr, Expr]:
        past = hinge(x - start, eps)
        force, energy = law(x - past, bps, vals, eps)
        at_start = law(start, bps, vals, eps)[0]
        return force + slope * past, energy + at_start * past + 0.5 * slope * past * past

    return tailed


def damper_force(rate: Expr, bps, vals, eps: float) -> Expr:
    """Paper Eq. (2): F = c(|v|) v with c piecewise linear over crush-rate breakpoints."""
    speed = ca.sqrt(rate * rate + eps * eps) - eps
    return piecewise_linear(speed, bps, vals, eps) * rate


def elastic_unloading(load: Callable[[Expr], Expr], x: Expr, x_max: Expr, stiffness: Expr, eps: float) -> tuple[Expr, Expr]:
    """The paper: unloading retraces the loading curve; the history has no effect."""
    return load(x), None


def plastic_unloading(load: Callable[[Expr], Expr], x: Expr, x_max: Expr, stiffness: Expr, eps: float) -> tuple[Expr, Expr]:
    """Unload from the largest crush so far along `stiffness` to a permanent set.

    The force is the smaller of the loading curve and the unloading line; the
    switch between them is smoothed over a tenth of the crush smoothing width.
    x_max is the model's history state, so the switch is the model's own event.
    The stored (recoverable) energy is that of the unloading spring.
    """
    loading, unloading = load(x), load(x_max) - stiffness * (x_max - x)
    if eps == 0:
        force = ca.fmin(loading, unloading)
    else:
        z, width = loading - unloading, 0.1 * eps * stiffness
        force = loading - 0.5 * (z + ca.sqrt(z * z + width * width) - width)
    return force, 0.5 * ca.fmax(force, 0) ** 2 / stiffness


def no_set(at_largest: Expr, largest: Expr, stiffness: Expr) -> Expr:
    """The elastic law's permanent set: none, the front end springs back along its loading curve."""
    return 0 * largest


def plastic_set(at_largest: Expr, largest: Expr, stiffness: Expr) -> Expr:
    """The plastic law's permanent set: the crush where the unloading line from the largest crush
    (whose loading force is `at_largest`) meets zero force."""
    return largest - at_largest / stiffness


# (the loading curve, crush, largest crush so far, unloading stiffness, eps) -> (force, stored energy;
# None: the loading curve's own)
UnloadingForce = Callable[[Callable[[Expr], Expr], Expr, Expr, Expr, float], tuple[Expr, Expr | None]]
# (the loading force at the largest crush so far, that crush, the unloading stiffness) -> the crush
# the law leaves once its force is zero
PermanentSet = Callable[[Expr, Expr, Expr], Expr]


@dataclass(frozen=True)
class UnloadingLaw:
    """An unloading law: its force (crashnlp.models.form's front end) and the permanent set it
    leaves (CrashModel.permanent_set), kept together so that a new law is one entry."""

    force: UnloadingForce
    permanent_set: PermanentSet


UNLOADING_LAWS: dict[str, UnloadingLaw] = {
    "elastic": UnloadingLaw(elastic_unloading, no_set),
    "plastic": UnloadingLaw(plastic_unloading, plastic_set),
}
