"""Flight modes as a pure state machine: DETUMBLE -> ACQUISITION -> POINTING, SAFE on stale or frozen sensors.

``ModeLogic(params).step(state, measurements, t) -> (state, transition or None)``: no clock, no I/O,
no global state, so the mode manager node, the offline mode simulation
(:mod:`magtune_core.sim.modes_loop`) and campaigns fly the same logic and a scripted measurement
sequence tests it. Transitions use measured quantities only (gyro rate norm, filtered |db/dt|,
the attitude estimate's pointing error, the sensors' staleness flag), never the truth; every
guard holds for a persistence time before it fires, and each entry threshold lies beyond the
matching exit threshold (hysteresis), as in flight mode managers (e.g. the C2A AOBC mode manager's
transition conditions). Thresholds and timers: ``params.MODE_FIELDS`` (SI units).

SAFE recovers once the sensors have been fresh for ``safe_recovery_time``: to ACQUISITION (POINTING without
it) when the body is calm (|w| below ``detumble_exit_rate``) and the attitude valid at that instant, since a
short outage leaves nothing to detumble, else to DETUMBLE.

A magnetometer that repeats its sample bit for bit (``Measurements.field_step == 0``) for
``frozen_time`` is frozen: SAFE, as a stale stream (a working magnetometer's noise, or the field's
motion along the orbit, changes every sample). A SAFE commanded by :meth:`ModeLogic.request` is
sticky (``ModeState.held``): no automatic recovery until another mode is commanded (flight practice:
a ground-commanded safe mode waits for the ground, docs/decisions.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from ..base.errors import ConfigError
from ..base.schema import parse
from .params import MODE_FIELDS, check_modes

DETUMBLE, ACQUISITION, POINTING, SAFE = "DETUMBLE", "ACQUISITION", "POINTING", "SAFE"
#: Every mode, in the order a deployment flies them.
MODES = (DETUMBLE, ACQUISITION, POINTING, SAFE)


@dataclass(frozen=True)
class ModeParams:
    """Thresholds [rad/s, T/s, rad] and persistence times [s] of the mode logic (``MODE_FIELDS``)."""

    detumble_exit_rate: float = 4.5e-3
    detumble_exit_bdot: float = 5e-7
    detumble_exit_time: float = 600.0
    detumble_entry_rate: float = 9e-3
    detumble_entry_time: float = 60.0
    acquisition_abort_rate: float = 0.09
    acquisition: bool = True
    handover_angle: float = 0.087
    handover_time: float = 600.0
    acquisition_entry_angle: float = 0.26
    acquisition_entry_time: float = 120.0
    safe_recovery_time: float = 10.0
    frozen_time: float = 30.0
    attitude_loss_time: float = 180.0

    @classmethod
    def from_mapping(cls, params: dict, where="mode parameters") -> "ModeParams":
        """Validate ``params`` against ``MODE_FIELDS`` (defaults filled in, other keys ignored) and the
        hysteresis rules (``check_modes``); ConfigError naming the field otherwise.

        Parameters
        ----------
        params : dict
            Parameter values by field name.
        where : str
            Where the values came from (file or node), named in errors.

        Returns
        -------
        ModeParams
            The validated parameters.

        Raises
        ------
        ConfigError
            From :func:`~magtune_core.base.schema.parse` or :func:`~magtune_core.onboard.params.check_modes`.
        """
        v = parse(params, MODE_FIELDS, where)
        check_modes(v, where)
        return cls(**{f.name: v[f.name] for f in fields(cls)})


@dataclass(frozen=True)
class Measurements:
    """What the mode logic sees at one instant (all measured).

    ``rate`` |w_gyro| [rad/s] (inertial body rate norm), ``bdot`` filtered |db/dt| [T/s] (nan if
    unknown: the rate guard alone decides), ``pointing_error`` the attitude estimate's rotation
    angle from the orbital axes [rad] (nan if no estimate), ``stale`` True when a sensor stream is
    older than its timeout (decided by the caller on sim time), ``field_step`` |b_k - b_(k-1)| of
    the measured field [T] (0: the sample repeated bit for bit; nan: unknown, never frozen),
    ``attitude_known`` False while the attitude estimate is not valid (before the estimator's fix, or
    its covariance or innovations inconsistent: onboard.estimator.ValidityMonitor).
    """

    rate: float
    bdot: float = math.nan
    pointing_error: float = math.nan
    stale: bool = False
    field_step: float = math.nan
    attitude_known: bool = True


@dataclass(frozen=True)
class ModeState:
    """Current mode, when it was entered and why, and the start times of the pending guards (None: not holding)."""

    mode: str = DETUMBLE
    since: float = 0.0
    reason: str = "start"
    #: guard name -> sim time [s] since which its condition has held continuously
    pending: tuple = ()
    #: a commanded SAFE: no automatic recovery (only another request leaves it)
    held: bool = False

    def held_since(self, guard: str):
        """Start time of ``guard``'s condition, or None.

        Parameters
        ----------
        guard : str
            Guard name (e.g. "calm", "stale").

        Returns
        -------
        float or None
            Sim time [s] since which its condition has held, None if it does not hold.
        """
        return dict(self.pending).get(guard)


@dataclass(frozen=True)
class Transition:
    """One mode change: from, to, sim time [s] and the reason (a sentence naming the measured quantity)."""

    source: str
    target: str
    t: float
    reason: str


@dataclass(frozen=True)
class ModeLogic:
    """The guards of each mode (``params``: :class:`ModeParams`); :meth:`step` is the whole machine."""

    params: ModeParams = ModeParams()

    def guards(self, mode: str, m: Measurements, held: bool = False):
        """(guard name, condition holds, persistence [s], target, reason) of ``mode``, in priority order
        (``held``: a commanded SAFE, which has none).

        Parameters
        ----------
        mode : str
            Current mode, one of :data:`MODES`.
        m : Measurements
            Measurements of this instant.
        held : bool
            The current mode is a commanded (sticky) SAFE.

        Returns
        -------
        list of tuple (str, bool, float, str, str)
            The guards of ``mode`` (empty for a held SAFE).
        """
        p = self.params
        frozen = m.field_step == 0.0
        if mode == SAFE:
            if held:
                return []
            if m.rate < p.detumble_exit_rate and m.attitude_known:  # nothing to detumble: straight to the capture
                return [("fresh", not (m.stale or frozen), p.safe_recovery_time, ACQUISITION if p.acquisition else POINTING,
                         f"sensors fresh for {p.safe_recovery_time:g} s, |w| < {p.detumble_exit_rate:g} rad/s and the "
                         "attitude valid")]
            return [("fresh", not (m.stale or frozen), p.safe_recovery_time, DETUMBLE,
                     f"sensors fresh for {p.safe_recovery_time:g} s")]
        out = [("stale", m.stale, 0.0, SAFE, "sensor data stale"),
               ("frozen", frozen, p.frozen_time, SAFE, f"magnetometer frozen (sample repeated) for {p.frozen_time:g} s")]
        if mode == DETUMBLE:
            bdot_ok = math.isnan(m.bdot) or m.bdot < p.detumble_exit_bdot
            calm = m.rate < p.detumble_exit_rate and bdot_ok and m.attitude_known
            nxt = ACQUISITION if p.acquisition else POINTING
            out.append(("calm", calm, p.detumble_exit_time, nxt,
                        f"|w| < {p.detumble_exit_rate:g} rad/s and |db/dt| < {p.detumble_exit_bdot:g} T/s "
                        f"and the attitude valid for {p.detumble_exit_time:g} s"))
            return out
        # capturing from a large error spins the body up (measured up to 0.064 rad/s): a higher abort rate
        limit = p.acquisition_abort_rate if mode == ACQUISITION else p.detumble_entry_rate
        out.append(("tumbling", m.rate > limit, p.detumble_entry_time, DETUMBLE,
                    f"|w| > {limit:g} rad/s for {p.detumble_entry_time:g} s"))
        out.append(("unknown", not m.attitude_known, p.attitude_loss_time, DETUMBLE,
                    f"attitude estimate not valid for {p.attitude_loss_time:g} s"))
        err = m.pointing_error
        if mode == ACQUISITION:
            out.append(("inside", err < p.handover_angle, p.handover_time, POINTING,
                        f"pointing error < {p.handover_angle:g} rad for {p.handover_time:g} s"))
        elif mode == POINTING and p.acquisition:
            out.append(("outside", err > p.acquisition_entry_angle, p.acquisition_entry_time, ACQUISITION,
                        f"pointing error > {p.acquisition_entry_angle:g} rad for {p.acquisition_entry_time:g} s"))
        return out

    def step(self, state: ModeState, m: Measurements, t: float) -> tuple[ModeState, Transition | None]:
        """Advance the machine to sim time ``t`` [s] with measurements ``m``.

        A guard's timer starts at the first instant its condition holds and resets when it fails
        (a nan measurement fails every comparison: no estimate, no hand-over); the first guard (in
        priority order) whose condition has held for its persistence time fires; the new mode's
        guards start at the next call (one sample after the transition).

        Parameters
        ----------
        state : ModeState
            State after the previous call.
        m : Measurements
            Measurements at ``t``.
        t : float
            Sim time [s].

        Returns
        -------
        state : ModeState
            The new state (pending timers updated, or the new mode with none).
        transition : Transition or None
            The mode change, None if the mode did not change.
        """
        pending = dict(state.pending)
        new_pending = {}
        for name, holds, persist, target, reason in self.guards(state.mode, m, state.held):
            if not holds:
                continue
            start = pending.get(name, t)
            new_pending[name] = start
            if t - start >= persist:
                tr = Transition(state.mode, target, float(t), reason)
                return ModeState(target, float(t), reason, ()), tr
        return replace(state, pending=tuple(sorted(new_pending.items()))), None

    def request(self, state: ModeState, mode: str, t: float, reason: str = "commanded",
                hold: bool = True) -> tuple[ModeState, Transition]:
        """A commanded mode change (the mode manager's service); ConfigError naming the field on an unknown mode.

        A commanded SAFE is sticky (``hold``, the default): it stays until another mode is requested. The
        manager's own SAFE on a lost heartbeat passes ``hold=False`` (it recovers when the data are fresh).

        Parameters
        ----------
        state : ModeState
            Current state.
        mode : str
            Requested mode, one of :data:`MODES`.
        t : float
            Sim time of the request [s].
        reason : str
            Reason recorded in the state and the transition.
        hold : bool
            Make a requested SAFE sticky.

        Returns
        -------
        state : ModeState
            The new state, in ``mode`` with no pending guards.
        transition : Transition
            The commanded change (also when ``mode`` is the current mode).

        Raises
        ------
        ConfigError
            If ``mode`` is not one of :data:`MODES`.
        """
        if mode not in MODES:
            raise ConfigError("mode request", "mode", f"expected one of {', '.join(MODES)}, got {mode!r}")
        return (ModeState(mode, float(t), reason, (), held=bool(hold and mode == SAFE)),
                Transition(state.mode, mode, float(t), reason))
