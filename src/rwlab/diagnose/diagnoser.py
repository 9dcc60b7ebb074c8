"""The fault detector: every sample against the healthy reference of the identification.

One :class:`Diagnoser` serves both uses: ``rwlab diagnose`` feeds it a
record's samples in a loop (:func:`diagnose`), and the experiment runner feeds
it each sample as it arrives, so offline and live alarms are the same. It is
calibrated by the :class:`~rwlab.diagnose.reference.HealthyReference` that
``rwlab identify`` stored with the model (:func:`healthy_reference` measures
one), never by the record under test: a fault present at power-up is a fault.

Each sample (Ts) gives, where it qualifies, a value to each block test:

=========  ==============================================  =====================  ==========
test       qualifies                                       value                  alarms on
=========  ==============================================  =====================  ==========
friction   constant speed (|α| < 10 rpm/s), |ω| ≥ 500 rpm  relative excess of     increase
                                                           current over the
                                                           friction current
motor      sustained acceleration, |I·α/k_t| ≥ 0.1 A       relative excess of     increase
                                                           current over the
                                                           inertial current
speed      command held ≥ 30 s, wheel and model quiet      speed − command, rpm   either way
           (|α| < 10 rpm/s) ≥ 10 s
lag        model at ≥ 80 % of its acceleration limit       (α − α_model)/α_lim    decrease
offset     a 60-s window of a continuously changing        the speed residual's   either way
           command whose model speed swings through zero   intercept, rpm
slew       a slew at the acceleration limit through zero   towards-zero minus     increase
           speed                                           away-from-zero rate
=========  ==============================================  =====================  ==========

``clamped`` (:class:`~rwlab.diagnose.blocktests.ClampedFriction`) reads worn bearings
behind a lowered current clamp: there the current is the same on both halves of a slew
through zero, so the rates' difference is the whole friction, which it compares with
the unit's own friction current before the first clamped slew (the slew test reads only
the excess over the controller's feed-forward, which a clamp removes). ``charge``
(:class:`~rwlab.diagnose.blocktests.FrozenMotor`) reads a weak motor after a stuck
alarm: the wheel's loop still closes on its true speed, so a settled speed change draws
the charge I·Δω/k_t (:class:`~rwlab.diagnose.motion.StepCharge`), 1/F of the unit's own
before the freeze for k_t × F.

The offset and slew tests (:func:`~rwlab.diagnose.motion.speed_offset`,
:func:`~rwlab.diagnose.motion.slew_asymmetry`) see a biased sensor and worn bearings
where the wheel never holds a speed (a chirp): the speed residual's offset at zero
speed is no model mismatch, and at its limit the wheel's controller sets the current
open loop, so friction it does not know shows in the slew's acceleration.

``friction_change`` compares the friction test's samples at ≥ 1500 rpm with the
unit's own friction law (viscous, Coulomb and current offset over the
reference's; ridge least squares on the record's samples older than 300 s), at
speeds those samples span at that sign (the law interpolates, never extrapolates):
a friction rise smaller than the spread between units, when it starts within the
record. ``slew_change`` (:class:`~rwlab.diagnose.blocktests.SlewChange`) compares
each slew's asymmetry with the record's own slews a minute old or more: friction ×1.5
on a chirp, whose short slews read below the reference's PRBS level and come only
for about three minutes. ``hold`` (:class:`HoldChange`) compares the current at a held
command with this record's own first settled samples there, or with the mirror
command's level (friction is even in speed; the sense offset from the rest before
the first motion): friction ×1.5 on steps, named once the motor test has seen an
acceleration since (a weak motor raises the held current too). A lag alarm is
named by the current balance on the lag samples: a weak motor draws 1/F the
current the achieved acceleration needs, a lowered clamp exactly that current.

Friction raises the current at constant speed and not under acceleration; a
weak motor (k_t × F) raises both by 1/F (so ``motor`` separates them); a
lowered current limit slows large speed changes with a healthy current
balance (``lag`` without ``motor``); a biased sensor shifts the held speed.

A block test averages ``block`` qualifying values, standardises the mean by
the reference's mean and σ, and runs a one-sided CUSUM (two for ``speed``)
whose reference value is 0.5 σ plus the tolerance between healthy units; its
threshold is the one whose false-alarm rate, measured on healthy records of
other units, is the requested one (:mod:`~rwlab.diagnose.calibration`; a rate
the full tolerance cannot deliver keeps less of it, and a rate no setting
delivers is a warning), Siegmund's approximation (:mod:`detect`) where the
calibration cannot say. Two
sample tests complete the set: ``stuck`` (a run of identical non-zero speed
readings, length from the reference's repeat probability) and ``dropout``
(telemetry frames lost in a 10 s block beyond what the bus's loss rate allows,
Poisson: the reference record's rate where it lost more than chance, else the
calibration's); a third, ``rest``
(:class:`~rwlab.diagnose.motion.RestReading`), reads a telemetry bias in the
reading where the wheel passes through zero speed. Samples without a new frame,
and the one after them, enter no test. A detector alarms once and stays latched
(``latch=False`` restarts it, for measuring false-alarm rates).

The block tests' own state lives in :mod:`~rwlab.diagnose.blocktests`; a record's run
and its result (:func:`~rwlab.diagnose.diagnosis.diagnose`,
:class:`~rwlab.diagnose.diagnosis.Diagnosis`) in :mod:`~rwlab.diagnose.diagnosis`. This
Why this module is long: one class, :class:`Diagnoser`, whose calibration, per-sample
tests and verdicts share its state.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.stats import poisson

from rwlab.diagnose.blocktests import (
    CLAMP_EXCESS,
    CLAMP_QUIET_RPM_S,
    CUSUM_K,
    HISTORY_S,
    BlockCusum,
    ClampedFriction,
    Dropout,
    FrictionChange,
    FrozenMotor,
    HoldChange,
    SlewChange,
    steady,
)
from rwlab.diagnose.calibration import (
    RESOLVED,
    ThresholdCalibration,
)
from rwlab.diagnose.detect import RunTest, arl_to_samples, cusum_threshold, run_length
from rwlab.diagnose.isolate import (
    SPEED_UNIT_SD,
    Z95,
    BlockName,
    Evidence,
    isolate,
)
from rwlab.diagnose.motion import (
    CLAMP_SHARE,
    OFFSET_SIGMA_RPM,
    OFFSET_WINDOW,
    REST_BAND_RPM,
    REST_MODEL_RPM,
    REST_STEP_RPM,
    SLEW_SHARE,
    SLEW_SIGMA,
    RestReading,
    Slews,
    StepCharge,
    clamped_deceleration,
    slew_asymmetry,
    slew_friction_gain,
    speed_offset,
)
from rwlab.diagnose.reference import (
    DEFAULT_TOLERANCE,
    BlockStats,
    HealthyReference,
    nominal_friction_currents,
    nominal_inertial_current,
    unit_bounds,
)
from rwlab.diagnose.residuals import ResidualGenerator
from rwlab.errors import ConfigError, RwlabWarning
from rwlab.wheelspec import WheelSpec

__all__ = ["Alarm", "Diagnoser"]

QUIET_RPM_S = 10.0  # "constant speed": |measured acceleration| below ≈ 7 σ of its noise at 0.5 s
STILL_SPAN_S = 2.0  # the wheel's quiet for the speed test: its mean acceleration over this
FRICTION_MIN_RPM = 500.0  # the friction current is large enough to compare relative to it
OFFSET_MIN_SAMPLES = 10  # friction samples of each sign before the current offset counts
MOTOR_MIN_NOISE = 25.0  # the inertial current is large enough to compare relative to it:
# this many σ of the wheel's current noise (its spec's), so the motor value's noise is ≤ 4 %
LAG_SHARE = 0.8  # the model runs at ≥ this share of its acceleration limit
LAG_MIN_RPM = 50.0  # ... and at least this fast (a Hall reading near zero is no rate), rpm
SETTLE_S = 30.0  # a command held this long: wheel and model settled, s
STILL_S = 10.0  # ... and both quiet (|α| < QUIET_RPM_S) this long: a step of 12000 rpm at the
# acceleration limit outlasts any fixed hold time, s
STILL_RPM = 50.0  # below this the wheel may rest in stiction while the model turns, rpm
HELD_MAX_SHARE = 5 / 6  # held speeds any unit reaches: this share of the lower of the
# wheel's speed limit and its no-load back-EMF speed (the driver's largest duty over k_t),
# where the loop keeps room to reject a unit's friction and drift
BLOCKS = {"friction": 20, "motor": 10, "speed": 20, "lag": 10}
# every CUSUM test, in the order a report shows them (stat_NAME in the history)
CUSUM_TESTS = (*BLOCKS, "friction_change", "hold", "offset", "slew", "slew_change")
# what each test decides on (Diagnoser.coverage); the model-based tests are all but the
# last three, which read the telemetry alone
DECIDES_ON = {
    **{name: "blocks" for name in (*BLOCKS, "friction_change", "hold")},
    "offset": "60-s windows",
    "slew": "slews",
    "slew_change": "slews",
    "rest": "readings near 0 rpm",
    "clamped": "clamped slews",
    "charge": "speed changes after a frozen reading",
    "stuck": "moving samples",
    "dropout": "10-s blocks",
}
ROTOR_FAULTS = ("friction", "torque_constant", "current_limit")
# the tests whose values since their change isolation reads
EVIDENCE_BLOCKS: tuple[BlockName, ...] = ("friction", "motor", "speed", "lag", "offset", "slew")
LOAD_SETTLE_S = 30.0  # a held-speed error the loop rejects (a load step) is gone by then, s
DROPOUT_BLOCK_S = 10.0


@dataclass(frozen=True)
class Alarm:
    """One alarm: when, which fault, how large, which detector fired.

    Parameters
    ----------
    t_s : float
        Sample time of the alarm, s.
    kind : str
        The fault named (:data:`rwlab.wheel.faults.FAULTS`).
    statistic, threshold : float
        The detector's statistic and threshold when it fired.
    detector : str
    magnitude : float or None
        The fault's estimated size in ``unit`` (factor, A, rpm, frames).
    ci : tuple of 2 float or None
        Its 95 % confidence interval.
    unit : str
    """

    t_s: float
    kind: str
    statistic: float
    detector: str
    threshold: float
    magnitude: float | None = None
    ci: tuple[float, float] | None = None
    unit: str = ""

    def to_dict(self) -> dict:
        return {
            "t_s": self.t_s,
            "kind": self.kind,
            "statistic": self.statistic,
            "detector": self.detector,
            "threshold": self.threshold,
            "magnitude": self.magnitude,
            "ci95": None if self.ci is None else list(self.ci),
            "unit": self.unit,
        }


class SpeedModel(Protocol):
    """What the diagnoser runs beside the telemetry: an identified wheel
    (:class:`~rwlab.wheel.IdentifiedWheel`) or a stand-in with its sample time, its
    acceleration limit, ``reset`` and ``step``."""

    @property
    def Ts(self) -> float: ...

    @property
    def accel_limit_rpm_s(self) -> float: ...

    def reset(self, speed_rpm: float) -> None: ...

    def step(self, command_rpm: float) -> float: ...


class _ChangeValues(FrictionChange):
    """The friction-change test's values, collected and never tested (measuring a
    reference: the values after its baseline go to ``values``)."""

    def __init__(self, values: list[float], spec: WheelSpec) -> None:
        probe = BlockStats(0.0, 1.0, BLOCKS["friction"], 1.0, 0, "")
        super().__init__(probe, 0.0, math.inf, 6, (0.0,) * 4, spec=spec)
        self.values = values

    def add(self, t_s: float, value: float, allowance: float = 0.0) -> bool:
        self.values.append(value)
        return False


@dataclass
class _Sample:
    """What one sample gives the tests."""

    values: dict[str, float] = field(default_factory=dict)
    usable: bool = False


class Diagnoser:
    """Residuals, detectors and isolation, fed one sample at a time.

    Parameters
    ----------
    wheel : IdentifiedWheel
        The identified model; the samples come at its Ts. Its ``wheel_spec`` (the
        wheel model ``model.json`` names) gives the nominal friction, inertia, current
        noise, speed limits and the tolerances between units the tests are scaled by;
        a model without one (a version-1 ``model.json``) is judged by the RW90's.
    reference : HealthyReference or None
        The healthy reference (``model.json``'s); None only to measure one
        (:func:`healthy_reference`): then nothing is tested.
    false_alarms_per_hour : float
        Wanted false-alarm rate of each detector on healthy records (sets the thresholds).
    latch : bool
        A detector alarms once (True), or restarts after each alarm (False: for
        counting false alarms).
    calibration : ThresholdCalibration or bool
        Where the thresholds come from: True, the package's calibration (false
        alarms measured on healthy records of other units of the twin,
        :mod:`~rwlab.diagnose.calibration`) where it matches the model; False,
        the analytic approximations alone; or a calibration of one's own.
    trace : bool
        Keep every block's standardised mean, the runs of repeated readings and
        the lost frames per block (for measuring a calibration).

    Warns
    -----
    RwlabWarning
        A detector cannot deliver the requested rate (within a factor 2); the
        reasons are kept in ``notes``.
    """

    def __init__(
        self,
        wheel: SpeedModel,
        reference: HealthyReference | None,
        *,
        false_alarms_per_hour: float = 1e-3,
        latch: bool = True,
        calibration: ThresholdCalibration | bool = True,
        trace: bool = False,
    ) -> None:
        self.Ts = float(wheel.Ts)
        self.accel_limit = float(wheel.accel_limit_rpm_s)
        self.reference = reference
        spec = getattr(wheel, "wheel_spec", None)
        self.spec: WheelSpec = spec if spec is not None else WheelSpec.load("rw90")
        self.bounds = unit_bounds(self.spec)
        self.motor_min_a = MOTOR_MIN_NOISE * self.spec.current_noise_a
        s = self.spec
        emf_rpm = s.bus_voltage_v * s.driver_max_duty / s.torque_constant_nm_a * 30 / math.pi
        self.held_max_rpm = HELD_MAX_SHARE * min(s.max_speed_rpm, emf_rpm)
        self.latch = latch
        self.false_alarms_per_hour = float(false_alarms_per_hour)
        self.arl0 = arl_to_samples(false_alarms_per_hour, self.Ts)
        self.residuals = ResidualGenerator(wheel)
        self.alarms: list[Alarm] = []
        self.thresholds: dict[str, float] = {}
        self.notes: list[str] = []  # why a threshold does not give the requested rate
        self._trace = trace
        self.stuck_runs: list[int] = []  # runs of repeated readings while moving (trace)
        self._stuck_run = 0
        self.calibration: ThresholdCalibration | None = None
        if isinstance(calibration, ThresholdCalibration):
            self.calibration = calibration
        elif calibration and reference is not None:
            self.calibration = ThresholdCalibration.load()
        self.collected: dict[str, list[float]] = {
            name: [] for name in (*BLOCKS, "friction_change", "offset", "slew")
        }
        self.repeats = [0, 0]  # (repeats, non-zero readings) for a reference
        self.history: dict[str, list[float]] = {
            name: []
            for name in (
                "t_s",
                "speed",
                "acceleration",
                "current",
                *(f"stat_{b}" for b in CUSUM_TESTS),
            )
        }
        # each test's state, by its name: the block tests' classes, RunTest, Dropout, ...
        self._detectors: dict[str, Any] = {}
        self._lag_currents: deque[tuple[float, float]] = deque(maxlen=1200)
        self._friction_allowance = 0.0
        self._friction_sample = (0.0, 0.0, 0.0)
        self._hold_sample: tuple[float, float] | None = None  # (command rpm, current A)
        self._rest_current: float | None = None  # current of a settled 0-rpm rest, A
        self._moved = False  # a non-zero command came (the rest after it holds the loop's
        # integrator: up to a few mA on the twin's units)
        self._offset_sums = [0.0, 0.0, 0, 0]  # friction samples' residual: sums, counts (±)
        self._lag_excess: deque[tuple[float, float]] = deque(
            maxlen=1200
        )  # the motor test's value while lagging
        self._recent_speed: deque[float] = deque(maxlen=8)
        self._offset_window: list[tuple[float, float, float, float]] = []
        self._offset_command = math.nan
        self._slews = Slews(self.accel_limit, SLEW_SHARE)
        self._clamped_slews = Slews(self.accel_limit, CLAMP_SHARE)
        self._slew_gain = 1.0
        self._slew_gains: deque[float] = deque(maxlen=400)  # each slew value's friction gain
        self._slew_scale = None if reference is None else reference.slew_scale_rpm_s
        self._prev: dict[str, float] = {}
        self._last_speed: float | None = None
        self._reading_since = 0.0  # when the speed reading last changed, s
        self._frozen_s: float | None = None  # a stuck alarm's reading froze then, s
        self._charge: StepCharge | None = None
        self._moving = False
        self._was_stale = True
        self._lost: float | None = None
        self._command: tuple[float, float] = (math.nan, -math.inf)
        self._still_since = math.inf  # since when wheel and model are quiet, s
        self._still_speeds: deque[float] = deque(maxlen=max(2, round(STILL_SPAN_S / self.Ts) + 1))
        if reference is None:  # measuring a reference: collect the change test's values
            self._change_probe = _ChangeValues(self.collected["friction_change"], self.spec)
        else:
            if not math.isclose(reference.Ts, self.Ts, rel_tol=1e-6):
                raise ConfigError(
                    f"the healthy reference is at Ts = {reference.Ts} s, the model at {self.Ts} s"
                )
            self.residuals.current_model = np.asarray(reference.current_model, dtype=float)
            self._arm(reference)
            if trace:
                for det in self._detectors.values():
                    if isinstance(det, (BlockCusum, Dropout)):
                        det.trace = []

    # -- thresholds ----------------------------------------------------------------------
    def _arm(self, ref: HealthyReference) -> None:
        for name, stats in ref.tests.items():
            if name in ("friction_change", "slew"):
                continue  # armed with the friction test, and after the loop
            sides = {"friction": "up", "motor": "up", "lag": "down"}.get(name, "both")
            arl_blocks = self.arl0 / stats.block_s * (2 if sides == "both" else 1)
            h_analytic = cusum_threshold(max(arl_blocks, 1.5), CUSUM_K)
            tol = ref.tolerance.get(name, DEFAULT_TOLERANCE[name])
            if name == "motor":
                tol = min(tol, self._motor_headroom(ref))
            self._detectors[name] = BlockCusum(stats, tol, h_analytic, sides)
            h = self._calibrated(name, h_analytic, self._detectors[name])
            self._detectors[name].h = self.thresholds[name] = h
            if name == "friction":  # onsets smaller than the spread between units
                tol = ref.tolerance.get("friction_change", DEFAULT_TOLERANCE["friction_change"])
                # its own σ where the reference has it (hold-to-hold scatter of the
                # change values, which the plain friction test's σ does not hold)
                change = ref.tests.get("friction_change", stats)
                change = BlockStats(0.0, change.sigma, change.block, stats.fraction, 0, "")
                law = FrictionChange(change, tol, h_analytic, 6, ref.current_model, spec=self.spec)
                law.h = self._calibrated("friction_change", h_analytic, law)
                self._detectors["friction_change"] = law
                self.thresholds["friction_change"] = law.h
        # the speed offset on a continuously changing command: its σ is the measured one
        # (the identification record, a stepped PRBS, has no window that qualifies)
        stats = BlockStats(
            0.0, OFFSET_SIGMA_RPM, 1, 1 / OFFSET_WINDOW, 0, "detector_constants.toml"
        )
        h_analytic = cusum_threshold(max(self.arl0 / stats.block_s * 2, 1.5), CUSUM_K)
        det = BlockCusum(stats, 0.0, h_analytic, "both")
        det.h = self.thresholds["offset"] = self._calibrated("offset", h_analytic, det)
        self._detectors["offset"] = det
        if "slew" in ref.tests:  # older references lack it
            stats = self._slew_stats(ref)
            h_analytic = cusum_threshold(max(self.arl0 / stats.block_s, 1.5), CUSUM_K)
            tol = ref.tolerance.get("slew", DEFAULT_TOLERANCE["slew"])
            if ref.slew_scale_rpm_s is not None:  # the reference's level rests on ~10 slews
                tol = math.hypot(tol, Z95 * stats.sigma / math.sqrt(stats.samples))
            det = BlockCusum(stats, tol, h_analytic, "up")
            det.h = self.thresholds["slew"] = self._calibrated("slew", h_analytic, det)
            self._detectors["slew"] = det
            slew_change = SlewChange(SLEW_SIGMA, stats.fraction, h_analytic)
            slew_change.h = self._calibrated("slew_change", h_analytic, slew_change)
            self.thresholds["slew_change"] = slew_change.h
            self._detectors["slew_change"] = slew_change
        h_analytic = cusum_threshold(max(self.arl0 / (BLOCKS["friction"] / 0.05), 1.5), CUSUM_K)
        hold = HoldChange(h_analytic, BLOCKS["friction"], self.Ts)
        hold.h = self.thresholds["hold"] = self._calibrated("hold", h_analytic, hold)
        self._detectors["hold"] = hold
        self._detectors["rest"] = RestReading()
        clamped = ClampedFriction(ref.current_model, CLAMP_EXCESS, spec=self.spec)
        self._detectors["clamped"] = clamped
        self.thresholds["clamped"] = CLAMP_EXCESS
        self._charge = StepCharge(ref.current_model, self.Ts, QUIET_RPM_S)
        self._detectors["charge"] = FrozenMotor(self._motor_headroom(ref))
        self.thresholds["charge"] = self._detectors["charge"].h
        self.thresholds["rest"] = self._detectors["rest"].n
        n_stuck = self._calibrated("stuck", run_length(self.arl0, ref.repeat_probability))
        self._detectors["stuck"] = RunTest(int(n_stuck))
        self.thresholds["stuck"] = self._detectors["stuck"].n
        block = max(1, round(DROPOUT_BLOCK_S / self.Ts))
        mean = self._loss_rate(ref, block) * block
        p_block = block / self.arl0  # a block's share of the false-alarm budget
        n = 1
        while poisson.sf(n - 1, mean) > p_block:
            n += 1
        n = int(self._calibrated("dropout", n))
        self._detectors["dropout"] = Dropout(block, n)
        self.thresholds["dropout"] = n

    def _loss_rate(self, ref: HealthyReference, block: int) -> float:
        """Telemetry frames a healthy bus loses per sample: the reference record's rate
        where its losses are more than the calibration's hours of the bus would give it by
        chance (p < 0.01), else the calibration's rate (its blocks with a lost frame). A
        20-minute record's few losses are a poor rate: a reference record that lost 3 frames
        against 1.3 expected set the count at 4 frames a block, and a 0.3-s dropout loses
        3, so the model never saw one."""
        cal = self.calibration
        same_ts = cal is not None and math.isclose(cal.Ts, self.Ts, rel_tol=1e-6)
        curve = cal.curves.get("dropout") if cal is not None and same_ts else None
        if curve is None or not curve.decisions or curve.thresholds[0] != 1:
            return ref.lost_per_sample
        bus = -math.log1p(-curve.alarms[0] / curve.decisions) / block  # per sample
        lost = round(ref.lost_per_sample * ref.samples - 0.5)  # the Jeffreys estimate's count
        if lost > 0 and poisson.sf(lost - 1, bus * ref.samples) < 0.01:
            return ref.lost_per_sample
        return bus

    def _motor_headroom(self, ref: HealthyReference) -> float:
        """How far above the reference's inertial current a healthy unit's may sit: the
        datasheet's upper bound of I/k_t (the spec's tolerances: the RW90's I +2 %, k_t
        −5 % give 1.074 × nominal) over the
        reference's identified one (within 0.5 % of its unit's on the twin). The constant
        tolerance (0.15, two units at opposite bounds) made the rate a requested 1/h
        delivers depend on where the reference unit sits: 0 to 4.5/h over the calibration's
        reference models (a reference at 1.056 × nominal leaves a healthy unit only 2 % of
        room)."""
        nominal = nominal_inertial_current(self.spec)
        return max(self.bounds.motor_upper * nominal / ref.current_model[0] - 1.0, 0.0)

    @staticmethod
    def _slew_stats(ref: HealthyReference) -> BlockStats:
        """The slew test's healthy statistics: the reference's level, and the larger of its
        σ and the one pooled over many records (:data:`~rwlab.diagnose.motion.SLEW_SIGMA`),
        where the values are in nominal Coulomb decelerations: 9–10 slews of one record put
        σ anywhere in 0.13–0.46, and a reference's low σ alarmed on a healthy unit's PRBS."""
        stats = ref.tests["slew"]
        if ref.slew_scale_rpm_s is None or stats.sigma >= SLEW_SIGMA:
            return stats
        return BlockStats(
            stats.mean,
            SLEW_SIGMA,
            stats.block,
            stats.fraction,
            stats.samples,
            "detector_constants.toml",
        )

    def _calibrated(self, name: str, analytic: float, det: BlockCusum | None = None) -> float:
        """The threshold whose measured false-alarm rate is the requested one, where the
        calibration holds this detector at this sample time: a CUSUM's with all of its
        tolerance between units, or the largest share of it that delivers that rate. Where
        the rate is not measured (extrapolated, analytic) a note says so; where it cannot be
        delivered, a warning too."""
        cal = self.calibration
        if cal is None or not cal.covers(name):
            return analytic
        per_hour = self.false_alarms_per_hour
        if not math.isclose(cal.Ts, self.Ts, rel_tol=1e-6):
            note = (
                f"{name}: the calibration was measured at Ts = {cal.Ts:g} s, this model's is "
                f"{self.Ts:g} s: the analytic threshold, whose rate is not measured "
                "(bench/calibrate_thresholds.py measures one at this sample time)"
            )
            self._note(note, warn=per_hour * cal.hours >= RESOLVED)
            return analytic
        k = 0.0 if det is None else det.k
        s = cal.setting(name, per_hour, analytic, k)
        if det is not None and s.k < k:
            det.k = s.k
            self.notes.append(
                f"{name}: {per_hour:g}/h needs the tolerance between units cut to "
                f"{s.share:.0%} (k = {det.k:.3g} σ): a healthy unit "
                "farther from the reference than that alarms"
            )
        if s.info:
            self._note(s.info, warn=False)
        if s.note:
            self._note(s.note, warn=True)
        return s.threshold

    def _note(self, note: str, warn: bool) -> None:
        self.notes.append(note)
        if warn:
            warnings.warn(note, RwlabWarning, stacklevel=5)

    # -- one sample ----------------------------------------------------------------------
    def update(
        self,
        t_s: float,
        command_rpm: float,
        speed_rpm: float,
        current_a: float,
        age_s: float,
        lost_frames: float = 0.0,
    ) -> list[Alarm]:
        """Take the sample at ``t_s``; the new alarms.

        Parameters
        ----------
        t_s : float
            Sample time, s.
        command_rpm : float
            The speed command held over the interval that ends here, rpm.
        speed_rpm, current_a : float
            The newest telemetry: measured speed (rpm), motor current (A; NaN if none).
        age_s : float
            Age of that telemetry frame, s.
        lost_frames : float
            Telemetry frames lost so far (the frame counter's gaps), cumulative.
        """
        r = self.residuals.update(command_rpm, speed_rpm, current_a)
        if command_rpm != self._command[0]:
            self._command = (command_rpm, t_s)
        stale = age_s >= self.Ts
        usable = not (stale or self._was_stale)
        self._was_stale = stale
        lost = 0.0 if self._lost is None else max(0.0, lost_frames - self._lost)
        self._lost = lost_frames
        repeat = speed_rpm != 0 and speed_rpm == self._last_speed
        # a repeated reading is evidence only while the model says the wheel moves (in a
        # hold a well-regulated wheel's Hall reading repeats; the speed and lag tests and
        # the frozen check catch a sensor stuck there once the command changes)
        self._moving = abs(r["acceleration"] - r["accel_rpm_s"]) >= QUIET_RPM_S
        # the wheel's own quiet: its mean acceleration over STILL_SPAN_S (a weak motor's
        # loop holds a speed with a few rpm of ripple, which a single difference reads
        # as acceleration)
        self._still_speeds.append(speed_rpm if usable else math.nan)
        span = (self._still_speeds[-1] - self._still_speeds[0]) / (
            (len(self._still_speeds) - 1) * self.Ts or math.inf
        )
        if self._moving or not abs(span) < QUIET_RPM_S or not usable:
            self._still_since = math.inf
        elif self._still_since == math.inf:
            self._still_since = t_s
        # a reading near zero repeats while the wheel rests in stiction: no evidence
        self._moving = self._moving and abs(speed_rpm) >= STILL_RPM
        if usable and self._moving and self._last_speed not in (None, 0.0):
            self.repeats[0] += repeat
            self.repeats[1] += 1
        # near zero speed and passing through it (a healthy reading held at a low speed
        # may repeat one value)
        model_accel = r["accel_rpm_s"] - r["acceleration"]
        # (or where the reading itself moves fast: a clamped wheel passes zero when the
        # model does not)
        moved = self._last_speed is not None and abs(speed_rpm - self._last_speed) >= REST_STEP_RPM
        crossing = abs(r["model_rpm"]) < REST_MODEL_RPM and abs(model_accel) >= QUIET_RPM_S
        near_zero = abs(speed_rpm) < REST_BAND_RPM and (moved or crossing)
        rest = usable and near_zero and speed_rpm != self._last_speed
        if speed_rpm != self._last_speed:
            self._reading_since = t_s
        self._last_speed = speed_rpm
        self._recent_speed.append(speed_rpm)
        self._hold_sample = None
        self._rest_current = None
        values = self._values(t_s, r, speed_rpm, current_a) if usable else {}
        offset = self._offset(r, command_rpm, usable)
        if offset is not None:
            values["offset"] = offset
        slew = self._slew_value(t_s - age_s, r, speed_rpm, current_a, usable)
        if slew is not None:
            values["slew"] = slew
            self._slew_gains.append(self._slew_gain)
        new: list[Alarm] = []
        change = self._detectors.get("slew_change")
        if slew is not None and change is not None and change.add_slew(t_s, slew):
            new += self._fire(t_s, "slew_change")
        if self._detectors:
            if self._detectors["dropout"].add(round(lost)):
                new += self._fire(t_s, "dropout")
            if rest and self._detectors["rest"].add(speed_rpm):
                new += self._fire(t_s, "rest")
            if usable and self._detectors["stuck"].update(repeat and self._moving):
                new += self._fire(t_s, "stuck")
            if usable and self._trace:
                self._trace_run(repeat and self._moving)
            clamped = self._detectors["clamped"]
            # the unit's own friction: until the first alarm (a clamp's comes seconds
            # after its onset; a PRBS's first clamped slew may come minutes later, and
            # worn bearings' samples in between made ×1.5 read as healthy)
            if usable and abs(span) < CLAMP_QUIET_RPM_S and not self.alarms:
                clamped.add_own(r["current"], speed_rpm)
            slew_samples = self._clamped_slews.add(
                t_s - age_s, r["accel_rpm_s"], speed_rpm, current_a, usable
            )
            found = slew_samples and clamped_deceleration(slew_samples)
            if found and clamped.add_slew(t_s, *found):
                new += self._fire(t_s, "clamped")
            new += self._frozen_motor(t_s, r, current_a)
            hold = self._detectors["hold"]
            if self._rest_current is not None:
                hold.add_rest(self._rest_current)
            if self._hold_sample is not None:
                hold.add_sample(t_s, *self._hold_sample)
            if hold.statistic > hold.h and self._motor_seen_since(hold.onset()):
                new += self._fire(t_s, "hold")
            sample = self._friction_sample
            if "friction" in values and self._detectors["friction_change"].add_sample(t_s, *sample):
                new += self._fire(t_s, "friction_change")
            for name, value in values.items():
                # a test the reference holds no statistics for (an identification record
                # with under four slews through zero has none for the slew test) is off
                if name not in self._detectors:
                    continue
                allowance = self._friction_allowance if name == "friction" else 0.0
                if not self._detectors[name].add(t_s, value, allowance):
                    continue
                new += self._speed_alarm(t_s) if name == "speed" else self._fire(t_s, name)
        else:
            for name, value in values.items():
                self.collected[name].append(value)
            if "friction" in values:  # the change test's values after its baseline
                self._change_probe.add_sample(t_s, *self._friction_sample)
        self._record(t_s, r, values)
        return new

    def _frozen_motor(self, t_s: float, r: dict[str, float], current_a: float) -> list[Alarm]:
        """A settled speed change's charge (:class:`FrozenMotor`): the unit's own level
        until a stuck alarm, a weak motor's test on the changes begun after its reading
        froze."""
        assert self._charge is not None
        model_accel = r["accel_rpm_s"] - r["acceleration"]
        value = self._charge.add(t_s, r["model_rpm"], model_accel, current_a)
        test = self._detectors["charge"]
        if value is None or not test.add(value, self._charge.start_s, t_s, self._frozen_s):
            return []
        self.thresholds["charge"] = test.h
        return self._fire(t_s, "charge")

    def _offset(self, r: dict[str, float], command_rpm: float, usable: bool) -> float | None:
        """Collect a window of usable samples; its speed offset when it is full."""
        if not usable:
            return None
        model_accel = r["accel_rpm_s"] - r["acceleration"]
        changed = float(command_rpm != self._offset_command)
        self._offset_command = command_rpm
        self._offset_window.append((r["speed"], r["model_rpm"], model_accel, changed))
        if len(self._offset_window) < OFFSET_WINDOW:
            return None
        window = np.array(self._offset_window)
        self._offset_window.clear()
        return speed_offset(window)

    def _slew_value(
        self, t_s: float, r: dict[str, float], speed_rpm: float, current_a: float, usable: bool
    ) -> float | None:
        """Collect one slew's samples (at the telemetry's own time); its asymmetry when
        it ends."""
        slew = self._slews.add(t_s, r["accel_rpm_s"], speed_rpm, current_a, usable)
        c = self.residuals.current_model
        if slew is None or c is None:
            return None
        value = slew_asymmetry(slew, c, self._slew_scale)
        if value is not None:
            self._slew_gain = slew_friction_gain(slew, self.spec) or 1.0
        return value

    def _trace_run(self, event: bool) -> None:
        if event:
            self._stuck_run += 1
        elif self._stuck_run:
            self.stuck_runs.append(self._stuck_run)
            self._stuck_run = 0

    def traces(self) -> dict[str, list[float] | list[int]]:
        """What a calibration counts: each block test's standardised block means, the
        runs of repeated readings while moving, the lost frames per dropout block."""
        self._trace_run(False)
        out: dict[str, list[float] | list[int]] = {
            name: list(det.trace)
            for name, det in self._detectors.items()
            if isinstance(det, (BlockCusum, Dropout)) and det.trace is not None
        }
        out["stuck"] = list(self.stuck_runs)
        return out

    def _values(
        self, t_s: float, r: dict[str, float], speed_rpm: float, current_a: float
    ) -> dict[str, float]:
        """The qualifying test values of a usable sample."""
        out: dict[str, float] = {}
        accel, model_accel = r["accel_rpm_s"], r["accel_rpm_s"] - r["acceleration"]
        prev = self._prev
        model_rpm = r["model_rpm"]
        self._prev = {"accel": accel, "model_accel": model_accel, "model_rpm": model_rpm}
        settled = t_s - self._command[1] >= SETTLE_S and t_s - self._still_since >= STILL_S
        # (not a hold inside the stiction band: there the wheel may rest at 0 instead)
        held = abs(self._command[0])
        self._moved = self._moved or self._command[0] != 0.0
        if settled and not self._moved and speed_rpm == 0.0 and math.isfinite(current_a):
            self._rest_current = current_a  # at rest since power-up: the sense offset
        if settled and (STILL_RPM <= held <= self.held_max_rpm or held == 0.0):
            # the wheel's PI loop holds the true speed at the command: model-free, and the
            # same for every unit (the identified model's own steady error is no part of it)
            out["speed"] = speed_rpm - self._command[0]
        if self._lagging(model_accel, model_rpm, prev):
            out["lag"] = (accel - model_accel) * math.copysign(1.0, model_accel) / self.accel_limit
            self._lag_currents.append((t_s, abs(current_a)))
        c = self.residuals.current_model
        if c is None or not math.isfinite(r["current"]):
            return out
        sign = 0.0 if speed_rpm == 0 else math.copysign(1.0, speed_rpm)
        friction = c[1] * speed_rpm + c[2] * sign
        inertial = c[0] * accel
        if "lag" in out and abs(inertial) >= self.motor_min_a:
            excess = math.copysign(1.0, inertial) * r["current"] / abs(inertial)
            self._lag_excess.append((t_s, excess))
        if abs(accel) < QUIET_RPM_S and abs(speed_rpm) >= FRICTION_MIN_RPM and friction * sign > 0:
            if settled and STILL_RPM <= held <= self.held_max_rpm:  # the hold test's sample
                self._hold_sample = (self._command[0], current_a)
            offset = self._current_offset(sign, r["current"])
            if offset is not None:
                out["friction"] = sign * (r["current"] - offset) / abs(friction)
                self._friction_allowance = self._allowance(abs(friction), speed_rpm)
            self._friction_sample = (r["current"], speed_rpm, friction)
        sustained = inertial * c[0] * prev.get("accel", 0.0) > 0
        floor = self.motor_min_a
        if abs(inertial) >= floor and sustained and abs(c[0] * prev["accel"]) >= floor:
            out["motor"] = math.copysign(1.0, inertial) * r["current"] / abs(inertial)
        return out

    def _speed_alarm(self, t_s: float) -> list[Alarm]:
        """A held-speed error is a bias when it stays: where the current at the hold rose
        with it (a load step: more friction, a weak motor), the wheel's loop brings the
        speed back within seconds, so wait :data:`LOAD_SETTLE_S`; alarm only if the
        latest block still holds the error (else forget it). Isolation's rule: with
        ``latch`` off (counting false alarms) every alarm of the detector counts."""
        det = self._detectors["speed"]
        if not self.latch:  # counting false alarms: the detector's own, as calibrated
            return self._fire(t_s, "speed")
        t0 = det.change_time()
        if self._detectors["hold"].load_change(t0, self._command[0]) and t_s - t0 < LOAD_SETTLE_S:
            return []
        # a load step that comes as (or just after) the wheel settles at a hold leaves no
        # earlier current there to compare (friction x1.5 starting 1.5 s after a hold settled
        # read a 4.5 rpm bias; x2 starting while the wheel slewed to the hold, -15 rpm):
        # an error that is not a step (it rises, or decays as the loop rejects the load)
        # waits LOAD_SETTLE_S from its change point too
        t1 = det.change_point()
        since = np.array([v for t, v in det.raw if t >= t1])
        sd = det.stats.sigma * math.sqrt(det.stats.block)  # σ of one value
        if not steady(since, sd) and t_s - t1 < LOAD_SETTLE_S:
            return []
        # a bias stays; forget an error that no longer holds (the loop has removed a load
        # step's or an overshoot's): the latest block, and this hold's latest values
        error = det.means[-1][1] - det.mean
        now = [v for t, v in det.raw if t > self._command[1]]
        if self._command[1] > t0 and len(now) < 4:
            return []  # a hold begun since the change: on its own values (wait for 4)
        held = [float(np.mean(x)) - det.mean for x in (now, now[-8:]) if len(x) >= 4]
        if abs(error) / det.stats.sigma <= det.k or any(abs(x) < 0.5 * abs(error) for x in held):
            det.restart()
            return []
        return self._fire(t_s, "speed")

    def _motor_seen_since(self, t0: float) -> bool:
        """The motor test has a block after ``t0``: a weak motor and more friction both
        raise the current at a held speed; only the current under acceleration tells
        which, so the hold test names nothing before it has one."""
        motor = self._detectors.get("motor")
        if motor is None:
            return True
        return sum(t > t0 for t, _ in motor.raw) >= motor.stats.block

    def _allowance(self, friction_a: float, speed_rpm: float) -> float:
        """How far beyond the friction test's tolerance a healthy unit may sit at this
        speed, relative to the reference's friction current ``friction_a`` (A): the
        datasheet's upper bound (the spec's tolerance: the RW90's 1.3) × the nominal
        friction current at this speed, over
        the reference's, less the tolerance the CUSUM already holds. A reference from a
        low-friction unit (or one whose identified viscous part is low) makes the bound
        a larger excess than the constant tolerance (×1.86, a reference at exactly the
        lower bound), most at high speeds: a low-friction reference model read healthy units
        ×2.0–2.4 there and alarmed."""
        ref = self.reference
        if ref is None:
            return 0.0
        viscous, coulomb = nominal_friction_currents(self.spec)
        upper = self.bounds.friction_upper * (viscous * abs(speed_rpm) + coulomb) / friction_a - 1.0
        return max(0.0, upper - ref.tolerance.get("friction", DEFAULT_TOLERANCE["friction"]))

    def _current_offset(self, sign: float, residual_a: float) -> float | None:
        """This unit's current-sense offset beyond the reference's, A (None until the
        wheel has held speeds of both signs).

        The friction current turns with the speed's sign, an offset does not: half the
        sum of the mean residuals at either sign is the offset, and friction (also a
        fault's) cancels in it. Units differ by up to ±5 mA of offset, as much as the
        friction current itself at 500 rpm: without this a reference from a unit with
        little friction and the opposite offset read friction ×3 on healthy units.
        """
        sums = self._offset_sums
        i = 0 if sign > 0 else 1
        sums[i] += residual_a
        sums[i + 2] += 1
        if min(sums[2], sums[3]) < OFFSET_MIN_SAMPLES:
            return None
        return 0.5 * (sums[0] / sums[2] + sums[1] / sums[3])

    def _lagging(self, model_accel: float, model_rpm: float, prev: dict[str, float]) -> bool:
        """The model ran at its acceleration limit, one way, over this and the last sample.

        Not a sample in which the model reverses (a triangle's corner: its mean rate is
        no limit, and where in the sample the wheel turns is the model's timing error),
        nor one in which it passes through zero speed: there a Hall-period reading is the
        speed of the last, long edge interval, or 0 below its measurable speed, so the
        reading's rate over that sample is not the wheel's. Both are at every reversal of
        a fast chirp, whose share of such samples depends on the model's timing: with
        them the test alarmed on healthy chirps for one reference model and not another.
        """
        limit = LAG_SHARE * self.accel_limit
        before, before_rpm = prev.get("model_accel", 0.0), prev.get("model_rpm", 0.0)
        return (
            abs(model_accel) >= limit
            and abs(before) >= limit
            and model_accel * before > 0
            and model_rpm * before_rpm > 0
            and min(abs(model_rpm), abs(before_rpm)) >= LAG_MIN_RPM
        )

    def _record(self, t_s: float, r: dict[str, float], values: dict[str, float]) -> None:
        h = self.history
        h["t_s"].append(t_s)
        for name in ("speed", "acceleration", "current"):
            h[name].append(r[name])
        for name in CUSUM_TESTS:
            det = self._detectors.get(name)
            h[f"stat_{name}"].append(det.statistic if det is not None else math.nan)

    def coverage(self) -> dict[str, dict]:
        """What each test has decided on so far: "no alarm" means only as much.

        Returns
        -------
        dict of str to dict
            Test name → ``{"decided": n, "unit": what n counts}`` (:data:`DECIDES_ON`):
            blocks of qualifying samples tested (block CUSUMs, after their baseline),
            60-s windows, slews, readings near zero speed, samples that could show a
            frozen reading, whole 10-s blocks of lost-frame counts. ``n = 0``: the test
            had nothing to decide on. Empty when nothing is armed (no reference).
        """
        out: dict[str, dict] = {}
        for name, det in self._detectors.items():
            if isinstance(det, (BlockCusum, ClampedFriction, FrozenMotor)):
                n = det.decided
            elif name == "rest":
                n = det.readings
            elif name == "stuck":
                n = self.repeats[1]
            elif name == "dropout":
                n = len(self.history["t_s"]) // det.block
            else:
                continue
            out[name] = {"decided": int(n), "unit": DECIDES_ON[name]}
        return out

    def estimates(self) -> dict[str, dict]:
        """Friction and torque-constant factors and the speed bias from the tests' values
        in the record's last :data:`HISTORY_S`, alarm or not: a wear trend below threshold.

        The current at constant speed over the reference's friction current is
        friction/k_t, the current under acceleration over the inertial current is
        I/k_t; with each excess e taken over the reference's own level on its healthy
        record, the torque-constant factor is 1/(1 + e_motor), the friction factor
        (1 + e_friction)/(1 + e_motor); the bias is the held-speed error less the
        reference's. Two 95 % intervals: ``ci95``, the record's noise (block σ of the
        reference, one independent value per block), for a trend of one wheel (the
        reference unit's own difference from the wheel is common to all its records,
        so it moves a trend as a whole and hides no change within it); and
        ``ci95_units``, which adds the spread between healthy units
        (the wheel spec's tolerances:
        :attr:`~rwlab.diagnose.reference.UnitBounds.friction_sd` and ``motor_sd``;
        :data:`~rwlab.diagnose.isolate.SPEED_UNIT_SD`), for a reading against a healthy
        unit of the wheel model.
        After a stuck-sensor alarm no estimate is given: each rests on the speed reading.

        Returns
        -------
        dict of str to dict
            ``friction``, ``torque_constant`` (factors), ``speed_sensor_bias`` (rpm),
            each ``{"magnitude", "ci95", "ci95_units", "unit", "blocks"}``, where the test
            had values.
        """
        ref = self.reference
        if ref is None or any(a.kind == "speed_sensor_stuck" for a in self.alarms):
            return {}

        times = self.history["t_s"]
        since = times[-1] - HISTORY_S if times else -math.inf

        def mean_ci(name: str) -> tuple[float, float, float] | None:
            # the record's latest HISTORY_S, not the test's: a test that last decided
            # long ago would mix the values before a fault's onset in
            det = self._detectors.get(name)
            stats = ref.tests.get(name)
            x = np.array([v for t, v in (det.raw if det else ()) if t >= since], dtype=float)
            if stats is None or not x.size:
                return None
            blocks = max(len(x) / stats.block, 1.0)
            return float(x.mean()), Z95 * stats.sigma / math.sqrt(blocks), blocks

        out: dict[str, dict] = {}
        motor, friction, speed = mean_ci("motor"), mean_ci("friction"), mean_ci("speed")
        e_m, h_m = (motor[0], motor[1]) if motor else (0.0, 0.0)
        # relative to the reference's own level on its healthy record (the tests' zero)
        e_m, h_m = _relative(e_m, h_m, ref.tests["motor"].mean if motor else 0.0)
        if motor:
            k_t, rel = 1 / (1 + e_m), h_m / (1 + e_m)
            unit_rel = Z95 * self.bounds.motor_sd
            out["torque_constant"] = _estimate(k_t, rel, unit_rel, "factor", motor[2])
        if friction:
            e_f, h_f, n = friction
            e_f, h_f = _relative(e_f, h_f, ref.tests["friction"].mean)
            rel = math.hypot(h_f / (1 + e_f), h_m / (1 + e_m))
            unit_rel = Z95 * self.bounds.friction_sd
            out["friction"] = _estimate((1 + e_f) / (1 + e_m), rel, unit_rel, "factor", n)
        if speed:
            bias = speed[0] - ref.tests["speed"].mean
            out["speed_sensor_bias"] = _estimate(
                bias, speed[1], Z95 * SPEED_UNIT_SD, "rpm", speed[2], relative=False
            )
        return out

    def _fire(self, t_s: float, detector: str) -> list[Alarm]:
        det = self._detectors[detector]
        statistic = det.statistic if detector != "dropout" else float(det.last_count)
        if not self.latch:
            det.restart()
        elif any(a.detector == detector for a in self.alarms):
            return []
        else:
            det.restart() if detector == "dropout" else None
        if self.latch and detector == "offset" and any(a.kind in ROTOR_FAULTS for a in self.alarms):
            # a rotor fault moves the speed residual's zero-speed offset too (friction
            # ×1.5–2.5 on a chirp: 20–25 rpm): after one, the offset names nothing (the
            # rest and held-speed tests still see a bias). Not when counting false alarms
            # (latch off): there each detector's own alarms count
            det.restart()
            return []
        findings = isolate(detector, self._evidence(detector))
        alarms = [
            Alarm(
                t_s,
                f.kind,
                float(statistic),
                detector,
                float(self.thresholds[detector]),
                f.magnitude,
                f.ci,
                f.unit,
            )
            for f in findings
        ]
        self.alarms += alarms
        if self._frozen_s is None and any(a.kind == "speed_sensor_stuck" for a in alarms):
            self._frozen_s = self._reading_since
        return alarms

    def _evidence(self, detector: str) -> Evidence:
        """What isolation reads: each block test's recent block means, and more."""
        ev: Evidence = {}
        for name in EVIDENCE_BLOCKS:
            if name in self._detectors and self._detectors[name].raw:
                ev[name] = self._detectors[name].since_change()
        change = self._detectors.get("friction_change")
        if detector == "friction_change" and change is not None and change.raw:
            # the size relative to the record's start, not to the reference's unit
            ev["friction"] = change.since_change()
            ev["friction_model_sd"] = change.law_uncertainty(len(ev["friction"]))
            detector = "friction"
        ref = self.reference
        assert ref is not None  # alarms come only from an armed detector
        # σ of one value, the block-mean σ scaled back (correlation included)
        ev["sigma"] = {name: s.sigma * math.sqrt(s.block) for name, s in ref.tests.items()}
        if "slew" in self._detectors:
            ev["sigma"]["slew"] = self._detectors["slew"].stats.sigma
        slew_test = "slew_change" if detector == "slew_change" else "slew"
        if detector == "slew_change":  # sized on its own change, against the record's own slews
            ev["slew"] = self._detectors[slew_test].since_change()
        if len(ev.get("slew", ())):  # the slews' friction at their speeds, Coulomb = 1
            slew = self._detectors[slew_test]
            ev["slew_gain"] = np.array(list(self._slew_gains)[-len(ev["slew"]) :])
            # this unit's own healthy level, where the record has slews before the change
            ev["slew_before"] = np.array([v for t, v in slew.raw if t < slew.change_point()])
        ev["sigma"]["offset"] = OFFSET_SIGMA_RPM
        ev["ref_mean"] = {name: s.mean for name, s in ref.tests.items()}
        motor, lag = self._detectors.get("motor"), self._detectors.get("lag")
        if motor is not None and lag is not None:  # the motor test before and after the lag
            t_change = lag.change_time()
            ev["motor_before"] = np.array([x for t, x in motor.raw if t < t_change])
            ev["motor_after"] = np.array([x for t, x in motor.raw if t >= t_change])
        ev["tolerance"] = dict(ref.tolerance)
        # a weak motor is named on the motor test's own tolerance (the datasheet's headroom):
        # on the constant one, a unit's k_t x 0.8, read with its own model, was named friction
        ev["tolerance"]["motor"] = min(
            ev["tolerance"].get("motor", DEFAULT_TOLERANCE["motor"]), self._motor_headroom(ref)
        )
        ev["recent_speed"] = np.array(self._recent_speed)
        ev["held_command_rpm"] = self._command[0]
        ev["moving_repeats"] = self._detectors["stuck"].run
        if any(a.kind == "speed_sensor_stuck" for a in self.alarms):
            ev["moving_repeats"] = math.inf  # a frozen reading misleads every later test
        # the lag samples since the change (since_change's single values, the latest ones)
        n_lag = len(ev.get("lag", ()))
        t0 = lag.raw[-n_lag][0] if lag is not None and 0 < n_lag <= len(lag.raw) else -math.inf
        ev["lag_currents"] = np.array([i for t, i in self._lag_currents if t >= t0][-200:])
        ev["lag_currents_before"] = np.array([i for t, i in self._lag_currents if t < t0])
        ev["lag_excess"] = np.array([e for t, e in self._lag_excess if t >= t0])
        ev["lost"] = self._detectors["dropout"].last_count
        hold = self._detectors["hold"]
        ev["hold"] = hold.since_change_sizes()
        if detector == "hold" and motor is not None:  # the motor test since the change
            ev["motor"] = np.array([x for t, x in motor.raw if t > hold.onset()])
        weak = [
            (a.magnitude, a.ci)
            for a in self.alarms
            if a.kind == "torque_constant" and a.magnitude is not None and a.ci is not None
        ]
        if weak:  # a weak motor named before: its share of a held current's rise
            ev["torque_constant"] = weak[-1]
        ev["rest_value"] = self._detectors["rest"].value
        if detector == "clamped":
            ev["clamped"] = self._detectors["clamped"].recent()
        if detector == "charge":
            ev["charge"] = self._detectors["charge"].recent()
        if detector in ("motor", "friction"):
            other: BlockName = "motor" if detector == "friction" else "friction"
            det = self._detectors.get(other)  # the other test's latest blocks too
            if det is not None and det.raw:
                ev[other] = np.array([x for _, x in list(det.raw)[-60:]])
        return ev

    @property
    def calibrated(self) -> bool:
        return bool(self._detectors)


def _relative(e: float, half: float, mean: float) -> tuple[float, float]:
    """An excess e (and its half-width) over the reference's level ``mean``, as an excess
    over 1 + mean."""
    return (1 + e) / (1 + mean) - 1, half / (1 + mean)


def _estimate(
    value: float, half: float, unit_half: float, unit: str, blocks: float, relative: bool = True
) -> dict:
    """An estimate with its record-noise half-width ``half`` and, in quadrature with the
    spread between units ``unit_half``, its interval against any healthy unit (both
    relative to ``value`` for a factor, absolute for a bias)."""
    scale = value if relative else 1.0
    wide = math.hypot(half, unit_half)
    return {
        "magnitude": value,
        "ci95": [value - scale * half, value + scale * half],
        "ci95_units": [value - scale * wide, value + scale * wide],
        "unit": unit,
        "blocks": round(blocks, 1),
    }
