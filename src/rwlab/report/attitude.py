"""The attitude-control report: paper B's figures for LQR, LQG and LQG/LTR.

Figure ids: ``fig1-7-quaternions-lqr-lqg``, ``fig1-7-rates-lqr-lqg``,
``fig9-15-quaternions``, ``fig9-15-rates``, ``fig16-18-torques``,
``fig-wheel-speeds``, ``fig8-sigma`` (LTR study), and ``fig-identified-wheel``
when the identified wheel model was flown (``fig-pointing`` otherwise).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rwlab._io import atomic_write_bytes
from rwlab.attitude.control import Comparison
from rwlab.attitude.design import LTRResult
from rwlab.report.html import Page, figure, signed, trace_styles

__all__ = ["write_comparison", "write_ltr"]

LABELS = {
    "lqr": "LQR (true state)",
    "lqg": "LQG (MEKF)",
    "lqg_ltr": "LQG/LTR",
    "lqg_identified_wheel": "LQG, identified wheel",
}
COLORS = {
    "lqr": "#1f77b4",
    "lqg": "#d62728",
    "lqg_ltr": "#2ca02c",
    "lqg_identified_wheel": "#9467bd",
}


def check_outputs(out: str | os.PathLike, names: list[str], force: bool) -> dict[str, Path]:
    """The output paths; refuses existing ones without ``force`` (call before a long run)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    targets = {n: out / n for n in names}
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} exist; pass force=True to overwrite them")
    return targets


def _check_out(out: Path, names: list[str], force: bool) -> dict[str, Path]:
    targets = check_outputs(out, names, force)
    out.mkdir(parents=True, exist_ok=True)
    return targets


def _write_json(path: Path, payload) -> None:
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(path, lambda tmp: tmp.write_text(text))


def _grid(page: Page, runs: dict, keys: list[str], series, ylabels, fig_id: str, caption: str):
    fig, axes = figure(10, 1.9 * len(ylabels), len(ylabels), 1, sharex=True)
    axes = np.atleast_1d(axes)
    for name, style in zip(keys, trace_styles(len(keys)), strict=True):
        r = runs[name]
        data = series(r)
        for i, ax in enumerate(axes):
            ax.plot(r.t, data[:, i], color=COLORS[name], label=LABELS[name], **style)
    for ax, label in zip(axes, ylabels, strict=True):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.ticklabel_format(axis="y", useOffset=False)
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    page.figure(fig, fig_id, caption)


def write_comparison(
    comp: Comparison,
    out_dir: str | os.PathLike,
    *,
    force: bool = False,
    ltr_result: LTRResult | None = None,
) -> dict[str, Path]:
    """Write ``report.html`` and ``metrics.json`` (and ``sigma.json`` with an LTR result).

    Parameters
    ----------
    comp : Comparison
        The runs and metrics.
    out_dir : str or os.PathLike
        The folder.
    force : bool
        Replace existing files.
    ltr_result : LTRResult, optional
        Adds ``sigma.json`` and the σ plot.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    names = ["report.html", "metrics.json"] + (["sigma.json"] if ltr_result else [])
    targets = _check_out(Path(out_dir), names, force)
    payload = {
        **comp.metrics,
        "scenario": comp.scenario.name,
        "rho": comp.rho,
        "requirement_deg": comp.scenario.control.pointing_requirement_deg,
        "config": comp.config,
    }
    if "lqg_identified_wheel" in comp.metrics:
        ideal = comp.metrics["lqg"]["steady_rms_error_deg"]
        real = comp.metrics["lqg_identified_wheel"]["steady_rms_error_deg"]
        payload["identified_wheel_lag_cost_deg"] = real - ideal
    _write_json(targets["metrics.json"], payload)
    if ltr_result is not None:
        _write_json(targets["sigma.json"], ltr_result.to_dict())
    _comparison_page(comp, payload, ltr_result).save(targets["report.html"])
    return targets


POINTING_ORDER = ("lqr", "lqg_ltr", "lqg", "lqg_identified_wheel")
"""The runs in drawing order: the last, the identified wheel where flown, on top."""


def _verdict(page: Page, metrics: dict, req: float) -> None:
    """First on the page: which runs meet the requirement, with each steady maximum."""
    failed = [LABELS[n] for n, m in metrics.items() if not m["meets_requirement"]]
    maxima = ", ".join(f"{LABELS[n]} {m['steady_max_error_deg']:.3g}°" for n, m in metrics.items())
    if failed:
        head = f"{', '.join(failed)} do{'es' if len(failed) == 1 else ''} NOT meet ±{req:g}°"
    else:
        head = f"Every run meets the ±{req:g}° requirement"
    page.verdict(f"{head}. Steady-state maximum pointing error: {maxima}.", not failed)


def _identified_wheel_note(page: Page, metrics: dict, payload: dict, req: float) -> None:
    """What flying the identified wheel model instead of an ideal torque source cost."""
    if "identified_wheel_lag_cost_deg" not in payload:
        return
    m = metrics["lqg_identified_wheel"]
    ideal = metrics["lqg"]["steady_rms_error_deg"]
    cost = payload["identified_wheel_lag_cost_deg"]
    verdict = "within" if m["meets_requirement"] else "outside"
    share = f" ({signed(100 * cost / ideal, 2)} %)" if ideal else ""
    page.text(
        f"With the identified wheel model as the actuator (LQG), the loop stays stable, "
        f"{verdict} the ±{req:g}° requirement (steady max "
        f"{m['steady_max_error_deg']:.3g}°). The wheel's lag costs {signed(cost)}°{share} "
        f"of steady RMS pointing error compared with an ideal torque source "
        f"({ideal:.3g}°).",
        note=True,
    )


def _forced_note(page: Page, forced) -> None:
    """First on the page: the wheels were flown although they cannot deliver what the
    scenario needs (``--force``)."""
    if forced:
        page.text(
            "The wheel model cannot deliver what this scenario needs; it was flown "
            "anyway (--force-wheel). " + " ".join(forced),
            note=True,
        )


def _comparison_page(comp: Comparison, payload: dict, ltr_result) -> Page:
    sc = comp.scenario
    req = sc.control.pointing_requirement_deg
    page = Page(f"Attitude control — LQR vs LQG vs LQG/LTR ({sc.name})")
    _verdict(page, comp.metrics, req)
    _forced_note(page, comp.config.get("wheel_forced"))
    _identified_wheel_note(page, comp.metrics, payload, req)
    page.text(
        f"Scenario {sc.name}: inertia {sc.spacecraft.inertia} kg·m², {sc.n_wheels} wheels "
        f"({sc.wheels.wheel_spec.name}, {sc.wheels.model}, ±{sc.wheels.max_torque:g} N·m, "
        f"{sc.wheels.max_momentum:.3g} N·m·s), "
        f"sun sensor {sc.sensors.sun_noise_deg:g}°, earth sensor "
        f"{sc.sensors.earth_noise_deg:g}° (1σ; the filter assumes ×{sc.filter.noise_margin:g}), "
        f"initial error {sc.run.initial_error_deg:g}°, "
        f"control period {sc.run.dt:g} s, sensors every {sc.sensors.period:g} s. Every controller "
        "sees the same process noise, sensor noise and initial estimate (one random stream "
        f"per source). SRP, tides and J2 are "
        f"{'known' if sc.filter.disturbances_known else 'unknown'} to the filter. "
        f"Requirement: ±{req:g}°."
    )
    columns = {
        "steady_max_error_deg": "max error [°]",
        "steady_rms_error_deg": "RMS error [°]",
        "settling_time_s": f"settling to {req:g}° [s]",
        "torque_saturated_fraction": "torque-saturated share",
        "torque_peak_Nm": "peak torque [N·m]",
        "torque_rms_Nm": "RMS torque [N·m]",
        "crossover_rad_s": "crossover [rad/s]",
        "wheel_momentum_peak_fraction": "peak momentum / limit",
        "meets_requirement": f"meets ±{req:g}°",
    }
    rows = [[LABELS[name]] + [_cell(m[k]) for k in columns] for name, m in comp.metrics.items()]
    page.heading("Metrics (every step; steady state after the first half, at most 1 h)", "metrics")
    page.table(["controller", *columns.values()], rows, table_id="table-metrics")
    runs = comp.runs
    q_label = ["q1", "q2", "q3", "q4"]
    w_label = ["ωx [rad/s]", "ωy [rad/s]", "ωz [rad/s]"]
    page.heading("LQR vs LQG (paper Fig. 1–7)", "lqr-lqg")
    _grid(
        page,
        runs,
        ["lqr", "lqg"],
        lambda r: r.q,
        q_label,
        "fig1-7-quaternions-lqr-lqg",
        "Attitude quaternion (body relative to the orbital frame), LQR vs LQG.",
    )
    _grid(
        page,
        runs,
        ["lqr", "lqg"],
        lambda r: r.w_bo,
        w_label,
        "fig1-7-rates-lqr-lqg",
        "Body rate relative to the orbital frame, LQR vs LQG.",
    )
    page.heading("LQR, LQG and LQG/LTR (paper Fig. 9–18)", "all")
    keys = [k for k in ("lqr", "lqg", "lqg_ltr") if k in runs]
    _grid(page, runs, keys, lambda r: r.q, q_label, "fig9-15-quaternions", "Quaternions.")
    _grid(page, runs, keys, lambda r: r.w_bo, w_label, "fig9-15-rates", "Body rates.")
    _grid(
        page,
        runs,
        keys,
        lambda r: r.torque,
        ["τx [N·m]", "τy [N·m]", "τz [N·m]"],
        "fig16-18-torques",
        "Control torque per axis (the noise of the estimate shows here).",
    )
    _grid(
        page,
        runs,
        keys,
        lambda r: r.wheel_speed_rpm[:, :3],
        [f"wheel {i + 1} [rpm]" for i in range(3)],
        "fig-wheel-speeds",
        "Wheel speeds.",
    )
    fig, ax = figure(10, 3.0)
    order = [k for k in POINTING_ORDER if k in runs]
    for name, style in zip(order, trace_styles(len(order)), strict=True):
        r = runs[name]
        ax.semilogy(
            r.t, np.maximum(r.error_deg, 1e-6), color=COLORS[name], label=LABELS[name], **style
        )
    ax.axhline(req, color="k", ls="--", lw=1, label=f"±{req:g}° requirement")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("pointing error [°]")
    ax.legend(fontsize=8, loc="upper right", ncol=3)
    fig_id = "fig-identified-wheel" if "lqg_identified_wheel" in runs else "fig-pointing"
    page.figure(fig, fig_id, f"Pointing error of every run against the ±{req:g}° requirement.")
    if ltr_result is not None:
        page.heading("Loop transfer recovery (paper Fig. 8)", "ltr")
        _sigma_figure(page, ltr_result)
    return page


def ltr_rows(res: LTRResult) -> list[list]:
    """Per ρ: the gap over paper B's band, the gap up to the target's crossover, and the
    recovered loop's crossover next to the target's (rad/s)."""
    from rwlab.attitude.control import GAP_BAND, crossover

    w_c = crossover(res.target, res.omega)
    return [
        [
            f"{rho:g}",
            round(res.max_gap(rho, GAP_BAND), 2),
            round(res.max_gap(rho, (GAP_BAND[0], w_c)), 2),
            round(crossover(res.loops[rho], res.omega), 4),
            round(w_c, 4),
        ]
        for rho in res.loops
    ]


LTR_COLUMNS = [
    "ρ",
    "max gap 1e-3..1e-1 rad/s [dB]",
    "max gap 1e-3 rad/s..target crossover [dB]",
    "crossover [rad/s]",
    "LQR crossover [rad/s]",
]


def _sigma_figure(page: Page, res: LTRResult) -> None:
    rhos = list(res.loops)
    cols = 2
    rows = (len(rhos) + 1) // 2
    keep = res.omega <= res.omega.max() / 2  # the hold's zero at z = −1 owns the last octave
    w = res.omega[keep]
    fig, axes = figure(10, 3.0 * rows, rows, cols, sharex=True, sharey=True)
    for ax, rho in zip(np.ravel(axes), rhos, strict=False):
        for k in range(min(2, res.target.shape[1])):
            ax.semilogx(
                w,
                20 * np.log10(res.target[keep, k]),
                color="k",
                lw=1.2,
                label="LQR target" if k == 0 else None,
            )
            ax.semilogx(
                w,
                20 * np.log10(res.loops[rho][keep, k]),
                color="#d62728",
                lw=1,
                ls="--",
                label="LQG/LTR" if k == 0 else None,
            )
        ax.axhline(0, color="#888", lw=0.8)
        ax.axvspan(1e-3, 1e-1, color="#1f77b4", alpha=0.06)
        ax.set_ylim(-80, 120)
        ax.set_title(f"ρ = {rho:g}")
        ax.set_ylabel("σ [dB]")
        ax.grid(alpha=0.3, which="both")
    np.ravel(axes)[0].legend(fontsize=8)
    for ax in np.ravel(axes)[-cols:]:
        ax.set_xlabel("ω [rad/s]")
    page.figure(
        fig,
        "fig8-sigma",
        "Two largest singular values (dB) of the loop broken at the plant input, K(z)G(z), "
        "for each ρ, next to the LQR loop K(zI − A)⁻¹B; shaded: paper B's comparison band, "
        "grey line: 0 dB. Shown up to half the Nyquist rate.",
    )


def write_ltr(
    res: LTRResult, scenario_name: str, out_dir: str | os.PathLike, *, force: bool = False
) -> dict[str, Path]:
    """Write ``sigma.json`` and ``report.html`` for the ρ sweep (paper Fig. 8).

    Parameters
    ----------
    res : LTRResult
        The ρ sweep.
    scenario_name : str
        For the title.
    out_dir : str or os.PathLike
        The folder.
    force : bool
        Replace existing files.

    Returns
    -------
    dict of str to Path
        File name → path written.
    """
    targets = _check_out(Path(out_dir), ["sigma.json", "report.html"], force)
    _write_json(targets["sigma.json"], res.to_dict())
    page = Page(f"Loop transfer recovery — {scenario_name}")
    page.table(LTR_COLUMNS, ltr_rows(res), table_id="table-gaps")
    _sigma_figure(page, res)
    page.save(targets["report.html"])
    return targets


def _spans(t: np.ndarray, flag: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) of each run of True in ``flag`` sampled at ``t``."""
    edges = np.diff(np.concatenate([[0], flag.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def _mark_sky(axes, run, scale: float = 1.0) -> bool:
    """Shade the Earth's shadow (grey) and the earth sensor's blinding (orange) on every
    axis (time in units of ``scale`` s); False when the run had neither."""
    if run.sky is None:
        return False
    marks = [
        (run.sky[:, 0] < 1, "#777777", "eclipse (sun sensor off)"),
        (run.sky[:, 2] == 1, "#ff7f0e", "earth sensor blinded"),
    ]
    axes = np.atleast_1d(axes)
    shown = False
    for flag, color, label in marks:
        for i, (a, b) in enumerate(_spans(run.t, flag)):
            for ax in axes:
                first = i == 0 and ax is axes[0]
                ax.axvspan(
                    a / scale,
                    b / scale,
                    color=color,
                    alpha=0.2,
                    lw=0,
                    label=label if first else None,
                )
            shown = True
    return shown


def _trace_table(r):
    """The decimated trace as a pyarrow table (one row per logged step)."""
    import pyarrow as pa

    cols = {"t_s": r.t, "error_deg": r.error_deg, "est_error_deg": r.est_error_deg}
    for i in range(4):
        cols[f"q{i + 1}"] = r.q[:, i]
    for i, axis in enumerate("xyz"):
        cols[f"w_bo_{axis}_rad_s"] = r.w_bo[:, i]
        cols[f"torque_{axis}_Nm"] = r.torque[:, i]
    for i in range(r.wheel_speed_rpm.shape[1]):
        cols[f"wheel{i + 1}_rpm"] = r.wheel_speed_rpm[:, i]
    if r.sky is not None:
        for i, name in enumerate(("sunlit_fraction", "sun_sensor_status", "earth_sensor_status")):
            cols[name] = r.sky[:, i]
    for name, est in _disturbance_estimates(r):
        for i, axis in enumerate("xyz"):
            cols[f"{name}_{axis}_Nm"] = est[:, i]
    if r.sigma is not None and np.any(r.sigma):  # a filter flew: its errors and its 1σ
        cols["nees"] = r.nees
        for i, axis in enumerate("xyz"):
            cols[f"est_error_{axis}_deg"] = np.degrees(r.est_error_axes[:, i])
            cols[f"est_sigma_{axis}_deg"] = np.degrees(r.sigma[:, i])
    if r.gyro_bias_est is not None and np.any(r.gyro_bias_est):
        for i, axis in enumerate("xyz"):
            cols[f"gyro_bias_est_{axis}_deg_h"] = np.degrees(r.gyro_bias_est[:, i]) * 3600
    return pa.table({k: np.ascontiguousarray(v, dtype=float) for k, v in cols.items()})


def _estimation_figure(page, run) -> None:
    """Each axis's estimation error inside the filter's ±3σ, and the NEES."""
    if run.sigma is None or not np.any(run.sigma):
        return
    fig, axes = figure(10, 8.0, 4, 1, sharex=True)
    t_h = run.t / 3600
    for i, axis in enumerate("xyz"):
        ax = axes[i]
        three = 3 * np.degrees(run.sigma[:, i])
        ax.fill_between(*envelope(t_h, three), 0, color="#1f77b4", alpha=0.15, lw=0)
        ax.plot(*envelope(t_h, three), color="#1f77b4", lw=0.6, label="±3σ")
        ax.plot(*envelope(t_h, -three), color="#1f77b4", lw=0.6)
        ax.plot(
            *envelope(t_h, np.degrees(run.est_error_axes[:, i])),
            color="k",
            lw=0.5,
            label=f"δθ{axis}",
        )
        ax.set_ylabel(f"{axis} [°]")
        ax.legend(fontsize=8, loc="upper right")
        ax.grid(alpha=0.3)
    nees = np.where(np.isfinite(run.nees), run.nees, np.nan)
    n = 6 if run.sigma.shape[1] >= 6 else run.sigma.shape[1]
    axes[3].semilogy(t_h, np.maximum(nees, 1e-3), ".", ms=1, color="#555555")
    axes[3].set_ylabel("NEES")
    axes[3].set_xlabel("t [h]")
    axes[3].grid(alpha=0.3)
    inside = np.mean(np.abs(run.est_error_axes) <= 3 * run.sigma[:, :3])
    mean = float(np.nanmean(nees)) if np.any(np.isfinite(nees)) else float("nan")
    page.figure(
        fig,
        "fig-estimation",
        f"Estimation error per body axis (the filter's δθ) inside its ±3σ ({inside:.1%} of "
        f"the logged samples inside on every axis's average), and the normalised estimation "
        f"error squared against the whole error state (mean {mean:.3g}; a consistent filter's "
        f"mean equals its state count, ≥ {n}).",
    )


def _disturbance_estimates(r) -> list[tuple[str, np.ndarray]]:
    """The filter's disturbance states that it has (name, (K, 3) N·m): a body torque and
    the SRP lever arm (see ``Scenario.filter.disturbance_state``)."""
    pairs = (("torque_est", r.torque_est), ("srp_lever_est", r.srp_lever_est))
    return [(name, est) for name, est in pairs if est is not None and np.any(est)]


def envelope(t: np.ndarray, y: np.ndarray, bins: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) thinned for a figure: each of ``bins`` equal slices keeps its minimum and
    maximum in time order, so every peak of a long trace is still drawn."""
    if t.size <= 2 * bins:
        return t, y
    m = t.size // bins
    idx = np.arange(bins * m).reshape(bins, m)
    lo = idx[np.arange(bins), np.argmin(y[idx], axis=1)]
    hi = idx[np.arange(bins), np.argmax(y[idx], axis=1)]
    keep = np.sort(np.concatenate([lo, hi, np.arange(bins * m, t.size)]))
    return t[keep], y[keep]


def write_simulation(
    run,
    metrics: dict,
    config: dict,
    scenario,
    out_dir: str | os.PathLike,
    *,
    force: bool = False,
) -> dict[str, Path]:
    """Write ``metrics.json``, ``trace.parquet`` and ``report.html`` of one simulation."""
    import pyarrow.parquet as pq

    targets = _check_out(Path(out_dir), ["metrics.json", "trace.parquet", "report.html"], force)
    _write_json(targets["metrics.json"], {**metrics, "config": config})
    table = _trace_table(run)
    atomic_write_bytes(targets["trace.parquet"], lambda tmp: pq.write_table(table, tmp))
    page = Page(f"Attitude simulation — {config['controller']} on {scenario.name}")
    req = scenario.control.pointing_requirement_deg
    met = bool(metrics["meets_requirement"])
    page.verdict(
        f"{config['controller']} {'meets' if met else 'does NOT meet'} the ±{req:g}° "
        f"requirement: steady-state pointing error max {metrics['steady_max_error_deg']:.3g}°, "
        f"RMS {metrics['steady_rms_error_deg']:.3g}° (from t = {run.steady_from_s:g} s).",
        met,
    )
    _forced_note(page, config.get("wheel_forced"))
    sky = (
        f"Sky: the ephemerides from {scenario.sky.epoch} (UTC), station at "
        f"{scenario.sky.station_longitude_deg:g}° E; in the Earth's shadow for "
        f"{metrics['eclipse_s']:g} s, earth sensor blinded for "
        f"{metrics['earth_sensor_blinded_s']:g} s."
        if scenario.sky.epoch
        else "Sky: paper B's fixed vectors (no epoch)."
    )
    page.text(
        f"{config['controller']} with estimator {config['estimator']}, {run.t[-1]:g} s at dt "
        f"{scenario.run.dt:g} s ({metrics['steps']} steps), seed {config['seed']}. Disturbances "
        f"{'known' if scenario.filter.disturbances_known else 'unknown'} to the filter. "
        f"Steady state from t = {run.steady_from_s:g} s. Requirement ±{req:g}°. {sky}"
    )
    rows = [[k, v] for k, v in metrics.items()]
    page.table(["metric", "value"], rows, table_id="table-metrics")
    fig, axes = figure(10, 7.5, 3, 1, sharex=True)
    t_h = run.t / 3600
    traces = ((run.est_error_deg, "C1", "estimation"), (run.error_deg, "C0", "pointing"))
    for (y, color, label), style in zip(traces, trace_styles(2), strict=True):
        axes[0].semilogy(
            *envelope(t_h, np.maximum(y, 1e-6)), color=color, label=f"{label} error", **style
        )
    axes[0].axhline(req, color="k", ls="--", lw=1, label=f"±{req:g}°")
    axes[0].set_ylabel("error [°]")
    axes[0].legend(fontsize=8, loc="upper right")
    h = run.wheel_speed_rpm * (np.pi / 30) * scenario.wheels.inertia / scenario.wheels.max_momentum
    for i in range(h.shape[1]):
        axes[1].plot(*envelope(t_h, h[:, i]), lw=0.8, label=f"wheel {i + 1}")
    axes[1].axhline(scenario.momentum.unload_start_fraction, color="k", ls=":", lw=1)
    axes[1].axhline(-scenario.momentum.unload_start_fraction, color="k", ls=":", lw=1)
    axes[1].set_ylabel("momentum / limit")
    axes[1].legend(fontsize=8, loc="upper right")
    for i, axis in enumerate("xyz"):
        axes[2].plot(*envelope(t_h, run.torque[:, i]), lw=0.6, label=f"τ{axis}")
    axes[2].set_ylabel("torque [N·m]")
    axes[2].set_xlabel("t [h]")
    axes[2].legend(fontsize=8, loc="upper right")
    for ax in axes:
        ax.grid(alpha=0.3)
    marked = _mark_sky(axes, run, 3600)
    if marked:
        axes[0].legend(fontsize=8, loc="upper right")
    page.figure(
        fig,
        "fig-simulation",
        "Pointing and estimation error, wheel momentum (dotted: unloading threshold) and "
        "control torque (decimated trace; maxima in the table come from every step)."
        + (
            " Shaded: the Earth's shadow (umbra and penumbra; the sun sensor is off) in grey, "
            "the earth sensor blinded by the Sun or the Moon in orange: the filter only "
            "propagates through these outages."
            if marked
            else ""
        ),
    )
    _estimation_figure(page, run)
    estimates = _disturbance_estimates(run)
    if estimates:
        n_rows = len(estimates)
        fig, axes = figure(10, 2.2 * n_rows, n_rows, 1, sharex=True, squeeze=False)
        axes = axes[:, 0]
        for ax, (name, est) in zip(axes, estimates, strict=True):
            for i, axis in enumerate("xyz"):
                ax.plot(*envelope(t_h, est[:, i]), lw=0.8, label=f"{axis}")
            ax.set_ylabel("b̂ [N·m]" if name == "torque_est" else "β̂ [N·m]")
            ax.legend(fontsize=8, loc="upper right")
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("t [h]")
        page.figure(
            fig,
            "fig-disturbance",
            "The filter's disturbance states: b̂ the constant body torque, β̂ the SRP lever "
            "arm (its torque is ν ŝ × β̂, ŝ the Sun in body axes, ν the sunlit fraction); "
            "the controller cancels their torque.",
        )
    page.save(targets["report.html"])
    return targets


def _cell(value):
    """A metrics table cell: a requirement met reads yes / NO, not True / False."""
    if isinstance(value, bool):
        return "yes" if value else "NO"
    return value
