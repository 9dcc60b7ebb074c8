"""rwlab's virtual bus (rwlab.wheel.virtual) is python-can's: it shares a channel with plain
python-can virtual buses, frames cross both ways unchanged, and an empty bus times out."""

from __future__ import annotations

import itertools
import time

import can
from can.interfaces.virtual import channels

from rwlab.wheel.virtual import CopyingVirtualBus

_names = (f"copying-virtual-{i}" for i in itertools.count())


def test_frames_cross_both_ways_with_plain_python_can_buses_on_one_channel():
    channel = next(_names)
    ours = CopyingVirtualBus(channel=channel)
    plain = [can.Bus(interface="virtual", channel=channel) for _ in range(2)]
    try:
        sent = can.Message(arbitration_id=0x123, data=[1, 2, 3], is_extended_id=False)
        ours.send(sent)
        for bus in plain:
            got = bus.recv(timeout=1.0)
            assert got is not None
            assert (got.arbitration_id, bytes(got.data), got.dlc) == (0x123, b"\x01\x02\x03", 3)
            assert got.is_rx and got.data is not sent.data  # each receiver its own copy
        plain[0].send(can.Message(arbitration_id=0x7FF, data=b"\xff" * 8, is_extended_id=False))
        got = ours.recv(timeout=1.0)
        assert got is not None and (got.arbitration_id, bytes(got.data)) == (0x7FF, b"\xff" * 8)
        assert ours.recv(timeout=0) is None and plain[1].recv(timeout=1.0) is not None
        start = time.monotonic()
        assert ours.recv(timeout=0.2) is None  # waits its timeout on an empty bus
        assert time.monotonic() - start >= 0.15
    finally:
        ours.shutdown()
        for bus in plain:
            bus.shutdown()
    assert channel not in channels  # the last bus to leave removes the channel
