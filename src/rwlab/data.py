"""Sampled input/output records (``IOData``) and their file formats.

``IOData`` is the one container every identification function takes. It plays
the role of MATLAB's ``iddata``: inputs ``u`` (N×nu), outputs ``y`` (N×ny), an
explicit sample time ``Ts`` in seconds, channel names and units. The sample
time is required and never defaulted: paper A's continuous-time model is wrong
precisely because its data silently carried MATLAB's default ``Ts = 1``.

Preprocessing (``detrend``, ``normalize``) returns a new record and keeps what
it removed in a :class:`Trend`, so results can be reported in physical units.
Nothing here modifies the caller's arrays.

Why this module is long: ``IOData`` and its file formats (CSV, .dat, Parquet, .mat and
the registered readers) are one concept: the container and how it is read and written.
"""

from __future__ import annotations

import copy
import importlib.metadata
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal as sps

from rwlab._io import atomic_write_bytes  # re-exported: it lived here before rwlab._io
from rwlab.errors import DataError, FileFormatError, RwlabError, RwlabWarning

__all__ = [
    "IOData",
    "Trend",
    "atomic_write_bytes",
    "load",
    "merge",
    "register_reader",
    "register_writer",
]


@dataclass(frozen=True)
class Trend:
    """Affine map from stored (preprocessed) values back to physical values.

    ``physical = scale * stored + offset + slope * t`` per channel, with ``t``
    the sample time stamp in seconds. MATLAB's ``TrendInfo`` plus a scale.

    Attributes
    ----------
    input_offset, input_slope, input_scale : numpy.ndarray, shape (nu,)
        Input offset (input unit), slope (input unit per s) and scale.
    output_offset, output_slope, output_scale : numpy.ndarray, shape (ny,)
        The same for the outputs.
    """

    input_offset: np.ndarray
    input_slope: np.ndarray
    input_scale: np.ndarray
    output_offset: np.ndarray
    output_slope: np.ndarray
    output_scale: np.ndarray

    @classmethod
    def identity(cls, nu: int, ny: int) -> Trend:
        """The trend of a record that has not been preprocessed."""
        return cls(np.zeros(nu), np.zeros(nu), np.ones(nu), np.zeros(ny), np.zeros(ny), np.ones(ny))

    def then(self, offset_u, slope_u, scale_u, offset_y, slope_y, scale_y) -> Trend:
        """Compose with a further step ``stored_old = scale*stored_new + offset + slope*t``."""
        return Trend(
            self.input_scale * offset_u + self.input_offset,
            self.input_scale * slope_u + self.input_slope,
            self.input_scale * scale_u,
            self.output_scale * offset_y + self.output_offset,
            self.output_scale * slope_y + self.output_slope,
            self.output_scale * scale_y,
        )

    def output_to_physical(self, y: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Map stored outputs ``y`` (N×ny or N) at times ``t`` (s) to physical units."""
        y2 = np.asarray(y, dtype=float)
        t2 = np.asarray(t, dtype=float)
        if y2.ndim == 1:
            return self.output_scale[0] * y2 + self.output_offset[0] + self.output_slope[0] * t2
        return self.output_scale * y2 + self.output_offset + np.outer(t2, self.output_slope)

    def input_to_physical(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Map stored inputs ``u`` (N×nu or N) at times ``t`` (s) to physical units."""
        u2 = np.asarray(u, dtype=float)
        t2 = np.asarray(t, dtype=float)
        if u2.ndim == 1:
            return self.input_scale[0] * u2 + self.input_offset[0] + self.input_slope[0] * t2
        return self.input_scale * u2 + self.input_offset + np.outer(t2, self.input_slope)

    def to_dict(self) -> dict:
        """Plain-JSON form."""
        return {k: np.asarray(v).tolist() for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> Trend:
        """Inverse of :meth:`to_dict`."""
        return cls(**{k: np.asarray(d[k], dtype=float) for k in cls.__dataclass_fields__})


def _as_matrix(x, what: str) -> np.ndarray:
    """Copy ``x`` to a float (N, n) array, rejecting anything that is not finite numbers."""
    try:
        arr = np.array(x, dtype=float, copy=True)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{what} must be numeric: {exc}") from None
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DataError(f"{what} must be 1-D (N,) or 2-D (N, channels); got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise DataError(
            f"{what} contains NaN or Inf (first at sample {bad[0]}, channel {bad[1]}); "
            "remove or interpolate the bad samples before identification"
        )
    return arr


def _names(names, n: int, prefix: str) -> tuple[str, ...]:
    if names is None:
        return tuple(f"{prefix}{i + 1}" for i in range(n))
    names = (names,) if isinstance(names, str) else tuple(str(s) for s in names)
    if len(names) != n:
        raise DataError(f"{len(names)} {prefix}-names given for {n} channels")
    return names


#: Time columns read in seconds, and in milliseconds (converted), by name.
TIME_NAMES = ("time_s", "time", "t", "ts_s", "timestamp_s")
TIME_MS_NAMES = ("time_ms", "t_ms", "timestamp_ms")

# A wheel's speed loop is sampled at 1 Hz-1 kHz (paper A: 2 Hz commands, 10 Hz
# telemetry) and a test lasts minutes to hours; the bundled process sets reach Ts = 9 s
# (gas furnace) and 1.2 h. Beyond these the time column is likely in other units.
PLAUSIBLE_TS_MAX_S = 10.0
PLAUSIBLE_SPAN_MAX_S = 86400.0


def warn_implausible_Ts(Ts: float, n: int, where: str) -> None:
    """Warn, with the numbers, when a time base read from a file is implausible.

    Parameters
    ----------
    Ts : float
        The sample time read, s.
    n : int
        Samples.
    where : str
        Where it was read (``"column 'time_s' of x.csv"``).
    """
    import warnings

    span = Ts * max(n - 1, 0)
    if Ts <= PLAUSIBLE_TS_MAX_S and span <= PLAUSIBLE_SPAN_MAX_S:
        return
    why = (
        f"Ts = {Ts:g} s"
        if Ts > PLAUSIBLE_TS_MAX_S
        else f"{n} samples spanning {span / 86400:.3g} days"
    )
    warnings.warn(
        f"{where} reads as seconds and gives {why}, implausible for a wheel test; if it is "
        f"in milliseconds, Ts is {Ts / 1000:g} s: divide it by 1000 or name the column time_ms",
        RwlabWarning,
        stacklevel=3,
    )


def _column_list(cols) -> list:
    if cols is None:
        return []
    return [cols] if isinstance(cols, str) else list(cols)


def _frame_time(frame, time: str | None) -> tuple[np.ndarray | None, str]:
    """A DataFrame's time stamps in seconds, and where they came from."""
    names = (
        [time]
        if time is not None
        else [c for c in frame.columns if str(c).lower() in TIME_NAMES + TIME_MS_NAMES]
    )
    if names:
        col = names[0]
        scale = 1e-3 if str(col).lower() in TIME_MS_NAMES or str(col).endswith("_ms") else 1.0
        try:
            return frame[col].to_numpy(dtype=float) * scale, f"column {col!r}"
        except (TypeError, ValueError):
            raise DataError(f"the time column {col!r} must be numeric") from None
    index = frame.index
    kind = getattr(getattr(index, "dtype", None), "kind", "")
    if kind in "Mm" and kind:  # datetimes or time deltas, at whatever resolution pandas keeps
        import pandas as pd

        since = index - index[0] if kind == "M" else index
        where = "the DatetimeIndex" if kind == "M" else "the TimedeltaIndex"
        return np.asarray(since / pd.Timedelta(seconds=1), dtype=float), where
    label = str(index.name or "").lower()
    if label in TIME_NAMES + TIME_MS_NAMES:
        scale = 1e-3 if label in TIME_MS_NAMES else 1.0
        return np.asarray(index, dtype=float) * scale, f"the index {index.name!r}"
    return None, ""


def check_Ts(Ts) -> float:
    """Validate a sample time in seconds: required, finite and > 0."""
    if Ts is None:
        raise DataError(
            "the sample time Ts is required (seconds); rwlab never assumes Ts = 1 "
            "because a wrong Ts silently corrupts every continuous-time result"
        )
    try:
        value = float(Ts)
    except (TypeError, ValueError):
        raise DataError(f"Ts must be a number of seconds, got {Ts!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise DataError(f"Ts must be finite and > 0 seconds, got {Ts!r}")
    return value


class IOData:
    """A sampled input/output record with an explicit sample time.

    Parameters
    ----------
    u : array_like, shape (N,) or (N, nu), or None
        Input samples. ``None`` (or an (N, 0) array): no input, a time series
        (MATLAB ``iddata(y, [], Ts)``).
    y : array_like, shape (N,) or (N, ny)
        Output samples.
    Ts : float
        Sample time in seconds; required, > 0.
    input_names, output_names : sequence of str, optional
        Channel names (default ``u1..``, ``y1..``).
    input_units, output_units : sequence of str, optional
        Channel units, free text (default empty).
    tstart : float, optional
        Time stamp of the first sample in seconds (default 0).
    trend : Trend, optional
        What preprocessing removed (default: nothing).
    name : str, optional
        A label for reports.
    source : dict, optional
        What the file said about where the samples came from (a testbed
        record's metadata: its wheel's parameters, mode, Ts); copied, kept
        through slicing and preprocessing.

    Notes
    -----
    The arrays are copied; the caller's arrays are never modified. NaN, Inf,
    unequal lengths and a missing or non-positive ``Ts`` raise ``DataError``.
    """

    def __init__(
        self,
        u,
        y,
        Ts,
        *,
        input_names=None,
        output_names=None,
        input_units=None,
        output_units=None,
        tstart: float = 0.0,
        trend: Trend | None = None,
        name: str = "",
        source: dict | None = None,
    ) -> None:
        self.Ts = check_Ts(Ts)
        self.y = _as_matrix(y, "y")
        self.u = np.zeros((self.y.shape[0], 0)) if u is None else _as_matrix(u, "u")
        if self.u.shape[0] != self.y.shape[0]:
            raise DataError(
                f"u has {self.u.shape[0]} samples but y has {self.y.shape[0]}; "
                "input and output must have the same length"
            )
        if self.y.shape[1] == 0:
            raise DataError("y must have at least one output channel")
        self.u.setflags(write=False)
        self.y.setflags(write=False)
        self.input_names = _names(input_names, self.nu, "u")
        self.output_names = _names(output_names, self.ny, "y")
        self.input_units = _names(input_units or [""] * self.nu, self.nu, "unit")
        self.output_units = _names(output_units or [""] * self.ny, self.ny, "unit")
        self.tstart = float(tstart)
        self.trend = trend if trend is not None else Trend.identity(self.nu, self.ny)
        self.name = name
        self.source = copy.deepcopy(dict(source or {}))

    # -- shape ---------------------------------------------------------------
    @property
    def N(self) -> int:
        """Number of samples."""
        return self.y.shape[0]

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return self.u.shape[1]

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return self.y.shape[1]

    @property
    def time(self) -> np.ndarray:
        """Sample time stamps in seconds, shape (N,)."""
        return self.tstart + self.Ts * np.arange(self.N)

    def __len__(self) -> int:
        return self.N

    def __repr__(self) -> str:
        return (
            f"IOData(N={self.N}, nu={self.nu}, ny={self.ny}, Ts={self.Ts:g} s, "
            f"inputs={list(self.input_names)}, outputs={list(self.output_names)})"
        )

    def _repr_html_(self) -> str:
        """A table of the channels (name, unit, range), for Jupyter."""
        import html

        rows = []
        for kind, names, units, x in (
            ("input", self.input_names, self.input_units, self.u),
            ("output", self.output_names, self.output_units, self.y),
        ):
            for j, (n, unit) in enumerate(zip(names, units, strict=True)):
                lo, hi = (float(x[:, j].min()), float(x[:, j].max())) if self.N else (0.0, 0.0)
                rows.append(
                    f"<tr><td>{kind}</td><td>{html.escape(n)}</td><td>{html.escape(unit)}</td>"
                    f"<td>{lo:.4g} … {hi:.4g}</td></tr>"
                )
        head = (
            f"<strong>IOData</strong> {html.escape(self.name)}: N = {self.N}, "
            f"Ts = {self.Ts:g} s ({self.N * self.Ts:g} s)"
        )
        return (
            f"<div>{head}<table><tr><th></th><th>channel</th><th>unit</th><th>range</th></tr>"
            f"{''.join(rows)}</table></div>"
        )

    def to_pandas(self):
        """The samples as a ``pandas.DataFrame``: one column per channel, indexed by time.

        Returns
        -------
        pandas.DataFrame
            Shape (N, nu + ny); index ``time_s`` (s); columns the channel names.
        """
        from rwlab._display import pandas

        pd = pandas()
        names = [*self.input_names, *self.output_names]
        frame = pd.DataFrame(np.hstack([self.u, self.y]), columns=names)
        frame.index = pd.Index(self.time, name="time_s")
        return frame

    @classmethod
    def from_pandas(
        cls,
        frame,
        u=None,
        y=None,
        Ts: float | None = None,
        *,
        time: str | None = None,
        name: str = "",
    ) -> IOData:
        """A record from a ``pandas.DataFrame`` (MATLAB's ``iddata`` from a table).

        Parameters
        ----------
        frame : pandas.DataFrame
            One row per sample. It is not modified.
        u : str or sequence of str, optional
            The input column(s); none for a time series.
        y : str or sequence of str
            The output column(s).
        Ts : float, optional
            Sample time, s. Default: from the time, which is the ``time`` column,
            else a column named ``time_s``/``time``/``t`` (or ``time_ms``, in ms),
            else the index when it holds times (a ``DatetimeIndex``, a
            ``TimedeltaIndex`` or an index named like those columns, as
            :meth:`to_pandas` writes it). Given with a time, the two must agree.
        time : str, optional
            The column of time stamps, s (``*_ms``: ms).
        name : str, optional
            A label for reports.

        Returns
        -------
        IOData
            ``tstart`` is the first time stamp (0 without one); channel names are
            the column names.

        Raises
        ------
        DataError
            No ``y``, an unknown or non-numeric column, time stamps that are not
            uniform or disagree with ``Ts``, no time and no ``Ts``.
        """
        outputs, inputs = _column_list(y), _column_list(u)
        if not outputs:
            raise DataError("from_pandas needs the output column(s): y='speed_rpm' or y=[...]")
        for col in [*inputs, *outputs, *([time] if time is not None else [])]:
            if col not in frame.columns:
                raise DataError(f"no column {col!r}; the frame's columns are {list(frame.columns)}")
        stamps, where = _frame_time(frame, time)
        tstart = 0.0
        if stamps is not None and len(stamps) >= 2:
            step = float(f"{(stamps[-1] - stamps[0]) / (len(stamps) - 1):.12g}")
            if step <= 0 or np.max(np.abs(np.diff(stamps) - step)) > 1e-6 * step + 1e-9:
                raise DataError(f"the time in {where} is not uniformly sampled; resample it first")
            if Ts is not None and not math.isclose(check_Ts(Ts), step, rel_tol=1e-6):
                raise DataError(f"Ts = {Ts} s disagrees with the time in {where} ({step:g} s)")
            warn_implausible_Ts(step, len(stamps), f"the time in {where}")
            Ts, tstart = step, float(stamps[0])

        def numbers(cols) -> np.ndarray | None:
            if not cols:
                return None
            try:
                return frame[list(cols)].to_numpy(dtype=float, copy=True)
            except (TypeError, ValueError):
                raise DataError(f"columns {list(cols)} must be numeric") from None

        return cls(
            numbers(inputs),
            numbers(outputs),
            Ts,
            input_names=[str(c) for c in inputs] or None,
            output_names=[str(c) for c in outputs],
            tstart=tstart,
            name=name,
        )

    def _with(self, u, y, **changes) -> IOData:
        kwargs: dict[str, Any] = dict(
            input_names=self.input_names,
            output_names=self.output_names,
            input_units=self.input_units,
            output_units=self.output_units,
            tstart=self.tstart,
            trend=self.trend,
            name=self.name,
            source=self.source,
        )
        kwargs.update(changes)
        Ts = kwargs.pop("Ts", self.Ts)
        return IOData(u, y, Ts, **kwargs)

    # -- selection -----------------------------------------------------------
    def __getitem__(self, index) -> IOData:
        """Select samples with a slice: ``data[100:500]``, ``data[::2]`` (Ts doubles)."""
        if not isinstance(index, slice):
            raise DataError("IOData supports slicing by samples only, e.g. data[100:500]")
        start, _, step = index.indices(self.N)
        if step <= 0:
            raise DataError("IOData slices must step forward")
        return self._with(
            self.u[index], self.y[index], Ts=self.Ts * step, tstart=self.tstart + start * self.Ts
        )

    def split(self, fraction: float = 0.7) -> tuple[IOData, IOData]:
        """Split into estimation and validation records at ``fraction`` of the samples.

        Parameters
        ----------
        fraction : float
            Share of the samples, in (0, 1), that goes to the first (estimation) part.
        """
        if not 0 < fraction < 1:
            raise DataError(f"split fraction must be in (0, 1), got {fraction}")
        k = round(fraction * self.N)
        if k < 1 or k >= self.N:
            raise DataError(f"cannot split {self.N} samples at {fraction}")
        return self[:k], self[k:]

    # -- preprocessing ---------------------------------------------------------
    def _reference(self, reference: IOData | None) -> IOData:
        if reference is None:
            return self
        if not isinstance(reference, IOData) or (reference.nu, reference.ny) != (self.nu, self.ny):
            raise DataError(
                "reference must be an IOData with the same inputs and outputs as the data "
                "(typically its estimation part)"
            )
        return reference

    def detrend(self, kind: str = "constant", *, reference: IOData | None = None) -> IOData:
        """Remove the mean (``kind='constant'``) or a straight line (``'linear'``).

        The removed offsets and slopes are kept in ``trend`` (MATLAB's TrendInfo).

        Parameters
        ----------
        kind : {'constant', 'linear'}
            What to remove.
        reference : IOData, optional
            Take the means (or lines) from this record, typically the estimation
            part, and remove them from every sample of ``self``: validation data
            then carry no information into the model. Default: ``self``.
        """
        if kind not in ("constant", "linear"):
            raise DataError(f"detrend kind must be 'constant' or 'linear', got {kind!r}")
        ref = self._reference(reference)
        t_ref = ref.time

        def fit(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            if kind == "constant" or ref.N < 2:
                return x.mean(axis=0), np.zeros(x.shape[1])
            coef = np.polyfit(t_ref, x, 1) if x.shape[1] else np.zeros((2, 0))
            return coef[1], coef[0]

        ou, su = fit(ref.u)
        oy, sy = fit(ref.y)
        t = self.time
        u = self.u - ou - np.outer(t, su)
        y = self.y - oy - np.outer(t, sy)
        trend = self.trend.then(ou, su, np.ones(self.nu), oy, sy, np.ones(self.ny))
        return self._with(u, y, trend=trend)

    def normalize(self, *, reference: IOData | None = None) -> IOData:
        """Scale every channel to [0, 1] (min → 0, max → 1), as paper A does.

        Beware the bias it brings to a model without an intercept (ARX, OE, BJ):
        physical zero maps to ``−min/(max − min)`` of each channel, not to 0, so
        ``A y = B u`` between normalised signals forces the static map through
        the two minima; unless ``y_min = G(1)·u_min`` the model's gain absorbs
        the offset. Prefer :meth:`detrend` or :meth:`scale` for estimation.

        Parameters
        ----------
        reference : IOData, optional
            Take minimum and range from this record (typically the estimation
            part). Default: ``self``.

        Returns
        -------
        IOData
            The normalised record; ``trend`` holds the offsets and ranges.

        Raises
        ------
        DataError
            A constant channel (its range is zero).
        """
        ref = self._reference(reference)

        def span(x: np.ndarray, names) -> tuple[np.ndarray, np.ndarray]:
            lo, hi = x.min(axis=0), x.max(axis=0)
            flat = np.flatnonzero(hi - lo <= 0)
            if flat.size:
                raise DataError(f"channel {names[flat[0]]!r} is constant; it cannot be normalised")
            return lo, hi - lo

        lu, ru = span(ref.u, self.input_names) if self.nu else (np.zeros(0), np.ones(0))
        ly, ry = span(ref.y, self.output_names)
        trend = self.trend.then(lu, np.zeros(self.nu), ru, ly, np.zeros(self.ny), ry)
        return self._with((self.u - lu) / ru, (self.y - ly) / ry, trend=trend)

    def scale(self, *, reference: IOData | None = None) -> IOData:
        """Divide every channel by its largest magnitude, without shifting it.

        Physical zero stays zero, so a model without intercept keeps its
        meaning (a wheel at rest under a zero command). The divisors are in
        ``trend.input_scale`` / ``trend.output_scale``.

        Parameters
        ----------
        reference : IOData, optional
            Take the magnitudes from this record (typically the estimation
            part). Default: ``self``.

        Returns
        -------
        IOData
            The scaled record.

        Raises
        ------
        DataError
            A channel that is zero throughout.
        """
        ref = self._reference(reference)

        def peak(x: np.ndarray, names) -> np.ndarray:
            m = np.max(np.abs(x), axis=0) if x.shape[0] else np.zeros(x.shape[1])
            flat = np.flatnonzero(m <= 0)
            if flat.size:
                raise DataError(
                    f"channel {names[flat[0]]!r} is zero throughout; it cannot be scaled"
                )
            return m

        su = peak(ref.u, self.input_names) if self.nu else np.ones(0)
        sy = peak(ref.y, self.output_names)
        trend = self.trend.then(
            np.zeros(self.nu), np.zeros(self.nu), su, np.zeros(self.ny), np.zeros(self.ny), sy
        )
        return self._with(self.u / su, self.y / sy, trend=trend)

    def resample(self, p: int, q: int) -> IOData:
        """Resample by the rational factor ``p/q`` with an anti-aliasing filter.

        The new sample time is ``Ts * q / p`` (MATLAB's ``resample(data, P, Q)``).
        """
        if int(p) != p or int(q) != q or p < 1 or q < 1:
            raise DataError(f"resample factors must be positive integers, got {p}/{q}")
        u = sps.resample_poly(self.u, p, q, axis=0) if self.nu else np.zeros((0, 0))
        y = sps.resample_poly(self.y, p, q, axis=0)
        if not self.nu:
            u = np.zeros((y.shape[0], 0))
        return self._with(u, y, Ts=self.Ts * q / p)

    # -- files -----------------------------------------------------------------
    def to_dict(self) -> dict:
        """Metadata as plain JSON types (no samples)."""
        return {
            "Ts": self.Ts,
            "tstart": self.tstart,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "input_units": list(self.input_units),
            "output_units": list(self.output_units),
            "name": self.name,
            "trend": self.trend.to_dict(),
        }

    def write(
        self, path: str | os.PathLike, *, overwrite: bool = False, plain: bool = False
    ) -> Path:
        """Write to ``.csv``, ``.parquet`` or ``.mat`` (chosen by suffix), atomically.

        The file appears complete or not at all. An existing file is an error
        unless ``overwrite=True``. ``plain=True`` writes what other tools
        expect: no rwlab metadata (CSV header first, Parquet without schema
        metadata) and a .mat with one vector per channel, named after it.
        """
        path = Path(path)
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
        writer = _registered(_WRITERS, WRITERS, path.suffix.lower())
        return atomic_write_bytes(path, lambda tmp: writer(self, tmp, plain=plain))


def merge(*datasets: IOData) -> list[IOData]:
    """Combine several experiments for joint estimation (MATLAB's ``merge``).

    Every estimator in ``rwlab.ident`` accepts the returned list: regressions and
    prediction errors are formed per experiment and never cross a boundary.

    Parameters
    ----------
    *datasets : IOData
        The experiments, with the same channels and sample time.

    Returns
    -------
    list of IOData
        One element per experiment.
    """
    if not datasets:
        raise DataError("merge needs at least one IOData")
    first = datasets[0]
    for d in datasets:
        if not isinstance(d, IOData):
            raise DataError(f"merge takes IOData records, got {type(d).__name__}")
        if (d.nu, d.ny) != (first.nu, first.ny):
            raise DataError("merged experiments must have the same numbers of inputs and outputs")
        if not math.isclose(d.Ts, first.Ts, rel_tol=1e-9):
            raise DataError(f"merged experiments must share Ts ({first.Ts} s vs {d.Ts} s)")
    return list(datasets)


def as_experiments(data: IOData | Sequence[IOData]) -> list[IOData]:
    """Normalise an estimator's ``data`` argument to a list of experiments."""
    if isinstance(data, IOData):
        return [data]
    if isinstance(data, Sequence) and data and all(isinstance(d, IOData) for d in data):
        return merge(*data)
    raise DataError(
        f"expected IOData or a list of IOData, got {type(data).__name__}; "
        "wrap arrays with rwlab.data.IOData(u, y, Ts)"
    )


def load(path: str | os.PathLike, Ts: float | None = None, **options) -> IOData:
    """Read a record from ``.mcap`` (a testbed record), ``.csv``, ``.dat``/``.txt``,
    ``.parquet`` or ``.mat``.

    Parameters
    ----------
    path : path-like
        The file.
    Ts : float, optional
        Sample time in seconds; required when the file does not carry one
        (a CSV without a time column, a .mat without ``Ts``).
    **options
        ``input_columns``/``output_columns``: column names (or indices), .mat
        variable names, or a testbed record's channels (default ``command`` →
        ``speed_rpm``); one name, a list, or ``"a,b"``. Without them a file
        with more than one input/output split is an error (``DataError``),
        never a guess, unless rwlab's own metadata says which is which.
        ``max_gap`` (s) for a record: see :func:`rwlab.testbed.load_record`.

    Returns
    -------
    IOData
        The record, with ``source`` holding what the file said about its origin.

    Raises
    ------
    DataError
        An ambiguous or unknown column choice, or a NaN/Inf in a chosen column
        (the message names the line and the column).
    FileFormatError
        A file that cannot be parsed.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such data file: {path}")
    suffix = path.suffix.lower()
    reader = _registered(_READERS, READERS, suffix)
    try:
        return reader(path, Ts, **options)
    except (RwlabError, OSError, TypeError):
        raise
    except Exception as exc:  # any parser failure becomes one typed, named error
        raise FileFormatError(f"{path}: not a readable {suffix} data file ({exc})") from exc


# -- file formats: registered by the layer that owns each ----------------------------
# Each reader and writer is declared where rwlab is installed, as an entry point of the
# group READERS or WRITERS (pyproject.toml: the suffix, without its dot, → the owner's
# function: rwlab.datafiles for tables, rwlab.testbed.load for testbed records), and
# another installed package may add its formats the same way. The data layer fills its
# registry from them on a suffix's first use and never names a module of its own.
READERS = "rwlab.readers"
WRITERS = "rwlab.writers"
_READERS: dict[str, Callable[..., IOData]] = {}
_WRITERS: dict[str, Callable[..., None]] = {}


def register_reader(suffix: str, reader: Callable[..., IOData]) -> None:
    """Make :func:`load` read files ending in ``suffix`` with ``reader``.

    Parameters
    ----------
    suffix : str
        The file suffix with its dot, e.g. ``".mcap"`` (case-insensitive).
    reader : callable
        ``reader(path, Ts, **options) -> IOData``; it raises ``FileFormatError``
        or ``DataError`` for a bad file.
    """
    _READERS[suffix.lower()] = reader


def register_writer(suffix: str, writer: Callable[..., None]) -> None:
    """Make :meth:`IOData.write` write files ending in ``suffix`` with ``writer``.

    Parameters
    ----------
    suffix : str
        The file suffix with its dot, e.g. ``".csv"`` (case-insensitive).
    writer : callable
        ``writer(data, tmp_path, plain=bool)``; it writes the temporary file that
        is then renamed onto the target.
    """
    _WRITERS[suffix.lower()] = writer


def _registered(table: dict[str, Callable], group: str, suffix: str) -> Callable:
    if suffix not in table:
        for point in importlib.metadata.entry_points(group=group, name=suffix.lstrip(".")):
            table[suffix] = point.load()
            break
    if suffix not in table:
        known = sorted(
            {*table, *(f".{p.name}" for p in importlib.metadata.entry_points(group=group))}
        )
        if not known:
            raise DataError(
                f"no data file formats are registered (entry points {group!r}): install rwlab "
                "(pip install -e .) so that its readers and writers are known"
            )
        raise DataError(f"unknown data file type {suffix!r}; use {', '.join(known)}")
    return table[suffix]
