"""Outputs that clean up after themselves (issue 45, item 3).

A run killed with SIGKILL cannot clean up: its staging folder (``.OUT.partial-PID``)
and lock file (``.OUT.lock``) stay. The next run on the same output removes them,
or restores the previous output a killed publish had moved away, and says so; a
full disk while a record is written names the record.
"""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from rwlab._io import output_folder
from rwlab.cli import main
from rwlab.errors import RwlabWarning

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src")}


def _leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


def _wait_for(condition, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.02)


def _killed_holding(out: Path) -> None:
    """A process that stages a file in ``out``'s folder, killed with SIGKILL mid-run."""
    code = textwrap.dedent(
        f"""
        import sys, time
        from rwlab._io import output_folder
        with output_folder({str(out)!r}, ["a.json"], force=True) as stage:
            (stage / "a.json").write_text("half")
            print("ready", flush=True)
            time.sleep(600)
        """
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code], env=ENV, stdout=subprocess.PIPE, text=True
    )
    assert child.stdout.readline().strip() == "ready"
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=30)


def test_the_next_run_removes_a_killed_runs_staging_folder_and_lock(tmp_path):
    out = tmp_path / "o"
    _killed_holding(out)
    left = _leftovers(out)
    assert ".o.lock" in left and any(n.startswith(".o.partial-") for n in left)
    with pytest.warns(
        RwlabWarning, match=r"a killed run left files beside it: removed \.o\.partial-"
    ):
        with output_folder(out, ["a.json"]) as stage:
            (stage / "a.json").write_text("whole")
    assert (out / "a.json").read_text() == "whole" and _leftovers(out) == []


def test_a_refused_next_run_still_clears_what_a_killed_one_left(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.json").write_text("previous")
    _killed_holding(out)
    with pytest.warns(RwlabWarning), pytest.raises(FileExistsError, match="force"):
        with output_folder(out, ["a.json"]):
            pass
    assert _leftovers(out) == [] and (out / "a.json").read_text() == "previous"


def test_a_publish_killed_midway_gets_the_previous_output_back(tmp_path):
    """Killed between moving the old output aside and moving the new one in."""
    out = tmp_path / "o"
    old = tmp_path / ".o.old-99999"
    old.mkdir()
    (old / "a.json").write_text("previous")
    with pytest.warns(RwlabWarning, match="restored"), pytest.raises(RuntimeError):
        with output_folder(out, ["a.json"], force=True):
            raise RuntimeError("this run fails too")
    assert (out / "a.json").read_text() == "previous" and _leftovers(out) == []


COMMANDS = {
    "identify": ["identify", "dryer"],
    "simulate": ["attitude", "simulate", "--duration", "86400"],
    "hil": ["hil", "--duration", "60"],
}


@pytest.mark.slow  # a whole run in another process, killed, then run again
@pytest.mark.parametrize("command", ["identify", "simulate", "hil"])
def test_after_kill_9_the_next_run_leaves_nothing_stale(tmp_path, command):
    out = tmp_path / "out"
    args = [sys.executable, "-m", "rwlab.cli", *COMMANDS[command], "--out", str(out)]
    child = subprocess.Popen(args, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(lambda: any(".partial-" in n for n in _leftovers(out)) or child.poll() is not None)
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=30)
    assert child.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    assert _leftovers(out), "a killed run leaves its staging folder and lock"
    again = subprocess.run([*args, "--force"], env=ENV, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "a killed run left files beside it: removed .out.partial-" in again.stderr
    assert _leftovers(out) == []


# -- a full disk while a record is written -----------------------------------------------------


@pytest.fixture
def full_disk(monkeypatch):
    """Every record's file fails as on a full disk after its first 100 kB."""
    import rwlab.testbed.record as record

    real = record._open_locked

    def open_full(path, asked):
        fh = real(path, asked)
        write, written = fh.write, [0]

        def write_until_full(data):
            written[0] += len(data)
            if written[0] > 100_000:
                raise OSError(errno.ENOSPC, "No space left on device")  # no file named
            return write(data)

        fh.write = write_until_full
        return fh

    monkeypatch.setattr(record, "_open_locked", open_full)


def _error_lines(result) -> list[str]:
    return [line for line in result.output.splitlines() if line.startswith("error:")]


def test_a_full_disk_during_an_experiment_names_the_record(tmp_path, full_disk):
    out = tmp_path / "e.mcap"
    r = CliRunner().invoke(main, ["experiment", "--duration", "600", "--out", str(out)])
    assert r.exit_code == 2
    assert _error_lines(r) == [f"error: {out}: No space left on device"]
    assert not out.exists()


def test_a_full_disk_during_hil_names_the_record(tmp_path, full_disk):
    out = tmp_path / "h"
    r = CliRunner().invoke(main, ["hil", "--duration", "600", "--out", str(out)])
    assert r.exit_code == 2
    [line] = _error_lines(r)
    assert line.startswith(f"error: {out / 'record.mcap'}: No space left on device")
    assert "outputs are kept in" in line and not out.exists()
