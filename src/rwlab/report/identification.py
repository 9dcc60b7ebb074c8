"""The identification report: paper A's tables and figures for one study.

Figure ids follow the paper: ``fig16-delay``, ``fig17-orders``, ``fig18-steps``,
``fig19-resid``, ``fig20-compare``, ``fig21-resid-armax``, ``fig22-compare-armax``,
``fig-oe-bj``, ``fig23-continuous``, ``fig24-acceleration``; tables ``table2-orders``
and ``table3-others``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from rwlab._io import atomic_write_bytes
from rwlab.ident.model_file import WheelModelFile
from rwlab.ident.study import StudyResult
from rwlab.report.html import Page
from rwlab.report.model_choice import choice_section
from rwlab.report.study_figures import (
    NONLINEAR_FIGURES,
    SIGMAS,
    armax_name,
    linear_plots,
    nonlinear_plots,
    step_level,
)

__all__ = ["FIGURES", "write_study"]


FIGURES = (
    "fig16-delay",
    "fig17-orders",
    "fig18-steps",
    "fig19-resid",
    "fig20-compare",
    "fig21-resid-armax",
    "fig22-compare-armax",
    "fig-oe-bj",
    "fig23-continuous",
    "fig24-acceleration",
    "fig-uncertainty",
)


def _poly(row: dict, letter: str) -> str:
    coeffs = row[letter]
    std = row.get("std") or {}
    out = []
    for i, c in enumerate(coeffs):
        if i == 0 and letter != "B":
            out.append("1")
            continue
        if c == 0 and letter == "B":
            continue
        s = std.get(f"{letter.lower()}{i}")
        pm = f" (±{s:.2g})" if s is not None else ""
        out.append(f"{c:+.4g}{pm} q⁻{i}" if i else f"{c:+.4g}{pm}")
    return " ".join(out)


def _resid_caption(res: dict, name: str) -> str:
    verdict = (
        "white" if res["white"] else "not white"
    ) + f" (Ljung–Box p = {res['whiteness_p']:.3g})"
    return (
        f"Residuals of {name} on validation data with "
        f"{res['confidence']:.0%} bounds: {verdict}; independence p = "
        f"{res['independence_p']:.3g}."
    )


def _minus(name: str, offset: float) -> str:
    """``name − offset`` with the sign folded in: never "x − -4772"."""
    if offset == 0:
        return name
    return f"{name} {'−' if offset > 0 else '+'} {abs(offset):.4g}"


def write_study(
    result: StudyResult,
    model_info: dict | WheelModelFile,
    out_dir: str | os.PathLike,
    *,
    force: bool = False,
    drawn: dict[str, bytes] | None = None,
) -> dict[str, Path]:
    """Write ``report.html``, ``study.json`` and ``model.json`` into ``out_dir``.

    Parameters
    ----------
    result : StudyResult
        The study.
    model_info : WheelModelFile or dict
        ``model.json``'s content.
    out_dir : str or os.PathLike
        The folder.
    force : bool
        Replace existing files.
    drawn : dict of str to bytes, optional
        The figures of the linear study, drawn already (:class:`~rwlab.report.html.FigureQueue`); by
        default drawn here.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    if isinstance(model_info, WheelModelFile):
        model_info = model_info.to_dict()
    out = Path(out_dir)
    targets = {name: out / name for name in ("report.html", "study.json", "model.json")}
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} exist; pass force=True to overwrite them")
    out.mkdir(parents=True, exist_ok=True)
    study = result.to_dict()
    study["model_file"] = "model.json"
    for name, payload in (("study.json", study), ("model.json", model_info)):
        text = json.dumps(payload, indent=2)

        def write(tmp: Path, text: str = text) -> None:
            tmp.write_text(text)

        atomic_write_bytes(targets[name], write)
    _page(result, study, model_info, drawn).save(targets["report.html"])
    return targets


def _reference_text(model_info: dict) -> str:
    """Whether model.json carries a healthy reference for ``rwlab diagnose``."""
    ref = model_info.get("healthy_reference")
    if not ref:
        return (
            "model.json holds no healthy reference: rwlab diagnose cannot use this model "
            "(it measures one only on a testbed record, .mcap, with motor current)."
        )
    return (
        f"model.json also holds the healthy reference for fault diagnosis, measured on this "
        f"record ({ref.get('samples', '?')} samples): the current balance, each test's "
        "healthy statistics and the repeat and frame-loss rates that rwlab diagnose and "
        "rwlab experiment --model compare records with."
    )


def _page(
    result: StudyResult, study: dict, model_info: dict, drawn: dict[str, bytes] | None
) -> Page:
    d = study["data"]
    figs = linear_plots(result, study) if drawn is None else drawn
    page = Page(f"Identification study — {d['name'] or 'record'}")
    choice_section(page, study)
    page.heading("The record", "record")
    page.text(
        f"Record: {d['N']} samples at Ts = {d['Ts']:g} s "
        f"(input {d['input']}, output {d['output']}), preprocessed: {d['preprocess']}; "
        f"estimation {d['n_estimation']} samples, validation {d['n_validation']} samples. "
        "Fit % is the NRMSE fit of the simulated output on the validation data "
        "(MATLAB compare's measure), in preprocessed units, as paper A reports it, with "
        "'steady' initial conditions (every signal held its first value), not compare's "
        "default of an initial state fitted to the validation output."
    )
    if study.get("segments"):
        parts = ", ".join(f"{a:.2f}–{b:.2f} s" for a, b in study["segments"])
        page.text(
            f"The record has telemetry gaps: it was split into {len(study['segments'])} "
            f"gap-free segments ({parts}), identified as separate experiments merged "
            "(MATLAB merge(iddata)): every segment's estimation part enters one estimate, "
            "no regressor crosses a gap; the delay scan, the validation and the nonlinear "
            "stage use the longest piece of their part. The samples in the gaps are not used.",
            note=True,
        )
    ch = study["chosen"]
    note = (study.get("parts") or {}).get("note")
    if note:
        page.text(f"Estimation and validation parts differ: {note}.", note=True)
    for line in _nonlinear_notes(study.get("nonlinear") or {}, study.get("wheel_stages")):
        page.text(line, note=True)
    page.text(_reference_text(model_info), note=True)

    steady = study.get("steady_state_gain")
    if steady:
        page.html(
            f"<p>Steady-state gain measured on the record: {steady['gain']:.4f} "
            f"({steady['holds']} settled holds of at least {steady['min_hold_s']:g} s, the "
            f"output averaged over the last {steady['tail_s']:g} s of each). The DC gain "
            "columns give each model's static gain in physical units and its error "
            "against it.</p>"
        )
    anchor = study.get("gain_constraint")
    if anchor:
        page.html(
            f"<p>Gain-constrained models (+K, section 4b): static gain constrained to "
            f"K = {anchor['gain']:.4f} ± {anchor['gain_std']:.4f} measured on "
            f"{anchor['holds']} settled holds of the estimation part only (the validation "
            "part does not inform them). Their DC gain equals K by construction; its "
            "agreement with the whole record's gain is no test of the dynamics.</p>"
        )
    else:
        page.text(
            "No gain-constrained models (+K): the estimation part has fewer than 3 settled "
            "holds at two or more levels to measure the static gain on.",
            note=True,
        )

    page.heading("1. Input delay (paper Fig. 16)", "delay")
    nk = study["delay"]["nk"]
    page.figure(
        figs["fig16-delay"],
        "fig16-delay",
        f"Loss of ARX(2,2,nk) per delay; minimum at nk = {nk} ({nk * d['Ts']:g} s).",
    )

    page.heading("2. ARX orders (paper Table 2, Fig. 17, Fig. 18)", "orders")
    rows = study["orders"]
    page.table(
        ["model", "fit %", "MSE", "FPE", "DC gain", "A(q)", "B(q)"],
        [
            [
                r["structure"],
                r["fit_percent"],
                r["mse"],
                r["fpe"],
                _dc(r),
                _poly(r, "A"),
                _poly(r, "B"),
            ]
            for r in rows
        ],
        table_id="table2-orders",
        highlight=next((i for i, r in enumerate(rows) if r["structure"] == ch["structure"]), None),
    )
    page.figure(figs["fig17-orders"], "fig17-orders", "Validation error per ARX order.")
    page.figure(figs["fig18-steps"], "fig18-steps", "Unit-step responses of the ARX models.")

    page.heading("3. Validation of the chosen model (paper Fig. 19, Fig. 20)", "validation")
    res = study["residuals"][ch["structure"]]
    page.figure(figs["fig19-resid"], "fig19-resid", _resid_caption(res, ch["structure"]))
    page.figure(
        figs["fig20-compare"],
        "fig20-compare",
        f"Simulated vs measured output of {ch['structure']} on validation data.",
    )
    if "fig-uncertainty" in figs:
        page.figure(figs["fig-uncertainty"], "fig-uncertainty", _uncertainty_caption(ch))
    else:
        page.text(f"{ch['structure']} has no parameter covariance: no confidence bands.", note=True)

    page.heading("4. ARMAX, OE and BJ (paper Table 3, Fig. 21, Fig. 22)", "others")
    others = study["others"]
    page.table(
        ["model", "fit %", "MSE", "DC gain", "stable", "A", "B", "C", "D", "F"],
        [
            [
                r["structure"],
                r["fit_percent"],
                r["mse"],
                _dc(r),
                r["stable"],
                _poly(r, "A"),
                _poly(r, "B"),
                _poly(r, "C"),
                _poly(r, "D"),
                _poly(r, "F"),
            ]
            for r in others
        ],
        table_id="table3-others",
    )
    armax = armax_name(study)
    if armax is not None:
        res = study["residuals"][armax]
        page.figure(figs["fig21-resid-armax"], "fig21-resid-armax", _resid_caption(res, armax))
        page.figure(
            figs["fig22-compare-armax"],
            "fig22-compare-armax",
            f"Simulated vs measured output of {armax} on validation data.",
        )
    else:
        page.text("ARMAX(2,2,1) could not be estimated from these data.", note=True)
    page.figure(figs["fig-oe-bj"], "fig-oe-bj", "All prediction-error models on validation data.")

    _constrained_section(page, study)

    page.heading("5. Continuous-time model (paper eq. 14, Fig. 23)", "continuous")
    cont = study["continuous"]
    lines = []
    for method, info in cont["methods"].items():
        if "error" in info:
            lines.append([method, info["error"], "", ""])
        else:
            lines.append(
                [
                    method,
                    _tf_text(info["num"], info["den"]),
                    info["fit_to_discrete_percent"],
                    info["max_abs_difference"],
                ]
            )
    page.table(
        ["method", "G(s)", "fit to discrete %", "max |difference|"],
        lines,
        table_id="table-continuous",
    )
    page.text(
        f"Converted with the record's real sample time Ts = {d['Ts']:g} s (paper A's "
        "eq. 14 used MATLAB's default Ts = 1 s by mistake). Each continuous model is driven "
        "by the held input exactly (discretized by ZOH at Ts), so the ZOH conversion "
        "returns the discrete model to round-off (a fractional delay: to its Padé "
        "approximation) and Tustin's difference is its frequency warping."
    )
    page.figure(
        figs["fig23-continuous"],
        "fig23-continuous",
        "Discrete and continuous models driven by a new piecewise-constant input.",
    )

    page.heading("6. Acceleration check (paper Fig. 24)", "acceleration")
    acc = study["acceleration"]
    page.figure(
        figs["fig24-acceleration"],
        "fig24-acceleration",
        f"Speed change per second, model vs measured: correlation {acc['correlation']:.3f}.",
    )

    page.heading("7. The model for control (model.json)", "model")
    sat = model_info["saturation"]
    u_off, y_off = model_info["input"]["offset"], model_info["output"]["offset"]
    page.text(
        f"{model_info['structure']} in physical units: {_minus('output', y_off)} "
        f"= B/(A F)·({_minus('input', u_off)}), Ts = {model_info['Ts']:g} s. "
        f"Wrap it with a speed-command saturation of ±{sat['speed_rpm']:g} rpm and an "
        f"acceleration limit of ±{sat['accel_rpm_s']:g} rpm/s ({sat['source']}): the wheel "
        "is linear only inside them (paper A, section 5)."
    )
    if result.servo is not None:
        ids = NONLINEAR_FIGURES
        nl_figs = {i: figs[i] for i in ids} if set(ids) <= set(figs) else nonlinear_plots(result)
        _nonlinear_section(page, result, study["nonlinear"], nl_figs)
    return page


def _nonlinear_section(page: Page, result: StudyResult, nl: dict, figs: dict) -> None:
    """Beyond the paper: the servo model next to the chosen linear one, in physical units
    (``figs``: :data:`NONLINEAR_FIGURES` by id, figures or their PNG bytes)."""
    servo, val = result.servo, result.physical_val
    if servo is None or val is None:  # the caller checked: a study with a servo model has both
        raise ValueError("the nonlinear section needs the study's servo model and data")
    ch = result.chosen_name
    page.heading("8. Nonlinear model: rate-limited servo (beyond the paper)", "nonlinear")
    par = nl["parameters"]
    page.text(
        f"A feedback block model (rwlab.ident.nonlinear): input saturation, gain "
        f"{par['gain']:.4g}, PI law kp = {par['kp']:.4g} s⁻¹, ki = {par['ki']:.4g} s⁻², "
        f"rate limit α = {nl['accel_limit_rpm_s']:.4g} (output unit)/s, input delay "
        f"{par['delay'] * 1e3:.0f} ms, fitted by simulation error from {ch}. Validation fit "
        f"{nl['fit_percent']:.2f} % against {ch}'s {_study_fit(result):.2f} %. The speed limit "
        f"is {nl['speed_limit_note']}."
    )
    page.figure(
        figs["fig-nonlinear-validation"],
        "fig-nonlinear-validation",
        "Both models on the validation data (simulation).",
    )
    page.figure(
        figs["fig-nonlinear-step"],
        "fig-nonlinear-step",
        f"A step of {step_level(val):.4g} from rest: the linear model jumps, the servo ramps "
        "at its estimated rate limit and settles.",
    )
    name = "servo (simulation error)"
    page.figure(figs["fig-nonlinear-resid"], "fig-nonlinear-resid",
                _resid_caption(nl["residuals"], name))  # fmt: skip


def _nonlinear_notes(nl: dict, stages: dict | None) -> list[str]:
    """One line per nonlinear model beyond the servo: its fit, or why it failed; and the
    wheel-specific stages left out of a record that is not a wheel's."""
    lines = []
    if stages is not None and not stages["run"]:
        lines.append(f"Wheel models (servo, grey box): none, {stages['why']}.")
    for name in ("greybox", "nlarx"):
        row = nl.get(name) or {}
        if row.get("fit_percent") is not None:
            lines.append(f"Nonlinear {name}: validation fit {row['fit_percent']:.2f} %.")
        elif row.get("failed") or row.get("error"):
            lines.append(f"Nonlinear {name}: failed, {row.get('failed') or row.get('error')}.")
    if nl.get("not_fitted"):
        lines.append(f"Nonlinear grey box and NLARX: {nl['not_fitted']}.")
    return lines


def _constrained_section(page: Page, study: dict) -> None:
    """Section 4b: every gain-constrained model next to its unconstrained twin."""
    fixed = study.get("constrained") or []
    if not fixed:
        return
    page.heading("4b. Static gain imposed (beyond the paper)", "constrained")
    free = {r["structure"]: r for r in study["orders"] + study["others"]}
    lines = []
    for r in fixed:
        twin = free.get(r["structure"].removesuffix("+K"), {})
        lines.append([r["structure"], r["fit_percent"], _dc(r), twin.get("fit_percent"), _dc(twin)])
    page.table(
        ["model", "fit %", "DC gain", "unconstrained fit %", "unconstrained DC gain"],
        lines,
        table_id="table-constrained",
        highlight=next(
            (i for i, r in enumerate(fixed) if r["structure"] == study["chosen"]["structure"]),
            None,
        ),
    )
    page.text(
        "A linear model fitted to a wheel that sometimes runs at its rate or current limit "
        "underestimates the static gain; the speed loop's integral action makes the true "
        "one 1. The +K models are the same structures estimated with B(1) = K·A(1)·F(1) "
        "imposed (equality-constrained least squares for ARX, the prediction-error search "
        "on the remaining parameters for the others)."
    )


def _dc(row: dict) -> str:
    """A row's DC gain (physical units) and its error against the measured gain."""
    if row.get("dc_gain") is None:
        return "—"
    err = row.get("dc_gain_error_percent")
    return f"{row['dc_gain']:.4f}" + ("" if err is None else f" ({err:+.1f} %)")


def _study_fit(result: StudyResult) -> float:
    return next(r["fit_percent"] for r in result.rows if r["structure"] == result.chosen_name)


def _tf_text(num, den) -> str:
    def poly(c):
        n = len(c) - 1
        terms = [
            f"{v:+.4g}" + (f" s^{n - i}" if n - i > 1 else (" s" if n - i == 1 else ""))
            for i, v in enumerate(c)
            if abs(v) > 1e-14
        ]
        return " ".join(terms) or "0"

    return f"({poly(num)}) / ({poly(den)})"


def _uncertainty_caption(chosen: dict) -> str:
    return (
        f"Step response and Bode magnitude of {chosen['structure']} with ±{SIGMAS:g}σ bands "
        "from its parameter covariance (first-order propagation, rwlab.ident.uncertainty)."
    )
