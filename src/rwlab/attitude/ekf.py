"""Continuous–discrete multiplicative extended Kalman filter on attitude and rate.

State: the attitude quaternion q̂ (orbital → body), the inertial body rate
ω̂ and, optionally, a disturbance state b̂ (3 or 6 values, N·m, random walks:
disturbance accommodation of torques the filter does not model) acting as the
torque ``B b̂``; the filter's error state is ``δx = [δθ, δω]`` (n = 6) or
``[δθ, δω, δb]`` (n = 9 or 12), with the true attitude ``A(q) = (I − [δθ×]) A(q̂)``.
Keeping the quaternion out of the covariance keeps P n×n, symmetric positive
definite and q̂ exactly unit (the reset folds δθ into q̂ after each update) —
the standard MEKF (Markley & Crassidis, ch. 6). Every function takes n from P
(or F); ``w`` is the rest of the state after q, ``[ω̂]`` (3,) or ``[ω̂, b̂]``.

Two disturbance states, alone or together (``bias_map`` B, their columns side by
side): a constant body torque, B = I; and solar pressure through an unknown
centre of pressure, B = ν [ŝ×] with ŝ the Sun in
body axes and ν the sunlit fraction (both known from the ephemeris): SRP's
torque is ρ × F = P A C_r ν ŝ × ρ, linear in the lever arm β = P A C_r ρ,
which is what b̂ estimates. It turns with the Sun in the body frame, so it
stays right through an outage where a frozen torque would not.

Error dynamics (analytic; ``F`` below, checked against finite differences):

    δθ̇ = −[ω̂×] δθ + δω
    J δω̇ = ([(Jω̂ + h)×] − [ω̂×] J) δω + 3n² ([r̂×] J − [(J r̂)×]) [r̂×] δθ + B δb + w
    δḃ = w_b

with r̂ the nadir in body axes, w the process-noise torque and w_b the
random-walk noise. The SRP state's torque also depends on δθ through ŝ
(−ν [β̂×][ŝ×] δθ, first order and larger than the gravity-gradient term): it is
left out of F, which an expert review measured to change the equinox day's
steady maximum by 1e-5° (0.04859° → 0.04860°). A vector measurement ``b = A(q) r + v`` (sun or earth
direction, r known in the orbital frame) has ``H = [[A(q̂) r ×], 0, 0]``.

Prediction propagates q̂, ω̂ with the plant's own RK4 (known wheel torques and
momenta, modelled disturbances) and P with Φ = expm(F·dt) and the matching
discrete process noise (Van Loan). Updates use the Joseph form.

Why this module is long: every step of the filter (Jacobian, covariance prediction,
measurement updates with their gate, the reset) is here twice on purpose — a readable
reference in plain numpy and the allocation-free twin the compiled loop calls, tested
against each other — and the two only make sense side by side. The references are not
compiled: only the tests call them, and compiling them cost a fresh clone's suite ~9 s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rwlab.attitude.frames import dcm, qmul, skew

__all__ = [
    "error_jacobian",
    "gated_update",
    "gated_update_into",
    "predict_covariance",
    "vector_jacobian",
]


def error_jacobian(q, w, h, J, J_inv, n, gg_gain, bias_map=None):
    """F of the error dynamics at (q̂, ω̂) (the module docstring's equations).

    Parameters
    ----------
    q : ndarray, shape (4,)
        q̂, orbital → body, scalar last.
    w : ndarray, shape (3,)
        ω̂, rad/s.
    h : ndarray, shape (3,)
        The wheels' momentum in body axes, N·m·s.
    J, J_inv : ndarray, shape (3, 3)
        The inertia without the wheels' spin inertia (kg·m²) and its inverse.
    n : float
        The orbit rate, rad/s (unused: the gradient's gain carries it).
    gg_gain : float
        The gravity gradient's gain 3n² (times 1 + the J2 correction), s⁻².
    bias_map : ndarray, shape (3, m), optional
        The disturbance state's torque map B; None: no disturbance state.

    Returns
    -------
    ndarray, shape (d, d)
        F, d = 6, or 6 + m with ``bias_map``.
    """
    r = dcm(q)[:, 2].copy()
    dim = 6 if bias_map is None else 6 + bias_map.shape[1]
    F = np.zeros((dim, dim))
    F[:3, :3] = -skew(w)
    F[:3, 3:6] = np.eye(3)
    F[3:6, :3] = J_inv @ (gg_gain * (skew(r) @ J - skew(J @ r)) @ skew(r))
    F[3:6, 3:6] = J_inv @ (skew(J @ w + h) - skew(w) @ J)
    if bias_map is not None:
        F[3:6, 6:] = J_inv @ bias_map
    return F


def vector_jacobian(q, ref, dim=6):
    """A vector sensor's prediction and its measurement matrix.

    Parameters
    ----------
    q : ndarray, shape (4,)
        q̂, orbital → body, scalar last.
    ref : ndarray, shape (3,)
        The unit vector in orbital axes (the Sun, the nadir).
    dim : int
        The error state's size d.

    Returns
    -------
    b : ndarray, shape (3,)
        The predicted body vector A(q̂) ref.
    H : ndarray, shape (3, d)
        ∂b/∂δx: [b×] on δθ, zeros elsewhere.
    """
    b = dcm(q) @ ref
    H = np.zeros((3, dim))
    H[:, :3] = skew(b)
    return b, H


def _update(q, w, P, b_meas, ref, sigma):
    """One vector-measurement update; returns q, w, P (Joseph form, symmetric).
    w: (n − 3,) the state after q, [ω̂] or [ω̂, b̂]."""
    q, w, P, _ = gated_update(q, w, P, b_meas, ref, sigma, 0.0)
    return q, w, P


def gated_update(q, w, P, b_meas, ref, sigma, gate):
    """One vector-measurement update (Joseph form) behind an innovation gate.

    The measurement is rejected (estimate and P unchanged) when its normalised
    innovation ν' S⁻¹ ν exceeds ``gate`` (a χ² bound; 0: no gate). The innovation
    of a unit vector has two degrees of freedom (its part along b is second order).

    Parameters
    ----------
    q : ndarray, shape (4,)
        q̂, orbital → body, scalar last.
    w : ndarray, shape (d − 3,)
        The state after q: [ω̂] (rad/s) or [ω̂, b̂].
    P : ndarray, shape (d, d)
        The error state's covariance.
    b_meas : ndarray, shape (3,)
        The measured unit vector, body axes.
    ref : ndarray, shape (3,)
        The same vector in orbital axes.
    sigma : float
        The sensor's noise per axis (rad on a unit vector).
    gate : float
        The χ² bound on the normalised innovation; 0: no gate.

    Returns
    -------
    q, w, P : ndarray
        The updated estimate and covariance (symmetric), new arrays.
    applied : bool
        False when the gate rejected the measurement.
    """
    dim = P.shape[0]
    b, H = vector_jacobian(q, ref, dim)
    R = sigma * sigma * np.eye(3)
    S = H @ P @ H.T + R
    S_inv = np.linalg.inv(S)
    nu = b_meas - b
    if gate > 0 and nu @ S_inv @ nu > gate:
        return q, w, P, False
    K = P @ H.T @ S_inv
    dx = K @ nu
    IKH = np.eye(dim) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    dq = np.empty(4)
    dq[:3] = 0.5 * dx[:3]
    dq[3] = 1.0
    q = qmul(dq, q)
    q /= np.sqrt(q @ q)
    return q, w + dx[3:], P, True


def predict_covariance(P, F, Qc, T):
    """P⁺ = Φ P Φᵀ + Q_d over T, Φ and Q_d to third order in F·T (the δθ̇ = δω block
    makes F·T of order 1 at a 0.5 s sensor period, so first order would not do).

    Parameters
    ----------
    P : ndarray, shape (d, d)
        The error state's covariance.
    F : ndarray, shape (d, d)
        The error dynamics (:func:`error_jacobian`), s⁻¹.
    Qc : ndarray, shape (d, d)
        The continuous process noise's spectral density.
    T : float
        The prediction's span, s.

    Returns
    -------
    ndarray, shape (d, d)
        P⁺, symmetric.
    """
    FT = F * T
    F2 = F @ F
    Phi = np.eye(P.shape[0]) + FT + 0.5 * FT @ FT + F2 @ FT * (T * T / 6.0)
    FQ = F @ Qc
    Qd = Qc * T + 0.5 * T * T * (FQ + FQ.T) + T**3 / 3.0 * (FQ @ F.T + 0.5 * (F2 @ Qc + Qc @ F2.T))
    P = Phi @ P @ Phi.T + Qd
    return 0.5 * (P + P.T)


# Scalar twins of the functions above for the kernel's inner loop: numba's ``@`` on
# 6×6 and 9×9 matrices calls BLAS (about a microsecond per call) and every readable line
# allocates. Hand-written because no library offers allocation-free small-matrix
# kernels callable from numba; tests hold each twin equal to its reference. The helpers
# they share or call more than once are compiled once and inlined by LLVM
# (``forceinline``) rather than by numba (``inline="always"``), which compiles a helper
# again at every call site: 54 copies of ``_dot_skip`` made
# ``gyro_predict_covariance_into`` take 5-6 s to compile, now 2 s (the same machine code).


@njit(cache=True, forceinline=True)
def _mm(A, B, out):
    """out = A @ B (out must not alias A or B), skipping A's zeros.

    The filter's matrices are mostly zeros (F, Φ = I + F T + …, I − K H, Qc), so the
    products run row by row over A's non-zero entries. Each out[i, j] still sums its
    terms in the order k = 0, 1, …: the result equals the plain triple loop's bit for bit
    (a skipped term adds an exact 0). Hand-written: numba's ``@`` calls BLAS, which costs
    microseconds on matrices this small.
    """
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            out[i, j] = 0.0
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[k, j]


@njit(cache=True, forceinline=True)
def _mmt(A, B, out):
    """out = A @ B.T (out must not alias A or B), skipping B's zeros (as :func:`_mm`: the
    same sums in the same order as the plain loop)."""
    for i in range(A.shape[0]):
        for j in range(B.shape[0]):
            out[i, j] = 0.0
    for j in range(B.shape[0]):
        for k in range(B.shape[1]):
            b = B[j, k]
            if b != 0.0:
                for i in range(A.shape[0]):
                    out[i, j] += A[i, k] * b


@njit(cache=True)
def error_jacobian_into(q, w, h, J, J_inv, n, gg_gain, bias_map, F, W):
    """:func:`error_jacobian` into F (n, n; n = 6, or 6 + m with the disturbance state and
    its (3, m) ``bias_map``, unread when n = 6), with a (4, 3, 3) scratch W."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    r0 = 2 * (q1 * q3 - q4 * q2)
    r1 = 2 * (q2 * q3 + q4 * q1)
    r2 = q4 * q4 - (q1 * q1 + q2 * q2) + q3 * q3
    F[:, :] = 0.0
    for i in range(3):
        F[i, 3 + i] = 1.0
    F[0, 1], F[0, 2], F[1, 0], F[1, 2], F[2, 0], F[2, 1] = w[2], -w[1], -w[2], w[0], w[1], -w[0]
    Jr = (
        J[0, 0] * r0 + J[0, 1] * r1 + J[0, 2] * r2,
        J[1, 0] * r0 + J[1, 1] * r1 + J[1, 2] * r2,
        J[2, 0] * r0 + J[2, 1] * r1 + J[2, 2] * r2,
    )
    Jw = (
        J[0, 0] * w[0] + J[0, 1] * w[1] + J[0, 2] * w[2] + h[0],
        J[1, 0] * w[0] + J[1, 1] * w[1] + J[1, 2] * w[2] + h[1],
        J[2, 0] * w[0] + J[2, 1] * w[1] + J[2, 2] * w[2] + h[2],
    )
    rx, A, B, S = W[0], W[1], W[2], W[3]
    skew_into(r0, r1, r2, rx)
    _mm(rx, J, A)  # [r×] J − [(J r)×]
    skew_into(Jr[0], Jr[1], Jr[2], B)
    for i in range(3):
        for j in range(3):
            A[i, j] = gg_gain * (A[i, j] - B[i, j])
    _mm(A, rx, B)  # (…) [r×]
    _mm(J_inv, B, S)
    for i in range(3):
        for j in range(3):
            F[3 + i, j] = S[i, j]
    skew_into(w[0], w[1], w[2], rx)  # [(J ω + h)×] − [ω×] J
    _mm(rx, J, A)
    skew_into(Jw[0], Jw[1], Jw[2], B)
    for i in range(3):
        for j in range(3):
            B[i, j] -= A[i, j]
    _mm(J_inv, B, S)
    for i in range(3):
        for j in range(3):
            F[3 + i, 3 + j] = S[i, j]
        for j in range(F.shape[0] - 6):
            F[3 + i, 6 + j] = (
                J_inv[i, 0] * bias_map[0, j]
                + J_inv[i, 1] * bias_map[1, j]
                + J_inv[i, 2] * bias_map[2, j]
            )


@njit(cache=True, forceinline=True)
def skew_into(a, b, c, out):
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -c, b
    out[1, 0], out[1, 1], out[1, 2] = c, 0.0, -a
    out[2, 0], out[2, 1], out[2, 2] = -b, a, 0.0


@njit(cache=True)
def predict_covariance_into(P, F, Qc, T, W):
    """:func:`predict_covariance` in place on P (n, n), with a (6, n, n) scratch W."""
    nx = P.shape[0]
    Phi, F2, FQ, X, Y, Z = W[0], W[1], W[2], W[3], W[4], W[5]
    _mm(F, F, F2)
    _mm(F2, F, X)  # F³
    _mm(F, Qc, FQ)
    _mmt(FQ, F, Y)  # F Qc Fᵀ
    _mmt(Qc, F2, Z)  # Qc F²ᵀ
    T2, T3 = T * T, T * T * T
    for i in range(nx):
        for j in range(nx):
            Phi[i, j] = (
                (1.0 if i == j else 0.0) + F[i, j] * T + F2[i, j] * T2 / 2 + X[i, j] * T3 / 6
            )
    for i in range(nx):  # Qd into Y: Qc T + T²/2 (FQ + FQᵀ) + T³/3 (F Qc Fᵀ + (F² Qc + Qc F²ᵀ)/2)
        for j in range(nx):
            Y[i, j] = (
                Qc[i, j] * T
                + 0.5 * T2 * (FQ[i, j] + FQ[j, i])
                + T3 / 3.0 * (Y[i, j] + 0.5 * (Z[j, i] + Z[i, j]))
            )
    _mm(Phi, P, X)
    _mmt(X, Phi, Z)
    for i in range(nx):
        for j in range(nx):
            P[i, j] = 0.5 * (Z[i, j] + Z[j, i] + Y[i, j] + Y[j, i])


@njit(cache=True, forceinline=True)
def _reset_attitude(q, d0, d1, d2):
    """q ← [δθ/2, 1] ⊗ q, renormalised (the multiplicative reset after an update), in place."""
    p1, p2, p3 = 0.5 * d0, 0.5 * d1, 0.5 * d2
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    n1 = q1 + q4 * p1 - (p2 * q3 - p3 * q2)
    n2 = q2 + q4 * p2 - (p3 * q1 - p1 * q3)
    n3 = q3 + q4 * p3 - (p1 * q2 - p2 * q1)
    n4 = q4 - (p1 * q1 + p2 * q2 + p3 * q3)
    norm = math.sqrt(n1 * n1 + n2 * n2 + n3 * n3 + n4 * n4)
    q[0], q[1], q[2], q[3] = n1 / norm, n2 / norm, n3 / norm, n4 / norm


@njit(cache=True)
def gated_update_into(q, w, P, b_meas, ref, sigma, gate, W):
    """One vector-measurement update in place on q (4,), w (n − 3,), P (n, n): the scalar
    twin of ``_update`` behind an innovation gate. Returns whether it was applied.

    Rejected (nothing changes) when ν' S⁻¹ ν > ``gate`` (a χ² bound; 0: no gate).
    ``W`` is a (4, n, n) scratch. H = [[b×], 0, …] is never formed: only its 3×3 block.
    """
    nx = P.shape[0]
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    s = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    b0 = (
        (s + 2 * q1 * q1) * ref[0]
        + 2 * (q1 * q2 + q4 * q3) * ref[1]
        + 2 * (q1 * q3 - q4 * q2) * ref[2]
    )
    b1 = (
        2 * (q1 * q2 - q4 * q3) * ref[0]
        + (s + 2 * q2 * q2) * ref[1]
        + 2 * (q2 * q3 + q4 * q1) * ref[2]
    )
    b2 = (
        2 * (q1 * q3 + q4 * q2) * ref[0]
        + 2 * (q2 * q3 - q4 * q1) * ref[1]
        + (s + 2 * q3 * q3) * ref[2]
    )
    Hx, PHt, K, X = W[0], W[1], W[2], W[3]  # Hx: [b×] in the top-left 3×3
    skew_into(b0, b1, b2, Hx)
    for i in range(nx):  # P Hᵀ (n×3)
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += P[i, k] * Hx[j, k]
            PHt[i, j] = acc
    r = sigma * sigma
    S, Si = X[:3, :3], X[3:, :3]  # X is free until the Joseph step
    for i in range(3):
        for j in range(3):
            acc = r if i == j else 0.0
            for k in range(3):
                acc += Hx[i, k] * PHt[k, j]
            S[i, j] = acc
    _cholesky3_into(S, Si)  # S = L Lᵀ (S is SPD; cofactors lose it when S is ill-conditioned)
    nu0, nu1, nu2 = b_meas[0] - b0, b_meas[1] - b1, b_meas[2] - b2
    if gate > 0:
        z0, z1, z2 = _forward3(Si, nu0, nu1, nu2)
        if z0 * z0 + z1 * z1 + z2 * z2 > gate:  # ν' S⁻¹ ν = |L⁻¹ ν|²
            return False
    dx = K[:, 3]  # K uses the first three columns
    for i in range(nx):  # row i of K = S⁻¹ (P Hᵀ)[i], δx = K ν
        z0, z1, z2 = _forward3(Si, PHt[i, 0], PHt[i, 1], PHt[i, 2])
        K[i, 0], K[i, 1], K[i, 2] = _backward3(Si, z0, z1, z2)
        dx[i] = K[i, 0] * nu0 + K[i, 1] * nu1 + K[i, 2] * nu2
    for i in range(nx):  # I − K H into PHt's buffer (it is no longer needed)
        for j in range(nx):
            v = 1.0 if i == j else 0.0
            if j < 3:
                v -= K[i, 0] * Hx[0, j] + K[i, 1] * Hx[1, j] + K[i, 2] * Hx[2, j]
            PHt[i, j] = v
    _joseph_products(PHt, P, X, Hx)  # (I − KH) P (I − KH)ᵀ into Hx
    for i in range(nx):
        for j in range(i, nx):
            kk = r * (K[i, 0] * K[j, 0] + K[i, 1] * K[j, 1] + K[i, 2] * K[j, 2])
            v = 0.5 * (Hx[i, j] + Hx[j, i]) + kk
            P[i, j] = v
            P[j, i] = v
    _reset_attitude(q, dx[0], dx[1], dx[2])
    for i in range(nx - 3):
        w[i] += dx[3 + i]
    return True


@njit(cache=True, inline="always")
def _joseph_products(A, P, X, out):
    """out = A P Aᵀ (X: scratch) for A = I − K H with H = [[b×], 0]: A's row i is zero
    outside columns 0, 1, 2 and i, so each entry is a sum of at most four terms.

    The same sums as ``_mm(A, P, X)`` then ``_mmt(X, A, out)``, term for term in the same
    order (k ascending, exact zeros of A skipped, from 0.0), so the result is equal bit for
    bit; only the loops over A's known zeros are gone and each sum stays in a register
    (the generic products load and store ``out`` at every term: 40 % of the update's time).
    """
    nx = P.shape[0]
    for i in range(nx):
        a0, a1, a2 = A[i, 0], A[i, 1], A[i, 2]
        ai = A[i, i] if i >= 3 else 0.0
        for j in range(nx):
            acc = 0.0
            if a0 != 0.0:
                acc += a0 * P[0, j]
            if a1 != 0.0:
                acc += a1 * P[1, j]
            if a2 != 0.0:
                acc += a2 * P[2, j]
            if ai != 0.0:
                acc += ai * P[i, j]
            X[i, j] = acc
    for j in range(nx):
        b0, b1, b2 = A[j, 0], A[j, 1], A[j, 2]
        bj = A[j, j] if j >= 3 else 0.0
        for i in range(nx):
            acc = 0.0
            if b0 != 0.0:
                acc += X[i, 0] * b0
            if b1 != 0.0:
                acc += X[i, 1] * b1
            if b2 != 0.0:
                acc += X[i, 2] * b2
            if bj != 0.0:
                acc += X[i, j] * bj
            out[i, j] = acc


@njit(cache=True, forceinline=True)
def _cholesky3_into(S, L):
    """Lower-triangular L with L Lᵀ = S for a 3×3 symmetric positive definite S."""
    L[0, 0] = math.sqrt(S[0, 0])
    L[1, 0] = S[1, 0] / L[0, 0]
    L[2, 0] = S[2, 0] / L[0, 0]
    L[1, 1] = math.sqrt(S[1, 1] - L[1, 0] * L[1, 0])
    L[2, 1] = (S[2, 1] - L[2, 0] * L[1, 0]) / L[1, 1]
    L[2, 2] = math.sqrt(S[2, 2] - L[2, 0] * L[2, 0] - L[2, 1] * L[2, 1])


@njit(cache=True, forceinline=True)
def _forward3(L, v0, v1, v2):
    """L⁻¹ v for the lower-triangular 3×3 L."""
    z0 = v0 / L[0, 0]
    z1 = (v1 - L[1, 0] * z0) / L[1, 1]
    return z0, z1, (v2 - L[2, 0] * z0 - L[2, 1] * z1) / L[2, 2]


@njit(cache=True, forceinline=True)
def _backward3(L, z0, z1, z2):
    """L⁻ᵀ z for the lower-triangular 3×3 L."""
    y2 = z2 / L[2, 2]
    y1 = (z1 - L[2, 1] * y2) / L[1, 1]
    return (z0 - L[1, 0] * y1 - L[2, 0] * y2) / L[0, 0], y1, y2


# -- the gyro-driven filter (Lefferts–Markley–Shuster) ----------------------------------
# With gyros the attitude is propagated with the measured rate, ω̂ = ω_m − β̂, and the error
# state is δx = [δθ, δβ] (n = 6; Markley & Crassidis 2014, §6.2.3):
#
#     δθ̇ = −[ω̂×] δθ − δβ − v,    δβ̇ = u,
#
# v the gyro's angle random walk (PSD σ_v²) and u its bias walk (σ_u²). The vector
# updates are the ones above (H = [[b×], 0]); a star tracker's quaternion is an update
# with H = [I, 0] (:func:`attitude_update_into`).


@njit(cache=True)
def gyro_jacobian_into(w, F):
    """F (n, n) of the gyro-driven error dynamics at the rate estimate ω̂ = ``w`` (3,):
    [[−[ω̂×], −I], [0, 0]] (n = 6; further rows and columns zero)."""
    F[:, :] = 0.0
    F[0, 1], F[0, 2], F[1, 0], F[1, 2], F[2, 0], F[2, 1] = w[2], -w[1], -w[2], w[0], w[1], -w[0]
    for i in range(3):
        F[i, 3 + i] = -1.0


@njit(cache=True)
def gyro_predict_covariance_into(P, w, Qc, T, W):
    """:func:`predict_covariance_into` for the gyro-driven filter's F (``gyro_jacobian_into``
    at ω̂ = ``w``), in place on P (n, n ≥ 6), with a (≥ 2, n, n) scratch W.

    The same third-order Φ and Q_d, written by blocks: with A = −[ω̂×], F = [[A, −I, 0],
    0] so Φ = [[Φ₁₁, Φ₁₂, 0], [0, I, 0], [0, 0, I]], Φ₁₁ = I + A T + A² T²/2 + A³ T³/6,
    Φ₁₂ = −(I T + A T²/2 + A² T³/6), and Qc block-diagonal [Q₁, Q₂, Q₃] (the filter's own:
    ``gyro_process_noise``) gives Q_d₁₁ = Q₁ T + (A Q₁ + Q₁ Aᵀ) T²/2 + (A Q₁ Aᵀ + Q₂
    + (A² Q₁ + Q₁ A²ᵀ)/2) T³/3, Q_d₁₂ = −Q₂ T²/2 − A Q₂ T³/6, Q_d₂₂ = Q₂ T, Q_d₃₃ = Q₃ T.
    Only the three attitude rows and columns of Φ P Φᵀ differ from P: about a tenth of
    the dense products' work. Equal to the dense form to round-off (a test holds them to
    1e-12 relative).
    """
    nx = P.shape[0]
    # the 3×3 blocks live in registers as row-major 9-tuples (views of W would be reloaded
    # at every use: numba cannot tell they do not alias P); every sum is the one the
    # readable form computes, in the same order (``_mm`` skips exact zeros: so do these)
    A = (0.0, w[2], -w[1], -w[2], 0.0, w[0], w[1], -w[0], 0.0)
    A2 = _mm3(A, A)
    A3 = _mm3(A2, A)
    T2, T3 = T * T, T * T * T
    F11 = _phi11(A, A2, A3, T, T2, T3)  # Φ₁₁
    F12 = _phi12(A, A2, T, T2, T3)  # Φ₁₂
    M, Z = W[0], W[1]
    for j in range(nx):  # M = Φ P: only the attitude rows mix; the rest are P's own rows
        for i in range(3):
            M[i, j] = _row_mix(
                F11[3 * i], F11[3 * i + 1], F11[3 * i + 2],
                F12[3 * i], F12[3 * i + 1], F12[3 * i + 2],
                P[0, j], P[1, j], P[2, j], P[3, j], P[4, j], P[5, j],
            )  # fmt: skip
    for i in range(nx):  # Z = M Φᵀ, its attitude columns (the others are M's)
        R = M if i < 3 else P
        r0, r1, r2, r3, r4, r5 = R[i, 0], R[i, 1], R[i, 2], R[i, 3], R[i, 4], R[i, 5]
        for j in range(3):
            Z[i, j] = _row_mix(
                F11[3 * j], F11[3 * j + 1], F11[3 * j + 2],
                F12[3 * j], F12[3 * j + 1], F12[3 * j + 2],
                r0, r1, r2, r3, r4, r5,
            )  # fmt: skip
    for i in range(3):  # symmetrised; rows and columns ≥ 3 keep P's (already symmetric)
        for j in range(i, 3):
            v = 0.5 * (Z[i, j] + Z[j, i])
            P[i, j] = v
            P[j, i] = v
        for j in range(3, nx):
            v = 0.5 * (M[i, j] + Z[j, i])
            P[i, j] = v
            P[j, i] = v
    # Q_d, added symmetrised by blocks
    Q1 = (Qc[0, 0], Qc[0, 1], Qc[0, 2], Qc[1, 0], Qc[1, 1], Qc[1, 2], Qc[2, 0], Qc[2, 1], Qc[2, 2])
    Q2 = (Qc[3, 3], Qc[3, 4], Qc[3, 5], Qc[4, 3], Qc[4, 4], Qc[4, 5], Qc[5, 3], Qc[5, 4], Qc[5, 5])
    AQ1 = _mm3(A, Q1)
    AQ2 = _mm3(A, Q2)
    A2Q1 = _mm3(A2, Q1)
    X = _mmt3(AQ1, A)  # A Q₁ Aᵀ
    for i in range(3):
        for j in range(3):
            ij, ji = 3 * i + j, 3 * j + i
            q11 = (
                Q1[ij] * T
                + 0.5 * T2 * (AQ1[ij] + AQ1[ji])
                + T3 / 3.0 * (X[ij] + Q2[ij] + 0.5 * (A2Q1[ij] + A2Q1[ji]))
            )
            q11t = (
                Q1[ji] * T
                + 0.5 * T2 * (AQ1[ji] + AQ1[ij])
                + T3 / 3.0 * (X[ji] + Q2[ji] + 0.5 * (A2Q1[ji] + A2Q1[ij]))
            )
            P[i, j] += 0.5 * (q11 + q11t)
            q12 = -0.5 * T2 * Q2[ij] - T3 / 6.0 * AQ2[ij]  # Q_d₂₁ = Q_d₁₂ᵀ
            P[i, 3 + j] += q12
            P[3 + j, i] += q12
            P[3 + i, 3 + j] += 0.5 * T * (Q2[ij] + Q2[ji])
    for i in range(6, nx):
        for j in range(6, nx):
            P[i, j] += 0.5 * T * (Qc[i, j] + Qc[j, i])


@njit(cache=True, forceinline=True)
def _row_mix(a0, a1, a2, b0, b1, b2, p0, p1, p2, p3, p4, p5):
    """Σₖ (aₖ pₖ + bₖ p₃₊ₖ), summed from 0.0 in k order: one entry of [Φ₁₁ Φ₁₂] times a
    column (or a row) of P."""
    acc = 0.0
    acc += a0 * p0 + b0 * p3
    acc += a1 * p1 + b1 * p4
    acc += a2 * p2 + b2 * p5
    return acc


@njit(cache=True, forceinline=True)
def _dot_skip(a0, a1, a2, b0, b1, b2):
    """Σₖ aₖ bₖ from 0.0 in k order, skipping a's exact zeros (as ``_mm``)."""
    acc = 0.0
    if a0 != 0.0:
        acc += a0 * b0
    if a1 != 0.0:
        acc += a1 * b1
    if a2 != 0.0:
        acc += a2 * b2
    return acc


@njit(cache=True, forceinline=True)
def _mm3(a, b):
    """a @ b for 3×3 matrices as row-major 9-tuples: ``_mm``'s sums (a's zeros skipped)."""
    return (
        _dot_skip(a[0], a[1], a[2], b[0], b[3], b[6]),
        _dot_skip(a[0], a[1], a[2], b[1], b[4], b[7]),
        _dot_skip(a[0], a[1], a[2], b[2], b[5], b[8]),
        _dot_skip(a[3], a[4], a[5], b[0], b[3], b[6]),
        _dot_skip(a[3], a[4], a[5], b[1], b[4], b[7]),
        _dot_skip(a[3], a[4], a[5], b[2], b[5], b[8]),
        _dot_skip(a[6], a[7], a[8], b[0], b[3], b[6]),
        _dot_skip(a[6], a[7], a[8], b[1], b[4], b[7]),
        _dot_skip(a[6], a[7], a[8], b[2], b[5], b[8]),
    )


@njit(cache=True, forceinline=True)
def _mmt3(a, b):
    """a @ bᵀ for 3×3 matrices as row-major 9-tuples: ``_mmt``'s sums (b's zeros skipped;
    each term a·b as ``_mmt`` writes it)."""
    out = (
        _dot_skip(b[0], b[1], b[2], a[0], a[1], a[2]),
        _dot_skip(b[3], b[4], b[5], a[0], a[1], a[2]),
        _dot_skip(b[6], b[7], b[8], a[0], a[1], a[2]),
        _dot_skip(b[0], b[1], b[2], a[3], a[4], a[5]),
        _dot_skip(b[3], b[4], b[5], a[3], a[4], a[5]),
        _dot_skip(b[6], b[7], b[8], a[3], a[4], a[5]),
        _dot_skip(b[0], b[1], b[2], a[6], a[7], a[8]),
        _dot_skip(b[3], b[4], b[5], a[6], a[7], a[8]),
        _dot_skip(b[6], b[7], b[8], a[6], a[7], a[8]),
    )
    return out


@njit(cache=True, forceinline=True)
def _phi11(A, A2, A3, T, T2, T3):
    """Φ₁₁ = I + A T + A² T²/2 + A³ T³/6 (9-tuples, row-major)."""
    return (
        1.0 + A[0] * T + A2[0] * T2 / 2 + A3[0] * T3 / 6,
        0.0 + A[1] * T + A2[1] * T2 / 2 + A3[1] * T3 / 6,
        0.0 + A[2] * T + A2[2] * T2 / 2 + A3[2] * T3 / 6,
        0.0 + A[3] * T + A2[3] * T2 / 2 + A3[3] * T3 / 6,
        1.0 + A[4] * T + A2[4] * T2 / 2 + A3[4] * T3 / 6,
        0.0 + A[5] * T + A2[5] * T2 / 2 + A3[5] * T3 / 6,
        0.0 + A[6] * T + A2[6] * T2 / 2 + A3[6] * T3 / 6,
        0.0 + A[7] * T + A2[7] * T2 / 2 + A3[7] * T3 / 6,
        1.0 + A[8] * T + A2[8] * T2 / 2 + A3[8] * T3 / 6,
    )


@njit(cache=True, forceinline=True)
def _phi12(A, A2, T, T2, T3):
    """Φ₁₂ = −(I T + A T²/2 + A² T³/6) (9-tuples, row-major)."""
    return (
        -(1.0 * T + A[0] * T2 / 2 + A2[0] * T3 / 6),
        -(0.0 * T + A[1] * T2 / 2 + A2[1] * T3 / 6),
        -(0.0 * T + A[2] * T2 / 2 + A2[2] * T3 / 6),
        -(0.0 * T + A[3] * T2 / 2 + A2[3] * T3 / 6),
        -(1.0 * T + A[4] * T2 / 2 + A2[4] * T3 / 6),
        -(0.0 * T + A[5] * T2 / 2 + A2[5] * T3 / 6),
        -(0.0 * T + A[6] * T2 / 2 + A2[6] * T3 / 6),
        -(0.0 * T + A[7] * T2 / 2 + A2[7] * T3 / 6),
        -(1.0 * T + A[8] * T2 / 2 + A2[8] * T3 / 6),
    )


def gyro_process_noise(psd_v: float, psd_u: float, n: int = 6) -> np.ndarray:
    """Qc (n, n) of the gyro-driven filter: σ_v² on δθ, σ_u² on δβ (rad²/s, rad²/s³); the
    rest (sensor alignment states) zero for the caller to fill."""
    Qc = np.zeros((n, n))
    Qc[:3, :3] = psd_v * np.eye(3)
    Qc[3:6, 3:6] = psd_u * np.eye(3)
    return Qc


@njit(cache=True, inline="always")
def propagate_attitude_into(q, b0, b1, b2, dt):
    """q ← δq(φ) ⊗ q in place, φ = ω_bo·dt the body rate relative to the orbital frame held
    over the step (the exact rotation, then renormalised)."""
    p0, p1, p2 = b0 * dt, b1 * dt, b2 * dt
    ang = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    c = math.cos(0.5 * ang)
    s = 0.5 - ang * ang / 48.0 if ang < 1e-6 else math.sin(0.5 * ang) / ang
    p0, p1, p2 = s * p0, s * p1, s * p2
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    n1 = c * q1 + q4 * p0 - (p1 * q3 - p2 * q2)
    n2 = c * q2 + q4 * p1 - (p2 * q1 - p0 * q3)
    n3 = c * q3 + q4 * p2 - (p0 * q2 - p1 * q1)
    n4 = c * q4 - (p0 * q1 + p1 * q2 + p2 * q3)
    norm = math.sqrt(n1 * n1 + n2 * n2 + n3 * n3 + n4 * n4)
    q[0], q[1], q[2], q[3] = n1 / norm, n2 / norm, n3 / norm, n4 / norm


@njit(cache=True, forceinline=True)
def attitude_error(a, b):
    """2 (a ⊗ b⁻¹)_v with the sign of the shorter rotation: the small angle (3-tuple, rad) that
    turns attitude b into a (A(a) = (I − [δθ×]) A(b))."""
    a1, a2, a3, a4 = a[0], a[1], a[2], a[3]
    b1, b2, b3, b4 = b[0], b[1], b[2], b[3]
    sign = 2.0 if a4 * b4 + a1 * b1 + a2 * b2 + a3 * b3 >= 0 else -2.0
    return (
        sign * (b4 * a1 - a4 * b1 + a2 * b3 - a3 * b2),
        sign * (b4 * a2 - a4 * b2 + a3 * b1 - a1 * b3),
        sign * (b4 * a3 - a4 * b3 + a1 * b2 - a2 * b1),
    )


@njit(cache=True)
def attitude_update_into(q, w, P, q_meas, R, W):
    """An attitude (star tracker) update in place on q (4,), w (n − 3,), P (n, n):
    residual δθ = 2 (q_m ⊗ q̂⁻¹)_v, H = [I, 0], R (3, 3) in body axes, Joseph form.
    ``W`` is a (4, n, n) scratch (n ≥ 6)."""
    nx = P.shape[0]
    nu0, nu1, nu2 = attitude_error(q_meas, q)
    K, X, Y = W[1], W[2], W[3]
    S, L = Y[:3, :3], Y[3:6, :3]  # n ≥ 6
    for i in range(3):
        for j in range(3):
            S[i, j] = P[i, j] + R[i, j]
    _cholesky3_into(S, L)
    dx = X[:, 0]
    for i in range(nx):  # K = P Hᵀ S⁻¹ = P[:, :3] S⁻¹
        z0, z1, z2 = _forward3(L, P[i, 0], P[i, 1], P[i, 2])
        K[i, 0], K[i, 1], K[i, 2] = _backward3(L, z0, z1, z2)
        dx[i] = K[i, 0] * nu0 + K[i, 1] * nu1 + K[i, 2] * nu2
    d0, d1, d2 = dx[0], dx[1], dx[2]  # X is reused below
    for i in range(nx - 3):
        w[i] += dx[3 + i]
    # Joseph form with H = [I, 0] never formed (as in ``aligned_update_into``):
    # M = P − K P[:3, :], P⁺ = M − M[:, :3] Kᵀ + K R Kᵀ (equal to round-off, tested)
    M = Y  # free once K is known
    for i in range(nx):
        for j in range(nx):
            M[i, j] = P[i, j] - (K[i, 0] * P[0, j] + K[i, 1] * P[1, j] + K[i, 2] * P[2, j])
    for i in range(nx):
        for j in range(i, nx):
            kk = 0.0
            for a in range(3):
                for b in range(3):
                    kk += K[i, a] * R[a, b] * K[j, b]
            v_ij = M[i, j] - (M[i, 0] * K[j, 0] + M[i, 1] * K[j, 1] + M[i, 2] * K[j, 2])
            v_ji = M[j, i] - (M[j, 0] * K[i, 0] + M[j, 1] * K[i, 1] + M[j, 2] * K[i, 2])
            v = 0.5 * (v_ij + v_ji) + kk
            P[i, j] = v
            P[j, i] = v
    _reset_attitude(q, d0, d1, d2)


@njit(cache=True)
def aligned_update_into(q, w, P, b_meas, ref, sigma, gate, at, W):
    """A vector update whose sensor is turned by a small unknown rotation φ (body axes) held
    in the state from w[at − 3] (3 values): the sensor reports (I + [φ×]) A(q) r, so
    H = [[b×], 0, …, −[b×] at column ``at``, …]. In place on q, w, P like
    :func:`gated_update_into` (which is this with no φ); returns whether it was applied.
    ``W`` is a (4, n, n) scratch (n ≥ 9). φ about the measured vector's own direction is
    unobservable at any instant and, with only this sensor fixing yaw, its component along
    the axis that sensor alone observes stays at its prior: the filter then carries that
    misalignment as the uncertainty it is (a consider state)."""
    nx = P.shape[0]
    A = W[1][:3, 3:6]  # scratch, free until K is written
    _dcm_rows_into(q, A)
    b0 = A[0, 0] * ref[0] + A[0, 1] * ref[1] + A[0, 2] * ref[2]
    b1 = A[1, 0] * ref[0] + A[1, 1] * ref[1] + A[1, 2] * ref[2]
    b2 = A[2, 0] * ref[0] + A[2, 1] * ref[1] + A[2, 2] * ref[2]
    f0, f1, f2 = w[at - 3], w[at - 2], w[at - 1]  # predicted report: b + φ × b
    p0, p1, p2 = b0 + f1 * b2 - f2 * b1, b1 + f2 * b0 - f0 * b2, b2 + f0 * b1 - f1 * b0
    # P Hᵀ, K and V = M Hᵀ (n, 3) are kept column by column, each a row of W
    T0, T1, T2, K0, K1, K2 = W[0, 0], W[0, 1], W[0, 2], W[1, 0], W[1, 1], W[1, 2]
    for i in range(nx):
        T0[i], T1[i], T2[i] = _times_ht(P[i], b0, b1, b2, at, 0.0, 0.0, 0.0)
    r = sigma * sigma
    S, L = W[3][:3, :3], W[3][3:6, :3]
    for j in range(3):  # S = H P Hᵀ + r I, column j = H (P Hᵀ)[:, j]
        S[0, j], S[1, j], S[2, j] = _times_ht(
            W[0, j],
            b0,
            b1,
            b2,
            at,
            r if j == 0 else 0.0,
            r if j == 1 else 0.0,
            r if j == 2 else 0.0,
        )
    _cholesky3_into(S, L)
    nu0, nu1, nu2 = b_meas[0] - p0, b_meas[1] - p1, b_meas[2] - p2
    if gate > 0:
        z0, z1, z2 = _forward3(L, nu0, nu1, nu2)
        if z0 * z0 + z1 * z1 + z2 * z2 > gate:
            return False
    dx = W[3, 6]
    for i in range(nx):  # row i of K = S⁻¹ (P Hᵀ)[i], δx = K ν
        z0, z1, z2 = _forward3(L, T0[i], T1[i], T2[i])
        K0[i], K1[i], K2[i] = _backward3(L, z0, z1, z2)
        dx[i] = K0[i] * nu0 + K1[i] * nu1 + K2[i] * nu2
    d0, d1, d2 = dx[0], dx[1], dx[2]
    for i in range(nx - 3):
        w[i] += dx[3 + i]
    _joseph_aligned(P, T0, T1, T2, K0, K1, K2, b0, b1, b2, at, r, W[2])
    _reset_attitude(q, d0, d1, d2)
    return True


@njit(cache=True, forceinline=True)
def _times_ht(R, b0, b1, b2, at, s0, s1, s2):
    """s + R Hᵀ for a row R (n,) and H = [[b×], 0, −[b×] at column ``at``]: H's exact zeros
    skipped, the other terms in column order, so each sum equals the dense one bit for bit."""
    a1, a2 = at + 1, at + 2
    return (
        s0 + R[1] * -b2 + R[2] * b1 + R[a1] * b2 + R[a2] * -b1,
        s1 + R[0] * b2 + R[2] * -b0 + R[at] * -b2 + R[a2] * b0,
        s2 + R[0] * -b1 + R[1] * b0 + R[at] * b1 + R[a1] * -b0,
    )


@njit(cache=True, inline="always")
def _joseph_aligned(P, T0, T1, T2, K0, K1, K2, b0, b1, b2, at, r, Z):
    """P ← (I − K H) P (I − K H)ᵀ + r K Kᵀ for :func:`aligned_update_into`, never forming
    I − K H: M = P − K (H P), V = M Hᵀ, Z = M − V Kᵀ row by row (Z: (n, n) scratch),
    P⁺ = (Z + Zᵀ)/2 + r K Kᵀ, with H P = (P Hᵀ)ᵀ (P is kept exactly symmetric). T, K, V:
    the columns of P Hᵀ, K and V. The same terms as the dense products, summed in another
    order (equal to round-off, tested)."""
    nx = P.shape[0]
    for i in range(nx):
        Zi, k0, k1, k2 = Z[i], K0[i], K1[i], K2[i]
        for j in range(nx):
            Zi[j] = P[i, j] - (k0 * T0[j] + k1 * T1[j] + k2 * T2[j])
        v0, v1, v2 = _times_ht(Zi, b0, b1, b2, at, 0.0, 0.0, 0.0)
        for j in range(nx):
            Zi[j] -= v0 * K0[j] + v1 * K1[j] + v2 * K2[j]
    for i in range(nx):
        k0, k1, k2 = K0[i], K1[i], K2[i]
        for j in range(i, nx):
            v = 0.5 * (Z[i, j] + Z[j, i]) + r * (k0 * K0[j] + k1 * K1[j] + k2 * K2[j])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, inline="always")
def _dcm_rows_into(q, C):
    """C = A(q) (frames.dcm) element by element."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    s = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    C[0, 0], C[1, 1], C[2, 2] = s + 2 * q1 * q1, s + 2 * q2 * q2, s + 2 * q3 * q3
    C[0, 1], C[1, 0] = 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q2 - q4 * q3)
    C[0, 2], C[2, 0] = 2 * (q1 * q3 - q4 * q2), 2 * (q1 * q3 + q4 * q2)
    C[1, 2], C[2, 1] = 2 * (q2 * q3 + q4 * q1), 2 * (q2 * q3 - q4 * q1)
