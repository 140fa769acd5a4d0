"""The load-cell barrier: summed wall force, channel status honoured, the shipped barrier fit."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from builders import ROOT

from bench.common import PROBLEMS, fine_outputs, fit_targets, judge_fit, load_case
from crashnlp.cli import main
from crashnlp.data.load import load_test_data
from crashnlp.data.nhtsa_ev5 import Curve, flat_after_impact, read_header, valid_until
from crashnlp.init import ev5_draft
from crashnlp.problem.schema import DataSpec

EV5 = ROOT / "problems" / "data" / "nhtsa-10146" / "v10146.EV5"
CELLS = [n for n in range(107, 633, 3)]
DEAD = (347, 500)
FLAT = (260, 287)  # loaded cells (H-04, H-13) made dead in `flat_copy`, the header left as it is
HELD = -2.250860  # N: the value cell 347's dead converter holds most of the time


def _load(channels: dict, **data) -> object:
    return load_test_data(DataSpec.model_validate({"file": EV5, "format": "nhtsa-ev5", "channels": channels, **data}))


def _file(number: int) -> np.ndarray:
    return np.loadtxt(EV5.with_suffix(f".{number:03d}"))


def test_every_valid_cell_is_the_sum_of_the_174_files_read_one_by_one():
    data = _load({"barrier_force": {"curves": "all-valid-barrier-fx", "sign": -1, "filter": None}})
    wall = data.channels["barrier_force"]
    valid = [n for n in CELLS if n not in DEAD]
    assert len(valid) == 174
    expected = -sum(_file(n)[:, 1] for n in valid)
    np.testing.assert_allclose(wall.values, expected, rtol=1e-12, atol=1e-6)
    (note,) = [n for n in data.notes if "summed" in n]
    assert "174 barrier Fx load cells summed" in note and "347" in note and "500" in note
    assert any("SAE J211" in n and "no CFC" in n for n in data.notes)  # filter: null, said beside J211's CFC 60


@pytest.fixture
def flat_copy(tmp_path):
    """The Camry's EV5 in a folder of its own, cells FLAT holding HELD throughout (the other curves linked)."""
    folder = tmp_path / "ev5"
    folder.mkdir()
    for file in EV5.parent.iterdir():
        (folder / file.name).symlink_to(file)
    (folder / EV5.name).unlink()
    shutil.copy(EV5, folder / EV5.name)
    for number in FLAT:
        cell = folder / f"v10146.{number:03d}"
        time = _file(number)[:, 0]
        cell.unlink()
        cell.write_text("".join(f"{t:.6f}\t{HELD:.6f}\n" for t in time))
    return folder / EV5.name


def test_cells_flat_after_impact_are_left_out_and_named_though_the_header_marks_them_valid(flat_copy):
    data = _load({"barrier_force": {"curves": "all-valid-barrier-fx", "sign": -1, "filter": None}}, file=flat_copy)
    live = [n for n in CELLS if n not in DEAD + FLAT]
    np.testing.assert_allclose(data.channels["barrier_force"].values, -sum(_file(n)[:, 1] for n in live), rtol=1e-12, atol=1e-6)
    (note,) = [n for n in data.notes if "summed" in n]
    assert "172 barrier Fx load cells summed" in note and "347 (CF:" in note and "500 (CF:" in note
    assert "260 (flat after impact, 1 distinct value: BARRIER H-04 Fx)" in note and "287 (flat after impact" in note


def _refused_cells(header: Path, curves: list[int], tmp_path: Path, capsys) -> str:
    """The shipped barrier problem reading `curves` of the EV5 test at `header`: identify exits 2
    with one line and no traceback, writes nothing, and that line is returned."""
    problem = yaml.safe_load((ROOT / "problems" / "nhtsa-10146-barrier.yaml").read_text())
    problem["tests"][0]["data"]["file"] = str(header)
    problem["tests"][0]["data"]["channels"]["barrier_force"] = {"curves": curves, "sign": -1}
    path = tmp_path / "cells.yaml"
    path.write_text(yaml.safe_dump(problem))
    out = tmp_path / "out"
    assert main(["identify", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()
    return err


def test_a_flat_cell_named_explicitly_exits_2_naming_file_and_curve(flat_copy, tmp_path, capsys):
    err = _refused_cells(flat_copy, [257, 260], tmp_path, capsys)
    assert "v10146.260" in err and "curve 260" in err and "dead (flat after impact" in err


def test_init_counts_the_flat_cells_with_the_marked_ones(flat_copy):
    comment = ev5_draft(flat_copy).comments["barrier_force"]
    assert "sum of the 172 valid load cells, 2 marked not valid and 2 flat after impact left out" in comment
    assert "sum of the 174 valid load cells, 2 marked not valid left out," in ev5_draft(EV5).comments["barrier_force"]


def test_the_shipped_dead_cells_are_flat_and_every_other_cell_is_not():
    """The criterion on the Camry's files: its two dead cells' converters flicker between a few
    counts (their files are never read for a fit: the header marks them), every other cell moves."""
    _, curves = read_header(EV5)
    flat = [n for n in CELLS if flat_after_impact(curves[n], *_file(n).T)]
    assert flat == list(DEAD)


def test_the_wall_force_is_filtered_at_cfc60_and_its_offset_removed_by_default():
    raw = _load({"barrier_force": {"curves": [107, 110], "sign": -1, "filter": None}})
    default = _load({"barrier_force": {"curves": [107, 110], "sign": -1}}, bias_window=[-0.05, 0.0])
    t, f = default.channels["barrier_force"].time, default.channels["barrier_force"].values
    assert abs(np.mean(f[t <= 0])) < 1.0  # N: the pre-impact mean is gone
    assert np.max(np.abs(np.diff(f))) < np.max(np.abs(np.diff(raw.channels["barrier_force"].values)))
    assert any("CFC60, the SAE J211 class" in n for n in default.notes)


def test_a_dead_cell_named_explicitly_exits_2_naming_file_and_curve(tmp_path, capsys):
    err = _refused_cells(EV5, [347], tmp_path, capsys)
    assert "v10146.347" in err and "curve 347" in err and "not valid" in err


def test_a_curve_valid_to_67_ms_is_never_read_past_it():
    engine = _load({"accel": {"curves": [96]}}).channels["accel"]
    assert engine.time[-1] <= 0.067 + 1e-9
    assert _file(96)[-1, 0] <= 0.067 + 1e-9  # the shipped file stops there too; the header alone decides


@pytest.mark.parametrize(
    ("status", "comment", "until"),
    [
        ("AM", "BARRIER K-01 Fx", np.inf),
        ("CF", "BARRIER F-01 Fx: No valid data", None),
        ("CF", "BOTTOM OF ENGINE X: No valid data after 67ms", 0.067),
        ("CF", "", None),
        ("NO", "DRIVER LAP BELT: Not installed", None),
        ("AM", "DRIVER LAP BELT: Not installed", None),
    ],
)
def test_status_and_comment_say_how_far_a_curve_is_valid(status, comment, until):
    curve = Curve(1, 1, "", "XG", "NWT", -500, 2999, 1e-4, status, comment)
    assert valid_until(curve) == until


def test_the_benchmarks_judge_rates_a_fitted_wall_force_in_the_channels_report_units():
    """bench/common.judge_fit on a problem that fits the barrier force: every fitted channel rated,
    each in its report unit (result.json's), the acceleration in g."""
    case = load_case(PROBLEMS / "nhtsa-10146-barrier.yaml")
    targets = fit_targets(case)
    rmse = judge_fit(case, case.base, targets)["rmse"]
    assert {k: r["unit"] for k, r in rmse.items()} == {"10146.accel": "g", "10146.velocity": "m/s", "10146.barrier_force": "N"}
    accel = next(t for t in targets if t.channel == "accel")
    miss = fine_outputs(case, case.base)[0]["accel"][accel.columns] - accel.data
    assert rmse["10146.accel"]["rmse"] == pytest.approx(np.sqrt(np.mean(miss**2)) / 9.80665)
