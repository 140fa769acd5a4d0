"""crashnlp's list of IPOPT's options agrees with the installed IPOPT, and is cached."""

from __future__ import annotations

import contextlib
import io

import casadi as ca
import pytest

from crashnlp.problem import ipopt
from crashnlp.problem.ipopt import check_ipopt, ipopt_options

VALUES = [
    ("max_iter", 0),
    ("max_iter", -1),
    ("max_iter", "many"),
    ("tol", 1e-6),
    ("tol", "tight"),
    ("tau_min", 0.5),
    ("mu_strategy", "adaptive"),
    ("mu_strategy", 2),
    ("hessian_approximation", "limited-memory"),
    ("sb", "yes"),
    ("sb", 1),
    ("max_itr", 5),
]


def ipopt_refuses(name: str, value: object) -> bool:
    x = ca.MX.sym("x")
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            ca.nlpsol("s", "ipopt", {"x": x, "f": x**2}, {"ipopt": {name: value}, "print_time": False})
    except RuntimeError:
        return True
    return False


@pytest.mark.parametrize("name, value", VALUES)
def test_crashnlp_refuses_what_ipopt_refuses(name, value):
    assert (name in check_ipopt({name: value})) == ipopt_refuses(name, value)


def test_the_list_is_read_from_ipopt_once_and_a_broken_cache_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path))
    ipopt_options.cache_clear()
    try:
        first = ipopt_options()
        (cached,) = tmp_path.glob("ipopt-options-*.json")
        assert len(first) > 200 and first["max_iter"].kind == "integer"
        assert first["mu_strategy"].settings == ("monotone", "adaptive")
        ipopt_options.cache_clear()
        monkeypatch.setattr(ipopt, "ipopt_documentation", lambda: pytest.fail("read IPOPT again"))
        assert ipopt_options() == first
        cached.write_text("{not json")
        ipopt_options.cache_clear()
        monkeypatch.undo()
        monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path))
        assert ipopt_options() == first
        assert [p.name for p in tmp_path.iterdir()] == [cached.name]
    finally:
        ipopt_options.cache_clear()
