"""Isolation and sizing: which fault explains an alarm, and how large it is.

Evidence (:meth:`rwlab.diagnose.Diagnoser._evidence`): each block test's block
means since its statistic last left zero (the change's estimated start), the
reference's σ of a block mean and the tolerance between healthy units, the
recent speed readings, the currents while the wheel lagged its model, the lost
frames of the last dropout block.

==========  ================================================  ======================
detector    signature                                         fault, size (unit)
==========  ================================================  ======================
dropout     telemetry frames lost beyond the healthy rate     ``telemetry_dropout``,
                                                              frames in 10 s
stuck       identical speed readings, longer than noise       ``speed_sensor_stuck``,
            allows (also: a repeat while the model moves      the frozen reading (rpm)
            when another test fires)
friction,   current in excess under acceleration (motor       ``torque_constant``,
motor       test beyond its tolerance, or the motor test's     k_t factor 1/(1 + e_α)
            own alarm): a weak motor needs 1/F the current
            for everything
friction    excess only at constant speed, beyond what a      ``friction``, factor
            weak motor named before explains                  (1 + e_ω)/(1 + e_α)
hold        the held current above this record's own at the   ``friction``, 1 + v
            same (or mirror) speed, no motor excess           (``torque_constant``
                                                              with a motor excess)
speed       held speed offset from the command                ``speed_sensor_bias``,
                                                              rpm
offset      offset of the speed residual at zero speed,       ``speed_sensor_bias``,
            continuous command                                rpm
rest        one non-zero reading, exactly, where the wheel    ``speed_sensor_bias``,
            passes through zero speed (healthy: 0)            that reading (rpm)
slew        at the acceleration limit: faster towards zero    ``friction``, factor
            speed than away (unknown friction)                1 + Δ/(2g)
clamped     a clamped slew's friction deceleration over the   ``friction``, factor
            unit's own friction before the first one          1 + median excess
lag         slower than the model at its acceleration limit   ``current_limit``: the
            with a healthy motor test                         current it flattens at (A);
                                                              with the motor test in
                                                              excess: ``torque_constant``
==========  ================================================  ======================

Why: the torque balance k_t·i = I·α + friction(ω) holds whatever the wheel's
controller does, so with the nominal balance î = î_α + î_ω the relative
excesses are e_α = 1/F_k − 1 (under acceleration) and e_ω = F_f/F_k − 1 (at
constant speed). Two faults at once are both named when both are significant
(a weak motor and worn bearings), or by their own detectors (a sensor fault and
a rotor fault). Confidence intervals are 95 %: the block means' σ on the healthy
reference (noise), and model uncertainty where the size rests on a model: a
friction-change size on the posterior σ of the record's own friction law, an
absolute friction or a torque-constant size (against the reference's unit) on
the spread between healthy units (:data:`FRICTION_UNIT_SD`, :data:`MOTOR_UNIT_SD`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypedDict

import numpy as np
from scipy.stats import chi2

from rwlab.diagnose.constants import measured
from rwlab.diagnose.motion import REST_BAND_RPM

__all__ = ["BlockName", "Evidence", "Finding", "combine", "isolate"]

Z95 = 1.959964
# σ of the friction ratio between two healthy units: viscous and Coulomb each uniform
# within ±30 % (rwlab.wheel.imperfections.TOLERANCES), so σ = √2·0.3/√3 ≈ 0.245 relative. A
# size from the absolute friction test is against the reference's unit; its interval holds
# this spread as model uncertainty (a friction-change size is against the unit itself).
FRICTION_UNIT_SD = math.sqrt(2) * 0.3 / math.sqrt(3)
# ... and of the inertial current I/k_t between two units: I ±2 %, k_t ±5 %, uniform
MOTOR_UNIT_SD = math.sqrt(2 * (0.02**2 + 0.05**2) / 3)
# σ of the held-speed error between two healthy units (Hall reading at a hold), rpm
SPEED_UNIT_SD = measured("SPEED_UNIT_SD")
# σ of the offset test's record-mean between healthy units beyond its windows' noise
# (the model's mismatch with a unit persists over a record), rpm
OFFSET_UNIT_SD_RPM = measured("OFFSET_UNIT_SD_RPM")
CURRENT_OFFSET_SD_A = 0.005 / math.sqrt(3)  # a unit's current-sense offset, ±5 mA uniform
SLEW_SCALE_SD = 0.25  # relative σ of the slew asymmetry's scale to 2(F − 1)
SLEW_OWN_MIN = 4  # slews before a change that give the unit's own healthy level
# ... which moves along one profile (a default chirp's later, shorter slews read lower
# than its earlier ones), so a level from the earlier slews sizes a later change low
SLEW_PROFILE_SD = measured("SLEW_PROFILE_SD")
REST_RPM = 0.1  # the no-edge reading is the bias to the telemetry's quantum (RW90: 0.1 rpm)
LAG_EXCESS_MIN = 3  # current-balance samples at the limit that tell a weak motor from a clamp
LAG_SPLIT = 0.1  # excess under acceleration between a clamp's 0 and a k_t × 0.8's 0.25
# the current at the limit over the unit's own before the change: a clamp lowers it, a
# weak motor leaves it (the controller's open-loop current); a clamp above this share of
# the unit's own current at its acceleration limit is then named a weak motor
CLAMP_RATIO = measured("CLAMP_RATIO")
# the clamped test's values on healthy units: their scatter within a record, and the
# records' medians, which sit below 0: the clamped slews read the unit's friction lower
# than its slow samples before, by an amount that varies between units (why is not
# measured; the twin's viscous friction falls as it warms)
CLAMP_SLEW_SD = measured("CLAMP_SLEW_SD")
CLAMP_LEVEL_SD = measured("CLAMP_LEVEL_SD")
CHARGE_SD = measured("CHARGE_SD")  # σ of one speed change's charge over the unit's own level
LAG_BEFORE_MIN = 20  # samples at the limit before the change that give the unit's own current


# the tests whose single values since their change isolation reads, by name
BlockName = Literal["friction", "motor", "speed", "lag", "offset", "slew"]


class Evidence(TypedDict, total=False):
    """What isolation reads (:meth:`rwlab.diagnose.Diagnoser._evidence` gathers it); each
    key only where the record has it.

    Attributes
    ----------
    friction, motor, speed, lag, offset, slew : ndarray, shape (n,)
        Each test's single values since its statistic last left zero (the test's unit).
    friction_model_sd : float
        σ of the baseline friction law's prediction (a friction-change alarm), relative.
    sigma, ref_mean, tolerance : dict of str to float
        Per test: σ of one value, the reference's mean, the tolerance between units.
    slew_gain : ndarray, shape (n,)
        Each slew value's friction at its speeds over the Coulomb friction.
    slew_before : ndarray, shape (m,)
        The record's slew values before the change (the unit's own level).
    motor_before, motor_after : ndarray
        The motor test's values before and after the lag test's change.
    recent_speed : ndarray, shape (8,)
        The latest speed readings, rpm.
    held_command_rpm : float
        The command held now, rpm.
    moving_repeats : float
        The current run of identical readings while moving (inf after a stuck alarm).
    lag_currents, lag_currents_before : ndarray
        |current| at the acceleration limit since and before the lag change, A.
    lag_excess : ndarray
        The motor test's value at the limit since the lag change.
    lost : int
        Frames lost in the last dropout block.
    hold : ndarray, shape (n, 3)
        The hold test's (v, σ of v, σ common to all blocks) since its change.
    torque_constant : (float, (float, float))
        A weak motor named before: k_t factor and its 95 % interval.
    rest_value : float
        The latest counted reading near zero speed, rpm.
    clamped : (ndarray, float)
        The clamped slews' excesses and the own friction law's relative σ.
    charge : (ndarray, int)
        Speed changes' charge over the unit's own level, and how many own values it rests on.
    """

    friction: np.ndarray
    motor: np.ndarray
    speed: np.ndarray
    lag: np.ndarray
    offset: np.ndarray
    slew: np.ndarray
    friction_model_sd: float
    sigma: dict[str, float]
    ref_mean: dict[str, float]
    tolerance: dict[str, float]
    slew_gain: np.ndarray
    slew_before: np.ndarray
    motor_before: np.ndarray
    motor_after: np.ndarray
    recent_speed: np.ndarray
    held_command_rpm: float
    moving_repeats: float
    lag_currents: np.ndarray
    lag_currents_before: np.ndarray
    lag_excess: np.ndarray
    lost: int
    hold: np.ndarray
    torque_constant: tuple[float, tuple[float, float]]
    rest_value: float
    clamped: tuple[np.ndarray, float]
    charge: tuple[np.ndarray, int]


@dataclass(frozen=True)
class Finding:
    """A named fault with its estimated size and 95 % confidence interval.

    Parameters
    ----------
    kind : str
        The fault's name.
    magnitude : float or None
        Its estimated size, in ``unit``.
    ci : (float, float) or None
        95 % confidence interval of the size.
    unit : str
        The size's unit.
    """

    kind: str
    magnitude: float | None
    ci: tuple[float, float] | None
    unit: str


def _median_se(sd: float, n: float) -> float:
    """Standard error of the median of ``n`` values of σ ``sd`` (√(π/2) that of the mean,
    for normal values)."""
    return 1.2533 * sd / math.sqrt(n)


def _mean_ci(x: np.ndarray, sigma: float) -> tuple[float, float]:
    """Mean of block means and its half-width at 95 %."""
    return float(np.mean(x)), Z95 * sigma / math.sqrt(len(x))


def _motor(ev: Evidence) -> tuple[float, float] | None:
    if len(ev.get("motor", ())) == 0:
        return None
    return _mean_ci(ev["motor"], ev["sigma"]["motor"])


def _torque_constant(e: float, half: float) -> Finding:
    half = math.hypot(half, Z95 * MOTOR_UNIT_SD * (1 + e))  # against the reference's unit
    lo, hi = 1 / (1 + e + half), 1 / max(1 + e - half, 1e-9)
    return Finding("torque_constant", 1 / (1 + e), (lo, hi), "factor")


def _rotor(ev: Evidence, detector: str) -> list[Finding]:
    """Friction, weak motor, or both, from the friction and motor tests' excesses.

    The motor test's own alarm is the weak motor's signature (the current under
    acceleration, which friction hardly moves): where its interval does not yet clear the
    tolerance and no friction excess is there, it names the weak motor, sized, not an
    unsized friction as well (a k_t × 0.9 on a chirp was named both)."""
    motor = _motor(ev)
    weak = motor is not None and motor[0] - motor[1] > ev["tolerance"].get("motor", 0.0)
    findings = []
    if weak:
        findings.append(_torque_constant(*motor))  # type: ignore[misc]
    if len(ev.get("friction", ())):
        e_f, half_f = _mean_ci(ev["friction"], ev["sigma"]["friction"])
        # model uncertainty: the baseline friction law's (a friction-change alarm)
        half_f = math.hypot(half_f, Z95 * ev.get("friction_model_sd", 0.0))
        e_a, half_a = motor if weak else (0.0, 0.0)  # type: ignore[misc]
        named = "torque_constant" in ev and not weak
        if named:  # a weak motor named before raises the constant-speed current by 1/F_k
            k, (k_lo, k_hi) = ev["torque_constant"]
            e_a, half_a = 1 / k - 1, (1 / k_lo - 1 / k_hi) / 2
        factor = (1 + e_f) / (1 + e_a)
        rel = math.hypot(half_f / (1 + e_f), half_a / (1 + e_a))
        beyond = factor * (1 - rel) > 1 + ev["tolerance"].get("friction", 0.0)
        if named and not beyond:  # the excess is the weak motor's
            k, ci = ev["torque_constant"]
            return [Finding("torque_constant", k, ci, "factor")]
        if not weak or beyond:
            if "friction_model_sd" not in ev:  # sized against the reference's unit
                rel = math.hypot(rel, Z95 * FRICTION_UNIT_SD)
            findings.append(
                Finding("friction", factor, (factor * (1 - rel), factor * (1 + rel)), "factor")
            )
    if not findings and detector == "motor" and motor is not None:
        return [_torque_constant(*motor)]
    return findings or [Finding("friction", None, None, "factor")]


def _slew(ev: Evidence) -> Finding:
    """A slew faster towards zero speed than away from it: friction beyond the
    feed-forward's, F ≈ 1 + Δ/(2g) (Δ in Coulomb decelerations over the reference's level,
    g the nominal friction at the slews' speeds over the Coulomb friction: worn bearings
    scale the viscous part too); a weak motor (the motor test in excess) slews slower
    both ways."""
    motor = _motor(ev)
    if motor is not None and motor[0] - motor[1] > ev["tolerance"].get("motor", 0.0):
        return _torque_constant(*motor)
    e, half = _mean_ci(ev["slew"], ev["sigma"]["slew"])
    before = np.asarray(ev.get("slew_before", ()), dtype=float)
    if before.size >= SLEW_OWN_MIN:  # the unit's own healthy level on this record's profile
        level, level_half = _mean_ci(before, ev["sigma"]["slew"])
        level_half = math.hypot(level_half, Z95 * SLEW_PROFILE_SD)
    else:  # the reference unit's, which a profile moves by up to the tolerance
        level, level_half = ev["ref_mean"]["slew"], Z95 * ev["tolerance"].get("slew", 0.0)
    e -= level
    gain = float(np.mean(ev.get("slew_gain", [1.0])))
    # model uncertainty: the healthy level's, and the factor's scale (the unit's friction
    # against the nominal, its temperature)
    half = math.hypot(half, level_half, Z95 * SLEW_SCALE_SD * e)
    scale = 2 * gain
    return Finding(
        "friction", 1 + e / scale, (1 + (e - half) / scale, 1 + (e + half) / scale), "factor"
    )


def _clamped(values: np.ndarray, law_sd: float) -> Finding:
    """Friction from clamped slews: 1 + the median excess over the unit's own friction.
    The interval holds the median's noise (σ of a slew's value at least
    :data:`CLAMP_SLEW_SD`: two slews say little of their own scatter), the healthy level's
    spread between units (:data:`CLAMP_LEVEL_SD`), the own law's σ and the unit's I/k_t
    (the reference's converts the deceleration into a current)."""
    mid = float(np.median(values))
    sd = max(float(np.std(values, ddof=1)) if len(values) > 1 else 0.0, CLAMP_SLEW_SD)
    se = _median_se(sd, len(values))
    half = Z95 * math.hypot(se, CLAMP_LEVEL_SD, (1 + mid) * law_sd, (1 + mid) * MOTOR_UNIT_SD)
    return Finding("friction", 1 + mid, (1 + mid - half, 1 + mid + half), "factor")


def _charge(values: np.ndarray, own: int) -> Finding:
    """A weak motor from speed changes' charge after a frozen reading: 1/F over the
    unit's own level before (σ :data:`CHARGE_SD` a value; the median of ``own`` values),
    or over the reference's (then the spread of I/k_t between units instead)."""
    mid = float(np.median(values))
    level_sd = _median_se(CHARGE_SD, own) if own else MOTOR_UNIT_SD
    half = Z95 * math.hypot(_median_se(CHARGE_SD, len(values)), level_sd)
    ci = (1 / (mid * (1 + half)), 1 / (mid * (1 - half)))
    return Finding("torque_constant", 1 / mid, ci, "factor")


def _hold(ev: Evidence) -> Finding:
    """The current's rise at a held speed over this record's own earlier current there:
    a weak motor when the motor test is in excess since (1/F_k − 1 under acceleration
    too), or when a weak motor named before explains it; else friction, F ≈ 1 + v (v
    relative to the unit's own friction current there; what every block shares — the
    baseline's offset, drift, the mirror speed's asymmetry — does not average out)."""
    motor = _motor(ev)
    if motor is not None and motor[0] - motor[1] > ev["tolerance"].get("motor", 0.0):
        return _torque_constant(*motor)
    rows = np.asarray(ev["hold"], dtype=float).reshape(-1, 3)
    weight = 1 / rows[:, 1] ** 2
    e = float(np.sum(weight * rows[:, 0]) / np.sum(weight))
    half = Z95 * math.hypot(1 / math.sqrt(float(np.sum(weight))), float(rows[:, 2].mean()))
    factor, lo, hi = 1 + e, 1 + e - half, 1 + e + half
    if "torque_constant" in ev:  # the current rises by 1/F_k with a weak motor alone
        k, (k_lo, k_hi) = ev["torque_constant"]
        if lo * k_lo <= 1 <= hi * k_hi:
            return Finding("torque_constant", k, (k_lo, k_hi), "factor")
        factor, lo, hi = factor * k, lo * k_lo, hi * k_hi
    return Finding("friction", factor, (lo, hi), "factor")


def isolate(detector: str, ev: Evidence) -> list[Finding]:
    """The faults that explain an alarm of ``detector``, sized.

    Parameters
    ----------
    detector : {'dropout', 'stuck', 'rest', 'friction', 'friction_change', 'hold', 'motor',
        'speed', 'offset', 'slew', 'lag'}
    ev : Evidence
        The evidence (see the module docstring).

    Returns
    -------
    list of Finding
        One, or two when two faults act.
    """
    speed = np.asarray(ev.get("recent_speed", ()), dtype=float)
    if detector == "charge":  # read with the reading frozen: no stuck finding again
        return [_charge(*ev["charge"])]
    if detector == "dropout":
        return [Finding("telemetry_dropout", float(ev.get("lost", 0)), None, "frames")]
    if detector == "rest":  # the no-edge reading at zero speed: the bias itself
        bias = float(ev["rest_value"])
        return [Finding("speed_sensor_bias", bias, (bias - REST_RPM, bias + REST_RPM), "rpm")]
    # identical readings while the model says the wheel moves (in a hold a regulated
    # wheel's reading repeats by itself)
    frozen = ev.get("moving_repeats", 0) >= 1  # healthy: p ≈ 1e-3 per moving sample
    if detector == "stuck" or frozen:
        return [
            Finding("speed_sensor_stuck", float(speed[-1]) if len(speed) else None, None, "rpm")
        ]
    if detector in ("friction", "friction_change", "motor"):
        return _rotor(ev, detector)
    if detector in ("slew", "slew_change"):
        return [_slew(ev)]
    if detector == "clamped":
        return [_clamped(*ev["clamped"])]
    if detector == "hold":
        return [_hold(ev)]
    if detector == "offset":  # the speed residual's offset on a continuous command
        bias, half = _mean_ci(ev["offset"], ev["sigma"]["offset"])
        half = math.hypot(half, Z95 * OFFSET_UNIT_SD_RPM)
        return [Finding("speed_sensor_bias", bias, (bias - half, bias + half), "rpm")]
    if detector == "speed":
        held = np.asarray(ev["speed"], dtype=float)
        if held.size >= 5 and np.ptp(held) == 0:  # one reading, over and over: not noise
            value = float(held[-1])
            if ev.get("held_command_rpm") == 0.0 and 0 < abs(value) <= REST_BAND_RPM:
                # ... but a wheel resting at 0 rpm reads exactly 0 (no Hall edge comes):
                # one small non-zero reading there is an offset on the report, the bias
                return [
                    Finding("speed_sensor_bias", value, (value - REST_RPM, value + REST_RPM), "rpm")
                ]
            return [Finding("speed_sensor_stuck", float(speed[-1]), None, "rpm")]
        bias, half = _mean_ci(ev["speed"], ev["sigma"]["speed"])
        bias -= ev.get("ref_mean", {}).get("speed", 0.0)  # the reference unit's held error
        half = math.hypot(half, Z95 * SPEED_UNIT_SD)  # ... which is not this unit's
        return [Finding("speed_sensor_bias", bias, (bias - half, bias + half), "rpm")]
    # lag: a reading that does not change at all while the model runs at its acceleration
    # limit is a frozen sensor (a clamped or weak wheel still moves; one resting at 0 rpm
    # on the full current for seconds is no wheel), also at 0 rpm, where repeats count not
    if speed.size >= 5 and np.ptp(speed) == 0:
        return [Finding("speed_sensor_stuck", float(speed[-1]), None, "rpm")]
    # the current balance holds at the limit too: a weak motor draws 1/F the current the
    # achieved acceleration needs (e_α = 1/F − 1), a lowered clamp exactly that current
    excess = np.asarray(ev.get("lag_excess", ()), dtype=float)
    excess = excess[np.isfinite(excess)]
    currents = np.asarray(ev.get("lag_currents", ()), dtype=float)
    currents = currents[np.isfinite(currents)]
    own = np.asarray(ev.get("lag_currents_before", ()), dtype=float)
    own = own[np.isfinite(own)]
    # this unit's own current at the limit before the change: a clamp lowers it, a weak
    # motor leaves it (the controller's open-loop current) and only slows the wheel; a
    # clamp's current excess is then worn bearings on top, not a weak motor
    known = own.size >= LAG_BEFORE_MIN and currents.size > 0
    clamped = known and bool(np.median(currents) < CLAMP_RATIO * np.median(own))
    if excess.size >= LAG_EXCESS_MIN and not clamped:
        e = float(np.median(excess)) - ev["ref_mean"]["motor"]
        half = _mean_ci(excess, ev["sigma"]["motor"])[1]
        weak = _torque_constant(e / (1 + ev["ref_mean"]["motor"]), half)
        # without the unit's own level, only an excess whose interval excludes 1: a
        # clamp's onset can read one
        if known or (e > LAG_SPLIT and weak.ci is not None and weak.ci[1] < 1):
            return [weak]
    after = np.asarray(ev.get("motor_after", ()), dtype=float)
    before = np.asarray(ev.get("motor_before", ()), dtype=float)
    if (
        after.size and excess.size < LAG_EXCESS_MIN and not clamped
    ):  # weak motor (e_α rises by 1/F − 1) or a clamp (e_α unchanged)
        base = float(np.mean(before)) if before.size else ev["ref_mean"]["motor"]
        e, half = float(np.median(after)), _mean_ci(after, ev["sigma"]["motor"])[1]
        if e - base > LAG_SPLIT:  # sized against this record's healthy start where it has one
            return [_torque_constant((1 + e) / (1 + base) - 1, half)]
    if currents.size == 0:
        return [Finding("current_limit", None, None, "A")]
    # the clamp: the median current at the limit; its interval, not the currents' spread:
    # the median's standard error (consecutive samples: half as many independent) and the
    # unit's current-sense offset, which every measured current carries
    mid = float(np.median(currents))
    spread = 1.4826 * float(np.median(np.abs(currents - mid)))
    se = _median_se(spread, max(currents.size / 2, 1))
    half = Z95 * math.hypot(se, CURRENT_OFFSET_SD_A)
    return [Finding("current_limit", mid, (mid - half, mid + half), "A")]


def combine(findings: list[Finding]) -> dict:
    """One size of a fault from the sizes several tests gave it.

    Each test sizes a fault on its own evidence (the slew test on the accelerations at the
    limit, the friction test on the current at constant speed, ...), so the sizes are
    independent estimates: their inverse-variance mean (σ from each 95 % interval), over
    those consistent with it: while the sizes' χ² about the mean exceeds its 95 % point,
    the one farthest from the mean (in its own σ) is left out (an interval that misses the
    others is a test whose model does not hold on this record).

    Parameters
    ----------
    findings : list of Finding
        Sizes of one fault, in time order; those without a size or interval are not
        combined (the first such size stands when no other has one).

    Returns
    -------
    dict
        ``magnitude``, ``ci95`` (95 %, or None), ``unit``, ``used`` and ``left_out`` (the
        indices into ``findings`` of the sizes combined and of those left out).
    """
    sized = [i for i, f in enumerate(findings) if f.magnitude is not None and f.ci is not None]
    if not sized:
        first = next((i for i, f in enumerate(findings) if f.magnitude is not None), None)
        f = findings[first] if first is not None else findings[0]
        used = [] if first is None else [first]
        return {
            "magnitude": f.magnitude,
            "ci95": None,
            "unit": f.unit,
            "used": used,
            "left_out": [],
        }
    x = np.array([findings[i].magnitude for i in sized], dtype=float)
    cis = [findings[i].ci or (0.0, 0.0) for i in sized]  # every one has an interval
    sd = np.array([(hi - lo) / (2 * Z95) for lo, hi in cis])
    sd = np.maximum(sd, 1e-12 * np.maximum(np.abs(x), 1.0))
    keep = np.ones(len(sized), dtype=bool)
    while True:
        w = keep / sd**2
        mean = float(np.sum(w * x) / np.sum(w))
        z = np.where(keep, np.abs(x - mean) / sd, -np.inf)
        if keep.sum() <= 1 or float(np.sum(z[keep] ** 2)) <= chi2.ppf(0.95, keep.sum() - 1):
            break
        keep[int(np.argmax(z))] = False
    half = Z95 / math.sqrt(float(np.sum(w)))
    return {
        "magnitude": mean,
        "ci95": (mean - half, mean + half),
        "unit": findings[sized[0]].unit,
        "used": [i for i, k in zip(sized, keep, strict=True) if k],
        "left_out": [i for i, k in zip(sized, keep, strict=True) if not k],
    }
