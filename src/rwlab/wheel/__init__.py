"""The reaction wheel: physics (RW90 default), CAN protocol, simulated node and host driver.

- :class:`WheelParams`, :data:`RW90`, :class:`WheelPhysics` — the wheel itself.
- ``rw.dbc`` / :mod:`rwlab.wheel.protocol` — the frames, shared by node and driver.
- :class:`WheelNode` — a simulated wheel on any python-can bus, with fault injection.
- :class:`WheelClient` — the host driver.
- :class:`SimClock`, :class:`WallClock` — time sources.
- :class:`SlipSerialBus` — the same frames over RS-232 (SLIP + CRC-16).
- :class:`IdentifiedWheel` — the model chosen by ``rwlab identify`` (``model.json``).
"""

from rwlab.errors import WheelCommandError, WheelFault, WheelTimeout
from rwlab.wheel.client import WheelClient
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.identified import IdentifiedWheel
from rwlab.wheel.node import FaultInjection, WheelNode
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, WheelPhysics
from rwlab.wheel.serial import SlipSerialBus

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
