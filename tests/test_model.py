"""Physics of the elastic-pendulum model and its forward simulation."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp
from builders import assert_contact_force_is_the_front_ends, make_case

from crashnlp.models.form import OUTPUTS
from crashnlp.models.simulation import simulate_batch

LAWS = ("plastic", "elastic")
TIGHT = {"simulation": {"rtol": 1e-11, "atol": 1e-12, "dt": 2e-4}}


def test_vehicle_at_rest_stays_at_rest():
    case = make_case({"vehicle": {"speed": 0}, **TIGHT})
    r = case.simulate()["t56"]
    assert r.time[-1] == pytest.approx(0.2)
    assert np.max(np.abs(r["crush"])) < 1e-9
    assert np.max(np.abs(r["pitch"])) < 1e-9


def test_one_degree_of_freedom_limit():
    """Linear spring, no damping, CG level with the impact point: a half sine."""
    m, k, v0 = 1500.0, 8.0e5, 15.0
    case = make_case(
        {
            "vehicle": {
                "mass": m,
                "speed": v0,
                "cg_above_impact": 0,
                "pitch_inertia": 0,
                "crush_offset": 0,
                "suspension": {"c_front": 0, "c_rear": 0},
            },
            "model": {"spring": {"crush_breakpoints": [0, 1], "values": [0, k]}, "damper": None, "unloading": {"law": "elastic"}},
            "simulation": {"rtol": 1e-12, "atol": 1e-12, "dt": 1e-5},
            "tests": [{"name": "t56", "duration": 0.1}],
        }
    )
    r = case.simulate()["t56"]
    i = int(np.argmax(r["crush"]))
    # refine the peak with a parabola through the three samples around it
    y0, y1, y2 = r["crush"][i - 1 : i + 2]
    dt = r.time[1] - r.time[0]
    shift = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    peak, t_peak = y1 - 0.25 * (y0 - y2) * shift, r.time[i] + shift * dt
    assert peak == pytest.approx(v0 * np.sqrt(m / k), rel=1e-3)
    assert t_peak == pytest.approx(0.5 * np.pi * np.sqrt(m / k), rel=1e-3)
    assert np.max(np.abs(r["pitch"])) < 1e-12


def _energy(r):
    return r["kinetic"] + r["potential"] + r["dissipated"]


def test_energy_conserved_without_dissipation():
    case = make_case(
        {
            "vehicle": {"suspension": {"c_front": 0, "c_rear": 0}, "crush_offset": 0},
            "model": {"damper": None, "unloading": {"law": "elastic"}},
            **TIGHT,
        }
    )
    r = case.simulate()["t56"]
    total = r["kinetic"] + r["potential"]
    assert np.max(r["crush"]) > 0.3  # the spring really worked
    assert np.max(np.abs(total - total[0])) < 1e-6 * total[0]
    assert np.max(np.abs(r["dissipated"])) < 1e-6 * total[0]


@pytest.mark.parametrize("law", ["elastic", "plastic"])
def test_energy_balance_with_dissipation(law):
    case = make_case({"model": {"unloading": {"law": law}}, **TIGHT})
    r = case.simulate()["t56"]
    total = _energy(r)
    assert r["dissipated"][-1] > 0.1 * total[0]
    assert np.max(np.abs(total - total[0])) < 1e-6 * total[0]


@pytest.fixture(scope="module")
def released():
    """Per unloading law, a case whose vehicle leaves the barrier well within its 0.3 s, and its response."""
    cases = {law: make_case({"model": {"unloading": {"law": law}}, "tests": [{"name": "t56", "duration": 0.3}]}) for law in LAWS}
    return {law: (case, case.simulate()["t56"]) for law, case in cases.items()}


def test_plastic_unloading_leaves_permanent_set_and_never_pulls(released):
    cases = {law: case for law, (case, _) in released.items()}
    plastic, elastic = (released[law][1] for law in LAWS)
    for law, r in zip(LAWS, (plastic, elastic)):
        assert_contact_force_is_the_front_ends(cases[law], r, cases[law].test_parameters(cases[law].tests[0]))
    # the elastic spring and the rebounding damper would pull before the crush is back at zero
    assert np.any((elastic["crush"] > 1e-3) & (elastic["contact_force"] == 0))

    # contact is lost at the permanent set: close to the largest crush for the
    # plastic front end, back at zero for the elastic one; and it is not found again
    def crush_at_separation(r):
        after = np.flatnonzero((r.time > r.time[np.argmax(r["crush"])]) & (r["contact_force"] == 0))
        assert after.size, "the vehicle never separates"
        assert np.all(r["contact_force"][after[0] :] == 0), "the vehicle hits the barrier again"
        return r["crush"][after[0]]

    peak = np.max(plastic["crush"])
    permanent = crush_at_separation(plastic)
    assert 0.9 * peak < permanent < peak
    assert abs(crush_at_separation(elastic)) < 0.02 * peak
    # rebound: the elastic spring returns far more energy
    assert -np.min(plastic["velocity"]) < 0.5 * -np.min(elastic["velocity"])


@pytest.mark.parametrize("law", LAWS)
def test_the_crush_stays_at_the_permanent_set_once_the_front_end_lets_go(released, law):
    """Once contact ends the vehicle moves away, and the shortening of the front end's line of
    action falls with the growing gap; the front end's crush stays at what its unloading law
    leaves at zero force: where the unloading line from the largest crush meets zero (plastic),
    none (elastic, back at zero crush). Its largest value is the largest crush the model's history
    state carried, the barrier force is zero."""
    case, r = released[law]
    p = case.test_parameters(case.tests[0])
    gone = np.arange(r.time.size) > np.flatnonzero(r["contact_force"] > 0)[-1]
    largest = r.states[case.model.nx - 1][-1]
    stiffness = p[case.layout.index("model.unloading.stiffness")][0]
    # the model's permanent set after several largest crushes, the last the simulation's
    held = np.linspace(0.0, largest, 6)
    states = np.repeat(r.states[: case.model.nx, -1:], held.size, axis=1)
    states[-1] = held
    unloaded = held - case.loading_curve(p)(held) / stiffness if law == "plastic" else np.zeros(held.size)
    np.testing.assert_allclose(case.model.permanent_set(states, p).full().ravel(), unloaded, rtol=0, atol=1e-12)
    permanent = unloaded[-1]
    assert r["approach"][-1] < permanent - 0.05  # the vehicle has moved 50 mm and more away
    # springing back past the end of contact (the damper let go first), then at the set
    np.testing.assert_allclose(r["crush"][gone], np.maximum(r["approach"][gone], permanent), rtol=0, atol=1e-9)
    assert r["crush"][-1] == pytest.approx(permanent, abs=1e-9)
    np.testing.assert_array_equal(r["crush"][~gone], r["approach"][~gone])  # while it touches: the line of action's
    assert np.all(r["barrier_force"][gone] == 0)
    # the history state integrates the loading crush rate on its own: its end is the crush's peak
    assert np.max(r["crush"]) == pytest.approx(largest, abs=1e-6)


def _sympy_accelerations(v: dict, state, contact: float) -> np.ndarray:
    """Lagrange's equations derived independently in polar form with sympy."""
    t = sp.symbols("t")
    r, th = sp.Function("r")(t), sp.Function("th")(t)
    m, inertia, g, h, L = v["mass"], v["pitch_inertia"], v["gravity"], v["cg_above_impact"], v["cg_to_impact"]
    af, ar = v["cg_to_front_axle"], v["cg_to_rear_axle"]
    l0, th0 = sp.sqrt(L**2 + h**2), sp.atan2(h, L)
    rho = l0 + r
    T = sp.Rational(1, 2) * m * (r.diff(t) ** 2 + rho**2 * th.diff(t) ** 2) + sp.Rational(1, 2) * inertia * th.diff(t) ** 2
    V = m * g * (rho * sp.sin(th) - h)
    D = 0
    for d, share, k, c in ((af, ar, v["k_front"], v["c_front"]), (-ar, af, v["k_rear"], v["c_rear"])):
        delta = h - rho * sp.sin(th) + d * sp.sin(th - th0)
        V += sp.Rational(1, 2) * k * delta**2 + m * g * share / (af + ar) * delta
        D += sp.Rational(1, 2) * c * delta.diff(t) ** 2
    # the front end's force acts along its crush c = -r - e (th - th0): Q = -F dc/dq
    Q = {r: contact, th: v["offset"] * contact}
    Lag = T - V
    eqs = []
    for q in (r, th):
        eqs.append(Lag.diff(q.diff(t)).diff(t) - Lag.diff(q) + D.diff(q.diff(t)) - Q[q])
    rd, thd, rdd, thdd = sp.symbols("rd thd rdd thdd")
    subs = [(r.diff(t, 2), rdd), (th.diff(t, 2), thdd), (r.diff(t), rd), (th.diff(t), thd)]
    eqs = [e.subs(subs).subs({r: state[0], th: state[1], rd: state[2], thd: state[3]}) for e in eqs]
    sol = sp.solve(eqs, [rdd, thdd], dict=True)[0]
    return np.array([float(sol[rdd]), float(sol[thdd])])


def test_equations_match_an_independent_sympy_derivation():
    case = make_case()
    model, p = case.model, case.base
    P = {k: float(np.asarray(x).ravel()[0]) for k, x in case.layout.split(p).items() if np.size(x) == 1}
    v = {k.split(".")[-1]: val for k, val in P.items()}
    v["offset"] = P["vehicle.crush_offset"]
    rng = np.random.default_rng(1)
    theta0 = np.arctan2(v["cg_above_impact"], v["cg_to_impact"])
    for _ in range(4):
        x = np.array([-rng.uniform(0.05, 0.6), theta0 + rng.uniform(-0.1, 0.2), -rng.uniform(0, 15), rng.uniform(-1, 1), 0])
        crush = float(np.asarray(model.outputs(x, p)).ravel()[OUTPUTS.index("crush")])
        x[4] = crush + rng.uniform(0, 0.002)  # largest crush so far: loading, or just unloading
        xdot = np.asarray(model.rhs(x, p)).ravel()
        contact = float(np.asarray(model.outputs(x, p)).ravel()[OUTPUTS.index("contact_force")])
        assert contact > 0
        np.testing.assert_allclose(xdot[2:4], _sympy_accelerations(v, x, contact), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("law", ["force", "secant"])
def test_breakpoint_derivatives_match_finite_differences(law):
    """Hinge-form laws differentiate in their values (an inlined interpolant would give zeros)."""
    case = make_case(
        {"model": {"spring": {"law": law, "values": [1e6 + 1e5 * i for i in range(8)] if law == "secant" else None}}}
        if law == "secant"
        else {}
    )
    model, p = case.model, case.base
    where = case.layout.index("model.spring.values")
    crush = np.linspace(0.01, 0.8, 23)
    f = model.loading_curve.map(len(crush))
    psym = ca.SX.sym("p", len(p))
    jac = ca.Function("J", [psym], [ca.jacobian(f(crush, psym).T, psym)])
    J = np.asarray(jac(p))[:, where]
    fd = np.zeros_like(J)
    for j in range(J.shape[1]):
        dp = np.zeros_like(p)
        dp[where.start + j] = 1e-3 * max(abs(p[where.start + j]), 1.0)
        fd[:, j] = (np.asarray(f(crush, p + dp)).ravel() - np.asarray(f(crush, p - dp)).ravel()) / (2 * dp[where.start + j])
    assert np.abs(J).max() > 0
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def _largest_crush_rate(case, gap: float, rate: float = 10.0) -> float:
    """d x_max / dt of the case's model at 0.3 m of crush, crushing at `rate`, with the largest
    crush `gap` above the crush (pitch and its rate zero, so crush = -r)."""
    model, p = case.model, case.test_parameters(case.tests[0])
    theta0 = np.arctan2(0.18, 2.45)  # make_case's cg_above_impact over cg_to_impact
    x = [-0.3, theta0, -rate, 0.0, 0.3 + gap]
    return float(model.rhs(x, p)[4])


def test_largest_crush_follows_a_crush_that_outruns_it():
    """A simulation keeps the largest crush at or above the crush; a shooting node's states are
    free variables and can put it below. There it must grow with the crush at the full rate:
    stalled (a gate on both sides), such a node's defect cannot close, and corpus vehicles 13 and
    17 wander for hundreds of iterations. Above the crush, unloaded, the gate still stops it
    within a few millimetres."""
    case, rate = make_case(), 10.0
    hinged = 0.5 * (rate + np.sqrt(rate**2 + 1e-3**2))  # the crush rate's hinge, smoothed over 1 mm/s
    for gap in (0.0, -0.005, -0.02):
        assert _largest_crush_rate(case, gap, rate) == pytest.approx(hinged, rel=1e-12)
    assert _largest_crush_rate(case, 0.01, rate) == pytest.approx(hinged / 17, rel=1e-12)  # 2 gates above


def test_rk_and_cvodes_agree():
    r1 = make_case().simulate()["t56"]
    r2 = make_case({"simulation": {"integrator": "rk", "substeps": 4}}).simulate()["t56"]
    assert np.max(r1["crush"]) == pytest.approx(np.max(r2["crush"]), rel=1e-4)


def test_rk_takes_its_substeps_per_output_step():
    """On an output step of 2 ms, rk with 8 substeps per step comes far closer to CVODES than with
    one (CasADi's option counts steps over the whole horizon: 8 had given the same as 1)."""
    coarse = {"dt": "2 ms"}
    reference = make_case({"simulation": coarse}).simulate()["t56"]

    def miss(substeps: int) -> float:
        r = make_case({"simulation": {**coarse, "integrator": "rk", "substeps": substeps}}).simulate()["t56"]
        return float(np.max(np.abs(r["velocity"] - reference["velocity"])))

    assert miss(8) < miss(1) / 10


def test_batch_simulation_matches_single_simulations():
    """The mapped fixed-step batch gives each member's own response (what-if studies)."""
    case = make_case()
    where = case.layout.index("model.spring.values")
    P = np.tile(case.base[:, None], (1, 3))
    P[where, 1] *= 0.8
    P[where, 2] *= 1.2
    batch = simulate_batch(case.model, P, case.tests[0].speed, 0.2, 2.5e-4)
    for k in range(3):
        case.base = P[:, k]
        single = case.simulate(dt=2.5e-4)["t56"]
        np.testing.assert_allclose(batch["crush"][k], single["crush"], atol=2e-4)
    assert np.max(batch["crush"][2]) < np.max(batch["crush"][0]) < np.max(batch["crush"][1])


def test_compiled_evaluation_equals_the_virtual_machine(monkeypatch, tmp_path):
    """Simulation and batches give the same numbers compiled to C or in CasADi's VM."""
    from crashnlp.numerics import compiled
    from crashnlp.numerics.compiled import CACHE_ENV, SWITCH_ENV, compiler

    if compiler() is None:
        pytest.skip("no C compiler: crashnlp evaluates in the VM anyway")
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(compiled, "_loaded", {})  # nothing loaded earlier in this process
    compiled_run = make_case().simulate()["t56"]
    assert list(tmp_path.glob("*.so"))  # really compiled, into the chosen cache
    monkeypatch.setenv(SWITCH_ENV, "0")
    vm_run = make_case().simulate()["t56"]
    for name in ("crush", "accel", "pitch", "front_energy"):
        np.testing.assert_allclose(compiled_run[name], vm_run[name], rtol=1e-10, atol=1e-12)
    case = make_case()
    P = np.tile(case.base[:, None], (1, 2))
    vm_batch = simulate_batch(case.model, P, case.tests[0].speed, 0.1, 5e-4, jit=True)
    monkeypatch.delenv(SWITCH_ENV)
    c_batch = simulate_batch(make_case().model, P, case.tests[0].speed, 0.1, 5e-4, jit=True)
    np.testing.assert_allclose(c_batch["accel"], vm_batch["accel"], rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("law", ["force", "secant"])
@pytest.mark.parametrize("eps", [0.0, 1e-3])
def test_a_tail_bends_the_law_into_its_line_and_stores_the_work_of_its_force(law, eps):
    """Before the tail's start the law is untouched; past it the force is the line from the law's
    force there; the energy's derivative is the force (exactly with exact kinks, to first order in
    the smoothing width otherwise, as the laws' own)."""
    from crashnlp.models.laws import SPRING_LAWS, with_tail

    bps, vals = [0.0, 0.2, 0.4, 0.6], {"force": [0.0, 4e5, 3e5, 9e5], "secant": [2e6, 2e6, 1e6, 1.5e6]}[law]
    start, slope = 0.45, 2e5
    plain, tailed = SPRING_LAWS[law], with_tail(SPRING_LAWS[law], start, slope)
    force = lambda f, x: float(f(x, bps, vals, eps)[0])  # noqa: E731
    energy = lambda f, x: float(f(x, bps, vals, eps)[1])  # noqa: E731
    for x in (0.1, 0.3, start - 0.05):
        assert force(tailed, x) == pytest.approx(force(plain, x), rel=1e-4)
    for x in (start + 0.05, 0.7, 0.9):  # the law's own segment there would rise at 3 MN/m (force) or more
        assert force(tailed, x) == pytest.approx(force(plain, start) + slope * (x - start), rel=1e-4)
    xs, h = np.linspace(0.01, 0.8, 120), 1e-6
    work = np.array([(energy(tailed, x + h) - energy(tailed, x - h)) / (2 * h) for x in xs])
    forces = np.array([force(tailed, x) for x in xs])
    assert np.max(np.abs(work - forces)) <= (1e-8 if eps == 0 else 2e-3) * np.max(np.abs(forces))


def test_a_tail_in_the_problem_caps_the_force_past_its_start():
    """A tail given in the problem acts in the simulation: past its start the contact force follows
    the line (flat here), not the law's last segments (which would reach 1.5 MN at 0.85 m)."""
    case = make_case({"model": {"spring": {"tail": {"start": "0.3 m", "slope": "0 kN/m"}}, "unloading": {"law": "elastic"}}})
    p = case.test_parameters(case.tests[0])
    plateau = case.loading_curve(p)(np.array([0.35, 0.6, 0.85]))
    assert np.allclose(plateau, plateau[0], rtol=1e-4)
    assert plateau[0] == pytest.approx(380e3 + (520e3 - 380e3) * (0.3 - 0.25) / 0.15, rel=1e-3)  # the law's force at 0.3 m
    r = case.simulate()["t56"]
    assert np.max(r["crush"]) > 0.45  # well past the start: the plateau lets the front end crush further
    past = (r["crush_rate"] > 0) & (r["crush"] > 0.31)
    assert np.allclose(r["contact_force"][past] - _damper(r)[past], plateau[0], rtol=1e-4)


def _damper(r) -> np.ndarray:
    """The front-end damper's force along a response (its power over the crush rate)."""
    return np.divide(r["front_damper_power"], r["crush_rate"], out=np.zeros_like(r.time), where=np.abs(r["crush_rate"]) > 1e-6)


def test_the_rounded_end_of_contact_is_exact_outside_its_band_and_once_differentiable():
    """The contact force's switch to zero (crashnlp.models.laws.rounded_hinge): zero below the
    band, the push itself above it, never negative, and its slope continuous (against finite
    differences) across both edges, where a fit's iterates would otherwise cycle."""
    from crashnlp.models.laws import rounded_hinge

    z = ca.SX.sym("z")
    width = 2.0e3
    f = ca.Function("f", [z], [rounded_hinge(z, width)])
    slope = ca.Function("df", [z], [ca.jacobian(rounded_hinge(z, width), z)])
    pushes = np.linspace(-3e3, 3e3, 601)
    values = np.array([float(f(p)) for p in pushes])
    assert np.all(values >= 0)
    assert np.all(values[pushes <= -0.5 * width] == 0) and np.allclose(
        values[pushes >= 0.5 * width], pushes[pushes >= 0.5 * width]
    )
    h = 1e-3
    for edge in (-0.5 * width, 0.5 * width):
        left, right = float(slope(edge - h)), float(slope(edge + h))
        assert left == pytest.approx(right, abs=1e-5)
        assert float(slope(edge)) == pytest.approx((float(f(edge + h)) - float(f(edge - h))) / (2 * h), abs=1e-5)
