"""The satellite with reaction wheels: rigid-body dynamics, disturbances, fixed-step RK4.

    J ω̇ = −ω × (J ω + h) − ḣ + τ_d,    h = G h_w,    q̇ = ½ Ξ(q) ω_bo

State ``x = [q1..q4, ωx, ωy, ωz, h_w1..h_wN]`` (wheel momenta in N·m·s along
the wheel axes, the columns of G). The wheels' torques ``ḣ_w`` are held
constant over each call of :func:`propagate` (a zero-order hold, as a digital
controller applies them); ideal wheels stop at their momentum limit.

Disturbances (each switchable, all in body axes):

- gravity gradient 3n² r̂ × (J r̂), r̂ the nadir direction;
- Earth oblateness: the J2 correction to that gradient at the equator,
  3·J2·(R⊕/a)² times it (≈ 7e-5 of it at GEO);
- solar radiation pressure on sun-tracking arrays: F = −P·A·C_r·ŝ acting at
  an offset r_cp from the centre of mass, τ = r_cp × F;
- Sun and Moon third-body gravity gradient 3 μ/R³ ŝ × (J ŝ);
- a constant torque (a stand-in used by the Basilisk comparison).

Wheel-spin-inertia convention. ``h_w`` is each wheel's *absolute* spin momentum,
h_w = J_s (Ω + gᵀω) (Ω its speed relative to the body, g its axis), so ḣ_w is the
motor torque, and J is the spacecraft's inertia *without* the wheels' spin-axis
inertia: J = I_sc − Σ J_s g gᵀ. Basilisk's ``reactionWheelStateEffector`` keeps Ω
as the state and I_sc with the wheels' full inertia; the two give the same
motion (tests/test_wheel_convention.py holds rwlab's trajectory to Basilisk's
equation of motion, I_sc ω̇ + Σ g J_s Ω̇ = −ω × (I_sc ω + Σ g J_s Ω) + τ), so a
Basilisk scenario's hub inertia maps to J = I_sc − Σ J_s g gᵀ. The reported
wheel speed h_w / J_s is Ω + gᵀω: at GEO gᵀω ≤ 7.3e-5 rad/s (7e-4 rpm).

The inner loop is numba-compiled: the whole RK4 step runs without Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rwlab.attitude.frames import EARTH_RADIUS, GEO_RADIUS, GEO_RATE, J2_EARTH, dcm, xi

__all__ = ["DisturbanceModel", "derivative", "propagate", "rk4_step", "rk4_step_forced"]

SOLAR_PRESSURE = 4.56e-6  # N/m² at 1 AU
SUN_TIDE = 1.32712440018e20 / 1.495978707e11**3  # μ/R³ of the Sun at 1 AU, 1/s²
MOON_TIDE = 4.9048695e12 / 3.844e8**3  # μ/R³ of the Moon, 1/s²


@dataclass(frozen=True)
class DisturbanceModel:
    """Which disturbance torques act, and the SRP geometry.

    Attributes
    ----------
    gravity_gradient, oblateness, solar_pressure, third_body : bool
    srp_area : float
        Sunlit area, m².
    srp_reflectivity : float
        C_r (1 = absorbing, 2 = mirror).
    srp_offset : tuple of float
        Centre of pressure minus centre of mass, body axes, m.
    constant_torque : tuple of float
        An extra constant body torque, N·m.
    """

    gravity_gradient: bool = True
    oblateness: bool = True
    solar_pressure: bool = True
    third_body: bool = True
    srp_area: float = 30.0
    srp_reflectivity: float = 1.3
    srp_offset: tuple[float, float, float] = (0.3, -0.2, 0.5)
    constant_torque: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def vector(self) -> np.ndarray:
        """The flat parameter vector the compiled kernel reads."""
        gg = (
            3
            * GEO_RATE**2
            * (
                float(self.gravity_gradient)
                + float(self.oblateness) * 3 * J2_EARTH * (EARTH_RADIUS / GEO_RADIUS) ** 2
            )
        )
        srp = SOLAR_PRESSURE * self.srp_area * self.srp_reflectivity * float(self.solar_pressure)
        tb = float(self.third_body)
        return np.array(
            [
                gg,
                srp,
                *self.srp_offset,
                3 * SUN_TIDE * tb,
                3 * MOON_TIDE * tb,
                *self.constant_torque,
            ]
        )


def disturbance_torque(q, J, dist, sun_orb, moon_orb):
    """The disturbance torque (see the module docstring).

    Parameters
    ----------
    q : ndarray, shape (4,)
        Orbital → body, scalar last.
    J : ndarray, shape (3, 3)
        The inertia without the wheels' spin inertia, kg·m².
    dist : ndarray, shape (10,)
        :meth:`DisturbanceModel.vector`: the gains and the constant torque.
    sun_orb, moon_orb : ndarray, shape (3,)
        The Sun's and the Moon's unit vectors in orbital axes.

    Returns
    -------
    ndarray, shape (3,)
        τ_d in body axes, N·m.
    """
    C = dcm(q)
    r = C[:, 2].copy()  # nadir (orbital z) in body axes
    tau = dist[0] * np.cross(r, J @ r)
    s = C @ sun_orb
    tau += np.cross(dist[2:5], -dist[1] * s)
    m = C @ moon_orb
    tau += dist[5] * np.cross(s, J @ s) + dist[6] * np.cross(m, J @ m)
    tau += dist[7:10]
    return tau


def derivative(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb):
    """ẋ for state x with wheel torques ``hw_dot``, all in SI units.

    The readable reference, in plain numpy (only the tests call it); :func:`propagate`
    runs its compiled scalar twin ``_derivative_into``.

    Parameters
    ----------
    x : ndarray, shape (7 + N,)
        [q (scalar last), ω (rad/s), h_w (N·m·s)].
    hw_dot : ndarray, shape (N,)
        The wheels' torques, N·m.
    J, J_inv : ndarray, shape (3, 3)
        The inertia without the wheels' spin inertia (kg·m²) and its inverse.
    G : ndarray, shape (3, N)
        The wheels' axes in body axes.
    h_max : ndarray, shape (N,)
        Each wheel's momentum limit, N·m·s.
    n : float
        The orbit rate, rad/s.
    dist, sun_orb, moon_orb : ndarray
        As :func:`disturbance_torque` takes them.

    Returns
    -------
    ndarray, shape (7 + N,)
        ẋ.
    """
    q = x[:4].copy()
    w = x[4:7].copy()
    hw = x[7:].copy()
    nw = hw.shape[0]
    hd = hw_dot.copy()
    for i in range(nw):  # a wheel at its momentum limit cannot be pushed further
        if abs(hw[i]) >= h_max[i] and hd[i] * hw[i] > 0:
            hd[i] = 0.0
    C = dcm(q)
    w_bo = w - C @ np.array([0.0, -n, 0.0])
    h = G @ hw
    tau = disturbance_torque(q, J, dist, sun_orb, moon_orb)
    out = np.empty_like(x)
    out[:4] = 0.5 * (xi(q) @ w_bo)
    out[4:7] = J_inv @ (-np.cross(w, J @ w + h) - G @ hd + tau)
    out[7:] = hd
    return out


# The scalar twin's helpers are compiled once and inlined by LLVM (``forceinline``), not by
# numba, which would compile ``_derivative_into`` four times in ``rk4_step`` and ``_mv`` 20
# times: the same machine code, 2 s of compile instead of 5 (measured).
@njit(cache=True, forceinline=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, forceinline=True)
def _mv(M, a0, a1, a2):
    """M @ a for a 3×3 M, as a tuple (no array is allocated)."""
    return (
        M[0, 0] * a0 + M[0, 1] * a1 + M[0, 2] * a2,
        M[1, 0] * a0 + M[1, 1] * a1 + M[1, 2] * a2,
        M[2, 0] * a0 + M[2, 1] * a1 + M[2, 2] * a2,
    )


@njit(cache=True, forceinline=True)
def _derivative_into(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, out):
    """:func:`derivative` written with scalars into ``out``: the same maths, no temporaries.

    Hand-written because this is the loop's inner call (8 per step): numba
    allocates every small array the readable version creates. A test holds the
    two equal to round-off.
    """
    q1, q2, q3, q4 = x[0], x[1], x[2], x[3]
    s = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    c00, c11, c22 = s + 2 * q1 * q1, s + 2 * q2 * q2, s + 2 * q3 * q3
    c01, c10 = 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q2 - q4 * q3)
    c02, c20 = 2 * (q1 * q3 - q4 * q2), 2 * (q1 * q3 + q4 * q2)
    c12, c21 = 2 * (q2 * q3 + q4 * q1), 2 * (q2 * q3 - q4 * q1)
    w0, w1, w2 = x[4], x[5], x[6]
    b0, b1, b2 = w0 + n * c01, w1 + n * c11, w2 + n * c21  # ω_bo = ω − C (0, −n, 0)
    out[0] = 0.5 * (q4 * b0 + q2 * b2 - q3 * b1)
    out[1] = 0.5 * (q4 * b1 + q3 * b0 - q1 * b2)
    out[2] = 0.5 * (q4 * b2 + q1 * b1 - q2 * b0)
    out[3] = -0.5 * (q1 * b0 + q2 * b1 + q3 * b2)
    nw = h_max.shape[0]
    h0 = h1 = h2 = 0.0  # wheel momentum and torque in body axes
    g0 = g1 = g2 = 0.0
    for i in range(nw):
        hw, hd = x[7 + i], hw_dot[i]
        if abs(hw) >= h_max[i] and hd * hw > 0:  # a wheel at its limit cannot be pushed further
            hd = 0.0
        out[7 + i] = hd
        h0 += G[0, i] * hw
        h1 += G[1, i] * hw
        h2 += G[2, i] * hw
        g0 += G[0, i] * hd
        g1 += G[1, i] * hd
        g2 += G[2, i] * hd
    # disturbances (see disturbance_torque)
    r0, r1, r2 = c02, c12, c22
    j0, j1, j2 = _mv(J, r0, r1, r2)
    t0, t1, t2 = _cross(r0, r1, r2, j0, j1, j2)
    t0, t1, t2 = dist[0] * t0, dist[0] * t1, dist[0] * t2
    s0 = c00 * sun_orb[0] + c01 * sun_orb[1] + c02 * sun_orb[2]
    s1 = c10 * sun_orb[0] + c11 * sun_orb[1] + c12 * sun_orb[2]
    s2 = c20 * sun_orb[0] + c21 * sun_orb[1] + c22 * sun_orb[2]
    p0, p1, p2 = _cross(dist[2], dist[3], dist[4], s0, s1, s2)
    t0, t1, t2 = t0 - dist[1] * p0, t1 - dist[1] * p1, t2 - dist[1] * p2
    j0, j1, j2 = _mv(J, s0, s1, s2)
    p0, p1, p2 = _cross(s0, s1, s2, j0, j1, j2)
    t0, t1, t2 = t0 + dist[5] * p0, t1 + dist[5] * p1, t2 + dist[5] * p2
    m0 = c00 * moon_orb[0] + c01 * moon_orb[1] + c02 * moon_orb[2]
    m1 = c10 * moon_orb[0] + c11 * moon_orb[1] + c12 * moon_orb[2]
    m2 = c20 * moon_orb[0] + c21 * moon_orb[1] + c22 * moon_orb[2]
    j0, j1, j2 = _mv(J, m0, m1, m2)
    p0, p1, p2 = _cross(m0, m1, m2, j0, j1, j2)
    t0, t1, t2 = (
        t0 + dist[6] * p0 + dist[7],
        t1 + dist[6] * p1 + dist[8],
        t2 + dist[6] * p2 + dist[9],
    )
    # J ω̇ = −ω × (J ω + h) − G ḣ_w + τ
    j0, j1, j2 = _mv(J, w0, w1, w2)
    p0, p1, p2 = _cross(w0, w1, w2, j0 + h0, j1 + h1, j2 + h2)
    a0, a1, a2 = _mv(J_inv, -p0 - g0 + t0, -p1 - g1 + t1, -p2 - g2 + t2)
    out[4], out[5], out[6] = a0, a1, a2


@njit(cache=True)
def rk4_step(x, hw_dot, dt, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, work):
    """One RK4 step of ``dt`` seconds on ``x`` in place (q renormalised, wheels clipped).

    ``work`` is a (5, len(x)) scratch array: the kernel calls this every step and
    allocates nothing.
    """
    m = x.shape[0]
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]
    _derivative_into(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, k1)
    for i in range(m):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    _derivative_into(xt, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, k2)
    for i in range(m):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    _derivative_into(xt, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, k3)
    for i in range(m):
        xt[i] = x[i] + dt * k3[i]
    _derivative_into(xt, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, k4)
    for i in range(m):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    norm = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
    for i in range(4):
        x[i] /= norm
    for i in range(h_max.shape[0]):
        x[7 + i] = min(max(x[7 + i], -h_max[i]), h_max[i])


@njit(cache=True)
def rk4_step_forced(x, hw_dot, dt, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, work, forcing):
    """:func:`rk4_step` with an extra body torque that changes within the step: ``forcing``
    (3, 3) N·m at the step's start, middle and end (the RK4 stages' times), e.g. the wheels'
    imbalance turning with the rotors. ``dist`` is used as scratch and restored.

    Written beside :func:`rk4_step` rather than through it: the balanced loop keeps its
    step as it was (bit for bit, and as fast).
    """
    m = x.shape[0]
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]
    base0, base1, base2 = dist[7], dist[8], dist[9]
    stage = (0, 1, 1, 2)
    ks = (k1, k2, k3, k4)
    for s in range(4):
        dist[7] = base0 + forcing[stage[s], 0]
        dist[8] = base1 + forcing[stage[s], 1]
        dist[9] = base2 + forcing[stage[s], 2]
        if s == 0:
            _derivative_into(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, k1)
        else:
            h = dt if s == 3 else 0.5 * dt
            prev = ks[s - 1]
            for i in range(m):
                xt[i] = x[i] + h * prev[i]
            _derivative_into(xt, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, ks[s])
    dist[7], dist[8], dist[9] = base0, base1, base2
    for i in range(m):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    norm = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
    for i in range(4):
        x[i] /= norm
    for i in range(h_max.shape[0]):
        x[7 + i] = min(max(x[7 + i], -h_max[i]), h_max[i])


@njit(cache=True)
def propagate(x, hw_dot, dt, steps, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb):
    """``steps`` fixed RK4 steps of ``dt`` seconds with constant wheel torques; returns a new x."""
    x = x.copy()
    work = np.empty((5, x.shape[0]))
    for _ in range(steps):
        rk4_step(x, hw_dot, dt, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb, work)
    return x
