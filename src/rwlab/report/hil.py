"""The hardware-in-the-loop report: the bench run beside the simulation, and its events.

Figure ids: ``fig-hil-pointing`` (pointing error, bench and simulation),
``fig-hil-wheels`` (wheel speeds, bench and simulation), ``fig-hil-torque``
(commanded minus realised wheel torque on the bench).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rwlab.report.attitude import envelope
from rwlab.report.html import Page, figure, trace_styles

__all__ = ["write_hil_report"]

_COMPARED = (
    "steady_max_error_deg",
    "steady_rms_error_deg",
    "steady_p99_73_error_deg",
    "max_error_deg",
    "settling_time_s",
    "steady_rms_estimation_error_deg",
    "torque_rms_Nm",
    "torque_peak_Nm",
    "peak_wheel_speed_rpm",
    "wheel_momentum_peak_fraction",
)


def write_hil_report(result, out_dir: str | os.PathLike) -> Path:
    """Write ``report.html`` of a :class:`rwlab.hil.HilResult` into ``out_dir``; its path.

    Parameters
    ----------
    result : HilResult
        The run.
    out_dir : str or os.PathLike
        The folder.

    Returns
    -------
    Path
        ``report.html``.
    """
    page = _page(result)
    return page.save(Path(out_dir) / "report.html")


def _page(result) -> Page:
    m, sc, run, ref = result.metrics, result.scenario, result.run, result.reference
    cfg = m["config"]
    req = sc.control.pointing_requirement_deg
    page = Page(f"Hardware in the loop — {cfg['controller']} on {sc.name}")
    ref_m = m.get("reference_simulation")
    beside = f" ({ref_m['steady_max_error_deg']:.3g}° in the simulation beside it)" if ref_m else ""
    lost = "; ".join(
        f"wheel {f['node']}: {f['named_kind']} named at {f['detected_s']:.1f} s, {f['action']}"
        for f in m["wheel_faults"]
    )
    page.verdict(
        f"Requirement ±{req:g}° {'met' if m['meets_requirement'] else 'NOT met'} on the bus: "
        f"steady-state maximum {m['steady_max_error_deg']:.3g}°{beside}."
        + (f" {lost}." if lost else ""),
        bool(m["meets_requirement"]),
    )
    if cfg.get("wheel_forced"):
        page.text(
            "The wheel model cannot deliver what this scenario needs; it was flown anyway "
            "(--force-wheel). " + " ".join(cfg["wheel_forced"]),
            note=True,
        )
    clock = "the wall clock" if cfg["clock"] == "wall" else "the simulated clock"
    page.text(
        f"{cfg['controller']} ({cfg['estimator']}) flew {cfg['duration_s']:g} s on {clock}, "
        f"control period {sc.run.dt:g} s, seed {cfg['seed']}. Each wheel was node "
        f"{', '.join(map(str, cfg['nodes']))} on the {cfg['interface']} bus"
        f"{' (twins started by the run)' if cfg['twins'] else ''}; every period the torques "
        "went out as acceleration commands and the plant took each wheel's momentum from "
        f"its reported speed. Requirement ±{req:g}°: "
        f"{'met' if m['meets_requirement'] else 'NOT met'} (steady maximum "
        f"{m['steady_max_error_deg']:.4g}°)."
    )
    _comparison(page, m)
    _pointing_figure(page, run, ref, req)
    _wheel_figure(page, result)
    _measurement(page, m, result, sc)
    _events(page, result)
    _timing(page, m)
    return page


def _time_unit(t: np.ndarray) -> tuple[float, str]:
    """Seconds for a run shorter than two hours, hours beyond: (s per unit, its name)."""
    return (3600.0, "h") if t.size and t[-1] > 7200 else (1.0, "s")


def _comparison(page: Page, m: dict) -> None:
    ref = m.get("reference_simulation")
    page.heading("Bench and simulation side by side", "comparison")
    if ref is None:
        page.text("No reference simulation was flown (--no-reference).", note=True)
        rows = [[k, m[k]] for k in _COMPARED]
        page.table(["metric", "bench"], rows, table_id="table-comparison")
        return
    rows = []
    for k in _COMPARED:
        a, b = m[k], ref[k]
        ratio = a / b if isinstance(a, float) and isinstance(b, float) and b else None
        rows.append([k, a, b, ratio])
    page.text(
        "The simulation is rwlab attitude simulate on the same scenario, controller and seed with "
        "the physics wheel (healthy) started at the bench's wheel momenta: it draws the same "
        "sensor and disturbance noise, so the difference is the wheels' (next section)."
    )
    page.table(
        ["metric", "bench", "simulation", "bench / simulation"], rows, table_id="table-comparison"
    )


def _pointing_figure(page: Page, run, ref, req: float) -> None:
    scale, unit = _time_unit(run.t)
    paired = ref is not None and ref.t.shape == run.t.shape and np.allclose(ref.t, run.t)
    fig, axes = figure(
        10, 6.0 if paired else 3.6, 2 if paired else 1, 1, sharex=True, squeeze=False
    )
    ax = axes[0, 0]
    t_h = run.t / scale
    under, over = trace_styles(2)
    if ref is not None:  # drawn first and wider: the bench run, the main trace, on top
        ax.semilogy(
            *envelope(ref.t / scale, np.maximum(ref.error_deg, 1e-6)),
            color="C1",
            label="simulation (physics wheel)",
            **under,
        )
    ax.semilogy(*envelope(t_h, np.maximum(run.error_deg, 1e-6)), color="C0", label="bench", **over)
    ax.axhline(req, color="k", ls="--", lw=1, label=f"±{req:g}°")
    ax.axvline(run.steady_from_s / scale, color="grey", ls=":", lw=1, label="steady window")
    ax.set_ylabel("pointing error [°]")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    if paired:  # same noise, same rows: the difference is the wheels'
        diff = run.error_deg - ref.error_deg
        axes[1, 0].plot(*envelope(t_h, diff), lw=0.6, color="k")
        axes[1, 0].set_ylabel("bench − simulation [°]")
        axes[1, 0].grid(alpha=0.3)
    axes[-1, 0].set_xlabel(f"t [{unit}]")
    page.figure(
        fig,
        "fig-hil-pointing",
        "True pointing error, bench and simulation"
        + (" (same noise streams), and their difference." if paired else "."),
    )


def _wheel_figure(page: Page, result) -> None:
    run, ref = result.run, result.reference
    scale, unit = _time_unit(run.t)
    n = run.wheel_speed_rpm.shape[1]
    fig, axes = figure(10, 1.8 * n + 0.6, n, 1, sharex=True, squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        under, over = trace_styles(2)
        if ref is not None:
            ax.plot(
                *envelope(ref.t / scale, ref.wheel_speed_rpm[:, i]), color="C1",
                label="simulation", **under,
            )  # fmt: skip
        ax.plot(
            *envelope(run.t / scale, run.wheel_speed_rpm[:, i]), color="C0", label="bench", **over
        )
        ax.set_ylabel(f"node {result.metrics['config']['nodes'][i]} [rpm]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel(f"t [{unit}]")
    for e in result.events:
        if e["kind"] in ("alarm", "fault_injected", "reallocate"):
            for ax in axes[:, 0]:
                ax.axvline(e["t"] / scale, color="r", lw=0.8, ls=":")
    page.figure(
        fig,
        "fig-hil-wheels",
        "Wheel speeds as the wheels reported them on the bus, and the simulated wheels "
        "(dotted red: alarm and reallocation).",
    )


def _measurement(page: Page, m: dict, result, sc) -> None:
    meas = m["measurement"]
    page.heading("The difference, measured", "measurement")
    ref = m.get("reference_simulation")
    delta = ""
    if ref is not None:
        delta = (
            f" The bench's steady maximum is {m['steady_max_error_deg']:.4g}° against "
            f"{ref['steady_max_error_deg']:.4g}° simulated "
            f"({m['steady_max_error_deg'] - ref['steady_max_error_deg']:+.3g}°)."
        )
    page.text(
        "What the wheels on the bus add to the simulated wheel: (1) latency — a command "
        f"acts {meas['twin_latency_s'] * 1000:g} ms after it is sent, and the plant learns the "
        "wheel's torque only from the next telemetry frame; (2) quantisation — the reported "
        f"speed has a {meas['speed_quantum_rpm']:g} rpm quantum and noise, which is a "
        f"{meas['momentum_quantum_Nms']:.2g} N·m·s momentum step, "
        f"{meas['torque_quantum_per_period_Nm']:.2g} N·m over one period: the satellite feels it "
        "as a white torque whose integral stays bounded (momentum telescopes), so it moves the "
        "attitude by far less than it looks; (3) friction at zero crossing — the drive's "
        "Coulomb feed-forward turns over with the sign of the speed and the Hall sensors read 0 "
        f"below {meas['hall_dead_zone_rpm']:g} rpm." + delta
    )
    rows = [
        [
            node,
            w["torque_command_rms_Nm"],
            w["torque_error_rms_Nm"],
            w["torque_error_mean_Nm"],
            w["zero_crossings"],
            w["time_reading_zero_s"],
        ]
        for node, w in meas["wheels"].items()
    ]
    page.table(
        [
            "node",
            "commanded torque RMS [N·m]",
            "realised − commanded RMS [N·m]",
            "mean [N·m]",
            "zero crossings",
            "time reading 0 [s]",
        ],
        rows,
        table_id="table-measurement",
    )
    scale, unit = _time_unit(result.run.t)
    fig, ax = figure(10, 3.0)
    for node, log in result.wheel_log.items():
        if log["speed_rpm"].size < 3:
            continue
        realised = np.diff(log["speed_rpm"]) / sc.run.dt
        err = (realised - log["command_rpm_s"][1:]) * sc.wheels.inertia * np.pi / 30
        ax.plot(*envelope(log["t"][1:] / scale, err), lw=0.5, label=f"node {node}")
    ax.set_xlabel(f"t [{unit}]")
    ax.set_ylabel("realised − commanded [N·m]")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    page.figure(
        fig,
        "fig-hil-torque",
        "Wheel torque realised (from the change of the reported speed over each period) "
        "minus commanded: the quantisation and noise of the reading, the latency at each "
        "change of command, and a dead or idled wheel's missing torque.",
    )


def _events(page: Page, result) -> None:
    page.heading("Events", "events")
    rows = [[f"{e['t']:.1f}", e["kind"], e["message"]] for e in result.events]
    page.table(["t [s]", "event", "message"], rows, table_id="table-events")
    faults = result.metrics["wheel_faults"]
    worst = result.metrics.get("max_error_from_first_fault_deg")
    if worst is not None:
        page.text(
            f"Largest pointing error from the first injected fault to the end (every control "
            f"period): {worst:.4g}°."
        )
    if faults:
        rows = [
            [
                f["node"],
                f["kind"],
                _seconds(f["injected_s"]),
                _seconds(f["detected_s"]),
                None if f["injected_s"] is None else _seconds(f["detected_s"] - f["injected_s"]),
                f["named_kind"],
                f["detector"],
                f["action"],
            ]
            for f in faults
        ]
        page.table(
            ["node", "injected", "at [s]", "detected [s]", "delay [s]", "named", "by", "action"],
            rows,
            table_id="table-wheel-faults",
        )


def _seconds(t: float | None) -> str | None:
    """A time to the control loop's tenth of a second (its floats carry 1e-6 of drift)."""
    return None if t is None else f"{t:.1f}"


def _timing(page: Page, m: dict) -> None:
    page.heading("Loop timing and the bus", "timing")
    rows = [[k, v] for k, v in m["timing"].items()]
    bench = m["bench"]
    for key in ("commands_sent", "lost_commands", "lost_telemetry_frames", "stale_telemetry_reads"):
        rows.append([key, ", ".join(f"{n}: {v}" for n, v in bench[key].items())])
    telemetry = m["telemetry_check"]
    for key in ("blocks_tested", "alarm_count"):  # the dropout test's, per wheel
        values = ", ".join(f"{n}: {v}" for n, v in telemetry[key].items())
        rows.append([f"dropout test {key}", values])
    page.table(["figure", "value"], rows, table_id="table-timing")
