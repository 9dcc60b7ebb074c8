"""State-space models in innovations form: ``SSModel`` (MATLAB ``idss``), ``n4sid`` and ``ssest``.

The model is MATLAB's discrete-time innovations form::

    x(t+1) = A x(t) + B u(t) + K e(t)
      y(t) = C x(t) + D u(t) + e(t),        E e eᵀ = NoiseVariance

with several inputs and outputs. ``D`` is zero (no feedthrough) unless asked
for, as in MATLAB. ``n4sid`` is a subspace method (N4SID, MOESP or CVA
weighting); ``ssest`` refines its result by minimising the one-step prediction
errors (prediction-error method), in a free parameterisation with data-driven
local coordinates or in an observability canonical form.

The subspace step and the state-space prediction-error search are written
here because no maintained Python library offers them with innovations-form
noise models (python-control has ERA only; SIPPY is unmaintained and slow).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import control
import numpy as np
from numba import njit
from scipy import linalg, optimize
from scipy import signal as sps
from threadpoolctl import threadpool_limits

from rwlab.data import IOData, as_experiments, check_Ts
from rwlab.errors import DataError, EstimationError, FileFormatError, ModelError, RwlabWarning

__all__ = ["SSModel", "n4sid", "ssest"]

_FORMAT = "rwlab.SSModel/1"
_WEIGHTINGS = ("auto", "CVA", "MOESP", "N4SID", "SSARX")
_INITIAL = ("auto", "zero", "estimate", "steady")


@njit(cache=True)
def _run(A, B, C, D, w, x0):  # pragma: no cover - compiled
    """out(t) = C x(t) + D w(t), x(t+1) = A x(t) + B w(t), x(0) = x0; w is (N, m)."""
    N = w.shape[0]
    n = A.shape[0]
    p = C.shape[0]
    m = w.shape[1]
    out = np.empty((N, p))
    x = x0.copy()
    xn = np.empty(n)
    for t in range(N):
        for i in range(p):
            s = 0.0
            for j in range(n):
                s += C[i, j] * x[j]
            for j in range(m):
                s += D[i, j] * w[t, j]
            out[t, i] = s
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += A[i, j] * x[j]
            for j in range(m):
                s += B[i, j] * w[t, j]
            xn[i] = s
        for i in range(n):
            x[i] = xn[i]
    return out


def _matrix(value, shape: tuple[int, int], name: str) -> np.ndarray:
    arr = np.array(np.zeros(shape) if value is None else value, dtype=float)
    if arr.size == 0 and 0 in shape:
        arr = np.zeros(shape)
    arr = arr.reshape(shape) if arr.ndim < 2 and arr.size == shape[0] * shape[1] else arr
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} must be a finite {shape[0]}×{shape[1]} matrix, got {arr.shape}")
    arr.setflags(write=False)
    return arr


def _names(names, n: int, prefix: str) -> tuple[str, ...]:
    if names is None:
        return tuple(f"{prefix}{i + 1}" for i in range(n))
    names = (names,) if isinstance(names, str) else tuple(str(s) for s in names)
    if len(names) != n:
        raise ModelError(f"{len(names)} names given for {n} {prefix}-channels")
    return names


class SSModel:
    """Discrete-time state-space model in innovations form (MATLAB ``idss``).

    Parameters
    ----------
    A : array_like, shape (nx, nx)
    B : array_like, shape (nx, nu)
        ``nu = 0`` (or ``None``): a time-series model.
    C : array_like, shape (ny, nx)
    D : array_like, shape (ny, nu), optional
        Feedthrough (default zero).
    K : array_like, shape (nx, ny), optional
        Innovations (Kalman) gain (default zero: an output-error model).
    Ts : float
        Sample time in seconds (required).
    noise_variance : array_like, shape (ny, ny), optional
        Covariance of the innovations e(t) (MATLAB ``NoiseVariance``).
    covariance : array_like, shape (d, d), optional
        Covariance of :attr:`parameters` (vec A, B, C, D when ``feedthrough``,
        K; row by row). Rank deficient for a free parameterisation: only
        quantities invariant under a change of state basis (poles, responses)
        have meaningful variances.
    feedthrough : bool
        Whether D is a free parameter (MATLAB ``Feedthrough``; default False).
    x0 : array_like, shape (nx,), optional
        Initial state estimated with the model (MATLAB's second output).
    report : dict, optional
        Estimation report (method, loss, fit %, singular values, ...).
    input_names, output_names : sequence of str, optional
    """

    def __init__(
        self,
        A,
        B,
        C,
        D=None,
        K=None,
        *,
        Ts,
        noise_variance=None,
        covariance=None,
        feedthrough: bool = False,
        x0=None,
        report: dict | None = None,
        input_names=None,
        output_names=None,
    ) -> None:
        self.Ts = check_Ts(Ts)
        A = np.atleast_2d(np.array(A, dtype=float))
        nx = A.shape[0]
        self.A = _matrix(A, (nx, nx), "A")
        C = np.atleast_2d(np.array(C, dtype=float))
        ny = C.shape[0] if C.size else 0
        if ny == 0:
            raise ModelError("C must have at least one row (one output)")
        self.C = _matrix(C, (ny, nx), "C")
        nu = (
            0 if B is None or np.size(B) == 0 else np.array(B, dtype=float).reshape(nx, -1).shape[1]
        )
        self.B = _matrix(None if nu == 0 else np.reshape(B, (nx, nu)), (nx, nu), "B")
        self.D = _matrix(D, (ny, nu), "D")
        self.K = _matrix(K, (nx, ny), "K")
        self.feedthrough = bool(feedthrough)
        if not self.feedthrough and np.any(self.D != 0):
            self.feedthrough = True
        self.noise_variance = None
        if noise_variance is not None:
            self.noise_variance = _matrix(np.atleast_2d(noise_variance), (ny, ny), "noise_variance")
        self.covariance = None if covariance is None else np.array(covariance, dtype=float)
        if self.covariance is not None and self.covariance.shape != (self.n_params,) * 2:
            raise ModelError(
                f"covariance must be {self.n_params}×{self.n_params}, got {self.covariance.shape}"
            )
        self.x0 = None if x0 is None else np.array(x0, dtype=float).reshape(nx)
        self.report = dict(report or {})
        self.input_names = _names(input_names, nu, "u")
        self.output_names = _names(output_names, ny, "y")

    # -- structure -------------------------------------------------------------------
    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        return self.B.shape[1]

    @property
    def ny(self) -> int:
        return self.C.shape[0]

    @property
    def parameters(self) -> np.ndarray:
        """vec(A), vec(B), vec(C), vec(D) if ``feedthrough``, vec(K) (row-major)."""
        parts = [self.A, self.B, self.C, *([self.D] if self.feedthrough else []), self.K]
        return np.concatenate([p.ravel() for p in parts])

    @property
    def n_params(self) -> int:
        return self.parameters.size

    def with_parameters(self, theta) -> SSModel:
        """The same structure with :attr:`parameters` replaced by ``theta`` (no covariance)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise ModelError(f"expected {self.n_params} parameters, got {theta.shape}")
        shapes = [self.A.shape, self.B.shape, self.C.shape]
        shapes += [self.D.shape] if self.feedthrough else []
        shapes += [self.K.shape]
        mats, k = [], 0
        for shape in shapes:
            size = shape[0] * shape[1]
            mats.append(theta[k : k + size].reshape(shape))
            k += size
        D = mats[3] if self.feedthrough else self.D
        return SSModel(
            mats[0],
            mats[1],
            mats[2],
            D,
            mats[-1],
            Ts=self.Ts,
            noise_variance=self.noise_variance,
            feedthrough=self.feedthrough,
            input_names=self.input_names,
            output_names=self.output_names,
        )

    # -- responses ---------------------------------------------------------------------
    def _inputs(self, u) -> np.ndarray:
        if isinstance(u, IOData):
            u = u.u
        arr = np.asarray(u, dtype=float)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != self.nu:
            raise DataError(f"u must have shape (N, {self.nu}); got {np.shape(u)}")
        if not np.all(np.isfinite(arr)):
            raise DataError("u contains NaN or Inf")
        return arr

    def simulate(self, u, x0=None) -> np.ndarray:
        """Noise-free output ``y = C x + D u`` (MATLAB ``sim``), shape (N, ny).

        Parameters
        ----------
        u : array_like, shape (N, nu), or IOData
        x0 : array_like, shape (nx,), optional
            Initial state (default zero).
        """
        u2 = self._inputs(u)
        x0 = np.zeros(self.nx) if x0 is None else np.asarray(x0, float).reshape(self.nx)
        return _run(
            np.ascontiguousarray(self.A),
            np.ascontiguousarray(self.B),
            np.ascontiguousarray(self.C),
            np.ascontiguousarray(self.D),
            np.ascontiguousarray(u2),
            x0,
        )

    def _predictor(self):
        """Matrices of the one-step predictor driven by w = [u, y]."""
        Ab = self.A - self.K @ self.C
        Bb = np.hstack([self.B - self.K @ self.D, self.K])
        Db = np.hstack([self.D, np.zeros((self.ny, self.ny))])
        return Ab, Bb, Db

    def predict(self, data: IOData, horizon: float = 1, initial="zero") -> np.ndarray:
        """k-step-ahead prediction ŷ(t | t−k) from measured inputs and outputs, shape (N, ny).

        Parameters
        ----------
        data : IOData
            Measured inputs and outputs.
        horizon : int or numpy.inf
            Samples ahead (MATLAB ``predict(sys, data, K)``); ``inf`` simulates
            (MATLAB ``sim``). The one-step predictor runs the Kalman filter
            ``A − K C``; k steps propagate its state k − 1 samples with the
            inputs only.
        initial : {'zero', 'steady', 'estimate'} or array_like, shape (nx,)
            'zero'; 'steady' (the predictor, or the simulation, at rest with
            every signal held at its first sample); 'estimate' (the initial
            state fitted to the output by least squares, MATLAB's 'e'); or an
            initial state.
        """
        if isinstance(horizon, str) or np.ndim(horizon):  # the old predict(data, initial)
            horizon, initial = 1, horizon
        if not isinstance(data, IOData):
            raise DataError("predict needs an IOData (it uses the measured outputs)")
        if (data.nu, data.ny) != (self.nu, self.ny):
            raise DataError(
                f"the model has {self.nu} inputs and {self.ny} outputs; "
                f"the data have {data.nu} and {data.ny}"
            )
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        if horizon == np.inf or horizon >= data.N:
            return _simulate_from(self, data, initial)
        if horizon == 1:
            return _predict(self, data.u, data.y, initial)[0]
        return _k_step(self, data, int(horizon), initial)

    def residuals(self, data: IOData, initial="zero") -> np.ndarray:
        """One-step prediction errors e(t) = y(t) − ŷ(t | t−1), shape (N, ny)."""
        return data.y - self.predict(data, 1, initial)

    def step_response(self, n: int) -> np.ndarray:
        """Unit-step responses from rest, shape (n, ny, nu): ``[t, output, input]``."""
        out = np.empty((n, self.ny, self.nu))
        for j in range(self.nu):
            u = np.zeros((n, self.nu))
            u[:, j] = 1.0
            out[:, :, j] = self.simulate(u)
        return out

    def impulse_response(self, n: int) -> np.ndarray:
        """Responses to a unit pulse at t = 0, shape (n, ny, nu): D, CB, CAB, ..."""
        out = np.empty((n, self.ny, self.nu))
        for j in range(self.nu):
            u = np.zeros((n, self.nu))
            u[0, j] = 1.0
            out[:, :, j] = self.simulate(u)
        return out

    def frequency_response(self, omega) -> np.ndarray:
        """G(e^{jωTs}) = C (zI − A)⁻¹ B + D at ``omega`` (rad/s), shape (len(omega), ny, nu)."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        z = np.exp(1j * w * self.Ts)
        eye = np.eye(self.nx)
        out = np.empty((w.size, self.ny, self.nu), dtype=complex)
        for i, zi in enumerate(z):
            out[i] = self.C @ np.linalg.solve(zi * eye - self.A, self.B) + self.D
        return out

    def poles(self) -> np.ndarray:
        """Eigenvalues of A (the poles in z)."""
        return np.linalg.eigvals(self.A) if self.nx else np.zeros(0)

    def is_stable(self) -> bool:
        return bool(np.all(np.abs(self.poles()) < 1.0))

    # -- conversions -----------------------------------------------------------------
    def to_ss(self) -> control.StateSpace:
        """G as a discrete ``control.StateSpace`` (A, B, C, D; dt = Ts)."""
        return control.ss(self.A, self.B, self.C, self.D, self.Ts)

    def noise_ss(self) -> control.StateSpace:
        """H = C (zI − A)⁻¹ K + I, the innovations-to-output system, as ``control.StateSpace``."""
        return control.ss(self.A, self.K, self.C, np.eye(self.ny), self.Ts)

    @classmethod
    def from_ss(cls, sys: control.StateSpace, K=None, noise_variance=None, **kwargs) -> SSModel:
        """Build from a discrete ``control.StateSpace`` (dt > 0) and an optional gain ``K``."""
        if not isinstance(sys, control.StateSpace) or not control.isdtime(sys, strict=True):
            raise ModelError("from_ss needs a discrete-time control.StateSpace with dt > 0")
        if sys.dt is True:
            raise ModelError("the StateSpace has an unspecified sample time (dt=True)")
        return cls(
            sys.A, sys.B, sys.C, sys.D, K, Ts=sys.dt, noise_variance=noise_variance, **kwargs
        )

    def to_poly(self):
        """The SISO model as a ``PolyModel`` ``A y = B u + C e`` (MATLAB ``idpoly(sys)``).

        A is det(I − A q⁻¹), C is det(I − (A − KC) q⁻¹) and B the numerator of
        G, so the input–output and the noise dynamics are both preserved.
        """
        from rwlab.ident.models import PolyModel

        if self.ny != 1 or self.nu > 1:
            raise ModelError(
                f"to_poly needs one output and at most one input; this model is "
                f"{self.ny}×{self.nu} (PolyModel is single-output)"
            )
        a = np.real(np.poly(self.A)) if self.nx else np.ones(1)
        c = np.real(np.poly(self.A - self.K @ self.C)) if self.nx else np.ones(1)
        var = None if self.noise_variance is None else float(self.noise_variance[0, 0])
        if self.nu == 0:
            return PolyModel(a, None, c, Ts=self.Ts, noise_variance=var)
        num, _ = sps.ss2tf(self.A, self.B, self.C, self.D)
        num = np.atleast_2d(num)[0]  # descending powers of z, degree nx = powers of q⁻¹
        num = np.where(np.abs(num) < 1e-12 * max(1.0, np.max(np.abs(num))), 0.0, num)
        if not num.any():
            num = np.zeros(2)
        return PolyModel(
            a,
            num,
            c,
            Ts=self.Ts,
            noise_variance=var,
            input_name=self.input_names[0],
            output_name=self.output_names[0],
        )

    # -- files ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain-JSON form (lossless for float64 values)."""
        return {
            "format": _FORMAT,
            "structure": f"SS{self.nx}",
            "Ts": self.Ts,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "K": self.K.tolist(),
            "feedthrough": self.feedthrough,
            "noise_variance": None if self.noise_variance is None else self.noise_variance.tolist(),
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "x0": None if self.x0 is None else self.x0.tolist(),
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "report": self.report,
        }

    @classmethod
    def from_dict(cls, d: dict) -> SSModel:
        """Inverse of :meth:`to_dict`; raises ``FileFormatError`` when fields are missing."""
        if not isinstance(d, dict) or d.get("format") != _FORMAT:
            raise FileFormatError(f"not an rwlab SSModel (expected format {_FORMAT!r})")
        try:
            nx = len(d["A"])
            B = np.array(d["B"], dtype=float).reshape(nx, -1) if nx else d["B"]
            return cls(
                d["A"],
                B,
                d["C"],
                d["D"],
                d["K"],
                Ts=d["Ts"],
                noise_variance=d.get("noise_variance"),
                covariance=d.get("covariance"),
                feedthrough=d.get("feedthrough", False),
                x0=d.get("x0"),
                report=d.get("report"),
                input_names=d.get("input_names"),
                output_names=d.get("output_names"),
            )
        except KeyError as exc:
            raise FileFormatError(f"SSModel JSON lacks field {exc}") from None
        except (TypeError, ValueError) as exc:
            raise FileFormatError(f"SSModel JSON is malformed: {exc}") from None

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write JSON atomically; refuses to replace a file unless ``overwrite``."""
        from rwlab.ident.models import save_model_json

        return save_model_json(path, self.to_dict(), overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> SSModel:
        """Read a model written by :meth:`save`."""
        from rwlab.ident.models import load_model_json

        return cls.from_dict(load_model_json(path))

    # -- printing ------------------------------------------------------------------
    def __repr__(self) -> str:
        return f"<SSModel nx={self.nx} ny={self.ny} nu={self.nu} Ts={self.Ts:g} s>"

    def __str__(self) -> str:
        def block(name: str, M: np.ndarray) -> list[str]:
            if M.size == 0:
                return []
            rows = ["    " + "  ".join(f"{v:10.4g}" for v in row) for row in M]
            return [f"  {name} =", *rows]

        lines = [
            f"Discrete-time state-space model, {self.nx} states (Ts = {self.Ts:g} s):",
            "  x(t+Ts) = A x(t) + B u(t) + K e(t)",
            "     y(t) = C x(t) + D u(t) + e(t)",
        ]
        for name in "ABCDK":
            lines += block(name, getattr(self, name))
        poles = ", ".join(f"{p:.4g}" for p in self.poles())
        lines.append(f"  poles: {poles}")
        if self.noise_variance is not None:
            nv = np.array2string(self.noise_variance, precision=4, separator=", ")
            lines.append(f"  noise variance: {' '.join(nv.split())}")
        rep = self.report
        if "fit_percent" in rep:
            fits = ", ".join(f"{f:.2f}" for f in rep["fit_percent"])
            lines.append(
                f"  {rep.get('method', '')}: 1-step prediction fit {fits} %, "
                f"loss det(Λ) {rep.get('loss', float('nan')):.4g}, MSE {rep.get('mse', 0):.4g}"
            )
        return "\n".join(lines)


# -- prediction and initial state --------------------------------------------------------
def _predict(model: SSModel, u, y, initial) -> tuple[np.ndarray, np.ndarray]:
    """One-step prediction and the initial state used."""
    Ab, Bb, Db = model._predictor()
    w = np.ascontiguousarray(np.hstack([u, y]))
    C = np.ascontiguousarray(model.C)
    Ab, Bb, Db = (np.ascontiguousarray(m) for m in (Ab, Bb, Db))
    if isinstance(initial, str):
        if initial not in ("zero", "steady", "estimate"):
            raise DataError(f"initial must be 'zero', 'steady' or 'estimate', got {initial!r}")
        x0 = np.zeros(model.nx)
        if initial == "steady" and model.nx:
            try:
                x0 = np.linalg.solve(np.eye(model.nx) - Ab, Bb @ w[0])
            except np.linalg.LinAlgError:
                raise ModelError("the predictor has a pole at z = 1: no steady state") from None
    else:
        x0 = np.asarray(initial, float).reshape(model.nx)
    yhat = _run(Ab, Bb, C, Db, w, x0)
    if isinstance(initial, str) and initial == "estimate" and model.nx:
        free = _free_responses(Ab, C, y.shape[0])
        e = (y - yhat).ravel()
        dx, *_ = np.linalg.lstsq(free, e, rcond=None)
        yhat = yhat + (free @ dx).reshape(yhat.shape)
        x0 = dx
    return yhat, x0


def _simulate_from(model: SSModel, data: IOData, initial) -> np.ndarray:
    """Simulation ``y = C x + D u`` from the initial state ``initial`` asks for."""
    u = data.u
    if isinstance(initial, str):
        if initial not in ("zero", "steady", "estimate"):
            raise DataError(f"initial must be 'zero', 'steady' or 'estimate', got {initial!r}")
        x0 = np.zeros(model.nx)
        if initial == "steady" and model.nx and model.nu:
            try:
                x0 = np.linalg.solve(np.eye(model.nx) - model.A, model.B @ u[0])
            except np.linalg.LinAlgError:
                raise ModelError("the model has a pole at z = 1: no steady state") from None
    else:
        x0 = np.asarray(initial, float).reshape(model.nx)
    yhat = model.simulate(u, x0) if model.nu else np.zeros((data.N, model.ny))
    if isinstance(initial, str) and initial == "estimate" and model.nx:
        free = _free_responses(np.ascontiguousarray(model.A), np.ascontiguousarray(model.C), data.N)
        dx, *_ = np.linalg.lstsq(free, (data.y - yhat).ravel(), rcond=None)
        yhat = yhat + (free @ dx).reshape(yhat.shape)
    return yhat


def _k_step(model: SSModel, data: IOData, k: int, initial) -> np.ndarray:
    """ŷ(t | t−k): the one-step predicted state x̂(t−k+1 | t−k) propagated k − 1 samples
    through ``x ← A x + B u``; the first samples, with no data k back, from the initial state."""
    # x̂(t | t−1) for every t: the predictor's state (its "output" with C = I)
    Ab, Bb, _ = model._predictor()
    w = np.ascontiguousarray(np.hstack([data.u, data.y]))
    x0 = _predict(model, data.u, data.y, initial)[1]
    states = _run(
        np.ascontiguousarray(Ab),
        np.ascontiguousarray(Bb),
        np.eye(model.nx),
        np.zeros((model.nx, w.shape[1])),
        w,
        np.ascontiguousarray(x0, dtype=float),
    )
    u = data.u
    for _ in range(k - 1):
        nxt = np.empty_like(states)
        nxt[0] = states[0]
        nxt[1:] = states[:-1] @ model.A.T + u[:-1] @ model.B.T
        states = nxt
    return states @ model.C.T + u @ model.D.T


def _free_responses(Ab: np.ndarray, C: np.ndarray, N: int) -> np.ndarray:
    """Columns: the predictor's output (flattened N×ny) from each unit initial state."""
    nx = Ab.shape[0]
    cols = np.empty((N * C.shape[0], nx))
    zero_w = np.zeros((N, 1))
    zero_b = np.zeros((nx, 1))
    zero_d = np.zeros((C.shape[0], 1))
    for j in range(nx):
        e = np.zeros(nx)
        e[j] = 1.0
        cols[:, j] = _run(Ab, zero_b, C, zero_d, zero_w, e).ravel()
    return cols


def _fit_report(model: SSModel, experiments: list[IOData], initial: str, method: str) -> dict:
    """Loss det(Λ), MSE, FPE-like counts and per-output 1-step prediction fit %."""
    errors, ys, x0s = [], [], []
    for d in experiments:
        yhat, x0 = _predict(model, d.u, d.y, initial)
        errors.append(d.y - yhat)
        ys.append(d.y)
        x0s.append(x0)
    E = np.vstack(errors)
    Y = np.vstack(ys)
    Lam = E.T @ E / E.shape[0]
    den = np.linalg.norm(Y - Y.mean(axis=0), axis=0)
    fit = 100 * (1 - np.linalg.norm(E, axis=0) / np.where(den > 0, den, np.nan))
    return {
        "method": method,
        "loss": float(np.linalg.det(Lam)),
        "mse": float(np.mean(E**2)),
        "fit_percent": [float(f) for f in fit],
        "n_samples": int(E.shape[0]),
        "initial_state": initial,
        "_Lambda": Lam,
        "_x0": x0s[0],
    }


# -- n4sid ------------------------------------------------------------------------------
def _horizons(horizon, nx: int, nu: int) -> tuple[int, int, int]:
    if horizon is None or horizon == "auto":
        r = max(nx + 1, 10)
        return r, r, (r if nu else 0)
    try:
        r, sy, su = (int(h) for h in horizon)
    except (TypeError, ValueError):
        raise DataError(f"horizon must be 'auto' or (r, sy, su), got {horizon!r}") from None
    if r <= nx or sy < 1 or su < 0:
        raise DataError(f"horizon (r, sy, su) = {horizon} needs r > nx = {nx}, sy ≥ 1, su ≥ 0")
    return r, sy, (su if nu else 0)


def _gram(experiments: list[IOData], r: int, sy: int, su: int) -> tuple[np.ndarray, int]:
    """Σ z zᵀ over windows z = [u(t−su … t+r−1); y(t−sy … t+r−1)] of every experiment.

    Ordering inside z: input channel-major then lag, then output channel-major
    then lag. Each entry is a sum of x_a(t) x_b(t+δ) over a run of t, so it is
    read off the prefix sums of that product: O(N·L) work per channel pair
    instead of the O(N·L²) of forming the windows and multiplying them.
    """
    nu, ny = experiments[0].nu, experiments[0].ny
    s = max(sy, su)
    lengths = [su + r] * nu + [sy + r] * ny
    offsets = [s - su] * nu + [s - sy] * ny
    starts = np.concatenate([[0], np.cumsum(lengths)])
    G = np.zeros((starts[-1], starts[-1]))
    count = 0
    for d in experiments:
        n_cols = d.N - s - r + 1
        if n_cols < 1:
            continue
        count += n_cols
        x = np.hstack([d.u, d.y])
        Gd = np.zeros_like(G)
        for a in range(nu + ny):
            for b in range(a, nu + ny):
                rel = offsets[b] - offsets[a]
                for delta in range(rel - lengths[a] + 1, rel + lengths[b]):
                    i = np.arange(lengths[a])
                    j = delta - rel + i
                    ok = (j >= 0) & (j < lengths[b])
                    i, j = i[ok], j[ok]
                    lo, hi = max(0, -delta), min(d.N, d.N - delta)
                    prefix = np.concatenate(
                        [[0.0], np.cumsum(x[lo:hi, a] * x[lo + delta : hi + delta, b])]
                    )
                    t0 = offsets[a] + i - lo
                    vals = prefix[t0 + n_cols] - prefix[t0]
                    Gd[starts[a] + i, starts[b] + j] = vals
                    Gd[starts[b] + j, starts[a] + i] = vals
        G += Gd
    return G, count


class _Index:
    """Positions of u(t+j) and y(t+j) in the window vector z."""

    def __init__(self, nu, ny, r, sy, su):
        self.nu, self.ny, self.r, self.sy, self.su = nu, ny, r, sy, su
        self.Lu, self.Ly = su + r, sy + r

    def u(self, lags) -> list[int]:
        return [c * self.Lu + self.su + j for j in lags for c in range(self.nu)]

    def y(self, lags) -> list[int]:
        off = self.nu * self.Lu
        return [off + c * self.Ly + self.sy + j for j in lags for c in range(self.ny)]

    def past(self, shift: int = 0) -> list[int]:
        """p(t+shift) = [y(t+shift−1 … t+shift−sy), u(t+shift−1 … t+shift−su)]."""
        ys = self.y([shift - j for j in range(1, self.sy + 1)])
        us = self.u([shift - j for j in range(1, self.su + 1)])
        return ys + us


def _solve_psd(M: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """M⁻¹ rhs for a symmetric positive semi-definite M, scaled and regularised."""
    scale = np.sqrt(np.clip(np.diag(M), 1e-300, None))
    Ms = M / np.outer(scale, scale)
    Ms = Ms + 1e-12 * np.eye(len(M))
    sol = linalg.solve(Ms, rhs / scale[:, None], assume_a="pos")
    return sol / scale[:, None]


def _sqrtm_inv(M: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh((M + M.T) / 2)
    w = np.clip(w, 1e-12 * max(w.max(), 1e-300), None)
    return (V / np.sqrt(w)) @ V.T


def n4sid(
    data: IOData | Sequence[IOData],
    nx: int | str | Sequence[int] = "best",
    *,
    weighting: str = "auto",
    horizon=None,
    feedthrough: bool = False,
    disturbance: str = "estimate",
    initial: str = "estimate",
    enforce_stability: bool = False,
) -> SSModel:
    """Estimate a state-space model by a subspace method (MATLAB ``n4sid``).

    Parameters
    ----------
    data : IOData or list of IOData
        Any number of inputs (nu ≥ 0) and outputs (ny ≥ 1); a list is several
        experiments (``rwlab.data.merge``).
    nx : int, sequence of int, or 'best'
        Model order, or candidate orders (default 'best' = 1…10) from which the
        order after the largest relative gap in the singular values is chosen.
        ``report['singular_values']`` holds the values for an order plot.
    weighting : {'auto', 'CVA', 'MOESP', 'N4SID', 'SSARX'}
        Weighting of the oblique projection before the SVD (MATLAB
        ``N4Weight``; 'auto' is CVA). CVA, MOESP and N4SID assume the future
        inputs uncorrelated with past noise, which feedback breaks: on
        closed-loop data use 'SSARX' (Jansson 2003): a high-order ARX
        predictor first removes the future inputs' and outputs' contribution
        from the future outputs, whose regression on the past is then weighted
        as CVA does.
    horizon : (r, sy, su) or 'auto'
        Future (prediction) horizon and past output / input horizons in samples
        (MATLAB ``N4Horizon``). 'auto' (default): r = sy = su = max(nx + 1, 10).
    feedthrough : bool
        Estimate D (default False: D = 0, as MATLAB).
    disturbance : {'estimate', 'none'}
        Estimate K (MATLAB ``DisturbanceModel``) or fix it to zero.
    initial : {'estimate', 'zero'}
        How the initial state is handled in the reported fit and noise variance.
    enforce_stability : bool
        A subspace estimate can be unstable (noise, short records, high
        orders). Without this option an unstable A is returned with a
        ``RwlabWarning``; with it (MATLAB ``EnforceStability``) each eigenvalue
        of A outside the unit circle is reflected inside (λ → 1/λ̄, at most
        radius ``1 − 1e-4``), B and D are re-estimated by least squares on the
        simulation error with A and C fixed, and K is recomputed from the
        Riccati equation. ``report['stability']`` says what was done.

    Returns
    -------
    SSModel
        With ``noise_variance`` from the one-step prediction errors and no
        parameter covariance (a subspace estimate has no simple one; use
        :func:`ssest` for one).

    Notes
    -----
    The states are estimated as x(t) = T p(t), a linear map of the past data
    p(t), from the SVD of the weighted oblique projection of the future outputs
    on the past along the future inputs (Van Overschee & De Moor; Larimore's CVA).
    A, B, C, D follow by least squares on [x(t+1); y(t)] = [A B; C D][x(t); u(t)]
    and K from the Riccati equation of the residual covariances. Every product is
    formed from one Gram matrix of the data windows, read off prefix sums of
    lagged products: O(N) memory and O(N·L) work per channel pair.
    """
    experiments = as_experiments(data)
    nu, ny = experiments[0].nu, experiments[0].ny
    if weighting not in _WEIGHTINGS:
        raise DataError(f"weighting must be one of {_WEIGHTINGS}, got {weighting!r}")
    if disturbance not in ("estimate", "none"):
        raise DataError(f"disturbance must be 'estimate' or 'none', got {disturbance!r}")
    if initial not in ("estimate", "zero"):
        raise DataError(f"initial must be 'estimate' or 'zero', got {initial!r}")
    candidates = _orders(nx)
    r, sy, su = _horizons(horizon, max(candidates), nu)
    if r * ny < max(candidates):
        raise DataError(f"horizon r = {r} with {ny} outputs cannot hold {max(candidates)} states")
    G, count = _gram(experiments, r, sy, su)
    p_dim = sy * ny + su * nu
    if count < 2 * (r * (nu + ny) + p_dim):
        raise DataError(
            f"{count} usable samples are too few for n4sid with horizons (r, sy, su) = "
            f"({r}, {sy}, {su}); give more data or shorter horizons"
        )
    G = G / count
    ix = _Index(nu, ny, r, sy, su)
    iu, ip, iy = ix.u(range(r)), ix.past(), ix.y(range(r))
    sub = lambda a, b: G[np.ix_(a, b)]  # noqa: E731
    # regression of the future outputs on [future inputs, past]: Yf = Lu Uf + Lp P
    reg = iu + ip
    L = _solve_psd(sub(reg, reg), sub(reg, iy)).T
    Lp = L[:, len(iu) :]
    if nu:
        Ruu = sub(iu, iu)
        proj = lambda a, b: sub(a, b) - sub(a, iu) @ _solve_psd(Ruu, sub(iu, b))  # noqa: E731
    else:
        proj = sub
    w = "CVA" if weighting == "auto" else weighting
    if w == "SSARX":
        Lp, Rpp, W1 = _ssarx(G, ix, feedthrough)
    else:
        Rpp = sub(ip, ip) if w == "N4SID" else proj(ip, ip)
        W1 = _sqrtm_inv(proj(iy, iy)) if w == "CVA" else np.eye(len(iy))
    M = W1 @ Lp @ Rpp @ Lp.T @ W1.T
    ev, U = np.linalg.eigh((M + M.T) / 2)
    order = np.argsort(ev)[::-1]
    sv = np.sqrt(np.clip(ev[order], 0, None))
    U = U[:, order]
    n = _choose_order(sv, candidates)
    if n == 0:
        raise EstimationError("order 0 chosen; n4sid needs at least one state")
    # state map x(t) = T p(t), T = S^-1/2 U1ᵀ W1 Lp
    T = (U[:, :n] / np.sqrt(np.maximum(sv[:n], 1e-300))).T @ W1 @ Lp
    Sx = np.zeros((n, G.shape[0]))
    Sx[:, ip] = T
    Sx1 = np.zeros((n, G.shape[0]))
    Sx1[:, ix.past(1)] = T
    Su = np.eye(G.shape[0])[ix.u([0])] if nu else np.zeros((0, G.shape[0]))
    Sy = np.eye(G.shape[0])[ix.y([0])]
    phi = np.vstack([Sx, Su])
    AB = _solve_psd(phi @ G @ phi.T, phi @ G @ Sx1.T).T
    phi_y = phi if feedthrough else Sx
    CD = _solve_psd(phi_y @ G @ phi_y.T, phi_y @ G @ Sy.T).T
    A, B = AB[:, :n], AB[:, n:]
    C = CD[:, :n]
    D = CD[:, n:] if feedthrough else np.zeros((ny, nu))
    Sres = np.vstack([Sx1 - AB @ phi, Sy - CD @ phi_y])
    R = Sres @ G @ Sres.T
    K_ssarx = None
    if w == "SSARX":
        # under feedback u(t) correlates with e(t): regress x(t+1) on [x, u, ê] with
        # ê = y − C x − D u, so A and B are not biased by it (Jansson 2003)
        Se = Sy - CD @ phi_y
        phi_e = np.vstack([Sx, Su, Se])
        ABK = _solve_psd(phi_e @ G @ phi_e.T, phi_e @ G @ Sx1.T).T
        A, B, K_ssarx = ABK[:, :n], ABK[:, n : n + nu], ABK[:, n + nu :]
    stability = _stability(A, enforce_stability)
    if stability["enforced"]:
        A = stability.pop("_A")
        B, D = _refit_b_d(A, C, experiments, feedthrough)
        K_ssarx = None
    if disturbance != "estimate":
        K = None
    elif K_ssarx is not None and np.all(np.abs(np.linalg.eigvals(A - K_ssarx @ C)) < 1):
        K = K_ssarx
    else:
        K = _kalman_gain(A, C, R[:n, :n], R[:n, n:], R[n:, n:])
    model = SSModel(
        A,
        B,
        C,
        D,
        K,
        Ts=experiments[0].Ts,
        feedthrough=feedthrough,
        input_names=experiments[0].input_names,
        output_names=experiments[0].output_names,
    )
    rep = _fit_report(model, experiments, initial, "n4sid")
    return _finish(
        model,
        rep,
        covariance=None,
        extra={
            "weighting": w,
            "horizon": [r, sy, su],
            "singular_values": sv.tolist(),
            "order_candidates": candidates,
            "stability": stability,
        },
    )


def _ssarx(G: np.ndarray, ix: _Index, feedthrough: bool):
    """SSARX (Jansson 2003): the future outputs less what a high-order ARX predictor
    attributes to the future inputs and outputs, z(t+k) ≈ C Āᵏ x(t) + e(t+k); their
    regression on the past Lp, the past's covariance and the CVA weight of z."""
    ny, nu, r, sy, su = ix.ny, ix.nu, ix.r, ix.sy, ix.su
    ip = ix.past()
    regs = ip + (ix.u([0]) if feedthrough else [])
    theta = _solve_psd(G[np.ix_(regs, regs)], G[np.ix_(regs, ix.y([0]))]).T  # (ny, len(regs))
    Z = np.zeros((r * ny, G.shape[0]))
    for k in range(r):
        for i in range(ny):
            row = Z[k * ny + i]
            row[ix.y([k])[i]] = 1.0
            for lag in range(1, min(k, sy) + 1):
                for c in range(ny):
                    row[ix.y([k - lag])[c]] -= theta[i, (lag - 1) * ny + c]
            for lag in range(1, min(k, su) + 1):
                for c in range(nu):
                    row[ix.u([k - lag])[c]] -= theta[i, sy * ny + (lag - 1) * nu + c]
            if feedthrough and k:
                for c in range(nu):
                    row[ix.u([k])[c]] -= theta[i, len(ip) + c]
    Rpp = G[np.ix_(ip, ip)]
    ZGp = Z @ G[:, ip]
    Lp = _solve_psd(Rpp, ZGp.T).T
    residual = Z @ G @ Z.T - Lp @ Rpp @ Lp.T
    return Lp, Rpp, _sqrtm_inv(residual)


STABLE_RADIUS = 1.0 - 1e-4


def _stability(A: np.ndarray, enforce: bool) -> dict:
    """Check A's spectral radius; warn, or reflect the unstable eigenvalues inside."""
    ev, V = np.linalg.eig(A)
    radius = float(np.max(np.abs(ev))) if ev.size else 0.0
    out: dict = {"spectral_radius": radius, "stable": radius < 1.0, "enforced": False}
    if radius < 1.0:
        return out
    if not enforce:
        warnings.warn(
            f"n4sid: the estimated A is unstable (spectral radius {radius:.4f}); pass "
            "enforce_stability=True (MATLAB EnforceStability), lower the order, or try "
            "another weighting or horizon",
            RwlabWarning,
            stacklevel=3,
        )
        return out
    outside = np.abs(ev) >= STABLE_RADIUS
    new = ev.copy()
    new[outside] = 1.0 / np.conj(ev[outside])
    new[outside] *= np.minimum(1.0, STABLE_RADIUS / np.abs(new[outside]))
    A_new = np.real(V @ np.diag(new) @ np.linalg.inv(V))
    out.update(
        enforced=True,
        reflected=int(outside.sum()),
        spectral_radius_after=float(np.max(np.abs(np.linalg.eigvals(A_new)))),
        _A=A_new,
    )
    return out


def _refit_b_d(A, C, experiments, feedthrough: bool):
    """B (and D) by least squares on the simulation error with A and C fixed (and a
    free initial state per experiment): the output is linear in B, D and x0."""
    nx, ny = A.shape[0], C.shape[0]
    nu = experiments[0].nu
    n_b, n_d = nx * nu, (ny * nu if feedthrough else 0)
    blocks, targets = [], []
    n_x0 = nx * len(experiments)
    for e_i, d in enumerate(experiments):
        cols = np.zeros((d.N * ny, n_b + n_d + n_x0))
        zero = np.zeros((ny, nu))
        for a in range(nx):
            for j in range(nu):
                Bu = np.zeros((nx, nu))
                Bu[a, j] = 1.0
                cols[:, a * nu + j] = SSModel(A, Bu, C, zero, Ts=d.Ts).simulate(d.u).ravel()
        for i in range(n_d // max(nu, 1)):
            for j in range(nu):
                col = np.zeros((d.N, ny))
                col[:, i] = d.u[:, j]
                cols[:, n_b + i * nu + j] = col.ravel()
        cols[:, n_b + n_d + e_i * nx : n_b + n_d + (e_i + 1) * nx] = _free_responses(
            np.ascontiguousarray(A), np.ascontiguousarray(C), d.N
        )
        blocks.append(cols)
        targets.append(d.y.ravel())
    theta, *_ = np.linalg.lstsq(np.vstack(blocks), np.concatenate(targets), rcond=None)
    B = theta[:n_b].reshape(nx, nu)
    D = theta[n_b : n_b + n_d].reshape(ny, nu) if feedthrough else np.zeros((ny, nu))
    return B, D


def _orders(nx) -> list[int]:
    if isinstance(nx, str):
        if nx != "best":
            raise DataError(f"nx must be an order, a list of orders or 'best', got {nx!r}")
        return list(range(1, 11))
    values = [int(v) for v in np.atleast_1d(nx)]
    if not values or min(values) < 1 or any(int(v) != v for v in np.atleast_1d(nx)):
        raise DataError(f"model orders must be integers ≥ 1, got {nx!r}")
    return sorted(set(values))


def _choose_order(sv: np.ndarray, candidates: list[int]) -> int:
    if len(candidates) == 1:
        return candidates[0]
    logs = np.log10(np.maximum(sv, 1e-300 + sv[0] * 1e-16))
    gaps = {n: logs[n - 1] - logs[n] for n in candidates if n < len(sv)}
    return max(gaps, key=gaps.get)


def _kalman_gain(A, C, Q, S, R) -> np.ndarray:
    """Stationary Kalman gain (A P Cᵀ + S)(C P Cᵀ + R)⁻¹ of x⁺ = A x + w, y = C x + v."""
    Q, R = (Q + Q.T) / 2, (R + R.T) / 2
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            P = linalg.solve_discrete_are(A.T, C.T, Q, R, s=S)
        K = linalg.solve(C @ P @ C.T + R, (A @ P @ C.T + S).T, assume_a="pos").T
    except (np.linalg.LinAlgError, ValueError):
        K = linalg.lstsq(R, S.T)[0].T  # the residuals' own regression, when the DARE fails
    return K


def _finish(model: SSModel, rep: dict, covariance, extra: dict) -> SSModel:
    Lam = rep.pop("_Lambda")
    x0 = rep.pop("_x0")
    rep.update(extra)
    return SSModel(
        model.A,
        model.B,
        model.C,
        model.D,
        model.K,
        Ts=model.Ts,
        noise_variance=Lam,
        covariance=covariance,
        feedthrough=model.feedthrough,
        x0=x0,
        report=rep,
        input_names=model.input_names,
        output_names=model.output_names,
    )


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
    if initial not in _INITIAL:
        raise DataError(f"initial must be one of {_INITIAL}, got {initial!r}")
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
    Lam0 = _fit_report(start, experiments, init, "start")["_Lambda"]
    Wt = np.linalg.cholesky(np.linalg.inv((Lam0 + Lam0.T) / 2))  # e Wt: whitened errors
    nb = basis.shape[1]
    n_x0 = start.nx * len(experiments) if init == "estimate" else 0
    x0_start = []
    for d in experiments:
        x0_start.append(_predict(start, d.u, d.y, init)[1] if n_x0 else np.zeros(start.nx))

    def residuals(beta: np.ndarray) -> np.ndarray:
        model = start.with_parameters(theta0 + basis @ beta[:nb])
        out = []
        for i, d in enumerate(experiments):
            x0 = beta[nb + i * start.nx : nb + (i + 1) * start.nx] if n_x0 else init
            with np.errstate(all="ignore"):
                yhat, _ = _predict(model, d.u, d.y, x0)
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
    rep = _fit_report(model, experiments, init, "ssest")
    return _finish(
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
