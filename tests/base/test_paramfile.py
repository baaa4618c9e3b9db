"""magtune_core.base.paramfile: what rcl's parameter-file parser rejects although PyYAML loads it."""
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import check_ros_params


@pytest.mark.parametrize("value, ok", [
    ("[1.0, 2.5]", True), ("[1, 2]", True), ("[a, b]", True), ("[]", True), ("{a: 1.0}", True),
    ("[1, 2.5]", False), ("[[1.0, 2.0], [3.0, 4.0]]", False), ("[1.0, null]", False), ("[x, y]", False),
])
def test_rcl_rules(tmp_path, value, ok):
    f = tmp_path / "p.yaml"
    f.write_text(f"controller:\n  ros__parameters:\n    gain_meta:\n      x: {value}\n")
    if ok:
        check_ros_params(f)
    else:
        with pytest.raises(ConfigError, match="gain_meta.x"):
            check_ros_params(f)


# ---------------------------------------------------------------- section keys (node-name wildcards)
import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402

from magtune_core.base.paramfile import node_matches, read_ros_params  # noqa: E402
from magtune_core.design.gains import load_gains  # noqa: E402


@pytest.mark.parametrize("key, node, ok", [
    ("/**", "/controller", True), ("/**", "/sat1/controller", True), ("/**", "ctl", True),
    ("controller", "controller", True), ("controller", "/controller", True),
    ("controller", "/sat1/controller", False), ("/controller", "/sat1/controller", False),
    ("/**/controller", "/controller", True), ("/**/controller", "/sat1/controller", True),
    ("/**/controller", "/a/b/controller", True), ("/**/controller", "/sat1/ctl", False),
    ("/*/controller", "/controller", False), ("/*/controller", "/sat1/controller", True),
    ("/*/controller", "/a/b/controller", False), ("/sat*/controller", "/sat2/controller", True),
    ("/sat1/**", "/sat1/controller", True), ("/sat1/**", "/sat2/controller", False),
    ("/**/contr*", "/sat1/controller", True),
])
def test_node_matches_rcl_rules(key, node, ok):
    assert node_matches(key, node) is ok


PROBE = """
import json, sys, rclpy
from rclpy.node import Node
rclpy.init(args=sys.argv)
out = {}
for ns, name in json.loads(sys.argv[1]):
    n = Node(name, namespace=ns, automatically_declare_parameters_from_overrides=True)
    out[n.get_fully_qualified_name()] = {k: p.value for k, p in n._parameters.items()
                                         if k not in ("use_sim_time", "start_type_description_service")}
    n.destroy_node()
print(json.dumps(out))
rclpy.shutdown()
"""


@pytest.mark.ros
def test_section_matching_agrees_with_rclpy(tmp_path):
    """read_ros_params(file, fqn) == the parameters rclpy hands a node of that name/namespace,
    for every kind of section key and conflicting values (file order decides, as in rcl)."""
    pytest.importorskip("rclpy")
    from magtune_core.ros.process import DomainLock

    f = tmp_path / "p.yaml"
    f.write_text("controller:\n  ros__parameters: {a: 3, only_root: 1}\n"
                 "/**:\n  ros__parameters: {a: 1, b: 1, every: 1}\n"
                 "/**/controller:\n  ros__parameters: {b: 2, any_ns: 1}\n"
                 "/*/controller:\n  ros__parameters: {c: 4, one_ns: 1}\n"
                 "/sat1/**:\n  ros__parameters: {c: 5, under_sat1: 1}\n")
    nodes = [["", "controller"], ["/sat1", "controller"], ["/sat2", "controller"], ["/a/b", "controller"],
             ["/sat1", "ctl"], ["", "simulator"]]
    with DomainLock() as lock:
        env = dict(os.environ, ROS_DOMAIN_ID=str(lock.domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        r = subprocess.run([sys.executable, "-c", PROBE, json.dumps(nodes), "--ros-args", "--params-file", str(f)],
                           capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert len(got) == len(nodes)
    for fqn, params in got.items():
        assert read_ros_params(f, fqn) == params, fqn


def test_gains_files_old_and_new_keys(tmp_path):
    """Shipped gains are keyed ``/**`` (any namespace or node name); files keyed ``controller:``
    (written before) and ``/**/controller:`` load to the same gains."""
    from magtune_core.base.ament import ROOT

    shipped = ROOT / "config" / "gains" / "sigma_60.yaml"
    text = shipped.read_text()
    assert "\n/**:\n" in text
    ref = load_gains(shipped)
    for key in ("controller", "/**/controller", "/controller"):
        old = tmp_path / f"{key.replace('/', '_').replace('*', 'x')}.yaml"
        old.write_text(text.replace("\n/**:\n", f"\n{key}:\n"))
        g = load_gains(old)
        assert (g.K == ref.K).all() and g.sigma == ref.sigma and g.ts == ref.ts
    other = tmp_path / "other.yaml"
    other.write_text(text.replace("\n/**:\n", "\n/**/simulator:\n"))
    with pytest.raises(ConfigError, match="'gain'"):
        load_gains(other)


def test_written_gains_load_again(tmp_path):
    """save_gains of an LQ design (provenance design, design_field, start) writes a /**-keyed
    file that load_gains accepts (the strict provenance check must know every key written)."""
    from magtune_core.design.gains import save_gains
    from magtune_core.design.lq import lq_gains
    from magtune_core.design.model import AttitudeLTP
    from magtune_core.design.params import SpacecraftParams

    g = lq_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, 1.0)
    g.provenance["start"] = "LQ of sigma 60"
    f = tmp_path / "g.yaml"
    save_gains(f, g)
    assert "\n/**:\n" in f.read_text()
    back = load_gains(f)
    assert (back.K == g.K).all() and back.provenance["design_field"] == g.provenance["design_field"]
