"""`crashnlp init`: problem files from EV5, CSV and ISO-MME data that identify as they stand."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
import yaml
from builders import ROOT
from test_readers import CODE_X, _mme_set, channel_export, offset_ev5

from bench.corpus import random_vehicle, simulate, write_csv
from crashnlp.base.errors import InputError
from crashnlp.cli import _print_solution, main
from crashnlp.data.csv_reader import Table
from crashnlp.data.load import load_test_data
from crashnlp.init import Options, _csv_columns, _data_spec, csv_draft, draft_for, init_problem, mme_draft, unit_in_name
from crashnlp.problem import load_problem

EV5 = ROOT / "problems" / "data" / "nhtsa-10146" / "v10146.EV5"
CAMRY_DATA = {"crush_mm": 746.0, "stop_ms": 73.96}  # the data's own metrics (README)


def _identify(problem_file, out) -> dict:
    assert main(["identify", str(problem_file), "--out", str(out)]) == 0
    return json.loads((out / "result.json").read_text())


@pytest.mark.integration
def test_init_on_the_ev5_reproduces_the_camry_fit(tmp_path):
    out = tmp_path / "camry.yaml"
    assert main(["init", str(EV5), "--out", str(out)]) == 0
    text = out.read_text()
    assert "mass: 1719 kg" in text and "VEHTWT" in text and "57.09 km/h" in text
    assert "curves: [93, 94]" in text and "REAR SEAT CROSSMEMBER" in text
    assert "# barrier_force: {curves: all-valid-barrier-fx, sign: -1}" in text and "174 valid load cells" in text
    assert "cg_to_front_axle: 1.246 m" in text and "cg_to_impact: 2.219 m" in text and "estimate" in text
    (test,) = _identify(out, tmp_path / "res")["tests"].values()
    model = test["metrics"]["model"]
    assert model["max_displacement_m"] * 1e3 == pytest.approx(CAMRY_DATA["crush_mm"], rel=0.02)
    assert abs(model["time_zero_velocity_s"] * 1e3 - CAMRY_DATA["stop_ms"]) <= 2.0


def test_init_removes_an_accelerometer_offset_before_impact(tmp_path):
    """init sets the bias window before it reads the data, which refuse an offset no window
    removes: test 10146 plus 3 g gets its window, and its crush as the shipped test's."""
    out = tmp_path / "camry.yaml"
    assert main(["init", str(offset_ev5(tmp_path / "off")), "--out", str(out)]) == 0
    assert "bias_window: [-0.05 s, 0 s]" in out.read_text() and "to 746 mm" in out.read_text()


def test_init_writes_a_bias_window_over_as_little_record_before_impact_as_an_offset_is_refused_on(tmp_path):
    """The pickup's 56 km/h record with 7 ms at its speed put before impact and 0.5 g on its
    accelerometer: the data refuse an offset over 5 ms or more of such record that no window
    removes, so init writes the window over those 7 ms (it wrote none under 10 ms, and could
    write no problem)."""
    data = np.genfromtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", names=True)
    before = np.arange(-70, 0) * 1e-4
    rows = [(t, 0.0, data["vel_x_mps"][0], 0.0, 0.0) for t in before] + [tuple(r) for r in data]
    table = np.array([list(r) for r in rows])
    table[:, 1] += 0.5
    header = ",".join(data.dtype.names)
    np.savetxt(tmp_path / "pre7.csv", table, delimiter=",", header=header, comments="", fmt="%.7g")
    out = tmp_path / "pre7.yaml"
    assert main(["init", str(tmp_path / "pre7.csv"), "--mass", "2550 kg", "--out", str(out)]) == 0
    assert "bias_window: [-0.007 s, 0 s]" in out.read_text()


def test_init_names_a_symlinked_data_file_where_the_user_put_it(tmp_path):
    folder = tmp_path / "ev5"
    folder.mkdir()
    for file in EV5.parent.iterdir():
        (folder / file.name).symlink_to(file)
    problem, _ = init_problem(folder / EV5.name, tmp_path / "camry.yaml", Options())
    assert "      file: ev5/v10146.EV5\n" in (tmp_path / "camry.yaml").read_text()
    assert problem.tests[0].data is not None and problem.tests[0].data.file == folder.resolve() / EV5.name


@pytest.fixture(scope="module")
def compact_csv(tmp_path_factory):
    """A corpus vehicle recorded with x pointing away from the wall (every sign flipped), time in ms, speed in km/h."""
    v = random_vehicle(3, seed=11)
    truth = simulate(v)
    path = tmp_path_factory.mktemp("csv") / "compact.csv"
    write_csv(
        path,
        {
            "Time [ms]": truth["time"] * 1e3,
            "acc_x_g": -truth["accel"] / 9.80665,
            "speed_kph": -truth["velocity"] * 3.6,
            "disp_mm": -truth["displacement"] * 1e3,
        },
    )
    return v, truth, path


def test_csv_columns_units_and_signs_are_recognised(compact_csv):
    _, _, path = compact_csv
    draft = csv_draft(path, {})
    assert draft.data["time"] == {"column": "Time [ms]", "unit": "ms"}
    assert {ch: (c["column"], c["unit"]) for ch, c in draft.data["channels"].items() if "column" in c} == {
        "accel": ("acc_x_g", "g"),
        "velocity": ("speed_kph", "km/h"),
        "displacement": ("disp_mm", "mm"),
    }
    assert unit_in_name("a_mps2") == "m/s^2" and unit_in_name("accel") is None


@pytest.mark.integration
def test_init_on_a_csv_given_mass_and_speed_identifies(compact_csv, tmp_path):
    v, truth, path = compact_csv
    out = tmp_path / "compact.yaml"
    assert main(["init", str(path), "--mass", f"{v.mass} kg", "--speed", f"{v.speed * 3.6} km/h", "--out", str(out)]) == 0
    written = yaml.safe_load(out.read_text())
    assert all(written["tests"][0]["data"]["channels"][ch]["sign"] == -1 for ch in ("accel", "velocity", "displacement"))
    (test,) = _identify(out, tmp_path / "res")["tests"].values()
    model = test["metrics"]["model"]
    crush = float(np.max(truth["displacement"]))
    stop = float(truth["time"][np.flatnonzero(truth["velocity"] <= 0)[0]])
    assert model["max_displacement_m"] == pytest.approx(crush, rel=0.02)
    assert abs(model["time_zero_velocity_s"] - stop) <= 2e-3


def test_csv_without_units_asks_for_them(tmp_path, capsys):
    path = tmp_path / "plain.csv"
    path.write_text("time,accel\n0,0\n0.001,-1\n")
    assert main(["init", str(path), "--mass", "1000 kg", "--speed", "40 km/h", "--out", str(tmp_path / "p.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.endswith(
        "no unit in the column names 'time' (time), 'accel' (accel); give --column time=time:UNIT --column accel=accel:UNIT\n"
    )
    assert not (tmp_path / "p.yaml").exists()


def test_init_on_iso_mme_reads_mass_speed_and_the_cg_accelerometer(tmp_path):
    _mme_set(tmp_path / "T001", n=2000, peak_g=55.0)  # a pulse that stops it: init refuses data identify would
    problem, _ = init_problem(tmp_path / "T001", tmp_path / "mme.yaml", Options())
    assert problem.vehicle.mass == 1500 and problem.vehicle.speed == 15.0
    assert problem.tests[0].data.channels["accel"].code == CODE_X
    assert problem.vehicle.cg_to_front_axle == pytest.approx(0.44 * 2.65)  # a 1500 kg compact's typical geometry


def test_init_on_iso_mme_reads_a_decimal_comma_and_refuses_a_header_value_it_cannot_read(tmp_path):
    _mme_set(tmp_path / "T001")
    f = tmp_path / "T001" / "T001.mme"
    f.write_text(f.read_text().replace(":1500\n", ":1500,0\n").replace(":15.0\n", ":15,5\n"))
    draft = mme_draft(tmp_path / "T001")
    assert draft.vehicle["mass"][0] == 1500.0 and draft.vehicle["speed"][0] == 15.5
    f.write_text(f.read_text().replace(":1500,0\n", ":1500 kgs\n"))
    with pytest.raises(InputError, match=r"T001\.mme: header line 'mass test object 1 :1500 kgs'"):
        mme_draft(tmp_path / "T001")


RAW, CFC60_LAB, CFC1000_LAB = "10VEHCCG0000ACX0", "10VEHCCG0000ACXD", "10VEHCCG0000ACXA"  # ISO filter classes 0, D, A


@pytest.mark.parametrize(
    ("accels", "chosen", "said"),
    [
        ((CFC60_LAB, RAW), RAW, "unfiltered (ISO filter class 0)"),
        ((CFC1000_LAB, CFC60_LAB), CFC60_LAB, "filtered by the lab, ISO filter class D (CFC60): not filtered at CFC60 again"),
        ((CFC1000_LAB,), CFC1000_LAB, "filtered by the lab, ISO filter class A (CFC1000); filtered at CFC60 over it"),
    ],
)
def test_init_reads_the_unfiltered_accelerometer_else_one_the_lab_filtered_at_cfc60(tmp_path, accels, chosen, said):
    """The audit's test listed the CFC 60 code first and init filtered it at CFC 60 a second time."""
    _mme_set(tmp_path / "T001", accels=accels)
    draft = mme_draft(tmp_path / "T001")
    assert draft.data["channels"]["accel"] == {"code": chosen, "filter": "CFC60"}
    assert draft.comments["accel"] == f"vehicle X accelerometer at the CG, {said}"


def test_print_solution_shows_a_solve_that_never_ran(capsys):
    from crashnlp.results.result import Result, SolverStats

    result = Result(
        "x",
        "identify",
        "solver failed: Invalid_Number_Detected",
        SolverStats(None, 0, None, None, None),
        {},
        {"model.spring.values": [1.0, None]},
        {},
        {},
        (),
        {},
        (),
        {},
    )
    _print_solution(result)
    out = capsys.readouterr().out
    assert "(IPOPT -, 0 iterations, objective -, not solved)" in out and "[1 nan]" in out


def _pickup_columns(path, columns: dict) -> None:
    """The shipped pickup's record written under other column names, in other units."""
    raw = np.loadtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", skiprows=1)
    t, a, v, x = raw[:, 0], raw[:, 1], raw[:, 2], raw[:, 3]
    values = {"time_s": t, "Speed_mph": v / 0.44704, "Travel_in": x / 0.0254, "Decel_G": -a, "Belt_N": 0 * t}
    values.update({"Speed_ft/s": v / 0.3048, "Accel_ft/s2": a * 9.80665 / 0.3048, "Travel_mm": x * 1e3})
    write_csv(path, {name: values[name] for name in columns})


def test_init_refuses_data_that_identify_would_and_writes_nothing(tmp_path, capsys):
    """A deceleration in g under a header that says ft/s^2 (the pickup's g column named
    Accel_ft/s2): its velocity channel falls 30 times more than it does. init says so in one line,
    naming the data file and the key, as identify would, and writes no problem file."""
    path = tmp_path / "mixed.csv"
    _pickup_columns(path, ["time_s", "Speed_ft/s", "Travel_mm"])
    raw = np.loadtxt(path, delimiter=",", skiprows=1)
    g = np.loadtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", skiprows=1)[:, 1]
    write_csv(path, {"time_s": raw[:, 0], "Speed_ft/s": raw[:, 1], "Accel_ft/s2": g, "Travel_mm": raw[:, 2]})
    assert main(["init", str(path), "--mass", "2550 kg", "--out", str(tmp_path / "p.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {path}: as read for the problem file: tests.0.data.channels.accel.unit: ")
    assert err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


@pytest.mark.parametrize("encoding", ["utf-16-le", "utf-16-be"])
def test_init_of_a_utf16_file_says_to_save_it_as_utf8(tmp_path, capsys, encoding):
    """A CSV saved as Excel's "Unicode Text" (UTF-16, a byte-order mark first) was called no text
    file (its NUL bytes); it is named as UTF-16, to save as UTF-8."""
    data = tmp_path / "pulse.csv"
    data.write_bytes("\ufefftime_s,accel_g\n0,0\n0.001,-1\n".encode(encoding))
    out = tmp_path / "p.yaml"
    assert main(["init", str(data), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {data}: UTF-16 text") and "save it as UTF-8" in err and err.count("\n") == 1, err
    assert not out.exists()


def test_init_of_a_file_that_is_no_text_says_so_not_its_bytes(tmp_path, capsys):
    """A program given as data (`init /bin/ls`) had its bytes named as the columns it lacked."""
    data = tmp_path / "program"
    data.write_bytes(b"\x7fELF\x02\x01\x01\x00\x00\x00\n\x03\x00>\x00\x01\xef\xbf\xbd")
    out = tmp_path / "p.yaml"
    assert main(["init", str(data), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"crashnlp: error: {data}: not a text file (it holds NUL bytes): give the test's data as delimited text\n"
    assert not out.exists()


def test_init_refuses_a_record_on_a_shifted_clock_and_writes_nothing(tmp_path, capsys):
    """The pickup with its time starting at 1 s (a data system's clock): init wrote a window
    [0 s, 1.25 s] the fit never finished on. Refused in one line naming the time column."""
    path = tmp_path / "shifted.csv"
    header, *rows = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    path.write_text("\n".join([header] + [f"{float(r.split(',')[0]) + 1.0:.6f},{r.split(',', 1)[1]}" for r in rows]))
    assert main(["init", str(path), "--mass", "2550 kg", "--out", str(tmp_path / "p.yaml")]) == 2
    err = capsys.readouterr().err
    assert f"{path}: time column time_s: the record begins 1000 ms after impact" in err
    assert err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


@pytest.mark.parametrize(
    ("column", "value", "said"),
    [("Travel_mm", 250.0, "stays at 0.25 m"), ("Speed_ft/s", 0.0, "stays at 0 m/s")],
    ids=["displacement-constant", "velocity-zero"],
)
def test_init_refuses_a_flat_column_naming_the_file_and_column(tmp_path, capsys, column, value, said):
    """A displacement column of one value had init fail on the crush breakpoints of the problem file
    it had not written yet; a velocity column of zeros was set against --speed. Each is refused in
    one line naming the data file, the channel's key and the column, as flat; nothing is written."""
    path = tmp_path / "flat.csv"
    _pickup_columns(path, ["time_s", "Speed_ft/s", "Decel_G", "Travel_mm"])
    raw = np.loadtxt(path, delimiter=",", skiprows=1)
    names = ["time_s", "Speed_ft/s", "Decel_G", "Travel_mm"]
    write_csv(path, {name: 0 * raw[:, k] + value if name == column else raw[:, k] for k, name in enumerate(names)})
    args = ["init", str(path), "--mass", "2550 kg", "--speed", "56 km/h", "--out", str(tmp_path / "p.yaml")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {path}: as read for the problem file: tests.0.data.channels.")
    assert f"(flat.csv:{column}) {said}" in err and "the channel is flat (a dead sensor" in err
    assert err.count("\n") == 1 and not (tmp_path / "p.yaml").exists()


def test_init_s_window_reaches_past_a_measured_pitch_s_peak():
    """The pickup stops at 68 ms and pitches most at 171 ms: twice the stop time (140 ms) would cut
    the pitch off before its max, so the window runs 10 ms past the peak, and the note says why."""
    draft, _ = draft_for([ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv"], Options(mass=2550.0))
    assert 0.18 <= draft.data["window"][1] <= 0.19
    assert any("past the pitch's peak at 17" in n for n in draft.notes), draft.notes


@pytest.mark.parametrize("kind", ["glitch", "drift"])
def test_init_reads_a_pitch_too_small_to_be_the_crash_s_as_it_is(tmp_path, kind):
    """A vehicle that barely pitches (0.45 deg) with one -0.6 deg glitch keeps its sign; one that
    drifts to 0.2 deg by the record's end does not stretch the window to its peak: below 1 deg a
    pitch is noise or drift, and neither turns a channel nor sets the window."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    rows = [row.split(",") for row in lines]
    t = np.array([float(r[0]) for r in rows])
    if kind == "glitch":
        pitch = np.array([float(r[4]) for r in rows]) * 0.45 / 9.0
        pitch[np.searchsorted(t, 0.05)] = -0.6
    else:
        pitch = 0.2 * t / t[-1]
    text = [",".join([*r[:4], f"{p:.5f}"]) for r, p in zip(rows, pitch)]
    (tmp_path / "small.csv").write_text("\n".join([header, *text]) + "\n")
    draft, _ = draft_for([tmp_path / "small.csv"], Options(mass=2550.0))
    assert "sign" not in draft.data["channels"]["pitch"]
    assert draft.data["window"][1] <= 0.15 and not any("pitch's peak" in n for n in draft.notes)


def test_init_turns_a_pitch_read_nose_up(tmp_path):
    """The pickup's pitch written nose-up positive: init reads it with `sign: -1`, as it turns the
    other channels into the model frame; as written, nose-down, it keeps its sign."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    turned = [",".join([*row.split(",")[:4], str(-float(row.split(",")[4]))]) for row in lines]
    for name, rows, sign in (("turned", turned, -1), ("as-is", lines, None)):
        (tmp_path / f"{name}.csv").write_text("\n".join([header, *rows]) + "\n")
        draft, _ = draft_for([tmp_path / f"{name}.csv"], Options(mass=2550.0))
        assert draft.data["channels"]["pitch"].get("sign") == sign
        assert ("nose-down pitch is positive" if sign else "taken as nose-down positive") in draft.comments["pitch"]


def test_csv_columns_in_mph_inches_and_g_are_read_and_the_rest_named(tmp_path):
    path = tmp_path / "us.csv"
    _pickup_columns(path, ["time_s", "Speed_mph", "Travel_in", "Decel_G", "Belt_N", "Accel_ft/s2"])
    draft, _ = draft_for([path], Options(mass=2550.0))
    channels = draft.data["channels"]
    assert (channels["accel"]["column"], channels["accel"]["unit"], channels["accel"]["sign"]) == ("Decel_G", "g", -1)
    assert (channels["velocity"]["column"], channels["velocity"]["unit"]) == ("Speed_mph", "mph")
    assert (channels["displacement"]["column"], channels["displacement"]["unit"]) == ("Travel_in", "in")
    assert draft.vehicle["speed"][0] == pytest.approx(56 / 3.6, rel=1e-3)
    assert "Columns not read: 'Belt_N', 'Accel_ft/s2' (--column CHANNEL=NAME:UNIT reads one)." in draft.notes
    data = load_test_data(_data_spec(draft, path), None)
    assert -data.channels["accel"].values.min() / 9.80665 == pytest.approx(29.8, rel=0.1)
    assert data.channels["displacement"].values.max() == pytest.approx(0.593, abs=0.003)


def test_csv_columns_found_by_their_unit(tmp_path):
    path = tmp_path / "si.csv"
    _pickup_columns(path, ["time_s", "Speed_ft/s", "Accel_ft/s2", "Travel_mm"])
    found, unread = _csv_columns(Table.read(path), {})
    assert found == {
        "time": ("time_s", "s"),
        "velocity": ("Speed_ft/s", "ft/s"),
        "accel": ("Accel_ft/s2", "ft/s^2"),
        "displacement": ("Travel_mm", "mm"),
    }
    assert unread == []
    (tmp_path / "x.csv").write_text("t_ms,ax_g,vx_kph\n0,1,56\n")  # named by nothing but their units
    assert _csv_columns(Table.read(tmp_path / "x.csv"), {})[0] == {
        "time": ("t_ms", "ms"),
        "accel": ("ax_g", "g"),
        "velocity": ("vx_kph", "km/h"),
    }


def test_csv_without_a_header_line_takes_columns_by_number(tmp_path, capsys):
    raw = np.loadtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", skiprows=1)
    path = tmp_path / "plain.txt"
    path.write_bytes(b"".join(b"%.4f\t%.6f\r\n" % (t, a) for t, a in raw[:, :2]))
    draft = csv_draft(path, {"time": "1:s", "accel": "2:g"})
    assert draft.data["time"] == {"column": 1, "unit": "s"} and draft.data["channels"]["accel"]["column"] == 2
    out = str(tmp_path / "p.yaml")
    assert main(["init", str(path), "--mass", "2550 kg", "--speed", "56 km/h", "--out", out]) == 2
    assert capsys.readouterr().err.endswith(
        "plain.txt: no header line; give the columns by number, e.g. --column time=1:s --column accel=2:g\n"
    )
    assert main(["init", str(path), "--column", "time=1:s", "--column", "accel=2", "--speed", "56 km/h", "--out", out]) == 2
    assert capsys.readouterr().err.endswith("no unit in the column names 2 (accel); give --column accel=2:UNIT\n")
    assert not (tmp_path / "p.yaml").exists()


@pytest.fixture
def camry_channels(tmp_path) -> list:
    return channel_export(tmp_path / "export", (93, 94, 95))


@pytest.mark.integration
def test_init_on_nhtsa_channel_files_with_mass_and_speed_identifies(camry_channels, tmp_path, capsys):
    out = tmp_path / "camry.yaml"
    files = [str(f) for f in camry_channels[:2]]
    assert main(["init", *files, "--mass", "1719 kg", "--speed", "57.09 km/h", "--out", str(out)]) == 0
    text = out.read_text()
    assert "format: nhtsa-channel" in text and "accel: {curves: [93, 94], unit: g, filter: CFC60}" in text
    assert "file: export/v10146tsv.093" in text and 'name: "v10146"' in text
    assert main(["identify", str(out), "--out", str(tmp_path / "res"), "--no-figures"]) == 0
    assert "v10146: ok (IPOPT" in capsys.readouterr().out
    (test,) = json.loads((tmp_path / "res" / "result.json").read_text())["tests"].values()
    assert test["metrics"]["model"]["max_displacement_m"] * 1e3 == pytest.approx(CAMRY_DATA["crush_mm"], rel=0.02)


def test_init_reads_the_channels_named_in_a_folder(camry_channels, tmp_path):
    options = Options(mass=1719.0, speed=57.09 / 3.6, columns={"accel": "93,v10146tsv.094:g"})
    draft, _ = draft_for([camry_channels[0].parent], options)
    assert draft.data["format"] == "nhtsa-channel" and draft.data["channels"]["accel"]["curves"] == [93, 94]
    assert draft.data["window"] == [0.0, 0.15]


@pytest.mark.parametrize(
    "paths, columns, message",
    [
        (["export"], {}, "export: name its channels, e.g. --column accel=CCC,CCC:g (channel files 093, 094, 095)"),
        (["export/v10146tsv.093"], {"velocity": "95"}, "--column velocity=95: an NHTSA channel file carries no unit"),
        (["export/v10146tsv.093"], {"accel": "96:g"}, "--column accel=96: no channel file 096 of the test beside"),
        (["export/v10146tsv.093"], {"accel": "x.csv:g"}, "--column accel=x.csv: name channel files by their number CCC"),
        (["export/v10146tsv.093"], {"time": "1:s"}, "--column time=1:s: nhtsa-channel channels are"),
        (["export/v10146tsv.093", "other/v10147tsv.094"], {}, "give one folder, or channel files vNNNNNtsv.CCC of one test"),
    ],
)
def test_init_on_nhtsa_channel_files_refuses_what_it_cannot_read(camry_channels, tmp_path, paths, columns, message):
    channel_export(tmp_path / "other", (94,), test="10147")
    with pytest.raises(InputError, match=re.escape(message)):
        draft_for([tmp_path / p for p in paths], Options(mass=1719.0, speed=15.0, columns=columns))


@pytest.mark.parametrize(
    "data, column, message",
    [
        (
            "problems/data/synthetic-pickup/pickup-56kph.csv",
            "acel=accel_x_g:g",
            "--column acel=accel_x_g:g: csv channels are time,",
        ),
        (
            "problems/data/nhtsa-10146/v10146.EV5",
            "accel=93:g",
            "--column accel=93:g: nhtsa-ev5 data say what their channels hold",
        ),
    ],
)
def test_init_refuses_a_column_of_no_channel_in_one_line(tmp_path, capsys, data, column, message):
    out = tmp_path / "p.yaml"
    assert main(["init", str(ROOT / data), "--column", column, "--mass", "1 t", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {message}") and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize(
    "out, options, message",
    [
        ("pickup.csv", [], "--out {tmp}/pickup.csv: is one of the test's data files; name the problem file to write"),
        (".", [], "--out {tmp}: is a folder; name the file to write"),
        ("new/dir/", [], "--out {tmp}/new/dir/: a folder; name the file to write"),
        ("pickup.csv/p.yaml", [], "--out {tmp}/pickup.csv: exists and is not a folder"),
        (
            "p.yaml",
            ["--column", "accel=accel_x_g:g", "--column", "accel=2:g"],
            "--column accel=2:g: accel is given twice (--column accel=accel_x_g:g)",
        ),
        ("p.yaml", ["--speed", "56"], '--speed 56: give its unit, e.g. "56 km/h" or "56 m/s"'),
        ("p.yaml", ["--speed", "56 kg"], "--speed 56 kg: '56 kg' does not convert to m/s"),
        # as simulate's what-if reads them (crashnlp.problem.schema.what_if): one line, exit 2
        ("p.yaml", ["--speed", "0 km/h"], "--speed 0 km/h: 0 m/s is no impact"),
        ("p.yaml", ["--mass", "nan"], "--mass nan: not a finite number"),
    ],
)
def test_init_refuses_a_careless_out_or_option_before_any_work(tmp_path, capsys, out, options, message):
    data = tmp_path / "pickup.csv"
    shutil.copy(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", data)
    before = {p: p.read_bytes() for p in tmp_path.iterdir()}
    mass = [] if "--mass" in options else ["--mass", "2550 kg"]  # an option given twice is refused as such
    assert main(["init", str(data), *mass, *options, "--out", f"{tmp_path}/{out}"]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {message.format(tmp=tmp_path)}\n"
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize(
    "data, out",
    [
        ("ev5/v10146.EV5", "ev5/v10146.093"),  # the accelerometer file the problem reads
        ("ev5/v10146.EV5", "ev5/v10146.EV5"),
        ("export/v10146tsv.093", "export/v10146tsv.095"),  # a channel file of the test it does not read
        ("T001", "T001/Channel/T001.002"),
    ],
)
def test_init_never_writes_over_a_data_file_even_with_force(tmp_path, capsys, data, out):
    (tmp_path / "ev5").mkdir()
    for suffix in (".EV5", ".093", ".094"):
        shutil.copy(EV5.with_suffix(suffix), tmp_path / "ev5")
    channel_export(tmp_path / "export", (93, 94, 95))
    _mme_set(tmp_path / "T001")
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert main(["init", str(tmp_path / data), "--out", str(tmp_path / out), "--force"]) == 2
    expected = f"--out {tmp_path / out}: is one of the test's data files; name the problem file to write"
    assert capsys.readouterr().err == f"crashnlp: error: {expected}\n"
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_init_writes_over_an_existing_file_only_with_force(tmp_path, capsys):
    out = tmp_path / "p.yaml"
    out.write_text("# the user's edits\n")
    assert main(["init", str(EV5), "--out", str(out)]) == 2
    expected = f"--out {out}: exists; give --force to write over it, or name another file"
    assert capsys.readouterr().err == f"crashnlp: error: {expected}\n"
    assert out.read_text() == "# the user's edits\n"
    # a mass 3.5 % above the header's (ballast, instruments) is no contradiction
    assert main(["init", str(EV5), "--mass", "1780 kg", "--out", str(out), "--force"]) == 0
    assert load_problem(out).vehicle.mass == 1780


@pytest.mark.parametrize(
    "data, options, message",
    [
        (
            EV5,
            ["--speed", "40 km/h"],
            "--speed: 11.1111 m/s (40 km/h), but the data header of test v10146 says 15.8583 m/s (57.09 km/h)"
            " (more than 5 % apart)",
        ),
        (
            EV5,
            ["--mass", "2500 kg"],
            "--mass: 2500 kg, but the data header of test v10146 says 1719 kg (more than 10 % apart; the fitted forces scale"
            " with the mass)",
        ),
        (
            ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv",
            ["--mass", "2550 kg", "--speed", "40 km/h"],
            "--speed: 11.1111 m/s (40 km/h), but the velocity data of test pickup-56kph start at 15.5586 m/s (56.01 km/h)"
            " (pickup-56kph.csv); speed and data disagree by more than 5 %",
        ),
    ],
    ids=["header-speed", "header-mass", "velocity-data"],
)
def test_init_refuses_a_speed_or_mass_the_data_contradict(tmp_path, capsys, data, options, message):
    """As identify would refuse the file written (crashnlp.case.testcase): said at init, nothing written."""
    out = tmp_path / "p.yaml"
    assert main(["init", str(data), *options, "--out", str(out)]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {message}\n"
    assert not out.exists()


def test_init_writes_into_a_folder_it_makes_and_the_file_names_the_data(tmp_path, capsys):
    out = tmp_path / "new" / "deeper" / "p.yaml"
    data = ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv"
    assert main(["init", str(data), "--mass", "2550 kg", "--out", str(out)]) == 0
    assert load_problem(out).tests[0].data.file.resolve() == data.resolve()


def test_init_on_a_folder_of_other_files_names_them(tmp_path, capsys):
    for name in ("a.csv", "b.csv", "notes.txt"):
        (tmp_path / name).write_text("time_s,accel_g\n")
    assert main(["init", str(tmp_path), "--mass", "1 t", "--out", str(tmp_path / "p.yaml")]) == 2
    expected = f"{tmp_path}: no .mme file (not an ISO-MME test?); it holds a.csv, b.csv, notes.txt: name the data file"
    assert capsys.readouterr().err == f"crashnlp: error: {expected}\n"


def test_a_trailing_delimiter_is_no_column_to_name(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_text("time_s,accel_g,note,\n0,1,a,\n0.0001,2,b,\n")
    found, unread = _csv_columns(Table.read(path), {})
    assert found == {"time": ("time_s", "s"), "accel": ("accel_g", "g")} and unread == ["note"]
