"""A model read from the cache (crashnlp.models.stored) is the derived model, to the last bit."""

from __future__ import annotations

import casadi as ca
import pytest
from builders import make_case

from crashnlp.base.cache import CACHE_ENV
from crashnlp.models.form import CrashModel, build_model

ENGINE = {
    "mass": 380.0,
    "mount_stiffness": 1.5e6,
    "mount_damping": 2.4e4,
    "gap": 0.3,
    "contact_stiffness": 8e6,
    "contact_damping": 5e4,
}
FUNCTIONS = ("rhs", "outputs", "initial_state", "loading_curve", "augmented_rhs")


def _read_back(model: CrashModel) -> CrashModel:
    """The model as a later process reads it: its whole Function serialized and read again."""
    return type(model)(model.structure, model.layout, ca.Function.deserialize(model.whole().serialize()))


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"model": {"smoothing": {"crush": 0.0, "rate": 0.0}}},
        {"model": {"form": "rigid-body"}},
        {"model": {"form": "engine-on-mounts"}, "vehicle": {"engine": ENGINE}},
    ],
    ids=["pendulum", "pendulum-unsmoothed", "rigid-body", "engine-on-mounts"],
)
def test_a_read_model_serializes_as_the_derived_one(changes):
    """Every Function of a read model, and what the simulator derives from them, serializes byte
    for byte as the derived model's: the same compiled libraries, the same numbers."""
    case = make_case(changes)
    derived = type(case.model)(case.model.structure, case.model.layout)
    read = _read_back(derived)
    for name in FUNCTIONS:
        assert getattr(read, name).serialize() == getattr(derived, name).serialize(), name


def test_a_model_is_derived_once_then_read(monkeypatch, tmp_path):
    """The first build keeps the model in the cache and the second reads it; a file that cannot be
    read is passed over: the model is derived again."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    case = make_case()
    spec, layout = case.problem.model, case.layout
    derived = build_model(spec, layout)
    (kept,) = tmp_path.glob("model-pendulum-*.casadi")
    calls = []
    derive = type(derived)._build
    monkeypatch.setattr(type(derived), "_build", lambda self: calls.append(self) or derive(self))
    read = build_model(spec, layout)
    assert not calls  # read, not derived
    assert read.rhs.serialize() == derived.rhs.serialize()
    kept.write_text("not a CasADi function")
    again = build_model(spec, layout)
    assert len(calls) == 1
    assert again.rhs.serialize() == derived.rhs.serialize()
