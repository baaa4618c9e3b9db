"""IGRF-14 geomagnetic main field at ECI positions, in tesla, evaluated by our own recursion.

Coefficients: the official IGRF-14 table (IAGA V-MOD, Alken et al. 2025; Schmidt semi-normalized
g_n^m, h_n^m in nT, DGRF/IGRF every 5 years 1900-2025 and the 2025-2030 secular variation),
read from the copy bundled with the PyPI package ``pyIGRF14`` (``src/igrf14coeffs.txt``; no
network access). Between model epochs the coefficients are interpolated linearly; after 2025.0
they are extrapolated with the secular variation, as the IGRF definition prescribes.

Evaluation: the Cartesian recursion of Montenbruck & Gill (2000), section 3.2
(recursions for V_nm, W_nm and the acceleration formulas), written for the gravity potential, applied to the magnetic scalar potential
V = a sum_n (a/r)^(n+1) sum_m (g cos m lon + h sin m lon) P_n^m(sin lat) with
a = 6371.2 km and B = -grad V. Schmidt functions relate to the unnormalized Legendre functions
of M&G (no Condon-Shortley phase) by P_n^m = sqrt((2 - delta_m0) (n-m)!/(n+m)!) P_nm, so
C_nm = S_nm g_n^m and S_nm h_n^m play the role of M&G's C_nm, S_nm, with GM/R^2 -> 1
(B in the units of g). The recursion is singularity-free at the poles and gives B directly in
Earth-fixed Cartesian axes. The same code runs on Python floats (one point: ~50 us) or on numpy
arrays (many points), so the simulator's 1 Hz calls stay well under 1 ms.

ECI -> ECEF uses the Greenwich mean sidereal angle only (see :mod:`magtune_core.env.earth` for the
documented simplifications). Cross-checked in tests/env/test_igrf.py against pyIGRF14's own synthesis
routine and against ppigrf (independent code) to < 1 nT.
"""
from __future__ import annotations

import math
from functools import lru_cache
from importlib import resources
from math import factorial

import numpy as np

from .earth import decimal_year, eci_to_ecef
from .orbit import eci_to_orbital

IGRF_RADIUS = 6371.2e3  #: IGRF reference radius a [m]
NT = 1e-9


@lru_cache(maxsize=1)
def _coefficient_table():
    """(epochs (K,), gh (K, P), sv (P,), index [(kind, n, m)]) from the bundled IGRF-14 table."""
    path = resources.files("pyIGRF14").joinpath("src/igrf14coeffs.txt")
    rows, index, epochs = [], [], None
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "g/h":  # header: g/h n m 1900.0 ... 2025.0 2025-30
            epochs = np.array([float(p) for p in parts[3:-1]])
        elif parts[0] in ("g", "h"):
            index.append((parts[0], int(parts[1]), int(parts[2])))
            rows.append([float(p) for p in parts[3:]])
    if epochs is None or not rows:
        raise RuntimeError(f"cannot parse IGRF coefficient file {path}")
    data = np.array(rows)
    return epochs, data[:, :-1].T, data[:, -1], index


def igrf_years() -> tuple[float, float]:
    """The decimal years IGRF-14 defines the field for: its first model and its last plus the 5-year secular variation.

    Returns
    -------
    (float, float)
        (1900.0, 2030.0).
    """
    epochs = _coefficient_table()[0]
    return float(epochs[0]), float(epochs[-1]) + 5.0


def igrf_coefficients(year: float, degree: int = 13) -> tuple[np.ndarray, np.ndarray]:
    """Schmidt semi-normalized (g, h) [nT], arrays (degree+1, degree+1) indexed [n, m], at decimal ``year``."""
    epochs, gh, sv, index = _coefficient_table()
    first, last = igrf_years()
    if not first <= year <= last:
        raise ValueError(f"IGRF-14 is defined for {first:.0f}-{last:.0f}, got year {year:.3f}")
    if year >= epochs[-1]:
        vals = gh[-1] + (year - epochs[-1]) * sv
    else:
        k = int(np.searchsorted(epochs, year, side="right") - 1)
        w = (year - epochs[k]) / (epochs[k + 1] - epochs[k])
        vals = (1 - w) * gh[k] + w * gh[k + 1]
    g = np.zeros((degree + 1, degree + 1))
    h = np.zeros((degree + 1, degree + 1))
    for (kind, n, m), val in zip(index, vals):
        if n <= degree:
            (g if kind == "g" else h)[n, m] = val
    return g, h


class IGRF:
    """IGRF-14 main field truncated at ``degree`` (default 10, as in the paper), coefficients frozen
    at the decimal year of ``jd`` (secular variation over a simulation of days: < 0.1 nT/day)."""

    def __init__(self, jd: float, degree: int = 10):
        if not 1 <= degree <= 13:
            raise ValueError(f"IGRF degree must be 1..13, got {degree}")
        self.degree = degree
        self.year = float(decimal_year(jd))
        g, h = igrf_coefficients(self.year, degree)
        C = np.zeros((degree + 1, degree + 1))
        S = np.zeros((degree + 1, degree + 1))
        for n in range(1, degree + 1):
            for m in range(n + 1):
                f = math.sqrt((2.0 if m else 1.0) * factorial(n - m) / factorial(n + m))
                C[n, m], S[n, m] = f * g[n, m], f * h[n, m]
        self._C = C.tolist()
        self._S = S.tolist()
        # (n-m+2)!/(n-m)! factors of M&G's acceleration formulas
        self._fac = [[(n - m + 2) * (n - m + 1) for m in range(n + 1)] for n in range(degree + 1)]

    def ecef(self, r_ecef) -> np.ndarray:
        """B [T] in ECEF axes at ECEF positions [m]; r_ecef shape (3,) or (..., 3)."""
        r = np.asarray(r_ecef, dtype=float)
        if r.shape == (3,):
            return np.array(self._field(float(r[0]), float(r[1]), float(r[2]))) * NT
        b = self._field(r[..., 0], r[..., 1], r[..., 2])
        return np.stack(b, axis=-1) * NT

    def _field(self, x, y, z):
        """M&G section 3.2 recursion with R = a; x, y, z floats or arrays [m]; returns B [nT]."""
        N = self.degree + 1  # V/W needed to degree N
        a = IGRF_RADIUS
        r2 = x * x + y * y + z * z
        rho = a * a / r2
        x0, y0, z0 = a * x / r2, a * y / r2, a * z / r2
        V = [[0.0] * (N + 2) for _ in range(N + 2)]
        W = [[0.0] * (N + 2) for _ in range(N + 2)]
        V[0][0] = a / np.sqrt(r2) if not isinstance(r2, float) else a / math.sqrt(r2)
        W[0][0] = 0.0 * V[0][0]
        V[1][0] = z0 * V[0][0]
        W[1][0] = W[0][0]
        for n in range(2, N + 1):
            V[n][0] = ((2 * n - 1) * z0 * V[n - 1][0] - (n - 1) * rho * V[n - 2][0]) / n
            W[n][0] = W[0][0]
        for m in range(1, N + 1):
            V[m][m] = (2 * m - 1) * (x0 * V[m - 1][m - 1] - y0 * W[m - 1][m - 1])
            W[m][m] = (2 * m - 1) * (x0 * W[m - 1][m - 1] + y0 * V[m - 1][m - 1])
            if m < N:
                V[m + 1][m] = (2 * m + 1) * z0 * V[m][m]
                W[m + 1][m] = (2 * m + 1) * z0 * W[m][m]
            for n in range(m + 2, N + 1):
                V[n][m] = ((2 * n - 1) * z0 * V[n - 1][m] - (n + m - 1) * rho * V[n - 2][m]) / (n - m)
                W[n][m] = ((2 * n - 1) * z0 * W[n - 1][m] - (n + m - 1) * rho * W[n - 2][m]) / (n - m)
        gx = gy = gz = 0.0 * V[0][0]
        C, S, fac = self._C, self._S, self._fac
        for n in range(1, self.degree + 1):
            for m in range(n + 1):
                c, s = C[n][m], S[n][m]
                if m == 0:
                    gx = gx - c * V[n + 1][1]
                    gy = gy - c * W[n + 1][1]
                else:
                    f = fac[n][m]
                    gx = gx + 0.5 * ((-c * V[n + 1][m + 1] - s * W[n + 1][m + 1])
                                     + f * (c * V[n + 1][m - 1] + s * W[n + 1][m - 1]))
                    gy = gy + 0.5 * ((-c * W[n + 1][m + 1] + s * V[n + 1][m + 1])
                                     + f * (-c * W[n + 1][m - 1] + s * V[n + 1][m - 1]))
                gz = gz + (n - m + 1) * (-c * V[n + 1][m] - s * W[n + 1][m])
        # grad V_mag = (a / a) * sum(...) ; B = -grad V_mag
        return -gx, -gy, -gz

    def eci(self, r_eci, jd) -> np.ndarray:
        """B [T] in ECI axes at ECI positions [m] and Julian date(s) jd (broadcast over leading axes)."""
        R = eci_to_ecef(jd)  # (..., 3, 3)
        r = np.asarray(r_eci, dtype=float)
        r_ecef = np.einsum("...ij,...j->...i", R, r)
        b_ecef = self.ecef(r_ecef)
        return np.einsum("...ji,...j->...i", R, b_ecef)

    def orbital(self, r_eci, v_eci, jd) -> np.ndarray:
        """B [T] in orbital axes (X nadir, Y along-track, Z = -orbit normal), see :mod:`orbit`."""

        b = self.eci(r_eci, jd)
        return np.einsum("...ij,...j->...i", eci_to_orbital(r_eci, v_eci), b)


def field_eci(r_eci, jd, degree: int = 10) -> np.ndarray:
    """Convenience: IGRF-14 field [T] in ECI at ECI positions and Julian date (model built per call)."""
    return IGRF(float(np.mean(jd)), degree).eci(r_eci, jd)


def geocentric_spherical(r_ecef) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radius [m], colatitude [deg], east longitude [deg]) of ECEF positions (for cross-checks)."""
    r = np.asarray(r_ecef, dtype=float)
    rn = np.linalg.norm(r, axis=-1)
    return rn, np.degrees(np.arccos(r[..., 2] / rn)), np.degrees(np.arctan2(r[..., 1], r[..., 0]))


def ecef_to_ned(b_ecef, r_ecef) -> np.ndarray:
    """Express ECEF vectors in local geocentric (north, east, down) axes at r_ecef (for cross-checks)."""
    r = np.asarray(r_ecef, dtype=float)
    _, colat, lon = geocentric_spherical(r)
    th, ph = np.radians(colat), np.radians(lon)
    up = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    east = np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], axis=-1)
    north = np.cross(up, east)
    b = np.asarray(b_ecef, dtype=float)
    return np.stack([np.sum(b * north, -1), np.sum(b * east, -1), -np.sum(b * up, -1)], axis=-1)
