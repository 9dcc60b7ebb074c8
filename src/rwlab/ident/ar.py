"""AR models of a time series by least squares (MATLAB ``ar``).

``A(q) y(t) = e(t)`` with ``A = 1 + a₁q⁻¹ + … + a_na q⁻ⁿᵃ``. Two of MATLAB's
approaches, both without windowing (only rows whose lags lie inside the record):

- ``'ls'``: forward least squares, min Σₜ [A(q) y(t)]², t = na … N−1 (as ``arx``);
- ``'fb'`` (MATLAB's default): the sum of that forward criterion and the same
  criterion for the time-reversed record, Σₜ [y(t) + a₁y(t+1) + … + a_na y(t+na)]²,
  t = 0 … N−1−na. For a stationary process both have the same A; using both
  halves the end effects and tends to give a stable A on short records.

The noise variance is that of the forward prediction errors, Σ ε_f²/(N_f − na),
and the covariance λ·(Φ_fᵀΦ_f)⁻¹ of the forward regressors Φ_f for both
approaches: forward-backward and forward least squares have the same asymptotic
covariance (the backward rows repeat the forward information, they do not
double it), so stacking both in the covariance would understate it twice over.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import linalg

from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError
from rwlab.ident.arx import check_order, triangular_factor
from rwlab.ident.models import PolyModel
from rwlab.ident.validation import estimation_report

__all__ = ["ar"]

APPROACHES = ("fb", "ls")


def _rows(y: np.ndarray, na: int, backward: bool) -> np.ndarray:
    """[−y(t−1) … −y(t−na) | y(t)] (forward) or its time-reversed twin, one row per t."""
    x = y[::-1] if backward else y
    N = len(x)
    out = np.empty((N - na, na + 1))
    for i in range(1, na + 1):
        out[:, i - 1] = -x[na - i : N - i]
    out[:, na] = x[na:]
    return out


def ar(data: IOData | Sequence[IOData], na: int, approach: str = "fb") -> PolyModel:
    """Estimate an AR model ``A y = e`` of a time series (MATLAB ``ar(y, na, approach)``).

    Parameters
    ----------
    data : IOData or list of IOData
        Output-only record(s), N samples each (``IOData(None, y, Ts)``);
        several experiments are estimated jointly.
    na : int
        Order of A (≥ 0).
    approach : {'fb', 'ls'}
        Forward-backward least squares (MATLAB's default) or forward least squares.

    Returns
    -------
    PolyModel
        No input (``nu == 0``); ``A`` of shape (na+1,), ``noise_variance`` in
        the output's unit squared and the (na, na) parameter covariance.
    """
    experiments = as_experiments(data)
    first = experiments[0]
    if first.ny != 1 or first.nu != 0:
        raise DataError(
            f"ar models a single-output time series; the data have {first.nu} inputs and "
            f"{first.ny} outputs (use IOData(None, y, Ts), or arx for input-output data)"
        )
    if approach not in APPROACHES:
        raise DataError(f"approach must be one of {', '.join(APPROACHES)}; got {approach!r}")
    na = check_order("na", na)
    used = [e.y[:, 0] for e in experiments if e.N > na]
    forward = [_rows(y, na, False) for y in used]
    rows_f = sum(len(f) for f in forward)
    if rows_f < na + 1:
        raise DataError(
            f"too few samples: AR({na}) needs more than {2 * na} samples "
            f"(got {max(e.N for e in experiments)})"
        )
    blocks = forward + ([_rows(y, na, True) for y in used] if approach == "fb" else [])
    R = triangular_factor(np.vstack(blocks))
    R11 = R[:na, :na]
    diag = np.abs(np.diag(R11))
    if na and diag.min() <= 1e-11 * max(diag.max(), 1e-300):
        raise EstimationError("the regression is rank deficient: the record does not excite AR(na)")
    theta = linalg.solve_triangular(R11, R[:na, na]) if na else np.zeros(0)
    Phi_f = np.vstack(forward)
    eps = Phi_f[:, na] - Phi_f[:, :na] @ theta
    sse = float(eps @ eps)
    lam = sse / (rows_f - na)
    Rf = triangular_factor(Phi_f[:, :na])
    Rinv = linalg.solve_triangular(Rf, np.eye(na)) if na else np.zeros((0, 0))
    model = PolyModel(
        np.concatenate([[1.0], theta]),
        None,
        Ts=first.Ts,
        noise_variance=lam,
        covariance=lam * Rinv @ Rinv.T,
        input_name=(),
        output_name=first.output_names[0],
    )
    method = "ar (forward-backward least squares)" if approach == "fb" else "ar (least squares)"
    model.report.update(
        estimation_report(model, experiments, method=method, loss=sse / rows_f, approach=approach)
    )
    return model
