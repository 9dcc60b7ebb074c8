"""Tests that need no held speed: a biased sensor and worn bearings during a chirp.

A chirp (or multisine) never holds a command and its fast part never holds a
speed, so the held-speed and constant-speed tests of :mod:`~rwlab.diagnose.diagnoser`
take no sample there. Two statistics use what such a record does have:

- :func:`speed_offset`: the speed residual (measured − model) over a window of a
  continuously changing command, regressed on the model's speed, its sign and
  acceleration; the intercept is the residual at zero speed, which the model's
  mismatch with another unit (gain, lag, friction) does not move and a biased
  sensor does;
- :func:`slew_asymmetry`: at its acceleration limit the wheel's controller sets
  the current open loop (inertial current plus its friction feed-forward), so
  friction the feed-forward does not know changes the acceleration: a slew runs
  faster towards zero speed than away from it.

- :func:`clamped_deceleration`: where the motor current is clamped below what the
  acceleration limit needs, the current is the same on both sides of zero speed, so
  the difference between a slew's rates towards and away from zero is the whole
  friction (not its excess over a feed-forward);
- :class:`StepCharge`: the charge (∫ current dt) a speed change draws beyond friction is
  I·Δω/k_t wherever the wheel's loop closes on its true speed, whatever the reading
  does: a weak motor's step draws 1/F of it, seen with a frozen reading too;
- :class:`RestReading`: the reading the firmware gives when no Hall edge came
  within its timeout (the wheel passing through zero speed) is exactly 0 on a
  healthy wheel; with a telemetry bias it is exactly the bias, over and over.

Hand-written (no library computes these).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from rwlab.diagnose.constants import measured
from rwlab.wheelspec import WheelSpec

__all__ = [
    "OFFSET_SIGMA_RPM",
    "OFFSET_WINDOW",
    "REST_BAND_RPM",
    "REST_MODEL_RPM",
    "REST_NEAR_RPM",
    "SLEW_SHARE",
    "SLEW_SIGMA",
    "RestReading",
    "Slews",
    "StepCharge",
    "clamped_deceleration",
    "slew_asymmetry",
    "slew_friction_gain",
    "speed_offset",
]

OFFSET_WINDOW = 120  # samples of one speed-offset regression (60 s at 0.5 s)
OFFSET_SWING_RPM = 200.0  # the model's speed reaches ± this within the window
OFFSET_SE_RPM = 1.5  # the intercept's standard error must be below this, rpm
OFFSET_CONTINUOUS = 0.9  # share of samples at which the command changes (no holds)
# σ of one window's intercept on healthy units of the twin (model mismatch, not noise),
# measured on healthy chirps and multisines, rpm
OFFSET_SIGMA_RPM = measured("OFFSET_SIGMA_RPM")
REST_BAND_RPM = 30.0  # a reading within this of zero may be the no-edge reading, rpm
REST_MODEL_RPM = 60.0  # ... taken where the model passes this close to zero speed, rpm
REST_STEP_RPM = 50.0  # ... or where the reading moved this much since the last sample, rpm
# (≥ 100 rpm/s at 0.5 s: a third of the acceleration limit, so not a wheel held at a low speed)
REST_COUNT = 4  # the same non-zero value this often, no 0 between: a bias (healthy units:
# at most 3 over 30 h of the bench's healthy records, 90 records, with 0 between)
# A reading this close to a counted value, but not equal, restarts that value's count: a
# motion that repeats (a chirp's fast end rocking the wheel through zero at one amplitude)
# reads nearly the same low speed at each pass, now and then exactly, and would count as
# a bias. Next to a bias b, the other readings near zero are b plus a speed the Hall
# edges measured, at least the firmware's lowest (the twin's min_measurable_rpm, 5 rpm),
# never within this of b, rpm
REST_NEAR_RPM = measured("REST_NEAR_RPM")
# σ of one slew's asymmetry on healthy units (nominal Coulomb decelerations) on the
# identification's signal, a stepped PRBS, pooled over many records: one identification
# record has 9–10 slews, too few for its own σ, so the detector takes the larger of the two
SLEW_SIGMA = measured("SLEW_SIGMA")
SLEW_SHARE = 0.8  # a slew: |measured α| ≥ this share of the acceleration limit
SLEW_SPEED_RPM = (100.0, 3000.0)  # |ω| in a slew's halves: beyond the Hall sensor's and
# the Stribeck band's low speeds, below the back-EMF's supply limit
CLAMP_SHARE = 0.5  # a clamped slew: |measured α| ≥ this share of the acceleration limit
# (a 0.45 A clamp holds the RW90 at ≈ 0.8 of its limit, right at SLEW_SHARE)
CLAMP_PLATEAU_A = 0.02  # samples this far below the slew's median current have left it, A
CLAMP_FLAT_A = 0.008  # the current's step across zero below this: clamped, A (a slew at
# the acceleration limit steps by twice its Coulomb current, ≈ 18 mA on the RW90)
CHARGE_WINDOW_S = 5.0  # a settled level: the current's mean over this, s
CHARGE_MIN_RPM = 1000.0  # a speed change this large draws ≥ 1.6 A·s on the RW90: the
# friction law's shape error between the two settled levels stays below 1 % of it
CHARGE_MONOTONE = 0.9  # ... in one direction: its net change at least this share of the
# model's whole path (a PRBS's several holds between two settled levels add the law's
# error on each leg to a small net change)
SLEW_MIN = 4  # samples in each half of a slew (over ≥ 1.5 s: the Hall reading's noise
# over a shorter half moves its acceleration by about the Coulomb deceleration)


def speed_offset(window: np.ndarray) -> float | None:
    """The speed residual's offset over a window of a continuously changing command.

    A biased speed sensor adds a constant to the measured speed, which no model of the
    wheel's dynamics explains; the identified model's mismatch with another unit (gain,
    lag) is proportional to the model's speed and acceleration. The offset is the
    intercept of the least squares r_ω ≈ b + g·ω_m + c·sign ω_m + h·α_m(k) + h'·α_m(k − 1)
    (c: a friction unlike the model's lags the wheel by a Coulomb-like term): where the
    model's speed swings through zero (both signs beyond :data:`OFFSET_SWING_RPM`), b is
    the residual at zero speed, an interpolation, not an extrapolation.

    Parameters
    ----------
    window : ndarray, shape (n, 4)
        Per sample: speed residual (rpm), model speed (rpm), model acceleration (rpm/s),
        1 if the command changed at that sample else 0.

    Returns
    -------
    float or None
        The offset b, rpm; None where the window does not qualify (holds, no swing
        through zero, or an intercept less certain than :data:`OFFSET_SE_RPM`).
    """
    rs, m, am, changed = window.T
    if np.mean(changed) < OFFSET_CONTINUOUS or m.min() > -OFFSET_SWING_RPM:
        return None
    if m.max() < OFFSET_SWING_RPM:
        return None
    X = np.column_stack([np.ones(len(rs) - 1), m[1:], np.sign(m[1:]), am[1:], am[:-1]])
    coef, *_ = np.linalg.lstsq(X, rs[1:], rcond=None)
    e = rs[1:] - X @ coef
    dof = len(e) - X.shape[1]
    cov = np.linalg.pinv(X.T @ X) * float(e @ e) / dof
    if not math.sqrt(max(cov[0, 0], 0.0)) <= OFFSET_SE_RPM:
        return None
    return float(coef[0])


def slew_asymmetry(
    segment: list[tuple[float, float, float]], c, scale_rpm_s: float | None = None
) -> float | None:
    """How much faster a wheel slews towards zero speed than away from it.

    At its acceleration limit the wheel's controller sets the current open loop (the
    inertial current plus its friction feed-forward), so friction the feed-forward does
    not know changes the acceleration, not the current: it slows the half of a slew that
    runs away from zero speed and speeds up the half that runs towards it. Each half's
    acceleration is taken from its first and last speed (the samples' own differences
    are Hall noise); the difference is in units of ``scale_rpm_s``: the wheel model's
    nominal (datasheet) Coulomb deceleration τ_c/I, the same for every reference (the
    reference unit's identified c₂/c₀ splits Coulomb and viscous friction poorly: 3.2 rpm/s
    for a unit whose true value is 4.7). The healthy level is a unit's own (its controller
    feeds its own friction forward), so it hardly moves between units. A friction factor F
    raises it by about 2(F − 1) times the unit's friction over the nominal Coulomb torque.
    A clamped current (no feed-forward step at the zero crossing) is the lag test's.

    Parameters
    ----------
    segment : list of (t_s, speed_rpm, current_a)
        Consecutive samples of one slew (one sign of acceleration); t_s the time the
        telemetry was measured.
    c : array_like, shape (4,)
        The reference's current model [A per rpm/s, A per rpm, A, A].
    scale_rpm_s : float, optional
        The unit of the result, rpm/s (default: the current model's c₂/c₀, as older
        references were measured).

    Returns
    -------
    float or None
        The asymmetry; None where either half has fewer than :data:`SLEW_MIN` samples
        in :data:`SLEW_SPEED_RPM` or the current does not step at the zero crossing.
    """
    inner = segment[1:-1]  # the first and last samples enter and leave the limit
    pos, neg = _halves(inner)
    if min(len(pos), len(neg)) < SLEW_MIN or not c[0] > 0 or not c[2] > 0:
        return None
    step = np.mean([x[2] for x in pos]) - np.mean([x[2] for x in neg])
    if step < c[2]:  # half the reference's feed-forward step: a clamped current
        return None
    toward, away = _rates(inner, pos, neg)
    scale = c[2] / c[0] if scale_rpm_s is None else scale_rpm_s
    return float((toward - away) / scale)


def _halves(inner: list) -> tuple[list, list]:
    """A slew's samples in :data:`SLEW_SPEED_RPM` at positive and at negative speed."""
    lo, hi = SLEW_SPEED_RPM
    return [x for x in inner if lo < x[1] < hi], [x for x in inner if -hi < x[1] < -lo]


def _rates(inner: list, pos: list, neg: list) -> tuple[float, float]:
    """The rates (rpm/s) of a slew's half towards zero speed and of its half away, each
    from its first and last sample (the samples' own differences are Hall noise)."""

    def rate(half):
        return abs(half[-1][1] - half[0][1]) / (half[-1][0] - half[0][0])

    rising = inner[-1][1] > inner[0][1]
    return (rate(neg), rate(pos)) if rising else (rate(pos), rate(neg))


class Slews:
    """A wheel's slews, sample by sample: runs of one sign of acceleration at ≥ ``share``
    of the acceleration limit.

    Parameters
    ----------
    limit_rpm_s : float
        The acceleration limit, rpm/s.
    share : float
        The share of it a slew's samples reach (:data:`SLEW_SHARE`, :data:`CLAMP_SHARE`).
    """

    def __init__(self, limit_rpm_s: float, share: float) -> None:
        self.limit = share * limit_rpm_s
        self._sign = 0.0
        self._samples: list[tuple[float, float, float]] = []

    def add(
        self, t_s: float, accel_rpm_s: float, speed_rpm: float, current_a: float, usable: bool
    ) -> list[tuple[float, float, float]] | None:
        """One sample; the slew it ends, if any.

        Parameters
        ----------
        t_s : float
            The telemetry's own time, s.
        accel_rpm_s, speed_rpm, current_a : float
            Measured acceleration (rpm/s), speed (rpm) and current (A).
        usable : bool
            A new frame (a stale one ends a slew).

        Returns
        -------
        list of (t_s, speed_rpm, current_a) or None
            The samples of the slew this sample ends.
        """
        slewing = usable and abs(accel_rpm_s) >= self.limit and math.isfinite(current_a)
        sign = math.copysign(1.0, accel_rpm_s) if slewing else 0.0
        ended = None
        if sign != self._sign and self._samples:
            ended, self._samples = self._samples, []
        self._sign = sign
        if slewing:
            self._samples.append((t_s, speed_rpm, current_a))
        return ended


def clamped_deceleration(segment: list[tuple[float, float, float]]) -> tuple[float, float] | None:
    """The friction deceleration in a slew through zero speed at a clamped current.

    With the current clamped (the same on both halves: no feed-forward step at the
    zero crossing), I·α = k_t·i ∓ friction, so half the difference between the rates
    towards and away from zero speed is the friction over the inertia, whatever k_t
    is. Each half's rate is taken from its first and last sample (as in
    :func:`slew_asymmetry`), over the samples at the clamp (within
    :data:`CLAMP_PLATEAU_A` of the slew's median current: not where the loop leaves it).

    Parameters
    ----------
    segment : list of (t_s, speed_rpm, current_a)
        Consecutive samples of one slew (one sign of acceleration).

    Returns
    -------
    (float, float) or None
        The friction deceleration (rpm/s) and the halves' mean speed (rpm, ≥ 0); None
        where either half has fewer than :data:`SLEW_MIN` samples in
        :data:`SLEW_SPEED_RPM` or the current is not flat across zero speed
        (:data:`CLAMP_FLAT_A`: a healthy slew at the limit steps by twice its Coulomb
        current there).
    """
    inner = segment[1:-1]
    if len(inner) < 2 * SLEW_MIN:
        return None
    level = float(np.median([abs(x[2]) for x in inner]))
    inner = [x for x in inner if abs(x[2]) >= level - CLAMP_PLATEAU_A]
    pos, neg = _halves(inner)
    if min(len(pos), len(neg)) < SLEW_MIN:
        return None
    if abs(np.mean([x[2] for x in pos]) - np.mean([x[2] for x in neg])) >= CLAMP_FLAT_A:
        return None
    toward, away = _rates(inner, pos, neg)
    speed = float(np.mean([abs(x[1]) for x in pos + neg]))
    return float((toward - away) / 2), speed


def slew_friction_gain(
    segment: list[tuple[float, float, float]], spec: WheelSpec | None = None
) -> float | None:
    """The friction at a slew's speeds over the Coulomb friction, nominal: 1 + b·|ω̄|/τ_c.

    The slew asymmetry is in Coulomb decelerations, but worn bearings scale the viscous
    friction too: a factor F raises the asymmetry by 2(F − 1) times the friction at the
    slew's speeds, which at 2000 rpm is twice the Coulomb part (RW90: viscous equals
    Coulomb at 1910 rpm). Each half's acceleration is its end points' difference, so its
    friction is the mean of its end speeds' (the speed runs linearly at the limit).

    Parameters
    ----------
    segment : list of (t_s, speed_rpm, current_a)
        One slew's samples, as :func:`slew_asymmetry` takes them.
    spec : WheelSpec, optional
        The wheel model whose datasheet friction law is nominal (default the RW90's).

    Returns
    -------
    float or None
        The gain (≥ 1); None where :func:`slew_asymmetry` takes no value.
    """
    from rwlab.diagnose.reference import nominal_friction_currents

    halves = _halves(segment[1:-1])
    if min(len(h) for h in halves) < SLEW_MIN:
        return None
    viscous, coulomb = nominal_friction_currents(spec)
    mean_rpm = np.mean([(abs(h[0][1]) + abs(h[-1][1])) / 2 for h in halves])
    return float(1 + viscous * mean_rpm / coulomb)


class RestReading:
    """The speed reading where the wheel passes through zero: 0, or a telemetry bias.

    A Hall-period firmware reads 0 when no edge came within its timeout, which it
    does, for a sample now and then, each time the wheel passes through zero speed
    (a chirp does often). A bias added to the reported speed makes that reading the
    bias itself, exactly, every time; a healthy reading near zero repeats a non-zero
    value only by chance. The test counts the non-zero values read near zero speed
    (changed readings only: a frozen sensor is the stuck test's) and alarms when one
    value comes :data:`REST_COUNT` times with no 0 between and no other reading within
    :data:`REST_NEAR_RPM` of it (a repeating motion's near-equal readings). The diagnoser gives it
    readings within :data:`REST_BAND_RPM` where the model passes through zero (within
    :data:`REST_MODEL_RPM`, accelerating) or where the reading moved by
    :data:`REST_STEP_RPM` since the last sample (a wheel whose current is clamped passes
    through zero when the model does not: with the model's crossings alone, a bias with a
    0.45 A clamp on a chirp was named 385 s after its onset, with these 165–255 s): a wheel
    held at a low speed may repeat one reading by itself.

    What it needs of a real wheel: firmware that reports a fixed 0 for "no edge" (the
    twin's Hall sensor does, as Hall-period firmware does) and a bias added after that
    reading (a telemetry or scaling offset, as the twin's ``speed_sensor_bias``). A
    bias inside the sensing (an analog tachometer's offset) reads noise around the
    bias, never the same value: this test then stays silent and the held-speed and
    offset tests remain.

    Parameters
    ----------
    n : int
        How many times one non-zero value must come (default :data:`REST_COUNT`).
    """

    def __init__(self, n: int = REST_COUNT) -> None:
        self.n = int(n)
        self._counts: dict[float, int] = {}
        self.value = 0.0  # the latest counted reading, rpm
        self.statistic = 0.0
        self.readings = 0  # readings taken: what "no alarm" rests on

    def add(self, speed_rpm: float) -> bool:
        """Count one changed reading taken near zero speed; True when it alarms."""
        self.readings += 1
        if speed_rpm == 0.0:
            self.restart()
            return False
        for near in [v for v in self._counts if 0 < abs(v - speed_rpm) <= REST_NEAR_RPM]:
            del self._counts[near]  # a repeating motion's cluster, not one exact value
        self._counts[speed_rpm] = self._counts.get(speed_rpm, 0) + 1
        self.value = speed_rpm
        self.statistic = float(self._counts[speed_rpm])
        return self._counts[speed_rpm] >= self.n

    def restart(self) -> None:
        """Forget the counts (after an alarm, or a 0 reading)."""
        self._counts.clear()
        self.statistic = 0.0


class StepCharge:
    """The charge a speed change draws, from settled level to settled level.

    Where the wheel's loop closes on its true speed (the reading may be frozen or
    biased), a change of the model's speed from ω_a to ω_b, settled at both ends,
    takes the rotor from ω_a to ω_b too, so the current's integral beyond friction
    is I·(ω_b − ω_a)/k_t whatever the path: at the acceleration limit the current
    is the controller's and a weak motor takes 1/F as long, below it the loop draws
    1/F the current. Friction along the way is the reference's law at the model's
    speed, shifted to the currents measured at both settled ends (so the unit's own
    friction and sense offset cancel). The value is that charge over the reference's
    (I/k_t × Δω): 1 on the reference's unit, 1/F for a motor of k_t × F.

    "Settled": the model quiet (|α| below ``quiet_rpm_s``) for :data:`CHARGE_WINDOW_S`
    plus the longer of that and its last motion's duration (a motor as weak as
    k_t × 0.5 takes twice as long as the model). Speed changes below
    :data:`CHARGE_MIN_RPM`, or less than :data:`CHARGE_MONOTONE` of the model's path
    between the two levels, give no value.

    Parameters
    ----------
    c : array_like, shape (4,)
        The reference's current model [A per rpm/s, A per rpm, A, A].
    Ts : float
        Sample time, s.
    quiet_rpm_s : float
        The model's acceleration below which it is quiet, rpm/s.
    """

    def __init__(self, c, Ts: float, quiet_rpm_s: float) -> None:
        self.c = np.asarray(c, dtype=float)
        self.Ts = float(Ts)
        self.quiet = float(quiet_rpm_s)
        # the last CHARGE_WINDOW_S: (ω rpm, i A)
        self._window: deque = deque(maxlen=max(1, round(CHARGE_WINDOW_S / self.Ts)))
        self._segment: list[tuple[float, float]] = []  # since the last settled sample
        self._anchor: tuple[float, float] | None = None  # settled (ω rpm, i A)
        self._quiet_since: float | None = None
        self._moving_since: float | None = None
        self._motion_s = 0.0
        self._current = math.nan
        self.start_s = math.nan  # when the segment of the latest value began, s

    def add(
        self, t_s: float, model_rpm: float, model_accel_rpm_s: float, current_a: float
    ) -> float | None:
        """One sample (the model's speed and acceleration, the measured current); the
        value of the speed change it completes, if any (float, else None)."""
        if math.isfinite(current_a):
            self._current = current_a  # a lost frame: the latest current holds
        elif not math.isfinite(self._current):
            return None
        if abs(model_accel_rpm_s) < self.quiet:
            if self._quiet_since is None:
                self._quiet_since = t_s
                if self._moving_since is not None:
                    self._motion_s = t_s - self._moving_since
                self._moving_since = None
        else:
            self._quiet_since = None
            if self._moving_since is None:
                self._moving_since = t_s
        sample = (model_rpm, self._current)
        self._window.append(sample)
        wait = CHARGE_WINDOW_S + max(CHARGE_WINDOW_S, self._motion_s)
        if self._quiet_since is None or t_s - self._quiet_since < wait:
            if not self._segment:
                self.start_s = t_s
            self._segment.append(sample)
            return None
        speed, current = (float(x) for x in np.mean(self._window, axis=0))
        value = None
        if self._anchor is not None and abs(speed - self._anchor[0]) >= CHARGE_MIN_RPM:
            value = self._value(self._anchor, (speed, current))
        self._anchor, self._segment, self._motion_s = (speed, current), [], 0.0
        return value

    def _law(self, speed_rpm):
        """The reference's friction current (A) at ``speed_rpm`` (float or array)."""
        return self.c[1] * speed_rpm + self.c[2] * np.sign(speed_rpm)

    def _value(self, a: tuple[float, float], b: tuple[float, float]) -> float | None:
        speed, current = np.array(self._segment).T
        (w_a, i_a), (w_b, i_b) = a, b
        path = float(np.sum(np.abs(np.diff(speed)))) + abs(speed[0] - w_a)
        if abs(w_b - w_a) < CHARGE_MONOTONE * path:
            return None
        # the law shifted to the measured settled currents at both ends
        d_a, d_b = i_a - self._law(w_a), i_b - self._law(w_b)
        friction = self._law(speed) + d_a + (d_b - d_a) * (speed - w_a) / (w_b - w_a)
        charge = float(np.sum(current - friction)) * self.Ts
        return charge / (self.c[0] * (w_b - w_a))
