"""pyproject.toml and scripts/requirements.txt name the same packages (pins vs ranges)."""
from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _name(req: str) -> str:
    return re.split(r"[\[<>=!~ ;]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_requirements_match_pyproject():
    proj = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {_name(r) for r in proj["dependencies"]}
    for extra in proj["optional-dependencies"].values():
        declared |= {_name(r) for r in extra}
    pinned = {_name(ln.split("#")[0]) for ln in (ROOT / "scripts" / "requirements.txt").read_text().splitlines()
              if ln.split("#")[0].strip()}
    assert declared == pinned, f"only in pyproject: {declared - pinned}; only in requirements: {pinned - declared}"


def test_runtime_imports_are_declared():
    """Every third-party module magtune_core imports is a runtime dependency."""
    proj = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    runtime = {_name(r) for r in proj["dependencies"]}
    module_to_dist = {"yaml": "pyyaml", "pyIGRF14": "pyigrf14", "numpy": "numpy", "scipy": "scipy", "tqdm": "tqdm",
                      "mcap": "mcap", "rosbags": "rosbags", "matplotlib": "matplotlib", "cma": "cma",
                      "threadpoolctl": "threadpoolctl", "dask": "dask", "distributed": "distributed", "pyarrow": "pyarrow", "numba": "numba",
                      "foxglove": "foxglove-sdk", "sgp4": "sgp4"}
    seen = set()
    for p in (ROOT / "magtune_core").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Import):
                seen |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level:
                seen.add((node.module or "").split(".")[0])
    third = {m for m in seen if m not in sys.stdlib_module_names and m not in ("magtune_core", "__future__")}
    assert {"numpy", "scipy", "yaml", "mcap"} <= third  # the walk sees the imports
    assert third <= set(module_to_dist), f"undeclared third-party imports: {third - set(module_to_dist)}"
    assert {module_to_dist[m] for m in third} <= runtime


def test_no_symlink_and_no_environment_is_tracked():
    """The repository holds no symlink (a worktree's .venv or ros2_ws/install link, once committed, replaced
    the real ones of a checkout on merge) and nothing of what bootstrap builds."""
    import subprocess

    if not (ROOT / ".git").exists():
        return  # an sdist or unpacked copy: nothing tracked to check
    staged = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-s"], capture_output=True, text=True, check=True)
    links = [ln.split("\t", 1)[1] for ln in staged.stdout.splitlines() if ln.startswith("120000")]
    assert not links, f"tracked symlinks: {links}"
    built = [p for p in (ln.split("\t", 1)[1] for ln in staged.stdout.splitlines())
             if p.split("/")[0] == ".venv" or p.startswith(("ros2_ws/install", "ros2_ws/build", "ros2_ws/log"))]
    assert not built, f"tracked build outputs: {built[:5]}"
