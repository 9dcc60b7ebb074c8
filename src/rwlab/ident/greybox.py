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
observable only while the current limit binds. The current limit ``i_max`` is a
known setting of the driver (a record that never reaches it cannot tell where
it is), as is ω_max. Estimated, each with its standard deviation
(λ·(JᵀJ)⁻¹ at the optimum; simulation errors are correlated, so these are lower
bounds): kt, τc, τbrk, b, α, kp, ki. ωs is fixed (10 rpm typical: a Stribeck
speed is not identifiable from a PRBS that crosses zero a few times).

No library offers this model; the simulation is written here and compiled with
numba, the fit is ``scipy.optimize.least_squares`` on the simulation error.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from rwlab.data import IOData
from rwlab.errors import DataError, EstimationError, ModelError

__all__ = ["WheelGreyBox", "greybox_fit"]

STRUCTURE = "greybox"
RPM = math.pi / 30.0  # rad/s per rpm
ESTIMATED = ("torque_constant", "coulomb", "breakaway", "viscous", "accel_limit", "kp", "ki")


@njit(cache=True)
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
        i_max, A (known driver setting).
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
        Estimated parameters the record did not inform: the simulation error
        does not change with them at the optimum (e.g. ``breakaway`` when the
        wheel only crosses zero at its acceleration limit, where it dwells
        milliseconds in a 0.5-s sample, and the fit leaves it at ``coulomb``).
        Their values are not estimates; a λ(JᵀJ)⁻¹ standard deviation would be
        a meaningless ~0.
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

    nu = 1
    ny = 1
    nk = 1
    structure = STRUCTURE

    def __post_init__(self) -> None:
        object.__setattr__(self, "unidentified", tuple(self.unidentified))
        if not set(self.unidentified) <= set(ESTIMATED):
            raise ModelError(f"unidentified must name estimated parameters {ESTIMATED}")
        values = [v for k, v in asdict(self).items() if k not in ("std", "unidentified")]
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
        return len(ESTIMATED)

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
        u = np.asarray(u_rpm, dtype=float).ravel()
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
        u = np.asarray(u_rpm, dtype=float).ravel()
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
        d["estimated"] = list(ESTIMATED)
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
    substeps: int = 50,
    current=None,
) -> WheelGreyBox:
    """Estimate the grey-box wheel by simulation error from its datasheet values.

    Parameters
    ----------
    data : IOData
        Speed command → measured speed, both rpm, SISO, starting at rest.
    inertia, torque_constant, current_limit, coulomb, viscous : float
        Datasheet values (kg·m², N·m/A, A, N·m, N·m·s/rad): J, the current
        limit and the firmware's feed-forward stay fixed; kt and the friction
        start from them.
    accel_limit_rpm_s, max_speed_rpm : float
        The rate limit's start value and the known speed limit.
    kp, ki : float
        Start values of the PI gains, 1/s and 1/s².
    stribeck_speed_rpm : float
        ωs, fixed.
    substeps : int
        Euler steps per sample.
    current : array_like, shape (N,), optional
        The measured motor current (A) at the speed's instants: a second
        output that makes kt, τc and b observable (module docstring). Speed
        and current errors are each scaled by their output's spread.

    Returns
    -------
    WheelGreyBox
        With ``std`` of the estimated parameters.
    """
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
        substeps,
    )
    x0 = np.array([getattr(base, k) for k in ESTIMATED], dtype=float)
    scale = np.abs(x0) + 1e-12
    p = base.vector
    index = [1, 3, 4, 6, 7, 8, 9]  # positions of ESTIMATED in the vector
    sd_y = float(np.std(y)) or 1.0
    i_meas = None
    if current is not None:
        i_meas = np.asarray(current, dtype=float).ravel()
        if i_meas.shape != y.shape or not np.all(np.isfinite(i_meas)):
            raise DataError("current must be finite with one sample per speed sample")
    sd_i = float(np.std(i_meas)) if i_meas is not None else 1.0
    sd_i = sd_i or 1.0

    def residuals(z):
        q = p.copy()
        q[index] = z * scale
        q[4] = max(q[4], q[3])
        speed, cur = _simulate(u, float(y[0]), q)
        if i_meas is None:
            return (speed - y) / sd_y
        return np.concatenate([(speed - y) / sd_y, (cur - i_meas) / sd_i])

    lower = np.array([0.2, 0.0, 0.0, 0.0, 0.2, 1e-3, 0.0])
    upper = np.array([5.0, 20.0, 30.0, 50.0, 5.0, 1e3, 1e3])
    # the loss is piecewise smooth (anti-windup switching, stiction): from a few starts
    # of the PI gains, with finite differences wide enough to see across the kinks
    sol = None
    for fk, fi in ((1.0, 1.0), (0.7, 1.4), (1.4, 0.7), (1.0, 2.0), (1.0, 0.5)):
        z0 = np.ones(len(x0))
        z0[5], z0[6] = fk, fi
        trial = least_squares(
            residuals,
            np.clip(z0, lower, upper),
            bounds=(lower, upper),
            diff_step=1e-3,
            x_scale="jac",
            ftol=1e-10,
            xtol=1e-10,
        )
        if sol is None or trial.cost < sol.cost:
            sol = trial
    if sol is None or not np.all(np.isfinite(sol.x)):
        raise EstimationError(
            "the grey-box fit diverged; check the record and the datasheet values"
        )
    values = sol.x * scale
    # covariance: each output's residual variance, in its own units
    n_y = y.size
    parts = [(sol.fun[:n_y], sol.jac[:n_y])]
    if i_meas is not None:
        parts.append((sol.fun[n_y:], sol.jac[n_y:]))
    info = np.zeros((len(x0), len(x0)))
    for res, jac in parts:
        lam = float(res @ res) / max(res.size - len(x0), 1)  # in scaled units
        info += (jac.T @ jac) / lam
    # a parameter the loss does not see at the optimum (zero Jacobian column, or breakaway
    # clipped to Coulomb) has no standard deviation: it is reported as unidentified
    fitted = dict(zip(ESTIMATED, (float(v) for v in values), strict=True))
    norms = np.linalg.norm(sol.jac, axis=0)
    blind = norms <= 1e-8 * max(float(norms.max()), 1e-300)
    blind[ESTIMATED.index("breakaway")] |= fitted["breakaway"] <= fitted["coulomb"]
    seen = ~blind
    cov = np.zeros((len(x0), len(x0)))
    cov[np.ix_(seen, seen)] = np.linalg.pinv(info[np.ix_(seen, seen)])
    cov /= np.outer(1 / scale, 1 / scale)
    std = {k: float(math.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(ESTIMATED) if seen[i]}
    unidentified = tuple(k for i, k in enumerate(ESTIMATED) if blind[i])
    fitted["breakaway"] = max(fitted["breakaway"], fitted["coulomb"])
    return replace(base, **fitted, std=std, unidentified=unidentified)  # type: ignore[arg-type]
