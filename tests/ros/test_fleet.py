"""Two satellites side by side in one ROS domain, namespaces /sat1 and /sat2, each with its own
gains and clock, recorded in one bag (real nodes over real DDS, separate processes).

Each satellite must reproduce the offline simulation of its own gain exactly, and the bag must
hold both satellites' topics, with each dipole stream equal to that satellite's trajectory (so
neither controller picked up the other's gains or inputs). Domain: DomainLock (run_fleet),
every process stopped in run_fleet's ``finally`` (checked).
"""
from __future__ import annotations

import numpy as np
import pytest

from magtune_core import bags as baglib
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.base.rotations import rotation_matrix
from magtune_core.design.gains import load_gains, save_gains
from magtune_core.design.lq import lq_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.ros import sil
from magtune_core.ros.scenario import SilRequest, SilScenario
from magtune_core.sim.simulate import simulate
from magtune_core.studies import report

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]


STEPS = 150


def test_two_namespaced_satellites_one_bag(tmp_path):
    model = AttitudeLTP.from_params(SpacecraftParams())
    files = {}
    for ns, sigma in (("sat1", 60.0), ("/sat2", 240.0)):  # both spellings of a namespace
        files[ns] = tmp_path / f"gains_{sigma:g}.yaml"
        save_gains(files[ns], lq_gains(model, sigma, 1.0))
    procs = []
    bag = tmp_path / "two"
    fleet = SilScenario.build(files, SilRequest(steps=STEPS, bag=bag, log_dir=tmp_path / "logs", timeout=180))
    runs = sil.run_fleet(fleet, on_start=lambda did, ps: procs.extend(ps))
    assert sorted(runs) == ["/sat1", "/sat2"]
    assert len(procs) == 7 and all(p.popen.poll() is not None for p in procs)  # 2 x 3 nodes + recorder
    assert (tmp_path / "logs" / "sat1_controller.log").is_file() and (tmp_path / "logs" / "sat2_simulator.log").is_file()

    dec = Decoder()
    for ns, key in (("/sat1", "sat1"), ("/sat2", "/sat2")):
        run = runs[ns]
        assert run.counters["missed_steps"] == 0
        off = simulate(load_gains(files[key]).K, SpacecraftParams(), steps=STEPS, substeps=2)
        # same float64 operations on both sides (see test_sil_one_orbit_matches_offline): 1e-9 bounds zero
        assert np.max(np.abs(run.result.x - off.x)) <= 1e-9 and np.max(np.abs(run.result.m - off.m)) <= 1e-9
        # the bag's dipole stream of this namespace is this satellite's command sequence
        m = {stamp_ns(o := dec.decode(msg.data, msg.type)): (o.vector.x, o.vector.y, o.vector.z)
             for msg in baglib.iter_messages(bag, topics=[f"{ns}/controller/dipole_command"])}
        assert len(m) == STEPS + 1
        t_ns = np.round(run.result.t * 1e9).astype(np.int64)
        rec = np.array([m[int(t)] for t in t_ns])
        assert np.array_equal(rec, run.result.m)  # float64 through CDR unchanged
        # REP-105 truth: Odometry twist = rate w.r.t. the orbital frame, inertial rate on its own topic
        tw, wi = {}, {}
        for msg in baglib.iter_messages(bag, topics=[f"{ns}/sim/truth", f"{ns}/sim/inertial_rate"]):
            o = dec.decode(msg.data, msg.type)
            if msg.topic.endswith("truth"):
                a = o.twist.twist.angular
                tw[stamp_ns(o)] = (a.x, a.y, a.z)
            else:
                wi[stamp_ns(o)] = (o.vector.x, o.vector.y, o.vector.z)
        assert np.array_equal(np.array([wi[int(t)] for t in t_ns]), run.result.w)  # inertial, exact
        w0 = SpacecraftParams().orbit_rate
        rel = np.array([w - rotation_matrix(q).T @ [0.0, 0.0, -w0] for q, w in zip(run.result.q, run.result.w)])
        # one R(q)^T product of O(W0 = 1.1e-3) rounded in another order: 1e-15 rad/s bounds it
        assert np.max(np.abs(np.array([tw[int(t)] for t in t_ns]) - rel)) <= 1e-15
        # the report reads the exact inertial rate, and converting the relative twist agrees
        x_topic = report.load_run(bag, truth=f"{ns}/sim/truth", dipole=f"{ns}/controller/dipole_command").x
        assert np.max(np.abs(x_topic - run.result.x)) <= 1e-12
    # different gains, different commands: sigma = 240 penalizes effort (peak |m| ~4x smaller)
    assert runs["/sat2"].figures["peak_m"] < 0.5 * runs["/sat1"].figures["peak_m"]
    topics = baglib.topics_of(bag)
    for ns in ("/sat1", "/sat2"):
        for t in ("/clock", "/sim/truth", "/sensors/attitude", "/controller/dipole_command"):
            assert topics[ns + t].message_count == STEPS + 1, (ns + t, topics[ns + t])
    assert "/clock" not in topics  # each satellite's clock lives in its namespace
    meta = baglib.read_metadata(bag)["custom_data"]
    assert meta["satellites"] == "/sat1,/sat2" and meta["sat1.sigma"] == "60" and meta["sat2.sigma"] == "240"
