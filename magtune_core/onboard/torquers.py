"""The magnetorquers as the magnetometer and the plant see them: coupling and duty-cycling.

The torquers' own field reaches the magnetometer: at a sample it reads the geomagnetic field
plus ``C m_s``, ``C`` the coupling matrix [T/(A m^2)] (body axes; the dipole field of
:func:`dipole_coupling` for a magnetometer at r from the rods, or a measured matrix) and ``m_s``
the dipole flowing at the sample instant. Flight software time-shares the two (the C2A AOBC
cycle: measure 100 ms with the torquers off, actuate 800 ms, wait 100 ms for the field to
decay): here, per control period Ts, the torquers drive over [t_k, t_k + Ts - off_time) and are
off over the last ``off_time`` seconds (the integrators' sub-steps aligned on the switch:
:meth:`Torquers.substeps`), so the sample at t_k+1 sees the field of the last drive
decayed by exp(-off_time / decay_time) (0 with decay_time 0). With ``compensate`` the controller
drives ``m / f`` (f = on fraction, saturated per axis) so that the period's mean dipole is the
law's, as the sample-and-hold design assumes. One model for the controller node, the simulator
node, the offline loops and the batched campaigns (docs/torquers.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Most RK4 sub-steps per period :meth:`Torquers.substeps` uses to put the switch-off on the grid.
MAX_SUBSTEPS = 1000
#: mu0 / (4 pi) [T m / A].
MU0_4PI = 1e-7
_ZERO9 = (0.0,) * 9


def dipole_coupling(r) -> np.ndarray:
    """Coupling matrix C (3, 3) [T/(A m^2)] of a point dipole at the origin seen at ``r`` [m] (body axes):
    b = mu0/(4 pi |r|^3) (3 r_hat r_hat^T - I) m (Jackson, Classical Electrodynamics, eq. 5.56).

    Parameters
    ----------
    r : array_like (3,)
        Position of the magnetometer relative to the torquers [m], body axes.

    Returns
    -------
    ndarray (3, 3)
        The coupling matrix C [T/(A m^2)].

    Raises
    ------
    ValueError
        If |r| is not positive (zero or NaN).
    """
    r = np.asarray(r, dtype=float)
    d = float(np.linalg.norm(r))
    if not d > 0:
        raise ValueError("the magnetometer must sit away from the torquers (|r| > 0)")
    u = r / d
    return MU0_4PI / d**3 * (3.0 * np.outer(u, u) - np.eye(3))


@dataclass(frozen=True)
class Torquers:
    """Coupling into the magnetometer and the duty cycle of one satellite's torquers (SI units)."""

    coupling: tuple = _ZERO9  #: C, row-major [T/(A m^2)]: field at the magnetometer per unit dipole
    off_time: float = 0.0  #: torquers off for the last off_time [s] of every period (0: always on)
    decay_time: float = 0.0  #: time constant of the torquers' field after switch-off [s] (0: instant)
    compensate: bool = True  #: drive m / on_fraction so the period's mean dipole is the law's

    @classmethod
    def from_values(cls, v: dict) -> "Torquers":
        """From the parsed :data:`magtune_core.onboard.params.TORQUER_FIELDS` values.

        Parameters
        ----------
        v : dict
            Parsed values: ``torquer_coupling`` (9,), ``torquer_off_time``, ``torquer_decay_time``, ``duty_compensation``.

        Returns
        -------
        Torquers
            The torquers those values describe.
        """
        return cls(tuple(float(x) for x in np.asarray(v["torquer_coupling"], dtype=float).ravel()),
                   float(v["torquer_off_time"]), float(v["torquer_decay_time"]), bool(v["duty_compensation"]))

    @property
    def coupled(self) -> bool:
        """Any coupling (else the magnetometer sees the geomagnetic field only).

        Returns
        -------
        bool
            True when any entry of C is nonzero.
        """
        return any(self.coupling)

    @property
    def matrix(self) -> np.ndarray:
        """C as (3, 3).

        Returns
        -------
        ndarray (3, 3)
            The coupling matrix C [T/(A m^2)], body axes.
        """
        return np.reshape(np.asarray(self.coupling, dtype=float), (3, 3))

    def on_fraction(self, ts: float) -> float:
        """f = (Ts - off_time) / Ts: the fraction of a period the torquers drive.

        Parameters
        ----------
        ts : float
            Control sample period Ts [s].

        Returns
        -------
        float
            f (1.0 when ``off_time`` is 0).
        """
        return (ts - self.off_time) / ts if self.off_time > 0 else 1.0

    def command_scale(self, ts: float) -> float:
        """c: the law's dipole limit is c times the torquers' and it drives the law's dipole / c
        (c = f with ``compensate``, else 1: the law's dipole driven for the on time only).

        Parameters
        ----------
        ts : float
            Control sample period Ts [s].

        Returns
        -------
        float
            c: :meth:`on_fraction` with ``compensate``, else 1.0.
        """
        return self.on_fraction(ts) if self.compensate else 1.0

    def law_limit(self, dipole_limit, ts: float) -> np.ndarray:
        """The per-axis limit [A m^2] the laws saturate at: c times the torquers' (:meth:`command_scale`).

        Parameters
        ----------
        dipole_limit : float or array_like (3,)
            The torquers' per-axis dipole limit [A m^2].
        ts : float
            Control sample period Ts [s].

        Returns
        -------
        ndarray
            c times ``dipole_limit`` [A m^2] (its shape).
        """
        return np.asarray(dipole_limit, dtype=float) * self.command_scale(ts)

    def drive(self, m, ts: float) -> np.ndarray:
        """The dipole the torquers drive while on [A m^2]: the law's (saturated at :meth:`law_limit`) / c.

        Parameters
        ----------
        m : array_like (3,)
            The law's dipole [A m^2].
        ts : float
            Control sample period Ts [s].

        Returns
        -------
        ndarray (3,)
            m / c [A m^2] (m itself when c = 1).
        """
        c = self.command_scale(ts)
        return np.asarray(m, dtype=float) / c if c != 1.0 else np.asarray(m, dtype=float)

    def sample_factor(self) -> float:
        """g: the fraction of the last drive's field left at the sample (1 always on, exp(-off/tau) off).

        Returns
        -------
        float
            g: 1.0 always on, exp(-off_time / decay_time) when off, 0.0 with an instant decay.
        """
        if self.off_time <= 0:
            return 1.0
        return math.exp(-self.off_time / self.decay_time) if self.decay_time > 0 else 0.0

    def substeps(self, ts: float, substeps: int) -> int:
        """The RK4 sub-steps per period: the fewest >= ``substeps`` that put the switch-off on a sub-step
        boundary (:data:`MAX_SUBSTEPS` at most; ``substeps`` itself when always on).

        A sub-step straddling the switch could only carry the mean dipole, and with a pitch wheel's
        momentum the torque's timing inside the step matters: 2 sub-steps at Ts = 1 s with a 0.2 s off
        time put the attitude 2e-5 off an exact switch within 600 s, 60 % of the duty cycle's own
        effect; on the grid it is 3e-10 (tests/onboard/test_torquers.py).

        Parameters
        ----------
        ts : float
            Control sample period Ts [s].
        substeps : int
            The fewest RK4 sub-steps per period wanted.

        Returns
        -------
        int
            Sub-steps per period, the switch-off at Ts - off_time on a sub-step boundary.

        Raises
        ------
        ValueError
            If no count from ``substeps`` to :data:`MAX_SUBSTEPS` puts the switch-off on a boundary.
        """
        if self.off_time <= 0:
            return int(substeps)
        for n in range(int(substeps), MAX_SUBSTEPS + 1):
            x = (ts - self.off_time) * n / ts
            if abs(x - round(x)) < 1e-9 * max(1.0, x):
                return n
        raise ValueError(f"no grid of at most {MAX_SUBSTEPS} sub-steps per period puts a switch-off "
                         f"{self.off_time:g} s before the end of {ts:g} s on a sub-step")

    def substep_weights(self, ts: float, substeps: int) -> np.ndarray:
        """Per RK4 sub-step of a period: 1 inside the drive window [0, Ts - off_time), 0 after
        (``substeps`` from :meth:`substeps`: the switch on the grid; all ones when always on).

        Parameters
        ----------
        ts : float
            Control sample period Ts [s].
        substeps : int
            Sub-steps per period (from :meth:`substeps`).

        Returns
        -------
        ndarray (substeps,)
            1.0 for the sub-steps the torquers drive, 0.0 for those after the switch-off.
        """
        n_on = int(round((ts - self.off_time) * substeps / ts)) if self.off_time > 0 else int(substeps)
        return np.array([1.0] * n_on + [0.0] * (int(substeps) - n_on))

    def field(self, m_last) -> np.ndarray:
        """C g m_last [T], body axes: the torquers' field at the sample after the period's drive ``m_last``.

        Parameters
        ----------
        m_last : array_like (3,)
            The dipole driven over the period just ended [A m^2].

        Returns
        -------
        ndarray (3,)
            Field of the torquers at the magnetometer [T], body axes (zeros when uncoupled or g = 0).
        """
        g = self.sample_factor()
        if not self.coupled or g == 0.0:
            return np.zeros(3)
        c = [g * x for x in self.coupling]  # (g C) m in the batch kernel's order: the same numbers
        m0, m1, m2 = (float(x) for x in m_last)
        return np.array([c[0] * m0 + c[1] * m1 + c[2] * m2, c[3] * m0 + c[4] * m1 + c[5] * m2,
                         c[6] * m0 + c[7] * m1 + c[8] * m2])

    def check(self, ts: float, where: str) -> None:
        """ConfigError naming ``torquer_off_time`` unless the torquers drive for part of every period.

        Parameters
        ----------
        ts : float
            Control sample period Ts [s].
        where : str
            Where the values came from (file or node), named in the error.

        Raises
        ------
        ConfigError
            If ``off_time`` >= ``ts``, or no grid of at most :data:`MAX_SUBSTEPS` sub-steps puts the switch-off on a sub-step.
        """
        from ..base.errors import ConfigError

        if self.off_time >= ts:
            raise ConfigError(where, "torquer_off_time", f"expected less than the sample period ts = {ts:g} s, "
                                                         f"got {self.off_time:g} s (the torquers would never drive)")
        try:
            self.substeps(ts, 1)
        except ValueError as exc:
            raise ConfigError(where, "torquer_off_time", f"{exc}: round it to a multiple of ts/{MAX_SUBSTEPS}") from None


NONE = Torquers()
