"""Crash-pulse design: constraints at every grid point, and the square-wave limit."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from builders import (
    ROOT,
    assert_contact_force_is_the_front_ends,
    assert_exact_hessian_is_casadis,
    assert_monotone_crush,
    make_case,
)

from crashnlp.cli import main
from crashnlp.optimize.design import design
from crashnlp.optimize.outcome import result_of
from crashnlp.results.result import Result, figure_jobs

V0, CRUSH_SPACE = 15.0, 0.5


def design_case(n_breakpoints: int, extra: dict | None = None):
    """A level pendulum (no pitch lever) so horizontal motion is the crush: 1-D physics."""
    bps = np.linspace(0.0, 1.2 * CRUSH_SPACE, n_breakpoints).round(4).tolist()
    changes = {
        "name": "design",
        "kind": "design",
        "design": {"minimize": "peak_decel"},
        "vehicle": {"speed": V0, "cg_above_impact": 0, "crush_offset": 0},
        "model": {"spring": {"crush_breakpoints": bps, "values": ["300 kN"] * n_breakpoints}, "damper": None},
        "tests": [{"name": "t", "duration": 0.1}],
        "estimate": {"model.spring.values": {"bounds": ["0 kN", "3 MN"]}},
        "constraints": {"monotone_crush": True, "bounds": {"crush": [None, CRUSH_SPACE]}},
        "transcription": {"method": "multiple-shooting", "intervals": 60, "substeps": 2},
    }
    from builders import merge

    return make_case(merge(changes, extra or {}))


@pytest.fixture(scope="module")
def fine():
    case = design_case(13)
    return case, design(case, progress=None)


@pytest.mark.integration
@pytest.mark.slow
def test_design_meets_every_constraint_at_every_grid_point(fine):
    case, sol = fine
    assert sol.ok, sol.status
    ts = sol.tests[0]
    assert np.all(ts.outputs["crush"] <= CRUSH_SPACE + 1e-7)
    assert_monotone_crush(ts)
    # the solver's own values, before the report clips them into their bounds: inside them
    # but for IPOPT's relaxation of each bound (1e-8 of it)
    free = sol.ocp.free
    raw = sol.ocp.nlp.value("theta", sol.result.z).ravel()
    assert np.all((raw >= free.lower - 1e-6 * free.scale) & (raw <= free.upper + 1e-6 * free.scale))
    # the design simulated by the separate integrator on a grid 16 times finer than the NLP's
    # keeps the crush space and the monotone crush too: the NLP did not live off its grid
    p = case.test_parameters(case.tests[0], free.full(sol.theta))
    sim = case.simulate(free.full(sol.theta), dt=1e-4)["t"]
    assert np.max(sim["crush"]) <= CRUSH_SPACE + 1e-6
    assert_monotone_crush(sim)
    for r in (ts, sim):
        assert_contact_force_is_the_front_ends(case, r, p)


@pytest.mark.integration
@pytest.mark.slow
def test_a_designs_figure_is_its_response_with_its_crush_space(fine, tmp_path):
    _, sol = fine
    result = result_of(sol)
    ((_, (path, title, model, *_, limits, _)),) = [job for job in figure_jobs(result, tmp_path) if job[0] == "response_figure"]
    assert path.name == "response.png" and title == "design, test t: design"
    assert "crush" in model and limits["crush"] == (None, pytest.approx(CRUSH_SPACE))
    result.save(tmp_path, figures=False)
    assert Result.load(tmp_path).output_bounds == result.output_bounds


@pytest.mark.integration
@pytest.mark.slow
def test_a_prediction_from_a_design_says_why_it_has_no_intervals(fine, tmp_path):
    """A design's values are chosen, fitted to no data: its result says it is a design's vehicle,
    read back too, and its prediction at another speed says that nothing measures their
    uncertainty, not that the data do not determine them."""
    import crashnlp

    _, sol = fine
    result = result_of(sol)
    assert result.identified is not None and result.identified.designed
    result.save(tmp_path, figures=False)
    read = Result.load(tmp_path)
    assert read.identified is not None and read.identified.designed
    (test,) = crashnlp.simulate(read, speed="12 m/s").values()
    assert all(v is None for v in test.intervals.values())
    assert any("no intervals: a design's values are chosen for its goal, fitted to no data" in n for n in test.notes)
    assert not any("the data do not determine" in n for n in test.notes)


@pytest.mark.integration
def test_a_design_whose_vehicle_does_not_stop_is_not_ok(tmp_path, capsys):
    """The shipped design with a crush space of 600 m (600 mm meant): its least peak lets the
    vehicle through the barrier at 12.8 m/s, which the solve had called ok (exit 0); the design is
    not ok now, and says that its vehicle does not stop."""
    raw = yaml.safe_load((ROOT / "problems/design-crush-space.yaml").read_text())
    raw["constraints"]["bounds"]["crush"] = [None, 600]
    (tmp_path / "d.yaml").write_text(yaml.safe_dump(raw))
    assert main(["design", str(tmp_path / "d.yaml"), "--out", str(tmp_path / "out"), "--no-figures"]) == 1
    assert "56kph: the designed vehicle does not stop within the window" in capsys.readouterr().err


@pytest.mark.integration
@pytest.mark.slow
def test_peak_deceleration_against_the_square_wave_bound(fine):
    case, sol = fine
    square_wave = V0**2 / (2 * CRUSH_SPACE)
    peak = -np.min(sol.tests[0].outputs["accel"])
    assert peak >= square_wave * (1 - 1e-6)  # no pulse beats the square wave
    assert peak <= 1.10 * square_wave  # enough breakpoints come within 10 %
    # and a real design: the flat initial spring runs out of crush space, the design does not:
    # it is the square wave itself, the constant force m v0^2 / (2 C) over the crush reached
    start = case.simulate()["t"]
    assert np.max(start["crush"]) > 1.05 * CRUSH_SPACE
    assert np.max(sol.tests[0].outputs["crush"]) <= CRUSH_SPACE + 1e-7
    mass = case.problem.vehicle.mass
    values = np.asarray(sol.parameters["model.spring.values"])
    reached = np.asarray(case.problem.model.spring.crush_breakpoints) <= CRUSH_SPACE
    np.testing.assert_allclose(values[reached][1:], mass * V0**2 / (2 * CRUSH_SPACE), rtol=0.02)


@pytest.mark.integration
def test_pitch_bound_holds_in_design():
    case = design_case(
        7, {"vehicle": {"cg_above_impact": 0.18, "crush_offset": 0.1}, "constraints": {"bounds": {"pitch": [None, "3 deg"]}}}
    )
    sol = design(case, progress=None)
    assert sol.ok, sol.status
    assert np.max(sol.tests[0].outputs["pitch"]) <= np.radians(3) + 1e-7  # 3.3 deg without the bound
    assert np.max(sol.tests[0].outputs["crush"]) <= CRUSH_SPACE + 1e-7


@pytest.mark.parametrize("goal", ["peak_decel", "olc"])
def test_structured_exact_hessian_of_a_design_equals_casadis_own(goal):
    # the design's outer expressions are nonlinear in the decision vector and in the mapped
    # outputs together (the OLC's hat functions of its own time variables, epigraphs)
    from crashnlp.optimize.design import DESIGN_OBJECTIVES
    from crashnlp.optimize.ocp import OptimalControl

    ocp = OptimalControl(design_case(5, {"transcription": {"intervals": 12}, "design": {"minimize": goal}}))
    DESIGN_OBJECTIVES[goal](ocp)
    x0 = ocp.nlp.bounds()["x0"]
    z = x0 * (1 + 0.05 * np.random.default_rng(5).standard_normal(x0.size))
    assert_exact_hessian_is_casadis(ocp.nlp, z, 1.3, seed=6)
