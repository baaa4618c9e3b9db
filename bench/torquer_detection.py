"""Torquer fault detection (magtune_core.onboard.torquer_watch) measured offline: false alarms and detection.

Flights: ``magtune_core.sim.modes_loop.simulate_modes`` in POINTING (paper environment, shipped gains
``config/gains/sigma_60.yaml``, truth attitude in the loop), each from its own small attitude and rate
error and orbit phase. The watch reads what the board would: the commanded dipole (the law on the
flight's state, the dipole before the fault), the field through the default suite's magnetometer, the gyro
of the default suite (``design.sensors.gyro``) minus a bias estimate, the attitude. Bias estimate: the
true bias minus a Gauss-Markov error (``--bias-std``, ``--bias-time``: the on-board MEKF's figures), or
(``--mekf`` runs) the compiled on-board MEKF itself run on the flight's sensors.

Each flight is replayed with ``--draws`` independent noise draws at once (the watch's batch axis: the same
arithmetic as the flight's single watch). Prints the fault-free statistic against its threshold (the
fraction of tests above chi-square(2) levels, the largest, false declarations per orbit), then per fault
kind, axis and size the detected fraction within 600 s of the onset and the time to detect.

The figures of docs/modes.md#torquer-fault-detection, one command each (2 shared cores, load 2-3):

    python bench/torquer_detection.py --only false --flights 4 --first-flight 0 --draws 1250   # 3 min
    python bench/torquer_detection.py --only false --flights 4 --first-flight 4 --draws 1250   # 2.5 min
    python bench/torquer_detection.py --only mekf --mekf 3 --mekf-orbits 3                     # 1.5 min
    python bench/torquer_detection.py --only faults --onsets 3 --fault-draws 20                # 4.5 min
    python bench/torquer_detection.py --quick                                                  # a smoke run
"""
from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from magtune_core.base.rotations import rotation_matrix
from magtune_core.design.gains import load_gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.sensors import GYRO_U, GYRO_V, MAG, default_suite, draw, gyro, magnetometer
from magtune_core.onboard.estimator import MekfStream
from magtune_core.onboard.law import DEFAULT_DIPOLE_LIMIT, ProjectionController, linear_state
from magtune_core.onboard.modes import ACQUISITION, POINTING
from magtune_core.onboard.torquer_watch import (
    AXES,
    KINDS,
    UNRESOLVED_CODE,
    TorquerWatch,
    TorquerWatchParams,
    chi2_even_level,
)
from magtune_core.sim.dynamics import AttitudeDynamics
from magtune_core.sim.initial import initial_conditions
from magtune_core.sim.modes_loop import simulate_modes

GAINS = "config/gains/sigma_60.yaml"


@dataclass
class Flight:
    """One flight's truth at t_k = k ts: attitude w.r.t. orbital axes, inertial rate, field (body), the commanded
    dipole of [t_k, t_k+1) and whether the watch may run (eq. 17 flown)."""

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    b: np.ndarray
    m: np.ndarray
    active: np.ndarray


def fly(K, p: SpacecraftParams, seconds: float, faults=(), seed: int = 0) -> Flight:
    """POINTING from a small random attitude (up to 2 deg) and rate (0.2 W0) error (the paper's field is a
    function of t alone: the orbit phase of a fault is its onset time)."""
    rng = np.random.default_rng(seed)
    att = rng.normal(size=3)
    att *= rng.uniform(0.0, 2.0) / np.linalg.norm(att)
    rate = rng.normal(size=3) * math.degrees(0.2 * p.orbit_rate / math.sqrt(3.0))
    q0, dw0 = initial_conditions(tuple(att), tuple(rate))
    r = simulate_modes(K, p, q0=q0, dw0=dw0, orbits=seconds / p.orbit_period, initial_mode=POINTING,
                       faults=list(faults))
    dyn = AttitudeDynamics.from_params(p)
    law = ProjectionController(K, DEFAULT_DIPOLE_LIMIT)
    b = np.array([dyn.body_field(t, q) for t, q in zip(r.t, r.q)])
    m = np.array([law(linear_state(q, w, p.orbit_rate), bk).m for q, w, bk in zip(r.q, r.w, b)])
    active = np.isin(r.mode, (ACQUISITION, POINTING))
    if not faults:  # the recomputed command is the flight's (no fault acted on it)
        assert np.array_equal(m[active], r.m[active]), "commanded dipole not reproduced"
    return Flight(r.t, r.q, r.w, b, m, active)


def noisy_inputs(f: Flight, draws: int, seed: int, bias_std: float, bias_time: float, chunk: int = 400):
    """Chunks of (w - bias estimate, measured field), (draws, chunk, 3) each, from the default suite: the gyro's
    bias walk and white noise (``design.sensors.gyro``), the estimate = the true bias minus a first-order
    Gauss-Markov error (std ``bias_std``, time ``bias_time``); the magnetometer's white noise."""
    suite = default_suite()
    rng = np.random.default_rng(seed)
    n, ts = len(f.t), suite.ts
    beta = np.broadcast_to(np.asarray(suite.gyro.bias), (draws, 3)).copy()
    rho = math.exp(-ts / bias_time)
    err = bias_std * rng.standard_normal((draws, 1, 3))
    for k0 in range(0, n, chunk):
        c = min(n, k0 + chunk) - k0
        nrm = rng.standard_normal((4, draws, c, 3))
        w_m, walk = gyro(suite.gyro, np.broadcast_to(f.w[k0:k0 + c], (draws, c, 3)), ts, beta, nrm[0], nrm[1])
        b_m = magnetometer(suite.magnetometer, f.b[k0:k0 + c], nrm[2])
        beta = walk[:, -1]
        e, _ = lfilter([1.0], [1.0, -rho], nrm[3] * (bias_std * math.sqrt(1.0 - rho * rho)), axis=1,
                       zi=rho * err)
        err = e[:, -1:]
        yield w_m - 0.5 * (walk[:, 1:] + walk[:, :-1]) + e, b_m


def replay(f: Flight, params: TorquerWatchParams, draws: int, seed: int, bias_std: float, bias_time: float):
    """The watch on ``draws`` noise draws of flight ``f``: statistics of every test and the verdicts."""
    watch = TorquerWatch(params, shape=(draws,))
    stats, first = [], np.full((draws, 3), np.nan)
    kinds, resolved = np.full((draws, 3), -1), np.full((draws, 3), np.nan)
    sd = []
    k = 0
    for W, B in noisy_inputs(f, draws, seed, bias_std, bias_time):
        for i in range(W.shape[1]):
            tests = watch.tests
            new = watch.advance(W[:, i], B[:, i], f.m[k - 1] if k else np.zeros(3), f.q[k], bool(f.active[k]))
            if watch.tests > tests:
                stats.append((f.t[k], watch.d0.copy()))
                info = np.diagonal(np.linalg.inv(watch.P), axis1=-2, axis2=-1)  # 1 / std given the other five
                sd.append(np.nanmedian(info[:, :3] ** -0.5, axis=0))
                if new.any():
                    fresh = new & np.isnan(first)
                    first = np.where(fresh, f.t[k], first)
                    named = new & (watch.declared != UNRESOLVED_CODE) & np.isnan(resolved)
                    resolved = np.where(named, f.t[k], resolved)
                    kinds = np.where(new, watch.declared, kinds)
            k += 1
    return stats, first, kinds, resolved, np.array(sd)


def mekf_replay(f: Flight, params: TorquerWatchParams, seed: int, start: float):
    """One noise draw with the compiled on-board MEKF giving the bias estimate (paper environment: the
    reference axes are the orbital axes at t = 0), the watch active from ``start``."""
    p = SpacecraftParams()
    suite = default_suite()
    rng = np.random.default_rng(seed)
    n = len(f.t)
    nrm = draw(rng, n)
    w_m, _ = gyro(suite.gyro, f.w, suite.ts, suite.gyro.bias, nrm[:, GYRO_V], nrm[:, GYRO_U])
    b_m = magnetometer(suite.magnetometer, f.b, nrm[:, MAG])
    ang = -p.orbit_rate * f.t
    c, s = np.cos(ang), np.sin(ang)
    b_orb = np.einsum("kij,kj->ki", rotation_matrix(f.q), f.b)  # field in orbital axes
    b_ref = np.stack([c * b_orb[:, 0] - s * b_orb[:, 1], s * b_orb[:, 0] + c * b_orb[:, 1], b_orb[:, 2]], -1)
    stream = MekfStream(suite, compiled=True)
    watch = TorquerWatch(params)
    stats, verdicts = [], []
    for k in range(n):
        out = stream.step(w_m[k - 1] if k else None, b_m[k], b_ref[k])
        if out.state is None:
            continue
        tests = watch.tests
        v = watch.step(w_m[k] - out.state.b, b_m[k], f.m[k - 1], f.q[k], bool(f.active[k]) and f.t[k] >= start)
        if watch.tests > tests:
            stats.append((f.t[k], watch.d0[None].copy()))
        if v is not None:
            verdicts.append((f.t[k], v))
    return stats, verdicts


def chi2_tail(x: float, dof: int = 6) -> float:
    """P(chi-square(dof) > x), even dof."""
    term, total = 1.0, 1.0
    for k in range(1, dof // 2):
        term *= 0.5 * x / k
        total += term
    return math.exp(-0.5 * x) * total


def chi2_table(D0, gamma: float) -> list[str]:
    """Fraction of tests whose D0 (the distance from the fault-free set; every axis' T is below it) is above
    chi-square(6) levels, against the bound P(chi-square(6) > x)."""
    D0 = D0[np.isfinite(D0)]
    rows = []
    for p in (1e-1, 1e-2, 1e-3, 1e-4, 1e-5):
        x = chi2_even_level(p, 6)
        rows.append(f"| {x:.1f} | {p:.0e} | {np.mean(D0 > x):.2e} |")
    rows.append(f"| {gamma:.1f} (threshold) | {chi2_tail(gamma):.0e} | {np.mean(D0 > gamma):.2e} |")
    return rows


def false_alarms(a, K, p, params) -> None:
    orbit = p.orbit_period
    T, fa, tests, orbits, sds = [], 0, 0, 0.0, []
    t0 = time.perf_counter()
    for i in range(a.first_flight, a.first_flight + a.flights):
        f = fly(K, p, a.orbits * orbit, seed=100 + i)
        stats, first, _, _, sd = replay(f, params, a.draws, 1000 + i, a.bias_std, a.bias_time)
        sds.append(sd)
        s = np.array([st for _, st in stats])
        T.append(s.ravel())
        tests += s.size
        fa += int(np.isfinite(first).any(-1).sum())
        orbits += a.draws * (f.t[-1] - params.sub_window * (params.min_window + 1)) / orbit
    T = np.concatenate(T)
    print(f"\n## Fault-free: flights {a.first_flight}..{a.first_flight + a.flights - 1} x {a.draws} noise draws, "
          f"{a.orbits} orbits each "
          f"({orbits:.0f} orbits of tests; {time.perf_counter() - t0:.0f} s)")
    print(f"tests {tests}, largest D0 {T.max():.1f} (threshold {params.threshold:.1f}), "
          f"runs with a false declaration: {fa}, per orbit {fa / orbits:.1e}")
    print("| level x | bound P(chi2(6) > x) | fraction of tests with D0 above |\n|---|---|---|")
    print("\n".join(chi2_table(T, params.threshold)))
    q = np.percentile(np.concatenate(sds), [10, 50, 90], axis=0)  # (3 percentiles, axis)
    print("std of an axis' dipole error given the other unknowns (what an offset must exceed, over the residual "
          "bound, by ~sqrt(threshold) of it) [A m^2], p10 / p50 / p90 over the tests: "
          + "; ".join(f"{AXES[i]} {q[0, i]:.2f} / {q[1, i]:.2f} / {q[2, i]:.2f}" for i in range(3)))


def mekf_runs(a, K, p, params) -> None:
    orbit = p.orbit_period
    t0 = time.perf_counter()
    T, n_fa, orbits = [], 0, 0.0
    for i in range(a.mekf):
        f = fly(K, p, (a.mekf_orbits + 1.0) * orbit, seed=200 + i)
        stats, verdicts = mekf_replay(f, params, 300 + i, start=orbit)
        T.append(np.array([s for _, s in stats]).ravel())
        n_fa += len(verdicts)
        orbits += a.mekf_orbits
        for t, v in verdicts:
            print(f"  flight {i}: false declaration at {t:.0f} s: {v.detail}")
    T = np.concatenate(T)
    print(f"\n## Fault-free with the on-board MEKF: {a.mekf} flights x {a.mekf_orbits} orbits after a 1-orbit "
          f"convergence ({time.perf_counter() - t0:.0f} s)")
    print(f"tests {T.size}, largest D0 {T.max():.1f}, false declarations {n_fa} in {orbits:.0f} orbits")
    print("| level x | bound P(chi2(6) > x) | fraction of tests with D0 above |\n|---|---|---|")
    print("\n".join(chi2_table(T, params.threshold)))


CASES = [("torquer_stuck", 10.0), ("torquer_stuck", -10.0), ("torquer_stuck", 25.0), ("torquer_reversed", None),
         ("torquer_dead", None), ("torquer_gain", 0.5)]


def detection(a, K, p, params) -> None:
    base = params.sub_window * (params.min_window + 2) + 30.0  # the watch is full
    onsets = [base + i * p.orbit_period / a.onsets for i in range(a.onsets)]
    print(f"\n## Faults at {', '.join(f'{o:.0f}' for o in onsets)} s (orbit phases), {a.fault_draws} noise draws "
          f"each; detected = declared on the right axis within {a.horizon:.0f} s of the onset")
    print("| fault | axis | detected | time to detect p50 / p95 / max [s] | kind named (right) | time to name p50 "
          "[s] | another axis first | kinds at the end | per onset: detected (commanded RMS on the axis [A m^2]) |")
    print("|---|---|---|---|---|---|---|---|---|")
    expect = {"torquer_stuck": "stuck", "torquer_reversed": "reversed", "torquer_dead": "dead",
              "torquer_gain": "gain drop"}
    for kind, value in CASES:
        for ax in range(3):
            det, right, named, other, delays, naming, seen, rms = 0, 0, 0, 0, [], [], {}, []
            for i, onset in enumerate(onsets):
                spec = f"{kind}@{onset},axis={AXES[ax]}" + (f",value={value}" if value is not None else "")
                f = fly(K, p, onset + a.horizon + 120.0, faults=[spec], seed=400 + i)
                _, first, kinds, resolved, _ = replay(f, params, a.fault_draws, 500 + i, a.bias_std, a.bias_time)
                after = (f.t >= onset) & (f.t <= onset + a.horizon)
                tdet = first[:, ax] - onset
                ok = (tdet >= 0) & (tdet <= a.horizon)
                rms.append(f"{int(ok.sum())}/{a.fault_draws} ({np.sqrt(np.mean(f.m[after, ax] ** 2)):.1f})")
                mine = np.where(np.isfinite(first[:, ax]), first[:, ax], np.inf)
                other += int(np.sum(np.min(np.where(np.isfinite(first), first, np.inf), axis=1) < mine))
                det += int(ok.sum())
                delays += list(tdet[ok])
                tname = resolved[:, ax] - onset
                nm = ok & (tname <= a.horizon + 120.0)
                named += int(nm.sum())
                naming += list(tname[nm])
                for k in kinds[ok, ax]:
                    seen[KINDS[k]] = seen.get(KINDS[k], 0) + 1
                right += int(sum(KINDS[k] == expect[kind] for k in kinds[nm, ax]))
            N = a.onsets * a.fault_draws
            d = np.array(delays)
            times = f"{np.percentile(d, 50):.0f} / {np.percentile(d, 95):.0f} / {d.max():.0f}" if d.size else "-"
            label = kind.replace("torquer_", "") + (f" {value:g}" if value is not None else "")
            tn = f"{np.percentile(naming, 50):.0f}" if naming else "-"
            print(f"| {label} | {AXES[ax]} | {100 * det / N:.0f} % | {times} | {named} ({right}) | {tn} | {other} "
                  f"| {', '.join(f'{k} {v}' for k, v in sorted(seen.items()))} | {', '.join(rms)} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=8, help="fault-free flights")
    ap.add_argument("--first-flight", type=int, default=0, help="index of the first fault-free flight (its seeds)")
    ap.add_argument("--orbits", type=float, default=1.0, help="orbits per fault-free flight")
    ap.add_argument("--draws", type=int, default=1250, help="noise draws per fault-free flight")
    ap.add_argument("--mekf", type=int, default=2, help="fault-free flights with the on-board MEKF")
    ap.add_argument("--mekf-orbits", type=float, default=3.0)
    ap.add_argument("--onsets", type=int, default=3, help="flights (orbit phases) per fault case")
    ap.add_argument("--fault-draws", type=int, default=20, help="noise draws per fault flight")
    ap.add_argument("--horizon", type=float, default=600.0, help="detection deadline after the onset [s]")
    ap.add_argument("--bias-std", type=float, default=None, help="bias estimate's error std [rad/s] (default: "
                    "the watch's)")
    ap.add_argument("--bias-time", type=float, default=None, help="its correlation time [s]")
    ap.add_argument("--quick", action="store_true", help="a smoke run (2 flights x 50 draws, 1 onset x 5 draws)")
    ap.add_argument("--only", choices=("false", "mekf", "faults"), default=None)
    a = ap.parse_args()
    params = TorquerWatchParams()
    a.bias_std = params.bias_error_std if a.bias_std is None else a.bias_std
    a.bias_time = params.bias_error_time if a.bias_time is None else a.bias_time
    if a.quick:
        a.flights, a.draws, a.mekf, a.mekf_orbits, a.onsets, a.fault_draws = 2, 50, 1, 1.0, 1, 5
    K, p = load_gains(GAINS).K, SpacecraftParams()
    t0 = time.perf_counter()
    print(f"# Torquer fault detection; load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}")
    print(f"watch: sub-windows of {params.sub_window} s, windows of {params.windows} equations, threshold "
          f"{params.threshold:.1f} (false alarm {params.false_alarm:g} per test), persistence "
          f"{params.persistence}; simulated bias-estimate error {a.bias_std:g} rad/s, {a.bias_time:g} s")
    if a.only in (None, "false"):
        false_alarms(a, K, p, params)
    if a.only in (None, "mekf") and a.mekf:
        mekf_runs(a, K, p, params)
    if a.only in (None, "faults"):
        detection(a, K, p, params)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
