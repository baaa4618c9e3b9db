"""Disturbance plug-ins used by the tests (imported by the simulator node as 'tests.support.plugins:...')."""
from magtune_core.sim.dynamics import residual_dipole_disturbance


def residual_dipole_x2(params):
    """Factory: SpacecraftParams -> torque(t, q, w, b) = [2, 2, 2] x b."""
    return residual_dipole_disturbance([2.0, 2.0, 2.0])
