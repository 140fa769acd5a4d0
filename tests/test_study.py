"""Constraint what-if studies: monotone costs, executors agree, resume, failures, bad study files."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, merge

from crashnlp.case import Case
from crashnlp.errors import InputError
from crashnlp.problem import problem_from_dict
from crashnlp.studies import load_study, run_study
from crashnlp.studies.plan import case_indices, plan_cases, warm_start_plan

PITCH = "constraints.bounds.pitch"
BOUNDS = [[None, "2 deg"], [None, "2.5 deg"], [None, "3 deg"], [None, "4 deg"]]  # the free fit pitches ~3.2 deg


def truth() -> dict:
    return merge(
        BASE,
        {
            "name": "small",
            "vehicle": {"crush_offset": 0.15},
            "model": {"spring": {"crush_breakpoints": [0, 0.2, 0.4, 0.7], "values": [0.0, 380e3, 520e3, 900e3]}},
            "tests": [{"name": "t56", "duration": 0.12}],
            "simulation": {"dt": 2e-4},
        },
    )


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """A small identification problem (40 intervals, < 1 s a solve) with synthetic data, as fit.yaml."""
    folder = tmp_path_factory.mktemp("small")
    r = Case(problem_from_dict(truth(), folder)).simulate()["t56"]
    noise = np.random.default_rng(3).standard_normal((3, r.time.size))
    columns = {
        "time_s": r.time,
        "accel_g": r["accel"] / 9.80665 + 0.5 * noise[0],
        "disp_m": r["displacement"] + 0.001 * noise[1],
        "pitch_deg": np.degrees(r["pitch"]) + 0.05 * noise[2],
    }
    with (folder / "data.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(zip(*columns.values()))
    channels = {
        "accel": {"column": "accel_g", "unit": "g", "sigma": "0.5 g"},
        "displacement": {"column": "disp_m", "unit": "m", "sigma": 0.001},
        "pitch": {"column": "pitch_deg", "unit": "deg", "sigma": "0.05 deg"},
    }
    fit = merge(
        truth(),
        {
            "model": {"spring": {"values": ["500 kN"] * 4}},
            "vehicle": {"crush_offset": 0.1},
            "tests": [{"name": "t56", "data": {"file": "data.csv", "window": ["0 s", "0.12 s"], "channels": channels}}],
            "estimate": {"model.spring.values": {"bounds": ["0 kN", "3 MN"]}, "vehicle.crush_offset": {"bounds": [-0.3, 0.5]}},
            "transcription": {"method": "multiple-shooting", "intervals": 40, "substeps": 2},
        },
    )
    (folder / "fit.yaml").write_text(yaml.safe_dump(fit))
    return folder


def write_study(folder: Path, name: str = "small-study", **changes) -> Path:
    spec = {"name": name, "problem": "fit.yaml", "sweep": {PITCH: BOUNDS}, "mode": "grid", **changes}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def without_wall_time(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def read_table(path: Path) -> list[dict]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------------------- (1) the shipped study
@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    out = tmp_path_factory.mktemp("pitch-bound")
    rows = run_study(ROOT / "problems/studies/pitch-bound.yaml", out, workers=2, progress=False)
    return out, rows


def test_tighter_pitch_bound_never_fits_better(shipped):
    out, rows = shipped
    assert [r["status"] for r in rows] == ["ok"] * 4
    rows = sorted(rows, key=lambda r: r[f"{PITCH}_si"])
    objective = [r["objective"] for r in rows]
    assert all(a >= b * (1 - 1e-6) for a, b in zip(objective, objective[1:])), objective
    assert objective[0] > objective[-1]
    for r in rows:
        active = r["56kph.max_pitch_deg"] >= np.degrees(r[f"{PITCH}_si"]) - 1e-4
        multiplier = r["multiplier.56kph.bound.pitch.upper"]
        assert multiplier > 0 if active else multiplier == 0, r
    # tighter bound, dearer: the multiplier falls as the bound loosens
    active = [r["multiplier.56kph.bound.pitch.upper"] for r in rows if r["multiplier.56kph.bound.pitch.upper"] > 0]
    assert len(active) >= 2 and active == sorted(active, reverse=True)
    table = read_table(out / "table.csv")
    assert [t[PITCH] for t in table] == ["[null, 4 deg]", "[null, 6 deg]", "[null, 8 deg]", "[null, 10 deg]"]
    assert (out / "figures" / f"{PITCH}.png").is_file()


# --------------------------------------------------------------------------- the plan
def test_warm_start_plan_is_fixed_by_the_case_list():
    parent, wave = warm_start_plan([(0,), (1,), (2,), (3,)], [0, 3])
    assert parent == [None, 0, 3, None] and wave == [0, 1, 1, 0]
    grid = [(i, j) for i in range(3) for j in range(3)]
    parent, wave = warm_start_plan(grid, [0, 8])
    assert wave == [0, 1, 2, 1, 1, 1, 2, 1, 0]
    assert parent[4] == 0 and parent[1] == 0 and parent[2] == 1


def test_grid_and_zip_cases(small):
    grid = load_study(write_study(small, sweep={PITCH: BOUNDS[:2], "vehicle.mass": ["2400 kg", "2500 kg", 2600]}))
    assert case_indices(grid) == [(i, j) for i in range(2) for j in range(3)]
    assert [c.parent for c in plan_cases(grid)] == [None, 0, None, None, 3, None]
    zipped = load_study(write_study(small, mode="zip", sweep={PITCH: BOUNDS[:3], "vehicle.mass": [2400, 2500, 2600]}))
    assert [c.values for c in plan_cases(zipped)][1] == (BOUNDS[1], 2500)
    assert zipped.entries[0].si(BOUNDS[0]) == pytest.approx(np.radians(2))
    assert grid.entries[1].si("2.5 t") == pytest.approx(2500)


# --------------------------------------------------------------------------- (2) executors agree
def test_local_and_dask_executors_give_the_same_table(small, tmp_path):
    study = write_study(small)
    local = run_study(study, tmp_path / "local", executor="local", workers=2, progress=False)
    dask = run_study(study, tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert [r["status"] for r in local] == ["ok"] * 4
    assert [r["warm_start"] for r in local] == ["", "case-000", "case-003", ""]
    assert without_wall_time(local) == without_wall_time(dask)
    a, b = read_table(tmp_path / "local/table.csv"), read_table(tmp_path / "dask/table.csv")
    assert without_wall_time(a) == without_wall_time(b)


# --------------------------------------------------------------------------- (3) resume
def test_an_interrupted_study_resumes_without_redoing_finished_cases(small, tmp_path):
    study, out = write_study(small), tmp_path / "out"
    first = run_study(study, out, workers=2, progress=False)
    cases = out / "cases"
    stamp = {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")}
    for name in ("case-001", "case-002"):  # as if stopped after the seed wave
        (cases / f"{name}.json").unlink()
        (cases / f"{name}.npy").unlink()
    again = run_study(study, out, workers=2, progress=False)
    restamp = {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")}
    redone = {n for n in restamp if restamp[n] != stamp.get(n)}
    assert redone == {"case-001.json", "case-002.json"}
    assert without_wall_time(again) == without_wall_time(first)
    # nothing left to do: no solve at all, the same table
    run_study(study, out, executor="dask", address="tcp://127.0.0.1:1", progress=False)  # never connects
    assert {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")} == restamp


def test_a_changed_case_is_solved_again(small, tmp_path):
    out = tmp_path / "out"
    run_study(write_study(small, sweep={PITCH: BOUNDS[:2]}), out, workers=1, progress=False)
    stamp = {p.name: p.stat().st_mtime_ns for p in (out / "cases").glob("*.json")}
    rows = run_study(write_study(small, sweep={PITCH: [BOUNDS[0], BOUNDS[2]]}), out, workers=1, progress=False)
    restamp = {p.name: p.stat().st_mtime_ns for p in (out / "cases").glob("*.json")}
    assert restamp["case-000.json"] == stamp["case-000.json"] and restamp["case-001.json"] != stamp["case-001.json"]
    assert rows[1][PITCH] == "[null, 3 deg]"


# --------------------------------------------------------------------------- (4) failures
def test_a_failing_case_is_recorded_and_the_others_finish(small, tmp_path):
    sweep = {PITCH: BOUNDS, "solver.ipopt.max_iter": [1000, 1000, 0, 1000]}
    rows = run_study(write_study(small, mode="zip", sweep=sweep), tmp_path / "out", workers=2, progress=False)
    status = [r["status"] for r in rows]
    assert status[0] == "ok" and status[1] == "ok" and status[3] == "ok"
    assert status[2].startswith("solver failed")
    table = read_table(tmp_path / "out/table.csv")
    assert len(table) == 4 and table[2]["status"].startswith("solver failed")


def test_a_bad_swept_value_is_refused_before_any_solve(small, tmp_path):
    sweep = {PITCH: [BOUNDS[0], [None, "2 kg"], BOUNDS[2], BOUNDS[3]]}
    with pytest.raises(InputError, match=r"small-study.yaml: sweep: case-001 \(constraints.bounds.pitch = \[null, 2 kg\]\)"):
        run_study(write_study(small, mode="zip", sweep=sweep), tmp_path / "out", workers=2, progress=False)
    assert not (tmp_path / "out").exists()


def test_cli_refuses_a_bad_swept_value_with_exit_2_and_writes_nothing(small, tmp_path, capsys):
    from crashnlp.cli import main

    study = write_study(small, sweep={PITCH: [BOUNDS[0], [None, "x deg"]]})
    code = main(["study", str(study), "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "case-001" in err and "x deg" in err
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- bad study files
@pytest.mark.parametrize(
    "changes, message",
    [
        ({"sweeps": {}}, "sweeps: unknown key"),
        ({"sweep": {"constraints.bounds.pich": BOUNDS}}, "sweep.constraints.bounds.pich: not an entry"),
        ({"sweep": {"vehicle.mass.kg": [1]}}, "sweep.vehicle.mass.kg: not an entry"),
        ({"mode": "zip", "sweep": {PITCH: BOUNDS, "vehicle.mass": [1, 2]}}, "sweep: zip mode needs lists of the same length"),
        ({"problem": "missing.yaml"}, "problem: file not found"),
        ({"sweep": {PITCH: []}}, f"sweep.{PITCH}:"),
        ({"seeds": [9]}, "seeds:"),
    ],
)
def test_bad_study_file_is_one_line_naming_the_key(small, changes, message):
    study = write_study(small, name="bad", **changes)
    with pytest.raises(InputError) as err:
        run_study(study, small / "never", progress=False)
    text = str(err.value)
    assert text.startswith(str(study)) and message in text and "\n" not in text
    assert not (small / "never").exists()
