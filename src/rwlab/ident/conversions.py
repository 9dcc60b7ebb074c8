"""Continuous ↔ discrete conversions of polynomial models: ``d2c`` and ``c2d``.

python-control has ``c2d`` (``sample_system``) but no ``d2c``: the inverse ZOH
(through the matrix logarithm) and the inverse bilinear transform are written
here. The functions work on coefficient arrays; :meth:`PolyModel.d2c
<rwlab.ident.models.PolyModel.d2c>` and :func:`rwlab.ident.c2d` wrap them.
"""

from __future__ import annotations

import warnings

import control
import numpy as np
from scipy import linalg
from scipy import signal as sps

from rwlab.data import check_Ts
from rwlab.errors import ModelError
from rwlab.ident.polynomials import to_z

__all__ = ["c2d_coefficients", "d2c_tf"]


def d2c_tf(
    B: np.ndarray,
    den: np.ndarray,
    Ts: float,
    *,
    nk: int = 1,
    method: str = "zoh",
    pade_order: int | None = None,
) -> control.TransferFunction:
    """Continuous-time equivalent G(s) of ``B/den`` (polynomials in q⁻¹).

    Parameters
    ----------
    B : ndarray, shape (nb,)
        Numerator in q⁻¹ with its ``nk`` leading zeros.
    den : ndarray
        Monic denominator in q⁻¹ (``A·F``).
    Ts : float
        Sample time, s.
    nk : int
        Input delay in samples; ``nk − 1`` of them are a pure delay beyond the ZOH's.
    method : {'zoh', 'tustin'}
        Inverse zero-order hold, or the bilinear transform s = (2/Ts)(z−1)/(z+1).
    pade_order : int, optional
        ZOH only: approximate a delay of ``nk − 1 > 0`` samples by a Padé
        approximant of this order; without it such a model raises ``ModelError``.

    Returns
    -------
    control.TransferFunction
        Continuous time (dt = 0), SISO.
    """
    if method == "tustin":
        num_s, den_s = _inverse_bilinear(*to_z(B, den), Ts)
        return control.tf(num_s, den_s)
    if method != "zoh":
        raise ModelError(f"d2c method must be 'zoh' or 'tustin', got {method!r}")
    delay = max(nk - 1, 0)
    tf = _inverse_zoh(*to_z(B[delay:], den), Ts)
    if delay:
        if pade_order is None:
            raise ModelError(
                f"the model has an input delay of {delay} samples ({delay * Ts:g} s) "
                "that a rational G(s) cannot hold; pass pade_order=N to approximate it, "
                "or use method='tustin'"
            )
        tf = tf * control.tf(*control.pade(delay * Ts, int(pade_order)))
    return tf


def _inverse_bilinear(num_z, den_z, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Substitute z = (1 + sTs/2)/(1 − sTs/2) into num(z)/den(z) (descending powers)."""
    n = len(den_z) - 1
    plus, minus = np.array([Ts / 2, 1.0]), np.array([-Ts / 2, 1.0])

    def substitute(p):
        out = np.zeros(n + 1)
        for k, c in enumerate(p):  # c multiplies z^(n-k)
            term = c * np.polymul(_polypow(plus, n - k), _polypow(minus, k))
            out[-len(term) :] += term
        return out

    num_s, den_s = substitute(num_z), substitute(den_z)
    if abs(den_s[0]) < 1e-300:
        raise ModelError("the model has a pole at z = −1; it has no Tustin equivalent")
    return num_s / den_s[0], den_s / den_s[0]


def _polypow(p: np.ndarray, k: int) -> np.ndarray:
    out = np.array([1.0])
    for _ in range(k):
        out = np.polymul(out, p)
    return out


def _inverse_zoh(num_z, den_z, Ts: float) -> control.TransferFunction:
    """Continuous G(s) whose ZOH sampling at Ts is num(z)/den(z) (matrix logarithm)."""
    num_z = np.trim_zeros(np.asarray(num_z, float), "f")
    if num_z.size == 0:
        return control.tf([0.0], [1.0])
    if len(num_z) > len(den_z):
        raise ModelError("improper discrete model: more zeros than poles")
    Ad, Bd, Cd, Dd = sps.tf2ss(num_z, den_z)
    n = Ad.shape[0]
    if n == 0:
        return control.tf(Dd.ravel(), [1.0])
    eig = np.linalg.eigvals(Ad)
    if np.any(np.abs(eig) < 1e-12) or np.any((np.abs(eig.imag) < 1e-12) & (eig.real < 0)):
        raise ModelError(
            "the model has a pole at z = 0 or on the negative real axis, which no "
            "continuous system sampled with a ZOH produces; use method='tustin'"
        )
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = Ad, Bd
    M[n, n] = 1.0
    L = linalg.logm(M) / Ts
    if np.max(np.abs(np.imag(L))) > 1e-8 * max(1.0, np.max(np.abs(L))):
        raise ModelError("the matrix logarithm is complex: no real ZOH equivalent exists")
    L = np.real(L)
    num_s, den_s = sps.ss2tf(L[:n, :n], L[:n, n:], Cd, Dd)
    return control.tf(np.atleast_2d(num_s)[0], den_s)


def c2d_coefficients(
    sys: control.TransferFunction, Ts: float, method: str = "zoh"
) -> tuple[np.ndarray, np.ndarray]:
    """The monic ``A`` and ``B`` (in q⁻¹) of a continuous SISO system sampled at ``Ts``.

    Parameters
    ----------
    sys : control.TransferFunction or control.StateSpace
        Continuous-time (dt = 0) SISO system.
    Ts : float
        Sample time in seconds.
    method : {'zoh', 'tustin'}
        Zero-order hold or bilinear transform.

    Returns
    -------
    A, B : ndarray
        Denominator (``A[0] = 1``) and numerator, same length, in powers of q⁻¹.
    """
    Ts = check_Ts(Ts)
    if method not in ("zoh", "tustin"):
        raise ModelError(f"c2d method must be 'zoh' or 'tustin', got {method!r}")
    tf = control.tf(sys)
    if not control.isctime(tf, strict=True):
        raise ModelError("c2d needs a continuous-time system (dt = 0)")
    if tf.ninputs != 1 or tf.noutputs != 1:
        raise ModelError("c2d supports SISO systems")
    num, den = np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
    tiny = 1e-14 * max(np.max(np.abs(num)), 1e-300)
    num = num[np.argmax(np.abs(num) > tiny) :] if np.any(np.abs(num) > tiny) else np.zeros(1)
    with (
        warnings.catch_warnings()
    ):  # scipy flags |coefficient| < 1e-14 absolute, even when meaningful
        warnings.simplefilter("ignore", sps.BadCoefficients)
        numd, dend, _ = sps.cont2discrete(
            (num, den), Ts, method="zoh" if method == "zoh" else "bilinear"
        )
    numd = np.atleast_2d(numd)[0]
    numd = np.concatenate([np.zeros(len(dend) - len(numd)), numd])  # align powers of z
    scale = dend[0]
    B = numd / scale
    B[np.abs(B) < 1e-14 * max(1.0, np.max(np.abs(B)))] = 0.0
    return dend / scale, B
