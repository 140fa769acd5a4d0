"""The one registry of the model's outputs: name, SI unit, report unit, label.

The symbolic model evaluates its outputs in this order; the simulator, the
result files, the figures, the console and the problem schema (the channels a
test can measure) all read their names and units from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from crashnlp.units import G0


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
