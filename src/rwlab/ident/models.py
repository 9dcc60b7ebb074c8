"""The polynomial model ``A(q) y(t) = [B(q)/F(q)] u(t−nk) + [C(q)/D(q)] e(t)``.

``PolyModel`` is MATLAB's ``idpoly``: ARX, ARMAX, OE and BJ are special cases.
Polynomials are in q⁻¹ with MATLAB's layout: ``A = [1, a1, ..., a_na]`` and
``B`` carrying ``nk`` leading zeros (``B = [0, b1, b2]`` for nk = 1).

Several inputs (MISO): ``B`` and ``F`` are 2-D arrays with one row per input
(rows padded with trailing zeros), so ``y = Σⱼ [Bⱼ/(A Fⱼ)] uⱼ + [C/(A D)] e``.
No input (a time series, MATLAB ``idpoly(A, [], C)``): ``B=None``; then
``A y = (C/D) e``.

The sample time ``Ts`` (seconds) is required. Continuous-time conversion
(:meth:`PolyModel.d2c`) is written here because python-control has no d2c.
"""

from __future__ import annotations

import control
import numpy as np
from scipy import signal as sps

from rwlab.data import IOData, check_Ts
from rwlab.errors import DataError, FileFormatError, ModelError
from rwlab.ident.base import IdentifiedModel
from rwlab.ident.conversions import c2d_coefficients, d2c_tf
from rwlab.ident.polynomials import check_initial, filt, fit_initial, is_stable, roots_z, to_z

__all__ = ["PolyModel", "c2d"]

_FORMAT = "rwlab.PolyModel/1"


def _monic(p, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.array(1.0 if p is None else p, dtype=float))
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} must be a finite 1-D coefficient array")
    if arr[0] != 1.0:
        raise ModelError(f"{name} must be monic ({name}[0] = 1), got {name}[0] = {arr[0]}")
    return arr


def _denominators(F, nu: int) -> np.ndarray:
    """F as an (nu, L) array of monic rows (one per input; a 1-D F is shared by all inputs)."""
    arr = np.array(1.0 if F is None else F, dtype=float)
    rows = np.atleast_2d(arr)
    if nu == 0 and arr.size > 1:
        raise ModelError("a model without input (time series) has no F")
    if arr.ndim <= 1:
        rows = np.repeat(_monic(arr, "F")[None, :], nu, axis=0)
    if rows.ndim != 2 or rows.shape[0] != nu or rows.shape[1] == 0:
        raise ModelError(f"F must be 1-D, or 2-D with one row per input ({nu}); got {arr.shape}")
    for row in rows:
        _monic(row, "F")
    return rows


def _leading_zeros(row: np.ndarray) -> int:
    nz = np.flatnonzero(row)
    return int(nz[0]) if nz.size else len(row)


class PolyModel(IdentifiedModel):
    """Discrete-time polynomial input/output model (MATLAB ``idpoly``).

    Parameters
    ----------
    A, C, D : array_like, optional
        Monic polynomials in q⁻¹ (default 1).
    B : array_like or None
        Shape (nb_total,) for one input, (nu, L) for several; ``nk`` leading zeros.
        ``None`` (or shape (0, L)): no input, a time-series model ``A y = (C/D) e``.
    F : array_like, optional
        Monic, shape (nf+1,), or (nu, L) with one row per input (default 1).
    Ts : float
        Sample time in seconds (required, > 0).
    nk : int or sequence of int, optional
        Input delay in samples per input (default: B's leading zeros).
    nb : int or sequence of int, optional
        Number of free B coefficients per input, from ``b_nk`` on (default: the
        rest of each row). Give it when rows are padded with trailing zeros,
        e.g. for several inputs with different ``nb + nk``.
    nf : int or sequence of int, optional
        Order of F per input (default: the width of F's rows minus one). Give
        it when F's rows are padded with trailing zeros.
    noise_variance : float, optional
        Variance of the innovation e(t).
    covariance : array_like, shape (d, d), optional
        Covariance of the free parameters, in :attr:`parameter_names` order.
    report : dict, optional
        Estimation report (method, loss, fit, iterations, ...).
    input_name, output_name : str, optional
        Channel labels for printouts.
    """

    FORMAT = _FORMAT

    def __init__(
        self,
        A=None,
        B=None,
        C=None,
        D=None,
        F=None,
        *,
        Ts,
        nk=None,
        nb=None,
        nf=None,
        noise_variance: float | None = None,
        covariance=None,
        report: dict | None = None,
        input_name: str | tuple[str, ...] = "u",
        output_name: str = "y",
    ) -> None:
        self.Ts = check_Ts(Ts)
        self.A = _monic(A, "A")
        self.C = _monic(C, "C")
        self.D = _monic(D, "D")
        no_input = B is None or np.size(B) == 0
        B2 = np.zeros((0, 1)) if no_input else np.atleast_2d(np.array(B, dtype=float))
        if B2.ndim != 2 or not np.all(np.isfinite(B2)):
            raise ModelError("B must be a finite 1-D array, or 2-D with one row per input")
        self._B = B2
        self._F = _denominators(F, self.nu)
        width_f = self._F.shape[1]
        nf = [width_f - 1] * self.nu if nf is None else [int(n) for n in np.atleast_1d(nf)]
        if len(nf) != self.nu or any(n < 0 or n + 1 > width_f for n in nf):
            raise ModelError(f"nf must give one order per input with nf < {width_f}, got {nf}")
        for row, n in zip(self._F, nf, strict=True):
            if np.any(row[n + 1 :] != 0):
                raise ModelError(f"F must end with zeros after its nf = {n} coefficients")
        self._nf = tuple(nf)
        if nk is None:
            nk = [_leading_zeros(r) for r in B2]
        nk = [int(k) for k in np.atleast_1d(nk)]
        if len(nk) != self.nu or any(k < 0 for k in nk):
            raise ModelError(f"nk must give one non-negative delay per input, got {nk}")
        for row, k in zip(B2, nk, strict=True):
            if np.any(row[: min(k, len(row))] != 0):
                raise ModelError(f"B must start with nk = {k} zeros, got {row}")
        self.nk = tuple(nk)
        width = B2.shape[1]
        nb = [max(width - k, 0) for k in nk] if nb is None else [int(b) for b in np.atleast_1d(nb)]
        if len(nb) != self.nu or any(b < 0 or k + b > width for b, k in zip(nb, nk, strict=True)):
            raise ModelError(f"nb must give one count per input with nk + nb ≤ {width}, got {nb}")
        for row, k, b in zip(B2, nk, nb, strict=True):
            if np.any(row[k + b :] != 0):
                raise ModelError(f"B must end with zeros after its nb = {b} free coefficients")
        self.nb = tuple(nb)
        self.noise_variance = None if noise_variance is None else float(noise_variance)
        self.covariance = None if covariance is None else np.array(covariance, dtype=float)
        if self.covariance is not None and self.covariance.shape != (self.n_params,) * 2:
            raise ModelError(
                f"covariance must be {self.n_params}×{self.n_params} for this structure, "
                f"got {self.covariance.shape}"
            )
        self.report = dict(report or {})
        self.input_name = input_name
        self.output_name = output_name
        for arr in (self.A, self.C, self.D, self._F, self._B):
            arr.setflags(write=False)

    # -- structure ---------------------------------------------------------------
    @property
    def nu(self) -> int:
        """Number of inputs (0: a time series)."""
        return self._B.shape[0]

    @property
    def B(self) -> np.ndarray:
        """B in MATLAB layout: 1-D for one input, (nu, L) for several."""
        return self._B[0] if self.nu == 1 else self._B

    @property
    def F(self) -> np.ndarray:
        """F in MATLAB layout: 1-D for one input (or none), (nu, L) for several."""
        if self.nu == 0:
            return np.ones(1)
        return self._F[0, : self._nf[0] + 1] if self.nu == 1 else self._F

    def _den(self, j: int) -> np.ndarray:
        """A·Fⱼ, the denominator of input j's transfer function."""
        return np.convolve(self.A, self._F[j, : self._nf[j] + 1])

    def _all_den(self, first: np.ndarray) -> np.ndarray:
        """``first`` times every Fⱼ: a common denominator over all inputs."""
        out = np.asarray(first, float)
        for row, n in zip(self._F, self._nf, strict=True):
            out = np.convolve(out, row[: n + 1])
        return out

    @property
    def na(self) -> int:
        return len(self.A) - 1

    @property
    def nc(self) -> int:
        return len(self.C) - 1

    @property
    def nd(self) -> int:
        return len(self.D) - 1

    @property
    def nf(self) -> int | tuple[int, ...]:
        """Order of F: an int for one input (0 for none), a tuple per input for several."""
        if self.nu <= 1:
            return self._nf[0] if self.nu else 0
        return self._nf

    @property
    def structure(self) -> str:
        """MATLAB-style name of the structure and orders, e.g. ``ARX221`` or ``BJ22221``."""
        if self.nu == 0:
            if self.nd:
                return f"POLY{self.na}{self.nc}{self.nd}"
            return f"ARMA{self.na}{self.nc}" if self.nc else f"AR{self.na}"
        nb = "".join(map(str, self.nb)) if self.nu == 1 else str(list(self.nb))
        nk = "".join(map(str, self.nk)) if self.nu == 1 else str(list(self.nk))
        nf = "".join(map(str, self._nf)) if self.nu == 1 else str(list(self._nf))
        if not any(self._nf) and self.nd == 0:
            if self.nc == 0:
                return f"ARX{self.na}{nb}{nk}"
            return f"ARMAX{self.na}{nb}{self.nc}{nk}"
        if self.na == 0 and self.nc == 0 and self.nd == 0:
            return f"OE{nb}{nf}{nk}"
        if self.na == 0:
            return f"BJ{nb}{self.nc}{self.nd}{nf}{nk}"
        return f"POLY{self.na}{nb}{self.nc}{self.nd}{nf}{nk}"

    @property
    def parameters(self) -> np.ndarray:
        """Free parameters: a…, b… (per input, from b_nk), c…, d…, f… (per input; MATLAB order)."""
        bs = [row[k : k + n] for row, k, n in zip(self._B, self.nk, self.nb, strict=True)]
        fs = [row[1 : n + 1] for row, n in zip(self._F, self._nf, strict=True)]
        return np.concatenate([self.A[1:], *bs, self.C[1:], self.D[1:], *fs])

    @property
    def parameter_names(self) -> list[str]:
        names = [f"a{i}" for i in range(1, self.na + 1)]
        for j, (k, n) in enumerate(zip(self.nk, self.nb, strict=True)):
            tag = "" if self.nu == 1 else f"[{j + 1}]"
            names += [f"b{tag}{i}" for i in range(k, k + n)]
        names += [f"c{i}" for i in range(1, self.nc + 1)]
        names += [f"d{i}" for i in range(1, self.nd + 1)]
        for j, n in enumerate(self._nf):
            tag = "" if self.nu == 1 else f"[{j + 1}]"
            names += [f"f{tag}{i}" for i in range(1, n + 1)]
        return names

    def with_parameters(self, theta) -> PolyModel:
        """The same structure with :attr:`parameters` replaced by ``theta`` (no covariance)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise ModelError(f"expected {self.n_params} parameters, got {theta.shape}")
        parts = iter(np.split(theta, np.cumsum([self.na, *self.nb, self.nc, self.nd])))
        A = np.concatenate([[1.0], next(parts)])
        B = self._B.copy()
        for row, k, n in zip(B, self.nk, self.nb, strict=True):
            row[k : k + n] = next(parts)
        C = np.concatenate([[1.0], next(parts)])
        D = np.concatenate([[1.0], next(parts)])
        F = self._F.copy()
        fs = np.split(next(parts), np.cumsum(self._nf)[:-1])
        for row, n, f in zip(F, self._nf, fs, strict=False):
            row[1 : n + 1] = f
        return PolyModel(
            A, B if self.nu else None, C, D, F if self.nu else None, Ts=self.Ts, nk=self.nk,
            nb=self.nb, nf=self._nf, noise_variance=self.noise_variance,
            input_name=self.input_name, output_name=self.output_name,
        )  # fmt: skip

    @property
    def parameter_std(self) -> np.ndarray | None:
        """One standard deviation per free parameter, or None without a covariance."""
        if self.covariance is None:
            return None
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    # -- time responses ------------------------------------------------------------
    def simulate(self, u, initial: str = "zero") -> np.ndarray:
        """Noise-free output ``y = Σⱼ Bⱼ/(A Fⱼ) uⱼ`` (zero for a time series, as MATLAB's ``sim``).

        Parameters
        ----------
        u : array_like, shape (N,) or (N, nu), or IOData
            Input samples (an IOData, with its measured output, for ``'estimate'``).
        initial : {'zero', 'steady', 'estimate'}
            Pre-sample values: zero; the input held at ``u[0]`` forever (start in
            equilibrium); or the initial state that best fits the measured output
            in the least-squares sense (MATLAB ``InitialCondition = 'e'``).

        Returns
        -------
        numpy.ndarray, shape (N,)
        """
        initial = check_initial(initial)
        u2 = self._inputs(u)
        yhat = np.zeros(u2.shape[0])
        for j, b in enumerate(self._B):
            yhat = yhat + filt(b, self._den(j), u2[:, j], initial == "steady")
        if initial != "estimate" or self.nu == 0:
            return yhat
        if not isinstance(u, IOData) or u.ny != 1:
            raise DataError("initial='estimate' needs an IOData with the measured output")
        # every term shares the denominator A·F₁·…·F_nu (term j: numerator Bⱼ·Πᵢ≠ⱼ Fᵢ)
        den = self._all_den(self.A)
        n = max(len(den), self._B.shape[1] + sum(self._nf)) - 1
        return fit_initial(u.y[:, 0], yhat, den, n)

    def predict(self, data: IOData, horizon: float = 1, initial: str = "zero") -> np.ndarray:
        """k-step-ahead prediction ŷ(t | t−k) from measured inputs and outputs.

        Uses ``ŷ = H̄ₖ D B/(C F) u + (1 − H̄ₖ A D / C) y`` where ``H̄ₖ`` holds the
        first k impulse-response coefficients of the noise model ``C/(A D)``.
        ``initial``: pre-sample values zero, every signal held at its first
        sample ('steady'), or the predictor's initial state fitted to the
        measured output by least squares ('estimate', MATLAB's 'e').
        ``horizon=numpy.inf`` is pure simulation.

        Returns
        -------
        numpy.ndarray, shape (N,)
        """
        if not isinstance(data, IOData):
            raise DataError("predict needs an IOData (it uses the measured outputs)")
        if data.ny != 1:
            raise DataError("PolyModel is single-output; data must have one output")
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        initial = check_initial(initial)
        steady = initial == "steady"
        if horizon == np.inf or horizon >= data.N:
            return self.simulate(data, initial)
        k = int(horizon)
        AD = np.convolve(self.A, self.D)
        impulse = np.zeros(k)
        impulse[0] = 1.0
        hk = sps.lfilter(self.C, AD, impulse)
        y = data.y[:, 0]
        u = self._inputs(data)
        num_y = np.convolve(hk, AD)
        num_u = [np.convolve(np.convolve(hk, self.D), b) for b in self._B]
        yhat = y - filt(num_y, self.C, y, steady)
        for j, num in enumerate(num_u):
            den_u = np.convolve(self.C, self._F[j, : self._nf[j] + 1])
            yhat = yhat + filt(num, den_u, u[:, j], steady)
        if initial != "estimate":
            return yhat
        # every filter above has the common denominator C·F₁·…·F_nu
        den = self._all_den(self.C)
        extra = sum(self._nf)
        n = max(len(den), len(num_y) + extra, *[len(v) + extra for v in num_u]) - 1
        return fit_initial(y, yhat, den, n)

    def step_response(self, n: int, input_index: int = 0) -> np.ndarray:
        """Response to a unit step on one input, ``n`` samples from rest, shape (n,)."""
        u = np.zeros((n, self.nu))
        u[:, input_index] = 1.0
        return self.simulate(u)

    def impulse_response(self, n: int, input_index: int = 0) -> np.ndarray:
        """Response to a unit pulse at t = 0 on one input, shape (n,)."""
        u = np.zeros((n, self.nu))
        u[0, input_index] = 1.0
        return self.simulate(u)

    # -- frequency domain, poles, zeros ----------------------------------------------
    def frequency_response(self, omega) -> np.ndarray:
        """G(e^{jωTs}) at ``omega`` (rad/s); shape (len(omega),), or (nu, len(omega))."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        zinv = np.exp(-1j * w * self.Ts)
        out = np.array(
            [
                np.polyval(b[::-1], zinv) / np.polyval(self._den(j)[::-1], zinv)
                for j, b in enumerate(self._B)
            ]
        ).reshape(self.nu, w.size)
        return out[0] if self.nu == 1 else out

    def poles(self) -> np.ndarray:
        """Poles of the input–output part B/(A F) (of A·F₁·…·F_nu with several inputs), in z."""
        return roots_z(self._all_den(self.A))

    def zeros(self, input_index: int = 0) -> np.ndarray:
        """Finite nonzero-delay zeros of B for one input, in z."""
        row = self._B[input_index]
        return roots_z(row[self.nk[input_index] :]) if row.any() else np.zeros(0)

    def dc_gain(self) -> np.ndarray | float:
        """Static gain B(1)/(A(1) F(1)) per input."""
        den = np.array([np.sum(self._den(j)) for j in range(self.nu)])
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(np.abs(den) < 1e-14, np.inf, self._B.sum(axis=1) / den)
        return float(g[0]) if self.nu == 1 else g

    def is_stable(self) -> bool:
        """True when every pole of B/(A F) is strictly inside the unit circle."""
        return is_stable(self._all_den(self.A))

    # -- python-control ----------------------------------------------------------
    def to_tf(self) -> control.TransferFunction:
        """G(z) = B/(A F) as a discrete ``control.TransferFunction`` (dt = Ts), 1×nu."""
        nums, dens = [], []
        for j, b in enumerate(self._B):
            n, d = to_z(b, self._den(j))
            nums.append(n)
            dens.append(d)
        return control.tf([nums], [dens], self.Ts)

    def noise_tf(self) -> control.TransferFunction:
        """H(z) = C/(A D) as a discrete ``control.TransferFunction`` (dt = Ts)."""
        n, d = to_z(self.C, np.convolve(self.A, self.D))
        return control.tf(n, d, self.Ts)

    def to_ss(self) -> control.StateSpace:
        """G(z) as a discrete ``control.StateSpace`` (dt = Ts)."""
        return control.tf2ss(self.to_tf())

    @property
    def input_delay_s(self) -> float:
        """Pure input delay beyond the one sample a ZOH already implies, in seconds."""
        return max(min(self.nk) - 1, 0) * self.Ts

    def d2c(
        self, method: str = "zoh", *, pade_order: int | None = None
    ) -> control.TransferFunction:
        """Continuous-time equivalent G(s) of the input–output part.

        Parameters
        ----------
        method : {'zoh', 'tustin'}
            Zero-order hold (exact for piecewise-constant inputs; inverse of
            ``c2d(..., 'zoh')``) or the bilinear transform s = (2/Ts)(z−1)/(z+1).
        pade_order : int, optional
            ZOH only: a delay of nk−1 > 0 samples cannot be held by a rational
            transfer function; give a Padé order to approximate it. Without
            it such a model raises ``ModelError`` (``input_delay_s`` says the delay).

        Returns
        -------
        control.TransferFunction
            Continuous time (dt = 0), 1×nu.
        """
        if self.nu != 1:
            raise ModelError("d2c supports single-input models; convert each input separately")
        den = np.convolve(self.A, self.F)
        return d2c_tf(self.B, den, self.Ts, nk=self.nk[0], method=method, pade_order=pade_order)

    # -- files ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain-JSON form (lossless for float64 values)."""
        return {
            "format": _FORMAT,
            "structure": self.structure,
            "Ts": self.Ts,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "F": self.F.tolist(),
            "nk": list(self.nk),
            "nb": list(self.nb),
            "nf": list(self._nf),
            "noise_variance": self.noise_variance,
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "parameter_names": self.parameter_names,
            "input_name": self.input_name,
            "output_name": self.output_name,
            "report": self.report,
        }

    @classmethod
    def from_dict(cls, d: dict) -> PolyModel:
        """Inverse of :meth:`to_dict`; raises ``FileFormatError`` when fields are missing."""
        if not isinstance(d, dict) or d.get("format") != _FORMAT:
            raise FileFormatError(f"not an rwlab PolyModel (expected format {_FORMAT!r})")
        try:
            return cls(
                d["A"],
                d["B"],
                d["C"],
                d["D"],
                d["F"],
                Ts=d["Ts"],
                nk=d["nk"],
                nb=d.get("nb"),
                nf=d.get("nf"),
                noise_variance=d.get("noise_variance"),
                covariance=d.get("covariance"),
                report=d.get("report"),
                input_name=d.get("input_name", "u"),
                output_name=d.get("output_name", "y"),
            )
        except KeyError as exc:
            raise FileFormatError(f"PolyModel JSON lacks field {exc}") from None

    # -- printing ------------------------------------------------------------------
    def __repr__(self) -> str:
        return f"<PolyModel {self.structure} Ts={self.Ts:g} s>"

    def __str__(self) -> str:
        std = self.parameter_std
        names = self.parameter_names
        sd = dict(zip(names, std, strict=True)) if std is not None else {}

        def poly(letter: str, coeffs: np.ndarray, first: int, tag: str = "") -> str:
            terms = []
            for i, c in enumerate(coeffs):
                if i < first or (i == 0 and letter != "B"):
                    if i == 0 and letter != "B":
                        terms.append("1")
                    continue
                pm = sd.get(f"{letter.lower()}{tag}{i}")
                pm_s = f" (+/- {pm:.4g})" if pm is not None else ""
                power = "" if i == 0 else f" z^-{i}"
                sign = "-" if c < 0 else "+"
                terms.append(f"{sign} {abs(c):.4g}{pm_s}{power}")
            s = " ".join(terms)
            return s[2:] if s.startswith("+ ") else ("-" + s[2:] if s.startswith("- ") else s)

        kinds = {"A": self.na, "C": self.nc, "D": self.nd}
        lines = [f"Discrete-time {self.structure} model (Ts = {self.Ts:g} s)"]
        if self.na:
            lines.append(f"  A(z) = {poly('A', self.A, 0)}")
        for j, (row, k, b) in enumerate(zip(self._B, self.nk, self.nb, strict=True)):
            tag = "" if self.nu == 1 else f"[{j + 1}]"
            label = "B(z)" if self.nu == 1 else f"B{j + 1}(z)"
            lines.append(f"  {label} = {poly('B', row[: k + b], k, tag)}")
        for letter in "CD":
            if kinds[letter]:
                lines.append(f"  {letter}(z) = {poly(letter, getattr(self, letter), 0)}")
        for j, n in enumerate(self._nf):
            if n:
                tag = "" if self.nu == 1 else f"[{j + 1}]"
                label = "F(z)" if self.nu == 1 else f"F{j + 1}(z)"
                lines.append(f"  {label} = {poly('F', self._F[j, : n + 1], 0, tag)}")
        if self.noise_variance is not None:
            lines.append(f"  noise variance: {self.noise_variance:.4g}")
        rep = self.report
        if "fit_percent" in rep:
            lines.append(
                f"  fit to estimation data: {rep['fit_percent']:.2f} % ({rep.get('focus', '')}), "
                f"MSE {rep.get('mse', float('nan')):.4g}, FPE {rep.get('fpe', float('nan')):.4g}"
            )
        return "\n".join(lines)


def c2d(sys: control.TransferFunction, Ts: float, method: str = "zoh") -> PolyModel:
    """Discretise a continuous SISO transfer function into a ``PolyModel`` (B/A form).

    Parameters
    ----------
    sys, Ts, method
        As for :func:`rwlab.ident.conversions.c2d_coefficients`: the continuous system
        (dt = 0), the sample time (s), and ``'zoh'`` or ``'tustin'``.

    Returns
    -------
    PolyModel
        ``B/A`` with ``A`` monic, at sample time ``Ts``.
    """
    A, B = c2d_coefficients(sys, Ts, method)
    return PolyModel(A, B, Ts=Ts)
