"""A record against the healthy reference: :func:`diagnose` runs a
:class:`~rwlab.diagnose.diagnoser.Diagnoser` over a record's samples into a
:class:`Diagnosis`; :func:`healthy_reference` measures the reference on the
identification record, :func:`measure_calibration` the detectors' healthy traces for
the thresholds."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from rwlab.data import IOData
from rwlab.diagnose.blocktests import (
    BlockCusum,
)
from rwlab.diagnose.calibration import N_MAX as _N_MAX
from rwlab.diagnose.calibration import Curve as _Curve
from rwlab.diagnose.calibration import (
    ThresholdCalibration,
    count_alarms,
    cusum_curves,
    run_alarms,
)
from rwlab.diagnose.diagnoser import (
    BLOCKS,
    DECIDES_ON,
    ROTOR_FAULTS,
    Alarm,
    Diagnoser,
)
from rwlab.diagnose.isolate import (
    Finding,
    combine,
)
from rwlab.diagnose.reference import (
    HealthyReference,
    block_stats,
    nominal_coulomb_deceleration,
    unit_tolerance,
)
from rwlab.diagnose.residuals import fit_current_model
from rwlab.errors import ConfigError, DataError, RwlabWarning

__all__ = ["Diagnosis", "diagnose", "healthy_reference", "measure_calibration"]

TELEMETRY_TESTS = ("rest", "stuck", "dropout")
# the tests that can name each fault: where none decided on anything, "no alarm" says
# nothing of that fault
FAULT_TESTS = {
    "friction": ("friction", "friction_change", "hold", "slew", "slew_change", "clamped"),
    "torque_constant": ("motor", "charge"),
    "current_limit": ("lag",),
    "speed_sensor_bias": ("speed", "offset", "rest"),
    "speed_sensor_stuck": ("stuck",),
    "telemetry_dropout": ("dropout",),
}
# what load_record must give diagnose (its default is the speed alone)
RECORD_OUTPUTS = ("speed", "current", "age", "lost")
# tests a healthy reference may lack (too few qualifying samples on the identification
# record: a PRBS that seldom holds ≥ 1500 rpm): friction_change then takes friction's σ
OPTIONAL_TESTS = ("friction_change",)


def healthy_reference(
    data: IOData, wheel, *, tolerance: dict | None = None, source: str = ""
) -> HealthyReference:
    """Measure the healthy reference on a fault-free record (the identification record).

    Parameters
    ----------
    data : IOData
        As :func:`diagnose` takes it (speed, current, age and lost frames), speed mode.
    wheel : IdentifiedWheel
        The model identified on it.
    tolerance : dict, optional
        Tolerance between healthy units per test (default: the wheel model's,
        :func:`~rwlab.diagnose.reference.unit_tolerance` of ``wheel.wheel_spec``).
    source : str
        Where the record came from.

    Returns
    -------
    HealthyReference
        Block statistics per test, for ``model.json``.

    Raises
    ------
    DataError
        No motor current, too few samples for a test, or not a speed-mode record.
    """
    t, u, speed, current, age, lost = record_columns(data, wheel)
    if not np.isfinite(current).all():
        raise DataError("the healthy reference needs the motor current on every sample")
    accel = np.concatenate([[0.0], np.diff(speed) / data.Ts])
    fresh = age < data.Ts
    keep = fresh & np.concatenate([[False], fresh[:-1]])  # as the tests take samples
    coef = fit_current_model(accel[keep], speed[keep], current[keep])
    second = Diagnoser(wheel, None)
    second.residuals.current_model = coef
    second._change_probe.c = coef
    second._slew_scale = scale = nominal_coulomb_deceleration(second.spec)
    for k in range(data.N):
        second.update(float(t[k]), float(u[k]), speed[k], current[k], age[k], lost[k])
    tests = {}
    for name, values in second.collected.items():
        if name in ("offset", "slew"):  # no window of a stepped PRBS qualifies: σ is a constant
            continue
        try:
            tests[name] = block_stats(
                np.array(values), BLOCKS.get(name, BLOCKS["friction"]), data.N
            )
        except DataError as exc:
            if name not in OPTIONAL_TESTS:
                raise DataError(f"the {name} test: {exc}") from exc
    if len(second.collected["slew"]) >= 4:  # slews through zero speed: few in a record
        tests["slew"] = block_stats(np.array(second.collected["slew"]), 1, data.N)
    reps, readings = second.repeats
    return HealthyReference(
        Ts=float(data.Ts),
        current_model=tuple(float(x) for x in coef),  # type: ignore[arg-type]
        tests=tests,
        repeat_probability=(reps + 1) / (readings + 2),  # Laplace's rule: never 0 or 1
        repeat_samples=int(readings),
        lost_per_sample=(float(lost[-1] - lost[0]) + 0.5) / data.N,  # Jeffreys: never 0
        samples=int(data.N),
        tolerance=dict(unit_tolerance(second.spec) if tolerance is None else tolerance),
        source=source,
        slew_scale_rpm_s=scale,
    )


def measure_calibration(
    records: list[IOData],
    wheel,
    reference: HealthyReference,
    *,
    origin: str = "",
    more_models: tuple = (),
) -> ThresholdCalibration:
    """Count each detector's false alarms over its thresholds on healthy records.

    Parameters
    ----------
    records : list of IOData
        Healthy records of units other than the references', as :func:`diagnose`
        takes them.
    wheel : IdentifiedWheel
    reference : HealthyReference
        The identified unit's, as the detectors will use it.
    origin : str
        How the records were made (stored with the calibration).
    more_models : sequence of (IdentifiedWheel, HealthyReference)
        Models of other units (same Ts): each runs over every record too, so the
        rates are those of a model from any of these units (the user identifies on
        one unit and diagnoses others); each CUSUM is counted with each model's own
        reference value, over shares of its tolerance between units
        (:data:`~rwlab.diagnose.calibration.SHARES`), so a model of any unit (any k)
        takes the curve of its share.

    Returns
    -------
    ThresholdCalibration
        Alarms per threshold (detectors restarted after each alarm) and the hours
        (record hours times models).
    """
    if not records:
        raise ConfigError("a calibration needs at least one healthy record")
    models = [(wheel, reference), *more_models]
    if any(not math.isclose(w.Ts, wheel.Ts, rel_tol=1e-6) for w, _ in models):
        raise ConfigError("a calibration's models must share one sample time")
    per_model = [model_traces(records, w, ref) for w, ref in models]
    hours = len(models) * sum(data.N * data.Ts for data in records) / 3600
    curves = {}
    for name, (_, sides) in per_model[0][1].items():
        # each model at its own k, over shares of its tolerance: what carries to a model
        # of another unit is the share, not k (calibration's docstring)
        curves.update(cusum_curves(name, [(m[0][name], m[1][name][0]) for m in per_model], sides))
    n = tuple(float(x) for x in range(1, _N_MAX + 1))
    runs = [int(r) for m in per_model for rec in m[0]["stuck"] for r in rec]
    moving = sum(m[2] for m in per_model)
    curves["stuck"] = _Curve("count", n, tuple(int(a) for a in run_alarms(runs)), 0.0, moving)
    blocks = [int(c) for m in per_model for rec in m[0]["dropout"] for c in rec]
    curves["dropout"] = _Curve(
        "count", n, tuple(int(a) for a in count_alarms(blocks)), 0.0, len(blocks)
    )
    return ThresholdCalibration(float(wheel.Ts), float(hours), curves, origin)


def model_traces(records: list[IOData], wheel, reference: HealthyReference):
    """One model over every record: each test's traces per record, each CUSUM's (k,
    sides), and the moving samples."""
    traces: dict[str, list] = {}
    k: dict[str, tuple[float, str]] = {}
    moving = 0
    for data in records:
        t, held, speed, current, age, lost = record_columns(data, wheel)
        d = Diagnoser(
            wheel, reference, false_alarms_per_hour=1e-9, latch=False, calibration=False, trace=True
        )
        for i in range(data.N):
            d.update(float(t[i]), float(held[i]), speed[i], current[i], age[i], lost[i])
        for name, values in d.traces().items():
            traces.setdefault(name, []).append(np.array(values))
        for name, det in d._detectors.items():
            if isinstance(det, BlockCusum):
                k[name] = (det.k, det.sides)
        moving += d.repeats[1]
    return traces, k, moving


@dataclass(repr=False)
class Diagnosis:
    """What :func:`diagnose` found in a record.

    Parameters
    ----------
    alarms : list of Alarm
        In time order.
    thresholds : dict
        Each detector's threshold.
    reference : HealthyReference
        The healthy reference the detectors compared the record with.
    history : dict of str to numpy.ndarray
        The residuals and statistics at every sample (``t_s``, ``speed``, ...,
        ``stat_NAME`` for each CUSUM test), each shape (N,).
    false_alarms_per_hour : float
        The false-alarm rate the thresholds were set for, per detector.
    duration_s : float
        Length of the record, s.
    notes : list of str
        Detectors that cannot deliver the requested rate, and why.
    coverage : dict of str to dict
        What each test decided on (:meth:`Diagnoser.coverage`; a test the data
        could not feed has ``decided`` 0 and a ``why``).
    estimates : dict of str to dict
        Friction and torque-constant factors and the speed bias against the healthy
        reference, alarm or not (:meth:`Diagnoser.estimates`), for trends.
    """

    alarms: list[Alarm]
    thresholds: dict
    reference: HealthyReference
    history: dict[str, np.ndarray]
    false_alarms_per_hour: float
    duration_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    coverage: dict[str, dict] = field(default_factory=dict)
    estimates: dict[str, dict] = field(default_factory=dict)

    def __repr__(self) -> str:
        found = ", ".join(self.faults()) or "no alarm"
        return (
            f"Diagnosis({found}; {len(self.alarms)} alarm{'' if len(self.alarms) == 1 else 's'} "
            f"over {self.duration_s:g} s, "
            f"{len(self.tested())} of {len(self.coverage)} tests decided)"
        )

    def faults(self) -> list[str]:
        """The faults named, in the order of their first alarm."""
        return list(dict.fromkeys(a.kind for a in self.alarms))

    def tested(self) -> list[str]:
        """The tests that decided on at least one block, window, slew or sample."""
        return [name for name, c in self.coverage.items() if c["decided"] > 0]

    def untested(self) -> list[str]:
        """The tests that had nothing to decide on: their silence says nothing."""
        return [name for name, c in self.coverage.items() if c["decided"] == 0]

    def unseen(self) -> list[str]:
        """The faults (:data:`FAULT_TESTS`) none of whose tests decided on anything and
        that no alarm named: the record could not show them (too short, or without the
        motions they need). A fault another test named was seen (a reading frozen at
        0 rpm from power-up gives the stuck test nothing; the lag test names it)."""
        tested, named = set(self.tested()), set(self.faults())
        return [
            kind
            for kind, tests in FAULT_TESTS.items()
            if not tested.intersection(tests) and kind not in named
        ]

    def blind(self) -> dict[str, float]:
        """The faults not named that no test could see after a frozen speed reading: from
        the first stuck-sensor alarm on, every model-based test reads a speed that no longer
        moves (no acceleration, no constant speed, no lag to measure), so worn bearings,
        a lowered current limit or a bias that comes with the stuck sensor goes unseen:
        said, not a silent miss. A weak motor is seen where the record has a settled
        speed change after the freeze (the ``charge`` test, whose coverage counts them).

        Returns
        -------
        dict of str to float
            Per fault (of :data:`ROTOR_FAULTS` and ``speed_sensor_bias``) not named before
            it: the time of the stuck alarm, s. Empty without one.
        """
        stuck = [a.t_s for a in self.alarms if a.kind == "speed_sensor_stuck"]
        if not stuck:
            return {}
        seen = {a.kind for a in self.alarms if a.t_s <= stuck[0]}
        if self.coverage.get("charge", {}).get("decided"):
            seen.add("torque_constant")
        kinds = (*ROTOR_FAULTS, "speed_sensor_bias")
        return {kind: stuck[0] for kind in kinds if kind not in seen}

    def model_tested(self) -> bool:
        """Whether any model-based test (all but rest, stuck, dropout) decided anything:
        False, and "no alarm" says nothing of friction, the motor, the current limit or
        a sensor bias."""
        return any(name not in TELEMETRY_TESTS for name in self.tested())

    def sizes(self) -> dict:
        """Each fault's one size: the consistent sizes of its alarms combined
        (:func:`~rwlab.diagnose.isolate.combine`), with the alarms' own sizes kept.

        Returns
        -------
        dict of str to dict
            Per fault: ``magnitude``, ``ci95``, ``unit``, ``detectors`` (the alarms
            combined) and ``left_out`` (those whose sizes disagree with them).
        """
        out = {}
        for kind in self.faults():
            alarms = [a for a in self.alarms if a.kind == kind]
            found = combine([Finding(a.kind, a.magnitude, a.ci, a.unit) for a in alarms])
            out[kind] = {
                "magnitude": found["magnitude"],
                "ci95": found["ci95"],
                "unit": found["unit"],
                "detectors": [alarms[i].detector for i in found["used"]],
                "left_out": [alarms[i].detector for i in found["left_out"]],
            }
        return out

    def residual_statistics(self) -> dict:
        """Mean, σ and largest |value| of each residual: before and after the first
        alarm, or over the whole record when nothing alarmed."""
        t = self.history["t_s"]
        first = min((a.t_s for a in self.alarms), default=None)
        if first is None:
            parts = {"whole_record": np.ones(t.shape, dtype=bool)}
        else:
            parts = {"before_alarm": t < first, "after_alarm": t >= first}
        out: dict[str, dict] = {}
        for name, unit in (("speed", "rpm"), ("acceleration", "rpm/s"), ("current", "A")):
            x = self.history[name]
            for part, mask in parts.items():
                v = x[mask & np.isfinite(x)]
                out.setdefault(name, {"unit": unit})[part] = (
                    {
                        "mean": float(v.mean()),
                        "std": float(v.std()),
                        "max_abs": float(np.abs(v).max()),
                    }
                    if v.size
                    else None
                )
        return out

    def to_dict(self) -> dict:
        return {
            "format": "rwlab.Diagnosis/3",
            "alarms": [a.to_dict() for a in self.alarms],
            "faults": self.faults(),
            "sizes": self.sizes(),
            "thresholds": self.thresholds,
            "false_alarms_per_hour_per_detector": self.false_alarms_per_hour,
            "duration_s": self.duration_s,
            "threshold_notes": list(self.notes),
            "coverage": {name: dict(c) for name, c in self.coverage.items()},
            "untested": self.untested(),
            "unseen_faults": self.unseen(),
            "blind_after_s": self.blind(),
            "model_tested": self.model_tested(),
            "estimates": {kind: dict(e) for kind, e in self.estimates.items()},
            "reference": self.reference.to_dict(),
            "residual_statistics": self.residual_statistics(),
        }


def record_columns(data: IOData, wheel):
    """Time, held command, speed, current, age and lost frames of a record, checked."""
    if not math.isclose(data.Ts, wheel.Ts, rel_tol=1e-6):
        raise DataError(
            f"the data are sampled at {data.Ts:g} s, the model at {wheel.Ts:g} s: load the "
            f"record on the model's grid, load_record(path, {wheel.Ts:g}, outputs=("
            f"{', '.join(repr(o) for o in RECORD_OUTPUTS)}))"
        )
    issued = data.source.get("Ts")  # a testbed record's command period, s
    if isinstance(issued, (int, float)) and not math.isclose(issued, wheel.Ts, rel_tol=1e-6):
        # a chirp commanded every 0.1 s, sampled at the model's 0.5 s, is not what the wheel
        # was given: the model lags it, and healthy chirps raised a current-limit alarm
        raise DataError(
            f"the record's commands came every {issued:g} s and the model runs at "
            f"{wheel.Ts:g} s: the model cannot follow the command the wheel was given; "
            f"record the test at --Ts {wheel.Ts:g}, or identify a model at {issued:g} s"
        )
    if data.nu != 1:
        raise DataError(f"diagnosis needs one input (the speed command), got {data.nu}")
    if data.input_units and data.input_units[0] == "rpm/s":
        raise DataError(
            "an acceleration-mode record cannot be diagnosed: the identified model maps a "
            "speed command to speed; record the test in speed mode"
        )
    names = list(data.output_names)
    if "speed_rpm" not in names:
        raise DataError(f"diagnosis needs a speed_rpm output, got {names}")

    def column(name, default):
        return data.y[:, names.index(name)] if name in names else np.full(data.N, default)

    u = data.u[:, 0]
    held = np.concatenate([u[:1], u[:-1]])  # the command in force over the last interval
    t = data.tstart + data.Ts * np.arange(data.N)
    return (
        t,
        held,
        column("speed_rpm", 0.0),
        column("current_a", math.nan),
        column("telemetry_age_s", 0.0),
        column("lost_frames", 0.0),
    )


def diagnose(
    data: IOData,
    wheel,
    reference: HealthyReference,
    *,
    false_alarms_per_hour: float = 1e-3,
    latch: bool = True,
    calibration: ThresholdCalibration | bool = True,
) -> Diagnosis:
    """Run the detector over a record's samples.

    Parameters
    ----------
    data : IOData
        u = speed command (rpm) issued at each sample; outputs ``speed_rpm`` and
        optionally ``current_a``, ``telemetry_age_s`` and ``lost_frames`` (as
        ``load_record(..., outputs=('speed', 'current', 'age', 'lost'))`` gives),
        sampled at the model's Ts.
    wheel : IdentifiedWheel
    reference : HealthyReference
        From the model file (:meth:`HealthyReference.from_model_file`).
    false_alarms_per_hour, latch, calibration :
        See :class:`Diagnoser`.

    Returns
    -------
    Diagnosis
        The alarms, thresholds and residual histories.

    Raises
    ------
    DataError
        Another Ts, no speed, no motor current, an acceleration-mode record.

    Warns
    -----
    RwlabWarning
        A fault none of whose tests had anything to decide on (a record too
        short, or without the motions they need): "no alarm" says nothing of it.

    Notes
    -----
    Without ``lost_frames`` the dropout test has nothing to decide on, without
    ``telemetry_age_s`` the stuck test takes every sample as a new reading (both
    said in ``coverage`` and ``notes``); without ``current_a`` the data are refused.
    """
    _require_current(data, wheel)
    t, held, speed, current, age, lost = record_columns(data, wheel)
    d = Diagnoser(
        wheel,
        reference,
        false_alarms_per_hour=false_alarms_per_hour,
        latch=latch,
        calibration=calibration,
    )
    for k in range(data.N):
        d.update(float(t[k]), float(held[k]), speed[k], current[k], age[k], lost[k])
    coverage = d.coverage()
    notes = list(d.notes)
    if "lost_frames" not in data.output_names:  # a degraded run, said so
        why = "the data have no lost_frames output (load_record(..., outputs=(..., 'lost')))"
        coverage["dropout"] = {"decided": 0, "unit": DECIDES_ON["dropout"], "why": why}
        notes.append(f"dropout: not tested, {why}")
    if "telemetry_age_s" not in data.output_names:
        notes.append(
            "stuck: the data have no telemetry_age_s output, so a sample without a new "
            "frame counts as a reading (a held frame may read as a frozen sensor)"
        )
    result = Diagnosis(
        d.alarms,
        d.thresholds,
        reference,
        {k: np.asarray(v, dtype=float) for k, v in d.history.items()},
        false_alarms_per_hour,
        data.N * data.Ts,
        notes,
        coverage,
        d.estimates(),
    )
    if result.unseen():
        warnings.warn(
            f"the record ({result.duration_s:g} s) gave no test that names "
            f"{', '.join(result.unseen())} anything to decide on: no alarm says nothing of "
            + ("them" if len(result.unseen()) > 1 else "it")
            + "; record at least 20 minutes of a test signal with speeds held at both signs",
            RwlabWarning,
            stacklevel=2,
        )
    return result


def _require_current(data: IOData, wheel) -> None:
    """Refuse data without the motor current: every rotor test reads it (load_record's
    default gives the speed alone, and a silent run named k_t × 0.8 a current limit)."""
    names = list(data.output_names)
    if "current_a" in names:
        return
    outputs = ", ".join(repr(o) for o in RECORD_OUTPUTS)
    raise DataError(
        f"diagnosis needs the motor current (a current_a output), got {names}: load the "
        f"record with load_record(path, {wheel.Ts:g}, outputs=({outputs}))"
    )
