"""Physics of the rigid-body form (model.form: rigid-body): its equations against an independent
derivation, its analytic limits, its energy audit, its contact, and a fit recovering its own
parameters."""

from __future__ import annotations

import csv
import dataclasses

import casadi as ca
import numpy as np
import pytest
import sympy as sp
from builders import BASE, ROOT, assert_contact_force_is_the_front_ends, make_case, merge

from bench.corpus import Body, Vehicle, tall_vehicle
from bench.corpus import simulate as generate
from bench.forms import release
from crashnlp.analysis.energy import energy_audit
from crashnlp.analysis.metrics import STOPPED, lift_off, zero_crossing
from crashnlp.base.errors import InputError
from crashnlp.case.case import Case
from crashnlp.models.form import OUTPUTS, Structure
from crashnlp.models.simulation import simulate
from crashnlp.numerics.compiled import SWITCH_ENV
from crashnlp.optimize.identify import identify
from crashnlp.problem import problem_from_dict
from crashnlp.problem.forms import FORMS
from crashnlp.problem.schema import Model

RIGID = {"model": {"form": "rigid-body"}}
TIGHT = {"simulation": {"rtol": 1e-11, "atol": 1e-12, "dt": 2e-4}}


def rigid_case(changes: dict | None = None) -> Case:
    return make_case(merge(changes or {}, RIGID))  # the changes' None entries reach BASE


def _scalars(case: Case) -> dict[str, float]:
    split = case.layout.split(case.base)
    return {k.split(".")[-1]: float(np.asarray(x).ravel()[0]) for k, x in split.items() if np.size(x) == 1}


def _sympy_accelerations(v: dict, state: np.ndarray, contact: float) -> np.ndarray:
    """Lagrange's equations of a body on two axle springs, derived with sympy in the body's own
    words: the CG at (x, z), the axles' heights z -+ a sin(phi), the front end's force horizontal
    at the body point L ahead of and h below the CG."""
    t = sp.symbols("t")
    x, z, phi = (sp.Function(n)(t) for n in ("x", "z", "phi"))
    m, inertia, g, h, L = v["mass"], v["pitch_inertia"], v["gravity"], v["cg_above_impact"], v["cg_to_impact"]
    af, ar = v["cg_to_front_axle"], v["cg_to_rear_axle"]
    T = sp.Rational(1, 2) * m * (x.diff(t) ** 2 + z.diff(t) ** 2) + sp.Rational(1, 2) * inertia * phi.diff(t) ** 2
    V, D = m * g * z, 0
    for axle_height, share, k, c in (
        (z - af * sp.sin(phi), ar, v["k_front"], v["c_front"]),
        (z + ar * sp.sin(phi), af, v["k_rear"], v["c_rear"]),
    ):
        delta = -axle_height  # compression from rest
        V += sp.Rational(1, 2) * k * delta**2 + m * g * share / (af + ar) * delta
        D += sp.Rational(1, 2) * c * delta.diff(t) ** 2
    # the force point: the body vector (L, -h) turned nose-down by phi
    px = x + L * sp.cos(phi) - h * sp.sin(phi)
    Q = {q: -contact * px.diff(q) for q in (x, z, phi)}  # a horizontal force -F at that point
    Lag = T - V
    qdd = sp.symbols("xdd zdd phidd")
    qd = sp.symbols("xd zd phid")
    eqs = [Lag.diff(q.diff(t)).diff(t) - Lag.diff(q) + D.diff(q.diff(t)) - Q[q] for q in (x, z, phi)]
    subs = [(q.diff(t, 2), a) for q, a in zip((x, z, phi), qdd)] + [(q.diff(t), b) for q, b in zip((x, z, phi), qd)]
    values = dict(zip((x, z, phi, *qd), state[:6]))
    eqs = [e.subs(subs).subs(values) for e in eqs]
    sol = sp.solve(eqs, qdd, dict=True)[0]
    return np.array([float(sol[a]) for a in qdd])


def test_the_schema_offers_every_registered_form():
    assert set(Model.model_json_schema()["properties"]["form"]["enum"]) == set(FORMS)
    assert Model().form == "pendulum"  # the paper's form stays the default


def test_the_point_mass_is_refused_in_one_line_naming_the_entry():
    """The paper's point mass (pitch_inertia 0) gives a body pitching about its CG no inertia to
    pitch with; the line names the problem's form (the engine form's had said rigid-body)."""
    with pytest.raises(InputError, match=r"^vehicle.pitch_inertia: 0 .*model.form rigid-body pitches") as err:
        rigid_case({"vehicle": {"pitch_inertia": 0}})
    assert "\n" not in str(err.value)
    engine = {
        "model": {"form": "engine-on-mounts"},
        "vehicle": {"pitch_inertia": 0, "engine": {"gap": 0.3, "contact_stiffness": 8e6}},
    }
    with pytest.raises(InputError, match=r"^vehicle.pitch_inertia: 0 .*model.form engine-on-mounts pitches"):
        make_case(merge(BASE, engine))


def test_equations_match_an_independent_sympy_derivation():
    case = rigid_case()
    model, p = case.model, case.base
    assert model.states() == ("x", "z", "phi", "xdot", "zdot", "phidot", "x_max")
    v = _scalars(case)
    rng = np.random.default_rng(3)
    for _ in range(4):
        x = np.array([rng.uniform(0.1, 0.6), rng.uniform(-0.05, 0.05), rng.uniform(-0.1, 0.2)] + [0.0] * 4)
        x[3:6] = rng.uniform(2, 15), rng.uniform(-1, 1), rng.uniform(-2, 2)
        y = np.asarray(model.outputs(x, p)).ravel()
        x[6] = y[OUTPUTS.index("crush")] + rng.uniform(0, 0.002)  # loading, or just unloading
        y = np.asarray(model.outputs(x, p)).ravel()
        contact = y[OUTPUTS.index("contact_force")]
        assert contact > 0
        xdot = np.asarray(model.rhs(x, p)).ravel()
        np.testing.assert_allclose(xdot[:3], x[3:6])
        np.testing.assert_allclose(xdot[3:6], _sympy_accelerations(v, x, contact), rtol=1e-9, atol=1e-9)


def test_at_rest_it_stays_at_rest_and_without_contact_it_flies_freely():
    """Rest on the preloaded suspension is an equilibrium; away from the barrier and without
    suspension forces (no stiffness or damping: the preload alone holds the weight) every
    acceleration is zero, whatever the body's rates."""
    r = rigid_case({"vehicle": {"speed": 0}, **TIGHT}).simulate()["t56"]
    assert np.max(np.abs(r.states[:6])) < 1e-12  # x_max follows the smoothed crush rate's hinge
    case = rigid_case({"vehicle": {"suspension": {"k_front": 0, "k_rear": 0, "c_front": 0, "c_rear": 0}}})
    x = np.array([-0.2, 0.03, 0.05, -3.0, 0.5, 1.5, 0.0])  # moving away from the barrier, heaving and pitching
    xdot = np.asarray(case.model.rhs(x, case.base)).ravel()
    np.testing.assert_allclose(xdot[3:6], 0.0, atol=1e-12)


def test_small_pitch_oscillation_has_the_suspensions_frequency():
    """With k_f a_f = k_r a_r heave and pitch decouple: pitch swings at sqrt((k_f a_f^2 + k_r a_r^2) / I)."""
    af, ar, k_rear = 1.55, 2.10, 60e3
    k_front = k_rear * ar / af
    case = rigid_case({"vehicle": {"suspension": {"k_front": k_front, "k_rear": k_rear, "c_front": 0, "c_rear": 0}}})
    jac = ca.Function("j", [case.model.x], [ca.jacobian(case.model.rhs(case.model.x, case.base), case.model.x)])
    at_rest_away = np.array([-0.1, 0, 0, 0, 0, 0, 0.0])
    A = np.asarray(jac(at_rest_away))
    # the pitch row: phi'' = A[5, 2] phi, uncoupled from the heave
    assert A[5, 1] == pytest.approx(0.0, abs=1e-9)
    assert -A[5, 2] == pytest.approx((k_front * af**2 + k_rear * ar**2) / 4800.0, rel=1e-12)
    assert -A[4, 1] == pytest.approx((k_front + k_rear) / 2550.0, rel=1e-12)


def test_a_line_of_action_through_the_cg_gives_no_pitch_and_a_one_degree_of_freedom_crash():
    """h = 0 and no coupling: the body never pitches and its travel is a half sine, m x'' = -k x."""
    m, k, v0 = 1500.0, 8.0e5, 15.0
    case = rigid_case(
        {
            "vehicle": {"mass": m, "speed": v0, "cg_above_impact": 0, "suspension": {"c_front": 0, "c_rear": 0}},
            "model": {"spring": {"crush_breakpoints": [0, 1], "values": [0, k]}, "damper": None, "unloading": {"law": "elastic"}},
            "simulation": {"rtol": 1e-12, "atol": 1e-12, "dt": 1e-5},
            "tests": [{"name": "t56", "duration": 0.05}],
        }
    )
    r = case.simulate()["t56"]
    assert np.max(np.abs(r["pitch"])) < 1e-12
    w = np.sqrt(k / m)
    loading = r.time < 0.5 * np.pi / w
    np.testing.assert_allclose(r["displacement"][loading], v0 / w * np.sin(w * r.time[loading]), atol=1e-7)
    np.testing.assert_allclose(r["crush"], r["displacement"], atol=1e-12)


@pytest.mark.parametrize("law", ["elastic", "plastic"])
def test_the_energy_audit_closes(law):
    case = rigid_case({"model": {"unloading": {"law": law}}, "vehicle": {"cg_above_impact": "0.36 m"}, **TIGHT})
    r = case.simulate()["t56"]
    audit = energy_audit(r, 2550.0, 56 / 3.6)
    assert np.max(np.abs(r["pitch"])) > np.radians(1)  # the body did pitch
    assert audit["impact_loss"] == pytest.approx(0.0, abs=1e-9)  # no impulse at impact
    assert abs(audit["balance_error_relative"]) < 1e-6
    assert audit["front_end_returned_excess"] <= 1e-6 * audit["impact_kinetic"]
    assert audit["suspension_damping"] > 0
    total = r["kinetic"] + r["potential"] + r["dissipated"]
    assert np.max(np.abs(total - total[0])) < 1e-6 * total[0]
    assert_contact_force_is_the_front_ends(case, r, case.test_parameters(case.tests[0]))


@pytest.mark.parametrize("speed", ["40 km/h", "56 km/h", "64 km/h"])
def test_a_tall_body_keeps_its_front_on_the_barrier_while_it_moves_forward(speed):
    """A tall van's CG 0.36 m above the impact point pitches the body nose-down; the front end stays
    in contact until the CG stops (`lift_off` finds no time it lets go while moving forward)."""
    case = rigid_case(
        {
            "vehicle": {"speed": speed, "cg_above_impact": "0.36 m", "pitch_inertia": "4000 kg*m^2"},
            "tests": [{"name": "t56", "duration": "0.2 s"}],
        }
    )
    r = case.simulate()["t56"]
    assert np.max(np.degrees(r["pitch"])) > 2
    assert lift_off(r.time, r["velocity"], r["contact_force"]) is None


def test_lift_off_finds_a_front_end_that_lets_go_while_the_cg_moves_on():
    """The check itself: a pendulum with a large pitch lever pitches its front end off the barrier."""
    r = make_case({"vehicle": {"crush_offset": "0.9 m", "cg_above_impact": "0.45 m", "pitch_inertia": "1500 kg*m^2"}}).simulate()[
        "t56"
    ]
    t = lift_off(r.time, r["velocity"], r["contact_force"])
    assert t is not None
    i = int(np.searchsorted(r.time, t))
    assert r["contact_force"][i] == 0 and r["velocity"][i] > 0


def _generators_problem(v: Vehicle) -> dict:
    """The rigid-body form of bench.corpus's generator `v`: its body, its load curve sampled at
    101 breakpoints, its unloading line."""
    crush = np.linspace(0.0, v.load_crush[-1], 101)
    suspension = {"k_front": v.k_front, "k_rear": v.k_rear, "c_front": v.c_front, "c_rear": v.c_rear}
    body = ("mass", "pitch_inertia", "cg_to_impact", "cg_above_impact", "cg_to_front_axle", "cg_to_rear_axle")
    return {
        "name": "generator",
        "vehicle": {**{k: getattr(v, k) for k in body}, "speed": v.speed, "suspension": suspension},
        "model": {
            "form": "rigid-body",
            "spring": {"law": "force", "crush_breakpoints": crush.tolist(), "values": Body(v).load(crush).tolist()},
            "unloading": {"law": "plastic", "stiffness": v.unloading_stiffness},
        },
        "tests": [{"name": "t", "duration": 0.2}],
        "simulation": {"dt": 1e-4},
    }


@pytest.mark.parametrize("index", [0, 1])
def test_the_form_lets_go_of_the_barrier_when_an_independent_rigid_body_does(index, tmp_path, monkeypatch):
    """bench.corpus's generator (a planar body written without crashnlp) and the form given its
    load curve and unloading line (and neither crush damping nor the wall's vertical force, which
    the form does not have), at 56 km/h: on both tall vans the pitch draws the contact point back
    while the CG still moves forward at more than 0.5 m/s, so the front end unloads before the CG
    stops; van 0 then lets go while still moving forward, van 1 stops first. The form does either
    when and as fast as the generator does: lifting off while moving forward is the body's doing,
    not the contact law's."""
    v = dataclasses.replace(tall_vehicle(index, 7, speed=56 / 3.6), crush_damping=0.0, vertical_ratio=0.0)
    g = generate(v)
    # in CasADi's virtual machine (the same numbers, tests/test_model.py): the C of a 101-breakpoint
    # spring's model functions costs ~14 s of CPU to compile, the simulation 0.4 s in the VM
    monkeypatch.setenv(SWITCH_ENV, "0")
    r = Case(problem_from_dict(_generators_problem(v), tmp_path)).simulate()["t"]
    back = np.flatnonzero((r["crush_rate"] < 0) & (r["contact_force"] > 0))
    assert back.size and r["velocity"][back[0]] > 0.5
    stops = [zero_crossing(t, vel, STOPPED * v.speed) for t, vel in ((g["time"], g["velocity"]), (r.time, r["velocity"]))]
    offs = [lift_off(g["time"], g["velocity"], g["barrier_force"]), lift_off(r.time, r["velocity"], r["contact_force"])]
    ends = [release(g["time"], g["velocity"], g["barrier_force"]), release(r.time, r["velocity"], r["contact_force"])]
    assert (offs[0] is None) == (offs[1] is None) == (index == 1)
    assert np.isnan(stops[0]) == np.isnan(stops[1]) == (index == 0)
    if index == 1:
        assert abs(stops[0] - stops[1]) < 1e-4
    else:
        assert abs(offs[0] - offs[1]) < 2e-4
    assert abs(ends[0][0] - ends[1][0]) < 2e-4 and abs(ends[0][1] - ends[1][1]) < 0.02
    assert abs(np.degrees(g["pitch"].max() - r["pitch"].max())) < 0.05


CHANNELS = {"accel": ("accel_g", "g"), "velocity": ("vel_mps", "m/s"), "pitch": ("pitch_deg", "deg")}
TRUTH = {"model.spring.values": [0.0, 380e3, 520e3, 900e3], "vehicle.cg_above_impact": 0.3, "vehicle.pitch_inertia": 4000.0}
WINDOW = 0.1


def _truth() -> dict:
    return merge(
        BASE,
        {
            "name": "rigid",
            "model": {
                "form": "rigid-body",
                "spring": {"crush_breakpoints": [0, 0.2, 0.4, 0.7], "values": TRUTH["model.spring.values"]},
            },
            "vehicle": {"cg_above_impact": TRUTH["vehicle.cg_above_impact"], "pitch_inertia": TRUTH["vehicle.pitch_inertia"]},
            "tests": [{"name": "t56", "duration": WINDOW}],
            "simulation": {"dt": 1e-4},
        },
    )


@pytest.mark.integration
@pytest.mark.slow
def test_a_fit_recovers_the_rigid_bodys_own_parameters(tmp_path):
    r = Case(problem_from_dict(_truth(), tmp_path)).simulate()["t56"]
    path = tmp_path / "rigid.csv"
    columns = {"time_s": r.time, "accel_g": r["accel"] / 9.80665, "vel_mps": r["velocity"], "pitch_deg": np.degrees(r["pitch"])}
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(zip(*columns.values()))
    channels = {name: {"column": column, "unit": unit} for name, (column, unit) in CHANNELS.items()}
    problem = merge(
        _truth(),
        {
            "vehicle": {"cg_above_impact": 0.15, "pitch_inertia": 5500.0},
            "model": {"spring": {"values": ["500 kN"] * 4}},
            "tests": [{"name": "t56", "data": {"file": str(path), "window": ["0 s", f"{WINDOW} s"], "channels": channels}}],
            "estimate": {
                "model.spring.values": {"bounds": ["0 kN", "3 MN"]},
                "vehicle.cg_above_impact": {"bounds": [0.0, 0.6]},
                "vehicle.pitch_inertia": {"bounds": [1000.0, 10000.0]},
            },
            "transcription": {"method": "multiple-shooting", "intervals": 100, "substeps": 2},
        },
    )
    sol = identify(Case(problem_from_dict(problem, tmp_path)), progress=None)
    assert sol.ok, sol.status
    for key, truth in TRUTH.items():
        est, truth = np.asarray(sol.parameters[key], float), np.asarray(truth, float)
        assert np.all(np.abs(est - truth) < 0.01 * np.max(np.abs(truth))), (key, est, truth)
    energy = sol.verification.energy["t56"]
    assert abs(energy["balance_error_relative"]) < 5e-3


def test_the_worked_example_of_a_new_form_in_the_developers_guide_runs():
    """docs/development.md's point mass, built by the seam as it stands: its crash is the half
    sine of m x'' = -k x, and its energy closes."""
    text = (ROOT / "docs/development.md").read_text()
    code = text.split("<!-- worked-form -->\n```python\n", 1)[1].split("```", 1)[0]
    namespace: dict = {}
    exec(compile(code, "docs/development.md", "exec"), namespace)
    m, k, v0 = 1500.0, 8.0e5, 15.0
    case = make_case(
        {
            "vehicle": {"mass": m, "speed": v0},
            "model": {"spring": {"crush_breakpoints": [0, 1], "values": [0, k]}, "damper": None, "unloading": {"law": "elastic"}},
            "simulation": {"rtol": 1e-12, "atol": 1e-12, "dt": 1e-5},
            "tests": [{"name": "t56", "duration": 0.05}],
        }
    )
    model = namespace["PointMassModel"](Structure.of(case.problem.model), case.layout)
    r = simulate(model, case.base, v0, np.arange(0, 0.05, 1e-4), case.problem.simulation)
    w = np.sqrt(k / m)
    np.testing.assert_allclose(r["displacement"], v0 / w * np.sin(w * r.time), atol=1e-7)
    assert abs(energy_audit(r, m, v0)["balance_error_relative"]) < 1e-8
