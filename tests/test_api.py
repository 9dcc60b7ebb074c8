"""The workflows at the top: importable from ``rwlab``, lazily, and they run."""

from __future__ import annotations

import subprocess
import sys

import pytest

import rwlab
from rwlab.errors import ConfigError

NAMES = ("WheelSpec", "identify", "diagnose", "simulate", "montecarlo", "hil")


def test_every_workflow_is_reached_from_rwlab():
    for name in NAMES:
        assert callable(getattr(rwlab, name)) and name in rwlab.__all__
    with pytest.raises(AttributeError):
        rwlab.simulatee  # noqa: B018


def test_dir_lists_the_public_names_only():
    """dir(rwlab) is the API (tab completion): the workflows before their first use, and
    not the modules rwlab imports for itself (it listed importlib, sys, types)."""
    names = dir(rwlab)
    assert names == sorted(rwlab.__all__)
    assert not {"importlib", "sys", "types", "lazy_exports", "errors"} & set(names)
    assert {"montecarlo", "simulate", "WheelSpec"} <= set(names)
    code = "import rwlab; print(' '.join(dir(rwlab)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == sorted(rwlab.__all__)  # in a fresh interpreter too


def test_diagnose_and_hil_are_the_workflows_and_still_their_packages():
    import rwlab.diagnose
    import rwlab.hil.run  # binds the packages on rwlab

    assert callable(rwlab.diagnose) and callable(rwlab.hil)
    assert rwlab.diagnose.Diagnoser.__name__ == "Diagnoser"
    assert rwlab.hil.run.HilConfig.__name__ == "HilConfig"
    assert "fault" in rwlab.diagnose.__doc__


def test_import_rwlab_loads_no_workflow():
    code = "import sys, rwlab; print(any(m.startswith('rwlab.workflows') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_python_errors_name_python_arguments_and_the_cli_its_flags():
    """A Python caller is told force_wheel=True / salvage=True, not the command line's
    --force-wheel / --salvage; the command line translates them (cli._common.FLAGS)."""
    from rwlab.cli._common import _flags
    from rwlab.testbed.record import SALVAGE_ADVICE

    with pytest.raises(ConfigError) as err:
        rwlab.simulate("geo-comsat", "lqr", duration=60.0, wheel="rw90")
    assert "force_wheel=True" in str(err.value) and "--" not in str(err.value)
    assert _flags(str(err.value)).endswith("or fly it with --force-wheel")
    assert "--" not in SALVAGE_ADVICE and "salvage=True" in SALVAGE_ADVICE
    assert _flags(f"x: {SALVAGE_ADVICE} (every output") == (
        "x: pass --salvage to read up to the damage (every output"
    )


def test_simulate_flies_the_scenarios_wheel_and_refuses_a_misfit():
    run, metrics = rwlab.simulate("geo-cubesat", "lqr", duration=60.0, seed=1)
    assert metrics["wheel_forced"] == [] and run.t[-1] == pytest.approx(60.0)
    with pytest.raises(ConfigError, match=r"needs 0\.1 N·m"):
        rwlab.simulate("geo-comsat", "lqr", duration=60.0, wheel="rw90")
    _, forced = rwlab.simulate("geo-comsat", "lqr", duration=60.0, wheel="rw90", force_wheel=True)
    assert forced["wheel_forced"][0].startswith("FORCED: geo-comsat needs 0.1 N·m")
    assert rwlab.WheelSpec.load("rw-0.01").max_torque_nm == 0.001
