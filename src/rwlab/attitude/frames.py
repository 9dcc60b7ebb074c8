"""Orbit, frames and quaternions for a geostationary satellite.

Conventions (Markley & Crassidis, *Fundamentals of Spacecraft Attitude
Determination and Control*; paper B plots q1..q4 with q4 the scalar):

- ``q = [q1, q2, q3, q4]``, vector part first, **scalar last**, unit norm.
- ``A(q)`` (:func:`dcm`) maps vectors from the **orbital frame** to the **body**
  frame: ``v_body = A(q) v_orbital``. q = [0, 0, 0, 1] means body = orbital.
- Orbital frame (LVLH): z toward the Earth's centre (nadir), x along the
  velocity, y = z × x, i.e. the negative orbit normal. It rotates with
  respect to inertial space at ``ω_oi = [0, −n, 0]`` (orbital frame).
- ``ω`` is the body's inertial rate in body axes; ``ω_bo = ω − A(q) ω_oi``
  the rate relative to the orbital frame, and ``q̇ = ½ Ξ(q) ω_bo``.

The functions are numba-compiled so the plant's inner loop can call them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "EARTH_RADIUS",
    "GEO_RADIUS",
    "GEO_RATE",
    "MU_EARTH",
    "angle_deg",
    "dcm",
    "from_axis_angle",
    "omega_orbit",
    "qmul",
    "skew",
]

MU_EARTH = 3.986004418e14  # m³/s²
GEO_RATE = 7.2921159e-5  # rad/s, sidereal rotation rate of the Earth = GEO mean motion
GEO_RADIUS = (MU_EARTH / GEO_RATE**2) ** (1 / 3)  # 42,164 km
EARTH_RADIUS = 6.378137e6  # m
J2_EARTH = 1.08263e-3


@njit(cache=True)
def skew(v: np.ndarray) -> np.ndarray:
    """[v×], shape (3, 3)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@njit(cache=True)
def dcm(q: np.ndarray) -> np.ndarray:
    """A(q): orbital → body direction-cosine matrix of a scalar-last unit quaternion,
    (q4² − e·e) I + 2 e eᵀ − 2 q4 [e×] with e = q[:3].

    Written element by element: the same operations in the same order as the matrix
    expression (equal bit for bit), without numpy's outer product and array expressions,
    which cost numba seconds to compile on a first run.
    """
    e = q[:3].copy()
    q4 = q[3]
    s, c, S = q4 * q4 - e @ e, 2.0 * q4, skew(e)
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = s * (1.0 if i == j else 0.0) + 2.0 * (e[i] * e[j]) - c * S[i, j]
    return out


@njit(cache=True)
def xi(q: np.ndarray) -> np.ndarray:
    """Ξ(q), shape (4, 3): ``q̇ = ½ Ξ(q) ω``."""
    # q₄ I + [e×] over −eᵀ, element by element: slices assigned from arrays compile numba's
    # shape-checking error path, 3 s of a cold compile (measured) for twelve numbers
    e1, e2, e3, q4 = q[0], q[1], q[2], q[3]
    out = np.empty((4, 3))
    out[0, 0], out[0, 1], out[0, 2] = q4, -e3, e2
    out[1, 0], out[1, 1], out[1, 2] = e3, q4, -e1
    out[2, 0], out[2, 1], out[2, 2] = -e2, e1, q4
    out[3, 0], out[3, 1], out[3, 2] = -e1, -e2, -e3
    return out


@njit(cache=True)
def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quaternion product p ⊗ q with ``A(p ⊗ q) = A(p) A(q)`` (scalar last)."""
    pv, p4 = p[:3].copy(), p[3]
    qv, q4 = q[:3].copy(), q[3]
    out = np.empty(4)  # p4 qv + q4 pv − pv × qv, element by element (as in :func:`dcm`)
    out[0] = p4 * qv[0] + q4 * pv[0] - (pv[1] * qv[2] - pv[2] * qv[1])
    out[1] = p4 * qv[1] + q4 * pv[1] - (pv[2] * qv[0] - pv[0] * qv[2])
    out[2] = p4 * qv[2] + q4 * pv[2] - (pv[0] * qv[1] - pv[1] * qv[0])
    out[3] = p4 * q4 - pv @ qv
    return out


def from_axis_angle(axis, angle_rad: float) -> np.ndarray:
    """Unit quaternion of a rotation by ``angle_rad`` about ``axis`` (scalar last).

    Parameters
    ----------
    axis : array_like, shape (3,)
        Rotation axis (normalised here).
    angle_rad : float
        Rotation angle, rad.

    Returns
    -------
    numpy.ndarray, shape (4,)
        The quaternion, scalar last.
    """
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return np.concatenate([a * math.sin(angle_rad / 2), [math.cos(angle_rad / 2)]])


def angle_deg(q: np.ndarray) -> np.ndarray:
    """Rotation angle of q (or of each row of an (N, 4) array), degrees: the pointing error.

    Parameters
    ----------
    q : numpy.ndarray, shape (4,) or (N, 4)
        Quaternion(s), scalar last.

    Returns
    -------
    float or numpy.ndarray, shape (N,)
        The angle(s), degrees in [0, 180].
    """
    q = np.asarray(q, dtype=float)
    return np.degrees(2 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3])))


def omega_orbit(n: float = GEO_RATE) -> np.ndarray:
    """The orbital frame's inertial rate, in orbital axes, rad/s.

    Parameters
    ----------
    n : float
        Orbital rate, rad/s (GEO by default).

    Returns
    -------
    numpy.ndarray, shape (3,)
    """
    return np.array([0.0, -n, 0.0])
