"""Peak-to-peak (L-inf-induced) gain of a stable LTP system: the literal reading of paper eq. (29).

Eq. (29) reads c2 = sup ||m||_inf / ||T_d||_inf over T_d in L_inf (SPEC.md reads it as an H2
norm instead). With the max-abs norm on vectors, the induced norm is

    ||G||_{inf->inf} = sup_t max_i sum_j int_{-inf}^t |g_ij(t, tau)| dtau,

g(t, tau) = C(t) phi(t, tau) B(tau) the impulse response. It is computed on a uniform grid:
for output times t_m spread over one period, the rows C(t_m) phi(t_m, tau) are propagated
backwards in tau with the transposed interval transitions (the adjoint system) over
``periods`` periods (the closed loops decay by ~rho per period), and |g| is integrated by the
trapezoid rule. Accuracy is set by ``steps`` (|g| has kinks at zero crossings: first order in
the step near them) and the truncation after ``periods`` periods.
"""
from __future__ import annotations

import numpy as np

from .system import LTPSystem, interval_grid, interval_transitions


def peak_to_peak(sys: LTPSystem, steps: int = 2048, periods: int = 3, outputs: int = 64) -> float:
    """sup_t max_i sum_j int |g_ij(t, tau)| dtau over ``outputs`` output times per period.

    Parameters
    ----------
    sys : LTPSystem
        One stable system (no batch axes).
    steps : int
        Intervals per period of the uniform grid (transitions, trapezoid rule in tau).
    periods : int
        Periods of the impulse response integrated back from each output time (truncation).
    outputs : int
        Output times t_m per period (every ``steps // outputs``-th grid point).

    Returns
    -------
    float
        The L-inf-induced (peak-to-peak) gain, eq. 29 read literally: max over output times and rows.

    Raises
    ------
    ValueError
        If ``sys`` has batch axes.
    """
    phi = interval_transitions(sys, steps)  # phi_k = phi(t_{k+1}, t_k), (steps, n, n)
    if phi.ndim != 3:
        raise ValueError("peak_to_peak: only a single system (no batch axes) is supported")
    t, h, _ = interval_grid(sys.period, steps)
    B = np.broadcast_to(sys.sample("B", t), (steps,) + sys.sample("B", t[:1]).shape[-2:])
    C = np.broadcast_to(sys.sample("C", t), (steps,) + sys.sample("C", t[:1]).shape[-2:])
    stride = max(1, steps // outputs)
    starts = np.arange(0, steps, stride)  # output times t_m = starts[m] * h (one period)
    # global tau index j runs from periods*steps + max(starts) down to 0; output m starts at
    # j_m = periods*steps + starts[m] and integrates back to j_m - periods*steps.
    j_end = periods * steps + starts
    P = np.zeros((starts.size,) + C.shape[1:])  # C(t_m) phi(t_m, tau_j)
    acc = np.zeros((starts.size, C.shape[1]))
    for j in range(int(j_end.max()), -1, -1):
        k = j % steps
        begin = j_end == j
        if begin.any():
            P[begin] = C[k]
        active = (j <= j_end) & (j >= j_end - periods * steps)
        g = np.abs(P @ B[k]).sum(axis=-1)  # sum_j |g_ij| at this tau, per output row i
        w = np.where(begin | (j == j_end - periods * steps), 0.5, 1.0)[:, None]
        acc += np.where(active[:, None], w * h * g, 0.0)
        if j > 0:  # phi(t_m, tau_{j-1}) = phi(t_m, tau_j) phi(tau_j, tau_{j-1})
            P = P @ phi[(j - 1) % steps]
    return float(acc.max())
