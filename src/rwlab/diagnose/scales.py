"""The wheel's own scales the diagnosis reads: sample time, limits, the healthy current
balance, the speed loop's gain and the band where friction is breakaway.

Every scale comes from the model file or the wheel model's parameters: no wheel's
numbers are written here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["STICTION_BAND", "WheelScales", "stiction_band_rpm"]

# textbook, not tuned: at three Stribeck speeds the Stribeck excess is e⁻⁹ of itself, so
# outside that band (or three times the slowest reading) a wheel's friction is its
# Coulomb and viscous law
STICTION_BAND = 3.0


def stiction_band_rpm(params) -> float:
    """The speed under which the wheel's healthy friction law is breakaway.

    Parameters
    ----------
    params : WheelParams
        The wheel model.

    Returns
    -------
    float
        :data:`STICTION_BAND` × its Stribeck speed or the speed sensor's dead zone,
        whichever is larger, rpm (a magnitude).
    """
    stribeck = params.stribeck_speed_rpm if params.stiction else 0.0
    return STICTION_BAND * max(stribeck, params.min_measurable_rpm)


@dataclass(frozen=True)
class WheelScales:
    """What the pipeline takes from ``model.json``: the wheel's own scales.

    Attributes
    ----------
    Ts : float
        Sample time, s.
    accel_limit_rpm_s : float
        The loop's acceleration limit, rpm/s.
    current_limit_a : float
        The driver's specified current clamp, A.
    current_model : tuple of 4 float
        c of the current balance (A per rpm/s, A per rpm, A, A).
    loop_gain_per_s : float
        The speed loop's proportional gain kp, 1/s: the grey box's, else the servo
        model's (``rwlab identify`` fits the grey box only with ``--nonlinear-models``;
        the two differed by 1.2 % on a 25-minute twin PRBS), else 0 (the catch-up term
        is then left out).
    stiction_band_rpm : float
        Under this speed the bearing's law is breakaway, not the balance's Coulomb and
        viscous law: the current and the reach are not read there (0: read down to the
        slowest reading).
    """

    Ts: float
    accel_limit_rpm_s: float
    current_limit_a: float
    current_model: tuple[float, float, float, float]
    loop_gain_per_s: float = 0.0
    stiction_band_rpm: float = 0.0

    @classmethod
    def from_model_file(cls, path) -> WheelScales:
        """The scales of a ``model.json`` written by ``rwlab identify``.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        WheelScales

        Raises
        ------
        FileFormatError
            No healthy reference in the file (identify on a record with motor current).
        """
        from rwlab.diagnose.reference import HealthyReference
        from rwlab.ident.model_file import WheelModelFile

        info = WheelModelFile.load(path)
        reference = HealthyReference.from_model_file(path)
        grey = info.nonlinear_models.get("greybox") or {}
        c = reference.current_model
        # the clamp: the file's, the grey box's, the wheel model's, else the current the
        # balance needs at the limit
        spec = info.wheel_spec
        limit = (
            info.current_limit_a
            or grey.get("current_limit")
            or (spec.current_limit_a if spec is not None else None)
        )
        if not limit:  # the current the balance needs at the acceleration limit
            limit = c[0] * info.accel_limit_rpm_s + abs(c[2])
        return cls(
            Ts=float(info.model.Ts),
            accel_limit_rpm_s=float(info.accel_limit_rpm_s),
            current_limit_a=float(limit),
            current_model=c,
            loop_gain_per_s=float(
                grey.get("kp") or (info.servo.kp if info.servo is not None else 0.0)
            ),
        )

    @classmethod
    def from_params(cls, params, Ts: float) -> WheelScales:
        """The scales of a wheel model's parameters (a twin's, or a datasheet's), for
        acceleration-mode records: the driver's feed-forward is this model's current
        balance, so it is the healthy reference (c₃ = 0: no sense offset).

        Parameters
        ----------
        params : WheelParams
            The wheel model.
        Ts : float
            Sample time of the records, s.

        Returns
        -------
        WheelScales
            With the stiction band :data:`STICTION_BAND` × the Stribeck speed or the
            slowest reading, whichever is larger.
        """
        rad = math.pi / 30  # rad/s per rpm
        kt = params.torque_constant
        return cls(
            Ts=float(Ts),
            accel_limit_rpm_s=float(params.max_accel_rpm_s),
            current_limit_a=float(params.current_limit),
            current_model=(
                params.inertia * rad / kt,
                params.viscous_friction * rad / kt,
                params.coulomb_friction / kt,
                0.0,
            ),
            stiction_band_rpm=stiction_band_rpm(params),
        )
