import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab.wheel import Fault, Mode
from rwlab.wheel import protocol as proto
from rwlab.wheel.serial import crc16_ccitt, pack, slip_decode, slip_encode, unpack

node_ids = st.integers(0, 15)


@given(
    node=node_ids,
    mode=st.sampled_from(list(Mode)),
    seq=st.integers(0, 255),
    setpoint=st.floats(-1e6, 1e6, allow_nan=False, width=32),
)
def test_command_round_trip(node, mode, seq, setpoint):
    msg = proto.encode(proto.Command(node, mode, setpoint, seq))
    assert msg.arbitration_id == 0x100 + node and len(msg.data) == 8
    assert proto.decode(msg) == proto.Command(node, mode, setpoint, seq)


@given(
    node=node_ids,
    speed=st.integers(-8_388_608, 8_388_607),
    current=st.integers(-2048, 2047),
    mode=st.sampled_from([Mode.IDLE, Mode.SPEED, Mode.ACCELERATION]),
    fault=st.booleans(),
    limited=st.booleans(),
    seq=st.integers(0, 255),
    counter=st.integers(0, 255),
)
def test_telemetry_round_trip(node, speed, current, mode, fault, limited, seq, counter):
    t = proto.Telemetry(node, speed / 100, current / 1000, mode, fault, limited, seq, counter)
    back = proto.decode(proto.encode(t))
    assert back.speed_rpm == pytest.approx(t.speed_rpm, abs=1e-9)
    assert back.current == pytest.approx(t.current, abs=1e-9)
    assert (back.mode, back.fault_active, back.speed_limited, back.sequence_echo, back.counter) == (
        mode,
        fault,
        limited,
        seq,
        counter,
    )


@given(
    node=node_ids,
    faults=st.integers(0, 15),
    temp2=st.integers(-80, 175),
    uptime=st.integers(0, 65535),
)
def test_heartbeat_round_trip(node, faults, temp2, uptime):
    h = proto.Heartbeat(node, Mode.IDLE, Fault(faults), temp2 / 2, uptime, 7)
    assert proto.decode(proto.encode(h)) == h


@settings(max_examples=300)
@given(
    base=st.sampled_from([0x100, 0x180, 0x700]),
    node=node_ids,
    data=st.binary(min_size=0, max_size=8),
)
def test_any_payload_decodes_or_raises_protocol_error(base, node, data):
    msg = can.Message(arbitration_id=base + node, data=data, is_extended_id=False)
    try:
        proto.decode(msg)
    except proto.ProtocolError:
        pass


def test_a_corrupted_byte_fails_the_checksum_and_foreign_frames_are_ignored():
    msg = proto.encode(proto.Command(1, Mode.SPEED, 100.0, 5))
    bad = bytearray(msg.data)
    bad[2] ^= 0x10
    with pytest.raises(proto.ProtocolError, match="checksum"):
        proto.decode(can.Message(arbitration_id=msg.arbitration_id, data=bad, is_extended_id=False))
    assert (
        proto.decode(can.Message(arbitration_id=0x555, data=b"\0" * 8, is_extended_id=False))
        is None
    )
    assert (
        proto.decode(can.Message(arbitration_id=0x101, data=b"\0" * 8, is_extended_id=True)) is None
    )


def test_unencodable_commands_are_refused():
    with pytest.raises(proto.ProtocolError):
        proto.encode(proto.Command(16, Mode.SPEED, 1.0, 1))
    with pytest.raises(proto.ProtocolError):
        proto.encode(proto.Command(0, Mode.SPEED, float("nan"), 1))


def test_dbc_declares_one_megabit_and_has_a_stable_hash():
    assert proto.database().dbc.attributes["Baudrate"].value == 1_000_000
    assert len(proto.dbc_sha256()) == 64


def test_crc16_ccitt_check_value():
    assert crc16_ccitt(b"123456789") == 0x29B1  # the catalogue's check value for CRC-16/CCITT-FALSE


@given(payload=st.binary(max_size=64))
def test_slip_round_trip_and_no_stray_end_bytes(payload):
    framed = slip_encode(payload)
    assert framed[0] == framed[-1] == 0xC0 and 0xC0 not in framed[1:-1]
    assert slip_decode(framed[1:-1]) == payload


@given(
    arb=st.integers(0, 0x7FF),
    data=st.binary(max_size=8),
    flip=st.integers(0, 255),
    where=st.integers(0, 100),
)
def test_serial_payload_crc_catches_any_single_byte_error(arb, data, flip, where):
    msg = can.Message(arbitration_id=arb, data=data, is_extended_id=False)
    payload = bytearray(pack(msg))
    back = unpack(bytes(payload))
    assert back.arbitration_id == arb and bytes(back.data) == data
    if flip:
        payload[where % len(payload)] ^= flip
        assert unpack(bytes(payload)) is None
