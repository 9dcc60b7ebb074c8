"""The GLR diagnosis's page: the verdict first, then the alarms, then the evidence."""

from __future__ import annotations

import html
import math
import os
from pathlib import Path

from rwlab.diagnose.features import Features
from rwlab.diagnose.pipeline import Result
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.report.html import Page, figure

__all__ = ["fdi_page"]


def _interval(ci: tuple[float, float]) -> str:
    return "" if math.isnan(ci[0]) else f"[{ci[0]:.4g}, {ci[1]:.4g}]"


def fdi_page(
    result: Result,
    calibration: DiagnosisCalibration,
    calibration_path: str | os.PathLike,
    *,
    title: str,
    record_note: str | None = None,
    features: Features | None = None,
) -> Page:
    """The page a lab engineer reads in ten seconds.

    Parameters
    ----------
    result : Result
        What :func:`rwlab.diagnose.pipeline.run` found.
    calibration : DiagnosisCalibration
        The calibration it ran with.
    calibration_path : path-like
        Its file (linked from the provenance line).
    title : str
    record_note : str, optional
        What is wrong with the record (truncated, salvaged), shown under the verdict.
    features : Features, optional
        The record's features: the residuals and each detector's statistic are plotted.

    Returns
    -------
    Page
        Verdict, alarm table, the residuals and statistics (with ``features``), evidence
        (thresholds with their measured rates).
    """
    page = Page(title)
    page.heading("Verdict", "verdict")
    page.html(f'<p class="verdict"><strong>{html.escape(result.verdict())}</strong></p>')
    if record_note:
        page.html(f'<p class="note">{html.escape(record_note)}</p>')
    link = Path(calibration_path).resolve().as_uri()
    provenance = (
        f"Calibrated on {calibration.records} healthy records, {calibration.hours:.3g} h"
        + (f" ({calibration.origin})" if calibration.origin else "")
    )
    page.html(f'<p class="note">{html.escape(provenance)}: <a href="{link}">details</a></p>')
    page.heading("Alarms", "alarms")
    if result.events:
        rows = []
        for e in result.events:
            f = e.fit
            rows.append(
                [
                    e.t_s,
                    f.fault,
                    None if math.isnan(f.size) else f.size,
                    _interval(f.ci95),
                    f.unit,
                    e.onset_s,
                    e.runner_up,
                    e.runner_up_log_lr,
                    ", ".join(f"{was} until {t:g} s" for t, was in e.relabelled),
                    "yes" if result.confirmed(e) else "no",
                ]
            )
        page.table(
            [
                "alarm s",
                "fault",
                "size",
                "95 % interval",
                "unit",
                "onset s",
                "runner-up",
                "ln LR over runner-up",
                "re-labelled from",
                "confirmed at the end",
            ],
            rows,
            table_id="alarms",
        )
    else:
        page.text("No alarm.")
    if features is not None:
        _residuals_figure(page, result, features)
    page.heading("Evidence", "evidence")
    page.text(
        f"Each detector's threshold on its log-likelihood ratio for "
        f"{result.per_hour:g} false alarms per hour, and the rate counted at it on the "
        "calibration's healthy records (Garwood 95 % interval); an extrapolated threshold "
        "lies beyond what those hours resolve."
    )
    page.table(
        ["detector", "threshold (ln LR)", "measured /h", "95 % interval /h", "extrapolated"],
        [
            [name, t.log_lr, t.measured_per_hour, _interval(t.ci95_per_hour), t.extrapolated]
            for name, t in result.thresholds.items()
        ],
        table_id="thresholds",
    )
    return page


def _residuals_figure(page: Page, result: Result, features: Features) -> None:
    """The three residual channels and each detector's statistic over its threshold."""
    f = features
    fig, axes = figure(9, 8.0, 4, 1, sharex=True)
    channels = (
        (f.speed_residual_rpm, "speed [rpm]"),
        (f.accel_residual_rpm_s, "acceleration [rpm/s]"),
        (f.current_residual_a, "current [A]"),
    )
    for ax, (values, label) in zip(axes, channels, strict=False):
        ax.plot(f.t_s, values, lw=0.6)
        ax.set_ylabel(label, fontsize=8)
    for name, points in result.statistics.items():
        t, log_lr = zip(*points, strict=True)
        ratio = [max(v / result.thresholds[name].log_lr, 0.01) for v in log_lr]
        axes[3].semilogy(t, ratio, lw=0.8, label=name)
    axes[3].axhline(1.0, color="k", ls=":", lw=0.8)
    axes[3].set_ylim(bottom=0.01)
    axes[3].set_ylabel("log-LR / threshold", fontsize=8)
    axes[3].legend(loc="upper left", fontsize=7, ncol=2)
    for ax in axes:
        for e in result.events:
            ax.axvline(e.t_s, color="r", ls="--", lw=0.8)
    axes[-1].set_xlabel("time [s]")
    page.figure(
        fig,
        "fig-residuals",
        "Measured minus modelled speed and acceleration (the identified model and its loop's "
        "demand) and measured minus the reference's current balance; below, each detector's "
        "statistic over its threshold at each decision (a fault named is followed, no longer "
        "tested); red dashes: alarms.",
    )
