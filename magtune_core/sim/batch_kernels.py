"""Compiled inner loops of the batched simulator (numba): environment rows and the closed loop.

Why compiled code. A profile of :func:`magtune_core.sim.batch.simulate_batch` written with whole-array
numpy (200 runs x 1 orbit, full environment) spent ~55 % of its time in the attitude-independent
environment (IGRF degree 10 alone ~27 %: ~1,200 array operations per point, each one a pass over memory)
and ~40 % in the plant right-hand side (~110 numpy calls per RK4 stage on (3, B) arrays). Both are
hundreds of scalar flops per point or per run-step, i.e. exactly what a compiled loop does 10-30x faster
than a sequence of numpy temporaries (measured: 61.6 s -> 6.2 s for that task). The formulas are those of
the numpy code they replace, term by term (same order where it matters), so every run still equals the
single-run ``simulate`` to ~1e-12 (state):

* :func:`env_rows` = :func:`magtune_core.sim.fullenv.environment_table` with the IGRF field (field,
  density, Sun and ephemeris interpolated between the controller instants: see its docstring): J2(+J3, J4)
  orbital-frame rate (:func:`magtune_core.env.orbit.orbital_rate`), ECI -> orbital axes
  (:func:`~magtune_core.env.orbit.eci_to_orbital`), IGRF via ECEF at the GMST angle
  (:class:`magtune_core.env.igrf.IGRF`, Montenbruck & Gill 2000 sec. 3.2 recursion), 3 GM/|r|^3,
  Harris-Priester density with the WGS-84 geodetic height (:mod:`magtune_core.env.atmosphere`),
  co-rotating-air wind, low-precision Sun and cylindrical shadow (:mod:`magtune_core.env.sun`).
* :func:`closed_loop` = the loop body of ``simulate_batch`` (sensors, projection controller of paper
  eq. 17 with saturation and weak-field guard, sample-and-hold, classical RK4 steps re-chosen from the rate,
  quaternion renormalization, divergence flag), for each run over a chunk of controller steps; with
  :class:`Modes` ``on``, the flight modes pick the law each step (the mode machine and the B-dot law
  of :mod:`magtune_core.onboard.modes_kernel`, as :func:`magtune_core.sim.modes_loop.simulate_modes`).

Compiled on first use and cached on disk (``cache=True``: ~40 s once per installation, in
``__pycache__`` next to this file; the Dask workers load the cached machine code). ``error_model="numpy"``:
a division by zero gives inf/nan as in array code (a diverging run is flagged, not raised).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..env.atmosphere import HP_HEIGHT_KM, HP_RHO_MAX, HP_RHO_MIN, RA_LAG
from ..env.earth import F_WGS84, GM_EARTH, J2, J3, J4, JD_J2000, OMEGA_EARTH, R_EARTH, R_WGS84, SECONDS_PER_DAY
from ..env.igrf import IGRF_RADIUS, NT
from ..env.sun import AU, OBLIQUITY_J2000, SOLAR_PRESSURE_1AU
from ..onboard.mekf_kernel import matrix_quat, rotation, stream_step, valid_step
from ..onboard.modes_kernel import MODE_CODE, KernelModeParams, bdot_dipole, filter_step, mode_step
from ..onboard.sensor_watch import ARMED, BACK_CODE, GYRO_FAULT, watch_step
from ..onboard.sensor_watch import NONE as WATCH_NONE
from .fault_kernels import sensor_faults, torquer_faults

#: heights, rho_min, rho_max, scale heights of rho_min and rho_max per interval (atmosphere.harris_priester_bounds)
_HP = np.ascontiguousarray(np.vstack([HP_HEIGHT_KM, HP_RHO_MIN, HP_RHO_MAX] + [
    np.r_[(HP_HEIGHT_KM[:-1] - HP_HEIGHT_KM[1:]) / np.log(tab[1:] / tab[:-1]), 1.0] for tab in (HP_RHO_MIN, HP_RHO_MAX)]))
_D2R = np.pi / 180.0
_TWO_PI = 2.0 * np.pi
_K2 = -1.5 * J2 * GM_EARTH * R_EARTH**2
_K3 = -2.5 * J3 * GM_EARTH * R_EARTH**3
_K4 = 1.875 * J4 * GM_EARTH * R_EARTH**4
_CE, _SE = math.cos(OBLIQUITY_J2000), math.sin(OBLIQUITY_J2000)


def igrf_arrays(igrf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C, S, fac) float arrays of an :class:`magtune_core.env.igrf.IGRF` model (its recursion's inputs)."""
    return (np.array(igrf._C, dtype=float), np.array(igrf._S, dtype=float),
            np.array([row + [0] * (len(igrf._fac) - len(row)) for row in igrf._fac], dtype=float))


@njit(cache=True, inline="always", error_model="numpy")
def _cube(x):
    return x * x * x


@njit(cache=True, error_model="numpy")
def _geodetic_height(x, y, z):
    """:func:`magtune_core.env.earth.geodetic_height` (Bowring + 2 fixed-point refinements) of one point."""
    a, f = R_WGS84, F_WGS84
    b = a * (1.0 - f)
    e2 = f * (2.0 - f)
    ep2 = e2 / (1.0 - e2)
    p = math.hypot(x, y)
    theta = math.atan2(z * a, p * b)
    lat = math.atan2(z + ep2 * b * _cube(math.sin(theta)), p - e2 * a * _cube(math.cos(theta)))
    for _ in range(2):
        N = a / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
        cl = math.cos(lat)
        h = p / max(cl, 1e-300) - N if abs(cl) > 1e-8 else abs(z) - b
        lat = math.atan2(z, p * (1.0 - e2 * N / (N + h)))
    N = a / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
    cl = math.cos(lat)
    return p / max(cl, 1e-300) - N if abs(cl) > 1e-8 else abs(z) - b


@njit(cache=True, error_model="numpy")
def _hp_bounds(height, hp, which):
    """One of :func:`magtune_core.env.atmosphere.harris_priester_bounds` ((rho_min, rho_max)[which])."""
    h = height / 1e3
    H = hp[0]
    i = np.searchsorted(H, h, side="right") - 1
    i = min(max(i, 0), H.size - 2)
    h0 = H[i]
    tab = hp[1 + which]
    scale = hp[3 + which, i]  # (h0 - h1) / log(tab[i + 1] / tab[i]) [km]
    if h > 100.0 and h < 1000.0:
        return tab[i] * math.exp((h0 - h) / scale) * 1e-12
    return 0.0


@njit(cache=True, error_model="numpy")
def _igrf_field(x, y, z, C, S, fac, degree, V, W, inv):
    """:meth:`magtune_core.env.igrf.IGRF._field` on one ECEF point [m]; returns B [nT] (ECEF)."""
    N = degree + 1
    a = IGRF_RADIUS
    r2 = x * x + y * y + z * z
    ir2 = 1.0 / r2
    rho = a * a * ir2
    x0, y0, z0 = a * x * ir2, a * y * ir2, a * z * ir2
    V[0, 0] = a / math.sqrt(r2)
    W[0, 0] = 0.0
    V[1, 0] = z0 * V[0, 0]
    W[1, 0] = 0.0
    for n in range(2, N + 1):  # inv[k] = 1/k: multiplications instead of serial divisions (~1 ulp)
        V[n, 0] = ((2 * n - 1) * z0 * V[n - 1, 0] - (n - 1) * rho * V[n - 2, 0]) * inv[n]
        W[n, 0] = 0.0
    for m in range(1, N + 1):
        V[m, m] = (2 * m - 1) * (x0 * V[m - 1, m - 1] - y0 * W[m - 1, m - 1])
        W[m, m] = (2 * m - 1) * (x0 * W[m - 1, m - 1] + y0 * V[m - 1, m - 1])
        if m < N:
            V[m + 1, m] = (2 * m + 1) * z0 * V[m, m]
            W[m + 1, m] = (2 * m + 1) * z0 * W[m, m]
        for n in range(m + 2, N + 1):
            V[n, m] = ((2 * n - 1) * z0 * V[n - 1, m] - (n + m - 1) * rho * V[n - 2, m]) * inv[n - m]
            W[n, m] = ((2 * n - 1) * z0 * W[n - 1, m] - (n + m - 1) * rho * W[n - 2, m]) * inv[n - m]
    gx = gy = gz = 0.0
    for n in range(1, degree + 1):
        for m in range(n + 1):
            c, s = C[n, m], S[n, m]
            if m == 0:
                gx = gx - c * V[n + 1, 1]
                gy = gy - c * W[n + 1, 1]
            else:
                f = fac[n, m]
                gx = gx + 0.5 * ((-c * V[n + 1, m + 1] - s * W[n + 1, m + 1])
                                 + f * (c * V[n + 1, m - 1] + s * W[n + 1, m - 1]))
                gy = gy + 0.5 * ((-c * W[n + 1, m + 1] + s * V[n + 1, m + 1])
                                 + f * (-c * W[n + 1, m - 1] + s * V[n + 1, m - 1]))
            gz = gz + (n - m + 1) * (-c * V[n + 1, m] - s * W[n + 1, m])
    return -gx, -gy, -gz


@njit(cache=True, error_model="numpy")
def _lagrange_weights(x, w):
    """Weights of the degree-7 Lagrange polynomial through the nodes 0..7 at abscissa ``x`` (into w (8,))."""
    for i in range(8):
        num, den = 1.0, 1.0
        for k in range(8):
            if k != i:
                num *= x - k
                den *= i - k
        w[i] = num / den


@njit(cache=True, error_model="numpy")
def _hp_density(rx, ry, rz, rn, sx, sy, sz, hp, hp_n):
    """:func:`magtune_core.env.atmosphere.harris_priester` at one point; (rho [kg/m^3], table interval)."""
    ra = math.atan2(sy, sx) + RA_LAG
    dec = math.atan2(sz, math.hypot(sx, sy))
    cos_psi = (rx * math.cos(dec) * math.cos(ra) + ry * math.cos(dec) * math.sin(ra) + rz * math.sin(dec)) / rn
    c_half2 = 0.5 * (1.0 + cos_psi)
    hgt = _geodetic_height(rx, ry, rz)
    rmin, rmax = _hp_bounds(hgt, hp, 0), _hp_bounds(hgt, hp, 1)
    band = np.searchsorted(hp[0], hgt / 1e3, side="right")
    return rmin + (rmax - rmin) * (_cube(c_half2) if hp_n == 6.0 else c_half2 ** (hp_n / 2.0)), band


@njit(cache=True, error_model="numpy")
def orbit_rhs(y, zonal):
    """d/dt of B stacked orbits y (6 B,) = [r, v] per run: :func:`magtune_core.env.orbit.gravity_acceleration`."""
    out = np.empty_like(y)
    for b in range(y.size // 6):
        o = 6 * b
        x, yy, z = y[o], y[o + 1], y[o + 2]
        r2 = x * x + yy * yy + z * z
        rn = math.sqrt(r2)
        r3 = rn**3
        ax, ay, az = -GM_EARTH * x / r3, -GM_EARTH * yy / r3, -GM_EARTH * z / r3
        if zonal >= 2:
            s2 = z * z / r2
            k = _K2 / rn**5
            ax, ay, az = ax + k * x * (1 - 5 * s2), ay + k * yy * (1 - 5 * s2), az + k * z * (3 - 5 * s2)
        if zonal >= 3:
            k = _K3 / rn**7
            cxy = 3 * z - 7 * z**3 / r2
            ax, ay, az = ax + k * x * cxy, ay + k * yy * cxy, az + k * (6 * z * z - 7 * z**4 / r2 - 0.6 * r2)
        if zonal >= 4:
            k = _K4 / rn**7
            s2 = z * z / r2
            cxy = 1 - 14 * s2 + 21 * s2 * s2
            ax, ay, az = ax + k * x * cxy, ay + k * yy * cxy, az + k * z * (5 - 70.0 / 3.0 * s2 + 21 * s2 * s2)
        out[o], out[o + 1], out[o + 2] = y[o + 3], y[o + 4], y[o + 5]
        out[o + 3], out[o + 4], out[o + 5] = ax, ay, az
    return out


@njit(cache=True, error_model="numpy")
def _sun(jd):
    """:func:`magtune_core.env.sun.sun_position` (of date) at one Julian date [m, ECI]."""
    T = (jd - JD_J2000) / 36525.0
    M = _D2R * (357.5256 + 35999.049 * T)
    lam = _D2R * 282.9400 + M + _D2R * ((6892.0 * math.sin(M) + 72.0 * math.sin(2 * M)) / 3600.0)
    lam = lam + _D2R * 1.3972 * T
    rs = (149.619 - 2.499 * math.cos(M) - 0.021 * math.cos(2 * M)) * 1e9
    return rs * math.cos(lam), rs * math.sin(lam) * _CE, rs * math.sin(lam) * _SE


@njit(cache=True, error_model="numpy")
def env_rows(Y, t, j0, stride, last_node, ia, ib, jd0, C, S, fac, degree, zonal, drag, srp, hp_n, out):
    """Environment rows of one orbit at the grid times ``t`` (n,) into ``out`` (n, 15) (the layout of
    :func:`magtune_core.sim.fullenv.environment_table`, IGRF field). ``Y`` (6, n) ECI position [m] and
    velocity [m/s] at ``t`` (the run's ephemeris: only the nodes are read, the other columns are
    overwritten), ``jd0`` the epoch's Julian date; ``t[i]`` is grid point ``j0 + i``; rows ``ia .. ib-1``
    are filled (the others hold the nodes of their interpolation windows, only partly filled).

    The frame, its rate, 3 GM/|r|^3, the wind and the SRP columns (with the shadow) are evaluated at
    every point. The costly smooth inputs -- the IGRF field (~60 % of the work), the Harris-Priester
    density (~35 %) and the Sun position -- are evaluated at the nodes ``j % stride == 0`` (the caller
    puts them at the controller instants, so the control law sees exactly the single-run field) and
    interpolated in between with the degree-7 Lagrange polynomial through the 8 nearest nodes
    (window centred, shifted inside ``[0, last_node]`` at the ends; the caller passes points covering
    the window). Where a window straddles a height of the Harris-Priester table (a kink of the
    density) the density is evaluated exactly. The ephemeris itself (a DOP853 dense output, i.e. a
    degree-7 polynomial per solver step of ~30-60 s) is interpolated the same way. Deviation from the
    all-points evaluation, measured over an orbit at 1 s nodes: field ~1e-9 relative (the IGRF-side
    jitter of ``jd0 + t/86400`` rounding, ~4e-5 s of Earth rotation, that the interpolation smooths),
    density ~5e-12, the rest ~1e-13. ``stride = 1``: everything exact.
    """
    n = t.size
    N = degree + 1
    V = np.zeros((N + 2, N + 2))
    W = np.zeros((N + 2, N + 2))
    inv = np.ones(N + 2)
    for k in range(1, N + 2):
        inv[k] = 1.0 / k
    hp = _HP
    sun = np.zeros((n, 3))
    band = np.zeros(n, dtype=np.int64)
    w = np.empty(8)
    for p in range(2):  # pass 0: the nodes; pass 1: every point
        for i in range(0 if p == 0 else ia, n if p == 0 else ib):
            node = (j0 + i) % stride == 0
            if p == 0 and not node:
                continue
            if not node:  # Lagrange weights of this point; the ephemeris interpolated from the nodes too
                j = j0 + i
                n0 = min(max(j // stride - 3, 0), last_node - 7)
                _lagrange_weights(j / stride - n0, w)
                l0 = n0 * stride - j0  # local index of the first node of the window
                if l0 < 0 or l0 + 7 * stride >= n:
                    raise IndexError("env_rows: the interpolation window leaves the points passed")
                for col in range(6):
                    acc = 0.0
                    for k in range(8):
                        acc += w[k] * Y[col, l0 + k * stride]
                    Y[col, i] = acc
            rx, ry, rz, vx, vy, vz = Y[0, i], Y[1, i], Y[2, i], Y[3, i], Y[4, i], Y[5, i]
            r2 = rx * rx + ry * ry + rz * rz
            rn = math.sqrt(r2)
            # orbital axes (orbit.eci_to_orbital): X = -r/|r|, Z = -h/|h|, Y = Z x X
            hx, hy, hz = ry * vz - rz * vy, rz * vx - rx * vz, rx * vy - ry * vx
            hn = math.sqrt(hx * hx + hy * hy + hz * hz)
            X0, X1, X2 = -rx / rn, -ry / rn, -rz / rn
            Z0, Z1, Z2 = -hx / hn, -hy / hn, -hz / hn
            Y0, Y1, Y2 = Z1 * X2 - Z2 * X1, Z2 * X0 - Z0 * X2, Z0 * X1 - Z1 * X0
            if p == 0:
                jd = jd0 + t[i] / SECONDS_PER_DAY
                # IGRF in ECEF (R_z(GMST)), back to ECI, then orbital axes
                ang = (_D2R * (280.46061837 + 360.98564736629 * (jd - JD_J2000))) % _TWO_PI
                c, s = math.cos(ang), math.sin(ang)
                bx, by, bz = _igrf_field(c * rx + s * ry, -s * rx + c * ry, rz, C, S, fac, degree, V, W, inv)
                bx, by, bz = bx * NT, by * NT, bz * NT
                ex, ey, ez = c * bx - s * by, s * bx + c * by, bz
                out[i, 3] = X0 * ex + X1 * ey + X2 * ez
                out[i, 4] = Y0 * ex + Y1 * ey + Y2 * ez
                out[i, 5] = Z0 * ex + Z1 * ey + Z2 * ez
                out[i, 7] = 0.0
                if drag or srp:
                    sun[i, 0], sun[i, 1], sun[i, 2] = _sun(jd)
                if drag:
                    out[i, 7], band[i] = _hp_density(rx, ry, rz, rn, sun[i, 0], sun[i, 1], sun[i, 2], hp, hp_n)
                continue
            if not node:  # interpolate the field, the Sun and the density from the nodes
                for col in (3, 4, 5):
                    acc = 0.0
                    for k in range(8):
                        acc += w[k] * out[l0 + k * stride, col]
                    out[i, col] = acc
                if drag or srp:
                    for col in range(3):
                        acc = 0.0
                        for k in range(8):
                            acc += w[k] * sun[l0 + k * stride, col]
                        sun[i, col] = acc
                out[i, 7] = 0.0
                if drag:
                    same = True
                    for k in range(1, 8):
                        same = same and band[l0 + k * stride] == band[l0]
                    if same:
                        acc = 0.0
                        for k in range(8):
                            acc += w[k] * out[l0 + k * stride, 7]
                        out[i, 7] = acc
                    else:  # the window crosses a table height: exact
                        out[i, 7] = _hp_density(rx, ry, rz, rn, sun[i, 0], sun[i, 1], sun[i, 2], hp, hp_n)[0]
            # orbital-frame rate (orbit.orbital_rate with orbit.gravity_acceleration)
            r3 = rn * rn * rn
            ax, ay, az = -GM_EARTH * rx / r3, -GM_EARTH * ry / r3, -GM_EARTH * rz / r3
            if zonal >= 2:
                s2 = rz * rz / r2
                k = _K2 / (r3 * r2)
                ax, ay, az = ax + k * rx * (1 - 5 * s2), ay + k * ry * (1 - 5 * s2), az + k * rz * (3 - 5 * s2)
            if zonal >= 3:
                k = _K3 / (r3 * r2 * r2)
                cxy = 3 * rz - 7 * rz**3 / r2
                ax, ay, az = ax + k * rx * cxy, ay + k * ry * cxy, az + k * (6 * rz * rz - 7 * rz**4 / r2 - 0.6 * r2)
            if zonal >= 4:
                k = _K4 / (r3 * r2 * r2)
                s2 = rz * rz / r2
                cxy = 1 - 14 * s2 + 21 * s2 * s2
                ax, ay, az = ax + k * rx * cxy, ay + k * ry * cxy, az + k * rz * (5 - 70.0 / 3.0 * s2 + 21 * s2 * s2)
            a_h = (ax * hx + ay * hy + az * hz) / hn
            out[i, 0] = -rn * a_h / hn
            out[i, 1] = 0.0
            out[i, 2] = -hn / r2
            out[i, 6] = 3.0 * GM_EARTH / r3
            for col in range(8, 15):
                out[i, col] = 0.0
            if drag:  # relative_wind_eci in orbital axes
                wx, wy, wz = vx + OMEGA_EARTH * ry, vy - OMEGA_EARTH * rx, vz
                out[i, 8] = X0 * wx + X1 * wy + X2 * wz
                out[i, 9] = Y0 * wx + Y1 * wy + Y2 * wz
                out[i, 10] = Z0 * wx + Z1 * wy + Z2 * wz
            if srp:  # unit satellite -> Sun, P (AU/d)^2 nu (sun.shadow_cylindrical)
                sx, sy, sz = sun[i, 0], sun[i, 1], sun[i, 2]
                dx, dy, dz = sx - rx, sy - ry, sz - rz
                dist = math.sqrt(dx * dx + dy * dy + dz * dz)
                dx, dy, dz = dx / dist, dy / dist, dz / dist
                out[i, 11] = X0 * dx + X1 * dy + X2 * dz
                out[i, 12] = Y0 * dx + Y1 * dy + Y2 * dz
                out[i, 13] = Z0 * dx + Z1 * dy + Z2 * dz
                sn = math.sqrt(sx * sx + sy * sy + sz * sz)
                ux, uy, uz = sx / sn, sy / sn, sz / sn
                proj = rx * ux + ry * uy + rz * uz
                px, py, pz = rx - proj * ux, ry - proj * uy, rz - proj * uz
                lit = 0.0 if (proj < 0 and math.sqrt(px * px + py * py + pz * pz) < R_EARTH) else 1.0
                out[i, 14] = SOLAR_PRESSURE_1AU * (AU / dist) ** 2 * lit


@njit(cache=True, error_model="numpy")
def _rhs(E, y, m0, m1, m2, Ib, Jb, hw, mr, gg, drag, srp, A, cp, cd, es, ed, out):
    """dy/dt of one run into ``out`` (7,): :meth:`FullDynamics._rhs` on floats (paper environment: the table
    w_oi = [0, 0, -W0], k_gg = 3 W0^2, no drag, no SRP, as :meth:`AttitudeDynamics._rhs`)."""
    q0, q1, q2, q3, wx, wy, wz = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
    n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    if n2 == 1.0:
        a0, a1, a2, a3 = q0, q1, q2, q3
    else:
        nn = 1.0 / math.sqrt(n2)
        a0, a1, a2, a3 = q0 * nn, q1 * nn, q2 * nn, q3 * nn
    # R(q) body -> orbital, row-major (base.rotations.dcm_floats)
    r00 = a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3
    r01 = 2 * (a1 * a2 - a0 * a3)
    r02 = 2 * (a1 * a3 + a0 * a2)
    r10 = 2 * (a1 * a2 + a0 * a3)
    r11 = a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3
    r12 = 2 * (a2 * a3 - a0 * a1)
    r20 = 2 * (a1 * a3 - a0 * a2)
    r21 = 2 * (a2 * a3 + a0 * a1)
    r22 = a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3
    fo0, fo1, fo2 = E[3], E[4], E[5]
    b0 = r00 * fo0 + r10 * fo1 + r20 * fo2
    b1 = r01 * fo0 + r11 * fo1 + r21 * fo2
    b2 = r02 * fo0 + r12 * fo1 + r22 * fo2
    tx = ty = tz = 0.0
    if gg:  # 3 GM/|r|^3 c x (I c), c = nadir in body axes
        k = E[6]
        c0, c1, c2 = r00, r01, r02
        i0 = Ib[0, 0] * c0 + Ib[0, 1] * c1 + Ib[0, 2] * c2
        i1 = Ib[1, 0] * c0 + Ib[1, 1] * c1 + Ib[1, 2] * c2
        i2 = Ib[2, 0] * c0 + Ib[2, 1] * c1 + Ib[2, 2] * c2
        tx, ty, tz = k * (c1 * i2 - c2 * i1), k * (c2 * i0 - c0 * i2), k * (c0 * i1 - c1 * i0)
    fx = fy = fz = 0.0
    if drag:  # F = -1/2 Cd rho (sum_i A_i |v_i|) v
        ux, uy, uz = E[8], E[9], E[10]
        vx = r00 * ux + r10 * uy + r20 * uz
        vy = r01 * ux + r11 * uy + r21 * uz
        vz = r02 * ux + r12 * uy + r22 * uz
        k = -0.5 * cd * E[7] * (A[0] * abs(vx) + A[1] * abs(vy) + A[2] * abs(vz))
        fx, fy, fz = k * vx, k * vy, k * vz
    if srp:  # F = -P sum_i A_i c_i [(1 - es) s + 2 (es c_i + ed/3) sgn(s_i) e_i]
        P = E[14]
        sx0, sy0, sz0 = E[11], E[12], E[13]
        sx = r00 * sx0 + r10 * sy0 + r20 * sz0
        sy = r01 * sx0 + r11 * sy0 + r21 * sz0
        sz = r02 * sx0 + r12 * sy0 + r22 * sz0
        cx, cy, cz = abs(sx), abs(sy), abs(sz)
        a = (1.0 - es) * (A[0] * cx + A[1] * cy + A[2] * cz)
        fx -= P * (a * sx + 2.0 * A[0] * cx * (es * cx + ed / 3.0) * math.copysign(1.0, sx))
        fy -= P * (a * sy + 2.0 * A[1] * cy * (es * cy + ed / 3.0) * math.copysign(1.0, sy))
        fz -= P * (a * sz + 2.0 * A[2] * cz * (es * cz + ed / 3.0) * math.copysign(1.0, sz))
    if drag or srp:  # convex box: torque = cp_offset x F
        tx, ty, tz = tx + (cp[1] * fz - cp[2] * fy), ty + (cp[2] * fx - cp[0] * fz), tz + (cp[0] * fy - cp[1] * fx)
    n0, n1, n2_ = m0 + mr[0], m1 + mr[1], m2 + mr[2]
    tx, ty, tz = tx + (n1 * b2 - n2_ * b1), ty + (n2_ * b0 - n0 * b2), tz + (n0 * b1 - n1 * b0)
    o0, o1, o2 = E[0], E[1], E[2]
    vx = wx - (r00 * o0 + r10 * o1 + r20 * o2)
    vy = wy - (r01 * o0 + r11 * o1 + r21 * o2)
    vz = wz - (r02 * o0 + r12 * o1 + r22 * o2)
    # Euler: I w' = T - w x (I w + h)
    L0 = Ib[0, 0] * wx + Ib[0, 1] * wy + Ib[0, 2] * wz + hw[0]
    L1 = Ib[1, 0] * wx + Ib[1, 1] * wy + Ib[1, 2] * wz + hw[1]
    L2 = Ib[2, 0] * wx + Ib[2, 1] * wy + Ib[2, 2] * wz + hw[2]
    e0, e1, e2 = tx - (wy * L2 - wz * L1), ty - (wz * L0 - wx * L2), tz - (wx * L1 - wy * L0)
    out[0] = -0.5 * (q1 * vx + q2 * vy + q3 * vz)
    out[1] = 0.5 * (q0 * vx + (q2 * vz - q3 * vy))
    out[2] = 0.5 * (q0 * vy + (q3 * vx - q1 * vz))
    out[3] = 0.5 * (q0 * vz + (q1 * vy - q2 * vx))
    out[4] = Jb[0, 0] * e0 + Jb[0, 1] * e1 + Jb[0, 2] * e2
    out[5] = Jb[1, 0] * e0 + Jb[1, 1] * e1 + Jb[1, 2] * e2
    out[6] = Jb[2, 0] * e0 + Jb[2, 1] * e1 + Jb[2, 2] * e2


class Chunk(NamedTuple):
    """The controller steps one :func:`closed_loop` call advances and the environment rows they read."""

    table: np.ndarray  #: (U, npts, 15) environment rows on the RK4 stage grid from step ``kc`` on
    idx: np.ndarray  #: (B,) int64: run b reads ``table[idx[b]]``
    kc: int  #: controller step of the table's first row
    ka: int  #: first controller step advanced
    kb: int  #: one past the last controller step advanced
    n: int  #: the run's last controller step (recorded, not integrated over)
    per: int  #: table rows per controller step (2 x the finest level)
    levels: np.ndarray  #: (L,) int64 RK4 steps per controller period, the ladder of sim.substeps.Substeps
    thr: np.ndarray  #: (L,) the largest squared body rate [rad^2/s^2] each level covers
    h: np.ndarray  #: (L,) RK4 step Ts / level [s]


class Plant(NamedTuple):
    """Per-run rigid body, residual dipole and disturbance torques of :func:`_rhs`."""

    I: np.ndarray  #: (B, 3, 3) inertia [kg m^2]
    J: np.ndarray  #: (B, 3, 3) its inverse
    hw: np.ndarray  #: (3,) wheel momentum [N m s]
    mres: np.ndarray  #: (3, B) residual dipole [A m^2]
    gg: bool  #: gravity-gradient torque on
    drag: bool  #: aerodynamic torque on
    srp: bool  #: solar radiation pressure torque on
    A: np.ndarray  #: (3,) face areas of the box [m^2]
    cp: np.ndarray  #: (3,) centre-of-pressure offset [m]
    cd: float  #: drag coefficient
    es: float  #: specular reflectivity
    ed: float  #: diffuse reflectivity


class Controller(NamedTuple):
    """Per-run projection controller (paper eq. 17) with saturation and the weak-field guard."""

    K: np.ndarray  #: (B, 3, 6) gains
    lim: np.ndarray  #: (3, B) the laws' dipole limits [A m^2] (onboard.torquers.Torquers.law_limit)
    W0: np.ndarray  #: (B,) orbit rate of the controller's linear state [rad/s]
    min_b2: float  #: weak-field guard: no command below this |b|^2 [T^2]
    scale: float  #: the torquers drive the law's dipole / scale (Torquers.command_scale; 1: as commanded)
    weights: np.ndarray  #: (L, most) the driven dipole's weight per RK4 step of each level (Torquers.substep_weights)


class Sensors(NamedTuple):
    """Per-run sensor model (``batch.SensorNoise``) and the chunk of normals it reads."""

    noisy: bool  #: any noise or bias at all (else the true state is measured)
    noise: np.ndarray  #: (B, CHUNK, 12) normals (layout of design.sensors); step k reads row k - noise_k0
    noise_k0: int  #: controller step of noise row 0
    mag_bias: np.ndarray  #: (3, B) magnetometer bias [T]
    mag_std: np.ndarray  #: (B,) magnetometer white-noise std [T]
    quantum: float  #: magnetometer quantization step [T] (0: none)
    mag_on: bool  #: apply the scale/misalignment matrices
    mag_M: np.ndarray  #: (B, 3, 3) magnetometer scale factor and misalignment
    att_std: np.ndarray  #: (B,) attitude-determination error std [rad]
    gyro_avg: np.ndarray  #: (B, CHUNK, 3) (beta_k + beta_k+1)/2 of the Farrenkopf bias walk [rad/s]
    gyro_white: np.ndarray  #: (B,) std of the gyro's white part sqrt(sigma_v^2/Ts + sigma_u^2 Ts/12) [rad/s]
    coupled: bool  #: the torquers' field reaches the magnetometer (onboard.torquers)
    C: np.ndarray  #: (3, 3) g C: the coupling times the field left at the sample [T/(A m^2)]
    m_last: np.ndarray  #: (3, B) the dipole each run's torquers drove over the last period [A m^2] (updated)


class Outputs(NamedTuple):
    """What :func:`closed_loop` accumulates and records (arrays written in place)."""

    sat: np.ndarray  #: (B,) int64 saturated steps
    weak: np.ndarray  #: (B,) int64 weak-field steps
    diverged: np.ndarray  #: (B,) bool
    diverged_rate: float  #: a body rate above this [rad/s] (or a non-finite state) marks the run diverged
    full: bool  #: write the per-step series ang_all, mn_all, sat_all
    ang_all: np.ndarray  #: (B, n + 1) |q_vec| per step (with ``full``)
    mn_all: np.ndarray  #: (B, n + 1) |m| per step (with ``full``)
    rec_slot: np.ndarray  #: (n + 1,) int64 history slot of step k (-1: not recorded)
    Q: np.ndarray  #: (B, R, 4) recorded attitude
    Wr: np.ndarray  #: (B, R, 3) recorded body rate
    X: np.ndarray  #: (B, R, 6) recorded controller state
    M: np.ndarray  #: (B, R, 3) recorded dipole
    Bb: np.ndarray  #: (B, R, 3) recorded true body field
    sat_all: np.ndarray  #: (B, n + 1) bool: step k saturated an axis (with ``full``)


_DET, _ACQ, _PNT, _SAFE = MODE_CODE["DETUMBLE"], MODE_CODE["ACQUISITION"], MODE_CODE["POINTING"], MODE_CODE["SAFE"]


class Modes(NamedTuple):
    """The flight modes of every run (``on`` False: the projection law throughout, as before) and their state.

    The measurements the mode machine reads are the sensors' (the gyro's |w|, the filtered |db/dt| of the
    measured field, the pointing error of the measured attitude), as in the mode manager node.
    """

    on: bool  #: fly the modes
    P: KernelModeParams  #: thresholds and timers (onboard.modes.ModeParams)
    k: np.ndarray  #: (B,) B-dot gain [N m s] (normalized law) or [A m^2 s / T] (raw)
    normalized: bool  #: the normalized B-dot law (onboard.bdot.BdotController)
    min_field: float  #: B-dot weak-field guard [T]
    a: float  #: derivative-filter pole exp(-cutoff Ts)
    ts: float  #: controller period [s] (sim time t_k = k ts)
    mode: np.ndarray  #: (B,) int64 current mode code (onboard.modes_kernel.MODE_CODE)
    pending: np.ndarray  #: (B, 8) guard start times [s] (nan: not holding)
    fb: np.ndarray  #: (B, 3) previous measured field [T] (filter memory)
    fy: np.ndarray  #: (B, 3) previous filter output [T/s]
    first: np.ndarray  #: (B,) bool: no field sample yet
    n_tr: np.ndarray  #: (B,) int64 transitions so far
    t_detumble: np.ndarray  #: (B,) first instant DETUMBLE was left [s] (nan: not yet)
    t_pointing: np.ndarray  #: (B,) first instant POINTING was entered [s] (nan: not yet)
    mode_all: np.ndarray  #: (B, n + 1) int8 mode code after each step's decision (with ``Outputs.full``)


class EstimatorIO(NamedTuple):
    """What the estimator in the loop reads besides the sensors' normals (:class:`~magtune_core.onboard.mekf_kernel.KernelMekf`
    holds the filters) and what it writes."""

    #: (U, steps of the chunk, 13) at the controller instants: R_oi (ECI -> orbital, row-major 9), unit
    #: satellite->Sun in ECI (3), lit (1)
    cols: np.ndarray
    aux: np.ndarray  #: (B, CHUNK, 9) auxiliary normals (design.sensors.AUX_NORMALS layout); step k reads row k - noise_k0
    sun_std: np.ndarray  #: (B,) the sun sensor's angle error std per axis [rad] (the truth's sensor)
    err: np.ndarray  #: (B, n + 1, 3) float32 estimation error dtheta [rad], body axes (with Outputs.full; nan: no estimate)
    sig: np.ndarray  #: (B, n + 1, 3) float32 sqrt of the attitude variances [rad] (with Outputs.full)
    nees: np.ndarray  #: (B, n + 1) float32 dtheta^T P_tt^-1 dtheta (with Outputs.full)
    no_att: np.ndarray  #: (B,) int64 steps without a valid estimate (before the coarse fix, or not valid: zero dipole)
    Qe: np.ndarray  #: (B, R, 4) recorded estimate, body w.r.t. orbital axes
    be: np.ndarray  #: (B, R, 3) recorded bias estimate [rad/s]
    Pe: np.ndarray  #: (B, R, 9, 9) recorded covariance
    me: np.ndarray  #: (B, R, 3) recorded magnetometer-bias estimate [T]
    #: the sensor watch (onboard.sensor_watch, the estimator node's watch_sensors): per-run state (B, NS), the
    #: parameter array (NP,; empty: no watch), its arming rate [rad/s] and the recovery's 1-sigmas (magnetometer
    #: bias [T], gyro bias [rad/s], attitude [rad])
    ws: np.ndarray
    wp: np.ndarray
    arm_rate: float
    recover: np.ndarray  #: (3,)
    fdir_code: np.ndarray  #: (B,) int64 the first verdict's code (0: none; sensor_watch.MAG_FAULT, GYRO_FAULT, MAG_AMBIGUOUS)
    fdir_t: np.ndarray  #: (B,) its time [s] (nan: none)
    fdir_n: np.ndarray  #: (B,) int64 verdicts (failed)
    fdir_back: np.ndarray  #: (B,) int64 units reported back
    #: the torquer watch's inputs at every step (``tw_on``; the attitude_estimator node's ``watch_torquers``, replayed
    #: after the run by sim.batch_torquer): gyro minus the estimated bias [rad/s] and the estimate w.r.t. the orbital
    #: axes (nan: the filter has no state, the node does not step the watch), the measured field [T], the dipole
    #: commanded (published) the step before [A m^2] (nan at step 0), and active (a valid estimate in POINTING or an
    #: ACQUISITION after it, or without modes, and a command); (B, n + 1, .) or (1, 1, .)
    tw_on: bool
    tw_w: np.ndarray
    tw_b: np.ndarray
    tw_m: np.ndarray
    tw_q: np.ndarray
    tw_act: np.ndarray
    tw_armed: np.ndarray  #: (B,) bool: torquer_watch.watch_mode's armed flag per run


@njit(cache=True, error_model="numpy")
def _reopen(P, i, std):
    """MekfStream.reopen on one block: rows and columns i..i+2 zeroed, std^2 on its diagonal."""
    for r in range(3):
        for c in range(P.shape[0]):
            P[i + r, c] = 0.0
            P[c, i + r] = 0.0
        P[i + r, i + r] = std * std


@njit(cache=True, error_model="numpy")
def _watch(est, eio, b, k, nis_m, nis_s, started, valid, w0, w1, w2, held):
    """The estimator node's ``watch_sensors`` for run ``b`` at step ``k``: the sensor watch armed by a valid estimate of a
    calm body; at a verdict the recovery (the unit's bias block reopened, the gyro's with the attitude; the validity's
    NIS average restarted) and the run's record (first verdict, counts). ``held``: a mode other than POINTING (the
    node's mode topic): disarmed as by a restart."""
    ws = eio.ws[b]
    calm = math.sqrt((w0 - est.b[b, 0]) ** 2 + (w1 - est.b[b, 1]) ** 2 + (w2 - est.b[b, 2]) ** 2) < eio.arm_rate
    sun_ok = nis_s <= est.gate_sun  # False for nan (no sun update)
    code = watch_step(ws, eio.wp, nis_m, nis_s, sun_ok, est.b[b], est.P[b, 3:6, 3:6],
                      valid and (calm or ws[ARMED] != 0.0), started or held)
    if code == WATCH_NONE:
        return
    if code == BACK_CODE:
        eio.fdir_back[b] += 1
        return
    eio.fdir_n[b] += 1
    if eio.fdir_code[b] == 0:
        eio.fdir_code[b], eio.fdir_t[b] = code, k * est.ts
    if not est.started[b]:  # restarted at this sample: nothing to reopen (MekfStream.reopen of no state)
        return
    std = eio.recover[1] if code == GYRO_FAULT else eio.recover[0]
    if std > 0.0:
        _reopen(est.P[b], 3 if code == GYRO_FAULT else 6, std)
        if code == GYRO_FAULT and eio.recover[2] > 0.0:
            _reopen(est.P[b], 0, eio.recover[2])
        if not math.isnan(est.nis_avg[b]):  # ValidityMonitor.forgive
            est.nis_avg[b] = 3.0


@njit(cache=True, error_model="numpy")
def _record_watch(eio, b, k, active, qe, re, bm0, bm1, bm2):
    """The torquer watch's inputs of run ``b`` at step ``k`` (EstimatorIO.tw_*): the estimate's rate and attitude
    (:func:`_estimate`'s; nan without an estimate: its zero quaternion), the measured field, ``active``."""
    none = qe[0] == 0.0 and qe[1] == 0.0 and qe[2] == 0.0 and qe[3] == 0.0
    for i in range(3):
        eio.tw_w[b, k, i] = math.nan if none else re[i]
    for i in range(4):
        eio.tw_q[b, k, i] = math.nan if none else qe[i]
    eio.tw_b[b, k, 0], eio.tw_b[b, k, 1], eio.tw_b[b, k, 2] = bm0, bm1, bm2
    eio.tw_act[b, k] = active and not none


@njit(cache=True, error_model="numpy")
def _estimate(est, eio, u, b, r, k, kc, noise_k0, a0, a1, a2, a3, fo0, fo1, fo2, bm0, bm1, bm2, wm0, wm1, wm2, full,
              sun_lost, held):
    """The estimator of run ``b`` (environment rows ``u``) at step ``k`` (the attitude_estimator node's sample): the sun sensor on the
    true attitude (a0..a3, body w.r.t. orbital), the MEKF step (onboard.mekf_kernel.stream_step) on the
    measured field and the previous gyro sample against the reference vectors in ECI (the field of the
    table rotated back with R_oi^T, the Sun of date), the estimate in orbital axes. Returns (have, q_bo (4,),
    rate (3,)): the controller's attitude and rate (gyro minus the estimated bias); ``have`` False before the fix
    and while :func:`~magtune_core.onboard.mekf_kernel.valid_step` says not valid. ``sun_lost``: an injected sun
    sensor loss (no sun sample, as in eclipse); ``held``: the sensor watch held (a mode other than POINTING)."""
    ec = eio.cols[u, k - kc]
    Roi = ec[:9].reshape(3, 3)
    bref = np.empty(3)
    for i in range(3):
        bref[i] = Roi[0, i] * fo0 + Roi[1, i] * fo1 + Roi[2, i] * fo2
    mag = np.array([bm0, bm1, bm2])
    lit = ec[12] > 0.5 and not sun_lost
    sref = ec[9:12].copy()
    sm = np.zeros(3)
    if lit:
        so0 = Roi[0, 0] * sref[0] + Roi[0, 1] * sref[1] + Roi[0, 2] * sref[2]
        so1 = Roi[1, 0] * sref[0] + Roi[1, 1] * sref[1] + Roi[1, 2] * sref[2]
        so2 = Roi[2, 0] * sref[0] + Roi[2, 1] * sref[1] + Roi[2, 2] * sref[2]
        s0 = (a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3) * so0 + 2 * (a1 * a2 + a0 * a3) * so1 + 2 * (a1 * a3 - a0 * a2) * so2
        s1 = 2 * (a1 * a2 - a0 * a3) * so0 + (a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3) * so1 + 2 * (a2 * a3 + a0 * a1) * so2
        s2 = 2 * (a1 * a3 + a0 * a2) * so0 + 2 * (a2 * a3 - a0 * a1) * so1 + (a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3) * so2
        ns = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        s0, s1, s2 = s0 / ns, s1 / ns, s2 / ns
        sd = eio.sun_std[b]
        if sd > 0:  # exp([std n]x) s, Rodrigues (design.sensors.sun_sensor)
            nz = eio.aux[b, k - noise_k0]
            t0, t1, t2 = sd * nz[0], sd * nz[1], sd * nz[2]
            ang = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            d = ang if ang > 0 else 1.0
            k0, k1, k2 = t0 / d, t1 / d, t2 / d
            c, sn = math.cos(ang), math.sin(ang)
            ks = k0 * s0 + k1 * s1 + k2 * s2
            r0 = s0 * c + (k1 * s2 - k2 * s1) * sn + k0 * ks * (1.0 - c)
            r1 = s1 * c + (k2 * s0 - k0 * s2) * sn + k1 * ks * (1.0 - c)
            r2 = s2 * c + (k0 * s1 - k1 * s0) * sn + k2 * ks * (1.0 - c)
            nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            s0, s1, s2 = r0 / nr, r1 / nr, r2 / nr
        sm[0], sm[1], sm[2] = s0, s1, s2
    was_started = est.started[b]
    nis_m, nis_s = stream_step(est, b, mag, bref, lit, sm, sref)
    est.w_prev[b, 0], est.w_prev[b, 1], est.w_prev[b, 2] = wm0, wm1, wm2
    qe = np.zeros(4)
    rate = np.zeros(3)
    if not est.started[b]:
        eio.no_att[b] += 1
        return False, qe, rate
    valid = valid_step(est, b, nis_m)  # not valid (validity gate): flown as no estimate, recorded as one
    if eio.wp.size:
        _watch(est, eio, b, k, nis_m, nis_s, not was_started, valid, wm0, wm1, wm2, held)
    if not valid:
        eio.no_att[b] += 1
    qe = matrix_quat(Roi @ rotation(est.q[b]))
    rate[0], rate[1], rate[2] = wm0 - est.b[b, 0], wm1 - est.b[b, 1], wm2 - est.b[b, 2]
    if full:  # dtheta with q_true = q_est (x) exp(dtheta/2) (onboard.mekf.attitude_error)
        e0 = qe[0] * a0 + qe[1] * a1 + qe[2] * a2 + qe[3] * a3
        e1 = qe[0] * a1 - qe[1] * a0 - qe[2] * a3 + qe[3] * a2
        e2 = qe[0] * a2 + qe[1] * a3 - qe[2] * a0 - qe[3] * a1
        e3 = qe[0] * a3 - qe[1] * a2 + qe[2] * a1 - qe[3] * a0
        if e0 < 0:
            e0, e1, e2, e3 = -e0, -e1, -e2, -e3
        sv = math.sqrt(e1 * e1 + e2 * e2 + e3 * e3)
        f = 2.0 if sv < 1e-12 else 2.0 * math.atan2(sv, e0) / sv
        dth = np.array([f * e1, f * e2, f * e3])
        Ptt = est.P[b, :3, :3].copy()
        for i in range(3):
            eio.err[b, k, i] = dth[i]
            eio.sig[b, k, i] = math.sqrt(Ptt[i, i])
        eio.nees[b, k] = dth @ np.linalg.solve(Ptt, dth)
    if r >= 0:
        for i in range(4):
            eio.Qe[b, r, i] = est.q[b, i]
        for i in range(3):
            eio.be[b, r, i] = est.b[b, i]
            eio.me[b, r, i] = est.mb[b, i]
        for i in range(9):
            for j in range(9):
                eio.Pe[b, r, i, j] = est.P[b, i, j]
    return valid, qe, rate


@njit(cache=True, error_model="numpy")
def closed_loop(y, chunk, plant, ctrl, sens, out, modes, est, eio, fk):
    """Controller steps ``chunk.ka .. chunk.kb-1`` (<= n) of every run (the loop of ``batch.simulate_batch``).

    Parameters
    ----------
    y : ndarray (7, B)
        State (quaternion, body rate) of every run, updated in place.
    chunk : Chunk
        The steps and the environment rows on the RK4 stage grid (``per`` rows per step from ``kc`` on).
    plant : Plant
    ctrl : Controller
    sens : Sensors
    out : Outputs
        Accumulates sat/weak/diverged, writes the per-step series (``full``) and the recorded
        instants (``rec_slot[k] >= 0``).
    modes : Modes
        With ``on``: the mode machine's state per run (updated), the law per mode (DETUMBLE: B-dot,
        ACQUISITION and POINTING: eq. 17, SAFE: zero dipole) and the mode series (``full``).
    est : onboard.mekf_kernel.KernelMekf
        With ``on``: the MEKF of every run (updated); the controller reads its estimate (zero dipole before
        the coarse fix) instead of the truth plus attitude noise.
    eio : EstimatorIO
        The estimator's reference rows, auxiliary normals and outputs.
    fk : sim.fault_kernels.KernelFaults
        Injected faults (none: F = 0): the sensor kinds on the measurements, the torquer kinds on the applied
        dipole (the commanded one is recorded and counted).
    """
    table, idx, kc, ka, kb, n, per, levels, thr, hs = chunk
    I, J, hw, mres, gg, drag, srp, A, cp, cd, es, ed = plant
    K, lim, W0, min_b2, cscale, wts = ctrl
    noisy, noise, noise_k0, mag_bias, mag_std, quantum, mag_on, mag_M, att_std, gyro_avg, gyro_white, coupled, Cg, \
        m_last = sens
    sat, weak, diverged, diverged_rate, full, ang_all, mn_all, rec_slot, Q, Wr, X, M, Bb, sat_all = out
    mon, MP, bk, bnorm, bmin, fa, mts = modes.on, modes.P, modes.k, modes.normalized, modes.min_field, modes.a, modes.ts
    B, top = y.shape[1], levels.size - 1
    ys = np.empty(7)
    yt = np.empty(7)
    k1 = np.empty(7)
    k2 = np.empty(7)
    k3 = np.empty(7)
    k4 = np.empty(7)
    for b in range(B):
        tab = table[idx[b]]
        Ib, Jb, mr = I[b], J[b], mres[:, b]
        for j in range(7):
            ys[j] = y[j, b]
        for k in range(ka, kb):
            base = (k - kc) * per
            q0, q1, q2, q3 = ys[0], ys[1], ys[2], ys[3]
            nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            a0, a1, a2, a3 = q0 / nq, q1 / nq, q2 / nq, q3 / nq
            fo0, fo1, fo2 = tab[base, 3], tab[base, 4], tab[base, 5]
            bt0 = (a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3) * fo0 + 2 * (a1 * a2 + a0 * a3) * fo1 \
                + 2 * (a1 * a3 - a0 * a2) * fo2
            bt1 = 2 * (a1 * a2 - a0 * a3) * fo0 + (a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3) * fo1 \
                + 2 * (a2 * a3 + a0 * a1) * fo2
            bt2 = 2 * (a1 * a3 + a0 * a2) * fo0 + 2 * (a2 * a3 - a0 * a1) * fo1 \
                + (a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3) * fo2
            qm0, qm1, qm2, qm3 = q0, q1, q2, q3
            wm0, wm1, wm2 = ys[4], ys[5], ys[6]
            bm0, bm1, bm2 = bt0, bt1, bt2
            if coupled:  # the field at the magnetometer: + g C m_last (onboard.torquers.Torquers.field)
                ml0, ml1, ml2 = m_last[0, b], m_last[1, b], m_last[2, b]
                bm0 = bt0 + (Cg[0, 0] * ml0 + Cg[0, 1] * ml1 + Cg[0, 2] * ml2)
                bm1 = bt1 + (Cg[1, 0] * ml0 + Cg[1, 1] * ml1 + Cg[1, 2] * ml2)
                bm2 = bt2 + (Cg[2, 0] * ml0 + Cg[2, 1] * ml1 + Cg[2, 2] * ml2)
            if noisy:
                nz = noise[b, k - noise_k0]
                if mag_on:  # b_m = M b + bias + std n (design.sensors.magnetometer)
                    Mb = mag_M[b]
                    c0, c1, c2 = bm0, bm1, bm2
                    bm0 = Mb[0, 0] * c0 + Mb[0, 1] * c1 + Mb[0, 2] * c2
                    bm1 = Mb[1, 0] * c0 + Mb[1, 1] * c1 + Mb[1, 2] * c2
                    bm2 = Mb[2, 0] * c0 + Mb[2, 1] * c1 + Mb[2, 2] * c2
                bm0 = bm0 + mag_bias[0, b] + mag_std[b] * nz[0]
                bm1 = bm1 + mag_bias[1, b] + mag_std[b] * nz[1]
                bm2 = bm2 + mag_bias[2, b] + mag_std[b] * nz[2]
                if quantum != 0.0:
                    bm0 = np.rint(bm0 / quantum) * quantum
                    bm1 = np.rint(bm1 / quantum) * quantum
                    bm2 = np.rint(bm2 / quantum) * quantum
                th0, th1, th2 = att_std[b] * nz[3], att_std[b] * nz[4], att_std[b] * nz[5]
                ang = math.sqrt(th0 * th0 + th1 * th1 + th2 * th2)
                s = math.sin(ang / 2) / ang if ang > 0 else 0.5
                p0, p1, p2, p3 = math.cos(ang / 2), s * th0, s * th1, s * th2
                qm0 = q0 * p0 - q1 * p1 - q2 * p2 - q3 * p3
                qm1 = q0 * p1 + q1 * p0 + q2 * p3 - q3 * p2
                qm2 = q0 * p2 - q1 * p3 + q2 * p0 + q3 * p1
                qm3 = q0 * p3 + q1 * p2 - q2 * p1 + q3 * p0
                ga = gyro_avg[b, k - noise_k0]  # Farrenkopf gyro (design.sensors.gyro)
                wm0 = ys[4] + ga[0] + gyro_white[b] * nz[6]
                wm1 = ys[5] + ga[1] + gyro_white[b] * nz[7]
                wm2 = ys[6] + ga[2] + gyro_white[b] * nz[8]
            sun_lost = False
            if fk.kind.size:  # injected sensor faults (design.faults.measure)
                fb, fw = np.array([bm0, bm1, bm2]), np.array([wm0, wm1, wm2])
                sun_lost = sensor_faults(fk, k * fk.ts, fb, fw)
                bm0, bm1, bm2, wm0, wm1, wm2 = fb[0], fb[1], fb[2], fw[0], fw[1], fw[2]
            have = True
            if est.on:  # the controller flies the estimate (attitude_estimator node), not the truth plus noise
                have, qe, re = _estimate(est, eio, idx[b], b, rec_slot[k], k, kc, noise_k0, a0, a1, a2, a3, fo0, fo1,
                                         fo2, bm0, bm1, bm2, wm0, wm1, wm2, full, sun_lost,
                                         mon and modes.mode[b] != _PNT)
                if eio.tw_on:  # the node's watch_torquers: a valid estimate in the modes of torquer_watch.watch_mode (the
                    # mode before this step's decision: the manager's last) or without modes, a command the step before
                    md = modes.mode[b]
                    eio.tw_armed[b] = (eio.tw_armed[b] or md == _PNT) and md != _DET and md != _SAFE
                    _record_watch(eio, b, k, have and k > 0 and (not mon or md == _PNT or (md == _ACQ and eio.tw_armed[b])),
                                  qe, re, bm0, bm1, bm2)
                qm0, qm1, qm2, qm3 = qe[0], qe[1], qe[2], qe[3]
                wm0, wm1, wm2 = re[0], re[1], re[2]
            sg = -1.0 if qm0 < 0.0 else 1.0
            x0, x1, x2, x3, x4, x5 = sg * qm1, sg * qm2, sg * qm3, wm0, wm1, wm2 + W0[b]
            # projection controller m = sat(S(b)^T K x / |b|^2) (paper eq. 17), weak-field guard
            b2 = bm0 * bm0 + bm1 * bm1 + bm2 * bm2
            ok = b2 >= min_b2
            Kb = K[b]
            u0 = Kb[0, 0] * x0 + Kb[0, 1] * x1 + Kb[0, 2] * x2 + Kb[0, 3] * x3 + Kb[0, 4] * x4 + Kb[0, 5] * x5
            u1 = Kb[1, 0] * x0 + Kb[1, 1] * x1 + Kb[1, 2] * x2 + Kb[1, 3] * x3 + Kb[1, 4] * x4 + Kb[1, 5] * x5
            u2 = Kb[2, 0] * x0 + Kb[2, 1] * x1 + Kb[2, 2] * x2 + Kb[2, 3] * x3 + Kb[2, 4] * x4 + Kb[2, 5] * x5
            m0 = (bm1 * u2 - bm2 * u1) / b2
            m1 = (bm2 * u0 - bm0 * u2) / b2
            m2 = (bm0 * u1 - bm1 * u0) / b2
            s0 = min(max(m0, -lim[0, b]), lim[0, b])
            s1 = min(max(m1, -lim[1, b]), lim[1, b])
            s2 = min(max(m2, -lim[2, b]), lim[2, b])
            md = -1
            d0 = d1 = d2 = 0.0
            if mon:  # the mode machine on the measurements (modes_loop.simulate_modes' order: decide, then command)
                fp = modes.fb[b]  # the previous sample: the frozen-magnetometer guard's |b_k - b_(k-1)|
                fst = math.nan if modes.first[b] else math.sqrt((bm0 - fp[0]) ** 2 + (bm1 - fp[1]) ** 2
                                                                + (bm2 - fp[2]) ** 2)
                d0, d1, d2 = filter_step(fa, mts, modes.first[b], modes.fb[b], modes.fy[b], bm0, bm1, bm2)
                modes.first[b] = False
                t = k * mts
                old = modes.mode[b]
                err = 2.0 * math.asin(min(math.sqrt(x0 * x0 + x1 * x1 + x2 * x2), 1.0)) if have else math.nan
                md = mode_step(old, modes.pending[b], math.sqrt(wm0 * wm0 + wm1 * wm1 + wm2 * wm2),
                               math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), err, False, t, MP, fst, False, have)
                if md != old:
                    modes.n_tr[b] += 1
                    if old == _DET and math.isnan(modes.t_detumble[b]):
                        modes.t_detumble[b] = t
                    if md == _PNT and math.isnan(modes.t_pointing[b]):
                        modes.t_pointing[b] = t
                modes.mode[b] = md
                if full:
                    modes.mode_all[b, k] = md
            if md == _DET:  # B-dot rate damping (onboard.bdot.BdotController)
                s0, s1, s2, wk, st = bdot_dipole(bm0, bm1, bm2, d0, d1, d2, bk[b], bnorm, bmin, lim[0, b], lim[1, b],
                                                 lim[2, b])
                if wk:
                    weak[b] += 1
                elif st:
                    sat[b] += 1
                    if full:
                        sat_all[b, k] = True
            elif md == _SAFE:
                s0 = s1 = s2 = 0.0
            elif not have:  # no estimate yet: zero dipole (the controller node's no_attitude)
                s0 = s1 = s2 = 0.0
            elif ok:
                if s0 != m0 or s1 != m1 or s2 != m2:
                    sat[b] += 1
                    if full:
                        sat_all[b, k] = True
            else:
                weak[b] += 1
                s0 = s1 = s2 = 0.0
            if cscale != 1.0:  # the duty cycle's compensation: drive m / c (onboard.torquers.Torquers.drive)
                s0, s1, s2 = s0 / cscale, s1 / cscale, s2 / cscale
            if eio.tw_on and k < n:  # the command as published (the controller node's drive), the next step's m_prev
                eio.tw_m[b, k + 1, 0], eio.tw_m[b, k + 1, 1], eio.tw_m[b, k + 1, 2] = s0, s1, s2
            p0, p1, p2 = s0, s1, s2  # the dipole the body gets (injected torquer faults: design.faults.actuate)
            if fk.kind.size:
                fm = np.array([s0, s1, s2])
                torquer_faults(fk, k * fk.ts, fm, m_last[:, b].copy(), k == 0)
                p0, p1, p2 = fm[0], fm[1], fm[2]
            m_last[0, b], m_last[1, b], m_last[2, b] = p0, p1, p2
            if full:
                ang_all[b, k] = math.sqrt(a1 * a1 + a2 * a2 + a3 * a3)
                mn_all[b, k] = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            r = rec_slot[k]
            if r >= 0:
                for j in range(4):
                    Q[b, r, j] = ys[j]
                for j in range(3):
                    Wr[b, r, j] = ys[4 + j]
                X[b, r, 0], X[b, r, 1], X[b, r, 2], X[b, r, 3], X[b, r, 4], X[b, r, 5] = x0, x1, x2, x3, x4, x5
                M[b, r, 0], M[b, r, 1], M[b, r, 2] = s0, s1, s2
                Bb[b, r, 0], Bb[b, r, 1], Bb[b, r, 2] = bt0, bt1, bt2
            if k == n:
                break
            # sample and hold over [t_k, t_k+1): the fewest RK4 steps of the ladder that cover |w| (Substeps.at),
            # their stage rows every r-th row of the finest grid
            w2 = ys[4] * ys[4] + ys[5] * ys[5] + ys[6] * ys[6]
            lv = 0
            while lv < top and w2 > thr[lv]:
                lv += 1
            S, h = levels[lv], hs[lv]
            r = levels[top] // S
            hh, h6 = 0.5 * h, h / 6.0
            for i in range(S):
                j0 = base + 2 * r * i
                Ea, Eb, Ec = tab[j0], tab[j0 + r], tab[j0 + 2 * r]
                wi = wts[lv, i]  # the duty cycle: the driven dipole's share of this RK4 step (1: always on)
                e0, e1, e2 = p0 * wi, p1 * wi, p2 * wi
                _rhs(Ea, ys, e0, e1, e2, Ib, Jb, hw, mr, gg, drag, srp, A, cp, cd, es, ed, k1)
                for j in range(7):
                    yt[j] = ys[j] + hh * k1[j]
                _rhs(Eb, yt, e0, e1, e2, Ib, Jb, hw, mr, gg, drag, srp, A, cp, cd, es, ed, k2)
                for j in range(7):
                    yt[j] = ys[j] + hh * k2[j]
                _rhs(Eb, yt, e0, e1, e2, Ib, Jb, hw, mr, gg, drag, srp, A, cp, cd, es, ed, k3)
                for j in range(7):
                    yt[j] = ys[j] + h * k3[j]
                _rhs(Ec, yt, e0, e1, e2, Ib, Jb, hw, mr, gg, drag, srp, A, cp, cd, es, ed, k4)
                for j in range(7):
                    ys[j] = ys[j] + h6 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
            nq = math.sqrt(ys[0] * ys[0] + ys[1] * ys[1] + ys[2] * ys[2] + ys[3] * ys[3])
            for j in range(4):
                ys[j] = ys[j] / nq
            bad = False
            for j in range(7):
                if not math.isfinite(ys[j]):
                    bad = True
            for j in range(4, 7):
                if abs(ys[j]) > diverged_rate:
                    bad = True
            if bad:
                diverged[b] = True
        for j in range(7):
            y[j, b] = ys[j]
