"""Continuous–discrete multiplicative extended Kalman filter on attitude and rate.

State: the attitude quaternion q̂ (orbital → body) and the inertial body rate
ω̂; the filter's error state is ``δx = [δθ, δω]`` (6), with the true attitude
``A(q) = (I − [δθ×]) A(q̂)``. Keeping the quaternion out of the covariance
keeps P 6×6, symmetric positive definite and q̂ exactly unit (the reset folds
δθ into q̂ after each update) — the standard MEKF (Markley & Crassidis, ch. 6).

Error dynamics (analytic; ``F`` below, checked against finite differences):

    δθ̇ = −[ω̂×] δθ + δω
    J δω̇ = ([(Jω̂ + h)×] − [ω̂×] J) δω + 3n² ([r̂×] J − [(J r̂)×]) [r̂×] δθ + w

with r̂ the nadir in body axes and w the process-noise torque. A vector
measurement ``b = A(q) r + v`` (sun or earth direction, r known in the orbital
frame) has ``H = [[A(q̂) r ×], 0]``.

Prediction propagates q̂, ω̂ with the plant's own RK4 (known wheel torques and
momenta, modelled disturbances) and P with Φ = expm(F·dt) and the matching
discrete process noise (Van Loan). Updates use the Joseph form.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.linalg import expm

from rwlab.attitude.frames import GEO_RATE, dcm, qmul, skew

__all__ = ["MEKF", "error_jacobian", "gated_update", "vector_jacobian"]


@njit(cache=True)
def error_jacobian(q, w, h, J, J_inv, n, gg_gain):
    """F (6×6) of the error dynamics at (q̂, ω̂) with wheel momentum h (body axes)."""
    r = dcm(q)[:, 2].copy()
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(w)
    F[:3, 3:] = np.eye(3)
    F[3:, :3] = J_inv @ (gg_gain * (skew(r) @ J - skew(J @ r)) @ skew(r))
    F[3:, 3:] = J_inv @ (skew(J @ w + h) - skew(w) @ J)
    return F


@njit(cache=True)
def vector_jacobian(q, ref):
    """Predicted body vector A(q̂) r and its H (3×6)."""
    b = dcm(q) @ ref
    H = np.zeros((3, 6))
    H[:, :3] = skew(b)
    return b, H


@njit(cache=True)
def _update(q, w, P, b_meas, ref, sigma):
    """One vector-measurement update; returns q, w, P (Joseph form, symmetric)."""
    q, w, P, _ = gated_update(q, w, P, b_meas, ref, sigma, 0.0)
    return q, w, P


@njit(cache=True)
def gated_update(q, w, P, b_meas, ref, sigma, gate):
    """:func:`_update` behind an innovation gate: returns q, w, P and whether it was applied.

    The measurement is rejected (estimate and P unchanged) when its normalised
    innovation ν' S⁻¹ ν exceeds ``gate`` (a χ² bound; 0: no gate). The innovation
    of a unit vector has two degrees of freedom (its part along b is second order).
    """
    b, H = vector_jacobian(q, ref)
    R = sigma * sigma * np.eye(3)
    S = H @ P @ H.T + R
    S_inv = np.linalg.inv(S)
    nu = b_meas - b
    if gate > 0 and nu @ S_inv @ nu > gate:
        return q, w, P, False
    K = P @ H.T @ S_inv
    dx = K @ nu
    IKH = np.eye(6) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    dq = np.empty(4)
    dq[:3] = 0.5 * dx[:3]
    dq[3] = 1.0
    q = qmul(dq, q)
    q /= np.sqrt(q @ q)
    return q, w + dx[3:], P, True


class MEKF:
    """The filter. ``predict`` with the plant model, ``update`` per vector measurement.

    Parameters
    ----------
    J : array_like, shape (3, 3)
        Satellite inertia, kg·m².
    q0, w0 : array_like
        Initial estimates (scalar-last quaternion; rad/s).
    P0 : array_like, shape (6, 6)
        Initial error covariance (rad², (rad/s)²).
    torque_psd : float
        Process noise: power spectral density of the unmodelled torque, N²·m²·s.
    n : float
        Orbital rate, rad/s.
    gg_gain : float
        3n² (0 to leave gravity gradient out of the model).
    """

    def __init__(
        self, J, q0, w0, P0, torque_psd: float, n: float = GEO_RATE, gg_gain: float | None = None
    ) -> None:
        self.J = np.asarray(J, float)
        self.J_inv = np.linalg.inv(self.J)
        self.q = np.asarray(q0, float) / np.linalg.norm(q0)
        self.w = np.asarray(w0, float).copy()
        self.P = np.asarray(P0, float).copy()
        self.n = n
        self.gg_gain = 3 * n * n if gg_gain is None else gg_gain
        self.torque_psd = float(torque_psd)
        self._cache: tuple | None = None

    def _discrete(self, F: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Φ and Q_d for this F over dt (Van Loan), cached while F barely changes."""
        if (
            self._cache is not None
            and self._cache[0] == dt
            and np.allclose(self._cache[1], F, rtol=1e-3, atol=1e-12)
        ):
            return self._cache[2], self._cache[3]
        G = np.zeros((6, 3))
        G[3:] = self.J_inv
        Qc = G @ (self.torque_psd * np.eye(3)) @ G.T
        M = np.zeros((12, 12))
        M[:6, :6] = -F
        M[:6, 6:] = Qc
        M[6:, 6:] = F.T
        E = expm(M * dt)
        Phi = E[6:, 6:].T
        Qd = Phi @ E[:6, 6:]
        Qd = 0.5 * (Qd + Qd.T)
        self._cache = (dt, F.copy(), Phi, Qd)
        return Phi, Qd

    def predict(self, x_next_model: np.ndarray, h_body: np.ndarray, dt: float) -> None:
        """Move to the next step: ``x_next_model`` is the plant model propagated from
        the current estimate (q̂, ω̂, wheel momenta) over ``dt``."""
        F = error_jacobian(self.q, self.w, h_body, self.J, self.J_inv, self.n, self.gg_gain)
        Phi, Qd = self._discrete(F, dt)
        self.q = x_next_model[:4] / np.linalg.norm(x_next_model[:4])
        self.w = x_next_model[4:7].copy()
        self.P = Phi @ self.P @ Phi.T + Qd
        self.P = 0.5 * (self.P + self.P.T)

    def update(self, b_meas: np.ndarray, ref: np.ndarray, sigma: float) -> None:
        """Fuse a unit-vector measurement ``b_meas`` (body) of ``ref`` (orbital), σ in rad."""
        self.q, self.w, self.P = _update(
            self.q, self.w, self.P, np.asarray(b_meas, float), np.asarray(ref, float), float(sigma)
        )

    def error(self, q_true: np.ndarray, w_true: np.ndarray) -> np.ndarray:
        """Estimation error δx = [δθ, δω] with A(q) = (I − [δθ×]) A(q̂), for NEES tests."""
        dq = qmul(q_true, np.array([-self.q[0], -self.q[1], -self.q[2], self.q[3]]))
        dq = dq if dq[3] >= 0 else -dq
        return np.concatenate([2 * dq[:3], w_true - self.w])


@njit(cache=True)
def predict_covariance(P, F, Qc, T):
    """P⁺ = Φ P Φᵀ + Q_d over T, Φ and Q_d to third order in F·T (the δθ̇ = δω block
    makes F·T of order 1 at a 0.5 s sensor period, so first order would not do)."""
    FT = F * T
    F2 = F @ F
    Phi = np.eye(6) + FT + 0.5 * FT @ FT + F2 @ FT * (T * T / 6.0)
    FQ = F @ Qc
    Qd = Qc * T + 0.5 * T * T * (FQ + FQ.T) + T**3 / 3.0 * (FQ @ F.T + 0.5 * (F2 @ Qc + Qc @ F2.T))
    P = Phi @ P @ Phi.T + Qd
    return 0.5 * (P + P.T)
