"""Stop signals wait for the end of a critical section (rwlab.interrupts)."""

from __future__ import annotations

import os
import signal
import sys
import threading

import pytest

from rwlab import interrupts


@pytest.fixture
def sigint_stops():
    """SIGINT handled as the CLI handles it: through :func:`interrupts.stop`."""
    interrupts.clear()
    previous = signal.signal(signal.SIGINT, lambda s, f: interrupts.stop("SIGINT"))
    yield
    signal.signal(signal.SIGINT, previous)
    interrupts.clear()


def test_a_stop_outside_a_section_raises_at_once(sigint_stops):
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10**6):  # the handler runs between two bytecodes
            pass
    assert interrupts.stopped() == "SIGINT"


def test_a_signal_inside_a_section_raises_when_it_ends(sigint_stops):
    done = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts.uninterrupted():
            with interrupts.uninterrupted():  # sections nest: only the outermost raises
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(10**5):
                    pass
                done.append("inner")
            done.append("outer")
    assert done == ["inner", "outer"]  # the whole block ran, then the stop


def test_a_clean_up_after_a_stop_is_not_stopped_again(sigint_stops):
    with pytest.raises(KeyboardInterrupt):
        interrupts.stop("SIGTERM")
    with interrupts.uninterrupted():  # e.g. idling the wheel after Ctrl-C
        pass
    assert interrupts.stopped() == "SIGTERM"
    with pytest.raises(KeyboardInterrupt):
        interrupts.check_stop()  # a command's checkpoint still sees it


def test_an_error_inside_a_section_goes_on_and_the_stop_is_kept(sigint_stops):
    with pytest.raises(OSError):
        with interrupts.uninterrupted():
            interrupts.stop("SIGHUP")
            raise OSError("bus gone")
    with interrupts.uninterrupted():
        pass  # no stale stop raised here
    assert interrupts.stopped() == "SIGHUP"


def test_other_threads_pass_through(sigint_stops):
    seen = []

    def worker():
        with interrupts.uninterrupted():
            seen.append(interrupts._held[0])

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [0]  # only the main thread's sections hold signals


def test_a_python_can_virtual_bus_survives_stops_during_reads(sigint_stops):
    """The measured hang: Ctrl-C inside the virtual bus's queue can leave its lock taken.
    With reads and writes uninterrupted, every stop lands outside, and the clean-up's
    write and read after it go through."""
    import can

    from rwlab.wheel.dbc_link import read_frames

    with (
        can.Bus(interface="virtual", channel="stops") as a,
        can.Bus(interface="virtual", channel="stops") as b,
    ):
        stops = 0
        previous = signal.signal(signal.SIGALRM, lambda s, f: interrupts.stop("SIGALRM"))
        for k in range(200):
            try:
                try:
                    signal.setitimer(signal.ITIMER_REAL, 1e-4)
                    for _ in range(20):
                        with interrupts.uninterrupted():
                            a.send(can.Message(arbitration_id=k % 0x7FF, data=b"\x01"))
                        read_frames(b)
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                for _ in range(1000):  # a handler still pending runs here, inside the try
                    pass
            except KeyboardInterrupt:
                stops += 1
        signal.signal(signal.SIGALRM, previous)
        assert stops > 0  # the alarms did land
        with interrupts.uninterrupted():
            a.send(can.Message(arbitration_id=1, data=b"\x02"))  # the clean-up's write
        assert any(m.data == b"\x02" for m in read_frames(b))


def test_a_stop_inside_a_c_callback_prints_no_traceback_and_is_raised_at_next_check(monkeypatch):
    """Numba's compiler calls back into Python through ctypes: a Ctrl-C landing there is
    swallowed by ctypes and printed as "Exception ignored ... Traceback" (measured: a
    demo stopped while its workers compiled the wheel's kernel)."""
    import ctypes

    from rwlab.cli._common import _stop_signals

    def callback():
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10**5):  # the handler runs here, inside the callback
            pass

    printed = []  # what Python's hook would print as "Exception ignored ..."
    monkeypatch.setattr(sys, "unraisablehook", printed.append)
    with _stop_signals():
        ctypes.CFUNCTYPE(None)(callback)()
        assert interrupts.stopped() == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            interrupts.check_stop()
    interrupts.clear()
    assert printed == []
