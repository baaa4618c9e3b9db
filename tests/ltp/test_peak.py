"""Peak-to-peak (L-inf-induced) gain against closed-form and finely sampled LTI references."""
import numpy as np
import pytest

from magtune_core.ltp import LTPSystem
from magtune_core.ltp.peak import peak_to_peak


def test_first_order_l1_norm_is_one():
    # g(t) = exp(-t): int |g| = 1; 4 periods of 10 s leave exp(-40); trapezoid error ~ h^2/12
    s = LTPSystem(np.array([[-1.0]]), np.array([[1.0]]), np.array([[1.0]]), None, 10.0)
    assert peak_to_peak(s, steps=2048, periods=4, outputs=4) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.slow
def test_oscillator_l1_norm_matches_fine_quadrature():
    # g(t) = exp(-0.1 t) sin(wd t) / wd: |g| has kinks at zero crossings, reference on 4e6 points
    s = LTPSystem(np.array([[0.0, 1.0], [-1.0, -0.2]]), np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]]), None, 20.0)
    t = np.linspace(0.0, 400.0, 4_000_001)
    wd = np.sqrt(0.99)
    ref = np.trapezoid(np.abs(np.exp(-0.1 * t) * np.sin(wd * t) / wd), t)
    assert peak_to_peak(s, steps=4096, periods=20, outputs=4) == pytest.approx(ref, rel=1e-5)
