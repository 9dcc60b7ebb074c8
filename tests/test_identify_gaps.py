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
    run_experiment(ExperimentConfig(duration=600, seed=4), clean)
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


def test_a_record_with_a_2s_dropout_is_refused_with_the_reason(records, tmp_path):
    clean, dropout = records
    assert _identify(clean, "--out", tmp_path / "clean").exit_code == 0
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
