"""General linear time-periodic (LTP) analysis: knows no satellite, imports nothing else
from magtune_core.

Paper section 2: transition and monodromy matrices, characteristic multipliers and stability
(eqs. 1-4, Theorem 2.1) in :mod:`.system`; the exact H-infinity norm by the periodic bounded
real lemma (eq. 21's norm) in :mod:`.hinf`, its exact gradient in :mod:`.hinf_gradient`; the harmonic transfer function (eqs. 5-10) in
:mod:`.htf`; the periodic H2 norm (eq. 29, standard reading) in :mod:`.h2`; the peak-to-peak
gain (eq. 29, literal reading) in :mod:`.peak`; batched matrix exponentials in :mod:`.expm`.

Public API::

    from magtune_core.ltp import LTPSystem, multipliers, hinfnorm, h2norm
"""
from .expm import expm
from .h2 import h2norm, periodic_gramian
from .hinf import gamma_test, hinfnorm
from .hinf_gradient import HinfGradient, hinfnorm_gradient
from .htf import htf_hinfnorm, htf_system, lti_hinfnorm
from .peak import peak_to_peak
from .system import DEFAULT_STEPS, LTPSystem, interval_transitions, is_stable, monodromy, multipliers, spectral_radius

__all__ = [
    "DEFAULT_STEPS", "HinfGradient", "LTPSystem", "expm", "gamma_test", "h2norm", "hinfnorm", "hinfnorm_gradient", "htf_hinfnorm", "htf_system",
    "interval_transitions", "is_stable", "lti_hinfnorm", "monodromy", "multipliers", "peak_to_peak",
    "periodic_gramian", "spectral_radius",
]
