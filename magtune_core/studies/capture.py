"""Region of attraction of the pointing law (paper eq. 17) from arbitrary attitudes, by batched simulation.

B-dot detumbling (onboard/bdot.py) leaves the attitude arbitrary and the body rate at a few orbital
rates, while the gains of eq. 17 are tuned on the model linearized about the nominal attitude.
This study flies the shipped pointing law (:func:`magtune_core.sim.batch.simulate_batch`, paper
environment) from initial attitude errors drawn on a grid of angles with random axes and initial
rate deviations of given multiples of W0 in random directions, and reports from which it captures:
a run is *captured* when its true pointing error stays below ``capture_deg`` over the last
``settle_orbits`` of the run; its capture time is the last instant it was above.
"""
from __future__ import annotations

import numpy as np

from ..design.params import SpacecraftParams
from ..onboard.params import TS_DEFAULT
from ..sim.batch import BatchRuns, simulate_batch


def deployment_draws(angles_deg, rate_scales, per_cell: int, orbit_rate: float, seed: int):
    """Initial attitudes and rate deviations of the study: for every (angle, rate scale) pair
    ``per_cell`` runs with random rotation axes and random rate directions (``seed``).

    Returns
    -------
    (angle_deg, rate_scale, q0, dw0)
        (B,) angles [deg], (B,) |dw0| / W0, (B, 4) scalar-first attitudes w.r.t. the orbital axes,
        (B, 3) rate deviations [rad/s] (body axes).
    """
    rng = np.random.default_rng(seed)
    ang, sc = np.meshgrid(np.asarray(angles_deg, float), np.asarray(rate_scales, float), indexing="ij")
    ang = np.repeat(ang.ravel(), per_cell)
    sc = np.repeat(sc.ravel(), per_cell)
    B = ang.size
    axis = rng.standard_normal((B, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    d = rng.standard_normal((B, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    half = np.radians(ang) / 2.0
    q0 = np.c_[np.cos(half), np.sin(half)[:, None] * axis]
    return ang, sc, q0, d * (sc * orbit_rate)[:, None]


def capture_region(K, p: SpacecraftParams | None = None, *, angles_deg=tuple(range(10, 181, 10)),
                   rate_scales=(1.0, 2.0, 4.0), per_cell: int = 8, seed: int = 0, orbits: float = 3.0,
                   ts: float = TS_DEFAULT, capture_deg: float = 5.0, settle_orbits: float = 0.5,
                   dipole_limit: float = 50.0) -> dict:
    """Fly eq. 17 with gain ``K`` (3, 6) from the draws of :func:`deployment_draws`; paper environment.

    Returns
    -------
    dict
        ``runs``; ``captured`` (B,) bool; ``capture_time`` (B,) [s] (nan if not captured);
        ``angle_deg``, ``rate_scale``, ``q0``, ``dw0`` the draws; ``by_angle`` {angle: captured
        fraction}; ``by_rate`` {scale: captured fraction}; ``capture_time_p50/p95/max`` [s] of the
        captured runs; ``failures`` [(angle, rate scale, final error deg)]; the settings.
    """
    p = p or SpacecraftParams()
    ang, sc, q0, dw0 = deployment_draws(angles_deg, rate_scales, per_cell, p.orbit_rate, seed)
    B = ang.size
    runs = BatchRuns(K=np.asarray(K, float), inertia=np.broadcast_to(p.inertia, (B, 3)),
                     residual_dipole=np.ones((B, 3)), dipole_limit=np.full(B, float(dipole_limit)), q0=q0, dw0=dw0,
                     p=p)
    n = int(round(orbits * p.orbit_period / ts))
    r = simulate_batch(runs, ts=ts, steps=n, substeps=2, record_every=max(1, n), full_series=True)
    err = r.pointing_deg  # (B, n + 1)
    settle = int(round(settle_orbits * p.orbit_period / ts))
    captured = (err[:, -settle:] < capture_deg).all(axis=1) & ~r.diverged
    above = err >= capture_deg
    last_above = np.where(above.any(axis=1), n - np.argmax(above[:, ::-1], axis=1), 0)
    t_cap = np.where(captured, last_above * ts, np.nan)
    tc = t_cap[captured]
    pct = (lambda q: float(np.percentile(tc, q))) if tc.size else (lambda q: float("nan"))
    return dict(
        runs=B, captured=captured, capture_time=t_cap, angle_deg=ang, rate_scale=sc, q0=q0, dw0=dw0,
        by_angle={float(a): float(captured[ang == a].mean()) for a in np.unique(ang)},
        by_rate={float(s): float(captured[sc == s].mean()) for s in np.unique(sc)},
        capture_time_p50=pct(50), capture_time_p95=pct(95), capture_time_max=float(tc.max()) if tc.size else np.nan,
        failures=[(float(ang[i]), float(sc[i]), float(err[i, -1])) for i in np.flatnonzero(~captured)],
        final_error_max_captured=float(err[captured, -1].max()) if captured.any() else float("nan"),
        settings=dict(orbits=orbits, ts=ts, capture_deg=capture_deg, settle_orbits=settle_orbits, seed=seed,
                      per_cell=per_cell, dipole_limit=dipole_limit, environment="paper"),
    )
