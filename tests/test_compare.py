"""crashnlp compare-results: fits and predictions on one set of axes, their metrics side by side,
checked against the folders they come from; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import csv
import html
import json
from pathlib import Path

import pytest
from builders import ROOT
from test_report import self_contained

from crashnlp.cli import main
from crashnlp.report.compare import FORCE_CRUSH, METRICS, PAGE, QUANTITIES

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


def test_speeds_side_by_side_give_a_figure_per_quantity_the_metrics_and_one_page(folders, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare-results", str(folders["48"]), str(folders["fit"]), str(folders["64"]), "--out", str(out)]) == 0
    console = capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == FIGURES | {METRICS, PAGE}
    with (out / METRICS).open() as fh:
        rows = list(csv.DictReader(fh))
    labels = [r["curve"] for r in rows]
    assert labels == [
        "pickup-56kph, predicted at 48.0 km/h",
        "pickup-56kph, fit at 56.0 km/h",
        "pickup-56kph, predicted at 64.0 km/h",
    ]
    fit = json.loads((folders["fit"] / "result.json").read_text())["tests"]["56kph"]["metrics"]["model"]
    assert float(rows[1]["max_crush_mm"]) == pytest.approx(fit["max_crush_m"] * 1e3) and rows[1]["max_crush_mm_low"] == ""
    for row, speed in ((rows[0], "48"), (rows[2], "64")):
        sim = json.loads((folders[speed] / "simulation.json").read_text())["tests"]["56kph"]
        assert float(row["peak_decel_g"]) == pytest.approx(sim["metrics"]["peak_decel_g"])
        assert float(row["peak_decel_g_low"]) == pytest.approx(sim["intervals"]["peak_decel_g"][0])
    assert float(rows[0]["max_crush_mm"]) < float(rows[1]["max_crush_mm"]) < float(rows[2]["max_crush_mm"])
    page = html.unescape((out / PAGE).read_text(encoding="utf-8"))
    assert len(self_contained(page)) == len(FIGURES)
    assert all(label in page and label in console for label in labels)
    assert f"{sim['metrics']['max_crush_m'] * 1e3:.1f} [" in page  # 64 km/h: value and interval in one cell


def test_two_fits_of_one_vehicle_are_told_apart_by_their_folders(folders, tmp_path):
    out = tmp_path / "cmp"
    assert main(["compare-results", str(folders["fit"]), str(folders["fit"]), "--out", str(out)]) == 0
    with (out / METRICS).open() as fh:
        labels = [r["curve"] for r in csv.DictReader(fh)]
    assert labels == [f"pickup-56kph, fit at 56.0 km/h ({folders['fit']})"] * 2


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
