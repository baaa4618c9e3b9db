"""Is the attitude estimate valid? The estimator's own figures, judged one sample at a time.

A flight mode manager must not point on an estimate that has not converged or that disagrees with
its measurements. :class:`ValidityMonitor` calls the estimate valid while

* the filter has made its coarse fix,
* every axis' attitude standard deviation (the MEKF's covariance) is below ``valid_sigma``, and
* the magnetometer's normalized innovation squared (NIS, chi-square with 3 degrees of freedom for
  a consistent filter), each capped at the filter's gate and averaged exponentially over
  ``valid_nis_tau``, is below ``valid_nis_limit``.

The defaults are derived, not picked (:func:`nis_limit`, docs/modes.md): ``valid_sigma`` is a third
of the hand-over angle; ``valid_nis_limit`` is the 1e-9 quantile of the average's distribution for a
consistent filter. The persistence before a mode changes on validity is the mode logic's
(``attitude_loss_time``, ``detumble_exit_time``). One timer is the monitor's: an estimate not valid for
``reinit_time`` after the fix is dropped (:attr:`ValidityMonitor.reinit_due`; the caller restarts the
filter from a coarse fix): a filter that diverged, e.g. while tumbling faster than its gyro model
allows, gates every update and would never come back by itself.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The NIS average's prior at the fix: its mean for a consistent filter (3 degrees of freedom).
NIS_DOF = 3


def nis_limit(tau: float, ts: float, probability: float, dof: int = NIS_DOF) -> float:
    """Upper quantile of the exponentially averaged NIS of a consistent filter.

    The average y_k = a y_(k-1) + (1 - a) nis_k, a = exp(-ts/tau), of independent chi-square(dof)
    samples has mean dof and variance 2 dof (1 - a)/(1 + a); it is approximated by c chi-square(nu)
    with the same two moments (Welch-Satterthwaite): nu = dof (1 + a)/(1 - a), c = dof/nu.

    Parameters
    ----------
    tau : float
        Averaging time constant [s].
    ts : float
        Sample period [s].
    probability : float
        Probability that a consistent filter's average exceeds the limit at a given sample.
    dof : int
        Degrees of freedom of one NIS (3: the magnetometer, 2: the sun sensor).

    Returns
    -------
    float
        The limit on the average.
    """
    from scipy.stats import chi2

    a = math.exp(-ts / tau)
    nu = dof * (1.0 + a) / (1.0 - a)
    return float(dof / nu * chi2.isf(probability, nu))


@dataclass
class ValidityMonitor:
    """The validity of the estimate, sample by sample (see the module docstring).

    ``ts`` [s] the sample period, ``sigma`` [rad] ``valid_sigma``, ``tau`` [s] ``valid_nis_tau``,
    ``limit`` ``valid_nis_limit``, ``cap`` the magnetometer gate (a rejected update counts as the
    gate's value, so one outlier moves the average by at most (1 - a) cap), ``reinit`` [s] ``reinit_time``
    (0: never).
    """

    ts: float
    sigma: float
    tau: float
    limit: float
    cap: float
    reinit: float = 0.0
    average: float = math.nan  #: the NIS average (nan before the fix)
    invalid: int = 0  #: samples in a row not valid since the fix

    @property
    def reinit_due(self) -> bool:
        """Whether the estimate has not been valid for ``reinit`` s since the fix.

        Returns
        -------
        bool
            True: the caller restarts the filter from a coarse fix, then calls :meth:`reset`.
        """
        return self.reinit > 0 and self.invalid * self.ts >= self.reinit

    def reset(self) -> None:
        """Back to the state before a fix (the filter restarts)."""
        self.average, self.invalid = math.nan, 0

    def forgive(self) -> None:
        """Restart the NIS average at its mean (the sensor watch named the unit whose innovations raised it and the
        filter re-estimates that unit's bias: the evidence is spent)."""
        if not math.isnan(self.average):
            self.average = float(NIS_DOF)

    @classmethod
    def from_values(cls, v: dict, ts: float, cap: float) -> "ValidityMonitor":
        """The monitor of parsed ``VALIDITY_FIELDS`` values.

        Parameters
        ----------
        v : dict
            Parsed values (``valid_sigma``, ``valid_nis_tau``, ``valid_nis_limit``, ``reinit_time``).
        ts : float
            Sample period [s].
        cap : float
            The magnetometer's chi-square gate (``MekfStream.gate_mag``).

        Returns
        -------
        ValidityMonitor
            A monitor before the fix.
        """
        return cls(ts, v["valid_sigma"], v["valid_nis_tau"], v["valid_nis_limit"], cap, v["reinit_time"])

    def step(self, P, nis_mag: float) -> bool:
        """Take one sample's covariance and NIS; is the estimate valid?

        Parameters
        ----------
        P : array_like (n, n) or None
            The filter's covariance (attitude block first, rad^2); None before the fix.
        nis_mag : float
            The magnetometer update's NIS (nan: no update this sample, the average holds).

        Returns
        -------
        bool
            True when fixed, every attitude sigma < ``sigma`` and the average < ``limit``.
        """
        if P is None:
            self.average = math.nan
            return False
        if math.isnan(self.average):
            self.average = float(NIS_DOF)
        if not math.isnan(nis_mag):
            a = math.exp(-self.ts / self.tau)
            self.average = a * self.average + (1.0 - a) * min(float(nis_mag), self.cap)
        var = np.diagonal(np.asarray(P))[:3]
        valid = bool(max(var) < self.sigma * self.sigma and self.average < self.limit)
        self.invalid = 0 if valid else self.invalid + 1
        return valid
