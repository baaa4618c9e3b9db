"""Figures of merit of a closed-loop run (paper Figs. 2-3), from time histories.

One implementation for the offline simulation, the SIL runner, the sampling study and the
bag report: arrays in, a dict of floats out.
"""
from __future__ import annotations

import numpy as np


def pointing_error_deg(dq) -> np.ndarray:
    """Pointing error [deg]: the rotation angle of the body w.r.t. the orbital axes,
    2 asin(|q_vec|), from |dq_R| = |q_vec| (paper eq. 14, hemisphere q0 >= 0). Array in, array out.

    Returns
    -------
    ndarray
        Angle in degrees, same shape as ``dq``, in [0, 180].
    """
    return np.degrees(2.0 * np.arcsin(np.clip(np.asarray(dq, dtype=float), 0.0, 1.0)))


def figures_of_merit(t, x, m, orbit_period: float, tm=None) -> dict:
    """|dq_R| and pointing error final/peak/RMS, peak |m| and RMS |m| (paper section 5).

    ``t`` (n,) [s], ``x`` (n, 6) linear state [dq; dw] (paper eq. 14), ``m`` (k, 3) dipole
    [A m^2] at times ``tm`` (default ``t``), ``orbit_period`` T [s].

    Returns
    -------
    dict
        ``final_dq``, ``peak_dq``, ``rms_dq`` (|dq_R| = |Z x| over the window ``rms_window`` =
        t in [T, 5T]; a run with fewer than two samples there, i.e. not longer than one orbit,
        uses all of it: the window is always stated), the same as pointing error in degrees
        (``final_deg``, ``peak_deg``, ``rms_deg``, see :func:`pointing_error_deg`), ``peak_m``,
        ``rms_m`` (over the dipole samples in ``rms_window``), ``rms_m_orbits_2_5`` (nan unless
        at least two dipole samples lie in [T, 5T]) and ``orbits``.
    """
    t = np.asarray(t, dtype=float)
    dq = np.linalg.norm(np.asarray(x, dtype=float)[:, :3], axis=1)  # |dq_R| = sqrt(x^T Z^T Z x)
    deg = pointing_error_deg(dq)
    tm = t if tm is None else np.asarray(tm, dtype=float)
    mn = np.linalg.norm(np.asarray(m, dtype=float).reshape(-1, 3), axis=1)
    T = float(orbit_period)
    sel = (t >= T) & (t <= 5 * T)
    if np.count_nonzero(sel) < 2:  # run not longer than one orbit: use all of it
        sel = np.ones_like(dq, dtype=bool)
    lo, hi = float(t[sel][0]), float(t[sel][-1])
    msel = (tm >= T) & (tm <= 5 * T) if len(mn) else np.zeros(0, bool)
    wsel = (tm >= lo) & (tm <= hi) if len(mn) else np.zeros(0, bool)
    return dict(
        final_dq=float(dq[-1]),
        peak_dq=float(dq.max()),
        rms_dq=float(np.sqrt(np.mean(dq[sel] ** 2))),
        rms_window=(lo, hi),
        final_deg=float(deg[-1]),
        peak_deg=float(deg.max()),
        rms_deg=float(np.sqrt(np.mean(deg[sel] ** 2))),
        peak_m=float(mn.max()) if len(mn) else float("nan"),
        rms_m=float(np.sqrt(np.mean(mn[wsel] ** 2))) if np.count_nonzero(wsel) else float("nan"),
        rms_m_orbits_2_5=float(np.sqrt(np.mean(mn[msel] ** 2))) if np.count_nonzero(msel) >= 2 else float("nan"),
        orbits=float(t[-1] / T),
    )


def settling_time(t, dq, threshold: float) -> float:
    """First t_k after which dq stays below ``threshold`` to the end (nan if it ends above).

    A figure of the transients of paper section 5 (Figs. 2-5), used by campaigns' pass criteria.

    Returns
    -------
    float
        The settling time [s, the unit of ``t``]; ``t[0]`` if dq never exceeds the threshold.
    """
    t, dq = np.asarray(t), np.asarray(dq)
    above = np.nonzero(~(dq < threshold))[0]
    if above.size == 0:
        return float(t[0])
    k = above[-1] + 1
    return float(t[k]) if k < t.size else float("nan")


def format_figures(fom: dict) -> str:
    """One line of :func:`figures_of_merit` for terminals."""
    a, b = fom["rms_window"]
    line = (f"|dq_R| final {fom['final_dq']:.4e}  peak {fom['peak_dq']:.4e}  "
            f"RMS[{a:.0f}s..{b:.0f}s] {fom['rms_dq']:.4e}  |m| peak {fom['peak_m']:.4g} A m^2")
    if "final_deg" in fom:
        line += (f"\npointing error final {fom['final_deg']:.3f} deg  peak {fom['peak_deg']:.3f} deg  "
                 f"RMS[{a:.0f}s..{b:.0f}s] {fom['rms_deg']:.3f} deg")
    return line
