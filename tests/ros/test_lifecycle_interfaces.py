"""A peer on the domain cannot kill or forge through a flight node's interfaces (issue 45).

* ``~/change_state``: a transition the current state does not have (by id, by label, an unknown id
  or label, from *unconfigured* and from *active*) is answered success=false, counted on /diagnostics
  (``rejected_transition``) and logged in one bounded line; the process lives, ``get_state``
  answers, and a valid transition afterwards works (``lifecycle.ManagedNode``; on today's rclpy the
  first such request ended the node with a traceback).
* ``set_mode``: a reason with a newline and ANSI escapes, and a 2 MB one, reach the Mode message
  and the manager's log as one bounded printable line (``base.text.printable``).

Real node processes (the ``ros2 run`` way, as tests/ros/test_node_params.py), each in its own
ROS_DOMAIN_ID (``process.DomainLock``) with DDS on loopback, stopped in a ``finally``; the peer is an
rclpy node of this process on a discovery range of LOCALHOST.
"""
from __future__ import annotations

import time

import pytest

from magtune_core.base.text import LIMIT
from magtune_core.ros import process, scenario

pytestmark = pytest.mark.ros

GAINS = "config/gains/sigma_60.yaml"



class Peer:
    """An rclpy node of the test process on the run's domain: service calls and subscriptions."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = Node("peer_probe", context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)

    def call(self, client, request, timeout: float = 20.0):
        """The response, or None without one within ``timeout`` wall seconds."""
        fut = client.call_async(request)
        self.executor.spin_until_future_complete(fut, timeout_sec=timeout)
        return fut.result() if fut.done() else None

    def wait_service(self, client, procs, timeout: float = 60.0):
        """Wait for a service while every node process lives (its log in the failure)."""
        deadline = time.monotonic() + timeout
        while not client.wait_for_service(timeout_sec=0.5):
            for p in procs:
                assert p.popen.poll() is None, p.log.read_text(errors="replace")
            assert time.monotonic() < deadline, "service never appeared"

    def spin_until(self, done, timeout: float = 30.0) -> bool:
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.1)
        return done()

    def close(self):
        import rclpy

        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def _start(name: str, domain_id: int, log_dir, *ros_args):
    env = process.child_env(domain_id, process.package_prefix())
    return process.start_node(name, process.resolve_executable(name), ["--params-file", str(scenario.DEFAULT_SPACECRAFT),
                                                                        *ros_args], env, log_dir)


def _state(peer, get_state):
    """The node's lifecycle state label by its ``get_state`` service (None: no answer)."""
    from lifecycle_msgs.srv import GetState

    r = peer.call(get_state, GetState.Request())
    return r.current_state.label if r else None


FORGED = "activate\n[ERROR] [controller]: forged\x1b[31m"
#: (transition id, label) a peer sends that the state does not have: refused, the state unchanged.
FROM_UNCONFIGURED = [(0, FORGED), (3, ""), (99, ""), (0, "activate"), (0, "no_such_transition")]
FROM_ACTIVE = [(1, ""), (99, ""), (255, ""), (0, "cleanup"), (0, "x" * 100_000)]


def _diagnostics_count(peer, key: str, want: int) -> str | None:
    """The controller's ``key`` counter once it reads ``want`` on /diagnostics (None if it never does)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    seen = {}

    def on(msg):
        for st in msg.status:
            if st.name == "magtune/controller":
                seen.update({kv.key: kv.value for kv in st.values})

    sub = peer.node.create_subscription(DiagnosticArray, "/diagnostics", on,
                                        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    try:
        peer.spin_until(lambda: seen.get(key) == str(want), timeout=10.0)
    finally:
        peer.node.destroy_subscription(sub)
    return seen.get(key)


def test_invalid_transitions_are_refused_and_the_node_lives(domain, tmp_path):
    """From unconfigured and from active: every invalid request by id or label -> success false, the
    process alive, the state unchanged; valid transitions still work; one bounded log line, no traceback."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    proc = _start("controller", domain, tmp_path, "--params-file", GAINS, "-p", "autostart:=false")
    peer = None
    try:
        peer = Peer(domain)
        change = peer.node.create_client(ChangeState, "/controller/change_state")
        get_state = peer.node.create_client(GetState, "/controller/get_state")
        peer.wait_service(change, [proc])
        peer.wait_service(get_state, [proc])

        def refused(cases, state):
            for tid, label in cases:
                r = peer.call(change, ChangeState.Request(transition=Transition(id=tid, label=label)))
                assert r is not None and r.success is False, (tid, label[:40], proc.tail())
                assert proc.popen.poll() is None, proc.log.read_text(errors="replace")
                assert _state(peer, get_state) == state

        def valid(tid, label, state):
            r = peer.call(change, ChangeState.Request(transition=Transition(id=tid, label=label)))
            assert r is not None and r.success is True, proc.tail()
            assert _state(peer, get_state) == state

        assert _state(peer, get_state) == "unconfigured"
        refused(FROM_UNCONFIGURED, "unconfigured")
        valid(Transition.TRANSITION_CONFIGURE, "", "inactive")
        valid(0, "activate", "active")
        refused(FROM_ACTIVE, "active")
        valid(Transition.TRANSITION_DEACTIVATE, "", "inactive")
        n = len(FROM_UNCONFIGURED) + len(FROM_ACTIVE)
        assert _diagnostics_count(peer, "rejected_transition", n) == str(n)
        assert proc.popen.poll() is None
    finally:
        if peer is not None:
            peer.close()
        process.stop_nodes([proc])
    log = proc.log.read_text(errors="replace")
    lines = [x for x in log.splitlines() if "rejected_transition" in x or "change_state refused" in x]
    # the first refusal is logged (then every 100th: a flooding peer cannot flood the log), the peer's
    # label spelled out on that one line
    assert len(lines) == 1, log
    assert "transition label 'activate\\n[ERROR] [controller]: forged\\x1b[31m' is not valid from state " \
           "'unconfigured' (valid: configure (1), shutdown (5))" in lines[0]
    assert "Traceback" not in log and "\x1b" not in log and "Transition is not registered" not in log
    assert not any(x.startswith("[ERROR] [controller]: forged") for x in log.splitlines()), log
    assert proc.popen.returncode == 0, log


def test_set_mode_reason_is_one_bounded_line(domain, tmp_path):
    """set_mode with a reason that forges a log line, then with a 2 MB reason: the Mode message's
    reason and the manager's log line are each one printable line of bounded length."""
    from magtune_interfaces.msg import Mode
    from magtune_interfaces.srv import SetMode
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    procs, peer = [], None
    try:
        ctl = _start("controller", domain, tmp_path, "--params-file", GAINS, "-p", "autostart:=false")
        procs.append(ctl)
        mgr = _start("mode_manager", domain, tmp_path, "-p", "managed_nodes:=[controller]")
        procs.insert(0, mgr)
        peer = Peer(domain)
        modes = []
        peer.node.create_subscription(Mode, "/mode", modes.append, QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        set_mode = peer.node.create_client(SetMode, "/set_mode")
        peer.wait_service(set_mode, [ctl, mgr])
        assert peer.spin_until(lambda: "controller: active" in mgr.log.read_text(errors="replace"), 60.0), mgr.tail()
        forged = "\n[ERROR] [mode_manager]: forged\x1b[31m"
        r = peer.call(set_mode, SetMode.Request(mode=Mode.SAFE, reason=forged))
        assert r is not None and r.success and r.mode == Mode.SAFE
        r = peer.call(set_mode, SetMode.Request(mode=Mode.DETUMBLE, reason="y" * (2 * 1024 * 1024)), timeout=60.0)
        assert r is not None and r.success and r.mode == Mode.DETUMBLE
        assert peer.spin_until(lambda: [m.label for m in modes][-2:] == ["SAFE", "DETUMBLE"], 20.0), modes
        assert all(p.popen.poll() is None for p in (ctl, mgr))
    finally:
        if peer is not None:
            peer.close()
        process.stop_nodes(procs)  # the manager first: it brings the controller down
    safe, detumble = modes[-2:]
    assert safe.reason == "commanded: \\n[ERROR] [mode_manager]: forged\\x1b[31m"
    assert detumble.reason.startswith("commanded: yyy") and detumble.reason.endswith(
        f"...[{2 * 1024 * 1024 - LIMIT} more characters]")
    for m in (safe, detumble):
        assert m.reason.isprintable() and len(m.reason) < LIMIT + 50
    log = mgr.log.read_text(errors="replace")
    assert "\x1b" not in log and len(log) < 20_000, len(log)
    assert not any(x.startswith("[ERROR] [mode_manager]: forged") for x in log.splitlines()), log
    (forged_line,) = [x for x in log.splitlines() if "-> SAFE: commanded:" in x]
    assert forged_line.endswith("-> SAFE: commanded: \\n[ERROR] [mode_manager]: forged\\x1b[31m")
    (long_line,) = [x for x in log.splitlines() if "-> DETUMBLE: commanded:" in x]
    assert len(long_line) < LIMIT + 150


def test_change_state_guard_and_rclpys_private_state_machine(domain, built_package):
    """In process, no DDS peer: ``lifecycle.state_machine`` reads rclpy's private ``_state_machine``
    (this fails if rclpy renames it or changes the shape of ``current_state`` / ``available_transitions``),
    and ManagedNode's ``~/change_state`` callback refuses what rclpy's own would raise on."""
    import rclpy
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rclpy.lifecycle import LifecycleNode

    from magtune_ros.lifecycle import ManagedNode, state_machine

    class Probe(ManagedNode):
        def configure(self):
            pass

        def activate(self):
            pass

    rclpy.init(domain_id=domain)  # the default context: ManagedNode takes no context
    try:
        plain = LifecycleNode("probe_plain")
        sm = getattr(plain, "_state_machine", None)
        assert sm is state_machine(plain)
        assert tuple(sm.current_state) == (1, "unconfigured")
        assert {tuple(t[:2]) for t in sm.available_transitions} == {(1, "configure"), (5, "shutdown")}
        assert all(len(t) == 6 for t in sm.available_transitions)
        plain.destroy_node()

        node = Probe("probe_managed", ["samples"])
        (srv,) = [s for s in node.services if s.srv_type is ChangeState]

        def ask(tid=0, label=""):
            return srv.callback(ChangeState.Request(transition=Transition(id=tid, label=label)),
                                ChangeState.Response()).success

        assert ask(3) is False and ask(99) is False and ask(label="activate") is False
        assert ask(label="bogus") is False and state_machine(node).current_state[1] == "unconfigured"
        assert ask(1) is True and ask(label="activate") is True
        assert ask(1) is False and ask(label="configure") is False and state_machine(node).current_state[1] == "active"
        assert node.diag.counts["rejected_transition"] == 6
        assert "is not valid from state 'active' (valid: deactivate (4), shutdown (7))" in node.refused_transition(
            Transition(id=1))
        node.destroy_node()
    finally:
        rclpy.shutdown()
