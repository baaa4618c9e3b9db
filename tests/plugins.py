"""Disturbance plug-ins used by the tests (imported by the simulator node as 'tests.plugins:...')."""
from magtune_core.dynamics import residual_dipole_torque


def residual_dipole_x2(params):
    """Factory: SpacecraftParams -> torque(t, q, w, b) = [2, 2, 2] x b."""
    return residual_dipole_torque([2.0, 2.0, 2.0])
