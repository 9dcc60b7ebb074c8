"""Every figure a page shows (the README's included), made from the code by the docs build.

``python docs/build.py`` calls :func:`build` first: it draws the workflow diagram,
runs the commands of the README's tour (``rwlab demo`` and the rest, in a
temporary folder, exactly as a user types them) and takes each tour figure from
the report the command wrote, so a figure cannot show what the code no longer
does. :data:`FIGURES` names every file it writes; ``tests/test_docs_figures.py``
fails when a page shows an image that is not in it. ``python docs/figures.py``
rebuilds the figures alone.
"""

from __future__ import annotations

import base64
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
OUT = DOCS / "figures"

#: The README's tour, run in this order by the build (each a command line's words after
#: ``rwlab``); tests/test_docs_figures.py checks that the README lists each one.
TOUR: list[list[str]] = [
    ["demo"],
    ["experiment", "--signal", "prbs", "--out", "r.mcap"],
    ["identify", "r.mcap", "--out", "study"],
    ["experiment", "--fault", "friction=3@600", "--seed", "2", "--out", "f.mcap"],
    ["diagnose", "f.mcap", "--model", "study/model.json", "--out", "diag"],
    ["attitude", "montecarlo", "--runs", "8", "--duration", "600", "--out", "mc"],
]

#: Each figure file (relative to docs/) → (its source in the tour's folder, the report
#: figure's id). ``drawn`` figures are drawn here; the others are cut from the reports.
FIGURES: dict[str, tuple[str, str]] = {
    "figures/workflow.png": ("drawn", "the workflow"),
    "figures/demo.png": ("rwlab-demo/index.html", "fig-pointing"),
    "figures/record.png": ("drawn", "r.mcap"),
    "figures/identify.png": ("study/report.html", "fig20-compare"),
    "figures/attitude.png": ("rwlab-demo/attitude/report.html", "fig-identified-wheel"),
    "figures/hil.png": ("rwlab-demo/hil/report.html", "fig-hil-pointing"),
    "figures/diagnose.png": ("diag/report.html", "fig-residuals"),
    "figures/montecarlo.png": ("mc/report.html", "fig-cdf"),
}

_FIGURE = re.compile(
    r'<figure id="(?P<id>[^"]+)"><img alt="[^"]*" src="data:image/png;base64,(?P<png>[^"]+)"'
)


def report_figures(html_path: Path) -> dict[str, bytes]:
    """The PNG figures a report embeds, by their ``<figure id>``."""
    text = html_path.read_text(encoding="utf-8")
    return {m["id"]: base64.b64decode(m["png"]) for m in _FIGURE.finditer(text)}


def run_tour(work: Path) -> None:
    """Run the README's tour commands in ``work`` (each must succeed or diagnose's 1)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "MPLBACKEND": "Agg"}
    for words in TOUR:
        print("docs figures: rwlab " + " ".join(words), flush=True)
        done = subprocess.run(
            [sys.executable, "-m", "rwlab", *words], cwd=work, env=env, capture_output=True
        )
        ok = (0, 1) if words[0] == "diagnose" else (0,)  # diagnose exits 1 on an alarm
        if done.returncode not in ok:
            sys.stderr.write(done.stdout.decode() + done.stderr.decode())
            raise RuntimeError(f"rwlab {' '.join(words)} exited {done.returncode}")


def draw_workflow(path: Path) -> None:
    """The workflow: bench → record → identify → model.json → attitude, with HIL and diagnosis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch

    # name: (x, y, what, the command); x, y the box's centre in data units
    boxes = {
        "bench": (0.0, 1.0, "wheel on the bench\nCAN or RS-232,\nor its twin", "rwlab experiment"),
        "record": (1.2, 1.0, "record (.mcap)\nevery command and\ntelemetry frame", "rwlab export"),
        "identify": (2.4, 1.0, "identification\npaper A's study", "rwlab identify"),
        "model": (3.6, 1.0, "model.json\nthe wheel's model,\nspec and reference", "rwlab compare"),
        "attitude": (4.8, 1.0, "attitude control\nLQR · LQG · LTR\n(paper B)", "rwlab attitude"),
        "hil": (
            0.0,
            -0.25,
            "hardware in the loop\nthe attitude loop,\nwheels on a bus",
            "rwlab hil",
        ),
        "diagnose": (2.4, -0.25, "fault diagnosis\ndetect, name, size", "rwlab diagnose"),
        "budget": (4.8, -0.25, "pointing budget\nMonte Carlo, ECSS", "rwlab attitude\nmontecarlo"),
    }
    arrows = [
        ("bench", "record"),
        ("record", "identify"),
        ("identify", "model"),
        ("model", "attitude"),
        ("attitude", "budget"),
        ("record", "diagnose"),
        ("model", "diagnose"),
        ("hil", "bench"),
    ]
    w, h = 1.04, 0.72

    def edge(a: str, b: str) -> tuple[float, float]:
        """Where the line from a's centre towards b's leaves box a."""
        (xa, ya), (xb, yb) = boxes[a][:2], boxes[b][:2]
        dx, dy = xb - xa, yb - ya
        t = min(w / 2 / abs(dx) if dx else 1e9, h / 2 / abs(dy) if dy else 1e9)
        return xa + 1.04 * t * dx, ya + 1.04 * t * dy

    fig, ax = plt.subplots(figsize=(10, 3.6))
    for x, y, text, command in boxes.values():
        box = FancyBboxPatch(
            (x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.02", fc="#eef3fb", ec="#3465a4"
        )
        ax.add_patch(box)
        ax.text(x, y + 0.08, text, ha="center", va="center", fontsize=8)
        ax.text(x, y - h / 2 + 0.07, command, ha="center", va="center", fontsize=7,
                family="monospace", color="#204a87")  # fmt: skip
    for a, b in arrows:
        both = "<|-|>" if (a, b) == ("hil", "bench") else "-|>"
        ax.annotate("", xy=edge(b, a), xytext=edge(a, b),
                    arrowprops={"arrowstyle": both, "color": "#555", "lw": 1.2})  # fmt: skip
    ax.set_xlim(-0.6, 5.45)
    ax.set_ylim(-0.65, 1.4)
    ax.set_aspect("equal")
    ax.set_axis_off()
    fig.savefig(path, dpi=110, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)


def draw_record(record: Path, path: Path) -> None:
    """A testbed record's channels: command and measured speed, motor current."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sys.path.insert(0, str(ROOT / "src"))
    from rwlab.testbed import load_record

    data = load_record(record, outputs=("speed", "current"))
    t = data.time - data.time[0]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 4.2), sharex=True, constrained_layout=True)
    top.plot(t, data.u[:, 0], color="0.6", lw=1, label="command", zorder=1)
    top.plot(t, data.y[:, 0], color="C0", lw=1.2, label="measured speed", zorder=2)
    top.set_ylabel("speed [rpm]")
    top.legend(loc="upper right", fontsize=8)
    bottom.plot(t, data.y[:, 1], color="C3", lw=0.8, label="motor current")
    bottom.set_ylabel("current [A]")
    bottom.set_xlabel("time [s]")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    fig.suptitle(f"{record.name}: a 20-minute PRBS through the wheel driver", fontsize=10)
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)


def build(work: Path | None = None) -> list[Path]:
    """Write every figure of :data:`FIGURES` into docs/figures; returns the files written.

    Parameters
    ----------
    work : Path, optional
        Where the tour runs (default: a temporary folder, removed afterwards).
    """
    if work is None:
        with tempfile.TemporaryDirectory(prefix="rwlab-docs-") as tmp:
            return build(Path(tmp))
    OUT.mkdir(exist_ok=True)
    run_tour(work)
    makers: dict[str, Callable[[Path], None]] = {
        "figures/workflow.png": draw_workflow,
        "figures/record.png": lambda p: draw_record(work / FIGURES["figures/record.png"][1], p),
    }
    written = []
    for name, (source, fig_id) in FIGURES.items():
        path = DOCS / name
        if name in makers:
            makers[name](path)
        else:
            figures = report_figures(work / source)
            if fig_id not in figures:
                raise RuntimeError(f"{source} has no figure {fig_id!r} (it has {sorted(figures)})")
            path.write_bytes(figures[fig_id])
        written.append(path)
    return written


if __name__ == "__main__":
    for p in build():
        print(p.relative_to(ROOT))
