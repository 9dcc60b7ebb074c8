"""ARX estimation by linear least squares (MATLAB ``arx``).

``A(q) y(t) = B₁(q) u₁(t−nk₁) + … + e(t)``, solved with a QR factorisation of
the regressor matrix (no normal equations).

Pre-sample values: the regression uses only the rows for which every lagged
sample exists, i.e. t = n₀ … N−1 with n₀ = max(na, nkᵢ + nbᵢ − 1). Nothing is
assumed about the signals before the record starts. With several experiments
(``rwlab.data.merge``) each contributes its own rows; no row spans two.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import linalg

from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError
from rwlab.ident.gain_constraint import StaticGain, constrained_least_squares
from rwlab.ident.models import PolyModel
from rwlab.ident.validation import estimation_report

__all__ = ["arx", "arx_loss", "check_order"]


def check_order(name: str, value, minimum: int = 0) -> int:
    """Validate one model order: an integer ≥ ``minimum``.

    Parameters
    ----------
    name : str
        The order's name for the message (``"na"``...).
    value : int
        The order given.
    minimum : int
        Smallest allowed value.

    Returns
    -------
    int
        ``value`` as an int.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DataError(f"order {name} must be an integer, got {value!r}")
    if value < minimum:
        raise DataError(f"order {name} must be ≥ {minimum}, got {value}")
    return int(value)


def _is_empty(value) -> bool:
    return isinstance(value, Sequence) and len(value) == 0


def _per_input(name: str, value, nu: int, minimum: int) -> list[int]:
    values = list(value) if isinstance(value, Sequence) else [value] * nu
    if len(values) != nu:
        raise DataError(f"{name} needs one value per input ({nu}), got {values}")
    return [check_order(name, v, minimum) for v in values]


def _fill(data: IOData, na: int, nb: list[int], nk: list[int], n0: int, out: np.ndarray) -> None:
    """Write rows t = n0..N−1 of [Φ | y(t)] for one experiment into ``out``."""
    y = data.y[:, 0]
    N = data.N
    col = 0
    for i in range(1, na + 1):
        out[:, col] = -y[n0 - i : N - i]
        col += 1
    for j, (b, k) in enumerate(zip(nb, nk, strict=True)):
        u = data.u[:, j]
        for i in range(b):
            out[:, col] = u[n0 - k - i : N - k - i]
            col += 1
    out[:, col] = y[n0:]


def regression(data: IOData, na: int, nb: list[int], nk: list[int], n0: int):
    """Regressor matrix Φ (rows t = n0..N−1) and target y(t) for one experiment."""
    out = np.empty((data.N - n0, na + sum(nb) + 1))
    _fill(data, na, nb, nk, n0, out)
    return out[:, :-1], out[:, -1]


def triangular_factor(M: np.ndarray, block: int = 65536) -> np.ndarray:
    """R of M = QR, by QR of row blocks then of the stacked block factors (TSQR).

    Same numerical stability as one Householder QR, but each block fits in
    cache: about 3× faster than a single LAPACK call on 10⁶ × 5 regressors.
    """
    if M.shape[0] <= 2 * block:
        return np.asarray(np.linalg.qr(M, mode="r"))
    parts = [np.linalg.qr(M[i : i + block], mode="r") for i in range(0, M.shape[0], block)]
    return np.asarray(np.linalg.qr(np.vstack(parts), mode="r"))


def _check_excitation(experiments: list[IOData], nb: list[int]) -> None:
    for j, b in enumerate(nb):
        if b and all(np.ptp(d.u[:, j]) == 0 for d in experiments):
            raise EstimationError(
                f"input {experiments[0].input_names[j]!r} is constant: it is not persistently "
                "exciting, so B cannot be identified; use a PRBS, chirp or multisine input"
            )


def first_row(na: int, nb: list[int], nk: list[int]) -> int:
    """First sample index at which every ARX regressor is available."""
    return max([na, *[k + b - 1 for b, k in zip(nb, nk, strict=True)], 0])


def _solve(experiments, na, nb, nk, n0=None):
    """QR least squares over all experiments. Returns θ, R11, sum of squares, rows, Qᵀy."""
    n0 = first_row(na, nb, nk) if n0 is None else n0
    d = na + sum(nb)
    used = [e for e in experiments if e.N > n0]
    rows = sum(e.N - n0 for e in used)
    if rows < d + 1:
        raise DataError(
            f"too few samples: ARX with {d} parameters needs more than {n0 + d} samples "
            f"(got {max(e.N for e in experiments)}); use lower orders or more data"
        )
    M = np.empty((rows, d + 1))
    pos = 0
    for e in used:
        _fill(e, na, nb, nk, n0, M[pos : pos + e.N - n0])
        pos += e.N - n0
    R = triangular_factor(M)
    R11, r12, r22 = R[:d, :d], R[:d, d], abs(R[d, d]) if R.shape[0] > d else 0.0
    diag = np.abs(np.diag(R11))
    if d and (diag.min() <= 1e-11 * max(diag.max(), 1e-300)):
        raise EstimationError(
            "the regression is rank deficient: the data do not excite all parameters "
            "(constant or too-slow input, or orders too high for this record)"
        )
    theta = linalg.solve_triangular(R11, r12) if d else np.zeros(0)
    return theta, R11, float(r22**2), rows, r12


def arx(
    data: IOData | Sequence[IOData], na: int, nb=None, nk=None, *, dc_gain: float | None = None
) -> PolyModel:
    """Estimate an ARX model by least squares (MATLAB ``arx(data, [na nb nk])``).

    With no input (a time series) this is the AR model ``A y = e`` by forward
    least squares (MATLAB ``arx(y, na)``; see also :func:`rwlab.ident.ar`).

    Parameters
    ----------
    data : IOData or list of IOData
        Single-output record(s); several experiments are estimated jointly.
    na : int
        Order of A (≥ 0).
    nb : int or sequence of int, optional
        Number of B coefficients per input (≥ 0; default 2). Omit for a time series.
    nk : int or sequence of int, optional
        Input delay in samples per input (≥ 0; default 1). Omit for a time series.
    dc_gain : float, optional
        A known static gain K (output unit per input unit, single input only):
        the estimate is the least-squares one subject to ``B(1) = K·A(1)``,
        solved exactly (:mod:`rwlab.ident.gain_constraint`; beyond MATLAB).

    Returns
    -------
    PolyModel
        With ``noise_variance`` = SSE/(rows − d) and the parameter covariance
        ``noise_variance · (ΦᵀΦ)⁻¹``; with ``dc_gain``, SSE/(rows − d + 1) and the
        constrained estimate's covariance (rank d − 1), and ``report['dc_gain']``.
    """
    experiments = as_experiments(data)
    first = experiments[0]
    if first.ny != 1:
        raise DataError(f"arx estimates single-output models; the data have {first.ny} outputs")
    if first.nu == 0 and not all(v is None or _is_empty(v) for v in (nb, nk)):
        raise DataError("the data have no input (a time series): omit nb and nk, arx(data, na)")
    nb = 2 if nb is None else nb
    nk = 1 if nk is None else nk
    na = check_order("na", na)
    nb = _per_input("nb", nb, first.nu, 0)
    nk = _per_input("nk", nk, first.nu, 0)
    _check_excitation(experiments, nb)
    theta, R11, sse, rows, r12 = _solve(experiments, na, nb, nk)
    d = len(theta)
    if dc_gain is not None:
        if first.nu != 1:
            raise DataError(f"dc_gain applies to one input; the data have {first.nu}")
        constraint = StaticGain(dc_gain, na, nb[0])
        theta, cov, sse = constrained_least_squares(R11, r12, sse, rows, constraint)
        lam = sse / (rows - d + 1)
    else:
        lam = sse / (rows - d)
        Rinv = linalg.solve_triangular(R11, np.eye(d)) if d else np.zeros((0, 0))
        cov = lam * Rinv @ Rinv.T
    A = np.concatenate([[1.0], theta[:na]])
    width = max([k + b for b, k in zip(nb, nk, strict=True)] + [1])
    B = np.zeros((first.nu, width))
    pos = na
    for j, (b, k) in enumerate(zip(nb, nk, strict=True)):
        B[j, k : k + b] = theta[pos : pos + b]
        pos += b
    model = PolyModel(
        A,
        (B if first.nu != 1 else B[0]) if first.nu else None,
        Ts=first.Ts,
        nk=nk,
        nb=nb,
        noise_variance=lam,
        covariance=cov,
        input_name=first.input_names[0] if first.nu == 1 else first.input_names,
        output_name=first.output_names[0],
    )
    method = "arx (QR least squares)"
    extra = {}
    if dc_gain is not None:
        method = "arx (QR least squares, static gain constrained)"
        extra = {"dc_gain": float(dc_gain), "n_free": d - 1}
    model.report.update(
        estimation_report(model, experiments, method=method, loss=sse / rows, **extra)
    )
    return model


def arx_loss(est: IOData, val: IOData | None, na: int, nb: int, nk: int, n0: int) -> float:
    """Mean squared one-step prediction error of ARX(na, nb, nk) fitted on ``est``.

    Rows start at the common index ``n0`` so losses over a scan of orders or
    delays are computed on exactly the same samples.

    Parameters
    ----------
    est : IOData
        Estimation record.
    val : IOData or None
        Record the loss is measured on (None: ``est`` itself).
    na, nb, nk : int
        ARX orders and delay, samples.
    n0 : int
        First row (sample index) of the regression, common to the whole scan.

    Returns
    -------
    float
        Mean squared one-step prediction error, in the output's unit squared.
    """
    theta, _, sse, rows, _ = _solve([est], na, [nb], [nk], n0)
    if val is None:
        return sse / rows
    phi, t = regression(val, na, [nb], [nk], n0)
    e = t - phi @ theta
    return float(e @ e / len(e))
