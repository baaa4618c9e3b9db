"""A node's parameters as a ROS user sees them: the schema's bounds in the descriptors (what
``ros2 param describe`` asks through ``describe_parameters``), the schema's one line for a value out
of range, the Nyquist check of a node started alone, and the one private rclpy attribute we read."""
from __future__ import annotations

import os
import subprocess
import time

import pytest
import yaml

from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import parse_value
from magtune_core.onboard.params import CONTROLLER_FIELDS, SAMPLE_PERIOD
from magtune_core.ros import process, scenario

pytestmark = pytest.mark.ros


def _controller(gains, log, domain_id, *extra):
    """The controller alone, the ``ros2 run`` way: its executable, node name /controller."""
    exe = process.resolve_executable("controller")
    env = process.child_env(domain_id, process.package_prefix())
    return subprocess.Popen([str(exe), "--ros-args", "--params-file", str(scenario.DEFAULT_SPACECRAFT), "--params-file",
                             str(gains), *extra], env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True, preexec_fn=process.die_with_parent())



def test_describe_parameters_shows_the_schema_bounds(gains60, tmp_path):
    """``describe_parameters`` of a controller started alone: ``ts`` has the schema's
    floating_point_range and is read-only; an int-free float field and a list field too."""
    import rclpy
    from rcl_interfaces.srv import DescribeParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    lock = process.DomainLock()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    log = open(tmp_path / "controller.log", "w")
    proc = _controller(gains60, log, lock.domain_id)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=lock.domain_id)
    node = Node("test_describe", context=ctx)
    try:
        cli = node.create_client(DescribeParameters, "/controller/describe_parameters")
        deadline = time.monotonic() + 60.0
        while not cli.wait_for_service(timeout_sec=0.5):
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "controller.log").read_text()
        fut = cli.call_async(DescribeParameters.Request(names=["ts", "min_field", "dipole_limit", "initial_mode"]))
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.spin_until_future_complete(fut, timeout_sec=30.0)
        d = {x.name: x for x in fut.result().descriptors}
        lo, hi = SAMPLE_PERIOD.bounds
        (r,) = d["ts"].floating_point_range
        assert (r.from_value, r.to_value, r.step) == (lo, hi, 0.0) and d["ts"].read_only
        (r,) = d["min_field"].floating_point_range
        assert (r.from_value, r.to_value) == next(f.bounds for f in CONTROLLER_FIELDS if f.name == "min_field")
        assert "[s]" in d["ts"].description or "Ts [s]" in d["ts"].description
        # ranges are for scalars (rclpy applies none to arrays); strings have none
        assert list(d["dipole_limit"].floating_point_range) == [] and list(d["initial_mode"].floating_point_range) == []
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        process.stop_nodes([process.NodeProcess("controller", proc, tmp_path / "controller.log")])
        log.close()
        lock.release()


@pytest.mark.parametrize("case", ["nyquist", "range"])
def test_controller_alone_refuses_with_the_schema_line(gains60, tmp_path, case):
    """Started alone, the controller checks what ``magtune sil`` checks: a ts past Nyquist (the
    paper's spacecraft nutates in 76.6 s) and a value outside the schema's bounds (refused by rclpy
    against the descriptor's range, reported with the schema's own words): one line, exit 2."""
    g = tmp_path / "g.yaml"
    doc = yaml.safe_load(gains60.read_text())
    extra = []
    if case == "nyquist":
        doc[next(iter(doc))]["ros__parameters"]["ts"] = 100.0
    else:
        extra = ["-p", "min_field:=0.5"]
    g.write_text(yaml.safe_dump(doc))
    lock = process.DomainLock()
    try:
        with open(tmp_path / "controller.log", "w") as log:
            proc = _controller(g, log, lock.domain_id, *extra)
            try:
                rc = proc.wait(timeout=60)
            finally:
                process.stop_nodes([process.NodeProcess("controller", proc, tmp_path / "controller.log")])
    finally:
        lock.release()
    out = [x for x in (tmp_path / "controller.log").read_text().splitlines() if x.strip()]
    assert rc == 2 and len(out) == 1, out
    if case == "nyquist":
        assert "parameter 'ts'" in out[0] and "does not resolve the nutation period 76.6 s" in out[0], out
    else:
        f = next(f for f in CONTROLLER_FIELDS if f.name == "min_field")
        with pytest.raises(ConfigError) as exc:
            parse_value(f, 0.5, "cli")
        assert out[0].endswith(f"parameter 'min_field': {exc.value.expected}"), out


def test_parameter_overrides_reads_rclpys_private_store(built_package):
    """rclpy has no public reader of the parameters a node was started with; magtune_ros.params
    reads ``Node._parameter_overrides`` in one place. This fails if rclpy renames or retypes it."""
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from magtune_ros.params import parameter_overrides

    lock = process.DomainLock()
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=lock.domain_id)
    try:
        node = Node("probe_overrides", context=ctx, parameter_overrides=[Parameter("provenance_x", value=1.5)])
        assert isinstance(getattr(node, "_parameter_overrides", None), dict)
        got = parameter_overrides(node)
        assert got["provenance_x"].value == 1.5
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
        lock.release()
