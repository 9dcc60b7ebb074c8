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
import scipy.linalg

from rwlab._display import ShortRepr
from rwlab.errors import DesignError  # DesignError re-exported here, where it was

__all__ = [
    "DesignError",
    "LTRResult",
    "kalman",
    "kalman_current",
    "lqg",
    "lqg_current",
    "lqr",
    "lqrd",
    "ltr",
    "sigma",
]


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


def _scales(Q: np.ndarray) -> np.ndarray:
    """Diagonal scales d with dᵢ = 1/√Qᵢᵢ, so the scaled weight has a unit diagonal.

    States a weight leaves at zero take the geometric mean of the others' scales.
    """
    q = np.diag(Q).copy()
    pos = q > 0
    d = np.ones_like(q)
    d[pos] = 1 / np.sqrt(q[pos])
    if pos.any():
        d[~pos] = np.exp(np.mean(np.log(d[pos])))
    return d


def _riccati_gain(A, B, Q, R, N, dt) -> np.ndarray:
    """u = −K x for the (continuous or discrete) LQ problem, solved on a scaled problem.

    The states are scaled by Q's diagonal and the inputs by R's, so the Riccati
    equation sees unit weights: raw SI attitude problems (torques of 1e-2 N·m,
    rates of 1e-4 rad/s, noise PSDs of 1e-12) otherwise make scipy's QZ
    reordering fail. A solver failure is a :class:`DesignError`, never a traceback.
    """
    dx, du = _scales(Q), _scales(R)
    As = A * dx[None, :] / dx[:, None]
    Bs = B * du[None, :] / dx[:, None]
    Qs, Rs = Q * np.outer(dx, dx), R * np.outer(du, du)
    Ns = None if N is None else N * np.outer(dx, du)
    try:
        with np.errstate(all="raise"):
            if dt:
                X = scipy.linalg.solve_discrete_are(As, Bs, Qs, Rs, s=Ns)
                Ks = np.linalg.solve(
                    Rs + Bs.T @ X @ Bs, Bs.T @ X @ As + (0 if Ns is None else Ns.T)
                )
            else:
                X = scipy.linalg.solve_continuous_are(As, Bs, Qs, Rs, s=Ns)
                Ks = np.linalg.solve(Rs, Bs.T @ X + (0 if Ns is None else Ns.T))
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        raise DesignError(
            f"the Riccati equation has no usable solution for these weights ({exc})"
        ) from None
    K = Ks * du[:, None] / dx[None, :]
    closed = np.linalg.eigvals(A - B @ K)
    stable = np.all(np.abs(closed) < 1) if dt else np.all(closed.real < 0)
    if not np.all(np.isfinite(K)) or not stable:
        raise DesignError(
            "the Riccati solution does not stabilise the plant (ill-conditioned weights)"
        )
    return K


def lqr(sys, Q, R) -> np.ndarray:
    """State-feedback gain K for u = −Kx, continuous or discrete by ``sys.dt`` (``lqr``/``dlqr``).

    Raises ``DesignError`` for weights that are not (semi)definite, an (A, B)
    pair that is not stabilisable, or a Riccati equation without a stabilising solution.

    Parameters
    ----------
    sys : control.StateSpace
        The plant.
    Q : array_like, shape (n, n)
        State weight (positive semidefinite).
    R : array_like, shape (m, m)
        Input weight (positive definite).

    Returns
    -------
    numpy.ndarray, shape (m, n)
        The gain K.
    """
    ss = _ss(sys)
    A, B = np.asarray(ss.A), np.asarray(ss.B)
    Q = _check_weight("Q", Q, A.shape[0], definite=False)
    R = _check_weight("R", R, B.shape[1], definite=True)
    if _uncontrollable_unstable(A, B, ss.dt):
        raise DesignError("(A, B) is not stabilisable: an unstable mode is uncontrollable")
    return _riccati_gain(A, B, Q, R, None, ss.isdtime(strict=True))


def lqrd(sys, Q, R, Ts: float) -> tuple[np.ndarray, control.StateSpace]:
    """Discrete gain for a continuous plant and cost under a zero-order hold (MATLAB ``lqrd``).

    The continuous cost ∫ xᵀQx + uᵀRu over each period, with u held, becomes
    the discrete weights Qd, Rd and cross term Nd (Van Loan's exponential).

    Parameters
    ----------
    sys : control.StateSpace
        Continuous plant.
    Q, R : array_like
        Continuous weights, (n, n) and (m, m).
    Ts : float
        Sample period, s.

    Returns
    -------
    K : (m, n) ndarray
        Gain of u[k] = −K x[k].
    sysd : control.StateSpace
        The plant discretised with a zero-order hold at Ts.
    """
    ss = _ss(sys)
    if ss.isdtime(strict=True):
        raise DesignError("lqrd needs a continuous plant")
    if not (np.isfinite(Ts) and Ts > 0):
        raise DesignError(f"Ts must be a positive number of seconds, got {Ts}")
    A, B = np.asarray(ss.A), np.asarray(ss.B)
    n, m = B.shape
    Q = _check_weight("Q", Q, n, definite=False)
    R = _check_weight("R", R, m, definite=True)
    # Van Loan: expm([[-Fᵀ, W], [0, F]]·Ts) with F = [[A, B], [0, 0]], W = blkdiag(Q, R)
    F = np.zeros((n + m, n + m))
    F[:n, :n], F[:n, n:] = A, B
    W = scipy.linalg.block_diag(Q, R)
    E = scipy.linalg.expm(np.block([[-F.T, W], [np.zeros_like(F), F]]) * Ts)
    Phi = E[n + m :, n + m :]
    Wd = Phi.T @ E[: n + m, n + m :]
    Wd = 0.5 * (Wd + Wd.T)
    Ad, Bd = Phi[:n, :n], Phi[:n, n:]
    if _uncontrollable_unstable(Ad, Bd, Ts):
        raise DesignError("(A, B) is not stabilisable: an unstable mode is uncontrollable")
    K = _riccati_gain(Ad, Bd, Wd[:n, :n], Wd[n:, n:], Wd[:n, n:], Ts)
    return K, control.ss(Ad, Bd, np.asarray(ss.C), np.asarray(ss.D), Ts)


def kalman(sys, Qn, Rn, G=None) -> np.ndarray:
    """Steady-state Kalman gain L (MATLAB ``kalman``'s L); G defaults to identity.

    Continuous: x̂̇ = A x̂ + B u + L (y − C x̂). Discrete: the predictor gain of
    x̂[k+1] = A x̂[k] + B u[k] + L (y[k] − C x̂[k]); the current-estimate gain is
    M = A⁻¹L (see :func:`kalman_current`).

    Parameters
    ----------
    sys : control.StateSpace
        The plant (continuous, or discrete with dt > 0).
    Qn : array_like, shape (g, g)
        Process noise intensity (covariance for a discrete plant).
    Rn : array_like, shape (p, p)
        Measurement noise intensity.
    G : array_like, shape (n, g), optional
        Process noise input matrix.

    Returns
    -------
    numpy.ndarray, shape (n, p)
        The gain L.
    """
    ss = _ss(sys)
    A, C = np.asarray(ss.A), np.asarray(ss.C)
    n = A.shape[0]
    G = np.eye(n) if G is None else np.atleast_2d(np.asarray(G, float))
    Qn = _check_weight("Qn", Qn, G.shape[1], definite=False)
    Rn = _check_weight("Rn", Rn, C.shape[0], definite=True)
    if _uncontrollable_unstable(A.T, C.T, ss.dt):
        raise DesignError("(A, C) is not detectable: an unstable mode is unobservable")
    return _riccati_gain(A.T, C.T, G @ Qn @ G.T, Rn, None, ss.isdtime(strict=True)).T


def kalman_current(sys, Qn, Rn, G=None) -> np.ndarray:
    """Discrete current-estimate (filter) gain M: x̂[k|k] = x̄[k] + M (y[k] − C x̄[k]).

    M = P̄ Cᵀ (C P̄ Cᵀ + Rn)⁻¹ with P̄ the steady predicted covariance; it is what
    a sampled Kalman filter that measures, then controls, uses each period.

    Parameters
    ----------
    sys : control.StateSpace
        Discrete plant.
    Qn, Rn, G
        As for :func:`kalman`.

    Returns
    -------
    numpy.ndarray, shape (n, p)
        The gain M.
    """
    ss = _ss(sys)
    if not ss.isdtime(strict=True):
        raise DesignError("kalman_current needs a discrete plant")
    L = kalman(ss, Qn, Rn, G)
    return np.linalg.solve(np.asarray(ss.A), L)


def lqg(sys, K, L) -> control.StateSpace:
    """The LQG compensator K(s) = K (sI − A + BK + LC)⁻¹ L (from y to −u), predictor form.

    Parameters
    ----------
    sys : control.StateSpace
        The plant.
    K : array_like, shape (m, n)
        Regulator gain.
    L : array_like, shape (n, p)
        Estimator gain.

    Returns
    -------
    control.StateSpace
        The compensator, p inputs, m outputs.
    """
    ss = _ss(sys)
    A, B, C = np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C)
    K, L = np.atleast_2d(K), np.atleast_2d(L)
    return control.ss(A - B @ K - L @ C, L, K, np.zeros((K.shape[0], L.shape[1])), ss.dt)


def lqg_current(sys, K, M) -> control.StateSpace:
    """Discrete LQG compensator with the current estimate (from y to −u).

    Each period: x̂ = x̄ + M (y − C x̄), u = −K x̂, x̄⁺ = A x̂ + B u, so
    K(z) = K(I − MC) (zI − (A − BK)(I − MC))⁻¹ (A − BK) M + K M.

    Parameters
    ----------
    sys : control.StateSpace
        Discrete plant.
    K : array_like, shape (m, n)
        Regulator gain.
    M : array_like, shape (n, p)
        Current-estimate filter gain.

    Returns
    -------
    control.StateSpace
        The compensator, discrete at the plant's dt.
    """
    ss = _ss(sys)
    if not ss.isdtime(strict=True):
        raise DesignError("lqg_current needs a discrete plant")
    A, B, C = np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C)
    K, M = np.atleast_2d(K), np.atleast_2d(M)
    I_MC = np.eye(A.shape[0]) - M @ C
    Acl = A - B @ K
    return control.ss(Acl @ I_MC, Acl @ M, K @ I_MC, K @ M, ss.dt)


def sigma(sys, omega) -> np.ndarray:
    """Singular values of sys(jω) (or of e^{jωdt}), largest first; shape (len(ω), min(p, m)).

    Parameters
    ----------
    sys : control.StateSpace or control.TransferFunction
        The system.
    omega : array_like, shape (nw,)
        Frequencies, rad/s.

    Returns
    -------
    numpy.ndarray, shape (nw, min(p, m))
        The singular values.
    """
    sys = _ss(sys)
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    resp = sys.frequency_response(w)
    H = np.asarray(resp.frdata if hasattr(resp, "frdata") else resp.fresp)
    if H.ndim == 1:
        H = H[None, None, :]
    return np.array([np.linalg.svd(H[:, :, i], compute_uv=False) for i in range(w.size)])


@dataclass(repr=False)
class LTRResult(ShortRepr):
    """Loop transfer recovery over a list of ρ.

    Attributes
    ----------
    omega : (F,) rad/s
    target : (F, k) singular values of the LQR (or Kalman) target loop
    loops : dict ρ → (F, k) singular values of the recovered loop
    compensators : dict ρ → control.StateSpace K(s)
    K : (m, n) regulator gain
    L : dict ρ → estimator gain
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
        """Largest |20 log10 σᵢ_loop − 20 log10 σᵢ_target| over a frequency band, dB."""
        sel = (
            np.ones(self.omega.size, bool)
            if band is None
            else ((self.omega >= band[0]) & (self.omega <= band[1]))
        )
        diff = 20 * (np.log10(self.loops[rho][sel]) - np.log10(self.target[sel]))
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
    sys,
    Q,
    R,
    rhos,
    *,
    R0=None,
    Q0=None,
    q2: float = 1.0,
    side: str = "input",
    omega=None,
    K=None,
) -> LTRResult:
    """Loop transfer recovery for a list of ρ (paper B: 76.92, 7.692, 0.7692, 0.007692).

    Continuous plants use the classic compensator; discrete plants the
    current-estimate one (:func:`lqg_current`), which recovers the target loop
    exactly as ρ → 0 for a minimum-phase plant with CB of full rank.

    Parameters
    ----------
    sys : control.StateSpace
        Plant G(s) = C (sI − A)⁻¹ B (or G(z)).
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
        Frequencies, rad/s (default 1e-4..1e2 log-spaced, up to Nyquist for a discrete plant).
    K : array_like, optional
        Input LTR: the regulator gain of the target loop, when designed elsewhere
        (e.g. :func:`lqrd`); Q and R are then not used.

    Returns
    -------
    LTRResult
        ``omega``, the target loop's and each recovered loop's singular values.
    """
    ss = _ss(sys)
    A, B, C = np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C)
    n = A.shape[0]
    discrete = ss.isdtime(strict=True)
    rhos = [float(r) for r in rhos]
    if not rhos or any(not np.isfinite(r) or r <= 0 for r in rhos):
        raise DesignError(f"every ρ must be a positive finite number, got {rhos}")
    if side not in ("input", "output"):
        raise DesignError(f"side must be 'input' or 'output', got {side!r}")
    w_max = np.pi / ss.dt if discrete else 1e2
    w = np.logspace(-4, np.log10(w_max) - 1e-9, 300) if omega is None else np.asarray(omega, float)
    loops, comps, Ls = {}, {}, {}

    def compensator(Kr, Lf):
        if discrete:
            return lqg_current(ss, Kr, np.linalg.solve(A, Lf))
        return lqg(ss, Kr, Lf)

    if side == "input":
        K = lqr(ss, Q, R) if K is None else np.atleast_2d(np.asarray(K, float))
        target = sigma(control.ss(A, B, K, 0 * K @ B, ss.dt), w)
        R0 = np.eye(C.shape[0]) if R0 is None else np.asarray(R0, float)
        Qf = (np.zeros((n, n)) if Q0 is None else np.asarray(Q0, float)) + q2 * B @ B.T
        for rho in rhos:
            L = kalman(ss, Qf, rho * R0)
            Kc = compensator(K, L)
            Ls[rho], comps[rho] = L, Kc
            loops[rho] = sigma(control.series(ss, Kc), w)  # K(s) G(s): first G, then K
    else:
        L = kalman(ss, Q, R)
        target = sigma(control.ss(A, L, C, 0 * C @ L, ss.dt), w)
        R0 = np.eye(B.shape[1]) if R0 is None else np.asarray(R0, float)
        Qr = (np.zeros((n, n)) if Q0 is None else np.asarray(Q0, float)) + q2 * C.T @ C
        for rho in rhos:
            Kr = lqr(ss, Qr, rho * R0)
            Kc = compensator(Kr, L)
            Ls[rho], comps[rho] = L, Kc
            loops[rho] = sigma(control.series(Kc, ss), w)  # G(s) K(s)
        K = None
    return LTRResult(w, target, loops, comps, K, Ls, side)
