import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.signal import lfilter

from rwlab.cli import main
from rwlab.data import IOData
from rwlab.ident import PolyModel


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_arx_on_the_bundled_dryer_prints_json_with_validation():
    r = run("ident", "arx", "dryer", "2", "2", "3", "--detrend", "constant", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["model"]["structure"] == "ARX223" and out["model"]["Ts"] == 0.08
    assert out["validation"]["fit_percent"] > 80


def test_ar_command_fits_the_output_alone(tmp_path):
    r = np.random.default_rng(3)
    y = lfilter([1], [1, -1.5, 0.7], r.standard_normal(3000))
    IOData(r.standard_normal(3000), y, 0.5).write(tmp_path / "ts.csv")
    out = run("ident", "ar", str(tmp_path / "ts.csv"), "2", "--approach", "ls", "--json")
    assert out.exit_code == 0, out.output
    result = json.loads(out.output)
    assert result["model"]["structure"] == "AR2" and result["model"]["B"] == []
    assert np.allclose(result["model"]["A"], [1, -1.5, 0.7], atol=0.05)
    assert result["validation"]["residuals_white"]
    assert "ar (least squares)" in result["model"]["report"]["method"]
    bad = run("ident", "ar", str(tmp_path / "ts.csv"), "5000")
    assert bad.exit_code == 2 and "too few samples" in bad.output


def test_delay_command_reports_the_dryer_delay():
    r = run("ident", "delay", "dryer", "--detrend", "constant", "--json")
    assert r.exit_code == 0 and json.loads(r.output)["nk"] == 3


def test_estimators_recover_a_system_from_a_csv_file(tmp_path):
    rng = np.random.default_rng(0)
    u = rng.standard_normal(1500)
    y = lfilter([0, 1.0, 0.5], [1, -0.7], u) + 0.01 * rng.standard_normal(1500)
    path = IOData(u, y, 0.2, input_names=["cmd"], output_names=["speed"]).write(tmp_path / "r.csv")
    r = run("ident", "oe", str(path), "2", "1", "1", "--json", "--split", "1")
    assert r.exit_code == 0, r.output
    model = json.loads(r.output)["model"]
    assert np.allclose(model["B"], [0, 1.0, 0.5], atol=0.01) and model["Ts"] == 0.2


def test_saved_model_loads_and_is_not_overwritten_without_force(tmp_path):
    target = tmp_path / "m.json"
    assert (
        run(
            "ident",
            "armax",
            "dryer",
            "2",
            "2",
            "1",
            "3",
            "--detrend",
            "constant",
            "--save",
            str(target),
        ).exit_code
        == 0
    )
    assert PolyModel.load(target).structure == "ARMAX2213"
    again = run("ident", "armax", "dryer", "2", "2", "1", "3", "--save", str(target))
    assert again.exit_code == 2 and "exists" in again.output
    assert (
        run("ident", "arx", "dryer", "2", "2", "3", "--save", str(target), "--force").exit_code == 0
    )
    assert PolyModel.load(target).structure == "ARX223"


def test_struct_selects_an_order_for_the_dryer():
    r = run(
        "ident",
        "struct",
        "dryer",
        "--detrend",
        "constant",
        "--na",
        "1:4",
        "--nb",
        "1:4",
        "--criterion",
        "mdl",
        "--json",
    )
    assert r.exit_code == 0
    best = json.loads(r.output)["best"]
    assert best["nk"] == 3 and 1 <= best["na"] <= 4


def test_errors_are_one_line_messages_with_status_2(tmp_path):
    r = run("ident", "arx", str(tmp_path / "missing.csv"), "2", "2", "1")
    assert r.exit_code == 2 and r.output.startswith("error: no such data file")
    plain = tmp_path / "plain.csv"
    plain.write_text("u,y\n1,2\n3,4\n")
    r = run("ident", "arx", str(plain), "1", "1", "1")
    assert r.exit_code == 2 and "Ts" in r.output


@pytest.mark.parametrize(
    "cmd",
    [
        [],
        ["ident"],
        ["ident", "arx"],
        ["ident", "armax"],
        ["ident", "oe"],
        ["ident", "bj"],
        ["ident", "ar"],
        ["ident", "delay"],
        ["ident", "struct"],
        ["datasets"],
    ],
)
def test_every_command_has_help(cmd):
    r = run(*cmd, "--help")
    assert r.exit_code == 0 and "Usage:" in r.output


def test_an_estimator_warning_is_one_line_on_stderr_and_json_stays_clean():
    args = "ident oe cascaded_tanks_est 4 4 1 --detrend constant --split 1 --max-iter 2 --json"
    r = CliRunner().invoke(main, args.split())
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["model"]["report"]["termination"] == "maximum iterations reached"
    lines = r.stderr.strip().splitlines()  # one line per warning, no file, line or source
    assert lines and all(line.startswith("warning: ") for line in lines)
    assert lines[0].startswith("warning: oe: stopped after 2 iterations")


def test_datasets_lists_every_bundled_record():
    from rwlab import datasets

    r = run("datasets")
    listed = [line.split()[0] for line in r.output.splitlines()]
    assert listed == list(datasets.NAMES)
    assert {"cascaded_tanks_est", "cascaded_tanks_val"} <= set(listed)
    assert datasets.get("cascaded_tanks_val").N == 1024
