"""The GLR diagnosis pipeline against known truth: records made from the pipeline's own
wheel physics (current balance, loop, sensor) with Gaussian noise of known σ."""

from __future__ import annotations

import itertools
import json
import math
import types
from dataclasses import replace

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jsonschema import Draft202012Validator

from rwlab.data import IOData
from rwlab.diagnose.bank import WindowFit, widened
from rwlab.diagnose.detectors import MODEL_BASED, REGISTRY, SIGNATURE, detector
from rwlab.diagnose.detectors.base import HALF_CHI2_95, Detector, Fit, profile_fit
from rwlab.diagnose.detectors.current_limit import CurrentLimit
from rwlab.diagnose.detectors.frozen_reading import FrozenReading
from rwlab.diagnose.detectors.sensor_bias import SensorBias
from rwlab.diagnose.features import (
    REFERENCE_LAG_S,
    STEADY_SHARE,
    WheelScales,
    channel_mask,
    compute_features,
    past_covers,
)
from rwlab.diagnose.noise import JERK_EDGES, SPEED_EDGES, NoiseModel, bins, speed_bins
from rwlab.diagnose.past_fits import least_norm_solve
from rwlab.diagnose.pipeline import Event, Live, Result, _follow, run
from rwlab.diagnose.wheel_calibration import (
    DiagnosisCalibration,
    Threshold,
    excursion_peaks,
    garwood,
    twin_calibration_file,
)
from rwlab.errors import ConfigError, DataError, FileFormatError
from rwlab.schemas import schema
from rwlab.wheel.faults import FAULTS

TS = 0.5
# c = [I/k_t, b/k_t, τ_c/k_t, offset] of a small wheel, A per (rpm/s, rpm, 1, 1)
C = (1.8e-3, 2.5e-6, 9.2e-3, 0.0)
SCALES = WheelScales(TS, accel_limit_rpm_s=300.0, current_limit_a=0.7, current_model=C)
SIGMA_A = 0.004  # current noise, A
SIGMA_RPM = 0.3  # speed noise, rpm


class Replay:
    """A perfect model: it replays the healthy wheel's speed (reset/step as IdentifiedWheel)."""

    def __init__(self, speed: np.ndarray) -> None:
        self.speed, self.k, self.Ts = speed, 0, TS

    def reset(self, speed_rpm: float = 0.0) -> None:
        self.k = 0

    def step(self, command_rpm: float) -> float:
        self.k += 1
        return float(self.speed[self.k])


def profile(n: int) -> np.ndarray:
    """Holds at ±1000..±3000 rpm joined by 150 rpm/s ramps (under the limit), rpm."""
    levels = [1000.0, 3000.0, -2000.0, 2500.0, -1000.0, 2000.0]
    out, w = [0.0], 0.0
    i = 0
    while len(out) < n:
        target = levels[i % len(levels)]
        while abs(target - w) > 1e-9 and len(out) < n:
            w += float(np.clip(target - w, -150 * TS, 150 * TS))
            out.append(w)
        out += [w] * min(60, n - len(out))
        i += 1
    return np.array(out[:n])


def record(
    seed: int,
    n: int = 2400,
    fault: str = "",
    size: float = 1.0,
    onset: int = 1200,
    unit_friction: float = 1.0,
    unit_offset_a: float = 0.0,
    speed: np.ndarray | None = None,
):
    """(IOData, wheel) of a healthy wheel, with ``fault`` of ``size`` from sample ``onset``;
    ``unit_friction`` and ``unit_offset_a``: another unit's friction (× the reference's)
    and current offset (A); ``speed``: the wheel's speed, rpm (default :func:`profile`)."""
    rng = np.random.default_rng(seed)
    speed = profile(n) if speed is None else speed
    accel = np.concatenate([[0.0], np.diff(speed) / TS])
    friction = unit_friction * (C[1] * speed + C[2] * np.sign(speed))
    after = np.arange(n) >= onset
    f_fric = np.where(after & (fault == "friction"), size, 1.0)
    f_kt = np.where(after & (fault == "torque_constant"), size, 1.0)
    current = (C[0] * accel + f_fric * friction) / f_kt + C[3] + unit_offset_a
    current = current + SIGMA_A * rng.standard_normal(n)
    reported = speed + SIGMA_RPM * rng.standard_normal(n)
    reported += np.where(after & (fault == "speed_sensor_bias"), size, 0.0)
    y = np.column_stack([reported, current, np.zeros(n), np.zeros(n)])
    names = ["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"]
    return IOData(speed, y, TS, output_names=names), Replay(speed)


def features(seed: int, **fault):
    data, wheel = record(seed, **fault)
    return compute_features(data, wheel, SCALES)


@pytest.fixture(scope="module")
def calibration() -> DiagnosisCalibration:
    return DiagnosisCalibration.measure([features(s) for s in range(6)], origin="synthetic")


def test_every_fault_has_one_registered_detector():
    assert set(REGISTRY) == set(FAULTS)
    assert set(SIGNATURE) == set(FAULTS)
    for name in FAULTS:
        assert detector(name).fault == name
    with pytest.raises(ConfigError, match="known"):
        detector("gearbox")


def test_noise_free_residuals_are_zero():
    data, wheel = record(0)
    f = compute_features(data, wheel, SCALES)
    # the model starts at the first reading, then replays the true speed: the residual
    # is the sensor noise alone
    assert f.speed_residual_rpm[0] == 0.0
    assert np.allclose(f.speed_residual_rpm[1:], (data.y[:, 0] - wheel.speed)[1:])
    assert abs(np.median(f.current_residual_a)) < SIGMA_A
    assert not np.shares_memory(f.speed_rpm, data.y)


def test_profile_interval_of_a_gaussian_is_textbook():
    """ll(θ) = −(θ − 2)²/(2·0.1²): θ̂ = 2, interval 2 ± 1.96·0.1."""
    grid = np.linspace(0, 4, 40001)
    ll = -((grid - 2.0) ** 2) / (2 * 0.1**2)
    fit = profile_fit("x", "u", grid, ll, grid <= 1.0)
    assert fit.size == pytest.approx(2.0, abs=1e-3)
    half = math.sqrt(2 * HALF_CHI2_95) * 0.1
    assert fit.ci95 == pytest.approx((2 - half, 2 + half), abs=2e-4)
    assert fit.log_lr == pytest.approx(1.0**2 / (2 * 0.1**2), rel=1e-3)
    # on a grid ten times coarser than the interval the bounds fall between grid points
    coarse = np.linspace(0, 4, 11)  # step 0.4
    fit = profile_fit("x", "u", coarse, -((coarse - 2.0) ** 2) / (2 * 0.1**2), coarse <= 1.0)
    lo, hi = fit.ci95
    assert lo < 2.0 < hi and hi - lo < 0.8  # not the point 2 alone, nor past its neighbours
    assert (lo, hi) == pytest.approx((2 - half, 2 + half))  # exact for a quadratic profile


def test_a_one_sided_fault_fits_only_its_side_of_the_healthy_zone():
    """ll peaked at 2 above a zone [0.8, 1.2]: a fault that raises the size finds it (the
    textbook log-LR over the zone's edge); one that lowers it finds nothing there; a peak
    at 0.5, below the zone, is the other way round."""
    grid = np.linspace(0, 4, 40001)
    zone = (grid >= 0.8) & (grid <= 1.2)
    for peak, up, down in ((2.0, 0.8, 0.0), (0.5, 0.0, 0.3)):
        ll = -((grid - peak) ** 2) / (2 * 0.1**2)
        raised = profile_fit("x", "u", grid, ll, zone, worse=1)
        lowered = profile_fit("x", "u", grid, ll, zone, worse=-1)
        for fit, gap in ((raised, up), (lowered, down)):
            assert fit.log_lr == pytest.approx(gap**2 / (2 * 0.1**2), rel=1e-3, abs=1e-9)
    assert raised.size >= 0.8 and lowered.size == pytest.approx(0.5, abs=1e-3)


@pytest.mark.parametrize(
    ("fault", "size", "unit"),
    [
        ("friction", 2.0, "factor"),
        ("torque_constant", 0.85, "factor"),
        ("speed_sensor_bias", 12.0, "rpm"),
    ],
)
def test_a_fault_is_named_and_sized_with_an_interval_holding_it(calibration, fault, size, unit):
    result = run(features(100, fault=fault, size=size), calibration)
    assert result.events, result.verdict()
    first = result.events[0]
    assert first.fault == fault
    assert first.t_s >= 600.0  # onset at sample 1200: no alarm before
    assert first.fit.unit == unit
    assert first.fit.ci95[0] <= size <= first.fit.ci95[1]
    assert first.runner_up in MODEL_BASED and first.runner_up_log_lr >= 0
    assert f"{fault} {first.fit.size_text()} from {first.t_s:g} s" in result.verdict()


def test_the_size_at_the_alarm_is_the_named_faults(calibration, monkeypatch):
    """Decision windows that rank a rival first (a clamp read for a weak motor) open the
    event; it is named on its onset's window, and its size then is that fault's fit on
    an onset found for it, not the rival's."""
    import rwlab.diagnose.pipeline as pipeline

    isolate = pipeline._isolate

    def rival_first(bank, k, names, limits):
        return sorted(isolate(bank, k, names, limits), key=lambda w: w.fit.fault != "current_limit")

    monkeypatch.setattr(pipeline, "_isolate", rival_first)
    result = run(features(100, fault="torque_constant", size=0.85), calibration)
    first = result.events[0]
    assert first.first == "torque_constant" and first.relabelled == []
    # the runner-up is fitted on the named fault's window, where the weak motor is likelier
    assert first.runner_up in MODEL_BASED and first.runner_up_log_lr > 0
    assert first.at_alarm.fault == "torque_constant" and first.at_alarm.unit == "factor"
    assert first.at_alarm.ci95[0] <= 0.85 <= first.at_alarm.ci95[1]
    assert abs(first.onset_s - 600.0) <= 15.0  # the weak motor's onset (sample 1200)
    alarm = first.to_dict()["at_alarm"]
    assert (alarm["size"], alarm["unit"]) == (first.at_alarm.size, "factor")


@pytest.mark.parametrize("fault", ["friction", "torque_constant"])
def test_a_fault_past_the_size_a_healthy_record_would_show_is_shown(calibration, fault):
    """The sizes a healthy record would have shown from its start: a fault from power-up
    one and a half times as far from healthy as the bound on any unit is found, one half
    as far as the reference unit's bound is not (this record is of the reference unit;
    another seed, the fault injected here: truth independent of the bounds)."""
    healthy = run(features(110), calibration)
    live = Live(calibration)
    live.update(features(110))
    side = 1 if fault == "friction" else 0
    any_unit = healthy.detectable[fault][side]
    reference = live.detectable(unit_spread=False)[fault][side]
    assert abs(reference - 1.0) < abs(any_unit - 1.0) and fault not in healthy.unseen
    assert f"{fault} {('below', 'above')[side]} ×{any_unit:.3g}" in healthy.verdict()
    for bound, share, shown in ((any_unit, 1.5, True), (reference, 0.5, False)):
        size = 1.0 + share * (bound - 1.0)
        result = run(features(111, fault=fault, size=size, onset=0), calibration)
        assert (fault in result.faults()) is shown, (share, size, result.verdict())


def test_healthy_records_of_other_seeds_raise_no_alarm(calibration):
    for seed in (200, 201):
        result = run(features(seed), calibration)
        assert result.events == [], result.verdict()
        assert result.verdict().startswith("healthy")


def test_thresholds_fall_as_the_rate_asked_rises(calibration):
    few = replace(calibration, peaks={n: (9.0, 6.0, 4.0) for n in calibration.peaks})
    for cal in (calibration, few):
        for name in MODEL_BASED:
            hs = [cal.threshold(name, r).log_lr for r in (1e-3, 1e-1, 1.0, 10.0, 1000.0)]
            assert all(a >= b for a, b in itertools.pairwise(hs)), (name, hs)
    # more alarms asked than the healthy statistic ever gave: its floor, and what it gives
    asked = 100 / few.hours
    floor = few.threshold("friction", asked)
    assert floor.log_lr == HALF_CHI2_95 and floor.measured_per_hour == 3 / few.hours
    with pytest.raises(ConfigError):
        calibration.threshold("friction", 0.0)


def test_an_extrapolated_tail_is_never_lighter_than_the_glrs_own(calibration):
    """Twenty peaks crowded just over the floor (an exponential of scale 0.19 fits them)
    say little of the rare ones: a rate far below them is extrapolated at the GLR's own
    unit scale, h = u + ln(m / (rate·hours)), u the twentieth peak."""
    crowded = tuple(2.0 + 0.02 * i for i in range(20))[::-1]
    cal = replace(calibration, peaks={n: crowded for n in calibration.peaks}, hours=3.0)
    t = cal.threshold("friction", 1e-3)
    assert t.extrapolated
    assert t.log_lr == pytest.approx(2.0 + math.log(20 / (1e-3 * 3.0)))


def test_calibration_file_round_trips(calibration, tmp_path):
    path = calibration.save(tmp_path / "calibration.json")
    again = DiagnosisCalibration.load(path)
    assert again.to_dict() == calibration.to_dict()
    (tmp_path / "bad.json").write_text('{"format": "rwlab.Other/1"}')
    with pytest.raises(FileFormatError, match="rwlab diagnose calibrate"):
        DiagnosisCalibration.load(tmp_path / "bad.json")


def test_written_files_validate_against_their_schemas(calibration, tmp_path):
    path = calibration.save(tmp_path / "calibration.json")
    kind = Draft202012Validator
    jsonschema.validate(json.loads(path.read_text()), schema("diagnosis_calibration"), cls=kind)
    result = run(features(100, fault="friction", size=2.0), calibration)
    jsonschema.validate(result.to_dict(str(path)), schema("fdi_diagnosis"), cls=kind)


def test_garwood_interval_known_values():
    """Exact Poisson 95 % limits (Garwood 1936): n = 0 → [0, 3.689]; n = 1 → [0.0253, 5.572]."""
    assert garwood(0, 1.0) == pytest.approx((0.0, 3.6889), abs=1e-4)
    assert garwood(1, 2.0) == pytest.approx((0.02532 / 2, 5.5716 / 2), abs=1e-4)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-5, 50, allow_nan=False), max_size=60))
def test_excursion_peaks_are_the_maxima_of_runs_over_the_floor(xs):
    peaks = excursion_peaks(np.array(xs), floor=2.0)
    above = [x for x in xs if x > 2.0]
    assert len(peaks) <= len(above)
    assert (max(above) in peaks) if above else peaks == []


def test_a_record_without_current_is_refused():
    data, wheel = record(0)
    speed_only = IOData(data.u, data.y[:, :1], TS, output_names=["speed_rpm"])
    with pytest.raises(DataError, match="current_a"):
        compute_features(speed_only, wheel, SCALES)


def test_the_page_gives_the_verdict_before_the_alarms(calibration, tmp_path):
    from rwlab.report.fdi import fdi_page

    path = calibration.save(tmp_path / "calibration.json")
    f = features(100, fault="speed_sensor_bias", size=12.0)
    result = run(f, calibration)
    text = fdi_page(result, calibration, path, title="rec").render()
    verdict = text.index("speed_sensor_bias")
    assert verdict < text.index('id="alarms"') < text.index('id="thresholds"')
    assert path.resolve().as_uri() in text and "synthetic" in text
    with_figure = fdi_page(result, calibration, path, title="rec", features=f).render()
    assert 'id="fig-residuals"' in with_figure and 'id="fig-residuals"' not in text


def test_a_record_too_short_to_tell_a_fault_says_so(calibration):
    """Six seconds of a ramp from rest: no constant speed, so friction cannot be told from
    healthy, and the verdict says it was not seen (the whole healthy record sees every
    fault)."""
    data, wheel = record(103, n=12)
    short = run(compute_features(data, wheel, SCALES), calibration)
    assert "friction" in short.unseen
    assert not short.events and short.unseen
    assert "not seen" in short.verdict() and short.unseen[0] in short.verdict()
    whole = run(features(103), calibration)
    assert not whole.events and whole.unseen == [] and "not seen" not in whole.verdict()


def test_the_own_reference_takes_out_a_units_friction_and_offset():
    """A unit with 1.4 × the reference's friction and a +6 mA offset: against the population
    its constant-speed current residual is that misfit; against its own past (fitted on
    samples older than the lag) it is the noise alone."""
    data, wheel = record(3, unit_friction=1.4, unit_offset_a=0.006)
    f = compute_features(data, wheel, SCALES)
    late = f.t_s >= REFERENCE_LAG_S + 120.0
    steady = channel_mask(f, "current") & f.steady(STEADY_SHARE) & late
    own = f.own()
    n = int(steady.sum())
    assert n > 200
    misfit = 0.4 * f.friction_current_a[steady] + 0.006
    assert np.abs(misfit).mean() > 1.5 * SIGMA_A
    assert abs((f.current_residual_a[steady] - misfit).mean()) < 4 * SIGMA_A / math.sqrt(n)
    assert abs(own.current_residual_a[steady].mean()) < 4 * SIGMA_A / math.sqrt(n)
    assert own.current_residual_a[steady].std() < 1.3 * SIGMA_A
    assert not own.usable[: round(REFERENCE_LAG_S / TS)].any()  # no reference yet
    # what a friction × F multiplies against the unit's own friction law: its friction,
    # not the reference's (a ×1.5 on this unit would otherwise size as 1 + 0.5·1.4 = 1.7)
    law = f.own(law=True)
    ratio = law.friction_current_a[steady] / f.friction_current_a[steady]
    assert np.median(ratio) == pytest.approx(1.4, abs=0.05)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 3),
    st.floats(1e-3, 1e3),
)
def test_the_stacked_least_norm_solve_is_lstsqs(seed, rank, scale):
    """Symmetric positive semi-definite 3 × 3 systems of every rank, and near-singular ones:
    the same solution as numpy's lstsq with its cutoff (rcond 1e-6), system by system."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((8, 20, rank)) @ rng.standard_normal((8, rank, 3))
    X[4:, :, 2] = X[4:, :, 1] + 1e-5 * rng.standard_normal((4, 20))  # nearly collinear
    A = scale * np.einsum("kni,knj->kij", X, X)
    b = np.einsum("kij,kj->ki", A, rng.standard_normal((8, 3)))
    got = least_norm_solve(A, b)
    for k in range(8):
        want = np.linalg.lstsq(A[k], b[k], rcond=1e-6)[0]
        assert np.allclose(A[k] @ got[k], A[k] @ want, rtol=1e-6, atol=1e-9 * scale)
        assert np.linalg.norm(got[k]) <= np.linalg.norm(want) * (1 + 1e-5) + 1e-12


def test_a_growing_record_reuses_its_own_references_past_fits_unchanged():
    """The features of a record grown in flight (each from the last's) equal those of the
    whole record computed at once, own references included: a sample's fit reads its past
    only, so the fits kept from the shorter record are the longer one's."""
    # ten minutes one way (a past where the offset and the Coulomb friction are alike), then
    # the other way, faster (the friction current's scale grows)
    ramp = np.linspace(0.0, 1000.0, 20)
    speed = np.concatenate([ramp, np.full(1200, 1000.0), 1000.0 - 3 * ramp, np.full(760, -2000.0)])
    speed = np.concatenate([speed, -2000.0 + profile(3000 - speed.size)])
    data, wheel = record(4, n=3000, unit_friction=1.3, unit_offset_a=0.004, speed=speed)
    whole = compute_features(data, wheel, SCALES)
    grown = None
    for n in (1400, 1500, 2200, 3000):
        part = IOData(data.u[:n], data.y[:n], TS, output_names=data.output_names)
        grown = compute_features(part, wheel, SCALES, grown)
    assert grown is not None and set(grown.past_fits) == {False}
    assert np.array_equal(grown.model_rpm, whole.model_rpm)  # the model run on, not again
    for law in (False, True):
        assert np.array_equal(
            grown.own(law).current_nuisance_a, whole.own(law).current_nuisance_a, equal_nan=True
        )
    # a record that is not the same past is fitted afresh, not from the other's fits
    other, _ = record(5, n=3000)
    assert not np.array_equal(
        compute_features(other, wheel, SCALES, whole).current_nuisance_a,
        whole.current_nuisance_a,
        equal_nan=True,
    )


def test_the_own_reference_is_read_only_at_speeds_its_past_spans():
    """The own law interpolates: past the lag, a sample at a speed the past held on its
    side of zero is read against it; one faster than the past ever turned, or on the other
    side of zero, is not (the law would extrapolate)."""
    lag = round(REFERENCE_LAG_S / TS)
    past = 1500.0 + 500.0 * np.sin(np.arange(lag + 200) * TS / 20.0)  # 1000-2000 rpm
    later = np.repeat([1500.0, 3000.0, -1500.0], 100)
    speed = np.concatenate([past, later])
    n = len(speed)
    current = C[1] * speed + C[2] * np.sign(speed) + C[0] * np.gradient(speed, TS)
    y = np.column_stack([speed, current, np.zeros(n), np.zeros(n)])
    names = ["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"]
    f = compute_features(IOData(speed, y, TS, output_names=names), Replay(speed), SCALES)
    covered = past_covers(f)
    assert not covered[:lag].any()
    at = len(past)
    assert covered[at + 10 : at + 90].all()  # 1500 rpm: inside the past's span
    assert not covered[at + 110 :].any()  # 3000 rpm, then -1500 rpm: never held before
    law = f.own(law=True)
    assert not channel_mask(law, "current")[at + 110 :].any()
    assert law.usable[at + 110 :].all()  # the law gates the current channel alone
    assert f.own().usable[at + 110 :].all()  # the offset's reference: every speed


@pytest.mark.slow
def test_a_friction_change_on_a_unit_off_the_reference_is_named_friction():
    """Calibrated on units whose friction spreads ×0.7–1.45 about the reference's, friction
    × 1.5 mid-record on a unit of 1.3 × (within the spread: no power-up alarm): the change
    against its own past names friction."""
    spread = (0.7, 0.85, 1.0, 1.15, 1.3, 1.45)
    calibration = DiagnosisCalibration.measure(
        [features(s, unit_friction=u) for s, u in enumerate(spread)], origin="synthetic"
    )
    f = features(101, fault="friction", size=1.5, unit_friction=1.3)
    result = run(f, calibration)
    assert result.events and result.events[0].fault == "friction", result.verdict()
    assert result.events[0].t_s >= 600.0
    fit = result.events[0].fit  # sized on the unit's friction: 1.5, not 1 + 0.5·1.3
    assert fit.ci95[0] <= 1.5 <= fit.ci95[1] and abs(fit.size - 1.5) < abs(fit.size - 1.65)


def test_a_weak_motor_or_more_friction_fall_short_only_where_the_clamp_binds():
    """The loop's integrator makes up lost torque until the driver's clamp binds: no
    shortfall where the demand needs less than the clamp, never one for a stronger motor."""
    f = compute_features(*record(0), SCALES)
    c0 = C[0]
    needed = np.abs(c0 * f.demand_accel_rpm_s + f.friction_current_a)
    stronger = Detector.shortfall(f, SCALES.current_limit_a, torque_factor=np.array([1.3]))
    assert not stronger.any()
    weak = Detector.shortfall(f, SCALES.current_limit_a, torque_factor=np.array([0.3]))[:, 0]
    assert (weak[needed < 0.3 * SCALES.current_limit_a - 1e-9] == 0).all()
    binding = needed > 0.3 * SCALES.current_limit_a + 1e-9
    assert (
        binding.any() and (np.sign(weak[binding]) == -np.sign(f.demand_accel_rpm_s[binding])).all()
    )


def test_at_the_acceleration_limit_a_motor_reaches_its_share_of_the_capped_request():
    """The capped request drives the current a healthy wheel needs for the limit; a motor
    of F·k_t turns it into F of the torque (the integrator holds), so the wheel reaches
    F·α_limit less (1 − F) of friction's share; a clamp under that current cuts it to L."""
    f = compute_features(*record(0), SCALES)
    limit = SCALES.accel_limit_rpm_s
    capped = replace(f, demand_accel_rpm_s=np.where(f.speed_rpm >= 0, limit, -limit))
    assert capped.saturated.all()
    factors = np.array([0.8, 1.0, 1.25])
    p = Detector.shortfall(capped, SCALES.current_limit_a, torque_factor=factors)
    friction_rpm_s = capped.friction_current_a / C[0]  # friction's share of the limit
    d = np.sign(capped.demand_accel_rpm_s)
    for j, factor in enumerate(factors):
        assert np.allclose(p[:, j], (factor - 1) * (d * limit + friction_rpm_s), atol=1e-9)
    clamp = 0.4  # under c₀·α_limit + friction: the clamp sets the current
    q = Detector.shortfall(capped, clamp)[:, 0]
    assert np.allclose(q, d * (clamp - C[3]) / C[0] - friction_rpm_s - d * limit, atol=1e-9)


def test_the_speed_readings_scatter_is_measured_per_speed_at_held_speeds():
    """A reading ten times coarser under 600 rpm (as a Hall-timed one is) gets a factor
    of about ten in those speed bins and about one above; never under one."""
    records = []
    for seed in range(6):
        data, wheel = record(seed)
        rng = np.random.default_rng(100 + seed)
        slow = np.abs(data.u[:, 0]) < 600
        y = data.y.copy()
        y[:, 0] += np.where(slow, 10 * SIGMA_RPM * rng.standard_normal(data.N), 0.0)
        noisy = IOData(data.u, y, TS, output_names=data.output_names)
        records.append(compute_features(noisy, wheel, SCALES))
    factor = np.asarray(NoiseModel.measure(records).speed_factor["speed"])
    slow_bin = np.searchsorted(SPEED_EDGES, 450.0)
    fast_bins = np.searchsorted(SPEED_EDGES, [1500.0, 2800.0])
    assert 7 < factor[slow_bin] < 13, factor
    assert np.all((factor[fast_bins] >= 1) & (factor[fast_bins] < 1.5)), factor
    assert factor.min() >= 1


def test_a_reading_of_zero_is_no_evidence_of_a_bias(calibration):
    """At rest a speed sensor reads exactly 0 below the speed it measures, while the model
    may creep: those samples weigh nothing in the bias test; the same misfit read at a
    held speed does."""
    f = compute_features(*record(0), SCALES)
    held = np.flatnonzero(f.steady(STEADY_SHARE) & f.usable)[:40]
    misfit = f.speed_residual_rpm.copy()
    misfit[held] = -2.0
    detector = SensorBias()
    grid = detector.grid(f)

    def gains(reading):
        speed = f.speed_rpm.copy()
        speed[held] = reading
        g = replace(f, speed_rpm=speed, speed_residual_rpm=misfit)
        return detector.gains(g, calibration.noise.weights(g), grid)[held]

    assert not gains(0.0).any()
    assert gains(1000.0).any()


def test_a_frozen_reading_counts_only_while_the_wheel_is_meant_to_move():
    """A reading repeated through a held speed (as a Hall reading may be) leaves the run
    at 0; frozen through a ramp, the run grows a sample per sample."""
    data, wheel = record(0)
    speed = data.u[:, 0]
    held = np.flatnonzero(np.diff(speed) == 0)[5:35]  # inside the first hold
    moving = np.flatnonzero(np.abs(np.diff(speed)) > 0)
    ramps = np.split(moving, np.flatnonzero(np.diff(moving) > 1) + 1)
    ramp = max(ramps, key=len)[10:40]  # inside the longest ramp
    y = data.y.copy()
    y[held, 0] = y[held[0], 0]
    y[ramp, 0] = y[ramp[0], 0]
    f = compute_features(IOData(data.u, y, TS, output_names=data.output_names), wheel, SCALES)
    runs = FrozenReading.runs(f)
    assert runs[held].max() == 0
    assert runs[ramp[-1]] == len(ramp) - 1


def test_a_clamp_is_sized_at_its_flat_top_whatever_the_reach_said():
    """The GLR's clamp (here 2 % low, as a unit's own inertia/k_t pulls the reach) is read
    again off the current where it binds: the interval holds the clamp, a few mA wide."""
    clamp, rng = 0.25, np.random.default_rng(7)
    f = compute_features(*record(0), SCALES)
    binding = Detector.shortfall(f, clamp)[:, 0] != 0
    level = np.sign(f.demand_accel_rpm_s) * clamp + SIGMA_A * rng.standard_normal(f.N)
    f = replace(f, current_a=np.where(binding, level, f.current_a))
    weights = {"current_level": np.full(f.N, SIGMA_A**-2)}
    detector = CurrentLimit()
    glr = Fit("current_limit", 0.245, (0.244, 0.246), 100.0, "A")
    refined = detector.refine(f, weights, glr, 0, f.N)
    assert binding.sum() > 100
    assert refined.ci95[0] <= clamp <= refined.ci95[1]
    assert refined.ci95[1] - refined.ci95[0] < 4 * 1.96 * SIGMA_A / np.sqrt(binding.sum())
    assert (refined.log_lr, refined.fault) == (glr.log_lr, glr.fault)  # the evidence is kept
    # a reading quantised coarser than its noise: every binding sample reads the same step,
    # and the interval is the step's width about it, not a point
    lsb = 0.004
    quantised = replace(f, current_a=np.round(f.current_a / lsb) * lsb)
    coarse = detector.refine(quantised, weights, glr, 0, f.N)
    assert coarse.ci95[1] - coarse.ci95[0] >= lsb - 1e-12
    assert coarse.ci95[0] <= clamp <= coarse.ci95[1]


def test_a_slew_that_ends_within_a_sample_does_not_refute_its_clamp():
    """Where a clamped slew ends inside a sample's interval, the reading has already left
    the flat top: it may read under the clamp there (never over it) at no cost, so the
    clamp's likelihood is the one of a record whose slews end on the sample."""
    clamp, rng = 0.25, np.random.default_rng(3)
    f = compute_features(*record(0), SCALES)
    binding = Detector.shortfall(f, clamp)[:, 0] != 0
    last = binding & ~np.append(
        binding[1:], True
    )  # each binding run's last (the record's end: none)
    noise = SIGMA_A * rng.standard_normal(f.N)
    noise[last] = -np.abs(noise[last])  # the reading there under the clamp in both records
    level = np.sign(f.demand_accel_rpm_s) * (clamp + noise)
    on_top = replace(f, current_a=np.where(binding, level, f.current_a))
    left = replace(on_top, current_a=np.where(last, 0.4 * level, on_top.current_a))
    weights = {"accel": np.full(f.N, 1.0), "current_level": np.full(f.N, SIGMA_A**-2)}
    detector = CurrentLimit()
    grid = np.array([clamp])
    assert last.sum() >= 5
    kept, costed = (detector.gains(g, weights, grid).sum() for g in (on_top, left))
    assert costed == pytest.approx(kept, abs=1e-6)
    over = replace(on_top, current_a=np.where(last, 1.5 * level, on_top.current_a))
    assert detector.gains(over, weights, grid).sum() < kept - 100  # over the clamp never
    inside = binding & ~last  # within a run the reading holds the flat top: under it costs
    under = replace(on_top, current_a=np.where(inside, 0.4 * level, on_top.current_a))
    assert detector.gains(under, weights, grid).sum() < kept - 100


def test_no_motion_sample_weighs_more_than_the_speed_reading_allows_at_its_speed():
    """A slew through a speed the sensor reads coarsely (30 times coarser under 600 rpm
    here) weighs in the acceleration channel no more than a hold at that speed does; the
    bias test's held weights keep the hold's scale in the hold's bin alone."""
    f = compute_features(*record(0), SCALES)
    g = np.array([30.0 if edge <= 640.0 else 1.0 for edge in (*SPEED_EDGES, np.inf)])
    sigma = (0.05, *([0.5] * (len(JERK_EDGES) + 1)))  # a hold's σ, a slew's ten times it
    names = ("current", "accel", "speed", "current_steady")
    kappa = 2.0  # the inflation divides every weight, floored or not
    noise = NoiseModel(
        dict.fromkeys(names, sigma),
        dict.fromkeys(names, kappa),
        {"accel": tuple(g), "speed": tuple(g)},
    )
    w = noise.weights(f)
    usable, slew, slow = w["accel"] > 0, bins(f) != 0, g[speed_bins(f)] > 1
    assert (usable & slew & slow).any() and (usable & slew & ~slow).any()
    # 0.05 × 30 at a slow speed, a slew or a hold
    assert np.allclose(w["accel"][usable & slow], 1 / (1.5**2 * kappa))
    assert np.allclose(w["accel"][usable & slew & ~slow], 1 / (0.5**2 * kappa))
    assert np.allclose(w["accel_held"][usable & slew], 1 / (0.5**2 * kappa))
    assert np.allclose(w["accel_held"][usable & ~slew & ~slow], 1 / (0.05**2 * kappa))


@pytest.mark.parametrize("wheel", ["rw90", "nrwa-t6", "rw-0.01"])
def test_every_preset_ships_a_twin_calibration_with_its_provenance(wheel):
    calibration = DiagnosisCalibration.load(twin_calibration_file(wheel))
    assert calibration.hours >= 1.0 and calibration.records == len(calibration.sources)
    assert wheel in calibration.origin and "bench_fdi.py" in calibration.origin
    jsonschema.validate(
        json.loads(twin_calibration_file(wheel).read_text()),
        schema("diagnosis_calibration"),
        cls=Draft202012Validator,
    )


def test_an_unshipped_wheel_has_no_twin_calibration():
    with pytest.raises(ConfigError, match="rwlab diagnose calibrate"):
        twin_calibration_file("gearbox-wheel")


class FixedBank:
    """A bank whose every window fits each fault at a fixed log-LR (``_follow``'s view)."""

    def __init__(self, log_lr: dict[str, float]) -> None:
        self.log_lr = log_lr
        self.features = types.SimpleNamespace(t_s=np.arange(100.0))

    def fit(self, name: str, a: int, k: int) -> WindowFit:
        fit = Fit(name, 0.8, (0.7, 0.9), self.log_lr.get(name, 0.0), "factor")
        return WindowFit(fit, float(a), float(k), "population")


@pytest.mark.parametrize(
    ("motor_log_lr", "one_event"), [(500.0, True), (31.0, False), (25.0, False)]
)
def test_one_fault_explaining_two_events_absorbs_them_when_likelier_than_both(
    motor_log_lr, one_event
):
    """A weak motor first read as friction (current at constant speed, excess 2 over its
    threshold), then as a clamp (acceleration at the limit, excess 20): once the motor,
    whose signature spans both, is likelier beyond its threshold than the two faults
    together (excess > 22), the friction event is re-labelled and absorbs the clamp's;
    while it is not (21: likelier than either alone), both events stand."""
    limits = {n: types.SimpleNamespace(log_lr=10.0) for n in MODEL_BASED}
    bank = FixedBank({"friction": 12.0, "torque_constant": motor_log_lr})
    fits = [
        Fit(n, 0.8, (0.7, 0.9), v, "factor")
        for n, v in [("friction", 12.0), ("current_limit", 30.0)]
    ]
    events = [
        Event(t_s=10.0 * i, onset_s=0.0, fit=f, detector=f.fault, threshold=10.0)
        for i, f in enumerate(fits)
    ]
    friction, clamp = events
    _follow(friction, events, bank, 50, limits)
    if one_event:
        assert events == [friction] and friction.fault == "torque_constant"
        assert {was for _, was in friction.relabelled} == {"friction", "current_limit"}
    else:
        assert events == [friction, clamp] and friction.fault == "friction"
        assert not friction.relabelled


def test_against_its_own_law_friction_reads_the_current_alone():
    """The own past is a reference for the current only: a shortfall of acceleration (a
    clamp's) moves friction's gains against the population, never against the own law."""
    f = features(5)
    f = replace(f, demand_accel_rpm_s=np.full(f.N, SCALES.accel_limit_rpm_s))  # at the limit
    short = replace(f, accel_residual_rpm_s=f.accel_residual_rpm_s - 50.0)
    det, noise = detector("friction"), NoiseModel.measure([f])
    grid = det.grid(f)

    def gains(x):
        return det.gains(x, noise.weights(x), grid)

    assert np.array_equal(gains(f.own(law=True)), gains(short.own(law=True)))
    assert not np.array_equal(gains(f), gains(short))


def test_a_size_against_the_population_spans_the_units_own_wherever_it_sits():
    """From power-up the fit is against the reference, and a healthy unit sits anywhere in
    the zone u: friction F_ref on it is F_ref/u of its own, a bias b_ref is b_ref − u."""
    factor = widened(Fit("friction", 4.0, (3.6, 4.4), 10.0, "factor"), (0.6, 2.5))
    assert factor.ci95 == pytest.approx((3.6 / 2.5, 4.4 / 0.6))
    bias = widened(Fit("speed_sensor_bias", 11.0, (10.0, 12.0), 10.0, "rpm"), (-2.0, 6.0))
    assert bias.ci95 == pytest.approx((10.0 - 6.0, 12.0 + 2.0))


def test_an_alarm_the_record_no_longer_supports_is_said_so_not_called_a_fault():
    """An event whose fit from its onset to the record's end is back under its threshold
    (a noise excursion) is listed as not confirmed, and the verdict does not call it a
    fault; one still beyond it is the verdict's fault."""
    limits = {n: Threshold(10.0, 1e-3, 0.0, (0.0, 1.8), True) for n in MODEL_BASED}

    def result(log_lr: float):
        fit = Fit("speed_sensor_bias", 0.0, (-0.5, 0.25), log_lr, "rpm")
        event = Event(t_s=199.5, onset_s=150.0, fit=fit, detector=fit.fault, threshold=10.0)
        return Result([event], limits, 600.0, 1e-3)

    faded, held = result(0.0), result(40.0)
    assert not faded.confirmed(faded.events[0]) and held.confirmed(held.events[0])
    assert faded.verdict().startswith("healthy;") and "not confirmed" in faded.verdict()
    assert held.verdict().startswith("speed_sensor_bias") and "not confirmed" not in held.verdict()
    assert faded.to_dict()["events"][0]["confirmed"] is False


def test_an_event_whose_rivals_all_stand_aside_is_refitted_as_it_stands():
    """A friction event beside one named a weak motor (which holds the current too): its
    only rival, the motor, would absorb the other event without being likelier than both,
    so the event keeps its name, refitted on its window up to now (not its alarm's fit)."""
    limits = {n: Threshold(10.0, 1e-3, 0.0, (0.0, 1.8), True) for n in MODEL_BASED}
    bank = FixedBank({"friction": 12.0, "torque_constant": 15.0})
    stale = Fit("friction", 0.8, (0.7, 0.9), 99.0, "factor")
    motor = Fit("torque_constant", 0.8, (0.7, 0.9), 60.0, "factor")
    e = Event(t_s=0.0, onset_s=0.0, fit=stale, detector="friction", threshold=10.0)
    x = Event(t_s=10.0, onset_s=0.0, fit=motor, detector="torque_constant", threshold=10.0)
    events = [e, x]
    _follow(e, events, bank, 50, limits)
    assert events == [e, x] and e.fault == "friction" and e.fit.log_lr == 12.0


def triangle_record(seed: int, n: int = 2400, size: float = 1.0, unit_friction: float = 1.3):
    """(IOData, wheel) of a wheel slewing between ±2000 rpm at its acceleration limit,
    never at constant speed (a chirp's fast part): the driver feeds the reference's
    friction forward, so a unit of ``unit_friction`` × it, and friction × ``size`` from
    the middle sample on, reach the limit short by their friction's excess."""
    rng = np.random.default_rng(seed)
    L, c0 = SCALES.accel_limit_rpm_s, C[0]
    speed, w, up = np.zeros(n), -1900.0, True
    for k in range(n):
        up = (up and w < 2000.0) or w <= -2000.0
        law = C[1] * w + C[2] * np.sign(w)
        f = unit_friction * (size if k >= n // 2 else 1.0)
        w += ((1 if up else -1) * L - (f - 1.0) * law / c0) * TS
        speed[k] = w
    accel = np.concatenate([[0.0], np.diff(speed) / TS])
    current = c0 * np.sign(accel) * L + C[1] * speed + C[2] * np.sign(speed)
    current = current + SIGMA_A * rng.standard_normal(n)
    reported = speed + SIGMA_RPM * rng.standard_normal(n)
    y = np.column_stack([reported, current, np.zeros(n), np.zeros(n)])
    names = ["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"]
    return IOData(speed, y, TS, output_names=names), Replay(speed)


def test_the_units_own_reach_at_the_limit_is_its_reference():
    """A unit dragging 1.3 × the reference's friction reaches the limit short by its
    excess: its own reference at the limit reads δ = 1 − 1.3 from the past alone, and
    the reach less its reference is the noise."""
    from rwlab.diagnose.features import at_limit, limit_reach

    f = compute_features(*triangle_record(0), SCALES).own(law=True)
    reach, x, s = limit_reach(f)
    delta, beta = f.limit_reference.T
    lag = round(150.0 / TS)
    assert not np.isfinite(delta[:lag]).any()  # the past only
    at = at_limit(f) & np.isfinite(delta)
    assert at.sum() > 300
    assert np.allclose(delta[at], -0.3, atol=0.02)
    noise = np.sqrt(2) * SIGMA_RPM / TS  # a difference of two readings, rpm/s
    assert np.std(reach[at]) > 2 * noise
    assert np.std((reach - delta * x - beta * s)[at]) < 1.1 * noise


def test_friction_at_the_limit_is_named_against_the_units_own_past():
    """Never at constant speed, on a unit of 1.3 × the reference's friction (a chirp's
    fast part): friction × 1.7 from mid-record is read at the acceleration limit against
    the unit's own reach, named and sized; the healthy records of such units raise none."""
    slews = [compute_features(*triangle_record(s), SCALES) for s in range(4)]
    holds = [features(s) for s in range(2)]  # the steady channels' noise
    calibration = DiagnosisCalibration.measure(slews + holds, origin="synthetic")
    # the reach's own scatter is measured for its weights: the difference of two readings
    sigma = calibration.noise.sigma["limit_own"][0]
    assert sigma == pytest.approx(np.sqrt(2) * SIGMA_RPM / TS, rel=0.15)
    healthy = run(compute_features(*triangle_record(10), SCALES), calibration)
    assert not healthy.events, healthy.verdict()
    result = run(compute_features(*triangle_record(11, size=1.7), SCALES), calibration)
    assert result.events and result.events[0].fault == "friction", result.verdict()
    fit = result.events[0].fit
    assert result.events[0].t_s >= 600.0 and fit.ci95[0] <= 1.7 <= fit.ci95[1]


def test_a_fits_size_reads_with_its_unit_and_interval():
    """One format on every console line: a factor as ×, a size in its unit, none for a
    fault with no size (the frozen reading)."""
    assert Fit("friction", 2.014, (1.886, 2.151), 30.0, "factor").size_text() == (
        "×2.01 [1.89, 2.15]"
    )
    assert Fit("current_limit", 0.49, (0.45, 0.52), 30.0, "A").size_text() == (
        "0.49 A [0.45, 0.52]"
    )
    assert Fit("speed_sensor_stuck", math.nan, (math.nan, math.nan), 30.0, "").size_text() == ""
