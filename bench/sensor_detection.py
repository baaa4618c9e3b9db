"""Magnetometer bias jumps and gyro bias steps detected from the MEKF's innovations (docs/modes.md,
"Sensor fault detection from the innovations").

The filter (``onboard.mekf_kernel``: ``MekfStream``'s arithmetic compiled), its validity monitor with the
300-s restart (``valid_step``) and ``onboard.sensor_watch.watch_step`` (compiled as it is) run on simulated
sensors along one kinematic truth: an Earth-pointing body with a slow wobble, the paper's field (eq. 26) along
the 5614.8-s orbit, a fixed Sun seen by whole-sphere sun sensors except in an eclipse of 38 % of each orbit
(phase 0.30-0.68). Sensors: ``design.sensors.default_suite`` (100 nT magnetometer, gyro sigma_v 1e-4,
sigma_u 1e-6, bias (40, -60, 30) deg/h, 0.5 deg sun), the filter matched to them; the noise is drawn in the
compiled loop from numba's generator, seeded per run.

* fault-free: ``--free-orbits`` armed orbits in runs of ``--run-orbits``: false verdicts, the fraction of armed
  samples above the limits of p = 1e-2 ... 1e-6 (the derivation's check) and the largest statistic over its limit;
* faults: ``--runs`` runs; in each, one filter per case (fault-free, and each kind x axis x magnitude, random
  sign) on the same sensor noise, the fault added to the measurement from an onset drawn uniformly over one
  orbit after the watch has been armed for 360 s; per case detected %, right unit %, wrong unit %, ambiguous %
  (a magnetometer verdict without the sun), time to detect (median, 95 %, max) within 600 s, split by the onset
  in sunlight / in eclipse.

The numba compile (~25-45 s) is paid once, in the parent, before the workers fork. The table of docs/modes.md:

    python bench/sensor_detection.py --runs 0 --free-orbits 1000     # 3.7 min under load ~4.5
    python bench/sensor_detection.py --runs 80 --free-orbits 0       # 3.5 min under load ~4.6
    python bench/sensor_detection.py --runs 0 --free-orbits 10000    # the issue's figure: ~12 CPU-min (not run)
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from magtune_core.design.field import paper_field  # noqa: E402
from magtune_core.design.sensors import default_suite  # noqa: E402
from magtune_core.onboard import mekf_kernel as K  # noqa: E402
from magtune_core.onboard import sensor_watch as SW  # noqa: E402
from magtune_core.onboard.validity import nis_limit  # noqa: E402
from magtune_core.sim.estimation import kinematic_truth  # noqa: E402

PERIOD = 5614.8
W0 = 2 * math.pi / PERIOD
ECLIPSE = (0.30, 0.68)  #: orbit phase of the eclipse
SUN_REF = np.array([1.0, 1.0, 0.3]) / np.linalg.norm([1.0, 1.0, 0.3])
MAG_VALUES = (3e-7, 2e-6, 5e-6)  #: magnetometer bias jumps [T]
GYRO_VALUES = tuple(math.radians(d) for d in (0.005, 0.02, 0.05, 0.2, 1.0))  #: gyro bias steps [rad/s]
DRIFT_VALUES = (3e-9,)  #: magnetometer drifts [T/s] (1800 nT after 600 s)
WINDOW = 600  #: samples after the onset in which a verdict counts as a detection
SETTLE = 300  #: samples armed before the earliest onset
CHECK_P = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)  #: lower probabilities whose exceedance fractions check the derivation

watch_step = SW.watch_step  # compiled (cached) in the module; the functions here are compiled per run (not cached)


def truth_arrays(n: int) -> tuple:
    """The kinematic truth of ``n`` samples: (w (n, 3), b_ref, b_body, sun_ref, sun_body (n + 1, 3), lit)."""
    t = np.arange(n + 1) * 1.0
    phase = (t % PERIOD) / PERIOD
    lit = ~((phase > ECLIPSE[0]) & (phase < ECLIPSE[1]))

    def b_ref(tt):
        b = np.asarray(paper_field(W0)(tt)).reshape(len(tt), 3)
        c, s = np.cos(-W0 * tt), np.sin(-W0 * tt)
        return np.stack([c * b[:, 0] - s * b[:, 1], s * b[:, 0] + c * b[:, 1], b[:, 2]], -1)

    def rate(tt):
        return np.stack([1e-3 * np.sin(2 * np.pi * tt / 700), 1e-3 * np.cos(2 * np.pi * tt / 900), -W0 + 0 * tt], -1)

    tr = kinematic_truth(n, 1.0, rate, b_ref, sun_ref=SUN_REF, lit=lit)
    return (np.ascontiguousarray(tr.w), np.ascontiguousarray(tr.b_ref), np.ascontiguousarray(tr.b_body),
            np.ascontiguousarray(tr.sun_ref), np.ascontiguousarray(tr.sun_body), np.ascontiguousarray(tr.lit))


@njit
def _rotate(v, th):
    """v rotated by the small rotation vector th (Rodrigues), normalized: the sun sensor's error."""
    ang = math.sqrt(th[0] ** 2 + th[1] ** 2 + th[2] ** 2)
    if ang == 0.0:
        return v.copy()
    k = th / ang
    kv = np.array([k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]])
    out = v * math.cos(ang) + kv * math.sin(ang) + k * (k @ v) * (1.0 - math.cos(ang))
    return out / math.sqrt(out @ out)


@njit
def run_batch(m, ws, wp, w, bref, bbody, sref, sbody, lit, n, onset, kinds, axes, values, seed, sensors,
              check, out, trace, trace_i):
    """``n`` + 1 samples of the B filters of ``m`` and their watches ``ws`` (B, NS) on one draw of sensor noise
    (numba's generator seeded ``seed``); filter i gets fault ``kinds[i]`` (0 none, 1 magnetometer bias,
    2 gyro bias, 3 magnetometer drift [T/s]) of ``values[i]`` on axis ``axes[i]`` from sample ``onset``. ``sensors`` = (mag std,
    sigma_v, sigma_u, sun std, gyro bias x, y, z). ``out`` (B, 11 + 3 len(check)): first verdict code and
    sample, verdicts before the onset, samples armed, verdicts, restarts, -, -, max M, S, G over their limits,
    exceedance counts of M, S, G above ``check`` (3, C) limits. ``trace`` (n + 1, 7) of filter ``trace_i``:
    M, S, G, armed, valid, code, magnetometer NIS."""
    np.random.seed(seed)
    B = ws.shape[0]
    su = sensors[2]
    white = math.sqrt(sensors[1] ** 2 + su**2 / 12.0)
    beta = sensors[4:7].copy()
    wm = np.zeros(3)
    C = check.shape[1]
    for k in range(n + 1):
        mag = bbody[k] + sensors[0] * np.random.standard_normal(3)
        th = sensors[3] * np.random.standard_normal(3)
        sun = _rotate(sbody[k], th)
        if k < n:
            nb = beta + su * np.random.standard_normal(3)
            wm = w[k] + 0.5 * (beta + nb) + white * np.random.standard_normal(3)
            beta = nb
        for i in range(B):
            mi = mag.copy()
            gi = wm.copy()
            if k >= onset and kinds[i] == 1:
                mi[axes[i]] += values[i]
            if k >= onset and kinds[i] == 2:
                gi[axes[i]] += values[i]
            if k >= onset and kinds[i] == 3:
                mi[axes[i]] += values[i] * (k - onset)
            was = m.started[i]
            nis_m, nis_s = K.stream_step(m, i, mi, bref[k], lit[k], sun, sref[k])
            if not m.started[i]:
                code = watch_step(ws[i], wp, math.nan, math.nan, False, m.b[i], m.P[i, 3:6, 3:6], False, True)
                valid = False
            else:
                valid = K.valid_step(m, i, nis_m)
                if not m.started[i]:
                    out[i, 5] += 1
                code = watch_step(ws[i], wp, nis_m, nis_s, lit[k] and nis_s <= m.gate_sun, m.b[i],
                                  m.P[i, 3:6, 3:6], valid, not was)
            m.w_prev[i] = gi
            s = ws[i]
            if s[SW.ARMED] != 0.0:
                out[i, 3] += 1
                stats = (s[SW.M_AVG], s[SW.S_AVG], s[SW.G_LAST])
                for j in range(3):
                    out[i, 8 + j] = max(out[i, 8 + j], stats[j] / wp[SW.P_LIM_MAG + j])
                    for c in range(C):
                        if stats[j] > check[j, c]:
                            out[i, 11 + j * C + c] += 1
            if code != 0 and code != SW.BACK_CODE:
                out[i, 4] += 1
                if k < onset:
                    out[i, 2] += 1
                elif out[i, 0] == 0:
                    out[i, 0], out[i, 1] = code, k - onset
            if i == trace_i:
                trace[k, 0], trace[k, 1], trace[k, 2] = s[SW.M_AVG], s[SW.S_AVG], s[SW.G_LAST]
                trace[k, 3], trace[k, 4], trace[k, 5], trace[k, 6] = s[SW.ARMED], valid, code, nis_m


def filters(B: int, suite, wparams: SW.SensorWatchParams):
    """B fresh filters matched to ``suite`` with the validity gate and its 300-s restart, and B watches."""
    m = K.kernel_state(B, 1.0, arw=suite.gyro.arw, rrw=suite.gyro.rrw, mag_cov=suite.magnetometer.covariance,
                       sun_std=suite.sun.noise_std)
    m = K.with_validity(m, 0.029, 60.0, 4.6, 300.0)
    return m, np.stack([SW.new_state() for _ in range(B)])


def sensor_vector(suite) -> np.ndarray:
    """(mag std, sigma_v, sigma_u, sun std, gyro bias x, y, z) of ``run_batch``."""
    return np.array([suite.magnetometer.noise_std, suite.gyro.arw, suite.gyro.rrw, suite.sun.noise_std,
                     *suite.gyro.bias])


def check_limits(wp: SW.SensorWatchParams) -> np.ndarray:
    """(3, C) limits of M, S, G at the probabilities ``CHECK_P``."""
    from dataclasses import replace

    return np.array([replace(wp, probability=p).limits() for p in CHECK_P]).T.copy()


def cases() -> list[tuple[int, int, float]]:
    """(kind, axis, |value|) of every filter of a fault run: fault-free first, then each kind x axis x magnitude."""
    out = [(0, 0, 0.0)]
    out += [(1, ax, v) for v in MAG_VALUES for ax in range(3)]
    out += [(2, ax, v) for v in GYRO_VALUES for ax in range(3)]
    out += [(3, ax, v) for v in DRIFT_VALUES for ax in range(3)]
    return out


def _setup(wparams):
    suite = default_suite(1.0)
    return suite, wparams.array(), sensor_vector(suite), check_limits(wparams)


def fault_runs(seeds, n_truth: int, wparams) -> np.ndarray:
    """One fault run per seed: (runs, cases, columns of ``run_batch``'s out + onset sample + lit at the onset)."""
    suite, wp, sv, chk = _setup(wparams)
    tr = truth_arrays(n_truth)
    cs = cases()
    kinds = np.array([c[0] for c in cs])
    axes = np.array([c[1] for c in cs])
    res = []
    arm = int(wparams.arm_time)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        onset = int(arm + SETTLE + 60 + rng.uniform(0.0, PERIOD))
        values = np.array([c[2] for c in cs]) * rng.choice([-1.0, 1.0], size=len(cs))
        m, ws = filters(len(cs), suite, wparams)
        out = np.zeros((len(cs), 11 + 3 * len(CHECK_P)))
        run_batch(m, ws, wp, *tr, onset + WINDOW, onset, kinds, axes, values, int(seed), sv, chk, out,
                  np.zeros((1, 7)), -1)
        extra = np.tile([onset, float(tr[5][onset])], (len(cs), 1))
        res.append(np.hstack([out, extra]))
    return np.array(res)


def free_runs(seeds, n: int, wparams) -> np.ndarray:
    """Fault-free runs of ``n`` samples, one per seed: (runs, columns of ``run_batch``'s out)."""
    suite, wp, sv, chk = _setup(wparams)
    tr = truth_arrays(n)
    res = []
    for seed in seeds:
        m, ws = filters(1, suite, wparams)
        out = np.zeros((1, 11 + 3 * len(CHECK_P)))
        run_batch(m, ws, wp, *tr, n, n + 1, np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64),
                  np.zeros(1), int(seed), sv, chk, out, np.zeros((1, 7)), -1)
        res.append(out[0])
    return np.array(res)


def _pool(fn, seeds, workers, *args) -> np.ndarray:
    chunks = [list(c) for c in np.array_split(np.asarray(seeds), workers) if len(c)]
    if workers == 1:
        return fn(chunks[0], *args)
    with ProcessPoolExecutor(workers) as ex:
        return np.concatenate(list(ex.map(fn, chunks, *[[a] * len(chunks) for a in args])))


def _pct(x) -> str:
    return f"{100.0 * x:.1f}"


def report_free(res: np.ndarray, wparams, n: int) -> None:
    """Fault-free figures: false verdicts per orbit, exceedance fractions against p, the largest statistic."""
    armed = res[:, 3].sum()
    orbits = armed / PERIOD
    print(f"\nfault-free: {len(res)} runs of {n} samples ({n / PERIOD:.2f} orbits), armed {armed:.0f} samples "
          f"= {orbits:.1f} orbits; restarts {res[:, 5].sum():.0f}")
    print(f"  false verdicts: {res[:, 4].sum():.0f} ({res[:, 4].sum() / orbits:.2e} per armed orbit)")
    lim = wparams.limits()
    for j, name in enumerate(("M (magnetometer NIS average)", "S (sun NIS average)", "G (gyro-bias drift)")):
        frac = [res[:, 11 + j * len(CHECK_P) + c].sum() / armed for c in range(len(CHECK_P))]
        print(f"  {name}: limit {lim[j]:.3f}; fraction of armed samples above the limit of p = "
              + ", ".join(f"{p:g}: {f:.2e}" for p, f in zip(CHECK_P, frac))
              + f"; largest / limit {res[:, 8 + j].max():.3f} (median over runs {np.median(res[:, 8 + j]):.3f})")


def report_faults(res: np.ndarray, wparams) -> None:
    """Per case: detected, right unit, wrong unit, ambiguous, time to detect; by onset in sunlight / eclipse."""
    cs = cases()
    lit = res[:, 0, -1].astype(bool)
    print(f"\nfaults: {len(res)} runs ({lit.sum()} onsets lit, {(~lit).sum()} in eclipse); verdict within {WINDOW} s")
    print("| fault | axis | magnitude | onset | runs | detected % | right unit % | wrong unit % | ambiguous % "
          "| time to detect median / 95 % / max [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    pre = res[:, :, 2].sum()
    for c, (kind, ax, v) in enumerate(cs):
        if kind == 0:
            continue
        for where, sel in (("lit", lit), ("eclipse", ~lit)):
            r = res[sel, c]
            if not len(r):
                continue
            code, t = r[:, 0], r[:, 1]
            det = code > 0
            right = (code == (SW.GYRO_FAULT if kind == 2 else SW.MAG_FAULT)) | ((code == SW.MAG_AMBIGUOUS) & (kind != 2))
            wrong = det & ~right
            amb = code == SW.MAG_AMBIGUOUS
            tt = t[det]
            times = (f"{np.median(tt):.0f} / {np.percentile(tt, 95):.0f} / {tt.max():.0f}" if len(tt) else "-")
            mag = (f"{v * 1e9:.0f} nT" if kind == 1 else f"{math.degrees(v):g} deg/s" if kind == 2
                   else f"{v * 1e9:g} nT/s")
            name = {1: "magnetometer bias", 2: "gyro bias", 3: "magnetometer drift"}[kind]
            print(f"| {name} | {'xyz'[ax]} | {mag} | {where} | {len(r)} "
                  f"| {_pct(det.mean())} | {_pct(right.mean())} | {_pct(wrong.mean())} | {_pct(amb.mean())} | {times} |")
    print(f"verdicts before the onset (any filter of a fault run): {pre:.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=60, help="fault runs (each flies every case; 0: none)")
    ap.add_argument("--free-orbits", type=float, default=300.0, help="fault-free orbits, armed (0: none)")
    ap.add_argument("--run-orbits", type=float, default=4.0, help="length of one fault-free run [orbits]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    wparams = SW.SensorWatchParams()
    print(f"load average {os.getloadavg()}; watch {wparams}; limits M, S, G {wparams.limits()}; "
          f"validity limit {nis_limit(60.0, 1.0, 1e-9):.3f}")
    t0 = time.perf_counter()
    free_runs([0], 3, wparams)  # compile once here: the workers fork with it
    print(f"compiled in {time.perf_counter() - t0:.0f} s")
    t0 = time.perf_counter()
    n = int(a.run_orbits * PERIOD)
    armed_per_run = n - wparams.arm_time - 2
    runs_free = int(math.ceil(a.free_orbits * PERIOD / armed_per_run))
    if runs_free:
        free = _pool(free_runs, range(a.seed + 100_000, a.seed + 100_000 + runs_free), a.workers, n, wparams)
        report_free(free, wparams, n)
        print(f"  ({time.perf_counter() - t0:.0f} s; load average {os.getloadavg()})")
    if a.runs:
        t1 = time.perf_counter()
        n_truth = int(wparams.arm_time + SETTLE + 60 + PERIOD + WINDOW + 2)
        res = _pool(fault_runs, range(a.seed, a.seed + a.runs), a.workers, n_truth, wparams)
        report_faults(res, wparams)
        print(f"  ({time.perf_counter() - t1:.0f} s; load average {os.getloadavg()})")


if __name__ == "__main__":
    main()
