"""The state-space model in innovations form: ``SSModel`` (MATLAB ``idss``).

The model is MATLAB's discrete-time innovations form::

    x(t+1) = A x(t) + B u(t) + K e(t)
      y(t) = C x(t) + D u(t) + e(t),        E e eᵀ = NoiseVariance

with several inputs and outputs. ``D`` is zero (no feedthrough) unless asked
for, as in MATLAB. The estimators are :func:`rwlab.ident.subspace.n4sid` and
:func:`rwlab.ident.sspem.ssest`; the prediction and fit report they share are here.
"""

from __future__ import annotations

import control
import numpy as np
from numba import njit
from scipy import signal as sps

from rwlab.data import IOData, check_Ts
from rwlab.errors import DataError, FileFormatError, ModelError
from rwlab.ident.base import IdentifiedModel

__all__ = ["SSModel"]

_FORMAT = "rwlab.SSModel/1"
WEIGHTINGS = ("auto", "CVA", "MOESP", "N4SID", "SSARX")
INITIAL = ("auto", "zero", "estimate", "steady")


def _run(A, B, C, D, w, x0) -> np.ndarray:
    """out(t) = C x(t) + D w(t), x(t+1) = A x(t) + B w(t), x(0) = x0; w is (N, m).

    Numba compiles a kernel once per argument type, and a read-only array is another type
    than a writable one: the matrices go in as writable C-contiguous float arrays (copies
    where they are not), so one compiled version serves them all (eight had been compiled).
    """
    A, B, C, D, w = (np.require(m, dtype=float, requirements=("C", "W")) for m in (A, B, C, D, w))
    return _run_compiled(A, B, C, D, w, np.array(x0, dtype=float))


@njit(cache=True)
def _run_compiled(A, B, C, D, w, x0):  # pragma: no cover - compiled
    """:func:`_run` on writable C-contiguous float matrices (one compiled version)."""
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


class SSModel(IdentifiedModel):
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

    FORMAT = _FORMAT

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
        return _run(self.A, self.B, self.C, self.D, u2, x0)

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
            return predict_one_step(self, data.u, data.y, initial)[0]
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
def predict_one_step(model: SSModel, u, y, initial) -> tuple[np.ndarray, np.ndarray]:
    """One-step prediction and the initial state used."""
    Ab, Bb, Db = model._predictor()
    w = np.hstack([u, y])
    C = model.C
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
        free = free_responses(Ab, C, y.shape[0])
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
        free = free_responses(model.A, model.C, data.N)
        dx, *_ = np.linalg.lstsq(free, (data.y - yhat).ravel(), rcond=None)
        yhat = yhat + (free @ dx).reshape(yhat.shape)
    return yhat


def _k_step(model: SSModel, data: IOData, k: int, initial) -> np.ndarray:
    """ŷ(t | t−k): the one-step predicted state x̂(t−k+1 | t−k) propagated k − 1 samples
    through ``x ← A x + B u``; the first samples, with no data k back, from the initial state."""
    # x̂(t | t−1) for every t: the predictor's state (its "output" with C = I)
    Ab, Bb, _ = model._predictor()
    w = np.hstack([data.u, data.y])
    x0 = predict_one_step(model, data.u, data.y, initial)[1]
    states = _run(Ab, Bb, np.eye(model.nx), np.zeros((model.nx, w.shape[1])), w, x0)
    u = data.u
    for _ in range(k - 1):
        nxt = np.empty_like(states)
        nxt[0] = states[0]
        nxt[1:] = states[:-1] @ model.A.T + u[:-1] @ model.B.T
        states = nxt
    return states @ model.C.T + u @ model.D.T


def free_responses(Ab: np.ndarray, C: np.ndarray, N: int) -> np.ndarray:
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


def fit_report(model: SSModel, experiments: list[IOData], initial: str, method: str) -> dict:
    """Loss det(Λ), MSE, FPE-like counts and per-output 1-step prediction fit %."""
    errors, ys, x0s = [], [], []
    for d in experiments:
        yhat, x0 = predict_one_step(model, d.u, d.y, initial)
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


def finish_estimate(model: SSModel, rep: dict, covariance, extra: dict) -> SSModel:
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
