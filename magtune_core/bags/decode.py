"""Decode CDR payloads of a bag without rclpy, with the ``rosbags`` type system.

The type store starts from rosbags' built-in ROS 2 Jazzy types and learns any other type from
the ``ros2msg`` schema text stored in the bag, so bags with project-specific messages decode too.
"""
from __future__ import annotations

from functools import lru_cache

from rosbags.typesys import Stores, get_types_from_msg, get_typestore


@lru_cache(maxsize=1)
def _base_store():
    return get_typestore(Stores.ROS2_JAZZY)


class Decoder:
    """CDR <-> rosbags message objects for the types of one or more bags."""

    def __init__(self):
        self.store = get_typestore(Stores.ROS2_JAZZY)

    def learn(self, msg_type: str, definition: str) -> None:
        """Register a type (and its dependencies) from a ``ros2msg`` schema text if unknown."""
        if msg_type in self.store.fielddefs:
            return
        types = {}
        parts = definition.split("\n" + "=" * 80 + "\n")
        types.update(get_types_from_msg(parts[0], msg_type))
        for part in parts[1:]:
            head, _, body = part.partition("\n")
            name = head.removeprefix("MSG: ").strip()
            if "/msg/" not in name:
                pkg, _, typ = name.partition("/")
                name = f"{pkg}/msg/{typ}"
            if name not in self.store.fielddefs:
                types.update(get_types_from_msg(body, name))
        self.store.register(types)

    def decode(self, data: bytes, msg_type: str):
        """Deserialize CDR bytes of ``msg_type`` (``pkg/msg/Type``)."""
        return self.store.deserialize_cdr(data, msg_type)

    def encode(self, msg, msg_type: str) -> bytes:
        """Serialize a rosbags message object to CDR bytes (little endian)."""
        return bytes(self.store.serialize_cdr(msg, msg_type))

    def types(self):
        """Message classes, e.g. ``decoder.types()['sensor_msgs/msg/Imu']``."""
        return self.store.types


def stamp_ns(msg) -> int | None:
    """``header.stamp`` of a decoded message in ns, or None if it has no header."""
    h = getattr(msg, "header", None)
    if h is None:
        return None
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
