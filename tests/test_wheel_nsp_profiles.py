"""NSP profiles nrwa-t6 and rw4-12 (issue 43): the families' CRC, hand-built frames, refusals.

Every frame the twins are sent here is built byte by byte in this file and its CRC
computed by software nobody here wrote (``crccheck``'s CRC-16/MCRF4XX and the
standard library's ``binascii.crc_hqx`` on bit-reversed bytes), never by rwlab.
"""

import binascii
import math
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from crccheck.crc import Crc16Mcrf4Xx
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab.errors import ProtocolError
from rwlab.testbed import ExperimentConfig, read_record, run_experiment
from rwlab.wheel import WheelNode
from rwlab.wheel.clock import WallClock
from rwlab.wheel.link import get_protocol
from rwlab.wheel.nsp_t6 import q_decode, q_encode
from rwlab.wheel.nsp_wire import (
    NspPacket,
    SlipReader,
    crc16_nsp,
    decode_packet,
    encode_packet,
    setpoint_allowed,
)
from rwlab.wheel.physics import Mode
from rwlab.wheel.protocol import Command, Heartbeat, Telemetry
from rwlab.wheel.serial import open_pty

SRC = str(Path(__file__).resolve().parents[1] / "src")
RPM = 2 * math.pi / 60


def _reflect8(byte: int) -> int:
    return int(f"{byte:08b}"[::-1], 2)


def crc_by_binascii(data: bytes) -> int:
    """The reflected CCITT CRC from the MSB-first one: reflect each byte in, the result out."""
    crc = binascii.crc_hqx(bytes(_reflect8(b) for b in data), 0xFFFF)
    return int(f"{crc:016b}"[::-1], 2)


# -- the CRC and the codec ------------------------------------------------------------------
def test_the_crc_is_the_catalogued_mcrf4xx():
    # reveng's CRC catalogue: CRC-16/MCRF4XX (poly 0x1021 reflected, init 0xFFFF, no xorout)
    assert crc16_nsp(b"123456789") == 0x6F91
    assert Crc16Mcrf4Xx.calc(b"123456789") == 0x6F91


@given(data=st.binary(max_size=300))
def test_the_crc_agrees_with_two_independent_implementations(data):
    assert crc16_nsp(data) == Crc16Mcrf4Xx.calc(data) == crc_by_binascii(data)


packets = st.builds(
    NspPacket,
    dst=st.integers(0, 255),
    src=st.integers(0, 255),
    mcf=st.integers(0, 255),
    payload=st.binary(max_size=260),
)


@given(packet=packets)
def test_any_packet_survives_the_wire(packet):
    wire = encode_packet(packet)
    assert wire[0] == wire[-1] == 0xC0 and 0xC0 not in wire[1:-1]
    raw = bytes([packet.dst, packet.src, packet.mcf]) + packet.payload
    unescaped = wire[1:-1].replace(b"\xdb\xdc", b"\xc0").replace(b"\xdb\xdd", b"\xdb")
    assert unescaped == raw + Crc16Mcrf4Xx.calc(raw).to_bytes(2, "little")
    assert decode_packet(wire[1:-1]) == packet


@given(packet=packets, bit=st.integers(0, 10_000))
def test_any_single_bit_error_is_caught(packet, bit):
    raw = bytearray(encode_packet(packet)[1:-1].replace(b"\xdb\xdc", b"\xc0"))
    raw = bytearray(bytes(raw).replace(b"\xdb\xdd", b"\xdb"))
    raw[bit // 8 % len(raw)] ^= 1 << bit % 8
    escaped = bytes(raw).replace(b"\xdb", b"\xdb\xdd").replace(b"\xc0", b"\xdb\xdc")
    with pytest.raises(ProtocolError):
        decode_packet(escaped)


@given(junk=st.binary(max_size=400))
def test_any_bytes_decode_or_raise_protocol_error(junk):
    for body in SlipReader().feed(b"\xc0" + junk + b"\xc0"):
        try:
            decode_packet(body)
        except ProtocolError:
            pass


@settings(max_examples=50)
@given(packets=st.lists(packets, max_size=5), junk=st.binary(max_size=20))
def test_frames_are_found_in_a_stream_cut_anywhere(packets, junk):
    stream = junk.replace(b"\xc0", b"") + b"".join(encode_packet(p) for p in packets)
    reader, bodies = SlipReader(), []
    for i in range(0, len(stream), 7):
        bodies += reader.feed(stream[i : i + 7])
    decoded = []
    for body in bodies:
        try:
            decoded.append(decode_packet(body))
        except ProtocolError:
            pass  # the junk before the first frame
    assert decoded == packets


def test_a_longer_data_field_than_the_icd_allows_is_refused():
    with pytest.raises(ProtocolError, match="at most 260"):
        encode_packet(NspPacket(1, 0x11, 0x80, bytes(261)))


@given(value=st.floats(-8192, 8191.99), frac=st.sampled_from([18, 22, 8, 12]))
def test_q_formats_round_trip_to_their_resolution(value, frac):
    top = (1 << (31 - frac)) - 1 / (1 << frac)
    value = max(-top, min(top, value))
    assert abs(q_decode(q_encode(value, frac), frac) - value) <= 0.5 / (1 << frac)


def test_q_format_words_are_the_icds_examples():
    # ICD Table 12-26: CURRENT 1000 mA in Q14.18 is 0x0FA00000
    assert q_encode(1000.0, 18) == 0x0FA00000
    assert q_decode(0xFFFFFF00, 8) == -1.0  # Q24.8, two's complement
    for bad in (math.nan, math.inf, 1e30, 8192.0):
        with pytest.raises(ProtocolError):
            q_encode(bad, 18)


# -- the twins, sent hand-built frames over a pty ---------------------------------------------
def request(port, dst: int, mcf: int, payload: bytes = b"", crc=Crc16Mcrf4Xx.calc) -> bytes:
    """Frame a request by hand: ``crc`` low byte first, SLIP escapes, FENDs."""
    body = bytes([dst, 0x11, mcf]) + payload
    raw = body + crc(body).to_bytes(2, "little")
    return b"\xc0" + raw.replace(b"\xdb", b"\xdb\xdd").replace(b"\xc0", b"\xdb\xdc") + b"\xc0"


def exchange(port, frame: bytes, wait: float = 2.0) -> bytes | None:
    """Write a frame; the unescaped reply (with its CRC), or None if none comes in ``wait`` s."""
    port.write(frame)
    deadline, buffer = time.monotonic() + wait, b""
    while time.monotonic() < deadline:
        buffer += port.read(port.in_waiting or 1)
        frames = [f for f in buffer.split(b"\xc0") if f]
        if frames and buffer.endswith(b"\xc0"):
            return frames[-1].replace(b"\xdb\xdc", b"\xc0").replace(b"\xdb\xdd", b"\xdb")
        time.sleep(0.001)
    return None


def check(reply: bytes | None, src: int, command: int, ack: bool = True) -> bytes:
    """The reply's data after checking its CRC independently and its header."""
    assert reply is not None, "the twin did not answer"
    assert Crc16Mcrf4Xx.calc(reply[:-2]) == int.from_bytes(reply[-2:], "little")
    assert crc_by_binascii(reply[:-2]) == int.from_bytes(reply[-2:], "little")
    assert reply[0] == 0x11 and reply[1] == src  # to the host, from the wheel
    assert reply[2] == (0x20 if ack else 0) | command  # A bit, the command echoed, Poll clear
    return reply[3:-2]


@pytest.fixture
def twin(request):
    protocol, node_id = request.param
    twin_port, host_port = open_pty()
    node = WheelNode(twin_port, node_id, telemetry_rate=100, protocol=protocol, watchdog=0)
    node.start()
    yield node, host_port
    node.stop()
    twin_port.close()
    host_port.close()


def t6_standard(port, address):
    block = check(exchange(port, request(port, address, 0x87, b"\x00")), address, 0x07)
    assert len(block) == 25
    return struct.unpack("<IIBihhii", block)


@pytest.mark.parametrize("twin", [("nsp/nrwa-t6", 1)], indirect=True)
def test_an_nrwa_t6_ping_gets_an_ack_whose_crc_checks(twin):
    node, port = twin
    data = check(exchange(port, request(port, 0x01, 0x80)), 0x01, 0x00)
    assert len(data) == 5  # device type, serial, firmware major.minor.patch (Table 12-3)
    # the redundant port's address (+0x80) answers too, from that address
    check(exchange(port, request(port, 0x81, 0x80)), 0x81, 0x00)
    # rwlab's old MSB-first CRC: counted bad, no answer (ICD §11.3)
    old = request(port, 0x01, 0x80, crc=lambda body: binascii.crc_hqx(body, 0xFFFF))
    assert exchange(port, old, wait=0.3) is None
    # another wheel's address: no answer, counted foreign
    assert exchange(port, request(port, 0x02, 0x80), wait=0.3) is None
    assert node.bad_frames == 1 and node.foreign_frames == 1
    faults = t6_standard(port, 0x01)[1]
    assert faults & 1 << 12  # the CRC error is latched in the Fault register …
    check(exchange(port, request(port, 0x01, 0x89, (1 << 12).to_bytes(4, "little"))), 1, 0x09)
    assert t6_standard(port, 0x01)[1] & 1 << 12 == 0  # … until CLEAR-FAULT clears it


@pytest.mark.parametrize("twin", [("nsp/nrwa-t6", 1)], indirect=True)
def test_the_nrwa_t6_twin_latches_slip_and_crc_errors_in_their_own_bits(twin):
    _, port = twin
    assert exchange(port, b"\xc0\x01\x11\x80\xdb\x01\x00\x00\xc0", wait=0.3) is None
    faults = t6_standard(port, 0x01)[1]
    assert faults & 1 << 11 and not faults & 1 << 12  # SLIP frame error (ICD Table 12-15)
    old = request(port, 0x01, 0x80, crc=lambda body: binascii.crc_hqx(body, 0xFFFF))
    assert exchange(port, old, wait=0.3) is None
    assert t6_standard(port, 0x01)[1] & 1 << 12  # CRC error


@pytest.mark.parametrize("twin", [("nsp/nrwa-t6", 1)], indirect=True)
def test_the_nrwa_t6_twin_configures_only_the_protections_it_can_do_without(twin):
    _, port = twin
    protection = lambda bits: request(port, 1, 0x8A, bits.to_bytes(4, "little"))  # noqa: E731
    # EDAC scrub and braking load (Table 12-29 bits 3, 4): ACK, shown in status bits 20, 21
    check(exchange(port, protection(0b11000)), 1, 0x0A)
    assert t6_standard(port, 1)[0] >> 17 & 0x1F == 0b11000
    # the overspeed fault, the overspeed limit, the current limit: the twin keeps them: NACK
    for bit in range(3):
        check(exchange(port, protection(1 << bit)), 1, 0x0A, ack=False)
    assert t6_standard(port, 1)[0] >> 17 & 0x1F == 0b11000
    check(exchange(port, protection(0)), 1, 0x0A)  # all enabled again
    assert t6_standard(port, 1)[0] >> 17 & 0x1F == 0


@pytest.mark.parametrize("twin", [("nsp/nrwa-t6", 1)], indirect=True)
def test_the_nrwa_t6_twin_holds_the_icd_defaults_in_its_parameter_words(twin):
    node, port = twin
    peek = lambda address: int.from_bytes(  # noqa: E731
        check(exchange(port, request(port, 1, 0x82, bytes([address]))), 1, 0x02), "little"
    )
    assert peek(0x05) / (1 << 16) == 36.0  # +30 V drive overvoltage limit, V (§9.5.1.1)
    assert peek(0x08) / (1 << 14) == 100e3  # motor power limit, mW (§9.5.1.4)
    assert peek(0x20) / (1 << 16) == 31.0  # braking overvoltage load setpoint, V (§9.5.2.1)
    params = node.wheel.params
    assert peek(0x06) / (1 << 8) == params.overspeed_fault_rpm
    assert peek(0x09) / (1 << 14) == pytest.approx(params.current_limit * 1000, abs=1e-4)


class _CannedWheel:
    """A port that answers every request with one reply frame (built by hand here)."""

    def __init__(self, reply: bytes) -> None:
        self.reply, self.inbox = reply, b""

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def read(self, size: int) -> bytes:
        data, self.inbox = self.inbox[:size], self.inbox[size:]
        return data

    def write(self, data: bytes) -> int:
        self.inbox += self.reply
        return len(data)


@pytest.mark.parametrize(
    ("faults", "fault_active"),
    [(1 << 6 | 1 << 7 | 1 << 8 | 1 << 12, False), (1 << 5, True), (1 << 0, True)],
)
def test_the_nrwa_t6_driver_reads_only_faults_as_faults(faults, fault_active):
    """Overspeed-, overpower- and current-limited (Table 12-15 bits 6-8) latch on every
    saturated manoeuvre of a real NRWA-T6: flags, not faults; the overspeed and drive faults
    (bits 5, 0) are."""
    block = struct.pack("<IIBihhii", 1, faults, 0x04, 0, 0, 0, 0, 300 << 8)
    body = bytes([0x11, 0x01, 0x27]) + block
    raw = body + Crc16Mcrf4Xx.calc(body).to_bytes(2, "little")
    port = _CannedWheel(
        b"\xc0" + raw.replace(b"\xdb", b"\xdb\xdd").replace(b"\xc0", b"\xdb\xdc") + b"\xc0"
    )
    link = get_protocol("nsp/nrwa-t6").host_link(port, 1, clock=WallClock())
    telemetry = link.read_telemetry()
    assert telemetry is not None and telemetry.speed_rpm == 300.0
    assert telemetry.fault_active is fault_active


@pytest.mark.slow  # against a twin on the wall clock (its seconds are real ones)
@pytest.mark.parametrize("twin", [("nsp/nrwa-t6", 1)], indirect=True)
def test_the_nrwa_t6_twin_follows_app_command_and_refuses_what_it_cannot_do(twin):
    node, port = twin
    speed_300 = bytes([0x02]) + (300 << 18).to_bytes(4, "little")  # SPEED, Q14.18 rpm
    assert check(exchange(port, request(port, 1, 0x88, speed_300)), 1, 0x08) == b"\x02"
    time.sleep(1.5)
    _, _, mode, setpoint, _, _, current, speed = t6_standard(port, 1)
    assert mode == 0x02 and setpoint == 300 << 18
    assert 100 < speed / 256 < 310 and current / 4096 > 0  # Q24.8 rpm, Q20.12 mA
    before = speed / 256
    # 8192 rpm (the Q14.18 top) is beyond the twin's 7800 rpm: NACK, the register unchanged
    beyond = bytes([0x02]) + (0x7FFFFFFF).to_bytes(4, "little")
    assert check(exchange(port, request(port, 1, 0x88, beyond)), 1, 0x08, ack=False) == b"\x02"
    # CURRENT and PWM modes: the twin has no current loop: NACK
    current_mode = bytes([0x01]) + (1000 << 18).to_bytes(4, "little")
    check(exchange(port, request(port, 1, 0x88, current_mode)), 1, 0x08, ack=False)
    # malformed (3 data bytes), unimplemented (INIT, TRIP-LCL), unknown block: NACK
    check(exchange(port, request(port, 1, 0x88, b"\x02\x00\x00")), 1, 0x08, ack=False)
    check(exchange(port, request(port, 1, 0x81)), 1, 0x01, ack=False)
    check(exchange(port, request(port, 1, 0x8B)), 1, 0x0B, ack=False)
    check(exchange(port, request(port, 1, 0x87, b"\x09")), 1, 0x07, ack=False)
    time.sleep(0.3)
    assert node.wheel.setpoint == pytest.approx(300 * RPM)  # nothing refused was applied
    assert abs(t6_standard(port, 1)[7] / 256 - before) < 60  # still on its way to 300
    assert node.rejected_commands == 1  # the out-of-range setpoint, counted by the wheel
    assert node.link.nacked == 6
    # PEEK of the active speed limit (UQ14.18 rpm): the twin's limit
    word = check(exchange(port, request(port, 1, 0x82, b"\x07")), 1, 0x02)
    assert int.from_bytes(word, "little") / (1 << 18) == node.wheel.params.max_speed_rpm
    check(exchange(port, request(port, 1, 0x82, b"\x40")), 1, 0x02, ack=False)  # reserved
    # TORQUE mode: Q10.22 mN·m, the net torque: acceleration = torque / inertia
    torque = bytes([0x04]) + (1 << 22).to_bytes(4, "little", signed=True)  # 1 mN·m
    check(exchange(port, request(port, 1, 0x88, torque)), 1, 0x08)
    time.sleep(0.1)
    assert node.wheel.setpoint == pytest.approx(1e-3 / node.wheel.params.inertia)


@pytest.mark.slow  # against a twin on the wall clock (its seconds are real ones)
@pytest.mark.parametrize("twin", [("nsp/rw4-12", 0)], indirect=True)
def test_the_rw4_12_twin_answers_as_the_familys_drivers_expect(twin):
    node, port = twin

    def read(file: int) -> float:
        data = check(exchange(port, request(port, 0x20, 0x87, bytes([file]))), 0x20, 0x07)
        assert data[0] == file and len(data) == 5
        return struct.unpack("<f", data[1:])[0]

    assert check(exchange(port, request(port, 0x20, 0x80)), 0x20, 0x00).isascii()
    assert read(0x15) == 0.0  # speed, rad/s
    assert 20 < read(0x03) < 28  # bus voltage, V (RW90: a 24 V bus)
    assert read(0x28) == pytest.approx(node.wheel.params.inertia)  # kg·m²
    target = 300 * RPM
    write = b"\x00\x03" + struct.pack("<f", target)  # file 0, SPEED, rad/s
    check(exchange(port, request(port, 0x20, 0x88, write)), 0x20, 0x08)
    time.sleep(1.5)
    speed = read(0x15)
    assert 0.3 * target < speed < 1.05 * target  # the wheel moves
    assert read(0x1F) > 0.01  # motor current, A
    assert read(0x16) == pytest.approx(node.wheel.params.inertia * read(0x15), rel=0.05)
    for bad in (math.nan, math.inf, 1e30, -2 * node.wheel.params.max_speed):
        write = b"\x00\x03" + struct.pack("<f", bad)
        check(exchange(port, request(port, 0x20, 0x88, write)), 0x20, 0x08, ack=False)
    for bad_request in (b"\x00\x07" + struct.pack("<f", 1.0), b"\x01\x03" + bytes(4), b"\x00"):
        check(exchange(port, request(port, 0x20, 0x88, bad_request)), 0x20, 0x08, ack=False)
    check(exchange(port, request(port, 0x20, 0x87, b"\x77")), 0x20, 0x07, ack=False)
    time.sleep(0.1)
    assert node.wheel.setpoint == pytest.approx(target)  # none applied
    assert node.rejected_commands == 4 and node.errors == 0


# -- rwlab's driver sends the frames built by hand above ------------------------------------
@pytest.mark.slow  # against a twin on the wall clock (its seconds are real ones)
@pytest.mark.parametrize(
    ("protocol", "node_id", "expected"),
    [
        ("nsp/nrwa-t6", 1, (0x01, 0x88, bytes([0x02]) + (300 << 18).to_bytes(4, "little"))),
        ("nsp/rw4-12", 0, (0x20, 0x88, b"\x00\x03" + struct.pack("<f", 300 * RPM))),
    ],
)
def test_rwlabs_driver_sends_the_hand_built_frames_and_reads_the_replies(
    protocol, node_id, expected
):
    twin_port, host_port = open_pty()
    node = WheelNode(twin_port, node_id, telemetry_rate=100, protocol=protocol, watchdog=0)
    node.start()
    link = get_protocol(protocol).host_link(host_port, node_id, clock=WallClock())
    sent: list[bytes] = []
    link.raw_listener = lambda t, mcf, data, way: sent.append(data) if way == "tx" else None
    try:
        link.send(Command(node_id, Mode.SPEED, 300.0, 1), 0.0)
        assert sent[-1] == request(host_port, *expected)  # byte for byte
        assert link.lost_commands == 0
        time.sleep(1.0)
        frames = []
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            frames += [i.frame for i in link.receive(time.monotonic())]
            time.sleep(0.02)
        telemetry = [f for f in frames if isinstance(f, Telemetry)]
        assert telemetry and telemetry[-1].mode == Mode.SPEED and telemetry[-1].speed_rpm > 100
        assert telemetry[-1].sequence_echo == 1
        beats = [f for f in frames if isinstance(f, Heartbeat)]
        assert beats and beats[-1].commands_seen == 1 and 15 < beats[-1].temperature < 60
        if protocol == "nsp/rw4-12":  # a float32 carries 1e6 rpm; the wheel NACKs it
            link.send(Command(node_id, Mode.SPEED, 1e6, 2), 0.0)
            assert link.lost_commands == 1 and link.nacks == 1
        else:  # Q14.18 cannot carry it: refused before the wire
            with pytest.raises(ProtocolError):
                link.send(Command(node_id, Mode.SPEED, 1e6, 2), 0.0)
    finally:
        link.close()
        node.stop()
        twin_port.close()
        host_port.close()


def test_the_nrwa_t6_driver_refuses_to_encode_what_its_formats_cannot_carry():
    link = get_protocol("nsp/nrwa-t6").host_link(None, 1, clock=WallClock())
    with pytest.raises(ProtocolError, match="range"):
        link.encode_command(Command(1, Mode.SPEED, 9000.0, 1))  # Q14.18 tops at 8192 rpm
    with pytest.raises(ProtocolError, match=r"use node id 0\.\.7"):
        get_protocol("nsp/nrwa-t6").host_link(None, 8, clock=WallClock())


# -- the CLI -------------------------------------------------------------------------------
def test_served_nrwa_t6_prints_its_address_and_answers_a_hand_built_ping():
    env = {**os.environ, "PYTHONPATH": SRC}
    serve = subprocess.Popen(
        [sys.executable, "-m", "rwlab.cli", "wheel", "serve", "--protocol", "nsp/nrwa-t6",
         "--interface", "serial", "--channel", "pty", "--node-id", "2", "--duration", "20"],
        stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        path = serve.stderr.readline().split("serial:")[1].split(";")[0]
        assert "NSP address 0x02 (redundant port 0x82)" in serve.stderr.readline()
        # the NRWA-T6's own wheel model, named, unless --wheel says otherwise
        assert serve.stderr.readline().startswith("wheel model nrwa-t6 (nsp/nrwa-t6's default")
        assert f"--channel {path} --node-id 2" in serve.stderr.readline()
        import serial

        port = serial.serial_for_url(path, baudrate=460800, timeout=0)
        try:
            assert len(check(exchange(port, request(port, 0x02, 0x80)), 0x02, 0x00)) == 5
        finally:
            port.close()
    finally:
        serve.terminate()
        serve.communicate(timeout=20)


@pytest.mark.slow  # against a twin on the wall clock (its seconds are real ones)
@pytest.mark.parametrize("protocol", ["nsp/nrwa-t6", "nsp/rw4-12"])
def test_a_prbs_experiment_through_each_profile_loses_no_command(tmp_path, protocol):
    out = tmp_path / "r.mcap"
    run = subprocess.run(
        [sys.executable, "-m", "rwlab.cli", "experiment", "--protocol", protocol,
         "--signal", "prbs", "--duration", "60", "--amplitude", "3000", "--out", str(out)],
        capture_output=True, text=True, env={**os.environ, "PYTHONPATH": SRC}, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "120 commands" in run.stdout and "0 lost" in run.stdout
    assert "not acknowledged" not in run.stdout + run.stderr  # 0 lost commands
    record = read_record(out)
    assert record.metadata["protocol"] == protocol
    assert max(abs(t["speed_rpm"]) for t in record.topic("/telemetry")) > 1000


# -- open drivers nobody here wrote, when a checkout is at hand -----------------------------
DRIVERS = os.environ.get("RWLAB_NSP_DRIVERS", "")


@pytest.mark.skipif(not DRIVERS, reason="set RWLAB_NSP_DRIVERS to checkouts of the open drivers")
def test_the_rw4_12_twin_answers_the_open_rxnreflect_driver_unchanged(monkeypatch):
    """github.com/Rivercraft911/rxnReflect, written against a real RW4-12 (needs crcmod)."""
    pytest.importorskip("crcmod")
    monkeypatch.syspath_prepend(os.path.join(DRIVERS, "rxnReflect"))
    from rw_wheel import ReactionWheel, WheelNackError  # type: ignore[import-not-found]

    twin_port, host_port = open_pty()
    node = WheelNode(twin_port, 0, telemetry_rate=100, protocol="nsp/rw4-12", watchdog=0).start()
    try:
        with ReactionWheel(host_port.port, 115200, 0x20, 0x11) as wheel:
            assert wheel.ping().startswith("rwlab")
            assert wheel.read_speed() == 0.0 and 20 < wheel.read_vbus() < 28
            wheel.set_speed_rpm(300)
            time.sleep(1.5)
            assert wheel.read_current() > 0.01 and wheel.read_speed() > 0.3 * 300 * RPM
            speed = wheel.read_speed()
            with pytest.raises(WheelNackError):
                wheel.set_speed_rpm(1e30)
            assert abs(wheel.read_speed() - speed) < 0.2 * speed
    finally:
        node.stop()
        twin_port.close()
        host_port.close()


@pytest.mark.skipif(not DRIVERS, reason="set RWLAB_NSP_DRIVERS to checkouts of the open drivers")
def test_the_nrwa_t6_twin_answers_the_open_nss_host_driver_unchanged(monkeypatch):
    """github.com/ryan-rbw/nsrw_test's ``nss_host`` (MIT), an NRWA-T6 host after the ICD."""
    monkeypatch.syspath_prepend(os.path.join(DRIVERS, "nsrw_test"))
    from nss_host import nsp  # type: ignore[import-not-found]
    from nss_host.commands import Session  # type: ignore[import-not-found]

    twin_port, host_port = open_pty()  # nss_host talks to address 0x07
    node = WheelNode(twin_port, 7, telemetry_rate=100, protocol="nsp/nrwa-t6", watchdog=0)
    node.start()
    try:
        with Session.open(host_port.port, baud=460800, timeout_ms=50) as session:
            assert session.ping()[0] == 0x06
            session.app_command(nsp.ControlMode.SPEED, 300.0)
            time.sleep(1.5)
            standard = session.app_telemetry("STANDARD")
            assert standard.control_mode == 2 and 100 < standard.speed_rpm < 310
            assert standard.current_ma > 0
            with pytest.raises(nsp.NspNackError):
                session.app_command(nsp.ControlMode.SPEED, 8191.0)  # beyond the twin's limit
            assert session.peek(0x07) / (1 << 18) == node.wheel.params.max_speed_rpm
            session.config_protection(0b11000)  # EDAC scrub, braking load: the twin has neither
            with pytest.raises(nsp.NspNackError):
                session.config_protection(0b1)  # the overspeed fault: the twin keeps it
            session.config_protection(0)
            session.clear_fault()
            session.app_command(nsp.ControlMode.IDLE)
    finally:
        node.stop()
        twin_port.close()
        host_port.close()


def test_the_same_wheel_answers_through_every_nsp_profile(tmp_path):
    speeds = {}
    for name in ("rwlab", "nsp/nrwa-t6", "nsp/rw4-12"):
        path = tmp_path / f"{name.replace('/', '_')}.mcap"
        cfg = ExperimentConfig(
            signal="step", amplitude=1500, duration=60, Ts=0.5, seed=4, protocol=name, wheel="ideal"
        )
        summary = run_experiment(cfg, path)
        assert summary.status == "completed" and summary.lost_frames == 0
        speeds[name] = {
            round(t["t"], 6): t["speed_rpm"] for t in read_record(path).topic("/telemetry")
        }
    ref = speeds["rwlab"]
    assert max(ref.values()) > 1000  # it moved
    for name in ("nsp/nrwa-t6", "nsp/rw4-12"):
        common = sorted(t for t in set(speeds[name]) & set(ref) if t < 60.0)
        assert len(common) >= 600  # sampled at the same instants
        # one physics, one seed: within the DBC's 0.01 rpm, Q24.8 and float32
        assert max(abs(speeds[name][t] - ref[t]) for t in common) < 0.02


class _Port:
    """A pyserial-like port fed by the test: what the twin reads, what it writes."""

    def __init__(self) -> None:
        self.inbox, self.outbox = bytearray(), bytearray()

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def read(self, size: int) -> bytes:
        data, self.inbox = bytes(self.inbox[:size]), self.inbox[size:]
        return data

    def write(self, data: bytes) -> int:
        self.outbox += data
        return len(data)


@settings(max_examples=300, deadline=None)
@given(
    protocol=st.sampled_from(["nsp/nrwa-t6", "nsp/rw4-12"]),
    poll=st.booleans(),
    command=st.integers(0, 31),
    data=st.one_of(
        st.binary(max_size=12),
        st.tuples(st.integers(0, 255), st.floats(width=32)).map(
            lambda m: b"\x00" + struct.pack("<Bf", *m)
        ),
    ),
)
def test_any_well_framed_request_is_answered_never_raised(protocol, poll, command, data):
    from rwlab.wheel import RW90

    port = _Port()
    link = get_protocol(protocol).node_link(port, 1, clock=WallClock())
    link.configure(RW90)
    address = 0x01 if protocol == "nsp/nrwa-t6" else 0x21
    port.inbox += request(port, address, (0x80 if poll else 0) | command, data)
    commands = link.receive(0.0)
    if not poll:
        assert port.outbox == b""  # no Poll bit, no reply (ICD §11.4)
    else:
        reply = decode_packet(bytes(port.outbox[1:-1]))
        assert (reply.dst, reply.src, reply.command) == (0x11, address, command)
        assert reply.acked != (link.nacked == 1)
    if link.nacked == 0:  # what the twin ACKs, the wheel may obey (a NACKed one it refuses)
        assert all(setpoint_allowed(RW90, c.mode, c.setpoint) for _, c in commands)


# -- a command's echo comes in one round trip, not at the next poll ---------------------------
@pytest.mark.parametrize("protocol", ["nsp/nrwa-t6", "nsp/rw4-12", "nsp"])
def test_an_acked_command_is_echoed_at_once_not_at_the_next_poll(protocol):
    from rwlab.wheel import SimClock, WheelClient

    clock = SimClock()
    twin_port, host_port = open_pty()
    node = WheelNode(twin_port, 0, clock=clock, protocol=protocol, watchdog=0)
    client = WheelClient(host_port, 0, clock=clock, protocol=protocol)
    try:
        clock.sleep(0.01)  # the first poll is done: the next is a poll period (0.1 s) away
        assert client.poll()
        sent = clock.now()
        seq = client.set_speed(300.0)
        assert client.wait_ack(seq).sequence_echo == seq
        assert clock.now() - sent < 1e-3  # was up to 0.1 s: `wheel cmd` printed ~100 ms
    finally:
        client.link.close()
        node.stop()
        twin_port.close()
        host_port.close()
