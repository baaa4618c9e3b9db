"""The mode machine and the B-dot law on floats, compiled (numba), for the batched simulation.

The batched closed loop (:func:`magtune_core.sim.batch_kernels.closed_loop`) is a numba kernel and
cannot call the Python :class:`~magtune_core.onboard.modes.ModeLogic`; this module is the same machine
written on scalars from the same parameters (:class:`KernelModeParams` is
:class:`~magtune_core.onboard.modes.ModeParams` field for field, built by :func:`kernel_params`), guard
for guard in the same priority order, with the same persistence rule (a timer starts at the first
instant its condition holds, restarts when it fails, fires when ``t - start >= persistence``; the new
mode's timers start at the next call). :func:`bdot_dipole` is
:meth:`~magtune_core.onboard.bdot.BdotController.dipole` and :func:`filter_step` the
:class:`~magtune_core.onboard.bdot.FieldDerivativeFilter` recursion. tests/sim/test_batch_modes.py
checks a batched deployment against :func:`magtune_core.sim.modes_loop.simulate_modes`: same
transitions to the sample, same trajectory to 1e-9.
"""
from __future__ import annotations

import math
from dataclasses import asdict
from typing import NamedTuple

import numpy as np
from numba import njit

from .modes import ACQUISITION, DETUMBLE, MODES, POINTING, SAFE, ModeParams

#: Mode codes of the kernel: the index in :data:`~magtune_core.onboard.modes.MODES`.
MODE_CODE = {m: i for i, m in enumerate(MODES)}
_DET, _ACQ, _PNT, _SAFE = (MODE_CODE[m] for m in (DETUMBLE, ACQUISITION, POINTING, SAFE))
#: Guard slots of the pending timers (ModeLogic's guard names).
GUARDS = ("stale", "fresh", "calm", "tumbling", "inside", "outside", "frozen", "unknown")
_STALE, _FRESH, _CALM, _TUMBLING, _INSIDE, _OUTSIDE, _FROZEN, _UNKNOWN = range(len(GUARDS))


class KernelModeParams(NamedTuple):
    """:class:`~magtune_core.onboard.modes.ModeParams` as a tuple numba can read (same names, SI units)."""

    detumble_exit_rate: float
    detumble_exit_bdot: float
    detumble_exit_time: float
    detumble_entry_rate: float
    detumble_entry_time: float
    acquisition_abort_rate: float
    acquisition: bool
    handover_angle: float
    handover_time: float
    acquisition_entry_angle: float
    acquisition_entry_time: float
    safe_recovery_time: float
    frozen_time: float
    attitude_loss_time: float


def kernel_params(p: ModeParams) -> KernelModeParams:
    """The kernel's copy of ``p`` (every field of ModeParams, by name: a field on one side only fails here).

    Parameters
    ----------
    p : ModeParams
        The mode logic's parameters.

    Returns
    -------
    KernelModeParams
        The same values by name (``acquisition`` as bool, the others as float).

    Raises
    ------
    ValueError
        ``p`` has a field the kernel lacks, or the reverse (the compiled twin would drift silently).
    """
    v = asdict(p)
    if set(v) != set(KernelModeParams._fields):
        raise ValueError(f"ModeParams and KernelModeParams differ in {sorted(set(v) ^ set(KernelModeParams._fields))}")
    return KernelModeParams(**{k: (bool(v[k]) if k == "acquisition" else float(v[k])) for k in KernelModeParams._fields})


@njit(cache=True, inline="always")
def _hold(holds, g, persist, t, pending, newp):
    """One guard: keep (or start) its timer while ``holds``; True when it has held for ``persist``."""
    if not holds:
        return False
    start = pending[g] if not math.isnan(pending[g]) else t
    newp[g] = start
    return t - start >= persist


@njit(cache=True, error_model="numpy")
def mode_step(mode, pending, rate, bdot, err, stale, t, P, fstep=math.nan, held=False, known=True):
    """:meth:`ModeLogic.step` on floats: the new mode code (== ``mode``: no transition).

    ``pending`` (8,) the guards' start times [s] (nan: not holding; :data:`GUARDS`), updated in
    place (cleared on a transition); ``rate`` |w_gyro| [rad/s], ``bdot`` filtered |db/dt| [T/s] (nan:
    unknown), ``err`` estimated pointing error [rad] (nan: none), ``stale`` bool, ``t`` sim time [s],
    ``fstep`` |b_k - b_(k-1)| [T] (0: frozen sample; nan: unknown), ``held`` a commanded (sticky) SAFE,
    ``known`` the attitude estimate is valid.
    """
    newp = np.full(pending.size, np.nan)
    target = -1
    frozen = fstep == 0.0
    if mode == _SAFE:
        if not held and _hold(not (stale or frozen), _FRESH, P.safe_recovery_time, t, pending, newp):
            calm = rate < P.detumble_exit_rate and known  # nothing to detumble: straight to the capture
            target = (_ACQ if P.acquisition else _PNT) if calm else _DET
    elif _hold(stale, _STALE, 0.0, t, pending, newp):
        target = _SAFE
    elif _hold(frozen, _FROZEN, P.frozen_time, t, pending, newp):
        target = _SAFE
    elif mode == _DET:
        bdot_ok = math.isnan(bdot) or bdot < P.detumble_exit_bdot
        calm = rate < P.detumble_exit_rate and bdot_ok and known
        if _hold(calm, _CALM, P.detumble_exit_time, t, pending, newp):
            target = _ACQ if P.acquisition else _PNT
    else:
        limit = P.acquisition_abort_rate if mode == _ACQ else P.detumble_entry_rate
        if _hold(rate > limit, _TUMBLING, P.detumble_entry_time, t, pending, newp):
            target = _DET
        elif _hold(not known, _UNKNOWN, P.attitude_loss_time, t, pending, newp):
            target = _DET
        elif mode == _ACQ:
            if _hold(err < P.handover_angle, _INSIDE, P.handover_time, t, pending, newp):
                target = _PNT
        elif mode == _PNT and P.acquisition:
            if _hold(err > P.acquisition_entry_angle, _OUTSIDE, P.acquisition_entry_time, t, pending, newp):
                target = _ACQ
    if target >= 0:
        pending[:] = np.nan
        return target
    pending[:] = newp
    return mode


@njit(cache=True, inline="always", error_model="numpy")
def filter_step(a, ts, first, bp, yf, b0, b1, b2):
    """One sample of the field-derivative filter (FieldDerivativeFilter.step): ``bp``, ``yf`` (3,) the previous
    sample and output, updated in place; ``first``: no previous sample (output zero). Returns db/dt [T/s]."""
    if first:
        yf[0] = yf[1] = yf[2] = 0.0
    else:
        yf[0] = a * yf[0] + (1.0 - a) * (b0 - bp[0]) / ts
        yf[1] = a * yf[1] + (1.0 - a) * (b1 - bp[1]) / ts
        yf[2] = a * yf[2] + (1.0 - a) * (b2 - bp[2]) / ts
    bp[0], bp[1], bp[2] = b0, b1, b2
    return yf[0], yf[1], yf[2]


@njit(cache=True, inline="always", error_model="numpy")
def bdot_dipole(b0, b1, b2, d0, d1, d2, k, normalized, min_field, l0, l1, l2):
    """BdotController.dipole on floats: (m0, m1, m2 [A m^2], weak field, saturated) from the measured field
    b [T] and db/dt [T/s]."""
    nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if not nb >= min_field:
        return 0.0, 0.0, 0.0, True, False
    if normalized:  # m = -(k/|b|) d(b/|b|)/dt, d(b/|b|)/dt = (bdot - b_hat (b_hat . bdot)) / |b|
        h0, h1, h2 = b0 / nb, b1 / nb, b2 / nb
        dot = h0 * d0 + h1 * d1 + h2 * d2
        n2 = nb * nb
        m0, m1, m2 = -k * (d0 - h0 * dot) / n2, -k * (d1 - h1 * dot) / n2, -k * (d2 - h2 * dot) / n2
    else:
        m0, m1, m2 = -k * d0, -k * d1, -k * d2
    s0, s1, s2 = min(max(m0, -l0), l0), min(max(m1, -l1), l1), min(max(m2, -l2), l2)
    return s0, s1, s2, False, (s0 != m0 or s1 != m1 or s2 != m2)
