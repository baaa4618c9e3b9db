"""The one error type for anything a user can get wrong in a file or a parameter.

Every command maps it to one line on stderr and exit status 2 (``magtune_core.cli``); the
nodes map it to one line and exit status 2 too (``magtune_ros.main.run``).
"""
from __future__ import annotations


class ConfigError(ValueError):
    """A parameter file (or node parameter set) is missing, malformed, or holds an invalid value.

    ``str(exc)`` reads ``<where>: field '<name>': <what was expected>``.
    """

    def __init__(self, path, field_name: str | None, expected: str):
        self.path, self.field, self.expected = str(path), field_name, expected
        where = f"{self.path}: " + (f"field '{field_name}': " if field_name else "")
        super().__init__(where + expected)


class SilError(RuntimeError):
    """A node run (SIL, replay) could not be started or a node failed: exit status 1 in the CLI."""
