"""The ament resource index without ament_index_python: where packages, executables and
interface definitions are installed.

One lookup for the whole project: the SIL and replay runners find node executables here
(``<prefix>/lib/<package>/<exe>``, exactly where ``ros2 run`` looks), the bag writer finds
``.msg`` definitions (``<prefix>/share/<package>/msg``).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

#: The repository root (the ROS 2 workspace ``ros2_ws`` lives beside magtune_core).
ROOT = Path(__file__).resolve().parents[2]
WORKSPACE_INSTALL = ROOT / "ros2_ws" / "install"


class AmentNotFound(LookupError):
    """A package or executable is not in any ament prefix."""


def prefixes() -> list[Path]:
    """Install prefixes searched, in order: AMENT_PREFIX_PATH, the running Python environment
    (the ``ros-jazzy-*`` wheels install there), then every package of the project's workspace
    (``ros2_ws/install/<pkg>``, built by ``scripts/bootstrap.sh``)."""
    out: list[Path] = []
    for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if p and Path(p) not in out:
            out.append(Path(p))
    extra = [Path(sys.prefix)]
    if WORKSPACE_INSTALL.is_dir():
        extra += sorted(p for p in WORKSPACE_INSTALL.iterdir() if p.is_dir())
    return out + [p for p in extra if p not in out]


def package_prefix(package: str) -> Path:
    """The install prefix of ``package`` from the ament resource index (as ament_index_python)."""
    for prefix in prefixes():
        if (prefix / "share" / "ament_index" / "resource_index" / "packages" / package).is_file():
            return prefix
    raise AmentNotFound(f"package '{package}' not found in AMENT_PREFIX_PATH; run 'bash scripts/bootstrap.sh' "
                        f"and '. scripts/env.sh'")


def executable(package: str, exe: str) -> Path:
    """``<prefix>/lib/<package>/<exe>``, exactly where ``ros2 run <package> <exe>`` looks."""
    path = package_prefix(package) / "lib" / package / exe
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise AmentNotFound(f"executable '{exe}' of package '{package}' not found at {path}")
    return path


def python_site(prefix: Path) -> Path:
    """The ``site-packages`` directory of a colcon install prefix for this Python."""
    return Path(prefix) / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"


def child_env(*package_prefixes: Path) -> dict:
    """Environment for a node process: ``package_prefixes``, then the workspace's packages
    (``ros2_ws/install/*``: the nodes, the interface packages), first on AMENT_PREFIX_PATH and
    their Python packages (and the repository, for magtune_core) first on PYTHONPATH."""
    env = dict(os.environ)
    # then every package of the project's workspace (interface packages such as tf2_msgs)
    ws = sorted(p for p in WORKSPACE_INSTALL.iterdir() if p.is_dir()) if WORKSPACE_INSTALL.is_dir() else []
    package_prefixes = tuple(package_prefixes) + tuple(p for p in ws if p not in package_prefixes)
    mine = [str(x) for x in package_prefixes]
    amp = mine + [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p and p not in mine]
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(amp)
    sites = [str(python_site(x)) for x in package_prefixes]
    pp = sites + [str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(pp)
    # the interface packages' typesupport libraries (<prefix>/lib), as colcon's local_setup does
    libs = [str(Path(x) / "lib") for x in package_prefixes if (Path(x) / "lib").is_dir()]
    ld = libs + [p for p in env.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p and p not in libs]
    env["LD_LIBRARY_PATH"] = os.pathsep.join(ld)
    return env
