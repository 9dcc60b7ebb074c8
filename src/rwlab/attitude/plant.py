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

The inner loop is numba-compiled: the whole RK4 step runs without Python.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from rwlab.attitude.frames import EARTH_RADIUS, GEO_RADIUS, GEO_RATE, J2_EARTH, dcm, xi

__all__ = ["DisturbanceModel", "derivative", "propagate"]

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


@njit(cache=True)
def disturbance_torque(q, J, dist, sun_orb, moon_orb):
    """τ_d in body axes, N·m (see the module docstring)."""
    C = dcm(q)
    r = C[:, 2].copy()  # nadir (orbital z) in body axes
    tau = dist[0] * np.cross(r, J @ r)
    s = C @ sun_orb
    tau += np.cross(dist[2:5], -dist[1] * s)
    m = C @ moon_orb
    tau += dist[5] * np.cross(s, J @ s) + dist[6] * np.cross(m, J @ m)
    tau += dist[7:10]
    return tau


@njit(cache=True)
def derivative(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb):
    """ẋ for state x with wheel torques ``hw_dot`` (N·m each), all in SI units."""
    q = x[:4].copy()  # contiguous copies: faster matrix products in numba
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


@njit(cache=True)
def propagate(x, hw_dot, dt, steps, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb):
    """``steps`` fixed RK4 steps of ``dt`` seconds with constant wheel torques; q renormalised."""
    x = x.copy()
    for _ in range(steps):
        k1 = derivative(x, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb)
        k2 = derivative(x + 0.5 * dt * k1, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb)
        k3 = derivative(x + 0.5 * dt * k2, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb)
        k4 = derivative(x + dt * k3, hw_dot, J, J_inv, G, h_max, n, dist, sun_orb, moon_orb)
        x += dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        x[:4] /= np.sqrt(x[:4] @ x[:4])
        for i in range(h_max.shape[0]):
            x[7 + i] = min(max(x[7 + i], -h_max[i]), h_max[i])
    return x
