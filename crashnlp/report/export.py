"""`crashnlp export`: the identified front end and the crash pulse, for the tools that come next.

- `ls-dyna`: a keyword file of *DEFINE_CURVE_TITLE cards in mm, ms, kg, kN: the loading curve
  with the tail the identified model extrapolates with (crashnlp.models.tail), the unloading and
  the damper, and a comment block saying what each curve is and which material field takes it
  (docs/handing-on.md: a discrete spring, *MAT_SPRING_GENERAL_NONLINEAR for loading and unloading,
  *MAT_DAMPER_NONLINEAR_VISCOUS for the damper).
- `csv`: the same curves in SI, one file each.
- `pulse`: a test's fitted or predicted acceleration at a chosen rate, as a sled-test input: by
  default the acceleration the model's metrics are read from, through the CFC class its tests'
  accelerometers recorded (SAE J211 from rest before impact, crashnlp.data.instrument, as a fit
  compares the model), or a design's own, which no accelerometer reads; at a chosen class
  filtered so. With a check of its velocity change, under a header saying whose it is and of
  which impact (speed, mass, a prediction's source, the test's notes) and what the filter did to its peak.

The curves are the identified model's own laws (crashnlp.models.laws) evaluated at its values,
smoothing and tail: sampled densely where a hinge bends (a breakpoint, the tail's start) and
at a fixed spacing elsewhere, so that straight lines between the points follow the law. The
loading force is clipped at zero, as the model's contact never pulls; both formats say where the
fitted tests' data end on the loading curve (`reach_lines`), which breakpoints lie past there and
which values no test determines, whatever the tail: an FE model driven past that crush runs on
force the data never saw.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from crashnlp.analysis.summary import goes_on
from crashnlp.base.errors import InputError
from crashnlp.base.outputs import OUTPUT
from crashnlp.base.units import G0
from crashnlp.data.channels import SAMPLE_INTERVALS
from crashnlp.data.instrument import cfc_recorded
from crashnlp.data.signal import CFC_CLASSES, cfc_coefficients, cumtrapz
from crashnlp.models.laws import SPRING_LAWS, damper_force, with_tail
from crashnlp.results.files import OutputKind, atomic_open, write_columns
from crashnlp.results.identified import DAMPER_VALUES, SPRING_VALUES, IdentifiedModel, takes_in_zero_note
from crashnlp.results.response import NOT_WRITTEN, OWN_ACCEL, RESPONSE_FILE, Response
from crashnlp.results.result import Result, unconverged
from crashnlp.results.simulation import PredictedTest, extrapolation_line
from crashnlp.results.source import UNRECORDED, source_line

EXTENT = 1.5  # the curves run to this times the last breakpoint (or the tail's start); a keyword reader extends the last segment
SPACING = 100  # points at a fixed spacing over a curve, beside those at its bends
BENDS = np.array([-8.0, -4.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 4.0, 8.0])  # smoothing widths around a bend
FIRST_ID = 1001  # the curves' ids (loading, unloading, damper): clear of a deck's low numbers
PEAK_MOVED = 0.01  # relative: a filter that moves a pulse's peak deceleration more than this is said to
EXPORTED = "crashnlp export of"  # the first words of every exported file's header, after any warning
KEYWORD_FILE = OutputKind("LS-DYNA keyword file")  # what --out may write over (check_writable_file)
PULSE_FILE = OutputKind("pulse")
CURVE_FILE = OutputKind("curve file")  # each file of the CSV export
TITLE_COLUMNS = 80  # a *DEFINE_CURVE_TITLE title line: LS-DYNA reads 80 columns of it
# relative to the loading curve's largest force: a clip at zero up to this is the smoothing's
# rounding (the shipped pickup's law gives -2 N at zero crush, where its tail's hinge reaches back), not said
NEGLIGIBLE = 1e-4
# LS-DYNA's consistent units mm, ms, kg, kN: factors from SI
MM, KN, MM_PER_MS, KN_PER_MM = 1e3, 1e-3, 1.0, 1e-6


@dataclass(frozen=True)
class Curves:
    """The identified front end's curves, SI. `loading`: force against crush, with the tail;
    `unloading`: force against the crush recovered from the permanent set (a straight line at
    the unloading stiffness; the loading curve for an elastic front end); `damper`: force
    against crush rate (None without a damper). `loading_notes`: what both formats say of the
    loading curve (where the data end on it, `reach_lines`, and a clip at zero, `_not_pulling`);
    `designed`: a design's front end (crashnlp design), its values chosen for a goal, fitted to no
    data; `damper_notes`: what both formats say of the damper curve (`damper_lines`)."""

    loading: tuple[np.ndarray, np.ndarray]
    unloading: tuple[np.ndarray, np.ndarray]
    damper: tuple[np.ndarray, np.ndarray] | None
    unloading_law: str
    unloading_stiffness: float
    loading_notes: tuple[str, ...] = ()
    designed: bool = False
    damper_notes: tuple[str, ...] = ()

    @property
    def whose(self) -> str:
        """The model the curves are of, as their files name it."""
        return _whose(self.designed)


def _whose(designed: bool) -> str:
    """A model as the exports name it: "designed" for a design's, "identified" for a fit's."""
    return "designed" if designed else "identified"


def identified_curves(identified: IdentifiedModel, not_identified: Collection[str] = (), zero: Collection[str] = ()) -> Curves:
    """The curves of an identified model, sampled from its own laws; `not_identified`: the labels
    of its estimates the data do not determine (Result.not_identified), `zero` those whose 95 %
    interval takes in zero (Result.takes_in_zero). The model is taken as valid:
    one read from a file a user may have edited goes through IdentifiedModel.as_problem first."""
    model = identified.model
    spring, smoothing, unloading = model["spring"], model["smoothing"], model["unloading"]
    bps, values = list(spring["crush_breakpoints"]), list(spring["values"])
    law = SPRING_LAWS[spring["law"]]
    tail = identified.tail_line
    bends = bps + ([tail["start"]] if tail else [])
    if tail:
        law = with_tail(law, tail["start"], tail["slope"])
    crush = _samples(0.0, EXTENT * max(bends), bends, smoothing["crush"])
    force, clipped = _not_pulling(crush, _evaluated(law(ca.DM(crush), bps, values, smoothing["crush"])[0]))
    stiffness, unloading_curve = 0.0, (crush, force)  # elastic: unloading retraces loading
    if unloading["law"] == "plastic":
        stiffness = float(unloading["stiffness"])  # a fit writes it: None (edited out) is a TypeError
        recovered = np.array([0.0, float(np.max(force)) / stiffness])
        unloading_curve = (recovered, stiffness * recovered)
    speed = float(identified.vehicle.get("speed") or 0.0)
    notes = (*reach_lines(identified, not_identified, zero), *clipped)
    damper = _damper(model, speed)
    return Curves(
        (crush, force),
        unloading_curve,
        damper,
        unloading["law"],
        stiffness,
        notes,
        identified.designed,
        damper_lines(identified, not_identified, zero) if damper is not None else (),
    )


def _not_pulling(crush: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """The loading force clipped at zero, as the model's contact force is (it never pulls:
    crashnlp.models.laws.never_pulling), and a line saying where and by how much where the clip
    is more than the smoothing's rounding (NEGLIGIBLE): a smoothed hinge reaches back past its
    breakpoint, and a tail's can take the force below zero at zero crush. A negative force in a
    discrete spring's curve would pull the barrier."""
    clipped = np.maximum(force, 0.0)
    depth = -float(np.min(force, initial=0.0))
    if depth <= NEGLIGIBLE * float(np.max(clipped, initial=0.0)):
        return clipped, ()
    below = crush[force < 0] * MM
    where = f"at {below[0]:.1f} mm" if below.size == 1 else f"from {below[0]:.1f} to {below[-1]:.1f} mm"
    return clipped, (
        f"clipped at zero force {where}, where the smoothed law falls to {-depth * KN:.4g} kN: the model's contact never pulls",
    )


def reach_lines(identified: IdentifiedModel, not_identified: Collection[str] = (), zero: Collection[str] = ()) -> tuple[str, ...]:
    """Where the data end on the loading curve, in the words every format gives: the largest crush
    the model went through in the fitted tests (a design's: in its own, which no data determine),
    the breakpoints past it, the spring values the data do not determine (`not_identified`), each
    at its breakpoint, and the tail, where the model bends its curve into one. Past that crush a
    curve's force is the law's extension, or the solver's leftover at a bound, not a measurement."""
    spring = identified.model["spring"]
    bps, values = spring["crush_breakpoints"], spring["values"]
    reach = identified.range.model_crush
    if identified.designed:
        lines = [f"the design's tests took the model to {reach * MM:.1f} mm of crush: the force past there met none of its goals"]
    else:
        takes_zero = any(label.startswith(SPRING_VALUES) for label in zero)
        lines = [
            f"the fitted tests took the model to {reach * MM:.1f} mm of crush: the data determine the force up to there,"
            " not past it" + (", and not at the values whose interval takes in zero, said so below" if takes_zero else "")
        ]
    past = [f"{b * MM:.4g}" for b in bps if b > reach]
    if past:
        lines.append(f"breakpoints past it: {', '.join(past)} mm")
    at = [f"{b * MM:.4g} mm" for b in bps]
    lines += _undetermined(SPRING_VALUES, values, at, "kN", not_identified, zero)
    tail = identified.tail_line
    if tail:
        lines.append(
            f"past {tail['start'] * MM:.1f} mm: the {_whose(identified.designed)} model's tail, a straight line at"
            f" {tail['slope'] * KN_PER_MM:.4g} kN/mm, in place of the law"
        )
    return tuple(lines)


def damper_lines(
    identified: IdentifiedModel, not_identified: Collection[str] = (), zero: Collection[str] = ()
) -> tuple[str, ...]:
    """What the damper curve's values rest on, in the words every format gives: a fit's damper whose
    values it did not estimate is the problem's (nominal: one test does not tell the damper from the
    spring), and the values it estimated that the data do not determine (`not_identified`)."""
    if identified.designed:
        return ()
    if not any(label.startswith(DAMPER_VALUES) for label in identified.labels):
        return ("not estimated: the problem's values, which no test determined (nominal where the problem left them out)",)
    damper = identified.model["damper"]
    rates = [f"{r:.4g} m/s" for r in damper["rate_breakpoints"]]
    return _undetermined(DAMPER_VALUES, damper["values"], rates, "kN*s/m", not_identified, zero)


def _undetermined(
    entry: str, values: list[float], at: list[str], unit: str, not_identified: Collection[str], zero: Collection[str]
) -> tuple[str, ...]:
    """The lines naming `entry`'s values the data do not determine (`not_identified`), and those
    whose 95 % interval takes in zero (`zero`: Result.takes_in_zero), each with its value (in kN or
    kN*s/m: the .k file's unit) and where it stands; none where the data determine them all."""
    undetermined = _named(entry, values, at, unit, not_identified)
    loose = _named(entry, values, at, unit, zero)
    return (
        *(
            [f"not identified (no test determines them; the fit left them where it stopped): {', '.join(undetermined)}"]
            if undetermined
            else []
        ),
        *([takes_in_zero_note(loose)] if loose else []),
    )


def _named(entry: str, values: list[float], at: list[str], unit: str, labels: Collection[str]) -> list[str]:
    """`entry`'s values among `labels`, each with its value (in `unit`) and where it stands."""
    return [
        f"{label} = {values[i] * KN:.4g} {unit} at {at[i]}"
        for i, label in enumerate(f"{entry}[{i}]" for i in range(len(values)))
        if label in labels
    ]


def _damper(model: dict, speed: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The damper's force against crush rate, from 0 to the impact speed or its last breakpoint."""
    damper = model.get("damper")
    if not damper:
        return None
    bps, values, eps = list(damper["rate_breakpoints"]), list(damper["values"]), model["smoothing"]["rate"]
    rate = _samples(0.0, max(speed, bps[-1]), bps, eps)
    return rate, _evaluated(damper_force(ca.DM(rate), bps, values, eps))


def _samples(start: float, end: float, bends: list[float], eps: float) -> np.ndarray:
    """Points from `start` to `end`: SPACING at a fixed spacing, and BENDS smoothing widths around each bend."""
    near = (np.asarray(bends, dtype=float)[:, None] + max(eps, 1e-9) * BENDS[None, :]).ravel()
    points = np.unique(np.concatenate([np.linspace(start, end, SPACING + 1), near]))
    points = points[(points >= start) & (points <= end)]
    distinct = np.concatenate([[True], np.diff(points) > 1e-9 * (end - start)])  # 0.042 once, not twice in rounding
    return points[distinct]


def _evaluated(expr: ca.DM) -> np.ndarray:
    return np.asarray(ca.DM(expr)).ravel()


# --------------------------------------------------------------------------- ls-dyna
def keyword_file(name: str, source: Path, curves: Curves, status: str | None = None) -> str:
    """The .k text: *KEYWORD, the comment block (the fit's status first where it did not
    converge), a *DEFINE_CURVE_TITLE per curve, *END."""
    lines = ["*KEYWORD", *(f"$ {line}" for line in [*unconverged(status), *_keyword_comments(name, source, curves)])]
    crush, force = curves.loading
    lines += _curve(FIRST_ID, _title("loading: force (kN) against crush (mm)", name), crush * MM, force * KN)
    recovered, back = curves.unloading
    unloading = _title("unloading: force (kN) against crush (mm) from the set", name)
    lines += _curve(FIRST_ID + 1, unloading, recovered * MM, back * KN)
    if curves.damper is not None:
        rate, damping = curves.damper
        lines += _curve(
            FIRST_ID + 2, _title("damper: force (kN) against crush rate (mm/ms)", name), rate * MM_PER_MS, damping * KN
        )
    return "\n".join([*lines, "*END", ""])


def _keyword_comments(name: str, source: Path, curves: Curves) -> list[str]:
    """What each curve is, in which units, and which material field takes it."""
    lines = [
        f"{_whose_curves(name, source, curves)} as curves",
        "units: mm, ms, kg, kN (consistent: 1 kN = 1 kg mm/ms^2); crush in mm, crush rate in mm/ms (= m/s), force in kN",
        "signs: crush and crush rate positive in compression, force positive resisting it; for a discrete",
        "  element whose compression is a negative displacement, set SFA = SFO = -1.0 on each curve",
        f"curve {FIRST_ID}: loading, force against crush (LCDL of *MAT_SPRING_GENERAL_NONLINEAR, MAT_S06)",
        *(f"  {note}" for note in curves.loading_notes),
        f"  past the last point, continue the last segment (as the {curves.whose} model does)",
    ]
    if curves.unloading_law == "plastic":
        lines.append(
            f"curve {FIRST_ID + 1}: unloading, a line at the unloading stiffness {curves.unloading_stiffness * KN_PER_MM:.4g}"
            " kN/mm, force against crush from the permanent set (LCDU of MAT_S06)"
        )
    else:
        lines.append(f"curve {FIRST_ID + 1}: unloading retraces loading (elastic front end): the loading curve (LCDU of MAT_S06)")
    if curves.damper is not None:
        lines += [
            f"curve {FIRST_ID + 2}: damper, force against crush rate (LCDR of *MAT_DAMPER_NONLINEAR_VISCOUS, MAT_S05),",
            f"  on a discrete damper beside the spring; the {curves.whose} model engages it over its first millimetre of crush",
            *(f"  {note}" for note in curves.damper_notes),
        ]
    else:
        lines.append(f"no damper: the {curves.whose} model has none")
    return lines


def _whose_curves(name: str, source: Path, curves: Curves) -> str:
    """The first words of every curve file: the export of which problem, from which folder, of whose front end."""
    return f"{EXPORTED} {name} ({source}): the {curves.whose} front end"


def _curve(lcid: int, title: str, x: np.ndarray, y: np.ndarray) -> list[str]:
    """One *DEFINE_CURVE_TITLE card: fixed fields (10 columns on the first card, 20 for the points)."""
    head = f"{lcid:>10d}{0:>10d}{1.0:>10.1f}{1.0:>10.1f}{0.0:>10.1f}{0.0:>10.1f}{0:>10d}{0:>10d}"
    points = [f"{a:>20.10g}{o:>20.10g}" for a, o in zip(x, y)]
    names = "$#    lcid      sidr       sfa       sfo      offa      offo    dattyp     lcint"
    return ["*DEFINE_CURVE_TITLE", title, names, head, "$#                a1                  o1", *points]


def _title(what: str, name: str) -> str:
    """A curve's title line, at most 80 columns: what the curve is first, then the problem's
    `name`, cut to what is left, so that a long name never cuts off which curve it is. Starting
    with the curve's role, it never starts with `*` (a keyword) or `$` (a comment), whatever the name."""
    return f"{what}, {name}"[:TITLE_COLUMNS]


def write_keyword_file(path: Path, name: str, source: Path, curves: Curves, status: str | None = None) -> None:
    with atomic_open(path, kind=KEYWORD_FILE) as fh:
        fh.write(keyword_file(name, source, curves, status))


NOTES_FILE = "curves-notes.txt"  # beside the curve CSVs: what the .k file's comments say of them


def write_curves_csv(folder: Path, name: str, source: Path, curves: Curves, status: str | None = None) -> list[Path]:
    """loading.csv, unloading.csv and (with a damper) damper.csv in `folder`, SI, each under the
    fit's status where it did not converge (a plain table otherwise, which any CSV reader
    takes), and NOTES_FILE beside them: whose curves they are and what the .k file says
    of the loading curve (`Curves.loading_notes`: where the data end on it), a line each. The
    paths written."""
    tables = _tables(curves)
    for file, (x_name, (x, y)) in tables.items():
        write_columns(folder / file, {x_name: x, "force_N": y}, unconverged(status), CURVE_FILE)
    said = [
        *unconverged(status),
        f"{_whose_curves(name, source, curves)} as curves, SI: {', '.join(tables)}",
        *(f"loading.csv: {note}" for note in curves.loading_notes),
        *(f"damper.csv: {note}" for note in curves.damper_notes),
    ]
    with atomic_open(folder / NOTES_FILE, kind=CURVE_FILE) as fh:
        fh.write("".join(f"{line}\n" for line in said))
    return [*(folder / f for f in tables), folder / NOTES_FILE]


def _tables(curves: Curves) -> dict[str, tuple[str, tuple[np.ndarray, np.ndarray]]]:
    """The curve CSVs of `curves` by file name: the crush column's name and the curve."""
    tables = {"loading.csv": ("crush_m", curves.loading), "unloading.csv": ("crush_m", curves.unloading)}
    if curves.damper is not None:
        tables["damper.csv"] = ("crush_rate_mps", curves.damper)
    return tables


def curve_files(curves: Curves) -> list[str]:
    """The files `write_curves_csv` writes for `curves`, by name within its folder."""
    return [*_tables(curves), NOTES_FILE]


# --------------------------------------------------------------------------- pulse
@dataclass(frozen=True)
class PulseTest:
    """The test a pulse is exported from, as its header names it: its response (read back from its
    response.csv), impact speed (m/s) and mass (kg; None where its folder does not record it), and
    its notes (what its fit or its prediction said of it); `source`: a prediction's, in one line
    (crashnlp.results.source.source_line), or None for a fit's or a design's own test; `designed`:
    a design's test (its model's values chosen for a goal, fitted to no data); `goes_on`: the words for a
    response whose crash goes on past its end (crashnlp.analysis.summary.goes_on, as the console
    says them), None where it holds the crash whole."""

    name: str
    response: Response
    speed: float
    mass: float | None
    source: str | None
    notes: tuple[str, ...]
    goes_on: str | None
    designed: bool = False

    @property
    def warning(self) -> str | None:
        """The warning a pulse that ends before its crash does carries, first in its header and
        on the console: a sled run on it does not run the whole crash."""
        if self.goes_on is None:
            return None
        return f"WARNING: the crash goes on past the end of this pulse: the model {self.goes_on}"

    def said(self) -> tuple[str, ...]:
        """The test's notes but those the warning says already."""
        return tuple(note for note in self.notes if self.goes_on is None or self.goes_on not in note)

    def header(self, name: str) -> tuple[str, ...]:
        """Whose acceleration the pulse is (of the fit or the simulation `name`), the impact it is of
        and, for a prediction, where it came from."""
        fitted = self.source is None
        whose = "the fitted model's acceleration in"
        if not fitted:
            whose = "a prediction's acceleration (crashnlp simulate) of"
        elif self.designed:
            whose = "the designed model's acceleration (crashnlp design) in"
        mass = "mass not recorded (result.json keeps no energy audit of it)" if self.mass is None else f"mass {self.mass:.0f} kg"
        lines = (
            f"{EXPORTED} {name}: {whose} test {self.name}, as a sled-test input",
            f"impact at {self.speed * 3.6:.1f} km/h ({self.speed:.3f} m/s), {mass}",
        )
        return lines if fitted else (*lines, f"source: {self.source}")


def fitted_test(folder: Path, result: Result, name: str) -> PulseTest:
    """Test `name` of the fit (or the design) in `folder`: its mass from the energy audit of it
    (TestResult.mass), its notes those of the result that name it."""
    t = result.tests[name]
    notes = tuple(note for note in result.notes if note.startswith(f"test {name}: "))
    response = finite(folder / name / RESPONSE_FILE, t.response)
    return PulseTest(name, response, t.speed, t.mass, None, notes, goes_on(t.metrics), designed=result.kind == "design")


def predicted_test(folder: Path, test: PredictedTest) -> PulseTest:
    """A test of the simulation in `folder`, with its source, how far it lies past the identified
    range and its notes, as `crashnlp simulate` printed them."""
    beyond = (f"{test.name}: {extrapolation_line(test.extrapolation)}",) if test.extrapolation else ()
    response = finite(folder / test.name / RESPONSE_FILE, test.response)
    source = source_line(test.source) or UNRECORDED
    return PulseTest(test.name, response, test.speed, test.mass, source, beyond + test.notes, goes_on(test.metrics))


@dataclass(frozen=True)
class Pulse:
    """A test's acceleration (m/s^2) at `rate` Hz filtered to CFC `cfc` (None: not filtered),
    the peak deceleration of the model's own acceleration at that rate (m/s^2, what the filter
    moves), and what its velocity change is checked against (m/s): the impact speed, the model's
    velocity just after impact (the pivot's impulse at impact takes the difference, which no
    acceleration sample holds) and its velocity at the record's end, toward the barrier: negative
    where it rebounds, positive where the crash goes on past the record."""

    time: np.ndarray
    accel: np.ndarray
    rate: float
    cfc: float | None
    own_peak: float
    speed: float
    after_impact: float
    end_velocity: float

    def filter_line(self) -> str:
        """How the pulse is sampled and filtered, and, where the filter moves the peak deceleration
        more than PEAK_MOVED, the model's own peak and the pulse's: a sled run to a filtered
        step onset runs a higher peak than the model's."""
        if self.cfc is None:
            return (
                f"sampled at {self.rate:g} Hz, not filtered: the model's own acceleration, as its result reads it (a"
                " design's, or a fit's to unfiltered data), its peak the result's; --cfc filters it as SAE J211 filters a"
                " measured channel"
            )
        line = f"sampled at {self.rate:g} Hz, filtered to CFC {self.cfc:g} (SAE J211)"
        peak = float(np.max(-self.accel))
        if abs(peak - self.own_peak) <= PEAK_MOVED * abs(self.own_peak):
            return line
        return (
            f"{line}; the filter moves the peak deceleration from {self.own_peak / G0:.2f} g (the model's own)"
            f" to {peak / G0:.2f} g ({100 * (peak / self.own_peak - 1):+.1f} %)"
        )

    @property
    def delta_v(self) -> float:
        """The velocity change the pulse integrates to (m/s, negative: it slows the vehicle)."""
        return float(cumtrapz(self.time, self.accel)[-1])

    @property
    def miss(self) -> float:
        """The pulse's velocity change against the impact speed less the velocity at the record's end, relative."""
        return -self.delta_v / (self.speed - self.end_velocity) - 1.0

    def check_line(self) -> str:
        """The velocity-change check in words: against the impact speed plus the rebound at the
        record's end, or, where the vehicle still moves toward the barrier there, less that speed
        (no rebound in the record)."""
        end = self.end_velocity
        if end > 0:
            at_end = f"- {end:.3f} m/s still moving toward the barrier at the end of the record (no rebound in it)"
        else:
            at_end = f"+ rebound {-end + 0.0:.3f} m/s at the end of the record"  # + 0.0: no -0.000
        return (
            f"delta-v: the pulse integrates to {-self.delta_v:.3f} m/s; impact speed {self.speed:.3f} m/s {at_end}"
            f" = {self.speed - end:.3f} m/s ({100 * self.miss:+.2f} %); the model's velocity just after impact is"
            f" {self.after_impact:.3f} m/s (its impulse at impact takes {self.speed - self.after_impact:.3f} m/s)"
        )


def finite(file: Path, response: Response) -> Response:
    """`response` as read back from `file` (a response.csv), refused (InputError naming the file,
    the column and the row) where a column a pulse reads holds a value that is not a number: a
    pulse of it would hand on nan samples."""
    columns = {"time_s": response.time, str(OUTPUT["accel"].column): response["accel"]}
    if response.own_accel is not None:
        columns[OWN_ACCEL] = response.own_accel
    columns[str(OUTPUT["velocity"].column)] = response["velocity"]
    for column, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputError(f"{file}: {column} is {values[bad[0]]:g} in data row {bad[0] + 1}: {NOT_WRITTEN}")
    return response


def pulse(response: Response, speed: float, rate: float, cfc: float | None = None) -> Pulse:
    """The acceleration of a response to an impact at `speed`, resampled at `rate` Hz over its
    record and CFC-filtered (J211) at class `cfc` as a test's accelerometer records it, at rest
    before impact (crashnlp.data.instrument.cfc_recorded: the filter a fit compares the model
    through, and the one its reported peak and ratings are read through). A response read through
    that class already (Response.accel_filter: a fit's or a prediction's, as the fitted tests'
    accelerometers record it) is only resampled; at another class the model's own acceleration is
    filtered: never twice. No `cfc`: the class the response is read through, and none for one no
    accelerometer reads (a design's: its peak is the model's own, which filtering a step onset
    would raise)."""
    if cfc is None and response.accel_filter is not None:
        cfc = CFC_CLASSES[response.accel_filter]
    read = response.accel_filter is not None and CFC_CLASSES[response.accel_filter] == cfc
    own = response["accel"] if response.own_accel is None else response.own_accel
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"--rate {rate:g}: must be a positive number of Hz")
    if rate * SAMPLE_INTERVALS[0] > 1:
        raise InputError(f"--rate {rate:g}: faster than any crash record is sampled (at most {1 / SAMPLE_INTERVALS[0]:g} Hz)")
    time = np.arange(response.time[0], response.time[-1] + 0.5 / rate, 1.0 / rate)
    time = time[time <= response.time[-1] + 1e-12]
    resampled = np.interp(time, response.time, own)
    accel = resampled
    if cfc is not None:
        try:
            cfc_coefficients(cfc, 1.0 / rate)  # a rate the class cannot be sampled at is refused
            accel = np.interp(time, response.time, response["accel"]) if read else cfc_recorded(time - time[0], accel, cfc)
        except ValueError as exc:
            raise InputError(f"--rate {rate:g} Hz, --cfc {cfc:g}: {exc}") from None
    velocity = response["velocity"]
    return Pulse(time, accel, rate, cfc, float(np.max(-resampled)), speed, float(velocity[0]), float(velocity[-1]))


def write_pulse(path: Path, name: str, test: PulseTest, p: Pulse, status: str | None = None) -> None:
    """The pulse as a sled-test input CSV: time_s, accel_g, under a header saying what it is (the
    fit's status first where it did not converge, then its warning where the crash goes on past
    it): whose pulse of which impact (PulseTest.header), how it is sampled, its velocity-change
    check, and the test's notes."""
    comments = (
        *unconverged(status),
        *([test.warning] if test.warning else []),
        *test.header(name),
        f"{p.filter_line()}; x toward the barrier: the crash pulse is negative",
        p.check_line(),
        *(f"note: {note}" for note in test.said()),
    )
    accel = OUTPUT["accel"]
    write_columns(path, {"time_s": p.time, str(accel.column): p.accel * accel.factor}, comments, PULSE_FILE)
