"""The batched tuning objective J(K) (design/objective.py) against independent LTI references."""
import numpy as np
import pytest

from magtune_core.design.lq import lq_gain
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.objective import HinfObjective
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import performance_system
from magtune_core.ltp import hinfnorm

SIGMA = 60.0


def constant_model(b=(2e-5, 1e-5, 1.5e-5)):
    return AttitudeLTP.from_params(SpacecraftParams(field_model="constant", constant_field=np.array(b)))


def lti_norm(model, K, sigma):
    """||G_zTd||_inf of the constant-field (LTI) loop by python-control (SLICOT ab13dd)."""
    control = pytest.importorskip("control")
    Acl = model.A + model.B(0.0) @ K
    Cz = np.vstack([np.eye(3, 6), sigma * K])
    return control.linfnorm(control.ss(Acl, model.BT, Cz, np.zeros((6, 3))), tol=1e-10)[0]


@pytest.fixture(scope="module")
def population():
    model = constant_model()
    K = lq_gain(model, SIGMA)
    rng = np.random.default_rng(5)
    return model, K * (1 + 0.2 * rng.standard_normal((4, 3, 6)))


def test_batch_equals_lti_reference(population):
    model, Ks = population
    obj = HinfObjective(model, SIGMA, steps=8, rtol=1e-8)
    J = obj(Ks)
    ref = np.array([lti_norm(model, K, SIGMA) for K in Ks])
    # Magnus is exact for a constant A; bisection bracket 1e-8: 1e-6 leaves room for SLICOT's tol
    assert J == pytest.approx(ref, rel=1e-6)
    assert obj.evaluations == len(Ks)
    # a guess and a narrow first bracket change the levels tested, not the result
    assert obj(Ks, guess=ref.mean(), spread=1.05) == pytest.approx(ref, rel=1e-6)


def test_batch_equals_single_on_the_periodic_model():
    model = AttitudeLTP.from_params(SpacecraftParams())
    K = lq_gain(model, SIGMA)
    rng = np.random.default_rng(2)
    Ks = K * (1 + 0.05 * rng.standard_normal((4, 3, 6)))
    J = HinfObjective(model, SIGMA, steps=32, rtol=1e-7)(Ks, guess=390.0, spread=1.1)
    single = [float(hinfnorm(performance_system(model, k, SIGMA), rtol=1e-7, steps=32)) for k in Ks]
    assert J == pytest.approx(single, rel=3e-7)  # two brackets of 1e-7 around the same norm


def test_unstable_gain_is_inf(population):
    model, Ks = population
    bad = -Ks[0]  # positive feedback: the closed loop diverges
    J = HinfObjective(model, SIGMA, steps=8)(np.stack([Ks[0], bad]))
    assert np.isfinite(J[0]) and np.isinf(J[1])


def test_several_models_take_the_worst(population):
    model, Ks = population
    other = constant_model((1e-5, 2e-5, -1e-5))
    obj = HinfObjective([model, other], SIGMA, steps=8, rtol=1e-8)
    per = obj.per_model(Ks)
    assert per.shape == (len(Ks), 2)
    ref = np.array([[lti_norm(m, K, SIGMA) for m in (model, other)] for K in Ks])
    assert per == pytest.approx(ref, rel=1e-6)
    assert obj(Ks) == pytest.approx(ref.max(axis=1), rel=1e-6)
    assert np.array_equal(obj.worst(Ks), np.argmax(ref, axis=1))


def test_workers_give_the_same_values(population):
    model, Ks = population
    one = HinfObjective(model, SIGMA, steps=8, rtol=1e-8)(Ks)
    with HinfObjective(model, SIGMA, steps=8, rtol=1e-8, workers=2) as obj:
        two = obj(Ks)
    assert np.array_equal(one, two)  # same arithmetic on each slice


def test_pool_workers_hold_the_constants(population):
    """The local pool's parts carry a key, not the models and screens (sent once per worker when it
    starts: 7 MB per part under the default design spec), and give the values of one process."""
    import pickle

    model, Ks = population
    with HinfObjective(model, SIGMA, steps=8, rtol=1e-8, workers=2) as obj:
        two = obj(Ks)
        handle = obj._shared_handle()
        assert len(pickle.dumps(handle)) < 200 < len(pickle.dumps(obj._shared))
        again = obj(Ks)
    assert np.array_equal(two, again)
    assert np.array_equal(two, HinfObjective(model, SIGMA, steps=8, rtol=1e-8)(Ks))
