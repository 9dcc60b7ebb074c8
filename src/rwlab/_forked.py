"""Work done in a forked copy of this process while this one goes on (:class:`Forked`).

A fork copies the process as it is (imports, data, figures): nothing to pickle on
the way in, only the result on the way back, through a pipe. Used where the work
is drawing (matplotlib holds the GIL, so threads would not overlap it).
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

__all__ = ["Forked", "die_with_parent", "forkable"]

T = TypeVar("T")


def forkable() -> bool:
    """Whether :class:`Forked` runs its work in a child here.

    Returns
    -------
    bool
        False where ``os.fork`` is missing or the process runs another Python thread:
        a fork copies only the calling thread, and a lock another thread holds (an
        import's, a queue's) would stay held in the child.
    """
    return hasattr(os, "fork") and threading.active_count() == 1


_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int) -> None:
    """In a forked child: be killed (SIGKILL) when the parent dies, at once if it has.

    A child holds copies of the parent's descriptors, its output folder's lock among
    them (``flock`` lives while any copy is open): a child left drawing after its
    parent was killed kept the folder locked 0.5-2 s, and a rerun in that time was
    refused. Linux's ``prctl(PR_SET_PDEATHSIG)``, through ctypes (no maintained
    package wraps it alone); elsewhere a no-op.

    Parameters
    ----------
    parent : int
        The parent's process id, taken before the fork.
    """
    import ctypes
    import ctypes.util

    libc_name = ctypes.util.find_library("c")
    if not sys.platform.startswith("linux") or libc_name is None:
        return
    ctypes.CDLL(libc_name, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:  # it died before the request took
        os._exit(1)


class Forked(Generic[T]):
    """``fn()`` computed in a forked child process; :meth:`result` waits for its value.

    Where no child can be forked (:func:`forkable`, or ``fork`` fails) or the child
    fails, :meth:`result` calls ``fn()`` in this process: the value is the same either
    way, and an error is raised here, as if there had been no child. The child never
    returns into the caller's code (its clean-up is this process's): it ends with
    ``os._exit``, and a stop signal ends it at once. Leaving a ``with`` block before
    :meth:`result` kills the child.

    Parameters
    ----------
    fn : callable
        ``fn()``, returning a picklable value.
    """

    def __init__(self, fn: Callable[[], T]) -> None:
        self._fn = fn
        self._child: tuple[int, int] | None = None  # (pid, the pipe's read end)
        if forkable():
            try:
                self._child = _start(fn)
            except OSError:  # no process to be had: result() computes it here
                pass

    @property
    def forked(self) -> bool:
        """Whether a child computes ``fn()`` (until :meth:`result` or :meth:`close`)."""
        return self._child is not None

    def result(self) -> T:
        """``fn()``'s value, from the child or computed here.

        Returns
        -------
        object
            What ``fn()`` returns.
        """
        if self._child is not None:
            pid, fd = self._child
            self._child = None
            ok, value = _finish(pid, fd)
            if ok:
                return value
        return self._fn()

    def close(self) -> None:
        """Kill the child if it still runs (its value is not needed)."""
        if self._child is not None:
            pid, fd = self._child
            self._child = None
            os.close(fd)
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)

    def __enter__(self) -> Forked[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _start(fn: Callable[[], Any]) -> tuple[int, int]:
    read, write = os.pipe()
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:
        os.close(read)
        os.close(write)
        raise
    if pid == 0:  # the child
        code = 1
        try:
            die_with_parent(parent)
            signal.signal(signal.SIGINT, signal.SIG_DFL)  # a stop ends it, quietly
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.close(read)
            with os.fdopen(write, "wb") as pipe:
                pickle.dump(fn(), pipe, protocol=pickle.HIGHEST_PROTOCOL)
            code = 0
        finally:
            os._exit(code)
    os.close(write)
    return pid, read


def _finish(pid: int, fd: int) -> tuple[bool, Any]:
    """(True, the child's value), or (False, None) where it failed; the child reaped."""
    try:
        with os.fdopen(fd, "rb") as pipe:
            data = pipe.read()
    finally:  # the pipe closed: a child still writing ends (broken pipe)
        _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        return False, None
    return True, pickle.loads(data)
