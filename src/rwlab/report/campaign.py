"""Campaign reports: a Monte Carlo pointing budget, and a wheel fleet's identification.

Monte Carlo figure ids: ``fig-histograms`` (per-run steady-state maximum error per
axis and total), ``fig-cdf`` (its empirical CDF against the requirement),
``fig-worst-run`` (the worst seed's time history, flown again).
Fleet: ``table-fleet``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rwlab._io import atomic_write_bytes
from rwlab.campaign.runs import AXES, Campaign, axis_errors_deg
from rwlab.report.attitude import check_outputs
from rwlab.report.html import Page, figure

__all__ = ["CAMPAIGN_FILES", "FLEET_FILES", "write_campaign", "write_fleet"]

CAMPAIGN_FILES = ["results.parquet", "budget.json", "report.html"]
FLEET_FILES = ["fleet.json", "fleet.html"]
_COLORS = {"x": "#1f77b4", "y": "#2ca02c", "z": "#d62728", "total": "#222222"}


def _write_json(path: Path, payload) -> None:
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(path, lambda tmp: tmp.write_text(text))


def _results_table(rows: list[dict], campaign: Campaign):
    """One row per run as a pyarrow table (None → null); the campaign in the metadata."""
    import pyarrow as pa

    columns = {k: pa.array([r[k] for r in rows]) for k in rows[0]}
    meta = {
        "scenario": campaign.scenario.name,
        "controller": campaign.controller,
        "duration_s": campaign.duration,
        "campaign_seed": campaign.seed,
        "dispersions": [d.__dict__ for d in campaign.dispersions],
    }
    return pa.table(columns).replace_schema_metadata({b"rwlab": json.dumps(meta).encode()})


def write_campaign(
    rows: list[dict],
    budget: dict,
    campaign: Campaign,
    worst,
    out_dir: str | os.PathLike,
    *,
    force: bool = False,
) -> dict[str, Path]:
    """Write ``results.parquet``, ``budget.json`` and ``report.html``.

    ``worst`` is the worst run's ``SimResult`` (flown again from its seed).

    Parameters
    ----------
    rows : list of dict
        One per run.
    budget : dict
        :func:`rwlab.campaign.budget.budget` of the rows.
    campaign : Campaign
        The campaign flown.
    worst : SimResult
        The worst run, flown again.
    out_dir : str or os.PathLike
        The folder.
    force : bool
        Replace existing files.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    import pyarrow.parquet as pq

    targets = check_outputs(out_dir, CAMPAIGN_FILES, force)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    table = _results_table(rows, campaign)
    atomic_write_bytes(targets["results.parquet"], lambda tmp: pq.write_table(table, tmp))
    _write_json(targets["budget.json"], budget)
    _campaign_page(rows, budget, campaign, worst).save(targets["report.html"])
    return targets


def _confidence_section(page: Page, budget: dict, req: float) -> None:
    """What the runs support, in words and a table: quantile bounds of the total error,
    the ECSS indices per axis (the verdict's share of runs is in the verdict, once)."""
    page.heading("What these runs support", "confidence")
    n = budget["campaign"]["runs"]
    total = budget["total_error"]
    words = []
    for q in total["quantiles"]:
        if q["upper_bound"] is None:
            words.append(
                f"The {q['p']:.2%} quantile of {total['column']} is estimated at "
                f"{q['estimate']:.4g}° but {n} runs cannot bound it at "
                f"{q['confidence']:.0%} confidence: that needs {q['runs_needed']} runs."
            )
        else:
            words.append(
                f"The {q['p']:.2%} quantile is ≤ {q['upper_bound']:.4g}° with "
                f"{q['confidence']:.0%} confidence (order statistic "
                f"{q['upper_bound_rank']} of {n}; estimate {q['estimate']:.4g}°)."
            )
    if budget["campaign"].get("epoch"):
        spread = budget["campaign"].get("epoch_spread_days") or 0
        words.append(
            f"Real sky from {budget['campaign']['epoch']}"
            + (f", starts spread over {spread:g} days" if spread else "")
            + f"; time in shadow per run {budget['shadow_s']['min']:.0f}–"
            f"{budget['shadow_s']['max']:.0f} s."
        )
    page.text(" ".join(words))
    rows = []
    for name, entry in budget["indices"].items():
        for a in AXES:
            if entry[a] is None:
                continue
            q = {row["p"]: row for row in entry[a]["quantiles"]}
            p = budget["requirement"]["probability"]
            worst = entry[a]["worst_runs"][0]
            rows.append(
                [
                    name,
                    a,
                    q[0.5]["estimate"],
                    q[p]["estimate"],
                    q[p]["upper_bound"],
                    entry[a]["max"],
                    f"run {worst['run']}",
                ]
            )
    conf = budget["requirement"]["confidence"]
    p = budget["requirement"]["probability"]
    page.table(
        [
            "ECSS index",
            "axis",
            "median [°]",
            f"{p:.4g} quantile [°]",
            f"its bound ({conf:.0%}) [°]",
            "max [°]",
            "set by",
        ],
        rows,
        table_id="table-ecss",
    )
    page.text(
        "ECSS-E-ST-60-10C indices over runs, each run's over the steady window: "
        + "; ".join(f"{k} {v['definition']}" for k, v in budget["indices"].items())
        + ". An empty bound: too few runs for that quantile at that confidence.",
        note=True,
    )


def _verdict_section(page: Page, budget: dict) -> None:
    """The first screen: the requirement, its statistical interpretation and the verdict."""
    req, verdict, window = budget["requirement"], budget["verdict"], budget["steady_window"]
    interp = budget["interpretation"]
    page.heading("Requirement, interpretation, verdict", "verdict")
    rows = [
        [
            "requirement",
            f"APE ≤ {req['ape_deg']:g}° on the total error for P = "
            f"{req['probability']:g}, bounds at {req['confidence']:.0%} confidence",
        ],
        ["interpretation", f"{interp['name']} (ECSS-E-ST-60-10C): {interp['statement']}"],
        ["verdict", verdict["text"]],
        [
            "set by",
            ", ".join(
                f"run {w['run']} (seed {w['seed']}): {w['value']:.4g}"
                for w in verdict["worst_runs"]
            ),
        ],
        [
            "steady window",
            f"t ≥ {window['start_s']:g} s ({window['source']}); runs start "
            f"from {window['start']}; acquired by {_at(window['acquired'])}, settled by "
            f"{_at(window['settled'])}, filter converged by {_at(window['filter_converged'])}",
        ],
    ]
    if verdict.get("rpe"):
        r = verdict["rpe"]
        rows.append(
            [
                "RPE",
                f"≤ {r['bound_deg']:g}° over {r['window_s']:g} s on every axis: "
                f"{'met' if r['met'] else 'NOT MET'}, {r['estimate']:.1%} of runs "
                f"(≥ {r['lower_bound']:.1%})",
            ]
        )
    page.table(["", "this campaign"], rows, table_id="table-verdict")
    acquired = window["runs_acquired_after_start"]
    if acquired:
        page.text(
            f"{len(acquired)} run(s) first came within the bound after the steady window's "
            f"start: runs {acquired}. Their steady statistics include acquisition; start the "
            "window later (--steady-after).",
            note=True,
        )
    filtered = window["runs_filter_converged_after_start"]
    if filtered:
        page.text(
            f"The filter of {len(filtered)} run(s) converged after the steady window's start: "
            f"runs {filtered}.",
            note=True,
        )


def _at(entry: dict) -> str:
    if entry["max_s"] is None:
        return "never"
    never = entry["never_runs"]
    tail = f"; never: runs {never}" if never else ""
    return f"{entry['max_s']:.0f} s (run {entry['run']}){tail}"


def _execution_note(page: Page, execution: dict | None) -> None:
    """How the campaign ran: runs resumed from an interrupted one, batches retried."""
    if not execution:
        return
    parts = []
    if execution.get("resumed_runs"):
        parts.append(
            f"{execution['resumed_runs']} runs were kept from an interrupted campaign and "
            "resumed (each run depends only on its seed, so the rows are those of an "
            "uninterrupted campaign)"
        )
    if execution.get("runs_flown_again"):
        parts.append(
            f"{execution['runs_flown_again']} run execution(s) were repeated after a worker "
            f"was lost: runs {execution['retried_runs']}"
        )
    if parts:
        page.html(f'<p class="note" id="execution">{"; ".join(parts)}.</p>')


def _campaign_page(rows, budget, campaign: Campaign, worst) -> Page:
    sc = campaign.scenario
    req = budget["requirement"]["ape_deg"]
    page = Page(f"Monte Carlo pointing budget — {campaign.controller} on {sc.name}")
    verdict = budget["verdict"]
    shown = True if verdict["demonstrated"] else (None if verdict["met"] else False)
    page.verdict(verdict["text"][:1].upper() + verdict["text"][1:], shown)
    page.text(
        f"{budget['campaign']['runs']} runs of {campaign.duration:g} s, campaign seed "
        f"{campaign.seed}; each "
        "run's seed is a child of numpy's SeedSequence(campaign seed), and from it alone come "
        "the run's dispersions and noise. The controller is designed on the nominal scenario "
        "and flown on the dispersed one; the filter keeps the nominal inertia (its model "
        f"error) and uses the dispersed sensor noise. Requirement ±{req:g}°."
    )
    _verdict_section(page, budget)
    _confidence_section(page, budget, req)
    _execution_note(page, budget.get("execution"))
    page.heading("Pointing budget", "budget")
    ape = budget["indices"]["APE"]
    spread = [*((a, ape[a]) for a in AXES), ("total", budget["total_error"])]
    page.table(
        ["axis", "mean [°]", "std [°]", "max [°]"],
        [[axis, s["mean"], s["std"], s["max"]] for axis, s in spread],
        table_id="table-budget",
    )
    page.text(
        "Statistics over runs of each run's steady-state maximum |error| (total: every step; "
        "axes: the logged trace, the rotation vector's components); its quantiles with their "
        "distribution-free bounds are above.",
        note=True,
    )
    page.table(
        ["maximum over runs", "value", "run", "seed"],
        [[key, p["max"], p["run"], str(p["seed"])] for key, p in budget["peaks"].items()],
        table_id="table-peaks",
    )
    data = {a: np.array([r[f"steady_max_error_{a}_deg"] for r in rows]) for a in AXES}
    data["total"] = np.array([r["steady_max_error_deg"] for r in rows])
    fig, axes = figure(10, 5.0, 2, 2)
    for ax, (name, x) in zip(np.ravel(axes), data.items(), strict=True):
        ax.hist(x, bins=max(5, min(40, len(x) // 3)), color=_COLORS[name], alpha=0.8)
        ax.set_title(f"{name}: steady max |error|", fontsize=9)
        ax.set_xlabel("[°]")
        ax.set_ylabel("runs")
        ax.grid(alpha=0.3)
    page.figure(fig, "fig-histograms", "Each run's steady-state maximum error, per axis and total.")
    fig, ax = figure(10, 3.2)
    for name, x in data.items():
        xs = np.sort(x)
        ax.step(
            xs, np.arange(1, xs.size + 1) / xs.size, where="post", color=_COLORS[name], label=name
        )
    ax.axvline(req, color="k", ls="--", lw=1, label=f"requirement ±{req:g}°")
    ax.set_xlabel("steady-state maximum |error| [°]")
    ax.set_ylabel("share of runs ≤")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    page.figure(fig, "fig-cdf", "Empirical CDF of each run's steady-state maximum error.")
    w = budget["verdict"]["worst_runs"][0]
    page.heading(f"Worst run: run {w['run']}, seed {w['seed']}", "worst")
    _worst_figure(page, worst, req)
    by_seed = {r["seed"]: r for r in rows}
    fields = [d.field for d in campaign.dispersions]
    page.table(
        ["run", "seed", "steady max error [°]", *fields],
        [
            [s["run"], str(s["seed"]), by_seed[s["seed"]]["steady_max_error_deg"]]
            + [by_seed[s["seed"]][f] for f in fields]
            for s in budget["verdict"]["worst_runs"]
        ],
        table_id="table-worst",
    )
    page.heading("Dispersions", "dispersions")
    page.table(
        ["field", "distribution", "sigma", "mean", "bounds", "relative"],
        [
            [
                d.field,
                d.distribution,
                d.sigma if d.distribution == "normal" else None,
                d.mean if d.distribution == "normal" else None,
                d.bounds,
                d.relative,
            ]
            for d in campaign.dispersions
        ],
        table_id="table-dispersions",
    )
    return page


def _worst_figure(page: Page, run, req: float) -> None:
    fig, axes = figure(10, 7.0, 3, 1, sharex=True)
    err = axis_errors_deg(run.q)
    axes[0].semilogy(run.t, np.maximum(run.error_deg, 1e-6), color="k", lw=0.8, label="total")
    axes[0].axhline(req, color="k", ls="--", lw=1)
    axes[0].set_ylabel("pointing error [°]")
    for ax in axes:
        ax.axvspan(run.steady_from_s, run.t[-1], color="#888", alpha=0.08)
    for i, a in enumerate(AXES):
        axes[1].plot(run.t, err[:, i], color=_COLORS[a], lw=0.8, label=a)
        axes[2].plot(run.t, run.torque[:, i], color=_COLORS[a], lw=0.8, label=f"τ{a}")
    axes[1].set_ylabel("error per axis [°]")
    axes[1].set_ylim(-3 * req, 3 * req)
    axes[2].set_ylabel("torque [N·m]")
    axes[2].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    page.figure(
        fig,
        "fig-worst-run",
        "The worst run flown again from its seed: pointing error (total, and per axis as the "
        "rotation vector of the attitude) and control torque; shaded: the steady-state window "
        "the budget uses.",
    )


def write_fleet(
    records: list[dict], out_dir: str | os.PathLike, *, force: bool = False
) -> dict[str, Path]:
    """Write ``fleet.json`` and ``fleet.html``: one line per record (its study or its error).

    Parameters
    ----------
    records : list of dict
        One per record: its name, study summary or error.
    out_dir, force
        As for :func:`write_campaign`.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    targets = check_outputs(out_dir, FLEET_FILES, force)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    ok = [r for r in records if r["error"] is None]
    fits = np.array([r["fit_percent"] for r in ok if r["fit_percent"] is not None], dtype=float)
    summary = {
        "records": len(records),
        "identified": len(ok),
        "fit_percent": {
            "min": float(fits.min()),
            "median": float(np.median(fits)),
            "max": float(fits.max()),
        }
        if fits.size
        else None,
        "structures": {
            s: sum(r["structure"] == s for r in ok) for s in sorted({r["structure"] for r in ok})
        },
        "per_record": records,
    }
    _write_json(targets["fleet.json"], summary)
    page = Page(f"Fleet identification — {len(records)} records")
    page.text(
        f"{len(ok)} of {len(records)} records identified, each by the same study as "
        "`rwlab identify` on one record (its folder holds report.html, study.json, model.json)."
    )
    page.table(
        ["record", "study", "delay nk", "chosen", "fit %", "error"],
        [
            [r["record"], r["study"], r["nk"], r["structure"], r["fit_percent"], r["error"]]
            for r in records
        ],
        table_id="table-fleet",
    )
    page.save(targets["fleet.html"])
    return targets
