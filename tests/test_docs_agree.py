"""Docs and code agree: the QoS depths the package README states are the code's, and every file
names the orbital Z axis the same way (X nadir, Y along-track, Z = X x Y = -orbit normal)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "ros2_ws" / "src" / "magtune_ros"


def test_readme_qos_depths_are_the_code_s():
    code = (PKG / "magtune_ros" / "common.py").read_text()
    depth = {name: int(d) for name, d in re.findall(r"^(\w+_QOS) = QoSProfile\([^)]*?depth=(\d+)", code, re.M | re.S)}
    assert set(depth) >= {"LOCKSTEP_QOS", "CLOCK_QOS", "DIAG_QOS"}, depth
    readme = (PKG / "README.md").read_text()
    stated = {name: int(d) for d, name in re.findall(r"KEEP_LAST (\d+)\s*\(`(\w+_QOS)`", readme)}
    assert stated == {k: depth[k] for k in ("LOCKSTEP_QOS", "CLOCK_QOS", "DIAG_QOS")}, stated


def _project_files():
    for sub in ("README.md", "docs", "magtune_core", "ros2_ws/src", "config", "bags/README.md"):
        path = ROOT / sub
        files = [path] if path.is_file() else [*path.rglob("*.py"), *path.rglob("*.md"), *path.rglob("*.yaml")]
        yield from (f for f in files if "__pycache__" not in f.parts)


def test_orbital_z_is_minus_orbit_normal_everywhere():
    """A Z axis called the orbit normal must carry the minus sign (or say 'minus'/'opposite')."""
    bad = []
    for f in _project_files():
        text = " ".join(f.read_text(errors="replace").split())
        for m in re.finditer(r"\bZ\b[^.;\n]{0,12}?orbit[ -]normal", text):
            if not re.search(r"(-|minus|opposite|anti)\s*(the\s+)?orbit[ -]normal", m.group(0)):
                bad.append(f"{f.relative_to(ROOT)}: ...{m.group(0)}...")
    assert not bad, bad
