"""Schema of the recorder node's options (each a ROS parameter and a ``ros2 bag record``-style flag).

:data:`RECORDER_FIELDS` is declared by the recorder node as ROS parameters; command-line options
win over them; :func:`recording_options` validates the merged values once (ConfigError naming
the option: one line, exit status 2).
"""
from __future__ import annotations

import re

from ..base.errors import ConfigError
from ..base.schema import Field, parse
from ..base.topics import topic_specs
from .writer import DEFAULT_CHUNK_SIZE

RECORDER_FIELDS = (
    Field("path", "str", "bag directory to create (bags/NAME); the -o option", ""),
    Field("topics", "str[]", "topics to record: /name or /name:pkg/msg/Type (typed: subscribed at once)", ()),
    Field("all", "bool", "record every discovered topic", False),
    Field("include_hidden", "bool", "with all, also /rosout and /parameter_events", False),
    Field("custom_data", "str[]", "KEY=VALUE pairs stored in metadata.yaml custom_data (e.g. sigma=60)", ()),
    Field("chunk_size", "int", "MCAP chunk size [bytes]", DEFAULT_CHUNK_SIZE, positive=True),
    Field("flush_period", "float", "close the open chunk every S wall seconds (crash safety)", 1.0, positive=True,
          unit="s"),
    Field("depth", "int", "subscription queue depth", 10000, positive=True),
    Field("wall_time", "bool", "log wall time, not sim time", False),
    Field("max_messages", "int", "stop after N messages (0: never)", 0, nonnegative=True),
    Field("duration", "float", "stop after S wall seconds (0: never)", 0.0, nonnegative=True, unit="s"),
    Field("overwrite", "bool", "replace an existing bag directory", False),
    Field("regex", "str", "also record every discovered topic matching REGEX (as ros2 bag record -e)", ""),
    Field("exclude", "str", "never record topics matching REGEX (applies to topics, regex and all)", ""),
    Field("max_bag_size", "int", "split: start NAME_<i+1>.mcap when the file holds BYTES (0: never)", 0,
          nonnegative=True, unit="B"),
    Field("max_bag_duration", "float", "split: start a new file every S seconds of log time (0: never)", 0.0,
          nonnegative=True, unit="s"),
)


def recording_options(values: dict, where: str) -> dict:
    """Validate the recorder's options (``values``: parameter name -> value) against
    :data:`RECORDER_FIELDS` and each other.

    Returns
    -------
    dict
        the options with defaults filled in, ``regex``/``exclude`` compiled (None when empty),
        ``topics`` the project's topics when nothing else selects any.
    """
    v = parse(values, RECORDER_FIELDS, where)
    if not v["path"]:
        raise ConfigError(where, "path", "no output bag given (-o bags/NAME or -p path:=bags/NAME)")
    for key in ("regex", "exclude"):
        try:
            v[key] = re.compile(v[key]) if v[key] else None
        except re.error as exc:
            raise ConfigError(where, key, f"--{key} {v[key]!r} is not a regular expression ({exc})") from None
    if any("=" not in kv for kv in v["custom_data"]):
        raise ConfigError(where, "custom_data", f"expected KEY=VALUE pairs, got {list(v['custom_data'])}")
    v["topics"] = list(v["topics"]) or ([] if v["all"] or v["regex"] is not None else topic_specs())
    return v
