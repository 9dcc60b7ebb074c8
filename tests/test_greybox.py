"""The physical grey-box wheel and the nonlinear ARX, judged on twin wheels they were not fit on."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import DataError, ModelError
from rwlab.ident import arx, fit_percent
from rwlab.ident.greybox import RPM, Uncertainty, WheelGreyBox, clamp_visible, greybox_fit
from rwlab.ident.nlarx import NLARXModel, nlarx
from rwlab.ident.study import DATASHEET
from rwlab.signals import prbs, rate_limit
from rwlab.wheel import RW90, IdentifiedWheel
from rwlab.wheel.physics import IDEAL, Mode, WheelPhysics

TS = 0.5


def _record(params, seed: int, minutes: float = 8.0) -> tuple[IOData, np.ndarray]:
    """A rate-limited PRBS into the twin (no bus): speed (rpm) and current (A) measured
    before each command, as a testbed record has them."""
    u = prbs(minutes * 60, TS, 6000.0, 5.0, seed=seed)
    return _run(params, seed, rate_limit(u, 314.0, TS, initial=0.0))


def _run(params, seed: int, u: np.ndarray) -> tuple[IOData, np.ndarray]:
    wheel = WheelPhysics(params, seed)
    y, current = np.empty(u.size), np.empty(u.size)
    for k, c in enumerate(u):
        y[k], current[k] = wheel.measured_speed_rpm(), wheel.measured_current()
        wheel.command(Mode.SPEED, c)
        for _ in range(100):
            wheel.step(TS / 100)
    return IOData(u, y, TS, input_names="command", output_names="speed_rpm"), current


@pytest.fixture(scope="module")
def unit_a():
    """A drawn unit of the ideal twin (exact dynamics, no stiction): kt ±5 %, friction ±30 %."""
    return IDEAL.for_unit(4)


@pytest.fixture(scope="module")
def grey(unit_a):
    data, current = _record(unit_a, 1)
    est = data.split(0.7)[0]
    return greybox_fit(est, kp=0.4, ki=0.08, current=current[: est.N], **DATASHEET), data


def test_greybox_recovers_the_units_physics_and_its_loop(grey, unit_a):
    model, _ = grey
    # speed and current make kt/J, τc/kt and b/kt observable: J stays at the datasheet value
    assert model.inertia == DATASHEET["inertia"]
    ratio = model.torque_constant / model.inertia
    true_ratio = unit_a.torque_constant / unit_a.inertia
    assert ratio == pytest.approx(true_ratio, rel=0.01)
    # friction where the wheel runs (3000 rpm): Coulomb and viscous apart trade off
    # (sign ω and ω are nearly collinear over a PRBS that seldom crosses zero)
    j = unit_a.inertia / model.inertia  # the model's torques are in units of its J
    w = 3000 * RPM
    friction = (model.coulomb + model.viscous * w) * j
    truth = unit_a.coulomb_friction + unit_a.viscous_friction * w
    assert friction == pytest.approx(truth, rel=0.15)
    assert model.kp == pytest.approx(unit_a.speed_kp, rel=0.05)
    assert model.ki == pytest.approx(unit_a.speed_ki, rel=0.05)
    assert model.accel_limit / RPM == pytest.approx(unit_a.max_accel_rpm_s, rel=0.01)
    estimated = {"torque_constant", "coulomb", "breakaway", "viscous", "accel_limit", "kp", "ki"}
    assert set(model.std) | set(model.unidentified) == estimated
    assert not set(model.std) & set(model.unidentified)
    # the ideal twin has no stiction (breakaway = Coulomb): nothing in the record shows it
    assert model.unidentified == ("breakaway",) and model.breakaway == model.coulomb
    assert all(v > 0 and math.isfinite(v) for v in model.std.values())


@pytest.mark.slow  # two grey-box fits on a 20-minute twin record, twice
@pytest.mark.parametrize("stiction", [False, True])
def test_slow_reversals_cannot_tell_stiction_from_its_absence(stiction):
    # a ±600 rpm square wave at 20 rpm/s dwells at rest on every reversal. The raw fit
    # (no structure term on breakaway) reads a breakaway above the unit's truth with and
    # without the stiction band (the Hall speed's dwell at rest looks like stiction:
    # bench/greybox_breakaway.py), so with its measured structure term the default fit
    # cannot tell it from Coulomb and reports it unidentified, held at Coulomb
    unit = replace(RW90, stiction=stiction, breakaway_friction=4e-4).for_unit(20)
    t = np.arange(0.0, 1200.0, TS)
    u = rate_limit(600.0 * np.sign(np.sin(2 * np.pi * t / 120.0)), 20.0, TS, initial=0.0)
    data, current = _run(unit, 2, u)
    fit = dict(kp=0.4, ki=0.08, current=current, **DATASHEET)
    raw = greybox_fit(data, uncertainty=Uncertainty(structure_error={}), **fit)
    truth = unit.breakaway_friction if stiction else unit.coulomb_friction
    assert "breakaway" not in raw.unidentified and raw.breakaway > 1.3 * truth
    model = greybox_fit(data, **fit)
    assert "breakaway" in model.unidentified and model.breakaway == model.coulomb
    assert "breakaway" not in model.std


def test_greybox_takes_another_wheels_current_limit_where_a_linear_model_cannot(grey):
    model, data = grey
    est = data.split(0.7)[0]
    # another unit whose driver limits the current to 0.35 A: it cannot reach 314 rpm/s
    derated = replace(RW90, current_limit=0.35).for_unit(9)
    other, _ = _record(derated, 2)
    y = other.y[:, 0]
    grey_fit = fit_percent(y, model.with_limits(current_limit=0.35).simulate(other.u[:, 0], 0.0))
    linear = arx(est.detrend(reference=est), 2, 2, 1)
    wheel = IdentifiedWheel(
        linear, input_offset=float(est.u.mean()), output_offset=float(est.y.mean())
    )
    lin = np.concatenate([[0.0], wheel.simulate(other.u[:, 0])[:-1]])
    linear_fit = fit_percent(y, lin)
    assert grey_fit > 95
    assert grey_fit > linear_fit + 10


def test_greybox_round_trips_and_refuses_bad_parameters(grey):
    model, _ = grey
    back = WheelGreyBox.from_dict(model.to_dict())
    np.testing.assert_array_equal(back.vector, model.vector)
    with pytest.raises(ModelError):
        replace(model, torque_constant=-1.0)
    with pytest.raises(DataError):
        model.simulate([np.nan, 1.0])


def test_nlarx_fits_a_static_nonlinearity_a_linear_arx_cannot():
    # y(t) = 0.5 y(t−1) + sat(u(t−1) − y(t−1), ±1): a rate limit on a first-order servo
    r = np.random.default_rng(0)
    u = np.repeat(r.uniform(-5, 5, 200), 10)
    y = np.zeros(u.size)
    for t in range(1, u.size):
        y[t] = y[t - 1] + np.clip(u[t - 1] - y[t - 1], -1.0, 1.0)
    data = IOData(u, y + 0.01 * r.standard_normal(u.size), 1.0)
    est, val = data.split(0.7)
    model = nlarx(est)
    assert model.report["knot_count"] > 0
    sim = model.predict(val, np.inf)
    lin = arx(est, 2, 2, 1)
    assert fit_percent(val.y[:, 0], sim) > 95
    assert fit_percent(val.y[:, 0], sim) > fit_percent(val.y[:, 0], lin.simulate(val.u)) + 5
    assert NLARXModel.from_dict(model.to_dict()) == model


def test_greybox_std_is_a_budget_and_covers_the_units_truth(grey, unit_a):
    model, _ = grey
    # J's datasheet tolerance (±2 %, uniform) enters every parameter that needs J, and
    # only those; σ is the root sum of squares of the budget's terms
    for name, parts in model.std_budget.items():
        assert model.std[name] == pytest.approx(math.sqrt(sum(v**2 for v in parts.values())))
        needs_j = name in ("torque_constant", "coulomb", "breakaway", "viscous")
        assert ("inertia" in parts) == needs_j
        if needs_j:
            assert parts["inertia"] == pytest.approx(abs(getattr(model, name)) * 0.02 / 3**0.5)
    ratio = model.ratios["torque_constant/inertia"]
    assert ratio["value"] == pytest.approx(model.torque_constant / model.inertia)
    # the unit's truth within 3 σ: the physical kt (J off by the unit's draw) and kt/J
    z_kt = (model.torque_constant - unit_a.torque_constant) / model.std["torque_constant"]
    true_ratio = unit_a.torque_constant / unit_a.inertia
    z_ratio = (ratio["value"] - true_ratio) / ratio["std"]
    assert abs(z_kt) < 3 and abs(z_ratio) < 3
    assert model.accel_limit == pytest.approx(
        unit_a.max_accel_rpm_s * RPM, abs=3 * model.std["accel_limit"]
    )
    assert "Newey–West" in model.std_method


def test_greybox_refuses_bad_uncertainty_settings(unit_a):
    data, current = _record(unit_a, 3, minutes=2.0)
    with pytest.raises(DataError, match="inertia_tolerance"):
        Uncertainty(inertia_tolerance=-0.1)
    with pytest.raises(DataError, match="hac_lags"):
        Uncertainty(hac_lags=-1)
    with pytest.raises(DataError, match="structure_error"):
        Uncertainty(structure_error={"mass": 0.1})
    # no J tolerance, no structure error, white residuals: σ is the statistical term alone
    bare = greybox_fit(data, current=current, uncertainty=Uncertainty(0.0, 0, {}), **DATASHEET)
    assert all(p["structure"] == 0 and p.get("inertia", 0) == 0 for p in bare.std_budget.values())
    assert all(bare.std[k] == pytest.approx(p["statistical"]) for k, p in bare.std_budget.items())


def test_newey_west_sandwich_matches_the_spread_under_coloured_errors():
    """Least squares with an autocorrelated regressor and AR(1) errors (ρ = 0.9): the
    white-noise covariance is too small, the Newey–West sandwich matches the spread."""
    from rwlab.ident.greybox import sandwich_covariance

    rng = np.random.default_rng(0)
    n, runs = 800, 300
    x = lfilter([1.0], [1.0, -0.9], rng.standard_normal(n))
    X = np.column_stack([x, np.ones(n)])
    seen = np.array([True, True])
    slopes, hac, white = [], [], []
    for _ in range(runs):
        e = lfilter([1.0], [1.0, -0.9], rng.standard_normal(n))
        beta, *_ = np.linalg.lstsq(X, 2.0 * x + e, rcond=None)
        r = X @ beta - (2.0 * x + e)
        slopes.append(beta[0])
        hac.append(math.sqrt(sandwich_covariance(r, X, n, seen, None)[0][0, 0]))
        lam = r @ r / (n - 2)
        white.append(math.sqrt(lam * np.linalg.inv(X.T @ X)[0, 0]))
    spread = np.std(slopes, ddof=1)
    assert np.mean(hac) == pytest.approx(spread, rel=0.25)
    assert np.mean(white) < 0.5 * spread  # what λ(JᵀJ)⁻¹ reports here


@pytest.fixture(scope="module")
def clamped():
    """A unit whose driver is configured to 0.35 A; its clamp drawn 1.4 % lower (0.345 A):
    the PRBS's large steps run into it, below the 314 rpm/s rate limit."""
    unit = replace(IDEAL, current_limit=0.35).for_unit(8)
    data, current = _record(unit, 5, minutes=5.0)
    sheet = {**DATASHEET, "current_limit": 0.35}
    return unit, data, current, sheet


def test_greybox_estimates_a_binding_current_limit_and_keeps_kt_over_j_unbiased(clamped):
    unit, data, current, sheet = clamped
    assert clamp_visible(current, 0.35)
    model = greybox_fit(data, current=current, **sheet)
    assert model.current_limit_estimated and "current_limit" in model.std
    # the unit's clamp, not the configured value: 0.35 A is 1.4 % off, the estimate 0.2 %
    assert abs(unit.current_limit / 0.35 - 1) > 0.01
    assert model.current_limit == pytest.approx(unit.current_limit, rel=0.002)
    # kt/J is what the clamp's acceleration and the current tell apart (within 0.5 %)
    true_ratio = unit.torque_constant / unit.inertia
    assert model.ratios["torque_constant/inertia"]["value"] == pytest.approx(true_ratio, rel=5e-3)
    # the clamp keeps the wheel below 314 rpm/s: α is held, not estimated
    assert not model.accel_limit_estimated and "accel_limit" not in model.std
    assert model.accel_limit == pytest.approx(314 * RPM)
    assert WheelGreyBox.from_dict(model.to_dict()).estimated == model.estimated


def test_greybox_carries_a_fixed_current_limits_tolerance_into_sigma(clamped, grey):
    unit, data, current, sheet = clamped
    held = greybox_fit(data, current=current, estimate_current_limit=False, **sheet)
    assert not held.current_limit_estimated and held.current_limit == 0.35
    # held at 0.35 A while the clamp is at 0.345 A: kt/J absorbs it; σ says so
    ratio = held.ratios["torque_constant/inertia"]
    true_ratio = unit.torque_constant / unit.inertia
    assert abs(ratio["value"] / true_ratio - 1) > 0.005  # biased by the clamp's offset
    assert abs(ratio["value"] - true_ratio) < 3 * ratio["std"]  # ...and σ covers it
    assert (
        held.std_budget["torque_constant"]["current_limit"]
        > (held.std_budget["torque_constant"]["statistical"])
    )
    # a record that never reaches the clamp: the term is zero
    model, _ = grey
    assert not model.current_limit_estimated
    assert all(p["current_limit"] == 0 for p in model.std_budget.values())


def test_the_structure_envelope_is_measured_data_per_wheel_model(tmp_path, monkeypatch):
    import json

    from rwlab.ident import greybox_std

    entry = json.loads(greybox_std.STRUCTURE_FILE.read_text())["models"]["rw90"]
    assert entry["measurement"]["command"].startswith("python bench/bench_greybox_z.py")
    assert greybox_std.structure_error("rw90")[0] == entry["relative_error"]
    # the σ budget reads the file, not a constant in the code
    edited = {"format": "x", "models": {"rw90": {**entry, "relative_error": {"kp": 0.5}}}}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(edited))
    monkeypatch.setattr(greybox_std, "STRUCTURE_FILE", path)
    std, _, budget = greybox_std.uncertainty_budget(
        {"kp": 0.0}, {"kp": 2.0}, None, greybox_std.Uncertainty(), 4.2e-4
    )
    assert budget["kp"]["structure"] == pytest.approx(1.0) and std["kp"] == pytest.approx(1.0)
    # a wheel model without its own measurement: the widest measured envelope, said so
    shape, source = greybox_std.structure_error("t6")
    assert shape == {"kp": 0.5} and "no measured envelope" in source


@pytest.mark.parametrize("name", ["rw90", "nrwa-t6", "rw-0.01"])
def test_the_study_names_the_records_wheel_model_to_the_grey_box(name):
    """The study's datasheet for a record carries its wheel spec's name (issue 41: the
    envelope was the RW90's for every wheel)."""
    from rwlab.ident.study import wheel_datasheet
    from rwlab.wheelspec import WheelSpec

    sheet = wheel_datasheet(WheelSpec.load(name))
    assert sheet["wheel_model"] == name
    assert sheet["max_speed_rpm"] == WheelSpec.load(name).max_speed_rpm


def test_a_wheel_model_without_its_own_envelope_gets_the_widest_and_says_so(grey, unit_a):
    """The grey box of a record of another wheel model: σ from the widest measured
    envelope, and ``std_method`` says which wheel had none; the RW90's names its own."""
    from rwlab.ident import greybox_std

    model, data = grey
    assert "the rw90 envelope measured by" in model.std_method
    _, current = _record(unit_a, 1)
    est = data.split(0.7)[0]
    sheet = {**DATASHEET, "wheel_model": "nrwa-t6"}
    other = greybox_fit(est, kp=0.4, ki=0.08, current=current[: est.N], **sheet)
    assert "nrwa-t6 has no measured envelope" in other.std_method
    widest, _ = greybox_std.structure_error("nrwa-t6")
    kp = other.std_budget["kp"]["structure"]
    assert kp == pytest.approx(widest["kp"] * abs(other.kp))


def test_a_coulomb_the_fit_cannot_see_is_unidentified_not_a_key_error(monkeypatch):
    # a record whose current is clipped (a protocol's signal range) can leave Coulomb
    # friction without a Jacobian column at the optimum: it and the breakaway's excess
    # over it are unidentified, without a σ; before, std["coulomb"] raised KeyError
    import rwlab.ident.greybox as gb

    real = gb.least_squares

    def blind_coulomb(*args, **kwargs):
        sol = real(*args, **kwargs)
        sol.jac[:, gb.ESTIMATED.index("coulomb")] = 0.0
        return sol

    monkeypatch.setattr(gb, "least_squares", blind_coulomb)
    data, current = _record(RW90.for_unit(4), 1, minutes=4.0)  # stiction: breakaway seen
    model = greybox_fit(data, kp=0.4, ki=0.08, current=current, **DATASHEET)
    assert {"coulomb", "breakaway"} <= set(model.unidentified)
    assert "coulomb" not in model.std and model.breakaway == model.coulomb
