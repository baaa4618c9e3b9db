"""The SIL scenario (magtune_core.ros.scenario): every input file read once, validated before any
process starts, the orbit period derived once, one parameter file per node that carries exactly
what the node needs (no ROS process is started here)."""
from __future__ import annotations

import numpy as np
import pytest

from magtune_core.base import paramfile
from magtune_core.base.errors import ConfigError
from magtune_core.design.gains import Gains, load_gains
from magtune_core.design.node_params import SIMULATOR_FIELDS
from magtune_core.design.params import SpacecraftParams, load_spacecraft
from magtune_core.env.orbit import keplerian_period
from magtune_core.ros.scenario import DEFAULT_SPACECRAFT, SilRequest, SilScenario
from magtune_core.sim.fullenv import FullEnvironmentOptions, full_params

GAINS = [DEFAULT_SPACECRAFT.parents[0] / "gains" / f"sigma_{s}.yaml" for s in (60, 240)]


def test_each_file_read_once_and_node_files_carry_the_validated_values(tmp_path, monkeypatch):
    reads: dict = {}
    load = paramfile._load

    def counting(path):
        reads[str(path)] = reads.get(str(path), 0) + 1
        return load(path)

    monkeypatch.setattr(paramfile, "_load", counting)
    sc = SilScenario.build({"sat1": GAINS[0], "/sat2": GAINS[1]}, SilRequest(steps=10, log_dir=tmp_path))
    assert reads == {str(DEFAULT_SPACECRAFT): 1, str(GAINS[0]): 1, str(GAINS[1]): 1}
    assert [s.namespace for s in sc.satellites] == ["/sat1", "/sat2"] and sc.multi
    for sat, gfile in zip(sc.satellites, GAINS):
        files = sc.write_parameter_files(sat, tmp_path, sc.results_path(sat, tmp_path))
        assert sorted(files) == ["attitude_sensors", "controller", "simulator"]
        for node, f in files.items():
            params = paramfile.check_ros_params(f, f"{sat.namespace}/{node}")
            # the node reads the spacecraft file's values and the period derived by the runner, bit for bit
            p = SpacecraftParams.from_mapping(params)
            ref = load_spacecraft(DEFAULT_SPACECRAFT)
            assert p.orbit_period == ref.orbit_period and np.array_equal(p.inertia, ref.inertia)
            assert params["ts"] == sat.ts and params["use_sim_time"] is True
        ctl = paramfile.check_ros_params(files["controller"], f"{sat.namespace}/controller")
        g = Gains.from_mapping(ctl)
        assert np.array_equal(g.K, load_gains(gfile).K) and g.provenance["J"] == load_gains(gfile).provenance["J"]
        sim = paramfile.check_ros_params(files["simulator"], f"{sat.namespace}/simulator")
        assert sim["steps"] == 10 and set(sim) - {"use_sim_time"} <= {f.name for f in SIMULATOR_FIELDS} | {
            f.name for f in SpacecraftParams.FIELDS}
        assert "gain" not in sim  # the gains go to the controller only


def test_full_environment_period_derived_once_for_every_node(tmp_path):
    sc = SilScenario.build({"": GAINS[0]}, SilRequest(steps=5, environment="full"))
    want = full_params(load_spacecraft(DEFAULT_SPACECRAFT), FullEnvironmentOptions()).orbit_period
    assert sc.spacecraft.orbit_period == want != keplerian_period(sc.spacecraft.altitude)
    sat = sc.satellites[0]
    for node, f in sc.write_parameter_files(sat, tmp_path, tmp_path / "r.npz").items():
        assert paramfile.check_ros_params(f, node)["orbit_period"] == want


@pytest.mark.parametrize("kwargs, field", [
    (dict(steps=0), "--steps"), (dict(ts=-1.0), "--ts"), (dict(substeps=0), "--substeps"),
    (dict(bag_exclude="("), "--bag-exclude"), (dict(foxglove=70000), "--foxglove"),
    (dict(bag_topics=["/clock"]), "--bag-topics/--bag-exclude"),
])
def test_bad_input_is_one_config_error_before_anything_is_written(tmp_path, kwargs, field):
    logs = tmp_path / "logs"
    with pytest.raises(ConfigError) as exc:
        SilScenario.build({"": GAINS[0]}, SilRequest(log_dir=logs, **kwargs))
    assert str(exc.value).startswith(field) and "\n" not in str(exc.value)
    assert not logs.exists()


def test_tle_file_reaches_the_nodes_as_its_lines(tmp_path):
    """A spacecraft file with a relative tle_file (the 12U example's): each node's parameter file (in the log
    directory, far from the TLE file) carries the TLE's lines, and the node's reading of it - without the
    spacecraft file's directory - is the runner's orbit bit for bit (SGP4's state at the epoch, the period)."""
    example = DEFAULT_SPACECRAFT.parent / "examples" / "cubesat12u"
    sc = SilScenario.build({"": GAINS[0]}, SilRequest(steps=5, environment="full",
                                                      spacecraft=example / "spacecraft_tle.yaml"))
    assert sc.spacecraft.tle is not None and sc.spacecraft.tle_field == "tle_file"
    for node, f in sc.write_parameter_files(sc.satellites[0], tmp_path, tmp_path / "r.npz").items():
        params = paramfile.check_ros_params(f, node)
        assert "tle_file" not in params and params["tle"][1:] == [sc.spacecraft.tle.line1, sc.spacecraft.tle.line2]
        p = SpacecraftParams.from_mapping(params, f"node '{node}'")
        assert p.state0 == sc.spacecraft.state0 and p.epoch == sc.spacecraft.epoch
        assert p.orbit_period == sc.spacecraft.orbit_period and p.orbit_config() == sc.spacecraft.orbit_config()


def test_viewer_outputs_only_where_something_can_read_them(tmp_path):
    """/tf, sim/markers and sim/*_torque: off in a run on its own domain with no bag and no live view, on with
    any of a bag, the live view, a domain the user chose; the spacecraft file's simulator section wins."""
    keys = ("publish_tf", "publish_markers", "publish_torques")

    def sim(sc_path=DEFAULT_SPACECRAFT, **kw):
        sc = SilScenario.build({"": GAINS[0]}, SilRequest(steps=5, spacecraft=sc_path, **kw))
        p = sc.node_parameters(sc.satellites[0], tmp_path / "r.npz")["simulator"]
        return tuple(p.get(k, True) for k in keys)  # absent: the node's default (true)

    assert sim() == (False, False, False)
    assert sim(bag=tmp_path / "bag") == (True, True, True)
    assert sim(foxglove=0) == (True, True, True)
    assert sim(domain_id=42) == (True, True, True)
    own = tmp_path / "spacecraft.yaml"
    own.write_text(DEFAULT_SPACECRAFT.read_text() + "/**/simulator:\n  ros__parameters:\n    publish_tf: true\n")
    assert sim(own) == (True, False, False)
