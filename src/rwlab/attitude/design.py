"""LQR, Kalman, LQG and loop transfer recovery for any LTI plant (python-control in and out).

MATLAB has ``lqr``, ``kalman``, ``lqg``, ``ltrsyn`` and ``sigma``; python-control
has ``lqr``, ``lqe`` and singular-value plots but no LQG or LTR: those are here.

Conventions (continuous or discrete, following ``sys.dt``):

- regulator u = −K x̂ minimising ∫ xᵀQx + uᵀRu;
- estimator x̂̇ = A x̂ + B u + L (y − C x̂), with process noise G w (cov Qn) and
  measurement noise v (cov Rn);
- the compensator K(s) = K (sI − A + BK + LC)⁻¹ L maps y to −u (paper B, eq. 14),
  so the loop broken at the plant input is K(s) G(s) and its LQR target is
  K (sI − A)⁻¹ B.

Input LTR (paper B): keep the fictitious process noise through B fixed and
let the measurement noise R = ρ·R₀ shrink; as ρ → 0 the loop K(s)G(s) recovers
the LQR loop for minimum-phase square plants. Output LTR is the dual: the
regulator weights ρ·R₀ shrink with Q = CᵀC, and the loop G(s)K(s) broken at
the output recovers C (sI − A)⁻¹ L.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from rwlab.errors import RwlabError

__all__ = ["DesignError", "LTRResult", "kalman", "lqg", "lqr", "ltr", "sigma"]


class DesignError(RwlabError, ValueError):
    """Weights or a plant for which the requested design does not exist."""


def _check_weight(name: str, M, n: int, definite: bool) -> np.ndarray:
    M = np.atleast_2d(np.asarray(M, dtype=float))
    if M.shape != (n, n):
        raise DesignError(f"{name} must be {n}×{n}, got {M.shape}")
    if not np.all(np.isfinite(M)) or not np.allclose(M, M.T, atol=1e-12 * max(1, abs(M).max())):
        raise DesignError(f"{name} must be a finite symmetric matrix")
    ev = np.linalg.eigvalsh(M)
    tol = 1e-12 * abs(ev).max()  # relative: noise covariances can be tiny numbers
    if (definite and (ev.min() <= tol or ev.max() <= 0)) or ev.min() < -tol:
        kind = "positive definite" if definite else "positive semidefinite"
        raise DesignError(f"{name} must be {kind}; its smallest eigenvalue is {ev.min():.3g}")
    return M


def _uncontrollable_unstable(A, B, dt) -> bool:
    """True when some mode that is not asymptotically stable cannot be reached by B (PBH)."""
    n = A.shape[0]
    for lam in np.linalg.eigvals(A):
        unstable = abs(lam) >= 1 - 1e-12 if dt else lam.real >= -1e-12
        if unstable and np.linalg.matrix_rank(np.hstack([lam * np.eye(n) - A, B]), tol=1e-9) < n:
            return True
    return False


def _ss(sys) -> control.StateSpace:
    if not isinstance(sys, (control.StateSpace, control.TransferFunction)):
        raise DesignError(f"expected a python-control system, got {type(sys).__name__}")
    return control.ss(sys)


def lqr(sys, Q, R) -> np.ndarray:
    """State-feedback gain K for u = −Kx (``control.lqr`` / ``dlqr`` by ``sys.dt``).

    Raises ``DesignError`` for weights that are not (semi)definite or an
    (A, B) pair that is not stabilisable.
    """
    ss = _ss(sys)
    A, B = np.asarray(ss.A), np.asarray(ss.B)
    Q = _check_weight("Q", Q, A.shape[0], definite=False)
    R = _check_weight("R", R, B.shape[1], definite=True)
    if _uncontrollable_unstable(A, B, ss.dt):
        raise DesignError("(A, B) is not stabilisable: an unstable mode is uncontrollable")
    fn = control.dlqr if ss.isdtime(strict=True) else control.lqr
    K, _, _ = fn(A, B, Q, R)
    return np.asarray(K)


def kalman(sys, Qn, Rn, G=None) -> np.ndarray:
    """Steady-state Kalman gain L (``control.lqe`` / ``dlqe``); G defaults to identity."""
    ss = _ss(sys)
    A, C = np.asarray(ss.A), np.asarray(ss.C)
    n = A.shape[0]
    G = np.eye(n) if G is None else np.atleast_2d(np.asarray(G, float))
    Qn = _check_weight("Qn", Qn, G.shape[1], definite=False)
    Rn = _check_weight("Rn", Rn, C.shape[0], definite=True)
    if _uncontrollable_unstable(A.T, C.T, ss.dt):
        raise DesignError("(A, C) is not detectable: an unstable mode is unobservable")
    fn = control.dlqe if ss.isdtime(strict=True) else control.lqe
    L, _, _ = fn(A, G, C, Qn, Rn)
    return np.asarray(L)


def lqg(sys, K, L) -> control.StateSpace:
    """The LQG compensator K(s) = K (sI − A + BK + LC)⁻¹ L (from y to −u)."""
    ss = _ss(sys)
    A, B, C = np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C)
    K, L = np.atleast_2d(K), np.atleast_2d(L)
    return control.ss(A - B @ K - L @ C, L, K, np.zeros((K.shape[0], L.shape[1])), ss.dt)


def sigma(sys, omega) -> np.ndarray:
    """Singular values of sys(jω) (or of e^{jωdt}), largest first; shape (len(ω), min(p, m))."""
    sys = _ss(sys)
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    resp = sys.frequency_response(w)
    H = np.asarray(resp.frdata if hasattr(resp, "frdata") else resp.fresp)
    if H.ndim == 1:
        H = H[None, None, :]
    return np.array([np.linalg.svd(H[:, :, i], compute_uv=False) for i in range(w.size)])


@dataclass
class LTRResult:
    """Loop transfer recovery over a list of ρ.

    Attributes
    ----------
    omega : (F,) rad/s
    target : (F, k) singular values of the LQR (or Kalman) target loop
    loops : dict ρ → (F, k) singular values of the recovered loop
    compensators : dict ρ → control.StateSpace K(s)
    K : regulator gain; L : dict ρ → estimator gain
    side : 'input' or 'output'
    """

    omega: np.ndarray
    target: np.ndarray
    loops: dict
    compensators: dict
    K: np.ndarray
    L: dict
    side: str

    def max_gap(self, rho: float, band: tuple[float, float] | None = None) -> float:
        """Largest |log10 σ_loop − log10 σ_target| over a frequency band (decades)."""
        sel = (
            np.ones(self.omega.size, bool)
            if band is None
            else ((self.omega >= band[0]) & (self.omega <= band[1]))
        )
        diff = np.log10(self.loops[rho][sel]) - np.log10(self.target[sel])
        return float(np.max(np.abs(diff)))

    def to_dict(self) -> dict:
        """``sigma.json``: plain magnitudes, the loop broken at the plant input (or output)."""
        return {
            "omega": self.omega.tolist(),
            "target": self.target.tolist(),
            "loops": {f"{rho:g}": s.tolist() for rho, s in self.loops.items()},
            "side": self.side,
        }


def ltr(
    sys, Q, R, rhos, *, R0=None, Q0=None, q2: float = 1.0, side: str = "input", omega=None
) -> LTRResult:
    """Loop transfer recovery for a list of ρ (paper B: 76.92, 7.692, 0.7692, 0.007692).

    Parameters
    ----------
    sys : control.StateSpace
        Plant G(s) = C (sI − A)⁻¹ B.
    Q, R : array_like
        Regulator weights (input LTR) or estimator weights (output LTR) of the target loop.
    rhos : sequence of float > 0
        Recovery parameters; smaller recovers more.
    R0 : array_like, optional
        Nominal measurement (input LTR) or control (output LTR) weight; default I.
    Q0 : array_like, optional
        Nominal process noise (input LTR) or state weight (output LTR) added to the
        fictitious term q²·B Bᵀ (or q²·CᵀC); default 0.
    q2 : float
        Intensity q² of that fictitious term (Doyle–Stein); default 1.
    side : {'input', 'output'}
    omega : array_like, optional
        Frequencies, rad/s (default 1e-4..1e2 log-spaced).
    """
    ss = _ss(sys)
    A, B, C = np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C)
    n = A.shape[0]
    rhos = [float(r) for r in rhos]
    if not rhos or any(not np.isfinite(r) or r <= 0 for r in rhos):
        raise DesignError(f"every ρ must be a positive finite number, got {rhos}")
    if side not in ("input", "output"):
        raise DesignError(f"side must be 'input' or 'output', got {side!r}")
    w = np.logspace(-4, 2, 300) if omega is None else np.asarray(omega, float)
    loops, comps, Ls = {}, {}, {}
    if side == "input":
        K = lqr(ss, Q, R)
        target = sigma(control.ss(A, B, K, 0 * K @ B, ss.dt), w)
        R0 = np.eye(C.shape[0]) if R0 is None else np.asarray(R0, float)
        Qf = (np.zeros((n, n)) if Q0 is None else np.asarray(Q0, float)) + q2 * B @ B.T
        for rho in rhos:
            L = kalman(ss, Qf, rho * R0)
            Kc = lqg(ss, K, L)
            Ls[rho], comps[rho] = L, Kc
            loops[rho] = sigma(control.series(ss, Kc), w)  # K(s) G(s): first G, then K
    else:
        L = kalman(ss, Q, R)
        target = sigma(control.ss(A, L, C, 0 * C @ L, ss.dt), w)
        R0 = np.eye(B.shape[1]) if R0 is None else np.asarray(R0, float)
        Qr = (np.zeros((n, n)) if Q0 is None else np.asarray(Q0, float)) + q2 * C.T @ C
        for rho in rhos:
            Kr = lqr(ss, Qr, rho * R0)
            Kc = lqg(ss, Kr, L)
            Ls[rho], comps[rho] = L, Kc
            loops[rho] = sigma(control.series(Kc, ss), w)  # G(s) K(s)
        K = None
    return LTRResult(w, target, loops, comps, K, Ls, side)
