"""Shared test setup: the helpers in tests/support are importable by name, markers are defined
in pyproject.toml (``ros``: starts real rclpy nodes over DDS; ``slow``: long numerical checks), and the
suite's split over pytest-xdist workers (scripts/test.sh: ``--dist loadgroup``)."""
from __future__ import annotations

import sys
from pathlib import Path

SUPPORT = Path(__file__).resolve().parent / "support"
if str(SUPPORT) not in sys.path:
    sys.path.insert(0, str(SUPPORT))

import pytest  # noqa: E402

#: Modules that start nodes beyond tests/ros/ (a SIL run inside a numerical check).
_NODE_MODULES = ("tests/ros/", "tests/sim/test_fullenv.py")


def worker_group(nodeid: str) -> str:
    """The suite's split over pytest-xdist workers: every test that starts nodes in one group, run one at a time (as
    without xdist: a node test beside another one starves both, and the lockstep timeouts and pacing of these tests
    were set for one at a time); every other module its own group, so a module-scoped fixture is computed once."""
    return "nodes" if nodeid.startswith(_NODE_MODULES) else nodeid.split("::")[0]


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scope scheduler with :func:`worker_group` as the scope (``--dist loadgroup`` would do it with marks,
    but xdist 3.8 renames the node id through an attribute pytest 9 no longer reads)."""
    from xdist.scheduler import LoadScopeScheduling

    class NodeTestsTogether(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return worker_group(nodeid)

    return NodeTestsTogether(config, log)


def pytest_collection_modifyitems(config, items):
    """The node tests first, so their group, the longest, starts at once."""
    items.sort(key=lambda i: worker_group(i.nodeid) != "nodes")  # stable: the rest keep their order
