"""The healthy reference: what the detectors know of a healthy wheel, from its identification.

``rwlab identify`` on a testbed record measures, on that record, everything the
detectors compare a later record with, and stores it in ``model.json`` under
``"healthy_reference"`` (format ``rwlab.HealthyReference/1``):

- ``current_model``: the motor's current balance i = c·[α, ω, sign ω, 1]
  (A per rpm/s, A per rpm, A, A), least squares on the record's usable samples;
- ``tests``: per block test (``friction``, ``motor``, ``speed``, ``lag``) the
  mean and the σ of its block means on the healthy record, the block length
  (qualifying samples), the share of samples that qualify and how many samples
  the figures rest on; ``friction_change`` (optional: older files fall back to
  ``friction``'s σ) holds the σ of the friction-change test's values on the
  record, its own friction law fitted on the record's older samples, so the
  hold-to-hold scatter of that comparison is in its threshold;
- ``repeat_probability``: how often a non-zero speed reading repeats exactly
  (Hall quantisation), counted over the whole record;
- ``lost_per_sample``: telemetry frames lost per sample (the 8-bit frame
  counter's gaps);
- ``slew_scale_rpm_s`` (optional: older files use the current model's c₂/c₀): the
  unit of the slew test's values, the wheel model's nominal Coulomb deceleration;
- ``tolerance``: how far another healthy unit of the same wheel model may sit
  from this one, relative (friction, motor) or absolute (speed, rpm; lag,
  fraction of the acceleration limit). A stated assumption of the
  datasheet-like spread between units, not a measurement: one record of one
  unit cannot measure it. Where the reference unit sits within that spread
  matters, so the detectors also hold each test against the datasheet's bounds
  about nominal (:func:`nominal_friction_currents`, :func:`nominal_inertial_current`):
  a reference from a low-friction unit allows a healthy unit more friction
  excess, one from a unit of high I/k_t less motor excess.

Because the reference comes from the identification record, a record under
test is tested from its first sample on: a fault present at power-up is a fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rwlab.errors import DataError, FileFormatError
from rwlab.wheelspec import WheelSpec

__all__ = [
    "FORMAT",
    "BlockStats",
    "HealthyReference",
    "UnitBounds",
    "block_stats",
    "nominal_coulomb_deceleration",
    "nominal_friction_currents",
    "nominal_inertial_current",
    "unit_bounds",
    "unit_tolerance",
]

FORMAT = "rwlab.HealthyReference/1"
# Between two healthy units (the reference's and another) of a wheel model whose friction
# is within ±30 %, k_t ±5 % and inertia ±2 % (rwlab.wheel.imperfections.TOLERANCES):
# friction ratio up to 1.3/0.7 = 1.86, inertial current I/k_t up to 1.15; held speed:
# the Hall reading's error at a held speed, ~1 rpm.
DEFAULT_TOLERANCE = {
    "friction": 0.86,
    "motor": 0.15,
    "speed": 2.0,
    "lag": 0.03,
    "friction_change": 0.15,  # within one record: drift 5 %/√h and the bearing warm-up
    # slew asymmetry (units of the Coulomb deceleration): its healthy level moves with the
    # slew's profile (speeds, length) by about this much between a PRBS and a chirp
    "slew": 0.3,
}


def _spec(spec: WheelSpec | None) -> WheelSpec:
    """The wheel model's spec; the RW90's for a model that carries none."""
    return spec if spec is not None else WheelSpec.load("rw90")


def _relative(spec: WheelSpec, *names: str) -> float:
    """The largest relative unit-to-unit tolerance among ``names`` (0 where the spec
    states none: every unit has the nominal value)."""
    return max((spec.tolerances[n].relative for n in names if n in spec.tolerances), default=0.0)


@dataclass(frozen=True)
class UnitBounds:
    """How far a healthy unit of a wheel model may sit from nominal: its spec's tolerances.

    Attributes
    ----------
    friction_upper : float
        A healthy unit's friction at most this × nominal (1 + the larger of the Coulomb
        and viscous tolerances).
    motor_upper : float
        A healthy unit's inertial current I/k_t at most this × nominal ((1 + I's
        tolerance) / (1 − k_t's)).
    current_offset_a : float
        Half-width of a unit's current-sense offset, A.
    friction_sd, motor_sd : float
        σ of the friction ratio and of the I/k_t ratio between two healthy units, each
        part uniform within its tolerance (relative).
    """

    friction_upper: float
    motor_upper: float
    current_offset_a: float
    friction_sd: float
    motor_sd: float


def unit_bounds(spec: WheelSpec | None = None) -> UnitBounds:
    """The spread of healthy units about nominal, from the wheel spec's tolerances.

    Parameters
    ----------
    spec : WheelSpec, optional
        The wheel model (``model.json``'s ``wheel_spec``); default the RW90's.

    Returns
    -------
    UnitBounds
    """
    s = _spec(spec)
    friction = _relative(s, "coulomb_friction_nm", "viscous_friction_nm_s")
    inertia = _relative(s, "inertia_kg_m2")
    k_t = _relative(s, "torque_constant_nm_a")
    offset = s.tolerances.get("current_offset_a")
    return UnitBounds(
        friction_upper=1.0 + friction,
        motor_upper=(1.0 + inertia) / (1.0 - k_t),
        current_offset_a=0.0 if offset is None else offset.absolute,
        friction_sd=math.sqrt(2) * friction / math.sqrt(3),
        motor_sd=math.sqrt(2 * (inertia**2 + k_t**2) / 3),
    )


def unit_tolerance(spec: WheelSpec | None = None) -> dict[str, float]:
    """:data:`DEFAULT_TOLERANCE` with the wheel model's own spread between two healthy
    units for the friction and motor tests: a friction ratio up to (1 + f)/(1 − f), an
    inertial-current ratio up to (1 + δI)(1 + δk_t)/((1 − δI)(1 − δk_t)), from the spec's
    tolerances, to two decimals (the RW90's ±30 %, ±2 %, ±5 % give the defaults' 0.86
    and 0.15).

    Parameters
    ----------
    spec : WheelSpec, optional
        The wheel model; default the RW90's.

    Returns
    -------
    dict of str to float
        Tolerance per test, as :attr:`HealthyReference.tolerance`.
    """
    s = _spec(spec)
    friction = _relative(s, "coulomb_friction_nm", "viscous_friction_nm_s")
    inertia = _relative(s, "inertia_kg_m2")
    k_t = _relative(s, "torque_constant_nm_a")
    motor = (1 + inertia) * (1 + k_t) / ((1 - inertia) * (1 - k_t)) - 1.0
    return DEFAULT_TOLERANCE | {
        "friction": round((1 + friction) / (1 - friction) - 1.0, 2),
        "motor": round(motor, 2),
    }


def nominal_coulomb_deceleration(spec: WheelSpec | None = None) -> float:
    """The wheel model's datasheet Coulomb deceleration τ_c/I, rpm/s.

    The unit in which the slew test reads friction: the same for every reference, so
    a slew's healthy level and its size do not inherit the identified reference unit's
    Coulomb/viscous split.

    Parameters
    ----------
    spec : WheelSpec, optional
        The wheel model (``model.json``'s ``wheel_spec``); default the RW90's.

    Returns
    -------
    float
        τ_c/I of the nominal wheel, rpm/s.
    """
    s = _spec(spec)
    return s.coulomb_friction_nm / s.inertia_kg_m2 * 60.0 / (2.0 * math.pi)


def nominal_friction_currents(spec: WheelSpec | None = None) -> tuple[float, float]:
    """The wheel model's datasheet friction as motor current: viscous and Coulomb.

    Parameters
    ----------
    spec : WheelSpec, optional
        The wheel model (``model.json``'s ``wheel_spec``); default the RW90's.

    Returns
    -------
    viscous : float
        b/k_t, A per rpm.
    coulomb : float
        τ_c/k_t, A.
    """
    s = _spec(spec)
    return s.viscous_friction_nm_s / s.torque_constant_nm_a * 2.0 * math.pi / 60.0, (
        s.coulomb_friction_nm / s.torque_constant_nm_a
    )


def nominal_inertial_current(spec: WheelSpec | None = None) -> float:
    """The wheel model's datasheet inertial current I/k_t per rpm/s, A (the current
    model's c₀ of a nominal unit).

    Parameters
    ----------
    spec : WheelSpec, optional
        The wheel model; default the RW90's.

    Returns
    -------
    float
        A per rpm/s.
    """
    s = _spec(spec)
    return s.inertia_kg_m2 / s.torque_constant_nm_a * 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class BlockStats:
    """The healthy statistics of one block test.

    Attributes
    ----------
    mean : float
        Mean of the qualifying values (the test's unit).
    sigma : float
        σ of a block mean of ``block`` qualifying values.
    block : int
        Qualifying samples per block.
    fraction : float
        Share of samples that qualified on the reference record.
    samples : int
        Qualifying samples the figures rest on.
    method : str
        ``batch means`` (σ of the record's block means, ≥ 20 blocks) or
        ``AR(1)`` (sample σ with the lag-1 correlation's variance inflation).
    """

    mean: float
    sigma: float
    block: int
    fraction: float
    samples: int
    method: str

    @property
    def block_s(self) -> float:
        """Mean duration of one block at the reference's qualifying share, in samples."""
        return self.block / self.fraction


def block_stats(values: np.ndarray, block: int, total_samples: int) -> BlockStats:
    """Block statistics of a test's qualifying values on a healthy record.

    Parameters
    ----------
    values : ndarray, shape (n,)
        The qualifying values in time order.
    block : int
        Values per block.
    total_samples : int
        All samples of the record (for the qualifying share).

    Returns
    -------
    BlockStats

    Raises
    ------
    DataError
        Fewer than 4 blocks' worth of values.
    """
    x = np.asarray(values, dtype=float)
    if x.size < 4 * block:
        raise DataError(
            f"only {x.size} qualifying samples; the test needs ≥ {4 * block} on the "
            "identification record (a longer or richer record)"
        )
    n_blocks = x.size // block
    means = x[: n_blocks * block].reshape(n_blocks, block).mean(axis=1)
    if n_blocks >= 20:
        sigma, method = float(np.std(means, ddof=1)), "batch means"
    else:
        d = x - x.mean()
        rho = float(np.clip(np.dot(d[1:], d[:-1]) / np.dot(d, d), 0.0, 0.95))
        sigma = float(np.std(x, ddof=1) * math.sqrt((1 + rho) / (1 - rho) / block))
        method = "AR(1)"
    if not sigma > 0:
        raise DataError("a test's healthy values are constant; nothing to normalise by")
    return BlockStats(float(x.mean()), sigma, block, x.size / total_samples, int(x.size), method)


@dataclass(frozen=True)
class HealthyReference:
    """What the detectors compare with (see the module docstring).

    Attributes
    ----------
    Ts : float
        Sample time, s.
    current_model : tuple of 4 float
        c of i = c·[α (rpm/s), ω (rpm), sign ω, 1], A.
    tests : dict of str to BlockStats
    repeat_probability : float
    repeat_samples : int
    lost_per_sample : float
    samples : int
        Samples of the identification record.
    tolerance : dict of str to float
    source : str
        Which record it was measured on.
    slew_scale_rpm_s : float or None
        The slew test's unit, rpm/s: the nominal Coulomb deceleration of the wheel model
        (None: the current model's c₂/c₀, as older references were measured).
    """

    Ts: float
    current_model: tuple[float, float, float, float]
    tests: dict[str, BlockStats]
    repeat_probability: float
    repeat_samples: int
    lost_per_sample: float
    samples: int
    tolerance: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_TOLERANCE))
    source: str = ""
    slew_scale_rpm_s: float | None = None

    def to_dict(self) -> dict:
        """The JSON form stored under ``model.json``'s ``"healthy_reference"``."""
        return {
            "format": FORMAT,
            "Ts": self.Ts,
            "current_model": {
                "a_per_rpm_s": self.current_model[0],
                "a_per_rpm": self.current_model[1],
                "a_coulomb": self.current_model[2],
                "a_offset": self.current_model[3],
            },
            "tests": {
                name: {
                    "mean": s.mean,
                    "sigma": s.sigma,
                    "block": s.block,
                    "fraction": s.fraction,
                    "samples": s.samples,
                    "method": s.method,
                }
                for name, s in self.tests.items()
            },
            "repeat_probability": self.repeat_probability,
            "repeat_samples": self.repeat_samples,
            "lost_per_sample": self.lost_per_sample,
            "samples": self.samples,
            "tolerance": dict(self.tolerance),
            "source": self.source,
        } | ({} if self.slew_scale_rpm_s is None else {"slew_scale_rpm_s": self.slew_scale_rpm_s})

    @classmethod
    def from_dict(cls, d: dict) -> HealthyReference:
        """Read the JSON form (``FileFormatError`` when it is not one)."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise FileFormatError(
                f"not a healthy reference ({FORMAT}); run rwlab identify on a testbed record"
            )
        try:
            c = d["current_model"]
            return cls(
                Ts=float(d["Ts"]),
                current_model=(
                    float(c["a_per_rpm_s"]),
                    float(c["a_per_rpm"]),
                    float(c["a_coulomb"]),
                    float(c["a_offset"]),
                ),
                tests={
                    name: BlockStats(
                        float(s["mean"]),
                        float(s["sigma"]),
                        int(s["block"]),
                        float(s["fraction"]),
                        int(s["samples"]),
                        str(s["method"]),
                    )
                    for name, s in d["tests"].items()
                },
                repeat_probability=float(d["repeat_probability"]),
                repeat_samples=int(d["repeat_samples"]),
                lost_per_sample=float(d["lost_per_sample"]),
                samples=int(d["samples"]),
                tolerance={k: float(v) for k, v in d["tolerance"].items()},
                source=str(d.get("source", "")),
                slew_scale_rpm_s=(
                    None if d.get("slew_scale_rpm_s") is None else float(d["slew_scale_rpm_s"])
                ),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(
                f"bad healthy reference ({exc!r}); run rwlab identify again"
            ) from None

    @classmethod
    def from_model_file(cls, path) -> HealthyReference:
        """The reference stored in ``model.json`` (``FileFormatError`` when it holds none)."""
        import json
        from pathlib import Path

        try:
            info = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{path}: not a readable model file ({exc})") from None
        if "healthy_reference" not in info:
            raise FileFormatError(
                f"{path} holds no healthy reference: run rwlab identify on a testbed record "
                "(.mcap with motor current) to write one"
            )
        return cls.from_dict(info["healthy_reference"])
