"""Writing files safely: the small I/O layer under every module that writes.

``atomic_write_bytes`` writes through a temporary file renamed onto the target,
so a reader never sees a half-written file.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes"]


def _umask_mode() -> int:
    """The mode a plainly created file gets here (0666 less the umask)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write_bytes(path: Path, writer) -> Path:
    """Call ``writer(tmp_path)`` then rename onto ``path``: never a half-written file.

    The file gets the usual permissions (0666 less the umask), not the
    temporary file's private 0600.

    Parameters
    ----------
    path : Path
        The file to write; its folder is created if missing.
    writer : callable
        ``writer(tmp_path)`` writes the whole content to the temporary file.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    if path.parent.exists() and not path.parent.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(path.parent))
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # name the file the caller asked for, not the temporary one
        raise OSError(exc.errno, f"cannot write here ({exc.strerror})", str(path)) from None
    os.close(fd)
    try:
        writer(Path(tmp))
        os.chmod(tmp, _umask_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
