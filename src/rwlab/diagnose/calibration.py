"""Thresholds from false-alarm rates measured on healthy records of other units.

Siegmund's formula (:mod:`~rwlab.diagnose.detect`) assumes independent N(0, 1)
block means. The tests' block means are neither Gaussian nor centred on another
unit (their reference value holds the spread between units on purpose), so the
analytic thresholds alarm far less often than asked. A
:class:`ThresholdCalibration` instead holds, per detector, the false alarms it
raised (restarted after each alarm) over a grid of thresholds, counted on hours
of healthy records of units other than the identified ones, with the models of
several units.

A CUSUM's reference value k is the model's own: 0.5 σ plus the tolerance
between units over the model's σ (4.3 σ and 11.6 σ for two reference models' friction
tests). What carries from one model to another is not k but the share of
that tolerance kept in it: a reference unit's block means sit off the other
units' by where it lies in the spread, and the tolerance is sized for that
spread, so the CUSUM's increment z − k, not z, is alike between models. Each
model is therefore counted at its own k over a grid of shares of its tolerance
(:data:`SHARES`), a model of any unit takes the curve of its share (all of it,
unless the rate asks for less), and no model's k is out of range. Counted
instead at common values of k (every model's block means through one grid of
k, interpolated at a new model's k), the rates did not carry: leaving each of
the five tune models out in turn, 23 of 60 (detector, model, rate) cells came
within a factor 2 at 1 and 10/h, against 33 of 60 by share (the motor test 2 of
10 against 8 of 10).

A requested rate maps to the threshold whose measured rate it is (log-linear
interpolation); below the rates the hours resolve (fewer than :data:`RESOLVED`
alarms) the tail is extrapolated with the measured slope of log(rate), never
steeper than the Gaussian's 2k, and the threshold is the larger of that and the
analytic one: an unverified rate errs towards fewer alarms (the default 1e-3/h
is such a rate), and the :class:`Setting` says so in its ``info``. Where a
detector cannot deliver a rate with all of its tolerance, the largest share
that can is used (asking for more false alarms buys sensitivity to the spread
between units); where none can, or no integer threshold gives a rate within a
factor 2 (the run and count tests), the ``note`` says so and the
:class:`~rwlab.diagnose.Diagnoser` warns (:class:`~rwlab.errors.RwlabWarning`).

The package's file ``thresholds.json`` (format ``rwlab.ThresholdCalibration/2``;
format 1, the same curves on a coarser grid of shares, is still read) was
measured by ``bench/calibrate_thresholds.py`` on the twin's tune units (its
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
    "SHARES",
    "Curve",
    "Setting",
    "ThresholdCalibration",
    "count_alarms",
    "cusum_alarms",
    "cusum_alarms_k",
    "cusum_curves",
    "run_alarms",
]

FORMAT = "rwlab.ThresholdCalibration/2"
OLD_FORMATS = ("rwlab.ThresholdCalibration/1",)
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
CUSUM_K = 0.5  # σ: a CUSUM's reference value without tolerance (the diagnoser's)
# shares of the tolerance between units kept in a CUSUM's reference value, scanned for
# rates the full tolerance cannot deliver (curves named "<detector>@<share>")
SHARES = (1.0, 0.9, 0.75, 0.6, 0.5, 0.4, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1, 0.05, 0.0)


def cusum_alarms_k(zs: list[np.ndarray], ks, sides: str, grid=H_GRID) -> np.ndarray:
    """Alarms of a restarted CUSUM over standardised block means, per reference value
    and threshold.

    Parameters
    ----------
    zs : list of numpy.ndarray
        One record's block means each (σ units); each record starts at zero.
    ks : sequence of float
        Reference values, σ units.
    sides : {'up', 'down', 'both'}
    grid : sequence of float
        Thresholds, σ units.

    Returns
    -------
    numpy.ndarray
        Alarm count per reference value and threshold, shape (len(ks), len(grid)).
    """
    h = np.asarray(grid, dtype=float)[None, :]
    k = np.asarray(ks, dtype=float)[:, None]
    alarms = np.zeros((k.size, h.size), dtype=int)
    for z in zs:
        up = np.zeros(alarms.shape)
        down = np.zeros(alarms.shape)
        for x in np.asarray(z, dtype=float):
            if sides in ("up", "both"):
                up = np.maximum(0.0, up + (x - k))
            if sides in ("down", "both"):
                down = np.maximum(0.0, down - (x + k))
            fired = np.maximum(up, down) > h
            alarms += fired
            up[fired] = 0.0
            down[fired] = 0.0
    return alarms


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
    return cusum_alarms_k(zs, (k,), sides, grid)[0]


def run_alarms(runs: list[int], n_max: int = N_MAX) -> np.ndarray:
    """Alarms of a restarted run test (n in a row) over runs of events, for n = 1..n_max.

    Parameters
    ----------
    runs : list of int
        The lengths of the runs of consecutive events.
    n_max : int
        The largest n.

    Returns
    -------
    numpy.ndarray of int, shape (n_max,)
        Alarms at n = 1..n_max (a run of r events raises r // n).
    """
    n = np.arange(1, n_max + 1)
    return np.array([sum(r // m for r in runs) for m in n], dtype=int)


def count_alarms(counts: list[int], n_max: int = N_MAX) -> np.ndarray:
    """Blocks whose event count reaches n, for n = 1..n_max.

    Parameters
    ----------
    counts : list of int
        Events in each block.
    n_max : int
        The largest n.

    Returns
    -------
    numpy.ndarray of int, shape (n_max,)
        Blocks with at least n events, n = 1..n_max.
    """
    c = np.asarray(counts, dtype=int)
    return np.array([int((c >= m).sum()) for m in range(1, n_max + 1)], dtype=int)


@dataclass(frozen=True)
class Curve:
    """One detector's measured false alarms over its thresholds, at one share of its tolerance.

    Parameters
    ----------
    kind : {'cusum', 'count'}
        A CUSUM threshold (σ) or an integer one (events in a row / in a block).
    thresholds : tuple of float
        Increasing.
    alarms : tuple of int
        Alarms raised over the calibration's hours at each threshold.
    k : float
        The median over the calibration's models of the CUSUM reference value (σ) it
        was counted with (each model its own; 0 for counts).
    decisions : int
        Decisions (blocks or qualifying samples) behind the curve.
    share : float
        The share of each model's tolerance between units in its k (1: all of it).
    """

    kind: str
    thresholds: tuple[float, ...]
    alarms: tuple[int, ...]
    k: float = 0.0
    decisions: int = 0
    share: float = 1.0


@dataclass(frozen=True)
class Setting:
    """A detector's calibrated threshold for one requested rate.

    Parameters
    ----------
    threshold : float
        σ for a CUSUM, events for a count.
    k : float
        The CUSUM reference value to run with, σ (the model's, or less where the model's
        cannot deliver the rate; 0 for counts).
    share : float
        The share of the model's tolerance between units kept in ``k``.
    note : str
        Empty, or why the request cannot be honoured (within a factor 2): a warning.
    info : str
        Empty, or where the threshold comes from when its rate is not measured
        (extrapolated, analytic, beyond the grid of k): no warning, but said.
    """

    threshold: float
    k: float = 0.0
    note: str = ""
    info: str = ""
    share: float = 1.0


@dataclass(frozen=True)
class ThresholdCalibration:
    """Measured false-alarm rates per detector, reference value and threshold.

    Parameters
    ----------
    Ts : float
        Sample time of the models it was measured with, s.
    hours : float
        Healthy record hours behind every curve (records × models).
    curves : dict of str to Curve
        A count test's curve under its name; a CUSUM's under ``"<name>@<share>"``, one
        per share of :data:`SHARES` (one, ``@1``, for a test without tolerance).
    origin : str
        How it was measured (command, units, seeds).
    """

    Ts: float
    hours: float
    curves: dict
    origin: str = ""

    # -- one curve --------------------------------------------------------------------------
    def rates(self, key: str) -> np.ndarray:
        """Measured alarms per hour of curve ``key`` at each threshold (non-increasing)."""
        a = np.asarray(self.curves[key].alarms, dtype=float)
        return np.minimum.accumulate(a) / self.hours

    def max_per_hour(self, key: str) -> float:
        """The most false alarms per hour curve ``key`` raised at its lowest threshold."""
        return float(self.rates(key)[0])

    def family(self, name: str) -> list[tuple[float, str]]:
        """A CUSUM detector's curves as (share, key), share increasing (empty: none)."""
        return sorted((c.share, key) for key, c in self.curves.items() if key.split("@")[0] == name)

    def covers(self, name: str) -> bool:
        """Whether the calibration measured detector ``name``."""
        return name in self.curves or bool(self.family(name))

    # -- a requested rate -------------------------------------------------------------------
    def setting(self, name: str, per_hour: float, analytic: float, k: float = 0.5) -> Setting:
        """The threshold (and reference value) whose measured false-alarm rate is ``per_hour``.

        Parameters
        ----------
        name : str
            Detector.
        per_hour : float
            Requested false alarms per hour.
        analytic : float
            The analytic threshold, used where the calibration cannot say.
        k : float
            The detector's reference value for this model, σ (CUSUMs): 0.5 σ plus its
            whole tolerance between units.

        Returns
        -------
        Setting
        """
        if name in self.curves and self.curves[name].kind == "count":
            c = self.curves[name]
            return self._count(name, np.array(c.thresholds), self.rates(name), per_hour, analytic)
        fam = self.family(name)
        key = fam[-1][1]
        rate0 = self.max_per_hour(key)
        unresolvable = per_hour * self.hours < RESOLVED
        if not (per_hour <= rate0 or unresolvable or len(fam) == 1):
            # all of the tolerance cannot deliver the rate at any threshold: the largest
            # share that can (or the smallest)
            key = next(
                (kk for _, kk in reversed(fam) if self.max_per_hour(kk) >= per_hour), fam[0][1]
            )
        share = self.curves[key].share
        return self._cusum(name, key, per_hour, analytic, CUSUM_K + share * (k - CUSUM_K), share)

    def threshold(self, name: str, per_hour: float, analytic: float, k: float = 0.5):
        """``setting``'s threshold and warning note (see :meth:`setting`).

        Parameters
        ----------
        name : str
        per_hour : float
        analytic : float
        k : float

        Returns
        -------
        threshold : float
        note : str
        """
        s = self.setting(name, per_hour, analytic, k)
        return s.threshold, s.note

    def _cusum(self, name, key, per_hour, analytic, k, share) -> Setting:
        h = np.asarray(self.curves[key].thresholds, dtype=float)
        rate = self.rates(key)
        alarms = rate * self.hours
        resolvable = per_hour * self.hours >= RESOLVED
        base = (
            f"{name}: with {share:.0%} of its tolerance between units (k = {k:.3g} σ), over "
            f"{self.hours:.1f} h of healthy records,"
        )
        if rate[0] == 0.0:
            note = (
                f"{base} no false alarm at any threshold (a healthy unit stays within its "
                f"tolerance): it cannot deliver {per_hour:g}/h"
            )
            info = f"{base} no false alarm at any threshold: the analytic threshold, not measured"
            return Setting(
                analytic, k, note if resolvable else "", "" if resolvable else info, share
            )
        if per_hour >= rate[0]:
            note = (
                f"{base} at most {rate[0]:.3g} false alarms per hour at its lowest threshold: "
                f"it cannot deliver {per_hour:g}/h"
            )
            return Setting(float(h[0]), k, note if per_hour > 2 * rate[0] else "", "", share)
        ok = alarms >= RESOLVED
        if not ok.any():  # too few alarms to measure a tail: the analytic threshold
            info = (
                f"{base} fewer than {RESOLVED} alarms at any threshold: the analytic threshold, "
                "its rate not measured"
            )
            return Setting(analytic, k, "", info, share)
        if per_hour >= rate[ok].min():
            j = int(np.nonzero(ok & (rate <= per_hour))[0][0])  # first at or below
            lo, hi = rate[j - 1], rate[j]
            x = (math.log(lo) - math.log(per_hour)) / (math.log(lo) - math.log(hi))
            return Setting(float(h[j - 1] + x * (h[j] - h[j - 1])), k, share=share)
        # unmeasured: the larger of the extrapolated and the analytic threshold (a lower
        # one would trade the isolation of other faults for a rate nobody has verified)
        tail = self._tail(h, rate, ok, per_hour, k)
        value = max(tail, analytic, 0.0)
        last = float(rate[ok].min())
        how = "extrapolated from the measured tail" if value == tail else "the analytic one"
        info = (
            f"{base} {per_hour:g}/h is below the rates measured (down to {last:.3g}/h): "
            f"threshold {value:.3g} σ, {how} (the larger of the two), its rate not verified"
        )
        return Setting(value, k, "", info, share)

    def _tail(self, h, rate, ok, per_hour, k) -> float:
        """Below the resolved rates: the measured log-rate slope, between half and all of
        Gaussian's 2k. A flatter measured curve is a few records' excursions above every
        threshold measured, which says nothing of the tail; extrapolated, it put
        friction_change's default threshold at 6.6e15 (the detector off)."""
        last = int(np.nonzero(ok)[0][-1])
        fit = ok & (rate * self.hours <= 10 * RESOLVED)
        slope = 2 * max(k, 0.5)
        if fit.sum() >= 3:
            s = -np.polyfit(h[fit], np.log(rate[fit]), 1)[0]
            slope = min(slope, max(float(s), slope / 2))
        return float(h[last] + math.log(rate[last] / per_hour) / slope)

    def _count(self, name, n, rate, per_hour, analytic) -> Setting:
        """An integer threshold: the one whose measured rate is nearest the request within a
        factor 2, else the smallest whose rate is at most the request."""
        resolvable = per_hour * self.hours >= RESOLVED
        if per_hour >= rate[0] and rate[0] > 0:
            note = (
                f"{name}: at most {rate[0]:.3g} false alarms per hour at its lowest threshold "
                f"(measured over {self.hours:.1f} h of healthy records): it cannot deliver "
                f"{per_hour:g}/h"
            )
            return Setting(float(n[0]), 0.0, note if per_hour > 2 * rate[0] else "")
        near = np.nonzero((rate >= per_hour / 2) & (rate <= 2 * per_hour))[0]
        if near.size:
            j = int(near[np.argmin(np.abs(np.log(rate[near] / per_hour)))])
        elif (rate <= per_hour).any():
            j = int(np.nonzero(rate <= per_hour)[0][0])
        else:
            j = len(n) - 1
        value = float(n[j])
        info = ""
        if rate[j] * self.hours < RESOLVED:  # not measured: the analytic one if higher
            value = max(value, float(analytic))
            info = (
                f"{name}: {per_hour:g}/h is below the rates {self.hours:.1f} h of healthy "
                f"records resolve: {value:g}, the larger of the first threshold without "
                f"{RESOLVED} alarms ({n[j]:g}) and the analytic one, its rate not verified"
            )
        if not resolvable or rate[j] >= per_hour / 2:
            return Setting(value, 0.0, "", info)
        # the note below says what is delivered: the info would repeat it
        steps = ", ".join(f"{n[i]:g}: {rate[i]:.3g}/h" for i in range(max(j - 1, 0), j + 1))
        note = (
            f"{name}: its thresholds step in whole events ({steps}, measured over "
            f"{self.hours:.1f} h of healthy records): {per_hour:g}/h is not within a factor 2 "
            f"of any; the lower rate is delivered"
        )
        return Setting(value, 0.0, note)

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
                    **({} if c.kind == "count" else {"share": c.share}),
                    "thresholds": list(c.thresholds[: end(c)]),
                    "alarms": list(c.alarms[: end(c)]),
                }
                for name, c in self.curves.items()
            },
        }

    @classmethod
    def from_dict(cls, d: dict) -> ThresholdCalibration:
        """A calibration from its file's content (format 2, or 1: the same curves on a
        coarser grid of shares, a CUSUM's whole-tolerance curve under its plain name).

        Parameters
        ----------
        d : dict

        Returns
        -------
        ThresholdCalibration
        """
        if d.get("format") not in (FORMAT, *OLD_FORMATS):
            raise FileFormatError(
                f"not a threshold calibration ({FORMAT}): {d.get('format')!r}; "
                "bench/calibrate_thresholds.py measures one"
            )
        try:
            curves = {}
            for name, c in d["curves"].items():
                curve = Curve(
                    c["kind"],
                    tuple(float(x) for x in c["thresholds"]),
                    tuple(int(x) for x in c["alarms"]),
                    float(c["k"]),
                    int(c["decisions"]),
                    float(c.get("share", 1.0)),
                )
                if curve.kind not in ("cusum", "count"):
                    raise ValueError(f"curve {name!r}: kind {curve.kind!r}")
                if curve.kind == "cusum" and "@" not in name:  # format 1
                    name = f"{name}@1"
                curves[name] = curve
            out = cls(float(d["Ts"]), float(d["hours"]), curves, str(d.get("origin", "")))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise FileFormatError(f"threshold calibration: bad or missing field ({exc})") from exc
        if not out.hours > 0 or any(
            len(c.thresholds) != len(c.alarms) or not c.alarms for c in curves.values()
        ):
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


def cusum_curves(
    name: str, per_model: list[tuple[list[np.ndarray], float]], sides: str, shares=SHARES
) -> dict[str, Curve]:
    """One CUSUM detector's curves over shares of its tolerance, summed over models.

    Parameters
    ----------
    name : str
        Detector.
    per_model : list of (list of numpy.ndarray, float)
        Per model: its standardised block means, one array per record (each starts
        the CUSUM at zero), and its reference value k (σ, all of its tolerance).
    sides : {'up', 'down', 'both'}
    shares : sequence of float
        Shares of each model's tolerance kept in its k (k = 0.5 + share (k − 0.5));
        one (1) where no model has a tolerance.

    Returns
    -------
    dict of str to Curve
        Keyed ``"<name>@<share>"``.
    """
    if all(k <= CUSUM_K for _, k in per_model):
        shares = (1.0,)
    alarms = np.zeros((len(shares), len(H_GRID)), dtype=int)
    for traces, k in per_model:
        alarms += cusum_alarms_k(traces, [CUSUM_K + s * (k - CUSUM_K) for s in shares], sides)
    n = int(sum(z.size for traces, _ in per_model for z in traces))
    h = tuple(float(x) for x in H_GRID)
    out = {}
    for share, row in zip(shares, alarms, strict=True):
        ks = [CUSUM_K + share * (k - CUSUM_K) for _, k in per_model]
        curve = Curve("cusum", h, tuple(int(a) for a in row), float(np.median(ks)), n, share)
        out[f"{name}@{share:g}"] = curve
    return out
