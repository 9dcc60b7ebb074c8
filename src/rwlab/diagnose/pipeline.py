"""The diagnosis pipeline: residuals → evaluation → decision → isolation → sizing.

:func:`run` takes a record's features (:mod:`~rwlab.diagnose.features`), the
calibration (:mod:`~rwlab.diagnose.wheel_calibration`) and a false-alarm rate:

1. evaluation and decision: every model-based detector's GLR statistic at
   each decision time (:class:`~rwlab.diagnose.bank.Bank`) against its
   threshold for the rate; the stuck and dropout tests on the telemetry;
2. isolation: when any statistic crosses its threshold, every fault model is
   fitted on the same samples and the largest log-likelihood ratio beyond that
   model's healthy level (its threshold: a fault model's misfit on a healthy
   wheel is measured, not assumed) names the fault, then again on the window from
   its onset; the runner-up on that window and its log-likelihood ratio to the
   winner on that scale are kept;
3. the event then follows the record: its window grows from its onset, the
   faults that share its signature channel (:data:`SIGNATURE`) are refitted on
   it, and one that becomes better supported re-labels the event (the history
   is kept). A fault on another channel opens an event of its own (two faults);
4. sizing: each event's size and 95 % interval are its fault's profile
   likelihood on the event's window at the record's end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rwlab.diagnose.bank import Bank, WindowFit, widened
from rwlab.diagnose.detectors import (
    MODEL_BASED,
    REGISTRY,
    SIGNATURE,
    Fit,
    FrozenReading,
    LostFrames,
)
from rwlab.diagnose.detectors.base import crossing
from rwlab.diagnose.features import Features
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, Threshold
from rwlab.errors import ConfigError

__all__ = ["Event", "Live", "Result", "run"]


@dataclass
class Event:
    """One fault found: when, what, how large, and how sure.

    Attributes
    ----------
    t_s : float
        Alarm time, s.
    onset_s : float
        Start of the window that raised it, s.
    fit : Fit
        The named fault, its size and 95 % interval (at the record's end).
    detector : str
        The detector whose threshold was crossed.
    threshold : float
        That threshold (log-LR).
    runner_up : str or None
        The next most likely fault at the alarm, fitted on the same window (from the
        onset).
    runner_up_log_lr : float or None
        ln(L(named) / L(runner-up)) on that window, each beyond its threshold.
    relabelled : list of (float, str)
        (time s, earlier name) for each re-labelling.
    start : int
        Sample index where the window that raised it starts.
    first : str
        The fault named at the alarm (set from ``fit``).
    at_alarm : Fit
        The fit at the alarm, of the fault named then (``fit`` follows the record).
    """

    t_s: float
    onset_s: float
    fit: Fit
    detector: str
    threshold: float
    runner_up: str | None = None
    runner_up_log_lr: float | None = None
    relabelled: list[tuple[float, str]] = field(default_factory=list)
    start: int = 0

    def __post_init__(self) -> None:
        self.first = self.fit.fault  # the name at the alarm
        self.at_alarm = self.fit  # the fit at the alarm (``fit`` follows the record)

    @property
    def fault(self) -> str:
        """The fault named now (after any re-labelling)."""
        return self.fit.fault

    def to_dict(self) -> dict:
        f, a = self.fit, self.at_alarm
        return {
            "t_s": self.t_s,
            "onset_s": self.onset_s,
            "fault": f.fault,
            "size": _number(f.size),
            "ci95": None if math.isnan(f.ci95[0]) else list(f.ci95),
            "unit": f.unit,
            "log_lr": f.log_lr,
            "detector": self.detector,
            "threshold": self.threshold,
            "runner_up": self.runner_up,
            "runner_up_log_lr": self.runner_up_log_lr,
            "relabelled": [{"t_s": t, "was": was} for t, was in self.relabelled],
            "at_alarm": {
                "fault": self.first,
                "size": _number(a.size),
                "ci95": None if math.isnan(a.ci95[0]) else list(a.ci95),
                "unit": a.unit,
            },
        }


@dataclass
class Result:
    """What :func:`run` found.

    Attributes
    ----------
    events : list of Event
        In alarm order.
    thresholds : dict of str to Threshold
    duration_s : float
    per_hour : float
        The false-alarm rate asked, per detector.
    unseen : list of str
        The model-based faults the record cannot tell from healthy (:meth:`Live.unseen`):
        "no alarm" says nothing of them.
    statistics : dict of str to list of (float, float)
        Each detector's (decision time s, log-LR) at the decisions it was evaluated at
        (a fault named is followed, not tested again).
    detectable : dict of str to (float, float)
        Per model-based fault, the smallest sizes below and above the healthy ones the
        record would have shown from its start (:meth:`Live.detectable`; NaN: none).
    """

    events: list[Event]
    thresholds: dict[str, Threshold]
    duration_s: float
    per_hour: float
    unseen: list[str] = field(default_factory=list)
    statistics: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    detectable: dict[str, tuple[float, float]] = field(default_factory=dict)

    def to_dict(self, calibration: str = "") -> dict:
        """The JSON form (``rwlab.FdiDiagnosis/1``): the verdict first."""
        return {
            "format": "rwlab.FdiDiagnosis/1",
            "verdict": self.verdict(),
            "events": [e.to_dict() | {"confirmed": self.confirmed(e)} for e in self.events],
            "duration_s": self.duration_s,
            "false_alarms_per_hour_per_detector": self.per_hour,
            "calibration": calibration,
            "thresholds": {
                name: {
                    "log_lr": t.log_lr,
                    "measured_per_hour": t.measured_per_hour,
                    "ci95_per_hour": list(t.ci95_per_hour),
                    "extrapolated": t.extrapolated,
                }
                for name, t in self.thresholds.items()
            },
            "unseen": list(self.unseen),
            "detectable": {
                n: {"below": _number(lo), "above": _number(hi)}
                for n, (lo, hi) in self.detectable.items()
            },
        }

    def faults(self) -> list[str]:
        """The faults named, in alarm order."""
        return [e.fault for e in self.events]

    def confirmed(self, event: Event) -> bool:
        """Whether the record still supports an alarm at its end: the named fault's fit on
        the window from its onset to the record's end is beyond its threshold (a noise
        excursion's support fades as the window grows; a fault's grows). The telemetry
        tests' alarms (a frozen reading, lost frames) stand."""
        limit = self.thresholds.get(event.fault)
        return event.fault not in MODEL_BASED or limit is None or event.fit.log_lr > limit.log_lr

    def verdict(self) -> str:
        """One line: healthy, or each confirmed fault with its size, interval and alarm
        time, then the alarms the record no longer supports."""
        if not self.events:
            line = f"healthy: no alarm in {self.duration_s:g} s at {self.per_hour:g} false alarms/h"
            seen = [_beyond(n, *sizes) for n, sizes in self.detectable.items()]
            seen = [text for text in seen if text]
            if seen:
                line += "; from its start, on any healthy unit, it would have shown " + ", ".join(
                    seen
                )
            if self.unseen:
                line += "; not seen (the record cannot tell them from healthy): "
                line += ", ".join(self.unseen)
            return line
        found, faded = [], []
        for e in self.events:
            f = e.fit
            if not self.confirmed(e):
                faded.append(f"{f.fault} at {e.t_s:g} s")
                continue
            found.append(" ".join(filter(None, (f.fault, f.size_text(), f"from {e.t_s:g} s"))))
        line = "; ".join(found) if found else "healthy"
        if faded:
            line += "; not confirmed by the record's end: " + ", ".join(faded)
        return line


def _beyond(fault: str, below: float, above: float) -> str:
    """'friction above ×1.9', 'current_limit below 0.45 A', 'bias below -3 or above 4 rpm';
    empty where neither side is seen."""
    unit = REGISTRY[fault].unit

    def size(x: float) -> str:
        return f"×{x:.3g}" if unit == "factor" else f"{x:.3g} {unit}"

    pairs = (("below", below), ("above", above))
    sides = [f"{word} {size(x)}" for word, x in pairs if not math.isnan(x)]
    return f"{fault} {' or '.join(sides)}" if sides else ""


def _number(x: float) -> float | None:
    """JSON's number: None for NaN."""
    return None if math.isnan(x) else x


def _onset(bank: Bank, fault: str, k: int) -> int:
    """The change time's maximum-likelihood estimate: the window start, on the decision
    grid within the longest window before k, whose fit of ``fault`` has the largest log-LR
    (a window reaching back before the onset mixes healthy samples in and fits worse).

    Of starts that tie, the latest: a fault whose model predicts no residual on most
    samples (a clamp between the pushes it cuts) fits every start before its first
    effect equally, and the earliest would measure its rivals, named on this window,
    over healthy samples that dilute them (a drag read as a clamp in one push)."""
    starts = np.arange(max(0, k - bank.windows[-1]), k - 1, bank.every)
    ll = np.array([bank.fit(fault, int(a), k).fit.log_lr for a in starts])
    tied = np.isclose(ll, ll.max(), rtol=1e-9, atol=1e-6)
    return int(starts[np.nonzero(tied)[0][-1]])


def _owned(events) -> frozenset[str]:
    """The channels the events' faults, first and present names, already explain."""
    out: frozenset[str] = frozenset()
    for e in events:
        out |= SIGNATURE[e.first] | SIGNATURE[e.fault]
    return out


def _excess(fit: Fit, limits: dict[str, Threshold]) -> float:
    """A fit's log-LR beyond what healthy records reach at the rate asked: the model's
    misfit on a healthy wheel differs between fault models (a clamp model fits the
    back-EMF limit of a healthy wheel at high speed), so the raw log-LRs of two fault
    models compare only beyond their own healthy level."""
    return fit.log_lr - limits[fit.fault].log_lr


def _follow(e: Event, events: list[Event], bank: Bank, k: int, limits) -> None:
    """Refit event ``e``'s rivals on its window up to sample k and name it by the likeliest.

    The rivals share a channel with ``e``'s first name and leave the other events'
    channels alone, or explain another event's whole signature: one fault where two
    events stand (a weak motor first read as friction at constant speed, then as a clamp
    at the acceleration limit) absorbs those events when it is likelier than the two
    faults together (their excesses over their thresholds add: their channels are
    disjoint; an event under its threshold adds none). With no rival left, ``e``'s
    fault is refitted on its window as it stands."""
    others = [x for x in events if x is not e]

    def covered(n: str) -> list[Event]:
        return [x for x in others if SIGNATURE[n] & _owned([x])]

    rivals = [
        n
        for n in MODEL_BASED
        if SIGNATURE[n] & SIGNATURE[e.first]
        and all(SIGNATURE[n] >= _owned([x]) for x in covered(n))
    ]
    fits = sorted((bank.fit(n, e.start, k) for n in rivals), key=lambda w: -_excess(w.fit, limits))
    alone = [w for w in fits if not covered(w.fit.fault)]
    best = alone[0] if alone else bank.fit(e.fault, e.start, k)
    t = float(bank.features.t_s[k - 1])
    for w in fits:
        # an event no longer beyond its threshold adds nothing (it would not stand alone)
        two = max(_excess(best.fit, limits), 0.0) + sum(
            max(_excess(x.fit, limits), 0.0) for x in covered(w.fit.fault)
        )
        if covered(w.fit.fault) and _excess(w.fit, limits) > two:
            for x in covered(w.fit.fault):
                events.remove(x)
                e.relabelled.append((t, x.fault))
            best = w
            break
    if best.fit.fault != e.fault:
        e.relabelled.append((t, e.fault))
    e.fit = best.fit


def _detectable(
    grid: np.ndarray, ll: np.ndarray, threshold: float, zone: tuple[float, float]
) -> tuple[float, float]:
    """The sizes beyond which a fault on these samples would cross ``threshold``: (below,
    above) the healthy ``zone``, NaN where no size of the grid does.

    The residuals are linear in a fault's size (Gaussian about a small fault): had a fault
    of size θ been there, the window's profile log-likelihood would peak at θ with the
    curvature it has now, and its log-LR would be the profile's drop over θ's distance to
    the zone. So the distance at which the observed profile falls ``threshold`` below its
    top, on each side, is how far beyond the zone a fault must lie to be seen.
    """
    top = int(ll.argmax())
    cut = float(ll[top]) - threshold
    out = []
    for side, edge in ((-1, zone[0]), (1, zone[1])):
        under = np.nonzero(ll < cut)[0]
        beyond = under[under > top] if side > 0 else under[under < top]
        if not beyond.size:
            out.append(math.nan)
            continue
        j = int(beyond.min() if side > 0 else beyond.max())
        reach = abs(crossing(grid, ll, float(ll[top]), cut, j - side, side) - grid[top])
        size = edge + side * reach
        out.append(float(size) if grid[0] <= size <= grid[-1] else math.nan)
    return out[0], out[1]


def _runner_up(e: Event, bank: Bank, k: int, limits) -> tuple[str | None, float | None]:
    """The likeliest other fault on event ``e``'s window (from its onset to sample k), and
    the log-LR of ``e``'s fault over it, each beyond its threshold."""
    rivals = [bank.fit(n, e.start, k).fit for n in MODEL_BASED if n != e.fault]
    if not rivals:
        return None, None
    runner = max(rivals, key=lambda f: _excess(f, limits))
    return runner.fault, _excess(e.fit, limits) - _excess(runner, limits)


def _isolate(bank: Bank, k: int, names, limits) -> list[WindowFit]:
    """Every candidate fault on its best window ending at k, most likely first."""
    return sorted((bank.at(n, k) for n in names), key=lambda w: -_excess(w.fit, limits))


# design choice: an alarm once a threshold has been crossed at this many consecutive
# decisions, the fault then named by its likeliest model on the window from its onset (as
# an open event is followed): at a first crossing a clamp, a weak motor and a drag were
# often named one for another and re-labelled at the next decision
# (docs/workflows/diagnosis-glr.md, "Named at the alarm")
CONFIRM_DECISIONS = 2


class Live:
    """The pipeline on a growing record (a wheel's telemetry in flight): each
    :meth:`update` takes the record so far and decides at the decision times new since
    the last one, as :func:`run` would on the whole record (a sample's features depend on
    its past only; the bank keeps the gains it has, :class:`~rwlab.diagnose.bank.Bank`'s
    ``before``).

    Parameters
    ----------
    calibration : DiagnosisCalibration
    per_hour : float
        False alarms per hour asked of each detector.

    Attributes
    ----------
    events : list of Event
        Every event so far, in alarm order (their names and sizes follow the record).
    limits : dict of str to Threshold
        Each detector's threshold at the rate asked.
    decisions : int
        Decision times taken so far.
    statistics : dict of str to list of (float, float)
        Each free detector's (decision time s, log-LR) at each decision.
    """

    def __init__(self, calibration: DiagnosisCalibration, per_hour: float = 1e-3) -> None:
        self.calibration, self.per_hour = calibration, per_hour
        names = (*MODEL_BASED, "speed_sensor_stuck")
        self.limits = {n: calibration.threshold(n, per_hour) for n in names}
        self.events: list[Event] = []
        self._bank: Bank | None = None
        self._done = 0  # the last decision time taken (exclusive sample index)
        self.decisions = 0  # decision times taken
        self._telemetry_named: set[str] = set()
        self.statistics: dict[str, list[tuple[float, float]]] = {}
        self._crossings = 0  # consecutive decisions with a threshold crossed

    def update(self, features: Features) -> list[Event]:
        """Decide on the record so far.

        Parameters
        ----------
        features : Features
            The whole record so far (the samples of earlier updates and new ones).

        Returns
        -------
        list of Event
            The events opened by this update, in alarm order.
        """
        cal, limits = self.calibration, self.limits
        self.check_sample_time(features.scales.Ts)
        # what a later decision reads: its longest window back from the last decision,
        # and each open event's window from its onset
        old = self._bank
        keep = [0 if old is None else self._done - old.windows[-1] - old.every]
        keep += [e.start for e in self.events if e.first in MODEL_BASED]
        bank = self._bank = Bank(
            features,
            cal.noise,
            cal.zones,
            cal.drift,
            cal.dispersion,
            quick_s=cal.quick_window_s,
            before=old,
            keep_from=max(0, min(keep)),
        )
        events, new = self.events, []
        stuck = FrozenReading().first_alarm(features, limits["speed_sensor_stuck"].log_lr)
        end = features.N if stuck is None else stuck[0]  # a frozen reading blinds the models
        for k in bank.ends():
            if k <= self._done:
                continue
            if k > end:
                break
            self._done = k
            self.decisions += 1
            for e in list(events):  # follow each open event on its growing window
                if e in events and e.first in MODEL_BASED:
                    _follow(e, events, bank, k, limits)
            free = [n for n in MODEL_BASED if not SIGNATURE[n] & _owned(events)]
            fits = {n: bank.at(n, k).fit for n in free}
            for n, fit in fits.items():
                self.statistics.setdefault(n, []).append((float(features.t_s[k - 1]), fit.log_lr))
            crossed = [n for n in free if fits[n].log_lr > limits[n].log_lr]
            self._crossings = self._crossings + 1 if crossed else 0
            if self._crossings >= CONFIRM_DECISIONS:  # held: named on its onset's window
                e = self._open(bank, k, free, crossed)
                events.append(e)
                named = e.fault
                _follow(e, events, bank, k, limits)
                if e.fault != named:  # its name at the alarm, not the decision windows'
                    e.relabelled.remove((float(bank.features.t_s[k - 1]), named))
                    e.first = e.fault
                    # its onset is this fault's, not the decision windows' winner's
                    e.start = _onset(bank, e.fault, k)
                    e.onset_s = float(features.t_s[e.start])
                    e.fit = bank.fit(e.fault, e.start, k).fit
                e.at_alarm = e.fit  # the fit on its onset's window, as named
                e.runner_up, e.runner_up_log_lr = _runner_up(e, bank, k, limits)
                new.append(e)
                self._crossings = 0
        dropout = LostFrames().first_alarm(features, cal.lost_per_sample, self.per_hour)
        for found in (stuck, dropout):
            if found is not None and found[1].fault not in self._telemetry_named:
                self._telemetry_named.add(found[1].fault)
                k, fit = found
                t = float(features.t_s[k])
                new.append(Event(t, t, fit, fit.fault, fit.log_lr))
                events.append(new[-1])
        return new

    def check_sample_time(self, Ts: float) -> None:
        """Refuse records at another sample time than the calibration's.

        Parameters
        ----------
        Ts : float
            The records' sample time, s.

        Raises
        ------
        ConfigError
        """
        if not math.isclose(Ts, self.calibration.Ts, rel_tol=1e-6):
            raise ConfigError(
                f"the calibration was measured at Ts = {self.calibration.Ts:g} s, the record "
                f"is at {Ts:g} s: calibrate on records at the model's Ts (rwlab diagnose "
                "calibrate RECORDS... --model model.json --out calibration.json)"
            )

    def detectable(self, unit_spread: bool = True) -> dict[str, tuple[float, float]]:
        """Per model-based fault, the smallest sizes the record so far would have shown
        had the fault been there from its start: (below, above) the healthy sizes, NaN
        on a side no size of the grid reaches or the fault never takes
        (:attr:`Detector.worse`); the smallest over the record's back-to-back longest
        windows (:meth:`~rwlab.diagnose.bank.Bank.tiles`, the whole record if shorter),
        against the population, as a fault from power-up is decided.

        Parameters
        ----------
        unit_spread : bool
            Sizes of the unit's own, wherever it sits in the healthy units' spread
            (:func:`~rwlab.diagnose.bank.widened`: friction × F shows on a unit at the
            spread's low end only when F × that end is past the bound); False: sizes on
            the reference unit's scale, as the detector's grid.

        Returns
        -------
        dict of str to (float, float)
        """
        bank = self._bank
        if bank is None:
            return {n: (math.nan, math.nan) for n in MODEL_BASED}
        out = {}
        for n in MODEL_BASED:
            det, grid, zone = bank.detectors[n], bank.grid[n], bank.zone_bounds[n]
            lo, hi = math.nan, math.nan
            for a, k in bank.tiles() or [(0, bank.features.N)]:
                if a < bank.keep_from:  # a live bank's rows no window reads any more
                    continue
                ll = bank.cum[n][k] - bank.cum[n][a]
                sizes = _detectable(grid, ll, self.limits[n].log_lr, zone)
                lo, hi = float(np.fmax(lo, sizes[0])), float(np.fmin(hi, sizes[1]))
            if unit_spread:
                lo, hi = widened(Fit(n, math.nan, (lo, hi), 0.0, det.unit), zone).ci95
            out[n] = (lo if det.worse <= 0 else math.nan, hi if det.worse >= 0 else math.nan)
        return out

    def unseen(self) -> list[str]:
        """The model-based faults the record so far cannot tell from healthy: no size of
        the detector's grid would have crossed its threshold (:meth:`detectable`; 20 s of
        the RW90's PRBS: a weak motor).

        Returns
        -------
        list of str
        """
        return [
            n for n, sizes in self.detectable(unit_spread=False).items() if np.isnan(sizes).all()
        ]

    def _open(self, bank: Bank, k: int, free: list[str], crossed: list[str]) -> Event:
        """The event a crossing at sample k opens: named by the likeliest fault."""
        limits = self.limits
        best = _isolate(bank, k, free, limits)[0]
        start = _onset(bank, best.fit.fault, k)
        t = bank.features.t_s
        return Event(
            t_s=float(t[k - 1]),
            onset_s=float(t[start]),
            fit=best.fit,
            detector=crossed[0],
            threshold=limits[crossed[0]].log_lr,
            start=start,
        )


def run(features: Features, calibration: DiagnosisCalibration, per_hour: float = 1e-3) -> Result:
    """Diagnose one record (module docstring).

    Parameters
    ----------
    features : Features
    calibration : DiagnosisCalibration
    per_hour : float
        False alarms per hour asked of each detector.

    Returns
    -------
    Result
    """
    live = Live(calibration, per_hour)
    live.update(features)
    events = sorted(live.events, key=lambda e: e.t_s)
    duration_s = features.N * features.scales.Ts
    return Result(
        events,
        live.limits,
        duration_s,
        per_hour,
        live.unseen(),
        live.statistics,
        live.detectable(),
    )
