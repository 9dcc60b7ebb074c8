"""``rwlab ident spa`` and ``rwlab ident impulse``: nonparametric estimates."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rwlab.cli._common import _check_folder, _data_options, _echo_json, _friendly_errors, _load
from rwlab.cli.ident import ident


def _write_json(path, payload: dict, force: bool) -> None:
    from rwlab._io import atomic_write_bytes

    if Path(path).exists() and not force:
        raise FileExistsError(f"{path} exists; give --force to overwrite it")
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(Path(path), lambda tmp: tmp.write_text(text))


def _response_table(fr, rows: int = 16) -> None:
    """A few frequencies of every input→output pair: |G| in dB with ±1σ, phase in degrees."""
    import numpy as np

    mag, phase = fr.magnitude_db(), fr.phase_deg()
    sd = fr.magnitude_sd()
    for i in range(fr.response.shape[1]):
        for j in range(fr.response.shape[2]):
            click.echo(f"output {i + 1} / input {j + 1}:")
            click.echo(f"{'omega rad/s':>12} {'|G| dB':>9} {'± dB (1σ)':>10} {'phase deg':>10}")
            for k in np.unique(np.linspace(0, len(fr.omega) - 1, rows).astype(int)):
                g = abs(fr.response[k, i, j])
                pm = "" if sd is None else f"{20 * np.log10(1 + sd[k, i, j] / g):10.2f}"
                click.echo(
                    f"{fr.omega[k]:12.4g} {mag[k, i, j]:9.2f} {pm:>10} {phase[k, i, j]:10.1f}"
                )


@ident.command("spa")
@_data_options
@click.option(
    "--window", type=click.IntRange(min=1), help="Hann lag window [default: min(N/10, 30)]."
)
@click.option("--json", "as_json", is_flag=True, help="Print the whole estimate as JSON.")
@click.option("--save", type=click.Path(dir_okay=False), help="Write the estimate as JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --save's file.")
@_friendly_errors
def ident_spa(file, Ts, input_col, output_col, detrend, normalize, window, as_json, save, force):
    """Frequency response by spectral analysis (MATLAB spa): Blackman–Tukey, Hann window."""
    import numpy as np

    from rwlab.ident import spa

    if save:
        _check_folder(Path(save).parent)
    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    fr = spa(data, window)
    if save:
        _write_json(save, fr.to_dict(), force)
    if as_json:
        _echo_json(fr.to_dict())
        return
    click.echo(f"data: {data!r}; spa at {len(fr.omega)} frequencies")
    bias = fr.report.get("bias")
    if bias:
        click.echo(
            f"the ±σ band is the variance only: the Hann window (M = {bias['window_size']}) "
            f"smooths G over ~{bias['resolution_rad_s']:.3g} rad/s, a bias it leaves out "
            f"(estimated up to {float(np.max(bias['estimate'])):.3g} here)"
        )
    _response_table(fr)
    if save:
        click.echo(f"estimate written to {save}")


@ident.command("impulse")
@_data_options
@click.option("--n", "n_coef", type=click.IntRange(min=1), default=70, show_default=True,
              help="Number of FIR coefficients.")  # fmt: skip
@click.option("--nk", type=click.IntRange(min=0), default=0, show_default=True, help="Delay.")
@click.option("--kernel", type=click.Choice(["TC", "none"]), default="TC", show_default=True,
              help="TC (MATLAB's default) or none (least squares).")  # fmt: skip
@click.option("--json", "as_json", is_flag=True, help="Print the coefficients as JSON.")
@click.option("--save", type=click.Path(dir_okay=False), help="Write the estimate as JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --save's file.")
@_friendly_errors
def ident_impulse(file, Ts, input_col, output_col, detrend, normalize, n_coef, nk, kernel,
                  as_json, save, force):  # fmt: skip
    """Impulse response as a regularised FIR model (MATLAB impulseest), with ±3σ."""
    import numpy as np

    from rwlab.ident import impulseest

    if save:
        _check_folder(Path(save).parent)
    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    m = impulseest(data, n_coef, nk, kernel=kernel)
    payload = {
        "Ts": m.Ts,
        "lags": m.lags.tolist(),
        "coefficients": m.coefficients.tolist(),
        "sd": m.sd.tolist(),
        "noise_variance": m.noise_variance.tolist(),
        "report": m.report,
    }
    if save:
        _write_json(save, payload, force)
    if as_json:
        _echo_json(payload)
        return
    click.echo(f"data: {data!r}; FIR with {n_coef} coefficients from lag {nk} ({kernel} kernel)")
    for i in range(m.coefficients.shape[1]):
        for j in range(m.coefficients.shape[2]):
            g, s = m.coefficients[:, i, j], m.sd[:, i, j]
            big = np.flatnonzero(np.abs(g) > 3 * s)
            click.echo(
                f"output {i + 1} / input {j + 1}: {big.size} coefficients outside ±3σ of zero"
                + (
                    f", the first at lag {m.lags[big[0]]} ({g[big[0]]:.4g} ± {s[big[0]]:.2g})"
                    if big.size
                    else ""
                )
            )
            for k in range(min(10, len(g))):
                click.echo(f"  g[{m.lags[k]:>3}] = {g[k]:+.4g} ± {3 * s[k]:.2g} (3σ)")
    if save:
        click.echo(f"estimate written to {save}")
