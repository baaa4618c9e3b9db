"""docs/foxglove_layout.json names only topics the project publishes, field paths that exist in
their ROS 2 Jazzy message definitions (checked with rosbags' type store, an independent
definition of the standard messages), and panels its layout tree uses."""
from __future__ import annotations

import json
from pathlib import Path

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype

from magtune_core.base.topics import FRAME_BODY, FRAME_ECI, FRAME_ORBITAL, PROJECT_TOPICS

LAYOUT = Path(__file__).resolve().parents[2] / "docs" / "foxglove_layout.json"


def _resolve(store, msgtype: str, fields: list[str]) -> str:
    """Type name at the end of a field path (a base type such as float64, or a message type)."""
    for i, name in enumerate(fields):
        _, defs = store.fielddefs[msgtype]
        desc = dict(defs)[name]          # KeyError: no such field
        if desc[0] == Nodetype.NAME:
            msgtype = desc[1]
        else:
            assert desc[0] == Nodetype.BASE and i == len(fields) - 1, f"{name}: not a scalar leaf"
            return desc[1][0]
    return msgtype


def _panels(tree) -> set:
    return {tree} if isinstance(tree, str) else _panels(tree["first"]) | _panels(tree["second"])


def test_layout_topics_paths_and_panels():
    doc = json.loads(LAYOUT.read_text())
    store = get_typestore(Stores.ROS2_JAZZY)
    assert _panels(doc["layout"]) == set(doc["configById"])
    seen = set()
    for pid, cfg in doc["configById"].items():
        paths = [p["value"] for p in cfg.get("paths", [])] + ([cfg["topicPath"]] if "topicPath" in cfg else [])
        for path in paths:
            topic, *fields = path.split(".")
            assert topic in PROJECT_TOPICS, (pid, topic)
            if fields:
                assert _resolve(store, PROJECT_TOPICS[topic][0], fields) == "float64", path
            seen.add(topic)
        for topic in cfg.get("topics", {}):
            assert topic in PROJECT_TOPICS, (pid, topic)
        if pid.startswith("3D!"):
            assert cfg["followTf"] == FRAME_ORBITAL
            assert {f"frame:{f}" for f in (FRAME_ECI, FRAME_ORBITAL, FRAME_BODY)} == set(cfg["transforms"])
    assert {"/sim/truth", "/controller/dipole_command", "/sim/magnetic_field"} <= seen
