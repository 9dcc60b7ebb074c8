"""rwlab's small I/O module: atomic files, JSON outputs, output folders.

- :func:`atomic_write_bytes` / :func:`write_json`: one file, complete or absent.
- :func:`output_folder`: a run's whole output folder, written under a temporary
  name and renamed when complete, under a lock taken before any work.

Every error names the file the caller asked for, never a temporary one.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from rwlab.errors import OutputBusyError, RwlabWarning

__all__ = ["atomic_write_bytes", "naming", "output_folder", "write_json"]


# -- single files ---------------------------------------------------------------------
def _umask_mode() -> int:
    """The mode a plainly created file gets here (0666 less the umask)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def naming(exc: OSError, path: str | os.PathLike) -> OSError:
    """``exc`` again, naming ``path`` (the file asked for) instead of a temporary one.

    Parameters
    ----------
    exc : OSError
        The error (a full disk, a lost mount ...), naming no file or a temporary one.
    path : str or os.PathLike
        The file the caller asked for.

    Returns
    -------
    OSError
        Same errno and reason, ``filename`` = ``path``.
    """
    return _named(exc, Path(path))


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
def lock_exclusive(path: Path, busy: Exception) -> int:
    """A descriptor of ``path`` (created if need be) under an exclusive ``flock``.

    The lock is advisory and the OS releases it when the process dies. A file
    renamed or removed between opening and locking is stale: the lock is taken
    again on the new one (ten tries).

    Parameters
    ----------
    path : Path
        The file to lock.
    busy : Exception
        Raised, at once, when another process holds the lock (or the file keeps
        being replaced); its message says what to do.

    Returns
    -------
    int
        The open descriptor, read-write, holding the lock.
    """
    for _ in range(10):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise busy from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise busy


def _lock(lock_path: Path, out: Path) -> int:
    """An exclusive lock on ``lock_path`` (its descriptor), or ``OutputBusyError`` at once
    (the lock file is removed on release)."""
    busy = OutputBusyError(
        f"{out}: another rwlab run is writing this output folder now; wait for it "
        "to finish or choose another folder"
    )
    return lock_exclusive(lock_path, busy)


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
            f"{', '.join(str(out / n) for n in held)} exist; pass force=True to replace them"
        )


@contextlib.contextmanager
def output_folder(
    out: str | os.PathLike,
    names: Iterable[str],
    *,
    force: bool = False,
    replace_previous: bool = False,
    what: str = "rwlab run",
    keep_failed: bool = False,
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
    keep_failed : bool
        On an exception keep what the run wrote, for diagnosis, as the folder
        ``OUT.failed-YYYYmmddTHHMMSSZ`` beside ``out`` (never ``out`` itself: it
        must not look complete); the exception's message then names that folder
        instead of the staging one. (A run on hardware keeps its record this way.)

    Yields
    ------
    Path
        The staging folder (``.OUT.partial-PID`` beside ``out``), empty. When the
        block ends normally it is renamed to ``out``; on any exception, SIGTERM
        included when the caller turns it into one, it is removed (or kept under
        a failed name with ``keep_failed``).

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
        _clear_stale(out)  # first: even a run refused below leaves nothing of a killed one
        _check_existing(out, set(names), force, replace_previous, what)
        stage.mkdir()
        try:
            yield stage
            _publish(stage, out)
        except OSError as exc:
            if keep_failed:
                _keep_failed(exc, stage, out)
            raise _unstaged(exc, stage, out) from exc
        except BaseException as exc:
            if keep_failed:
                _keep_failed(exc, stage, out)
            raise
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    finally:
        _unlock(fd, lock_path)


def _clear_stale(out: Path) -> None:
    """Clear what killed runs left beside ``out``; the caller holds its lock.

    Under the lock no other run can be writing, so every staging folder
    (``.OUT.partial-PID``) is a killed run's: it is removed. A run killed while it
    published moved the previous output to ``.OUT.old-PID`` and may not have put
    its own in place: that previous output is restored to ``out``. Each is named
    in a warning.
    """
    cleared = []
    for old in sorted(out.parent.glob(f".{out.name}.old-*")):
        if not out.exists():
            os.rename(old, out)
            cleared.append(f"restored {out} from {old.name}")
        else:
            shutil.rmtree(old, ignore_errors=True)
            cleared.append(f"removed {old.name}")
    for stale in sorted(out.parent.glob(f".{out.name}.partial-*")):
        shutil.rmtree(stale, ignore_errors=True)
        cleared.append(f"removed {stale.name}")
    if cleared:
        warnings.warn(
            f"{out}: a killed run left files beside it: {'; '.join(cleared)}",
            RwlabWarning,
            stacklevel=4,
        )


def _keep_failed(exc: BaseException, stage: Path, out: Path) -> None:
    """Rename a failed run's ``stage`` to ``OUT.failed-<UTC time>`` and say so in ``exc``."""
    import time

    if not stage.is_dir() or not any(stage.iterdir()):
        return
    failed = out.parent / f"{out.name}.failed-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}"
    try:
        os.rename(stage, failed)
    except OSError:
        return  # the staging folder is then removed: the error itself still stands
    note = f" (the failed run's outputs are kept in {failed}; {out} was not written)"
    if isinstance(exc, OSError) and exc.strerror:  # shown as "file: reason"
        exc.strerror += note
    elif exc.args and isinstance(exc.args[0], str):
        text = exc.args[0].replace(str(stage), str(failed))
        exc.args = (text + note, *exc.args[1:])


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
