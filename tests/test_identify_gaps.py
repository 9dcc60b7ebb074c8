"""Identification refuses what it cannot trust (issue 28, item 3).

Truth: the same record without the dropout. A 2-s telemetry dropout (0.3 % of
the frames) once turned ARX221 into ARX222 and the rate limit from 314 to
8499 rpm/s, silently; now the record is refused with the reason, and a sample
time finer than the telemetry is refused too.
"""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.testbed.record import RecordWriter, read_record


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """A clean 600-s PRBS record and the same record with telemetry lost for 2 s."""
    root = tmp_path_factory.mktemp("gaps")
    clean = root / "clean.mcap"
    # a ramped PRBS: its study's choice is clear-cut (ARX221, ~98.5 %), so the split test
    # below is about the gap handling; a stepped record's structures tie within 1 point
    # and its choice can turn on the gain rule's margin
    run_experiment(ExperimentConfig(duration=600, seed=4, rate_limit=True), clean)
    rec = read_record(clean)
    dropout = root / "dropout.mcap"
    with RecordWriter(dropout, rec.metadata) as writer:
        for topic, messages in rec.messages.items():
            for m in messages:
                if topic == "/telemetry" and 300.0 <= m["t"] < 302.0:
                    continue
                writer.write(topic, m)
    return clean, dropout


def _identify(*args):
    return CliRunner().invoke(main, ["identify", *map(str, args)])


@pytest.fixture(scope="module")
def clean_study(records, tmp_path_factory):
    """The clean record identified (once: two tests read it), its study folder."""
    out = tmp_path_factory.mktemp("gaps-clean") / "c"
    result = _identify(records[0], "--out", out)
    assert result.exit_code == 0, result.output
    return out


def test_a_record_with_a_2s_dropout_is_refused_with_the_reason(records, clean_study, tmp_path):
    _, dropout = records
    assert (clean_study / "study.json").exists()  # the clean record is identified
    r = _identify(dropout, "--out", tmp_path / "d")
    assert r.exit_code == 2
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "telemetry gap" in errors[0] and "2" in errors[0]
    assert "Identification refuses a record with gaps" in errors[0]
    assert not (tmp_path / "d").exists()


def test_a_sample_time_finer_than_the_telemetry_is_refused(records, tmp_path):
    clean, _ = records
    period = 1 / ExperimentConfig().telemetry_rate  # the record's telemetry period
    r = _identify(clean, "--Ts", period / 2, "--out", tmp_path / "fine")
    assert r.exit_code == 2 and "shorter than the telemetry period" in r.output
    assert not (tmp_path / "fine").exists()


def test_split_at_the_gap_gives_the_clean_records_model(records, clean_study, tmp_path):
    """--gaps split: the two gap-free parts identified as one merged multi-experiment
    data set choose the clean record's structure, every parameter within its σ."""
    import json

    _, dropout = records
    r = _identify(dropout, "--gaps", "split", "--out", tmp_path / "s")
    assert r.exit_code == 0, r.output
    assert "split at telemetry gaps into 2 experiments" in r.output
    a = json.loads((clean_study / "study.json").read_text())
    b = json.loads((tmp_path / "s" / "study.json").read_text())
    assert a["segments"] is None
    [(s0, e0), (s1, e1)] = b["segments"]
    assert s0 == 0 and 299.0 < e0 < 300.5 and 301.5 < s1 <= 303.0 and e1 > 590
    assert b["chosen"]["structure"] == a["chosen"]["structure"]
    assert b["delay"]["nk"] == a["delay"]["nk"]
    for name, value in a["chosen"]["parameters"].items():
        sigma = max(a["chosen"]["std"][name], b["chosen"]["std"][name])
        assert abs(b["chosen"]["parameters"][name] - value) <= sigma, name
    model = json.loads((tmp_path / "s" / "model.json").read_text())
    assert model["data_segments"] == b["segments"]


def test_gap_free_segments_cut_out_exactly_the_stale_samples(records):
    """Truth: the frames removed. A clean record is one segment; the dropout's samples
    that repeat the frame before it belong to no segment, and nothing else is cut."""
    import numpy as np

    from rwlab.testbed import load_record
    from rwlab.testbed.load import gap_free_segments

    clean, dropout = records
    full = load_record(clean)
    assert gap_free_segments(clean) == [(0, full.N)]
    data = load_record(dropout, outputs=("speed", "age"), max_gap=np.inf)
    [(a0, b0), (a1, b1)] = gap_free_segments(dropout)
    assert a0 == 0 and b1 == data.N
    t = data.tstart + data.Ts * np.arange(data.N)
    assert np.all((t[b0:a1] > 300.0) & (t[b0:a1] < 302.1))  # only the dropout is cut
    age, period = data.y[:, 1], 0.1  # the twin's telemetry: 10 Hz
    assert np.all(age[b0:a1] > period)  # every cut sample holds a stale frame ...
    assert np.all(age[a0:b0] < period) and np.all(age[a1:b1] < period)  # ... no kept one


def test_segments_cut_at_the_split_never_cross_a_gap():
    """The estimation pieces end at the split or at a gap, the validation is the longest
    gap-free piece after the split, and a piece too short to estimate from is dropped."""
    from rwlab.errors import DataError
    from rwlab.ident.study import _pieces

    # 1000 samples, split at 700; gaps at 300-310 (estimation) and 850-860 (validation)
    p = _pieces(1000, 0.7, [(0, 300), (310, 850), (860, 1000)], needed_per_piece=30)
    assert p["est"] == [(0, 300), (310, 700)]
    assert p["val"] == (700, 850)  # 150 samples against 140 after the second gap
    assert p["longest"] == (310, 850)
    assert _pieces(1000, 0.7, [(0, 1000)], 30) is None  # no gap: the plain study
    p = _pieces(1000, 0.7, [(0, 20), (25, 1000)], needed_per_piece=30)
    assert p["est"] == [(25, 700)]  # 20 samples: too short for the regressors
    for bad in ([(0, 500), (400, 1000)], [(0, 1200)], []):
        with pytest.raises(DataError):
            _pieces(1000, 0.7, bad, 30)
    with pytest.raises(DataError, match="no estimation or validation piece"):
        _pieces(1000, 0.7, [(0, 690), (720, 1000)], needed_per_piece=300)
