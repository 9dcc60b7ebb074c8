"""The reaction wheel: physics (RW90 default), CAN protocol, simulated node and host driver.

- :class:`WheelParams`, :data:`RW90`, :class:`WheelPhysics` — the wheel itself.
- ``rw.dbc`` / :mod:`rwlab.wheel.protocol` — the frames, shared by node and driver.
- :class:`WheelNode` — a simulated wheel on any python-can bus, with fault injection.
- :class:`WheelClient` — the host driver.
- :class:`SimClock`, :class:`WallClock` — time sources.
- :class:`SlipSerialBus` — the same frames over RS-232 (SLIP + CRC-16).
- :class:`IdentifiedWheel` — the model chosen by ``rwlab identify`` (``model.json``).
"""

import importlib

_SOURCES = {
    "WheelCommandError": "rwlab.errors",
    "WheelFault": "rwlab.errors",
    "WheelTimeout": "rwlab.errors",
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


def __getattr__(name: str):
    """Import on first use (PEP 562): ``rwlab --help`` must not load python-can and SciPy."""
    if name not in _SOURCES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_SOURCES[name]), name)
    globals()[name] = value
    return value


__all__ = [
    "RW90",
    "Fault",
    "FaultInjection",
    "IdentifiedWheel",
    "Mode",
    "SimClock",
    "SlipSerialBus",
    "WallClock",
    "WheelClient",
    "WheelCommandError",
    "WheelFault",
    "WheelNode",
    "WheelParams",
    "WheelPhysics",
    "WheelTimeout",
]
