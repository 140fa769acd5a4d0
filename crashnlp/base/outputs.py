"""The one registry of the model's outputs (name, SI unit, report unit, label) and of the crash
metrics (key, label, shown unit, factor, digits, how each is read).

The symbolic model evaluates its outputs in this order; the simulator, the
result files, the figures, the console and the problem schema (the channels a
test can measure, the outputs a bound may limit) all read their names and units
from here. Every table and column of crash metrics reads METRICS: the console's
metric table, prediction lines and channel consistency, the report's and
compare-results' tables, metrics.csv and a study's columns. A sentence of a note
or a warning that quotes one value (a stop time, where a record ends) formats it
where it is written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from crashnlp.base.units import G0

# the normal quantile of every 95 % interval crashnlp gives (two-sided: a metric's, a band's, a
# parameter's): statistics.NormalDist().inv_cdf(0.975) to its last bit, typed because a run imports
# no statistics (tests/test_imports.py); tests/test_prediction.py holds it to the computed value
Z95 = 1.9599639845400536


@dataclass(frozen=True)
class Output:
    name: str
    unit: str  # SI
    report_unit: str  # in result files and the console
    factor: float  # SI -> report unit
    label: str  # figure axis label
    plot_factor: float  # SI -> the label's unit
    column: str | None = None  # response.csv column, if written
    measurable: bool = False  # a test may measure it (a data channel)

    @property
    def plot_unit(self) -> str:
        """The unit of the figure's axis, as its label gives it."""
        return self.label[self.label.rindex("(") + 1 : -1]

    def label_through(self, accel_filter: str | None) -> str:
        """The axis label, for the acceleration with the CFC class it was read through after its
        unit, as tables name its peak (Metric.heading_through): "acceleration (g, CFC60)"."""
        cfc = accel_filter if self.name == "accel" else None
        return f"{self.label[: self.label.rindex('(')]}({through(self.plot_unit, cfc)})"

    def shown(self, value: float) -> str:
        """An SI value of this output as its figures show it: 3 significant digits, the axis's unit."""
        return f"{value * self.plot_factor:.3g} {self.plot_unit}"

    @property
    def key(self) -> str:
        """Name with its SI unit, as the Python API returns it: crush_m, accel_mps2."""
        return f"{self.name}_{SUFFIX[self.unit]}"


SUFFIX = {"m": "m", "m/s": "mps", "m/s^2": "mps2", "rad": "rad", "N": "N", "J": "J", "W": "W"}


OUTPUTS: tuple[Output, ...] = (
    Output("displacement", "m", "m", 1.0, "displacement (mm)", 1e3, "displacement_m", True),
    Output("velocity", "m/s", "m/s", 1.0, "velocity (m/s)", 1.0, "velocity_mps", True),
    Output("accel", "m/s^2", "g", 1 / G0, "acceleration (g)", 1 / G0, "accel_g", True),
    Output("pitch", "rad", "deg", 180 / math.pi, "pitch (deg)", 180 / math.pi, "pitch_deg", True),
    Output("crush", "m", "m", 1.0, "crush (mm)", 1e3, "crush_m"),
    Output("crush_rate", "m/s", "m/s", 1.0, "crush rate (m/s)", 1.0),
    Output("barrier_force", "N", "N", 1.0, "barrier force (kN)", 1e-3, "barrier_force_N", True),
    Output("contact_force", "N", "N", 1.0, "front-end force (kN)", 1e-3),
    Output("kinetic", "J", "J", 1.0, "kinetic energy (kJ)", 1e-3),
    Output("potential", "J", "J", 1.0, "potential energy (kJ)", 1e-3),
    Output("front_energy", "J", "J", 1.0, "stored front-end energy (kJ)", 1e-3),
    Output("barrier_power", "W", "W", 1.0, "power into the front end (kW)", 1e-3),
    Output("front_damper_power", "W", "W", 1.0, "front-end damper power (kW)", 1e-3),
    Output("damper_power", "W", "W", 1.0, "suspension damper power (kW)", 1e-3),
)
OUTPUT: dict[str, Output] = {o.name: o for o in OUTPUTS}
NAMES: tuple[str, ...] = tuple(o.name for o in OUTPUTS)
MEASURABLE: tuple[str, ...] = tuple(o.name for o in OUTPUTS if o.measurable)
COLUMNS: tuple[Output, ...] = tuple(o for o in OUTPUTS if o.column)
PANELS: tuple[str, ...] = (*MEASURABLE, "crush")  # a response figure's panels: what a test measures, and the crush
BOUNDED: tuple[str, ...] = PANELS  # the outputs a problem's constraints may bound: the same


@dataclass(frozen=True)
class Metric:
    """A crash metric of result.json: its key (whose suffix is the unit of the stored value), how it
    is read from a pulse, and how a person reads it (label, unit, factor and digits of every
    console line, table, CSV column and report that shows it)."""

    key: str
    label: str  # what it is, in a fit's metric table: "max displacement"
    unit: str  # the unit it is shown in
    factor: float  # stored value -> shown unit
    read: str | None  # the crashnlp.analysis.metrics.CrashMetrics field it is (None: read from another curve)
    per: float = 1.0  # the stored value is that field (SI) over this: G0 for a value in g
    short: str | None = None  # its name in a prediction's line; None: a prediction does not give it
    digits: int = 1  # digits after the point in a prediction's line
    table: bool = True  # a fit's metric table shows it
    channel: str | None = None  # the fitted channel it is read from (the channel's report unit is the metric's)
    extreme: float = 0.0  # the channel's instant it is: +1 its max, -1 its min, 0 no one instant
    plotted: bool = False  # a study plots it against a swept entry
    whole_pulse: bool = True  # only a record that holds the whole pulse gives it (UNFINISHED below)
    whole_crash: bool = False  # only a record in which the vehicle stops gives it (UNSETTLED below)
    bounds: tuple[float, float | None] | None = None  # a predicted metric's physical range, SI (METRIC_RANGE below)

    @property
    def heading(self) -> str:
        """Label with its unit, as a table's row or column names it: "max displacement (mm)"."""
        return f"{self.label} ({self.unit})"

    def read_through(self, accel_filter: str | None) -> str | None:
        """The CFC class it was read through, for an acceleration's extreme read through one: the
        class moves the peak most (one Camry test's accelerometers peak at 41 g through CFC60, 47 g
        through CFC180 and 99 g unfiltered), so tables name it."""
        return accel_filter if self.channel == "accel" and self.extreme else None

    def heading_through(self, accel_filter: str | None, short: bool = False) -> str:
        """The heading (its short label with `short`), with the CFC class it was read through
        (read_through) after the unit: "peak deceleration (g, CFC60)"."""
        return f"{self.short if short else self.label} ({through(self.unit, self.read_through(accel_filter))})"

    @property
    def column(self) -> str:
        """Its column in a CSV of shown values: the key with the shown unit, "max_displacement_mm"."""
        return f"{self.key.rsplit('_', 1)[0]}_{self.unit.replace('/', 'p')}"

    def shown(self, value: float, digits: int | None = None) -> str:
        """A stored value as a prediction's line prints it: in the shown unit, `digits` after the
        point (the metric's own where not given)."""
        return f"{value * self.factor:.{self.digits if digits is None else digits}f}"

    def band(self, band: tuple[float, float] | list[float]) -> str:
        """A 95 % interval as a prediction's line prints it: "[low, high]"."""
        return f"[{self.shown(band[0])}, {self.shown(band[1])}]"

    def cell(self, value: float | None, band: tuple[float, float] | list[float] | None = None) -> str:
        """A stored value as a prediction's line and a comparison's table print it, with its 95 %
        interval where it has one: "612.3 [600.0, 625.0]"; "-" where there is no value."""
        if value is None:
            return "-"
        return self.shown(value) if band is None else f"{self.shown(value)} {self.band(band)}"

    def tabled(self, value: float | None) -> str:
        """A stored value as a fit's metric table prints it (the console's, the report's, the
        docs' numbers of it): in the shown unit, `significant`."""
        return significant(value, self.factor)


def through(unit: str, cfc: str | None) -> str:
    """A unit with the CFC class a value was read through after it, where it was: "g, CFC60"."""
    return f"{unit}, {cfc}" if cfc else unit


def significant(value: float | None, factor: float = 1.0, digits: int = 4) -> str:
    """A number in the unit `factor` converts it to, to `digits` significant digits, as a fit's
    tables print it; "-" where there is none (None, or not finite)."""
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value * factor:.{digits}g}"


# result.json's crash metrics, in its order (crashnlp.analysis.summary.metrics writes them). Two
# quantities, two names: displacement is the CG's travel since impact (NHTSA's "maximum dynamic crush"
# is its largest value), crush is the front end's shortening along the crush force's line of action
# fmt: off
METRICS: tuple[Metric, ...] = (
    Metric("max_displacement_m", "max displacement", "mm", 1e3, "max_displacement", short="max displacement",
           channel="displacement", extreme=1.0, plotted=True, bounds=(0.0, math.inf)),
    Metric("time_max_displacement_s", "time of max displacement", "ms", 1e3, "t_max_displacement"),
    Metric("max_front_end_crush_m", "max front-end crush", "mm", 1e3, None),
    Metric("time_zero_velocity_s", "time of zero velocity", "ms", 1e3, "t_zero_velocity", short="zero velocity", digits=2,
           bounds=(0.0, None)),
    Metric("peak_decel_g", "peak deceleration", "g", 1.0, "peak_decel", G0, short="peak decel",
           channel="accel", extreme=-1.0, plotted=True, bounds=(0.0, math.inf)),
    Metric("rebound_velocity_mps", "rebound velocity", "m/s", 1.0, "rebound_velocity", short="rebound", digits=2,
           channel="velocity", extreme=-1.0, whole_crash=True, bounds=(0.0, math.inf)),
    Metric("delta_v_mps", "delta-V", "m/s", 1.0, "delta_v", table=False, whole_crash=True),
    Metric("esw_g", "ESW", "g", 1.0, "esw", G0, table=False),
    Metric("tesw_g", "TESW", "g", 1.0, "tesw", G0, table=False),
    Metric("olc_g", "OLC", "g", 1.0, "olc", G0, short="OLC", channel="accel", plotted=True, whole_pulse=False,
           bounds=(0.0, math.inf)),
    Metric("record_end_s", "end of the record", "ms", 1e3, None, table=False, whole_pulse=False),
    Metric("end_velocity_mps", "velocity at the record's end", "m/s", 1.0, "end_velocity", table=False, whole_pulse=False),
    Metric("max_pitch_deg", "max pitch", "deg", 1.0, None, short="max pitch", digits=2,
           channel="pitch", extreme=1.0, plotted=True, whole_crash=True, bounds=(0.0, math.inf)),
)
# fmt: on
METRIC: dict[str, Metric] = {m.key: m for m in METRICS}
TABLED: tuple[Metric, ...] = tuple(m for m in METRICS if m.table)  # a fit's metric table, model against test
# what a prediction gives, each with its 95 % interval; a study's table records these of every test
PREDICTED: tuple[Metric, ...] = tuple(m for m in METRICS if m.short)
PREDICTED_KEYS: tuple[str, ...] = tuple(m.key for m in PREDICTED)
PLOTTED: tuple[str, ...] = tuple(m.key for m in METRICS if m.plotted)
# what a record that ends mid-crash (crashnlp.analysis.summary.MID_CRASH) does not hold: the crash
# goes on past its end, so its largest travel, crush, deceleration and pitch so far, its velocity
# change and its rebound are only where the record leaves them (lower limits), and it has no stop.
# Its OLC is held where the occupant gets to 300 mm within the record: it is read from the pulse up
# to there alone.
UNFINISHED: tuple[str, ...] = tuple(m.key for m in METRICS if m.whole_pulse)
# what a record that ends after the pulse with the vehicle still moving toward the barrier (its
# pitch lifted the front end off, or a last creep) does not hold either: the crash goes on past
# it, so its velocity change and rebound are not over, and its pitch goes on as it drifts and when
# it meets the barrier again (bench/truncated.py, "Records cut short")
UNSETTLED: tuple[str, ...] = tuple(m.key for m in METRICS if m.whole_crash)
# each predicted metric's physical range (SI; None: the record's end): why each, and how an interval
# is cut to it, in crashnlp.analysis.limits
METRIC_RANGE: dict[str, tuple[float, float | None]] = {m.key: m.bounds for m in PREDICTED if m.bounds is not None}

# the keys of the CG's travel that files written before issue 40's rename called crush: old name ->
# current name. RENAMED: the crash metrics' keys, wherever a file keeps them (result.json's and
# simulation.json's metrics, intervals and identified range, a study's columns "test.key");
# RENAMED_EXTRAPOLATION: a prediction's extrapolation, whose "crush_m" was the CG's travel past the
# fitted tests' largest ("crush_m" elsewhere is the front end's crush, and stays)
RENAMED: dict[str, str] = {"max_crush_m": "max_displacement_m", "time_max_crush_s": "time_max_displacement_s"}
RENAMED_EXTRAPOLATION: dict[str, str] = {"crush_m": "displacement_m", "crush_rel": "displacement_rel"}


def current(key: str, renamed: dict[str, str] = RENAMED) -> str:
    """A key as it is named now: `key` itself, or the current name of a renamed one, also as the
    last part of a dotted column ("56kph.max_crush_m" -> "56kph.max_displacement_m")."""
    head, dot, last = key.rpartition(".")
    return f"{head}{dot}{renamed.get(last, last)}"


def current_names(doc: Any, renamed: dict[str, str] = RENAMED) -> Any:
    """A file's JSON document with every mapping's keys, at any depth, as they are named now
    (`current`): a file written before a rename reads as one written now."""
    if isinstance(doc, dict):
        return {current(k, renamed): current_names(v, renamed) for k, v in doc.items()}
    if isinstance(doc, list):
        return [current_names(v, renamed) for v in doc]
    return doc


# the unit a person reads an SI quantity in (reports, figures): SI unit -> (shown unit, factor from SI)
SHOWN_UNITS = {"N": ("kN", 1e-3), "N/m": ("kN/m", 1e-3), "N*s/m": ("kN*s/m", 1e-3), "rad": ("deg", 180 / math.pi)}


def shown_unit(unit: str) -> tuple[str, float]:
    """The unit an SI quantity is shown in, and the factor from SI to it (the SI unit itself, 1.0,
    where no other reads better)."""
    return SHOWN_UNITS.get(unit, (unit, 1.0))


def named_test(name: str, test: str) -> str:
    """A problem's test as a figure names it: the problem alone where its name holds the test's
    ("pickup-56kph", test "56kph"; "v10146", test "v10146"), else both."""
    return name if name.endswith(test) else f"{name}, test {test}"
