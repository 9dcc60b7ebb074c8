"""The attitude sensors GEO satellites fly besides sun and earth sensors: gyros and a star tracker.

Gyros (rate-integrating, one per body axis): each step ``dt`` they report the
angle turned over the step divided by dt,

    ω_m = (I + E) ω̄ + β + β_gm + v,

with ω̄ the mean true rate over the step, E = diag(scale factors) + the
off-diagonal misalignment (small angles), β the rate random walk (RRW,
σ_u) started at a turn-on bias, β_gm the bias instability (a first-order
Gauss–Markov process, σ_b with correlation time τ_b: the flicker floor a
datasheet quotes as "bias stability") and v the angle random walk (ARW, σ_v):
σ_v/√dt on each sample. This is the Farrenkamp model behind the
Lefferts–Markley–Shuster filter (Markley & Crassidis 2014, §4.7, §6.2.3),
plus the Gauss–Markov term and E.

Defaults are datasheet-class for a GEO platform's navigation-grade
fibre-optic gyro unit (Astrix-120 / SIRU class, not one unit's spec): ARW
0.005 °/√h, RRW 0.002 °/h/√h, bias instability 0.01 °/h (τ_b = 1 h), turn-on
bias 1 °/h (1σ per axis, unknown to the filter), scale factor 100 ppm and
misalignment 0.01° (1σ).

Star tracker (optional): a quaternion every ``period_s`` with noise
equivalent angles ``noise_arcsec`` about its two cross-boresight axes and
its boresight (datasheet-class, Hydra / ASTRO APS: 2″, 2″, 15″ 1σ), blinded
while the Sun, the Earth's limb or the Moon is inside its exclusion cone
around the boresight. The default boresight looks along body −y (orbit
north): 66.6° from the Sun at the solstices and 90° from nadir, so on a
nadir-pointing GEO satellite it is never blinded by the Sun or the Earth (why
trackers are mounted there); the Moon, up to 28.6° from the equator, can pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rwlab.errors import ConfigError

__all__ = [
    "EARTH_ANGULAR_RADIUS_DEG",
    "GyroModel",
    "StarTrackerModel",
    "draw_gyro_errors",
    "star_tracker_frame",
]

EARTH_ANGULAR_RADIUS_DEG = math.degrees(math.asin(6378.137 / 42164.17))  # 8.70° seen from GEO
ARCSEC = math.pi / 180 / 3600  # rad


@dataclass(frozen=True)
class GyroModel:
    """A three-axis rate-integrating gyro unit (see the module docstring).

    Attributes
    ----------
    arw_deg_rt_h : float
        Angle random walk, °/√h (σ_v).
    rrw_deg_h_rt_h : float
        Rate random walk, °/h/√h (σ_u).
    bias_instability_deg_h : float
        Bias instability (Gauss–Markov σ_b), °/h.
    bias_correlation_s : float
        Its correlation time τ_b, s.
    initial_bias_deg_h : float
        Turn-on bias, 1σ per axis, °/h (drawn per run; the filter starts at 0).
    scale_factor_ppm : float
        Scale-factor error, 1σ per axis, ppm.
    misalignment_deg : float
        Axis misalignment, 1σ per off-diagonal element, °.
    """

    arw_deg_rt_h: float = 0.005
    rrw_deg_h_rt_h: float = 0.002
    bias_instability_deg_h: float = 0.01
    bias_correlation_s: float = 3600.0
    initial_bias_deg_h: float = 1.0
    scale_factor_ppm: float = 100.0
    misalignment_deg: float = 0.01

    def __post_init__(self) -> None:
        for name in (
            "arw_deg_rt_h",
            "rrw_deg_h_rt_h",
            "bias_instability_deg_h",
            "initial_bias_deg_h",
            "scale_factor_ppm",
            "misalignment_deg",
        ):
            _check_nonneg(f"gyro.{name}", getattr(self, name))
        _check_positive("gyro.bias_correlation_s", self.bias_correlation_s)
        if self.arw_deg_rt_h <= 0:
            raise ConfigError("gyro.arw_deg_rt_h must be > 0 (no gyro is noise-free)")

    @property
    def sigma_v(self) -> float:
        """ARW as a rate-noise density, rad/√s."""
        return math.radians(self.arw_deg_rt_h) / 60.0

    @property
    def sigma_u(self) -> float:
        """RRW as a bias-noise density, rad/s^1.5."""
        return math.radians(self.rrw_deg_h_rt_h) / 3600.0 / 60.0

    @property
    def sigma_b(self) -> float:
        """Bias instability, rad/s."""
        return math.radians(self.bias_instability_deg_h) / 3600.0

    def filter_bias_psd(self) -> float:
        """The bias random-walk PSD the filter assumes, rad²/s³: σ_u² plus the Gauss–Markov
        term's low-frequency equivalent 2σ_b²/τ_b (its PSD below 1/τ_b)."""
        return self.sigma_u**2 + 2 * self.sigma_b**2 / self.bias_correlation_s

    def vector(self, dt: float) -> np.ndarray:
        """The kernel's gyro parameters: [σ_v/√dt (rad/s per sample), σ_u √dt (rad/s per step),
        e^{−dt/τ_b}, σ_b √(1 − e^{−2dt/τ_b}) (rad/s per step)]."""
        phi = math.exp(-dt / self.bias_correlation_s)
        return np.array(
            [
                self.sigma_v / math.sqrt(dt),
                self.sigma_u * math.sqrt(dt),
                phi,
                self.sigma_b * math.sqrt(1 - phi * phi),
            ]
        )


@dataclass(frozen=True)
class StarTrackerModel:
    """A star tracker (see the module docstring).

    Attributes
    ----------
    noise_arcsec : tuple of 3 floats
        Noise equivalent angle about its cross-boresight x, y and its boresight z, 1σ, ″.
    period_s : float
        Seconds between attitude outputs (a whole number of the simulation's dt).
    boresight : tuple of 3 floats
        The boresight in body axes (normalised).
    sun_exclusion_deg, earth_exclusion_deg, moon_exclusion_deg : float
        Exclusion half-angles around the boresight, °; the Earth's is from its limb.
    """

    noise_arcsec: tuple = (2.0, 2.0, 15.0)
    period_s: float = 0.5
    boresight: tuple = (0.0, -1.0, 0.0)
    sun_exclusion_deg: float = 30.0
    earth_exclusion_deg: float = 20.0
    moon_exclusion_deg: float = 10.0

    def __post_init__(self) -> None:
        if len(self.noise_arcsec) != 3 or len(self.boresight) != 3:
            raise ConfigError("star_tracker.noise_arcsec and .boresight need 3 numbers each")
        for v in self.noise_arcsec:
            _check_positive("star_tracker.noise_arcsec", v)
        if not np.linalg.norm(np.asarray(self.boresight, float)) > 0:
            raise ConfigError("star_tracker.boresight must not be the zero vector")
        _check_positive("star_tracker.period_s", self.period_s)
        for name in ("sun_exclusion_deg", "earth_exclusion_deg", "moon_exclusion_deg"):
            v = getattr(self, name)
            _check_nonneg(f"star_tracker.{name}", v)
            if v >= 180:
                raise ConfigError(f"star_tracker.{name} must be < 180°")

    def exclusion_cos(self) -> np.ndarray:
        """Cosines (3,) of the Sun, Earth-centre and Moon exclusion angles (Earth: limb + its
        angular radius from GEO)."""
        earth = min(self.earth_exclusion_deg + EARTH_ANGULAR_RADIUS_DEG, 180.0)
        angles = (self.sun_exclusion_deg, earth, self.moon_exclusion_deg)
        return np.cos(np.radians(angles))

    def sigma_rad(self) -> np.ndarray:
        """Noise equivalent angles (3,), rad."""
        return np.asarray(self.noise_arcsec, float) * ARCSEC

    def body_covariance(self) -> np.ndarray:
        """The measurement covariance (3, 3) of the attitude error in body axes, rad²."""
        C = star_tracker_frame(self.boresight)
        return C.T @ np.diag(self.sigma_rad() ** 2) @ C


def star_tracker_frame(boresight) -> np.ndarray:
    """The rotation (3, 3) from body axes to the tracker's (its z the boresight)."""
    z = np.asarray(boresight, float) / np.linalg.norm(boresight)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def draw_gyro_errors(model: GyroModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One unit's fixed errors: E (3, 3) = scale factors + misalignment, and the turn-on bias
    (3,), rad/s."""
    E = np.diag(rng.standard_normal(3) * model.scale_factor_ppm * 1e-6)
    off = ~np.eye(3, dtype=bool)
    E[off] = rng.standard_normal(6) * math.radians(model.misalignment_deg)
    bias = rng.standard_normal(3) * math.radians(model.initial_bias_deg_h) / 3600.0
    return E, bias


@njit(cache=True)
def gyro_sample_into(w_mean, E, par, state, e, out):
    """One gyro sample into ``out`` (3,), rad/s, for the mean true rate ``w_mean`` (3,).

    ``par`` is :meth:`GyroModel.vector`; ``state`` (6,) = [β (RRW walk), β_gm] is advanced
    one step in place; ``e`` (9,) the step's standard normals [ARW, RRW, Gauss–Markov].
    """
    for i in range(3):
        out[i] = (
            w_mean[i]
            + E[i, 0] * w_mean[0]
            + E[i, 1] * w_mean[1]
            + E[i, 2] * w_mean[2]
            + state[i]
            + state[3 + i]
            + par[0] * e[i]
        )
        state[i] += par[1] * e[3 + i]
        state[3 + i] = par[2] * state[3 + i] + par[3] * e[6 + i]


@njit(cache=True)
def tracker_visible(C_st, sun_b, moon_b, nadir_b, sunlit, moon_visible, cos_excl):
    """Whether the tracker sees stars: no sunlit Sun, Earth (centre, limb margin included) or
    visible Moon inside its exclusion cones (``cos_excl`` from
    :meth:`StarTrackerModel.exclusion_cos`; ``C_st`` body → tracker)."""
    bs = C_st[2]
    cs = bs[0] * sun_b[0] + bs[1] * sun_b[1] + bs[2] * sun_b[2]
    ce = bs[0] * nadir_b[0] + bs[1] * nadir_b[1] + bs[2] * nadir_b[2]
    cm = bs[0] * moon_b[0] + bs[1] * moon_b[1] + bs[2] * moon_b[2]
    if sunlit > 0.0 and cs >= cos_excl[0]:
        return False
    if ce >= cos_excl[1]:
        return False
    return not (moon_visible and cm >= cos_excl[2])


def _check_nonneg(name: str, v) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise ConfigError(f"{name} must be a number ≥ 0, got {v!r}")


def _check_positive(name: str, v) -> None:
    _check_nonneg(name, v)
    if v <= 0:
        raise ConfigError(f"{name} must be > 0, got {v!r}")
