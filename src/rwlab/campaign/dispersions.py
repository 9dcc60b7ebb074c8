"""Dispersions: a distribution per scenario field, drawn per run from the run's own seed.

A dispersion file is TOML (``[dispersions]`` or top-level keys), one table per
field, e.g.::

    [dispersions]
    spacecraft.inertia.xx = { distribution = "normal", sigma = 0.033, relative = true }
    spacecraft.disturbances.srp_offset.z = { distribution = "uniform", bounds = [-0.05, 0.05] }

A run's value is ``nominal + δ``, or ``nominal × (1 + δ)`` with ``relative = true``;
δ is ``normal`` (``sigma``, optional ``mean`` = 0, optional ``bounds`` that
truncate it) or ``uniform`` over ``bounds``. Fields are named as in
:meth:`rwlab.attitude.scenario.Scenario.with_` (``wheels.max_torque``), a vector's
component with ``.x``, ``.y``, ``.z``; the flat names of the old scenario format
(``wheel_max_torque``, ``inertia.xx``) are still read, with a ``FormatWarning``.
Products of inertia (``spacecraft.inertia.xy``, ``.xz``, ``.yz``) with
``relative = true`` are fractions of √(J_ii·J_jj) of the nominal inertia. The default
set (``default_dispersions.toml``, package data) is what a GEO comsat's
pointing-budget review expects.

Each field draws from its own stream, seeded by the run's seed and the field's
name (its flat name of the old format, so the draws did not change when the fields
moved into sections): adding or removing a dispersion never changes the draws of
the others.
"""

from __future__ import annotations

import math
import warnings
import zlib
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
from scipy import stats

from rwlab._toml import read_table, unknown_keys
from rwlab.attitude.scenario import LEGACY_NAMES, SECTIONS, Scenario
from rwlab.errors import ConfigError, FormatWarning

__all__ = ["FIELDS", "Dispersion", "apply", "draw", "load_dispersions"]

_AXES = ("x", "y", "z")
_INERTIA = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
_SCALARS = (
    "wheels.inertia",
    "wheels.max_torque",
    "wheels.max_momentum",
    "wheels.max_speed_rpm",
    "wheels.torque_scale",
    "sensors.sun_noise_deg",
    "sensors.earth_noise_deg",
    "spacecraft.process_noise_torque",
    "spacecraft.disturbances.srp_area",
    "spacecraft.disturbances.srp_reflectivity",
    "sky.sun_declination_deg",
    "sky.sun_phase_deg",
    "run.initial_error_deg",
    "filter.initial_error_deg",
    "momentum.thruster_torque",
    "wheels.friction_factor",
)
_VECTORS = {  # vector fields and the axes a dispersion may name
    "run.initial_axis": _AXES,
    "run.initial_rate": _AXES,
    "sensors.sun_sensor_misalignment_deg": _AXES,
    "sensors.earth_sensor_misalignment_deg": _AXES,
    "sensors.sun_sensor_bias_deg": _AXES[:2],  # two transverse axes
    "sensors.earth_sensor_bias_deg": _AXES[:2],
    "spacecraft.disturbances.srp_offset": _AXES,
    "spacecraft.disturbances.constant_torque": _AXES,
}

#: Every field a dispersion may name (scenario fields by their dotted names, a vector's
#: component as .x / .y / .z, the inertia's as spacecraft.inertia.xx … .yz): the physical
#: truth the design does not choose.
FIELDS = (
    tuple(f"spacecraft.inertia.{k}" for k in _INERTIA)
    + _SCALARS
    + tuple(f"{v}.{a}" for v, axes in _VECTORS.items() for a in axes)
)
_KEYS = {"distribution", "sigma", "mean", "bounds", "relative"}


@dataclass(frozen=True)
class Dispersion:
    """One field's distribution.

    Attributes
    ----------
    field : str
        One of :data:`FIELDS`.
    distribution : {'normal', 'uniform'}
    sigma, mean : float
        Normal: standard deviation and mean of δ (field units, or a fraction).
    bounds : (lo, hi) or None
        Uniform: its range; normal: truncation (None: none).
    relative : bool
        δ is a fraction of the nominal value (of √(J_ii·J_jj) for a product of inertia).
    """

    field: str
    distribution: str
    sigma: float = 0.0
    mean: float = 0.0
    bounds: tuple[float, float] | None = None
    relative: bool = False

    def sample(self, rng: np.random.Generator) -> float:
        """One δ."""
        if self.distribution == "uniform":
            low, high = self.bounds  # type: ignore[misc]  # a uniform one always has them
            return float(rng.uniform(low, high))
        if self.bounds is None:
            return float(rng.normal(self.mean, self.sigma))
        lo, hi = ((b - self.mean) / self.sigma for b in self.bounds)
        return float(stats.truncnorm.rvs(lo, hi, self.mean, self.sigma, random_state=rng))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _parse(name: str, spec: dict, where: str) -> Dispersion:
    """One field's table → :class:`Dispersion`; anything wrong is a ``ConfigError``."""
    bad = unknown_keys(spec, _KEYS)
    if bad:
        raise ConfigError(f"{where}: {name}: unknown key(s) {bad}; allowed {sorted(_KEYS)}")
    kind = spec["distribution"]
    if kind not in ("normal", "uniform"):
        raise ConfigError(
            f"{where}: {name}: distribution must be 'normal' or 'uniform', got {kind!r}"
        )
    relative = spec.get("relative", False)
    if not isinstance(relative, bool):
        raise ConfigError(f"{where}: {name}: relative must be true or false")
    bounds = spec.get("bounds")
    if bounds is not None:
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(map(_is_number, bounds))):
            raise ConfigError(f"{where}: {name}: bounds must be [low, high], two numbers")
        if not bounds[0] < bounds[1]:
            raise ConfigError(f"{where}: {name}: bounds {bounds} must have low < high")
        bounds = (float(bounds[0]), float(bounds[1]))
    if kind == "uniform":
        extra = sorted({"sigma", "mean"} & set(spec))
        if extra:
            raise ConfigError(f"{where}: {name}: a uniform dispersion takes bounds, not {extra}")
        if bounds is None:
            raise ConfigError(f"{where}: {name}: a uniform dispersion needs bounds = [low, high]")
        return Dispersion(name, kind, bounds=bounds, relative=relative)
    sigma: Any = spec.get("sigma")
    mean: Any = spec.get("mean", 0.0)
    if not (_is_number(sigma) and sigma > 0):
        raise ConfigError(f"{where}: {name}: a normal dispersion needs sigma > 0, got {sigma!r}")
    if not _is_number(mean):
        raise ConfigError(f"{where}: {name}: mean must be a number, got {mean!r}")
    if bounds is not None and not bounds[0] <= mean <= bounds[1]:
        raise ConfigError(f"{where}: {name}: bounds {list(bounds)} do not contain the mean {mean}")
    return Dispersion(name, kind, float(sigma), float(mean), bounds, relative)


def _leaves(table: dict, prefix: str, where: str):
    """(dotted name, spec) of every table that has a ``distribution`` key."""
    for key, value in table.items():
        name = f"{prefix}{key}"
        if not isinstance(value, dict):
            raise ConfigError(
                f"{where}: {name} must be a table such as "
                '{ distribution = "normal", sigma = 0.05 }'
            )
        if "distribution" in value:
            yield name, value
        else:
            yield from _leaves(value, f"{name}.", where)


def load_dispersions(path=None) -> tuple[Dispersion, ...]:
    """The dispersions of a TOML file (the default set when ``path`` is None).

    Parameters
    ----------
    path : str or os.PathLike, optional
        A dispersions TOML file.

    Returns
    -------
    tuple of Dispersion
    """
    if path is None:
        path = resources.files("rwlab.campaign") / "default_dispersions.toml"
    table = read_table(path, "dispersions", "dispersions")
    out, renamed = [], []
    for old, spec in _leaves(table, "", str(path)):
        name = _current_name(old)
        if name != old:
            renamed.append(f"{old} → {name}")
        if name not in FIELDS:
            raise ConfigError(
                f"{path}: unknown field {unknown_keys([old], FIELDS)[1:-1]}; dispersible "
                f"fields: {', '.join(FIELDS)}"
            )
        out.append(_parse(name, spec, str(path)))
    if renamed:
        warnings.warn(
            f"{path}: dispersions named by the flat scenario fields of the old format; "
            f"name them by section: {', '.join(renamed)}",
            FormatWarning,
            stacklevel=2,
        )
    if not out:
        raise ConfigError(
            f"{path}: no dispersion in the file; a campaign disperses at least one field "
            "(leave out the file for rwlab's GEO set)"
        )
    return tuple(out)


def _current_name(name: str) -> str:
    """A dispersion's field by its dotted scenario name (old flat names translated)."""
    head, _, rest = name.partition(".")
    if head in ("inertia", "disturbances"):
        return f"spacecraft.{name}"
    if head in LEGACY_NAMES and head not in SECTIONS:
        return LEGACY_NAMES[head] + (f".{rest}" if rest else "")
    return name


def _split(name: str) -> tuple[str, int | None]:
    """(the scenario field, the component's index or None) of a dispersion's field."""
    path, _, axis = name.rpartition(".")
    if path in _VECTORS:
        return path, _AXES.index(axis)
    return name, None


# the fields dispersible in the flat format keep its names; those added since, their own
_SINCE_SECTIONS = ("wheels.friction_factor", "wheels.stiction", "momentum.bias")
_FLAT = {dotted: flat for flat, dotted in LEGACY_NAMES.items() if dotted not in _SINCE_SECTIONS}


def _stream_name(name: str) -> str:
    """The name a field's random stream is seeded with: its name in the flat scenario
    format, so that a campaign draws the same values since the fields moved into sections."""
    if name.startswith(("spacecraft.inertia.", "spacecraft.disturbances.")):
        return name.removeprefix("spacecraft.")
    path, index = _split(name)
    flat = _FLAT.get(path, path)
    return flat if index is None else f"{flat}.{_AXES[index]}"


def _nominal(sc: Scenario, name: str) -> tuple[float, float]:
    """(nominal value, scale of a relative δ) of a field."""
    if name.startswith("spacecraft.inertia."):
        J = sc.inertia_matrix
        i, j = _INERTIA[name.rpartition(".")[2]]
        return float(J[i, j]), float(math.sqrt(J[i, i] * J[j, j]))
    path, index = _split(name)
    value = sc.get(path) if index is None else sc.get(path)[index]
    return float(value), abs(float(value))


def draw(dispersions, nominal: Scenario, run_seed: int) -> dict[str, float]:
    """Every dispersed field's value for one run (field units), from the run's seed alone.

    Parameters
    ----------
    dispersions : sequence of Dispersion
        What is dispersed, and how.
    nominal : Scenario
        The nominal values (relative dispersions scale them).
    run_seed : int
        The run's seed.

    Returns
    -------
    dict of str to float
        Field name → value.
    """
    values = {}
    for d in dispersions:
        rng = np.random.default_rng([run_seed, zlib.crc32(_stream_name(d.field).encode())])
        value, scale = _nominal(nominal, d.field)
        delta = d.sample(rng)
        values[d.field] = value + (delta * scale if d.relative else delta)
    return values


def apply(nominal: Scenario, values: dict[str, float]) -> Scenario:
    """The scenario with the dispersed values (validated like any scenario: ConfigError).

    Parameters
    ----------
    nominal : Scenario
        The scenario dispersed.
    values : dict of str to float
        Field name (``spacecraft.inertia.xx``, ``wheels.max_torque``, ...) → value, field units.

    Returns
    -------
    Scenario
        A new scenario (``nominal`` is unchanged).
    """
    J = nominal.inertia_matrix.copy()
    changes: dict[str, Any] = {}
    for name, value in values.items():
        if name.startswith("spacecraft.inertia."):
            i, j = _INERTIA[name.rpartition(".")[2]]
            J[i, j] = J[j, i] = value
            continue
        path, index = _split(name)
        if index is None:
            changes[path] = value
        else:
            vector = list(changes.get(path, nominal.get(path)))
            vector[index] = value
            changes[path] = tuple(vector)
    off_diagonal = np.any(J != np.diag(np.diag(J)))
    full = off_diagonal or np.size(nominal.spacecraft.inertia) == 9
    changes["spacecraft.inertia"] = tuple(float(v) for v in (J.ravel() if full else np.diag(J)))
    return nominal.with_(**changes)
