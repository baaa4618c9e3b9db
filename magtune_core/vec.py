"""Small vector helpers for (..., 3) arrays (faster than numpy's general-purpose versions on tiny arrays)."""
from __future__ import annotations

import numpy as np


def cross(a, b) -> np.ndarray:
    """a x b over the last axis with broadcasting; same result as np.cross, ~3x less overhead per call."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim == 1 and b.ndim == 1:  # one vector each: plain float arithmetic
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)
