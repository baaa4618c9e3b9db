"""RK4 sub-steps per controller period, re-chosen at every step from the body rate.

A deployment starts tumbling at several deg/s and ends pointing at the orbit rate: the sub-steps the
first minutes need are twice what the remaining hours need. :class:`Substeps` keeps the step angle
|w| h at most :data:`MAX_STEP_ANGLE` at the start of every period with the fewest sub-steps of a ladder
``fewest * 2**j`` (at most ``most``). The ladder's grids nest, so every sub-step's stage times lie on
the finest grid, ``Ts / (2 most)``: the stage-time environment table of the full environment
(:class:`magtune_core.sim.fullenv.FullDynamics`, the batch's tables) is the same table whatever the
level, and a run flown at ``most`` = 4 that drops to 2 reads exactly the rows a run flown at 2 reads.
The simulator node, :func:`~magtune_core.sim.simulate.simulate`,
:func:`~magtune_core.sim.modes_loop.simulate_modes` and the batch kernel all choose with this class
(the rate is the true state's: the choice is the integrator's, not the flight software's).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..onboard.torquers import NONE as NO_TORQUERS
from ..onboard.torquers import Torquers

#: Largest rotation [rad] of the body during one RK4 sub-step: 0.05 rad is what the paper set-up's
#: two sub-steps per second take at the nutation frequency of the momentum-biased body (0.082 rad/s x
#: 0.5 s = 0.041 rad), so a tumbling run is integrated no less accurately per step than the paper's.
MAX_STEP_ANGLE = 0.05
#: Sub-steps of the paper reproduction (simulate's and the simulator node's default).
MIN_SUBSTEPS = 2


def substeps_for_rate(rate, ts: float, max_step_angle: float = MAX_STEP_ANGLE, minimum: int = MIN_SUBSTEPS) -> int:
    """RK4 sub-steps per controller period so that |w| h <= ``max_step_angle`` (h = ts / substeps).

    ``rate`` the body rate [rad/s] (a 3-vector or its norm); at least ``minimum``. E.g. 5 deg/s per
    axis at Ts = 1 s: 4 (0.151 rad/s x 1 s / 0.05 rad = 3.02).
    """
    w = float(np.linalg.norm(np.asarray(rate, dtype=float)))
    if not math.isfinite(w):
        raise ValueError(f"substeps_for_rate: rate must be finite, got {rate!r}")
    return max(int(minimum), int(math.ceil(w * float(ts) / float(max_step_angle) - 1e-12)))


@dataclass(frozen=True)
class Substeps:
    """The ladder of sub-steps ``fewest * 2**j`` <= ``most`` and the rate each level covers.

    ``fewest``: the paper's 2, or what puts a duty cycle's switch-off on the grid
    (:meth:`magtune_core.onboard.torquers.Torquers.substeps`); ``most``: the level the fastest rate of
    the run needs (the finest grid, ``Ts / (2 most)``). ``fewest == most``: a fixed number of sub-steps.
    """

    ts: float
    fewest: int
    most: int
    max_step_angle: float = MAX_STEP_ANGLE

    def __post_init__(self):
        f, m = int(self.fewest), int(self.most)
        if f < 1 or m < f or m % f or (m // f) & (m // f - 1):
            raise ValueError(f"Substeps: most ({self.most}) must be fewest ({self.fewest}) times a power of 2")
        levels = tuple(f << j for j in range((m // f).bit_length()))
        object.__setattr__(self, "_levels", levels)
        object.__setattr__(self, "_thr", tuple((self.max_step_angle * s / self.ts) ** 2 for s in levels))

    @classmethod
    def ladder(cls, ts: float, fewest: int, need: int, torquers: Torquers = NO_TORQUERS) -> "Substeps":
        """The ladder from ``fewest`` (raised to put the duty cycle's switch-off on the grid) up to the
        first level >= ``need``."""
        lo = torquers.substeps(ts, int(fewest))
        hi = lo
        while hi < int(need):
            hi *= 2
        return cls(float(ts), lo, hi)

    @classmethod
    def for_rate(cls, ts: float, rate, fewest: int = MIN_SUBSTEPS, torquers: Torquers = NO_TORQUERS) -> "Substeps":
        """The ladder a run starting at body rate ``rate`` [rad/s] needs (B-dot and the pointing law only
        remove kinetic energy: the initial rate bounds the run's). The paper's dw(0): fixed at 2."""
        return cls.ladder(ts, fewest, substeps_for_rate(rate, ts, minimum=fewest), torquers)

    @property
    def levels(self) -> tuple[int, ...]:
        """The sub-step counts, fewest first."""
        return self._levels

    @property
    def adaptive(self) -> bool:
        """More than one level."""
        return self.most > self.fewest

    def thresholds(self) -> np.ndarray:
        """(levels,) the largest squared rate [rad^2/s^2] each level covers: (max_step_angle s / Ts)^2."""
        return np.array(self._thr)

    def at(self, y) -> int:
        """The sub-steps of the period starting at state ``y`` (q, w: reads y[4:7]), the batch kernel's rule
        term by term (the same squared rate against the same thresholds)."""
        w2 = float(y[4]) * float(y[4]) + float(y[5]) * float(y[5]) + float(y[6]) * float(y[6])
        for s, thr in zip(self._levels[:-1], self._thr):
            if not w2 > thr:
                return s
        return int(self.most)

    def weights(self, torquers: Torquers) -> dict:
        """{level: the duty cycle's per-sub-step weights (None: always on)}."""
        return {s: torquers.substep_weights(self.ts, s) if torquers.off_time > 0 else None for s in self.levels}
