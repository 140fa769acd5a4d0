"""What an engineer hands on: the report of a fit, a simulation and a study, and the exports
(LS-DYNA curves, CSV curves, a sled-test pulse), checked against the files and the model."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import html
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, merge, small_pickup_problem

from crashnlp.analysis.summary import goes_on
from crashnlp.base.outputs import METRIC, OUTPUT, PREDICTED, named_test, shown_unit
from crashnlp.base.units import G0
from crashnlp.cli import _print_solution, main
from crashnlp.data.instrument import cfc_recorded
from crashnlp.models.form import build_model
from crashnlp.models.parameters import ParameterLayout
from crashnlp.optimize import profile as profile_module
from crashnlp.report import export, result_page
from crashnlp.report.folders import read_result
from crashnlp.results.files import claim, run_name
from crashnlp.results.identified import IdentifiedModel
from crashnlp.results.result import LoadingCurve, Result, figure_jobs, unconverged
from crashnlp.results.simulation import extrapolation_line, read_simulation
from crashnlp.results.source import source_line
from crashnlp.studies.store import CaseStore

EMBEDDED = re.compile(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"')
EXTERNAL = re.compile(r'(?:src|href)\s*=\s*"(?!data:)[^"]*"|url\(|@import|<link|<script', re.IGNORECASE)


@pytest.fixture(scope="module")
def fit(tmp_path_factory) -> Path:
    """The shipped pickup fitted by the command line with --report (a few seconds)."""
    out = tmp_path_factory.mktemp("fit") / "pickup"
    assert main(["identify", str(ROOT / "problems/pickup-56kph.yaml"), "--out", str(out), "--report"]) == 0
    return out


@pytest.fixture(scope="module")
def prediction(fit, tmp_path_factory) -> Path:
    """The shipped 40 km/h problem predicted at 64 km/h from the fit: a simulation's folder."""
    out = tmp_path_factory.mktemp("prediction") / "sim"
    problem, params = str(ROOT / "problems/pickup-40kph.yaml"), str(fit / "result.json")
    assert main(["simulate", problem, "--params", params, "--speed", "64 km/h", "--out", str(out), "--no-figures"]) == 0
    return out


def self_contained(page: str) -> list[bytes]:
    """The page's embedded PNGs; fails on any resource it would fetch."""
    assert not EXTERNAL.findall(page), EXTERNAL.findall(page)[:3]
    pngs = [base64.b64decode(b) for b in EMBEDDED.findall(page)]
    assert all(png.startswith(b"\x89PNG\r\n\x1a\n") for png in pngs)
    return pngs


@pytest.mark.integration
def test_identify_report_is_one_page_with_the_figures_metrics_ratings_and_every_estimate(fit):
    page = (fit / "report.html").read_text(encoding="utf-8")
    assert len(self_contained(page)) >= 3  # the fit, its residuals, the loading curve, the correlations
    raw = json.loads((fit / "result.json").read_text())
    test = raw["tests"]["56kph"]
    assert "peak deceleration (g, CFC60)" in page  # the class the peak was read through
    assert f"<td>{test['metrics']['model']['peak_decel_g']:.4g}</td>" in page
    for channel, f in test["fit"].items():
        assert re.search(rf"<td class=\"l\">{channel}</td>.*<td>{f['iso18571']['overall']:.3g}</td></tr>", page), channel
    problem = Result.load(fit).identified.as_problem("pickup")
    for path, std in raw["std_errors"].items():
        unit, factor = shown_unit(problem.unit_at(path))
        for i, s in enumerate(std if isinstance(std, list) else [std]):
            label = f"{path}[{i}]" if isinstance(std, list) else path
            shown = re.escape(f"{s * factor:.2g}")
            assert re.search(rf"<td class=\"l\">{re.escape(label)}</td><td>[^<]+</td><td>{shown}</td>", page), label
    assert "correlation of the estimates" in page
    for note in raw["notes"]:
        assert note in html.unescape(page)


@pytest.mark.integration
def test_a_design_speaks_of_its_design_not_of_data_pulling_or_standard_errors(fit, tmp_path, capsys):
    """The fit's result as a design's is (a design has no standard errors, its bound pulls 0): the
    console, the page and the force-crush figure speak of a designed loading curve and of values
    at a bound, not of how far past it the data pull (it said "(0 std)"), nor of what is not identified."""
    result = Result.load(fit)
    label = next(iter(result.at_bound), "model.spring.values[0]")
    crush = np.linspace(0.0, 0.6, 7)
    design = dataclasses.replace(
        result,
        kind="design",
        std_errors={},
        correlation={},
        not_identified=(),
        at_bound={label: 0.0},
        force_crush=LoadingCurve(crush, 1e6 * crush, crush, 1e6 * crush),
    )
    _print_solution(design)
    console = capsys.readouterr().out
    page = result_page(design, fit)
    (job,) = [args for kind, args in figure_jobs(design, tmp_path) if kind == "force_crush_figure"]
    assert f"  at a bound: {label}\n" in console and "std" not in console and "data pull" not in console
    assert "designed loading curve" in page and "identified loading curve" not in page
    assert "Not identified" not in page and "data pull" not in page and " std)" not in page
    assert job[3] == f"{result.name}: designed loading curve" and "designed loading curve" in job[1]


def parameter_rows(page: str) -> dict[str, tuple[str, str, str]]:
    """The estimated values' rows of a report: label -> (standard error, 95 % interval, where it comes from)."""
    row = re.compile(r'<tr><td class="l">([^<]+)</td><td>[^<]*</td><td>([^<]*)</td><td>([^<]*)</td><td class="l">([^<]*)</td>')
    return {label: (std, interval, how) for label, std, interval, how in row.findall(html.unescape(page))}


def interval_ends(cell: str) -> list[float]:
    return [float(end.strip("<> ")) for end in cell.strip("[]").split(", ")]


@pytest.mark.integration
def test_a_profile_open_at_a_bound_runs_to_it_and_one_open_short_of_it_says_so(fit):
    """A profile writes null for an end where the objective never rose to its threshold
    (crashnlp.optimize.profile): the report gives the bound where the profile ran to it (the
    pickup's last spring value sits at its 3 MN bound, the data bound it only below) and the
    furthest value profiled, open, where the profile stopped short of the bound; it gave value
    ± 1.96 std cut at the bounds instead, [0, 3000] kN, losing the profile's lower end."""
    result = read_result(fit)
    labels, bounds = result.identified.labels, result.identified.bounds
    values, stds = result.parameters["model.spring.values"], result.std_errors["model.spring.values"]
    top, (_, bound) = values[6], bounds[labels.index("model.spring.values[6]")]
    assert top == pytest.approx(bound)  # the shipped fit's last spring value is at its bound
    steps = 0.75 * stds[2] * np.arange(1, 5)
    profiles = {
        "model.spring.values[6]": {"estimate": top, "lower": 0.7 * top, "upper": None, "points": [[top - 0.2 * top, 1.0]]},
        "model.spring.values[2]": {
            "estimate": values[2],
            "lower": values[2] - 2 * stds[2],
            "upper": None,
            "points": [[float(v), 1.0] for v in values[2] + steps],
        },
    }
    rows = parameter_rows(result_page(dataclasses.replace(result, profiles=profiles), fit))
    _, at_bound, how = rows["model.spring.values[6]"]
    assert interval_ends(at_bound) == pytest.approx([0.7 * top / 1e3, bound / 1e3], rel=1e-3) and how.startswith("profile")
    _, open_, how = rows["model.spring.values[2]"]
    assert interval_ends(open_) == pytest.approx([(values[2] - 2 * stds[2]) / 1e3, (values[2] + steps[-1]) / 1e3], rel=1e-3)
    assert "> " in open_ and "open" in how


@pytest.mark.integration
def test_a_profile_end_resting_on_a_solve_ipopt_did_not_finish_says_so(fit, monkeypatch, capsys):
    """Each profile point keeps its solve's IPOPT status, and an end resting on a solve IPOPT did
    not finish (the pickup's cg height with max_iter 15: three of four lower-side solves stopped
    at the limit) is said to be so by the console and the report, not shown as a plain number."""
    label, theta, std = "vehicle.cg_above_impact", 0.4, 0.1
    walks = {  # per side: (value, objective, status); the rise reaches its threshold (3.84) at the second point
        -1: [(0.325, 1.5, "Maximum_Iterations_Exceeded"), (0.25, 9.0, "Solve_Succeeded")],
        1: [(0.475, 1.5, "Solve_Succeeded"), (0.55, 9.0, "Solve_Succeeded")],
    }
    monkeypatch.setattr(
        profile_module, "map_all", lambda _, __, chains: enumerate(walks[-1 if c.values[0] < theta else 1] for c in chains)
    )
    problem = SimpleNamespace(uncertainty=SimpleNamespace(profile=(label,), points=2), with_values=lambda _: None)
    solution = SimpleNamespace(
        case=SimpleNamespace(problem=problem),
        regularization={},
        ocp=SimpleNamespace(free=SimpleNamespace(labels=lambda: [label], lower=np.array([0.0]), upper=np.array([0.6]))),
        covariance=SimpleNamespace(std=np.array([std]), hessian_inverse=np.array([[std**2]])),
        theta=np.array([theta]),
        result=SimpleNamespace(z=np.zeros(1), objective=0.0),
    )
    profiles = profile_module.profiles(solution, None)
    assert profiles[label]["statuses"] == [s for _, _, s in sorted(walks[-1] + walks[1])]
    assert profiles[label]["unsolved"] == {"lower": ["Maximum_Iterations_Exceeded"]}
    result = dataclasses.replace(read_result(fit), profiles=profiles)
    _, interval, how = parameter_rows(result_page(result, fit))[label]
    assert interval.startswith("[") and "unsolved" in interval.split(",")[0] and "unsolved" not in interval.split(",")[1]
    assert "lower end rests on a solve IPOPT did not finish (Maximum_Iterations_Exceeded)" in how
    _print_solution(result)
    said = [line for line in capsys.readouterr().out.splitlines() if label in line and "IPOPT did not finish" in line]
    assert len(said) == 1 and "lower end" in said[0]


@pytest.mark.integration
def test_a_value_whose_interval_takes_in_zero_is_said_to_be_so_where_zero_means_none(fit, capsys):
    """A spring value whose 95 % interval takes in zero (the damper estimated from one test: the
    spring's standard errors 1.6 to 6 times its values) is named on the console, in the report and
    in the curves' notes (one rule: Result.takes_in_zero). An offset or a height, whose zero means
    nothing, is not, however wide its interval; nor is a value whose profile interval excludes zero
    though value ± Z95 std would not. The shipped fit has none."""
    result = read_result(fit)
    assert result.takes_in_zero() == ()
    label, offset = "model.spring.values[2]", "vehicle.crush_offset"
    covariance = result.identified.covariance.copy()
    for entry, value in ((label, result.parameters["model.spring.values"][2]), (offset, 1.0)):
        i = result.identified.labels.index(entry)
        covariance[i, i] = value**2  # a standard error as large as the value (the offset's far larger)
    loose = dataclasses.replace(result, identified=dataclasses.replace(result.identified, covariance=covariance))
    assert loose.takes_in_zero() == (label,)
    value = result.parameters["model.spring.values"][2]
    profiled = {label: {"points": [[value, 0.0]], "estimate": value, "lower": value / 2, "upper": value * 2}}
    assert dataclasses.replace(loose, profiles=profiled).takes_in_zero() == ()
    bounds = list(loose.identified.bounds)
    bounds[loose.identified.labels.index(label)] = (value / 10, bounds[0][1])  # an interval cut above zero
    above = dataclasses.replace(loose.identified, bounds=tuple(bounds))
    assert dataclasses.replace(loose, identified=above).takes_in_zero() == ()
    _print_solution(loose)
    said = [line for line in capsys.readouterr().out.splitlines() if "takes in zero" in line]
    assert len(said) == 1 and said[0].endswith(f": {label}")
    page = html.unescape(result_page(loose, fit))
    assert re.search(rf"<li>95 % interval takes in zero \(.*\): {re.escape(label)}</li>", page)
    curves = export.identified_curves(loose.identified, loose.not_identified, loose.takes_in_zero())
    notes = [line for line in export.keyword_file(loose.name, fit, curves).splitlines() if "takes in zero" in line]
    assert len(notes) == 2 and f"{label} = " in notes[1]


@pytest.mark.integration
def test_result_json_notes_say_which_values_interval_takes_in_zero_as_the_console_does(tmp_path, capsys):
    """A fit of 60 ms of the pickup that estimates the damper from one test, whose 95 % intervals
    take in zero, says so in result.json's notes in the console's line (result.json had said
    nothing of it); the report, which names them with those at a bound, says it once."""
    raw = yaml.safe_load(small_pickup_problem(tmp_path).read_text())
    raw["model"]["damper"] = {"rate_breakpoints": [0, 16], "values": ["5 kN*s/m", "5 kN*s/m"]}
    raw["estimate"]["model.damper.values"] = {"bounds": [0, "200 kN*s/m"]}
    raw["solver"] = {"compile": "never"}
    (problem := tmp_path / "damper.yaml").write_text(yaml.safe_dump(raw))
    assert main(["identify", str(problem), "--out", str(tmp_path / "fit"), "--no-figures"]) == 0
    (said,) = [line.strip() for line in capsys.readouterr().out.splitlines() if "takes in zero" in line]
    result = read_result(tmp_path / "fit")
    assert result.takes_in_zero() and all(label in said for label in result.takes_in_zero())
    assert [note for note in result.notes if "takes in zero" in note] == [said]
    assert html.unescape(result_page(result, tmp_path / "fit")).count(said) == 1


@pytest.mark.integration
def test_a_fit_that_did_not_converge_leads_its_report_with_it_and_gives_no_errors_or_intervals(fit):
    """The report of a fit IPOPT stopped says so first, in the words its exports use, and gives
    its values without standard errors, intervals or correlations (a last iterate's, which
    `crashnlp simulate` does not take either); a converged fit's gives them, and no such line."""
    result = read_result(fit)
    status = "solver failed: Maximum_Iterations_Exceeded"
    for shown, converged in ((result, True), (dataclasses.replace(result, status=status), False)):
        page = result_page(shown, fit)
        rows = parameter_rows(page).values()
        assert rows and ("NOT CONVERGED" not in page) == converged
        assert all(std != "-" and interval != "-" for std, interval, _ in rows) == converged
        assert any(std != "-" or interval != "-" for std, interval, _ in rows) == converged
        assert ("correlation of the estimates" in page) == converged
    first = re.search(r"<p[^>]*>([^<]*)</p>", page.split("<body", 1)[1]).group(1)
    assert html.unescape(first) == unconverged(status)[0]


@pytest.mark.integration
def test_a_fit_ipopt_stopped_draws_no_band_about_its_loading_curve(tmp_path):
    """The loading curve's figure, which the report embeds, of a fit stopped after 3 iterations
    has no 95 % band: its covariance is a last iterate's (it drew one)."""
    import crashnlp

    given = (ROOT / "problems/pickup-56kph.yaml").read_text().replace("file: data/", f"file: {ROOT}/problems/data/")
    problem = tmp_path / "stopped.yaml"
    problem.write_text(given + "solver: {ipopt: {max_iter: 3}}\n")
    result = crashnlp.identify(problem)
    assert result.status == "solver failed: Maximum_Iterations_Exceeded" and result.std_errors
    assert result.force_crush is not None and result.force_crush.band is None


@pytest.mark.integration
def test_a_response_read_back_is_a_mapping_of_its_named_arrays(fit):
    """A fitted response iterates and converts like a dict: time, then every output, one length
    (it raised KeyError: 0, having only __getitem__)."""
    response = Result.load(fit).tests["56kph"].response
    table = dict(response)
    assert list(table)[0] == "time" and set(table) == {"time", *response.outputs}
    assert {len(v) for v in table.values()} == {response.time.size}


@pytest.mark.integration
def test_a_result_read_back_keeps_each_channels_ratings(fit):
    raw = json.loads((fit / "result.json").read_text())["tests"]["56kph"]["fit"]
    back = Result.load(fit).tests["56kph"].fit
    assert {c: f.iso18571 for c, f in back.items()} == {c: f["iso18571"] for c, f in raw.items()}
    assert back["accel"].rmse * 1 / G0 == pytest.approx(raw["accel"]["rmse"])


@pytest.mark.integration
def test_the_identified_channel_rmse_says_its_si_unit_and_an_older_file_reads_the_same(fit):
    raw = json.loads((fit / "result.json").read_text())
    saved, fits = raw["identified_model"]["channel_rmse"], raw["tests"]["56kph"]["fit"]
    assert set(saved) == {OUTPUT[c].key for c in fits} and "accel_mps2" in saved
    assert fits["accel"]["unit"] == "g" and saved["accel_mps2"] == pytest.approx(fits["accel"]["rmse"] * G0)  # one test
    now = Result.load(fit).identified
    assert now is not None and set(now.channel_rmse) == set(fits)
    older = {**raw["identified_model"], "channel_rmse": {c: saved[OUTPUT[c].key] for c in fits}}  # the channel's name alone
    assert IdentifiedModel.from_json(older).channel_rmse == now.channel_rmse


def read_curves(path: Path) -> dict[str, np.ndarray]:
    """The *DEFINE_CURVE_TITLE cards of a keyword file by their titles' first word (what the curve is):
    points (n x 2) from the fixed 20-column fields, after the 80-column curve card."""
    lines = path.read_text().splitlines()
    assert lines[0] == "*KEYWORD" and lines[-1] == "*END"
    curves = {}
    for start in [i for i, line in enumerate(lines) if line == "*DEFINE_CURVE_TITLE"]:
        end = next(i for i in range(start + 1, len(lines)) if lines[i].startswith("*"))
        card, *points = [line for line in lines[start + 2 : end] if not line.startswith("$")]
        assert len(card) == 80 and card[20:40].split() == ["1.0", "1.0"]  # sfa, sfo
        name = lines[start + 1].split(":")[0]
        curves[name] = np.array([(float(line[:20]), float(line[20:40])) for line in points])
    return curves


@pytest.mark.integration
def test_the_ls_dyna_curves_reproduce_the_identified_model_in_stated_units(fit, tmp_path):
    path = tmp_path / "pickup.k"
    assert main(["export", str(fit), "--format", "ls-dyna", "--out", str(path)]) == 0
    text = path.read_text()
    assert "units: mm, ms, kg, kN" in text and "*MAT_SPRING_GENERAL_NONLINEAR" in text
    curves = read_curves(path)
    identified = Result.load(fit).identified
    problem = identified.as_problem("pickup")
    layout = ParameterLayout.of(problem)
    model, p = build_model(problem.model, layout), layout.values(problem)
    crush, force = curves["loading"][:, 0] / 1e3, curves["loading"][:, 1] * 1e3  # mm, kN -> m, N
    tail = identified.model["spring"]["tail"]
    assert crush[-1] > tail["start"] * 1.2  # the tail the identified model extrapolates with is in the curve
    fine = np.linspace(0.0, crush[-1], 20001)
    own = np.asarray(model.loading_curve(fine[None, :], p)).ravel()
    assert np.max(np.abs(np.interp(fine, crush, force) - own)) <= 0.005 * np.max(own)
    stiffness = identified.model["unloading"]["stiffness"]
    recovered, back = curves["unloading"].T
    assert np.diff(back) / np.diff(recovered) == pytest.approx(stiffness * 1e-6)  # kN/mm
    rate, damping = curves["damper"].T  # mm/ms is m/s; kN
    assert damping[rate > 0.1] / rate[rate > 0.1] == pytest.approx(identified.model["damper"]["values"][0] * 1e-3, rel=1e-3)


@pytest.mark.parametrize("name", ["*pickup", "$pickup", "pickup-" + "x" * 89])
def test_a_curve_title_says_which_curve_it_is_and_never_reads_as_a_keyword_or_a_comment(name):
    """A problem named `*pickup` or `$pickup`, or 96 characters long: each *DEFINE_CURVE_TITLE's
    title line starts with what the curve is (loading, unloading, damper), so that LS-DYNA reads it
    as the title and the card after it as the curve's, and three curves never share a title; the
    name follows, cut to the 80 columns."""
    from crashnlp.report.export import Curves, keyword_file

    line = (np.array([0.0, 0.1]), np.array([0.0, 1e5]))
    lines = keyword_file(name, Path("fit"), Curves(line, line, line, "plastic", 1e6)).splitlines()
    titles = [lines[i + 1] for i, text in enumerate(lines) if text == "*DEFINE_CURVE_TITLE"]
    assert [t.split(":")[0] for t in titles] == ["loading", "unloading", "damper"], titles
    assert all(len(t) <= 80 and name[:10] in t for t in titles), titles
    assert [text for text in lines if text.startswith("*")] == ["*KEYWORD", *["*DEFINE_CURVE_TITLE"] * 3, "*END"]


@pytest.mark.integration
def test_the_csv_export_writes_every_curve_in_si(fit, tmp_path):
    assert main(["export", str(fit), "--format", "csv", "--out", str(tmp_path / "curves")]) == 0
    loading = csv_table(tmp_path / "curves/loading.csv")
    assert loading.dtype.names == ("crush_m", "force_N") and loading["crush_m"][-1] > 0.8
    assert {p.name for p in (tmp_path / "curves").iterdir()} == {"loading.csv", "unloading.csv", "damper.csv", "curves-notes.txt"}
    assert (tmp_path / "curves/loading.csv").read_text().startswith("crush_m,force_N\n")  # a plain table, any reader's


def csv_table(path: Path) -> np.ndarray:
    """A CSV crashnlp wrote, by its columns' names, under its comment lines."""
    comments = next(i for i, line in enumerate(path.read_text().splitlines()) if not line.startswith("# "))
    return np.genfromtxt(path, delimiter=",", names=True, skip_header=comments)


def exported_curves(folder: Path, tmp_path: Path) -> tuple[Path, Path]:
    """`folder`'s curves exported by the command line: its .k file and its CSV folder, in `tmp_path`."""
    k, csv = tmp_path / f"{folder.name}.k", tmp_path / f"{folder.name}-curves"
    assert main(["export", str(folder), "--format", "ls-dyna", "--out", str(k)]) == 0
    assert main(["export", str(folder), "--format", "csv", "--out", str(csv)]) == 0
    return k, csv


def loading_comments(k: Path, csv: Path) -> tuple[list[str], list[str]]:
    """What the .k file says under its loading curve's line (up to how a reader extends it), and
    what the CSV folder's curves-notes.txt says of loading.csv."""
    comments = [line[2:] for line in k.read_text().splitlines() if line.startswith("$ ")]
    first = next(i for i, line in enumerate(comments) if line.startswith("curve 1001:")) + 1
    last = next(i for i, line in enumerate(comments) if "past the last point" in line)
    said = (csv / "curves-notes.txt").read_text().splitlines()
    said_csv = [line.removeprefix("loading.csv: ") for line in said if line.startswith("loading.csv: ")]
    return [line.strip() for line in comments[first:last]], said_csv


@pytest.mark.integration
def test_every_curve_export_says_where_the_data_end_and_what_no_test_determines(fit, tmp_path):
    """The 40 km/h pickup fitted with `tail: segment` takes its model to 353 mm of crush; its values
    at 550 and 700 mm are not identified, at their 3 MN bound, and its loading curve hands them on.
    Its .k file had not said where the data end (only a tail's line did), its loading.csv nothing:
    both now say, in the same words, the crush the fitted tests reached, the breakpoints past it
    and each value not identified at its breakpoint; the fit with a trend tail says its reach too."""
    given = (ROOT / "problems/pickup-40kph.yaml").read_text().replace("file: data/", f"file: {ROOT}/problems/data/")
    problem, segment = tmp_path / "segment.yaml", tmp_path / "segment"
    problem.write_text(given.replace("    law: force\n", "    law: force\n    tail: segment\n"))
    assert main(["identify", str(problem), "--out", str(segment), "--no-figures"]) == 0
    for folder in (segment, fit):
        said_k, said_csv = loading_comments(*exported_curves(folder, tmp_path))
        assert said_k == said_csv and said_k, folder
        result = read_result(folder)
        identified = result.identified
        reach, bps = identified.range.model_crush, np.array(identified.model["spring"]["crush_breakpoints"])
        assert f"{reach * 1e3:.1f} mm" in said_k[0]
        (past,) = [line for line in said_k if line.startswith("breakpoints past it")]
        assert [float(x) for x in re.findall(r"\d+(?:\.\d+)?", past)] == pytest.approx(1e3 * bps[bps > reach])
        for label in result.not_identified:
            i = int(label.split("[")[1].rstrip("]"))
            assert re.search(rf"{re.escape(label)} = \d+ kN at {bps[i] * 1e3:.4g} mm", " ".join(said_k)), label
    assert read_result(segment).not_identified  # the values past the reach: the case this is about


@pytest.mark.integration
def test_a_damper_curve_says_what_its_values_rest_on(fit, tmp_path):
    """The damper curve handed on had said nothing of its values: a fit that did not estimate them
    hands on the problem's (nominal: one test does not tell a damper from a spring), and one that
    did names those the data do not determine, as the loading curve's notes do; .k and CSV alike."""
    from crashnlp.report.export import identified_curves

    k, csv = exported_curves(fit, tmp_path)
    identified = read_result(fit).identified
    assert not any(label.startswith("model.damper.values") for label in identified.labels)
    said = "not estimated: the problem's values, which no test determined"
    assert any(line.startswith(f"$   {said}") for line in k.read_text().splitlines())
    assert any(line.startswith(f"damper.csv: {said}") for line in (csv / "curves-notes.txt").read_text().splitlines())
    estimated = dataclasses.replace(identified, labels=(*identified.labels, "model.damper.values[1]"))
    (line,) = identified_curves(estimated, not_identified=("model.damper.values[1]",)).damper_notes
    rate = identified.model["damper"]["rate_breakpoints"][1]
    assert line.startswith("not identified") and "model.damper.values[1] = " in line and f"at {rate:.4g} m/s" in line


@pytest.mark.integration
def test_a_designs_curves_call_it_the_designed_front_end(tmp_path):
    """A design's .k file called its curves the identified front end's (its pulse says it is the
    designed model's): the .k file and each CSV now name the designed front end, and none an
    identified one."""
    design = tmp_path / "design"
    assert main(["design", str(ROOT / "problems/design-crush-space.yaml"), "--out", str(design), "--no-figures"]) == 0
    k, csv = exported_curves(design, tmp_path)
    firsts = [k.read_text().splitlines()[1], (csv / "curves-notes.txt").read_text().splitlines()[0]]
    assert all("the designed front end" in line for line in firsts), firsts
    assert not any("identified" in f.read_text() for f in [k, *csv.iterdir()])


@pytest.mark.integration
def test_an_exported_loading_curve_never_pulls_and_says_where_it_is_clipped(fit, tmp_path):
    """The pickup's smoothed law gives -1.9 N at zero crush (its tail's hinge reaches back there),
    which the .k and CSV loading curves handed on as the force at zero crush: they start at zero
    now and hold no force below it. A tail from zero crush takes the law to -2.4 kN there: the
    curve is the law clipped at zero, as the model's contact force is, and its files say so."""
    from crashnlp.report.export import identified_curves, keyword_file

    k, csv = exported_curves(fit, tmp_path)
    points = read_curves(k)["loading"]
    table = csv_table(csv / "loading.csv")
    for crush, force in (points.T, (table["crush_m"], table["force_N"])):
        assert crush[0] == 0.0 and force[0] == 0.0 and np.min(force) >= 0.0
    identified = read_result(fit).identified
    spring = {**identified.model["spring"], "tail": {"start": 0.0, "slope": 1e6}}
    from_zero = dataclasses.replace(identified, model={**identified.model, "spring": spring})
    curves = identified_curves(from_zero)
    problem = from_zero.as_problem("from-zero")
    layout = ParameterLayout.of(problem)
    crush, force = curves.loading
    own = np.asarray(build_model(problem.model, layout).loading_curve(crush[None, :], layout.values(problem))).ravel()
    assert np.min(own) < -1e3 and force == pytest.approx(np.maximum(own, 0.0), abs=1e-6)
    (said,) = [line for line in keyword_file("from-zero", Path("fit"), curves).splitlines() if "clipped" in line]
    assert f"{np.min(own) * 1e-3:.4g} kN" in said and said.removeprefix("$   ") in curves.loading_notes


@pytest.mark.integration
def test_the_pulse_is_sampled_filtered_and_keeps_the_velocity_change(fit, tmp_path, capsys):
    path = tmp_path / "pulse.csv"
    assert main(["export", str(fit), "--format", "pulse", "--rate", "20 kHz", "--cfc", "60", "--out", str(path)]) == 0
    check = capsys.readouterr().out.splitlines()[0]
    lines = path.read_text().splitlines()
    columns = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    assert lines[3] == f"# {check}" and lines[columns] == "time_s,accel_g"
    table = np.loadtxt(path, delimiter=",", skiprows=columns + 1)
    t, accel = table[:, 0], table[:, 1] * G0
    assert np.diff(t) == pytest.approx(5e-5)
    response = Result.load(fit).tests["56kph"].response
    delta_v = -np.sum(np.diff(t) * (accel[1:] + accel[:-1]) / 2)
    assert delta_v == pytest.approx(response["velocity"][0] - response["velocity"][-1], rel=0.005)  # the model's own
    numbers = [float(x) for x in re.findall(r"(\d+\.\d+) m/s", check)]
    assert numbers[0] == pytest.approx(delta_v, abs=1e-3) and numbers[3] == pytest.approx(numbers[1] + numbers[2], abs=2e-3)
    rough = tmp_path / "cfc1000.csv"
    assert main(["export", str(fit), "--format", "pulse", "--rate", "20 kHz", "--cfc", "1000", "--out", str(rough)]) == 0
    steps = [np.max(np.abs(np.diff(np.loadtxt(f, delimiter=",", skiprows=columns + 1)[:, 1]))) for f in (path, rough)]
    assert steps[0] < 0.9 * steps[1]  # CFC 60 smooths the pulse more than CFC 1000
    # the fit's response is read through CFC 60 already, as its test's accelerometers: the CFC 60
    # pulse is that curve resampled, not filtered twice; CFC 1000 filters the model's own
    assert response.accel_filter == "CFC60" and response.own_accel is not None
    resampled = np.interp(t, response.time, response["accel"])
    assert accel == pytest.approx(resampled, rel=1e-5, abs=1e-3)
    assert np.max(np.abs(cfc_recorded(t, resampled, 60.0) - resampled)) > 0.5  # m/s^2: what a second pass would change


def test_a_designs_pulse_is_its_own_acceleration_and_a_filter_that_moves_its_peak_says_so(tmp_path):
    """A model's acceleration no accelerometer reads (a design's: Response.accel_filter None) is
    handed on unfiltered by default, its peak the one the design optimised; a CFC 60 filter on its
    step onset overshoots, and the header then gives the model's own peak and the pulse's; it says
    the pulse is a designed model's. A fit's, read through its tests' class, is that curve by
    default, as before."""
    from crashnlp.report.export import PulseTest, pulse, write_pulse
    from crashnlp.results.response import Response

    time = np.arange(0.0, 0.12, 1e-4)
    accel = np.where(time < 0.08, -200.0, 0.0)  # a step onset at impact, as a design's model meets the barrier
    velocity = 16.0 + np.concatenate([[0.0], np.cumsum(accel[1:] * 1e-4)])
    design = Response(time, {"accel": accel, "velocity": velocity}, np.zeros((0, time.size)))
    own = pulse(design, 16.0, 1e4)
    assert own.cfc is None and np.max(-own.accel) == pytest.approx(200.0)
    filtered = pulse(design, 16.0, 1e4, 60)
    peak = np.max(-filtered.accel)
    assert peak > 1.01 * 200.0  # CFC 60 overshoots the step: a sled run to it runs harder than the design
    write_pulse(tmp_path / "p.csv", "d", PulseTest("t", design, 16.0, 1500.0, None, (), None, designed=True), filtered)
    lines = (tmp_path / "p.csv").read_text().splitlines()
    whose = "the designed model's acceleration (crashnlp design) in test t"
    assert lines[0] == f"# crashnlp export of d: {whose}, as a sled-test input"
    header = [line for line in lines if line.startswith("# sampled")]
    assert f"{200.0 / G0:.2f} g" in header[0] and f"{peak / G0:.2f} g" in header[0]
    fit = Response(time, {"accel": filtered.accel, "velocity": velocity}, np.zeros((0, time.size)), "CFC60", accel)
    assert pulse(fit, 16.0, 1e4).cfc == 60.0 and np.array_equal(pulse(fit, 16.0, 1e4).accel, filtered.accel)


@pytest.mark.integration
def test_a_pulse_says_whose_it_is_the_impact_it_is_of_and_the_tests_notes(fit, prediction, tmp_path):
    """A fit's pulse says it is the fitted model's, at its test's speed (km/h and m/s) and mass; a
    prediction's says it is a prediction's, at the speed and mass it was simulated at, where it
    came from (simulation.json's source, as `crashnlp simulate` printed it) and what the
    prediction noted: its extrapolation and its notes, a comment line each."""
    assert main(["export", str(fit), "--format", "pulse", "--out", str(tmp_path / "fit.csv")]) == 0
    header = (tmp_path / "fit.csv").read_text().split("time_s,accel_g")[0]
    assert "# crashnlp export of pickup-56kph: the fitted model's acceleration in test 56kph" in header
    assert "# impact at 56.0 km/h (15.556 m/s), mass 2550 kg\n" in header and "source:" not in header
    assert main(["export", str(prediction), "--format", "pulse", "--out", str(tmp_path / "predicted.csv")]) == 0
    header = (tmp_path / "predicted.csv").read_text().split("time_s,accel_g")[0]
    name, tests = read_simulation(prediction)
    test = tests["40kph"]
    assert f"# crashnlp export of {name}: a prediction's acceleration (crashnlp simulate) of test 40kph" in header
    assert f"# impact at 64.0 km/h (17.778 m/s), mass {test.mass:.0f} kg\n" in header
    assert f"# source: {source_line(test.source)}\n" in header and str(fit / "result.json") in header
    assert test.extrapolation and test.notes  # 64 km/h lies past the fitted 56 km/h
    notes = [f"40kph: {extrapolation_line(test.extrapolation)}", *test.notes]
    assert [line for line in header.splitlines() if line.startswith("# note: ")] == [f"# note: {note}" for note in notes]


@pytest.mark.integration
def test_a_pulse_whose_crash_goes_on_past_its_end_says_so_and_gives_no_negative_rebound(tmp_path, capsys):
    """The pickup fitted over its first 60 ms, which end mid-crash: its pulse is written (exit 0)
    under a warning, first in the header and on the console, in the words the fit's console
    uses (summary.goes_on), said once; its velocity-change check takes off the speed the vehicle
    still has toward the barrier and says the record holds no rebound, never a negative one."""
    given = (ROOT / "problems/pickup-56kph.yaml").read_text()
    short = given.replace("window: [0 s, 0.2 s]", "window: [0 s, 0.06 s]").replace("file: data/", f"file: {ROOT}/problems/data/")
    problem, fit = tmp_path / "short.yaml", tmp_path / "fit"
    problem.write_text(short)
    assert main(["identify", str(problem), "--out", str(fit), "--no-figures"]) == 0
    capsys.readouterr()
    assert main(["export", str(fit), "--format", "pulse"]) == 0
    out = capsys.readouterr().out
    result = read_result(fit)
    words = goes_on(result.tests["56kph"].metrics)
    assert words is not None and "still moving toward the barrier" in words
    warning = f"WARNING: the crash goes on past the end of this pulse: the model {words}"
    text = (fit / "56kph-pulse.csv").read_text()
    assert text.startswith(f"# {warning}\n") and text.count(words) == 1 and out.startswith(f"crashnlp: {warning}\n")
    check = next(line for line in text.splitlines() if line.startswith("# delta-v:"))
    assert check == f"# {out.splitlines()[1]}" and "rebound -" not in check and "(no rebound in it)" in check
    speed, still, total = (
        float(x) for x in re.findall(r"impact speed (\d+\.\d+) m/s - (\d+\.\d+) m/s.* = (\d+\.\d+) m/s", check)[0]
    )
    end = result.tests["56kph"].response["velocity"][-1]
    assert still == pytest.approx(end, abs=1e-3) and total == pytest.approx(speed - still, abs=2e-3)


@pytest.mark.integration
def test_an_export_of_a_fit_that_did_not_converge_says_so_in_every_file_and_on_the_console(fit, tmp_path, capsys):
    """Curves and a pulse handed on from a fit IPOPT stopped carry its status: the first comment
    of the .k file, of each curve CSV, of the pulse and of the force-crush table, and a console
    line; a converged fit's do not."""
    failed = tmp_path / "failed"
    shutil.copytree(fit, failed)
    raw = json.loads((failed / "result.json").read_text())
    status = "solver failed: Maximum_Iterations_Exceeded"
    (failed / "result.json").write_text(json.dumps({**raw, "status": status}))
    said = f"NOT CONVERGED: the fit ended {status}"
    for folder in (fit, failed):
        capsys.readouterr()
        assert main(["export", str(folder), "--format", "ls-dyna", "--out", str(tmp_path / f"{folder.name}.k")]) == 0
        assert main(["export", str(folder), "--format", "csv", "--out", str(tmp_path / f"{folder.name}-curves")]) == 0
        assert main(["export", str(folder), "--format", "pulse", "--out", str(tmp_path / f"{folder.name}-pulse.csv")]) == 0
        firsts = [(tmp_path / f"{folder.name}.k").read_text().splitlines()[1]]
        firsts += [f.read_text().splitlines()[0] for f in sorted((tmp_path / f"{folder.name}-curves").iterdir())]
        firsts.append((tmp_path / f"{folder.name}-pulse.csv").read_text().splitlines()[0])
        out = capsys.readouterr().out
        if folder is failed:
            assert all(said in line for line in firsts) and out.count(said) == 3
        else:
            assert not any("NOT CONVERGED" in line for line in firsts) and "NOT CONVERGED" not in out
    curve = np.loadtxt(fit / "force_crush.csv", delimiter=",", skiprows=1)
    loading = LoadingCurve(curve[:, 0], curve[:, 1], curve[:, 0], curve[:, 1])
    for folder, first in ((fit, "crush_m,spring_force_N"), (failed, f"# {said}")):  # and the force-crush table
        saved = tmp_path / f"{folder.name}-saved"
        dataclasses.replace(read_result(folder), force_crush=loading).save(saved, figures=False)
        assert (saved / "force_crush.csv").read_text().startswith(first)


def test_the_fit_s_force_crush_table_is_the_loading_curve_the_exports_hand_on(fit):
    """force_crush.csv runs a little past the crush the test reached, where the tail's trend takes
    over from the fitted law: the table gives the tail there, as the LS-DYNA and CSV exports and
    the predictions do, not the law's last segment (on the pickup 15 % more force at 570 mm)."""
    from crashnlp.report.export import identified_curves

    table = np.loadtxt(fit / "force_crush.csv", delimiter=",", skiprows=1)
    identified = read_result(fit).identified
    tail = identified.model["spring"]["tail"]
    past = table[:, 0] > tail["start"] + 0.005  # clear of the hinge's smoothing
    assert past.sum() >= 5
    exported = np.interp(table[:, 0], *identified_curves(identified).loading)
    clear = np.abs(table[:, 0] - tail["start"]) > 0.005  # the table's row at the start is the hinge's corner, unsmoothed
    assert np.max(np.abs(table[clear, 1] - exported[clear])) < 0.005 * np.max(exported)
    assert np.diff(table[past, 1]) / np.diff(table[past, 0]) == pytest.approx(tail["slope"], rel=1e-6)  # the tail's line


@pytest.mark.integration
def test_a_simulation_report_gives_the_intervals_and_the_extrapolation(fit, tmp_path):
    sim = tmp_path / "sim"
    problem = ROOT / "problems/pickup-40kph.yaml"
    assert main(["simulate", str(problem), "--params", str(fit / "result.json"), "--out", str(sim)]) == 0
    assert main(["report", str(sim)]) == 0
    page = (sim / "report.html").read_text(encoding="utf-8")
    assert len(self_contained(page)) == 1
    raw = json.loads((sim / "simulation.json").read_text())
    for test in raw["tests"].values():
        low, high = test["intervals"]["peak_decel_g"]
        assert f"<td>[{low:.1f}, {high:.1f}]</td>" in page
        if test["extrapolation"]:
            assert "extrapolates:" in page
    digest = hashlib.sha256((fit / "result.json").read_bytes()).hexdigest()
    assert f"source: from {problem}, with the parameters of {fit / 'result.json'}: pickup-56kph, status ok" in page
    assert f"sha256 {digest}" in page


@pytest.mark.integration
def test_a_prediction_that_ends_mid_crash_gives_the_note_why_it_has_no_metrics_not_an_empty_table(tmp_path):
    """A test simulated for 50 ms ends mid-crash, with none of the metrics a prediction gives: its
    page has no metrics table (it had one of a header row alone), and the note saying why."""
    problem, sim = tmp_path / "short.yaml", tmp_path / "sim"
    problem.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "t56", "duration": "0.05 s"}]})))
    assert main(["simulate", str(problem), "--out", str(sim), "--no-figures"]) == 0
    _, tests = read_simulation(sim)
    assert not any(tests["t56"].metrics.get(m.key) is not None for m in PREDICTED)
    assert main(["report", str(sim)]) == 0
    page = html.unescape((sim / "report.html").read_text(encoding="utf-8"))
    assert "<table" not in page
    assert any("mid-crash" in note and f"<li>{note}</li>" in page for note in tests["t56"].notes)


@pytest.mark.integration
def test_a_simulation_written_before_its_source_was_recorded_still_reads(fit, tmp_path):
    sim = tmp_path / "sim"
    problem = ROOT / "problems/pickup-40kph.yaml"
    assert main(["simulate", str(problem), "--params", str(fit / "result.json"), "--out", str(sim), "--no-figures"]) == 0
    raw = json.loads((sim / "simulation.json").read_text())
    del raw["source"]  # as crashnlp wrote it before it recorded the source
    (sim / "simulation.json").write_text(json.dumps(raw))
    name, tests = read_simulation(sim)
    assert name == "pickup-40kph" and tests and all(t.source == {} and t.intervals for t in tests.values())
    assert main(["report", str(sim)]) == 0
    assert "source: not recorded (written before crashnlp kept it)" in (sim / "report.html").read_text(encoding="utf-8")


def study_row(case: int, pitch: str, k_front: str, ok: bool = True) -> dict:
    si = {"4 deg": 0.0698, "8 deg": 0.1396, "50 kN/m": 5e4, "90 kN/m": 9e4}
    row = {"case": f"case-{case:03d}", "constraints.bounds.pitch": f"[null, {pitch}]", "vehicle.suspension.k_front": k_front}
    row |= {"constraints.bounds.pitch_si": si[pitch], "vehicle.suspension.k_front_si": si[k_front], "warm_start": ""}
    row |= {"status": "ok" if ok else "error: failed", "objective": 1.0 + case, "iterations": 10 + case, "wall_s": 0.1}
    return row | {"t.max_displacement_m": 0.5 + 0.01 * case, "t.peak_decel_g": 30.0 + case} if ok else row


def test_a_study_case_stored_before_the_rename_reads_as_one_stored_now(tmp_path):
    store = CaseStore(tmp_path / "cases")
    row = study_row(1, "4 deg", "50 kN/m")
    store.save("case-001", "key", {k.replace("max_displacement_m", "max_crush_m"): v for k, v in row.items()}, None)
    assert "t.max_crush_m" in (tmp_path / "cases" / "case-001.json").read_text()
    assert store.rows() == [row] and store.row("case-001", "key") == row


def test_a_two_entry_grid_study_reports_its_table_and_maps(tmp_path):
    store = CaseStore(tmp_path / "grid" / "cases")
    grid = [("8 deg", "90 kN/m"), ("4 deg", "50 kN/m"), ("8 deg", "50 kN/m"), ("4 deg", "90 kN/m")]
    for case, (pitch, k) in enumerate(grid):
        store.save(f"case-{case:03d}", "key", study_row(case, pitch, k, ok=case != 0), None)  # the first failed
    assert main(["report", str(tmp_path / "grid")]) == 0
    page = (tmp_path / "grid" / "report.html").read_text(encoding="utf-8")
    assert len(self_contained(page)) == 3  # objective, max displacement, peak deceleration over the grid
    assert page.count("<tr>") == 1 + 4 and "t: peak deceleration (g)" in page and "<td>500</td>" not in page
    assert "<td>510</td>" in page  # max displacement 0.51 m in mm, as the console shows it


def test_a_study_report_names_the_peaks_cfc_class_its_rows_record(tmp_path):
    """The page's table and maps head the peak as the console's table does, "(g, CFC60)", where the
    rows record the class (table.csv's <test>.accel_filter); rows written before it keep "(g)"."""
    store = CaseStore(tmp_path / "grid" / "cases")
    grid = [("8 deg", "90 kN/m"), ("4 deg", "50 kN/m"), ("8 deg", "50 kN/m"), ("4 deg", "90 kN/m")]
    for case, (pitch, k) in enumerate(grid):
        store.save(f"case-{case:03d}", "key", study_row(case, pitch, k) | {"t.accel_filter": "CFC60"}, None)
    assert main(["report", str(tmp_path / "grid")]) == 0
    page = (tmp_path / "grid" / "report.html").read_text(encoding="utf-8")
    heading = f"t: {METRIC['peak_decel_g'].heading_through('CFC60')}"
    assert page.count(heading) >= 2 and "t: peak deceleration (g)" not in page  # the table's head and the map's


def test_a_study_report_gives_ipopts_status_beside_each_cases_own(tmp_path):
    """A case IPOPT solved that failed a later check keeps IPOPT's status in table.csv: the page shows it too."""
    store = CaseStore(tmp_path / "study" / "cases")
    failed = study_row(0, "4 deg", "50 kN/m", ok=False) | {"return_status": "Solve_Succeeded"}
    store.save("case-000", "key", failed, None)
    store.save("case-001", "key", study_row(1, "8 deg", "50 kN/m") | {"return_status": "Solve_Succeeded"}, None)
    assert main(["report", str(tmp_path / "study")]) == 0
    page = (tmp_path / "study" / "report.html").read_text(encoding="utf-8")
    assert '<th class="l">return_status</th>' in page and page.count('<td class="l">Solve_Succeeded</td>') == 2


def test_a_study_report_is_titled_by_the_studys_name_not_its_folders(tmp_path):
    folder = tmp_path / "studydask"
    with claim(folder, run_name("study", "pitch-bound"), option=None):
        CaseStore(folder / "cases").save("case-000", "key", study_row(0, "4 deg", "50 kN/m"), None)
    assert main(["report", str(folder)]) == 0
    page = (folder / "report.html").read_text(encoding="utf-8")
    assert "<title>pitch-bound: study</title>" in page and "studydask" not in page


def test_a_zip_study_has_no_map(tmp_path):
    store = CaseStore(tmp_path / "zip" / "cases")
    for case, (pitch, k) in enumerate([("4 deg", "50 kN/m"), ("8 deg", "90 kN/m")]):
        store.save(f"case-{case:03d}", "key", study_row(case, pitch, k), None)
    assert main(["report", str(tmp_path / "zip")]) == 0
    assert len(self_contained((tmp_path / "zip" / "report.html").read_text())) == 0


@pytest.mark.parametrize(
    ("command", "make", "message"),
    [
        (["report"], None, "no such folder"),
        (["report"], "empty", "holds no result.json, simulation.json or cases/"),
        (["report"], "corrupt", "result.json: does not read as crashnlp writes it"),
        (["export", "--format", "ls-dyna"], "corrupt", "result.json: does not read as crashnlp writes it"),
        (["simulate"], "corrupt", "result.json: does not read as crashnlp writes it (JSONDecodeError"),
        (["export", "--format", "pulse"], "empty", "holds no result.json"),
        (["export", "--format", "csv"], "study", "a study's folder holds no curves or pulses"),
        (["export", "--format", "csv"], "simulation", "a simulation's folder holds no identified curves"),
    ],
)
def test_a_bad_folder_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, command, make, message):
    folder = tmp_path / "folder"
    if make is not None:
        folder.mkdir()
    if make == "corrupt":
        (folder / "result.json").write_text('{"name": "x", "tests": {')
    if make == "study":
        (folder / "cases").mkdir()
    if make == "simulation":
        (folder / "simulation.json").write_text("{}")
    before = sorted(tmp_path.rglob("*"))
    assert main([command[0], str(folder), *command[1:]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(folder) in err and message in err, err
    assert sorted(tmp_path.rglob("*")) == before


def test_a_solution_its_forward_simulation_departs_from_says_its_metrics_are_no_motion(fit, capsys):
    """A fit's test whose forward check departs past its tolerance (as an infeasible design's last
    iterate does, 114 mm of displacement at 33 times its tolerance): the console says, under its
    metrics, that they are of the solver's last iterate, not of the model's motion; within its
    tolerance it says nothing."""
    from crashnlp.cli import _print_solution

    result = Result.load(fit)
    (name, test), *_ = result.tests.items()
    departing = {
        "max_abs_error": {"displacement": 0.1138, "velocity": 1.313, "pitch": 0.002, "crush": 0.1137},
        "allowed": {"displacement": 0.00346, "velocity": 0.0777, "pitch": 0.00175, "crush": 0.00349},
        "worst_relative": 32.9,
    }
    for check, says in ((departing, True), ({**departing, "worst_relative": 0.4}, False)):
        tests = {**result.tests, name: dataclasses.replace(test, forward_check=check)}
        _print_solution(dataclasses.replace(result, tests=tests))
        out = capsys.readouterr().out
        line = "the forward simulation departs from this solution (displacement by 114 mm, 32.9 times its tolerance)"
        assert (line in out and "not of the model's motion" in out) == says, out


def test_a_fit_whose_vehicle_carries_an_engine_its_form_did_not_read_is_still_predicted(fit):
    """A pendulum fit written before an engine its form does not read was refused keeps it in its
    identified vehicle (nulls and all): its predictions simulate the vehicle as it was fitted,
    without the engine, and are not refused for it (its result.json cannot be edited to leave it
    out)."""
    import crashnlp

    result = Result.load(fit)
    engine = {"mass": 400.0, "gap": 0.45, "mount_stiffness": None, "mount_damping": None, "contact_damping": None}
    vehicle = {**result.identified.vehicle, "engine": engine}
    old = dataclasses.replace(result, identified=dataclasses.replace(result.identified, vehicle=vehicle))
    (test,) = crashnlp.simulate(old, speed="48 km/h").values()
    (plain,) = crashnlp.simulate(result, speed="48 km/h").values()
    assert test.metrics == plain.metrics


REMOVED = object()  # an entry taken out of result.json
UNFILLED = "is missing or null: a fit writes the value it used"
EDITS = {  # an identified model edited by hand: (entry, value) -> what the export says after the file's name
    ("spring", "values", REMOVED): f"identified_model.model.spring.values {UNFILLED}",
    ("spring", "values", 3, "abc"): "model.spring: cannot read 'abc' as a quantity",
    ("unloading", "stiffness", 0.0): "model.unloading.stiffness: must be positive",
    ("unloading", "stiffness", -5e6): "model.unloading.stiffness: must be positive",
    ("unloading", "stiffness", None): f"identified_model.model.unloading.stiffness {UNFILLED}",
    ("spring", "values", None): f"identified_model.model.spring.values {UNFILLED}",
    ("spring", "crush_breakpoints", 3, 0.1): "model.spring.crush_breakpoints: crush_breakpoints must be strictly increasing",
    ("smoothing", "crush", -0.01): "model.smoothing.crush: must not be negative",
    ("spring", "tail", "slope", float("nan")): "model.spring.tail: trend, segment, or {start: a crush, slope: a stiffness}",
}


@pytest.mark.parametrize(("edit", "why"), EDITS.items())
def test_an_identified_model_edited_is_one_line_to_the_exports_and_predictions(fit, tmp_path, capsys, edit, why):
    """A fit's result.json whose identified model was edited (an entry removed, made text, a
    stiffness zero, negative or none, breakpoints out of order, a negative smoothing, a tail's
    slope not a number): the curves' export and a prediction from it refuse it alike, naming the
    result.json (not the problem file the prediction reads) and the entry or what failed on it,
    exit 2, and write nothing (no ZeroDivisionError, no .k of nan, no unloading stiffness read
    from the predicted test's own data in place of a null)."""
    *path, key, value = edit
    folder = _edited(fit, tmp_path, ("identified_model", "model", *path, key), value)
    before = sorted(tmp_path.rglob("*"))
    problem, params = str(ROOT / "problems/pickup-40kph.yaml"), str(folder / "result.json")
    prediction = ["simulate", problem, "--params", params, "--out", str(tmp_path / "out-sim"), "--no-figures"]
    for command in _reading_the_folder(folder, tmp_path):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"crashnlp: error: {folder / 'result.json'}: {why}"), (command, err)
        assert err.count("\n") == 1
    assert main(prediction) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {folder / 'result.json'}: {why.split(' (')[0]}"), err
    assert sorted(tmp_path.rglob("*")) == before


def _edited(fit: Path, tmp_path: Path, keys: tuple, value: object) -> Path:
    """A copy of the fit's folder whose result.json holds `value` at the entry `keys` lead to from
    its top, or has that entry taken out (REMOVED)."""
    folder = tmp_path / "edited"
    shutil.copytree(fit, folder)
    raw = json.loads((folder / "result.json").read_text())
    *path, key = keys
    entry = raw
    for step in path:
        entry = entry[step]
    if value is REMOVED:
        del entry[key]
    else:
        entry[key] = value
    (folder / "result.json").write_text(json.dumps(raw))
    return folder


def _reading_the_folder(folder: Path, tmp_path: Path) -> list[list[str]]:
    """Every command that reads a fit's folder back: its exports (curves and pulse), its report
    and its own tests' prediction, each writing outside the folder."""
    exports = [["export", str(folder), "--format", fmt, "--out", str(tmp_path / f"out-{fmt}")] for fmt in FORMATS]
    report = ["report", str(folder), "--out", str(tmp_path / "report.html")]
    return [*exports, report, ["simulate", str(folder), "--out", str(tmp_path / "out-own"), "--no-figures"]]


FORMATS = ("ls-dyna", "csv", "pulse")
IDENTIFIED = "identified_model"
EDITED_ELSEWHERE = {  # result.json edited past the vehicle and the model: (keys from the top, value) -> the entry named
    ((IDENTIFIED, "discrepancy", "max_displacement_m"), -0.5): "identified_model.discrepancy.max_displacement_m is -0.5",
    ((IDENTIFIED, "covariance", 8, 8), -1e6): "identified_model.covariance row 8 (vehicle.pitch_inertia) has the variance",
    ((IDENTIFIED, "covariance", 0, 3), float("nan")): "identified_model.covariance row 0 (model.spring.values[0]) holds",
    ((IDENTIFIED, "range", "max_displacement_m"), -0.59): "identified_model.range.max_displacement_m is -0.59",
    ((IDENTIFIED, "channel_rmse", "accel_mps2"), -7.8): "identified_model.channel_rmse.accel_mps2 is -7.8",
    ((IDENTIFIED, "labels", -1), REMOVED): "identified_model.bounds has 10 entries for 9 labels",
    ((IDENTIFIED, "accel_filter"), "CFC61"): "identified_model.accel_filter is 'CFC61'",
    ((IDENTIFIED, "model", "damper", "values", 0), -5000.0): "model.damper.values.0: must not be negative",
    (("status",), None): "status is null",
    (("tests", "56kph", "speed_mps"), -15.5): "tests.56kph.speed_mps is -15.5",
    (("tests", "56kph", "energy", "impact_kinetic"), None): "tests.56kph.energy.impact_kinetic is None",
    (("std_errors", "vehicle.crush_offset"), -0.09): "std_errors.vehicle.crush_offset is -0.09",
    (("parameters", "vehicle.pitch_inertia"), -4800.0): "parameters.vehicle.pitch_inertia is -4800.0, where identified_model",
    (("parameters", "vehicle.crush_offset"), 0.05): "parameters.vehicle.crush_offset is 0.05, where identified_model has 0.",
    (("parameters", "vehicle.crush_offset"), float("nan")): "parameters.vehicle.crush_offset is NaN",
    (("parameters", "model.spring.values", 1), "abc"): 'parameters.model.spring.values is [0.0, "abc", ',
    (("parameters", "vehicle.foo"), 1.0): "parameters.vehicle.foo is 1.0, where identified_model has no such entry",
}


@pytest.mark.parametrize(("edit", "why"), EDITED_ELSEWHERE.items())
def test_a_result_edited_past_its_model_is_one_line_to_every_command_that_reads_it(fit, tmp_path, capsys, edit, why):
    """A fit's result.json edited by hand where a prediction's intervals, notes or impact, an
    export's pulse or a report's table read it (the identified model's covariance, range,
    discrepancy, RMSE, labels, filter or damper; the status; a test's speed or impact energy; a
    standard error): every command that reads the folder refuses it alike, naming the result.json
    and the entry, exit 2, and writes nothing (no pulse at a negative speed, no interval shifted by
    a negative variance, no null status read as converged); a prediction of another problem from
    it (--params) too, where it reads the entry."""
    folder = _edited(fit, tmp_path, *edit)
    before = sorted(tmp_path.rglob("*"))
    commands = _reading_the_folder(folder, tmp_path)
    if edit[0][0] in (IDENTIFIED, "status"):
        problem, params = str(ROOT / "problems/pickup-40kph.yaml"), str(folder / "result.json")
        commands.append(["simulate", problem, "--params", params, "--out", str(tmp_path / "sim"), "--no-figures"])
    for command in commands:
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"crashnlp: error: {folder / 'result.json'}: {why}"), (command, err)
        assert err.count("\n") == 1
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.integration
@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_a_response_with_a_value_that_is_not_a_number_is_refused_by_the_pulse(prediction, tmp_path, capsys, bad):
    """A simulation's response.csv with nan (or inf) in a row of its acceleration: the pulse
    export names the file, the column and the row, exit 2, and writes no pulse of nan samples."""
    folder = tmp_path / "sim"
    shutil.copytree(prediction, folder)
    lines = (folder / "40kph/response.csv").read_text().splitlines()
    head = lines[0].split(",")
    row = lines[30].split(",")
    row[head.index("accel_g")] = bad
    lines[30] = ",".join(row)
    (folder / "40kph/response.csv").write_text("\n".join(lines) + "\n")
    before = sorted(tmp_path.rglob("*"))
    assert main(["export", str(folder), "--format", "pulse"]) == 2
    err = capsys.readouterr().err
    said = f"{folder / '40kph/response.csv'}: accel_g is {bad} in data row 30: not a response crashnlp wrote"
    assert err == f"crashnlp: error: {said}\n"
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.integration
@pytest.mark.parametrize("bad", ["abc", "empty"])
def test_a_response_that_does_not_read_is_refused_alike_by_every_command_that_reads_it(fit, prediction, tmp_path, capsys, bad):
    """A cell "abc" in a fit's response.csv: the report and compare-results took it silently
    (as nan) where the export refused it; an empty response.csv was blamed on result.json
    (IndexError). One reader serves them all: one line naming the response.csv, exit 2."""
    folder = tmp_path / "fit"
    shutil.copytree(fit, folder)
    response = folder / "56kph/response.csv"
    lines = response.read_text().splitlines()
    lines[30] = lines[30].replace(lines[30].split(",")[1], "abc", 1)
    response.write_text("" if bad == "empty" else "\n".join(lines) + "\n")
    said = "empty" if bad == "empty" else "'abc' in data row 30"
    out = tmp_path / "out"
    for command in (
        ["report", str(folder), "--out", str(out / "report.html")],
        ["compare-results", str(folder), str(prediction), "--out", str(out / "compare")],
        ["export", str(folder), "--format", "pulse", "--out", str(out / "pulse.csv")],
        ["simulate", str(folder), "--out", str(out / "sim"), "--no-figures"],
    ):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"crashnlp: error: {response}: ") and said in err and err.count("\n") == 1, (command, err)
        assert not out.exists()


def test_a_figure_names_a_test_once():
    assert named_test("v10146", "v10146") == "v10146" and named_test("pickup-56kph", "56kph") == "pickup-56kph"
    assert named_test("pickup-joint", "40kph") == "pickup-joint, test 40kph"


@pytest.mark.integration
@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["report", "--out", "{tmp}"], "is a folder; name the file to write"),
        (["export", "--format", "ls-dyna", "--out", "{tmp}"], "is a folder; name the file to write"),
        (["report", "--out", "{tmp}/new/dir/"], "--out {tmp}/new/dir/: a folder; name the file to write"),
        (["export", "--format", "ls-dyna", "--out", "{tmp}/new/"], "--out {tmp}/new/: a folder; name the file to write"),
        (["export", "--format", "pulse", "--out", "{tmp}/new/"], "--out {tmp}/new/: a folder; name the file to write"),
        (["export", "--format", "pulse", "--test", "nope"], "--test nope: {fit} has tests 56kph"),
        (["export", "--format", "pulse", "--rate", "0"], "--rate 0: must be a positive number of Hz"),
        (["export", "--format", "pulse", "--rate", "100 Hz"], "CFC 60 needs a sample rate above"),
        (["export", "--format", "pulse", "--rate", "10 kg"], "--rate 10 kg:"),
        (["export", "--format", "pulse", "--rate", "1e12"], "--rate 1e+12: faster than any crash record is sampled"),
        (["export", "--format", "xml"], "--format: invalid choice"),
        (["export", "--format", "pulse", "--rate", ""], "--rate : cannot read '' as a quantity"),
        (["export", "--format", "csv", "--rate", "20 kHz"], "--rate: an option of --format pulse; --format csv writes no"),
        (["export", "--format", "ls-dyna", "--cfc", "180"], "--cfc: an option of --format pulse; --format ls-dyna writes"),
        (["report", "--out", "{tmp}/a.html", "--out", "{tmp}/b.html"], "--out: given twice; give it once"),
        (["report", "--out", "{fit}/result.json"], "--out {fit}/result.json: is a file of the run identify "),
        (["export", "--format", "pulse", "--out", "{fit}/56kph/response.csv"], "response.csv: is a file of the run identify "),
    ],
)
def test_bad_options_are_one_line_exit_2_and_nothing_written(fit, tmp_path, capsys, options, message):
    before = sorted(fit.rglob("*"))
    argv = [options[0], str(fit), *(o.format(tmp=tmp_path, fit=fit) for o in options[1:])]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.format(fit=fit, tmp=tmp_path) in err, err
    assert sorted(fit.rglob("*")) == before and not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "options",
    [["report"], ["export", "--format", "pulse"], ["export", "--format", "ls-dyna"]],
)
def test_an_out_that_is_a_file_crashnlp_did_not_write_as_that_output_is_refused(fit, tmp_path, capsys, options):
    """A problem file, a test's data, another kind of output, the command's own output edited (a
    deck the curves were pasted into) at --out is refused whole; the command's own earlier output
    there, untouched, is written again."""
    out = tmp_path / "out"
    argv = [options[0], str(fit), *options[1:], "--out", str(out)]
    assert main(argv) == 0 and main(argv) == 0
    other = ["report"] if options[0] == "export" else ["export", "--format", "pulse"]
    ours = tmp_path / "ours"
    assert main([other[0], str(fit), *other[1:], "--out", str(ours)]) == 0
    capsys.readouterr()
    problem = ROOT / "problems/pickup-56kph.yaml"
    data = problem.parent / yaml.safe_load(problem.read_text())["tests"][0]["data"]["file"]
    edited = tmp_path / "edited"
    edited.write_bytes(b"*KEYWORD\n$ the user's own line\n" + out.read_bytes() + b"*PART\n")
    for source in (problem, data, ours, edited):
        target = tmp_path / "target"
        shutil.copyfile(source, target)
        assert main([*argv[:-1], str(target)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--out {target}: exists" in err, err
        assert target.read_bytes() == source.read_bytes()


def test_the_csv_export_writes_over_none_of_a_users_own_files(fit, tmp_path, capsys):
    """A folder holding the user's own loading.csv and curves-notes.txt: the CSV export wrote over
    both. A file crashnlp did not write there, or edited since, is refused, one line naming it,
    nothing written; the export's own folder is written again."""
    out = tmp_path / "curves"
    argv = ["export", str(fit), "--format", "csv", "--out", str(out)]
    assert main(argv) == 0 and main(argv) == 0
    capsys.readouterr()
    for name in ("loading.csv", "curves-notes.txt"):
        mine = tmp_path / "mine"
        mine.mkdir()
        (mine / name).write_text("crush_m,force_N\n0,0\n")
        assert main([*argv[:-1], str(mine)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--out {mine / name}: exists" in err, err
        assert [p.name for p in mine.iterdir()] == [name] and (mine / name).read_text() == "crush_m,force_N\n0,0\n"
        shutil.rmtree(mine)
    with open(out / "loading.csv", "a") as fh:
        fh.write("1,1\n")
    assert main(argv) == 2 and f"--out {out / 'loading.csv'}: exists" in capsys.readouterr().err


def test_a_folder_where_the_csv_export_writes_a_curve_is_refused_before_any_curve(fit, tmp_path, capsys):
    """A folder named damper.csv in the export's folder had left loading.csv and unloading.csv
    written before the export failed on it: it is refused first, one line, nothing written."""
    out = tmp_path / "curves"
    (out / "damper.csv").mkdir(parents=True)
    assert main(["export", str(fit), "--format", "csv", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / 'damper.csv'} is a folder where crashnlp writes a file" in err, err
    assert [p.name for p in out.iterdir()] == ["damper.csv"]


@pytest.mark.integration
def test_a_result_folder_missing_a_response_names_it(fit, tmp_path, capsys):
    folder = tmp_path / "copy"
    folder.mkdir()
    (folder / "result.json").write_bytes((fit / "result.json").read_bytes())
    assert main(["report", str(folder)]) == 2
    err = capsys.readouterr().err
    assert f"{folder / 'result.json'}: does not read as crashnlp writes it" in err and "response.csv" in err
    assert not (folder / "report.html").exists()


@pytest.mark.integration  # a process of its own
def test_the_report_and_a_result_read_back_import_neither_casadi_nor_matplotlib():
    code = "import sys, crashnlp.report, crashnlp.report.folders; print(sorted({'casadi', 'matplotlib'} & set(sys.modules)))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "[]"


@pytest.mark.skipif(not (shutil.which("chromium") and shutil.which("pdftotext")), reason="headless Chromium and poppler")
def test_a_studys_wide_table_prints_whole(tmp_path):
    """A study's table of two swept entries, IPOPT's status, every predicted metric of a test and a
    multiplier, printed by headless Chromium: its last column is on the page (the print cut the
    table at the page's right edge after the first metric)."""
    store = CaseStore(tmp_path / "study" / "cases")
    multipliers = [-4.953, -2.562, -1.031, -0.517]
    for case, (pitch, k) in enumerate([("4 deg", "50 kN/m"), ("8 deg", "50 kN/m"), ("4 deg", "90 kN/m"), ("8 deg", "90 kN/m")]):
        row = study_row(case, pitch, k) | {"return_status": "Solved_To_Acceptable_Level"}
        row |= {f"56kph.{m.key}": 1.0 + case for m in PREDICTED} | {"multiplier.56kph.bound.pitch.upper": multipliers[case]}
        store.save(f"case-{case:03d}", "key", row, None)
    assert main(["report", str(tmp_path / "study")]) == 0
    pdf = tmp_path / "study.pdf"
    flags = ("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking")
    page = (tmp_path / "study" / "report.html").as_uri()
    subprocess.run(["chromium", *flags, f"--print-to-pdf={pdf}", page], capture_output=True, timeout=120, check=True)
    printed = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    last = re.findall(r"<td[^>]*>([^<]*)</td></tr>", (tmp_path / "study" / "report.html").read_text(encoding="utf-8"))
    assert len(last) == len(multipliers) and set(last) <= set(printed.split())


def test_a_what_ifs_console_line_names_the_speed_and_mass_it_ran_at(fit, tmp_path, capsys):
    """`crashnlp simulate FIT --speed "64 km/h" --mass ...` of the pickup's 56kph test: its
    metrics' line names the speed and mass simulation.json records, as its figure's title does
    (it named the test alone, which says 56 km/h)."""
    out = tmp_path / "what-if"
    assert main(["simulate", str(fit), "--speed", "64 km/h", "--mass", "2300 kg", "--out", str(out), "--no-figures"]) == 0
    ran = json.loads((out / "simulation.json").read_text())["tests"]["56kph"]
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("56kph") and "max displacement" in x)
    said = line.split(": max displacement")[0]
    assert f"{ran['speed_mps'] * 3.6:.1f} km/h" in said and f"{ran['mass_kg']:.0f} kg" in said
