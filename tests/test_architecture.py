"""The layering of magtune_core (docs/architecture.md), checked on the source itself.

Every import statement of every module (also those inside functions) is an edge; the tests
assert: no import circle between modules, every edge goes to the same subpackage or a lower
layer, ``ltp`` imports nothing else from magtune_core, no rclpy anywhere in the core, and
flight code (the controller node) imports no simulation code.
"""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "magtune_core"
#: Layer rank of each subpackage, bottom (0) to top. An import must go to the same
#: subpackage or to a strictly lower rank; ltp and base are both at the bottom and
#: independent of each other.
LAYERS = {"ltp": 0, "base": 0, "env": 1, "onboard": 2, "design": 3, "sim": 4, "bags": 4, "ros": 5, "studies": 6,
          "cli": 7}
#: What the on-board layer (the flight software) may import besides itself: no design, no simulation.
ONBOARD_MAY_IMPORT = {"onboard", "base", "env"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """magtune_core modules imported by ``name`` (resolved to the deepest existing module)."""
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = pkg.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            # ``from X import a``: the module X.a if there is one, else X itself
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t.startswith("magtune_core") and t != name:
                out.add(t)
    # importing a.b.c also runs a and a.b: parents of a target are edges of the package
    # __init__ files, which the walk covers on their own
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def _layer(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_walker_sees_the_packages():
    g = _graph()
    assert {"magtune_core.ltp.hinf", "magtune_core.design.tuner", "magtune_core.cli"} <= set(g)
    assert "magtune_core.ltp.system" in g["magtune_core.ltp.hinf"]  # relative import resolved
    assert "magtune_core.onboard.law" in g["magtune_core.sim.simulate"]


def test_no_import_circles():
    g = _graph()
    # Tarjan's strongly connected components: any component of size > 1 is a circle
    index, low, stack, on, comps = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(comp)

    sys.setrecursionlimit(10_000)
    for v in g:
        if v not in index:
            visit(v)
    circles = [sorted(c) for c in comps if len(c) > 1]
    assert circles == [], f"import circles: {circles}"


def test_imports_only_go_down():
    bad = []
    for mod, deps in _graph().items():
        lay = _layer(mod)
        if lay is None:  # magtune_core/__init__.py, __main__.py
            continue
        for d in deps:
            dl = _layer(d)
            if d in ("magtune_core",) and mod.startswith("magtune_core.cli"):
                continue  # __version__
            if dl is None or (dl != lay and LAYERS[dl] >= LAYERS[lay]):
                bad.append(f"{mod} -> {d}")
    assert bad == [], "imports against the layering:\n" + "\n".join(sorted(bad))


def test_ltp_knows_no_satellite():
    g = _graph()
    outside = {f"{m} -> {d}" for m, deps in g.items() if _layer(m) == "ltp" for d in deps if _layer(d) != "ltp"}
    assert outside == set()
    code = ("import sys, magtune_core.ltp as L; "
            "bad = [m for m in sys.modules if m.startswith(('magtune_core.design', 'magtune_core.env', "
            "'magtune_core.sim', 'magtune_core.base', 'magtune_core.bags'))]; "
            "assert not bad, bad; assert all(hasattr(L, n) for n in ('LTPSystem', 'multipliers', 'hinfnorm', 'h2norm'))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr


def test_core_never_imports_rclpy():
    for path in PKG.rglob("*.py"):
        tree = ast.parse(path.read_text())
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not any(x.split(".")[0] in ("rclpy", "rosidl_runtime_py") for x in names), path
    code = ("import sys, pkgutil, importlib, magtune_core; "
            "[importlib.import_module(m.name) for m in pkgutil.walk_packages(magtune_core.__path__, 'magtune_core.') "
            "if not m.name.endswith('__main__')]; assert 'rclpy' not in sys.modules")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("node", ["controller.py", "attitude_sensors.py", "attitude_estimator.py"])
def test_flight_nodes_import_no_simulation(node):
    src = (ROOT / "ros2_ws" / "src" / "magtune_ros" / "magtune_ros" / node).read_text()
    assert "magtune_core.sim" not in src


def test_no_argparse_below_cli():
    offenders = [str(p.relative_to(ROOT)) for p in PKG.rglob("*.py")
                 if _layer(_module_name(p)) not in (None, "cli") and ("import argparse" in p.read_text()
                                                                      or "def main(" in p.read_text())]
    assert offenders == []


def test_nodes_never_import_the_layer_that_launches_them():
    """No file of ros2_ws/src imports magtune_core.ros (the runners start the nodes; the nodes
    use the layers below: bags for the Foxglove server and playback options, design, sim)."""
    bad = []
    for f in sorted((ROOT / "ros2_ws" / "src").rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{f.relative_to(ROOT)}: {n}" for n in names if n == "magtune_core.ros" or n.startswith("magtune_core.ros.")]
    assert not bad, bad


def test_onboard_imports_only_base_and_env():
    """The flight software's boundary: onboard/ imports only base and env (the on-board Earth
    models), never the design problem, the simulation, studies, runners or the CLI."""
    g = _graph()
    bad = sorted(f"{m} -> {d}" for m, deps in g.items() if _layer(m) == "onboard"
                 for d in deps if _layer(d) not in ONBOARD_MAY_IMPORT)
    assert bad == [], bad
    assert {"magtune_core.onboard.law", "magtune_core.onboard.mekf", "magtune_core.onboard.modes"} <= set(g)


def _drawing_rows() -> dict[str, str]:
    """The text of each layer's rows in the drawing of docs/architecture.md (``N  name/`` starts a row)."""
    page = (ROOT / "docs" / "architecture.md").read_text()
    drawing = page.split("```")[1]
    rows: dict[str, str] = {}
    current = None
    for line in drawing.splitlines():
        m = re.match(r"\s*\d+\s+(\w+)/\s", line)
        if m:
            current = m.group(1)
        elif not line.strip() or line.strip() == "|":
            current = None
        if current:
            rows[current] = rows.get(current, "") + " " + line
    return rows


def test_architecture_page_names_every_module():
    """The drawing of docs/architecture.md names every module of the package in its layer's rows,
    at the rank the import test uses."""
    rows = _drawing_rows()
    assert set(rows) == set(LAYERS), sorted(rows)
    missing = [m for m in _modules() if len(m.split(".")) == 3 and m.split(".")[2] not in ("__init__", "__main__")
               and not re.search(rf"(?<![\w.]){m.split('.')[2]}(?!\w)", rows[m.split(".")[1]])]
    assert missing == [], f"modules missing from their layer in docs/architecture.md: {missing}"
    page = (ROOT / "docs" / "architecture.md").read_text().split("```")[1]
    for name, rank in LAYERS.items():
        assert re.search(rf"^\s*{rank}\s+{name}/", page, re.M), f"{name}/ not drawn at rank {rank}"


@pytest.mark.parametrize("node", ["controller.py", "attitude_estimator.py", "mode_manager.py"])
def test_flight_nodes_run_the_onboard_layer(node):
    """The flight nodes take their logic from onboard/ (law, B-dot, modes, estimator), not from design/
    (they read the mission's files, SpacecraftParams and Gains, from there)."""
    src = (ROOT / "ros2_ws" / "src" / "magtune_ros" / "magtune_ros" / node).read_text()
    imported = set(re.findall(r"from magtune_core\.(\w+)\.(\w+) import", src))
    assert {(lay, m) for lay, m in imported if lay == "design"} <= {("design", "params"), ("design", "gains")}, imported
    assert any(lay == "onboard" for lay, _ in imported)
