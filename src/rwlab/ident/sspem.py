"""Prediction-error refinement of state-space models: ``ssest`` (MATLAB ``ssest``).

Starts from :func:`rwlab.ident.subspace.n4sid` and minimises the one-step
prediction errors, in a free parameterisation with data-driven local
coordinates or in an observability canonical form. Written here because no
maintained Python library offers it with innovations-form noise models.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy import optimize
from threadpoolctl import threadpool_limits

from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError, ModelError, RwlabWarning
from rwlab.ident.ssmodel import INITIAL, SSModel, finish_estimate, fit_report, predict_one_step
from rwlab.ident.subspace import n4sid

__all__ = ["ssest"]


# -- ssest ------------------------------------------------------------------------------
def _ddlc(model: SSModel) -> np.ndarray:
    """Basis of the parameter directions orthogonal to changes of state basis.

    Data-driven local coordinates (McKelvey, Helmersson & Ribarits 2004): a
    similarity T = I + δ moves (A, B, C, D, K) by (δA − Aδ, δB, −Cδ, 0, δK); the
    search runs in the orthogonal complement of those n² directions.
    """
    n = model.nx
    tangents = []
    for i in range(n):
        for j in range(n):
            dlt = np.zeros((n, n))
            dlt[i, j] = 1.0
            parts = [dlt @ model.A - model.A @ dlt, dlt @ model.B, -model.C @ dlt]
            if model.feedthrough:
                parts.append(np.zeros_like(model.D))
            parts.append(dlt @ model.K)
            tangents.append(np.concatenate([p.ravel() for p in parts]))
    Tm = np.array(tangents).T
    U, s, _ = np.linalg.svd(Tm, full_matrices=True)
    rank = int(np.sum(s > 1e-10 * max(s.max(), 1e-300)))
    return U[:, rank:]


def _canonical(model: SSModel, estimate_k: bool) -> tuple[SSModel, np.ndarray]:
    """Observability canonical form and the selection of its free parameters.

    Observability indices are spread evenly over the outputs; C holds unit
    rows and A the shift structure with one free row per output (Ljung, §4.3).
    """
    n, ny = model.nx, model.ny
    if ny > n:
        raise ModelError(f"the canonical form needs ny ≤ nx; got ny = {ny}, nx = {n}")
    idx = [n // ny + (1 if i < n % ny else 0) for i in range(ny)]
    rows = []
    for i, k in enumerate(idx):
        ci = model.C[i]
        for _ in range(k):
            rows.append(ci)
            ci = ci @ model.A
    Ob = np.array(rows)
    if np.linalg.cond(Ob) > 1e10:
        raise EstimationError(
            "the initial model is not observable with evenly spread indices; use form='free'"
        )
    Ti = np.linalg.inv(Ob)
    A, B, K = Ob @ model.A @ Ti, Ob @ model.B, Ob @ model.K
    starts = np.cumsum([0, *idx[:-1]])
    free_rows = [s + k - 1 for s, k in zip(starts, idx, strict=True)]
    A2 = np.zeros((n, n))
    for s, k in zip(starts, idx, strict=True):
        for j in range(k - 1):
            A2[s + j, s + j + 1] = 1.0
    A2[free_rows] = A[free_rows]
    C2 = np.zeros((ny, n))
    C2[np.arange(ny), starts] = 1.0
    canon = SSModel(
        A2, B, C2, model.D, K, Ts=model.Ts, feedthrough=model.feedthrough,
        input_names=model.input_names, output_names=model.output_names,
    )  # fmt: skip
    mask = [np.zeros((n, n), bool), np.ones(B.shape, bool), np.zeros(C2.shape, bool)]
    mask[0][free_rows] = True
    if model.feedthrough:
        mask.append(np.ones(model.D.shape, bool))
    mask.append(np.full(K.shape, estimate_k))
    sel = np.flatnonzero(np.concatenate([m.ravel() for m in mask]))
    return canon, np.eye(canon.n_params)[:, sel]


def ssest(
    data: IOData | Sequence[IOData],
    nx: int | SSModel,
    *,
    form: str = "free",
    feedthrough: bool = False,
    disturbance: str = "estimate",
    initial: str = "auto",
    max_iter: int = 100,
    tol: float = 1e-8,
    n4sid_options: dict | None = None,
) -> SSModel:
    """Prediction-error estimate of a state-space model (MATLAB ``ssest``, discrete time).

    Parameters
    ----------
    data : IOData or list of IOData
    nx : int or SSModel
        Model order (then :func:`n4sid` gives the start) or an initial model.
    form : {'free', 'canonical'}
        Free parameterisation, searched in data-driven local coordinates
        (MATLAB's default), or the observability canonical form.
    feedthrough : bool
        Estimate D (default False).
    disturbance : {'estimate', 'none'}
        Estimate K, or fix it to zero (an output-error model).
    initial : {'auto', 'zero', 'estimate', 'steady'}
        Initial state: estimated with the parameters ('auto' and 'estimate'),
        zero, or the predictor's steady state for the first sample.
    max_iter, tol : int, float
        Limits of the Gauss–Newton / trust-region search (scipy ``least_squares``).
    n4sid_options : dict, optional
        Keyword arguments for the initial :func:`n4sid`.

    Returns
    -------
    SSModel
        With the parameter covariance (first order, from the Jacobian of the
        weighted prediction errors at the optimum) and ``noise_variance``.

    Notes
    -----
    The criterion is ``Σ eᵀ Λ₀⁻¹ e`` with Λ₀ the initial model's innovation
    covariance, which for several outputs approximates MATLAB's default
    ``det(Σ e eᵀ / N)`` at its optimum; the reported ``loss`` is that determinant.
    """
    experiments = as_experiments(data)
    nu, ny = experiments[0].nu, experiments[0].ny
    if form not in ("free", "canonical"):
        raise DataError(f"form must be 'free' or 'canonical', got {form!r}")
    if disturbance not in ("estimate", "none"):
        raise DataError(f"disturbance must be 'estimate' or 'none', got {disturbance!r}")
    if initial not in INITIAL:
        raise DataError(f"initial must be one of {INITIAL}, got {initial!r}")
    init = "estimate" if initial == "auto" else initial
    if isinstance(nx, SSModel):
        start = nx
        if (start.nu, start.ny) != (nu, ny):
            raise DataError("the initial model's input/output counts differ from the data's")
    else:
        start = n4sid(
            experiments,
            int(nx),
            feedthrough=feedthrough,
            disturbance=disturbance,
            **(n4sid_options or {}),
        )
    if feedthrough and not start.feedthrough:
        start = SSModel(
            start.A, start.B, start.C, start.D, start.K, Ts=start.Ts, feedthrough=True,
            input_names=start.input_names, output_names=start.output_names,
        )  # fmt: skip
    if disturbance == "none":
        start = SSModel(
            start.A, start.B, start.C, start.D, None, Ts=start.Ts, feedthrough=start.feedthrough,
            input_names=start.input_names, output_names=start.output_names,
        )  # fmt: skip
    if form == "canonical":
        start, basis = _canonical(start, disturbance == "estimate")
    else:
        basis = _ddlc(start)
        if disturbance == "none":
            k_rows = np.arange(start.n_params - start.K.size, start.n_params)
            basis = _restrict(basis, k_rows)
    theta0 = start.parameters
    Lam0 = fit_report(start, experiments, init, "start")["_Lambda"]
    Wt = np.linalg.cholesky(np.linalg.inv((Lam0 + Lam0.T) / 2))  # e Wt: whitened errors
    nb = basis.shape[1]
    n_x0 = start.nx * len(experiments) if init == "estimate" else 0
    x0_start = []
    for d in experiments:
        x0_start.append(predict_one_step(start, d.u, d.y, init)[1] if n_x0 else np.zeros(start.nx))

    def residuals(beta: np.ndarray) -> np.ndarray:
        model = start.with_parameters(theta0 + basis @ beta[:nb])
        out = []
        for i, d in enumerate(experiments):
            x0 = beta[nb + i * start.nx : nb + (i + 1) * start.nx] if n_x0 else init
            with np.errstate(all="ignore"):
                yhat, _ = predict_one_step(model, d.u, d.y, x0)
            out.append(((d.y - yhat) @ Wt).ravel())
        r = np.concatenate(out)
        return r if np.all(np.isfinite(r)) else np.full(r.shape, 1e10)

    beta0 = np.concatenate([np.zeros(nb), *(x0_start if n_x0 else [])])
    with threadpool_limits(1, user_api="blas"):  # small matrices: BLAS threads only cost
        sol = optimize.least_squares(
        residuals, beta0, method="trf", x_scale="jac", max_nfev=max_iter * (len(beta0) + 1),
        xtol=tol, ftol=tol, gtol=tol,
    )  # fmt: skip
    if not sol.success:
        warnings.warn(f"ssest stopped early: {sol.message}", RwlabWarning, stacklevel=2)
    model = start.with_parameters(theta0 + basis @ sol.x[:nb])
    J = sol.jac
    n_obs = J.shape[0]
    sigma2 = float(sol.fun @ sol.fun) / max(n_obs - J.shape[1], 1)
    cov_beta = sigma2 * np.linalg.pinv(J.T @ J)[:nb, :nb]
    covariance = basis @ cov_beta @ basis.T
    rep = fit_report(model, experiments, init, "ssest")
    return finish_estimate(
        model,
        rep,
        covariance=covariance,
        extra={
            "form": form,
            "iterations": int(sol.nfev),
            "termination": sol.message,
            "n_free_parameters": int(nb),
        },
    )


def _restrict(basis: np.ndarray, fixed_rows: np.ndarray) -> np.ndarray:
    """Columns of span(basis) that leave ``fixed_rows`` of the parameter vector unchanged."""
    sub = basis[fixed_rows]
    _, s, Vt = np.linalg.svd(sub, full_matrices=True)
    rank = int(np.sum(s > 1e-10 * max(s.max() if s.size else 0.0, 1e-300)))
    return basis @ Vt[rank:].T
