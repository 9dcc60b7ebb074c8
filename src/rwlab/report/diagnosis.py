"""The diagnosis report: residuals and test statistics of one record, with alarm marks.

Figure ids: ``fig-residuals`` (speed, acceleration and current residuals),
``fig-statistics`` (each CUSUM's statistic and threshold); table ``alarms``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rwlab.data import atomic_write_bytes
from rwlab.diagnose import Diagnosis
from rwlab.report.html import Page, figure

__all__ = ["write_diagnosis"]


def write_diagnosis(
    diagnosis: Diagnosis, out_dir: str | os.PathLike, *, title: str, force: bool = False
) -> dict[str, Path]:
    """Write ``diagnosis.json`` and ``report.html`` into ``out_dir``.

    Parameters
    ----------
    diagnosis : Diagnosis
        The alarms and statistics.
    out_dir : str or os.PathLike
        The folder.
    title : str
        The page's title.
    force : bool
        Replace existing files.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    out = Path(out_dir)
    targets = {name: out / name for name in ("diagnosis.json", "report.html")}
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} exist; use --force to overwrite")
    out.mkdir(parents=True, exist_ok=True)
    payload = diagnosis.to_dict()
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(targets["diagnosis.json"], lambda tmp: tmp.write_text(text))
    _page(diagnosis, payload, title).save(targets["report.html"])
    return targets


def _mark_alarms(ax, diagnosis: Diagnosis) -> None:
    for a in diagnosis.alarms:
        ax.axvline(a.t_s, color="r", ls="--", lw=1)


def _page(diagnosis: Diagnosis, payload: dict, title: str) -> Page:
    h = diagnosis.history
    t = h["t_s"]
    page = Page(f"Fault diagnosis — {title}")
    page.text(
        f"The identified model ran beside the telemetry at Ts = {np.median(np.diff(t)):g} s. "
        f"The first {diagnosis.calibration_s:g} s calibrated the residuals (assumed healthy); "
        f"the thresholds hold each detector to {diagnosis.false_alarms_per_hour:g} false alarms "
        "per hour on healthy data (CUSUM: Siegmund's approximation of ARL₀ on the whitened "
        "residual; frozen speed: the exact run-length ARL₀ of the calibrated repeat probability)."
    )
    page.heading("Alarms", "alarms-heading")
    if diagnosis.alarms:
        page.table(
            ["t [s]", "likely fault", "detector", "statistic", "threshold"],
            [[a.t_s, a.kind, a.detector, a.statistic, a.threshold] for a in diagnosis.alarms],
            table_id="alarms",
        )
    else:
        page.html('<p class="note" id="alarms">No alarm.</p>')
    page.heading("Residuals", "residuals")
    fig, axes = figure(9, 6.0, 3, 1, sharex=True)
    for ax, (name, unit) in zip(
        axes, (("speed", "rpm"), ("acceleration", "rpm/s"), ("current", "A")), strict=True
    ):
        ax.plot(t, h[name], lw=0.8)
        ax.set_ylabel(f"{name} [{unit}]")
        _mark_alarms(ax, diagnosis)
    axes[-1].set_xlabel("time [s]")
    page.figure(
        fig,
        "fig-residuals",
        "Measured minus modelled speed and acceleration (identified model), and measured "
        "minus calibrated current balance; red dashes: alarms.",
    )
    stats = [n for n in ("speed", "current") if n in diagnosis.thresholds]
    fig, axes = figure(9, 2.4 * len(stats), len(stats), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], stats, strict=True):
        ax.plot(t, h[f"stat_{name}"], lw=0.8, label=f"{name} CUSUM")
        ax.axhline(diagnosis.thresholds[name], color="k", ls=":", label="threshold")
        ax.set_yscale("symlog", linthresh=diagnosis.thresholds[name])
        ax.set_ylim(bottom=0)
        ax.set_ylabel("statistic [σ]")
        ax.legend(loc="upper left", fontsize=8)
        _mark_alarms(ax, diagnosis)
    axes[-1, 0].set_xlabel("time [s]")
    page.figure(fig, "fig-statistics", "CUSUM statistics against their thresholds.")
    page.heading("Residual statistics")
    rows = []
    for name, stats_ in payload["residual_statistics"].items():
        for part in ("before_alarm", "after_alarm"):
            s = stats_[part]
            if s is not None:
                rows.append([name, stats_["unit"], part.replace("_", " "), *s.values()])
    page.table(["residual", "unit", "part", "mean", "σ", "max |·|"], rows)
    return page
