"""Shared setup of the ROS tests: the skip guard (the nodes must be built and rclpy importable)
and the fixtures several modules use. Every process a test here starts dies with the test run
(``magtune_core.ros.process.die_with_parent``, as the runners do), runs in its own
ROS_DOMAIN_ID (``process.DomainLock``) with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
(``process.child_env``), and is stopped in a ``finally``."""
from __future__ import annotations

import sys

import pytest

from magtune_core.base.errors import SilError
from magtune_core.design.gains import save_gains
from magtune_core.design.lq import lq_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams, load_spacecraft
from magtune_core.ros import process, sil


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
def built_package(monkeypatch):
    """magtune_ros as colcon installed it (what the node processes run) importable in this test."""
    monkeypatch.syspath_prepend(str(process.package_prefix() / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}"
                                    / "site-packages"))


@pytest.fixture
def domain(monkeypatch):
    """A free ROS_DOMAIN_ID, locked for the test; the test process discovers on LOCALHOST only."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    lock = process.DomainLock()
    try:
        yield lock.domain_id
    finally:
        lock.release()


#: The estimator flight's length: 0.5 orbit (2806 steps of 1 s), a lit start (Davenport fix at t = 0)
#: and eclipse from ~1720 s, where the attitude sigma grows about the field.
ESTIMATOR_FLIGHT_ORBITS = 0.5


@pytest.fixture(scope="session")
def estimator_flight(tmp_path_factory):
    """One full-environment SIL run flying on the estimator (sigma = 120), every topic recorded: (bag, orbit
    period [s]). Shared by the modules that check different things of that flight (test_estimator_sil on
    its lit first 0.2 orbit, test_report_estimation on the whole): the lockstep is deterministic, so a
    prefix of this run is the shorter run (the node tests share one pytest worker: tests/conftest.py)."""
    tmp = tmp_path_factory.mktemp("estimator_flight")
    sil.run_sil("config/gains/sigma_120.yaml", orbits=ESTIMATOR_FLIGHT_ORBITS, environment="full", attitude="estimator",
                log_dir=tmp / "logs", bag=tmp / "bag", timeout=600)
    return tmp / "bag", load_spacecraft("config/spacecraft.yaml").orbit_period
