"""Each registry a problem file chooses from: the schema takes its choices from the names below it
(crashnlp.base.choices, crashnlp.base.outputs), and each implementation registry above holds
exactly those names, so that no choice the schema accepts lacks an implementation and no
implementation is out of the schema's reach. And the crash metrics: one registry, whose keys are
the ones the metrics of a pulse carry, in result.json's order."""

from __future__ import annotations

import math
from typing import get_args

import numpy as np
import pytest

from crashnlp.analysis.summary import metrics
from crashnlp.base import choices
from crashnlp.base.errors import InputError
from crashnlp.base.outputs import (
    BOUNDED,
    COLUMNS,
    MEASURABLE,
    METRIC,
    METRICS,
    OUTPUT,
    OUTPUTS,
    PREDICTED,
    RENAMED,
    RENAMED_EXTRAPOLATION,
    TABLED,
    current_names,
)
from crashnlp.data.load import READERS, SOURCES
from crashnlp.data.signal import CFC_CLASSES
from crashnlp.engine.executors import LocalExecutor, make_executor
from crashnlp.models.laws import SPRING_LAWS, UNLOADING_LAWS
from crashnlp.optimize.design import DESIGN_OBJECTIVES
from crashnlp.problem import schema
from crashnlp.transcription import TRANSCRIPTIONS


def test_laws_and_formats_hold_the_schemas_names():
    assert tuple(SPRING_LAWS) == tuple(choices.SPRING_LAWS) == get_args(schema.Spring.model_fields["law"].annotation)
    assert tuple(UNLOADING_LAWS) == choices.UNLOADING_LAWS == get_args(schema.Unloading.model_fields["law"].annotation)
    assert tuple(READERS) == tuple(SOURCES) == choices.DATA_FORMATS == get_args(schema.DataSpec.model_fields["format"].annotation)


def test_filters_executors_and_design_objectives_hold_the_schemas_names():
    assert tuple(choices.CFC_CLASSES) == get_args(schema.CFC) and choices.CFC_CLASSES is CFC_CLASSES  # the filters
    assert choices.EXECUTORS == get_args(schema.Uncertainty.model_fields["executor"].annotation)
    objectives = get_args(schema.Design.model_fields["minimize"].annotation)
    assert set(DESIGN_OBJECTIVES) == set(choices.DESIGN_OBJECTIVES) and choices.DESIGN_OBJECTIVES == objectives
    assert schema.Design().minimize == choices.DESIGN_OBJECTIVES[0]
    assert isinstance(make_executor("local", workers=1), LocalExecutor)
    with pytest.raises(InputError, match="none of local, dask"):
        make_executor("ray")


def test_each_transcription_has_its_spec_class():
    specs = get_args(get_args(schema.TranscriptionSpec)[0])
    assert {get_args(s.model_fields["method"].annotation)[0] for s in specs} == set(TRANSCRIPTIONS)


def test_the_schemas_outputs_are_the_output_registrys():
    assert get_args(schema.ChannelName) == MEASURABLE
    assert get_args(schema.OutputName) == BOUNDED
    assert schema.OUTPUT_UNITS == {name: OUTPUT[name].unit for name in BOUNDED}
    bounds = schema.Constraints.model_validate({"bounds": {"pitch": ["-2 deg", "10 deg"]}}).bounds
    assert bounds["pitch"] == pytest.approx((np.radians(-2), np.radians(10)))


def test_a_pulses_metrics_are_the_registrys_keys_in_its_order():
    t = np.linspace(0.0, 0.12, 1201)
    accel = -250.0 * np.sin(np.pi * t / 0.1) * (t < 0.1)  # a velocity change of 15.9 m/s: it stops, then rebounds
    velocity = 15.0 + np.concatenate(([0.0], np.cumsum((accel[1:] + accel[:-1]) / 2 * np.diff(t))))
    displacement = np.concatenate(([0.0], np.cumsum((velocity[1:] + velocity[:-1]) / 2 * np.diff(t))))
    out = metrics(t, accel, velocity, displacement, np.zeros_like(t), displacement)
    assert list(out) == [m.key for m in METRICS]
    assert out["peak_decel_g"] == pytest.approx(250.0 / 9.80665, rel=1e-6)  # read in g, as the key says
    assert out["max_displacement_m"] == out["max_front_end_crush_m"]


def test_metric_rows_read_as_they_say():
    assert {m.key for m in PREDICTED} <= {m.key for m in TABLED}
    travel = METRIC["max_displacement_m"]
    assert travel.heading == "max displacement (mm)" and travel.column == "max_displacement_mm"
    assert travel.shown(0.61234) == "612.3" and travel.band((0.6, 0.625)) == "[600.0, 625.0]"
    assert travel.cell(0.61234, (0.6, 0.625)) == "612.3 [600.0, 625.0]" and travel.cell(0.61234) == "612.3"
    assert travel.cell(None, (0.6, 0.625)) == "-"  # no value: no cell, whatever its interval
    assert travel.tabled(0.61234) == "612.3" and travel.tabled(None) == travel.tabled(math.nan) == "-"
    assert METRIC["rebound_velocity_mps"].column == "rebound_velocity_mps"
    for m in METRICS:
        assert m.channel is None or m.channel in OUTPUT
        assert not m.extreme or m.channel is not None  # an instant's value is some channel's extreme


def test_a_renamed_key_names_nothing_now_and_maps_to_a_metric():
    """An old key never comes back with another meaning: old files must read as they were meant."""
    now = {m.key for m in METRICS} | {o.key for o in OUTPUTS} | {o.column for o in COLUMNS}
    assert not set(RENAMED) & now and set(RENAMED.values()) <= {m.key for m in METRICS}
    assert not set(RENAMED_EXTRAPOLATION) & set(RENAMED_EXTRAPOLATION.values())
    old = {"tests": {"t": {"metrics": {"max_crush_m": 0.7, "crush_m": 0.6}}}, "rows": [{"56kph.time_max_crush_s": 0.07}]}
    assert current_names(old) == {
        "tests": {"t": {"metrics": {"max_displacement_m": 0.7, "crush_m": 0.6}}},  # crush_m: the front end's, as before
        "rows": [{"56kph.time_max_displacement_s": 0.07}],
    }
    assert current_names({"crush_m": 0.1, "crush_rel": 0.2}, RENAMED_EXTRAPOLATION) == {
        "displacement_m": 0.1,
        "displacement_rel": 0.2,
    }
