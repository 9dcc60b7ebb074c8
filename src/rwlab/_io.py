"""rwlab's small I/O module: atomic files, JSON outputs, output folders, data formats.

- :func:`atomic_write_bytes` / :func:`write_json`: one file, complete or absent.
- :func:`output_folder`: a run's whole output folder, written under a temporary
  name and renamed when complete, under a lock taken before any work.
- ``read``/``write``: ``IOData`` as CSV, whitespace text, Parquet and MATLAB .mat.
  Every reader turns a malformed file into ``FileFormatError`` naming the file.

Every error names the file the caller asked for, never a temporary one.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import fcntl
import io
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from rwlab.data import IOData, Trend, check_Ts
from rwlab.errors import DataError, FileFormatError, OutputBusyError, RwlabError

__all__ = ["atomic_write_bytes", "output_folder", "read", "write", "write_json"]


# -- single files ---------------------------------------------------------------------
def _umask_mode() -> int:
    """The mode a plainly created file gets here (0666 less the umask)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _named(exc: OSError, path: Path) -> OSError:
    """``exc`` again, naming ``path`` (the file asked for) instead of a temporary one."""
    why = exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
    return OSError(exc.errno or errno.EIO, why, str(path))


def atomic_write_bytes(path: str | os.PathLike, writer: Callable[[Path], object]) -> Path:
    """Call ``writer(tmp_path)`` then rename onto ``path``: never a half-written file.

    Parameters
    ----------
    path : path-like
        The file to write; its folder is created when missing.
    writer : callable
        ``writer(tmp)`` writes the whole content to the temporary file ``tmp``
        (in the same folder, so the final rename is atomic).

    Returns
    -------
    Path
        ``path``. The file gets the usual permissions (0666 less the umask), not
        the temporary file's private 0600. Any ``OSError`` (a full disk included)
        is raised naming ``path``; the temporary file is removed.
    """
    path = Path(path)
    if path.parent.exists() and not path.parent.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(path.parent))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # name the file the caller asked for, not the temporary one
        raise OSError(exc.errno, f"cannot write here ({exc.strerror})", str(path)) from None
    os.close(fd)
    try:
        writer(Path(tmp))
        os.chmod(tmp, _umask_mode())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _named(exc, path) from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path: str | os.PathLike, payload) -> Path:
    """Write ``payload`` as indented JSON, atomically (numpy values as plain numbers).

    Parameters
    ----------
    path : path-like
        The ``.json`` file.
    payload : dict or list
        Plain JSON types; numpy arrays and scalars are converted.

    Returns
    -------
    Path
        ``path``.
    """
    text = json.dumps(payload, indent=2, default=_json_default)
    return atomic_write_bytes(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _json_default(obj):
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


# -- output folders -------------------------------------------------------------------
def _lock(lock_path: Path, out: Path) -> int:
    """An exclusive lock on ``lock_path`` (its descriptor), or ``OutputBusyError`` at once.

    The lock file is removed on release; a descriptor locked on a file that was
    removed meanwhile is stale, so the lock is taken again on the new file.
    """
    for _ in range(10):
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputBusyError(
                f"{out}: another rwlab run is writing this output folder now; wait for it "
                "to finish or choose another folder"
            ) from None
        try:
            same = os.stat(lock_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise OutputBusyError(f"{out}: could not lock the output folder (it keeps changing)")


def _unlock(fd: int, lock_path: Path) -> None:
    with contextlib.suppress(OSError):
        lock_path.unlink()
    os.close(fd)


def _check_existing(out: Path, names: set[str], force: bool, replace_previous: bool, what: str):
    """Refuse an ``out`` that holds anything but a previous output, or one not to replace."""
    if not out.exists():
        return
    if not out.is_dir():
        raise FileExistsError(errno.EEXIST, "exists and is not a folder", str(out))
    held = sorted(p.name for p in out.iterdir())
    foreign = [n for n in held if n not in names]
    if foreign:
        shown = ", ".join(foreign[:3]) + (", …" if len(foreign) > 3 else "")
        raise FileExistsError(
            f"{out} is not a previous {what}'s output folder (it holds {shown}); an output "
            "folder is replaced whole, so choose a new or empty folder"
        )
    if held and not (force or replace_previous):
        raise FileExistsError(
            f"{', '.join(str(out / n) for n in held)} exist; pass force=True (--force) "
            "to replace them"
        )


@contextlib.contextmanager
def output_folder(
    out: str | os.PathLike,
    names: Iterable[str],
    *,
    force: bool = False,
    replace_previous: bool = False,
    what: str = "rwlab run",
) -> Iterator[Path]:
    """A run's output folder, written whole or not at all, by one run at a time.

    Use it around the whole run, so that a second run on the same folder is
    refused at once (before computing) and a failure leaves no folder that
    looks complete::

        with output_folder(out, ["report.html", "model.json"], force=force) as stage:
            ...  # compute, then write every file into ``stage``

    Parameters
    ----------
    out : path-like
        The output folder. It may not exist, be empty, or hold a previous
        output of the same kind (only ``names``); anything else is refused.
    names : iterable of str
        The entries (files or sub-folders) a run writes at the folder's top.
    force : bool
        Replace a previous output. It is replaced only when this run succeeds.
    replace_previous : bool
        Replace a previous output even without ``force`` (the demo's habit).
    what : str
        What the folder holds, for messages (``"identification study"``).

    Yields
    ------
    Path
        The staging folder (``.OUT.partial-PID`` beside ``out``), empty. When the
        block ends normally it is renamed to ``out``; on any exception, SIGTERM
        included when the caller turns it into one, it is removed.

    Raises
    ------
    OutputBusyError
        Another run holds the folder's lock.
    FileExistsError
        ``out`` is a file, holds other files, or holds a previous output
        without ``force``.
    OSError
        Any error writing the outputs, naming the file in ``out`` (not the
        staging folder), e.g. a full disk.
    """
    out = Path(os.path.abspath(out))
    if not out.name:
        raise IsADirectoryError(errno.EISDIR, "cannot be an output folder", str(out))
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _named(exc, out) from None
    lock_path = parent / f".{out.name}.lock"
    try:
        fd = _lock(lock_path, out)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write here ({exc.strerror})", str(out)) from None
    stage = parent / f".{out.name}.partial-{os.getpid()}"
    try:
        _check_existing(out, set(names), force, replace_previous, what)
        for stale in parent.glob(f".{out.name}.partial-*"):  # left by a killed run
            shutil.rmtree(stale, ignore_errors=True)
        stage.mkdir()
        try:
            yield stage
            _publish(stage, out)
        except OSError as exc:
            raise _unstaged(exc, stage, out) from exc
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    finally:
        _unlock(fd, lock_path)


def _publish(stage: Path, out: Path) -> None:
    """Rename the complete ``stage`` to ``out``, replacing a previous output."""
    if out.is_dir() and any(out.iterdir()):
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        shutil.rmtree(old, ignore_errors=True)
        os.rename(out, old)
        os.rename(stage, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(stage, out)  # an empty folder is replaced atomically


def _unstaged(exc: OSError, stage: Path, out: Path) -> OSError:
    """``exc`` naming the file in ``out`` where it named one in the staging folder."""
    name = exc.filename
    if name is None:
        return exc
    try:
        rel = Path(name).relative_to(stage)
    except ValueError:
        return exc
    return OSError(exc.errno or errno.EIO, exc.strerror or str(exc), str(out / rel))


# -- data files (IOData) --------------------------------------------------------------
_META_PREFIX = "# rwlab "
_HUGE = 1e150  # beyond this, sums of a few million squares overflow a double
_TIME_NAMES = {"time", "time_s", "t", "ts_s", "timestamp_s"}


def write(data: IOData, path: Path, *, overwrite: bool, plain: bool = False) -> Path:
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (CLI: --force) to replace it")
    suffix = path.suffix.lower()
    writers = {".csv": _write_csv, ".parquet": _write_parquet, ".mat": _write_mat}
    if suffix not in writers:
        raise DataError(f"unknown data file type {suffix!r}; use .csv, .parquet or .mat")
    return atomic_write_bytes(path, lambda tmp: writers[suffix](data, tmp, plain=plain))


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
        ".mcap": _read_mcap,
    }
    if suffix not in readers:
        raise DataError(
            f"unknown data file type {suffix!r}; use .mcap, .csv, .dat, .parquet or .mat"
        )
    try:
        return readers[suffix](path, Ts, **options)
    except (RwlabError, OSError, TypeError):
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
            "choose with --input and --output (input_columns=/output_columns=), "
            "several as a,b"
        )
    both = sorted({names[i] for i in in_idx} & {names[i] for i in out_idx})
    if both:
        raise DataError(f"{path}: column(s) {both} chosen as both input and output")
    return in_idx, out_idx


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
    values = table[:, cols]
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        r, c = bad[0]
        where = f"line {lines[r]}" if lines is not None else f"row {r + 1}"
        raise DataError(
            f"{path}: {where}, column {names[cols[c]]!r} is {float(table[r, cols[c]])}, not a "
            "finite number; remove or interpolate the bad samples (no column is dropped)"
        )


def _from_table(
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
    time_col = next((i for i, n in enumerate(names) if n.lower() in _TIME_NAMES), None)
    data_cols = [i for i in range(len(names)) if i != time_col]
    if not data_cols:
        raise FileFormatError(f"{path}: no data columns")
    in_idx, out_idx = _choose(names, data_cols, inputs, outputs, path)
    _check_finite(table, [*in_idx, *out_idx], names, path, lines)

    tstart = 0.0
    if time_col is not None and table.shape[0] >= 2:
        _check_finite(table, [time_col], names, path, lines)
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
def _write_csv(data: IOData, tmp: Path, plain: bool = False) -> None:
    names, table = _columns(data)
    with open(tmp, "w", newline="") as fh:
        if not plain:
            fh.write(_META_PREFIX + _meta(data) + "\n")
        writer = csv.writer(fh, lineterminator="\n")  # LF: what every tool reads
        writer.writerow(names)
        writer.writerows([[repr(float(v)) for v in row] for row in table])


def _read_csv(path: Path, Ts, **options) -> IOData:
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
    return _from_table(
        [header[i] for i in keep], table[:, keep], Ts, meta, path, lines=lines[1:], **options
    )


def _read_text(path: Path, Ts, **options) -> IOData:
    table = np.loadtxt(path, ndmin=2)
    names = [f"c{i + 1}" for i in range(table.shape[1])]
    opts = {k: (names[v] if isinstance(v, int) else v) for k, v in options.items()}
    return _from_table(names, table, Ts, None, path, **opts)


# -- Parquet ------------------------------------------------------------------------
def _write_parquet(data: IOData, tmp: Path, plain: bool = False) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names, table = _columns(data)
    arrow = pa.table({n: table[:, i] for i, n in enumerate(names)})
    if not plain:
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
def _write_mat(data: IOData, tmp: Path, plain: bool = False) -> None:
    """rwlab's form: u (N×nu), y (N×ny), Ts, t, metadata; ``plain``: one vector per channel."""
    from scipy.io import savemat

    if plain:
        names, table = _columns(data)
        bad = [n for n in names if not n.isidentifier()]
        if bad:
            raise DataError(f"channel names {bad} are not MATLAB variable names")
        variables = {n: table[:, [i]] for i, n in enumerate(names)} | {"Ts": data.Ts}
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


def _read_mat(path: Path, Ts, input_columns=None, output_columns=None) -> IOData:
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
    return _from_table(names, table, Ts, None, path, inputs, outputs)


# -- testbed records (.mcap) --------------------------------------------------------
def _read_mcap(path: Path, Ts, input_columns=None, output_columns=None, max_gap=None) -> IOData:
    """A testbed record on a uniform grid; input ``command``, output ``speed_rpm`` by default."""
    from rwlab.testbed.load import OUTPUTS, load_record

    rec = load_record(path, Ts, outputs=tuple(OUTPUTS), max_gap=max_gap)
    names = ["time_s", *rec.input_names, *rec.output_names]
    units = dict(zip(names[1:], [*rec.input_units, *rec.output_units], strict=True))
    table = np.column_stack([rec.time, rec.u, rec.y])
    data = _from_table(
        names,
        table,
        rec.Ts,
        None,
        path,
        "command" if input_columns is None else input_columns,
        "speed_rpm" if output_columns is None else output_columns,
        units=units,
    )
    return data._with(data.u, data.y, name=rec.name)
