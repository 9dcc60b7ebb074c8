"""A physical grey-box model of a speed-controlled reaction wheel, and its estimation.

Unlike the servo model (``rwlab.ident.nonlinear``), whose structure is the
tracking loop alone, this model is the wheel's physics behind the loop, each
block with a physical parameter (SI units inside; rpm only at the edges):

    r = sat(u, ±ω_max)                               speed command, rad/s
    z = kp·(r − ω) + I;  if |z| < α: I ← I + ki·(r − ω)·h     PI with anti-windup
    a = clip(z, ±α)                                  rate limit, rad/s²
    i = clip((J·a + τc·sign ω + b·ω) / kt, ±i_max)   driver: current command and limit
    J·ω̇ = kt·i − f(ω)                               rotor
    f(ω) = sign ω·(τc + (τbrk − τc)·exp(−(ω/ωs)²)) + b·ω;  stuck at ω = 0 while |kt·i| ≤ τbrk

The firmware's feed-forward is calibrated on the unit (J, kt, τc, b), so in
free motion the wheel follows the rate-limited PI loop, less the Stribeck
excess it does not compensate; the current limit makes the acceleration
depend on kt, J and friction. Integrated with ``substeps`` explicit Euler
steps per sample, the command held (ZOH). Outputs: the speed and, when the
record has it, the motor current.

Identifiability (stated, not hidden): with the current telemetry, kt/J, τc/kt
and b/kt are observable (the current is what the driver commands), so with J
fixed at its datasheet value kt, τc and b are estimated; without it they are
observable only while the current limit binds. Estimated: kt, τc, τbrk, b, α,
kp, ki, and the current limit ``i_max`` when the record shows it binding (at
least :data:`CLAMP_SAMPLES` measured currents at the configured limit, less
three tolerances: a clamp is visible in the current telemetry). Otherwise
``i_max`` stays at the driver's configured value, which the unit's clamp
misses by its tolerance (current-sense shunt and reference: ±2 %); a record
that never reaches the clamp cannot tell where it is. The rate limit α is
estimated unless the clamp may keep the wheel below it ((0.95·kt·i_max − τc)/J
< α with the datasheet kt: every large step is then current-limited and α acts
mostly on the anti-windup, which cannot place it; held at the driver's
configured value, ``accel_limit_estimated`` False). ω_max is a known setting.
ωs is fixed (10 rpm typical: a Stribeck speed is not identifiable from a PRBS
that crosses zero a few times).

Standard deviations (``std``, itemised in ``std_budget``) are the root sum of
squares of these terms, because λ·(JᵀJ)⁻¹ alone was far too small (measured on
twin units whose parameters are known, none of them used in tuning it: |z| up to 25):

- statistical: the sandwich H⁻¹SH⁻¹ of the simulation error with S the
  Newey–West long-run covariance of the scores (Andrews' bandwidth): the errors
  of a simulated output are coloured (a missed ramp is wrong for many samples);
- inertia: J is fixed at its datasheet value, so the record identifies kt/J,
  τc/J, τbrk/J and b/J (``ratios``, with σ without this term); the physical
  values carry J's datasheet tolerance (±2 % uniform by default);
- current_limit: when ``i_max`` is held at its configured value, its tolerance
  carried through the fit (the estimates' sensitivity to ``i_max`` at the
  optimum, −(JᵀJ)⁻¹Jᵀ∂r/∂i_max, times σ of the tolerance): zero when the record
  never reaches the clamp, the dominant term of kt/J when the clamp binds and
  the limit is held (no current telemetry, or ``estimate_current_limit=False``);
- structure: a bias envelope, not a noise term. :data:`STRUCTURE_ERROR` is the
  RMS relative error the model's structure left on three twin records against
  the units' truth (judged on other units by ``bench/bench_greybox_z.py``). The
  estimates of α and kt/J are biased low on every nominal twin unit and this
  term is most of their σ: it covers the twin's effects the grey box leaves
  out, and carries to a real wheel only as far as the twin is right about them.

No library offers this model; the simulation is written here and compiled with
numba, the fit is ``scipy.optimize.least_squares`` on the simulation error.

Why this module is long: the model, its compiled simulation and its estimation share
one parameter vector and its bounds; the standard deviations already live apart
(``greybox_std``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from rwlab.data import IOData
from rwlab.errors import DataError, EstimationError, ModelError
from rwlab.ident.greybox_std import (
    CLAMP,
    ESTIMATED,
    STRUCTURE_ERROR,
    Uncertainty,
    sandwich_covariance,
    structure_error,
    uncertainty_budget,
)
from rwlab.ident.nonlinear import in_threads

__all__ = [
    "CLAMP_SAMPLES",
    "STRUCTURE_ERROR",
    "Uncertainty",
    "WheelGreyBox",
    "clamp_visible",
    "greybox_fit",
]

STRUCTURE = "greybox"
RPM = math.pi / 30.0  # rad/s per rpm
_POSITION = dict(zip((*ESTIMATED, CLAMP), (1, 3, 4, 6, 7, 8, 9, 2), strict=True))  # in vector
CLAMP_SAMPLES = 10  # measured-current samples at the clamp that make it visible


@njit(cache=True, nogil=True)  # nogil: the fit's starts run in threads
def _simulate(u_rpm, w0_rpm, p):  # pragma: no cover - compiled
    """Speed (rpm) sampled before each command is applied, and the motor current (A)
    at the same instants; p: see WheelGreyBox.vector."""
    J, kt, imax, tc, tbrk, ws = p[0], p[1], p[2], p[3], p[4], p[5]
    b, alpha, kp, ki, wmax, Ts, m = p[6], p[7], p[8], p[9], p[13], p[14], int(p[15])
    h = Ts / m
    n = u_rpm.size
    y = np.empty(n)
    cur = np.empty(n)
    w = w0_rpm * 0.10471975511965977
    integral = 0.0
    i = 0.0
    for k in range(n):
        y[k] = w / 0.10471975511965977
        cur[k] = i
        r = min(max(u_rpm[k] * 0.10471975511965977, -wmax), wmax)
        for _ in range(m):
            e = r - w
            z = kp * e + integral
            if abs(z) < alpha:
                integral += ki * e * h
            a = min(max(z, -alpha), alpha)
            ff = b * w + (tc if w > 0 else (-tc if w < 0 else 0.0))
            i = min(max((J * a + ff) / kt, -imax), imax)
            motor = kt * i
            if w == 0.0:
                if abs(motor) > tbrk:
                    w = (motor - (tbrk if motor > 0 else -tbrk)) / J * h
                continue
            s = 1.0 if w > 0 else -1.0
            fr = s * (tc + (tbrk - tc) * math.exp(-((w / ws) ** 2))) + b * w
            nw = w + (motor - fr) / J * h
            w = 0.0 if nw * w < 0 else nw
    return y, cur


@dataclass(frozen=True)
class WheelGreyBox:
    """The wheel's physics behind its speed loop (equations in the module docstring).

    Attributes
    ----------
    Ts : float
        Sample time, s.
    inertia : float
        J, kg·m² (fixed: the datasheet value).
    torque_constant : float
        kt, N·m/A (estimated).
    current_limit : float
        i_max, A: estimated when the record shows the clamp binding (then in
        ``std``), else the driver's configured value.
    coulomb, breakaway : float
        τc and τbrk ≥ τc, N·m (estimated).
    stribeck_speed : float
        ωs, rad/s (fixed).
    viscous : float
        b, N·m·s/rad (estimated).
    accel_limit : float
        α, rad/s² (estimated).
    kp, ki : float
        PI gains, 1/s and 1/s² (estimated).
    nominal_torque_constant, nominal_coulomb, nominal_viscous : float
        The datasheet values the fit started from, N·m/A, N·m, N·m·s/rad
        (kept for the record: compare with the estimates).
    max_speed : float
        ω_max, rad/s (known).
    substeps : int
        Euler steps per sample.
    std : dict
        Standard deviation of each estimated parameter (same units), or empty;
        a parameter the record did not inform is left out (see ``unidentified``).
    unidentified : tuple of str
        Estimated parameters the record did not inform (their values are not
        estimates): the simulation error does not change with them at the
        optimum, or ``breakaway`` is within 2 σ of ``coulomb`` (then set to it):
        with the twin's structure term always, as the dwell at rest reads as
        stiction on units without it (``greybox_std.STRUCTURE_ERROR``).
    ratios : dict
        ``"torque_constant/inertia"`` … → ``{"value", "std"}``: the combinations the
        record identifies without J (σ: statistical and structure terms).
    std_method : str
        How ``std`` was computed (module docstring).
    std_budget : dict
        Per estimated parameter, its σ's terms: ``statistical``, ``structure``,
        ``current_limit`` (the configured limit's tolerance, when it is not
        estimated) and, for those that need J, ``inertia`` (same units as the
        parameter).
    current_limit_estimated : bool
        Whether ``current_limit`` was estimated (the record showed the clamp).
    accel_limit_estimated : bool
        Whether ``accel_limit`` was estimated; False when the current clamp keeps
        the wheel below it (then it acts only on the loop's anti-windup, which
        cannot place it: held at the driver's configured value, not in ``std``).
    """

    Ts: float
    inertia: float
    torque_constant: float
    current_limit: float
    coulomb: float
    breakaway: float
    stribeck_speed: float
    viscous: float
    accel_limit: float
    kp: float
    ki: float
    nominal_torque_constant: float
    nominal_coulomb: float
    nominal_viscous: float
    max_speed: float
    substeps: int = 50
    std: dict | None = None
    unidentified: tuple[str, ...] = ()
    ratios: dict | None = None
    std_method: str = ""
    std_budget: dict | None = None
    current_limit_estimated: bool = False
    accel_limit_estimated: bool = True

    nu = 1
    ny = 1
    nk = 1
    structure = STRUCTURE

    def __post_init__(self) -> None:
        object.__setattr__(self, "unidentified", tuple(self.unidentified))
        if not set(self.unidentified) <= set(self.estimated):
            raise ModelError(f"unidentified must name estimated parameters {self.estimated}")
        skip = {"std", "unidentified", "ratios", "std_method", "std_budget"}
        skip |= {"current_limit_estimated", "accel_limit_estimated"}
        values = [v for k, v in asdict(self).items() if k not in skip]
        if not all(math.isfinite(float(v)) for v in values):
            raise ModelError(f"grey-box parameters must be finite, got {values}")
        if min(self.Ts, self.inertia, self.torque_constant, self.current_limit) <= 0:
            raise ModelError("Ts, inertia, torque_constant and current_limit must be > 0")
        if self.substeps < 1 or self.stribeck_speed <= 0 or self.nominal_torque_constant <= 0:
            raise ModelError("substeps, stribeck_speed and nominal_torque_constant must be > 0")

    @property
    def vector(self) -> np.ndarray:
        """The simulation's parameter array (SI), shape (16,)."""
        return np.array(
            [
                self.inertia,
                self.torque_constant,
                self.current_limit,
                self.coulomb,
                max(self.breakaway, self.coulomb),
                self.stribeck_speed,
                self.viscous,
                self.accel_limit,
                self.kp,
                self.ki,
                self.nominal_torque_constant,
                self.nominal_coulomb,
                self.nominal_viscous,
                self.max_speed,
                self.Ts,
                float(self.substeps),
            ]
        )

    @property
    def n_params(self) -> int:
        """Number of estimated parameters."""
        return len(self.estimated)

    @property
    def estimated(self) -> tuple[str, ...]:
        """Names of the estimated parameters."""
        out = ESTIMATED if self.accel_limit_estimated else _without(ESTIMATED, "accel_limit")
        return (*out, CLAMP) if self.current_limit_estimated else out

    def with_limits(self, *, current_limit=None, max_speed=None) -> WheelGreyBox:
        """The same wheel under other known saturations (A, rad/s); None keeps one."""
        return replace(
            self,
            current_limit=self.current_limit if current_limit is None else float(current_limit),
            max_speed=self.max_speed if max_speed is None else float(max_speed),
        )

    def simulate(self, u_rpm, w0_rpm: float = 0.0) -> np.ndarray:
        """Speeds (rpm), ``y[k]`` measured before ``u_rpm[k]`` is applied, from ``w0_rpm`` at rest.

        Parameters
        ----------
        u_rpm : array_like, shape (N,)
            Speed commands, rpm.
        w0_rpm : float
            Initial speed, rpm (the loop's integral starts at 0).

        Returns
        -------
        numpy.ndarray, shape (N,)
        """
        u = np.array(u_rpm, dtype=float).ravel()
        if u.size == 0 or not np.all(np.isfinite(u)):
            raise DataError("u must be a non-empty finite sequence")
        return _simulate(u, float(w0_rpm), self.vector)[0]

    def simulate_current(self, u_rpm, w0_rpm: float = 0.0) -> np.ndarray:
        """Motor currents (A) at the same instants as :meth:`simulate`'s speeds, shape (N,).

        Parameters
        ----------
        u_rpm : array_like, shape (N,)
            Speed commands, rpm.
        w0_rpm : float
            Initial speed, rpm.
        """
        u = np.array(u_rpm, dtype=float).ravel()
        if u.size == 0 or not np.all(np.isfinite(u)):
            raise DataError("u must be a non-empty finite sequence")
        return _simulate(u, float(w0_rpm), self.vector)[1]

    def predict(self, data: IOData, horizon: float = np.inf, initial: str = "steady"):
        """Simulated speed on ``data`` (rpm), shape (N,): an output-error model predicts by
        simulating at every horizon. ``initial``: 'steady' or 'estimate' both start at the
        first measured speed (the wheel's state is its speed; the loop's integral starts at 0);
        'zero' starts at rest."""
        if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
            raise DataError("the grey-box wheel model needs a single-input single-output IOData")
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        w0 = 0.0 if initial == "zero" else float(data.y[0, 0])
        return self.simulate(data.u[:, 0], w0)

    def to_dict(self) -> dict:
        """Plain JSON: every parameter (SI) and ``std`` of the estimated ones."""
        d = asdict(self)
        d["structure"] = STRUCTURE
        d["units"] = "SI (N·m, A, rad/s, kg·m²); model input and output in rpm"
        d["estimated"] = list(self.estimated)
        d["unidentified"] = list(self.unidentified)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> WheelGreyBox:
        """Inverse of :meth:`to_dict`."""
        keys = {f for f in cls.__dataclass_fields__}
        try:
            return cls(**{k: v for k, v in d.items() if k in keys})
        except TypeError as exc:
            raise ModelError(f"bad grey-box model: {exc}") from None


FIT_SUBSTEPS = 50  # Euler steps per sample in the fit (the model's own default)


def greybox_fit(
    data: IOData,
    *,
    inertia: float,
    torque_constant: float,
    current_limit: float,
    coulomb: float,
    viscous: float,
    accel_limit_rpm_s: float,
    max_speed_rpm: float,
    kp: float = 0.5,
    ki: float = 0.1,
    stribeck_speed_rpm: float = 10.0,
    current=None,
    uncertainty: Uncertainty | None = None,
    estimate_current_limit: bool | None = None,
    wheel_model: str | None = None,
) -> WheelGreyBox:
    """Estimate the grey-box wheel by simulation error from its datasheet values.

    Parameters
    ----------
    data : IOData
        Speed command → measured speed, both rpm, SISO, starting at rest.
    inertia, torque_constant, current_limit, coulomb, viscous : float
        Datasheet values (kg·m², N·m/A, A, N·m, N·m·s/rad): J and the firmware's
        feed-forward stay fixed; kt, the friction and the current limit (the
        driver's configured value) start from them.
    accel_limit_rpm_s, max_speed_rpm : float
        The rate limit's start value and the known speed limit.
    kp, ki : float
        Start values of the PI gains, 1/s and 1/s².
    stribeck_speed_rpm : float
        ωs, fixed.
    current : array_like, shape (N,), optional
        The measured motor current (A) at the speed's instants: a second
        output that makes kt, τc and b observable (module docstring). Speed
        and current errors are each scaled by their output's spread.
    uncertainty : Uncertainty, optional
        How the standard deviations are formed (default: ``Uncertainty()``).
    estimate_current_limit : bool, optional
        Estimate the current limit (True), hold it at ``current_limit`` with its
        tolerance in every σ (False), or (None, default) estimate it when the
        measured ``current`` shows the clamp binding (:func:`clamp_visible`).
    wheel_model : str, optional
        The wheel model the record is of (its spec's name): whose measured
        structure-error envelope the σ hold (default ``uncertainty.wheel_model``, the
        RW90's); a model without its own gets the widest measured, and ``std_method``
        says so.

    Returns
    -------
    WheelGreyBox
        With ``std`` of the estimated parameters, ``ratios`` (the combinations the
        record identifies without J) and ``std_method``.
    """
    unc = Uncertainty() if uncertainty is None else uncertainty
    if wheel_model is not None:
        unc = replace(unc, wheel_model=wheel_model)
    inertia_tolerance, hac_lags = unc.inertia_tolerance, unc.hac_lags
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("the grey-box fit needs a single-input single-output IOData")
    if data.N < 50:
        raise DataError(f"the grey-box fit needs at least 50 samples, got {data.N}")
    u, y = data.u[:, 0].copy(), data.y[:, 0].copy()
    base = WheelGreyBox(
        data.Ts,
        inertia,
        torque_constant,
        current_limit,
        coulomb,
        1.5 * coulomb,
        stribeck_speed_rpm * RPM,
        viscous,
        accel_limit_rpm_s * RPM,
        kp,
        ki,
        torque_constant,
        coulomb,
        viscous,
        max_speed_rpm * RPM,
        FIT_SUBSTEPS,
    )
    i_meas = None
    if current is not None:
        i_meas = np.asarray(current, dtype=float).ravel()
        if i_meas.shape != y.shape or not np.all(np.isfinite(i_meas)):
            raise DataError("current must be finite with one sample per speed sample")
    sd_i = float(np.std(i_meas)) if i_meas is not None else 1.0
    sd_i = sd_i or 1.0
    tol_c = unc.current_limit_tolerance
    if estimate_current_limit is None:
        estimate_current_limit = i_meas is not None and clamp_visible(i_meas, current_limit, tol_c)
    names = ESTIMATED if _accel_reachable(base) else _without(ESTIMATED, "accel_limit")
    names = (*names, CLAMP) if estimate_current_limit else names
    x0 = np.array([getattr(base, k) for k in names], dtype=float)
    scale = np.abs(x0) + 1e-12
    p = base.vector
    index = [_POSITION[k] for k in names]
    sd_y = float(np.std(y)) or 1.0

    def residuals(z, q=p):
        q = q.copy()
        q[index] = z * scale
        q[4] = max(q[4], q[3])
        speed, cur = _simulate(u, float(y[0]), q)
        if i_meas is None:
            return (speed - y) / sd_y
        return np.concatenate([(speed - y) / sd_y, (cur - i_meas) / sd_i])

    bounds = dict(
        zip(
            (*ESTIMATED, CLAMP),
            ((0.2, 5), (0, 20), (0, 30), (0, 50), (0.2, 5), (1e-3, 1e3), (0, 1e3), (0.5, 1.5)),
            strict=True,
        )
    )
    lower = np.array([bounds[k][0] for k in names], dtype=float)
    upper = np.array([bounds[k][1] for k in names], dtype=float)

    # the loss is piecewise smooth (anti-windup switching, stiction): from a few starts
    # of the PI gains, with finite differences wide enough to see across the kinks
    def start(gains: tuple[float, float]):
        z0 = np.ones(len(x0))
        z0[names.index("kp")], z0[names.index("ki")] = gains
        return least_squares(
            residuals,
            np.clip(z0, lower, upper),
            bounds=(lower, upper),
            diff_step=1e-3,
            x_scale="jac",
            ftol=1e-10,
            xtol=1e-10,
        )

    sol = None
    for trial in in_threads(start, ((1.0, 1.0), (0.7, 1.4), (1.4, 0.7), (1.0, 2.0), (1.0, 0.5))):
        if sol is None or trial.cost < sol.cost:
            sol = trial
    if sol is None or not np.all(np.isfinite(sol.x)):
        raise EstimationError(
            "the grey-box fit diverged; check the record and the datasheet values"
        )
    values = sol.x * scale
    fitted = dict(zip(names, (float(v) for v in values), strict=True))
    # a parameter the loss does not see at the optimum (zero Jacobian column) has no σ: it
    # is unidentified, as is a breakaway whose excess over Coulomb is within 2 σ of the
    # difference (everything in σ: the statistical σ alone is degenerate at the kink)
    norms = np.linalg.norm(sol.jac, axis=0)
    blind = norms <= 1e-8 * max(float(norms.max()), 1e-300)

    def spread(seen):
        cov, lags = sandwich_covariance(sol.fun, sol.jac, y.size, seen, hac_lags)
        cov /= np.outer(1 / scale, 1 / scale)
        fit_std = {k: math.sqrt(max(cov[i, i], 0.0)) for i, k in enumerate(names) if seen[i]}
        clamp = None  # with the limit held: its tolerance carried through the fit
        if not estimate_current_limit:
            clamp = _clamp_sensitivity(residuals, sol, p, current_limit, seen, names)
            clamp = {k: abs(v) * current_limit * tol_c / math.sqrt(3.0) for k, v in clamp.items()}
        return cov, lags, *uncertainty_budget(fit_std, fitted, clamp, unc, inertia)

    b, c = names.index("breakaway"), names.index("coulomb")
    cov, lags, std, ratios, budget = spread(~blind)
    if not blind[b] and blind[c]:  # no Coulomb level to exceed: the excess is not seen either
        blind[b] = True
        cov, lags, std, ratios, budget = spread(~blind)
    if not blind[b]:
        diff_var = std["breakaway"] ** 2 + std["coulomb"] ** 2 - 2.0 * cov[b, c]
        if fitted["breakaway"] - fitted["coulomb"] <= 2.0 * math.sqrt(max(diff_var, 0.0)):
            blind[b] = True
            cov, lags, std, ratios, budget = spread(~blind)
    if blind[b]:
        fitted["breakaway"] = fitted["coulomb"]
    unidentified = tuple(k for i, k in enumerate(names) if blind[i])
    limit = (
        "current_limit: estimated (the record shows the clamp binding)"
        if estimate_current_limit
        else f"current_limit: held at the configured {current_limit:g} A, its tolerance "
        f"±{100 * tol_c:g} % (uniform) carried through the fit's sensitivity to it"
    )
    method = (
        f"statistical: sandwich H⁻¹SH⁻¹ of the simulation error, S by Newey–West with {lags} "
        f"lags ({'Andrews AR(1) plug-in' if hac_lags is None else 'given'}); structure: the "
        f"bias envelope the model's structure leaves ({_structure_source(unc)}); "
        f"{limit}; inertia: J's "
        f"datasheet tolerance ±{100 * inertia_tolerance:g} % (uniform) for the parameters "
        "that need J; std is their root sum of squares; ratios (x/J, the combinations the "
        "record identifies) leave the inertia term out"
    )
    return replace(
        base,
        **fitted,  # type: ignore[arg-type]
        std=std,
        unidentified=unidentified,
        ratios=ratios,
        std_method=method,
        std_budget=budget,
        current_limit_estimated=bool(estimate_current_limit),
        accel_limit_estimated="accel_limit" in names,
    )


def _structure_source(unc: Uncertainty) -> str:
    """Where the structure term's envelope comes from, for ``std_method``."""
    if unc.structure_error is not None:
        return "given"
    return structure_error(unc.wheel_model)[1]


def _without(names: tuple[str, ...], name: str) -> tuple[str, ...]:
    return tuple(k for k in names if k != name)


def _accel_reachable(base: WheelGreyBox) -> bool:
    """Whether the current clamp surely lets the wheel accelerate at its rate limit α:
    the clamp's torque (kt 5 % below its datasheet value, its tolerance) less the
    Coulomb friction, over J. When it does not, α acts mostly on the anti-windup and the
    fit cannot place it (measured: +5 % on a 0.35 A unit); it is a driver setting, held."""
    torque = 0.95 * base.torque_constant * base.current_limit - base.coulomb
    return torque / base.inertia >= base.accel_limit


def clamp_visible(current, current_limit: float, tolerance: float = 0.02) -> bool:
    """Whether a measured motor current shows the driver's clamp binding.

    Parameters
    ----------
    current : array_like, shape (N,)
        Measured motor current, A.
    current_limit : float
        The driver's configured limit, A.
    tolerance : float
        How far the unit's clamp may sit from it, ± fraction.

    Returns
    -------
    bool
        True when at least :data:`CLAMP_SAMPLES` samples reach the configured limit
        less three tolerances (the clamp's spread, the sensor's offset and noise).
    """
    level = float(current_limit) * (1.0 - 3.0 * tolerance)
    return int(np.count_nonzero(np.abs(np.asarray(current, dtype=float)) >= level)) >= (
        CLAMP_SAMPLES
    )


def _clamp_sensitivity(residuals, sol, p, current_limit, seen, names) -> dict:
    """d(estimate)/d(i_max) at the optimum with i_max held fixed (implicit function:
    −(JᵀJ)⁻¹Jᵀ ∂r/∂i_max), per parameter, in its units per A. A central difference
    over ±1 % of i_max: the clamp switches the simulation, a smaller step sees noise."""
    step = 0.01 * current_limit
    plus, minus = p.copy(), p.copy()
    plus[2] += step
    minus[2] -= step
    column = (residuals(sol.x, plus) - residuals(sol.x, minus)) / (2 * step)
    jac = sol.jac[:, seen]
    shift = -np.linalg.lstsq(jac, column, rcond=None)[0]
    scale = np.abs(np.array([p[_POSITION[k]] for k in names])) + 1e-12
    out, j = {}, 0
    for i, k in enumerate(names):
        if seen[i]:
            out[k] = float(shift[j] * scale[i])  # z-space → physical units
            j += 1
    return out
