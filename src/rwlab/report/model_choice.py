"""The identification report's first screen: which model was chosen, and why.

The verdict (the chosen model, its fit and DC gain), the choice's reason cut into its
clauses, one per line, and every candidate model in one table, the chosen one marked.
"""

from __future__ import annotations

import html

from rwlab.report.html import Page

__all__ = ["choice_section", "reason_clauses"]


def choice_section(page: Page, study: dict) -> None:
    """The verdict first, then why: the choice's reasons one per line and every candidate
    in a table (the reason is study.json's ``chosen.reason``, split, not re-worded).

    Parameters
    ----------
    page : Page
        The identification report, right after its title.
    study : dict
        study.json's content.
    """
    ch = study["chosen"]
    best = study["best_fit_percent"]
    dc = ""
    if ch.get("dc_gain") is not None:
        dc = f", DC gain {ch['dc_gain']:.4f}"
        if ch.get("dc_gain_error_percent") is not None:
            dc += f" ({ch['dc_gain_error_percent']:+.2f} % of the measured)"
    if study.get("no_model_fits"):
        page.verdict(
            f"No model fits: the best validation fit is {best:.2f} %, worse than the "
            f"validation output's mean (rwlab identify exits 1). Chosen model: "
            f"{ch['structure']}, validation fit {ch['fit_percent']:.2f} %.",
            False,
        )
    else:
        page.verdict(
            f"Chosen model: {ch['structure']}, validation fit {ch['fit_percent']:.2f} % "
            f"(best {best:.2f} %){dc}; model.json holds it for control.",
            True,
        )
    page.heading("How the model was chosen", "choice")
    items = "".join(f"<li>{html.escape(c)}</li>" for c in reason_clauses(ch["reason"]))
    page.html(f'<ul id="choice-reasons">{items}</ul>')
    rows = [
        r
        for r in study["orders"] + study["others"] + (study.get("constrained") or [])
        if r.get("fit_percent") is not None
    ]
    rows.sort(key=lambda r: -r["fit_percent"])
    table = [
        [
            r["structure"],
            r["n_params"],
            f"{r['fit_percent']:.2f}",
            f"{best - r['fit_percent']:.2f}",
            "none (a pole at 1)" if r.get("dc_gain") is None else f"{r['dc_gain']:.4f}",
            "" if r.get("dc_gain_error_percent") is None else f"{r['dc_gain_error_percent']:+.2f}",
        ]
        for r in rows
    ]
    chosen_at = next(i for i, r in enumerate(rows) if r["structure"] == ch["structure"])
    page.table(
        [
            "model",
            "parameters",
            "validation fit [%]",
            "below the best [points]",
            "DC gain",
            "DC gain − measured [%]",
        ],
        table,
        table_id="table-choice",
        highlight=chosen_at,
    )


def reason_clauses(reason: str) -> list[str]:
    """The choice's reason cut at its top-level semicolons (not those in parentheses),
    paper A's comparison kept whole, each clause capitalised.

    Parameters
    ----------
    reason : str
        study.json's ``chosen.reason``.

    Returns
    -------
    list of str
        The clauses, in order, every character of ``reason`` but the separators kept.
    """
    head, paper_sep, paper = reason.partition("; paper A's choice is not: ")
    clauses, depth, start = [], 0, 0
    for i, char in enumerate(head):
        depth += {"(": 1, ")": -1}.get(char, 0)
        if depth == 0 and head.startswith("; ", i):
            clauses.append(head[start:i])
            start = i + 2
    clauses.append(head[start:])
    if paper_sep:
        clauses.append(paper_sep[2:] + paper)
    return [c[:1].upper() + c[1:] for c in clauses if c]
