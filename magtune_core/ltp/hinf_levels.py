"""Compiled level model of :func:`.hinf.hinfnorm`'s refinement (numba): where to test next, per system.

Why compiled. After the bracket, every round of ``hinfnorm`` predicts the norm from the margins of
the last three passing levels (:func:`predict_one`: the zero of the quadratic through them, else of
a power law or a line), places one or two levels (:func:`plan_round`) and, after the gamma-tests,
moves the bracket and the history (:func:`update_round`). Written with numpy over the batch, that
bookkeeping was ~60 array operations per round: for a single gain (``magtune analyze``, the
tuner's incumbent checks) ~0.6 ms per round against ~0.65 ms for the gamma-test itself, i.e. ~45 %
of a J(K) (bench/bench_kernel.py). Here it is one loop over the systems in
scalars, the same arithmetic in the same order as the numpy version it replaced (git a3e4f25),
for a single system and a batch alike; ``hinf.predict_norm``, ``quadratic_zero`` and
``margin_zero`` are thin wrappers over the same functions, so there is one implementation.

``error_model="numpy"``: a division by zero gives inf / NaN as in numpy (the models' NaN / -inf
semantics rely on it), not ZeroDivisionError.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Points of the power-law scan of :func:`margin_zero_one` (log-spaced distances 1e-9 .. 1 below g_1).
SCAN_POINTS = 256
SCAN_FRAC = np.logspace(-9, 0, SCAN_POINTS)


@njit(cache=True, error_model="numpy")
def quadratic_zero_one(g1, g2, g3, m1, m2, m3, lo):
    """Zero below g1 of the quadratic through (g1, m1), (g2, m2), (g3, m3) (one margin), -inf if none.

    Newton form m(x) = m1 + f12 (x - g1) + f123 (x - g1)(x - g2); the root of smaller magnitude in
    x - g1 (stable form 2c / (-b - sign(b) sqrt(b^2 - 4ac))); kept where it lies below g1 and above
    lo and the margin increases with gamma there (m2 > m1 > 0).

    Returns
    -------
    float
        The zero (a prediction of the norm of paper eq. 21 from one margin of the gamma-test), or -inf.
    """
    f12 = (m2 - m1) / (g2 - g1)
    f123 = ((m3 - m2) / (g3 - g2) - f12) / (g3 - g1)
    a, b, c = f123, f12 - f123 * (g2 - g1), m1
    disc = b * b - 4.0 * a * c
    x = 2.0 * c / (-b - np.sign(b) * math.sqrt(max(disc, 0.0)))
    root = g1 + x
    if m1 > 0 and m2 > m1 and f12 > 0 and disc >= 0 and x < 0 and np.isfinite(root) and root > lo:
        return root
    return -np.inf


@njit(cache=True, error_model="numpy")
def margin_zero_one(g1, g2, g3, m1, m2, m3, lo, line, frac):
    """Zero of the power law m = c (gamma - gamma0)^p through three (gamma, margin) points (one
    margin; p in [0.25, 2]), else of the line through the first two where ``line``; -inf if none.

    The power law's zero is the root, nearest g1, of
    ln(m1/m2) ln((g2 - x)/(g3 - x)) = ln(m2/m3) ln((g1 - x)/(g2 - x)), found on the scan
    x = g1 - (g1 - lo) frac and interpolated linearly in the first interval that changes sign.

    Returns
    -------
    float
        The zero gamma0 (a prediction of the norm of paper eq. 21), or -inf.
    """
    lin = g1 - m1 * (g2 - g1) / (m2 - m1)
    if not (line and m2 > m1 and m1 > 0 and np.isfinite(lin)):
        lin = -np.inf
    span = max(g1 - lo, 0.0)
    l12, l23 = np.log(m1 / m2), np.log(m2 / m3)
    x_prev = F_prev = np.nan
    for k in range(frac.shape[0]):  # the first interval of the scan where F changes sign
        x = g1 - span * frac[k]
        F = l12 * np.log((g2 - x) / (g3 - x)) - l23 * np.log((g1 - x) / (g2 - x))
        if (F_prev > 0 and F < 0) or (F_prev < 0 and F > 0):  # never at k = 0 (F_prev NaN), nor for a NaN F
            root = x_prev - F_prev * (x - x_prev) / (F - F_prev)
            p = l12 / np.log((g1 - root) / (g2 - root))
            if m1 > 0 and m2 > m1 and m3 > m2 and p >= 0.25 and p <= 2.0 and np.isfinite(root):
                return root
            return lin
        x_prev, F_prev = x, F
    return lin


@njit(cache=True, error_model="numpy")
def predict_one(hist, lo, hi, frac):
    """The norm predicted from hist (3, 1 + q) = rows (gamma, margins...) of the last three passing
    levels, nearest first: per margin the quadratic's zero, else (where there is something to fit:
    three levels, or two within 1 % of the norm) the power law's / line's; the highest of them.

    Returns
    -------
    float
        The predicted norm (paper eq. 21); -inf where no margin gives a prediction.
    """
    g1, g2, g3 = hist[0, 0], hist[1, 0], hist[2, 0]
    q = hist.shape[1] - 1
    line = np.log(hi / lo) < 0.01
    est = np.empty(q)
    all_finite = True
    for j in range(q):
        est[j] = quadratic_zero_one(g1, g2, g3, hist[0, 1 + j], hist[1, 1 + j], hist[2, 1 + j], lo)
        all_finite = all_finite and np.isfinite(est[j])
    if not all_finite and np.isfinite(g2) and (np.isfinite(g3) or line):
        for j in range(q):
            if not np.isfinite(est[j]):
                est[j] = margin_zero_one(g1, g2, g3, hist[0, 1 + j], hist[1, 1 + j], hist[2, 1 + j], lo, line, frac)
    return est.max()


@njit(cache=True, error_model="numpy")
def plan_round(hist, lo, hi, cfac, bad, found_hi, rtol, frac, gam, need, model, closing):
    """Levels of one refinement round of every system (flat batch): gam (N, 2), need (N, 2) (which
    to test), and per system whether the level model was used and whether the round closes the
    bracket. Returns whether any system is still open (hi - lo > rtol hi).

    One level just above the prediction, est + u with u = cfac (g_1 - est) (at least 0.45 rtol hi);
    once 2u is within the tolerance, est - u and est + u together (closing); the geometric midpoint
    of the bracket where the prediction is unavailable, outside the bracket, or after two model
    rounds that did not halve it (``bad``)."""
    open_any = False
    for i in range(lo.shape[0]):
        need[i, 0] = need[i, 1] = False
        model[i] = closing[i] = False
        gam[i, 0] = gam[i, 1] = np.nan
        if not (found_hi[i] and hi[i] - lo[i] > rtol * hi[i]):
            continue
        open_any = True
        est = predict_one(hist[i], lo[i], hi[i], frac)
        mod = np.isfinite(est) and est > lo[i] and est < hi[i] and bad[i] < 2
        u = max(cfac[i] * (hist[i, 0, 0] - est), 0.45 * rtol * hi[i]) if mod else 0.0
        clo = mod and 2.0 * u <= 0.99 * rtol * hi[i]
        up = min(est + u, hi[i]) if mod else math.sqrt(lo[i] * hi[i])
        gam[i, 0] = max(est - u, lo[i]) if clo else up
        gam[i, 1] = up
        need[i, 0] = gam[i, 0] > lo[i] and gam[i, 0] < hi[i]
        need[i, 1] = clo and gam[i, 1] > lo[i] and gam[i, 1] < hi[i]
        model[i], closing[i] = mod, clo
    return open_any


@njit(cache=True, error_model="numpy")
def update_round(hist, lo, hi, cfac, bad, gam, need, passed, marg, model, closing, chase):
    """After the gamma-tests of :func:`plan_round`'s levels: a passing level lowers hi and, if it is
    below the newest history entry and has a finite margin, enters the history; a failing one raises
    lo. The chase factor grows x4 (at most 0.5) after a chased level failed and halves back (to
    ``chase``) after one passed; ``bad`` counts model rounds that did not halve the bracket."""
    for i in range(lo.shape[0]):
        width0 = hi[i] - lo[i]
        for j in range(2):
            if not need[i, j]:
                continue
            if passed[i, j]:
                fin = False
                for k in range(marg.shape[2]):
                    fin = fin or np.isfinite(marg[i, j, k])
                if fin and gam[i, j] < hist[i, 0, 0]:
                    hist[i, 2, :] = hist[i, 1, :]
                    hist[i, 1, :] = hist[i, 0, :]
                    hist[i, 0, 0] = gam[i, j]
                    hist[i, 0, 1:] = marg[i, j, :]
                hi[i] = min(hi[i], gam[i, j])
            else:
                lo[i] = max(lo[i], gam[i, j])
        if need[i, 0] and model[i] and not closing[i]:  # a level above the prediction: did it pass?
            cfac[i] = max(0.5 * cfac[i], chase) if passed[i, 0] else min(4.0 * cfac[i], 0.5)
        bad[i] = (0 if hi[i] - lo[i] <= 0.5 * width0 else bad[i] + 1) if model[i] else 0


@njit(cache=True, error_model="numpy")
def predict_many(hist, lo, hi, frac):
    """:func:`predict_one` of every system: hist (N, 3, 1 + q), lo, hi (N) -> (N).

    Returns
    -------
    ndarray (N,)
        The predicted norms; -inf where none.
    """
    out = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        out[i] = predict_one(hist[i], lo[i], hi[i], frac)
    return out


@njit(cache=True, error_model="numpy")
def zeros_many(g, m, lo, line, frac, power):
    """Per system and margin, :func:`margin_zero_one` (``power``) or :func:`quadratic_zero_one`:
    g (N, 3), m (N, 3, q), lo, line (N) -> (N, q).

    Returns
    -------
    ndarray (N, q)
        The predicted zero of every margin; -inf where none.
    """
    out = np.empty((g.shape[0], m.shape[2]))
    for i in range(g.shape[0]):
        for j in range(m.shape[2]):
            if power:
                out[i, j] = margin_zero_one(g[i, 0], g[i, 1], g[i, 2], m[i, 0, j], m[i, 1, j], m[i, 2, j], lo[i],
                                            line[i], frac)
            else:
                out[i, j] = quadratic_zero_one(g[i, 0], g[i, 1], g[i, 2], m[i, 0, j], m[i, 1, j], m[i, 2, j], lo[i])
    return out


def compile_all() -> None:
    """Compile (or load from numba's cache) every entry point; ``scripts/bootstrap.sh`` calls it at
    install time (see :func:`.hinf_kernel.compile_all`)."""
    hist = np.full((1, 3, 3), np.nan)
    hist[0, 0] = (2.0, 0.1, 0.2)
    lo, hi = np.ones(1), np.full(1, 2.0)
    cfac, bad, found = np.full(1, 0.05), np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.bool_)
    gam, need = np.empty((1, 2)), np.empty((1, 2), dtype=np.bool_)
    model, closing = np.empty(1, dtype=np.bool_), np.empty(1, dtype=np.bool_)
    plan_round(hist, lo, hi, cfac, bad, found, 1e-4, SCAN_FRAC, gam, need, model, closing)
    update_round(hist, lo, hi, cfac, bad, gam, need, np.zeros((1, 2), dtype=np.bool_), np.full((1, 2, 2), np.nan),
                 model, closing, 0.05)
    predict_many(hist, lo, hi, SCAN_FRAC)
    zeros_many(np.ascontiguousarray(hist[:, :, 0]), np.ascontiguousarray(hist[:, :, 1:]), lo, found, SCAN_FRAC, True)
