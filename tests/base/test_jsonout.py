"""base.jsonout: command output is strict JSON (null, never NaN/Infinity)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from magtune_core.base import jsonout


def test_strict_json_maps_non_finite_to_null():
    """Why: --json printed NaN (not JSON); base.jsonout writes null instead, numpy values included."""
    text = jsonout.dumps({"rho": float("inf"), "J": np.float64("nan"), "K": np.array([1.0, np.nan]), "n": np.int64(3),
                          "ok": True, "runs": [(-np.inf, "x")]})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c)) == {
        "rho": None, "J": None, "K": [1.0, None], "n": 3, "ok": True, "runs": [[None, "x"]]}
