"""Shared setup of the ROS tests: the skip guard (the nodes must be built and rclpy importable)
and the fixtures several modules use. Every process a test here starts dies with the test run
(``magtune_core.ros.process.die_with_parent``, as the runners do), runs in its own
ROS_DOMAIN_ID (``process.DomainLock``) with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
(``process.child_env``), and is stopped in a ``finally``."""
from __future__ import annotations

import pytest

from magtune_core.base.errors import SilError
from magtune_core.design.gains import save_gains
from magtune_core.design.lq import lq_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.ros import process


def _why_not_built() -> str | None:
    """None when every node executable resolves and rclpy imports, else the reason to skip."""
    try:
        for exe in ("simulator", "attitude_sensors", "controller", "recorder", "player", "live_bridge"):
            process.resolve_executable(exe)
        import rclpy  # noqa: F401
    except (SilError, ImportError) as exc:
        return f"magtune_ros not built or rclpy missing (run scripts/bootstrap.sh): {exc}"
    return None


NOT_BUILT = _why_not_built()


def pytest_collection_modifyitems(config, items):
    """Skip every test of tests/ros when the nodes cannot run (one reason, not a traceback each)."""
    if NOT_BUILT:
        for item in items:
            if "tests/ros/" in str(item.fspath).replace("\\", "/"):
                item.add_marker(pytest.mark.skip(reason=NOT_BUILT))


@pytest.fixture(scope="session")
def gains60(tmp_path_factory):
    """The LQ gain of the paper's satellite at sigma = 60, Ts = 1 s, as a gains file (a stable,
    quickly computed controller: the SIL tests check plumbing and bit-exactness, not tuning)."""
    path = tmp_path_factory.mktemp("gains") / "sigma_60.yaml"
    save_gains(path, lq_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, 1.0))
    return path


@pytest.fixture
def domain(monkeypatch):
    """A free ROS_DOMAIN_ID, locked for the test; the test process discovers on LOCALHOST only."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    lock = process.DomainLock()
    try:
        yield lock.domain_id
    finally:
        lock.release()
