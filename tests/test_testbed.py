import itertools
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.data import load
from rwlab.errors import ConfigError, DataError, FileFormatError, RecordDamagedError, RecordGapError
from rwlab.ident import arx, delayest
from rwlab.testbed import ExperimentConfig, RecordWriter, load_record, read_record, run_experiment
from rwlab.testbed.record import partial_path
from rwlab.wheel.protocol import dbc_sha256


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.fixture(scope="module")
def prbs_record(tmp_path_factory):
    """A 20-minute PRBS experiment on the simulated wheel and clock (paper A's set-up).

    The ideal twin: these tests check that every frame sent is recorded, so the
    realistic twin's rare frame loss would blur them.
    """
    path = tmp_path_factory.mktemp("rec") / "prbs.mcap"
    cfg = ExperimentConfig(duration=1200, Ts=0.5, seed=3, wheel="ideal")
    summary = run_experiment(cfg, path)
    return path, summary


def test_prbs_experiment_to_identification_end_to_end(prbs_record):
    path, summary = prbs_record
    assert summary.status == "completed" and summary.commands == 2400 and summary.lost_frames == 0
    data = load_record(path)
    assert data.Ts == 0.5 and data.N == 2401 and data.input_names == ("command",)
    assert data.name == path.name  # a run that reached its end: nothing said
    est, _ = data.normalize().split(0.7)
    assert delayest(est, nk_max=5) == 1
    model = arx(est, 2, 2, 1)
    assert model.is_stable() and 0.8 < model.dc_gain() < 1.2  # speed follows its command


def test_record_keeps_every_frame_with_metadata(prbs_record):
    path, _summary = prbs_record
    rec = read_record(path)
    assert rec.complete and not rec.problem
    meta = rec.metadata
    assert meta["Ts"] == 0.5 and meta["dbc_sha256"] == dbc_sha256()
    assert meta["wheel"]["max_speed_rpm"] == 7800 and meta["experiment"]["signal"] == "prbs"
    counters = [m["counter"] for m in rec.topic("/telemetry")]
    assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(counters))
    seqs = [c["sequence"] for c in rec.topic("/command")]
    echoed = {m["sequence_echo"] for m in rec.topic("/telemetry")}
    assert set(seqs[-200:]) <= echoed  # every command was acknowledged
    assert [e["kind"] for e in rec.topic("/event")] == ["start", "timing", "stop"]
    times = [c["t"] for c in rec.topic("/command")]
    assert np.allclose(np.diff(times), 0.5)  # absolute scheduling: no drift


def test_interrupted_experiment_idles_the_wheel_and_closes_the_record(tmp_path):
    path = tmp_path / "stop.mcap"

    def progress(k, n):
        if k == 40:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_experiment(ExperimentConfig(duration=100, seed=1), path, progress=progress)
    rec = read_record(path)
    assert rec.complete
    last_event = rec.topic("/event")[-1]
    assert (last_event["kind"], last_event["message"]) == ("stop", "interrupted")
    assert rec.topic("/telemetry")[-1]["mode"] == "IDLE"
    # what identify reads says the run was cut short
    assert load_record(path).name == "stop.mcap (interrupted: the run stopped before its end)"


def test_realtime_experiment_runs_on_the_wall_clock(tmp_path):
    start = time.monotonic()
    s = run_experiment(
        ExperimentConfig(duration=1.0, Ts=0.1, realtime=True, telemetry_rate=50, signal="step"),
        tmp_path / "rt.mcap",
    )
    assert s.status == "completed" and 0.9 <= time.monotonic() - start <= 5
    assert s.telemetry >= 40


def test_experiment_config_file_and_its_errors(tmp_path):
    good = tmp_path / "exp.toml"
    good.write_text('[experiment]\nsignal = "chirp"\nduration = 60\nTs = 0.1\namplitude = 2000\n')
    cfg = ExperimentConfig.from_toml(good, seed=9)
    assert (cfg.signal, cfg.duration, cfg.Ts, cfg.seed) == ("chirp", 60, 0.1, 9)
    (tmp_path / "bad.toml").write_text('[experiment]\nsignall = "prbs"\n')
    with pytest.raises(ConfigError, match="signall"):
        ExperimentConfig.from_toml(tmp_path / "bad.toml")
    with pytest.raises(ConfigError, match="unknown signal"):
        ExperimentConfig(signal="sawtooth")
    with pytest.raises(ConfigError, match="positive"):
        ExperimentConfig(Ts=-1)
    with pytest.raises(ConfigError, match="limit"):
        run_experiment(ExperimentConfig(amplitude=9000), tmp_path / "x.mcap")
    with pytest.raises(ConfigError, match="limit"):
        run_experiment(ExperimentConfig(mode="acceleration", amplitude=400), tmp_path / "y.mcap")
    assert not (tmp_path / "x.mcap").exists()


def test_experiment_takes_a_wheel_toml_and_records_its_driver_settings(tmp_path):
    toml = tmp_path / "limited.toml"
    toml.write_text('[wheel]\npreset = "ideal"\ncurrent_limit = 0.35\n')
    out = tmp_path / "step.mcap"
    r = CliRunner().invoke(
        main,
        ["experiment", "--signal", "step", "--amplitude", "3000", "--duration", "40",
         "--wheel", str(toml), "--out", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert read_record(out).metadata["wheel"]["current_limit"] == 0.35
    # the ideal twin reports the current exactly: the driver's clamp shows as the peak
    current = load_record(out, outputs=("current",)).y[:, 0]
    assert np.max(np.abs(current)) == pytest.approx(0.35, abs=1e-6)
    unit = ExperimentConfig(wheel=str(toml), unit=3).wheel_params()
    assert unit.current_limit == pytest.approx(0.35, rel=0.021)  # ±2 % per unit
    bad = CliRunner().invoke(main, ["experiment", "--wheel", "rw91", "--out", str(out)])
    assert bad.exit_code == 2 and "error:" in bad.output and "TOML" in bad.output
    missing = CliRunner().invoke(
        main, ["experiment", "--wheel", str(tmp_path / "no.toml"), "--out", str(out)]
    )
    assert missing.exit_code == 2 and "error:" in missing.output


def test_records_are_never_overwritten_without_force(tmp_path, prbs_record):
    path, _ = prbs_record
    before = path.read_bytes()
    with pytest.raises(FileExistsError):
        run_experiment(ExperimentConfig(duration=10), path)
    assert path.read_bytes() == before


def test_truncated_and_foreign_files(tmp_path, prbs_record):
    path, _ = prbs_record
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(RecordDamagedError, match="ends in the middle of a record"):
        read_record(cut)  # a copy cut short is no killed run's partial record
    killed = tmp_path / "cut.partial.mcap"  # the file a killed recorder leaves ends early
    killed.write_bytes(cut.read_bytes())
    rec = read_record(killed)
    assert not rec.complete and rec.problem and len(rec.topic("/telemetry")) > 1000
    assert load_record(killed).name.endswith("(truncated)")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not a record")
    with pytest.raises(FileFormatError, match="not an MCAP"):
        read_record(junk)
    with pytest.raises(FileNotFoundError):
        read_record(tmp_path / "missing.mcap")


def _write_synthetic(path, times):
    with RecordWriter(path, {"Ts": 0.5, "mode": "speed"}) as w:
        w.write("/command", {"t": 0.0, "sequence": 1, "mode": "speed", "setpoint": 100.0})
        for i, t in enumerate(times):
            w.write(
                "/telemetry",
                {
                    "t": t,
                    "speed_rpm": float(i),
                    "current_a": 0.0,
                    "mode": "SPEED",
                    "fault_active": False,
                    "speed_limited": False,
                    "sequence_echo": 1,
                    "counter": i % 256,
                },
            )


def test_gaps_in_telemetry_are_reported_not_hidden(tmp_path):
    times = np.concatenate([np.arange(0, 10, 0.1), np.arange(13, 20, 0.1)])
    _write_synthetic(tmp_path / "gap.mcap", times)
    with pytest.raises(RecordGapError, match="gap") as err:
        load_record(tmp_path / "gap.mcap")
    assert "3 s" in str(err.value) or "3.1 s" in str(err.value)
    data = load_record(tmp_path / "gap.mcap", max_gap=np.inf)
    assert data.N == 40


def test_load_record_samples_command_as_zoh_and_derives_acceleration(tmp_path):
    times = np.arange(0, 5.01, 0.05)
    _write_synthetic(tmp_path / "ramp.mcap", times)  # speed = frame index, a frame every 50 ms
    data = load_record(tmp_path / "ramp.mcap", outputs=("speed", "acceleration"))
    assert np.all(data.u[:, 0] == 100.0)
    assert np.allclose(data.y[1:, 1], 20.0)  # +10 rpm per 0.5 s


def test_a_sigkilled_recorder_loses_at_most_100_ms(tmp_path):
    path = tmp_path / "crash.mcap"
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"""
import time
from rwlab.testbed.record import RecordWriter
w = RecordWriter({str(path)!r}, {{"Ts": 0.001}})
print("started", flush=True)
k = 0
while True:
    now = time.time()
    w.write("/telemetry", {{"t": now, "speed_rpm": 0.0, "current_a": 0.0, "mode": "SPEED",
        "fault_active": False, "speed_limited": False, "sequence_echo": 0, "counter": k % 256}})
    k += 1
    time.sleep(0.001)
""",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert child.stdout.readline().strip() == "started"
    time.sleep(1.5)
    killed_at = time.time()
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    assert not path.exists()  # a killed run never replaces the record at its path...
    rec = read_record(partial_path(path))  # ...and its own opens although it has no footer
    frames = rec.topic("/telemetry")
    assert not rec.complete and len(frames) > 500  # ~1 kHz for 1.5 s
    assert killed_at - frames[-1]["t"] <= 0.100


def test_export_writes_csv_parquet_and_mat(tmp_path, prbs_record):
    path, _ = prbs_record
    runner = CliRunner()
    for fmt in ("csv", "parquet", "mat"):
        out = tmp_path / f"x.{fmt}"
        r = runner.invoke(main, ["export", str(path), "--format", fmt, "--out", str(out)])
        assert r.exit_code == 0, r.output
        with pytest.raises(DataError, match="ambiguous"):  # four channels: which is the output?
            load(out)
        back = load(out, input_columns="command", output_columns="current_a")
        assert back.N == 2401 and back.Ts == 0.5 and back.output_names == ("current_a",)
        assert oct(out.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    header = (tmp_path / "x.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["time_s", "command", "speed_rpm"]
    r = runner.invoke(
        main, ["export", str(path), "--format", "csv", "--out", str(tmp_path / "x.csv")]
    )
    assert r.exit_code == 2 and "exists" in r.output


def test_experiment_command_line(tmp_path):
    out = tmp_path / "cli.mcap"
    r = CliRunner().invoke(
        main,
        [
            "experiment",
            "--signal",
            "chirp",
            "--mode",
            "speed",
            "--amplitude",
            "3000",
            "--duration",
            "120",
            "--Ts",
            "0.1",
            "--out",
            str(out),
            "--seed",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    assert "1200 commands" in r.output
    assert json.loads(json.dumps(read_record(out).metadata))["experiment"]["signal"] == "chirp"
    bad = CliRunner().invoke(
        main, ["experiment", "--amplitude", "9000", "--out", str(tmp_path / "b.mcap")]
    )
    assert bad.exit_code == 2 and "limit" in bad.output
    unknown = CliRunner().invoke(main, ["experiment", "--signal", "sawtooth", "--out", "x.mcap"])
    assert unknown.exit_code == 2


def test_a_unit_in_the_wheel_file_and_another_unit_option_are_refused(tmp_path):
    """Both would draw: unit 4 around unit 3, a wheel that is neither (newcomer finding)."""
    wheel = tmp_path / "w.toml"
    wheel.write_text('[wheel]\npreset = "rw90"\nunit = 3\n', encoding="utf-8")
    with pytest.raises(ConfigError, match="give the unit in one place"):
        ExperimentConfig(wheel=str(wheel), unit=4).wheel_params()
    drawn = ExperimentConfig(wheel=str(wheel)).wheel_params()  # the file's unit alone
    assert drawn == ExperimentConfig(unit=3).wheel_params()
