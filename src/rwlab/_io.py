"""File formats for ``IOData``: CSV, whitespace text, Parquet and MATLAB .mat.

Every writer is atomic (temporary file, then rename). Every reader turns a
malformed file into ``FileFormatError`` naming the file and the problem.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from rwlab.data import IOData, Trend, atomic_write_bytes, check_Ts
from rwlab.errors import DataError, FileFormatError

_META_PREFIX = "# rwlab "
_TIME_NAMES = {"time", "time_s", "t", "ts_s", "timestamp_s"}


def write(data: IOData, path: Path, *, overwrite: bool, plain: bool = False) -> Path:
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (CLI: --force) to replace it")
    suffix = path.suffix.lower()
    writers = {".csv": _write_csv, ".parquet": _write_parquet, ".mat": _write_mat}
    if suffix not in writers:
        raise DataError(f"unknown data file type {suffix!r}; use .csv, .parquet or .mat")
    if suffix == ".csv":
        return atomic_write_bytes(path, lambda tmp: _write_csv(data, tmp, plain=plain))
    return atomic_write_bytes(path, lambda tmp: writers[suffix](data, tmp))


def read(path: Path, Ts: float | None, **options) -> IOData:
    if not path.is_file():
        raise FileNotFoundError(f"no such data file: {path}")
    suffix = path.suffix.lower()
    readers = {
        ".csv": _read_csv,
        ".dat": _read_text,
        ".txt": _read_text,
        ".parquet": _read_parquet,
        ".mat": _read_mat,
    }
    if suffix not in readers:
        raise DataError(f"unknown data file type {suffix!r}; use .csv, .dat, .parquet or .mat")
    try:
        return readers[suffix](path, Ts, **options)
    except (DataError, FileFormatError, TypeError):
        raise
    except Exception as exc:  # any parser failure becomes one typed, named error
        raise FileFormatError(f"{path}: not a readable {suffix} data file ({exc})") from exc


# -- shared helpers -----------------------------------------------------------------
def _columns(data: IOData) -> tuple[list[str], np.ndarray]:
    names = ["time_s", *data.input_names, *data.output_names]
    if len(set(names)) != len(names):
        raise DataError(f"channel names must be unique to be written as columns: {names}")
    return names, np.column_stack([data.time, data.u, data.y])


def _meta(data: IOData) -> str:
    return json.dumps(data.to_dict(), separators=(",", ":"))


def _from_table(names, table, Ts, meta, path, input_columns=None, output_columns=None) -> IOData:
    """Build IOData from a named numeric table, using rwlab metadata when present."""
    names = [str(n).strip() for n in names]
    if meta is not None:
        input_columns = meta["input_names"]
        output_columns = meta["output_names"]

    def index(col) -> int:
        if isinstance(col, (int, np.integer)):
            if not 0 <= col < len(names):
                raise DataError(f"{path}: column index {col} out of range")
            return int(col)
        if col not in names:
            raise DataError(f"{path}: no column {col!r}; columns are {names}")
        return names.index(col)

    time_col = next((i for i, n in enumerate(names) if n.lower() in _TIME_NAMES), None)
    data_cols = [i for i in range(len(names)) if i != time_col]
    if output_columns is None:
        if not data_cols:
            raise FileFormatError(f"{path}: no data columns")
        output_columns = [data_cols[-1]]
    if isinstance(output_columns, (str, int)):
        output_columns = [output_columns]
    out_idx = [index(c) for c in output_columns]
    if input_columns is None:
        input_columns = [i for i in data_cols if i not in out_idx]
    if isinstance(input_columns, (str, int)):
        input_columns = [input_columns]
    in_idx = [index(c) for c in input_columns]

    tstart = 0.0
    if time_col is not None and table.shape[0] >= 2:
        t = table[:, time_col]
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
        Ts, tstart = file_Ts, float(t[0])
    kwargs = {}
    if meta is not None:
        kwargs = dict(
            input_units=meta["input_units"],
            output_units=meta["output_units"],
            name=meta.get("name", ""),
            trend=Trend.from_dict(meta["trend"]),
        )
        Ts = meta["Ts"] if Ts is None else Ts
        tstart = meta.get("tstart", tstart)
    return IOData(
        table[:, in_idx] if in_idx else np.zeros((table.shape[0], 0)),
        table[:, out_idx],
        Ts,
        input_names=[names[i] for i in in_idx],
        output_names=[names[i] for i in out_idx],
        tstart=tstart,
        **kwargs,
    )


# -- CSV ----------------------------------------------------------------------------
def _write_csv(data: IOData, tmp: Path, plain: bool = False) -> None:
    names, table = _columns(data)
    with open(tmp, "w", newline="") as fh:
        if not plain:
            fh.write(_META_PREFIX + _meta(data) + "\n")
        writer = csv.writer(fh)
        writer.writerow(names)
        writer.writerows([[repr(float(v)) for v in row] for row in table])


def _read_csv(path: Path, Ts, **options) -> IOData:
    text = path.read_text()
    meta = None
    if text.startswith(_META_PREFIX):
        first, _, text = text.partition("\n")
        meta = json.loads(first[len(_META_PREFIX) :])
    rows = [r for r in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in r)]
    if len(rows) < 2:
        raise FileFormatError(f"{path}: a CSV record needs a header row and at least one data row")
    header = rows[0]
    # tolerate the trailing empty column some exporters write
    while header and not header[-1].strip():
        header = header[:-1]
    width = len(header)
    table = np.empty((len(rows) - 1, width))
    for k, row in enumerate(rows[1:], start=2):
        cells = row[:width] + [""] * (width - len(row))
        try:
            table[k - 2] = [float(c) if c.strip() else np.nan for c in cells]
        except ValueError:
            raise FileFormatError(f"{path}: line {k} is not numeric: {row}") from None
    # columns that are only partly filled (a Ts written once in the first row) are metadata
    keep = [i for i in range(width) if not np.isnan(table[:, i]).any()]
    return _from_table([header[i] for i in keep], table[:, keep], Ts, meta, path, **options)


def _read_text(path: Path, Ts, **options) -> IOData:
    table = np.loadtxt(path, ndmin=2)
    names = [f"c{i + 1}" for i in range(table.shape[1])]
    opts = {k: (names[v] if isinstance(v, int) else v) for k, v in options.items()}
    return _from_table(names, table, Ts, None, path, **opts)


# -- Parquet ------------------------------------------------------------------------
def _write_parquet(data: IOData, tmp: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names, table = _columns(data)
    arrow = pa.table({n: table[:, i] for i, n in enumerate(names)})
    arrow = arrow.replace_schema_metadata({b"rwlab": _meta(data).encode()})
    pq.write_table(arrow, tmp)


def _read_parquet(path: Path, Ts, **options) -> IOData:
    import pyarrow.parquet as pq

    arrow = pq.read_table(path)
    raw = (arrow.schema.metadata or {}).get(b"rwlab")
    meta = json.loads(raw) if raw else None
    table = np.column_stack(
        [arrow.column(i).to_numpy().astype(float) for i in range(arrow.num_columns)]
    )
    return _from_table(arrow.column_names, table, Ts, meta, path, **options)


# -- MATLAB .mat --------------------------------------------------------------------
def _write_mat(data: IOData, tmp: Path) -> None:
    from scipy.io import savemat

    with open(tmp, "wb") as fh:
        savemat(
            fh,
            {
                "u": data.u,
                "y": data.y,
                "Ts": data.Ts,
                "t": data.time[:, None],
                "rwlab_meta": _meta(data),
            },
        )


def _read_mat(path: Path, Ts, u: str = "u", y: str = "y") -> IOData:
    from scipy.io import loadmat

    mat = loadmat(path)
    missing = [v for v in (u, y) if v not in mat]
    if missing:
        found = sorted(k for k in mat if not k.startswith("__"))
        raise FileFormatError(f"{path}: no variable {missing[0]!r}; the file holds {found}")
    meta = json.loads(str(mat["rwlab_meta"][0])) if "rwlab_meta" in mat else None
    if Ts is None and "Ts" in mat:
        Ts = float(np.asarray(mat["Ts"]).ravel()[0])
    kwargs = {}
    if meta is not None:
        kwargs = dict(
            input_names=meta["input_names"],
            output_names=meta["output_names"],
            input_units=meta["input_units"],
            output_units=meta["output_units"],
            tstart=meta.get("tstart", 0.0),
            trend=Trend.from_dict(meta["trend"]),
            name=meta.get("name", ""),
        )
    return IOData(np.asarray(mat[u], float), np.asarray(mat[y], float), Ts, **kwargs)
