"""Timing of the compiled gamma-test (magtune_core/ltp/hinf_kernel.py) against its np.linalg version,
and of one J(K) = hinfnorm at rtol 1e-4 with and without what was added since (the exponent polynomial, the threads, the compiled level model).

The version before the hand-written linear algebra (git 4091808) is written to a temporary module and
compiled next to the current one, so both run in the same process on the same inputs: one full
gamma-test at gamma = 1.001 J for the four shipped / paper gains, and the pieces (Pade-13 of one 12x12
interval exponent, one star product of 6x6 blocks, kappa alone) in compiled loops (no dispatch cost).
The last table times a whole single-gain J(K) (``hinfnorm``, rtol 1e-4, no guess: ``magtune analyze``'s
call) four ways in one run, alternating: A = the Hamiltonian assembled and its Magnus exponents formed
at every level (``exponent_polynomial`` switched off), B = the ``hinf.py`` before the compiled level model (git PREV_COMMIT:
the level model and its bookkeeping in numpy over the batch, exponents from the polynomial in numpy),
C = now (level model compiled, ``hinf_levels``; exponents gathered by ``exponents_at``) on one thread,
D = now with the kernel's intervals split over all threads.
Timings are printed, never asserted; run on an idle machine (the load line says how idle).

    PYTHONPATH=. python bench/bench_kernel.py
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np
from numba import njit

import magtune_core.ltp.hinf as H
import magtune_core.ltp.hinf_kernel as new
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import performance_system
from magtune_core.ltp.system import generator_at_nodes, magnus_exponent

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OLD_COMMIT = "4091808"
PREV_COMMIT = "a3e4f25"  # level model of hinfnorm in numpy
CASES = (  # (gain file, sigma, Magnus steps)
    ("config/gains/paper_method/sigma_60.yaml", 60.0, 64),
    ("config/gains/sigma_60.yaml", 60.0, 256),
    ("config/gains/sigma_120.yaml", 120.0, 512),
    ("config/gains/sigma_240.yaml", 240.0, 256),
)


def module_at(commit, relpath):
    """The module ``relpath`` of git ``commit`` as an importable module (its relative imports made
    absolute; written to a temp file, where numba caches what it compiles)."""
    src = subprocess.run(["git", "show", f"{commit}:{relpath}"], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout
    src = src.replace("from .", "from magtune_core.ltp.")
    name = f"magtune_{os.path.basename(relpath)[:-3]}_{commit}"
    path = os.path.join(tempfile.gettempdir(), name + ".py")
    if not os.path.exists(path) or open(path).read() != src:
        with open(path, "w") as f:
            f.write(src)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def omegas(path, sigma, steps, rel=1.001):
    """Magnus exponents (1, steps, 12, 12) of the Hamiltonian at gamma = rel J for one gain file."""
    model = AttitudeLTP.from_params(SpacecraftParams())
    s = performance_system(model, load_gains(os.path.join(ROOT, path)).K, sigma)
    J = float(H.hinfnorm(s, rtol=1e-9, steps=steps))
    M1, M2, h = generator_at_nodes(lambda t: H.hamiltonian(s, rel * J, t), s.period, steps)
    return np.ascontiguousarray(magnus_exponent(M1, M2, h))[None]


def paired_times(f_old, f_new, reps):
    """Median wall times of f_old() and f_new(), called alternately reps times each (after a warm-up
    call), so that a change of machine load hits both alike."""
    f_old(), f_new()
    t_old, t_new = [], []
    for _ in range(reps):
        for f, ts in ((f_old, t_old), (f_new, t_new)):
            t0 = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t0)
    return float(np.median(t_old)), float(np.median(t_new))


def piece_loops(old):
    """Compiled timing loops: (name, old loop, new loop); each loop(reps, args...) returns a checksum."""
    op, np_, ok_, nk_, os_, ns_ = old._pade_scaled, new._pade_into, old._kappa, new._kappa_into, old._star, new._star_into

    @njit
    def pade_old(reps, a, r, w, piv):
        acc = 0.0
        for _ in range(reps):
            x, s = op(a)
            acc += x[0, 0] + s
        return acc

    @njit
    def pade_new(reps, a, r, w, piv):
        acc = 0.0
        for _ in range(reps):
            s = np_(a, r, w, piv)
            acc += r[0, 0] + s
        return acc

    @njit
    def kappa_old(reps, Ga, Hb, w, ww, wv):
        acc = 0.0
        for _ in range(reps):
            acc += ok_(Ga, Hb)
        return acc

    @njit
    def kappa_new(reps, Ga, Hb, w, ww, wv):
        acc = 0.0
        for _ in range(reps):
            acc += nk_(Ga, Hb, w, wv)
        return acc

    @njit
    def star_old(reps, a, b, out, w, ww, wv, piv):
        acc = 0.0
        for _ in range(reps):
            E, G, Hs, F, ok, kap = os_(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])
            acc += E[0, 0] + kap
        return acc

    @njit
    def star_new(reps, a, b, out, w, ww, wv, piv):
        acc = 0.0
        for _ in range(reps):
            ok, kap = ns_(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3], out[0], out[1], out[2], out[3], w, ww, wv, piv)
            acc += out[0][0, 0] + kap
        return acc

    return pade_old, pade_new, kappa_old, kappa_new, star_old, star_new


def main():
    """Print the load, the full-test table and the per-piece table."""
    with open("/proc/loadavg") as f:
        print(f"load (/proc/loadavg): {f.read().strip()}   cores: {os.cpu_count()}")
    old = module_at(OLD_COMMIT, "magtune_core/ltp/hinf_kernel.py")
    threads = numba.get_num_threads()
    numba.set_num_threads(1)  # the kernels compared on one thread
    print(f"\nfull gamma-test at gamma = 1.001 J (median, old and new alternating), old = git {OLD_COMMIT} (np.linalg), new = hand-written")
    print(f"{'case':<44} {'steps':>5} {'old ms':>8} {'new ms':>8} {'ratio':>6}")
    first = None
    for path, sigma, steps in CASES:
        om = omegas(path, sigma, steps)
        if first is None:
            first = om
        reps = max(15, int(6000 // steps))
        for growth in (1e6, np.inf):
            t_old, t_new = paired_times(lambda: old.gamma_test_omegas(om, True, growth),
                                        lambda: new.gamma_test_omegas(om, True, growth), reps)
            name = path.replace("config/gains/", "") + ("" if growth == 1e6 else "  growth=inf")
            print(f"{name:<44} {steps:>5} {1e3 * t_old:>8.2f} {1e3 * t_new:>8.2f} {t_old / t_new:>6.2f}")

    # pieces, on blocks of the first case (paper sigma 60, 64 steps: a typical interval and junction)
    n2 = first.shape[-1]
    n = n2 // 2
    a = np.ascontiguousarray(first[0, 0])
    (E, G, Hs, F), _, _ = H.interval_scattering(first[0, :2])
    blk = [tuple(np.ascontiguousarray(x[k]) for x in (E, G, Hs, F)) for k in range(2)]
    out = tuple(np.empty((n, n)) for _ in range(4))
    wp, ws, piv = np.empty((new._NW_PADE, n2, n2)), np.empty((new._NW_STAR, n, n)), np.empty(n2, dtype=np.int64)
    ww, wv = np.empty((new._NW_WIDE, n, n2)), np.empty((4, n))
    r = np.empty((n2, n2))
    pade_old, pade_new, kappa_old, kappa_new, star_old, star_new = piece_loops(old)
    rows = (
        (f"Pade-13 {n2}x{n2} (s = {int(H.pade13_scaled(a)[1])})", lambda k: pade_old(k, a, r, wp, piv),
         lambda k: pade_new(k, a, r, wp, piv)),
        (f"star product ({n}x{n} blocks)", lambda k: star_old(k, blk[0], blk[1], out, ws, ww, wv, piv),
         lambda k: star_new(k, blk[0], blk[1], out, ws, ww, wv, piv)),
        ("kappa (Cholesky + top eigenvalue)", lambda k: kappa_old(k, blk[0][1], blk[1][2], ws, ww, wv),
         lambda k: kappa_new(k, blk[0][1], blk[1][2], ws, ww, wv)),
    )
    print("\npieces (compiled loops, median of 15 x 2000 calls, old and new alternating)")
    print(f"{'piece':<44} {'old us':>8} {'new us':>8} {'ratio':>6}")
    for name, f_old, f_new in rows:
        f_old(1), f_new(1)  # compile
        reps = 2000
        t_old, t_new = paired_times(lambda: f_old(reps), lambda: f_new(reps), 15)
        t_old, t_new = t_old / reps, t_new / reps
        print(f"{name:<44} {1e6 * t_old:>8.2f} {1e6 * t_new:>8.2f} {t_old / t_new:>6.2f}")
    single_j(threads)


def single_j(threads):
    """One J(K) per case four ways (module docstring): median ms, alternating, and the ratios."""
    model = AttitudeLTP.from_params(SpacecraftParams())
    poly = H.exponent_polynomial
    prev = module_at(PREV_COMMIT, "magtune_core/ltp/hinf.py")

    def run(s, steps, way, nthreads):
        H.exponent_polynomial = poly if way != "A" else (lambda *a: None)
        numba.set_num_threads(nthreads)
        try:
            return float((prev if way == "B" else H).hinfnorm(s, rtol=1e-4, steps=steps))
        finally:
            H.exponent_polynomial = poly

    print(f"\nsingle J(K), hinfnorm rtol 1e-4 (median ms, alternating): A = Hamiltonian at every level "
          f"({threads} threads), B = git {PREV_COMMIT} (level model in numpy; polynomial, {threads} threads), "
          f"C = now on 1 thread, D = now on {threads} threads")
    print(f"{'case':<44} {'steps':>5} {'A ms':>7} {'B ms':>7} {'C ms':>7} {'D ms':>7} {'A/D':>5} {'B/D':>5} {'C/D':>5}")
    for path, sigma, steps in CASES:
        s = performance_system(model, load_gains(os.path.join(ROOT, path)).K, sigma)
        ways = [("A", threads), ("B", threads), ("C", 1), ("D", threads)]
        J = [run(s, steps, *w) for w in ways]  # warm-up; the four agree to the bracket
        assert max(J) - min(J) <= 1e-4 * max(J)
        ts = [[] for _ in ways]
        for _ in range(max(5, int(2000 // steps))):
            for w, t in zip(ways, ts):
                t0 = time.perf_counter()
                run(s, steps, *w)
                t.append(time.perf_counter() - t0)
        a, b, c, d = (1e3 * float(np.median(t)) for t in ts)
        name = path.replace("config/gains/", "")
        print(f"{name:<44} {steps:>5} {a:>7.1f} {b:>7.1f} {c:>7.1f} {d:>7.1f} {a / d:>5.2f} {b / d:>5.2f} {c / d:>5.2f}")
    numba.set_num_threads(threads)
    with open("/proc/loadavg") as f:
        print(f"load at the end (/proc/loadavg): {f.read().strip()}")


if __name__ == "__main__":
    main()
