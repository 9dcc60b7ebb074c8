"""``rwlab demo``: the whole system in one command."""

from __future__ import annotations

import sys

import click

from rwlab.cli._common import _check_folder, _friendly_errors, _stop_signals, main
from rwlab.cli.attitude import single_thread_blas


@main.command("demo")
@click.option("--out", type=click.Path(file_okay=False), default="rwlab-demo", show_default=True)
@click.option("--realtime", is_flag=True, help="Run the experiments on the wall clock (slow).")
@click.option("--monitor", is_flag=True, help="Serve the live monitor during the experiments.")
@click.option("--quick", is_flag=True, help="Shortened records and runs (a quick look).")
@_friendly_errors
def demo(out, realtime, monitor, quick):
    """The whole system: test a simulated wheel, identify it, fly it on a GEO satellite.

    Writes OUT/index.html (start here) and OUT/summary.json; a previous demo in OUT is
    replaced when this one succeeds, a folder holding anything else is refused.
    """
    import dataclasses

    from rwlab.demo import DemoConfig, run_demo

    single_thread_blas()
    _check_folder(out)
    cfg = DemoConfig.quick() if quick else DemoConfig()
    cfg = dataclasses.replace(cfg, realtime=realtime, monitor=monitor)

    def progress(label, n):
        return click.progressbar(length=n, label=f"  {label}", show_eta=True, file=sys.stderr)

    try:
        with _stop_signals():
            summary = run_demo(out, cfg, echo=lambda t: click.echo(t, err=True), progress=progress)
    except KeyboardInterrupt as exc:
        why = exc.args[0] if exc.args else "Ctrl-C"
        click.echo(
            f"\ninterrupted ({why}): the wheel is idle, every record closed, and nothing "
            f"written to {out}",
            err=True,
        )
        sys.exit(130)
    cm = summary["chosen_model"]
    click.echo(f"wheel model: {cm['structure']} (validation fit {cm['fit_percent']:.2f} %)")
    for name, m in summary["controllers"].items():
        ideal = "  (fed the true state, no sensors: the ideal bound)" if name == "lqr" else ""
        click.echo(f"  {name:<24} steady max error {m['steady_max_error_deg']:.3g} deg{ideal}")
