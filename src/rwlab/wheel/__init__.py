"""The reaction wheel: physics (RW90 default), CAN protocol, simulated node and host driver.

- :class:`WheelParams`, :data:`RW90`, :class:`WheelPhysics` — the wheel itself.
- :mod:`rwlab.wheel.protocol` — the protocol-free messages, and ``rw.dbc``'s frames.
- :mod:`rwlab.wheel.link` — wheel protocols by name (``rwlab``, ``canopen``, ``nsp``,
  and any added by the entry-point group ``rwlab.wheel_protocols``).
- :class:`WheelNode` — a simulated wheel speaking any of them, with fault injection.
- :class:`WheelClient` — the host driver, the same for every protocol.
- :class:`SimClock`, :class:`WallClock` — time sources.
- :class:`SlipSerialBus` — the same frames over RS-232 (SLIP + CRC-16).
- :class:`IdentifiedWheel` — the model chosen by ``rwlab identify`` (``model.json``).
"""

from rwlab._lazy import lazy_exports

_SOURCES = {
    "WheelCommandError": "rwlab.errors",
    "WheelFault": "rwlab.errors",
    "WheelTimeout": "rwlab.errors",
    "WheelConflict": "rwlab.errors",
    "Implausible": "rwlab.wheel.client",
    "WheelProtocol": "rwlab.wheel.link",
    "get_protocol": "rwlab.wheel.link",
    "WheelClient": "rwlab.wheel.client",
    "SimClock": "rwlab.wheel.clock",
    "WallClock": "rwlab.wheel.clock",
    "IdentifiedWheel": "rwlab.wheel.identified",
    "FaultInjection": "rwlab.wheel.node",
    "WheelNode": "rwlab.wheel.node",
    "RW90": "rwlab.wheel.physics",
    "Fault": "rwlab.wheel.physics",
    "Mode": "rwlab.wheel.physics",
    "WheelParams": "rwlab.wheel.physics",
    "WheelPhysics": "rwlab.wheel.physics",
    "SlipSerialBus": "rwlab.wheel.serial",
}


# imported on first use: ``rwlab --help`` must not load python-can and SciPy
__getattr__ = lazy_exports(__name__, _SOURCES)


__all__ = [
    "RW90",
    "Fault",
    "FaultInjection",
    "IdentifiedWheel",
    "Implausible",
    "Mode",
    "SimClock",
    "SlipSerialBus",
    "WallClock",
    "WheelClient",
    "WheelCommandError",
    "WheelConflict",
    "WheelFault",
    "WheelNode",
    "WheelParams",
    "WheelPhysics",
    "WheelProtocol",
    "WheelTimeout",
    "get_protocol",
]
