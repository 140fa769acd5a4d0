"""The one registry of the model's outputs: name, SI unit, report unit, label; and of the crash
metrics as the console and the report show them.

The symbolic model evaluates its outputs in this order; the simulator, the
result files, the figures, the console and the problem schema (the channels a
test can measure) all read their names and units from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from crashnlp.base.units import G0


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

# the crash metrics of a fit, as the console and the report show them: result.json key, label, factor
METRIC_ROWS = (
    ("max_crush_m", "max dynamic crush (mm)", 1e3),
    ("max_front_end_crush_m", "max front-end crush (mm)", 1e3),
    ("time_max_crush_s", "time of max crush (ms)", 1e3),
    ("time_zero_velocity_s", "time of zero velocity (ms)", 1e3),
    ("peak_decel_g", "peak deceleration (g)", 1.0),
    ("rebound_velocity_mps", "rebound velocity (m/s)", 1.0),
    ("olc_g", "OLC (g)", 1.0),
    ("max_pitch_deg", "max pitch (deg)", 1.0),
)
# a prediction's: metric key, what it is, factor to the printed unit, the unit, digits after the point
PREDICTED_ROWS = (
    ("max_crush_m", "max crush", 1e3, "mm", 1),
    ("time_zero_velocity_s", "zero velocity", 1e3, "ms", 2),
    ("peak_decel_g", "peak decel", 1.0, "g", 1),
    ("rebound_velocity_mps", "rebound", 1.0, "m/s", 2),
    ("olc_g", "OLC", 1.0, "g", 1),
    ("max_pitch_deg", "max pitch", 1.0, "deg", 2),
)

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
