"""Issue 22's nonlinear must-show, end to end through the CLI: the nonlinear model that
`rwlab identify` chooses on one unit's default 20-minute PRBS, judged by `rwlab compare
--json` on records of two other units (other seeds), one whose driver's current limit binds."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.testbed import load_record
from rwlab.wheel.physics import RW90


def _cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def heldout(tmp_path_factory):
    root = tmp_path_factory.mktemp("heldout")
    limited = root / "limited.toml"  # half the RW90's current: 314 rpm/s is out of reach
    limited.write_text('[wheel]\npreset = "rw90"\ncurrent_limit = 0.35\n')
    records = {
        "a": ("--unit", "1", "--seed", "7"),
        "b": ("--unit", "2", "--seed", "3"),
        "c": ("--unit", "5", "--seed", "11", "--wheel", str(limited)),
    }
    for name, options in records.items():
        _cli("experiment", "--out", str(root / f"{name}.mcap"), *options)
    _cli("identify", str(root / "a.mcap"), "--out", str(root / "a"), "--nonlinear-models")
    model = root / "a" / "model.json"
    scores = {
        name: json.loads(_cli("compare", str(model), str(root / f"{name}.mcap"), "--json"))
        for name in ("b", "c")
    }
    return root, json.loads(model.read_text()), scores


@pytest.mark.slow
def test_the_chosen_nonlinear_model_beats_the_linear_one_by_10_points_on_other_units(heldout):
    _, model, scores = heldout
    chosen = model["nonlinear_chosen"]
    assert chosen in ("greybox", "nlarx")  # chosen by validation fit on unit a's record
    for name, row in scores.items():
        assert set(row) >= {"linear", chosen}
        assert row[chosen]["fit_percent"] >= row["linear"]["fit_percent"] + 10, (name, row)


@pytest.mark.slow
def test_the_limited_units_current_limit_binds_and_slows_its_steps(heldout):
    root, _, _ = heldout
    # independent of any model: the records show the limit at work
    c = load_record(root / "c.mcap", outputs=("current", "acceleration"))
    b = load_record(root / "b.mcap", outputs=("current", "acceleration"))
    peak_current = np.percentile(np.abs(c.y[:, 0]), 99.5)
    assert 0.33 <= peak_current <= 0.37  # clamped at 0.35 A (± noise and offset)
    assert np.percentile(np.abs(b.y[:, 0]), 99.5) > 0.45  # the nominal unit draws more
    nominal_accel = np.percentile(np.abs(b.y[:, 1]), 99)
    assert nominal_accel == pytest.approx(RW90.max_accel_rpm_s, rel=0.05)
    assert np.percentile(np.abs(c.y[:, 1]), 99) < 0.8 * RW90.max_accel_rpm_s
