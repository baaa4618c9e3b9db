"""Truncated harmonic transfer function (HTF) of an LTP system, paper eqs. (5)-(10).

Wereley & Hall (1990), Zhou & Hagiwara (2002a): with the Fourier series A(t) = sum A_m e^{jm W t}
(eq. 8) and the block-Toeplitz operators of eq. (9), the HTF G(s) = C [sI - (A - N)]^-1 B + D
(eq. 10), N = blkdiag(j n W I), maps the harmonics of an exponentially modulated periodic
input to those of the output. Truncated to harmonics |n| <= N it is an ordinary complex LTI
system, and sup over all real w of its largest singular value approximates ||G||_inf: the
truncation is centred on every frequency, so a peak far from 0 (e.g. at the nutation
frequency, ~73 orbital harmonics up) is captured with a small N. This is the second,
independent method that cross-checks :mod:`magtune_core.ltp.hinf`.
"""
from __future__ import annotations

import numpy as np

from .system import LTPSystem


def fourier_coefficients(sys: LTPSystem, name: str, max_harmonic: int, samples: int | None = None) -> np.ndarray:
    """X_m = (1/T) int X(t) e^{-j m W t} dt for m = -max_harmonic..max_harmonic (FFT): (2M+1, r, c).

    The Fourier coefficients of paper eq. (8) (Wereley & Hall 1990), the blocks of the Toeplitz
    operators of eq. (9).

    Parameters
    ----------
    sys : LTPSystem
        One system (no batch axes).
    name : str
        Which matrix of ``sys``: "A", "B", "C" or "D".
    max_harmonic : int
        Highest harmonic M kept (m = -M..M, frequencies m W, W = 2 pi / T).
    samples : int, optional
        FFT length (default: at least 4 per harmonic kept, and 64).

    Returns
    -------
    ndarray (2 max_harmonic + 1, r, c), complex
        X_m, m ascending from -max_harmonic.

    Raises
    ------
    ValueError
        If ``sys`` has batch axes.
    """
    samples = samples or max(64, 4 * (2 * max_harmonic + 1))
    t = np.arange(samples) * sys.period / samples
    X = sys.sample(name, t)
    if X.ndim != 3:
        raise ValueError("htf: only a single system (no batch axes) is supported")
    X = np.broadcast_to(X, (samples,) + X.shape[1:])
    coef = np.fft.fft(X, axis=0) / samples
    idx = np.arange(-max_harmonic, max_harmonic + 1) % samples
    return coef[idx]


def htf_system(sys: LTPSystem, harmonics: int, margin: int | None = None):
    """Complex LTI realization of the HTF (eqs. 9-10), compressed to harmonics |n| <= ``harmonics``.

    The state keeps ``harmonics + margin`` harmonics and only the inputs and outputs are cut to
    ``harmonics``: the result is (nearly) the compression P G(s) P of the true operator. Cutting
    the state as well puts the bare averaged dynamics at the edge harmonics, whose spurious
    peaks can exceed the true norm (seen on the rotated LTI test case).

    Parameters
    ----------
    sys : LTPSystem
        One system (no batch axes).
    harmonics : int
        Harmonics |n| <= ``harmonics`` kept in the inputs and outputs.
    margin : int, optional
        Extra harmonics kept in the state only (default: ``harmonics``).

    Returns
    -------
    (A, B, C, D) : tuple of complex ndarrays
        LTI realization of the compressed HTF; inputs and outputs ordered by harmonic, then channel.
    """
    margin = harmonics if margin is None else margin
    N = harmonics + margin
    k = np.arange(-N, N + 1)
    diff = k[:, None] - k[None, :] + 2 * N  # index of A_{k-l} in the coefficient array
    mats = []
    for name in ("A", "B", "C", "D"):
        if name == "D" and not sys.has_feedthrough:
            p = sys.sample("C", np.zeros(1)).shape[-2]
            m = sys.sample("B", np.zeros(1)).shape[-1]
            mats.append(np.zeros(((2 * N + 1) * p, (2 * N + 1) * m), dtype=complex))
            continue
        coef = fourier_coefficients(sys, name, 2 * N)
        blocks = coef[diff]  # (2N+1, 2N+1, r, c)
        r, c = blocks.shape[-2:]
        mats.append(blocks.transpose(0, 2, 1, 3).reshape((2 * N + 1) * r, (2 * N + 1) * c))
    A, B, C, D = mats
    n = A.shape[0] // (2 * N + 1)
    m, p = B.shape[1] // (2 * N + 1), C.shape[0] // (2 * N + 1)
    w = 2 * np.pi / sys.period
    A = A - np.diag(np.repeat(1j * w * k, n))
    keep = np.abs(k) <= harmonics
    cols = np.repeat(keep, m)
    rows = np.repeat(keep, p)
    return A, B[:, cols], C[rows, :], D[np.ix_(rows, cols)]


def _sigma_max(A, B, C, D, w):
    G = C @ np.linalg.solve(1j * w * np.eye(A.shape[0]) - A, B) + D
    return np.linalg.norm(G, ord=2)


def lti_hinfnorm(A, B, C, D, rtol: float = 1e-9, max_iter: int = 50) -> tuple[float, float]:
    """H-inf norm and peak frequency of a (complex) stable LTI system.

    Boyd-Balakrishnan / Bruinsma-Steinbuch: gamma is a singular value at w iff jw is an
    eigenvalue of the Hamiltonian below; iterate on the midpoints of the imaginary eigenvalues.

    Parameters
    ----------
    A : ndarray (n, n)
        State matrix (real or complex).
    B : ndarray (n, m)
        Input matrix.
    C : ndarray (p, n)
        Output matrix.
    D : ndarray (p, m)
        Feedthrough.
    rtol : float
        Relative accuracy at which the iteration stops.
    max_iter : int
        Largest number of Hamiltonian eigenvalue iterations.

    Returns
    -------
    (norm, w_peak) : tuple of float
        The H-inf norm (to ``rtol``) and the frequency where it is attained; (inf, nan) if unstable.
    """
    lam = np.linalg.eigvals(A)
    if np.any(lam.real >= 0):
        return np.inf, np.nan
    cands = np.concatenate([[0.0], lam.imag, np.abs(lam)])
    vals = [_sigma_max(A, B, C, D, w) for w in cands]
    i = int(np.argmax(vals))
    lb, wpk = vals[i], cands[i]
    Dh = D.conj().T
    for _ in range(max_iter):
        g = (1.0 + 2.0 * rtol) * lb
        R = Dh @ D - g * g * np.eye(D.shape[1])
        S = D @ Dh - g * g * np.eye(D.shape[0])
        Ri = np.linalg.inv(R)
        Si = np.linalg.inv(S)
        H = np.block([[A - B @ Ri @ Dh @ C, -g * B @ Ri @ B.conj().T],
                      [g * C.conj().T @ Si @ C, -A.conj().T + C.conj().T @ D @ Ri @ B.conj().T]])
        ev = np.linalg.eigvals(H)
        tol = 1e-8 * np.maximum(1.0, np.abs(ev))
        ws = np.sort(ev.imag[np.abs(ev.real) < tol])
        if ws.size < 2:
            return 0.5 * (lb + g), wpk
        mids = 0.5 * (ws[:-1] + ws[1:])
        vals = [_sigma_max(A, B, C, D, w) for w in mids]
        j = int(np.argmax(vals))
        if vals[j] <= lb * (1.0 + rtol):
            return lb, wpk
        lb, wpk = vals[j], mids[j]
    return lb, wpk


def htf_hinfnorm(sys: LTPSystem, harmonics: int = 8, margin: int | None = None, rtol: float = 1e-9) -> float:
    """||G||_inf from the HTF compressed to |n| <= harmonics (converges from below as it grows).

    Paper eqs. (9)-(10) truncated (Zhou & Hagiwara 2002b), the norm of the truncation by
    :func:`lti_hinfnorm`: the independent cross-check of the exact :func:`.hinf.hinfnorm` (eq. 21).

    Parameters
    ----------
    sys : LTPSystem
        One stable system (no batch axes).
    harmonics : int
        Harmonics |n| <= ``harmonics`` kept in the inputs and outputs (:func:`htf_system`).
    margin : int, optional
        Extra harmonics kept in the state only (default: ``harmonics``).
    rtol : float
        Relative accuracy of :func:`lti_hinfnorm`.

    Returns
    -------
    float
        The H-inf norm of the compressed HTF, a lower bound that converges to ||G||_inf.
    """
    return lti_hinfnorm(*htf_system(sys, harmonics, margin), rtol=rtol)[0]
