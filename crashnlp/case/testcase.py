"""The first step of a Case: a problem's tests with their data loaded, impact speeds and horizons.

problem -> load_tests -> (problem with its vehicle mass, tests); crashnlp.case.completion then
completes the problem from the tests' data, and crashnlp.case.case lays out its parameters and
builds the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.units import G0, to_si
from crashnlp.data import TestData, load_test_data
from crashnlp.data.channels import END_TOLERANCE, Channel, DataError, median_interval
from crashnlp.data.signal import cumtrapz, integrate
from crashnlp.problem import Problem, Test
from crashnlp.problem.schema import ChannelSpec

SPEED_TOLERANCE = 0.05  # relative: data that start further from the test's speed contradict it
# relative: a test mass further from its data header's contradicts it. Headers give the test weight
# to the kg; ballast and instrumentation differences are a few percent, pounds taken for kg 2.2 times
MASS_TOLERANCE = 0.10
SAME_CONDITIONS = 0.01  # relative: a simulated test this close to its data's speed, mass and end runs as they were recorded
# A rigid barrier brings a vehicle to rest or throws it back. An acceleration that, integrated from
# the test's speed, still moves the vehicle toward the barrier faster than DRIFT_LIMIT of that speed
# once its pulse is over (the record's last PULSE_OVER below PULSE_QUIET of its peak) was recorded at
# another speed, or read in another unit. A van whose pitch lifts its front end off drifts on at a
# few percent of its speed, and a sensor offset the bias window leaves adds about as much.
DRIFT_LIMIT = 0.1
PULSE_OVER = 0.01  # s
PULSE_QUIET = 0.1
# A rigid barrier only pushes the vehicle away from it. An acceleration that over the record's last
# PULSE_OVER pushes it toward the barrier, steadily (within PULSE_QUIET of the peak about its mean),
# is an offset on a pulse that is over (3 g on the pickup reads 10 % of its peak, so it passed as
# a pulse going on), and its drift is judged too. Records cut short mid-crash push it that way only
# unsteadily (an engine on its mounts pulls the body back, up to 6 % of the peak on average):
# docs/design-notes.md, "An accelerometer's offset".
# An acceleration's steady level after its pulse is named as an offset where, held over the record,
# it adds at least this share of the drift it is refused for (a clean record's end reads a level too
# small to explain a wrong speed's drift: 0.09 g over 200 ms against 4.6 m/s)
OFFSET_SHARE = 0.5
# A pulse read with the wrong sign speeds the vehicle up by its velocity change: it leaves it at
# about twice its speed. Past FLIPPED times the speed the accel channel's sign, not the speed, is at fault.
FLIPPED = 1.5
# A rigid barrier gives back a small share of the impact speed (restitution of frontal tests: 0.05 to
# 0.3). A pulse that, integrated from the test's speed, throws the vehicle back faster than
# REBOUND_LIMIT of it was recorded at a higher speed (35 for 56 km/h: mph taken for km/h).
REBOUND_LIMIT = 0.5
# A speed read in another unit moves the recorded speed by 1.61 (mph, km/h) to 3.6 (km/h, m/s) times,
# and a rebound from it, at restitution up to 0.3, to at most 3.6 * 1.3 - 1 = 3.7 times the speed. An
# acceleration written in m/s^2 and read as g takes 9.81 times the velocity change, and throws the
# vehicle back at 8.8 times the speed or more. A rebound past UNIT_REBOUND times the speed, between
# the two, is the accel channel's unit, not the speed (an NHTSA curve in m/s^2 under a G'S header).
UNIT_REBOUND = 5.0
# A measured velocity and an acceleration of the same test change by the same amount over the
# record. Their changes further apart than a factor of UNIT_FACTOR were read in different units: g
# against m/s^2 parts them 9.81 times, km/h against m/s 3.6 times, while a filtered accelerometer
# integrates to within a few percent of the velocity. Below MOVED of the speed the velocity barely
# changes in the record, and its change tells nothing.
UNIT_FACTOR = 2.0
MOVED = 0.2
# the factors by which a unit read wrong parts the two changes, and the channel whose unit it is
UNIT_SLIPS = {"accel": 9.80665, "velocity": 3.6}
# the units a velocity column is written in: a column whose numbers, read in another of them, are
# the test's speed is read in the wrong unit (km/h read as m/s starts at 3.6 times the speed)
VELOCITY_UNITS = ("m/s", "km/h", "mph")
# A measured displacement travels what the velocity integrates to over the same time (the velocity
# channel's, else the acceleration's integrated from the speed). Travels further apart than
# UNIT_FACTOR were read in another unit than they were written in: mm read as m part them 1000
# times, cm 100, inches 39.4. Below TRAVELLED the record covers too little of the crash (a frontal
# test crushes tens of cm) for its travel to tell anything.
TRAVELLED = 0.05  # m
# A frontal crash pitches a vehicle whose impact point lies below its CG nose-down (positive); the
# generator's vehicles swing back nose-up by a small share of that (docs/design-notes.md, "The
# data's units and pitch sign"). A pitch whose nose-up swing is the larger, and past PITCH_SWING
# (below it a pitch is noise or drift, not the crash's), reads the other way.
PITCH_SWING = np.radians(1.0)
# A frontal barrier crash pitches a vehicle by tens of degrees at most; a pitch past PITCH_MOST was
# read in another unit (degrees read as radians swing 57 times as far).
PITCH_MOST = np.radians(45.0)
# A channel read from the file that changes after impact by no more than FLAT of the most it reads
# there is flat: a dead sensor, or a column of one value (all zeros, a constant offset). Fitted, it
# pins the model to a constant and the fit says ok. A crash moves every channel it measures by about
# as much as that channel reads at its largest (docs/design-notes.md, "The data's units and pitch
# sign"); a velocity record cut 10 ms into the crash still changes by a few percent of the speed.
FLAT = 0.01
# A crash's pulse changes the velocity by far more than SLOWED of the speed within PULSE_SPAN, its
# first tens of ms (the design notes give the least the generator's records do). An acceleration
# that changes it by less in every PULSE_SPAN of its record reads noise or an offset only. SLOWED
# lies below a tenth of that least, so that g read as m/s^2 (9.81 times too little) is left to the
# unit checks, which name the unit.
PULSE_SPAN = 0.02  # s
SLOWED = 0.01


@dataclass(frozen=True)
class Recorded:
    """The conditions a test's data were recorded at, SI, each with where it comes from: the speed
    from the data header, else the start of a measured velocity channel, else the test's own speed
    as the problem gives it (a derived velocity is integrated from it, so the data say nothing
    else); the mass from the header, else the test's mass as the problem gives it; and the time
    the data end (their window's end, else their last sample)."""

    speed: tuple[float, str]
    mass: tuple[float, str]
    end: float

    def other(self, speed: float, mass: float, duration: float) -> str | None:
        """Why a test simulated at `speed`, `mass` and `duration` is not the test its data recorded
        (None: it is, within SAME_CONDITIONS)."""
        why = []
        (v, v_from), (m, m_from) = self.speed, self.mass
        if _apart(speed, v):
            why.append(f"at {v * 3.6:.1f} km/h ({v_from}), simulated at {speed * 3.6:.1f} km/h")
        if _apart(mass, m):
            why.append(f"at {m:.0f} kg ({m_from}), simulated at {mass:.0f} kg")
        if _apart(duration, self.end):
            why.append(f"to {self.end * 1e3:.0f} ms, simulated to {duration * 1e3:.0f} ms")
        return "; ".join(why) or None


def _apart(a: float, b: float) -> bool:
    return abs(a - b) > SAME_CONDITIONS * max(abs(a), abs(b))


@dataclass
class TestCase:
    """One test of a problem: its impact speed, horizon, data (with the conditions they were
    recorded at) and parameter overrides."""

    spec: Test
    speed: float
    duration: float
    data: TestData | None
    overrides: dict[str, float]
    recorded: Recorded | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    def other_conditions(self, mass: float) -> str | None:
        """Why this test, at its speed, duration and `mass`, is not the test its data recorded, in
        words naming the test; None where it is (or it has no data)."""
        why = self.recorded.other(self.speed, mass, self.duration) if self.recorded is not None else None
        return None if why is None else f"{self.name}: data not shown: recorded {why}"


def load_tests(problem: Problem) -> tuple[Problem, list[TestCase]]:
    """The problem (with the vehicle mass from a test or a data header when it gives none) and
    its tests, their data read."""
    loaded = [_read(problem, i, t) for i, t in enumerate(problem.tests)]
    problem = _with_vehicle_mass(problem, loaded)
    return problem, [_test_case(problem, i, t, d) for i, (t, d) in enumerate(zip(problem.tests, loaded))]


def _read(problem: Problem, i: int, test: Test) -> TestData | None:
    """A test's data (None without), an error in them naming the key of the problem that led
    there (tests.0.data.channels.accel; tests.0.data.file for the file as a whole) before the
    data file and what in it is wrong."""
    if test.data is None:
        return None
    try:
        return load_test_data(test.data, problem.speed(test))
    except DataError as exc:
        raise InputError(f"tests.{i}.data.{exc.key or 'file'}: {exc}") from None


def _with_vehicle_mass(problem: Problem, loaded: list[TestData | None]) -> Problem:
    if problem.vehicle.mass is not None:
        return problem
    masses = [t.mass for t in problem.tests if t.mass] + [d.meta["mass"] for d in loaded if d and "mass" in d.meta]
    if not masses:
        raise InputError("vehicle.mass: not given and no data header gives it")
    return problem.with_values({"vehicle.mass": masses[0]})


def _test_case(problem: Problem, i: int, test: Test, data: TestData | None) -> TestCase:
    speed = problem.speed(test)
    if speed is None and data is not None:
        speed = data.meta.get("speed")
    if speed is None:
        raise InputError(f"tests.{i}.speed: no impact speed (give vehicle.speed, the test's speed or a data header)")
    window = test.data.window if test.data is not None else None
    if data is not None and window is not None:
        check_end(f"tests.{i}.data.window", window[1], test, data)
    end = _data_end(test, data) if data is not None else None
    duration = test.duration if test.duration is not None else end if end is not None else problem.simulation.duration
    overrides = {"vehicle.mass": test.mass} if test.mass is not None else {}
    mass = test.mass if test.mass is not None else problem.vehicle.known_mass
    recorded = _recorded(test, data, float(speed), mass, end) if data is not None and end is not None else None
    return TestCase(test, float(speed), float(duration), data, overrides, recorded)


def _data_end(test: Test, data: TestData) -> float:
    """When a test's data end: its window's end, else its last sample."""
    window = test.data.window if test.data is not None else None
    return window[1] if window is not None else max(float(ch.time[-1]) for ch in data.channels.values())


def _recorded(test: Test, data: TestData, speed: float, mass: float, end: float) -> Recorded:
    """The conditions the data were recorded at (Recorded), from the data where they say them."""
    header, start = data.meta.get("speed"), _velocity_start(test, data)
    if header:
        recorded_speed = (float(header), "the data header")
    elif start is not None:
        recorded_speed = (start, "its velocity data")
    else:
        recorded_speed = (speed, "the problem")
    weighed = data.meta.get("mass")
    return Recorded(recorded_speed, (float(weighed), "the data header") if weighed else (mass, "the problem"), end)


def check_data(tests: list[TestCase], mass: float, impact_above_cg: bool, vehicle_speed: bool) -> None:
    """Refuse test data with a dead channel (check_dead), a measured velocity and acceleration that
    disagree (check_units), data that contradict the problem's speed (check_speed), a displacement
    that disagrees with them (check_travel), a pitch past any crash's or that reads nose-up where the
    problem puts the impact point below the CG (check_pitch: `impact_above_cg` False), a mass in
    their header (`mass`, the vehicle's, where a test gives none: check_mass), a barrier force whose
    impulse disagrees with the accelerometers' at that mass (check_barrier), or data that end before
    a fit's duration (check_end; a window is checked as the data load). For fits: a simulation may
    well ask what a test would do at another speed or mass, or for longer. `vehicle_speed`: whether
    the problem gives vehicle.speed (without it, and without a test's own, the speed is the data
    header's, and the speed's refusals name the data file)."""
    for i, test in enumerate(tests):
        if test.data is not None:
            check_dead(i, test.speed, test.spec, test.data)
            check_units(i, test.speed, test.spec, test.data)  # channels apart name a channel, before the speed is
            check_speed(i, test.speed, test.spec, test.data, vehicle_speed)
            check_travel(i, test.speed, test.spec, test.data)
            check_pitch(i, test.spec, test.data, impact_above_cg)
            tested = test.overrides.get("vehicle.mass", mass)
            check_mass(i, tested, test.spec, test.data)
            check_barrier(i, tested, test.spec, test.data)
            if test.spec.duration is not None and test.spec.data is not None and test.spec.data.window is None:
                check_end(f"tests.{i}.duration", test.duration, test.spec, test.data)


def check_end(key: str, end: float, test: Test, data: TestData) -> None:
    """Refuse a span (the data window, or a fit's duration) that runs past a channel's last
    sample: the fit would take a record that ends early for the whole crash, and print "ok"."""
    name, channel = min(data.channels.items(), key=lambda item: float(item[1].time[-1]))
    last = float(channel.time[-1])
    if end - last > END_TOLERANCE * median_interval(channel.time):
        file = _file(test)
        raise InputError(
            f"{key}: runs to {end * 1e3:g} ms, but the data of test {test.name} end at {last * 1e3:g} ms "
            f"({file}, channel {name}); shorten it to the data, or give the whole record"
        )


def check_dead(i: int, speed: float, test: Test, data: TestData) -> None:
    """Refuse a channel read from the file that does not change after impact (`flat`), and an
    acceleration that changes the velocity by less than SLOWED of the `speed` in every PULSE_SPAN
    (`steepest_change`): dead sensors, or the wrong column, which a fit would take for the crash.
    Each names the channel's key and where it was read from (file and column)."""
    for name, channel in data.channels.items():
        spec = test.data.channels.get(name) if test.data is not None else None
        if spec is not None and spec.derive is None and flat(channel):
            after = channel.values[channel.time >= 0.0]
            raise InputError(
                f"tests.{i}.data.channels.{name}: the {name} of test {test.name} ({channel.source}) stays at "
                f"{after[0]:.4g} {channel.unit} after impact, changing by {np.ptp(after):.3g} {channel.unit}: the "
                "channel is flat (a dead sensor, or a column of one value), and a fit would take it for the crash; "
                "name the column that holds it, or leave the channel out"
            )
    accel = data.channels.get("accel")  # never derived
    change = steepest_change(accel) if accel is not None else None
    if accel is not None and change is not None and change < SLOWED * abs(speed):
        raise InputError(
            f"tests.{i}.data.channels.accel: the acceleration of test {test.name} ({accel.source}) changes the velocity "
            f"by at most {change:.3g} m/s in any {PULSE_SPAN * 1e3:g} ms after impact, less than {SLOWED * 100:g} % of the "
            f"speed ({_speed(speed)}): a crash's pulse changes it by far more, so the channel reads noise or an offset "
            "only (a dead sensor, or the wrong column)"
        )


def flat(channel: Channel) -> bool:
    """Whether a channel changes after impact by no more than FLAT of the most it reads there (an
    all-zero one too); False where fewer than two samples lie after impact."""
    after = channel.values[channel.time >= 0.0]
    return after.size > 1 and bool(np.ptp(after) <= FLAT * np.max(np.abs(after)))


def steepest_change(accel: Channel) -> float | None:
    """The most an acceleration changes the velocity by over any PULSE_SPAN of its record from impact
    on, either way (m/s); None where that record is shorter than PULSE_SPAN."""
    after = accel.time >= 0.0
    time, values = accel.time[after], accel.values[after]
    if time.size < 2 or time[-1] - time[0] < PULSE_SPAN:
        return None
    velocity = cumtrapz(time, values)
    starts = time <= time[-1] - PULSE_SPAN
    later = np.interp(time[starts] + PULSE_SPAN, time, velocity)
    return float(np.max(np.abs(later - velocity[starts])))


def check_speed(i: int, speed: float, test: Test, data: TestData, vehicle_speed: bool) -> None:
    """Refuse a test speed the data contradict (speed_contradicted), naming its key: the test's
    speed, vehicle.speed (`vehicle_speed`: the problem gives it), or else the data file whose
    header gave it."""
    contradiction = _contradiction(speed, test, data)
    if contradiction is not None:
        at_fault, why = contradiction
        key = f"tests.{i}.speed" if test.speed is not None else "vehicle.speed"
        if test.speed is None and not vehicle_speed:
            key = f"tests.{i}.data.file (the speed its header gives)"
        raise InputError(f"{f'tests.{i}.data.{at_fault}' if at_fault else key}: {why}")


def check_units(i: int, speed: float, test: Test, data: TestData) -> None:
    """Refuse a measured velocity and an acceleration that disagree over the record
    (`velocity_changes`): an acceleration that speeds the vehicle up where its velocity falls (its
    sign), or changes that part by more than UNIT_FACTOR, naming the unit of the channel the factor
    points to (UNIT_SLIPS)."""
    changes = velocity_changes(speed, test, data)
    if changes is None:
        return
    accel_change, velocity_change = changes
    factor = velocity_change / accel_change if accel_change > 0 else None
    if factor is not None and _agree(factor):
        return
    file = _file(test)
    said = (
        f"the acceleration of test {test.name} ({file}) changes the velocity by {accel_change:.3g} m/s over the "
        f"record, its velocity channel by {velocity_change:.3g} m/s"
    )
    if factor is None:
        raise InputError(f"tests.{i}.data.channels.accel.sign: {said}: the accel channel reads with the wrong sign")
    channel = min(UNIT_SLIPS, key=lambda c: abs(abs(np.log(factor)) - np.log(UNIT_SLIPS[c])))
    raise InputError(
        f"tests.{i}.data.channels.{channel}.unit: {said}, {factor:.3g} times as much: the two channels are read in "
        f"different units (g and m/s^2 part them 9.81 times, km/h and m/s 3.6 times), most likely the {channel} "
        "channel's"
    )


def _file(test: Test) -> str:
    """The name of a test's data file, as a refusal names it."""
    return test.data.file.name if test.data is not None else "the data"


def _agree(ratio: float) -> bool:
    """Whether two channels' measures of one quantity (their ratio) agree within UNIT_FACTOR."""
    return 1 / UNIT_FACTOR <= ratio <= UNIT_FACTOR


def _refuse_apart(key: str, ratio: float, said: str, wrong_sign: str, other_unit: str) -> None:
    """Refuse two channels' measures of one quantity that do not agree (`_agree`, their `ratio`),
    `said` in words: of opposite signs naming the sign of channel `key` (`wrong_sign` says why), else
    its unit (`other_unit` goes on from `said`)."""
    if _agree(ratio):
        return
    raise InputError(f"{key}.sign: {said}: {wrong_sign}" if ratio < 0 else f"{key}.unit: {said}{other_unit}")


def check_travel(i: int, speed: float, test: Test, data: TestData) -> None:
    """Refuse a measured displacement whose travel parts from the velocity's integral over the same
    time (`travels`) by more than UNIT_FACTOR, naming the displacement channel's unit, or that
    travels away from the barrier while the velocity goes toward it, naming its sign."""
    both = travels(speed, test, data)
    if both is None:
        return
    travel, integrated = both
    factor = travel / integrated
    said = (
        f"the displacement of test {test.name} ({_file(test)}) reads {travel:.3g} m where the velocity, integrated, "
        f"travels furthest: {integrated:.3g} m"
    )
    _refuse_apart(
        f"tests.{i}.data.channels.displacement",
        factor,
        said,
        "the channel reads with the wrong sign",
        f", {factor:.3g} times as much: the channel is read in another unit than it was written in (mm read as m part "
        "them 1000 times, cm 100, inches 39.4)",
    )


def travels(speed: float, test: Test, data: TestData) -> tuple[float, float] | None:
    """Where a test measures its displacement and its velocity or acceleration from impact on: how
    far the displacement channel and the velocity's integral (the velocity channel's, else the
    acceleration's from `speed`) travel from the start of the time both cover to where the integral
    lies furthest from it (m); None otherwise, or where that is less than TRAVELLED."""
    displacement = data.channels.get("displacement")
    measured = data.channels.get("velocity") if _velocity_start(test, data) is not None else None
    source = measured if measured is not None else data.channels.get("accel")
    if displacement is None or source is None or (measured is None and not source.time[0] <= 0.0 < source.time[-1]):
        return None
    velocity = measured.values if measured is not None else integrate(source.time, source.values, speed)[0]
    start = max(0.0, float(displacement.time[0]), float(source.time[0]))
    end = min(float(displacement.time[-1]), float(source.time[-1]))
    covered = (source.time >= start) & (source.time <= end)
    if not covered.any():
        return None
    time = source.time[covered]
    path = cumtrapz(source.time, velocity)[covered]
    path -= path[0]
    furthest = int(np.argmax(np.abs(path)))
    if abs(path[furthest]) < TRAVELLED:
        return None
    ends = np.interp([time[0], time[furthest]], displacement.time, displacement.values)
    return float(ends[1] - ends[0]), float(path[furthest])


def check_pitch(i: int, test: Test, data: TestData, impact_above_cg: bool) -> None:
    """Refuse a measured pitch past PITCH_MOST, naming its unit, and one that reads nose-up
    (`nose_up`) where the problem puts the impact point below the CG (`impact_above_cg` False: its
    cg_above_impact is not negative), naming the channel's sign and which way to turn it."""
    pitch = data.channels.get("pitch")
    after = pitch.values[pitch.time >= 0.0] if pitch is not None else None
    file = _file(test)
    if after is not None and after.size and np.max(np.abs(after)) > PITCH_MOST:
        raise InputError(
            f"tests.{i}.data.channels.pitch.unit: the pitch of test {test.name} ({file}) reaches "
            f"{np.degrees(np.max(np.abs(after))):.4g} deg: a frontal crash pitches a vehicle by tens of degrees at most, so "
            "the channel is read in another unit than it was written in (degrees read as radians swing 57 times as far)"
        )
    if after is None or impact_above_cg or not nose_up(after):
        return
    turn = _turn(test.data.channels.get("pitch") if test.data is not None else None)
    raise InputError(
        f"tests.{i}.data.channels.pitch.sign: the pitch of test {test.name} ({file}) swings to {np.degrees(after.min()):.3g} "
        f"deg and no further than {np.degrees(max(after.max(), 0.0)):.3g} deg the other way: a frontal crash pitches a "
        f"vehicle whose impact point lies below its CG nose-down, positive in the model's frame, so the channel reads "
        f"nose-up positive ({turn})"
    )


def _turn(spec: ChannelSpec | None) -> str:
    """How to turn a channel that reads with the wrong sign: drop the `sign: -1` it has, or give it one."""
    return "drop its sign: -1" if spec is not None and spec.sign == -1 else "sign: -1 turns it"


def check_barrier(i: int, mass: float, test: Test, data: TestData) -> None:
    """Refuse a barrier force whose impulse (`impulses`) pushes the vehicle toward the barrier,
    naming its sign and which way to turn it, or lies more than UNIT_FACTOR from the impulse the
    accelerometers take at `mass`, naming its unit: the wall and the vehicle take one impulse, and
    kN read as N part them 1000 times. Where the accelerometers take none, their own checks speak."""
    both = impulses(data, mass)
    if both is None or both[1] <= 0.0:
        return
    wall, taken = both
    ratio = wall / taken
    said = (
        f"the barrier force of test {test.name} ({_file(test)}) gives the vehicle an impulse of {wall / 1e3:.3g} kN s, "
        f"{ratio:.3g} times the one its accelerometers take at {mass:.0f} kg ({taken / 1e3:.3g} kN s)"
    )
    turn = _turn(test.data.channels.get("barrier_force") if test.data is not None else None)
    _refuse_apart(
        f"tests.{i}.data.channels.barrier_force",
        ratio,
        said,
        f"it pushes the vehicle into the barrier, so the channel reads compression negative, as NHTSA load cells store "
        f"it ({turn})",
        ": the wall and the vehicle take one impulse, so the channel is read in another unit than it was written in "
        "(kN read as N part them 1000 times), or the mass is off",
    )


def impulses(data: TestData, mass: float) -> tuple[float, float] | None:
    """Where a test measures the barrier force and the acceleration: the impulse the wall gives the
    vehicle and the one its accelerometers say it takes (`mass` times the velocity they take off),
    each over its record from impact on (N s); None otherwise. Read right, the two agree
    (check_barrier refuses them apart; crashnlp.analysis.summary.channel_consistency reports them)."""
    wall, accel = data.channels.get("barrier_force"), data.channels.get("accel")
    if wall is None or accel is None:
        return None
    return _from_impact(wall.time, wall.values), -mass * _from_impact(accel.time, accel.values)


def _from_impact(time: np.ndarray, values: np.ndarray) -> float:
    """The integral of `values` over `time` from impact (the record's start, if later) to its end."""
    integral = cumtrapz(time, values)
    return float(integral[-1] - np.interp(max(0.0, float(time[0])), time, integral))


def nose_up(pitch: np.ndarray) -> bool:
    """Whether a pitch after impact (rad) swings further nose-up than nose-down, and past PITCH_SWING."""
    up, down = -float(np.min(pitch, initial=0.0)), float(np.max(pitch, initial=0.0))
    return up > max(down, PITCH_SWING)


def velocity_changes(speed: float, test: Test, data: TestData) -> tuple[float, float] | None:
    """Where a test measures both its velocity and its acceleration, and the velocity falls by at
    least MOVED of the `speed` over the time both cover: how much the acceleration, integrated,
    and the velocity channel each lower the velocity over that time (m/s); None otherwise."""
    accel, velocity = data.channels.get("accel"), data.channels.get("velocity")
    if accel is None or velocity is None or _velocity_start(test, data) is None:
        return None
    start = max(0.0, float(accel.time[0]), float(velocity.time[0]))
    end = min(float(accel.time[-1]), float(velocity.time[-1]))
    if end <= start:
        return None
    ends = np.interp([start, end], velocity.time, velocity.values)
    velocity_change = float(ends[0] - ends[1])
    if velocity_change < MOVED * abs(speed):
        return None
    integrated, _ = integrate(accel.time, accel.values, 0.0, float(accel.time[0]))
    return float(np.interp(start, accel.time, integrated) - np.interp(end, accel.time, integrated)), velocity_change


def check_mass(i: int, mass: float, test: Test, data: TestData) -> None:
    """Refuse a test mass the data header contradicts (mass_contradicted), naming its key."""
    why = mass_contradicted(mass, test, data)
    if why is not None:
        raise InputError(f"{f'tests.{i}.mass' if test.mass is not None else 'vehicle.mass'}: {why}")


def speed_contradicted(speed: float, test: Test, data: TestData) -> str | None:
    """Why the data contradict a test speed: the header's speed, or a measured velocity at impact,
    more than SPEED_TOLERANCE away; None where they do not. `crashnlp init --speed` asks too.

    Speeds are said in m/s and km/h, since a problem may give either. A plain number is m/s, so
    `speed: 56` meant as km/h is 3.6 times the data's: fitting that runs into the iteration limit
    without ever saying why, and the message says so where the speed is that. Where instead the
    data show what is at fault (`_velocity_at_fault`: the window, the velocity channel's unit or
    sign; `_after_pulse`: the accel channel's sign or unit), the message says that.
    """
    contradiction = _contradiction(speed, test, data)
    return None if contradiction is None else contradiction[1]


def _contradiction(speed: float, test: Test, data: TestData) -> tuple[str | None, str] | None:
    """speed_contradicted's why, with the key under the test's `data` that the data say is at fault
    rather than the speed (`_velocity_at_fault`, `_accel_at_fault`; None: the speed)."""
    apart = f"more than {SPEED_TOLERANCE * 100:g} %"
    header = data.meta.get("speed")
    if header and abs(speed - header) > SPEED_TOLERANCE * header:
        return None, (
            f"{_speed(speed)}, but the data header of test {test.name} says {_speed(header)} "
            f"({apart} apart{_plain_number(speed, header)})"
        )
    start = _velocity_start(test, data)
    if start is not None and test.data is not None and abs(start - speed) > SPEED_TOLERANCE * abs(speed):
        begins = float(data.channels["velocity"].time[0])
        late = f" at {begins * 1e3:g} ms, where the record begins after impact" if begins > 0 else ""
        at_fault = _velocity_at_fault(speed, start, test)
        hint = f"; {at_fault[1]}" if at_fault is not None else _plain_number(speed, start)
        return at_fault[0] if at_fault is not None else None, (
            f"{_speed(speed)}, but the velocity data of test {test.name} start at {_speed(start)}{late} "
            f"({test.data.file.name}); speed and data disagree by {apart}{hint}"
        )
    after = _drift_after_pulse(speed, test, data)
    why = None if after is None else _after_pulse(speed, *after, test)
    return None if after is None or why is None else (_accel_at_fault(speed, after[0]), why)


def _accel_at_fault(speed: float, drift: float) -> str | None:
    """The key of the accel channel (under a test's data) that an acceleration leaving the vehicle
    at `drift` once its pulse is over puts at fault rather than the `speed`: its sign past FLIPPED
    times the speed toward the barrier, its unit past UNIT_REBOUND times it back; None otherwise."""
    if drift > FLIPPED * speed:
        return "channels.accel.sign"
    return "channels.accel.unit" if -drift > UNIT_REBOUND * speed else None


def _after_pulse(speed: float, drift: float, offset: float | None, test: Test) -> str | None:
    """Why an acceleration that leaves the vehicle at `drift` (m/s toward the barrier) once its
    pulse is over contradicts the test `speed`: a rebound past REBOUND_LIMIT of it (past
    UNIT_REBOUND, a unit read wrong), a drift past DRIFT_LIMIT (past FLIPPED, a sign read wrong);
    with an `offset` (m/s^2, `steady_offset`), that is said too; None where neither."""
    if -drift > REBOUND_LIMIT * speed:
        limit, went = REBOUND_LIMIT, f"throws the vehicle back at {-drift:.3g} m/s"
        why = "a rigid barrier gives back far less, so " + (
            "the accel channel is read in another unit than it was written in (m/s^2 read as g throws it back at "
            "several times the speed)"
            if -drift > UNIT_REBOUND * speed
            else "the data were recorded at a higher speed"
        )
    elif drift > DRIFT_LIMIT * speed:
        limit, went = DRIFT_LIMIT, f"leaves the vehicle moving toward the barrier at {drift:.3g} m/s"
        why = "a rigid barrier stops it, so " + (
            "the accel channel reads with the wrong sign (its pulse speeds the vehicle up)"
            if drift > FLIPPED * speed
            else "the data were recorded at a lower speed, or the accel channel's unit is off"
        )
    else:
        return None
    if offset is not None:
        why += (
            f"; or the accelerometer reads an offset: it holds {offset / G0:.3g} g steadily once its pulse is over, where "
            "a vehicle off the barrier reads none (a bias_window over samples before impact removes it)"
        )
    file = _file(test)
    return (
        f"{_speed(speed)}, but the acceleration of test {test.name} ({file}), integrated from it, {went} once its "
        f"pulse is over, more than {limit * 100:g} % of the speed: {why}"
    )


def _drift_after_pulse(speed: float, test: Test, data: TestData) -> tuple[float, float | None] | None:
    """Where no velocity is measured, the velocity the accel channel integrated from `speed` (m/s)
    leaves over the record's last PULSE_OVER where its pulse is over there (`pulse_over`), or
    where it throws the vehicle back past REBOUND_LIMIT (no record cut short mid-crash does), and
    the offset the channel reads there (`steady_offset`) where held over the record it adds
    OFFSET_SHARE of that velocity or more (None otherwise); None with a measured
    velocity, without an accel channel from impact on, or where the pulse goes on to the record's
    end (a record that ends early)."""
    accel = data.channels.get("accel")
    if _velocity_start(test, data) is not None or accel is None or not accel.time[0] <= 0.0 < accel.time[-1] - PULSE_OVER:
        return None
    last = accel.time >= accel.time[-1] - PULSE_OVER
    velocity, _ = integrate(accel.time, accel.values, speed)
    drift = float(np.mean(velocity[last]))
    if pulse_over(accel.values[last], accel.values) or drift < -REBOUND_LIMIT * speed:
        offset = steady_offset(accel.values[last], accel.values)
        added = offset * float(accel.time[-1]) if offset is not None else 0.0  # to the velocity, over the record
        return drift, offset if drift and added / drift >= OFFSET_SHARE else None
    return None


def pulse_over(end: np.ndarray, accel: np.ndarray) -> bool:
    """Whether an acceleration's pulse is over by the `end` of its record (its last PULSE_OVER):
    there it stays within PULSE_QUIET of its peak, or it pushes the vehicle toward the barrier
    steadily (`steady_mean`), as a sensor's offset does and no barrier can."""
    steady = steady_mean(end, accel)
    return bool(np.max(np.abs(end)) <= PULSE_QUIET * np.max(np.abs(accel)) or (steady is not None and steady > 0.0))


def steady_offset(end: np.ndarray, accel: np.ndarray) -> float | None:
    """What a sensor's offset reads over the `end` of an acceleration's record: its mean where it
    holds steady there (`steady_mean`), further from zero than the samples stray from it (a level,
    not noise about zero); None otherwise."""
    steady = steady_mean(end, accel)
    return steady if steady is not None and abs(steady) > float(np.max(np.abs(end - steady))) else None


def steady_mean(end: np.ndarray, accel: np.ndarray) -> float | None:
    """The mean of an acceleration over the `end` of its record where it stays within PULSE_QUIET of
    its peak about that mean; None where it varies more."""
    mean = float(np.mean(end))
    return mean if float(np.max(np.abs(end - mean))) <= PULSE_QUIET * float(np.max(np.abs(accel))) else None


def _velocity_at_fault(speed: float, start: float, test: Test) -> tuple[str, str] | None:
    """Where a measured velocity starting at `start` parts from the `speed` for a reason the data
    tell, the key under the test's data at fault and why in words: a window that starts after
    impact (the data there have slowed), a column whose numbers are the speed in another unit
    (`_unit_at_fault`), or one that starts at minus the speed (its sign); None otherwise."""
    spec = test.data.channels.get("velocity") if test.data is not None else None
    window = test.data.window if test.data is not None else None
    if window is not None and window[0] > 0:
        return "window", f"the window starts at {window[0] * 1e3:g} ms, after impact: start it at 0 s or before"
    if (slip := _unit_at_fault(speed, start, spec)) is not None:
        given, written = slip
        why = f"the column's numbers are the speed in {written}: the velocity channel's unit is not {given}"
        return "channels.velocity.unit", why
    if abs(start + speed) <= SPEED_TOLERANCE * abs(speed):
        why = f"the data start at minus the speed: the velocity channel reads with the wrong sign ({_turn(spec)})"
        return "channels.velocity.sign", why
    return None


def _unit_at_fault(speed: float, start: float, spec: ChannelSpec | None) -> tuple[str, str] | None:
    """The unit the problem gives a measured velocity channel (`spec`) starting at `start`, and
    the one of VELOCITY_UNITS in which the column's numbers are the test's speed; None otherwise."""
    if spec is None or spec.unit is None:
        return None
    given = to_si(f"1 {spec.unit}", "m/s")
    for unit in VELOCITY_UNITS:
        factor = to_si(f"1 {unit}", "m/s")
        if abs(factor - given) > 1e-9 * given and abs(start / given * factor - speed) <= SPEED_TOLERANCE * abs(speed):
            return spec.unit, unit
    return None


def _speed(v: float) -> str:
    return f"{v:g} m/s ({v * 3.6:.4g} km/h)"


def _plain_number(speed: float, recorded: float) -> str:
    """The hint for a speed 3.6 times the data's: km/h written as a plain number, which is m/s."""
    near = abs(speed - 3.6 * recorded) <= SPEED_TOLERANCE * 3.6 * abs(recorded)
    return f"; {speed:g} is 3.6 times the data's: a plain number is m/s, not km/h" if near else ""


def mass_contradicted(mass: float, test: Test, data: TestData) -> str | None:
    """Why the data header contradicts a test mass: its test weight more than MASS_TOLERANCE away;
    None where it does not, or gives none. The fitted forces scale with the mass (F = m a), so a
    wrong mass fits as well as the right one and goes unnoticed. `crashnlp init --mass` asks too."""
    header = data.meta.get("mass")
    if header and abs(mass - header) > MASS_TOLERANCE * header:
        return (
            f"{mass:.0f} kg, but the data header of test {test.name} says {header:.0f} kg (more than "
            f"{MASS_TOLERANCE * 100:g} % apart; the fitted forces scale with the mass)"
        )
    return None


def _velocity_start(test: Test, data: TestData) -> float | None:
    """A measured velocity channel's value at impact (t = 0, or its first sample after it); None
    without one, or where the velocity is derived from the speed."""
    spec = test.data.channels.get("velocity") if test.data is not None else None
    velocity = data.channels.get("velocity")
    if velocity is None or spec is None or spec.derive is not None:
        return None
    t0 = min(max(0.0, float(velocity.time[0])), float(velocity.time[-1]))
    return float(np.interp(t0, velocity.time, velocity.values))
