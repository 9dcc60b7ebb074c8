"""Damaged records are found, refused with where and how much is readable, or salvaged.

A record is chunked with CRCs (the ``mcap`` library checks them), its data
section and summary have CRCs, and the summary's message counts are compared
with what was read: whatever bytes are damaged, a record either reads exactly as
written or is refused (issue 45, item 1).
"""

from __future__ import annotations

import json
import re
import struct
import warnings

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rwlab.cli import main
from rwlab.data import load
from rwlab.errors import FileFormatError, RecordDamagedError, RwlabWarning
from rwlab.testbed import ExperimentConfig, load_record, read_record, run_experiment


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    path = tmp_path_factory.mktemp("damage") / "rec.mcap"
    run_experiment(ExperimentConfig(duration=60, Ts=0.5, seed=3), path)
    return path


def _zeroed(src, dst, at: int, n: int = 64):
    data = bytearray(src.read_bytes())
    data[at : at + n] = bytes(n)
    dst.write_bytes(data)
    return dst


def test_64_zeroed_bytes_mid_file_are_refused_with_the_offset_and_what_is_readable(
    record, tmp_path
):
    size = record.stat().st_size
    bad = _zeroed(record, tmp_path / "bad.mcap", size // 2)
    with pytest.raises(RecordDamagedError) as info:
        read_record(bad)
    text = str(info.value)
    offset = info.value.offset
    assert f"damaged at byte {offset} of {size}" in text
    assert "salvage=True" in text and "--" not in text  # Python's words (the CLI: --salvage)
    assert size // 2 - 40_000 < offset <= size // 2  # the chunk the zeros fell in (≤ 32 kB)
    seconds = float(re.search(r"the first ([0-9.]+) s are readable", text).group(1))
    samples = int(re.search(r"\((\d+) samples at Ts = 0.5 s", text).group(1))
    assert 15 < seconds < 45 and seconds == pytest.approx(info.value.readable_s, abs=0.05)
    with pytest.warns(RwlabWarning, match="salvaged"):
        data = load_record(bad, salvage=True)
    assert data.N == samples  # the error's count is what salvaging gives
    assert "salvaged" in data.name and data.source["salvaged"]["damaged_at_byte"] == offset
    whole = load_record(record)
    assert (data.y[:, 0] == whole.y[: data.N, 0]).all()  # the part before the damage, intact


def test_a_copy_cut_short_is_damaged_but_a_killed_recorders_file_is_not(record, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(record.read_bytes()[: record.stat().st_size // 3])
    with pytest.raises(RecordDamagedError, match="ends in the middle of a record"):
        read_record(cut)
    partial = tmp_path / "cut.partial.mcap"
    partial.write_bytes(cut.read_bytes())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_record(partial)
    assert not rec.complete and rec.damage is None and rec.topic("/telemetry")


def test_a_damaged_summary_is_found(record, tmp_path):
    data = bytearray(record.read_bytes())
    data[-40] ^= 0xFF  # inside the summary offsets / footer region
    bad = tmp_path / "summary.mcap"
    bad.write_bytes(data)
    with pytest.raises(RecordDamagedError):
        read_record(bad)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(at=st.floats(0.0, 1.0), flip=st.integers(1, 255), zeros=st.booleans())
def test_any_damage_is_refused_or_reads_exactly_as_written(record, tmp_path, at, flip, zeros):
    """One flipped byte or 64 zeroed ones anywhere after the magic: never a silent change."""
    original = read_record(record)
    data = bytearray(record.read_bytes())
    k = 8 + int(at * (len(data) - 8 - 64))
    if zeros:
        data[k : k + 64] = bytes(64)
    else:
        data[k] ^= flip
    bad = tmp_path / "fuzz.mcap"
    bad.write_bytes(data)
    try:
        rec = read_record(bad)
    except (RecordDamagedError, FileFormatError):
        return
    assert rec.messages == original.messages and rec.metadata == original.metadata


def test_a_record_written_unchunked_by_an_older_rwlab_still_reads(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "old.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, use_chunking=False)
        w.start(profile="rwlab", library="rwlab")
        sid = w.register_schema(name="s", encoding="jsonschema", data=b"{}")
        ch = w.register_channel(topic="/command", message_encoding="json", schema_id=sid)
        w.add_metadata("rwlab", {"json": json.dumps({"Ts": 0.5})})
        for k in range(3):
            msg = {"t": 0.5 * k, "sequence": k, "mode": "speed", "setpoint": 1.0}
            w.add_message(ch, log_time=k, publish_time=k, data=json.dumps(msg).encode())
        w.finish()
    rec = read_record(path)
    assert rec.complete and len(rec.topic("/command")) == 3


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="rwlab")


def test_export_refuses_a_damaged_record_and_salvages_it_when_asked(record, tmp_path):
    bad = _zeroed(record, tmp_path / "bad.mcap", record.stat().st_size // 2)
    out = tmp_path / "x.csv"
    refused = _cli("export", bad, "--format", "csv", "--out", out)
    assert refused.exit_code == 2 and not out.exists()
    lines = refused.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "--salvage" in lines[0]
    assert "damaged at byte" in lines[0] and "samples at Ts = 0.5 s" in lines[0]
    done = _cli("export", bad, "--format", "csv", "--out", out, "--salvage")
    assert done.exit_code == 0, done.output
    assert "warning: " in done.output and "salvaged" in done.output
    assert "salvaged" in out.read_text().splitlines()[0]  # the file's metadata line says so
    assert load(out).name.startswith("bad.mcap (salvaged")  # and reads back saying so


def test_identify_refuses_a_damaged_record(record, tmp_path):
    bad = _zeroed(record, tmp_path / "bad.mcap", record.stat().st_size // 2)
    r = _cli("identify", bad, "--out", tmp_path / "id")
    assert r.exit_code == 2 and "damaged at byte" in r.output and "--salvage" in r.output
    assert not (tmp_path / "id").exists()


def test_zeros_in_a_message_index_between_chunks_are_found_there(record, tmp_path):
    # message index records carry no CRC; each is checked against the chunk before it
    data = record.read_bytes()
    at = 8
    while data[at] != 0x07:  # the first message index record
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    bad = _zeroed(record, tmp_path / "bad.mcap", at + 9 + 6 + 8, n=16)  # its first entry
    with pytest.raises(RecordDamagedError, match="message index") as info:
        read_record(bad)
    assert info.value.offset == at
