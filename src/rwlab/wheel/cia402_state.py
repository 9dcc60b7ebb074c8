"""The CiA 402 drive state machine: controlword → state, state → statusword.

Written from CiA 402 as the ``canopen`` package's ``canopen.profiles.p402``
implements it: ``State402.TRANSITIONTABLE`` (which controlword takes which
state where, transitions 2..16), ``State402.SW_MASK`` (the statusword bits of
each state, mask 0x4F/0x6F) and the fault reset on bit 7's rising edge
(``tests/test_canopen_profiles.py`` checks every entry of both tables). The
code is ours; it knows nothing of the wheel.
"""

from __future__ import annotations

import enum

__all__ = ["DriveState", "S", "next_state", "statusword"]


class DriveState(enum.Enum):
    """CiA 402 states, each with its statusword bits (mask 0x6F, as ``BaseNode402`` reads)."""

    SWITCH_ON_DISABLED = 0x40
    READY_TO_SWITCH_ON = 0x21
    SWITCHED_ON = 0x23
    OPERATION_ENABLED = 0x27
    QUICK_STOP_ACTIVE = 0x07
    FAULT = 0x08


S = DriveState


def next_state(state: DriveState, controlword: int, previous: int) -> DriveState:
    """The state after the controlword ``controlword`` (the one before was ``previous``).

    Parameters
    ----------
    state : DriveState
    controlword, previous : int
        0..0xFFFF.

    Returns
    -------
    DriveState
    """
    if state is S.FAULT:  # only a fault reset (bit 7 rising) leaves it: transition 15
        return S.SWITCH_ON_DISABLED if controlword & 0x80 and not previous & 0x80 else S.FAULT
    if not controlword & 0x02:  # disable voltage: 7, 9, 10, 12
        return S.SWITCH_ON_DISABLED
    if not controlword & 0x04:  # quick stop: 11 from operation enabled, else 7 / 10
        active = state in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE)
        return S.QUICK_STOP_ACTIVE if active else S.SWITCH_ON_DISABLED
    if not controlword & 0x01:  # shutdown: 2, 6, 8 (none from quick stop active)
        return state if state is S.QUICK_STOP_ACTIVE else S.READY_TO_SWITCH_ON
    if state is S.SWITCH_ON_DISABLED:  # switch on needs ready to switch on first
        return state
    if controlword & 0x08:  # enable operation: 3 + 4, 4, 16
        return S.OPERATION_ENABLED
    return state if state is S.QUICK_STOP_ACTIVE else S.SWITCHED_ON  # switch on: 3, 5


def statusword(state: DriveState, *, limited: bool, at_target: bool, stopped: bool) -> int:
    """The statusword of ``state`` with its flag bits.

    Parameters
    ----------
    state : DriveState
    limited : bool
        Bit 11, internal limit active (a speed limit or a refused setpoint).
    at_target : bool
        Bit 10, target reached.
    stopped : bool
        Bit 12 in profile velocity: speed is zero.

    Returns
    -------
    int
    """
    word = state.value | 0x0200  # bit 9 remote: the drive takes the bus's commands
    if state not in (S.SWITCH_ON_DISABLED, S.FAULT):
        word |= 0x10  # voltage enabled
    return word | (0x800 if limited else 0) | (0x400 if at_target else 0) | (0x1000 * stopped)
