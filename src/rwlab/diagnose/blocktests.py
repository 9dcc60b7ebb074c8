"""The block tests of the diagnosis: one test's qualifying values into block means and a
CUSUM (:class:`BlockCusum`), and the tests that compare a record with its own past
(:class:`FrictionChange`, :class:`SlewChange`, :class:`HoldChange`,
:class:`ClampedFriction`, :class:`FrozenMotor`) or count lost frames (:class:`Dropout`).
:class:`~rwlab.diagnose.diagnoser.Diagnoser` feeds them each sample; its module docstring
says what each test takes and alarms on.

Why this module is long: the block tests share one CUSUM of block means and one
own-past comparison; each class is short. The GLR pipeline (``pipeline``) is to replace them.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from rwlab.diagnose.constants import measured
from rwlab.diagnose.isolate import (
    CURRENT_OFFSET_SD_A,
)
from rwlab.diagnose.reference import (
    BlockStats,
    nominal_friction_currents,
    unit_bounds,
)
from rwlab.wheelspec import WheelSpec

CUSUM_K = 0.5
# σ of the ridge prior of a unit's friction law about the reference's, in nominal friction
# currents: two units each within ±30 % of nominal differ by σ ≈ 0.25, and the reference's
# identified Coulomb/viscous split errs on top of that
CHANGE_PRIOR = measured("CHANGE_PRIOR")
GUARD_S = 300.0  # the change test's baseline: samples at least this old, s
CHANGE_MIN_RPM = 1500.0  # ... and its change within a record (below, the excess of a unit's
# friction over the reference's varies with speed beyond its viscous + Coulomb law)
# The change test compares a sample only where its baseline law interpolates: the law's
# excess over the reference is fitted mostly on the other sign's or other speeds' samples
# elsewhere, and the reference's own Coulomb/viscous/offset split errs (mA of offset, tens
# of % of viscous friction), so a law extrapolated from one held speed to another of its
# sign reads a healthy unit's holds many σ high: a false friction alarm
SIGN_MIN = 20  # baseline samples at the sample's sign of speed
SPAN_MARGIN_RPM = 300.0  # ... whose |ω| span reaches the sample's within this
BLOCK_OWN = 20  # samples per independent value of the own friction samples (as a block)
HOLD_BASE = 20  # settled samples at a held speed that give this record's own current there
HOLD_TOLERANCE = 0.1  # friction rise a healthy unit shows within a record (drift 5 %/√h,
# the bearing's warm-up), relative to its own friction current
HOLD_DRIFT_SD = 0.05  # relative drift of a unit's friction between two holds (the twin's
# random walk is 5 %/√h; a record's holds are minutes apart)
HOLD_SIGN_SD = measured("HOLD_SIGN_SD")  # relative σ between a unit's friction at +ω and −ω
REST_CURRENT_SD_A = 0.5e-3  # the current of a wheel resting since power-up at a 0-rpm
# command is the sense offset (the loop's integrator has not moved); after a motion the
# rest holds the integrator's residue (up to ~4 mA on the twin's units)
HOLD_MIN_SD_A = 1e-3  # floor of a hold's current σ (the current's LSB is 2 mA)
CLAMP_QUIET_RPM_S = 15.0  # the unit's own friction samples: its mean acceleration below
# this (the inertial current there differs between units by ≤ 1.2 mA of ~10 mA friction)
CLAMP_OWN_RPM = 200.0  # ... and at least this fast, rpm
CLAMP_OWN_MIN = 40  # own samples before a clamped slew is compared with them
CLAMP_COUNT = 2  # clamped slews before the test decides
CLAMP_RECENT = 6  # it decides on the median of the latest this many
CLAMP_EXCESS = 0.2  # ... and alarms where it exceeds this
CLAMP_SLEW_RPM = 500.0  # a slew's halves at least this fast on average: slower ones (a
# fast chirp's) are a few samples a half, and read up to +0.3–0.6 on healthy bearings
# a step's charge over the unit's own level before the freeze that alarms (a healthy
# unit's later charges scatter a few % about its earlier ones) ...
CHARGE_EXCESS = measured("CHARGE_EXCESS")
# ... or, without an own level, over the reference's, beyond the datasheet's I/k_t headroom
CHARGE_MARGIN = measured("CHARGE_MARGIN")
HISTORY_S = 600.0  # block means kept for estimating a fault's size, s
# The slew-change test's baseline: the record's slews at least SLEW_GUARD_S old, the
# latest SLEW_BASE_MAX of them, at least SLEW_BASE_MIN. A chirp's slews through zero
# qualify only while its swing is ±500–3000 rpm (the default chirp: 480–680 s, every
# 10–40 s), so a guard of minutes leaves no baseline before they end
SLEW_GUARD_S = 60.0
SLEW_BASE_MIN = 3
SLEW_BASE_MAX = 10


def _law_prior(spec: WheelSpec | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The datasheet's friction law as current [viscous A/rpm, Coulomb A, offset A] and
    the σ of a unit's law about it: :data:`CHANGE_PRIOR` of each friction part, the
    spec's current-sense offset tolerance (the RW90's 5 mA); ``spec`` default the RW90's."""
    viscous, coulomb = nominal_friction_currents(spec)
    offset = unit_bounds(spec).current_offset_a
    sd = np.array([CHANGE_PRIOR * viscous, CHANGE_PRIOR * coulomb, max(offset, HOLD_MIN_SD_A)])
    return np.array([viscous, coulomb, 0.0]), sd


class BlockCusum:
    """Block means of one test's values, standardised, into a one- or two-sided CUSUM."""

    def __init__(
        self, stats, tolerance: float, h: float, sides: str, baseline_blocks: int = 0
    ) -> None:
        self.stats, self.h, self.sides = stats, h, sides
        self.k = CUSUM_K + tolerance / stats.sigma
        self.baseline_blocks = baseline_blocks  # > 0: the mean of the record's first blocks
        self._baseline: list[float] = []
        self.mean = stats.mean
        self._values: list[float] = []
        self.up = self.down = 0.0
        self.means: deque = deque()  # (t_s, block mean, up, down)
        self.trace: list[float] | None = None  # every block's z, when calibrating
        self.raw: deque = deque()  # (t_s, value): the single values, for sizing a fault
        self.decided = 0  # blocks tested (after any baseline): what "no alarm" rests on

    @property
    def statistic(self) -> float:
        return max(self.up, self.down)

    def add(self, t_s: float, value: float, allowance: float = 0.0) -> bool:
        """One qualifying value; ``allowance``: tolerance beyond the CUSUM's own at this
        value (value units), taken off before the block mean (the value kept for sizing
        is the plain one). True on an alarm."""
        self._values.append(value - allowance)
        self.raw.append((t_s, value))
        while self.raw[0][0] < t_s - HISTORY_S:
            self.raw.popleft()
        if len(self._values) < self.stats.block:
            return False
        mean = float(np.mean(self._values))
        self._values.clear()
        if len(self._baseline) < self.baseline_blocks:
            self._baseline.append(mean)
            self.mean = float(np.mean(self._baseline))
            return False
        z = (mean - self.mean) / self.stats.sigma
        self.decided += 1
        if self.trace is not None:
            self.trace.append(z)
        if self.sides in ("up", "both"):
            self.up = max(0.0, self.up + z - self.k)
        if self.sides in ("down", "both"):
            self.down = max(0.0, self.down - z - self.k)
        self.means.append((t_s, mean, self.up, self.down))
        while self.means and self.means[0][0] < t_s - HISTORY_S:
            self.means.popleft()
        return self.statistic > self.h

    def restart(self) -> None:
        self.up = self.down = 0.0

    def change_time(self) -> float:
        """Time of the last block at which the statistic was zero (−inf: none kept)."""
        side = 2 if self.up >= self.down else 3
        zeros = [row[0] for row in self.means if row[side] == 0.0]
        return zeros[-1] if zeros else -math.inf

    def since_change(self) -> np.ndarray:
        """The single values since the change: the last zero of the statistic, then the
        split that best explains a shift from the healthy mean (the maximum-likelihood
        change point of a Gaussian mean), so a block straddling the onset does not dilute
        the size."""
        rows, j = self._split()
        return np.array([x for _, x in rows[j:]])

    def _split(self) -> tuple[list[tuple[float, float]], int]:
        t0 = self.change_time()
        rows = [r for r in self.raw if r[0] > t0] or list(self.raw)[-1:]
        d = np.array([x for _, x in rows]) - self.mean
        tail = np.cumsum(d[::-1])[::-1]  # Σ d[j:]
        n = np.arange(len(d), 0, -1)
        return rows, int(np.argmax(tail**2 / n))

    def change_point(self) -> float:
        """Time of the first single value of :meth:`since_change`, s."""
        rows, j = self._split()
        return rows[j][0]


def steady(values: np.ndarray, sd: float) -> bool:
    """A step, not a transient: the values' two halves agree within a fifth of their mean
    (from 4 values on: a PI loop's transient moves more than that), or within three σ of
    their difference from 8 values on. ``sd``: σ of one value."""
    if values.size < 4:
        return False
    first, second = np.array_split(values, 2)
    diff = abs(float(first.mean() - second.mean()))
    tol = 0.2 * abs(float(values.mean()))
    if values.size >= 8:
        tol = max(tol, 3 * sd * math.sqrt(4 / values.size))
    return diff <= tol


class FrictionChange(BlockCusum):
    """Friction against this record's own past: the unit's friction law (its viscous and
    Coulomb excess over the reference's and its current offset) fitted on the record's
    samples older than ``GUARD_S``, so holds at other speeds compare like with like (a
    plain mean of the relative excess does not: a unit whose viscous/Coulomb mix and
    current offset differ from the reference's has a speed-dependent excess), and a fault
    enters the baseline only ``GUARD_S`` after its onset."""

    def __init__(
        self,
        stats,
        tolerance: float,
        h: float,
        baseline_blocks: int,
        c,
        *,
        spec: WheelSpec | None = None,
    ) -> None:
        super().__init__(stats, tolerance, h, "up")
        self.spec = spec  # the wheel model whose datasheet law is the prior (None: RW90)
        self.mean = 0.0
        self.c = np.asarray(c, dtype=float)  # the reference's current model
        self._need = baseline_blocks * stats.block
        self._pending: deque = deque()  # (t_s, regressors, residual) younger than GUARD_S
        self._xtx = np.zeros((3, 3))
        self._xtr = np.zeros(3)
        self._r = [0, 0.0, 0.0]  # count, Σr, Σr² of the baseline
        self._signs = [0, 0]  # baseline samples at positive, negative speed
        self._spans = [[math.inf, 0.0], [math.inf, 0.0]]  # their |ω| range per sign, rpm
        self._law: np.ndarray | None = None
        self._cov: np.ndarray = np.zeros((3, 3))
        self.law_sd: deque = deque()  # (t_s, σ of the law's prediction, value units)

    def _ridge(self) -> np.ndarray:
        """The law's least squares, shrunk towards the reference's by the spread between
        units, so a baseline with few speeds does not extrapolate wildly: prior σ
        :data:`CHANGE_PRIOR` of the datasheet's nominal viscous and Coulomb currents (the
        spread is the datasheet's ±30 % around nominal, not around the reference unit: 30 %
        of a low-friction reference's currents held a high-friction unit's law down, and
        its holds at new speeds alarmed), 5 mA of offset
        (:data:`rwlab.wheel.imperfections.TOLERANCES`); one independent value per block
        (the samples of a hold are correlated). The noise is the samples' scatter about
        the law (a second pass), not about their mean: that counted the law's own change
        with speed and sign as noise (a unit whose sense offset is 10 mA off its
        reference's scatters ±10 mA between its holds), the prior then outweighed the
        data, and the law missed its own baseline by 7 mA (a healthy PRBS's +1700 rpm
        held at 18.6 mA, the law 11.5 at +1950: a friction alarm)."""
        n, s1, s2 = self._r
        var = max(s2 / n - (s1 / n) ** 2, 0.0)
        _, prior = _law_prior(self.spec)
        for _ in range(2):
            noise_sq = max(var, HOLD_MIN_SD_A**2) * self.stats.block
            self._cov = np.linalg.inv(self._xtx / noise_sq + np.diag(1 / prior**2))  # A²
            law = self._cov @ self._xtr / noise_sq
            var = (s2 - 2 * law @ self._xtr + law @ self._xtx @ law) / n  # about the law
        return law

    def add_sample(self, t_s: float, residual_a: float, speed_rpm: float, friction_a: float):
        """One constant-speed sample: current residual (A), speed (rpm), the reference's
        friction current there (A); True on an alarm."""
        if abs(speed_rpm) < CHANGE_MIN_RPM:
            return False
        sign = math.copysign(1.0, speed_rpm)
        x = np.array([speed_rpm, sign, 1.0])
        self._pending.append((t_s, x, residual_a))
        changed = False
        while self._pending[0][0] <= t_s - GUARD_S:
            _, xo, ro = self._pending.popleft()
            self._xtx += np.outer(xo, xo)
            self._xtr += xo * ro
            self._r = [self._r[0] + 1, self._r[1] + ro, self._r[2] + ro * ro]
            side = int(xo[1] < 0)
            self._signs[side] += 1
            span = self._spans[side]
            span[:] = [min(span[0], abs(xo[0])), max(span[1], abs(xo[0]))]
            changed = True
        n = self._r[0]
        if changed and (n >= 4 * self._need or (n >= self._need and min(self._signs) >= SIGN_MIN)):
            self._law = self._ridge()
        if self._law is None or not self._covered(speed_rpm):
            return False
        own = float(self._law @ x)
        friction_own = float(self._law[:2] @ x[:2])  # the offset is no friction
        unit_friction = max(abs(friction_a) + sign * friction_own, 0.3 * abs(friction_a))
        # the baseline law's own uncertainty at this speed, in the value's unit: the same
        # for every sample of a hold, so averaging does not shrink it (sizing's interval)
        self.law_sd.append((t_s, math.sqrt(float(x @ self._cov @ x)) / unit_friction))
        while self.law_sd[0][0] < t_s - HISTORY_S:
            self.law_sd.popleft()
        return self.add(t_s, sign * (residual_a - own) / unit_friction)

    def _covered(self, speed_rpm: float) -> bool:
        """The baseline holds this sign of speed (:data:`SIGN_MIN` samples) over a span of
        |ω| that reaches this speed, within :data:`SPAN_MARGIN_RPM`: the law interpolates."""
        side = int(speed_rpm < 0)
        lo, hi = self._spans[side]
        return (
            self._signs[side] >= SIGN_MIN
            and lo - SPAN_MARGIN_RPM <= abs(speed_rpm) <= hi + SPAN_MARGIN_RPM
        )

    def law_uncertainty(self, n: int) -> float:
        """Mean σ of the baseline law's prediction over the last ``n`` values."""
        sd = [v for _, v in list(self.law_sd)[-n:]]
        return float(np.mean(sd)) if sd else 0.0


class SlewChange(BlockCusum):
    """The slew asymmetry against this record's own earlier slews (:data:`SLEW_GUARD_S`
    old or more): friction smaller than the spread between units, on a profile the
    reference's level does not describe. A default chirp's later, shorter slews read about
    −1.1 nominal Coulomb decelerations on healthy units, its earlier ones −0.85, the
    references' PRBS −0.64 to −0.81 (20 healthy units' chirps, 4 reference models), so
    the reference test, with the tolerance between units, found friction ×1.5 from
    600 s on 16 of those 20 chirps, in the 7 slews after the onset;
    against its own slews the step is about +1 (3 σ) each."""

    def __init__(self, sigma: float, fraction: float, h: float) -> None:
        """``sigma``: one slew's σ within a record; ``fraction``: slews per sample."""
        stats = BlockStats(0.0, sigma, 1, fraction, 0, "detector_constants.toml")
        super().__init__(stats, 0.0, h, "up")
        self._pending: deque = deque()  # (t_s, value) younger than SLEW_GUARD_S
        self._base: deque = deque(maxlen=SLEW_BASE_MAX)

    def add_slew(self, t_s: float, value: float) -> bool:
        """One slew's asymmetry at ``t_s``; True on an alarm."""
        self._pending.append((t_s, value))
        while self._pending[0][0] <= t_s - SLEW_GUARD_S:
            self._base.append(self._pending.popleft()[1])
        if len(self._base) < SLEW_BASE_MIN:
            return False
        self.mean = float(np.mean(self._base))
        return self.add(t_s, value)


class HoldChange(BlockCusum):
    """Friction at a held speed against this record's own current at that speed.

    The wheel's loop holds the true speed at the command, so at a command held before
    (the same value: a step's or a PRBS's levels come back) the motor current is the
    unit's own friction there plus its current-sense offset, whatever the unit: the
    first :data:`HOLD_BASE` settled samples at each command are its baseline (their
    mean and σ), and each later block of settled samples there gives v, the current's
    rise relative to the baseline's (≈ F − 1 for friction × F, 1/F_k − 1 for a weak
    motor: the motor test tells them apart). The block's v beyond
    :data:`HOLD_TOLERANCE`, standardised by its noise (the baseline's σ per sample),
    feeds a one-sided CUSUM. Within a record only: a fault present from the first hold
    at a speed is its baseline (the absolute tests see those)."""

    def __init__(self, h: float, block: int, Ts: float) -> None:
        stats = BlockStats(0.0, 1.0, 1, 0.05, 0, "the record's own first settled samples")
        super().__init__(stats, 0.0, h, "up")
        self.block, self.Ts = block, Ts
        self._base: dict[float, list[float]] = {}  # command (rpm) → baseline currents (A)
        self._values: list[float] = []  # the block in progress: currents at one command
        self._key = math.nan
        self.sizes: deque = deque()  # (t_s, v, σ of v, relative σ of the baseline level)
        self.recent: deque = deque(maxlen=400)  # (t_s, command rpm, current A)
        self._rest = [0, 0.0, 0.0]  # count, Σi, Σi² of the currents at rest (0 rpm)

    def load_change(self, t0: float, command_rpm: float) -> bool:
        """The current at this held command (its latest 8 samples) rose beyond the
        tolerance over the one before ``t0`` (three σ): the wheel's load changed."""
        rows = [(t, i) for t, c, i in self.recent if c == command_rpm]
        before = np.array([i for t, i in rows if t <= t0])
        after = np.array([i for t, i in rows if t > t0][-8:])
        if min(before.size, after.size) < 4:
            return False
        scale = max(abs(float(before.mean())), 2 * HOLD_MIN_SD_A)
        e = math.copysign(1.0, command_rpm) * float(after.mean() - before.mean()) / scale
        sd = max(float(np.std(before, ddof=1)), HOLD_MIN_SD_A)
        return e - HOLD_TOLERANCE > 3 * sd * math.sqrt(1 / before.size + 1 / after.size) / scale

    def add_rest(self, current_a: float) -> None:
        """One settled sample of the wheel resting at a 0-rpm command (reading 0)."""
        n, s1, s2 = self._rest
        self._rest = [n + 1, s1 + current_a, s2 + current_a * current_a]

    def _offset(self) -> tuple[float, float] | None:
        """The current-sense offset from the rest samples and its σ, A (None: too few)."""
        n, s1, s2 = self._rest
        if n < HOLD_BASE:
            return None
        sd = math.sqrt(max(s2 / n - (s1 / n) ** 2, 0.0) * n / (n - 1))
        return s1 / n, math.hypot(sd / math.sqrt(n), REST_CURRENT_SD_A)

    def add_sample(self, t_s: float, command_rpm: float, current_a: float) -> bool:
        """One settled sample at a held speed; True when the CUSUM exceeds its threshold."""
        self.recent.append((t_s, command_rpm, current_a))
        base = self._base.setdefault(command_rpm, [])
        mirror = self._base.get(-command_rpm, [])
        offset = self._offset()
        cross = len(mirror) >= HOLD_BASE and offset is not None
        if len(base) < HOLD_BASE:
            base.append(current_a)
            if not cross:
                return False
        if command_rpm != self._key:
            self._values, self._key = [], command_rpm
        self._values.append(current_a)
        if len(self._values) < self.block:
            return False
        values, self._values = np.array(self._values), []
        tests = []  # (v, σ of v, σ common to every block) of each comparison
        if len(base) >= HOLD_BASE and values.size:
            tests.append(self._compare(values, np.array(base), command_rpm, 0.0, 0.0))
        if cross:
            off, off_sd = offset  # type: ignore[misc]
            level = -(np.array(mirror) - off) + off  # the mirror speed's current, sign turned
            tests.append(self._compare(values, level, command_rpm, off, off_sd))
        v, sd_v, level_sd = max(tests, key=lambda x: (x[0] - HOLD_TOLERANCE) / x[1])
        self.sizes.append((t_s, v, sd_v, level_sd))
        while self.sizes[0][0] < t_s - HISTORY_S:
            self.sizes.popleft()
        return self.add(t_s, (v - HOLD_TOLERANCE) / sd_v)

    @staticmethod
    def _compare(values, base, command_rpm: float, off: float, off_sd: float):
        """A block against a baseline: the relative rise v of the friction current, its σ
        and the σ that every block shares (the baseline's). Against the same command the offset
        cancels (``off_sd`` 0); against the mirror speed (friction is even in speed: the
        healthy units' ± levels agree within ~3 %) the rest's offset estimate enters
        twice, and the unit's asymmetry."""
        sign = math.copysign(1.0, command_rpm)
        level = sign * (float(np.mean(base)) - off)
        scale = max(abs(level), 2 * HOLD_MIN_SD_A)
        sd = max(float(np.std(base, ddof=1)), HOLD_MIN_SD_A)
        v = (sign * (float(np.mean(values)) - off) - level) / scale
        noise = sd * math.sqrt(1 / values.size + 1 / base.size) / scale
        # what averaging blocks does not shrink: the drift between the holds and, against
        # the same command, the level's offset (relative), against the mirror speed the
        # offset estimate and the unit's asymmetry (additive)
        if off_sd == 0.0:
            return v, noise, math.hypot(HOLD_DRIFT_SD, v * CURRENT_OFFSET_SD_A / scale)
        sd_v = math.hypot(noise, 2 * off_sd / scale, HOLD_SIGN_SD)
        return v, sd_v, math.hypot(2 * off_sd / scale, HOLD_SIGN_SD, HOLD_DRIFT_SD)

    def onset(self) -> float:
        """Start of the first block after the statistic last was zero, s (the blocks
        between may be minutes apart: other speeds, accelerations)."""
        t0 = self.change_time()
        after = [row[0] for row in self.means if row[0] > t0]
        return after[0] - self.block * self.Ts if after else t0

    def since_change_sizes(self) -> np.ndarray:
        """(v, σ of v, σ common to all blocks) of the blocks since the statistic last
        left zero, shape (n, 3)."""
        t0 = self.change_time()
        rows = [row[1:] for row in self.sizes if row[0] > t0] or [row[1:] for row in self.sizes][
            -1:
        ]
        return np.array(rows, dtype=float).reshape(-1, 3)


class Dropout:
    """Lost telemetry frames per block, against the reference's Poisson loss rate."""

    def __init__(self, block: int, n: int) -> None:
        self.block, self.n = block, n
        self.count = self.samples = 0
        self.last_count = 0
        self.trace: list[int] | None = None  # every block's count, when calibrating

    @property
    def statistic(self) -> float:
        return float(self.count)

    def add(self, lost: int) -> bool:
        self.count += lost
        self.samples += 1
        fired = self.count >= self.n
        if self.samples >= self.block or fired:
            if self.trace is not None:
                self.trace.append(self.count)
            self.last_count = self.count
            self.count = self.samples = 0
        return fired

    def restart(self) -> None:
        self.count = self.samples = 0


class ClampedFriction:
    """Friction read through a clamped current, against the unit's own friction before.

    A clamped slew (:func:`~rwlab.diagnose.motion.clamped_deceleration`) carries the
    whole friction, not its excess over the controller's feed-forward, so it is compared
    with this unit's friction current before the first clamped slew: the current less
    the reference's inertial current at its slow samples (mean acceleration below
    :data:`CLAMP_QUIET_RPM_S`, a chirp's slow start included) fitted as a viscous and
    Coulomb law and a sense offset, ridge-shrunk towards the datasheet's friction. Each
    slew's value is its friction deceleration times the reference's I/k_t over that
    own friction current at the slew's speed, less 1 (a weak motor moves neither); the
    test alarms when the median of the latest :data:`CLAMP_RECENT` values exceeds ``h``
    (after :data:`CLAMP_COUNT`). Why the whole friction: worn bearings behind a clamp
    leave the feed-forward's asymmetry (the slew test) nothing to read, and against the
    reference's unit ×1.5 lies inside the spread between units.

    Parameters
    ----------
    c : array_like, shape (4,)
        The reference's current model [A per rpm/s, A per rpm, A, A].
    h : float
        Threshold on the median relative excess.
    """

    def __init__(self, c, h: float, *, spec: WheelSpec | None = None) -> None:
        self.c = np.asarray(c, dtype=float)
        self.h = h
        self.spec = spec  # the wheel model whose datasheet law is the prior (None: RW90)
        self._xtx = np.zeros((3, 3))
        self._xtr = np.zeros(3)
        self._n, self._yy = 0, 0.0  # own samples: count, Σ of their friction currents², A²
        self.frozen = False  # a clamped slew came: the own samples end there
        self.values: list[tuple[float, float, float]] = []  # (t_s, value, σ of the own law)
        self.statistic = 0.0
        self.decided = 0
        self._start = 0  # the first value since the last restart

    def add_own(self, residual_a: float, speed_rpm: float) -> None:
        """One slow sample: the current residual (A) at ``speed_rpm``."""
        if self.frozen or abs(speed_rpm) < CLAMP_OWN_RPM or not math.isfinite(residual_a):
            return
        sign = math.copysign(1.0, speed_rpm)
        x = np.array([abs(speed_rpm), 1.0, sign])
        # the current less the reference's inertial current: the unit's friction and offset
        friction_a = sign * residual_a + self.c[1] * abs(speed_rpm) + self.c[2] + sign * self.c[3]
        self._xtx += np.outer(x, x)
        self._xtr += x * friction_a
        self._n += 1
        self._yy += friction_a**2

    def _own(self, speed_rpm: float) -> tuple[float, float]:
        """The unit's own friction current at ``speed_rpm`` (A) and its σ (A)."""
        fit = np.linalg.lstsq(self._xtx, self._xtr, rcond=None)[0]
        rss = float(self._yy - 2 * fit @ self._xtr + fit @ self._xtx @ fit)  # plain fit's
        noise = math.sqrt(max(rss / max(self._n - 3, 1), 0.0) * BLOCK_OWN) + 1e-6
        # prior: the datasheet's friction (not the reference's law: its identified
        # Coulomb/viscous split is poor, and a chirp's slow samples leave it standing)
        mean, prior = _law_prior(self.spec)
        precision = np.diag(1 / prior**2)
        cov = np.linalg.inv(self._xtx / noise**2 + precision)
        law = cov @ (self._xtr / noise**2 + precision @ mean)
        x = np.array([speed_rpm, 1.0])
        return float(law[:2] @ x), math.sqrt(float(x @ cov[:2, :2] @ x))

    def add_slew(self, t_s: float, decel_rpm_s: float, speed_rpm: float) -> bool:
        """One clamped slew's friction deceleration (rpm/s) at its mean speed (rpm); True
        on an alarm."""
        self.frozen = True
        if self._n < CLAMP_OWN_MIN or speed_rpm < CLAMP_SLEW_RPM:
            return False
        own, sd = self._own(speed_rpm)
        if own <= 0:
            return False
        self.values.append((t_s, decel_rpm_s * self.c[0] / own - 1.0, sd / own))
        if len(self.values) - self._start < CLAMP_COUNT:
            return False
        self.decided += 1
        recent = self.values[max(self._start, len(self.values) - CLAMP_RECENT) :]
        self.statistic = float(np.median([v for _, v, _ in recent]))
        return self.statistic > self.h

    def restart(self) -> None:
        self._start = len(self.values)
        self.statistic = 0.0

    def recent(self) -> tuple[np.ndarray, float]:
        """The latest values decided on and the own law's mean relative σ."""
        rows = self.values[-CLAMP_RECENT:]
        return np.array([v for _, v, _ in rows]), float(np.mean([s for _, _, s in rows]))


class FrozenMotor:
    """A weak motor behind a frozen speed reading: a speed change's charge.

    Once the reading is frozen no test can read an acceleration, but the wheel's loop
    still closes on its true speed, so each settled speed change draws the charge
    :class:`~rwlab.diagnose.motion.StepCharge` measures: 1/F of the reference's for
    k_t × F. The values of speed changes that settled before the freeze are the unit's
    own level; each one begun after it is compared with their median (tolerance
    :data:`CHARGE_EXCESS`) or, without any, with the reference's (the datasheet's
    headroom of I/k_t and :data:`CHARGE_MARGIN`). A change under way at the freeze is
    neither (a weak motor that came with the freeze is in part of it). A stronger
    charge is the only reading: a lowered clamp or worn bearings leave it (the clamp
    slows the change, the friction is measured at both settled ends).

    Parameters
    ----------
    headroom : float
        How far above the reference's I/k_t a healthy unit's may sit (relative).
    """

    def __init__(self, headroom: float) -> None:
        self.headroom = headroom
        self.own: list[tuple[float, float]] = []  # (settled at s, value) before the alarm
        self.values: list[float] = []  # relative to the level, after the freeze
        self.statistic = 0.0
        self.decided = 0
        self.h = headroom + CHARGE_MARGIN  # the tolerance on a value's excess over its level
        self._level = (1.0, 0)  # (level, own values behind it)

    def add(self, value: float, start_s: float, end_s: float, frozen_s: float | None) -> bool:
        """One speed change's value (begun at ``start_s``, settled at ``end_s``, s) with
        the reading frozen since ``frozen_s`` (s; None: no stuck alarm yet); True on an
        alarm."""
        if frozen_s is None:
            self.own.append((end_s, value))
            return False
        if start_s < frozen_s:
            return False  # settled before the freeze (own, kept above) or straddling it
        own = [v for end, v in self.own if end < frozen_s]
        self._level = (float(np.median(own)), len(own)) if own else (1.0, 0)
        self.h = CHARGE_EXCESS if own else self.headroom + CHARGE_MARGIN
        self.values.append(value / self._level[0])
        self.decided += 1
        self.statistic = self.values[-1] - 1.0
        return self.statistic > self.h

    def restart(self) -> None:
        self.statistic = 0.0

    def recent(self) -> tuple[np.ndarray, int]:
        """The values decided on (relative to the level) and how many own values set it."""
        return np.array(self.values), self._level[1]
