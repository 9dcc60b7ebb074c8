"""Work in a forked child (rwlab._forked) and the report figures drawn side by side
(rwlab.report.html.render_pngs): the same bytes as one process drawing them all."""

import os
import subprocess
import sys
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from rwlab._forked import Forked
from rwlab.report.html import FigureQueue, Page, figure, render_pngs

needs_fork = pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork on this system")


def _in_a_fresh_process(check) -> None:
    """Run ``check`` in a new interpreter, where :func:`forkable` holds: a test worker may
    still run threads that an earlier test left behind, and then nothing is forked."""
    code = (
        "import tests.test_forked as t, rwlab._forked as f; "
        f"assert f.forkable(); t.{check.__name__}()"
    )
    root = Path(__file__).parent.parent
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@needs_fork
def test_the_value_comes_from_a_child_process():
    _in_a_fresh_process(_value_from_a_child)


def _value_from_a_child():
    parent = os.getpid()
    with Forked(lambda: (os.getpid(), np.arange(3.0))) as child:
        pid, values = child.result()
    assert pid != parent
    assert values.tolist() == [0.0, 1.0, 2.0]


@needs_fork
def test_a_child_that_fails_leaves_the_work_to_this_process():
    _in_a_fresh_process(_work_left_to_this_process)


def _work_left_to_this_process():
    parent = os.getpid()

    def work():
        if os.getpid() != parent:
            raise RuntimeError("the child fails")
        return "computed here"

    assert Forked(work).result() == "computed here"


def test_an_error_of_the_work_is_raised_here():
    def work():
        raise ValueError("bad input")

    with pytest.raises(ValueError, match="bad input"):
        Forked(work).result()


@needs_fork
def test_leaving_the_block_before_the_result_ends_the_child():
    _in_a_fresh_process(_child_ended_on_leaving)


def _child_ended_on_leaving():
    t0 = time.perf_counter()
    with Forked(lambda: time.sleep(60)) as child:
        pid = child._child[0]
    assert time.perf_counter() - t0 < 10
    with pytest.raises(ChildProcessError):  # reaped: no zombie left behind
        os.waitpid(pid, 0)


@needs_fork
def test_a_child_does_not_keep_the_output_locked_when_this_process_is_killed(tmp_path):
    """A child drawing dies with its parent: the folder's lock goes at once (a child left
    running held it, and a rerun was refused)."""
    lock = tmp_path / "out.lock"
    code = (
        "import os, sys, time; from rwlab._io import lock_exclusive; "
        "from rwlab._forked import Forked; "
        f"fd = lock_exclusive(__import__('pathlib').Path({str(lock)!r}), RuntimeError()); "
        "child = Forked(lambda: time.sleep(60)); "
        "print(child._child[0], flush=True); time.sleep(60)"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 5.0
    while True:
        try:
            from rwlab._io import lock_exclusive

            os.close(lock_exclusive(lock, BlockingIOError()))
            break
        except BlockingIOError:
            if time.monotonic() > deadline:
                os.kill(child, 9)
                raise AssertionError("the killed parent's child keeps the lock") from None
            time.sleep(0.05)


def _figures(n: int) -> list:
    figs = []
    for i in range(n):
        fig, ax = figure(6, 2.5)
        ax.plot(np.sin(np.linspace(0, 10 + i, 500)), label=f"trace {i}")
        ax.set_title(f"figure {i}")
        ax.legend()
        figs.append(fig)
    return figs


@pytest.mark.parametrize("processes", [2, 3])
def test_figures_drawn_side_by_side_are_the_bytes_one_process_draws(processes):
    alone = render_pngs(_figures(5), processes=1)
    figs = _figures(5)
    shared = render_pngs(figs, processes=processes)
    assert shared == alone
    assert len(set(alone)) == 5  # five different figures, in their order
    assert all(png.startswith(b"\x89PNG") for png in shared)
    assert not any(plt.fignum_exists(fig.number) for fig in figs)  # every one closed


def test_a_page_takes_a_figure_drawn_already_and_draws_the_others():
    drawn, todo = _figures(2)
    png = render_pngs([drawn], processes=1)[0]
    page = Page("t")
    page.figure(png, "fig-a", "drawn already")
    page.figure(todo, "fig-b", "drawn by the page")
    html = page.render()
    assert html.index('id="fig-a"') < html.index('id="fig-b"')
    assert html.count("data:image/png;base64,") == 2
    assert not plt.fignum_exists(todo.number)


def _makers(n: int, fail_in_child_from: int | None = None) -> dict:
    """Figure id → maker of ``_figures``' i-th figure; from ``fail_in_child_from`` on the
    makers raise in any process but this one (a child that fails half-way)."""
    here = os.getpid()

    def make(i: int):
        if fail_in_child_from is not None and i >= fail_in_child_from and os.getpid() != here:
            raise RuntimeError("the child fails")
        fig, ax = figure(6, 2.5)
        ax.plot(np.sin(np.linspace(0, 10 + i, 500)), label=f"trace {i}")
        ax.set_title(f"figure {i}")
        ax.legend()
        return fig

    return {f"fig-{i}": (lambda i=i: make(i)) for i in range(n)}


def _check_queue_draws_each_figure_once_in_order(fail_in_child_from=None) -> None:
    alone = render_pngs(_figures(6), processes=1)
    open_before = set(plt.get_fignums())  # a test worker may hold other tests' figures
    with FigureQueue(lambda n: _makers(n, fail_in_child_from)) as queue:
        queue.start(6)
        time.sleep(0.2)  # the child takes some figures before this process joins in
        drawn = queue.result()
    assert list(drawn) == [f"fig-{i}" for i in range(6)]
    assert list(drawn.values()) == alone
    assert set(plt.get_fignums()) <= open_before  # every figure made here closed


@needs_fork
def test_a_figure_queue_draws_every_figure_once_shared_with_a_child():
    _in_a_fresh_process(_check_queue_draws_each_figure_once_in_order)


def _check_queue_child_failing() -> None:
    _check_queue_draws_each_figure_once_in_order(fail_in_child_from=1)


@needs_fork
def test_the_figures_a_failed_child_took_are_drawn_here():
    _in_a_fresh_process(_check_queue_child_failing)


def test_without_a_child_the_queue_draws_everything_here(monkeypatch):
    monkeypatch.setattr("rwlab._forked.forkable", lambda: False)
    _check_queue_draws_each_figure_once_in_order()


def _check_queue_first_work_in_the_child(first_fails_in_child: bool = False) -> None:
    here = os.getpid()
    warmed: list[int] = []

    def first(value):
        if first_fails_in_child and os.getpid() != here:
            raise RuntimeError("the child fails")
        return os.getpid(), warmed, value["values"]

    alone = render_pngs(_figures(4), processes=1)
    value = {"n": 4, "values": np.arange(100_000.0)}  # more than a pipe holds at once
    with FigureQueue(
        lambda v: _makers(v["n"]), first=first, warm=lambda: warmed.append(os.getpid())
    ) as queue:
        time.sleep(0.1)  # the child warms while this process computes the value
        queue.start(value)
        drawn = queue.result()
    pid, warmed_in, values = queue.first
    assert (pid == here) is first_fails_in_child  # computed where it could be
    assert warmed_in == ([] if first_fails_in_child else [pid])  # warm ran in the child first
    np.testing.assert_array_equal(values, value["values"])
    assert list(drawn.values()) == alone


def test_a_queues_result_before_its_value_is_refused():
    with FigureQueue(_makers) as queue, pytest.raises(RuntimeError, match="start"):
        queue.result()


def _check_queue_first_failing_in_the_child() -> None:
    _check_queue_first_work_in_the_child(first_fails_in_child=True)


@needs_fork
def test_a_figure_queues_first_work_is_done_in_the_child_and_its_value_returned():
    _in_a_fresh_process(_check_queue_first_work_in_the_child)


@needs_fork
def test_a_first_work_the_child_failed_is_done_here():
    _in_a_fresh_process(_check_queue_first_failing_in_the_child)
