"""DDS on loopback (magtune_core.ros.process.dds_env, issue 32 item 6): a node started the way
``magtune sil`` and ``magtune replay`` start theirs binds every unicast UDP socket to 127.0.0.1;
what remains is Fast DDS's multicast discovery socket bound to the group address 239.255.0.1
(joined on the loopback interface only). ``--dds-interfaces all`` restores Fast DDS's defaults
(sockets on 0.0.0.0): the check sees the difference.

The sockets are read with ``ss -ulnp`` (iproute2), matched by the node's PID.
"""
from __future__ import annotations

import ipaddress
import shutil
import subprocess
import time

import pytest

from magtune_core.ros import process, scenario

pytestmark = [pytest.mark.ros, pytest.mark.skipif(shutil.which("ss") is None, reason="ss (iproute2) not installed")]
GROUP = ipaddress.ip_address("239.255.0.1")  # Fast DDS's default discovery multicast group


def _udp_sockets(pid: int) -> list[ipaddress.IPv4Address]:
    """Local addresses of the UDP sockets of process ``pid`` (``ss -ulnpH``)."""
    out = subprocess.run(["ss", "-ulnpH"], capture_output=True, text=True, check=True).stdout
    return [ipaddress.ip_address(line.split()[3].rsplit(":", 1)[0].strip("[]"))
            for line in out.splitlines() if f"pid={pid}," in line]


def _node_sockets(tmp_path, interfaces: str) -> list:
    """Start the controller node (process.start_node, process.child_env: as the SIL does), wait
    until its participant's sockets stop changing, return their addresses; the node is stopped."""
    gains = scenario.DEFAULT_SPACECRAFT.parent / "gains" / "sigma_60.yaml"
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix(), interfaces=interfaces)
        node = process.start_node("controller", process.resolve_executable("controller"),
                                  ["--params-file", str(scenario.DEFAULT_SPACECRAFT), "--params-file", str(gains),
                                   "-p", "use_sim_time:=true"], env, tmp_path, (lock.fh.fileno(),))
        try:
            deadline, last, stable = time.monotonic() + 30, None, 0
            while stable < 5 and time.monotonic() < deadline:  # 1 s without change, after the first socket
                time.sleep(0.2)
                now = sorted(map(str, _udp_sockets(node.popen.pid)))
                stable = stable + 1 if now and now == last else 0
                last = now
            assert node.popen.poll() is None, node.tail()
            return _udp_sockets(node.popen.pid)
        finally:
            process.stop_nodes([node])


def test_node_sockets_on_loopback_only(tmp_path):
    socks = _node_sockets(tmp_path, "loopback")
    assert len(socks) >= 3, socks  # the participant's unicast metatraffic/user ports and its sender
    unicast = [a for a in socks if not a.is_multicast]
    assert unicast and all(a.is_loopback for a in unicast), socks
    # what remains off 127.0.0.1: the multicast discovery socket, bound to the group address
    # itself (never to 0.0.0.0 or a host address), membership on the loopback interface
    assert all(a == GROUP for a in socks if a.is_multicast), socks


def test_dds_interfaces_all_opens_them(tmp_path):
    """The multi-host setting: Fast DDS's builtin transports, unicast sockets on every interface."""
    socks = _node_sockets(tmp_path, "all")
    assert any(a == ipaddress.ip_address("0.0.0.0") for a in socks), socks


def test_unknown_scope_is_refused():
    with pytest.raises(process.SilError, match="--dds-interfaces: expected one of loopback, all"):
        process.dds_env({}, "lan")
