"""Does a protocol carry a wheel's numbers? A telemetry signal too narrow for the wheel is refused.

A protocol with a fixed wire format (rwlab's DBC: ``Current`` ±2.048 A in 1 mA steps,
``BusVoltage`` 10..41.5 V) clips a larger wheel's readings without a word: an NRWA-T6
class wheel's current read through it saturates at 2.047 A and identification then
returns a torque constant 2.7× the truth. :func:`misfits` compares every range the
protocol declares (:meth:`rwlab.wheel.link.WheelProtocol.signal_ranges`) with the
wheel's numbers that must pass through it; :func:`check_carries` refuses the first,
naming the signal, its range, the wheel's field and its number.
"""

from __future__ import annotations

from rwlab.errors import ConfigError
from rwlab.wheel.physics import WheelParams

__all__ = ["check_carries", "misfits", "wheel_ranges"]

# the protocol a simulated wheel that rwlab's DBC cannot carry is spoken to with by
# default: rwlab's NSP profile sends speed and current as IEEE floats; where wheels share
# one CAN bus (hil), CANopen (its current in mA as a 16-bit integer: ±32.8 A)
WIDE_PROTOCOL = "nsp"
WIDE_CAN_PROTOCOL = "canopen"


def wheel_ranges(params: WheelParams) -> dict[str, tuple[float, float, str]]:
    """The values each telemetry quantity must carry for this wheel: (low, high, why).

    Parameters
    ----------
    params : WheelParams
        The wheel.

    Returns
    -------
    dict
        Quantity (``speed_rpm``, ``current_a``, ``bus_voltage_v``, ``temperature_c``,
        ``setpoint``) → the lowest and highest value and the fields they come from.
    """
    top_speed = params.overspeed_fault_rpm
    current = params.overcurrent_fault
    setpoint = max(params.max_speed_rpm, params.max_accel_rpm_s)
    return {
        "speed_rpm": (-top_speed, top_speed, f"overspeed_fault_rpm {top_speed:g} rpm"),
        "current_a": (-current, current, f"overcurrent_fault {current:g} A"),
        "bus_voltage_v": (
            params.bus_voltage,
            params.bus_voltage,
            f"bus_voltage {params.bus_voltage:g} V",
        ),
        "temperature_c": (
            params.ambient_c,
            params.overtemp_fault_c,
            f"ambient_c {params.ambient_c:g} °C to overtemp_fault_c {params.overtemp_fault_c:g} °C",
        ),
        "setpoint": (-setpoint, setpoint, f"max_speed_rpm / max_accel_rpm_s {setpoint:g}"),
    }


def misfits(ranges: dict[str, tuple[float, float, str]], params: WheelParams) -> list[str]:
    """The wheel's numbers a protocol's signals cannot carry, one line each.

    Parameters
    ----------
    ranges : dict
        The protocol's declared ranges: quantity → (low, high, signal's name).
    params : WheelParams
        The wheel.

    Returns
    -------
    list of str
        Empty when every declared signal carries the wheel.
    """
    out = []
    for quantity, (low, high, why) in wheel_ranges(params).items():
        if quantity not in ranges:
            continue
        lo, hi, signal = ranges[quantity]
        if low < lo or high > hi:
            out.append(f"its {why} is outside the {signal} signal's range [{lo:g}, {hi:g}]")
    return out


def check_carries(
    protocol_name: str, params: WheelParams, wheel: str, instead: str = WIDE_PROTOCOL
) -> None:
    """Refuse a protocol whose signals would clip the wheel's readings or commands.

    Parameters
    ----------
    protocol_name : str
        A registry name (:func:`rwlab.wheel.link.get_protocol`).
    params : WheelParams
        The wheel.
    wheel : str
        The wheel's name, for the message.
    instead : str
        The protocol the message suggests.

    Raises
    ------
    ConfigError
        The first signal too narrow, with what to do.
    """
    from rwlab.wheel.link import get_protocol

    found = misfits(get_protocol(protocol_name).signal_ranges(), params)
    if found:
        raise ConfigError(
            f"protocol {protocol_name!r} cannot carry wheel {wheel}: {found[0]}"
            f"{f' (and {len(found) - 1} more)' if len(found) > 1 else ''}, so its readings "
            f"would clip; choose a protocol that carries it (e.g. --protocol {instead}, whose "
            "signals do; `rwlab wheel protocols`)"
        )
