"""Can the scenario's wheels deliver what its mission needs? A mismatch is refused, not flown.

Both ways: wheels too small (:func:`shortfalls`) and wheels far too large
(:func:`oversizes`: a torque over 100× the need, or a friction above it).

A scenario's wheel section names the torque and stored momentum the mission needs
about any body axis (``wheels.required_torque_nm``, ``wheels.required_momentum_nms``,
with their sources). The wheel set delivers, about its weakest body
axis (the G⁺ allocation: ``1 / max_i ‖row_i(G⁺)‖`` of one wheel's limit):

- torque: each wheel's rated torque (its spec), or for an identified model the
  torque its acceleration limit allows on its rotor (``I·α_max`` from model.json);
- momentum: each wheel's momentum capacity ``I·ω_max``;
- speed: the wheel speed the needed momentum takes, against the speed limit
  (model.json's for an identified model, else the spec's).

:func:`check_wheel_fit` raises one :class:`~rwlab.errors.ConfigError` line naming
both numbers and their sources, or, forced, returns the lines to print on the
report's first screen.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

from rwlab.errors import ConfigError

__all__ = ["Misfit", "Oversize", "Shortfall", "check_wheel_fit", "oversizes", "shortfalls"]

RPM = math.pi / 30  # rad/s per rpm
# a wheel set whose torque is more than this many times the largest the mission needs is
# refused: the mission's torques are then under 1 % of the wheel's range, where its
# friction, cogging and speed quantum (which an identified linear model does not carry)
# are the torque it gives; the shipped scenarios fly their own class at 3-5×
FAR_OFF = 100.0


class Misfit(abc.ABC):
    """A way the wheels do not fit the mission: a :class:`Shortfall` or an :class:`Oversize`."""

    @abc.abstractmethod
    def line(self, scenario: str, wheels: str) -> str:
        """The refusal, one line.

        Parameters
        ----------
        scenario, wheels : str
            The scenario's name and a description of its wheels.

        Returns
        -------
        str
        """


@dataclass(frozen=True)
class Shortfall(Misfit):
    """One thing the wheels cannot deliver.

    Attributes
    ----------
    quantity : str
        ``"torque"``, ``"momentum"`` or ``"speed"``.
    needed, available : float
        The scenario's need and the wheels' capacity (N·m, N·m·s or rpm).
    unit : str
        Their unit.
    needed_source, available_source : str
        Where each number comes from.
    """

    quantity: str
    needed: float
    available: float
    unit: str
    needed_source: str
    available_source: str

    def line(self, scenario: str, wheels: str) -> str:
        about = "a wheel's speed" if self.quantity == "speed" else f"{self.quantity} about any axis"
        return (
            f"{scenario} needs {self.needed:.4g} {self.unit} of {about} "
            f"({self.needed_source}), but {wheels} give {self.available:.4g} {self.unit} "
            f"({self.available_source})"
        )


@dataclass(frozen=True)
class Oversize(Misfit):
    """One way the wheels are far too large for the mission (refused as a shortfall is).

    Attributes
    ----------
    what : str
        The wheels' number, in words with its unit and source.
    why : str
        Why it does not fit.
    """

    what: str
    why: str

    def line(self, scenario: str, wheels: str) -> str:
        return f"{wheels} are far too large for {scenario}: {self.what}; {self.why}"


def oversizes(sc) -> list[Oversize]:
    """How the scenario's wheels are far too large for what its mission needs (empty: not).

    A wheel set is refused when its torque about the weakest axis exceeds the largest
    torque the mission needs by more than :data:`FAR_OFF`, or when one wheel's own
    Coulomb friction (its spec) exceeds that torque.

    Parameters
    ----------
    sc : Scenario
        Its wheels and their requirements.

    Returns
    -------
    list of Oversize
    """
    w = sc.wheels
    need = w.required_torque_nm
    if need is None:
        return []
    spec = w.wheel_spec
    source = w.required_torque_source or f"{sc.name}'s requirement"
    out = []
    torque = w.max_torque / _allocation(sc)
    if torque > FAR_OFF * need:
        out.append(
            Oversize(
                f"they give {torque:.4g} N·m about any axis ({spec.source('max_torque_nm')}), "
                f"{torque / need:.0f}× the {need:.4g} N·m it needs ({source})",
                f"its torques would be under {100 / FAR_OFF:g} % of the wheels' range, where "
                "their friction and speed quantum are the torque they give",
            )
        )
    if spec.coulomb_friction_nm > need:
        out.append(
            Oversize(
                f"one wheel's Coulomb friction, {spec.coulomb_friction_nm:.4g} N·m "
                f"({spec.source('coulomb_friction_nm')}), exceeds the {need:.4g} N·m the "
                f"mission needs ({source})",
                "every torque it asks for is below the wheel's own drag",
            )
        )
    return out


def _allocation(sc) -> float:
    """max_i ‖row_i(G⁺)‖: one wheel's share of a unit body torque about the worst axis."""
    return float(np.linalg.norm(np.linalg.pinv(sc.wheel_matrix), axis=1).max())


def shortfalls(sc) -> list[Shortfall]:
    """What the scenario's wheels cannot deliver of its requirements (empty: they fit).

    Parameters
    ----------
    sc : Scenario
        Its wheels and their requirements.

    Returns
    -------
    list of Shortfall
    """
    w = sc.wheels
    spec = w.wheel_spec
    share = _allocation(sc)
    torque, torque_src = w.max_torque, spec.source("max_torque_nm")
    speed, speed_src = w.max_speed_rpm, spec.source("max_speed_rpm")
    if w.model == "identified" and w.model_file:
        from rwlab.wheel.identified import IdentifiedWheel

        unit = IdentifiedWheel.from_json(w.model_file)
        by_accel = w.inertia * unit.accel_limit_rpm_s * RPM
        if by_accel < torque:
            torque = by_accel
            torque_src = (
                f"model.json's acceleration limit {unit.accel_limit_rpm_s:g} rpm/s × "
                f"inertia {w.inertia:g} kg·m²"
            )
        if unit.speed_limit_rpm < speed:
            speed, speed_src = unit.speed_limit_rpm, "model.json's speed limit"
    momentum = min(w.max_momentum, w.inertia * speed * RPM)
    out = []
    need_t, need_h = w.required_torque_nm, w.required_momentum_nms
    t_source = w.required_torque_source or f"{sc.name}'s requirement"
    h_source = w.required_momentum_source or f"{sc.name}'s requirement"
    if need_t is not None and torque / share < need_t * (1 - 1e-9):
        out.append(Shortfall("torque", need_t, torque / share, "N·m", t_source, torque_src))
    if need_h is not None and momentum / share < need_h * (1 - 1e-9):
        momentum_src = f"inertia × speed limit ({speed_src})"
        out.append(Shortfall("momentum", need_h, momentum / share, "N·m·s", h_source, momentum_src))
        need_rpm = need_h * share / w.inertia / RPM
        out.append(Shortfall("speed", need_rpm, speed, "rpm", h_source, speed_src))
    return out


def check_wheel_fit(sc, *, force: bool = False) -> list[str]:
    """Refuse wheels that cannot deliver the scenario's requirements, or are far too large
    for them (:func:`oversizes`), unless forced.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    force : bool
        Fly them anyway: the shortfalls are returned for the report instead.

    Returns
    -------
    list of str
        One line per shortfall when forced (empty when the wheels fit).

    Raises
    ------
    ConfigError
        The first shortfall, one line, when not forced.
    """
    w = sc.wheels
    what = f"model.json ({w.model_file})" if w.model == "identified" else w.wheel_spec.name
    wheels = f"{sc.n_wheels} × {what} ({w.axes})"
    lines = [s.line(sc.name, wheels) for s in shortfalls(sc)]
    lines += [o.line(sc.name, wheels) for o in oversizes(sc)]
    if lines and not force:
        raise ConfigError(
            f"{lines[0]}; pick a wheel model that fits, or fly it with force_wheel=True"
        )
    return [f"FORCED: {line}" for line in lines]
