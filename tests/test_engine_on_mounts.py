"""Physics of the engine-on-mounts form (model.form: engine-on-mounts): its equations against the
corpus generator's (bench.corpus, written without crashnlp), its energy audit, its defaults from
the data, what it refuses, and a fit recovering its own parameters, whose predictions take the
form's own calibration table (and, without one, give no intervals and say so)."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
import yaml
from builders import BASE, make_case, merge, write_channels

import crashnlp
from bench.corpus import Body, engine_vehicle
from bench.corpus import simulate as generate
from bench.cross_speed import fit_problem
from bench.forms import with_form
from crashnlp.analysis import prediction
from crashnlp.analysis.calibration import shipped
from crashnlp.analysis.energy import energy_audit
from crashnlp.base.errors import InputError
from crashnlp.base.outputs import PREDICTED_KEYS
from crashnlp.case.case import Case
from crashnlp.case.completion import pulse
from crashnlp.cli import main
from crashnlp.data.channels import Channel, TestData
from crashnlp.models.engine_on_mounts import CONTACT_WIDTH, ENGINE_SHARE, GAP_BOUNDS, MOUNT_FREQUENCY, default_gap
from crashnlp.problem.load import load_problem

ENGINE = {"mass": 380.0, "mount_stiffness": 1.5e6, "mount_damping": 2.4e4, "gap": 0.3}
ENGINE |= {"contact_stiffness": 8e6, "contact_damping": 5e4}
FORM = {"model": {"form": "engine-on-mounts"}, "vehicle": {"engine": ENGINE, "crush_offset": 0.0}}  # the form reads no offset


def engine_case(changes: dict | None = None):
    return make_case(merge(merge(BASE, FORM), changes or {}))


def _straight_generator(v):
    """`v` with a load curve that is a straight line (its monotone cubic through the knots is that
    line, so that crashnlp's piecewise-linear law of two breakpoints is the generator's), without
    crush damping or the wall's vertical force, which the form does not have."""
    slope = v.load_force[4] / v.load_crush[4]
    return dataclasses.replace(v, load_force=tuple(slope * c for c in v.load_crush), crush_damping=0.0, vertical_ratio=0.0)


def _generators_case(v):
    body = ("mass", "pitch_inertia", "cg_to_impact", "cg_above_impact", "cg_to_front_axle", "cg_to_rear_axle")
    top = v.load_crush[-1]
    return make_case(
        {
            "vehicle": {
                **{k: getattr(v, k) for k in body},
                "speed": v.speed,
                "crush_offset": 0.0,
                "suspension": {"k_front": v.k_front, "k_rear": v.k_rear, "c_front": v.c_front, "c_rear": v.c_rear},
                "engine": dataclasses.asdict(v.engine),
            },
            "model": {
                "form": "engine-on-mounts",
                "spring": {"crush_breakpoints": [0.0, top], "values": [0.0, float(Body(v).load(top))]},
                "damper": None,
                "unloading": {"law": "plastic", "stiffness": v.unloading_stiffness},
                "smoothing": {"crush": 0.0, "rate": 0.0},
            },
        }
    )


def test_equations_are_the_corpus_generators():
    """At states with the front end loading or unloading and the engine off the barrier, touching it
    or pushed back by it, the form's accelerations (exact hinges: no smoothing) are those of
    bench.corpus.Body, written without crashnlp: x, z, phi, and the engine's travel on its mounts."""
    v = _straight_generator(engine_vehicle(0, 3200, speed=56 / 3.6))
    case = _generators_case(v)
    assert case.model.states() == ("x", "z", "phi", "u", "xdot", "zdot", "phidot", "udot", "x_max")
    body, p = Body(v), case.base
    gap = v.engine.gap
    states = [  # x, z, phi, u, xdot, zdot, phidot, udot, x_max
        (0.10, -0.01, 0.02, 0.03, 12.0, 0.2, 0.5, 1.0, 0.2),  # unloading, engine off the barrier
        (gap - 0.02, 0.01, 0.05, 0.05, 9.0, -0.3, 1.0, 2.0, gap + 0.1),  # engine in contact, closing
        (gap, 0.02, 0.08, 0.04, 2.0, -0.1, -0.5, -3.0, gap + 0.05),  # engine in contact, pushed back
        (gap + 0.1, 0.0, 0.1, -0.02, 1.0, 0.1, 0.2, -1.0, gap + 0.2),  # engine behind its gap again
    ]
    for s in states:
        x = np.array(s)
        generator = body.rhs(0.0, np.array([s[0], s[1], s[2], s[4], s[5], s[6], s[8], s[3], s[7]]))
        form = np.asarray(case.model.rhs(x, p)).ravel()
        np.testing.assert_allclose(form[4:8], generator[[3, 4, 5, 8]], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(form[:4], x[4:8])


def test_the_barrier_force_and_the_crash_are_the_generators():
    """Simulated at 56 km/h, the form gives the generator's travel, pitch and barrier force: the
    engine meets the barrier late, carries part of its impulse, and does not pitch the body."""
    v = _straight_generator(engine_vehicle(0, 3200, speed=56 / 3.6))
    g = generate(v)
    r = _generators_case(v).simulate()["t56"]
    n = min(g["time"].size, r.time.size)
    assert np.sum(g["engine_force"]) > 0.2 * np.sum(g["barrier_force"])  # the engine's part matters
    assert np.max(np.abs(r["displacement"][:n] - g["displacement"][:n])) < 1e-4
    assert np.max(np.abs(r["velocity"][:n] - g["velocity"][:n])) < 5e-3
    assert np.degrees(np.max(np.abs(r["pitch"][:n] - g["pitch"][:n]))) < 5e-3
    impulse = [np.trapezoid(f[:n], g["time"][:n]) for f in (g["barrier_force"], r["barrier_force"])]
    assert impulse[1] == pytest.approx(impulse[0], rel=2e-3)


def test_the_energy_audit_closes():
    """Smoothed hinges, the engine's contact and mounts included: what the impact brought in is
    what the front end, the engine's contact, the suspension and mount dampers took, and what is
    left as motion and potential energy."""
    case = engine_case({"vehicle": {"speed": "64 km/h"}, "simulation": {"rtol": 1e-11, "atol": 1e-12, "dt": 2e-4}})
    r = case.simulate()["t56"]
    audit = energy_audit(r, 2550.0, case.tests[0].speed)
    assert np.max(r["barrier_force"] - r["contact_force"]) > 1e5  # the engine met the barrier
    assert abs(audit["balance_error_relative"]) < 1e-6
    assert audit["front_end_returned_excess"] <= 1e-6 * audit["impact_kinetic"]
    total = r["kinetic"] + r["potential"] + r["dissipated"]
    assert np.max(np.abs(total - total[0])) < 1e-6 * total[0]


def test_the_engine_pushes_the_barrier_only_once_its_gap_closes():
    """Before the engine (body travel plus its travel on the mounts) reaches its gap, less half the
    contact's width, the barrier force is the front end's alone; the engine's part never pulls."""
    case = engine_case()
    r = case.simulate()["t56"]
    engine = r["barrier_force"] - r["contact_force"]
    x, u = (r.states[case.model.states().index(name)] for name in ("x", "u"))
    reach = x + u - ENGINE["gap"]
    assert np.max(engine[reach < -0.5 * CONTACT_WIDTH]) < 1e-5  # N: the separation band, closed to OPEN of its width
    assert np.min(engine) >= 0.0 and np.max(engine) > 1e5


@pytest.mark.parametrize("corner", [0.0, CONTACT_WIDTH])
def test_the_contact_force_has_no_kink_where_its_damper_engages(corner):
    """The contact's force is once differentiable in the engine's reach where its damper starts
    and ends engaging (reach 0 and CONTACT_WIDTH), the engine closing at 10 m/s: the fitted gap
    moves those corners through the integration steps. A clamped engagement put a jump of
    c v / CONTACT_WIDTH (6 times the contact's stiffness here) into the slope."""
    case = engine_case()
    model = case.model
    contact = model.contacts()[0]
    force = ca.Function("force", [model.x, model.p], [contact.force])
    p = case.test_parameters(case.tests[0])
    moving = np.zeros(model.x.shape[0])
    moving[model.states().index("xdot")] = 10.0

    def slope(reach: float) -> float:
        """dF/dreach by a central difference of 10 nm, the engine's travel on its mounts held at 0."""
        x = [moving.copy() for _ in range(2)]
        for x_i, sign in zip(x, (1, -1)):
            x_i[model.states().index("x")] = ENGINE["gap"] + reach + sign * 1e-8
        return float(force(x[0], p) - force(x[1], p)) / 2e-8

    below, above = slope(corner - 1e-6), slope(corner + 1e-6)
    assert abs(above - below) < 0.05 * ENGINE["contact_stiffness"]
    # the damper's part: engaged, c v on top of the spring's k r
    assert slope(0.5 * CONTACT_WIDTH) > ENGINE["contact_stiffness"]


def test_defaults_come_from_the_vehicle_and_the_recorded_pulse():
    """Left out, the engine's mass is ENGINE_SHARE of the vehicle's, its mounts MOUNT_FREQUENCY, and
    its gap where the recorded pulse of a corpus engine vehicle rises a second time: within 12 % of
    the generator's gap (the body has travelled the gap less the engine's travel on its mounts
    when the engine touches, and the rise shows once the contact has built up)."""
    for index in (0, 2):  # e01: test_a_minimal_problem_fills_the_engine_in_from_its_data_and_estimates_the_gap
        v = engine_vehicle(index, 3200, speed=64 / 3.6)
        g = generate(v)
        units = {"accel": "m/s^2", "velocity": "m/s", "displacement": "m"}
        data = TestData({name: Channel(g["time"], g[name], unit, "generator") for name, unit in units.items()})
        found = default_gap([pulse(data, v.speed, v.mass)])
        assert found == pytest.approx(v.engine.gap, rel=0.12), (index, found, v.engine.gap)
    given = {"gap": 0.3, "contact_stiffness": 8e6}
    case = make_case(merge(BASE, {"model": {"form": "engine-on-mounts"}, "vehicle": {"engine": given}}))
    engine = case.problem.vehicle.engine
    assert engine.mass == pytest.approx(ENGINE_SHARE * 2550.0)
    assert np.sqrt(engine.mount_stiffness / engine.mass) / (2 * np.pi) == pytest.approx(MOUNT_FREQUENCY)
    assert (engine.gap, engine.contact_stiffness) == (0.3, 8e6)
    with pytest.raises(InputError, match=r"^vehicle.engine.gap: not given, and no test has accel or velocity data"):
        make_case(merge(BASE, {"model": {"form": "engine-on-mounts"}}))


def test_a_minimal_problem_fills_the_engine_in_from_its_data_and_estimates_the_gap(tmp_path):
    """The problem `crashnlp init` would write of a corpus engine vehicle's 40 and 64 km/h tests,
    with model.form engine-on-mounts and no engine section: the engine is filled in (the gap from
    the fastest test's pulse, the contact from its mean crush force) and a fit estimates the gap
    within GAP_BOUNDS of that, beside the rigid body's entries."""
    v = engine_vehicle(1, 3200, speed=56 / 3.6)
    case = Case(load_problem(with_form(fit_problem(v, (40.0, 64.0), tmp_path), "engine-on-mounts")))
    engine = case.problem.vehicle.engine
    assert engine.gap == pytest.approx(v.engine.gap, rel=0.12)
    assert engine.contact_stiffness == pytest.approx(v.engine.contact_stiffness, rel=0.5)
    bounds = case.problem.estimate["vehicle.engine.gap"].bounds
    assert bounds == pytest.approx((GAP_BOUNDS[0] * engine.gap, GAP_BOUNDS[1] * engine.gap))
    assert {"model.spring.values", "vehicle.cg_above_impact", "vehicle.pitch_inertia"} <= set(case.problem.estimate)


@pytest.mark.parametrize("gap", [None, "0.4 m"])
def test_an_estimate_that_does_not_name_the_gap_estimates_it_where_the_data_chose_it(tmp_path, gap):
    """The same problem with an estimate of its own (as `crashnlp init` writes and the shipped
    problems give) that names no engine entry: the gap the data chose is estimated too, within
    GAP_BOUNDS of it (held, the pickup's fit had ended at 300 times the objective, silently); a gap the problem
    gives stays as given."""
    v = engine_vehicle(1, 3200, speed=56 / 3.6)
    path = with_form(fit_problem(v, (40.0, 64.0), tmp_path), "engine-on-mounts")
    raw = yaml.safe_load(path.read_text())
    raw["estimate"] = {"model.spring.values": {"bounds": ["0 N", "3 MN"]}}
    if gap is not None:
        raw["vehicle"]["engine"] = {"gap": gap}
    path.write_text(yaml.safe_dump(raw))
    estimate = Case(load_problem(path)).problem.estimate
    assert "model.spring.values" in estimate
    assert ("vehicle.engine.gap" in estimate) == (gap is None)


def test_an_engine_heavier_than_the_vehicle_is_refused_in_one_line():
    with pytest.raises(InputError, match=r"^vehicle.engine.mass: 3000 kg is not less than vehicle.mass") as err:
        engine_case({"vehicle": {"engine": {"mass": "3000 kg"}}})
    assert "\n" not in str(err.value)


def test_a_bad_engine_entry_is_one_line_naming_the_file_and_the_key(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(merge(merge(BASE, FORM), {"vehicle": {"engine": {"gap": "-5 cm"}}})))
    assert main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "vehicle.engine.gap" in err and "must be positive" in err


TRUTH = {"model.spring.values": [0.0, 380e3, 520e3, 900e3], "vehicle.engine.gap": 0.3}
WINDOW = 0.1


def _truth() -> dict:
    return merge(
        merge(BASE, FORM),
        {
            "name": "engine",
            "model": {"spring": {"crush_breakpoints": [0, 0.2, 0.4, 0.7], "values": TRUTH["model.spring.values"]}},
            "tests": [{"name": "t64", "speed": "64 km/h", "duration": WINDOW}],
        },
    )


@pytest.mark.integration
@pytest.mark.slow
def test_a_fit_recovers_its_own_spring_and_gap_and_predicts_with_its_form_s_intervals(tmp_path, capsys, monkeypatch):
    """The form's own 64 km/h crash (accelerometer, velocity, displacement, pitch), refitted from a
    start 20 % off the spring and 15 % off the gap: both within 1 %. A prediction at 56 km/h takes
    the form's own calibration table (class down): every metric's interval, its parts named, and
    the command line prints them. Without a table of its own it gives no interval and says so."""
    r = make_case(_truth()).simulate()["t64"]
    write_channels(tmp_path / "engine.csv", r)
    units = {"accel": ("accel_g", "g"), "velocity": ("vel_mps", "m/s"), "displacement": ("disp_m", "m")}
    units["pitch"] = ("pitch_deg", "deg")
    channels = {k: {"column": c, "unit": u} for k, (c, u) in units.items()}
    data = {"file": "engine.csv", "window": [0, WINDOW], "channels": channels}
    problem = merge(
        _truth(),
        {
            "vehicle": {"engine": {"gap": 0.255}},
            "model": {"spring": {"values": [0.0, 456e3, 624e3, 1080e3]}},
            "tests": [{"name": "t64", "speed": "64 km/h", "data": data}],
            "estimate": {"model.spring.values": {"bounds": [0, "3 MN"]}, "vehicle.engine.gap": {"bounds": [0.15, 0.45]}},
            "transcription": {"method": "multiple-shooting", "intervals": 100, "substeps": 2},
        },
    )
    path = tmp_path / "engine.yaml"
    path.write_text(yaml.safe_dump(problem))
    result = crashnlp.identify(path)
    assert result.ok, result.status
    for key, truth in TRUTH.items():
        est, truth = np.asarray(result.parameters[key], float), np.asarray(truth, float)
        assert np.all(np.abs(est - truth) < 0.01 * np.max(np.abs(truth))), (key, est, truth)
    problem["tests"] = [{"name": "t56", "speed": "56 km/h", "duration": WINDOW}]
    path.write_text(yaml.safe_dump(problem))
    test = crashnlp.simulate(path, params=result)["t56"]
    table = shipped("engine-on-mounts")
    assert test.calibration["form"] == "engine-on-mounts" and test.form_q == {k: table.q("down", k) for k in test.form_q}
    shares = test.shares()
    assert set(shares) == set(PREDICTED_KEYS) and all(test.intervals[k] is not None for k in PREDICTED_KEYS)
    for metric, part in shares.items():
        assert {"parameters", "form", "past_the_reach", "dominant"} <= set(part)
        low, high = test.intervals[metric]
        assert low < test.metrics[metric] < high and test.parts[metric].unit > 0  # the calibrated form term carries it
        assert (high - low) / 2 == pytest.approx(np.sqrt(sum(part[k] ** 2 for k in ("parameters", "form", "past_the_reach"))))
    result.save(tmp_path / "fit", figures=False)
    assert main(["simulate", str(path), "--params", str(tmp_path / "fit" / "result.json"), "--out", str(tmp_path / "o")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("t56, predicted at"))
    assert line.endswith("(95 % intervals)")
    monkeypatch.setattr(prediction, "shipped", lambda form: None)  # a form without a table of its own
    test = crashnlp.simulate(path, params=result)["t56"]
    assert not any(test.intervals.values()) and not test.form_q
    assert any("no intervals: model form engine-on-mounts has no calibration table" in n for n in test.notes)
