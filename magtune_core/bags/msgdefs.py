"""ROS 2 message definitions for MCAP ``ros2msg`` schemas, read from the installed interfaces.

No rclpy: the definitions come from the ament index layout ``<prefix>/share/<pkg>/msg/<Type>.msg``
(the ``ros-jazzy-*`` wheels install them under the venv prefix; ``AMENT_PREFIX_PATH`` may add
more prefixes, e.g. ``ros2_ws/install/<pkg>``).

The concatenated text follows rosbag2_storage_mcap's ``MessageDefinitionCache::get_full_text``:
the root ``.msg`` verbatim, then every dependency once, depth first, dependencies of one file in
sorted order, each preceded by ``"\\n" + "=" * 80 + "\\nMSG: pkg/Type\\n"``. Dependencies are
found with the same rule (first token of each line that is not a primitive type; a type
without a package refers to the package of the file being parsed).

The RIHS01 type-description hash (``topic_type_hash``, ``type_description_hash``) is read from
``share/<pkg>/msg/<Type>.json``, which rosidl generates next to the ``.msg``.
"""
from __future__ import annotations

import json
import re
from functools import lru_cache
from pathlib import Path

from ..base.ament import prefixes

DELIMITER = "=" * 80
PRIMITIVE_TYPES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
_TYPE_RE = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*)/((?:msg|srv)/)?([a-zA-Z][a-zA-Z0-9_]*)$")
# first token of a line, optionally followed by an array suffix, then whitespace
_FIELD_TYPE_RE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")


class DefinitionNotFound(LookupError):
    """No ``.msg`` file for a type in any ament prefix."""


def split_type(name: str) -> tuple[str, str, str]:
    """``'sensor_msgs/msg/Imu'`` or ``'sensor_msgs/Imu'`` -> ``('sensor_msgs', 'msg', 'Imu')``."""
    m = _TYPE_RE.match(name)
    if not m:
        raise ValueError(f"not a ROS message type name: {name!r} (expected pkg/msg/Type)")
    return m.group(1), (m.group(2) or "msg/").rstrip("/"), m.group(3)


def normalize_type(name: str) -> str:
    """Canonical ``pkg/msg/Type`` form."""
    pkg, ns, typ = split_type(name)
    return f"{pkg}/{ns}/{typ}"


def _find_file(pkg: str, ns: str, typ: str, ext: str) -> Path:
    for prefix in prefixes():
        f = prefix / "share" / pkg / ns / f"{typ}{ext}"
        if f.is_file():
            return f
    raise DefinitionNotFound(f"{pkg}/{ns}/{typ}{ext} not found under share/ of {[str(p) for p in prefixes()]}")


@lru_cache(maxsize=None)
def msg_text(name: str) -> str:
    """Verbatim ``.msg`` text of a type."""
    pkg, ns, typ = split_type(name)
    return _find_file(pkg, ns, typ, ".msg").read_text()


def dependencies(text: str, package: str) -> list[str]:
    """Sorted non-primitive field types of a ``.msg`` text, as ``pkg/Type``."""
    deps = set()
    for m in _FIELD_TYPE_RE.finditer(text):
        t = m.group(1)
        if t in PRIMITIVE_TYPES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)


@lru_cache(maxsize=None)
def full_definition(name: str) -> str:
    """The ``ros2msg`` schema text of a type, as rosbag2's MCAP plugin writes it."""
    seen: set[str] = set()

    def append(type_name: str, depth: int) -> str:
        if depth <= 0:
            raise RecursionError(f"message definition of {name} nests too deep")
        text = msg_text(type_name)
        out = text
        for dep in dependencies(text, split_type(type_name)[0]):
            if dep not in seen:
                seen.add(dep)
                out += f"\n{DELIMITER}\nMSG: {dep}\n" + append(dep, depth - 1)
        return out

    return append(name, 50)


@lru_cache(maxsize=None)
def type_hash(name: str) -> str:
    """``RIHS01_<sha256>`` of a type from rosidl's generated ``.json``, or ``''`` if absent."""
    pkg, ns, typ = split_type(name)
    try:
        doc = json.loads(_find_file(pkg, ns, typ, ".json").read_text())
    except (DefinitionNotFound, ValueError):
        return ""
    full = f"{pkg}/{ns}/{typ}"
    for h in doc.get("type_hashes", []):
        if h.get("type_name") == full:
            return str(h.get("hash_string", ""))
    return ""
