"""Strict JSON for command output: ``null`` where a figure is NaN or infinite, never ``NaN``.

Python's :func:`json.dumps` writes ``NaN``/``Infinity`` by default, which no strict JSON parser
(``jq``, JavaScript's ``JSON.parse``) accepts; every ``--json`` output and every JSON file a
command writes goes through :func:`dumps`.
"""
from __future__ import annotations

import json
import math


def finite_or_none(obj):
    """``obj`` with every non-finite float (also numpy floats, inside dicts, lists, tuples and
    arrays) replaced by None and numpy scalars/arrays made plain Python values."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    tolist = getattr(obj, "tolist", None)
    if tolist is not None and not isinstance(obj, (str, bytes)):  # numpy scalars and arrays
        return finite_or_none(tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj, **kwargs) -> str:
    """``json.dumps`` of :func:`finite_or_none` of ``obj`` with ``allow_nan=False`` (strict JSON)."""
    return json.dumps(finite_or_none(obj), allow_nan=False, **kwargs)
