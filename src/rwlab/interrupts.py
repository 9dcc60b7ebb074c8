"""Stop signals (Ctrl-C, SIGTERM, SIGHUP) that wait for the end of a critical section.

Python raises a signal handler's KeyboardInterrupt wherever the main thread is. Raised
inside a lock's ``with`` block of the standard library, it can leave the lock held:
measured, a KeyboardInterrupt inside python-can's virtual bus (``queue.Queue.get``)
left the queue's mutex taken, and the run's clean-up, idling the wheel through the
same bus, then waited on it for ever. Bus reads and writes, imports and the
publishing of outputs therefore run :func:`uninterrupted`: a stop that comes inside
is recorded (:func:`stop`) and raised when the section ends.

Written here because the standard library offers no deferred delivery of signals
(``signal.pthread_sigmask`` defers the signal, not the handler's exception, and only
on POSIX).
"""

from __future__ import annotations

import contextlib
import threading

__all__ = ["check_stop", "clear", "stop", "stopped", "uninterrupted"]

_stopped: list[str] = []  # the signals that stopped the run, in order
_held = [0]  # depth of uninterrupted sections in the main thread
_pending: list[str] = []  # a stop that came inside the current section


def stop(name: str) -> None:
    """A stop signal came (call it from the signal handler).

    Parameters
    ----------
    name : str
        The signal's name, e.g. ``"SIGINT"``.

    Raises
    ------
    KeyboardInterrupt
        At once, unless inside :func:`uninterrupted`: then when it ends.
    """
    _stopped.append(name)
    if _held[0]:
        _pending[:] = [name]
    else:
        raise KeyboardInterrupt(name)


def stopped() -> str | None:
    """The first stop signal since :func:`clear`.

    Returns
    -------
    str or None
        Its name (``"SIGTERM"`` …), or None when none came.
    """
    return _stopped[0] if _stopped else None


def clear() -> None:
    """Forget earlier stop signals (a new run starts)."""
    _stopped.clear()
    _pending.clear()


def check_stop() -> None:
    """Raise KeyboardInterrupt if a stop signal came: at a command's checkpoints, where
    the exception may have been lost (swallowed where it was raised; measured: inside a
    run loop's imports the run then went on to the end).

    Raises
    ------
    KeyboardInterrupt
        A stop signal came (not inside :func:`uninterrupted`: there at its end).
    """
    if _stopped and not _held[0]:
        raise KeyboardInterrupt(_stopped[0])


class _Uninterrupted:
    """The context manager :func:`uninterrupted` returns: a class, not a generator, as
    every bus read and write enters one (a generator-based one cost a 1000-s HIL flight
    ~1 µs a frame, measured: 1.07 million sections)."""

    def __enter__(self) -> None:
        if threading.current_thread() is threading.main_thread():
            _held[0] += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        _held[0] -= 1
        if exc_type is not None:  # the block's own error goes on; the stop stays in stopped()
            if not _held[0]:
                _pending.clear()
            return
        if not _held[0] and _pending:
            raise KeyboardInterrupt(_pending.pop())


_SECTION = _Uninterrupted()


def uninterrupted() -> contextlib.AbstractContextManager[None]:
    """A block that a stop signal does not cut: its KeyboardInterrupt comes at the end.

    Sections nest; only the main thread's count (signal handlers run there), other
    threads pass through. A stop that came before the block (a clean-up after Ctrl-C
    talks to the wheel in such blocks) raises nothing again.

    Returns
    -------
    contextlib.AbstractContextManager
        Enter it around the block. Leaving the outermost section raises
        KeyboardInterrupt when a stop signal came inside it.
    """
    return _SECTION
