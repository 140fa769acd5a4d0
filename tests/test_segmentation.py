"""Breakpoints where a measured curve bends: the optimal piecewise-linear segmentation."""

from __future__ import annotations

import numpy as np
import pytest

from crashnlp.case.segmentation import BANDS, MIN_SPACING, bends, line_misfits, misfit


def test_line_misfits_are_the_least_squares_residuals():
    rng = np.random.default_rng(3)
    x, y = np.sort(rng.uniform(0, 1, 30)), rng.normal(size=30)
    cost = line_misfits(x, y)
    for i, j in [(0, 30), (4, 9), (10, 12), (17, 29)]:
        residual = y[i:j] - np.polyval(np.polyfit(x[i:j], y[i:j], 1), x[i:j])
        assert cost[i, j] == pytest.approx(float(residual @ residual), abs=1e-9)
    assert np.isinf(cost[5, 6]) and np.isinf(cost[5, 5])  # one point, none: no line


def test_the_knots_of_a_piecewise_linear_curve_are_found():
    """A plateau, a dip and a stack-up, measured with noise: each breakpoint within one band of
    the curve's knot, where even spacing misses them by up to 40 mm."""
    knots = np.array([0.0, 0.08, 0.2, 0.35, 0.5, 0.6])
    force = np.array([0.0, 5e5, 5.2e5, 3e5, 6e5, 1.4e6])
    crush = np.linspace(0.0, 0.6, 3000)
    measured = np.interp(crush, knots, force) + np.random.default_rng(0).normal(0.0, 2e4, crush.size)
    found = np.array(bends(crush, measured, 0.6, knots.size))
    assert found[0] == 0.0 and found[-1] == 0.6
    assert np.max(np.abs(found - knots)) <= 0.6 / BANDS + 1e-12
    assert np.max(np.abs(np.linspace(0.0, 0.6, knots.size) - knots)) > 0.035


def test_the_misfit_is_what_a_continuous_curve_through_the_breakpoints_leaves():
    """Nothing through the knots of a piecewise-linear curve (on band edges: no band straddles a
    knot); through fewer, the RMS of the best such curve, which noise raises by its own RMS."""
    knots, force = np.array([0.0, 0.2, 0.45, 0.7]), np.array([0.0, 4e5, 3e5, 9e5])
    crush = np.linspace(0.0, 0.7, 7001)
    curve = np.interp(crush, knots, force)
    assert misfit(crush, curve, 0.7, list(knots)) < 1e-6 * 9e5
    coarse = misfit(crush, curve, 0.7, [0.0, 0.35, 0.7])
    assert 2e4 < coarse < 2e5
    noisy = curve + np.random.default_rng(1).normal(0.0, 1e4, crush.size)
    assert misfit(crush, noisy, 0.7, list(knots)) == pytest.approx(1e4 / np.sqrt(crush.size / BANDS), rel=0.3)


def test_a_straight_curve_is_split_evenly():
    crush = np.linspace(0.0, 0.5, 500)
    found = bends(crush, 1e6 * crush, 0.5, 6)
    assert np.allclose(np.diff(found), 0.1, atol=0.5 / BANDS + 1e-12)


@pytest.mark.parametrize("count", [2, 5, 8, 30])
def test_no_two_breakpoints_come_closer_than_the_shortest_segment(count):
    """A curve with a bend every few millimetres (a noisy measurement) cannot crowd breakpoints."""
    crush = np.linspace(0.0, 0.7, 4000)
    force = 4e5 + 2e5 * np.sign(np.sin(crush * 900.0)) + np.random.default_rng(1).normal(0.0, 5e4, crush.size)
    found = np.array(bends(crush, force, 0.7, count))
    assert found.size == count and found[0] == 0.0 and found[-1] == pytest.approx(0.7)
    assert np.min(np.diff(found)) >= MIN_SPACING * 0.7 / (count - 1) - 1e-12
