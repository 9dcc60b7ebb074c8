"""Residual generation: every per-sample feature the detectors read, computed once.

The identified model (:class:`rwlab.wheel.IdentifiedWheel`) runs beside the
record on the commands the wheel was given; the motor's current balance

    i = c₀·α + c₁·ω + c₂·sign ω + c₃   (A; α in rpm/s, ω in rpm)

(``model.json``'s healthy reference: c = [I/k_t, b/k_t, τ_c/k_t, offset]) says what
current a healthy wheel draws for the acceleration it achieved. Three residual
channels follow, each zero-mean on a healthy wheel of the reference's unit:

- ``current_residual_a``: measured current minus the balance at the measured α, ω
  (friction and the torque constant show here);
- ``accel_residual_rpm_s``: measured acceleration minus the acceleration the
  wheel's loop asks for, the model's acceleration plus the loop's catch-up
  ``kp·(ω_model − ω)``, clipped at the acceleration limit (a current clamp or a
  weak motor at the limit shows here);
- ``speed_residual_rpm``: measured minus model speed (a sensor bias shows here).

The reference is one unit's (the identified one's); another unit of the same
model sits off it by its own current offset, friction and inertia/k_t, and
that misfit, constant over minutes, is many times the current's noise (on the
RW90 a unit's friction current is ±30 % of the reference's, several mA against
~4.5 mA of noise per sample). :meth:`Features.own` gives the same features
against the record's *own* past: the current residual less the unit's
deviation, ``current_nuisance_a``, fitted by least squares on the record's
samples older than ``REFERENCE_LAG_S`` (the longest detection window), in the
deviations a healthy unit has: an offset and scales of its viscous and Coulomb
friction currents (units differ in each). ``own(law=True)`` fits them on the
constant-speed samples alone (the unit's friction law, what the friction
detector reads), reads them only where that past spans the sample's speed
(:func:`past_covers`: the law interpolates), and has a friction × F multiply the
unit's own friction current (the reference's plus its fitted deviation). Its
inertia/k_t is left to the detectors' own-past comparison (the size the past
fits): a past of slow motion (a chirp's first minutes) does not determine it,
and a least-squares scale fitted there is extrapolated wildly into the fast part
(healthy chirps then gave log-LRs of 10⁵). A fault younger than the lag is a
change against the unit itself.

Every scale comes from the model file (sample time, acceleration and current
limits, the loop's gain where the grey box identified it): no wheel's numbers
are written here.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rwlab.data import IOData
from rwlab.diagnose.columns import RECORD_OUTPUTS, check_command_period, record_columns
from rwlab.diagnose.past_fits import fit_every_past
from rwlab.diagnose.scales import WheelScales

__all__ = [
    "RECORD_OUTPUTS",
    "REFERENCE_LAG_S",
    "Features",
    "WheelScales",
    "channel_mask",
    "compute_features",
    "current_nuisance",
]

# design choices, not measurements: the own reference is fitted on samples older than the
# longest detection window (5 min, the longest delay the lab accepts), and only once it
# holds this long of the current channel's samples
REFERENCE_LAG_S = 300.0
REFERENCE_MIN_S = 60.0
# design choice: the reach at the acceleration limit is referenced half as far back (a
# signal that reaches the limit late, a chirp's fast part, has little past there); a
# window reads its samples only that far from its start (Bank.own_gain)
LIMIT_REFERENCE_LAG_S = 150.0
# a twentieth of the acceleration limit: "constant speed" (the model's own lag is then a
# fraction of an rpm, and the inertia's current a few % of the clamp)
STEADY_SHARE = 0.05


@dataclass(frozen=True)
class Features:
    """Per-sample features of one record against the identified model, each shape (N,).

    Attributes
    ----------
    t_s : numpy.ndarray
        Sample times, s.
    speed_rpm, model_rpm : numpy.ndarray
        Measured and model speed, rpm.
    accel_rpm_s, model_accel_rpm_s, demand_accel_rpm_s : numpy.ndarray
        Measured and model acceleration (backward differences) and the loop's
        demand, rpm/s.
    current_a : numpy.ndarray
        Measured motor current, A.
    friction_current_a, drive_current_a : numpy.ndarray
        The balance's friction part c₁ω + c₂ sign ω and its whole motion part
        c₀α + c₁ω + c₂ sign ω at the measured α, ω, A.
    current_residual_a, accel_residual_rpm_s, speed_residual_rpm : numpy.ndarray
        The three residual channels (module docstring).
    usable : numpy.ndarray of bool
        A new telemetry frame at this sample and the one before (lost frames
        leave held values that are no measurement).
    repeated : numpy.ndarray of bool
        The speed reading equals the previous one and is not 0 rpm.
    lost_frames : numpy.ndarray
        Telemetry frames lost since the previous sample.
    scales : WheelScales
    current_nuisance_a : numpy.ndarray or None
        The unit's own deviation from the reference's current balance at each sample,
        fitted on the record's past older than ``REFERENCE_LAG_S``, A, shape (N, 3): its
        offset, viscous and Coulomb parts; NaN until that past holds
        ``REFERENCE_MIN_S`` of usable samples (module docstring).
    limit_reference : numpy.ndarray or None
        With ``own(law=True)``: the unit's own reach at the acceleration limit
        (:func:`limit_reference`), (δ, β), shape (N, 2); NaN where not fitted.
    current_ready : numpy.ndarray of bool or None
        With ``own(law=True)``: where the current channel's own law is fitted and
        interpolates (the other channels keep ``usable``); None: everywhere.
    against_own : bool
        The current residual is against the record's own past (:meth:`own`).
    open_loop : bool
        An acceleration-mode record: the driver feeds its model's current forward at
        every sample, as the speed loop does at its acceleration limit, so every sample
        is read as :attr:`saturated`; no speed reference (the speed residual is 0: a
        sensor bias is not observable).
    past_fits : dict of bool to numpy.ndarray
        :func:`current_nuisance`'s fits so far, per ``steady``: the coefficients fitted on
        the past ending at each sample, shape (M, 3), NaN rows where none is; kept so a
        longer record of the same samples (:func:`compute_features`'s ``before``) fits
        only its new pasts.
    model_end : IdentifiedWheel or None
        A copy of the model after the last sample (speed mode): a longer record of the
        same samples runs it on from there.
    """

    t_s: np.ndarray
    speed_rpm: np.ndarray
    model_rpm: np.ndarray
    accel_rpm_s: np.ndarray
    model_accel_rpm_s: np.ndarray
    demand_accel_rpm_s: np.ndarray
    current_a: np.ndarray
    friction_current_a: np.ndarray
    drive_current_a: np.ndarray
    current_residual_a: np.ndarray
    accel_residual_rpm_s: np.ndarray
    speed_residual_rpm: np.ndarray
    usable: np.ndarray
    repeated: np.ndarray
    lost_frames: np.ndarray
    scales: WheelScales
    current_nuisance_a: np.ndarray | None = None
    limit_reference: np.ndarray | None = None
    current_ready: np.ndarray | None = None
    against_own: bool = False
    open_loop: bool = False
    past_fits: dict[bool, np.ndarray] = field(default_factory=dict, compare=False, repr=False)
    model_end: Any = field(default=None, compare=False, repr=False)

    def own(self, law: bool = False) -> Features:
        """The same features with the current residual against the record's own past
        (samples whose own reference is not yet fitted are unusable).

        Parameters
        ----------
        law : bool
            The unit's friction law instead (:func:`current_nuisance` on constant-speed
            samples), read only where its past spans the speed (:func:`past_covers`), with
            the unit's own friction current as what a friction × F multiplies (a unit whose
            friction is twice the reference's draws twice the current for the same F).

        Returns
        -------
        Features
        """
        nuisance = current_nuisance(self, steady=True) if law else self.current_nuisance_a
        if nuisance is None:
            nuisance = current_nuisance(self)
        ready = np.isfinite(nuisance[:, 0])
        usable, friction = self.usable & ready, self.friction_current_a
        limit = current_ready = None
        if law:  # the law gates the current alone: the limit's reach has its own reference
            usable, current_ready = self.usable, ready & past_covers(self)
            unit = friction + nuisance[:, 1] + nuisance[:, 2]
            friction = np.where(ready, np.where(unit * friction > 0, unit, 0.0), friction)
            limit = limit_reference(self)
        return replace(
            self,
            current_residual_a=np.where(ready, self.current_residual_a - nuisance.sum(1), 0.0),
            friction_current_a=friction,
            usable=usable,
            current_nuisance_a=nuisance,
            limit_reference=limit,
            current_ready=current_ready,
            against_own=True,
        )

    @property
    def N(self) -> int:
        """Number of samples."""
        return len(self.t_s)

    def rows(self, start: int) -> Features:
        """The samples from ``start`` on, every per-sample array sliced (a sample's features
        depend on its past only, so these are the record's own from there).

        Parameters
        ----------
        start : int
            The first sample kept.

        Returns
        -------
        Features
        """
        n = self.N
        sliced: dict[str, Any] = {
            name: value[start:]
            for name, value in vars(self).items()
            if isinstance(value, np.ndarray) and value.shape[:1] == (n,)
        }
        return replace(self, **sliced, past_fits={}, model_end=None)

    def steady(self, share: float) -> np.ndarray:
        """Constant speed, bool, shape (N,): the model's and the measured acceleration both
        within ``share`` of the acceleration limit (a wheel that lags the model, as a weak
        motor or a clamp makes it, is not at constant speed while it catches up)."""
        limit = share * self.scales.accel_limit_rpm_s
        return (np.abs(self.model_accel_rpm_s) <= limit) & (np.abs(self.accel_rpm_s) <= limit)

    @property
    def saturated(self) -> np.ndarray:
        """The loop demands its acceleration limit, within ``STEADY_SHARE`` of it, bool,
        shape (N,). Not only the clipped samples: the demand of a slew's first samples sits
        just under the limit while the wheel is still ramping into it, and its misfit
        there is the slew's, not a quiet sample's (a healthy PRBS's slew entry otherwise
        gave one sample a log-LR of 860 for a weak motor)."""
        if self.open_loop:
            return np.ones(self.N, dtype=bool)
        limit = self.scales.accel_limit_rpm_s
        return np.abs(self.demand_accel_rpm_s) >= limit * (1 - STEADY_SHARE)


def compute_features(
    data: IOData, wheel, scales: WheelScales, before: Features | None = None
) -> Features:
    """Run the model beside the record and form every feature (module docstring).

    Parameters
    ----------
    data : IOData
        u = speed command (rpm), or acceleration command (rpm/s: an acceleration-mode
        record, ``Features.open_loop``); outputs ``speed_rpm``, ``current_a`` and, where
        the record has them, ``telemetry_age_s`` and ``lost_frames``, at the model's Ts.
    wheel : IdentifiedWheel or None
        The identified model (reset and stepped here; the caller's copy is reused);
        unused for an acceleration-mode record.
    scales : WheelScales
    before : Features, optional
        The features of this record's first samples (a record growing as it is recorded):
        the model runs on from its end and the own reference's past fits are reused
        (ignored unless its times, speeds and currents are this record's first).

    Returns
    -------
    Features

    Raises
    ------
    DataError
        Another sample time, no speed or current, more than one input, non-finite values,
        a speed-mode record commanded at another period than the model's.
    """
    Ts = scales.Ts
    col = record_columns(data, Ts)
    speed, current = col["speed_rpm"], col["current_a"]
    if before is not None and not _extends(before, data.tstart, speed, current, scales):
        before = None
    accel = np.concatenate([[0.0], np.diff(speed) / Ts])
    limit = scales.accel_limit_rpm_s
    open_loop = bool(data.input_units) and data.input_units[0] == "rpm/s"
    if open_loop:  # the driver's acceleration is the command, clipped: no speed model
        model, model_accel = speed, np.clip(col["held"], -limit, limit)
        demand, model_end = model_accel, None
    else:
        check_command_period(data, Ts)
        model = np.empty(data.N)
        if before is not None and before.model_end is not None:  # run on from its end
            wheel, done = copy.deepcopy(before.model_end), before.N
            model[:done] = before.model_rpm
        else:
            wheel.reset(float(speed[0]))
            model[0], done = speed[0], 1
        for k in range(done, data.N):
            model[k] = wheel.step(float(col["held"][k]))
        model_end = copy.deepcopy(wheel)
        model_accel = np.concatenate([[0.0], np.diff(model) / Ts])
        lag = np.concatenate([[0.0], (model - speed)[:-1]])  # the loop acts on the last error
        demand = np.clip(model_accel + scales.loop_gain_per_s * lag, -limit, limit)
    c0, c1, c2, c3 = scales.current_model
    friction = c1 * speed + c2 * np.sign(speed)
    drive = c0 * accel + friction
    fresh = col["telemetry_age_s"] < Ts
    usable = fresh & np.concatenate([[False], fresh[:-1]])
    repeated = np.concatenate([[False], (np.diff(speed) == 0) & (speed[1:] != 0)])
    lost = np.concatenate([[0.0], np.maximum(np.diff(col["lost_frames"]), 0.0)])
    t = data.tstart + Ts * np.arange(data.N)
    out = Features(
        t_s=t,
        speed_rpm=speed,
        model_rpm=model,
        accel_rpm_s=accel,
        model_accel_rpm_s=model_accel,
        demand_accel_rpm_s=demand,
        current_a=current,
        friction_current_a=friction,
        drive_current_a=drive,
        current_residual_a=current - drive - c3,
        accel_residual_rpm_s=accel - demand,
        speed_residual_rpm=speed - model,
        usable=usable,
        repeated=repeated,
        lost_frames=lost,
        scales=scales,
        open_loop=open_loop,
        model_end=model_end,
    )
    if before is not None:
        out.past_fits.update(before.past_fits)
    return replace(out, current_nuisance_a=current_nuisance(out))


def _extends(before: Features, t0_s: float, speed, current, scales: WheelScales) -> bool:
    """Whether ``before`` holds the first samples of a record (its first time, speeds and
    currents, the same scales)."""
    n = before.N
    return (
        n <= len(speed)
        and before.scales == scales
        and math.isclose(float(before.t_s[0]), t0_s, rel_tol=0.0, abs_tol=1e-9)
        and np.array_equal(before.speed_rpm, speed[:n])
        and np.array_equal(before.current_a, current[:n])
    )


def channel_mask(features: Features, name: str) -> np.ndarray:
    """The samples a channel is read on, bool, shape (N,): fresh, not a repeated reading,
    out of the stiction band (``WheelScales.stiction_band_rpm``); for the current channel
    also a turning wheel that kept its direction over the sample.
    At rest (a zero reading: below what the sensor measures) and through a reversal the
    bearing's friction is static, anywhere within its breakaway band, and the loop's
    integrator holds whatever current it last needed: the current there says nothing of
    the friction or the torque constant, and a healthy wheel's current at rest sits
    ±(breakaway friction)/k_t off the balance for minutes (measured: ±9 mA on an RW90).

    Parameters
    ----------
    features : Features
        The record's features.
    name : str
        The channel (:data:`rwlab.diagnose.noise.CHANNELS`), e.g. ``"current"``.

    Returns
    -------
    numpy.ndarray
        bool, shape (N,): True where the channel is read.
    """
    ok = features.usable & ~features.repeated
    # under the stiction band the bearing's law is breakaway, not the model's
    ok &= np.abs(features.speed_rpm) >= features.scales.stiction_band_rpm
    if name == "speed" and features.open_loop:  # no speed reference
        return np.zeros(features.N, dtype=bool)
    if name.startswith("current"):
        if features.current_ready is not None:
            ok = ok & features.current_ready
        ok = ok & _turning(features)
    if name == "current_steady":
        ok = ok & features.steady(STEADY_SHARE)
    return ok


def _turning(features: Features) -> np.ndarray:
    """A non-zero reading that kept its direction over the sample, bool, shape (N,)."""
    w = features.speed_rpm
    before = np.concatenate([w[:1], w[:-1]])
    return (w != 0) & (np.sign(w) == np.sign(before))


def past_covers(features: Features) -> np.ndarray:
    """Whether the own reference interpolates at each sample, bool, shape (N,): the
    current channel's samples older than ``REFERENCE_LAG_S`` span its speed on its side
    of zero. Beyond that span the fitted law extrapolates, and a unit's friction law is
    not linear in speed (its Stribeck part), so a chirp growing into new speeds read a
    healthy unit's friction ×3-7 against its own past (measured)."""
    f = features
    ok = channel_mask(f, "current_steady")
    speed = np.abs(f.speed_rpm)
    lag = round(REFERENCE_LAG_S / f.scales.Ts)
    covered = np.zeros(f.N, dtype=bool)
    if lag >= f.N:
        return covered
    for side in (1.0, -1.0):
        past = ok & (np.sign(f.speed_rpm) == side)
        lo = np.minimum.accumulate(np.where(past, speed, np.inf))[: f.N - lag]
        hi = np.maximum.accumulate(np.where(past, speed, -np.inf))[: f.N - lag]
        now = speed[lag:]
        here = np.sign(f.speed_rpm[lag:]) == side
        covered[lag:] |= here & (lo <= now) & (now <= hi)
    return covered


def at_limit(features: Features) -> np.ndarray:
    """The samples read at the acceleration limit, bool, shape (N,): the acceleration
    channel's (:func:`channel_mask`), the loop demanding its limit
    (:attr:`Features.saturated`), turning one way through the sample (through a reversal
    the bearing's friction is static, not its law).

    Parameters
    ----------
    features : Features

    Returns
    -------
    numpy.ndarray
    """
    return channel_mask(features, "accel") & features.saturated & _turning(features)


def limit_reach(features: Features) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the acceleration limit's reach is read on, shape (N,) each.

    Parameters
    ----------
    features : Features

    Returns
    -------
    reach : numpy.ndarray
        Measured acceleration less the limit in the demand's direction, rpm/s.
    x : numpy.ndarray
        The reference's friction law (c₁ω + c₂ sign ω)/c₀, rpm/s.
    s : numpy.ndarray
        The demand's direction, ±1.
    """
    f = features
    c0, c1, c2, _ = f.scales.current_model
    s = np.sign(f.demand_accel_rpm_s)
    reach = f.accel_rpm_s - s * f.scales.accel_limit_rpm_s
    return reach, (c1 * f.speed_rpm + c2 * np.sign(f.speed_rpm)) / c0, s


def own_limit_residual(features: Features) -> tuple[np.ndarray, np.ndarray]:
    """The reach at the acceleration limit less the unit's own (:func:`limit_reference`),
    rpm/s, and where it is read, bool, shape (N,) each.

    Parameters
    ----------
    features : Features
        Against the own past (``Features.own(law=True)``).

    Returns
    -------
    residual : numpy.ndarray
        0 where not read.
    read : numpy.ndarray of bool
    """
    ref = features.limit_reference
    if ref is None:
        ref = limit_reference(features)
    read = at_limit(features) & np.isfinite(ref[:, 0])
    delta, beta = np.where(read[:, None], ref, 0.0).T
    reach, x, s = limit_reach(features)
    return np.where(read, reach - delta * x - beta * s, 0.0), read


def limit_reference(features: Features) -> np.ndarray:
    """The unit's own reach at the acceleration limit, (δ, β) per sample, shape (N, 2).

    At the limit the driver's friction feed-forward is the model's, so a unit whose
    bearings drag u × the reference's reaches it short by (u − 1)·x (:func:`limit_reach`;
    x changes sign where a slew passes through zero), δ = 1 − u; and the whole slew's
    reach sits β·s off the limit in the demand's direction s (the unit's inertia and
    torque constant, the identified model's own limit). At sample k, (δ, β) is the
    least-squares fit of the reach on (x, s) over the samples :func:`at_limit` older
    than ``LIMIT_REFERENCE_LAG_S``; NaN until ``REFERENCE_MIN_S`` of such samples exist
    and the past has pushed toward and away from zero (else x and s are one). A chirp's
    fast part holds the wheel at its limit and never at constant speed: there this is
    the only reference for a friction change against the unit itself.

    Parameters
    ----------
    features : Features

    Returns
    -------
    numpy.ndarray
    """
    f = features
    reach, x, s = limit_reach(f)
    ok = at_limit(f)
    X = np.column_stack([x, s])
    Xo = X * ok[:, None]
    A = np.cumsum(Xo[:, :, None] * X[:, None, :], axis=0)
    b = np.cumsum(Xo * reach[:, None], axis=0)
    count = np.cumsum(ok)
    lag = round(LIMIT_REFERENCE_LAG_S / f.scales.Ts)
    out = np.full((f.N, 2), np.nan)
    if lag >= f.N:
        return out
    A, b, count = A[: f.N - lag], b[: f.N - lag], count[: f.N - lag]
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] ** 2
    # both directions held: x's part not along s is at least a tenth of it
    ready = (count >= round(REFERENCE_MIN_S / f.scales.Ts)) & (det > 0.1 * A[:, 0, 0] * A[:, 1, 1])
    det = np.where(ready, det, 1.0)
    delta = (A[:, 1, 1] * b[:, 0] - A[:, 0, 1] * b[:, 1]) / det
    beta = (A[:, 0, 0] * b[:, 1] - A[:, 0, 1] * b[:, 0]) / det
    out[lag:] = np.where(ready[:, None], np.column_stack([delta, beta]), np.nan)
    return out


def current_nuisance(features: Features, steady: bool = False) -> np.ndarray:
    """The unit's own deviation from the reference current balance, per sample, A, shape (N, 3).

    At sample k: the least-squares fit of the current residual on an offset and the
    balance's viscous and Coulomb currents, over the current channel's samples
    (:func:`channel_mask`; with ``steady``, its constant-speed ones, where the current
    is the friction's alone) older than ``REFERENCE_LAG_S``, evaluated at k, each of the
    three parts a column; NaN until ``REFERENCE_MIN_S`` of such samples exist. A direction the
    past has not excited (no motion yet: the friction and the offset alike) takes the
    least-norm solution, i.e. the reference's value. The fits of pasts already in
    ``features.past_fits`` are reused, and the new ones added there.

    Parameters
    ----------
    features : Features
    steady : bool
        Fit on the constant-speed samples only.

    Returns
    -------
    numpy.ndarray
    """
    f = features
    c1, c2 = f.scales.current_model[1:3]
    # the offset's column a tenth of the friction current's largest so far, the others'
    # size: a past at one speed (offset and Coulomb friction alike there) is then read as
    # friction, the deviation a unit has most
    unit = np.maximum.accumulate(np.maximum(np.abs(f.friction_current_a), 1e-12))
    X = np.column_stack([np.full(f.N, 0.1), c1 * f.speed_rpm, c2 * np.sign(f.speed_rpm)])
    ok = channel_mask(f, "current_steady" if steady else "current")
    lag = round(REFERENCE_LAG_S / f.scales.Ts)
    pasts = max(f.N - lag, 0)  # the pasts, ending at j = k − lag
    theta = fit_every_past(
        X[:pasts],
        f.current_residual_a[:pasts],
        ok[:pasts],
        round(REFERENCE_MIN_S / f.scales.Ts),
        unit[:pasts],
        f.past_fits.get(steady) if f.current_ready is None else None,
    )
    if f.current_ready is None:
        f.past_fits[steady] = theta
    out = np.full((f.N, 3), np.nan)
    out[lag:] = X[lag:] * theta
    return out
