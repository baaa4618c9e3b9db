"""Geomagnetic field models in orbital axes for the linear time-periodic design model.

The paper's eq. (26) is garbled in the extracted text; SPEC.md gives our reading (``eq26``)
and the literal extraction-order reading (``eq26_literal``). Both are first-order Fourier
series in the orbital rate, so one Fourier-series class holds them, the constant-field LTI
test case, and fits of IGRF along the orbit (``magtune fit-field``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MICRO_TESLA = 1e-6

#: Fourier coefficients (tesla) of the paper's eq. (26), our reading:
#: b = 1e-6 [7 cos + 48 sin ; 23 cos - 2 sin ; 5]  (radial ~2 B0, along-track ~B0, B0 ~ 25 uT).
EQ26 = dict(
    mean=np.array([0.0, 0.0, 5.0]) * MICRO_TESLA,
    cos=np.array([[7.0, 23.0, 0.0]]) * MICRO_TESLA,
    sin=np.array([[48.0, -2.0, 0.0]]) * MICRO_TESLA,
)
#: Literal reading, rows in extraction order: 1e-6 [7 cos + 48 sin ; -6 ; 23 cos - 2 sin].
EQ26_LITERAL = dict(
    mean=np.array([0.0, -6.0, 0.0]) * MICRO_TESLA,
    cos=np.array([[7.0, 0.0, 23.0]]) * MICRO_TESLA,
    sin=np.array([[48.0, 0.0, -2.0]]) * MICRO_TESLA,
)
FIELD_MODELS = ("eq26", "eq26_literal", "constant")


@dataclass(frozen=True)
class FourierField:
    """Periodic field b(t) = mean + sum_k [cos_k cos(k w t) + sin_k sin(k w t)] in orbital axes [T].

    ``cos`` and ``sin`` have shape (H, 3): row k-1 holds harmonic k of the orbital rate ``omega``.
    """

    omega: float
    mean: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    name: str = "fourier"

    def __post_init__(self):
        mean = np.asarray(self.mean, dtype=float).reshape(3)
        cos = np.asarray(self.cos, dtype=float).reshape(-1, 3)
        sin = np.asarray(self.sin, dtype=float).reshape(-1, 3)
        if cos.shape != sin.shape:
            raise ValueError(f"field '{self.name}': cos {cos.shape} and sin {sin.shape} coefficients differ in shape")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cos)) and np.all(np.isfinite(sin))):
            raise ValueError(f"field '{self.name}': coefficients must be finite")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cos", cos)
        object.__setattr__(self, "sin", sin)

    @property
    def period(self) -> float:
        """Period 2 pi / omega [s] of the field (the orbit period).

        Returns
        -------
        float
            2 pi / omega [s].
        """
        return 2.0 * np.pi / self.omega

    @property
    def is_constant(self) -> bool:
        """True when every harmonic is zero (a constant field in orbital axes).

        Returns
        -------
        bool
            True if all ``cos`` and ``sin`` coefficients are zero.
        """
        return not (np.any(self.cos) or np.any(self.sin))

    def __call__(self, t) -> np.ndarray:
        """b(t) in orbital axes, shape t.shape + (3,)."""
        t = np.asarray(t, dtype=float)
        k = np.arange(1, self.cos.shape[0] + 1)
        ang = self.omega * t[..., None] * k  # (..., H)
        return self.mean + np.cos(ang) @ self.cos + np.sin(ang) @ self.sin


def paper_field(omega: float, reading: str = "eq26", constant=None) -> FourierField:
    """The named design-model field: 'eq26' (SPEC reading), 'eq26_literal', or 'constant'.

    Parameters
    ----------
    omega : float
        Orbital rate W0 [rad/s] of the Fourier series.
    reading : str
        Field model name, one of :data:`FIELD_MODELS`.
    constant : array_like (3,) or None
        Field [T] in orbital axes; used (and required) only for ``reading = "constant"``.

    Returns
    -------
    FourierField
        The paper's eq. (26) field (either reading) or the constant field, named after ``reading``.

    Raises
    ------
    ValueError
        If ``reading`` is "constant" and ``constant`` is None, or ``reading`` is not in :data:`FIELD_MODELS`.
    """
    if reading == "eq26":
        return FourierField(omega, name="eq26", **EQ26)
    if reading == "eq26_literal":
        return FourierField(omega, name="eq26_literal", **EQ26_LITERAL)
    if reading == "constant":
        if constant is None:
            raise ValueError("field model 'constant' needs constant_field: [bx, by, bz] in tesla")
        zero = np.zeros((1, 3))
        return FourierField(omega, mean=constant, cos=zero, sin=zero, name="constant")
    raise ValueError(f"unknown field model '{reading}': expected one of {', '.join(FIELD_MODELS)}")
