"""The identification report's figures of the linear study (sections 1–6, paper A's).

Drawn apart from the page's text so that ``rwlab identify`` can draw them in a child
process while it fits the servo model (:func:`linear_makers`); the page
(:mod:`rwlab.report.identification`) takes them by figure id.
"""

from __future__ import annotations

import textwrap
from functools import partial

import numpy as np
from matplotlib.ticker import MaxNLocator

from rwlab.data import IOData
from rwlab.ident.nonlinear import ServoModel
from rwlab.ident.study import INITIAL, StudyResult, acceleration_pair
from rwlab.report.html import figure, trace_styles

__all__ = [
    "NONLINEAR_FIGURES",
    "SIGMAS",
    "armax_name",
    "linear_makers",
    "linear_plots",
    "nonlinear_makers",
    "nonlinear_plots",
    "resid_plot",
    "step_level",
]

SIGMAS = 3.0  # the chosen model's confidence bands: ± this many standard deviations
NONLINEAR_FIGURES = ("fig-nonlinear-validation", "fig-nonlinear-step", "fig-nonlinear-resid")


def resid_plot(res: dict, name: str):
    """Residual autocorrelation and input–residual cross-correlation with their bounds.

    Parameters
    ----------
    res : dict
        A residual test (``ResidResult.to_dict()``).
    name : str
        The model's name for the title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, (a1, a2) = figure(9, 3.0, 1, 2)
    a1.stem(res["lags"], res["acf"], basefmt=" ")
    for sign in (1, -1):
        a1.axhline(sign * res["acf_bound"], color="r", ls="--", lw=1)
    a1.set_title(f"residual autocorrelation, {name}")
    a1.set_xlabel("lag [samples]")
    a2.stem(res["ccf_lags"], res["ccf"], basefmt=" ")
    for sign in (1, -1):
        a2.axhline(sign * res["ccf_bound"], color="r", ls="--", lw=1)
    a2.set_title("input–residual cross-correlation")
    a2.set_xlabel("lag [samples]")
    return fig


def _compare_plot(result: StudyResult, names: list[str]):
    """The measured validation output and each stable model's simulation of it."""
    val = result.val
    t = val.time - val.time[0]
    fig, ax = figure(9, 3.2)
    stable = [name for name in names if result.models[name].is_stable()]
    styles = trace_styles(len(stable) + 1)  # the measured output widest, underneath
    ax.plot(t, val.y[:, 0], color="0.45", label="measured", **styles[0])
    for name, style in zip(stable, styles[1:], strict=True):
        ax.plot(t, result.models[name].simulate(val, initial=INITIAL), label=name, **style)
    ax.set_xlabel("time in validation record [s]")
    label = _preprocessed_label(val.output_names[0], val.output_units[0], result.preprocess)
    ax.set_ylabel(textwrap.fill(label, 28))  # a long label on two lines, not cut off
    ax.legend(loc="best", fontsize=8)
    return fig


def linear_plots(result: StudyResult, study: dict) -> dict:
    """The figures of sections 1–6, not drawn yet.

    Parameters
    ----------
    result : StudyResult
        The study.
    study : dict
        ``result.to_dict()``.

    Returns
    -------
    dict of str to matplotlib.figure.Figure
        By figure id, in the page's order (:func:`linear_makers`).
    """
    return {fig_id: make() for fig_id, make in linear_makers(result, study).items()}


def linear_makers(result: StudyResult, study: dict) -> dict:
    """What makes each figure of sections 1–6: ``rwlab identify`` draws them from a
    :class:`~rwlab.report.html.FigureQueue` while it fits the servo model.

    Parameters
    ----------
    result : StudyResult
        The study; only its linear part is read (the nonlinear stage may not have run).
    study : dict
        ``result.to_dict()``.

    Returns
    -------
    dict of str to callable
        By figure id, in the page's order, ``make()`` returning the figure: those of
        ``FIGURES`` the study has (no uncertainty bands without a covariance, no ARMAX
        figures without its model).
    """
    ch = study["chosen"]["structure"]
    makers = {
        "fig16-delay": partial(_delay_plot, study["delay"]),
        "fig17-orders": partial(_orders_plot, study["orders"]),
        "fig18-steps": partial(_steps_plot, result, study),
        "fig19-resid": partial(resid_plot, study["residuals"][ch], ch),
        "fig20-compare": partial(_compare_plot, result, [ch]),
    }
    if result.chosen.covariance is not None:
        makers["fig-uncertainty"] = partial(_uncertainty_plot, result.chosen, ch)
    armax = armax_name(study)
    if armax is not None:
        makers["fig21-resid-armax"] = partial(resid_plot, study["residuals"][armax], armax)
        makers["fig22-compare-armax"] = partial(_compare_plot, result, [armax])
    others = [r["structure"] for r in study["others"]]
    makers["fig-oe-bj"] = partial(_compare_plot, result, others)
    makers["fig23-continuous"] = partial(_continuous_plot, study)
    makers["fig24-acceleration"] = partial(_acceleration_plot, result, study)
    return makers


def nonlinear_plots(result: StudyResult) -> dict:
    """The figures of section 8 (the servo model), not drawn yet.

    Parameters
    ----------
    result : StudyResult
        A study with its servo model.

    Returns
    -------
    dict of str to matplotlib.figure.Figure
        By figure id, :data:`NONLINEAR_FIGURES` (:func:`nonlinear_makers`).
    """
    return {fig_id: make() for fig_id, make in nonlinear_makers(result).items()}


def nonlinear_makers(result: StudyResult) -> dict:
    """What makes each figure of section 8: the servo model against the chosen linear
    one on the validation data and on a large step, and its residual tests.

    Parameters
    ----------
    result : StudyResult
        A study with its servo model (``result.servo`` and ``result.nonlinear``).

    Returns
    -------
    dict of str to callable
        By figure id, :data:`NONLINEAR_FIGURES`, ``make()`` returning the figure.
    """
    residuals = _servo_parts(result)[2]["residuals"]
    return {
        "fig-nonlinear-validation": partial(_nonlinear_validation_plot, result),
        "fig-nonlinear-step": partial(_nonlinear_step_plot, result),
        "fig-nonlinear-resid": partial(resid_plot, residuals, "servo (simulation error)"),
    }


def step_level(val) -> float:
    """The step of section 8's figure: from rest to 80 % of the record's largest input
    level (1 where the input is all zero).

    Parameters
    ----------
    val : IOData
        The validation data in physical units.

    Returns
    -------
    float
    """
    return 0.8 * float(np.max(np.abs(val.u[:, 0]))) or 1.0


def _servo_parts(result: StudyResult) -> tuple[ServoModel, IOData, dict]:
    """The servo model, the physical validation data and the nonlinear row of a study."""
    servo, val, nl = result.servo, result.physical_val, result.nonlinear
    if servo is None or val is None or nl is None:
        raise ValueError("the nonlinear figures need the study's servo model and data")
    return servo, val, nl


def _nonlinear_validation_plot(result: StudyResult):
    (servo, val, _), ch = _servo_parts(result), result.chosen_name
    chosen_sim = result.chosen.simulate(result.val, initial=INITIAL)
    y_lin = result.data.trend.output_to_physical(chosen_sim, result.val.time)
    t = val.time - val.time[0]
    fig, ax = figure(9, 3.2)
    ax.plot(t, val.y[:, 0], color="k", lw=1.2, label="measured")
    ax.plot(t, y_lin, lw=1, label=f"{ch} (linear)")
    ax.plot(t, servo.predict(val, initial=INITIAL), lw=1, ls="--", label="servo (nonlinear)")
    ax.set_xlabel("time in validation record [s]")
    ax.set_ylabel(f"{val.output_names[0]} [{val.output_units[0] or 'output unit'}]")
    ax.legend(fontsize=8)
    return fig


def _nonlinear_step_plot(result: StudyResult):
    servo, val, nl = _servo_parts(result)
    trend, ch, accel = result.data.trend, result.chosen_name, nl["accel_limit_rpm_s"]
    level = step_level(val)
    n = max(20, int(4 * level / max(accel, 1e-12) / servo.Ts))
    u = np.full(n, level)
    u_p = (u - trend.input_offset[0]) / trend.input_scale[0]
    rest_p = (0 - trend.input_offset[0]) / trend.input_scale[0]
    y_steady = result.chosen.simulate(np.r_[rest_p, u_p], "steady")
    y_lin = trend.output_to_physical(y_steady, np.zeros(n + 1))
    y_nl = servo.simulate(np.r_[-servo.offset / servo.gain, u], 0.0)
    tt = np.arange(n + 1) * servo.Ts
    fig, ax = figure(9, 3.0)
    ax.plot(tt, y_lin, lw=1, label=f"{ch} (linear, no limit)")
    ax.plot(tt, y_nl, lw=1.5, label="servo (nonlinear)")
    ax.plot(tt, np.minimum(tt * accel, level), "k:", lw=1, label="±α ramp")
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8)
    return fig


def armax_name(study: dict) -> str | None:
    """The ARMAX row's name, where it was estimated and its residuals tested.

    Parameters
    ----------
    study : dict
        ``study.json``'s content.

    Returns
    -------
    str or None
    """
    others = study["others"]
    armax = next((r["structure"] for r in others if r["structure"].startswith("ARMAX")), None)
    return armax if armax and armax in study["residuals"] else None


def _delay_plot(delay: dict):
    nk = delay["nk"]
    losses = {int(k): v for k, v in delay["losses"].items()}
    fig, ax = figure(7, 2.8)
    ax.bar(
        list(losses),
        list(losses.values()),
        color=["#d62728" if k == nk else "#1f77b4" for k in losses],
    )
    ax.set_xlabel("delay nk [samples]")
    ax.set_ylabel("ARX(2,2,nk) loss")
    return fig


def _orders_plot(rows: list[dict]):
    fig, ax = figure(7, 2.8)
    ax.plot([r["na"] for r in rows], [r["mse"] for r in rows], "o-")
    ax.set_xlabel("na = nb")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # orders are whole numbers
    ax.set_ylabel("validation MSE")
    return fig


def _steps_plot(result: StudyResult, study: dict):
    Ts = study["data"]["Ts"]
    fig, ax = figure(8, 3.0)
    n_step = max(40, int(60 / Ts))
    for r in study["orders"]:
        m = result.models[r["structure"]]
        ax.plot(np.arange(n_step) * Ts, m.step_response(n_step), label=r["structure"])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("step response")
    ax.legend(fontsize=8)
    return fig


def _continuous_plot(study: dict):
    cont = study["continuous"]
    fig, ax = figure(9, 3.0)
    t = np.arange(len(cont["discrete"])) * study["data"]["Ts"]
    ax.plot(t, cont["discrete"], color="k", lw=1.5, label="discrete")
    for method, info in cont["methods"].items():
        if "y" in info:
            ax.plot(info["t"], info["y"], lw=1, ls="--", label=method)
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8)
    return fig


def _acceleration_plot(result: StudyResult, study: dict):
    val = result.val
    measured, simulated = acceleration_pair(result.chosen, val)
    fig, ax = figure(9, 3.0)
    tt = (val.time - val.time[0])[1:]
    ax.plot(tt, measured, color="k", lw=1, label="measured")
    ax.plot(tt, simulated, lw=1, label=study["chosen"]["structure"])
    ax.set_xlabel("time in validation record [s]")
    unit = val.output_units[0]
    ax.set_ylabel(f"{val.output_names[0]} change [{unit}/s]" if unit else "change per s")
    ax.legend(fontsize=8)
    return fig


def _preprocessed_label(name: str, unit: str, preprocess: str) -> str:
    """An axis label that says what the plotted numbers are."""
    unit = f" [{unit}]" if unit else ""
    if preprocess == "normalize":
        return f"{name}, normalised to [0, 1] over the estimation part"
    if preprocess == "detrend":
        return f"{name} − its estimation-part mean{unit}"
    if preprocess == "scale":
        return f"{name} / its estimation-part peak"
    return f"{name}{unit}"


def _uncertainty_plot(model, name: str):
    """Step response and Bode magnitude of the chosen model with ±kσ bands (first order)."""
    from rwlab.ident.uncertainty import bode_band, step_band

    k = SIGMAS
    n = max(40, int(60 / model.Ts))
    step = step_band(model, n)
    omega = np.logspace(-2, 0, 100) * np.pi / model.Ts
    mag, _ = bode_band(model, omega)
    fig, (a1, a2) = figure(9, 3.0, 1, 2)
    a1.plot(step.x, step.value[:, 0, 0], color="k", lw=1.2, label=name)
    a1.fill_between(step.x, step.lower(k)[:, 0, 0], step.upper(k)[:, 0, 0], alpha=0.3,
                    label=f"±{k:g}σ")  # fmt: skip
    a1.set_xlabel("t [s]")
    a1.set_ylabel("step response")
    a1.legend(fontsize=8)
    db = lambda x: 20 * np.log10(np.maximum(x, 1e-300))  # noqa: E731
    a2.semilogx(omega, db(mag.value[:, 0, 0]), color="k", lw=1.2)
    low = np.maximum(mag.lower(k), mag.value * 1e-3)  # a band through zero: floor at −60 dB
    a2.fill_between(omega, db(low[:, 0, 0]), db(mag.upper(k)[:, 0, 0]), alpha=0.3)
    a2.set_xlabel("ω [rad/s]")
    a2.set_ylabel("|G| [dB]")
    return fig
