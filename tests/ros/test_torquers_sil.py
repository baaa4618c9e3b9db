"""The torquers in the SIL (issue 30 item 6): the simulator publishes their field at the
magnetometer, the sensors add it, the controller duty-cycles and compensates, and the simulator
switches the torquers off on its sub-step grid. The run equals the offline loop with the same
:class:`magtune_core.onboard.torquers.Torquers`.

Isolated as every SIL test: a DomainLock ROS_DOMAIN_ID, LOCALHOST discovery, processes stopped in
``finally`` (magtune_core.ros.sil)."""
import numpy as np
import pytest

from magtune_core.design.gains import load_gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.torquers import Torquers, dipole_coupling
from magtune_core.ros import sil
from magtune_core.sim.simulate import simulate

pytestmark = pytest.mark.ros

C = tuple(dipole_coupling([0.5, 0.2, -0.1]).ravel())  # ~2e-6 T per A m^2: the field moves by up to ~10 %


@pytest.mark.parametrize("tq", [Torquers(C), Torquers(C, off_time=0.2, decay_time=0.1)],
                         ids=["always-on", "duty-cycled"])
def test_sil_with_coupling_and_duty_cycle_equals_offline(gains60, tmp_path, tq):
    n = 400
    values = dict(torquer_coupling=list(tq.coupling), torquer_off_time=tq.off_time, torquer_decay_time=tq.decay_time)
    run = sil.run_sil(gains60, steps=n, ts=1.0, log_dir=tmp_path, timeout=120, torquers=values)
    assert run.counters["missed_steps"] == 0
    off = simulate(load_gains(gains60).K, SpacecraftParams(), steps=n, substeps=2, torquers=tq)
    plain = simulate(load_gains(gains60).K, SpacecraftParams(), steps=n, substeps=2)
    # the same float64 operations on both sides (messages carry float64): 1e-9 is a loose bound on zero,
    # while the torquers move the commands by more than 1e-3 A m^2
    assert np.max(np.abs(run.result.q - off.q)) <= 1e-9 and np.max(np.abs(run.result.m - off.m)) <= 1e-9
    assert np.max(np.abs(off.m - plain.m)) > 1e-3
