"""General linear time-periodic (LTP) analysis: knows no satellite, imports nothing else
from magtune_core.

Paper section 2: transition and monodromy matrices, characteristic multipliers and stability
(eqs. 1-4, Theorem 2.1) in :mod:`.system`; the exact H-infinity norm by the periodic bounded
real lemma (eq. 21's norm) in :mod:`.hinf`, its exact gradient in :mod:`.hinf_gradient`; the harmonic transfer function (eqs. 5-10) in
:mod:`.htf`; the periodic H2 norm (eq. 29, standard reading) in :mod:`.h2`; the peak-to-peak
gain (eq. 29, literal reading) in :mod:`.peak`; batched matrix exponentials in :mod:`.expm`.

Public API::

    from magtune_core.ltp import LTPSystem, multipliers, hinfnorm, h2norm

Example (run by ``tests/ltp/test_doctest.py``): the lightly damped oscillator
G(s) = 1 / (s^2 + 2 zeta s + 1) is the LTI special case of an LTP system (constant matrices, any
period). Its H-infinity norm is the resonance peak 1 / (2 zeta sqrt(1 - zeta^2)), its characteristic
multipliers over T = 2 pi are exp(T eig(A)), of modulus exp(-zeta T) (Theorem 2.1: stable), and its
H2 norm is sqrt(1 / (4 zeta)):

>>> import numpy as np
>>> from magtune_core.ltp import LTPSystem, h2norm, hinfnorm, multipliers
>>> zeta = 0.1
>>> G = LTPSystem(A=[[0.0, 1.0], [-1.0, -2 * zeta]], B=[[0.0], [1.0]], C=[[1.0, 0.0]], period=2 * np.pi)
>>> print(f"{float(hinfnorm(G, rtol=1e-9)):.6f}  {1 / (2 * zeta * np.sqrt(1 - zeta**2)):.6f}")
5.025189  5.025189
>>> print(f"{np.abs(multipliers(G)).max():.6f}  {np.exp(-zeta * 2 * np.pi):.6f}")
0.533488  0.533488
>>> print(f"{float(h2norm(G)):.6f}  {np.sqrt(1 / (4 * zeta)):.6f}")
1.581139  1.581139
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
