"""The diagnosis report: residuals and test statistics of one record, with alarm marks.

Figure ids: ``fig-residuals`` (speed, acceleration and current residuals),
``fig-statistics`` (each block test's CUSUM statistic and threshold); table ``alarms``.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from rwlab._io import atomic_write_bytes
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
        raise FileExistsError(f"{', '.join(existing)} exist; pass force=True to overwrite them")
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
        f"The detectors compare it with the healthy reference measured on the identification "
        f"record ({diagnosis.reference.source or 'see model.json'}), from the first sample on; "
        f"the thresholds were asked for {diagnosis.false_alarms_per_hour:g} false alarms "
        "per hour per detector on healthy records: the rate measured on healthy records of "
        "other units (rwlab.diagnose.calibration) where it resolves that rate, otherwise the "
        "larger of its extrapolation and the analytic threshold (block CUSUMs: Siegmund's "
        "approximation of ARL₀; frozen speed: the run-length ARL₀ of the reference's repeat "
        "probability; dropouts: Poisson counts of lost frames)."
    )
    for note in diagnosis.notes:
        page.html(f'<p class="note">Cannot be honoured: {html.escape(note)}</p>')
    page.heading("Alarms", "alarms-heading")
    if diagnosis.alarms:
        page.table(
            [
                "t [s]",
                "likely fault",
                "size",
                "95 % CI",
                "unit",
                "detector",
                "statistic",
                "threshold",
            ],
            [
                [
                    a.t_s,
                    a.kind,
                    "—" if a.magnitude is None else f"{a.magnitude:.4g}",
                    "—" if a.ci is None else f"{a.ci[0]:.4g} … {a.ci[1]:.4g}",
                    a.unit,
                    a.detector,
                    a.statistic,
                    a.threshold,
                ]
                for a in diagnosis.alarms
            ],
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
        "minus the reference's current balance; red dashes: alarms.",
    )
    stats = [n for n in ("friction", "motor", "speed", "lag") if n in diagnosis.thresholds]
    fig, axes = figure(9, 2.4 * len(stats), len(stats), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], stats, strict=True):
        ax.plot(t, h[f"stat_{name}"], lw=0.8, label=f"{name} CUSUM")
        ax.axhline(diagnosis.thresholds[name], color="k", ls=":", label="threshold")
        ax.set_yscale("symlog", linthresh=max(diagnosis.thresholds[name], 0.1))
        ax.set_ylim(bottom=0)
        ax.set_ylabel("statistic [σ]")
        ax.legend(loc="upper left", fontsize=8)
        _mark_alarms(ax, diagnosis)
    axes[-1, 0].set_xlabel("time [s]")
    page.figure(fig, "fig-statistics", "Block tests' CUSUM statistics against their thresholds.")
    page.heading("Residual statistics")
    rows = []
    for name, stats_ in payload["residual_statistics"].items():
        for part in ("before_alarm", "after_alarm"):
            s = stats_[part]
            if s is not None:
                rows.append([name, stats_["unit"], part.replace("_", " "), *s.values()])
    page.table(["residual", "unit", "part", "mean", "σ", "max |·|"], rows)
    return page


TREND_FORMAT = "rwlab.DiagnosisTrend/1"


def trend_point(record: str, start_utc: str, diagnosis: Diagnosis) -> dict:
    """One record's line of the trend: each fault's one size (its alarms' consistent sizes
    combined, :meth:`Diagnosis.sizes`) and the time it was first named."""
    faults: dict[str, dict] = {}
    first = {}
    for a in diagnosis.alarms:
        first.setdefault(a.kind, a.t_s)
    for kind, size in diagnosis.sizes().items():
        if size["magnitude"] is not None:
            faults[kind] = {**size, "t_s": first[kind]}
    return {"record": record, "start_utc": start_utc, "faults": faults}


def write_trend(points: list[dict], out_dir: str | os.PathLike, *, force: bool = False):
    """Write ``trend.json`` and ``trend.html``: each fault's size over a wheel's records."""
    out = Path(out_dir)
    targets = {name: out / name for name in ("trend.json", "trend.html")}
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} exist; pass force=True to overwrite them")
    out.mkdir(parents=True, exist_ok=True)
    points = sorted(points, key=lambda p: (p["start_utc"], p["record"]))
    text = json.dumps({"format": TREND_FORMAT, "records": points}, indent=2)
    atomic_write_bytes(targets["trend.json"], lambda tmp: tmp.write_text(text))
    page = Page("Fault trend")
    page.text(
        "Each record of the wheel diagnosed against the same healthy reference; the size of "
        "each fault named (its alarms' consistent sizes combined) with its 95 % interval, "
        "in record order."
    )
    kinds = sorted({k for p in points for k in p["faults"]})
    if kinds:
        fig, axes = figure(9, 2.4 * len(kinds), len(kinds), 1, sharex=True, squeeze=False)
        x = np.arange(len(points))
        for ax, kind in zip(axes[:, 0], kinds, strict=True):
            rows = [(i, p["faults"][kind]) for i, p in enumerate(points) if kind in p["faults"]]
            mags = np.array([f["magnitude"] for _, f in rows])
            lo = np.array([(f["ci95"] or [f["magnitude"]] * 2)[0] for _, f in rows])
            hi = np.array([(f["ci95"] or [f["magnitude"]] * 2)[1] for _, f in rows])
            idx = np.array([i for i, _ in rows])
            ax.errorbar(idx, mags, yerr=[mags - lo, hi - mags], fmt="o-", capsize=3)
            ax.set_ylabel(f"{kind} [{rows[0][1]['unit']}]")
        axes[-1, 0].set_xticks(x, [p["record"] for p in points], rotation=30, fontsize=7)
        page.figure(fig, "fig-trend", "Estimated fault size per record (95 % intervals).")
    page.table(
        ["record", "start (UTC)", "faults"],
        [
            [
                p["record"],
                p["start_utc"],
                ", ".join(f"{k} {f['magnitude']:.4g} {f['unit']}" for k, f in p["faults"].items())
                or "none",
            ]
            for p in points
        ],
        table_id="trend",
    )
    page.save(targets["trend.html"])
    return targets
