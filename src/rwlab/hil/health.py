"""Wheel health in the loop: a null-space excitation and a command-tracking test.

A calm attitude loop barely moves its wheels (a few rpm/s at most), too little
for the :mod:`rwlab.diagnose` block tests, which need sustained accelerations
to compare a current against. A redundant wheel set has a direction the body
cannot feel: the null space ``n`` of the wheel matrix (``G n = 0``). A small
zero-mean acceleration along ``n`` (:class:`NullSpaceDither`) makes every
wheel accelerate and decelerate all the time while the satellite feels no
torque — as long as every wheel follows its command.

:class:`TrackingTest` watches exactly that: over each window it compares the
speed change a wheel reports with the change its commands asked for. The
residual (rpm/s) of a healthy wheel is the sensor noise and the drive's
tracking error; it is calibrated on the wheel's first ``calibration_s`` in the
loop (its healthy spread, never a fault's) and then standardised into a
two-sided CUSUM whose threshold gives the requested false-alarm rate
(:func:`rwlab.diagnose.detect.cusum_threshold`). At an alarm the samples of
the excursion name the fault by its signature (:func:`name_fault`): the
dither's share the wheel did not follow (a motor without torque), the current
the drive delivered against the one its own feed-forward asked for (a clamped
current), or a drag that does not depend on the command (friction).

A window in which the wheel's reading comes within
:data:`~rwlab.diagnose.scales.STICTION_BAND` ×
its Stribeck speed of zero (or of the Hall sensor's dead zone, where it reads
0) is not tested: there the healthy law is breakaway — the wheel sticks at
zero until its motor torque beats the static friction, which its drive's
Coulomb feed-forward does not model — so a healthy wheel's residual is not its
calibrated spread (measured: after a pyramid loses a wheel the three others
lose their null-space bias, cross zero and dwell there ~10 s, which the CUSUM
took for friction). At three Stribeck speeds the Stribeck excess is e⁻⁹ of
itself: outside the band the test sees the wheel as calibrated.

A current clamp that the calm loop never reaches is invisible to that test (a
wheel 1000 rpm from zero draws a few percent of its clamp) and harmless until
the loop needs the torque. So every :data:`PROBE_EVERY_S` the excitation adds
a **capacity probe**: a null-space push at :data:`PROBE_SHARE` of the wheel's
rated acceleration for :data:`PROBE_S`, then the same back (the speeds return,
the body feels nothing while every wheel follows). The speed change over the
push is compared with the command, against the wheel's own first
:data:`PROBE_CALIBRATION` probes; a shortfall beyond the false-alarm rate's
threshold is named by the probe's signature (:meth:`rwlab.hil.probe.Probe.named`): a clamp's
missing current explains at least half its missing speed change
(``current_limit``); a motor that lost torque misses the push and the way back
alike (``torque_constant``); a drag against the rotation costs the push away
from zero and helps the way back (``friction``); a reading that did not move
over the whole probe is a frozen sensor (``speed_sensor_stuck``). A weak motor also drags on the
held speed (its drive's friction feed-forward falls short), which the tracking
test sees first, and a drag the attitude loop fights looks like a motor that
does not follow (the commands grow as the wheel falls behind): the tracking
test's name of a rotor fault is a guess, which ``rwlab hil`` replaces by the
idled wheel's coast-down (:mod:`rwlab.hil.run`); a tracking alarm that names a
bias asks for a probe at once, and the probe names it.

Hand-written: no library offers a command-tracking monitor for a wheel drive.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from rwlab.diagnose.detect import Cusum, arl_to_samples, cusum_threshold
from rwlab.diagnose.scales import stiction_band_rpm
from rwlab.errors import ConfigError
from rwlab.hil.probe import Half, Probe
from rwlab.wheel.physics import WheelParams, rpm_to_rad_s

__all__ = [
    "NullSpaceDither",
    "TrackingAlarm",
    "TrackingTest",
    "name_fault",
    "nominal_friction_nm",
    "null_vector",
    "stiction_band_rpm",
]

DITHER_RPM_S = 10.0  # amplitude of the excitation's acceleration, rpm/s (±6 rpm of speed)
DITHER_PERIOD_S = 4.0  # its period, s: a few periods fit in the time a fault must be named
WINDOW_S = 1.0  # the tracking test's window, s
CLIP = 4.0  # standardised residuals enter the CUSUM clipped to ±CLIP σ
MIN_NAMING_S = 2.0  # the excursion's samples that name a fault: at least this many seconds
FOLLOW_MAX = -0.3  # residual ∝ −command beyond this share: the wheel does not follow
CURRENT_SHARE = 0.5  # delivered current below this share of the requested one: clamped
PROBE_SHARE = 0.9  # the probe's push, × the rated acceleration: a clamp costing more is seen
PROBE_S = 1.0  # the push lasts this long, s, and the way back as long
PROBE_EVERY_S = 60.0  # a probe starts every this many seconds of flight (the first at this)
PROBE_SETTLE_S = 1.0  # the tracking test skips this long after a probe (the drive's lag)
PROBE_CALIBRATION = 3  # a wheel's first probes in the loop are its healthy ones
PROBE_WAIT_S = 3.0  # a tracking alarm waits this long for the probe that names it
# a tracking alarm that names a bias waits for a probe to name it. One that names a rotor
# fault does not: the tracking test cannot tell a weak motor from a drag the attitude loop
# fights (friction x 4 was named torque_constant on 6 of 11 seeds), and a probe pushed with
# a wheel that cannot follow cost up to 0.096 deg of a 0.1 deg requirement after a dead
# motor; rwlab hil idles the wheel at once and names it by its coast-down (run.py)
DRAG_NAMES = ("speed_sensor_bias",)
# a drive that misses more of a push than this share is not a healthy one of its spec: a
# healthy drive's lag costs ~2 % (RW90 4.5-6.6 rpm of 289, NRWA-T6 3.3-4.4 of 203)
PROBE_LAG_MAX = 0.1


def nominal_friction_nm(params: WheelParams, speed_rpm: float) -> float:
    """The wheel model's friction torque against the rotation, N·m (viscous and Coulomb:
    its drive's feed-forward).

    Parameters
    ----------
    params : WheelParams
        The wheel model.
    speed_rpm : float
        The wheel's speed, rpm.

    Returns
    -------
    float
        Friction torque, N·m, with the sign of the speed.
    """
    w = rpm_to_rad_s(speed_rpm)
    coulomb = params.coulomb_friction * math.copysign(1.0, w) * (abs(w) > 1e-9)
    return params.viscous_friction * w + coulomb


def null_vector(G: np.ndarray) -> np.ndarray | None:
    """The wheel set's null direction (N,), largest entry ±1; None without one.

    Parameters
    ----------
    G : (3, N) array
        Wheel axes in the body frame (columns).

    Returns
    -------
    (N,) array or None
        ``n`` with ``G n = 0`` (the last right singular vector), scaled so that
        ``max |n| = 1``; None when the columns have no null space.
    """
    G = np.asarray(G, dtype=float)
    if G.shape[1] == 0:
        return None
    _, s, vt = np.linalg.svd(G)
    if G.shape[1] <= int(np.sum(s > 1e-9 * max(s.max(), 1.0))):
        return None
    n = vt[-1]
    return n / np.max(np.abs(n))


class NullSpaceDither:
    """A zero-mean acceleration of the wheels along the null space of the active set.

    Parameters
    ----------
    G : (3, N) array
        Wheel axes (columns).
    inertia : float
        One wheel's rotor inertia, kg·m².
    amplitude_rpm_s : float
        Peak commanded acceleration of the wheel that moves most, rpm/s.
    period_s : float
        Period of the cosine, s (its speed swing, ``amplitude · period / 2π``, is zero-mean).
    probe_rpm_s : float
        The capacity probe's push, rpm/s (0: no probe); see :meth:`probe_phase`.
    probe_every_s, probe_s : float
        A probe starts every ``probe_every_s`` s (the first at ``probe_every_s``) and
        pushes for ``probe_s`` s, then pulls back as long.
    """

    def __init__(
        self,
        G: np.ndarray,
        inertia: float,
        amplitude_rpm_s: float = DITHER_RPM_S,
        period_s: float = DITHER_PERIOD_S,
        probe_rpm_s: float = 0.0,
        probe_every_s: float = PROBE_EVERY_S,
        probe_s: float = PROBE_S,
    ) -> None:
        if not (amplitude_rpm_s >= 0 and period_s > 0 and inertia > 0 and probe_rpm_s >= 0):
            raise ConfigError("the dither needs amplitudes ≥ 0, a period > 0 and an inertia > 0")
        if probe_rpm_s > 0 and not 0 < 2 * probe_s < probe_every_s:
            raise ConfigError("a probe's push and return must fit in its period")
        self.G = np.asarray(G, dtype=float)
        self.torque_amplitude = inertia * rpm_to_rad_s(amplitude_rpm_s)  # N·m
        self.probe_torque = inertia * rpm_to_rad_s(probe_rpm_s)  # N·m
        self.period_s, self.probe_every_s, self.probe_s = period_s, probe_every_s, probe_s
        self._extra_start: float | None = None  # s: a probe asked for off the schedule
        self._active: tuple[bool, ...] | None = None
        self._n: np.ndarray | None = None

    def torques(self, t: float, active: np.ndarray) -> np.ndarray:
        """The excitation's wheel torques at a time, probes included.

        Parameters
        ----------
        t : float
            Flight time, s.
        active : (N,) array of bool
            The wheels being driven.

        Returns
        -------
        (N,) array
            Torques, N·m: zero on idle wheels, and everywhere once the active wheels have
            no null space left.
        """
        key = tuple(bool(a) for a in active)
        if key != self._active:
            self._active = key
            mask = np.array(key)
            n = null_vector(self.G[:, mask])
            self._n = None
            if n is not None:
                self._n = np.zeros(mask.size)
                self._n[mask] = n
        if self._n is None:
            return np.zeros(len(key))
        dither = self.torque_amplitude * math.cos(2 * math.pi * t / self.period_s)
        return (dither + self.probe_phase(t) * self.probe_torque) * self._n

    def probe_phase(self, t: float) -> int:
        """Where a capacity probe is at a time.

        Parameters
        ----------
        t : float
            Flight time, s.

        Returns
        -------
        int
            +1 while a probe pushes, −1 while it pulls back, else 0 (always 0 without a
            probe, or once the active wheels have no null space).
        """
        t += 1e-6  # s: a time k·dt computed as a float may fall a hair short of a boundary
        if self.probe_torque == 0.0 or self._n is None:
            return 0
        if self._extra_start is not None and t >= self._extra_start:
            into = t - self._extra_start
            if into < 2 * self.probe_s:
                return 1 if into < self.probe_s else -1
            self._extra_start = None
        if t < self.probe_every_s:
            return 0
        into = t % self.probe_every_s
        return 1 if into < self.probe_s else -1 if into < 2 * self.probe_s else 0

    def probe_soon(self, t: float) -> None:
        """Ask for a probe off the schedule, starting at ``t`` (s): none when one is under
        way, or when the scheduled one comes before this one would have settled.

        Parameters
        ----------
        t : float
            Flight time, s: the next control period's start.
        """
        if self.probe_phase(t) != 0 or self._extra_start is not None:
            return
        scheduled = max(self.probe_every_s, (t // self.probe_every_s + 1) * self.probe_every_s)
        if scheduled - t > 2 * self.probe_s + PROBE_SETTLE_S:
            self._extra_start = t


def name_fault(
    accel_cmd: np.ndarray,
    accel_meas: np.ndarray,
    current: np.ndarray,
    current_requested: np.ndarray,
    speed_rpm: float,
) -> str:
    """Name a tracking fault from its excursion's samples (one per control period).

    Parameters
    ----------
    accel_cmd, accel_meas : (K,) arrays
        Commanded and reported acceleration of each period, rpm/s.
    current, current_requested : (K,) arrays
        Reported current and the current the drive's feed-forward asks for, A.
    speed_rpm : float
        The wheel's speed, rpm (the sign a drag opposes).

    Returns
    -------
    str
        ``current_limit`` (the drive delivered well under the current it asked for),
        ``torque_constant`` (the current flows but the wheel does not follow its
        command), ``friction`` (it follows, with a drag against the rotation) or
        ``speed_sensor_bias`` (the reading moves without command or drag).
    """
    a_c, a_m = np.asarray(accel_cmd, float), np.asarray(accel_meas, float)
    asked = float(np.mean(np.abs(current_requested)))
    if asked > 0 and float(np.mean(np.abs(current))) < CURRENT_SHARE * asked:
        return "current_limit"
    r = a_m - a_c
    X = np.column_stack([a_c, np.ones_like(a_c)])
    (slope, offset), *_ = np.linalg.lstsq(X, r, rcond=None)
    if np.ptp(a_c) > 0 and slope < FOLLOW_MAX:
        return "torque_constant"
    if offset * math.copysign(1.0, speed_rpm) < 0:
        return "friction"
    return "speed_sensor_bias"


@dataclass(frozen=True)
class TrackingAlarm:
    """A wheel that does not follow its commands.

    Attributes
    ----------
    kind : str
        The fault named (:func:`name_fault`, or the probe's naming).
    test : str
        ``"tracking CUSUM"`` (the command-tracking test), ``"tracking CUSUM, named by a
        probe"``, ``"capacity probe"`` or ``"capacity probe, share missed"`` (a calibration
        probe).
    statistic, threshold : float
        The CUSUM statistic and its threshold, or the probe's shortfall in its healthy
        σ and the threshold of the false-alarm rate per probe.
    """

    kind: str
    test: str
    statistic: float
    threshold: float


class TrackingTest:
    """One wheel's command-tracking test and capacity probe (see the module's docstring).

    Parameters
    ----------
    dt : float
        The control period, s (one :meth:`update` per period).
    params : WheelParams
        The wheel's nominal parameters (its drive's feed-forward: the current it asks for).
    calibration_s : float
        Seconds of the wheel's own healthy residuals that calibrate the test.
    false_alarms_per_hour : float
        Accepted false-alarm rate of this wheel's tests together: with probes, half is
        the tracking test's and half the probes'.
    window_s : float
        The residual's window, s (a whole number of control periods).
    probe_every_s : float, optional
        How often a capacity probe comes, s (None: no probes).
    tracking : bool
        Run the command-tracking CUSUM (False: the GLR pipeline watches the wheel,
        :mod:`rwlab.hil.live`; the spread is still measured, the probes still judged).
    """

    def __init__(
        self,
        dt: float,
        params: WheelParams,
        calibration_s: float,
        false_alarms_per_hour: float,
        window_s: float = WINDOW_S,
        probe_every_s: float | None = None,
        tracking: bool = True,
    ) -> None:
        self.every = max(1, round(window_s / dt))
        self.dt, self.window_s, self.params = dt, self.every * dt, params
        self.tracking = tracking
        self.calibration_windows = max(30, math.ceil(calibration_s / self.window_s))
        rate = false_alarms_per_hour / (1 if probe_every_s is None else 2)
        self.cusum = Cusum(cusum_threshold(arl_to_samples(rate, self.window_s)), clip=CLIP)
        self.probe_z = float(norm.isf(rate * (probe_every_s or math.inf) / 3600.0))
        self.healthy_probes: list[Probe] = []
        self._probing: Probe | None = None
        # a tracking alarm whose drag a probe names (friction, or a motor that lost torque)
        self._pending: TrackingAlarm | None = None
        self._waited = 0  # periods the pending alarm has waited for its probe
        self.wants_probe = False
        self._settle = 0  # periods the tracking test still skips after a probe
        self.mean = self.sigma = self.robust_sigma = math.nan
        self.band_rpm = stiction_band_rpm(params)
        self._skip = False  # the window touched the stiction band or a probe
        self.skipped_windows = 0
        self.windows_tested = self.probes_tested = 0  # after calibration
        self._calibration: list[float] = []
        self._last_speed: float | None = None
        self._start_speed: float | None = None
        self._commanded = 0.0  # commanded speed change over the window so far, rpm
        self._n = 0
        keep = round(600.0 / dt)  # the longest excursion that names a fault, periods
        self._samples: deque[tuple[float, float, float, float]] = deque(maxlen=keep)
        self._excursion = 0  # samples since the alarming side of the CUSUM left zero

    @property
    def calibrated(self) -> bool:
        return math.isfinite(self.sigma)

    def _requested_current(self, accel_rpm_s: float, speed_rpm: float) -> float:
        p = self.params
        torque = p.inertia * rpm_to_rad_s(accel_rpm_s) + nominal_friction_nm(p, speed_rpm)
        return max(-p.current_limit, min(p.current_limit, torque / p.torque_constant))

    def update(
        self, accel_cmd_rpm_s: float, speed_rpm: float, current_a: float, probe: int = 0
    ) -> TrackingAlarm | None:
        """One control period.

        Parameters
        ----------
        accel_cmd_rpm_s : float
            The acceleration commanded over the period, rpm/s.
        speed_rpm, current_a : float
            The speed (rpm) and current (A) reported at its end.
        probe : int
            The capacity probe's phase over it (:meth:`NullSpaceDither.probe_phase`).

        Returns
        -------
        TrackingAlarm or None
            The alarm, if this period raised one.
        """
        last = speed_rpm if self._last_speed is None else self._last_speed
        self._last_speed = speed_rpm
        found = self._probe(probe, accel_cmd_rpm_s, last, speed_rpm, current_a)
        if self._pending is not None:
            return found or self._still_pending(probe)
        self._settle = round(PROBE_SETTLE_S / self.dt) if probe else max(self._settle - 1, 0)
        self._skip |= probe != 0 or self._settle > 0
        window = self._window(accel_cmd_rpm_s, last, speed_rpm, current_a)
        if window is not None and window.kind in DRAG_NAMES and self._named_by_probes:
            self._pending, self.wants_probe = window, True  # a drag: friction or a motor?
            self._waited = 0
            return found
        return found or window

    @property
    def _named_by_probes(self) -> bool:
        return len(self.healthy_probes) == PROBE_CALIBRATION

    def _still_pending(self, probe: int) -> TrackingAlarm | None:
        """The pending alarm as named by its probe once that probe is done; as the tracking
        test named it if no probe came within :data:`PROBE_WAIT_S`."""
        assert self._pending is not None
        self.wants_probe = self.wants_probe and probe == 0
        self._waited += 1
        if self._probing is None and self._waited * self.dt > PROBE_WAIT_S:
            pending, self._pending = self._pending, None
            return pending
        return None

    def _window(
        self, accel_cmd_rpm_s: float, last: float, speed_rpm: float, current_a: float
    ) -> TrackingAlarm | None:
        """The command-tracking test's step: a window's residual into the CUSUM."""
        if self._start_speed is None:
            self._start_speed = last
        self._samples.append(
            (
                accel_cmd_rpm_s,
                (speed_rpm - last) / self.dt,
                current_a,
                self._requested_current(accel_cmd_rpm_s, speed_rpm),
            )
        )
        self._commanded += accel_cmd_rpm_s * self.dt
        self._n += 1
        self._excursion += 1
        self._skip |= abs(speed_rpm) < self.band_rpm or abs(last) < self.band_rpm
        if self._n < self.every:
            return None
        residual = (speed_rpm - self._start_speed - self._commanded) / self.window_s
        self._start_speed, self._commanded, self._n = speed_rpm, 0.0, 0
        if self._skip:  # breakaway or a probe, not tracking, rules this window: no evidence
            self._skip = False
            self.skipped_windows += 1
            return None
        if not self.calibrated:
            self._calibration.append(residual)
            if len(self._calibration) >= self.calibration_windows:
                values = np.array(self._calibration)
                self.mean = float(np.mean(values))
                floor = self.params.speed_resolution_rpm / self.window_s / math.sqrt(12)
                self.sigma = max(float(np.std(values, ddof=1)), floor)
                # the probe's: one transient in calibration (a wheel at its speed limit
                # while the attitude is acquired) must not blunt every probe after it
                mad = float(np.median(np.abs(values - np.median(values))))
                self.robust_sigma = max(1.4826 * mad, floor)
            return None
        if not self.tracking:  # the GLR pipeline watches this wheel
            return None
        before = self.cusum.statistic
        self.windows_tested += 1
        alarm = self.cusum.update((residual - self.mean) / self.sigma)
        if before == 0.0:
            self._excursion = self.every  # the excursion starts with this window
        if not alarm:
            if self.cusum.statistic == 0.0:
                self._excursion = 0
            return None
        k = min(len(self._samples), max(self._excursion, round(MIN_NAMING_S / self.dt)))
        rows = np.array(list(self._samples)[-k:])
        kind = name_fault(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], speed_rpm)
        return TrackingAlarm(kind, "tracking CUSUM", self.cusum.statistic, self.cusum.h)

    def _probe(
        self, phase: int, accel_cmd_rpm_s: float, last: float, speed_rpm: float, current_a: float
    ) -> TrackingAlarm | None:
        """Follow a probe; when it is done, judge it against the wheel's healthy ones."""
        requested = self._requested_current(accel_cmd_rpm_s, speed_rpm)
        row = (accel_cmd_rpm_s * self.dt, speed_rpm, current_a, requested)
        if phase == 1:
            self._probing = self._probing or Probe(Half(last))
            self._probing.out.add(*row)
            return None
        if phase == -1 and self._probing is not None:
            self._probing.back = self._probing.back or Half(last)
            self._probing.back.add(*row)
            return None
        done, self._probing = self._probing, None
        if done is None or not done.complete:  # none, or cut short (a wheel was idled)
            return None
        if self._pending is not None:  # a tracking alarm: the probe names the drag
            pending, self._pending = self._pending, None
            if not self._probe_sees(done):  # nothing a probe can see: the test's name
                return pending
            kind, how = done.named(self.healthy_probes), "tracking CUSUM, named by a probe"
            return TrackingAlarm(kind, how, pending.statistic, pending.threshold)
        if not self._named_by_probes:
            share = done.out.shortfall_rpm / abs(done.out.commanded_rpm)
            if share > PROBE_LAG_MAX:  # faulty from the start: not a healthy probe
                kind = done.named([])
                return TrackingAlarm(kind, "capacity probe, share missed", share, PROBE_LAG_MAX)
            self.healthy_probes.append(done)
            return None
        if not self.calibrated:
            return None
        healthy = np.mean([p.out.shortfall_rpm for p in self.healthy_probes])
        self.probes_tested += 1
        z = (done.out.shortfall_rpm - healthy) / self._probe_sigma_rpm()
        if z <= self.probe_z:
            return None
        kind = done.named(self.healthy_probes)
        return TrackingAlarm(kind, "capacity probe", float(z), self.probe_z)

    def _probe_sigma_rpm(self) -> float:
        """A probe half's shortfall noise against the healthy probes' mean, rpm."""
        healthy = [p.out.shortfall_rpm for p in self.healthy_probes]
        # the window test's σ is the same reading noise over the same second
        sigma = max(self.robust_sigma * self.window_s, float(np.std(healthy, ddof=1)))
        return sigma * math.sqrt(1 + 1 / len(healthy))

    def _probe_sees(self, probe: Probe) -> bool:
        """Whether the probe's drag or symmetric shortfall left the healthy probes' spread."""
        if not self.calibrated:
            return False
        h = self.healthy_probes
        drag = probe.drag_rpm - np.mean([p.drag_rpm for p in h])
        symmetric = probe.symmetric_rpm - np.mean([p.symmetric_rpm for p in h])
        return bool(max(abs(drag), abs(symmetric)) > self.probe_z * self._probe_sigma_rpm())

    def healthy_spread_rpm_s(self) -> float:
        """The calibrated spread of the window residual.

        Returns
        -------
        float
            σ, rpm/s (NaN before calibration).
        """
        return self.sigma

    def healthy_probe_summary(self) -> dict | None:
        """What the wheel's healthy probes measured.

        Returns
        -------
        dict or None
            ``shortfall_rpm`` (mean speed change a push missed, rpm), ``drag_rpm`` (its
            part that a drag explains, :class:`Probe`) and ``current_a`` (mean current
            over a push, A); None before the healthy probes are in.
        """
        if len(self.healthy_probes) < PROBE_CALIBRATION:
            return None
        probes = self.healthy_probes
        return {
            "shortfall_rpm": float(np.mean([p.out.shortfall_rpm for p in probes])),
            "drag_rpm": float(np.mean([p.drag_rpm for p in probes])),
            "current_a": float(np.mean([p.out.current_a for p in probes])),
        }
