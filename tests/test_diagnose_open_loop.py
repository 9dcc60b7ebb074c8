"""The diagnosis pipeline on acceleration-mode records (``Features.open_loop``): a driver
that feeds its model's current forward, as ``rwlab hil``'s wheels fly.

Truth is a synthetic drive written here from its physics: the current the driver feeds
forward, c₀·α_cmd + the model's friction current, clamped at ±L, and the acceleration a
wheel with friction × F_f and torque constant × F_k reaches on it."""

from __future__ import annotations

import numpy as np
import pytest

from rwlab.data import IOData
from rwlab.diagnose.bank import Bank
from rwlab.diagnose.features import WheelScales, channel_mask, compute_features
from rwlab.diagnose.pipeline import Live, run
from rwlab.diagnose.scales import STICTION_BAND
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.wheel.physics import WheelParams

TS = 0.5
# c = [I/k_t, b/k_t, τ_c/k_t, offset] of a small wheel, A per (rpm/s, rpm, 1, 1)
C = (1.8e-3, 2.5e-6, 9.2e-3, 0.0)
LIMIT_A = 0.7
SCALES = WheelScales(TS, accel_limit_rpm_s=300.0, current_limit_a=LIMIT_A, current_model=C)
SIGMA_A = 0.004  # current noise, A
SIGMA_RPM = 0.3  # speed noise, rpm
N = 3600  # 30 min


def command(n: int) -> np.ndarray:
    """A calm loop's dither (±10 rpm/s, 4 s) and a ±3-s push to 270 rpm/s and back every
    minute, rpm/s."""
    t = TS * np.arange(n)
    push = np.where(t % 60 < 3, 270.0, np.where((t % 60 >= 3) & (t % 60 < 6), -270.0, 0.0))
    return 10.0 * np.cos(2 * np.pi * t / 4.0) + np.where(t >= 60, push, 0.0)


def record(
    seed: int,
    fault: str = "",
    size: float = 1.0,
    onset: int = N - 600,
    speed0: float = 1500.0,
    noise: float = 1.0,
) -> IOData:
    """An acceleration-mode record: u = the command (rpm/s), the drive's truth above;
    ``noise`` scales the sensors' noise."""
    rng = np.random.default_rng(seed)
    cmd = command(N)
    f_fric = np.where(np.arange(N) >= onset, size if fault == "friction" else 1.0, 1.0)
    f_kt = np.where(np.arange(N) >= onset, size if fault == "torque_constant" else 1.0, 1.0)
    clamp = np.where(np.arange(N) >= onset, size if fault == "current_limit" else LIMIT_A, LIMIT_A)
    speed, current = np.empty(N), np.empty(N)
    speed[0], current[0] = speed0, 0.0
    for k in range(1, N):  # the command of k-1 is in force over (k-1, k]
        w = speed[k - 1]
        friction = C[1] * w + C[2] * np.sign(w)
        i = np.clip(C[0] * cmd[k - 1] + friction, -clamp[k], clamp[k])
        speed[k] = w + TS * (f_kt[k] * i - f_fric[k] * friction) / C[0]
        current[k] = i
    y = np.column_stack(
        [
            speed + noise * SIGMA_RPM * rng.standard_normal(N),
            current + noise * SIGMA_A * rng.standard_normal(N),
            np.zeros(N),
            np.zeros(N),
        ]
    )
    names = ["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"]
    return IOData(cmd[:, None], y, TS, output_names=names, input_units=["rpm/s"])


@pytest.fixture(scope="module")
def calibration() -> DiagnosisCalibration:
    records = [compute_features(record(s), None, SCALES) for s in range(8)]
    return DiagnosisCalibration.measure(records, origin="synthetic drive")


def test_the_drives_own_model_leaves_no_residual():
    f = compute_features(record(0, noise=0.0), None, SCALES)
    assert f.open_loop and f.saturated.all()
    # the balance reads the friction at the sample's speed, the drive fed the one before
    # forward: they differ by c₁·Δω, 135 rpm × c₁ in a push
    step = np.max(np.abs(np.diff(f.speed_rpm)))
    assert np.max(np.abs(f.current_residual_a[1:])) <= C[1] * step * (1 + 1e-9)
    assert np.max(np.abs(f.accel_residual_rpm_s[1:])) < 1e-9
    # no speed reference: the speed channel is read nowhere
    assert not channel_mask(f, "speed").any()


@pytest.mark.parametrize(
    ("fault", "size"),
    [
        ("friction", 3.0),
        ("friction", 1.7),
        ("torque_constant", 0.5),
        # a clamp that binds only in the pushes (it was named a weak motor ×0.956 while
        # rounding made every sample of the record look clamped)
        ("current_limit", 0.45),
    ],
)
def test_a_drive_fault_is_named_and_sized(calibration, fault, size):
    result = run(compute_features(record(11, fault, size), None, SCALES), calibration)
    first = result.events[0]
    assert first.fault == fault
    assert (N - 600) * TS <= first.t_s <= (N - 600) * TS + 120
    # within 1 %: the balance reads the friction at the sample's speed, the drive fed the
    # previous sample's forward, and the intervals of noise this small are a few ‰ wide
    assert first.fit.ci95[0] / 1.01 <= size <= first.fit.ci95[1] * 1.01


def test_healthy_records_of_other_seeds_raise_no_alarm(calibration):
    for seed in (21, 22, 23):
        assert run(compute_features(record(seed), None, SCALES), calibration).events == []


def test_the_stiction_band_is_not_read():
    params = WheelParams()
    scales = WheelScales.from_params(params, TS)
    stribeck = params.stribeck_speed_rpm if params.stiction else 0.0
    assert scales.stiction_band_rpm == STICTION_BAND * max(stribeck, params.min_measurable_rpm)
    f = compute_features(record(0, speed0=0.5 * scales.stiction_band_rpm), None, scales)
    slow = np.abs(f.speed_rpm) < scales.stiction_band_rpm
    assert slow.any() and (~slow).any()
    assert not channel_mask(f, "current")[slow].any()
    assert channel_mask(f, "current")[~slow].any()


def test_the_scales_of_a_wheel_model_are_its_feed_forward():
    params = WheelParams()
    s = WheelScales.from_params(params, TS)
    rad = np.pi / 30
    kt = params.torque_constant
    assert s.current_model[0] == pytest.approx(params.inertia * rad / kt)
    # the current the model needs at 1000 rpm and rest: its friction torque over k_t
    torque = params.viscous_friction * 1000 * rad + params.coulomb_friction
    assert s.current_model[1] * 1000 + s.current_model[2] == pytest.approx(torque / kt)
    assert s.accel_limit_rpm_s == params.max_accel_rpm_s
    assert s.current_limit_a == params.current_limit


def test_a_growing_record_is_decided_as_the_whole_record(calibration):
    """``Live`` on the record as it grows (an update every 10 samples) opens the events
    ``run`` opens on the whole record, at the same times, named and sized alike; the bank
    it grows holds the batch bank's gains to round-off."""
    data = record(12, "friction", 2.0)
    whole = compute_features(data, None, SCALES)
    live = Live(calibration)
    for n in [*range(20, data.N, 10), data.N]:
        live.update(compute_features(data[:n], None, SCALES))
    batch = run(whole, calibration)
    assert [(e.t_s, e.first, e.fault) for e in live.events] == [
        (e.t_s, e.first, e.fault) for e in batch.events
    ]
    assert live.events and live.events[0].fault == "friction"
    assert live.events[0].fit.size == pytest.approx(batch.events[0].fit.size, rel=1e-9)
    # each alarm's onset and its size then, as the whole record's
    assert [e.onset_s for e in live.events] == [e.onset_s for e in batch.events]
    sizes = [e.at_alarm.size for e in batch.events]
    assert [e.at_alarm.size for e in live.events] == pytest.approx(sizes, rel=1e-9, nan_ok=True)
    grown = live._bank
    bank = Bank(whole, calibration.noise, calibration.zones, calibration.drift)
    for name in bank.cum:  # the rows the live bank still keeps: its last windows'
        for table, batch in ((grown.cum, bank.cum), (grown.cum_own, bank.cum_own)):
            kept = table[name]
            assert 0 < kept.first and kept.first + kept.n == whole.N + 1
            rows = batch[name].rows[kept.first :]
            scale = max(float(np.max(np.abs(rows))), 1.0)
            assert np.max(np.abs(kept.rows - rows)) <= 1e-9 * scale
    assert live.decisions == len(bank.ends())
