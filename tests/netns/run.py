"""Run a Python file inside a private network namespace (loopback only), for multicast tests.

Multicast tests must not reach the host's network nor meet another test's
group: ``unshare -n`` gives the process its own network stack with only
``lo``. Needs root (or user namespaces); the caller skips otherwise.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SRC = str(Path(__file__).resolve().parents[2] / "src")


def available() -> bool:
    """Whether a private network namespace can be made here."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, timeout=10, check=False)
    return probe.returncode == 0


def run_isolated(script: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run ``python script args`` in a fresh network namespace with only loopback up."""
    if not available():
        pytest.skip("no private network namespace (unshare -n needs root)")
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = ["unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$0" "$@"', sys.executable]
    return subprocess.run(
        [*cmd, str(script), *args], capture_output=True, text=True, timeout=timeout, env=env
    )
