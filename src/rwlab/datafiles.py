"""File formats for ``IOData``: CSV, whitespace text, Parquet and MATLAB .mat.

Every writer is atomic (temporary file, then rename). Every reader turns a
malformed file into ``FileFormatError`` naming the file and the problem. The
readers and writers are registered with :mod:`rwlab.data` as entry points
(``pyproject.toml``; testbed records, ``.mcap``, by :mod:`rwlab.testbed.load`,
their owner).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from rwlab.data import (
    TIME_MS_NAMES,
    TIME_NAMES,
    IOData,
    Trend,
    check_Ts,
    warn_implausible_Ts,
)
from rwlab.errors import DataError, FileFormatError

_META_PREFIX = "# rwlab "


# -- shared helpers -----------------------------------------------------------------
def _columns(data: IOData) -> tuple[list[str], np.ndarray]:
    names = ["time_s", *data.input_names, *data.output_names]
    if len(set(names)) != len(names):
        raise DataError(f"channel names must be unique to be written as columns: {names}")
    return names, np.column_stack([data.time, data.u, data.y])


def _meta(data: IOData) -> str:
    return json.dumps(data.to_dict(), separators=(",", ":"))


def _salvaged(data: IOData) -> bool:
    """Data read from a damaged record up to its damage: even a plain file says so."""
    return isinstance(data.source, dict) and "salvaged" in data.source


def _as_list(cols) -> list | None:
    """A column choice as a list: None, one name or index, "a,b", or a sequence."""
    if cols is None:
        return None
    if isinstance(cols, str):
        return [c.strip() for c in cols.split(",") if c.strip()]
    if isinstance(cols, (int, np.integer)):
        return [int(cols)]
    return list(cols)


def _choose(names, data_cols, inputs, outputs, path) -> tuple[list[int], list[int]]:
    """Indices of the input and output columns; a choice that is not unique is an error."""

    def index(col) -> int:
        if isinstance(col, (int, np.integer)):
            if not 0 <= col < len(names):
                raise DataError(f"{path}: column index {col} out of range")
            return int(col)
        if col not in names:
            raise DataError(f"{path}: no column {col!r}; columns are {names}")
        return names.index(col)

    in_idx = None if inputs is None else [index(c) for c in inputs]
    out_idx = None if outputs is None else [index(c) for c in outputs]
    if in_idx is None and out_idx is None and len(data_cols) <= 2:
        in_idx, out_idx = data_cols[:-1], data_cols[-1:]  # u, y or a time series y
    elif in_idx is not None and out_idx is None:
        rest = [i for i in data_cols if i not in in_idx]
        out_idx = rest if len(rest) == 1 else None
    elif out_idx is not None and in_idx is None:
        rest = [i for i in data_cols if i not in out_idx]
        in_idx = rest if len(rest) <= 1 else None
    if in_idx is None or not out_idx:
        shown = [names[i] for i in data_cols]
        raise DataError(
            f"{path}: which columns are inputs and which outputs is ambiguous ({shown}); "
            "choose with input_columns= and output_columns=, "
            "several as a,b"
        )
    both = sorted({names[i] for i in in_idx} & {names[i] for i in out_idx})
    if both:
        raise DataError(f"{path}: column(s) {both} chosen as both input and output")
    return in_idx, out_idx


_HUGE = 1e150  # beyond this, sums of a few million squares overflow a double


def check_magnitude(data: IOData, source) -> IOData:
    """Refuse samples too large to estimate from (their sums of squares overflow).

    Files keep any finite double exactly; an estimator cannot: beyond ±1e150 the
    regressions' sums of squares are inf and every result NaN.

    Parameters
    ----------
    data : IOData
    source : str or path
        Named in the message.

    Returns
    -------
    IOData
        ``data``, unchanged.
    """
    for name, x, names in (
        ("input", data.u, data.input_names),
        ("output", data.y, data.output_names),
    ):
        big = np.argwhere(np.abs(x) > _HUGE)
        if big.size:
            k, c = big[0]
            raise DataError(
                f"{source}: sample {k} of {name} {names[c]!r} is {float(x[k, c]):g}, too large "
                f"to estimate from (beyond ±{_HUGE:g}); check the file's units"
            )
    return data


def _check_finite(table, cols, names, path, lines=None) -> None:
    """A NaN or Inf in a chosen column is an error naming its row and column."""
    if not cols:
        return
    bad = np.argwhere(~np.isfinite(table[:, cols]))
    if bad.size:
        r, c = bad[0]
        where = f"line {lines[r]}" if lines is not None else f"row {r + 1}"
        raise DataError(
            f"{path}: {where}, column {names[cols[c]]!r} is {float(table[r, cols[c]])}, not a "
            "finite number; remove or interpolate the bad samples (no column is dropped)"
        )


def from_table(
    names,
    table,
    Ts,
    meta,
    path,
    input_columns=None,
    output_columns=None,
    *,
    lines=None,
    units=None,
) -> IOData:
    """Build IOData from a named numeric table, using rwlab metadata when present.

    Explicit ``input_columns``/``output_columns`` win over the file's metadata.
    ``lines`` gives each row's line in the file (for error messages); ``units``
    maps column names to units.
    """
    names = [str(n).strip() for n in names]
    inputs, outputs = _as_list(input_columns), _as_list(output_columns)
    chosen_by_meta = meta is not None and inputs is None and outputs is None
    if chosen_by_meta:
        inputs, outputs = list(meta["input_names"]), list(meta["output_names"])
    time_col = next(
        (i for i, n in enumerate(names) if n.lower() in TIME_NAMES + TIME_MS_NAMES), None
    )
    data_cols = [i for i in range(len(names)) if i != time_col]
    if not data_cols:
        raise FileFormatError(f"{path}: no data columns")
    in_idx, out_idx = _choose(names, data_cols, inputs, outputs, path)
    _check_finite(table, [*in_idx, *out_idx], names, path, lines)

    tstart = 0.0
    if time_col is not None and table.shape[0] >= 2:
        _check_finite(table, [time_col], names, path, lines)
        in_ms = names[time_col].lower() in TIME_MS_NAMES
        t = table[:, time_col] * (1e-3 if in_ms else 1.0)
        steps = np.diff(t)
        file_Ts = float(f"{(t[-1] - t[0]) / (len(t) - 1):.12g}")  # drop float noise of the stamps
        if meta is not None:
            file_Ts = float(meta["Ts"])
        if file_Ts <= 0 or np.max(np.abs(steps - file_Ts)) > 1e-6 * max(file_Ts, 1e-12) + 1e-9:
            raise DataError(
                f"{path}: the time column is not uniformly sampled; resample it first "
                "(rwlab.testbed.load_record does this for testbed records)"
            )
        if Ts is not None and not np.isclose(check_Ts(Ts), file_Ts, rtol=1e-6):
            raise DataError(
                f"{path}: Ts={Ts} s disagrees with the file's time column ({file_Ts} s)"
            )
        if meta is None:  # rwlab's own files carry their Ts: only others' are guessed at
            warn_implausible_Ts(file_Ts, len(t), f"{path}: column {names[time_col]!r}")
        Ts, tstart = file_Ts, float(t[0])
    units = dict(units or {})
    kwargs = {}
    if meta is not None:
        units.update(zip(meta["input_names"], meta["input_units"], strict=False))
        units.update(zip(meta["output_names"], meta["output_units"], strict=False))
        trend = Trend.from_dict(meta["trend"])
        if not chosen_by_meta:
            _check_plain_trend(trend, path)
        kwargs = dict(name=meta.get("name", ""), trend=trend if chosen_by_meta else None)
        Ts = meta["Ts"] if Ts is None else Ts
        tstart = meta.get("tstart", tstart)
    return IOData(
        table[:, in_idx] if in_idx else np.zeros((table.shape[0], 0)),
        table[:, out_idx],
        Ts,
        input_names=[names[i] for i in in_idx],
        output_names=[names[i] for i in out_idx],
        input_units=[units.get(names[i], "") for i in in_idx],
        output_units=[units.get(names[i], "") for i in out_idx],
        tstart=tstart,
        **kwargs,
    )


def _check_plain_trend(trend: Trend, path) -> None:
    """A preprocessed file's channels cannot be regrouped: its trend belongs to its choice."""
    identity = Trend.identity(len(trend.input_offset), len(trend.output_offset))
    if any(not np.array_equal(getattr(trend, k), getattr(identity, k)) for k in trend.__dict__):
        raise DataError(
            f"{path}: the file holds preprocessed (detrended/normalised) data; its input and "
            "output columns cannot be chosen differently from the file's own"
        )


# -- CSV ----------------------------------------------------------------------------
def write_csv(data: IOData, tmp: Path, plain: bool = False) -> None:
    names, table = _columns(data)
    with open(tmp, "w", newline="") as fh:
        if not plain or _salvaged(data):  # the metadata line: its name says salvaged
            fh.write(_META_PREFIX + _meta(data) + "\n")
        writer = csv.writer(fh, lineterminator="\n")  # LF: what every tool reads
        writer.writerow(names)
        writer.writerows([[repr(float(v)) for v in row] for row in table])


def read_csv(path: Path, Ts, **options) -> IOData:
    text = path.read_text()
    meta = None
    if text.startswith(_META_PREFIX):
        first, _, text = text.partition("\n")
        meta = json.loads(first[len(_META_PREFIX) :])
    reader = csv.reader(io.StringIO(text))
    rows, lines = [], []
    for row in reader:
        if any(cell.strip() for cell in row):
            rows.append(row)
            lines.append(reader.line_num + (meta is not None))
    if len(rows) < 2:
        raise FileFormatError(f"{path}: a CSV record needs a header row and at least one data row")
    header = rows[0]
    # tolerate the trailing empty column some exporters write
    while header and not header[-1].strip():
        header = header[:-1]
    width = len(header)
    table = np.empty((len(rows) - 1, width))
    for k, (row, line) in enumerate(zip(rows[1:], lines[1:], strict=True)):
        cells = row[:width] + [""] * (width - len(row))
        try:
            table[k] = [float(c) if c.strip() else np.nan for c in cells]
        except ValueError:
            raise FileFormatError(f"{path}: line {line} is not numeric: {row}") from None
    # a column filled in its first row only (a Ts written once) is metadata, not data;
    # any other missing value stays in its column and is an error if that column is chosen
    keep = [i for i in range(width) if len(table) < 2 or not np.isnan(table[1:, i]).all()]
    return from_table(
        [header[i] for i in keep], table[:, keep], Ts, meta, path, lines=lines[1:], **options
    )


def read_text(path: Path, Ts, **options) -> IOData:
    table = np.loadtxt(path, ndmin=2)
    names = [f"c{i + 1}" for i in range(table.shape[1])]
    opts = {k: (names[v] if isinstance(v, int) else v) for k, v in options.items()}
    return from_table(names, table, Ts, None, path, **opts)


# -- Parquet ------------------------------------------------------------------------
def write_parquet(data: IOData, tmp: Path, plain: bool = False) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names, table = _columns(data)
    arrow = pa.table({n: table[:, i] for i, n in enumerate(names)})
    if not plain or _salvaged(data):
        arrow = arrow.replace_schema_metadata({b"rwlab": _meta(data).encode()})
    pq.write_table(arrow, tmp)


def read_parquet(path: Path, Ts, **options) -> IOData:
    import pyarrow.parquet as pq

    arrow = pq.read_table(path)
    raw = (arrow.schema.metadata or {}).get(b"rwlab")
    meta = json.loads(raw) if raw else None
    table = np.column_stack(
        [arrow.column(i).to_numpy().astype(float) for i in range(arrow.num_columns)]
    )
    return from_table(arrow.column_names, table, Ts, meta, path, **options)


# -- MATLAB .mat --------------------------------------------------------------------
def write_mat(data: IOData, tmp: Path, plain: bool = False) -> None:
    """rwlab's form: u (N×nu), y (N×ny), Ts, t, metadata; ``plain``: one vector per channel."""
    from scipy.io import savemat

    if plain:
        names, table = _columns(data)
        bad = [n for n in names if not n.isidentifier()]
        if bad:
            raise DataError(f"channel names {bad} are not MATLAB variable names")
        variables: dict[str, Any] = {n: table[:, [i]] for i, n in enumerate(names)}
        variables["Ts"] = data.Ts
        if _salvaged(data):  # a text variable: no channel, read by a person
            variables["salvaged"] = data.name
    else:
        variables = {
            "u": data.u,
            "y": data.y,
            "Ts": data.Ts,
            "t": data.time[:, None],
            "rwlab_meta": _meta(data),
        }
    with open(tmp, "wb") as fh:
        savemat(fh, variables)


def read_mat(path: Path, Ts, input_columns=None, output_columns=None) -> IOData:
    """Variables ``u`` and ``y`` (rwlab's form) or any vectors chosen by name."""
    from scipy.io import loadmat

    mat = loadmat(path)
    if Ts is None and "Ts" in mat:
        Ts = float(np.asarray(mat["Ts"]).ravel()[0])
    meta = json.loads(str(mat["rwlab_meta"][0])) if "rwlab_meta" in mat else None
    found = sorted(k for k in mat if not k.startswith("__"))
    inputs, outputs = _as_list(input_columns), _as_list(output_columns)
    if (inputs or ["u"]) == ["u"] and (outputs or ["y"]) == ["y"] and {"u", "y"} <= set(mat):
        u, y = np.asarray(mat["u"], float), np.asarray(mat["y"], float)
        kwargs = {}
        if meta is not None:
            kwargs = {k: meta[k] for k in ("input_names", "output_names")}
            kwargs |= {k: meta[k] for k in ("input_units", "output_units")}
            kwargs |= dict(
                tstart=meta.get("tstart", 0.0),
                trend=Trend.from_dict(meta["trend"]),
                name=meta.get("name", ""),
            )
        return IOData(u, y, Ts, **kwargs)
    vectors = {
        k: np.asarray(v, float).ravel()
        for k, v in mat.items()
        if k in found
        and isinstance(v, np.ndarray)
        and v.dtype.kind in "fiu"
        and v.ndim == 2
        and min(v.shape) == 1
        and max(v.shape) > 1
    }
    for name in [*(inputs or []), *(outputs or [])]:
        if name not in vectors:
            raise FileFormatError(f"{path}: no vector variable {name!r}; the file holds {found}")
    names = list(vectors)
    if len({v.size for v in vectors.values()}) > 1:
        chosen = [*(inputs or []), *(outputs or [])]
        names = chosen or names
        if len({vectors[n].size for n in names}) > 1:
            raise FileFormatError(f"{path}: the variables {names} differ in length")
    table = np.column_stack([vectors[n] for n in names]) if names else np.zeros((0, 0))
    return from_table(names, table, Ts, None, path, inputs, outputs)
