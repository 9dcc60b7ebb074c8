"""A tiny HTML page builder for reports that open offline (no scripts, no links out).

Figures are matplotlib figures rendered to PNG and embedded as base64 data
URIs, each in a ``<figure id=...>`` so tests and readers can find them. A page
renders its figures when it is rendered, shares of them in forked processes
(:func:`render_pngs`): drawing is most of a report's time.
"""

from __future__ import annotations

import base64
import contextlib
import functools
import html
import io
import os
import pickle
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import Formatter, LogFormatterMathtext

from rwlab._forked import Forked
from rwlab._io import atomic_write_bytes

__all__ = [
    "FigureQueue",
    "Page",
    "PlainLogLabels",
    "figure",
    "png_uri",
    "render_pngs",
    "signed",
    "trace_styles",
]

DPI = 110  # the reports' figures: 8 × 3.2 in → 880 × 352 pixels

_STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;
margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.7em}h2{font-size:1.3em;margin-top:2em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:1em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.3em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}tr.chosen{background:#eef7ee;font-weight:600}
figure{margin:1.2em 0}figure img{max-width:100%}figcaption{font-size:.9em;color:#555}
.note{background:#fff8e1;padding:.6em 1em;border-left:4px solid #f0c040}
code{background:#f4f4f4;padding:0 .2em}
.verdict{padding:.7em 1em;border-left:5px solid;font-size:1.05em}
.verdict.ok{background:#eef7ee;border-color:#4a4}.verdict.bad{background:#fdecea;border-color:#c33}
.verdict.open{background:#fff8e1;border-color:#f0c040}
"""


def figure(width: float = 8.0, height: float = 3.2, nrows: int = 1, ncols: int = 1, **kw):
    """A new matplotlib figure and axes with the report's size.

    Parameters
    ----------
    width, height : float
        Size, inches.
    nrows, ncols : int
        Grid of axes.
    **kw
        Passed to ``matplotlib.pyplot.subplots``.

    Returns
    -------
    fig : matplotlib.figure.Figure
    ax : matplotlib.axes.Axes or numpy.ndarray of them
    """
    return plt.subplots(nrows, ncols, figsize=(width, height), constrained_layout=True, **kw)


def trace_styles(n: int) -> list[dict]:
    """Line widths and stacking for ``n`` traces drawn in order, the last the main one.

    Each trace is drawn narrower than the one before and above it, so the main trace
    is on top and a trace it covers still shows as a rim around it.

    Parameters
    ----------
    n : int
        Number of traces.

    Returns
    -------
    list of dict
        ``lw`` and ``zorder`` for each trace, keyword arguments of ``Axes.plot``.
    """
    return [{"lw": 0.9 + 0.8 * (n - 1 - i), "zorder": 2 + i} for i in range(n)]


def signed(value: float, digits: int = 3) -> str:
    """A signed number with ``digits`` significant digits (never "+0.0000" for 2e-5).

    Parameters
    ----------
    value : float
        The number.
    digits : int
        Significant digits.

    Returns
    -------
    str
        E.g. ``"+1.94e-05"``, ``"-0.0123"``, ``"+0"``.
    """
    return f"{value:+.{digits}g}"


def png_uri(fig) -> str:
    """A figure as an inline PNG (``data:`` URI), and the figure closed.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.

    Returns
    -------
    str
        ``data:image/png;base64,...``.
    """
    return _uri(render_pngs([fig], processes=1)[0])


def _uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode()


def _png(fig) -> bytes:
    """``fig`` as PNG bytes at :data:`DPI`, drawn once: ``savefig`` draws a figure with a
    layout engine twice (once to lay it out), for the same bytes (measured on every
    figure of a study report: 20 % of the drawing time)."""
    _plain_log_labels(fig)
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    fig.set_dpi(DPI)
    buf = io.BytesIO()
    canvas.print_png(buf)
    return buf.getvalue()


class PlainLogLabels(Formatter):
    """A log axis's tick labels as plain text, ``10⁻³`` and ``2×10⁻³``, where matplotlib's
    (:class:`~matplotlib.ticker.LogFormatterSciNotation`) writes them in mathtext: its
    parser costs ≈ 0.2 s to build in each process that draws one (measured), more than a
    figure. Hand-written: matplotlib has no plain-text log formatter with superscripts.
    A label beyond the forms above stays mathtext.

    Parameters
    ----------
    inner : matplotlib.ticker.LogFormatterMathtext
        The axis's formatter, which chooses the labels.
    """

    def __init__(self, inner: LogFormatterMathtext) -> None:
        self.inner = inner

    def set_axis(self, axis) -> None:
        """Label ``axis`` (a matplotlib axis), as the inner formatter does."""
        super().set_axis(axis)
        self.inner.set_axis(axis)

    def set_locs(self, locs) -> None:
        """The ticks' places, for the inner formatter: it picks the minor labels."""
        self.inner.set_locs(locs)

    def __call__(self, x: float, pos: int | None = None) -> str:
        """The label of the tick at ``x`` (data units), number ``pos``."""
        label = self.inner(x, pos)
        math = _MATH_LABEL.fullmatch(label)
        if math is None:
            return label
        text = math[1].replace("\\times", "×")
        text = _POWER.sub(lambda power: power[1].translate(_SUPERSCRIPT), text)
        if any(c in text for c in "\\{}^$"):
            return label
        return "\N{MINUS SIGN}" + text[1:] if text.startswith("-") else text


_MATH_LABEL = re.compile(r"\$\\mathdefault\{(.*)\}\$")
_POWER = re.compile(r"\^\{(-?\d+)\}")
_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def _plain_log_labels(fig) -> None:
    """Every log axis of ``fig`` labelled by :class:`PlainLogLabels`."""
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            if isinstance(axis.get_major_formatter(), LogFormatterMathtext):
                axis.set_major_formatter(PlainLogLabels(axis.get_major_formatter()))
            if isinstance(axis.get_minor_formatter(), LogFormatterMathtext):
                axis.set_minor_formatter(PlainLogLabels(axis.get_minor_formatter()))


def render_pngs(figs: Sequence, processes: int | None = None) -> list[bytes]:
    """Each figure as PNG bytes, every figure closed after; shares drawn side by side.

    The figures are dealt out in turn to ``processes`` processes: this one and forked
    children (:class:`rwlab._forked.Forked`), each drawing its share. The bytes are
    those this process would draw (a child is a copy of it).

    Parameters
    ----------
    figs : sequence of matplotlib.figure.Figure
        The figures.
    processes : int, optional
        How many processes draw. Default: one per core the process may use, at most
        one per figure. Where no child can be forked (:func:`rwlab._forked.forkable`),
        this process draws every share.

    Returns
    -------
    list of bytes
        The PNG files, in the order of ``figs``.
    """
    n = max(1, min(len(figs), _cores() if processes is None else processes))
    shares = [range(i, len(figs), n) for i in range(n)]
    pngs = [b""] * len(figs)
    try:
        with contextlib.ExitStack() as stack:
            children = [
                stack.enter_context(Forked(functools.partial(_pngs, figs, share)))
                for share in shares[1:]
            ]
            for i, png in zip(shares[0], _pngs(figs, shares[0]), strict=True):
                pngs[i] = png
            for share, child in zip(shares[1:], children, strict=True):
                for i, png in zip(share, child.result(), strict=True):
                    pngs[i] = png
    finally:
        for fig in figs:
            plt.close(fig)
    return pngs


class FigureQueue:
    """The figures of one value, drawn from one queue by a forked child and by this process.

    The child is forked at once and does ``warm()`` (imports, compiled code loaded)
    while this process computes the value the figures show; :meth:`start` hands it
    the value (pickled, through a pipe) and the figures' numbers. The child computes
    ``first(value)``, then draws; :meth:`result` has this process draw beside it.
    The numbers wait in a pipe that both processes read one byte at a time (one read
    of a pipe is atomic: each number reaches one process), so each draws what the
    other has not reached (``rwlab identify``: the servo fit in the child while the
    figures of the linear study are drawn here). A figure the child took and did not
    return (it failed) is drawn here, and ``first(value)`` computed here.
    Hand-written: a pool's task queue would need a feeder thread, and
    :class:`~rwlab._forked.Forked` forks only a process without threads.

    Parameters
    ----------
    makers_of : callable
        ``makers_of(value)``: figure id → ``make()``, returning a matplotlib figure (at
        most 256); each process calls it on its copy of the value.
    first : callable, optional
        ``first(value)``: work for the child before it draws, returning a picklable
        value, :attr:`first` once :meth:`result` returns.
    warm : callable, optional
        ``warm()``: what the child does while it waits for the value.

    Attributes
    ----------
    first : object
        ``first(value)``'s value (None before :meth:`result`, or without ``first``).
    """

    def __init__(
        self,
        makers_of: Callable[[Any], Mapping[str, Callable[[], Figure]]],
        *,
        first: Callable[[Any], Any] | None = None,
        warm: Callable[[], None] | None = None,
    ) -> None:
        self._makers_of, self._first, self._warm = makers_of, first, warm
        self.first: Any = None
        self._ids: list[str] = []
        self._makers: list[Callable[[], Figure]] = []
        self._value: Any = None
        self._parent = os.getpid()
        self._numbers, self._numbers_in = os.pipe()
        self._values, self._values_in = os.pipe()  # the value's way to the child
        self._child = Forked(self._in_child)
        os.close(self._values)

    def _in_child(self) -> tuple[Any, dict[int, bytes]]:
        """The child's work (``Forked`` also calls it here where the child failed)."""
        value = self._value
        if os.getpid() != self._parent:
            os.close(self._numbers_in)  # else the queue's pipe never ends
            os.close(self._values_in)
            if self._warm is not None:
                self._warm()
            with os.fdopen(self._values, "rb") as pipe:
                value = pickle.load(pipe)
            self._take(value)
        first = None if self._first is None else self._first(value)
        return first, self._drain()

    def _take(self, value: Any) -> None:
        makers = self._makers_of(value)
        if len(makers) > 256:
            raise ValueError(f"a FigureQueue holds at most 256 figures, got {len(makers)}")
        self._ids, self._makers = list(makers), list(makers.values())

    def start(self, value: Any) -> None:
        """Hand the child ``value``: it computes ``first(value)``, then both processes draw.

        Parameters
        ----------
        value : object
            What the figures show (picklable).
        """
        self._take(value)
        self._value = value
        os.write(self._numbers_in, bytes(range(len(self._makers))))  # < a pipe's buffer
        os.close(self._numbers_in)
        self._numbers_in = -1
        values_in, self._values_in = self._values_in, -1
        try:
            with os.fdopen(values_in, "wb") as pipe:
                if self._child.forked:
                    payload = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
                    _hold(values_in, len(payload))
                    pipe.write(payload)
        except BrokenPipeError:  # the child ended: result() does its work here
            pass

    def _drain(self) -> dict[int, bytes]:
        drawn = {}
        while number := os.read(self._numbers, 1):
            drawn[number[0]] = self._draw(number[0])
        return drawn

    def _draw(self, i: int) -> bytes:
        fig = self._makers[i]()
        try:
            return _png(fig)
        finally:
            plt.close(fig)

    def result(self) -> dict[str, bytes]:
        """Every figure's PNG, by id, in the makers' order (and :attr:`first` set).

        Returns
        -------
        dict of str to bytes

        Raises
        ------
        RuntimeError
            Before :meth:`start`.
        """
        if self._numbers_in >= 0:
            raise RuntimeError("FigureQueue.result() before start(): the child has no value")
        drawn = self._drain()
        self.first, by_child = self._child.result()
        drawn |= by_child
        self.close()
        for i in range(len(self._makers)):
            if i not in drawn:
                drawn[i] = self._draw(i)
        return {fig_id: drawn[i] for i, fig_id in enumerate(self._ids)}

    def close(self) -> None:
        """End the child if it still works; close the pipes."""
        self._child.close()
        for name in ("_numbers", "_numbers_in", "_values_in"):
            if getattr(self, name) >= 0:
                os.close(getattr(self, name))
                setattr(self, name, -1)

    def __enter__(self) -> FigureQueue:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _hold(fd: int, size: int) -> None:
    """Grow the pipe ``fd`` to hold ``size`` bytes where the system allows (Linux, up to
    its limit): a writer then goes on without waiting for a reader still busy."""
    try:
        import fcntl
    except ImportError:  # not a Unix
        return
    if hasattr(fcntl, "F_SETPIPE_SZ"):
        with contextlib.suppress(OSError):  # beyond the limit: the writer waits
            fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, size)


def _pngs(figs: Sequence, share: range) -> list[bytes]:
    return [_png(figs[i]) for i in share]


def _cores() -> int:
    """The cores this process may run on."""
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    return len(cores) if cores else os.cpu_count() or 1


class Page:
    """Collects sections, then writes one self-contained HTML file.

    Parameters
    ----------
    title : str
        The page's title.
    """

    def __init__(self, title: str) -> None:
        self.title = title
        self.parts: list[str] = [f"<h1>{html.escape(title)}</h1>"]
        self._figures: list[tuple] = []  # (figure, its part's index, id, caption), not drawn

    def heading(self, text: str, anchor: str | None = None) -> None:
        ident = f' id="{anchor}"' if anchor else ""
        self.parts.append(f"<h2{ident}>{html.escape(text)}</h2>")

    def text(self, text: str, *, note: bool = False) -> None:
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")

    def verdict(self, text: str, ok: bool | None) -> None:
        """The report's answer first after the title: green when ``ok``, red when not, yellow
        when undecided (``None``: met by the estimate but not demonstrated)."""
        cls = {True: "ok", False: "bad", None: "open"}[ok]
        self.parts.append(f'<p class="verdict {cls}" id="verdict">{html.escape(text)}</p>')

    def html(self, raw: str) -> None:
        """Insert trusted HTML written by rwlab itself."""
        self.parts.append(raw)

    def table(
        self,
        header: list[str],
        rows: list[list],
        *,
        table_id: str | None = None,
        highlight: int | None = None,
    ) -> None:
        ident = f' id="{table_id}"' if table_id else ""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = []
        for i, row in enumerate(rows):
            cls = ' class="chosen"' if i == highlight else ""
            cells = "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in row)
            body.append(f"<tr{cls}>{cells}</tr>")
        self.parts.append(f"<table{ident}><tr>{head}</tr>{''.join(body)}</table>")

    def figure(self, fig, fig_id: str, caption: str) -> None:
        """Add a figure: a matplotlib figure (drawn, and closed, when the page is
        rendered, :func:`render_pngs`) or its PNG bytes, drawn already."""
        self._figures.append((fig, len(self.parts), fig_id, caption))
        self.parts.append("")

    def render(self) -> str:
        todo = [fig for fig, *_ in self._figures if not isinstance(fig, bytes)]
        drawn = iter(render_pngs(todo))
        for fig, i, fig_id, caption in self._figures:
            png = fig if isinstance(fig, bytes) else next(drawn)
            self.parts[i] = (
                f'<figure id="{fig_id}"><img alt="{html.escape(caption)}" src="{_uri(png)}">'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
        self._figures = []
        return (
            '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head><body>"
            + "\n".join(self.parts)
            + "</body></html>"
        )

    def save(self, path: str | os.PathLike) -> Path:
        text = self.render()
        return atomic_write_bytes(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "" if value is None else str(value)
