"""Campaigns keep what they finished (issue 28, item 2).

Truth: an uninterrupted campaign. A campaign killed with SIGTERM and resumed
must give its rows and budget exactly; a killed worker must be retried and the
retry reported; a campaign too large to end is refused before it starts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from rwlab.attitude.scenario import load_scenario
from rwlab.campaign.dispersions import load_dispersions
from rwlab.campaign.engine import dask_client
from rwlab.campaign.montecarlo import Execution, run_campaign
from rwlab.campaign.runs import Campaign, run_batch, run_seeds
from rwlab.campaign.store import RunStore
from rwlab.cli import main
from rwlab.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SMALLSAT = load_scenario("geo-smallsat")
ARGS = [
    *("attitude", "montecarlo", "--scenario", "geo-smallsat", "--controller", "pd"),
    *("--runs", "12", "--duration", "200", "--workers", "1", "--seed", "3"),
]


def _rwlab(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _budget(out: Path) -> dict:
    b = json.loads((out / "budget.json").read_text())
    b.pop("execution")  # how it ran, not what it found
    return b


@pytest.mark.slow
def test_a_campaign_killed_with_sigterm_then_resumed_is_the_uninterrupted_one(tmp_path):
    whole = tmp_path / "whole"
    r = _rwlab(*ARGS, "--out", whole)
    assert r.exit_code == 0, r.output
    out = tmp_path / "cut"
    kept = tmp_path / "cut.partial"
    child = subprocess.Popen(
        [sys.executable, "-m", "rwlab.cli", *ARGS, "--out", str(out)],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    end = time.monotonic() + 300
    while len(list(kept.glob("batch-*.json"))) < 1:
        assert child.poll() is None and time.monotonic() < end, child.communicate()
        time.sleep(0.05)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=120)
    assert child.returncode == 130, err
    assert "campaign stopped:" in err and "--resume" in err and "Traceback" not in err, err
    said = [
        line
        for line in err.splitlines()
        if line.strip() and not line.startswith(("pd campaign", "12 runs of"))
    ]  # one line after the progress: the signal, what is kept, how to go on
    assert len(said) == 1 and said[0].startswith("interrupted (SIGTERM; campaign stopped:"), err
    assert not out.exists()  # nothing that looks like a complete campaign
    n_kept = sum(len(json.loads(p.read_text())["rows"]) for p in kept.glob("batch-*.json"))
    assert 1 <= n_kept < 12

    again = _rwlab(*ARGS, "--out", out)  # without --resume: refused, the runs kept
    assert again.exit_code == 2 and "--resume" in again.output and kept.exists()
    resumed = _rwlab(*ARGS, "--out", out, "--resume")
    assert resumed.exit_code == 0, resumed.output
    assert not kept.exists()
    assert pq.read_table(out / "results.parquet") == pq.read_table(whole / "results.parquet")
    assert _budget(out) == _budget(whole)
    execution = json.loads((out / "budget.json").read_text())["execution"]
    assert 1 <= execution["resumed_runs"] < 12
    assert "kept from an interrupted campaign" in (out / "report.html").read_text()


def test_resume_refuses_another_campaigns_runs(tmp_path):
    c = Campaign(SMALLSAT, load_dispersions(), 100.0, "pd", seed=1, runs=4)
    store = RunStore(tmp_path / "o.partial", c)
    store.create()
    other = Campaign(SMALLSAT, load_dispersions(), 100.0, "pd", seed=2, runs=4)
    with pytest.raises(ConfigError, match="another campaign"):
        RunStore(tmp_path / "o.partial", other).check()
    r = _rwlab(
        *("attitude", "montecarlo", "--scenario", "geo-smallsat", "--controller", "pd"),
        *("--runs", 4, "--duration", 100, "--seed", 2, "--out", tmp_path / "o", "--resume"),
    )
    assert r.exit_code == 2 and "another campaign" in r.output
    r = _rwlab(
        *("attitude", "montecarlo", "--scenario", "geo-smallsat", "--runs", 4),
        *("--duration", 100, "--out", tmp_path / "new", "--resume"),
    )
    assert r.exit_code == 2 and "nothing to resume" in r.output


def test_kept_rows_read_back_exactly(tmp_path):
    c = Campaign(SMALLSAT, load_dispersions(), 100.0, "pd", seed=1, runs=3)
    store = RunStore(tmp_path / "s", c)
    store.create()
    rows = [{"run": 0, "seed": 7, "x": 0.1 + 0.2, "settling_time_s": None, "ok": True}]
    store.add(rows)
    assert store.rows() == {0: rows[0]}


@pytest.mark.parametrize("runs", ["1e9", "1000000000", "-1", "0", "2.5", "nan"])
def test_impossible_run_counts_are_refused_before_starting(tmp_path, runs):
    start = time.monotonic()
    r = _rwlab(
        *("attitude", "montecarlo", "--runs", runs, "--duration", 100),
        *("--out", tmp_path / "o"),
    )
    assert r.exit_code == 2 and r.output.startswith("error:") and r.output.count("\n") == 1
    assert time.monotonic() - start < 10 and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_a_killed_worker_is_retried_and_the_retry_reported():
    c = Campaign(SMALLSAT, load_dispersions(), 200.0, "pd", seed=11, runs=8)
    expected = run_batch(list(enumerate(run_seeds(11, 8))), c)
    killed: list[int] = []
    execution = Execution()
    with dask_client(2) as client:
        pids = client.run(os.getpid)

        def kill_a_busy_worker(done):
            if killed:
                return
            busy = [w for w, keys in client.processing().items() if keys]
            assert busy, "nothing in flight to lose"
            killed.append(pids[busy[0]])
            os.kill(killed[0], signal.SIGKILL)  # a worker process this test started

        rows = run_campaign(c, client, progress=kill_a_busy_worker, execution=execution)
    assert rows == expected
    report = execution.to_dict()
    assert report["runs_flown_again"] >= 1 and report["retried_runs"]
    assert all(entry["reason"].startswith("worker lost") for entry in report["retry_log"])
    lost = report["lost_workers"]
    assert lost and set(lost[0]["running_runs"]) <= set(report["retried_runs"])
    assert set(report["retried_runs"]) <= set(range(8))
