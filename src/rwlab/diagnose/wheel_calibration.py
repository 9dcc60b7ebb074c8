"""Calibration from a wheel's own healthy records: noise, healthy zones, thresholds.

:meth:`DiagnosisCalibration.measure` takes the features of healthy records
(the lab's own wheel, or the twin's units for the shipped file) and measures
everything the pipeline decides with:

- the noise model (:class:`~rwlab.diagnose.noise.NoiseModel`);
- per model-based fault, the *population zone*: the narrowest interval that
  every healthy window's profile-likelihood 95 % interval of the fault's size
  meets (a unit of another friction or k_t than the reference's is healthy;
  a window that hardly constrains the size, a chirp's fast end for friction,
  widens nothing), the windows back-to-back at the decisions' shortest length;
- per fault, the *drift*: the largest gap between consecutive such windows'
  intervals (0 where they overlap) against the population, and against the
  record's own past the largest move of their middles (a detector against the
  unit's own law, ``Detector.own_law``, reads none: its healthy size is a point);
- per fault, the peaks of its statistic's excursions above χ²₁(0.95)/2 on every
  record (restarted detectors: each excursion is one false alarm). A rate r per
  hour maps to the threshold exceeded r·hours times; below one such peak per
  record-hour the tail is extrapolated as an exponential fitted to the largest
  peaks (peaks over threshold; with under ``MIN_TAIL`` peaks the GLR's own
  tail, 2·log-LR ~ χ²₁, i.e. a unit scale, which is also the lightest tail a fit
  may give), and the threshold says so;
- the telemetry's repeat probability of a non-zero speed reading (Laplace's
  rule) and frames lost per sample (Jeffreys): the stuck and dropout tests.

File format ``rwlab.DiagnosisCalibration/1`` (schema
``diagnosis_calibration.schema.json``); one owner, this class.

The package ships one twin-calibrated file per wheel preset,
``twin_calibration_<preset>.json`` (:func:`twin_calibration_file`): measured by
``bench/bench_fdi.py --save-calibration`` on the twin's healthy records of
that preset (its ``origin`` and ``sources`` say which records and how many
hours). It applies to a model of that preset identified with the defaults; a
lab's own wheel is better served by its own ``rwlab diagnose calibrate``.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from rwlab._io import write_json
from rwlab.diagnose.bank import Bank
from rwlab.diagnose.detectors import MODEL_BASED, FrozenReading
from rwlab.diagnose.detectors.base import HALF_CHI2_95, profile_fit
from rwlab.diagnose.features import Features
from rwlab.diagnose.noise import NoiseModel
from rwlab.errors import ConfigError, DataError, FileFormatError

__all__ = [
    "FORMAT",
    "DiagnosisCalibration",
    "Threshold",
    "model_calibration_file",
    "twin_calibration_file",
]

FORMAT = "rwlab.DiagnosisCalibration/1"
STUCK = "speed_sensor_stuck"
MIN_TAIL = 5  # peaks needed to fit the tail's scale
TAIL = 20  # the largest peaks the tail is fitted to


@dataclass(frozen=True)
class Threshold:
    """A threshold and the false-alarm rate measured at it.

    Attributes
    ----------
    log_lr : float
        The threshold on the detector's log-likelihood ratio.
    asked_per_hour : float
    measured_per_hour : float
        False alarms per hour counted at the threshold on the calibration records.
    ci95_per_hour : tuple of 2 float
        Garwood's exact Poisson 95 % interval of the measured rate.
    extrapolated : bool
        The rate asked is below what the hours resolve (the tail fit set it).
    """

    log_lr: float
    asked_per_hour: float
    measured_per_hour: float
    ci95_per_hour: tuple[float, float]
    extrapolated: bool


def garwood(n: int, hours: float) -> tuple[float, float]:
    """Exact 95 % interval of a Poisson rate from n events in ``hours``, per hour."""
    lo = 0.0 if n == 0 else float(chi2.ppf(0.025, 2 * n)) / 2
    return lo / hours, float(chi2.ppf(0.975, 2 * n + 2)) / 2 / hours


def excursion_peaks(stat: np.ndarray, floor: float = HALF_CHI2_95) -> list[float]:
    """The maximum of each run of ``stat`` above ``floor``."""
    peaks, top = [], None
    for x in stat:
        if x > floor:
            top = x if top is None else max(top, x)
        elif top is not None:
            peaks.append(float(top))
            top = None
    if top is not None:
        peaks.append(float(top))
    return peaks


def _moves(intervals: list[tuple[float, float]]) -> list[float]:
    """How far consecutive intervals' middles lie apart."""
    mids = [(lo + hi) / 2 for lo, hi in intervals]
    return [abs(b - a) for a, b in itertools.pairwise(mids)]


def _gaps(intervals: list[tuple[float, float]]) -> list[float]:
    """How far apart consecutive intervals lie (0 where they overlap)."""
    return [max(0.0, b[0] - a[1], a[0] - b[1]) for a, b in itertools.pairwise(intervals)]


@dataclass(frozen=True)
class DiagnosisCalibration:
    """What the pipeline decides with, measured on healthy records (module docstring).

    Attributes
    ----------
    Ts : float
        Sample time of the records, s.
    hours : float
        Healthy record-hours measured.
    noise : NoiseModel
    zones : dict of str to tuple of 2 float
    drift : dict of str to float
    dispersion : dict of str to float
        φ per model-based fault: how much more the window likelihoods spread on healthy
        records than a true likelihood's (1: not at all).
    peaks : dict of str to tuple of float
    repeat_probability, lost_per_sample : float
    sources : tuple of str
        The records (names) it was measured on.
    origin : str
        One line: whose wheel, which records.
    records : int
        How many healthy records it was measured on.
    quick_window_s : float or None
        The decisions' short window, s (:class:`~rwlab.diagnose.bank.Bank`'s ``quick_s``),
        its thresholds measured with it; None: none.
    """

    Ts: float
    hours: float
    noise: NoiseModel
    zones: dict[str, tuple[float, float]]
    drift: dict[str, float]
    dispersion: dict[str, float]
    peaks: dict[str, tuple[float, ...]]
    repeat_probability: float
    lost_per_sample: float
    sources: tuple[str, ...] = ()
    origin: str = ""
    records: int = field(default=0)
    quick_window_s: float | None = None

    @classmethod
    def measure(
        cls,
        records: list[Features],
        *,
        sources=(),
        origin: str = "",
        quick_window_s: float | None = None,
    ) -> DiagnosisCalibration:
        """Measure a calibration on healthy records' features (one wheel model, one Ts).

        Parameters
        ----------
        records : list of Features
            Healthy records, as :func:`~rwlab.diagnose.features.compute_features` gives them.
        sources : sequence of str
            Their names, kept in the file.
        origin : str
        quick_window_s : float, optional
            A short decision window, s (:class:`~rwlab.diagnose.bank.Bank`'s ``quick_s``).

        Returns
        -------
        DiagnosisCalibration

        Raises
        ------
        ConfigError
            No record, or records of different sample times.
        """
        if not records:
            raise ConfigError("a calibration needs at least one healthy record")
        Ts = records[0].scales.Ts
        if any(not math.isclose(f.scales.Ts, Ts) for f in records):
            raise ConfigError("a calibration's records must share one sample time")
        noise = NoiseModel.measure(records)
        point = {n: cls._healthy_point(n, records[0]) for n in MODEL_BASED}
        none = dict.fromkeys(MODEL_BASED, 0.0)
        # one bank per record for every fault (its gains are what costs), read into the
        # windows' log-likelihoods the dispersions and the zones are measured on
        tiles = [
            cls._tiles(Bank(f, noise, {n: (point[n],) * 2 for n in MODEL_BASED}, none))
            for f in records
        ]
        dispersion = {n: cls._dispersion([t[n]["longest"] for t in tiles]) for n in MODEL_BASED}
        dispersion |= {
            f"{n}@own": cls._dispersion([t[n]["longest@own"] for t in tiles]) for n in MODEL_BASED
        }
        zones: dict[str, tuple[float, float]] = {}
        drift: dict[str, float] = {}
        for name in MODEL_BASED:
            # a tile's size is known only to its interval (a chirp's fast end holds a few
            # steady samples: friction anywhere in 0.25-8): the zone holds the narrowest
            # one every healthy tile's interval meets and the sizes of the better-known
            # half of the tiles (interval at most the median width); a drift is the gap
            # between consecutive tiles' intervals, not the spread of their point estimates
            lows, highs, moves, moves_own = [point[name]], [point[name]], [0.0], [0.0]
            known: list[tuple[float, float]] = []
            phi_own = dispersion.get(f"{name}@own", 1.0)
            for t in tiles:
                grid, zone = t[name]["grid"], t[name]["zone"]
                sizes = [
                    _held(grid, profile_fit(name, "", grid, ll, zone, dispersion[name]).ci95)
                    for ll in t[name]["shortest"]
                ]
                lows += [hi for _, hi in sizes]
                highs += [lo for lo, _ in sizes]
                known += sizes
                moves += _gaps(sizes)
                own = [
                    _held(grid, profile_fit(name, "", grid, ll, zone, phi_own).ci95)
                    for ll in t[name]["shortest@own"]
                ]
                moves_own += _moves(own)
            if known:
                width = np.median([hi - lo for lo, hi in known])
                mids = [(lo + hi) / 2 for lo, hi in known if hi - lo <= width]
                lows, highs = lows + mids, highs + mids
            zones[name] = (float(min(lows)), float(max(highs)))
            drift[name] = float(max(moves))
            drift[f"{name}@own"] = float(max(moves_own))
        peaks: dict[str, list[float]] = {n: [] for n in MODEL_BASED}
        peaks[STUCK] = []
        for f in records:
            bank = Bank(f, noise, zones, drift, dispersion, quick_s=quick_window_s)
            for name, stat in bank.statistics().items():
                peaks[name] += excursion_peaks(stat)
            runs = FrozenReading.runs(f)
            peaks[STUCK] += [float(r) for r, nxt in itertools.pairwise(runs) if r > nxt]
        moving = sum(int((f.usable & (f.speed_rpm != 0)).sum()) for f in records)
        repeats = sum(int((f.usable & f.repeated).sum()) for f in records)
        lost = sum(float(f.lost_frames.sum()) for f in records)
        n = sum(f.N for f in records)
        return cls(
            Ts=float(Ts),
            hours=n * Ts / 3600,
            noise=noise,
            zones=zones,
            drift=drift,
            dispersion=dispersion,
            peaks={k: tuple(sorted(v, reverse=True)) for k, v in peaks.items()},
            repeat_probability=(repeats + 1) / (moving + 2),
            lost_per_sample=(lost + 0.5) / n,
            sources=tuple(str(s) for s in sources),
            origin=origin,
            records=len(records),
            quick_window_s=quick_window_s,
        )

    @staticmethod
    def _tiles(bank: Bank) -> dict[str, dict]:
        """Per fault of a record's bank: its grid, the reference's zone, and the
        log-likelihood over the grid of each back-to-back window, longest and shortest,
        against the reference and (``@own``) against the record's own past (the windows
        whose own reference is fitted on every sample only)."""

        def fitted(name: str, a: int, b: int) -> bool:
            return a >= bank.past_min and bool(bank.own_ready[name][a:b].all())

        out = {}
        for name in bank.detectors:
            cum = bank.cum[name]
            point = bank.zone_bounds[name][0]
            out[name] = {
                "grid": bank.grid[name],
                "zone": bank._between(name, point, point),
                "longest": [cum[b] - cum[a] for a, b in bank.tiles()],
                "longest@own": [
                    bank.own_gain(name, a, b) for a, b in bank.tiles() if fitted(name, a, b)
                ],
                "shortest": [cum[b] - cum[a] for a, b in bank.tiles(shortest=True)],
                "shortest@own": [
                    bank.own_gain(name, a, b)
                    for a, b in bank.tiles(shortest=True)
                    if fitted(name, a, b)
                ],
            }
        return out

    @staticmethod
    def _dispersion(records: list[list[np.ndarray]]) -> float:
        """φ: twice the log-likelihood by which each longest window prefers its own size to
        its record's, whose median is χ²₁'s (0.455) for a true likelihood, over 0.455.
        ``records``: per record, its longest windows' log-likelihoods over the grid (against
        the reference, or against the record's own past on its fitted windows)."""
        twice = []
        for tiles in records:
            if not tiles:
                continue
            whole = int(np.argmax(sum(tiles)))
            for ll in tiles:
                twice.append(2 * float(ll.max() - ll[whole]))
        if len(twice) < 3:
            return 1.0
        return max(1.0, float(np.median(twice)) / float(chi2.ppf(0.5, 1)))

    @staticmethod
    def _healthy_point(name: str, f: Features) -> float:
        return {"current_limit": f.scales.current_limit_a}.get(
            name, {"friction": 1.0, "torque_constant": 1.0}.get(name, 0.0)
        )

    def threshold(self, fault: str, per_hour: float) -> Threshold:
        """The threshold for ``per_hour`` false alarms of one detector, and its measured rate.

        Parameters
        ----------
        fault : str
            A model-based detector's fault.
        per_hour : float
            False alarms per hour asked (> 0).

        Returns
        -------
        Threshold
        """
        if not (math.isfinite(per_hour) and per_hour > 0):
            raise ConfigError(f"the false-alarm rate must be > 0 per hour, got {per_hour}")
        peaks = np.array(self.peaks[fault])
        wanted = per_hour * self.hours  # alarms over the calibration hours
        m = math.floor(wanted)
        if m >= 1 and peaks.size > m:  # exceeded m times: the m-th largest peak's successor
            h = float(peaks[m])
            extrapolated = False
        elif m >= 1:  # more alarms asked than the statistic ever rose above its floor: the
            # floor, where every excursion counts (the rate measured there is the most it gives)
            h = HALF_CHI2_95
            extrapolated = False
        else:
            tail = peaks[: min(TAIL, peaks.size)]
            if tail.size >= MIN_TAIL:
                u, scale, m = float(tail[-1]), float(np.mean(tail - tail[-1])), tail.size
            else:  # the GLR's own tail: P(log-LR > h) ∝ exp(−h)
                u, scale, m = HALF_CHI2_95, 1.0, max(peaks.size, 1)
            # never a lighter tail than the GLR's own (scale 1): a few peaks just over the
            # floor say little of the rare ones, which one channel of the statistic may hold
            h = u + max(scale, 1.0) * math.log(m / max(wanted, 1e-300))
            h = max(h, float(peaks[0]) if peaks.size else HALF_CHI2_95)
            extrapolated = True
        n = int(np.sum(peaks > h))
        return Threshold(h, per_hour, n / self.hours, garwood(n, self.hours), extrapolated)

    # -- the file -----------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "Ts": self.Ts,
            "hours": self.hours,
            "records": self.records,
            "origin": self.origin,
            "sources": list(self.sources),
            "noise": self.noise.to_dict(),
            "zones": {k: list(v) for k, v in self.zones.items()},
            "drift": dict(self.drift),
            "dispersion": dict(self.dispersion),
            "peaks": {k: list(v) for k, v in self.peaks.items()},
            "repeat_probability": self.repeat_probability,
            "lost_per_sample": self.lost_per_sample,
        } | ({} if self.quick_window_s is None else {"quick_window_s": self.quick_window_s})

    @classmethod
    def from_dict(cls, d: dict, source: str = "calibration") -> DiagnosisCalibration:
        """Read the JSON form (``FileFormatError`` when it is not one)."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise FileFormatError(
                f"{source}: not a diagnosis calibration ({FORMAT}); make one with "
                "rwlab diagnose calibrate RECORDS... --model model.json --out calibration.json"
            )
        try:
            return cls(
                Ts=float(d["Ts"]),
                hours=float(d["hours"]),
                noise=NoiseModel.from_dict(d["noise"]),
                zones={k: (float(v[0]), float(v[1])) for k, v in d["zones"].items()},
                drift={k: float(v) for k, v in d["drift"].items()},
                dispersion={k: float(v) for k, v in d["dispersion"].items()},
                peaks={k: tuple(float(x) for x in v) for k, v in d["peaks"].items()},
                repeat_probability=float(d["repeat_probability"]),
                lost_per_sample=float(d["lost_per_sample"]),
                sources=tuple(d.get("sources", ())),
                origin=str(d.get("origin", "")),
                records=int(d.get("records", 0)),
                quick_window_s=(
                    None if d.get("quick_window_s") is None else float(d["quick_window_s"])
                ),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise FileFormatError(f"{source}: bad diagnosis calibration ({exc!r})") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> DiagnosisCalibration:
        """Read a calibration file written by :meth:`save` (``rwlab diagnose calibrate``)."""
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{p}: not a readable calibration ({exc})") from None
        return cls.from_dict(d, str(p))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the file atomically."""
        if self.hours <= 0:
            raise DataError("an empty calibration cannot be saved")
        return write_json(path, self.to_dict())


def _held(grid: np.ndarray, ci: tuple[float, float]) -> tuple[float, float]:
    """The grid points an interval holds, its first and last: zones and drifts are measured
    on the grid the detectors decide on (an interval's end between two grid points would
    drop the point it reaches into: a healthy in-loop clamp zone lost its lowest point, and
    healthy wheels read a 0.06-A clamp after a reallocation)."""
    inside = grid[(grid >= ci[0]) & (grid <= ci[1])]  # the fit's own size at least
    return float(inside[0]), float(inside[-1])


def twin_calibration_file(wheel: str) -> Path:
    """The package's twin-calibrated file for a wheel preset (module docstring).

    Parameters
    ----------
    wheel : str
        A wheel preset's name (``rwlab wheel models``).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ConfigError
        No file shipped for that wheel.
    """
    path = Path(__file__).with_name(f"twin_calibration_{wheel}.json")
    if not path.is_file():
        shipped = sorted(
            p.stem.removeprefix("twin_calibration_")
            for p in path.parent.glob("twin_calibration_*.json")
        )
        raise ConfigError(
            f"no twin calibration for the wheel {wheel!r} (shipped: {', '.join(shipped)}); "
            "calibrate on the wheel's own healthy records: rwlab diagnose calibrate RECORDS... "
            "--model model.json --out calibration.json"
        )
    return path


def model_calibration_file(model_file: str | os.PathLike) -> Path:
    """The twin calibration of a ``model.json``'s wheel preset (``rwlab diagnose`` without
    ``--calibration``): only for a model of a preset's own spec (the same hash).

    Parameters
    ----------
    model_file : path-like
        A ``model.json`` written by ``rwlab identify``.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ConfigError
        A model of another wheel, or of no wheel spec: it needs the lab's own calibration.
    """
    from rwlab.ident.model_file import WheelModelFile
    from rwlab.wheelspec.files import preset_names

    spec = WheelModelFile.load(model_file).wheel_spec
    if spec is None or not spec.is_preset():
        wheel = "no wheel spec" if spec is None else f"the wheel {spec.name!r}, not a preset's own"
        raise ConfigError(
            f"{model_file} is a model of {wheel}: the shipped calibrations are measured on "
            f"the presets' twins ({', '.join(preset_names())}). Calibrate on this wheel's "
            "healthy records (rwlab diagnose calibrate RECORDS... --model model.json --out "
            "calibration.json) and give it (rwlab diagnose --calibration, rwlab experiment "
            "--diagnosis-calibration, calibration= in Python), or run the rule detectors "
            "(rwlab diagnose --rules)"
        )
    return twin_calibration_file(spec.name)
