"""The fault detector: calibrate on a healthy start, then test every sample.

One :class:`Diagnoser` serves both uses: ``rwlab diagnose`` feeds it a
record's samples in a loop (:func:`diagnose`), and the experiment runner feeds
it each sample as it arrives, so offline and live alarms are the same.

1. **Calibration** (the first ``calibration_s`` seconds, assumed fault-free):
   the current balance is fitted (:func:`~rwlab.diagnose.residuals.fit_current_model`);
   the speed and current residuals get their mean and an AR(2) whitening filter
   (:func:`rwlab.ident.ar`, forward-backward least squares), whose innovation σ
   normalises them; the probability that a steady reading repeats exactly
   (quantised Hall speed) is counted.
2. **Detection**, with thresholds from ``false_alarms_per_hour`` (per detector,
   derivations in :mod:`rwlab.diagnose.detect`):

   - ``speed`` and ``current``: two-sided CUSUMs (reference k = 0.5 σ, i.e. tuned
     to a 1 σ shift) on the whitened residuals; the current residual is taken
     in the direction of rotation (sign ω · r_i), so friction and a weak motor
     both push it up;
   - ``stuck``: a run of identical non-zero speed readings, with the run length
     from the calibrated repeat probability;
   - ``dropout``: a sample whose newest telemetry frame is older than Ts
     (deterministic: a whole sample period without a frame).

   Each detector alarms once and then stays latched, as the faults it looks
   for do not heal. Stale samples (no new frame) and the one after them do not
   enter the tests.
3. **Isolation** (:mod:`rwlab.diagnose.isolate`) names the likely fault from
   the last minute's residual signature when a detector alarms.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from rwlab.data import IOData
from rwlab.diagnose.detect import Cusum, RunTest, arl_to_samples, cusum_threshold, run_length
from rwlab.diagnose.isolate import isolate
from rwlab.diagnose.residuals import ResidualGenerator, fit_current_model
from rwlab.errors import ConfigError, DataError

__all__ = ["Alarm", "Diagnoser", "Diagnosis", "diagnose"]

AR_ORDER = 2
CUSUM_K = 0.5
WINDOW_S = 60.0  # the signature window for isolation, s
QUIET_RPM_S = 10.0  # |measured acceleration| below ≈ 7 σ of its noise at Ts = 0.5 s
SETTLE_S = 30.0  # steady: the command has not changed for this long, s (wheel and model settled)


@dataclass(frozen=True)
class Alarm:
    """One alarm: when (s, sample time), which fault is likely, which detector fired.

    Parameters
    ----------
    t_s : float
        Time of the alarm, s from the record's start.
    kind : str
        The likely fault (``friction``, ``speed_sensor_stuck``, ...).
    statistic : float
        The detector's statistic when it fired.
    detector : str
        Which detector fired.
    threshold : float
        Its threshold.
    """

    t_s: float
    kind: str
    statistic: float
    detector: str
    threshold: float

    def to_dict(self) -> dict:
        return {
            "t_s": self.t_s,
            "kind": self.kind,
            "statistic": self.statistic,
            "detector": self.detector,
            "threshold": self.threshold,
        }


def _segments(x: np.ndarray, keep: np.ndarray) -> list[np.ndarray]:
    """The runs of ``x`` where ``keep`` holds, longer than the AR order."""
    edges = np.flatnonzero(np.diff(np.r_[0, keep.astype(int), 0]))
    return [x[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a > AR_ORDER]


class _Whitener:
    """(r − μ) filtered by A(q) of an AR model, divided by the innovation σ.

    Fitted on one or several segments of healthy residuals; ``restart`` forgets
    the past (a gap), and the next ``AR_ORDER`` samples give no innovation.
    """

    def __init__(self, segments: list[np.ndarray], Ts: float) -> None:
        from rwlab.ident import ar

        if not segments:
            raise DataError("no calibration segment is long enough to fit the whitening filter")
        self.mean = float(np.mean(np.concatenate(segments)))
        model = ar([IOData(None, x - self.mean, Ts) for x in segments], AR_ORDER)
        self.A = np.asarray(model.A, dtype=float)
        self.sigma = math.sqrt(model.noise_variance)
        if not self.sigma > 0:
            raise DataError("a residual is constant on the calibration data; nothing to normalise")
        self._past: deque = deque(maxlen=AR_ORDER)

    def restart(self) -> None:
        self._past.clear()

    def __call__(self, r: float) -> float | None:
        x = r - self.mean
        full = len(self._past) == AR_ORDER
        e = x + sum(a * p for a, p in zip(self.A[1:], self._past, strict=False))
        self._past.appendleft(x)
        return e / self.sigma if full else None


class Diagnoser:
    """Residuals, detectors and isolation, fed one sample at a time.

    Parameters
    ----------
    wheel : IdentifiedWheel
        The identified model; the samples come at its Ts.
    calibration_s : float
        Length of the healthy start used to calibrate, s.
    false_alarms_per_hour : float
        Wanted false-alarm rate of each detector on healthy data (sets the thresholds).
    speed_test : bool
        Also run the speed-residual CUSUM (in steady holds). Off by default: with
        paper A's linear model (ARX221 in its rate-limit wrapper) the speed
        residual drifts in a hold by up to ~1 rpm per sample, more than the
        sensor noise the test is normalised by, so it false-alarms on healthy
        records. With the nonlinear servo model (issue 14, ``model.json``'s
        preferred model since then) the healthy speed residual is ≈ the sensor
        noise (σ ≈ 0.5 rpm over 2 h) and the test can be turned on.
    """

    def __init__(
        self,
        wheel,
        *,
        calibration_s: float = 300.0,
        false_alarms_per_hour: float = 1e-3,
        speed_test: bool = False,
    ) -> None:
        self.Ts = float(wheel.Ts)
        if not (math.isfinite(calibration_s) and calibration_s >= 60 * self.Ts):
            raise ConfigError(f"calibration_s must be ≥ 60 samples, got {calibration_s} s")
        self.calibration_s = float(calibration_s)
        self.speed_test = bool(speed_test)
        self.false_alarms_per_hour = float(false_alarms_per_hour)
        self.arl0 = arl_to_samples(false_alarms_per_hour, self.Ts)
        self.residuals = ResidualGenerator(wheel)
        self.history: dict[str, list[float]] = {
            name: []
            for name in ("t_s", "speed", "acceleration", "current", "stat_speed", "stat_current")
        }
        self.alarms: list[Alarm] = []
        self.calibration: dict = {}
        self._calib: list[tuple] = []
        self._detectors: dict = {}
        self._recent: deque = deque(maxlen=max(2, round(WINDOW_S / self.Ts)))
        self._last_speed: float | None = None
        self._was_stale = True
        self._t0: float | None = None
        self._command: tuple[float, float] = (math.nan, -math.inf)  # (value, since when)

    # -- one sample ----------------------------------------------------------------------
    def update(
        self, t_s: float, command_rpm: float, speed_rpm: float, current_a: float, age_s: float
    ) -> list[Alarm]:
        """Take the sample at ``t_s`` (command held since the last sample); new alarms."""
        if self._t0 is None:
            self._t0 = t_s
        r = self.residuals.update(command_rpm, speed_rpm, current_a)
        if command_rpm != self._command[0]:
            self._command = (command_rpm, t_s)
        r["steady"] = t_s - self._command[1] >= SETTLE_S
        stale = age_s >= self.Ts
        usable = not (stale or self._was_stale)
        self._was_stale = stale
        repeat = speed_rpm != 0 and speed_rpm == self._last_speed
        self._last_speed = speed_rpm
        new: list[Alarm] = []
        if stale and "dropout" in self._detectors:
            new += self._fire(t_s, "dropout", age_s, self.Ts)
        if not self._detectors:
            if usable:
                self._calib.append(
                    (r["accel_rpm_s"], speed_rpm, current_a, r["speed"], repeat, r["steady"])
                )
            if t_s - self._t0 >= self.calibration_s:
                self._calibrate()
        elif usable:
            new += self._test(t_s, r, speed_rpm, current_a, repeat)
        self._record(t_s, r)
        return new

    def _record(self, t_s: float, r: dict) -> None:
        h = self.history
        h["t_s"].append(t_s)
        for name in ("speed", "acceleration", "current"):
            h[name].append(r[name])
        for name in ("speed", "current"):
            det = self._detectors.get(name)
            h[f"stat_{name}"].append(det.statistic if det is not None else math.nan)

    # -- calibration ---------------------------------------------------------------------
    def _calibrate(self) -> None:
        rows = self._calib
        if len(rows) < 60:
            raise DataError(
                f"only {len(rows)} usable samples in the {self.calibration_s:g} s calibration "
                "window; the detector needs ≥ 60"
            )
        accel, speed, current, r_speed, repeat, steady = (
            np.array(c) for c in zip(*rows, strict=True)
        )
        if self.speed_test and steady.sum() < 30:
            raise DataError(
                f"only {steady.sum()} steady samples in the {self.calibration_s:g} s calibration "
                "window; the speed test needs ≥ 30 (hold the command longer, or calibrate longer)"
            )
        thresholds = {"dropout": self.Ts}
        h = cusum_threshold(self.arl0, CUSUM_K)
        self._detectors, self._white = {"dropout": None}, {}
        if self.speed_test:
            self._white["speed"] = _Whitener(_segments(r_speed, steady), self.Ts)
            self._detectors["speed"] = Cusum(h, CUSUM_K)
            thresholds["speed"] = h
        if np.isfinite(current).all():
            coef = fit_current_model(accel, speed, current)
            self.residuals.current_model = coef
            fitted = np.column_stack([accel, speed, np.sign(speed), np.ones_like(speed)]) @ coef
            self._white["current"] = _Whitener([np.sign(speed) * (current - fitted)], self.Ts)
            self._detectors["current"] = Cusum(h, CUSUM_K)
            thresholds["current"] = h
            self.calibration["current_model"] = dict(
                zip(
                    ("a_per_rpm_s", "a_per_rpm", "a_coulomb", "a_offset"),
                    coef.tolist(),
                    strict=True,
                )
            )
            self.calibration["current_peak_a"] = float(np.max(np.abs(current)))
        if steady.sum() < 30:  # few settled holds: samples whose speed barely changes
            steady = np.abs(accel) < QUIET_RPM_S
        p = (repeat[steady].sum() + 1) / (steady.sum() + 2)  # Laplace's rule: never 0 or 1
        n = run_length(self.arl0, p)
        self._detectors["stuck"] = RunTest(n)
        thresholds["stuck"] = n
        self.thresholds = thresholds
        self.calibration.update(
            samples=len(rows),
            repeat_probability=float(p),
            repeat_samples=int(steady.sum()),  # the settled samples p was counted on
            whitening={
                name: {"mean": w.mean, "A": w.A.tolist(), "sigma": w.sigma}
                for name, w in self._white.items()
            },
        )

    # -- detection -------------------------------------------------------------------------
    def _test(self, t_s: float, r: dict, speed_rpm: float, current_a: float, repeat: bool):
        sign = 0.0 if speed_rpm == 0 else math.copysign(1.0, speed_rpm)
        self._recent.append((r["speed"], r["accel_rpm_s"], speed_rpm, r["current"], current_a))
        new = []
        if "speed" not in self._detectors:
            pass
        elif not r["steady"]:
            self._white["speed"].restart()
        elif (z := self._white["speed"](r["speed"])) is not None:
            if self._detectors["speed"].update(z):
                new += self._fire(t_s, "speed")
        if "current" in self._detectors and math.isfinite(r["current"]):
            z = self._white["current"](sign * r["current"])
            if z is not None and self._detectors["current"].update(z):
                new += self._fire(t_s, "current")
        if self._detectors["stuck"].update(repeat):
            new += self._fire(t_s, "stuck")
        return new

    def _fire(self, t_s: float, detector: str, statistic=None, threshold=None) -> list[Alarm]:
        if any(a.detector == detector for a in self.alarms):
            return []  # latched
        det = self._detectors[detector]
        alarm = Alarm(
            t_s,
            isolate(detector, np.array(self._recent), self.calibration),
            float(det.statistic if statistic is None else statistic),
            detector,
            float(self.thresholds[detector] if threshold is None else threshold),
        )
        self.alarms.append(alarm)
        return [alarm]

    @property
    def calibrated(self) -> bool:
        return bool(self._detectors)


@dataclass
class Diagnosis:
    """What :func:`diagnose` found in a record.

    Parameters
    ----------
    alarms : list of Alarm
        In time order.
    thresholds : dict
        Each detector's threshold.
    calibration : dict
        What the healthy start of the record calibrated (whitening, current model).
    history : dict of str to numpy.ndarray
        The residuals and statistics at every sample (``t_s``, ``speed``, ...).
    false_alarms_per_hour : float
        The false-alarm rate the thresholds were set for, per detector.
    calibration_s : float
        Length of the calibration window, s.
    """

    alarms: list[Alarm]
    thresholds: dict
    calibration: dict
    history: dict[str, np.ndarray]
    false_alarms_per_hour: float
    calibration_s: float

    def residual_statistics(self) -> dict:
        """Mean, σ and largest |value| of each residual, before and after the first alarm."""
        t = self.history["t_s"] - self.history["t_s"][0]
        first = min((a.t_s for a in self.alarms), default=math.inf)
        out = {}
        for name, unit in (("speed", "rpm"), ("acceleration", "rpm/s"), ("current", "A")):
            x = self.history[name]
            for part, mask in (("before_alarm", t < first), ("after_alarm", t >= first)):
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
            "format": "rwlab.Diagnosis/1",
            "alarms": [a.to_dict() for a in self.alarms],
            "thresholds": self.thresholds,
            "false_alarms_per_hour_per_detector": self.false_alarms_per_hour,
            "calibration_s": self.calibration_s,
            "calibration": self.calibration,
            "residual_statistics": self.residual_statistics(),
        }


def diagnose(
    data: IOData,
    wheel,
    *,
    calibration_s: float = 300.0,
    false_alarms_per_hour: float = 1e-3,
    speed_test: bool = False,
) -> Diagnosis:
    """Run the detector over a record's samples.

    Parameters
    ----------
    data : IOData
        u = speed command (rpm); outputs ``speed_rpm`` and optionally
        ``current_a`` and ``telemetry_age_s`` (as ``load_record(..., outputs=
        ('speed', 'current', 'age'))`` gives), sampled at the model's Ts.
    wheel : IdentifiedWheel
    calibration_s, false_alarms_per_hour, speed_test :
        See :class:`Diagnoser`.

    Returns
    -------
    Diagnosis
        The alarms, thresholds and residual histories.
    """
    if not math.isclose(data.Ts, wheel.Ts, rel_tol=1e-6):
        raise DataError(f"the data are sampled at {data.Ts} s, the model at {wheel.Ts} s")
    if data.nu != 1:
        raise DataError(f"diagnosis needs one input (the speed command), got {data.nu}")
    names = list(data.output_names)
    if "speed_rpm" not in names:
        raise DataError(f"diagnosis needs a speed_rpm output, got {names}")

    def column(name, default):
        return data.y[:, names.index(name)] if name in names else np.full(data.N, default)

    speed, current, age = (
        column("speed_rpm", 0),
        column("current_a", math.nan),
        column("telemetry_age_s", 0.0),
    )
    u = data.u[:, 0]
    d = Diagnoser(
        wheel,
        calibration_s=calibration_s,
        false_alarms_per_hour=false_alarms_per_hour,
        speed_test=speed_test,
    )
    t = data.tstart + data.Ts * np.arange(data.N)
    for k in range(data.N):
        d.update(float(t[k]), float(u[k - 1] if k else u[0]), speed[k], current[k], age[k])
    if not d.calibrated:
        raise DataError(
            f"the record ({data.N * data.Ts:g} s) is shorter than the calibration window "
            f"({calibration_s:g} s)"
        )
    return Diagnosis(
        d.alarms,
        d.thresholds,
        d.calibration,
        {k: np.asarray(v, dtype=float) for k, v in d.history.items()},
        false_alarms_per_hour,
        calibration_s,
    )
