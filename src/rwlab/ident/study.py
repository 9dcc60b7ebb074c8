"""Paper A's identification procedure as one function: ``identification_study``.

The steps, in the paper's order (SPEC.md, paper A, "Procedure and results"):

1. split 70/30, then preprocess with statistics of the estimation part only
   (the validation part must not inform the model): remove the means
   (default), scale without shifting, or normalise to [0, 1] as the paper;
2. delay scan with ARX(2,2,nk) (Fig. 16);
3. ARX orders na = nb = 2…5 at that delay: fit %, MSE, polynomials ± std (Table 2,
   Fig. 17) and their step responses (Fig. 18);
4. residual analysis and validation of the ARX models, ARMAX(2,2,1,nk)
   (Table 3, Fig. 19–22), and OE and BJ of matching order;
5. model choice: the simplest model whose validation fit is within
   ``tolerance`` percentage points of the best (the paper's "simplicity wins")
   and whose DC gain agrees within ``gain_tolerance`` with the steady-state
   gain measured on the record's long holds (:func:`steady_state_gain`; beyond
   the paper: a speed-loop model with the wrong static gain settles at the
   wrong speed). A record without such holds is chosen by fit alone.
   Also beyond the paper: when the estimation part has settled holds, every
   structure is estimated again with its static gain constrained to the gain
   measured on them (``ARX221+K`` …, :mod:`rwlab.ident.gain_constraint`): a wheel
   that sometimes runs at its rate or current limit biases a free linear fit's
   gain low, while the speed loop's integral action makes the true one 1. The
   +K models compete under the same rule, each after its free twin (an imposed
   gain is an assumption: the free estimate wins when its own gain agrees), and
   ``reason`` states K, its holds and standard error, and the twin's fit and gain;
6. continuous-time models by ZOH and Tustin at the record's real Ts, checked
   against the discrete model on a new input (Fig. 23), and the acceleration
   check (Fig. 24);
7. the chosen model in physical units with the wheel's saturations;
8. beyond the paper (its future work): nonlinear models in physical units, fitted
   by simulation error on the estimation part and scored on the validation part:
   the servo model (``rwlab.ident.nonlinear``: the inner loop's structure alone),
   a physical grey-box wheel (``rwlab.ident.greybox``: inertia, torque constant,
   current limit, Stribeck friction, rate limit, PI loop, each estimated
   parameter with its standard deviation) and a nonlinear ARX
   (``rwlab.ident.nlarx``); the better of the grey box and the NLARX on the
   validation part is the study's nonlinear model (``nonlinear['chosen']``).

Fit % and MSE are computed on the validation data by simulation, in the
preprocessed units the paper reports. Every number (estimation, fit %, MSE,
one-step prediction fit, residuals) uses the ``'steady'`` pre-sample
convention (every signal held its first value): exact for a record that starts
at rest, and far closer than zero for normalised data, where physical zero is
not 0. This is not MATLAB ``compare``'s default (``'estimate'``, an initial
state fitted to the validation output), which can only score higher; the
convention is recorded in ``study.json`` as ``initial_conditions``.

Why this module is long: paper A's procedure is one function whose steps follow the
paper's order; they are kept together in that order.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import control
import numpy as np

from rwlab._display import ShortRepr
from rwlab._forked import Forked
from rwlab.data import IOData
from rwlab.errors import DataError, EstimationError, ModelError
from rwlab.ident.arx import arx
from rwlab.ident.gain_constraint import SUFFIX, study_name
from rwlab.ident.greybox import WheelGreyBox, greybox_fit
from rwlab.ident.model_file import Channel, WheelModelFile
from rwlab.ident.models import PolyModel
from rwlab.ident.nlarx import NLARXModel, nlarx
from rwlab.ident.nonlinear import ServoModel, servo_fit
from rwlab.ident.pem import armax, bj, oe
from rwlab.ident.structure import delay_scan
from rwlab.ident.validation import compare, fit_percent, resid
from rwlab.wheelspec import WheelSpec

__all__ = [
    "StudyResult",
    "identification_study",
    "nonlinear_stage",
    "physical_model",
    "steady_state_gain",
    "wheel_model",
]

PREPROCESSING = ("detrend", "scale", "normalize", "none")
_SIMPLICITY = ("ARX", "ARMAX", "OE", "BJ", "POLY")


CONSTRAINED = SUFFIX  # the name's suffix of a model whose static gain was imposed


def _kind(structure: str) -> str:
    return structure.removesuffix(CONSTRAINED).rstrip("0123456789[], ")


@dataclass(repr=False)
class StudyResult(ShortRepr):
    """Everything the study computed; ``to_dict()`` is ``study.json``.

    Attributes
    ----------
    data, est, val : IOData
        Preprocessed record and its estimation / validation parts.
    preprocess : str
        The preprocessing applied (``"detrend"``, …).
    delay : dict
        ``nk`` and ``losses`` (nk → loss).
    models : dict
        structure name → PolyModel, for every model the study estimated.
    orders : list of dict
        One row per ARX order (the paper's Table 2).
    others : list of dict
        ARMAX, OE and BJ rows (Table 3 and completeness).
    constrained : list of dict
        The same structures with their static gain constrained to the gain measured
        on the estimation part's settled holds (``gain_constraint``), named
        ``ARX221+K`` …; empty when that part has too few settled holds.
    chosen : PolyModel
        The selected model.
    chosen_name : str
        Its row's name (``ARX221+K`` for a constrained one).
    reason : str
        Why it was chosen.
    residuals : dict
        The residual tests (``resid``) of the chosen model and of the best other
        structure, on the validation part, by structure name.
    continuous : dict
        ZOH and Tustin transfer functions and the discrete-vs-continuous check.
    acceleration : dict
        The acceleration check (Fig. 24).
    new_input : dict
        ``u``: an input the record did not contain (for the continuous-time check).
    servo : ServoModel or None
        The nonlinear servo model, when the wheel stages ran.
    nonlinear : dict or None
        Its fit report, or why it was skipped; None with ``nonlinear=False``.
    greybox : WheelGreyBox or None
        The physical grey-box wheel model, when fitted.
    nlarx : NLARXModel or None
        The black-box nonlinear ARX model, when fitted.
    physical_val : IOData or None
        The validation part in physical units (before preprocessing).
    steady_state : dict or None
        The static gain measured on the record's settled holds.
    gain_constraint : dict or None
        The gain the ``+K`` models were constrained to, and where it was measured.
    parts : dict or None
        How the estimation and validation parts differ, and the chosen model's fit on each.
    segments : list of [t_start, t_end] or None
        The gap-free parts the record was split into (s from its start), each an
        experiment of its own; None for one record without gaps.
    wheel_stages : dict or None
        ``run`` (whether the servo and grey-box wheel models were fitted) and ``why``.
    best_fit_percent : float or None
        The best validation fit of every linear model, %; ``no_model_fits`` when negative.
    nonlinear_range : (int, int) or None
        ``[i0, i1)``, the samples of the record the nonlinear stage fits (the longest
        gap-free piece of a record split at its gaps); None: the whole record.
    """

    data: IOData
    est: IOData
    val: IOData
    preprocess: str
    delay: dict
    models: dict[str, PolyModel]
    orders: list[dict]
    others: list[dict]
    chosen: PolyModel
    reason: str
    residuals: dict
    continuous: dict
    acceleration: dict
    new_input: dict = field(repr=False)
    servo: ServoModel | None = None
    nonlinear: dict | None = None
    greybox: WheelGreyBox | None = None
    nlarx: NLARXModel | None = None
    physical_val: IOData | None = field(default=None, repr=False)
    segments: list[list[float]] | None = None
    steady_state: dict | None = None
    constrained: list[dict] = field(default_factory=list)
    gain_constraint: dict | None = None
    chosen_name: str = ""
    parts: dict | None = None
    wheel_stages: dict | None = None
    best_fit_percent: float | None = None
    nonlinear_range: tuple[int, int] | None = field(default=None, repr=False)

    @property
    def no_model_fits(self) -> bool:
        """True when even the best model's validation fit is negative (below the mean's)."""
        return self.best_fit_percent is not None and self.best_fit_percent < 0

    def __post_init__(self) -> None:
        self.chosen_name = self.chosen_name or self.chosen.structure

    @property
    def rows(self) -> list[dict]:
        """Every model's row: ARX orders, other structures, gain-constrained ones."""
        return self.orders + self.others + self.constrained

    def to_pandas(self):
        """The structures tried (orders and other structures), one row each.

        Returns
        -------
        pandas.DataFrame
            Index ``structure``; fit %, MSE, FPE, parameter count, stability.
        """
        from rwlab._display import pandas

        keep = ("structure", "n_params", "fit_percent", "prediction_fit_percent", "mse", "fpe")
        rows = [{k: r.get(k) for k in (*keep, "stable")} for r in self.rows]
        return pandas().DataFrame(rows).set_index("structure")

    def to_dict(self) -> dict:
        """Every number of the report, as plain JSON."""
        chosen_row = next(r for r in self.rows if r["structure"] == self.chosen_name)
        twin = None
        if chosen_row.get("gain_constrained"):
            name = self.chosen_name.removesuffix(CONSTRAINED)
            row = next((r for r in self.rows if r["structure"] == name), None)
            keep = ("structure", "fit_percent", "dc_gain", "dc_gain_error_percent")
            twin = None if row is None else {k: row.get(k) for k in keep}
        return {
            "data": {
                "name": self.data.name,
                "Ts": self.data.Ts,
                "N": self.data.N,
                "n_estimation": self.est.N,
                "n_validation": self.val.N,
                "input": self.data.input_names[0],
                "output": self.data.output_names[0],
                "preprocess": self.preprocess,
                "initial_conditions": INITIAL,
                "trend": self.data.trend.to_dict(),
            },
            "delay": {
                "nk": self.delay["nk"],
                "losses": {str(k): v for k, v in self.delay["losses"].items()},
            },
            "orders": self.orders,
            "others": self.others,
            "constrained": self.constrained,
            "chosen": {**chosen_row, "reason": self.reason, "unconstrained_twin": twin},
            "steady_state_gain": self.steady_state,
            "gain_constraint": self.gain_constraint,
            "parts": self.parts,
            "residuals": self.residuals,
            "continuous": {k: v for k, v in self.continuous.items() if k != "tf"},
            "acceleration": self.acceleration,
            "nonlinear": self.nonlinear,
            "segments": self.segments,
            "wheel_stages": self.wheel_stages,
            "best_fit_percent": self.best_fit_percent,
            "no_model_fits": self.no_model_fits,
        }


INITIAL = "steady"  # records start at rest; the validation part starts where it is


def _row(model: PolyModel, val: IOData) -> dict:
    stable = model.is_stable()
    cmp = compare(model, val, initial=INITIAL) if stable else None  # unstable: no finite score
    std = model.parameter_std
    return {
        "structure": model.structure,
        "n_params": model.n_params,
        "fit_percent": cmp.fit_percent if cmp else None,
        "mse": cmp.mse if cmp else None,
        "prediction_fit_percent": compare(model, val, horizon=1, initial=INITIAL).fit_percent,
        "fpe": model.report.get("fpe"),
        "stable": stable,
        "A": model.A.tolist(),
        "B": model.B.tolist(),
        "C": model.C.tolist(),
        "D": model.D.tolist(),
        "F": model.F.tolist(),
        "parameters": dict(zip(model.parameter_names, model.parameters.tolist(), strict=True)),
        "std": None if std is None else dict(zip(model.parameter_names, std.tolist(), strict=True)),
    }


def _try(estimate, *args, **options):
    try:
        return estimate(*args, initial=INITIAL, **options)
    except EstimationError:
        return None


def identification_study(
    data: IOData,
    *,
    preprocess: str = "detrend",
    split: float = 0.7,
    orders=(2, 3, 4, 5),
    nk_max: int = 10,
    tolerance: float = 3.0,
    gain_tolerance: float = 0.02,
    nonlinear: bool = True,
    limits_rpm: tuple[float, float] = (math.inf, math.inf),
    progress: Callable[[int, int, str], None] | None = None,
    datasheet: dict | None = None,
    current=None,
    segments: Sequence[tuple[int, int]] | None = None,
    wheel: bool | None = None,
    nonlinear_models: bool = False,
) -> StudyResult:
    """Run paper A's identification procedure on a SISO record.

    Parameters
    ----------
    data : IOData
        The raw record (physical units), single input and output.
    preprocess : {'detrend', 'scale', 'normalize', 'none'}
        Statistics always from the estimation part. 'detrend' (default) removes
        the means, so a model without intercept (ARX, OE, BJ) is left no offset
        to explain; 'scale' divides by the largest magnitude without shifting
        (physical zero stays zero); 'normalize' maps to [0, 1] as paper A and
        MATLAB's ``normalize`` do. That last one biases a model without
        intercept: physical zero becomes ``−min/range`` in each channel, and the
        static map is forced through both minima, so the DC gain absorbs the
        offset (measured on the twin: DC gain 1.016–1.023 against 0.995–0.999
        detrended, validation fit 2–5 points lower).
    split : float
        Estimation share (paper: 0.7).
    orders : sequence of int
        ARX orders na = nb to compare (paper: 2..5).
    nk_max : int
        Largest delay scanned.
    tolerance : float
        Percentage points of validation fit within which the simplest model wins
        (default 3: paper A kept ARX221 although ARX331 fitted 1.6 points better).
    gain_tolerance : float
        Largest relative difference between a model's DC gain (physical units)
        and the steady-state gain measured on the record (:func:`steady_state_gain`)
        for the model to be chosen (default 0.02). When no model within
        ``tolerance`` passes, or the record has too few long holds to measure
        the gain, the choice is by fit alone and ``reason`` says so.
    nonlinear : bool
        Add the nonlinear stage (step 8): ``servo`` and ``nonlinear`` stay None without it.
    limits_rpm : (float, float)
        Known input (command) and output saturations, ± in physical units, for
        the nonlinear model; they are not estimated.
    progress : callable, optional
        ``progress(done, total, label)`` after each stage (delay scan, each
        estimate, validation), for a progress bar.
    datasheet : dict, optional
        A wheel record: the wheel's datasheet values for the grey-box model
        (keys of :data:`DATASHEET`, missing ones the RW90's, paper A Table 1;
        ``{}`` for all of them). J and the current limit stay fixed; the rest
        start the fit. None (default): not a wheel, no grey box.
    current : array_like, shape (N,), optional
        The record's motor current (A) at the speed's instants: the grey box's
        second output (it makes kt and the friction observable).
    segments : sequence of (int, int), optional
        ``[i0, i1)`` sample ranges of the record's gap-free parts (e.g. from
        :func:`rwlab.testbed.load.gap_free_segments`); the samples between them are
        not used. Each part is an experiment of its own, as MATLAB's
        ``merge(iddata)``: the estimation part of every segment enters one estimate
        (the criteria summed, no regressor across a boundary); the delay scan, the
        validation and the nonlinear stage use the longest piece of their part, and
        the preprocessing takes its statistics from every estimation piece.
    wheel : bool, optional
        Whether the record is a reaction wheel's (speed command → speed): only a wheel's
        record gets the wheel-specific stages, the servo model (a rate-limited speed
        loop) and the grey box (a wheel's physics). None (default): a wheel when the
        output's unit is a rotation speed (:data:`SPEED_UNITS`, or a name that says
        it: a testbed record's or its exported CSV's ``speed_rpm``); a hair dryer, a
        furnace or a unitless file is not, and gets the linear study and the NLARX only.
        ``study.json``'s ``wheel_stages`` says which.
    nonlinear_models : bool
        Also fit the grey-box wheel and the NLARX (step 8, with ``nonlinear``). Off by
        default: they took over half of the study's time (the grey box alone 5 starts
        of a 50-substep simulation fit), and only ``rwlab compare``, the report and
        the GLR diagnosis's loop gain read them (which then takes the servo model's);
        ``nonlinear['not_fitted']`` says so.

    Returns
    -------
    StudyResult
        Every number of the report; ``to_dict()`` is ``study.json``. Its ``no_model_fits``
        is True when even the best validation fit is negative (every model is worse
        than the validation output's mean): ``rwlab identify`` then exits 1.
    """
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("the identification study needs a single-input single-output IOData")
    if preprocess not in PREPROCESSING:
        raise DataError(f"preprocess must be one of {PREPROCESSING}, got {preprocess!r}")
    orders = sorted({int(n) for n in orders})
    if not orders or orders[0] < 1:
        raise DataError(f"orders must be positive integers, got {orders}")
    worst = 2 * max(orders) + nk_max
    needed = math.ceil(10 * worst / min(split, 1 - split))
    if data.N < needed:
        Ts = data.Ts
        raise DataError(
            f"the record is too short for this study: {data.N} samples "
            f"({data.N * Ts:g} s at Ts = {Ts:g} s), but ARX{max(orders)}{max(orders)} with "
            f"delays up to {nk_max} needs at least {needed} samples, {needed * Ts:g} s (ten "
            "samples per parameter and lag in each part of the split); record an experiment "
            f"of at least {math.ceil(needed * Ts)} s, or (in Python) study lower orders "
            "(orders=, nk_max=)"
        )
    if not (math.isfinite(gain_tolerance) and gain_tolerance > 0):
        raise DataError(f"gain_tolerance must be a positive fraction, got {gain_tolerance!r}")
    pieces = _pieces(data.N, split, segments, needed_per_piece=worst + 2 * max(orders) + 2)
    prepared = _preprocessed(data, preprocess, split, pieces)
    est, val = prepared.split(split)
    fit_data: IOData | list[IOData] = est
    scan = est
    if pieces is not None:
        est_parts = [prepared[a:b] for a, b in pieces["est"]]
        fit_data = est_parts if len(est_parts) > 1 else est_parts[0]
        scan = max(est_parts, key=len)
        a, b = pieces["val"]
        val = prepared[a:b]
    total, done = len(orders) + 6 + int(nonlinear), 0

    def step(label: str) -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total, label)

    losses = delay_scan(scan, 2, 2, 0, nk_max)
    step("delay scan")
    nk = min(losses, key=lambda k: losses[k])
    if nk == 0:
        nk = 1 if losses.get(1, math.inf) <= losses[0] * 1.001 else 0

    models: dict[str, PolyModel] = {}
    rows = []
    for n in orders:
        m = arx(fit_data, n, n, nk)
        models[m.structure] = m
        rows.append({**_row(m, val), "na": n, "nb": n, "nk": nk, "loss": m.report["loss"]})
        step(m.structure)
    anchor = _estimation_gain(data, split, pieces)
    with contextlib.ExitStack() as stack:
        constrained = None
        if anchor is not None:  # refitted in a forked child while this process fits below
            scale = float(prepared.trend.input_scale[0] / prepared.trend.output_scale[0])
            refits = partial(_constrained_fits, fit_data, val, nk, orders, anchor["gain"] * scale)
            constrained = stack.enter_context(Forked(refits))
        others = []
        nk_pem = max(nk, 1)
        for name, estimate, args in (
            ("ARMAX", armax, (2, 2, 1, nk_pem)),
            ("OE", oe, (2, 2, nk_pem)),
            ("BJ", bj, (2, 1, 1, 2, nk_pem)),
        ):
            m = _try(estimate, fit_data, *args)
            if m is not None:
                models[m.structure] = m
                others.append(_row(m, val))
            step(name)
        fixed: list[dict] = []
        if constrained is not None:
            fixed, refitted = constrained.result()
            models.update(refitted)
    step("gain-constrained models")
    candidates = [r for r in rows + others + fixed if r["fit_percent"] is not None]
    if not candidates:
        raise EstimationError("no stable model was found; check the data and the delay")
    steady = steady_state_gain(data)
    for r in rows + others + fixed:
        _static_check(r, models[r["structure"]], prepared.trend, steady)
    pick, reason = _choose(candidates, tolerance, gain_tolerance, steady, anchor)
    chosen = models[pick["structure"]]

    residuals = {
        name: resid(models[name], val, max_lag=min(25, val.N // 2 - 1), initial=INITIAL).to_dict()
        for name in dict.fromkeys((pick["structure"], *(r["structure"] for r in others[:1])))
    }
    rng = np.random.default_rng(0)  # the continuous-time check's new input: fixed, reproducible
    new_u = _new_input(rng, scan, val.N)
    continuous = _continuous(chosen, new_u)
    step("validation")
    stages = _wheel_stages(data, wheel)
    result = StudyResult(
        data=prepared,
        est=est,
        val=val,
        preprocess=preprocess,
        delay={"nk": nk, "losses": losses},
        models=models,
        orders=rows,
        others=others,
        chosen=chosen,
        reason=reason,
        residuals=residuals,
        continuous=continuous,
        acceleration=_acceleration(chosen, val),
        new_input={"u": new_u},
        physical_val=data.split(split)[1] if pieces is None else data[slice(*pieces["val"])],
        segments=None if pieces is None else _segment_times(data, pieces["all"]),
        steady_state=steady,
        constrained=fixed,
        gain_constraint=anchor,
        chosen_name=pick["structure"],
        parts=_parts(chosen, scan, val),
        wheel_stages=stages,
        best_fit_percent=max(r["fit_percent"] for r in candidates),
        nonlinear_range=None if pieces is None else pieces["longest"],
    )
    if not nonlinear:
        return result
    result = nonlinear_stage(
        result,
        data,
        split=split,
        limits_rpm=limits_rpm,
        datasheet=datasheet,
        current=current,
        nonlinear_models=nonlinear_models,
    )
    step("nonlinear")
    return result


def nonlinear_stage(
    result: StudyResult,
    data: IOData,
    *,
    split: float = 0.7,
    limits_rpm: tuple[float, float] = (math.inf, math.inf),
    datasheet: dict | None = None,
    current=None,
    nonlinear_models: bool = False,
) -> StudyResult:
    """The study's step 8 on a study run with ``nonlinear=False``: the servo model of a
    wheel's record and, with ``nonlinear_models``, the grey box and the NLARX.

    :func:`identification_study` runs it last; ``rwlab identify`` runs it itself, to draw
    the report's figures of the linear study meanwhile.

    Parameters
    ----------
    result : StudyResult
        The study of ``data`` without its nonlinear stage.
    data : IOData
        The raw record the study was run on.
    split, limits_rpm, datasheet, current, nonlinear_models
        As given to :func:`identification_study`.

    Returns
    -------
    StudyResult
        ``result`` with ``servo``, ``nonlinear``, ``greybox`` and ``nlarx``.
    """
    physical, cur = data, current
    if result.nonlinear_range is not None:  # a record with gaps: one gap-free experiment
        a, b = result.nonlinear_range
        physical = data[a:b]
        cur = None if current is None else np.asarray(current, dtype=float)[a:b]
    servo, nl, grey, black = None, None, None, None
    stages = result.wheel_stages or _wheel_stages(data, None)  # a result made elsewhere
    if stages["run"]:
        trend = result.data.trend
        servo, nl = _nonlinear_stage(physical, split, result.chosen, trend, limits_rpm)
    else:
        nl = {"structure": "servo", "skipped": stages["why"]}
    if nonlinear_models:
        sheet = None if datasheet is None or not stages["run"] else {**DATASHEET, **datasheet}
        grey, black = _wheel_models(physical, split, servo, nl, sheet, cur)
    else:
        nl["not_fitted"] = NOT_FITTED
    return replace(result, servo=servo, nonlinear=nl, greybox=grey, nlarx=black)


NOT_FITTED = (
    "the grey-box wheel and the NLARX were not fitted (rwlab identify --nonlinear-models, "
    "or nonlinear_models=True, fits them)"
)
"""``nonlinear['not_fitted']`` of a study that left the grey box and the NLARX out."""

SPEED_UNITS = ("rpm", "rad/s", "deg/s", "rps")
"""Output units that make a record a wheel's (``identification_study``'s ``wheel=None``)."""


def _unit_in_name(name: str) -> str:
    """The unit a channel's name carries by the project's convention (``speed_rpm``:
    rpm; an exported record's CSV has no other), or ''."""
    suffixes = {"_rpm": "rpm", "_rad_s": "rad/s", "_deg_s": "deg/s", "_rps": "rps"}
    return next((u for sfx, u in suffixes.items() if name.lower().endswith(sfx)), "")


def _wheel_stages(data: IOData, wheel: bool | None) -> dict:
    """Whether the wheel-specific stages run on ``data``, and why (``study.json``)."""
    unit = data.output_units[0] or _unit_in_name(data.output_names[0])
    if wheel is None:
        wheel = unit.strip().lower() in SPEED_UNITS
        why = (
            f"the output's unit {unit!r} is a rotation speed: a wheel record"
            if wheel
            else f"not a wheel record: the output's unit {unit!r} is not a rotation speed "
            f"({', '.join(SPEED_UNITS)}); the servo and grey-box wheel models are not fitted"
        )
    else:
        why = "a wheel record, as the caller said" if wheel else "not a wheel, as the caller said"
    return {"run": bool(wheel), "why": why, "stages": ["servo", "greybox"]}


def _parts(chosen: PolyModel, est: IOData, val: IOData) -> dict:
    """How the estimation and validation parts differ, and what the chosen model makes of
    each: its simulation fit on both, the RMS input step and the output's spread (the
    parts' units: ratios between them do not depend on the preprocessing), and the share
    of samples slewing at ≥ 80 % of the fastest output rate of the two (a wheel at its
    rate or torque limit, which no linear model explains). ``note`` compares them when the
    validation fit is 5 points or more below the estimation fit."""
    # the fastest rate: the 99th percentile of |Δy|, so that one glitch does not set it
    fastest = float(np.quantile(np.abs(np.diff(np.concatenate([est.y[:, 0], val.y[:, 0]]))), 0.99))
    out: dict = {}
    for name, part in (("estimation", est), ("validation", val)):
        du, dy = np.diff(part.u[:, 0]), np.abs(np.diff(part.y[:, 0]))
        moved = du[du != 0]
        out[name] = {
            "fit_percent": compare(chosen, part, initial=INITIAL).fit_percent,
            "input_step_rms": float(np.sqrt(np.mean(moved**2))) if moved.size else 0.0,
            "output_std": float(np.std(part.y[:, 0])),
            "fast_share": float(np.mean(dy >= 0.8 * fastest)) if fastest > 0 else 0.0,
        }
    e, v = out["estimation"], out["validation"]
    out["note"] = None
    if e["fit_percent"] - v["fit_percent"] >= 5 and e["input_step_rms"] > 0:
        out["note"] = (
            f"the chosen model fits the estimation part at {e['fit_percent']:.1f} % and the "
            f"validation part at {v['fit_percent']:.1f} %; the validation part's input steps "
            f"are {v['input_step_rms'] / e['input_step_rms']:.2f}× the estimation part's "
            f"(RMS), its output spread {v['output_std'] / max(e['output_std'], 1e-300):.2f}×, "
            f"and its output slews at ≥ 80 % of the fastest rate in "
            f"{100 * v['fast_share']:.1f} % of its samples against {100 * e['fast_share']:.1f} %"
        )
    return out


def _segment_times(data: IOData, ranges) -> list[list[float]]:
    """``[t_start, t_end]`` (s) of the first and last sample of each range."""
    return [[data.tstart + a * data.Ts, data.tstart + (b - 1) * data.Ts] for a, b in ranges]


def _pieces(n: int, split: float, segments, needed_per_piece: int) -> dict | None:
    """The segments cut at the estimation/validation split: ``est`` (ranges of every
    estimation piece long enough to estimate from), ``val`` (the longest validation
    piece), ``longest`` (the longest segment); None without segments or with one whole."""
    if segments is None:
        return None
    ranges = [(int(a), int(b)) for a, b in segments]
    if (
        not ranges
        or any(not 0 <= a < b <= n for a, b in ranges)
        or any(b0 > a1 for (_, b0), (a1, _) in itertools.pairwise(ranges))
    ):
        raise DataError(f"segments must be ordered, disjoint sample ranges within 0..{n}")
    if ranges == [(0, n)]:
        return None
    k = round(split * n)
    est = [(a, min(b, k)) for a, b in ranges if min(b, k) - a >= needed_per_piece]
    val = [(max(a, k), b) for a, b in ranges if b - max(a, k) >= needed_per_piece]
    if not est or not val:
        raise DataError(
            f"the record's gap-free segments {ranges} leave no estimation or validation piece "
            f"of {needed_per_piece} samples at the split {split:g}; record again without gaps"
        )
    return {
        "est": est,
        "val": max(val, key=lambda r: r[1] - r[0]),
        "longest": max(ranges, key=lambda r: r[1] - r[0]),
        "all": ranges,
    }


def _simplicity(r: dict) -> tuple:
    """Fewest parameters of the structure, then ARX < ARMAX < OE < BJ, then a structure
    before its gain-constrained twin (an imposed gain is an assumption: the free
    estimate is preferred when its own gain agrees with the measured one)."""
    kind = _SIMPLICITY.index(_kind(r["structure"]))
    return (r["n_params"], kind, bool(r.get("gain_constrained")), -r["fit_percent"])


def _constrained_fits(fit_data, val: IOData, nk: int, orders, gain: float):
    """Every ARX order, ARMAX, OE and BJ again with the static gain ``gain`` (the data's
    units) imposed (:mod:`rwlab.ident.gain_constraint`): their rows, named ``…+K``, and
    their models by those names."""
    nk_pem = max(nk, 1)
    fits: list[tuple[Callable[..., PolyModel], tuple]] = [(arx, (n, n, nk)) for n in orders]
    fits += [(armax, (2, 2, 1, nk_pem)), (oe, (2, 2, nk_pem)), (bj, (2, 1, 1, 2, nk_pem))]
    rows, models = [], {}
    for estimate, args in fits:
        if estimate is arx:
            m = arx(fit_data, *args, dc_gain=gain)
        else:
            m = _try(estimate, fit_data, *args, dc_gain=gain)
        if m is None:
            continue
        name = study_name(m)
        models[name] = m
        row = {**_row(m, val), "structure": name, "gain_constrained": True}
        rows.append({**row, "n_params": m.n_params, "n_free": m.n_params - 1})
    return rows, models


def _choose(
    candidates: list[dict], tolerance: float, gain_tolerance: float, steady, anchor=None
) -> tuple:
    """The simplest row within ``tolerance`` of the best fit whose DC gain passes; why.

    When no row within that window passes the gain check, the window moves down to
    the best-fitting row that does (the simplest within ``tolerance`` of it is chosen,
    and the reason states the fit given up); only when no row fitting at least
    :data:`POOR_FIT` passes is the choice the nearest gain within the first window."""
    best = max(r["fit_percent"] for r in candidates)
    near = sorted((r for r in candidates if r["fit_percent"] >= best - tolerance), key=_simplicity)
    limit = 100 * gain_tolerance
    ok = [r for r in near if _gain_error(r) <= limit]
    top = best
    if steady is not None and not ok:  # beyond the window: the best that passes, if any
        passing = [
            r for r in candidates if _gain_error(r) <= limit and r["fit_percent"] >= POOR_FIT
        ]
        if passing:
            top = max(r["fit_percent"] for r in passing)
            ok = sorted(
                (r for r in passing if r["fit_percent"] >= top - tolerance), key=_simplicity
            )
            near = ok
    if steady is None:
        pick = near[0]
    elif ok:
        pick = ok[0]
    else:  # none passes: the nearest gain, not the simplest (a tighter tolerance never
        # chooses a worse gain than a looser one)
        pick = min(near, key=_gain_error)
    reason = (
        f"{pick['structure']} is the simplest model (fewest parameters: {pick['n_params']}; "
        "then ARX < ARMAX < OE < BJ, a free model before its gain-constrained twin +K) "
        f"whose validation fit ({pick['fit_percent']:.2f} %) "
        f"is within {tolerance:g} points of the best ({best:.2f} %)"
    )
    if top < best:
        reason = (
            f"no model within {tolerance:g} points of the best validation fit ({best:.2f} %) "
            f"has a DC gain within {limit:g} % of the measured steady-state gain "
            f"{steady['gain']:.4f}; the best-fitting model whose gain does fits {top:.2f} % "
            f"({best - top:.2f} points below the best), and {pick['structure']} is the "
            f"simplest within {tolerance:g} points of it (fit {pick['fit_percent']:.2f} %, "
            f"DC gain {_dc_text(pick)}; passed over for their gain: "
            + ", ".join(
                f"{r['structure']} ({_dc_text(r)})"
                for r in candidates
                if r["fit_percent"] >= best - tolerance
            )
            + ")"
        )
        if pick.get("gain_constrained") and anchor is not None:
            reason += "; " + _constraint_text(pick, anchor, candidates)
        return pick, reason + _paper_text(pick, candidates, best)
    if steady is None:
        reason += "; the record has too few settled holds to check the DC gain"
        return pick, reason + _paper_text(pick, candidates, best)
    g = steady["gain"]
    if not ok:
        return pick, reason + (
            f"; no such model's DC gain is within {limit:g} % of the measured steady-state "
            f"gain {g:.4f}: the one nearest it is chosen ({_dc_text(pick)})"
            + _paper_text(pick, candidates, best)
        )
    skipped = near[: near.index(pick)]
    reason += f" and whose DC gain ({_dc_text(pick)}) is within {limit:g} % of the measured "
    reason += f"steady-state gain {g:.4f} ({steady['holds']} settled holds of the whole record)"
    if skipped:
        reason += "; passed over for a DC gain off the measured one: " + ", ".join(
            f"{r['structure']} ({_dc_text(r)})" for r in skipped
        )
    if pick.get("gain_constrained") and anchor is not None:
        reason += "; " + _constraint_text(pick, anchor, candidates)
    return pick, reason + _paper_text(pick, candidates, best)


POOR_FIT = 50.0
"""Validation fit, %, below which the choice comes with a warning that no model is good."""


def _gain_error(row: dict) -> float:
    """|DC gain error| of a row, %; a model without a DC gain (a pole at 1) is the farthest."""
    err = row.get("dc_gain_error_percent")
    return math.inf if err is None else abs(err)


def _paper_text(pick: dict, candidates: list[dict], best: float) -> str:
    """Why paper A's ARX221 (and its +K twin) was not chosen, when it was not; a warning
    when even the best model fits poorly."""
    if best < POOR_FIT:
        return (
            f"; no model is good: the best validation fit is {best:.2f} % (a record that "
            "does not excite the wheel's dynamics, e.g. a chirp too fast for it, or a wheel "
            "beyond its linear range)"
        )
    if pick["structure"] in (PAPER_STRUCTURE, PAPER_STRUCTURE + CONSTRAINED):
        return ""
    named = {r["structure"]: r for r in candidates}
    parts = [
        f"{name} fits {named[name]['fit_percent']:.2f} % "
        f"({best - named[name]['fit_percent']:.2f} points below the best), DC gain "
        f"{_dc_text(named[name])}"
        for name in (PAPER_STRUCTURE, PAPER_STRUCTURE + CONSTRAINED)
        if name in named
    ]
    if not parts:
        return f"; paper A's {PAPER_STRUCTURE} is unstable or failed on this record"
    return f"; paper A's choice is not: {'; '.join(parts)}"


PAPER_STRUCTURE = "ARX221"
"""Paper A's chosen structure, which the reason discusses when another is chosen."""


def _constraint_text(pick: dict, anchor: dict, candidates: list[dict]) -> str:
    """What imposing the gain did: K and its source, and the unconstrained twin's numbers."""
    text = (
        f"static gain constrained to K = {anchor['gain']:.4f} ± {anchor['gain_std']:.4f} "
        f"measured on {anchor['holds']} settled holds of the estimation part (its DC gain "
        "agrees with the whole record's by construction, up to that difference; the "
        "model's covariance holds its dynamics given K, so its static gain's uncertainty "
        "is K's)"
    )
    name = pick["structure"].removesuffix(CONSTRAINED)
    twin = next((r for r in candidates if r["structure"] == name), None)
    if twin is None:
        return text + f"; its unconstrained twin {name} is unstable or failed"
    delta = pick["fit_percent"] - twin["fit_percent"]
    text += (
        f"; its unconstrained twin {name} fits {twin['fit_percent']:.2f} % with DC gain "
        f"{_dc_text(twin)}: the constraint "
        + (f"costs {-delta:.2f} points of fit" if delta < 0 else f"adds {delta:.2f} points of fit")
    )
    return text


def _dc_text(row: dict) -> str:
    if row.get("dc_gain") is None:
        return "none: a pole at 1"
    return f"{row['dc_gain']:.4f}, {row['dc_gain_error_percent']:+.1f} %"


def _static_check(row: dict, model: PolyModel, trend, steady) -> None:
    """Add the model's DC gain in physical units (and its error against ``steady``) to ``row``."""
    den = float(np.sum(model.A) * np.sum(model.F))
    scale = float(trend.output_scale[0] / trend.input_scale[0])
    dc = float(np.sum(model.B)) * scale / den if abs(den) > 1e-12 else None
    row["dc_gain"] = dc if dc is not None and math.isfinite(dc) else None
    row["dc_gain_error_percent"] = (
        None
        if row["dc_gain"] is None or steady is None
        else 100.0 * (row["dc_gain"] / steady["gain"] - 1.0)
    )


def steady_state_gain(
    data: IOData, *, min_hold: float = 30.0, tail: float = 5.0, settled: float = 0.01
) -> dict | None:
    """The static gain measured on a record: settled output against input over its long holds.

    Every hold of the input at least ``min_hold`` long gives one point: the input
    level and the mean output over the hold's last ``tail`` seconds, kept when the
    output has settled there: its range over the tail within ``settled`` of the
    input's whole range (a wheel still ramping at its acceleration limit is not),
    and its mean over the tail within a tenth of that of its mean over the tail
    before (a wheel still closing in on the level after an overshoot is not: its
    last mean would bias the gain).
    The gain is the least-squares slope through these points (with an intercept,
    as the physical model ``y − y0 = G·(u − u0)`` has).

    Parameters
    ----------
    data : IOData
        SISO record in physical units (e.g. command rpm → speed rpm).
    min_hold : float
        Shortest hold used, s (30 s: five closed-loop time constants of the RW90).
    tail : float
        Averaging window at the end of each hold, s.
    settled : float
        Largest output range over the tail, as a fraction of the input's range.

    Returns
    -------
    dict or None
        ``gain`` (output units per input unit), ``gain_std`` (its standard error),
        ``intercept``, ``holds`` (points used) and the settings; None when fewer
        than 3 settled holds at two or more levels exist.
    """
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("steady_state_gain needs a single-input single-output IOData")
    settings = {"min_hold": min_hold, "tail": tail, "settled": settled}
    return _gain_from_holds(*_hold_points(data, **settings), min_hold=min_hold, tail=tail)


def _hold_points(
    data: IOData, *, min_hold: float, tail: float, settled: float, span: float | None = None
) -> tuple[list[float], list[float]]:
    """(input level, settled mean output) of every long settled hold of ``data``."""
    u, y = data.u[:, 0], data.y[:, 0]
    edges = np.flatnonzero(np.diff(u) != 0) + 1
    bounds = np.concatenate([[0], edges, [u.size]])
    n_tail = max(1, round(tail / data.Ts))
    span = float(np.ptp(u)) if span is None else span
    levels, speeds = [], []
    for a, b in itertools.pairwise(bounds):
        if (b - a) * data.Ts < min_hold or b - a < 2 * n_tail:
            continue
        end, before = y[b - n_tail : b], y[b - 2 * n_tail : b - n_tail]
        drift = abs(end.mean() - before.mean())
        if np.ptp(end) <= settled * span and drift <= 0.1 * settled * span:
            levels.append(float(u[a]))
            speeds.append(float(end.mean()))
    return levels, speeds


def _gain_from_holds(levels, speeds, *, min_hold: float, tail: float) -> dict | None:
    """The least-squares line through the hold points, with the slope's standard error."""
    if len(levels) < 3 or np.ptp(levels) == 0:
        return None
    x, z = np.asarray(levels), np.asarray(speeds)
    slope, intercept = np.polyfit(x, z, 1)
    spread = float(np.sum((x - x.mean()) ** 2))
    rss = float(np.sum((z - intercept - slope * x) ** 2))
    return {
        "gain": float(slope),
        "gain_std": math.sqrt(rss / (len(x) - 2) / spread) if len(x) > 2 else None,
        "intercept": float(intercept),
        "holds": len(levels),
        "min_hold_s": min_hold,
        "tail_s": tail,
        "method": "least-squares slope of the mean output over the last tail_s of every "
        "settled input hold of at least min_hold_s, against the held input; gain_std its "
        "standard error from the scatter about the line",
    }


def _estimation_gain(data: IOData, split: float, pieces) -> dict | None:
    """The steady-state gain measured on the estimation part alone (every estimation piece
    with segments): what a gain-constrained model may be given without the validation
    part informing it. None when that part has fewer than 3 settled holds."""
    parts = [data.split(split)[0]] if pieces is None else [data[a:b] for a, b in pieces["est"]]
    span = float(max(np.ptp(p.u[:, 0]) for p in parts))
    levels, speeds = [], []
    for part in parts:
        x, z = _hold_points(part, min_hold=30.0, tail=5.0, settled=0.01, span=span)
        levels += x
        speeds += z
    out = _gain_from_holds(levels, speeds, min_hold=30.0, tail=5.0)
    if out is not None:
        out["part"] = "estimation"
    return out


def wheel_datasheet(spec: WheelSpec) -> dict:
    """A wheel model's datasheet values the grey box fixes or starts from.

    Parameters
    ----------
    spec : WheelSpec
        The wheel model.

    Returns
    -------
    dict
        inertia, torque_constant, current_limit, coulomb, viscous, accel_limit_rpm_s,
        max_speed_rpm (SI, rpm), and wheel_model (the spec's name: whose grey-box
        structure-error envelope).
    """
    return {
        "inertia": spec.inertia_kg_m2,
        "torque_constant": spec.torque_constant_nm_a,
        "current_limit": spec.current_limit_a,
        "coulomb": spec.coulomb_friction_nm,
        "viscous": spec.viscous_friction_nm_s,
        "accel_limit_rpm_s": spec.max_accel_rpm_s,
        "max_speed_rpm": spec.max_speed_rpm,
        "wheel_model": spec.name,
    }


_RW90 = WheelSpec.load("rw90")
DATASHEET = wheel_datasheet(_RW90)
"""The RW90's datasheet values (its spec, rw90.toml): the grey box's values for a record
that names no wheel model."""


def _wheel_models(data, split, servo, nl, datasheet, current) -> tuple:
    """The grey-box wheel and the NLARX on the physical estimation part, scored on the
    validation part (simulation from its first measured speed); the better one is
    ``nl['chosen']``. Adds ``nl['greybox']`` and ``nl['nlarx']``."""
    est, val = data.split(split)
    out: dict = {}
    grey = black = None
    kp, ki = 0.5, 0.1
    if servo is not None:
        kp, ki = servo.kp, servo.ki
    if datasheet is not None:
        try:
            i_est = None if current is None else np.asarray(current, dtype=float)[: est.N]
            grey = greybox_fit(est, kp=kp, ki=ki, current=i_est, **datasheet)
            out["greybox"] = _nonlinear_row(grey, val)
        except (EstimationError, ModelError, DataError) as exc:
            out["greybox"] = {"error": str(exc)}
    try:
        black = nlarx(est)
        out["nlarx"] = _nonlinear_row(black, val)
    except (EstimationError, ModelError, DataError) as exc:
        out["nlarx"] = {"error": str(exc)}
    scored = {k: v["fit_percent"] for k, v in out.items() if v.get("fit_percent") is not None}
    failed = [f"{k} failed ({v['failed']})" for k, v in out.items() if v.get("failed")]
    if failed:
        out["failed"] = failed
    if scored:
        best = max(scored, key=lambda k: scored[k])
        out["chosen"] = best
        out["choice"] = (
            f"{best}: the better simulation fit on the validation part "
            + ", ".join(f"{k} {v:.2f} %" for k, v in scored.items())
            + "".join(f"; {f}" for f in failed)
        )
    nl.update(out)
    return grey, black


def _nonlinear_row(model, val: IOData) -> dict:
    """A nonlinear model's validation row; ``failed`` (and no fit, so it is neither ranked
    nor chosen) when its simulation diverged (:func:`_divergence`)."""
    yhat = model.predict(val, np.inf, initial="steady")
    y = val.y[:, 0]
    row = {
        "structure": model.structure,
        "fit_percent": None,
        "n_params": model.n_params,
        "parameters": model.to_dict(),
        "initial_conditions": "the validation part's first measured speed, loop integral 0",
    }
    failed = _divergence(y, yhat)
    if failed is not None:
        return {**row, "failed": failed}
    return {**row, "fit_percent": fit_percent(y, yhat)}


DIVERGED_SPANS = 1.0
"""A simulation that leaves the measured output's range by more than this many times its
span has diverged: no bounded system it models does that on an input within the
estimation data's range. A wheel's speed beyond twice the span it was seen to cover is
not a prediction of it."""


def _divergence(y: np.ndarray, yhat: np.ndarray) -> str | None:
    """Why the simulation ``yhat`` of the measured ``y`` diverged, or None when it did not."""
    if not np.all(np.isfinite(yhat)):
        k = int(np.flatnonzero(~np.isfinite(yhat))[0])
        return f"diverged: the simulation is not finite from sample {k} of the validation part"
    lo, hi = float(np.min(y)), float(np.max(y))
    span = max(hi - lo, float(np.max(np.abs(y))), np.finfo(float).tiny)
    beyond = float(max(np.max(yhat) - hi, lo - np.min(yhat), 0.0))
    if beyond <= DIVERGED_SPANS * span:
        return None
    return (
        f"diverged: the simulation reaches {beyond / span:.3g} times the measured span "
        f"({span:.4g}) beyond the measured range [{lo:.4g}, {hi:.4g}] (fit "
        f"{fit_percent(y, yhat):.3g} %); not ranked, not chosen"
    )


def _preprocessed(data: IOData, preprocess: str, split: float, pieces=None) -> IOData:
    """``data`` preprocessed with the statistics of its estimation part only (of its
    estimation pieces, with segments: never of the stale samples in a gap)."""
    if preprocess == "none":
        return data
    reference = data.split(split)[0]
    if pieces is not None:
        rows = np.concatenate([np.arange(a, b) for a, b in pieces["est"]])
        reference = IOData(data.u[rows], data.y[rows], data.Ts)
    if preprocess == "detrend":
        return data.detrend(reference=reference)
    if preprocess == "scale":
        return data.scale(reference=reference)
    return data.normalize(reference=reference)


def _nonlinear_stage(data, split, chosen, trend, limits) -> tuple[ServoModel | None, dict]:
    """Fit the servo model in physical units from the chosen model; score it on validation.

    Fit % uses the study's 'steady' initial state, as every linear row. The
    residuals are simulation errors (an output-error model predicts by
    simulating) from the initial state fitted to the validation output: the
    validation part starts in motion, and the loop's integral state cannot be
    read off one sample the way a linear model's past outputs can.
    """
    est, val = data.split(split)
    if np.any(trend.input_slope) or np.any(trend.output_slope):
        return None, {"structure": "servo", "error": "needs offsets and scales, not a trend"}
    u_lim, y_lim = (-limits[0], limits[0]), (-limits[1], limits[1])
    try:
        servo = servo_fit(est, _to_physical(chosen, trend), input_limits=u_lim, output_limits=y_lim)
    except (EstimationError, ModelError, DataError) as exc:
        return None, {"structure": "servo", "error": str(exc)}
    cmp = compare(servo, val, initial=INITIAL)
    res = resid(servo, val, max_lag=min(25, val.N // 2 - 1), initial="estimate")
    hi = float(np.max(np.abs(est.y[:, 0])))
    return servo, {
        "structure": "servo",
        "equations": "rwlab.ident.nonlinear (module docstring)",
        "fit_percent": cmp.fit_percent,
        "mse": cmp.mse,
        "n_params": servo.n_params,
        "accel_limit_rpm_s": servo.rate_limit,
        "speed_limit_rpm": limits[1] if math.isfinite(limits[1]) else None,
        "speed_limit_estimated": False,
        "speed_limit_note": f"not estimated: the estimation data reach {hi:.0f}, "
        "short of any limit; the value is the record's",
        "parameters": servo.to_dict(),
        "initial_conditions": {"fit_percent": INITIAL, "residuals": "estimate"},
        "residuals": res.to_dict(),
    }


def _new_input(rng, est: IOData, n: int) -> np.ndarray:
    """A new piecewise-constant input with the estimation data's range (Fig. 23)."""
    lo, hi = float(est.u.min()), float(est.u.max())
    holds = rng.integers(5, 30, size=n)
    levels = rng.uniform(lo, hi, size=n)
    return np.repeat(levels, holds)[:n]


def _continuous(model: PolyModel, u: np.ndarray) -> dict:
    """d2c by ZOH and Tustin; simulate both on ``u`` (held) and compare with the discrete model."""
    y_d = model.simulate(u)
    out: dict = {"tf": {}, "methods": {}}
    for method in ("zoh", "tustin"):
        try:
            g = model.d2c(method, pade_order=3 if method == "zoh" else None)
        except ModelError as exc:
            out["methods"][method] = {"error": str(exc)}
            continue
        t = np.arange(len(u)) * model.Ts
        # the held input's exact response at the samples: the continuous model
        # discretized by ZOH, whatever method made it
        y_c = control.forced_response(control.c2d(g, model.Ts, "zoh"), U=u).outputs
        out["tf"][method] = g
        out["methods"][method] = {
            "num": np.asarray(g.num[0][0]).tolist(),
            "den": np.asarray(g.den[0][0]).tolist(),
            "fit_to_discrete_percent": fit_percent(y_d, y_c) if np.ptp(y_d) > 0 else None,
            "max_abs_difference": float(np.max(np.abs(y_d - y_c))),
            "t": t.tolist(),
            "y": y_c.tolist(),
        }
    out["discrete"] = y_d.tolist()
    return out


def _acceleration(model: PolyModel, val: IOData) -> dict:
    """Model speed change per second vs the measured one on validation data (Fig. 24).

    In physical units (output unit per second, rpm/s for a wheel record), not
    the preprocessed ones.
    """
    acc_meas, acc_model = acceleration_pair(model, val)
    corr = float(np.corrcoef(acc_model, acc_meas)[0, 1]) if np.std(acc_meas) > 0 else float("nan")
    return {
        "correlation": corr,
        "fit_percent": fit_percent(acc_meas, acc_model) if np.ptp(acc_meas) > 0 else None,
        "rms_measured": float(np.sqrt(np.mean(acc_meas**2))),
        "rms_model": float(np.sqrt(np.mean(acc_model**2))),
    }


def acceleration_pair(model: PolyModel, val: IOData) -> tuple[np.ndarray, np.ndarray]:
    """Measured and simulated output change per second on ``val``, in physical units."""
    t = val.time
    measured = val.trend.output_to_physical(val.y[:, 0], t)
    simulated = val.trend.output_to_physical(model.simulate(val, initial=INITIAL), t)
    return np.diff(measured) / val.Ts, np.diff(simulated) / val.Ts


def physical_model(
    result: StudyResult,
    *,
    speed_limit_rpm: float = _RW90.max_speed_rpm,
    accel_limit_rpm_s: float = _RW90.max_accel_rpm_s,
    saturation_source: str = "RW90 spec (rw90.toml)",
    wheel_spec: WheelSpec | None = None,
) -> dict:
    """The JSON form of :func:`wheel_model` (``model.json``), same arguments.

    Parameters
    ----------
    result, speed_limit_rpm, accel_limit_rpm_s, saturation_source, wheel_spec
        As for :func:`wheel_model`.

    Returns
    -------
    dict
        ``model.json``'s content (schema ``model``).
    """
    return wheel_model(
        result,
        speed_limit_rpm=speed_limit_rpm,
        accel_limit_rpm_s=accel_limit_rpm_s,
        saturation_source=saturation_source,
        wheel_spec=wheel_spec,
    ).to_dict()


def wheel_model(
    result: StudyResult,
    *,
    speed_limit_rpm: float = _RW90.max_speed_rpm,
    accel_limit_rpm_s: float = _RW90.max_accel_rpm_s,
    saturation_source: str = "RW90 spec (rw90.toml)",
    wheel_spec: WheelSpec | None = None,
) -> WheelModelFile:
    """The chosen model in physical units, with the saturations any control use needs.

    The study's model maps preprocessed input to preprocessed output. With
    ``u_p = (u − u_off)/u_scale`` and ``y = y_off + y_scale·y_p``, the physical
    model is ``y − y_off = G(q)·(u − u_off)`` with G's numerator scaled by
    ``y_scale/u_scale``; ``model.json`` stores G and both offsets, ``y_off`` the
    wheel's measured static speed at ``u_off`` where the record has settled holds
    (an equilibrium, so the model's static map is the wheel's).

    Parameters
    ----------
    result : StudyResult
        The study.
    speed_limit_rpm, accel_limit_rpm_s : float
        The wheel's saturations, rpm and rpm/s.
    saturation_source : str
        Where they come from.
    wheel_spec : WheelSpec, optional
        The wheel model the record came from (travels with the model).

    Returns
    -------
    WheelModelFile
        The content of ``model.json`` (``.save(path)`` writes it).
    """
    m = result.chosen
    trend = result.data.trend
    if np.any(trend.input_slope) or np.any(trend.output_slope):
        raise ModelError("a linear trend cannot be folded into model.json; use 'normalize'")
    d = result.data
    fit = next(r["fit_percent"] for r in result.rows if r["structure"] == result.chosen_name)
    nl = result.nonlinear or {}
    servo_fit = None if result.servo is None or not nl else nl["fit_percent"]
    others = {
        name: {**model.to_dict(), "validation_fit_percent": nl[name]["fit_percent"]}
        for name, model in (("greybox", result.greybox), ("nlarx", result.nlarx))
        if model is not None and nl.get(name, {}).get("fit_percent") is not None
    }
    return WheelModelFile(
        _to_physical(m, trend, d.input_names[0], d.output_names[0]),
        Channel(d.input_names[0], d.input_units[0] or "rpm", float(trend.input_offset[0])),
        Channel(d.output_names[0], d.output_units[0] or "rpm", _output_offset(result)),
        speed_limit_rpm=speed_limit_rpm,
        accel_limit_rpm_s=accel_limit_rpm_s,
        saturation_source=saturation_source,
        validation_fit_percent=fit,
        servo=result.servo,
        servo_fit_percent=servo_fit,
        preferred="nonlinear" if servo_fit is not None and servo_fit > fit else "linear",
        nonlinear_models=others,
        nonlinear_chosen=nl.get("chosen"),
        nonlinear_choice=nl.get("choice"),
        data_segments=None
        if result.segments is None
        else tuple((float(a), float(b)) for a, b in result.segments),
        wheel_spec=wheel_spec,
    )


def _output_offset(result: StudyResult) -> float:
    """The output offset ``model.json`` stores with the input offset u₀: the measured static
    line at u₀ (the estimation part's settled holds, else the whole record's), so that
    (u₀, y₀) is an equilibrium of the wheel and the model at rest reads what the wheel
    does. The estimation means are no equilibrium of a rate-limited wheel (its speed lags
    the command on every slew): a model without intercept between them settled at −286
    rpm for a zero command on the twin. Without settled holds: the estimation mean."""
    trend = result.data.trend
    line = result.gain_constraint or result.steady_state
    if line is None:
        return float(trend.output_offset[0])
    return float(line["gain"] * trend.input_offset[0] + line["intercept"])


def _to_physical(m: PolyModel, trend, input_name: str = "u", output_name: str = "y") -> PolyModel:
    """The preprocessed model ``m`` between the physical signals (offsets aside)."""
    gain = float(trend.output_scale[0] / trend.input_scale[0])
    report = {}
    if "dc_gain" in m.report:  # say that the static gain was imposed, in physical units
        report = {"method": m.report["method"], "dc_gain": m.report["dc_gain"] * gain}
    return PolyModel(
        m.A,
        m.B * gain,
        m.C,
        m.D,
        m.F,
        Ts=m.Ts,
        nk=m.nk,
        noise_variance=None
        if m.noise_variance is None
        else m.noise_variance * trend.output_scale[0] ** 2,
        input_name=input_name,
        output_name=output_name,
        report=report,
    )


def load_current(
    path: str, Ts: float | None = None, *, gaps: str = "refuse", reader=None
) -> np.ndarray | None:
    """The motor current (A) of a testbed record at the speed's instants, or None
    for a file without one (the grey box then fits the speed alone).

    Parameters
    ----------
    path : str
        A record (``.mcap``); other files give None.
    Ts : float, optional
        Sample time, s (the record's own by default).
    gaps : {'refuse', 'split'}
        ``split``: read a record with telemetry gaps whole (see :func:`load_study_data`).
    reader : callable, optional
        As for :func:`load_study_data`.
    """
    from pathlib import Path

    if Path(path).suffix.lower() != ".mcap":
        return None
    extra = {"max_gap": math.inf} if gaps == "split" else {}
    try:
        columns = {"input_columns": "command", "output_columns": "current_a"}
        return _reader(path, reader)(Ts, **columns, **extra).y[:, 0]
    except DataError:
        return None


def load_study_data(
    path: str,
    Ts: float | None = None,
    *,
    input_col: str | None = None,
    output_col: str | None = None,
    max_orders: int = 5,
    nk_max: int = 10,
    gaps: str = "refuse",
    reader=None,
) -> tuple[IOData, dict]:
    """Read a testbed record (``.mcap``), an exported or other data file, or a bundled set.

    ``input_col``/``output_col`` choose the columns (a record's default is
    command → speed_rpm). Returns the data and the saturations to store with
    the model: from the record's driver settings when present, else the RW90
    defaults; ``current_limit_a`` (a record's only) is the driver's current limit (A). A
    record whose telemetry has a gap longer than one sample time, or a ``Ts`` shorter than
    its telemetry period, is refused (``DataError``): its samples there would repeat a
    stale frame, and the estimates take that hold for wheel dynamics (a 2-s dropout in
    a 600-s PRBS turned ARX221 into ARX222 and the RW90's rate limit into 8499 rpm/s).
    With ``gaps="split"`` such a record is read whole, stale samples included: the caller
    identifies its gap-free parts as separate experiments (``identification_study``'s
    ``segments``, from :func:`rwlab.testbed.load.gap_free_segments`).
    ``reader(Ts, **options) -> IOData`` reads a ``.mcap`` in place of
    :func:`rwlab.data.load` of ``path``: a caller that decoded the record already
    (``rwlab identify`` reads it once for the study, the current and the healthy
    reference) passes one that samples it.
    """
    if gaps not in ("refuse", "split"):
        raise DataError(f"gaps must be 'refuse' or 'split', got {gaps!r}")
    from pathlib import Path

    from rwlab import datasets
    from rwlab.data import load

    saturation = {
        "speed_limit_rpm": _RW90.max_speed_rpm,
        "accel_limit_rpm_s": _RW90.max_accel_rpm_s,
        "saturation_source": "the RW90 spec (rw90.toml): the file names no wheel",
    }
    columns = {"input_columns": input_col, "output_columns": output_col}
    if Path(path).suffix.lower() == ".mcap":
        from rwlab.errors import RecordGapError

        read = _reader(path, reader)
        try:
            try:  # no max_gap: every gap and a too-fine Ts refused
                data = read(Ts, **columns)
            except RecordGapError:
                if gaps != "split":
                    raise
                # Ts was accepted before the gaps were found: read it whole
                data = read(Ts, **columns, max_gap=math.inf)
        except RecordGapError as exc:
            raise RecordGapError(
                f"{str(exc).partition(' Pass max_gap')[0]} Identification refuses a record "
                "with gaps: the held samples would be fitted as wheel dynamics. Record again, "
                "or identify its gap-free parts as separate experiments (--gaps split)."
            ) from None
        # the driver's configured limits, as a lab knows them (records before
        # driver_settings: the twin's own parameters)
        wheel = data.source.get("driver_settings") or data.source.get("wheel", {})
        if "max_speed_rpm" in wheel:
            saturation = {
                "speed_limit_rpm": float(wheel["max_speed_rpm"]),
                "accel_limit_rpm_s": float(wheel["max_accel_rpm_s"]),
                "saturation_source": "the record's driver settings",
            }
        if "current_limit" in wheel:
            saturation["current_limit_a"] = float(wheel["current_limit"])
        if isinstance(data.source.get("wheel_spec"), dict):  # the wheel model, as configured
            saturation["wheel_spec"] = WheelSpec.from_dict(
                data.source["wheel_spec"], f"{path}: wheel_spec"
            )
        return data, saturation
    if not Path(path).exists() and path in datasets.NAMES:
        if input_col or output_col:
            raise DataError(f"{path} is a bundled data set: it has one input and one output")
        return datasets.get(path), saturation
    from rwlab.datafiles import check_magnitude

    return check_magnitude(load(path, Ts, **columns), path), saturation


def _reader(path: str, reader=None) -> Callable[..., IOData]:
    """``reader``, or one that reads ``path`` with :func:`rwlab.data.load`."""
    if reader is not None:
        return reader
    from rwlab.data import load

    return lambda Ts, **options: load(path, Ts, **options)
