"""Injected faults: what a sensor or a torquer does wrong from a sim time on, as pure functions on arrays.

A :class:`Fault` is one kind, its onset ``t`` [s of sim time], a ``duration`` (inf: to the end of
the run), an ``axis`` and a ``value``. The kinds follow the fault catalogues of simulation
frameworks (Basilisk's sensor fault states: a signal that is off, stuck at its current value,
spiking; an actuator that is off or stuck), named for this satellite's hardware:

=================  ==============================================================================
``mag_stuck``      the magnetometer repeats its last sample before ``t`` (a frozen register)
``mag_spike``      one sample (the first at or after ``t``) with ``value`` [T] added on ``axis`` (at most
                   1e-3 T: the controller's plausibility bound; a larger one is rejected there)
``mag_bias``       ``value`` [T] added on ``axis`` from ``t`` (a bias jump: a new residual field)
``mag_dropout``    no magnetometer message for ``duration`` s (``duration`` required)
``gyro_bias``      ``value`` [rad/s] added on ``axis`` of the gyro from ``t``
``torquer_dead``   the torquer of ``axis`` produces no dipole from ``t``
``torquer_stuck``  the torquer of ``axis`` holds its dipole of the step before ``t`` (or ``value``)
``torquer_reversed`` the torquer of ``axis`` produces the opposite of its command (a swapped wire)
``torquer_gain``   the torquer of ``axis`` produces ``value`` times its command (default 0.5: a gain drop of
                   half, e.g. a lost winding or a drifted driver)
``sun_loss``       the sun sensor puts out nothing (as in eclipse) for ``duration`` s (default: to the end)
``sensors_killed`` the SIL runner sends SIGKILL to the attitude_sensors process at ``t`` (SIL only)
=================  ==============================================================================

One schema, :data:`FAULT_FIELDS`, for both spellings: a scenario file's ``faults:`` entries
(mappings) and the command line's ``KIND@T[:DURATION][,axis=x][,value=V]`` (:func:`parse_spec`);
a bad one is a ConfigError naming the field and the fix. :func:`measure` applies the sensor
faults to one sample (the attitude_sensors node and :func:`magtune_core.sim.modes_loop.simulate_modes`
call it), :func:`actuate` the torquer faults to the applied dipole (the simulator node, the truth
side, and the offline loop), so the SIL and the offline loop fly the same faults.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..base.errors import ConfigError
from ..base.schema import Field, parse

MAG_STUCK, MAG_SPIKE, MAG_BIAS, MAG_DROPOUT = "mag_stuck", "mag_spike", "mag_bias", "mag_dropout"
GYRO_BIAS, TORQUER_DEAD, TORQUER_STUCK, SENSORS_KILLED = "gyro_bias", "torquer_dead", "torquer_stuck", "sensors_killed"
TORQUER_REVERSED, TORQUER_GAIN, SUN_LOSS = "torquer_reversed", "torquer_gain", "sun_loss"
#: Every fault kind.
KINDS = (MAG_STUCK, MAG_SPIKE, MAG_BIAS, MAG_DROPOUT, GYRO_BIAS, TORQUER_DEAD, TORQUER_STUCK, TORQUER_REVERSED,
         TORQUER_GAIN, SUN_LOSS, SENSORS_KILLED)
#: Kinds that act on the sensors' samples / on the applied dipole.
SENSOR_KINDS = (MAG_STUCK, MAG_SPIKE, MAG_BIAS, MAG_DROPOUT, GYRO_BIAS, SUN_LOSS)
TORQUER_KINDS = (TORQUER_DEAD, TORQUER_STUCK, TORQUER_REVERSED, TORQUER_GAIN)
AXES = ("x", "y", "z")

#: kind -> (default value, largest |value|, unit) of the kinds that take a value.
VALUES = {MAG_SPIKE: (5e-4, 1e-3, "T"), MAG_BIAS: (1e-5, 1e-3, "T"), GYRO_BIAS: (1e-2, 1.0, "rad/s"),
          TORQUER_STUCK: (math.nan, 1e4, "A m^2"), TORQUER_GAIN: (0.5, 1.0, "(fraction of the command)")}
#: Kinds that act on a whole unit (no axis).
WHOLE_UNIT = (MAG_STUCK, MAG_DROPOUT, SUN_LOSS, SENSORS_KILLED)

#: The one schema of a fault (a scenario file's ``faults:`` entry; the CLI's spec parses into it).
FAULT_FIELDS = (
    Field("kind", "str", "what fails: " + ", ".join(KINDS), choices=KINDS),
    Field("t", "float", "onset [s of sim time from the start of the run]", nonnegative=True, bounds=(0.0, 1e8),
          unit="s"),
    Field("duration", "float", "how long [s] (default: to the end of the run; mag_dropout: required)", None,
          positive=True, bounds=(1e-9, 1e8), unit="s"),
    Field("axis", "str", "body axis of a bias, a spike or a torquer (x, y, z)", "x", choices=AXES),
    Field("value", "float", "size of a bias [T, rad/s], a spike [T], a stuck dipole [A m^2] or a torquer's remaining "
          "gain (fraction; default per kind)", None),
)


@dataclass(frozen=True)
class Fault:
    """One injected fault (see the module docstring); ``axis`` 0, 1, 2; ``value`` nan where the kind has none
    (``torquer_stuck``: nan holds the dipole of the step before ``t``)."""

    kind: str
    t: float
    duration: float = math.inf
    axis: int = 0
    value: float = math.nan

    def active(self, t: float) -> bool:
        """True while the fault acts at sim time ``t`` [s].

        Parameters
        ----------
        t : float
            Sim time [s].

        Returns
        -------
        bool
            True if onset <= t < onset + duration.
        """
        return self.t <= t < self.t + self.duration

    @property
    def spec(self) -> str:
        """The command-line spelling, exact (float repr): what the nodes are given and parse back.

        Returns
        -------
        str
            ``KIND@T[:DURATION][,axis=A][,value=V]`` (axis only for kinds that take one; value unless nan).
        """
        out = f"{self.kind}@{self.t!r}" + (f":{self.duration!r}" if math.isfinite(self.duration) else "")
        if self.kind not in WHOLE_UNIT:
            out += f",axis={AXES[self.axis]}"
        return out + (f",value={self.value!r}" if not math.isnan(self.value) else "")


def from_mapping(m, where: str = "fault") -> Fault:
    """A fault from a mapping of :data:`FAULT_FIELDS` (unknown keys, bad values and combinations a kind does not
    take: ConfigError naming the field and the fix).

    Parameters
    ----------
    m : dict
        Fault fields: kind, t [s], and optionally duration [s], axis ("x", "y", "z"), value.
    where : str
        Context named in error messages (e.g. ``faults[2]``).

    Returns
    -------
    Fault
        The validated fault; duration inf when not given, value the kind's default (or nan if it takes none).

    Raises
    ------
    ConfigError
        If ``m`` is not a dict, a field is unknown, missing or invalid, mag_dropout has no duration,
        mag_spike/sensors_killed have one, an axis is given to a whole-sensor kind, or a value is zero,
        beyond the kind's limit or given to a kind that takes none.
    """
    if not isinstance(m, dict):
        raise ConfigError(where, None, f"expected a mapping with kind and t (e.g. {{kind: mag_dropout, t: 100, "
                                       f"duration: 30}}), got {m!r}")
    v = parse(m, FAULT_FIELDS, where, allowed=())
    kind = v["kind"]
    if kind == MAG_DROPOUT and v["duration"] is None:
        raise ConfigError(where, "duration", "required for mag_dropout (how long no message arrives [s]), "
                                             "e.g. mag_dropout@100:30")
    if kind in (MAG_SPIKE, SENSORS_KILLED) and v["duration"] is not None:
        raise ConfigError(where, "duration", f"{kind} takes no duration ("
                          + ("one sample" if kind == MAG_SPIKE else "the process stays dead") + "); remove it")
    if kind in WHOLE_UNIT and "axis" in m:
        raise ConfigError(where, "axis", f"{kind} takes no axis (it acts on the whole sensor); remove it")
    value = v["value"]
    if kind in VALUES:
        default, limit, unit = VALUES[kind]
        if value is None:
            value = default
        elif not (value != 0.0 and abs(value) <= limit) or (kind == TORQUER_GAIN and not 0.0 < value < 1.0):
            expected = ("a fraction in (0, 1) (the torquer's remaining gain; 0 is torquer_dead, 1 no fault)"
                        if kind == TORQUER_GAIN else f"a nonzero number within +-{limit:g} {unit}")
            raise ConfigError(where, "value", f"expected {expected} for {kind}, got {value!r}")
    elif value is not None:
        raise ConfigError(where, "value", f"{kind} takes no value; remove it")
    duration = math.inf if v["duration"] is None else v["duration"]
    return Fault(kind, v["t"], duration, AXES.index(v["axis"]), math.nan if value is None else float(value))


def parse_spec(text: str, where: str | None = None) -> Fault:
    """``KIND@T[:DURATION][,axis=A][,value=V]`` (e.g. ``mag_dropout@3000:30``, ``gyro_bias@100,axis=z,value=0.02``)
    -> :class:`Fault` through :data:`FAULT_FIELDS`; ConfigError naming the field otherwise.

    Parameters
    ----------
    text : str
        Fault spec as given on the command line.
    where : str or None
        Context named in error messages; None: ``--fault <text>``.

    Returns
    -------
    Fault
        The validated fault (:func:`from_mapping`).

    Raises
    ------
    ConfigError
        If the spec lacks ``KIND@T``, an item after a comma is not ``name=value``, a name is given twice,
        a number does not parse, or :func:`from_mapping` rejects the fields.
    """
    where = where or f"--fault {text}"
    head, *params = str(text).strip().split(",")
    kind, at, when = head.partition("@")
    if not at or not kind:
        raise ConfigError(where, None, "expected KIND@T[:DURATION][,axis=x|y|z][,value=V], e.g. mag_dropout@3000:30 "
                                       f"(kinds: {', '.join(KINDS)})")
    t, colon, dur = when.partition(":")
    m: dict = {"kind": kind.strip(), "t": _number(t, "t", where)}
    if colon:
        m["duration"] = _number(dur, "duration", where)
    for item in params:
        name, eq, val = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise ConfigError(where, None, f"expected name=value after a comma, got {item!r}")
        if name in m:
            raise ConfigError(where, name, "given twice")
        m[name] = _number(val, name, where) if name == "value" else val.strip()
    return from_mapping(m, where)


def _number(text: str, name: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(where, name, f"expected a number, got {text.strip()!r}") from None


def from_list(items, where: str = "faults") -> tuple[Fault, ...]:
    """A scenario file's ``faults:`` list (mappings) or spec strings, each validated; ``where[i]`` names the entry.

    Parameters
    ----------
    items : list or tuple or None
        Entries, each a :class:`Fault`, a spec string or a mapping; None for no faults.
    where : str
        Context named in error messages.

    Returns
    -------
    tuple of Fault
        The faults in order (empty for None).

    Raises
    ------
    ConfigError
        If ``items`` is not a list or tuple (a single string or mapping included), an entry is invalid, or two
        faults of one kind on one unit overlap (:func:`check_overlaps`).
    """
    if items is None:
        return ()
    if isinstance(items, (str, dict)) or not isinstance(items, (list, tuple)):
        raise ConfigError(where, None, f"expected a list of faults, got {items!r}")
    out = tuple(f if isinstance(f, Fault) else parse_spec(f, f"{where}[{i}]") if isinstance(f, str)
                else from_mapping(f, f"{where}[{i}]") for i, f in enumerate(items))
    check_overlaps(out, where)
    return out


def run_end(ts, steps: int | None = None, orbits: float | None = None, period: float | None = None) -> float:
    """Sim time [s] at which a run of ``steps`` steps of ``ts`` (or ``orbits`` orbits of ``period``) ends,
    counted as the simulator counts its steps (``round(orbits * period / ts)`` of them).

    Parameters
    ----------
    ts : float
        Sample period [s].
    steps : int or None
        Run length in steps; None: from ``orbits``.
    orbits : float or None
        Run length in orbits (used when ``steps`` is None).
    period : float or None
        Orbit period [s] (with ``orbits``).

    Returns
    -------
    float
        The end [s] of sim time from the start of the run.
    """
    n = int(steps) if steps else int(round(float(orbits) * float(period) / float(ts)))
    return n * float(ts)


def check_times(faults, end: float, where: str = "fault") -> None:
    """Refuse a fault that starts at or after the end of the run (it would never act: a run that
    ends before its fault says nothing about it). A fault that starts before the end and lasts past
    it is fine (it acts until the end).

    Parameters
    ----------
    faults : iterable of Fault
        Injected faults.
    end : float
        Sim time [s] at which the run ends (:func:`run_end`).
    where : str
        Context named in the error (``--fault``, ``faults``).

    Raises
    ------
    ConfigError
        For the first fault whose onset ``t`` is not before ``end``: one line naming the fault and the end.
    """
    for f in faults:
        if not f.t < end:
            raise ConfigError(f"{where} {f.spec}", "t", f"the fault starts at {f.t:g} s, at or after the end of "
                                                        f"the run ({end:g} s): it would never act; give a time "
                                                        f"before {end:g} s or a longer run")


def check_overlaps(faults, where: str = "fault") -> None:
    """Refuse two faults of one kind on one unit whose times overlap: which of them acts would be an accident of
    the order they were given in (two overlapping ``torquer_stuck`` on x passed without a note).

    Parameters
    ----------
    faults : sequence of Fault
        Injected faults.
    where : str
        Context named in the error (``--fault``, ``faults``).

    Raises
    ------
    ConfigError
        Naming both faults.
    """
    faults = list(faults)

    def span(f):  # a spike is one sample: it overlaps only a spike of the same time
        return 0.0 if f.kind == MAG_SPIKE else f.duration

    for i, a in enumerate(faults):
        for b in faults[i + 1:]:
            same_unit = a.kind in WHOLE_UNIT or a.axis == b.axis
            meet = a.t == b.t or (a.t < b.t + span(b) and b.t < a.t + span(a))
            if a.kind == b.kind and same_unit and meet:
                raise ConfigError(f"{where} {b.spec}", None, f"overlaps {a.spec} (one kind on one unit at a time): "
                                                             "give one fault, or times that do not overlap")


def check_torquer_values(faults, dipole_limit, where: str = "fault") -> None:
    """Refuse a ``torquer_stuck`` value beyond its rod's dipole limit: a rod cannot hold more than it delivers (a
    stuck value 100 times the limit passed).

    Parameters
    ----------
    faults : sequence of Fault
        Injected faults.
    dipole_limit : array_like (3,)
        The rods' limits, body x, y, z [A m^2].
    where : str
        Context named in the error (``--fault``, ``faults``).

    Raises
    ------
    ConfigError
        Naming the fault, its value and the limit.
    """
    limit = np.broadcast_to(np.asarray(dipole_limit, dtype=float), (3,))
    for f in faults:
        if f.kind == TORQUER_STUCK and math.isfinite(f.value) and abs(f.value) > limit[f.axis]:
            raise ConfigError(f"{where} {f.spec}", "value", f"{f.value:g} A m^2 is beyond the rod's dipole_limit "
                                                            f"{limit[f.axis]:g} A m^2: give at most that")


def sun_lost(faults, t: float) -> bool:
    """True while a ``sun_loss`` fault silences the sun sensor at sim time ``t`` [s].

    Parameters
    ----------
    faults : iterable of Fault
        Injected faults (any kinds).
    t : float
        Sample time [s].

    Returns
    -------
    bool
        Whether the sun sensor puts out nothing at ``t``.
    """
    return any(f.kind == SUN_LOSS and f.active(t) for f in faults)


def kill_time(faults) -> float | None:
    """Sim time [s] of the first ``sensors_killed`` fault, or None.

    Parameters
    ----------
    faults : iterable of Fault
        Injected faults.

    Returns
    -------
    float or None
        Earliest onset [s] of a ``sensors_killed`` fault; None if there is none.
    """
    ts = [f.t for f in faults if f.kind == SENSORS_KILLED]
    return min(ts) if ts else None


@dataclass(frozen=True)
class FaultState:
    """What the faults remember: the last magnetometer sample put out and the last dipole applied (None: none yet)."""

    last_field: tuple | None = None
    last_dipole: tuple | None = None


def measure(faults, t: float, ts: float, b, w, state: FaultState = FaultState()):
    """The sensor faults active at sample ``t`` [s] (period ``ts``) on the measured field ``b`` [T] and gyro rate
    ``w`` [rad/s] (body axes).

    Order: biases and a spike add to the sample, a stuck magnetometer then repeats its last output, a dropout
    suppresses it. A spike acts on the one sample in [t0, t0 + ts).

    Parameters
    ----------
    faults : iterable of Fault
        Injected faults (any kinds; only the sensor kinds act here).
    t : float
        Sample time [s].
    ts : float
        Sample period [s] (the window of a spike).
    b : array_like (3,)
        Measured field [T], body axes.
    w : array_like (3,)
        Measured rate [rad/s], body axes.
    state : FaultState
        Last field put out and last dipole applied.

    Returns
    -------
    tuple
        (field or None when dropped, gyro rate, new :class:`FaultState`); without active faults the inputs
        unchanged (the same objects' values, bit for bit).
    """
    b = np.array(b, dtype=float)
    w = np.array(w, dtype=float)
    stuck = dropped = False
    for f in faults:
        if f.kind == MAG_SPIKE:
            if f.t <= t < f.t + ts:
                b[f.axis] += f.value
        elif not f.active(t):
            continue
        elif f.kind == MAG_BIAS:
            b[f.axis] += f.value
        elif f.kind == GYRO_BIAS:
            w[f.axis] += f.value
        elif f.kind == MAG_STUCK:
            stuck = True
        elif f.kind == MAG_DROPOUT:
            dropped = True
    if stuck and state.last_field is not None:
        b = np.array(state.last_field)
    if dropped:
        return None, w, state
    return b, w, FaultState(tuple(float(x) for x in b), state.last_dipole)


def actuate(faults, t: float, m, state: FaultState = FaultState()):
    """The torquer faults active at step ``t`` [s] on the dipole ``m`` [A m^2] the torquers are commanded.

    Parameters
    ----------
    faults : iterable of Fault
        Injected faults (any kinds; only the torquer kinds act here).
    t : float
        Step time [s].
    m : array_like (3,)
        Commanded dipole [A m^2], body axes.
    state : FaultState
        Last field put out and last dipole applied.

    Returns
    -------
    tuple
        (applied dipole, new :class:`FaultState`): a dead axis gives 0, a stuck axis its ``value`` or the dipole it
        applied the step before (the commanded one at the first step), a reversed axis minus its command, a
        gain-drop axis ``value`` times its command.
    """
    m = np.array(m, dtype=float)
    for f in faults:
        if f.kind not in TORQUER_KINDS or not f.active(t):
            continue
        if f.kind == TORQUER_DEAD:
            m[f.axis] = 0.0
        elif f.kind == TORQUER_REVERSED:
            m[f.axis] = -m[f.axis]
        elif f.kind == TORQUER_GAIN:
            m[f.axis] = f.value * m[f.axis]
        elif not math.isnan(f.value):
            m[f.axis] = f.value
        elif state.last_dipole is not None:
            m[f.axis] = state.last_dipole[f.axis]
    return m, FaultState(state.last_field, tuple(float(x) for x in m))
