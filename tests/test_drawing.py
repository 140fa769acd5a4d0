"""Figures drawn by a process forked before the solve: the same files as drawn in place."""

from __future__ import annotations

import os

import numpy as np
import pytest
from builders import ROOT, small_pickup_problem

from crashnlp import api
from crashnlp.base.outputs import METRIC
from crashnlp.results.drawing import FigureProcess
from crashnlp.results.result import figure_jobs, write_figures

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="drawn in place where there is no fork")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    return api.identify(small_pickup_problem(tmp_path_factory.mktemp("drawing")))


def pngs(folder) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.png"))}


@pytest.mark.integration
def test_the_figure_process_draws_what_drawing_in_place_draws(result, tmp_path):
    with FigureProcess() as figures:
        figures.draw(figure_jobs(result, tmp_path / "forked"), tmp_path / "forked")
    write_figures(result, tmp_path / "here")
    drawn = pngs(tmp_path / "forked")
    assert set(drawn) == {"force_crush.png", "56kph/fit.png", "56kph/residuals.png"}
    assert drawn == pngs(tmp_path / "here")


def test_a_failure_in_the_figure_process_is_reported(result, tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    with pytest.raises(RuntimeError, match="were not drawn"), FigureProcess() as figures:
        figures.draw(figure_jobs(result, blocked), blocked)


def test_a_failure_on_another_core_is_reported(result, tmp_path, monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)  # residuals.png is drawn by a second process
    (tmp_path / "56kph" / "residuals.png").mkdir(parents=True)
    with pytest.raises(RuntimeError, match="were not drawn"), FigureProcess() as figures:
        figures.draw(figure_jobs(result, tmp_path), tmp_path)
    assert (tmp_path / "56kph" / "fit.png").exists() and (tmp_path / "force_crush.png").exists()


def test_leaving_without_drawing_ends_the_process(tmp_path):
    with FigureProcess() as figures:
        pid = figures.pid
    assert pid is not None and figures.pid is None
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)
    assert not list(tmp_path.iterdir())


def test_simulate_draws_its_figure_in_the_figure_process(tmp_path):
    from crashnlp.cli import main

    assert main(["simulate", str(small_pickup_problem(tmp_path)), "--out", str(tmp_path / "sim")]) == 0
    assert set(pngs(tmp_path / "sim")) == {"56kph/response.png"}
    assert pngs(tmp_path / "sim")["56kph/response.png"].startswith(b"\x89PNG")


@pytest.mark.integration
def test_the_force_crush_figure_draws_the_band_the_measured_curve_and_the_unloading(result, tmp_path):
    ((_, (_, curves, _, title, measured, band)),) = [
        job for job in figure_jobs(result, tmp_path) if job[0] == "force_crush_figure"
    ]
    assert title == f"{result.name}: identified loading curve"
    x, low, high = band
    _, identified = curves["identified loading curve"]
    assert np.all(low <= identified) and np.all(identified <= high) and np.max(high - low) > 0
    crush, force = measured["measured m|a| vs CG travel"]
    test = result.tests["56kph"]
    assert test.data_metrics["max_displacement_m"] is None  # the 60 ms record ends still moving: loading to its last travel
    recorded = np.genfromtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", names=True)
    travel = recorded["disp_x_m"][recorded["time_s"] <= 0.06]
    assert np.max(crush) == pytest.approx(np.max(travel), rel=0.01)
    (x, f) = next(c for label, c in curves.items() if label.startswith("unloading"))
    top = float(np.max(test.response["crush"]))
    assert x[1] == pytest.approx(top) and f[0] == 0.0
    assert (f[1] - f[0]) / (x[1] - x[0]) == pytest.approx(result.identified.model["unloading"]["stiffness"])


@pytest.mark.integration
def test_the_fit_figure_names_each_channels_rmse_and_rating(result, tmp_path):
    ((_, (_, title, _, _, _, notes, _, _)),) = [job for job in figure_jobs(result, tmp_path) if job[0] == "response_figure"]
    assert title == f"{result.name}: fit to the data"  # pickup-56kph names its test already
    fit = result.tests["56kph"].fit
    assert set(notes) == set(fit)
    for channel, f in fit.items():
        assert notes[channel].endswith(f"ISO 18571 {f.iso18571['overall']:.3f}")
    assert notes["displacement"].startswith(f"RMSE {fit['displacement'].rmse * 1e3:.3g} mm")


@pytest.mark.integration
def test_the_fit_figure_legends_its_bounds_and_names_the_accelerations_class_as_the_table(result, tmp_path, monkeypatch):
    """fit.png's dashed bound lines are in its one legend (it named the first panel's curves
    alone, and a bound on the pitch was in none), and its acceleration axis names the CFC class
    the metric table names the peak's with ("(g, CFC60)")."""
    from crashnlp.results import plots

    ((_, (path, title, model, data, bands, notes, _, read)),) = [
        job for job in figure_jobs(result, tmp_path) if job[0] == "response_figure"
    ]
    drawn: dict[str, object] = {}
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.setdefault("figure", fig))
    plots.response_figure(path, title, model, data, bands, notes, {"pitch": (None, 0.1)}, read)
    axes = drawn["figure"].axes
    assert "bound" in [t.get_text() for t in axes[0].get_legend().get_texts()]
    table = METRIC["peak_decel_g"].heading_through(result.tests["56kph"].response.accel_filter)
    (accel,) = [ax.get_ylabel() for ax in axes if ax.get_ylabel().startswith("acceleration")]
    assert read == "CFC60" and accel.endswith(table[table.index("(") :])
