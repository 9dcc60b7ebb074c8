"""Every JSON file rwlab writes validates against the schema shipped in the package.

The files are made by the commands a user runs (small, fast cases); the schemas
are read from ``rwlab.schemas``. Also the reading rule for versions, and the one
owner of ``model.json`` on both sides (study writes, wheel reads).
"""

import json

import jsonschema
import pytest
from click.testing import CliRunner

from rwlab import datasets, schemas
from rwlab.cli import main
from rwlab.errors import FileFormatError
from rwlab.ident.model_file import WheelModelFile
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel import IdentifiedWheel


def _valid(path, name):
    payload = json.loads(path.read_text())
    jsonschema.validate(payload, schemas.schema(name), cls=jsonschema.Draft202012Validator)
    return payload


def _rwlab(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def study_out(identified_prbs):
    """``rwlab identify``'s folder for a 20-minute PRBS record of the simulated wheel."""
    return identified_prbs[1]


@pytest.mark.parametrize("name", schemas.NAMES)
def test_every_shipped_schema_is_a_valid_2020_12_schema(name):
    sch = schemas.schema(name)
    jsonschema.Draft202012Validator.check_schema(sch)
    version = sch["x-rwlab-version"]
    assert sch["$id"].endswith(f":{name}:{version}")
    assert sch["x-rwlab-format"].endswith(f"/{version}")


def test_identify_writes_a_valid_model_and_study(study_out):
    model = _valid(study_out / "model.json", "model")
    study = _valid(study_out / "study.json", "study")
    assert model["structure"] == study["chosen"]["structure"]


def test_model_json_has_one_owner_on_both_sides(study_out):
    path = study_out / "model.json"
    owner = WheelModelFile.load(path)
    assert owner.to_dict() == json.loads(path.read_text())  # lossless round trip
    wheel = IdentifiedWheel.from_json(path, model="linear")
    assert wheel.model.to_dict() == owner.model.to_dict()
    assert (wheel.u0, wheel.y0) == (owner.input.offset, owner.output.offset)
    assert wheel.accel_limit_rpm_s == owner.accel_limit_rpm_s


@pytest.mark.slow  # 12 s in the quick lane (-n 2, shared machine)
def test_fleet_identification_writes_a_valid_fleet_json(tmp_path):
    fleet = tmp_path / "fleet"
    fleet.mkdir()
    dryer = datasets.get("dryer")
    dryer.write(fleet / "unit_a.csv")
    dryer._with(dryer.u, dryer.y * 2.0 + 1.0).write(fleet / "unit_b.csv")
    _rwlab("identify", fleet, "--preprocess", "detrend", "--workers", 1, "--out", tmp_path / "o")
    summary = _valid(tmp_path / "o" / "fleet.json", "fleet")
    assert summary["identified"] == 2
    _valid(tmp_path / "o" / "unit_a" / "study.json", "study")


def test_attitude_simulate_and_ltr_write_valid_metrics_and_sigma(tmp_path):
    _rwlab("attitude", "simulate", "--scenario", "geo-smallsat", "--controller", "lqg",
           "--duration", 120, "--out", tmp_path / "sim")  # fmt: skip
    assert _valid(tmp_path / "sim" / "metrics.json", "metrics")["config"]["controller"] == "lqg"
    _rwlab("attitude", "ltr", "--scenario", "geo-comsat", "--rho", 1, "--rho", 0.01,
           "--out", tmp_path / "ltr")  # fmt: skip
    _valid(tmp_path / "ltr" / "sigma.json", "sigma")


def test_montecarlo_writes_a_valid_budget(tmp_path):
    _rwlab("attitude", "montecarlo", "--scenario", "geo-smallsat", "--runs", 2,
           "--duration", 120, "--workers", 1, "--seed", 3, "--out", tmp_path)  # fmt: skip
    assert _valid(tmp_path / "budget.json", "budget")["campaign"]["runs"] == 2


def test_diagnose_writes_a_valid_diagnosis(study_out, tmp_path):
    run_experiment(ExperimentConfig(duration=300, seed=2), tmp_path / "r.mcap")
    _rwlab("diagnose", tmp_path / "r.mcap", "--model", study_out / "model.json",
           "--out", tmp_path / "d", "--rules")  # fmt: skip
    _valid(tmp_path / "d" / "diagnosis.json", "diagnosis")
    _rwlab("diagnose", tmp_path / "r.mcap", "--model", study_out / "model.json",
           "--out", tmp_path / "g")  # fmt: skip
    _valid(tmp_path / "g" / "fdi.json", "fdi_diagnosis")


@pytest.mark.slow
def test_the_demo_writes_valid_files_everywhere(quick_demo):
    _valid(quick_demo / "summary.json", "demo")
    _valid(quick_demo / "identification" / "model.json", "model")
    _valid(quick_demo / "identification" / "study.json", "study")
    _valid(quick_demo / "attitude" / "metrics.json", "compare")
    _valid(quick_demo / "attitude" / "sigma.json", "sigma")


# -- the reading rule ------------------------------------------------------------------


def test_reading_rule_upgrades_older_refuses_newer_and_other_kinds():
    up = {1: lambda d: {**d, "b": d["a"] * 2}}
    assert schemas.read_versioned({"a": 3}, "X", 2, up) == {"a": 3, "b": 6, "format": "rwlab.X/2"}
    old = {"format": "rwlab.X/1", "a": 1}
    schemas.read_versioned(old, "X", 2, up)
    assert old == {"format": "rwlab.X/1", "a": 1}  # not modified
    with pytest.raises(FileFormatError, match=r"newer.*update rwlab"):
        schemas.read_versioned({"format": "rwlab.X/3"}, "X", 2, up)
    with pytest.raises(FileFormatError, match="not an rwlab X"):
        schemas.read_versioned({"format": "rwlab.Y/1"}, "X", 2, up)
    with pytest.raises(FileFormatError, match="no upgrade"):
        schemas.read_versioned({"format": "rwlab.X/1"}, "X", 2, {})


def test_a_newer_model_file_is_refused_with_what_to_do(study_out, tmp_path):
    d = json.loads((study_out / "model.json").read_text())
    (tmp_path / "m.json").write_text(json.dumps({**d, "format": "rwlab.WheelModel/3"}))
    with pytest.raises(FileFormatError, match="update rwlab"):
        IdentifiedWheel.from_json(tmp_path / "m.json")
    (tmp_path / "n.json").write_text(json.dumps({k: v for k, v in d.items() if k != "format"}))
    with pytest.raises(FileFormatError, match="not an rwlab wheel model"):
        WheelModelFile.load(tmp_path / "n.json")


@pytest.mark.parametrize(
    ("args", "name"),
    [
        (["arx", "dryer", 2, 2, 3], "polymodel"),
        (["armax", "dryer", 2, 2, 1, 3], "polymodel"),
        (["n4sid", "dryer", 2], "ssmodel"),
        (["spa", "dryer"], "frequency_response"),
        (["impulse", "dryer", "--n", 20], "fir"),
    ],
)
def test_ident_save_writes_valid_model_files(tmp_path, args, name):
    _rwlab("ident", *args, "--save", tmp_path / "m.json")
    _valid(tmp_path / "m.json", name)
