"""``rwlab demo``: both papers end to end, on a machine with nothing but Python.

1. A simulated RW90 answers on a virtual CAN bus; the paper's experiments run
   through the real driver and recorder: speed steps, acceleration commands,
   a 20-minute PRBS and a chirp (simulated clock by default).
2. Paper A's identification study runs on the PRBS record.
3. The chosen wheel model flies as the actuator of the GEO smallsat (three RW90)
   next to LQR, LQG and LQG/LTR with ideal wheels, and the ρ sweep runs.
4. Hardware in the loop: the LQG flies the smallsat with its three wheels as
   twins on the virtual bus (simulated clock), beside the same run simulated.
5. ``index.html`` links everything, with a summary on top; ``summary.json``
   holds the chosen model and each controller's pointing error.
"""

from __future__ import annotations

import html
import json
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rwlab._io import atomic_write_bytes

__all__ = ["DemoConfig", "run_demo"]


@dataclass(frozen=True)
class DemoConfig:
    """Durations (simulated seconds) of each part; the defaults are the full demo.

    Parameters
    ----------
    step_duration, accel_duration, prbs_duration, chirp_duration : float
        Length of each testbed record, simulated s.
    attitude_duration : float
        Length of each attitude run, s.
    hil_duration : float
        Length of the hardware-in-the-loop run, s.
    realtime : bool
        Run the testbed at wall-clock speed.
    monitor : bool
        Open the live monitor during the records.
    seed : int
        Seed of the records and the runs.
    """

    step_duration: float = 240.0
    accel_duration: float = 120.0
    prbs_duration: float = 1200.0
    chirp_duration: float = 600.0
    attitude_duration: float = 900.0
    hil_duration: float = 600.0
    realtime: bool = False
    monitor: bool = False
    seed: int = 1

    @classmethod
    def quick(cls) -> DemoConfig:
        """A shortened demo for tests (same steps, shorter records and runs)."""
        return cls(
            step_duration=100.0,
            accel_duration=40.0,
            prbs_duration=600.0,
            chirp_duration=120.0,
            attitude_duration=300.0,
            hil_duration=120.0,
        )


def _experiments(cfg: DemoConfig):
    from rwlab.testbed import ExperimentConfig

    base = ExperimentConfig(realtime=cfg.realtime, seed=cfg.seed, telemetry_rate=10.0)
    return [
        (
            "speed_steps",
            "Speed steps 0 → ±6000 rpm (paper Fig. 6)",
            replace(
                base,
                signal="step",
                amplitude=6000.0,
                duration=cfg.step_duration,
                Ts=0.5,
                step_levels=(0.0, 1.0, -1.0, 0.0),
            ),
        ),
        (
            "acceleration",
            "Acceleration commands ±200 rpm/s (paper Fig. 7–8)",
            replace(
                base,
                signal="step",
                mode="acceleration",
                amplitude=200.0,
                duration=cfg.accel_duration,
                Ts=0.5,
                step_levels=(1.0, 0.0, -1.0, 0.0),
            ),
        ),
        (
            "prbs",
            "PRBS ±6000 rpm, holds 5–60 s, Ts = 0.5 s (paper Fig. 14)",
            replace(base, signal="prbs", amplitude=6000.0, duration=cfg.prbs_duration, Ts=0.5),
        ),
        (
            "chirp",
            "Chirp 0.001–2 Hz at Ts = 0.1 s (paper Fig. 15)",
            replace(
                base,
                signal="chirp",
                amplitude=3000.0,
                duration=cfg.chirp_duration,
                Ts=0.1,
                f0=0.001,
                f1=2.0,
                telemetry_rate=20.0,
            ),
        ),
    ]


def run_demo(
    out: str | os.PathLike,
    cfg: DemoConfig = DemoConfig(),
    *,
    echo=print,
    progress=None,
) -> dict:
    """Run the whole demo into ``out``; returns the summary (also ``summary.json``).

    ``echo(text)`` reports each stage; ``progress(label, n)`` returns a context
    manager with ``update(k)`` for the long stages (a click progress bar in the CLI).
    ``out`` is written whole when the demo succeeds, or not at all; a previous
    demo there is replaced then, and a folder holding anything else is refused.

    Parameters
    ----------
    out : str or os.PathLike
        The output folder.
    cfg : DemoConfig
        Durations and options.
    echo : callable
        Prints each stage.
    progress : callable, optional
        ``progress(label, n)`` returns a context manager with ``update(k)``.

    Returns
    -------
    dict
        ``summary.json``'s content (schema ``demo``).
    """
    from rwlab._io import output_folder

    out = Path(out)
    with output_folder(out, DEMO_FILES, replace_previous=True, what="demo") as stage:
        summary = _run(stage, cfg, echo, progress)
    echo(f"[done] {out / 'index.html'} ({summary['elapsed_s']} s)")
    return summary


DEMO_FILES = ("records", "identification", "attitude", "hil", "summary.json", "index.html")


def _run(out: Path, cfg: DemoConfig, echo, progress) -> dict:
    """The demo's work, every file written into ``out`` (the staging folder)."""
    from rwlab.testbed import run_experiment

    (out / "records").mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()
    if _side_by_side(cfg):
        return _run_side_by_side(out, cfg, echo, t_start)
    records = []
    monitor = None
    for name, title, exp in _experiments(cfg):
        path = out / "records" / f"{name}.mcap"
        if cfg.monitor:
            from rwlab.testbed.monitor import start_process

            monitor = start_process(path, port=5006)
            echo(f"live monitor for {name}: http://127.0.0.1:5006/")
        n = round(exp.duration / exp.Ts)
        echo(f"[testbed] {title}: {n} commands")
        try:
            if progress:
                with progress(name, n) as bar:
                    run = run_experiment(
                        exp, path, force=True, progress=lambda k, total: bar.update(1)
                    )
            else:
                run = run_experiment(exp, path, force=True)
        finally:
            if monitor is not None:
                from rwlab.testbed.monitor import stop_process

                stop_process(monitor)
        records.append(
            {
                "name": name,
                "title": title,
                "file": f"records/{name}.mcap",
                "commands": run.commands,
                "telemetry": run.telemetry,
                "lost_frames": run.lost_frames,
            }
        )

    study, comparison = _identify_and_fly(out, cfg, echo)
    hil = _hil_stage(out, cfg, echo)
    return _finish(out, cfg, study, comparison, records, hil, t_start)


def _identify_and_fly(out: Path, cfg: DemoConfig, echo) -> tuple:
    """Paper A's study on the PRBS record, then the attitude comparison with its model."""
    from rwlab.attitude.control import compare, ltr_study
    from rwlab.attitude.scenario import SCENARIOS
    from rwlab.ident.study import identification_study
    from rwlab.report.attitude import write_comparison
    from rwlab.report.identification import write_study
    from rwlab.testbed import load_record

    echo("[identify] paper A's study on the PRBS record")
    record = out / "records" / "prbs.mcap"
    study = identification_study(load_record(record))
    model = demo_model(study, record)
    write_study(study, model, out / "identification", force=True)
    chosen = study.to_dict()["chosen"]
    echo(f"[identify] chosen {chosen['structure']}, validation fit {chosen['fit_percent']:.2f} %")

    echo(
        f"[attitude] GEO smallsat, LQR / LQG / LQG-LTR and the identified wheel, "
        f"{cfg.attitude_duration:g} s"
    )
    scenario = SCENARIOS["geo-smallsat"]
    comparison = compare(
        scenario,
        duration=cfg.attitude_duration,
        wheel_model_file=str(out / "identification" / "model.json"),
        progress=lambda name: echo(f"[attitude]   flying {name}"),
    )
    write_comparison(comparison, out / "attitude", force=True, ltr_result=ltr_study(scenario))
    return study, comparison


def demo_model(study, record: Path | None = None) -> dict:
    """``model.json`` of the demo's study, as ``rwlab identify`` writes it: with the wheel
    model the record names (its spec, hash and limits, so that a scenario whose wheels it
    cannot replace refuses it), the record's driver limits as its saturations and, given
    the record, the healthy reference ``rwlab diagnose`` compares later records with.

    Parameters
    ----------
    study : StudyResult
        The study of a testbed record.
    record : pathlib.Path, optional
        That record (``.mcap``): the healthy reference is measured on it.

    Returns
    -------
    dict
        ``model.json``'s content (schema ``model``).
    """
    from rwlab.diagnose import healthy_reference
    from rwlab.diagnose.features import RECORD_OUTPUTS
    from rwlab.ident.study import physical_model
    from rwlab.testbed import load_record
    from rwlab.wheel import IdentifiedWheel
    from rwlab.wheelspec import WheelSpec

    source = study.data.source
    spec = None
    if isinstance(source.get("wheel_spec"), dict):
        spec = WheelSpec.from_dict(source["wheel_spec"], "the PRBS record's wheel_spec")
    driver = source.get("driver_settings") or {}
    limits = {}
    if "max_speed_rpm" in driver:
        limits = {
            "speed_limit_rpm": float(driver["max_speed_rpm"]),
            "accel_limit_rpm_s": float(driver["max_accel_rpm_s"]),
        }
    model = physical_model(
        study, saturation_source="the record's driver settings", wheel_spec=spec, **limits
    )
    if record is not None:
        data = load_record(record, study.data.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
        wheel = IdentifiedWheel.from_info(model, source=str(record))
        model["healthy_reference"] = healthy_reference(data, wheel, source=data.name).to_dict()
    return model


def _side_by_side(cfg: DemoConfig) -> bool:
    """Whether the records and the HIL run in processes of their own, side by side: on
    the simulated clock (each is then its own simulation, seeded, the same in any
    process) on a machine of several cores; the wall clock and the live monitor run
    one record after the other, as a lab would."""
    return not (cfg.realtime or cfg.monitor) and (os.cpu_count() or 1) >= 2


def _record_job(exp, path: Path) -> dict:
    """One testbed record (in a worker process): its counts for the summary."""
    from rwlab.testbed import run_experiment

    run = run_experiment(exp, path, force=True)
    return {"commands": run.commands, "telemetry": run.telemetry, "lost_frames": run.lost_frames}


def _hil_job(out: Path, cfg: DemoConfig) -> tuple[dict, list[str]]:
    """The HIL stage (in a worker process): its summary and its console lines."""
    lines: list[str] = []
    return _hil_stage(out, cfg, lines.append), lines


def _run_side_by_side(out: Path, cfg: DemoConfig, echo, t_start: float) -> dict:
    """The demo with the records and the HIL in worker processes: the study and the
    attitude runs start as soon as the PRBS record is written, while the others run.
    The records are the same as one after the other (each its own seeded simulation on
    the simulated clock); the 20-minute PRBS is the longest, so the wall time is about
    its record, the study and the attitude runs."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from rwlab._forked import die_with_parent

    experiments = _experiments(cfg)
    # fork: the workers start with rwlab imported; none of them uses a thread it inherits
    context = multiprocessing.get_context("fork")
    # one worker per core, the PRBS first (the study waits for it) and the HIL next (the
    # longest of the rest): more workers than cores would share the PRBS's core
    workers = min(len(experiments) + 1, os.cpu_count() or 2)
    # a worker dies with this process: it holds a copy of the output folder's lock
    with ProcessPoolExecutor(
        workers, mp_context=context, initializer=die_with_parent, initargs=(os.getpid(),)
    ) as pool:
        try:
            jobs = {}
            for name, title, exp in sorted(experiments, key=lambda e: e[0] != "prbs"):
                echo(f"[testbed] {title}: {round(exp.duration / exp.Ts)} commands")
                jobs[name] = pool.submit(_record_job, exp, out / "records" / f"{name}.mcap")
                if name == "prbs":
                    hil_job = pool.submit(_hil_job, out, cfg)
            jobs["prbs"].result()
            study, comparison = _identify_and_fly(out, cfg, echo)
            records = [
                {"name": n, "title": t, "file": f"records/{n}.mcap", **jobs[n].result()}
                for n, t, _ in experiments
            ]
            hil, lines = hil_job.result()
        except BaseException:
            _stop_workers(pool)
            raise
    for line in lines:
        echo(line)
    return _finish(out, cfg, study, comparison, records, hil, t_start)


def _stop_workers(pool) -> None:
    """Stop the workers' runs now: a stop signal sent to this process alone (``kill``, a
    supervisor's SIGTERM, a test) would otherwise wait for every record to finish. Each
    worker, forked with this process's stop handlers, idles its wheel and closes its
    record as this process does (SIGTERM: a second one is ignored, unlike SIGINT)."""
    import multiprocessing
    import signal

    for child in multiprocessing.active_children():
        if child.pid is not None:
            os.kill(child.pid, signal.SIGTERM)
    pool.shutdown(wait=True, cancel_futures=True)  # their files closed before ours are removed


def _finish(out: Path, cfg, study, comparison, records, hil, t_start: float) -> dict:
    """``summary.json`` and ``index.html``; returns the summary."""
    from rwlab.attitude.scenario import SCENARIOS

    scenario = SCENARIOS["geo-smallsat"]
    chosen = study.to_dict()["chosen"]
    summary = {
        "chosen_model": {
            "structure": chosen["structure"],
            "fit_percent": chosen["fit_percent"],
            "reason": chosen["reason"],
            "delay_nk": study.delay["nk"],
            "Ts": study.data.Ts,
            "file": "identification/model.json",
        },
        "controllers": {
            name: {
                "steady_max_error_deg": m["steady_max_error_deg"],
                "steady_rms_error_deg": m["steady_rms_error_deg"],
                "meets_requirement": m["meets_requirement"],
            }
            for name, m in comparison.metrics.items()
        },
        "attitude_wheel_model": "identification/model.json",
        "scenario": scenario.name,
        "records": records,
        "hil": hil,
        "elapsed_s": round(time.monotonic() - t_start, 1),
        "realtime": cfg.realtime,
    }
    text = json.dumps(summary, indent=2)
    atomic_write_bytes(out / "summary.json", lambda tmp: tmp.write_text(text))
    page = _index(summary, _pointing_png(comparison))
    atomic_write_bytes(out / "index.html", lambda tmp: tmp.write_text(page, encoding="utf-8"))
    return summary


def _hil_stage(out: Path, cfg: DemoConfig, echo) -> dict:
    """The LQG on the smallsat with its wheels as twins on the bus (simulated clock)."""
    from rwlab.hil.run import HilConfig, run_hil
    from rwlab.report.hil import write_hil_report

    echo(f"[hil] GEO smallsat, LQG through three wheel twins on the bus, {cfg.hil_duration:g} s")
    result = run_hil(
        HilConfig(duration=cfg.hil_duration, seed=cfg.seed, channel="rwlab-demo-hil"),
        out / "hil",
        force=True,
    )
    write_hil_report(result, out / "hil")
    m = result.metrics
    lost = sum(v or 0 for v in m["bench"]["lost_commands"].values())
    echo(
        f"[hil] steady max {m['steady_max_error_deg']:#.3g}° on the bus, "
        f"{m['reference_simulation']['steady_max_error_deg']:#.3g}° simulated; {lost} lost commands"
    )
    return {
        "steady_max_error_deg": m["steady_max_error_deg"],
        "simulated_steady_max_error_deg": m["reference_simulation"]["steady_max_error_deg"],
        "commands_sent": sum(m["bench"]["commands_sent"].values()),
        "lost_commands": lost,
        "duration_s": cfg.hil_duration,
        "report": "hil/report.html",
    }


def _pointing_png(comparison) -> str:
    """The pointing error of every run as an embedded PNG (data URI)."""
    from rwlab.report.attitude import COLORS, LABELS, POINTING_ORDER
    from rwlab.report.html import figure, png_uri, trace_styles

    fig, ax = figure(8, 3.0)
    order = [k for k in POINTING_ORDER if k in comparison.runs]
    for name, style in zip(order, trace_styles(len(order)), strict=True):
        r = comparison.runs[name]
        ax.semilogy(
            r.t, np.maximum(r.error_deg, 1e-6), color=COLORS[name], label=LABELS[name], **style
        )
    req = comparison.scenario.control.pointing_requirement_deg
    ax.axhline(req, color="k", ls="--", lw=1, label=f"±{req:g}° requirement")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("pointing error [°]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right", ncol=3)
    return png_uri(fig)


def _verdict(s: dict) -> str:
    """The demo's answer in one line: the model chosen and which controllers meet ±0.1°."""
    failed = [n for n, m in s["controllers"].items() if not m["meets_requirement"]]
    flown = "every controller meets" if not failed else f"{', '.join(failed)} miss"
    return (
        f"The identified wheel model ({s['chosen_model']['structure']}) flies: {flown} the "
        f"±0.1° pointing requirement; on the bus (HIL) the LQG's steady maximum is "
        f"{s['hil']['steady_max_error_deg']:.3g}°."
    )


def _index(s: dict, figure_uri: str) -> str:
    esc = html.escape
    cm = s["chosen_model"]
    rows = "".join(
        f"<tr><td>{esc(name)}</td><td>{m['steady_max_error_deg']:.3g}</td>"
        f"<td>{m['steady_rms_error_deg']:.3g}</td>"
        f"<td>{'yes' if m['meets_requirement'] else 'NO'}</td></tr>"
        for name, m in s["controllers"].items()
    )
    recs = "".join(
        f'<li><a href="{esc(r["file"])}">{esc(r["title"])}</a> — {r["commands"]} commands, '
        f"{r['telemetry']} telemetry frames, {r['lost_frames']} lost</li>"
        for r in s["records"]
    )
    return f"""<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>rwlab demo</title>
<style>body{{font-family:system-ui,sans-serif;max-width:900px;margin:2em auto;padding:0 1em;
line-height:1.5;color:#222}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;
padding:.3em .7em}}th{{background:#f3f3f3}}.box{{background:#eef7ee;padding:.8em 1em;
border-left:4px solid #4a4}}img{{max-width:100%}}</style></head><body>
<h1>rwlab demo: a reaction wheel from the bench to the satellite</h1>
<div class="box" id="summary"><p id="verdict"><b>{esc(_verdict(s))}</b></p>
<p><b>Identified wheel model: {esc(cm["structure"])}</b>,
validation fit {cm["fit_percent"]:.2f} % (delay nk = {cm["delay_nk"]}, Ts = {cm["Ts"]:g} s);
why this one: the table at the top of the
<a href="identification/report.html#choice">identification report</a>.</p>
<p>GEO smallsat ({esc(s["scenario"])}), steady-state pointing error against the ±0.1°
requirement:</p>
<table id="pointing"><tr><th>controller</th><th>max [°]</th><th>RMS [°]</th>
<th>meets ±0.1°</th></tr>
{rows}</table>
<p>LQR acts on the true state: its error is only the unknown disturbance over its gain
(physics, not a pointing claim); the LQG rows are what sensors and the filter allow.</p>
<figure id="fig-pointing"><img alt="pointing error of each controller" src="{figure_uri}">
<figcaption>Pointing error of each run (dashed: the requirement).</figcaption></figure></div>
<h2>1. Testbed (paper A: simulated RW90 on a virtual CAN bus)</h2><ul id="records">{recs}</ul>
<p>Records are MCAP files (open with <code>rwlab monitor FILE --replay</code>, Foxglove, or
<code>rwlab export</code>).</p>
<h2>2. Identification (paper A)</h2>
<p><a href="identification/report.html">Identification report</a> ·
<a href="identification/study.json">study.json</a> ·
<a href="identification/model.json">model.json</a></p>
<h2>3. Attitude control (paper B)</h2>
<p><a href="attitude/report.html">LQR vs LQG vs LQG/LTR report</a> (with the identified wheel) ·
<a href="attitude/metrics.json">metrics.json</a> · <a href="attitude/sigma.json">sigma.json</a></p>
<h2>4. Hardware in the loop</h2>
<p id="hil">The LQG flew the smallsat for {s["hil"]["duration_s"]:g} s with its three wheels as
twins on the virtual bus: every command crossed the bus ({s["hil"]["commands_sent"]} sent,
{s["hil"]["lost_commands"]} lost) and the plant took each wheel's momentum from its
telemetry. Steady maximum {s["hil"]["steady_max_error_deg"]:.3g}° on the bus against
{s["hil"]["simulated_steady_max_error_deg"]:.3g}° simulated.
<a href="hil/report.html">HIL report</a> · <a href="hil/metrics.json">metrics.json</a> ·
<a href="hil/record.mcap">record.mcap</a></p>
<p>Ran in {s["elapsed_s"]} s{" on the wall clock" if s["realtime"] else " (simulated clock)"}.</p>
</body></html>"""
