"""Evaluation and decision: each model-based detector's GLR over windows of the record.

For detector j and a window of samples [a, k), the window's log-likelihood
over the size grid is a difference of cumulative sums of the per-sample gains
(:meth:`Detector.gains`), so every window costs O(grid). Its statistic is the
GLR against the sizes a healthy wheel may have, the larger of two:

- against the *population zone* (the sizes healthy records of the calibration
  were consistent with): a fault present from power-up;
- against the record's *own past* (the sizes the samples before the window are
  consistent with, widened by the drift measured within healthy records): a
  fault that starts within the record, smaller than the spread between units.

The windows end every ``EVERY_S`` and span each of ``WINDOWS_S`` (a coarse
grid of change times: the GLR's maximisation over the onset).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rwlab.diagnose.detectors import MODEL_BASED, Fit, detector
from rwlab.diagnose.detectors.base import HALF_CHI2_95, profile_fit
from rwlab.diagnose.features import LIMIT_REFERENCE_LAG_S, REFERENCE_LAG_S, Features
from rwlab.diagnose.noise import BLOCK_S, NoiseModel

__all__ = ["EVERY_S", "WINDOWS_S", "Bank", "WindowFit", "widened"]

# design choices, not measurements: a decision every 5 s; onsets 1, 2.5 and 5 min
# back (5 min is the longest detection delay the lab accepts)
EVERY_S = 5.0
WINDOWS_S = (BLOCK_S, 150.0, 300.0)
PAST_MIN_S = 120.0  # the record's own past counts once it spans this much
SUPPORT = 2 * HALF_CHI2_95  # a past consistent with a size: within this log-likelihood


@dataclass(frozen=True)
class WindowFit:
    """A detector's fit on one window.

    Attributes
    ----------
    fit : Fit
    start_s, end_s : float
        The window, s.
    against : str
        ``"population"`` or ``"own past"``: which healthy zone the log-LR is over.
    """

    fit: Fit
    start_s: float
    end_s: float
    against: str


def _relative(fit: Fit, before: Fit) -> Fit:
    """A change against the record's own past: a factor as the ratio to the past's, a bias
    as the difference (intervals combined in quadrature, in log for factors); a clamp in A
    is absolute."""
    if fit.unit == "factor":
        lo, hi = np.log(fit.ci95), np.log(before.ci95)
        mid = np.log(fit.size / before.size)
        half = np.hypot(np.diff(lo)[0], np.diff(hi)[0]) / 2
        return replace(
            fit,
            size=float(np.exp(mid)),
            ci95=(float(np.exp(mid - half)), float(np.exp(mid + half))),
        )
    if fit.unit == "rpm":
        half = float(np.hypot(fit.ci95[1] - fit.ci95[0], before.ci95[1] - before.ci95[0])) / 2
        mid = fit.size - before.size
        return replace(fit, size=mid, ci95=(mid - half, mid + half))
    return fit


def _away(size: float, before: float, healthy: float) -> bool:
    """A change from ``before`` to ``size`` moves away from the healthy size: a fault makes
    a wheel worse, never better (a chirp's slow start fits a clamp far below the spec's
    that its fast end refutes: a move back toward the healthy clamp is no fault)."""
    if np.isinf(healthy):
        return size < before if healthy > 0 else size > before
    return abs(size - healthy) > abs(before - healthy)


def widened(fit: Fit, zone: tuple[float, float]) -> Fit:
    """A fault from power-up against the population, as a size of the unit's own: the
    fit is against the reference, and the unit sits anywhere in the healthy zone u, so
    a factor F = F_ref/u and a bias b = b_ref − u (the zone about the nominal size).

    Parameters
    ----------
    fit : Fit
        A fit against the population (the reference unit's scale).
    zone : tuple of 2 float
        The healthy units' sizes [lo, hi], in ``fit.unit``.

    Returns
    -------
    Fit
        ``fit`` with its interval widened (a clamp's, in A, as it is).
    """
    lo, hi = fit.ci95
    if fit.unit == "factor":
        return replace(fit, ci95=(lo / max(zone[1], 1.0), hi / min(zone[0], 1.0)))
    if fit.unit == "rpm":
        return replace(fit, ci95=(lo - max(zone[1], 0.0), hi - min(zone[0], 0.0)))
    return fit


def _cumsum_rows(gains: np.ndarray) -> np.ndarray:
    """The cumulative sums of ``gains`` (N, G) down its rows after a row of zeros, shape
    (N + 1, G): numpy's ``cumsum(axis=0)``, the same additions in the same order, row by row
    (three times faster on a C-ordered (N, G): numpy's strides down the columns)."""
    out = np.empty((gains.shape[0] + 1, gains.shape[1]))
    out[0] = 0.0
    for k, row in enumerate(gains):
        np.add(out[k], row, out=out[k + 1])
    return out


class _Cumulative:
    """One detector's cumulative gains, row k the sum over samples [0, k) (row 0 is 0),
    kept from row ``first`` on in a buffer a growing record extends in place and that
    drops the rows no window reaches any more. Hand-written: numpy has no growable array,
    and copying a live record's whole history at every decision grew as its square."""

    def __init__(self, rows: np.ndarray) -> None:
        self.buf, self.first, self.n = rows, 0, rows.shape[0]

    def __getitem__(self, k: int) -> np.ndarray:
        i = k - self.first
        if 0 <= i < self.n:
            return self.buf[i]
        if k == 0:
            return np.zeros(self.buf.shape[1])
        raise IndexError(f"row {k} is no longer kept (rows {self.first}-{self.first + self.n - 1})")

    @property
    def rows(self) -> np.ndarray:
        """The rows kept, shape (n, G), from row ``first``."""
        return self.buf[: self.n]

    def extend(self, start: int, new: np.ndarray, keep_from: int) -> None:
        """Rows ``start + 1`` on become ``new`` (cumulative from row ``start``'s value); rows
        before ``keep_from`` (at most ``start``) may be dropped."""
        kept = start + 1 - self.first
        if kept + new.shape[0] > self.buf.shape[0]:  # full: drop the old rows, grow if need be
            drop = max(0, min(keep_from, start) - self.first)
            kept -= drop
            size = max(self.buf.shape[0], 2 * (kept + new.shape[0]))
            buf = np.empty((size, self.buf.shape[1])) if size > self.buf.shape[0] else self.buf
            buf[:kept] = self.buf[drop : drop + kept].copy()
            self.buf, self.first = buf, self.first + drop
        self.buf[kept : kept + new.shape[0]] = new
        self.n = kept + new.shape[0]


class Bank:
    """The model-based detectors' cumulative gains over one record.

    Parameters
    ----------
    features : Features
    noise : NoiseModel
    zones : dict of str to tuple of 2 float
        Per fault, the population's healthy sizes [lo, hi].
    drift : dict of str to float
        Per fault, how far a healthy record's size moves within it (size units).
    dispersion : dict of str to float, optional
        Per fault, φ: the healthy windows' scatter of the size over what the
        likelihood says (quasi-likelihood: the intervals are those of ll/φ, so
        they carry the model's misfit). 1 if absent.
    faults : sequence of str
        The model-based detectors to run.
    quick_s : float, optional
        A window shorter than ``WINDOWS_S``'s for the decisions (a large fault, a dead
        motor, crosses at once where the shortest window still holds mostly healthy
        samples); its thresholds come from a calibration measured with it.
    before : Bank, optional
        The same detectors on the record's first samples, as it was growing (a live
        diagnosis): its gains are kept and only the new samples' computed (a sample's gains
        depend on its past and, for a clamp's flat top, its next sample: the earlier
        bank's last sample is computed again). Its storage is taken over: ``before`` is
        not to be used after.
    keep_from : int
        With ``before``: the first sample any later window or event reads (earlier
        cumulative rows may be dropped).
    """

    def __init__(
        self,
        features: Features,
        noise: NoiseModel,
        zones,
        drift,
        dispersion=None,
        faults=MODEL_BASED,
        quick_s: float | None = None,
        before: Bank | None = None,
        keep_from: int = 0,
    ) -> None:
        self.features = features
        self.keep_from = keep_from
        self.detectors = {name: detector(name) for name in faults}
        self.grid = {n: d.grid(features) for n, d in self.detectors.items()}
        self.weights = noise.weights(features)  # the sizes are read again on them (refine)
        start = 0 if before is None else max(before.features.N - 1, 0)
        self.cum: dict[str, _Cumulative] = self._grown(
            None if before is None else before.cum, start, features, self.weights
        )
        # the same gains against the record's own past (features.own()): a change of the
        # unit against itself, free of its misfit to the reference unit
        # (``Detector.own_law``: against the unit's friction law alone)
        own = {law: features.own(law) for law in (False, True)}
        weights = {law: noise.weights(f) for law, f in own.items()}
        self.own_ready: dict[str, np.ndarray] = {}
        self.cum_own: dict[str, _Cumulative] = {}
        self.cum_limit: dict[str, _Cumulative] = {}
        for law in (False, True):
            names = [n for n, d in self.detectors.items() if d.own_law == law]
            f, w = own[law], weights[law]
            self.cum_own |= self._grown(before and before.cum_own, start, f, w, names)
            limited = [n for n in names if self.detectors[n].reads_limit]
            self.cum_limit |= self._grown(
                before and before.cum_limit, start, f, w, limited, limit=True
            )
            for n in names:
                self.own_ready[n] = np.isfinite(f.current_nuisance_a[:, 0])  # type: ignore[index]
        self.zone = {n: self._between(n, *zones[n]) for n in self.detectors}
        self.zone_bounds = {n: (float(zones[n][0]), float(zones[n][1])) for n in self.detectors}
        self.drift = drift
        self.dispersion = {n: (dispersion or {}).get(n, 1.0) for n in self.detectors}
        self.dispersion.update(
            {k: v for k, v in (dispersion or {}).items() if k.split("@")[0] in self.detectors}
        )
        Ts = features.scales.Ts
        self.every = max(1, round(EVERY_S / Ts))
        self.windows = tuple(max(2, round(w / Ts)) for w in WINDOWS_S)
        quick = () if quick_s is None else (max(2, round(quick_s / Ts)),)
        self.decision_windows = quick + self.windows
        self.past_min = round(PAST_MIN_S / Ts)
        self.own_span = round(REFERENCE_LAG_S / Ts)
        self.limit_span = round(LIMIT_REFERENCE_LAG_S / Ts)

    def _grown(
        self, before, start: int, features: Features, weights, names=None, limit: bool = False
    ) -> dict[str, _Cumulative]:
        """Per detector in ``names`` (all by default), the cumulative per-sample gains (with
        ``limit``: those read at the acceleration limit), rows 0 to N: ``before``'s up to
        sample ``start``, the rest computed on the samples from ``start`` with the one
        before as their past."""
        names = list(self.detectors) if names is None else names

        def gains(n: str, f: Features, w) -> np.ndarray:
            d = self.detectors[n]
            out = d.limit_gains(f, w, self.grid[n]) if limit else d.gains(f, w, self.grid[n])
            assert out is not None  # reads_limit: the detector has limit gains
            return out

        if start == 0 or before is None:
            return {n: _Cumulative(_cumsum_rows(gains(n, features, weights))) for n in names}
        f = features.rows(start - 1)
        w = {k: v[start - 1 :] for k, v in weights.items()}
        for n in names:
            new = _cumsum_rows(gains(n, f, w)[1:])
            before[n].extend(start, before[n][start] + new[1:], self.keep_from)
        return {n: before[n] for n in names}

    def _between(self, name: str, lo: float, hi: float) -> np.ndarray:
        g = self.grid[name]
        mask = (g >= lo) & (g <= hi)
        if not mask.any():  # a zone between grid points holds the nearest one
            mask[np.argmin(np.abs(g - 0.5 * (lo + hi)))] = True
        return mask

    def fit(self, name: str, a: int, k: int) -> WindowFit:
        """Detector ``name`` on samples [a, k): its GLR over the larger-supported healthy zone.

        Parameters
        ----------
        name : str
            A model-based detector's fault.
        a, k : int
            The window's first and past-the-last samples.

        Returns
        -------
        WindowFit
        """
        ll = self.cum[name][k] - self.cum[name][a]
        det = self.detectors[name]
        zone, phi = self.zone[name], self.dispersion[name]
        best = profile_fit(det.fault, det.unit, self.grid[name], ll, zone, phi, det.worse)
        against = "population"
        if a >= self.past_min:
            change = self._against_own(name, a, k)
            if change is not None and change.log_lr > best.log_lr:
                best, against = change, "own past"
        if against == "population":
            best = widened(best, self.zone_bounds[name])
        best = det.refine(self.features, self.weights, best, a, k)
        t = self.features.t_s
        return WindowFit(best, float(t[a]), float(t[k - 1]), against)

    def _against_own(self, name: str, a: int, k: int) -> Fit | None:
        """Detector ``name`` on samples [a, k) against the record's own past [0, a): the
        change's fit, relative to the past's, or None where it moves toward healthy.

        The healthy zone is the past's own support, widened by the healthy drift. A
        detector whose channel the own reference fits whole (``Detector.own_law``:
        friction, read at constant speed, where the reference is the unit's fitted
        law) is healthy at its healthy size alone (a point null: what a healthy unit's
        law drifts within a record its thresholds carry, measured on healthy records),
        and the past's support only widens the size's interval."""
        det, grid = self.detectors[name], self.grid[name]
        ll, past = self.own_gain(name, a, k), self.own_gain(name, 0, a, capped=False)
        phi = self.dispersion.get(f"{name}@own", self.dispersion[name])
        h = det.healthy_size
        if det.own_law:
            zone = self._between(name, h, h)
        else:
            drift = self.drift.get(f"{name}@own", self.drift[name])
            ok = grid[past >= past.max() - SUPPORT * phi]
            zone = self._between(name, ok[0] - drift, ok[-1] + drift)
        change = profile_fit(det.fault, det.unit, grid, ll, zone, phi, det.worse)
        before = profile_fit(det.fault, det.unit, grid, past, zone, phi)
        if det.own_law:  # the past's spread about the healthy size
            lo, hi = before.ci95
            before = replace(before, size=h, ci95=(lo / before.size * h, hi / before.size * h))
        elif not _away(change.size, before.size, det.healthy_size):
            return None
        return _relative(change, before)

    def own_gain(self, name: str, a: int, k: int, capped: bool = True) -> np.ndarray:
        """Detector ``name``'s log-likelihood over its grid on samples [a, k) against the
        record's own past.

        Parameters
        ----------
        name : str
            A model-based detector's fault.
        a, k : int
            The window's first and past-the-last samples.
        capped : bool
            Each channel's samples up to its reference's lag after a only (later
            samples' reference holds the window's own).

        Returns
        -------
        numpy.ndarray, shape (G,)
        """
        out = np.zeros(len(self.grid[name]))
        for cum, span in ((self.cum_own, self.own_span), (self.cum_limit, self.limit_span)):
            if name in cum:
                end = min(k, a + span) if capped else k
                out = out + cum[name][end] - cum[name][a]
        return out

    def at(self, name: str, k: int) -> WindowFit:
        """The best window ending at sample k (exclusive) for detector ``name``.

        Parameters
        ----------
        name : str
            A model-based detector's fault.
        k : int
            The decision's past-the-last sample.

        Returns
        -------
        WindowFit
            The window of the largest log-LR among the decision windows.
        """
        fits = [
            self.fit(name, max(0, k - w), k)
            for w in self.decision_windows
            if k - max(0, k - w) >= 2
        ]
        return max(fits, key=lambda f: f.fit.log_lr)

    def tiles(self, shortest: bool = False) -> list[tuple[int, int]]:
        """Back-to-back windows of the longest (or the ``shortest``) length over the
        record: (start, end)."""
        w = self.windows[0] if shortest else self.windows[-1]
        return [(a, a + w) for a in range(0, self.features.N - w + 1, w)]

    def ends(self) -> range:
        """The window ends the decisions are taken at (exclusive sample indices)."""
        return range(self.every, self.features.N + 1, self.every)

    def statistics(self) -> dict[str, np.ndarray]:
        """Each detector's statistic (log-LR) at every decision, shape (len(ends),)."""
        ends = list(self.ends())
        return {n: np.array([self.at(n, k).fit.log_lr for k in ends]) for n in self.detectors}
