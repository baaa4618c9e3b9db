"""Linear time-periodic attitude model of a magnetically actuated, momentum-biased satellite.

Paper section 3 (eqs. 11-19) as read in SPEC.md. State x = [dq (3); dw (3)]: vector part of
the body-to-orbital quaternion and the deviation of the inertial body rate from [0, 0, -W0].
Axes: X yaw (to Earth's centre), Y roll (along velocity), Z pitch (= X x Y: minus the orbit normal,
opposite the orbital angular momentum r x v).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base.rotations import skew_field
from .field import FourierField
from .params import SpacecraftParams

Z_ATT = np.hstack([np.eye(3), np.zeros((3, 3))])  #: Z = [I3 0], picks dq (paper eq. 20)


def state_matrix(p: SpacecraftParams) -> np.ndarray:
    """A of paper eq. (15): quaternion kinematics, gravity gradient and gyroscopic wheel coupling.

    Parameters
    ----------
    p : SpacecraftParams
        Inertia, wheel and orbit data.

    Returns
    -------
    ndarray (6, 6)
        State matrix A of x = [dq; dw].
    """
    Ixx, Iyy, Izz = p.inertia
    w0 = p.orbit_rate
    kx, ky, kz = (Iyy - Izz) / Ixx, (Izz - Ixx) / Iyy, (Ixx - Iyy) / Izz
    wx = -kx * w0 + p.wheel_inertia / Ixx * p.wheel_speed
    wy = -ky * w0 - p.wheel_inertia / Iyy * p.wheel_speed
    A = np.zeros((6, 6))
    A[0, 1], A[1, 0] = -w0, w0
    A[0, 3] = A[1, 4] = A[2, 5] = 0.5
    A[3, 4] = wx
    A[4, 1], A[4, 3] = -6.0 * ky * w0**2, wy
    A[5, 2] = 6.0 * kz * w0**2
    return A


def torque_input(p: SpacecraftParams) -> np.ndarray:
    """B_T = [0; I^-1] of paper eq. (16): body torque to state derivative.

    Parameters
    ----------
    p : SpacecraftParams
        Spacecraft whose principal moments of inertia [kg m^2] are used.

    Returns
    -------
    ndarray (6, 3)
        Torque input matrix B_T [1/(kg m^2)] in its lower block.
    """
    return np.vstack([np.zeros((3, 3)), np.diag(1.0 / p.inertia)])




def projector(b) -> np.ndarray:
    """S(b) S(b)^T / |b|^2 = I - b b^T / |b|^2 (paper eq. 18): projection orthogonal to b.

    Parameters
    ----------
    b : array_like (..., 3)
        Magnetic field vectors (any units; nonzero).

    Returns
    -------
    ndarray (..., 3, 3)
        Projector onto the plane orthogonal to each b.
    """
    b = np.asarray(b, dtype=float)
    bn = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.eye(3) - bn[..., :, None] * bn[..., None, :]


def projection_dipole(K, x, b) -> np.ndarray:
    """Projection-based law m = S(b)^T K x / |b|^2 (paper eq. 17), vectorized over leading axes.

    Parameters
    ----------
    K : array_like (..., 3, 6)
        Gain(s).
    x : array_like (..., 6)
        State(s) [dq; dw] (dw in rad/s).
    b : array_like (..., 3)
        Magnetic field [T] in body axes.

    Returns
    -------
    ndarray (..., 3)
        Commanded dipole m [A m^2] (for b in tesla and u = K x in N m).
    """
    u = np.einsum("...ij,...j->...i", K, x)
    S = skew_field(b)
    return np.einsum("...ji,...j->...i", S, u) / np.sum(np.asarray(b) ** 2, axis=-1)[..., None]


@dataclass(frozen=True)
class AttitudeLTP:
    """The LTP design model x' = A x + B(t) u + B_T T_d of paper eq. (19)."""

    params: SpacecraftParams
    field: FourierField

    @classmethod
    def from_params(cls, p: SpacecraftParams, field_model: str | None = None) -> "AttitudeLTP":
        """The model of ``p`` with its field model (or ``field_model``, a name of ``design.field.FIELD_MODELS``).

        Parameters
        ----------
        p : SpacecraftParams
            Spacecraft and orbit.
        field_model : str or None
            Field model overriding ``p.field_model``; None keeps it.

        Returns
        -------
        AttitudeLTP
            The model of ``p`` with field ``p.field(field_model)``.
        """
        return cls(p, p.field(field_model))

    @property
    def period(self) -> float:
        """Period T [s] of the LTP model: the field's (the orbit's).

        Returns
        -------
        float
            T [s].
        """
        return self.field.period

    @property
    def A(self) -> np.ndarray:
        """Constant state matrix A of the linearized attitude dynamics (paper section 3, eqs. 11-19), 6 x 6.

        Returns
        -------
        ndarray (6, 6)
            :func:`state_matrix` of ``params``.
        """
        return state_matrix(self.params)

    @property
    def BT(self) -> np.ndarray:
        """Torque input matrix (u -> x), 6 x 3 (paper section 3).

        Returns
        -------
        ndarray (6, 3)
            :func:`torque_input` of ``params``.
        """
        return torque_input(self.params)

    def B(self, t) -> np.ndarray:
        """B(t) = B_T S(b) S(b)^T / |b|^2, shape t.shape + (6, 3) (paper eq. 19).

        Parameters
        ----------
        t : float or array_like
            Time(s) [s] since the start of the period.

        Returns
        -------
        ndarray (t.shape + (6, 3))
            Input matrix B(t) of the torque u = K x.
        """
        return self.BT @ projector(self.field(t))

    def B_mean(self, samples: int = 4096) -> np.ndarray:
        """Time average (1/T) int_0^T B(t) dt (trapezoid on a periodic grid: spectrally accurate).

        Parameters
        ----------
        samples : int
            Points of the uniform grid over one period.

        Returns
        -------
        ndarray (6, 3)
            The averaged input matrix Bbar.
        """
        t = np.arange(samples) * self.period / samples
        return self.B(t).mean(axis=0)

    def closed_loop(self, K):
        """t -> A + B(t) K for a gain or a batch of gains K (..., 3, 6): shape (..., nt, 6, 6).

        Parameters
        ----------
        K : array_like (..., 3, 6)
            Gain or batch of gains.

        Returns
        -------
        callable
            ``a_cl(t)``: times (nt,) [s] (a scalar is taken as (1,)) -> ndarray (..., nt, 6, 6).
        """
        K = np.asarray(K, dtype=float)
        A = self.A

        def a_cl(t):
            Bt = self.B(np.atleast_1d(t))  # (nt, 6, 3)
            return A + np.einsum("tij,...jk->...tik", Bt, K)

        return a_cl

    def dipole_output(self, K):
        """t -> C_m(t) = S(b)^T K / |b|^2, the map x -> m of paper eq. (17): shape (..., nt, 3, 6).

        Parameters
        ----------
        K : array_like (..., 3, 6)
            Gain or batch of gains.

        Returns
        -------
        callable
            ``c_m(t)``: times (nt,) [s] (a scalar is taken as (1,)) -> ndarray (..., nt, 3, 6).
        """
        K = np.asarray(K, dtype=float)

        def c_m(t):
            b = self.field(np.atleast_1d(t))
            St = np.swapaxes(skew_field(b), -1, -2) / np.sum(b**2, axis=-1)[:, None, None]
            return np.einsum("tij,...jk->...tik", St, K)

        return c_m
