"""Thresholds from false-alarm rates measured on healthy records of other units.

Siegmund's formula (:mod:`~rwlab.diagnose.detect`) assumes independent N(0, 1)
block means. The tests' block means are neither Gaussian nor centred on another
unit (their reference value holds the spread between units on purpose), so the
analytic thresholds alarm far less often than asked. A
:class:`ThresholdCalibration` instead holds, per detector, the false alarms per
hour it raised (restarted after each alarm) over a grid of thresholds, counted
on hours of healthy records of units other than the identified one. A requested
rate maps to the threshold whose measured rate it is (log-linear interpolation);
below the rates the hours resolve (fewer than :data:`RESOLVED` alarms) the tail
is extrapolated with the measured slope of log(rate), never steeper than the
Gaussian's 2k, and the threshold is the larger of that and the analytic one: an
unverified rate errs towards fewer alarms (the default 1e-3/h is such a rate).

Where a detector cannot deliver a rate (a healthy unit never leaves its
tolerance band, or no threshold gives a rate within a factor 2 of the request:
the run and count tests step between integers), :meth:`ThresholdCalibration.threshold`
says so and the :class:`~rwlab.diagnose.Diagnoser` warns (:class:`~rwlab.errors.RwlabWarning`).

The package's file ``thresholds.json`` (format ``rwlab.ThresholdCalibration/1``)
was measured by ``bench/calibrate_thresholds.py`` on the twin's tune units (its
``origin`` field says how); it applies to RW90 models identified with the
defaults at its sample time. The scan is hand-written: no library computes a
restarted CUSUM's alarm count over a grid of thresholds.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rwlab.errors import FileFormatError

__all__ = [
    "FORMAT",
    "RESOLVED",
    "Curve",
    "ThresholdCalibration",
    "count_alarms",
    "cusum_alarms",
    "run_alarms",
]

FORMAT = "rwlab.ThresholdCalibration/1"
DEFAULT_FILE = Path(__file__).with_name("thresholds.json")
RESOLVED = 5  # alarms behind a rate the calibration counts as measured
H_GRID = tuple(  # CUSUM thresholds scanned, σ: finer where the requested rates fall
    float(h)
    for h in np.round(
        np.concatenate([np.arange(0, 2, 0.02), np.arange(2, 10, 0.1), np.arange(10, 60.01, 0.5)]),
        3,
    )
)
N_MAX = 40  # run / count thresholds scanned
# shares of the tolerance between units kept in a CUSUM's reference value, scanned for
# rates the full tolerance cannot deliver (curves named "<detector>@<share>")
SHARES = (0.75, 0.5, 0.35, 0.25, 0.15, 0.1, 0.05, 0.0)


def cusum_alarms(zs: list[np.ndarray], k: float, sides: str, grid=H_GRID) -> np.ndarray:
    """Alarms of a restarted CUSUM over standardised block means, per threshold.

    Parameters
    ----------
    zs : list of numpy.ndarray
        One record's block means each (σ units); each record starts at zero.
    k : float
        Reference value, σ units.
    sides : {'up', 'down', 'both'}
    grid : sequence of float
        Thresholds, σ units.

    Returns
    -------
    numpy.ndarray
        Alarm count per threshold, shape (len(grid),).
    """
    h = np.asarray(grid, dtype=float)
    alarms = np.zeros(h.size, dtype=int)
    for z in zs:
        up = np.zeros(h.size)
        down = np.zeros(h.size)
        for x in np.asarray(z, dtype=float):
            if sides in ("up", "both"):
                up = np.maximum(0.0, up + x - k)
            if sides in ("down", "both"):
                down = np.maximum(0.0, down - x - k)
            fired = np.maximum(up, down) > h
            alarms += fired
            up[fired] = 0.0
            down[fired] = 0.0
    return alarms


def run_alarms(runs: list[int], n_max: int = N_MAX) -> np.ndarray:
    """Alarms of a restarted run test (n in a row) over runs of events, for n = 1..n_max."""
    n = np.arange(1, n_max + 1)
    return np.array([sum(r // m for r in runs) for m in n], dtype=int)


def count_alarms(counts: list[int], n_max: int = N_MAX) -> np.ndarray:
    """Blocks whose event count reaches n, for n = 1..n_max."""
    c = np.asarray(counts, dtype=int)
    return np.array([int((c >= m).sum()) for m in range(1, n_max + 1)], dtype=int)


def _pair(x) -> tuple[float, float]:
    lo, hi = (float(v) for v in x)
    return lo, hi


@dataclass(frozen=True)
class Curve:
    """One detector's measured false alarms over its thresholds.

    Parameters
    ----------
    kind : {'cusum', 'count'}
        A CUSUM threshold (σ) or an integer one (events in a row / in a block).
    thresholds : tuple of float
        Increasing.
    alarms : tuple of int
        Alarms raised over the calibration's hours at each threshold.
    k : float
        The CUSUM's reference value (σ) it was measured with (0 for counts).
    decisions : int
        Decisions (blocks or qualifying samples) behind the curve.
    share : float
        The share of the tolerance between units in ``k`` (1: the detector's own).
    k_range : (float, float) or None
        The smallest and largest reference value of the models it was counted with
        (a calibration over several model units: each model's own k); None: ``k`` only.
    """

    kind: str
    thresholds: tuple[float, ...]
    alarms: tuple[int, ...]
    k: float = 0.0
    decisions: int = 0
    share: float = 1.0
    k_range: tuple[float, float] | None = None

    def holds(self, k: float) -> bool:
        """Whether a CUSUM with reference value ``k`` (σ) is one this curve measured:
        within the models' range of k, or 10 % of it."""
        lo, hi = self.k_range or (self.k, self.k)
        return lo / 1.1 <= k <= hi * 1.1


@dataclass(frozen=True)
class ThresholdCalibration:
    """Measured false-alarm rates per detector and threshold, on healthy hours.

    Parameters
    ----------
    Ts : float
        Sample time of the model it was measured with, s.
    hours : float
        Healthy record hours behind every curve.
    curves : dict of str to Curve
    origin : str
        How it was measured (command, units, seeds).
    """

    Ts: float
    hours: float
    curves: dict
    origin: str = ""

    def rates(self, name: str) -> np.ndarray:
        """Measured alarms per hour of ``name`` at each threshold (non-increasing)."""
        a = np.asarray(self.curves[name].alarms, dtype=float)
        return np.minimum.accumulate(a) / self.hours

    def max_per_hour(self, name: str) -> float:
        """The most false alarms per hour the detector raised at its lowest threshold."""
        return float(self.rates(name)[0])

    def setting(self, name: str, per_hour: float, analytic: float) -> tuple[float, float, str]:
        """Threshold and tolerance share whose measured false-alarm rate is ``per_hour``.

        A rate the detector's full tolerance between units cannot deliver is sought
        with less of that tolerance in the CUSUM's reference value (the largest share
        that reaches it): asking for more false alarms buys sensitivity to the spread
        between units.

        Parameters
        ----------
        name : str
            Detector.
        per_hour : float
            Requested false alarms per hour.
        analytic : float
            The analytic threshold, used where the calibration cannot say.

        Returns
        -------
        threshold : float
        share : float
            Share of the tolerance to keep in the reference value (1: all).
        note : str
            Empty, or why the request cannot be honoured (within a factor 2).
        """
        h, note = self.threshold(name, per_hour, analytic)
        if not note or self.curves[name].kind != "cusum" or per_hour < self.max_per_hour(name):
            return h, 1.0, note
        scaled = sorted(
            (c.share, key) for key, c in self.curves.items() if key.startswith(f"{name}@")
        )
        for share, key in reversed(scaled):
            if self.max_per_hour(key) >= per_hour or share == scaled[0][0]:
                h, note = self.threshold(key, per_hour, 0.0)
                within = f"{name}: with {share:.0%} of the tolerance between units,"
                return h, share, note.replace(f"{key}:", within, 1)
        return h, 1.0, note

    def threshold(self, name: str, per_hour: float, analytic: float) -> tuple[float, str]:
        """The threshold whose measured false-alarm rate is ``per_hour``.

        Parameters
        ----------
        name : str
            Detector.
        per_hour : float
            Requested false alarms per hour.
        analytic : float
            The analytic threshold, used where the calibration cannot say.

        Returns
        -------
        threshold : float
        note : str
            Empty, or why the request cannot be honoured (within a factor 2).
        """
        c = self.curves[name]
        h = np.asarray(c.thresholds, dtype=float)
        rate = self.rates(name)
        alarms = rate * self.hours
        resolvable = per_hour * self.hours >= RESOLVED
        if rate[0] == 0.0:
            note = (
                f"{name}: no false alarm at any threshold in {self.hours:.1f} h of healthy "
                f"records of other units (a healthy unit stays within its tolerance): it "
                f"cannot deliver {per_hour:g}/h"
            )
            return analytic, note if resolvable else ""
        if per_hour >= rate[0]:
            short = per_hour > 2 * rate[0]
            note = (
                f"{name}: at most {rate[0]:.3g} false alarms per hour at its lowest threshold "
                f"(measured over {self.hours:.1f} h of healthy records): it cannot deliver "
                f"{per_hour:g}/h"
            )
            return float(h[0]), note if short else ""
        if c.kind == "count":
            return self._count(name, h, rate, per_hour, analytic, resolvable)
        ok = alarms >= RESOLVED
        if not ok.any():  # too few alarms to measure a tail: the analytic threshold
            return analytic, ""
        if per_hour >= rate[ok].min():
            j = int(np.nonzero(ok & (rate <= per_hour))[0][0])  # first at or below
            lo, hi = rate[j - 1], rate[j]
            x = (math.log(lo) - math.log(per_hour)) / (math.log(lo) - math.log(hi))
            return float(h[j - 1] + x * (h[j] - h[j - 1])), ""
        # unmeasured: the larger of the extrapolated and the analytic threshold (a lower
        # one would trade the isolation of other faults for a rate nobody has verified)
        return max(self._tail(name, h, rate, ok, per_hour), analytic, 0.0), ""

    def _tail(self, name, h, rate, ok, per_hour) -> float:
        """Below the resolved rates: the measured log-rate slope, between half and all of
        Gaussian's 2k. A flatter measured curve is a few records' excursions above every
        threshold measured, which says nothing of the tail; extrapolated, it put
        friction_change's default threshold at 6.6e15 (the detector off)."""
        last = int(np.nonzero(ok)[0][-1])
        fit = ok & (rate * self.hours <= 10 * RESOLVED)
        slope = 2 * max(self.curves[name].k, 0.5)
        if fit.sum() >= 3:
            s = -np.polyfit(h[fit], np.log(rate[fit]), 1)[0]
            slope = min(slope, max(float(s), slope / 2))
        return float(h[last] + math.log(rate[last] / per_hour) / slope)

    def _count(self, name, n, rate, per_hour, analytic, resolvable) -> tuple[float, str]:
        """An integer threshold: the one whose measured rate is nearest the request within a
        factor 2, else the smallest whose rate is at most the request."""
        near = np.nonzero((rate >= per_hour / 2) & (rate <= 2 * per_hour))[0]
        if near.size:
            j = int(near[np.argmin(np.abs(np.log(rate[near] / per_hour)))])
        elif (rate <= per_hour).any():
            j = int(np.nonzero(rate <= per_hour)[0][0])
        else:
            j = len(n) - 1
        value = float(n[j])
        if rate[j] * self.hours < RESOLVED:  # not measured: the analytic one if higher
            value = max(value, float(analytic))
        if not resolvable or rate[j] >= per_hour / 2:
            return value, ""
        steps = ", ".join(f"{n[i]:g}: {rate[i]:.3g}/h" for i in range(max(j - 1, 0), j + 1))
        note = (
            f"{name}: its thresholds step in whole events ({steps}, measured over "
            f"{self.hours:.1f} h of healthy records): {per_hour:g}/h is not within a factor 2 "
            f"of any; the lower rate is delivered"
        )
        return value, note

    # -- file ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The file's content; each curve ends at its first threshold without an alarm."""

        def end(c: Curve) -> int:
            return next((i + 1 for i, a in enumerate(c.alarms) if a == 0), len(c.alarms))

        return {
            "format": FORMAT,
            "Ts": self.Ts,
            "hours": self.hours,
            "origin": self.origin,
            "curves": {
                name: {
                    "kind": c.kind,
                    "k": c.k,
                    "decisions": c.decisions,
                    "share": c.share,
                    **({} if c.k_range is None else {"k_range": list(c.k_range)}),
                    "thresholds": list(c.thresholds[: end(c)]),
                    "alarms": list(c.alarms[: end(c)]),
                }
                for name, c in self.curves.items()
            },
        }

    @classmethod
    def from_dict(cls, d: dict) -> ThresholdCalibration:
        if d.get("format") != FORMAT:
            raise FileFormatError(f"not a threshold calibration ({FORMAT}): {d.get('format')!r}")
        try:
            curves = {
                name: Curve(
                    c["kind"],
                    tuple(float(x) for x in c["thresholds"]),
                    tuple(int(x) for x in c["alarms"]),
                    float(c["k"]),
                    int(c["decisions"]),
                    float(c.get("share", 1.0)),
                    None if c.get("k_range") is None else _pair(c["k_range"]),
                )
                for name, c in d["curves"].items()
            }
            out = cls(float(d["Ts"]), float(d["hours"]), curves, str(d.get("origin", "")))
        except (KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(f"threshold calibration: bad or missing field ({exc})") from exc
        if not out.hours > 0 or any(len(c.thresholds) != len(c.alarms) for c in curves.values()):
            raise FileFormatError("threshold calibration: no hours, or curves of unequal length")
        return out

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> ThresholdCalibration:
        """Read a calibration file (default: the package's, measured on the twin).

        Parameters
        ----------
        path : path-like, optional

        Returns
        -------
        ThresholdCalibration
        """
        p = Path(DEFAULT_FILE if path is None else path)
        try:
            return cls.from_dict(json.loads(p.read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{p}: cannot read the threshold calibration ({exc})") from exc

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration atomically.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        pathlib.Path
        """
        p = Path(path)
        fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=p.name, suffix=".partial")
        d = self.to_dict()
        curves = d.pop("curves")
        with os.fdopen(fd, "w") as f:  # one line per curve: a small, diffable file
            f.write(json.dumps(d, ensure_ascii=False)[:-1] + ', "curves": {\n')
            f.write(",\n".join(f" {json.dumps(k)}: {json.dumps(v)}" for k, v in curves.items()))
            f.write("\n}}\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, p)
        return p
