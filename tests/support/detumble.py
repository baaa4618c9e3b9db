"""A saturated B-dot detumble from 5 deg/s per axis (paper environment) and its DOP853 replay: the
reference the RK4 sub-step tests measure against (tests/sim/test_initial.py, tests/sim/test_substeps.py)."""
import math

import numpy as np
from scipy.integrate import solve_ivp

from magtune_core.base.rotations import quat_mul
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain
from magtune_core.sim.dynamics import AttitudeDynamics
from magtune_core.sim.initial import initial_conditions
from magtune_core.sim.simulate import initial_state


def tumble():
    """(dyn, y0): the paper set-up's dynamics and a 5-deg/s-per-axis tumble at an arbitrary attitude."""
    p = SpacecraftParams()
    q0, dw0 = initial_conditions((40.0, -70.0, 100.0), (5.0, 5.0, 5.0))
    return AttitudeDynamics.from_params(p), initial_state(p, dw0, q0)


def rk4_run(dyn, y0, n, choose, dipoles=None):
    """n periods of 1 s with ``choose(y)`` RK4 sub-steps; B-dot at 50 A m^2 (the Avanzini-Giulietti gain)
    unless ``dipoles`` replays a dipole sequence. Returns (Y (n+1, 7), M (n, 3), sub-steps (n,))."""
    ctrl = BdotController(bdot_gain(dyn.orbit_rate, math.pi / 2, SpacecraftParams().inertia), 50.0)
    filt = FieldDerivativeFilter(1.0, 0.2)
    y, st, Y, M, L = y0.copy(), FilterState(), [y0], [], []
    for k in range(n):
        if dipoles is None:
            b = dyn.body_field(float(k), y[:4])
            st, bdot = filt.step(st, b)
            m = ctrl.dipole(b, bdot)
        else:
            m = dipoles[k]
        M.append(m)
        L.append(choose(y))
        y = dyn.step(float(k), y, 1.0, m, L[-1])
        Y.append(y)
    return np.array(Y), np.array(M), np.array(L)


def dop853_run(dyn, y0, dipoles):
    """The same held dipoles integrated by DOP853 at rtol 1e-12 per hold interval: (n+1, 7)."""
    ref, y = [y0], y0.copy()
    for k, m in enumerate(dipoles):
        sol = solve_ivp(lambda t, yy, m=m: dyn.rhs(t, yy, m), (float(k), k + 1.0), y, method="DOP853",
                        rtol=1e-12, atol=1e-14)
        y = sol.y[:, -1]
        y[:4] /= np.linalg.norm(y[:4])
        ref.append(y)
    return np.array(ref)


def angle(qa, qb):
    """Rotation angle [rad] between attitudes (2 asin |vec(qa* qb)|: no arccos loss near 0)."""
    d = np.array([quat_mul(np.r_[a[0], -a[1:]], b) for a, b in zip(qa, qb)])
    return 2.0 * np.arcsin(np.minimum(np.linalg.norm(d[:, 1:], axis=1), 1.0))
