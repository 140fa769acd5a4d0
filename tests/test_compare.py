"""crashnlp compare-results: fits and predictions on one set of axes, their metrics side by side,
checked against the folders they come from; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import csv
import html
import json
import shutil
from pathlib import Path

import pytest
from builders import ROOT
from test_report import self_contained

from crashnlp.cli import main
from crashnlp.report.compare import FORCE_CRUSH, METRICS, PAGE, QUANTITIES
from crashnlp.results.files import RECORD

pytestmark = pytest.mark.integration
FIGURES = {f"{name}.png" for name in QUANTITIES} | {FORCE_CRUSH}


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """The shipped pickup fitted, and its own test simulated at 48 and 64 km/h (a few seconds each)."""
    root = tmp_path_factory.mktemp("compare")
    fit = root / "fit"
    assert main(["identify", str(ROOT / "problems/pickup-56kph.yaml"), "--out", str(fit), "--no-figures"]) == 0
    out = {"fit": fit}
    for speed in ("48", "64"):
        out[speed] = root / f"sim{speed}"
        assert main(["simulate", str(fit), "--speed", f"{speed} km/h", "--out", str(out[speed]), "--no-figures"]) == 0
    return out


def test_a_simulation_of_a_fit_reads_its_result_json_once(folders, tmp_path, monkeypatch):
    """crashnlp simulate FIT: the parameters, the fit and the source's sha256 come from one read of
    its result.json (the bytes hashed are the bytes parsed)."""
    opened: list[Path] = []
    path_open = Path.open

    def counted(self: Path, *args, **kwargs):
        if self.name == "result.json":
            opened.append(self)
        return path_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", counted)
    assert main(["simulate", str(folders["fit"]), "--out", str(tmp_path / "sim"), "--no-figures"]) == 0
    assert opened == [folders["fit"] / "result.json"]


def test_speeds_side_by_side_give_a_figure_per_quantity_the_metrics_and_one_page(folders, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare-results", str(folders["48"]), str(folders["fit"]), str(folders["64"]), "--out", str(out)]) == 0
    console = capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == FIGURES | {METRICS, PAGE, RECORD}
    with (out / METRICS).open() as fh:
        rows = list(csv.DictReader(fh))
    labels = [r["curve"] for r in rows]
    assert labels == [
        "pickup-56kph, predicted at 48.0 km/h",
        "pickup-56kph, fit at 56.0 km/h",
        "pickup-56kph, predicted at 64.0 km/h",
    ]
    fit = json.loads((folders["fit"] / "result.json").read_text())["tests"]["56kph"]["metrics"]["model"]
    assert (
        float(rows[1]["max_displacement_mm"]) == pytest.approx(fit["max_displacement_m"] * 1e3)
        and rows[1]["max_displacement_mm_low"] == ""
    )
    for row, speed in ((rows[0], "48"), (rows[2], "64")):
        sim = json.loads((folders[speed] / "simulation.json").read_text())["tests"]["56kph"]
        assert float(row["peak_decel_g"]) == pytest.approx(sim["metrics"]["peak_decel_g"])
        assert float(row["peak_decel_g_low"]) == pytest.approx(sim["intervals"]["peak_decel_g"][0])
    assert float(rows[0]["max_displacement_mm"]) < float(rows[1]["max_displacement_mm"]) < float(rows[2]["max_displacement_mm"])
    page = html.unescape((out / PAGE).read_text(encoding="utf-8"))
    assert len(self_contained(page)) == len(FIGURES)
    assert all(label in page and label in console for label in labels)
    assert f"{sim['metrics']['max_displacement_m'] * 1e3:.1f} [" in page  # 64 km/h: value and interval in one cell
    assert "written by crashnlp compare-results:" in page  # the command that wrote it (it said crashnlp report)
    assert {r["accel_filter"] for r in rows} == {"CFC60"} and "peak decel (g, CFC60)" in page


def test_peaks_read_through_different_classes_each_name_their_own(folders):
    """One class for every curve heads the peak's row; where they differ, each cell names its own."""
    import dataclasses

    from crashnlp.report.compare import metric_table, read_curves

    (fit,) = read_curves(folders["fit"])
    raw = dataclasses.replace(fit, response=dataclasses.replace(fit.response, accel_filter=None))
    (same,) = [row for row in metric_table([fit, fit])[1] if row[0].startswith("peak decel")]
    assert same[0] == "peak decel (g, CFC60)" and same[1] == same[2] and "(" not in same[1]
    rows = metric_table([fit, raw])[1]
    (mixed,) = [row for row in rows if row[0].startswith("peak decel")]
    assert mixed[0] == "peak decel (g)" and mixed[1].endswith(" (CFC60)") and mixed[2].endswith(" (unfiltered)")
    assert all(row[1] == row[2] for row in rows if row is not mixed)


def test_two_fits_of_one_vehicle_are_told_apart_by_their_folders(folders, tmp_path):
    out = tmp_path / "cmp"
    assert main(["compare-results", str(folders["fit"]), str(folders["fit"]), "--out", str(out)]) == 0
    with (out / METRICS).open() as fh:
        labels = [r["curve"] for r in csv.DictReader(fh)]
    assert labels == [f"pickup-56kph, fit at 56.0 km/h ({folders['fit']})"] * 2


def curve_labels(folders: list[Path], out: Path) -> list[str]:
    """compare-results of `folders` into `out`: the labels of its curves in metrics.csv, checked to be
    those of its page."""
    assert main(["compare-results", *map(str, folders), "--out", str(out)]) == 0
    with (out / METRICS).open() as fh:
        labels = [r["curve"] for r in csv.DictReader(fh)]
    page = html.unescape((out / PAGE).read_text(encoding="utf-8"))
    assert all(label in page for label in labels)
    return labels


def test_a_what_if_of_the_mass_names_its_mass(folders, tmp_path):
    """A prediction at another mass than the fitted one says its mass, beside the fit (whose mass
    it then says too) and beside another prediction at that mass; it was labelled as if it ran
    at the fitted conditions. Curves at the fitted mass say none (the speeds above)."""
    light, light48 = tmp_path / "light", tmp_path / "light48"
    assert main(["simulate", str(folders["fit"]), "--mass", "1500 kg", "--out", str(light), "--no-figures"]) == 0
    what_if = ["--mass", "1500 kg", "--speed", "48 km/h"]
    assert main(["simulate", str(folders["fit"]), *what_if, "--out", str(light48), "--no-figures"]) == 0
    mass = 2.0 * json.loads((folders["fit"] / "result.json").read_text())["tests"]["56kph"]["energy"]["impact_kinetic"]
    mass /= (56 / 3.6) ** 2
    assert curve_labels([folders["fit"], light], tmp_path / "a") == [
        f"pickup-56kph, fit at 56.0 km/h, {mass:.0f} kg",
        "pickup-56kph, predicted at 56.0 km/h, 1500 kg",
    ]
    assert curve_labels([light, light48], tmp_path / "b") == [
        "pickup-56kph, predicted at 56.0 km/h, 1500 kg",
        "pickup-56kph, predicted at 48.0 km/h, 1500 kg",
    ]


def test_a_fit_that_did_not_converge_and_a_prediction_from_it_say_so(folders, tmp_path):
    """A fit IPOPT stopped, and a prediction from its values, are labelled with its status (in the
    words of its report and exports) on the page, the legend and metrics.csv; a converged fit is not."""
    failed, predicted = tmp_path / "failed", tmp_path / "predicted"
    shutil.copytree(folders["fit"], failed)
    raw = json.loads((failed / "result.json").read_text())
    status = "solver failed: Maximum_Iterations_Exceeded"
    (failed / "result.json").write_text(json.dumps({**raw, "status": status}))
    assert main(["simulate", str(failed), "--speed", "48 km/h", "--out", str(predicted), "--no-figures"]) == 0
    said = f" (NOT CONVERGED: the fit ended {status})"
    assert curve_labels([folders["fit"], failed, predicted], tmp_path / "cmp") == [
        "pickup-56kph, fit at 56.0 km/h",
        f"pickup-56kph, fit at 56.0 km/h{said}",
        f"pickup-56kph, predicted at 48.0 km/h{said}",
    ]


# the keys of the CG's travel as crashnlp wrote them before issue 40 named it displacement
OLD_METRICS = {"max_displacement_m": "max_crush_m", "time_max_displacement_s": "time_max_crush_s"}
OLD_EXTRAPOLATION = {"displacement_m": "crush_m", "displacement_rel": "crush_rel"}


def _renamed(doc, names: dict[str, str]):
    if isinstance(doc, dict):
        return {names.get(k, k): _renamed(v, names) for k, v in doc.items()}
    return [_renamed(v, names) for v in doc] if isinstance(doc, list) else doc


def written_before_the_rename(folder: Path, copy: Path) -> Path:
    """A copy of a fit's or a simulation's folder with its result.json or simulation.json as
    crashnlp wrote them before the rename: metrics, intervals and range under the old keys."""
    shutil.copytree(folder, copy)
    for path in (copy / "result.json", copy / "simulation.json"):
        if path.exists():
            doc = _renamed(json.loads(path.read_text()), OLD_METRICS)
            for test in doc["tests"].values():
                if "extrapolation" in test:
                    test["extrapolation"] = _renamed(test["extrapolation"], OLD_EXTRAPOLATION)
            path.write_text(json.dumps(doc))
    return copy


def test_folders_written_before_the_rename_read_as_written_now(folders, tmp_path):
    old = {k: written_before_the_rename(folders[k], tmp_path / f"old-{k}") for k in ("fit", "64")}
    fit, sim = ((old[k] / name).read_text() for k, name in (("fit", "result.json"), ("64", "simulation.json")))
    assert '"max_crush_m"' in fit and '"max_displacement_m"' not in fit and '"crush_rel"' in sim  # the old format
    tables = {}
    for which, given in (("now", folders), ("before", old)):
        out = tmp_path / f"cmp-{which}"
        assert main(["compare-results", str(given["fit"]), str(given["64"]), "--out", str(out)]) == 0
        with (out / METRICS).open() as fh:
            tables[which] = [{k: v for k, v in row.items() if k not in ("curve", "folder")} for row in csv.DictReader(fh)]
        # a prediction from each fit's result.json: the old one's identified range reads as the new one's
        problem, params = ROOT / "problems/pickup-40kph.yaml", given["fit"] / "result.json"
        assert (
            main(["simulate", str(problem), "--params", str(params), "--out", str(tmp_path / f"sim-{which}"), "--no-figures"])
            == 0
        )
    assert tables["before"] == tables["now"] and float(tables["now"][1]["max_displacement_mm_high"]) > 0
    predicted = [json.loads((tmp_path / f"sim-{w}" / "simulation.json").read_text())["tests"] for w in ("now", "before")]
    assert predicted[0] == predicted[1]
    assert main(["report", str(old["64"])]) == 0  # the extrapolation under its old keys
    page = html.unescape((old["64"] / "report.html").read_text(encoding="utf-8"))
    assert "extrapolates: max displacement" in page


@pytest.mark.parametrize(
    ("make", "message"),
    [
        ("one", "1 folder given: give two or more"),
        ("empty", "holds no result.json, simulation.json or cases/"),
        ("study", "a study's folder: compare fits or simulations"),
        ("missing", "no such folder"),
    ],
)
def test_bad_folders_are_one_line_exit_2_and_nothing_written(folders, tmp_path, capsys, make, message):
    other = tmp_path / "other"
    if make in ("empty", "study"):
        other.mkdir()
    if make == "study":
        (other / "cases").mkdir()
    given = [folders["fit"]] + ([] if make == "one" else [other])
    out = tmp_path / "cmp"
    before = sorted(tmp_path.rglob("*"))
    assert main(["compare-results", *map(str, given), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert sorted(tmp_path.rglob("*")) == before


def test_a_comparison_into_another_runs_folder_is_refused_and_into_its_own_written_again(folders, tmp_path, capsys):
    """One run per output folder: a comparison into a fit's folder would write over its figures
    (force_crush.png); it is refused as every command refuses it, and one into its own folder
    again replaces it."""
    fit = tmp_path / "fit"
    shutil.copytree(folders["fit"], fit)
    before = {p: p.read_bytes() for p in fit.rglob("*") if p.is_file()}
    assert main(["compare-results", str(folders["48"]), str(folders["64"]), "--out", str(fit)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--out {fit}: holds the results of another run (identify pickup-56kph)" in err, err
    assert {p: p.read_bytes() for p in fit.rglob("*") if p.is_file()} == before
    out = tmp_path / "cmp"
    for _ in range(2):
        assert main(["compare-results", str(folders["48"]), str(folders["64"]), "--out", str(out)]) == 0


def test_the_api_takes_the_params_files_the_command_takes_and_refuses_the_same(folders, tmp_path, capsys):
    """`crashnlp.simulate(params=...)` reads a result.json as `crashnlp simulate --params` does
    (crashnlp.results.params): the file of any name or its folder, its source the sha256 of that
    file; a folder without result.json is the same one line (InputError) in both."""
    import crashnlp
    from crashnlp.base.errors import InputError
    from crashnlp.results.files import file_sha256

    fit = shutil.copytree(folders["fit"], tmp_path / "fit")
    shutil.copy(fit / "result.json", tmp_path / "myfit.json")
    problem = ROOT / "problems/pickup-40kph.yaml"
    for given in (fit, fit / "result.json", tmp_path / "myfit.json"):
        test = next(iter(crashnlp.simulate(problem, params=given).values()))
        assert test.source["result"]["sha256"] == file_sha256(fit / "result.json")
        assert test.source["result"]["path"] == str(given)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError) as api:
        crashnlp.simulate(problem, params=empty)
    out = tmp_path / "o"
    assert main(["simulate", str(problem), "--params", str(empty), "--out", str(out)]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {api.value}\n" and str(empty) in str(api.value)
    assert not out.exists()


def test_the_force_crush_band_says_it_is_the_predictions_band_at_each_instant(folders, tmp_path, monkeypatch):
    """compare-results' force_crush.png of a fit and a prediction: the banded curve's legend and a
    note under the axes say the band is the barrier force's at each instant, not the loading
    curve's (a crash engineer read it as the loading curve unknown where it was measured); the
    fit's curve, without a band, says nothing of one."""
    from crashnlp.results import plots

    drawn: dict[str, object] = {}
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (drawn.setdefault(path.name, fig), save(fig, path)))
    assert main(["compare-results", str(folders["fit"]), str(folders["64"]), "--out", str(tmp_path / "cmp")]) == 0
    fig = drawn[FORCE_CRUSH]
    fitted, predicted = (t.get_text() for t in fig.axes[0].get_legend().get_texts())
    assert "band" not in fitted and "barrier force at each instant" in predicted
    assert any("loading curve" in t.get_text() for t in fig.texts)
    assert not drawn["accel.png"].texts  # a band over time is the quantity's own: no note


def test_the_acceleration_figure_names_the_cfc_class_the_metric_table_names(folders, tmp_path, monkeypatch):
    """compare-results' accel.png heads its axis as the page's metric table heads the peak: the CFC
    class the curves' accelerations were read through (it said "acceleration (g)")."""
    from crashnlp.results import plots

    drawn: dict[str, object] = {}
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (drawn.setdefault(path.name, fig), save(fig, path)))
    out = tmp_path / "cmp"
    assert main(["compare-results", str(folders["fit"]), str(folders["64"]), "--out", str(out)]) == 0
    with (out / METRICS).open() as fh:
        (cfc,) = {r["accel_filter"] for r in csv.DictReader(fh)}
    assert cfc and drawn["accel.png"].axes[0].get_ylabel().endswith(f", {cfc})")
