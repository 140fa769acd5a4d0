"""Hostile input and interrupted runs: one line, the right exit status, nothing half-written, no orphans."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, command, descendants, merge

import crashnlp
from crashnlp.base.errors import InputError
from crashnlp.case.testcase import impulses, load_tests
from crashnlp.cli import main
from crashnlp.problem import problem_from_dict
from crashnlp.results.jsonfile import write_json
from crashnlp.studies.store import CaseStore

PICKUP = ROOT / "problems/pickup-56kph.yaml"
CLI = [sys.executable, "-m", "crashnlp"]  # the console command (crashnlp.__main__), as a user starts it


def pickup(changes: dict | None = None, drop: tuple[str, ...] = ()) -> dict:
    """The shipped pickup problem as a dict, data path made absolute, with changes merged in."""
    raw = yaml.safe_load(PICKUP.read_text())
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    raw = merge(raw, changes or {})
    for key in drop:
        node = raw
        *parents, leaf = key.split(".")
        for k in parents:
            node = node[int(k)] if isinstance(node, list) else node[k]
        del node[leaf]
    return raw


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def refused(tmp_path: Path, capsys, raw_or_text, expected: str, command: str = "identify") -> str:
    """Write a problem, run a command on it: exit 2, one line containing `expected`, nothing written."""
    path = tmp_path / "p.yaml"
    if isinstance(raw_or_text, bytes):
        path.write_bytes(raw_or_text)
    else:
        path.write_text(raw_or_text if isinstance(raw_or_text, str) else yaml.safe_dump(raw_or_text))
    out = tmp_path / "out"
    code, _, err = run([command, str(path), "--out", str(out)], capsys)
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert expected in err, err
    assert not out.exists()
    return err


# --------------------------------------------------------------------------- values the model cannot integrate
@pytest.mark.parametrize(
    "changes, expected",
    [
        ({"vehicle": {"mass": ".nan"}}, "vehicle.mass: "),
        ({"vehicle": {"mass": float("nan")}}, "vehicle.mass: "),
        ({"vehicle": {"cg_to_impact": float("inf")}}, "vehicle.cg_to_impact: "),
        ({"vehicle": {"mass": 1e308}}, "vehicle.mass: "),
        ({"vehicle": {"mass": "1e308 kg"}}, "vehicle.mass: "),
        ({"vehicle": {"mass": -2550}}, "vehicle.mass: must be positive"),
        ({"vehicle": {"speed": "-56 km/h"}}, "vehicle.speed: must not be negative"),
        ({"tests": [{"name": "t", "speed": "-56 km/h"}]}, "tests.0.speed: must not be negative"),
        ({"tests": [{"name": "t", "duration": "-0.2 s"}]}, "tests.0.duration: must be positive"),
        ({"simulation": {"dt": 0}}, "simulation.dt: must be positive"),
        ({"simulation": {"dt": "10 ms"}}, "p.yaml: simulation.dt 0.01 s: 20 output steps over 0.2 s"),
        ({"model": {"spring": {"values": ["nan kN"] * 8}}}, "model.spring: "),
        ({"model": {"spring": {"values": ["0 kN", "-300 kN", *["450 kN"] * 6]}}}, "model.spring.values.1: must not be negative"),
        ({"model": {"damper": {"values": ["-5 kN*s/m", "5 kN*s/m"]}}}, "model.damper.values.0: must not be negative"),
        ({"estimate": {"vehicle.cg_above_impact": {"bounds": [0, "inf m"]}}}, "estimate.vehicle.cg_above_impact: "),
    ],
)
def test_values_the_model_cannot_integrate_are_refused_with_their_key(tmp_path, capsys, changes, expected):
    refused(tmp_path, capsys, merge(BASE, changes), expected, command="simulate")


@pytest.mark.parametrize("dt", ["0", "-1e-4", "nan", "inf", "1e-12", "0.5", "5 ms", "1e300", "0.1 mss"])
def test_bad_dt_is_refused(tmp_path, capsys, dt):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(BASE))
    code, _, err = run(["simulate", str(path), f"--dt={dt}", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and err.startswith("crashnlp: error: --dt") and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_initial_value_outside_its_bounds_is_refused(tmp_path, capsys):
    raw = pickup({"estimate": {"vehicle.cg_above_impact": {"initial": "0.9 m", "bounds": ["0 m", "0.6 m"]}}})
    refused(tmp_path, capsys, raw, "estimate.vehicle.cg_above_impact: initial 0.9 is outside the bounds")
    raw = pickup({"vehicle": {"pitch_inertia": "20000 kg*m^2"}})
    refused(tmp_path, capsys, raw, "estimate.vehicle.pitch_inertia: the problem's value")
    raw = pickup({"estimate": {"model.spring.values": {"initial": ["100 kN", "200 kN"]}}})
    expected = f"{tmp_path / 'p.yaml'}: estimate.model.spring.values.initial: 2 values for an entry of size 7"
    refused(tmp_path, capsys, raw, expected)
    assert main(["identify", str(tmp_path / "p.yaml"), "--check"]) == 2  # --check sees it too


# --------------------------------------------------------------------------- data that contradict the problem
def test_a_plain_speed_that_the_data_contradict_is_refused(tmp_path, capsys):
    raw = pickup({"vehicle": {"speed": 56}, "tests": [{**pickup()["tests"][0], "speed": 56}]})
    err = refused(tmp_path, capsys, raw, "tests.0.speed: 56 m/s (201.6 km/h), but the velocity data")
    assert "15.5586 m/s (56.01 km/h)" in err and "5 %" in err
    assert err.endswith("56 is 3.6 times the data's: a plain number is m/s, not km/h\n")


@pytest.mark.parametrize(("kmh", "refuses"), [(56, True), (40, False)])
def test_an_accelerometer_recorded_at_another_speed_is_refused_by_its_drift_after_the_pulse(tmp_path, capsys, kmh, refuses):
    """The 40 km/h pickup's acceleration alone (no velocity to start at the speed, no header): told
    56 km/h, its integral leaves the vehicle moving toward the barrier at 3 m/s once its pulse is
    over, which a rigid barrier cannot (it fitted and said ok); told 25 km/h, it throws the vehicle
    back at more than half its speed, which a rigid barrier does not; told 40 km/h it is taken."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-40kph.csv").read_text().splitlines()
    (tmp_path / "accel.csv").write_text("\n".join(",".join(row.split(",")[:2]) for row in [header, *lines]) + "\n")
    test = pickup()["tests"][0]
    data = {**test["data"], "file": str(tmp_path / "accel.csv"), "channels": {"accel": test["data"]["channels"]["accel"]}}
    raw = pickup({"vehicle": {"speed": f"{kmh} km/h"}, "tests": [{"name": "a", "data": data}]})
    if refuses:
        err = refused(tmp_path, capsys, raw, "vehicle.speed: 15.5556 m/s (56 km/h), but the acceleration of test a (accel.csv)")
        drift = float(re.search(r"toward the barrier at ([\d.]+) m/s once its pulse is over", err)[1])
        assert 2.0 < drift < 4.0  # 56 - 40 km/h less the rebound
        assert "offset" not in err  # its acceleration after the pulse is noise about zero, no level
    else:
        (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
        assert main(["identify", str(tmp_path / "p.yaml"), "--check"]) == 0
    # told 25 km/h (a slip of mph for km/h), the pulse throws the vehicle back at more than half its speed
    err = refused(tmp_path, capsys, pickup({"vehicle": {"speed": "25 km/h"}, "tests": [{"name": "a", "data": data}]}), "")
    assert "vehicle.speed: 6.94444 m/s (25 km/h)" in err and "throws the vehicle back at" in err
    # read with the wrong sign, the pulse speeds the vehicle up: the channel's sign is named, not the speed
    flipped = {**data, "channels": {"accel": {**data["channels"]["accel"], "sign": -data["channels"]["accel"].get("sign", 1)}}}
    err = refused(tmp_path, capsys, pickup({"vehicle": {"speed": "40 km/h"}, "tests": [{"name": "a", "data": flipped}]}), "")
    assert "tests.0.data.channels.accel.sign: 11.1111 m/s (40 km/h)" in err and "reads with the wrong sign" in err


def test_an_acceleration_and_a_velocity_read_in_different_units_are_refused(tmp_path, capsys):
    """The pickup measures both: its acceleration read in m/s^2 changes the velocity 9.81 times
    less than its velocity channel does (it fitted, said ok, at a sixth of the pulse); its velocity
    column written in km/h, with the speed the column starts at, 3.6 times more than the
    acceleration; an acceleration with the wrong sign speeds the vehicle up where the velocity
    falls. Each names the channel's key; read right, the same data are taken."""
    test = pickup()["tests"][0]
    channels = test["data"]["channels"]

    def reading(accel: dict, **data) -> dict:
        return {**test, "data": {**test["data"], **data, "channels": {**channels, "accel": {**channels["accel"], **accel}}}}

    err = refused(tmp_path, capsys, pickup({"tests": [reading({"unit": "m/s^2"})]}), "tests.0.data.channels.accel.unit: the")
    ratio = float(re.search(r"m/s, ([\d.]+) times as much", err)[1])
    assert ratio == pytest.approx(9.81, rel=0.02) and "most likely the accel channel's" in err
    refused(tmp_path, capsys, pickup({"tests": [reading({"sign": -1})]}), "tests.0.data.channels.accel.sign: the acceleration")
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    rows = [row.split(",") for row in lines]
    kmh = [",".join([r[0], r[1], f"{float(r[2]) * 3.6:.5f}", *r[3:]]) for r in rows]
    (tmp_path / "kmh.csv").write_text("\n".join([header, *kmh]) + "\n")
    raw = pickup({"vehicle": {"speed": f"{float(rows[0][2]) * 3.6} m/s"}, "tests": [reading({}, file=str(tmp_path / "kmh.csv"))]})
    err = refused(tmp_path, capsys, raw, "tests.0.data.channels.velocity.unit: the acceleration")
    assert "most likely the velocity channel's" in err


def test_a_displacement_read_in_another_unit_or_sign_is_refused(tmp_path, capsys):
    """The pickup's displacement written in mm under its m header reads 1000 times what its velocity
    integrates to (the fit ran into IPOPT's iteration limit without saying why); read with the
    other sign, it travels away from the barrier. Each names the channel's key; the Camry's
    displacement, derived from its acceleration, and the pickup's as written are taken."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    column = header.split(",").index("disp_x_m")
    mm = [",".join(f"{float(v) * 1e3:.6g}" if j == column else v for j, v in enumerate(row.split(","))) for row in lines]
    (tmp_path / "mm.csv").write_text("\n".join([header, *mm]) + "\n")
    test = pickup()["tests"][0]
    written = {**test, "data": {**test["data"], "file": str(tmp_path / "mm.csv")}}
    err = refused(tmp_path, capsys, pickup({"tests": [written]}), "tests.0.data.channels.displacement.unit: the displacement")
    ratio = float(re.search(r"travels furthest: ([\d.]+) m, ([\d.e+]+) times as much", err)[2])
    assert ratio == pytest.approx(1000, rel=0.01)
    channels = test["data"]["channels"]
    displacement = {**channels["displacement"], "sign": -1}
    turned = {**test, "data": {**test["data"], "channels": {**channels, "displacement": displacement}}}
    refused(tmp_path, capsys, pickup({"tests": [turned]}), "tests.0.data.channels.displacement.sign: the displacement")
    for name in ("pickup-56kph", "nhtsa-10146"):
        assert main(["identify", str(ROOT / f"problems/{name}.yaml"), "--check"]) == 0


def test_a_pitch_in_degrees_read_as_radians_is_refused(tmp_path, capsys):
    """The pickup's pitch column (9 deg at most) read as radians swings 515 deg: no frontal crash
    pitches a vehicle past 45 deg, so the channel's unit is named."""
    test = pickup()["tests"][0]
    channels = test["data"]["channels"]
    radians = {**test, "data": {**test["data"], "channels": {**channels, "pitch": {**channels["pitch"], "unit": "rad"}}}}
    err = refused(tmp_path, capsys, pickup({"tests": [radians]}), "tests.0.data.channels.pitch.unit: the pitch of test")
    assert 500 < float(re.search(r"reaches ([\d.]+) deg", err)[1]) < 530


def test_a_pitch_read_nose_up_is_refused(tmp_path, capsys):
    """The pickup's pitch read with the other sign swings 8.5 deg nose-up: a frontal crash pitches
    the nose down, and the fit had said ok with the lever at its bound and no pitch. The message
    says which way to turn the channel: drop a `sign: -1` that turned it, or give one to a column
    written nose-up. Where the problem puts the impact point above the CG, nose-up is the crash's."""
    test = pickup()["tests"][0]
    channels = test["data"]["channels"]
    turned = {**test, "data": {**test["data"], "channels": {**channels, "pitch": {**channels["pitch"], "sign": -1}}}}
    err = refused(tmp_path, capsys, pickup({"tests": [turned]}), "tests.0.data.channels.pitch.sign: the pitch of test")
    assert re.search(r"swings to -8\.\d+ deg and no further than 0\.\d+ deg the other way", err) and "(drop its sign: -1)" in err
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    nose_up = [",".join([*row.split(",")[:4], str(-float(row.split(",")[4]))]) for row in lines]
    (tmp_path / "nose-up.csv").write_text("\n".join([header, *nose_up]) + "\n")
    written = {**test, "data": {**test["data"], "file": str(tmp_path / "nose-up.csv")}}
    refused(tmp_path, capsys, pickup({"tests": [written]}), "(sign: -1 turns it)")
    above = pickup({"vehicle": {"cg_above_impact": "-0.1 m"}, "tests": [written]})
    above["estimate"]["vehicle.cg_above_impact"] = {"bounds": ["-0.3 m", "0.6 m"]}
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(above))
    assert main(["identify", str(tmp_path / "p.yaml"), "--check"]) == 0


def pickup_record(path: Path, changes: dict, channels: dict | None = None) -> dict:
    """The shipped pickup problem reading its record written to `path` with each column of `changes`
    made a function of its values (a new column of the time), and with `channels` (None: drop one)."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    names = header.split(",")
    columns = dict(zip(names, np.loadtxt(lines, delimiter=",", ndmin=2).T))
    columns.update({name: change(columns.get(name, columns["time_s"])) for name, change in changes.items()})
    (path.parent / path.name).write_text(
        "\n".join([",".join(columns), *(",".join(f"{v:.9g}" for v in row) for row in zip(*columns.values()))]) + "\n"
    )
    test = pickup()["tests"][0]
    merged = {**test["data"]["channels"], **(channels or {})}
    kept = {name: channel for name, channel in merged.items() if channel is not None}
    return pickup({"tests": [{**test, "data": {**test["data"], "file": str(path), "channels": kept}}]})


def checked(tmp_path: Path, capsys, raw: dict) -> tuple[int, str]:
    """`identify --check` of a problem: its exit status and what it wrote to stderr."""
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
    code = main(["identify", str(tmp_path / "p.yaml"), "--check"])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("column", "change", "channel"),
    [
        ("vel_x_mps", lambda v: 0 * v + 56 / 3.6, "velocity"),  # stuck at the speed: fitted, said ok
        ("disp_x_m", lambda x: 0 * x, "displacement"),  # named as the channel's unit
        ("disp_x_m", lambda x: 0 * x + 0.25, "displacement"),
        ("pitch_deg", lambda p: 0 * p, "pitch"),  # fitted, said ok
        ("accel_x_g", lambda a: 0 * a, "accel"),  # named as the accel channel's sign
        ("wall_N", lambda t: 0 * t, "barrier_force"),
    ],
    ids=["velocity-at-speed", "displacement-zero", "displacement-constant", "pitch-zero", "accel-zero", "wall-zero"],
)
def test_a_flat_channel_is_refused_as_a_dead_sensor(tmp_path, capsys, column, change, channel):
    """A channel that does not change after impact (a dead sensor, a column of zeros or of one value)
    is refused before the fit, naming its key, the file and column it was read from, and that it is
    flat: the fit would take it for the crash (the velocity at the speed and the zero pitch fitted
    and said ok), and the checks after this one would blame another key."""
    extra = {"barrier_force": {"column": "wall_N", "unit": "N"}} if channel == "barrier_force" else None
    code, err = checked(tmp_path, capsys, pickup_record(tmp_path / "dead.csv", {column: change}, extra))
    assert code == 2 and err.count("\n") == 1, err
    assert f"tests.0.data.channels.{channel}: the {channel} of test 56kph (dead.csv:{column}) stays at " in err
    assert "the channel is flat (a dead sensor" in err


@pytest.mark.parametrize("kind", ["noise", "offset"])
def test_an_acceleration_of_noise_or_an_offset_alone_is_refused(tmp_path, capsys, kind):
    """An accelerometer that reads only noise (0.5 g) or a constant offset (0.27 g), with no
    velocity channel, changes the velocity by almost nothing: it had fitted and said ok (its
    drift check stands down on a record whose end is as loud as its peak). It is refused naming
    the accel channel; the pickup's acceleration alone is taken."""
    only = {"velocity": None, "displacement": None, "pitch": None}
    noise = np.random.default_rng(5).normal(0.0, 0.5, 2501)
    dead = (lambda a: noise[: a.size]) if kind == "noise" else (lambda a: 0 * a + 0.27)
    code, err = checked(tmp_path, capsys, pickup_record(tmp_path / "a.csv", {"accel_x_g": dead}, only))
    assert code == 2 and err.count("\n") == 1, err
    said = "reads noise or an offset only" if kind == "noise" else "the channel is flat (a dead sensor"
    assert "tests.0.data.channels.accel: the acc" in err and "(a.csv:accel_x_g)" in err and said in err
    assert checked(tmp_path, capsys, pickup_record(tmp_path / "a.csv", {}, only))[0] == 0


def test_a_barrier_force_read_with_the_wrong_sign_or_unit_is_refused(tmp_path, capsys):
    """The Camry's wall force without the `sign: -1` its load cells need pushes the vehicle into the
    barrier: the fit ran to IPOPT's iteration limit (1596 iterations, 323 s). Its curves in N read
    as kN give 1000 times the impulse its accelerometers take (a wall force in kN read as N had
    fitted and said ok at a ratio of 0.001). Each is refused before the fit, naming the channel's
    sign or unit; the shipped problem is taken, its ratio the one its fit reports."""
    raw = yaml.safe_load((ROOT / "problems/nhtsa-10146-barrier.yaml").read_text())
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    wall = raw["tests"][0]["data"]["channels"]["barrier_force"]
    problem, tests = load_tests(problem_from_dict(raw, ROOT / "problems"))
    wall_impulse, taken = impulses(tests[0].data, problem.vehicle.known_mass)
    assert wall_impulse / taken == pytest.approx(1.056, abs=0.005)
    assert checked(tmp_path, capsys, raw)[0] == 0
    for changed, key, said in [
        ({k: v for k, v in wall.items() if k != "sign"}, "sign", "-1.06 times the one its accelerometers take"),
        ({**wall, "unit": "kN"}, "unit", "1.06e+03 times the one its accelerometers take"),
    ]:
        raw["tests"][0]["data"]["channels"]["barrier_force"] = changed
        code, err = checked(tmp_path, capsys, raw)
        assert code == 2 and err.count("\n") == 1, err
        assert f"tests.0.data.channels.barrier_force.{key}: the barrier force of test 10146 (v10146.EV5)" in err and said in err


def _accel_only(tmp_path: Path, time: np.ndarray, g: np.ndarray, kmh: float, mass: float = 2550.0) -> dict:
    """The pickup problem on an accelerometer-only CSV (`time` s, `g`), at `kmh`, to the record's end."""
    (tmp_path / "accel.csv").write_text("time_s,accel_x_g\n" + "".join(f"{t:.6f},{a:.6f}\n" for t, a in zip(time, g)))
    test = pickup()["tests"][0]
    data = {**test["data"], "file": str(tmp_path / "accel.csv"), "channels": {"accel": test["data"]["channels"]["accel"]}}
    data.pop("window", None)
    return pickup({"vehicle": {"speed": f"{kmh} km/h", "mass": f"{mass} kg"}, "tests": [{"name": "a", "data": data}]})


@pytest.mark.parametrize("offset", [3.0, -3.0])
def test_an_accelerometer_offset_that_outlasts_the_pulse_is_refused_by_its_drift(tmp_path, capsys, offset):
    """The pickup's acceleration alone plus 3 g (no pre-impact samples to read the offset from): its
    last 10 ms read 10 % of its peak, so the drift check took the pulse for one going on and the fit
    said ok with 190 mm too much crush. A steady push toward the barrier is no barrier's: refused.
    Less 3 g, it throws the vehicle back past half its speed. Either refusal says that the
    accelerometer may read an offset, and what it holds."""
    raw = np.loadtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", skiprows=1)
    err = refused(tmp_path, capsys, _accel_only(tmp_path, raw[:, 0], raw[:, 1] + offset, 56), "vehicle.speed: ")
    if offset > 0:
        drift = float(re.search(r"toward the barrier at ([\d.]+) m/s once its pulse is over", err)[1])
        assert drift > 0.1 * 56 / 3.6
    else:
        assert float(re.search(r"throws the vehicle back at ([\d.]+) m/s", err)[1]) > 0.5 * 56 / 3.6
    held = float(re.search(r"the accelerometer reads an offset: it holds ([-\d.]+) g steadily", err)[1])
    assert held == pytest.approx(offset, abs=0.2)


def test_a_speed_only_a_data_header_gives_is_named_there_when_the_data_contradict_it(tmp_path, capsys):
    """Test 10146's EV5 header with its closing speed made 40 km/h, and a problem that gives no
    speed: the accelerometers throw the vehicle back past half that speed, and the refusal names
    the data file whose header gave the speed, not vehicle.speed, which the problem does not give."""
    source = ROOT / "problems/data/nhtsa-10146"
    for curve in ("v10146.093", "v10146.094"):
        shutil.copy(source / curve, tmp_path)
    header = (source / "v10146.EV5").read_text().replace("|OTH|OTH|57.09|", "|OTH|OTH|40.00|")
    (tmp_path / "v10146.EV5").write_text(header)
    raw = yaml.safe_load((ROOT / "problems/nhtsa-10146.yaml").read_text())
    raw["tests"][0]["data"]["file"] = str(tmp_path / "v10146.EV5")
    err = refused(tmp_path, capsys, raw, "tests.0.data.file (the speed its header gives): 11.1111 m/s (40 km/h), but")
    assert "vehicle.speed" not in err


def test_a_clean_accelerometer_told_another_speed_names_no_offset(tmp_path, capsys):
    """The pickup's 56 km/h acceleration alone, as recorded, told 80 km/h: refused for its drift,
    and its end's steady 0.09 g, which held over the record adds a twentieth of that drift, is not
    named as an offset that might explain it (OFFSET_SHARE)."""
    raw = np.loadtxt(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv", delimiter=",", skiprows=1)
    problem = _accel_only(tmp_path, raw[:, 0], raw[:, 1], 80)
    problem["tests"][0]["data"]["window"] = ["0 s", "0.2 s"]
    err = refused(tmp_path, capsys, problem, "vehicle.speed: ")
    assert "toward the barrier at" in err and "offset" not in err


def test_a_record_cut_while_an_engine_pulls_the_body_back_is_taken(tmp_path):
    """Of the corpus's records cut short (seeds 3100 and 3200, every 2 ms), the one whose end pushes
    the body toward the barrier most (6 % of its peak on average: its engine on its mounts pulls it
    back) does so unsteadily: its pulse goes on, and it is taken."""
    from bench import corpus

    v = corpus.engine_vehicle(17, 3100, speed=72 / 3.6)
    recorded = corpus.measured(v, corpus.simulate(v, duration=0.108))
    raw = _accel_only(tmp_path, recorded["time_s"], recorded["accel_x_g"], 72, v.mass)
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
    assert main(["identify", str(tmp_path / "p.yaml"), "--check"]) == 0


@pytest.mark.parametrize(
    ("maker", "seed", "index", "kmh"),
    [("tall_vehicle", 3200, 4, 56), ("random_vehicle", 7777, 0, 64)],
    ids=["drifts-most", "rebounds-most"],
)
def test_generator_accelerometers_at_their_own_speed_are_taken(tmp_path, maker, seed, index, kmh):
    """DRIFT_LIMIT and REBOUND_LIMIT were argued, not fitted; on 271 generator records of seeds 7777
    and 3200 (every form, 40 to 64 km/h) the recorded acceleration, integrated unfiltered, drifts
    toward the barrier at 3.7 % of the speed at most and rebounds at 28 % (docs/design-notes.md):
    the two that come nearest, read alone at their own speed, are taken."""
    from bench import corpus
    from bench.cross_speed import at_speed

    v = at_speed(getattr(corpus, maker)(index, seed, speed=56 / 3.6), kmh)
    recorded = corpus.measured(v, corpus.simulate(v))
    rows = zip(recorded["time_s"], recorded["accel_x_g"])
    (tmp_path / "accel.csv").write_text("time_s,accel_x_g\n" + "".join(f"{t:.6f},{a:.6f}\n" for t, a in rows))
    test = pickup()["tests"][0]
    data = {**test["data"], "file": str(tmp_path / "accel.csv"), "channels": {"accel": test["data"]["channels"]["accel"]}}
    raw = pickup({"vehicle": {"speed": f"{kmh} km/h", "mass": f"{v.mass} kg"}, "tests": [{"name": "a", "data": data}]})
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
    assert main(["identify", str(tmp_path / "p.yaml"), "--check"]) == 0


def test_a_velocity_channel_in_the_wrong_unit_is_named_not_the_speed(tmp_path, capsys):
    """The speed has its unit and the velocity column is in m/s, read as km/h: the channel's unit is
    at fault, named as the key (it said `vehicle.speed: ... a plain number is m/s, not km/h`), by
    the acceleration beside it, or without one by the speed its numbers are."""
    test = pickup()["tests"][0]
    channels = {**test["data"]["channels"], "velocity": {"column": "vel_x_mps", "unit": "km/h"}}
    raw = pickup({"tests": [{**test, "data": {**test["data"], "channels": channels}}]})
    err = refused(tmp_path, capsys, raw, "tests.0.data.channels.velocity.unit: the acceleration of test 56kph")
    assert err.endswith("most likely the velocity channel's\n")
    raw = pickup({"tests": [{**test, "data": {**test["data"], "channels": {"velocity": channels["velocity"]}}}]})
    err = refused(tmp_path, capsys, raw, "tests.0.data.channels.velocity.unit: 15.5556 m/s (56 km/h), but the velocity data")
    assert err.endswith("the column's numbers are the speed in m/s: the velocity channel's unit is not km/h\n")


def _scaled_pickup(tmp_path: Path, column: str, factor: float) -> str:
    """The shipped pickup's CSV with one column times `factor` (written in another unit), its path."""
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    k = header.split(",").index(column)
    rows = [[f"{float(c) * factor:.6g}" if j == k else c for j, c in enumerate(line.split(","))] for line in lines]
    (tmp_path / "scaled.csv").write_text("\n".join([header, *(",".join(r) for r in rows)]) + "\n")
    return str(tmp_path / "scaled.csv")


@pytest.mark.parametrize(
    ("column", "factor", "channels", "window", "expected"),
    [
        ("vel_x_mps", 3.6, ("velocity",), None, "tests.0.data.channels.velocity.unit: 15.5556 m/s"),
        ("vel_x_mps", 3.6, ("accel", "velocity"), None, "tests.0.data.channels.velocity.unit: the acceleration"),
        ("vel_x_mps", -1.0, ("velocity",), None, "tests.0.data.channels.velocity.sign: 15.5556 m/s"),
        ("vel_x_mps", 1.0, ("accel", "velocity"), ["0.01 s", "0.2 s"], "tests.0.data.window: 15.5556 m/s"),
        ("accel_x_g", 9.80665, ("accel",), None, "tests.0.data.channels.accel.unit: 15.5556 m/s"),
    ],
)
def test_data_that_part_from_the_speed_by_a_unit_sign_or_window_name_that_not_the_speed(
    tmp_path, capsys, column, factor, channels, window, expected
):
    """A velocity column written in km/h and read as m/s (alone, or beside an acceleration that
    changes the velocity 3.6 times less), one read with the wrong sign, a window that starts after
    impact, and an acceleration written in m/s^2 read as g (it throws the vehicle back at 10 times
    the speed): each was refused as `vehicle.speed`, and names the channel's unit or sign, or the
    window."""
    test = pickup()["tests"][0]
    data = {**test["data"], "file": _scaled_pickup(tmp_path, column, factor)}
    data["channels"] = {name: data["channels"][name] for name in channels}
    data["channels"].setdefault("velocity", {"derive": "integrate"})
    if window is not None:
        data["window"] = window
    refused(tmp_path, capsys, pickup({"tests": [{**test, "data": data}]}), expected)


@pytest.mark.parametrize(
    ("rows", "expected"),
    [
        (slice(0, 1), "channel accel (column accel_x_g): fewer than two samples"),
        (slice(0, 451), "tests.0.data.window: runs to 200 ms, but the data of test 56kph end at 45 ms (cut.csv, channel"),
        (slice(300, None), "cut.csv: time column time_s: the record begins 30 ms after impact (t = 0 is the first contact)"),
    ],
    ids=["one-row", "mid-crush", "head-cut"],
)
def test_a_record_cut_short_is_refused_saying_where_it_ends_or_begins(tmp_path, capsys, rows, expected):
    header, *lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines(keepends=True)
    cut = tmp_path / "cut.csv"
    cut.write_text(header + "".join(lines[rows]))
    test = pickup()["tests"][0]
    refused(tmp_path, capsys, pickup({"tests": [{**test, "data": {**test["data"], "file": str(cut)}}]}), expected)


def camry(vehicle: dict, test: dict) -> dict:
    """The shipped Camry problem (mass and speed from its EV5 header) with `vehicle` and its test's entries merged in."""
    raw = yaml.safe_load((ROOT / "problems/nhtsa-10146.yaml").read_text())
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    raw["tests"][0].update(test)
    return merge(raw, {"vehicle": vehicle})


def test_a_header_speed_the_problem_contradicts_is_refused(tmp_path, capsys):
    raw = camry({}, {"speed": 57.09})  # km/h meant
    err = refused(tmp_path, capsys, raw, "tests.0.speed: 57.09 m/s (205.5 km/h), but the data header")
    assert err.endswith("57.09 is 3.6 times the data's: a plain number is m/s, not km/h)\n")


@pytest.mark.parametrize(
    "vehicle, test, expected",
    [
        (
            {"speed": "60 km/h"},
            {},
            "vehicle.speed: 16.6667 m/s (60 km/h), but the data header of test 10146 says 15.8583 m/s (57.09 km/h) "
            "(more than 5 % apart)\n",
        ),
        (
            {"mass": "2500 kg"},
            {},
            "vehicle.mass: 2500 kg, but the data header of test 10146 says 1719 kg (more than 10 % apart; the fitted "
            "forces scale with the mass)\n",
        ),
        ({}, {"mass": "1500 kg"}, "tests.0.mass: 1500 kg, but the data header of test 10146 says 1719 kg (more than 10 %"),
    ],
    ids=["speed-in-km/h", "vehicle-mass", "test-mass"],
)
def test_a_speed_or_mass_the_data_header_contradicts_is_refused(tmp_path, capsys, vehicle, test, expected):
    """A 45 % heavier vehicle fits as well, every force 45 % larger: refused as a 5 % speed is, both
    units said (a problem may give either); a few percent of ballast are not refused."""
    err = refused(tmp_path, capsys, camry(vehicle, test), expected)
    assert "plain number" not in err
    (tmp_path / "ok.yaml").write_text(yaml.safe_dump(camry({"mass": "1780 kg"}, {})))
    assert main(["identify", str(tmp_path / "ok.yaml"), "--check"]) == 0


@pytest.mark.parametrize("unit", ["ms", "h"])
def test_a_time_unit_that_makes_the_sample_rate_absurd_is_refused(tmp_path, capsys, unit):
    raw = pickup({"tests": [merge(pickup()["tests"][0], {"data": {"time": {"column": "time_s", "unit": unit}}})]})
    refused(tmp_path, capsys, raw, "is the time unit right?")


def test_identify_refuses_a_duration_its_data_window_overrides(tmp_path, capsys):
    raw = pickup({"tests": [{**pickup()["tests"][0], "duration": "0.25 s"}]})
    refused(tmp_path, capsys, raw, "tests.0.duration: 0.25 s would be ignored")


def _bad_cell(tmp_path: Path) -> dict:
    """The pickup problem reading a copy of its CSV whose accel cell on line 101 is not a number."""
    source = Path(pickup()["tests"][0]["data"]["file"])
    lines = source.read_text().splitlines()
    lines[100] = ",".join([lines[100].split(",")[0], "abc", *lines[100].split(",")[2:]])
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    return pickup({"tests": [merge(pickup()["tests"][0], {"data": {"file": str(tmp_path / "bad.csv")}})]})


EV5 = ROOT / "problems/data/nhtsa-10146/v10146.EV5"
CSV = ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv"


@pytest.mark.parametrize(
    "raw, expected",
    [
        (
            lambda _: camry({}, {"data": {**camry({}, {})["tests"][0]["data"], "channels": {"accel": {"curves": [93, 999]}}}}),
            f"tests.0.data.channels.accel: {EV5}: channel accel (curve 999): curve not in the INSTRUMENTATION card\n",
        ),
        (
            lambda _: pickup({"tests": [merge(pickup()["tests"][0], {"data": {"channels": {"velocity": {"column": "vel_x"}}}})]}),
            f"tests.0.data.channels.velocity: {CSV}: channel velocity: no column 'vel_x' (columns time_s,",
        ),
        (
            _bad_cell,
            "tests.0.data.channels.accel: {tmp}/bad.csv: channel accel (column accel_x_g): line 101: 'abc' is not a number\n",
        ),
        (
            lambda _: pickup({"tests": [merge(pickup()["tests"][0], {"data": {"time": {"column": "time_s", "unit": "kg"}}})]}),
            f"tests.0.data.time: {CSV}: channel time: unit 'kg' is not a time\n",
        ),
        (
            lambda _: pickup({"tests": [merge(pickup()["tests"][0], {"data": {"window": ["5 s", "6 s"]}})]}),
            f"tests.0.data.window: {CSV}: channel accel: window 5 s to 6 s holds no samples\n",
        ),
    ],
    ids=["ev5-curve", "csv-column", "csv-cell", "csv-time-unit", "window"],
)
def test_a_data_error_names_the_problem_key_and_the_data_file(tmp_path, capsys, raw, expected):
    """The one line names the problem file and the key that led to the data, then the data file and
    what in it is wrong; through the Python API the problem's name and the same key."""
    raw, expected = raw(tmp_path), expected.replace("{tmp}", str(tmp_path))
    refused(tmp_path, capsys, raw, f"crashnlp: error: {tmp_path / 'p.yaml'}: {expected}")
    with pytest.raises(InputError, match=f"^{raw['name']}: {re.escape(expected.rstrip())}"):
        crashnlp.identify(problem_from_dict(raw, tmp_path))


# --------------------------------------------------------------------------- files
def test_a_file_that_is_not_utf8_is_one_line(tmp_path, capsys):
    refused(tmp_path, capsys, b"name: caf\xe9\nvehicle: {}\n", "not valid UTF-8")


def test_duplicate_keys_are_refused(tmp_path, capsys):
    text = PICKUP.read_text().replace("  mass: 2550 kg\n", "  mass: 2550 kg\n  mass: 1200 kg\n")
    text = text.replace("file: data/", f"file: {ROOT}/problems/data/")
    refused(tmp_path, capsys, text, "duplicate key 'mass'")


def test_all_missing_and_unknown_keys_are_reported_at_once(tmp_path, capsys):
    raw = merge(BASE, {"vehicle": {"cg_to_impact": None, "cg_to_front_axle": None, "colour": "red"}, "model": None})
    err = refused(tmp_path, capsys, raw, "vehicle.cg_to_impact: missing key", command="simulate")
    for part in ("vehicle.cg_to_front_axle: missing key", "vehicle.colour: unknown key", "model: missing key"):
        assert part in err


def test_params_of_another_problem_name_the_length_mismatch(tmp_path, capsys):
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(BASE))
    params = tmp_path / "result.json"
    params.write_text(json.dumps({"parameters": {"model.spring.values": [1e5] * 9}}))
    code, _, err = run(["simulate", str(problem), "--params", str(params), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "parameters.model.spring.values: 9 values, but unit has 8" in err and "length mismatch" in err
    assert not (tmp_path / "o").exists()


BAD_PARAMS = {
    "not a parameter": {"vehicle.colour": 1.0},
    "another problem's length": {"model.spring.values": [1e5] * 9},
    "not finite": {"vehicle.mass": float("nan")},
    "beyond any physical value": {"vehicle.mass": 1e13},
    "not a number": {"vehicle.mass": "heavy"},
}


@pytest.mark.parametrize("name", list(BAD_PARAMS))
def test_the_api_and_the_command_line_refuse_the_same_params(tmp_path, capsys, name):
    """`crashnlp.simulate(params={...})` and `crashnlp simulate --params result.json` check a fit's
    parameters in one place (crashnlp.problem.parameters): one line naming the key, the same but
    for the source (the file, or crashnlp.simulate); exit 2 and nothing written."""
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(BASE))
    params = tmp_path / "result.json"
    params.write_text(json.dumps({"parameters": BAD_PARAMS[name]}))
    code, _, err = run(["simulate", str(problem), "--params", str(params), "--out", str(tmp_path / "o")], capsys)
    with pytest.raises(InputError) as api:
        crashnlp.simulate(problem, params=BAD_PARAMS[name])
    assert str(api.value).startswith("crashnlp.simulate: ") and "\n" not in str(api.value)
    assert code == 2 and err == f"crashnlp: error: {str(api.value).replace('crashnlp.simulate', str(params), 1)}\n"
    assert not (tmp_path / "o").exists()


def test_an_output_folder_that_cannot_be_written_is_refused_before_solving(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(pickup()))
    for out in (blocker, blocker / "sub"):
        code, stdout, err = run(["identify", str(problem), "--out", str(out)], capsys)
        assert code == 2 and err.startswith(f"crashnlp: error: --out {out}") and err.count("\n") == 1
        assert "iter" not in stdout  # nothing was solved


def test_usage_errors_are_one_line(capsys):
    for argv in (["frob"], [], ["simulate"], ["study", "x.yaml", "--workers", "two"]):
        code, _, err = run(argv, capsys)
        assert code == 2 and err.count("\n") == 1 and err.startswith("crashnlp: error:"), (argv, err)
    assert run(["--help"], capsys)[0] == 0


def test_files_are_written_with_the_mode_the_umask_gives(tmp_path):
    old = os.umask(0o027)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
        CaseStore(tmp_path / "cases").save("case-000", "k", {"status": "ok"}, np.ones(3))
    finally:
        os.umask(old)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o640
    for name in ("case-000.json", "case-000.npy"):
        assert (tmp_path / "cases" / name).stat().st_mode & 0o777 == 0o640


@pytest.mark.integration
def test_simulate_writes_to_a_folder_of_its_own(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "t56", "duration": 0.05}]})))
    code, out, _ = run(["simulate", str(problem)], capsys)
    assert code == 0 and "wrote results/unit/simulation/" in out
    assert (tmp_path / "results/unit/simulation/simulation.json").is_file()
    assert not (tmp_path / "results/unit/t56").exists()


@pytest.mark.integration
def test_the_readme_example_problem_runs_as_written(tmp_path, capsys):
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```yaml\n(.*?)```", text, re.S).group(1)
    (tmp_path / "data").symlink_to(ROOT / "problems/data")
    path = tmp_path / "example.yaml"
    path.write_text(block)
    code, out, err = run(["identify", str(path), "--out", str(tmp_path / "out"), "--check"], capsys)
    assert code == 0 and "ok (1 tests" in out, err  # all but the solve (15 s with the figures and ratings)
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- failures the input did not cause
def test_an_integrator_failure_is_one_line_and_exit_1(tmp_path, capsys, monkeypatch):
    from crashnlp.case.case import Case

    def fail(self, *a, **k):
        raise RuntimeError(
            ".../casadi/core/function.cpp:1458: Error in Function::call for 'sim' [CvodesInterface]\n"
            '.../cvodes_interface.cpp:300: CVode returned "CV_FIRST_RHSFUNC_ERR".'
        )

    monkeypatch.setattr(Case, "simulate_test", fail)
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(BASE))
    code, _, err = run(["simulate", str(problem), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and err.count("\n") == 1 and "CV_FIRST_RHSFUNC_ERR" in err and "Traceback" not in err
    code, _, err = run(["simulate", str(problem), "--out", str(tmp_path / "o"), "--debug"], capsys)
    assert code == 1 and "Traceback" in err


def test_a_write_failure_is_one_line_and_exit_1(tmp_path, capsys, monkeypatch):
    import crashnlp.results.simulation

    def fail(*a, **k):
        raise OSError(28, "No space left on device", str(tmp_path / "o/simulation.json"))

    monkeypatch.setattr(crashnlp.results.simulation, "write_simulation", fail)
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "t56", "duration": 0.05}]})))
    code, _, err = run(["simulate", str(problem), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and err.count("\n") == 1 and "No space left on device" in err


@pytest.mark.integration
def test_an_unreachable_dask_scheduler_fails_in_time(tmp_path):
    started = time.monotonic()
    proc = subprocess.run(
        [
            *CLI,
            "study",
            str(ROOT / "problems/studies/pitch-bound.yaml"),
            "--executor",
            "dask",
            "--address",
            "tcp://127.0.0.1:1",
            "--timeout",
            "2",
            "--out",
            str(tmp_path / "o"),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert time.monotonic() - started < 20
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "--address tcp://127.0.0.1:1: no dask scheduler answered within 2 s" in proc.stderr
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- study resume and signals
def test_corrupt_case_files_are_solved_again(tmp_path):
    store = CaseStore(tmp_path)
    store.save("case-000", "k", {"status": "ok"}, np.ones(4))
    assert store.row("case-000", "k") == {"status": "ok"}
    (tmp_path / "case-000.npy").write_bytes(b"")
    assert store.row("case-000", "k") is None
    store.save("case-000", "k", {"status": "ok"}, np.ones(4))
    (tmp_path / "case-000.npy").write_bytes((tmp_path / "case-000.npy").read_bytes()[:-8])
    assert store.row("case-000", "k") is None
    for text in ("", "[1, 2]", '{"key": "k"}', '{"key": "k", "row": {"status": 3}}', "\xff"):
        (tmp_path / "case-000.json").write_text(text, encoding="latin-1")
        assert store.row("case-000", "k") is None


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_killing_a_study_leaves_no_process_and_the_rerun_resumes(tmp_path):
    study = ROOT / "problems/studies/pitch-bound.yaml"
    out = tmp_path / "study"
    argv = [*CLI, "study", str(study), "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    children: set[int] = set()
    # until the tracker, the fork server and two workers are up, or a first case is done (the
    # study must not finish before it is signalled)
    while time.monotonic() < deadline and len(children) < 4 and not list(out.glob("cases/*.json")):
        time.sleep(0.1)
        children |= descendants(proc.pid)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].startswith("crashnlp: interrupted (SIGTERM)") and "Traceback" not in err
    time.sleep(1.0)
    assert not [p for p in children if _alive(p)], "processes left behind"
    rerun = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    table = (out / "table.csv").read_text().splitlines()
    assert len(table) == 5 and all(",ok," in row for row in table[1:])


@pytest.mark.integration
@pytest.mark.skipif(not Path("/proc").is_dir() or shutil.which("cc") is None, reason="needs /proc and a C compiler")
def test_sigterm_stops_a_study_its_workers_and_their_background_compiles(tmp_path):
    """With the NLPs compiled (unlike the other tests), SIGTERM once a worker's background
    compile is running: nothing the study started survives, the cache holds no partial library,
    and the message names no folder that does not exist."""
    cache, out = tmp_path / "cache", tmp_path / "study"
    env = {k: v for k, v in os.environ.items() if k not in ("CRASHNLP_COMPILE", "CRASHNLP_KEEP_COMPILING")}
    env["CRASHNLP_CACHE"] = str(cache)
    argv = [*CLI, "study", str(ROOT / "problems/studies/pitch-bound.yaml"), "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, started = time.monotonic() + 60, set()
    while time.monotonic() < deadline and not any("cc1" in command(p) for p in started):
        time.sleep(0.1)
        started |= descendants(proc.pid)
    started |= descendants(proc.pid)
    assert any("cc1" in command(p) for p in started), "no background compile was started"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and any(_alive(p) for p in started):
        time.sleep(0.1)
    assert not [command(p) for p in started if _alive(p)], "processes left behind"
    assert not [p.name for p in cache.iterdir() if p.suffix in (".c", ".tmp", ".so")], "a compile's files left behind"
    # the last line of crashnlp's own: the pool's resource tracker may warn after it, as it exits
    line = [text for text in err.strip().splitlines() if text.startswith("crashnlp: ")][-1]
    assert line.startswith("crashnlp: interrupted (SIGTERM)"), err
    assert all(Path(folder).is_dir() for folder in re.findall(r"(\S+)/:", line)), line
    assert "kept in" in line or "no case had finished" in line, line


@pytest.mark.integration
def test_a_stopped_compile_ends_its_whole_group_and_leaves_no_file(tmp_path):
    from crashnlp.numerics import compile_job

    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    job = _compiling(tmp_path)
    group = descendants(job.pid) | {job.pid}
    assert any("cc1" in command(p) for p in group)
    compile_job.stop_compiles()
    time.sleep(0.2)
    assert not [command(p) for p in group if _alive(p)]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.integration
def test_kill_with_the_pid_the_line_names_stops_the_compiler_too_and_leaves_no_file(tmp_path):
    """`kill PID` with the compile's pid (the one the background line prints) ends its whole group,
    cc1 too, and the compile removes its files."""
    from crashnlp.numerics import compile_job

    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    job = _compiling(tmp_path)
    try:
        group = descendants(job.pid) | {job.pid}
        assert any("cc1" in command(p) for p in group)
        os.kill(job.pid, signal.SIGTERM)
        assert job.wait(timeout=10) == 1
        time.sleep(0.2)
        assert not [command(p) for p in group if _alive(p)]
        assert list(tmp_path.iterdir()) == []
    finally:
        compile_job.stop_compiles([job])


def _compiling(tmp_path: Path):
    """A compile of `_big_source` into tmp_path, once its cc1 runs (or 10 s on)."""
    from crashnlp.numerics import compile_job

    source = _big_source(tmp_path / "big.c")
    job = compile_job.start("cc", source, tmp_path / "big.so", ("-O2", "-fPIC", "-shared"), cleanup=(source,))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not any("cc1" in command(p) for p in descendants(job.pid)):
        time.sleep(0.05)
    return job


def _big_source(path: Path) -> Path:
    """C that takes cc several seconds: a compile that is still running when it is looked at."""
    path.write_text("".join(f"double f{i}(double x) {{ return x * {i} + x * x / {i + 1}; }}\n" for i in range(100_000)))
    return path


def _nice(pid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, pid)


@pytest.mark.integration
def test_a_released_compile_goes_on_at_the_lowest_priority_and_says_so(tmp_path, capsys, monkeypatch):
    """The end of a command (the default): the compile's whole group, cc1 too, goes on at nice 19
    after its starter let go of it, and one line on stderr says so and how to turn it off."""
    from crashnlp.numerics import compile_job

    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    monkeypatch.delenv(compile_job.KEEP_ENV, raising=False)
    job = _compiling(tmp_path)
    try:
        assert _nice(job.pid) < compile_job.BACKGROUND_NICE  # the command's own priority while it runs
        assert compile_job.release_compiles() == [job.pid]
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and _nice(job.pid) != compile_job.BACKGROUND_NICE:
            time.sleep(0.05)
        group = descendants(job.pid) | {job.pid}
        assert any("cc1" in command(p) for p in group)
        assert {_nice(p) for p in group} == {compile_job.BACKGROUND_NICE}
        assert job.poll() is None, "the released compile was stopped"
    finally:
        os.killpg(job.pid, signal.SIGTERM)
        job.wait(timeout=30)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "in the background" in err[0] and f"{compile_job.KEEP_ENV}=0" in err[0], err
    assert list(tmp_path.iterdir()) == [], "a stopped compile left files"


@pytest.mark.integration
def test_a_compile_no_run_waits_for_gives_way_from_its_start_and_is_named(tmp_path, capsys, monkeypatch):
    """A compile started at nice 19 (the ISO 18571 rating's time warping: no run waits for it)
    runs so from its start, cc1 too, while its starter still runs; released with an NLP's compile,
    one line names both."""
    from crashnlp.numerics import compile_job

    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    monkeypatch.delenv(compile_job.KEEP_ENV, raising=False)
    jobs = [
        compile_job.start("cc", _big_source(tmp_path / f"{name}.c"), tmp_path / f"{name}.so", ("-O2", "-fPIC", "-shared"), **kw)
        for name, kw in (("nlp", {}), ("kernel", {"what": "the kernel", "nice": compile_job.BACKGROUND_NICE}))
    ]
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not all(any("cc1" in command(p) for p in descendants(j.pid)) for j in jobs):
            time.sleep(0.05)
        assert {_nice(p) for p in descendants(jobs[1].pid) | {jobs[1].pid}} == {compile_job.BACKGROUND_NICE}
        assert _nice(jobs[0].pid) < compile_job.BACKGROUND_NICE
        assert compile_job.release_compiles() == [j.pid for j in jobs]
    finally:
        for job in jobs:
            os.killpg(job.pid, signal.SIGTERM)
            job.wait(timeout=30)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "compiling this problem's NLP and the kernel in the background" in err[0], err


@pytest.mark.integration
def test_a_released_compile_finishes_its_library_and_the_switch_stops_it(tmp_path, capsys, monkeypatch):
    """Released, a compile outlives its starter's letting go and leaves the library and its record
    (its source removed); with CRASHNLP_KEEP_COMPILING=0 the end of a command stops it, silently."""
    from crashnlp.numerics import compile_job

    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    monkeypatch.delenv(compile_job.KEEP_ENV, raising=False)
    source = tmp_path / "small.c"
    source.write_text("double twice(double x) { return 2 * x; }\n")
    job = compile_job.start("cc", source, tmp_path / "small.so", ("-O1", "-fPIC", "-shared"), cleanup=(source,))
    compile_job.release_compiles()
    assert job.wait(timeout=60) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.sha256", "small.so"]
    monkeypatch.setenv(compile_job.KEEP_ENV, "0")
    capsys.readouterr()
    source = _big_source(tmp_path / "big.c")
    job = compile_job.start("cc", source, tmp_path / "big.so", ("-O2", "-fPIC", "-shared"), cleanup=(source,))
    assert compile_job.release_compiles() == []
    assert job.poll() is not None and not (tmp_path / "big.so").exists() and not source.exists()
    assert capsys.readouterr().err == ""


# a script using crashnlp as a library: it starts a compile, as crashnlp.identify does on a new
# shape, prints the compile's process id, and ends normally or by Ctrl-C
LIBRARY_SCRIPT = """
import sys
from pathlib import Path
from crashnlp.numerics import compile_job
source = Path(sys.argv[1])
job = compile_job.start("cc", source, source.with_suffix(".so"), ("-O2", "-fPIC", "-shared"), cleanup=(source,))
print(job.pid, flush=True)
if sys.argv[2] == "interrupted":
    raise KeyboardInterrupt
"""


@pytest.mark.integration
@pytest.mark.parametrize("ending", ["normal", "interrupted"])
def test_a_script_s_compiles_finish_after_it_at_the_lowest_priority_unless_ctrl_c_ended_it(tmp_path, ending):
    """The Python API's compiles, left running by the script, go on at nice 19 after its
    interpreter exits, with the command line's one line; a script ended by Ctrl-C stops them and
    their files go, as a command's do."""
    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    source = _big_source(tmp_path / "big.c")
    env = {k: v for k, v in os.environ.items() if k != "CRASHNLP_KEEP_COMPILING"}
    script = subprocess.run(
        [sys.executable, "-c", LIBRARY_SCRIPT, str(source), ending], env=env, capture_output=True, text=True, timeout=60
    )
    pid = int(script.stdout.split()[0])
    lines = [line for line in script.stderr.splitlines() if line.startswith("crashnlp:")]
    try:
        if ending == "interrupted":
            assert lines == [], script.stderr
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and _alive(pid):
                time.sleep(0.05)
            assert not _alive(pid), "the compile outlived a script ended by Ctrl-C"
        else:
            assert len(lines) == 1 and "in the background" in lines[0] and f"pid {pid}" in lines[0], script.stderr
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and _alive(pid) and _nice(pid) != 19:
                time.sleep(0.05)
            assert _alive(pid) and _nice(pid) == 19, "the released compile is not running at nice 19"
    finally:
        if _alive(pid):
            os.killpg(pid, signal.SIGTERM)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (_alive(pid) or list(tmp_path.iterdir())):
            time.sleep(0.1)
    assert list(tmp_path.iterdir()) == [], "a stopped compile left files"


def test_a_command_that_succeeds_releases_its_compiles_and_any_other_ending_stops_them(monkeypatch, capsys):
    """Only exit 0 lets a compile finish after the command: a failed one's line stays its only one."""
    import crashnlp.cli as cli

    endings: list[str] = []
    monkeypatch.setattr(cli, "release_compiles", lambda: endings.append("released"))
    monkeypatch.setattr(cli, "stop_compiles", lambda: endings.append("stopped"))
    assert main(["schema"]) == 0
    assert main(["identify", "no-such-problem.yaml"]) == 2
    assert endings == ["released", "stopped"]
    capsys.readouterr()


def test_a_yaml_bomb_is_refused(tmp_path, capsys):
    levels = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for k in range(1, 10):
        levels.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 12) + "]")
    refused(tmp_path, capsys, "\n".join(levels) + "\n", "more than 100 aliases")


def test_a_study_refuses_data_that_contradict_a_case(tmp_path, capsys):
    raw = pickup({"vehicle": {"speed": 56}, "tests": [{**pickup()["tests"][0], "speed": 56}]})
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"name": "s", "problem": "p.yaml", "sweep": {"constraints.bounds.pitch": [[None, "4 deg"]]}}))
    code, _, err = run(["study", str(study), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert code == 2 and err.count("\n") == 1 and "case-000" in err and "speed and data disagree" in err
    assert not (tmp_path / "out").exists()


def test_a_mass_no_vehicle_has_is_refused_before_the_integrator_sees_it(tmp_path, capsys):
    refused(tmp_path, capsys, pickup({"vehicle": {"mass": "1e-9 kg"}}), "vehicle.mass: 1e-09 kg is no vehicle's mass")
    refused(tmp_path, capsys, pickup({"vehicle": {"speed": "2000 km/h"}}), "vehicle.speed: ")


@pytest.mark.integration
def test_ctrl_c_inside_ipopt_ends_the_run_as_interrupted_and_writes_nothing(tmp_path, capsys, monkeypatch):
    from crashnlp.optimize.watch import Watch

    iteration = Watch.eval

    def interrupted_at_the_third(self, arg):  # the user's Ctrl-C, while IPOPT iterates
        if self.count == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return iteration(self, arg)

    monkeypatch.setattr(Watch, "eval", interrupted_at_the_third)
    out = tmp_path / "out"
    code, _, err = run(["design", str(ROOT / "problems/design-crush-space.yaml"), "--out", str(out)], capsys)
    assert code == 130 and err == "crashnlp: interrupted (SIGINT)\n", err
    assert not out.exists()


@pytest.mark.parametrize("name", ["../escape", "a/b", "..", "", "x\x00"])
def test_a_name_that_would_leave_the_results_folder_is_refused(tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    refused(tmp_path, capsys, merge(BASE, {"name": name}), "name: ", command="simulate")
    refused(tmp_path, capsys, merge(BASE, {"tests": [{"name": name, "duration": 0.1}]}), "tests.0.name: ", command="simulate")
    assert not (tmp_path / "results").exists() and not (tmp_path.parent / "escape").exists()
