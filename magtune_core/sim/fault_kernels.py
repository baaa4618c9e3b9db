"""Injected faults in the batched simulation: :mod:`magtune_core.design.faults` on scalars, compiled (numba).

The batched closed loop (:func:`magtune_core.sim.batch_kernels.closed_loop`) cannot call
:func:`~magtune_core.design.faults.measure` and :func:`~magtune_core.design.faults.actuate`; these are the same
rules on the kernel's arrays, fault for fault in list order: a spike adds to the one sample in [t0, t0 + Ts),
a magnetometer or gyro bias adds from t0 for its duration, a sun-sensor loss suppresses the sun samples,
and on the dipole the torquers are driven with, a dead axis gives 0, a reversed one minus its command, a
gain drop ``value`` times it and a stuck one its ``value`` or the dipole it applied the step before. Every
run of a batch flies the same fault list (a campaign's ``faults`` section). The kinds that need a memory of
the sensor stream or processes (``mag_stuck``, ``mag_dropout``, ``sensors_killed``) are the SIL's and the
offline loop's: :func:`kernel_faults` refuses them. tests/sim/test_batch_faults.py checks a batched run
against :func:`magtune_core.sim.modes_loop.simulate_modes` with the same faults.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..design import faults as fl

#: Kind codes of the kernel (the kinds it flies).
FAULT_CODE = {fl.MAG_SPIKE: 0, fl.MAG_BIAS: 1, fl.GYRO_BIAS: 2, fl.SUN_LOSS: 3, fl.TORQUER_DEAD: 4,
              fl.TORQUER_STUCK: 5, fl.TORQUER_REVERSED: 6, fl.TORQUER_GAIN: 7}
_SPIKE, _MBIAS, _GBIAS, _SUN, _DEAD, _STUCK, _REV, _GAIN = range(8)
#: Kinds only the SIL and the offline loop fly.
NOT_BATCHED = tuple(k for k in fl.KINDS if k not in FAULT_CODE)


class KernelFaults(NamedTuple):
    """The fault list of every run as arrays (:func:`kernel_faults`); F = 0: no fault."""

    kind: np.ndarray  #: (F,) int64 code (FAULT_CODE)
    t0: np.ndarray  #: (F,) onset [s]
    t1: np.ndarray  #: (F,) end [s] (onset + duration; inf: to the end)
    axis: np.ndarray  #: (F,) int64 body axis
    value: np.ndarray  #: (F,) size (nan: the kind's default behaviour, e.g. a stuck torquer holds its last dipole)
    ts: float  #: sample period [s] (a spike's window)


def kernel_faults(faults, ts: float) -> KernelFaults:
    """The kernel's copy of a fault list.

    Parameters
    ----------
    faults : sequence of Fault or str
        Injected faults (:func:`magtune_core.design.faults.from_list` takes either).
    ts : float
        Controller sample period [s].

    Returns
    -------
    KernelFaults
        The arrays :func:`sensor_faults` and :func:`torquer_faults` read.

    Raises
    ------
    ValueError
        A kind the batch does not fly (:data:`NOT_BATCHED`), naming it.
    """
    fs = fl.from_list(list(faults))
    for f in fs:
        if f.kind in NOT_BATCHED:
            raise ValueError(f"{f.kind} is flown by magtune sil and the offline mode loop, not by the batch "
                             f"(batched kinds: {', '.join(FAULT_CODE)})")
    return KernelFaults(np.array([FAULT_CODE[f.kind] for f in fs], dtype=np.int64),
                        np.array([f.t for f in fs], dtype=float), np.array([f.t + f.duration for f in fs], dtype=float),
                        np.array([f.axis for f in fs], dtype=np.int64), np.array([f.value for f in fs], dtype=float),
                        float(ts))


@njit(cache=True, error_model="numpy")
def sensor_faults(fk, t, bm, wm):
    """The sensor faults active at sample ``t`` on the measured field ``bm`` and gyro rate ``wm`` (in place).

    Parameters
    ----------
    fk : KernelFaults
        The faults.
    t : float
        Sample time [s].
    bm, wm : ndarray (3,)
        Measured field [T] and gyro rate [rad/s], body axes (changed in place).

    Returns
    -------
    bool
        True when the sun sensor is lost at ``t`` (no sun sample).
    """
    lost = False
    for i in range(fk.kind.size):
        c = fk.kind[i]
        if c == _SPIKE:
            if fk.t0[i] <= t < fk.t0[i] + fk.ts:
                bm[fk.axis[i]] += fk.value[i]
        elif not (fk.t0[i] <= t < fk.t1[i]):
            continue
        elif c == _MBIAS:
            bm[fk.axis[i]] += fk.value[i]
        elif c == _GBIAS:
            wm[fk.axis[i]] += fk.value[i]
        elif c == _SUN:
            lost = True
    return lost


@njit(cache=True, error_model="numpy")
def torquer_faults(fk, t, m, last, first):
    """The torquer faults active at step ``t`` on the dipole ``m`` the torquers are driven with (in place).

    Parameters
    ----------
    fk : KernelFaults
        The faults.
    t : float
        Step time [s].
    m : ndarray (3,)
        Driven dipole [A m^2] -> applied dipole (in place).
    last : ndarray (3,)
        The dipole applied the step before [A m^2] (a stuck torquer without a value holds it).
    first : bool
        No step before (a stuck torquer then holds the driven dipole).
    """
    for i in range(fk.kind.size):
        c = fk.kind[i]
        if c < _DEAD or not (fk.t0[i] <= t < fk.t1[i]):
            continue
        a = fk.axis[i]
        if c == _DEAD:
            m[a] = 0.0
        elif c == _REV:
            m[a] = -m[a]
        elif c == _GAIN:
            m[a] = fk.value[i] * m[a]
        elif not math.isnan(fk.value[i]):
            m[a] = fk.value[i]
        elif not first:
            m[a] = last[a]
