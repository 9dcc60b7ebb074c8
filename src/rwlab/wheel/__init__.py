"""The reaction wheel: physics (RW90 default), CAN protocol, simulated node and host driver."""

from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, WheelPhysics

__all__ = ["RW90", "Fault", "Mode", "WheelParams", "WheelPhysics"]
