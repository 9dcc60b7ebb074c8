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
from rwlab.diagnose import Alarm, Diagnosis
from rwlab.report.attitude import check_outputs
from rwlab.report.html import Page, figure

__all__ = ["write_diagnosis"]


def write_diagnosis(
    diagnosis: Diagnosis,
    out_dir: str | os.PathLike,
    *,
    title: str,
    force: bool = False,
    events: list[dict] | None = None,
    record_note: str | None = None,
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
    events : list of dict, optional
        The record's events (``{"t", "kind", "message"}``, t in s since the first
        command): its ``fault_injected`` ones are shown beside the alarms.
    record_note : str, optional
        What is wrong with the record (truncated), shown on the page.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    targets = check_outputs(out_dir, ["diagnosis.json", "report.html"], force)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    payload = diagnosis.to_dict()
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(targets["diagnosis.json"], lambda tmp: tmp.write_text(text))
    injected = [e for e in events or () if e.get("kind") == "fault_injected"]
    _page(diagnosis, payload, title, injected, record_note).save(targets["report.html"])
    return targets


def _mark_alarms(ax, diagnosis: Diagnosis, injected: list[dict]) -> None:
    for i, a in enumerate(diagnosis.alarms):
        ax.axvline(a.t_s, color="r", ls="--", lw=1, label=None if i else "alarm")
    for i, e in enumerate(injected):
        ax.axvline(e["t"], color="tab:purple", ls=":", lw=1, label=None if i else "injected")


def _page(
    diagnosis: Diagnosis, payload: dict, title: str, injected: list[dict], record_note
) -> Page:
    h = diagnosis.history
    t = h["t_s"]
    page = Page(f"Fault diagnosis — {title}")
    _verdict(page, diagnosis)
    if record_note:
        page.html(f'<p class="note">{html.escape(record_note)}.</p>')
    if not diagnosis.model_tested():
        page.html(
            '<p class="note" id="nothing-tested">No model-based test had anything to decide '
            f"on in this {diagnosis.duration_s:g}-s record: no alarm says nothing of friction, "
            "the motor, the current limit or a sensor bias.</p>"
        )
    page.heading("Alarms", "alarms-heading")
    _alarm_table(page, diagnosis, injected)
    page.heading("How it was decided", "method")
    page.text(
        f"The identified model ran beside the telemetry at Ts = {diagnosis.reference.Ts:g} s. "
        f"The detectors compare it with the healthy reference measured on the identification "
        f"record ({diagnosis.reference.source or 'see model.json'}), from the first sample on; "
        f"the thresholds were asked for {diagnosis.false_alarms_per_hour:g} false alarms "
        "per hour per detector on healthy records: the rate measured on healthy records of "
        "other units (rwlab.diagnose.calibration) where it resolves that rate, otherwise the "
        "larger of its extrapolation and the analytic threshold (block CUSUMs: Siegmund's "
        "approximation of ARL₀; frozen speed: the run-length ARL₀ of the reference's repeat "
        "probability; dropouts: Poisson counts of lost frames)."
    )
    _coverage_table(page, diagnosis)
    _threshold_table(page, diagnosis.notes)
    if diagnosis.estimates:
        page.heading("Sizes against the healthy reference", "estimates")
        page.text(
            "From the tests' latest 10 minutes, alarm or not (a fault below its threshold "
            "shows here first). Two 95 % intervals: this record's noise alone, for a trend "
            "of one wheel (rwlab diagnose FOLDER), and with the spread between healthy units "
            "added, for a reading against any healthy unit of the wheel model."
        )
        page.table(
            ["quantity", "estimate", "95 % CI, record", "95 % CI, any unit", "unit", "blocks"],
            [
                [
                    kind,
                    f"{e['magnitude']:.4g}",
                    _interval(e["ci95"]),
                    _interval(e.get("ci95_units")),
                    e["unit"],
                    e["blocks"],
                ]
                for kind, e in diagnosis.estimates.items()
            ],
            table_id="estimates-table",
        )
    page.heading("Residuals", "residuals")
    fig, axes = figure(9, 6.0, 3, 1, sharex=True)
    for ax, (name, unit) in zip(
        axes, (("speed", "rpm"), ("acceleration", "rpm/s"), ("current", "A")), strict=True
    ):
        ax.plot(t, h[name], lw=0.8, label=f"{name} residual")
        ax.set_ylabel(f"{name} [{unit}]")
        _mark_alarms(ax, diagnosis, injected)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    page.figure(
        fig,
        "fig-residuals",
        "Measured minus modelled speed and acceleration (identified model), and measured "
        "minus the reference's current balance; red dashes: alarms; purple dots: faults "
        "the record says were injected.",
    )
    _statistics_figure(page, diagnosis, injected)
    page.heading("Residual statistics")
    rows = []
    for name, stats_ in payload["residual_statistics"].items():
        for part, s in stats_.items():
            if part != "unit" and s is not None:
                rows.append([name, stats_["unit"], part.replace("_", " "), *s.values()])
    page.table(["residual", "unit", "part", "mean", "σ", "max |·|"], rows)
    return page


def _verdict(page: Page, diagnosis: Diagnosis) -> None:
    """First on the page: the faults named, each first alarm's time and test, or none."""
    first: dict[str, Alarm] = {}
    for a in sorted(diagnosis.alarms, key=lambda a: a.t_s):
        first.setdefault(a.kind, a)
    if first:
        named = "; ".join(
            f"{kind}{_size_text(a)} at {a.t_s:g} s ({a.detector} test)" for kind, a in first.items()
        )
        page.verdict(
            f"{len(diagnosis.alarms)} alarm{'s' if len(diagnosis.alarms) != 1 else ''}, "
            f"first of each fault: {named}.",
            False,
        )
    elif diagnosis.model_tested():
        page.verdict(f"No alarm in this {diagnosis.duration_s:g}-s record.", True)
    else:
        page.verdict(
            f"No alarm, but no model-based test had anything to decide on in this "
            f"{diagnosis.duration_s:g}-s record (see below).",
            False,
        )


def _size_text(alarm: Alarm) -> str:
    """`` ×2.1 (95 % CI 1.8 … 2.4)``: an alarm's size as the verdict gives it, or ``""``."""
    if alarm.magnitude is None:
        return ""
    ci = "" if alarm.ci is None else f" (95 % CI {_interval(alarm.ci)})"
    if alarm.unit == "factor":
        return f" ×{alarm.magnitude:.3g}{ci}"
    return f" {alarm.magnitude:.3g} {alarm.unit}{ci}"


def _threshold_table(page: Page, notes: list[str]) -> None:
    """How each detector's threshold was set (the diagnosis's notes, one row each)."""
    if not notes:
        return
    page.heading("How each threshold was set", "threshold-setting")
    rows = [note.split(": ", 1) if ": " in note else ["", note] for note in notes]
    page.table(["detector", "threshold"], rows, table_id="threshold-notes")


def _alarm_table(page: Page, diagnosis: Diagnosis, injected: list[dict]) -> None:
    """The alarms, and the record's injected faults among them in time order."""
    rows = [
        [
            a.t_s,
            a.kind,
            "—" if a.magnitude is None else f"{a.magnitude:.4g}",
            "—" if a.ci is None else _interval(a.ci),
            a.unit,
            a.detector,
            a.statistic,
            a.threshold,
        ]
        for a in diagnosis.alarms
    ]
    rows += [
        [float(e["t"]), f"injected: {e['message']}", "", "", "", "record event", "", ""]
        for e in injected
    ]
    if not rows:
        page.html('<p class="note" id="alarms">No alarm.</p>')
        return
    if not diagnosis.alarms:
        page.html('<p class="note">No alarm.</p>')
    page.table(
        ["t [s]", "likely fault", "size", "95 % CI", "unit", "detector", "statistic", "threshold"],
        sorted(rows, key=lambda r: r[0]),
        table_id="alarms",
    )


def _coverage_table(page: Page, diagnosis: Diagnosis) -> None:
    """What each test decided on: a test with nothing to decide on says nothing."""
    page.heading("What each test decided on", "coverage")
    page.table(
        ["test", "decided on", "unit", "verdict"],
        [
            [
                name,
                c["decided"],
                c["unit"],
                ("alarm" if any(a.detector == name for a in diagnosis.alarms) else "no alarm")
                if c["decided"]
                else f"nothing to decide on{': ' + c['why'] if c.get('why') else ''}",
            ]
            for name, c in diagnosis.coverage.items()
        ],
        table_id="coverage-table",
    )


def _statistics_figure(page: Page, diagnosis: Diagnosis, injected: list[dict]) -> None:
    """Every CUSUM test that decided on something, against its threshold."""
    h, t = diagnosis.history, diagnosis.history["t_s"]
    stats = [
        name for name in diagnosis.tested() if f"stat_{name}" in h and name in diagnosis.thresholds
    ]
    if not stats:
        page.html('<p class="note" id="fig-statistics">No CUSUM test decided on anything.</p>')
        return
    fig, axes = figure(9, 2.0 * len(stats), len(stats), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], stats, strict=True):
        ax.plot(t, h[f"stat_{name}"], lw=0.8, label=f"{name} CUSUM")
        ax.axhline(diagnosis.thresholds[name], color="k", ls=":", label="threshold")
        ax.set_yscale("symlog", linthresh=max(diagnosis.thresholds[name], 0.1))
        ax.set_ylim(bottom=0)
        ax.set_ylabel("[σ]")
        _mark_alarms(ax, diagnosis, injected)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    page.figure(
        fig,
        "fig-statistics",
        "The CUSUM statistic of every test that decided on something, against its threshold.",
    )


TREND_FORMAT = "rwlab.DiagnosisTrend/2"


def trend_point(record: str, start_utc: str, diagnosis: Diagnosis) -> dict:
    """One record's line of the trend: each fault named, its one size (its alarms'
    consistent sizes combined, :meth:`Diagnosis.sizes`) and the time it was first named;
    and the friction, torque-constant and bias estimates against the healthy reference,
    alarm or not (:meth:`rwlab.diagnose.Diagnoser.estimates`)."""
    faults: dict[str, dict] = {}
    first: dict[str, float] = {}
    for a in diagnosis.alarms:
        first.setdefault(a.kind, a.t_s)
    for kind, size in diagnosis.sizes().items():
        if size["magnitude"] is not None:
            faults[kind] = {**size, "t_s": first[kind]}
    return {
        "record": record,
        "start_utc": start_utc,
        "faults": faults,
        "estimates": {kind: dict(e) for kind, e in diagnosis.estimates.items()},
    }


def write_trend(points: list[dict], out_dir: str | os.PathLike, *, force: bool = False):
    """Write ``trend.json`` and ``trend.html``: each record's friction, torque-constant and
    bias estimates (alarm or not) and the faults named, over a wheel's records.

    Parameters
    ----------
    points : list of dict
        :func:`trend_point` of each record.
    out_dir : str or os.PathLike
        The folder.
    force : bool
        Replace existing files.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    targets = check_outputs(out_dir, ["trend.json", "trend.html"], force)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    points = sorted(points, key=lambda p: (p["start_utc"], p["record"]))
    text = json.dumps({"format": TREND_FORMAT, "records": points}, indent=2)
    atomic_write_bytes(targets["trend.json"], lambda tmp: tmp.write_text(text))
    page = Page("Fault trend")
    if not any(p["estimates"] for p in points):  # the GLR pipeline's: the faults named
        page.text(
            "Each record of the wheel diagnosed against the same healthy reference, in "
            "record order, with the faults the pipeline named and their sizes (no size is "
            "estimated below an alarm)."
        )
    else:
        page.text(
            "Each record of the wheel diagnosed against the same healthy reference, in record "
            "order: its friction and torque-constant factors and speed bias estimated from the "
            "tests' latest 10 minutes whether or not a test alarmed (slow wear below the "
            "thresholds shows here first), with 95 % intervals of the record's noise; circled "
            "red: a record in which that fault was named. The intervals leave out the "
            "reference unit's own difference from this wheel, which shifts every record alike "
            "where they run the same test signal (speeds held elsewhere weigh the unit's "
            "friction law differently)."
        )
    kinds = [k for k in ("friction", "torque_constant", "speed_sensor_bias")
             if any(k in p["estimates"] for p in points)]  # fmt: skip
    if kinds:
        fig, axes = figure(9, 2.4 * len(kinds), len(kinds), 1, sharex=True, squeeze=False)
        for ax, kind in zip(axes[:, 0], kinds, strict=True):
            _trend_axis(ax, points, kind)
        axes[-1, 0].set_xticks(
            np.arange(len(points)), [p["record"] for p in points], rotation=30, fontsize=7
        )
        page.figure(fig, "fig-trend", "Estimated size per record (95 % intervals of its noise).")
    page.table(
        ["record", "start (UTC)", *kinds, "faults named"],
        [
            [
                p["record"],
                p["start_utc"],
                *(_estimate_text(p["estimates"].get(k)) for k in kinds),
                ", ".join(f"{k} {f['magnitude']:.4g} {f['unit']}" for k, f in p["faults"].items())
                or "none",
            ]
            for p in points
        ],
        table_id="trend",
    )
    page.save(targets["trend.html"])
    return targets


def _trend_axis(ax, points: list[dict], kind: str) -> None:
    rows = [(i, p["estimates"][kind]) for i, p in enumerate(points) if kind in p["estimates"]]
    idx = np.array([i for i, _ in rows])
    mags = np.array([e["magnitude"] for _, e in rows])
    lo = np.array([e["ci95"][0] for _, e in rows])
    hi = np.array([e["ci95"][1] for _, e in rows])
    ax.errorbar(idx, mags, yerr=[mags - lo, hi - mags], fmt="o-", capsize=3)
    named = [i for i, _ in rows if kind in points[i]["faults"]]
    ax.plot(named, [mags[list(idx).index(i)] for i in named], "o", mfc="none", mec="r", ms=12)
    ax.axhline(0.0 if rows[0][1]["unit"] == "rpm" else 1.0, color="k", ls=":", lw=0.8)
    ax.set_ylabel(f"{kind} [{rows[0][1]['unit']}]")


def _interval(ci) -> str:
    """An interval's text; reports written before ``ci95_units`` have none."""
    return "" if ci is None else f"{ci[0]:.4g} … {ci[1]:.4g}"


def _estimate_text(e: dict | None) -> str:
    if e is None:
        return "—"
    return f"{e['magnitude']:.4g} [{e['ci95'][0]:.4g}, {e['ci95'][1]:.4g}] {e['unit']}"
