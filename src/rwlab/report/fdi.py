"""The GLR diagnosis's page: the verdict first, then the alarms, then the evidence."""

from __future__ import annotations

import html
import math
import os
from pathlib import Path

from rwlab.diagnose.pipeline import Result
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.report.html import Page

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

    Returns
    -------
    Page
        Verdict, alarm table, estimates, evidence (thresholds with their measured rates).
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
    if result.estimates:
        page.heading("Estimates", "estimates")
        page.text(
            "Each fault's size over the record's last 5 minutes against the reference, alarm "
            "or not (a wheel's records side by side show wear below the thresholds); each "
            "presumes its fault alone, so after an alarm only the faults named are given. The "
            "intervals are the record's noise: a unit's own offset from the reference moves "
            "every record of it alike."
        )
        page.table(
            ["fault", "size", "95 % interval", "unit", "ln LR over healthy"],
            [
                [name, f.size, _interval(f.ci95), f.unit, f.log_lr]
                for name, f in result.estimates.items()
            ],
            table_id="estimates",
        )
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
