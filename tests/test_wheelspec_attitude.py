"""The attitude loop flies the wheel model's spec: its saturation follows the wheel file,
and a wheel model that cannot deliver what the scenario needs is refused."""

from __future__ import annotations

import json
import re
import warnings
from importlib import resources

import pytest
from click.testing import CliRunner

from rwlab.attitude.control import fly
from rwlab.attitude.scenario import load_scenario
from rwlab.attitude.wheel_fit import check_wheel_fit, shortfalls
from rwlab.cli import main
from rwlab.errors import ConfigError, FormatWarning
from rwlab.wheelspec import WheelSpec

SIZED = {"nrwa-t6": "geo-comsat", "rw90": "geo-smallsat", "rw-0.01": "geo-cubesat"}


def _spec_file(tmp_path, name: str, max_torque: float):
    text = (resources.files("rwlab.wheelspec") / "presets" / f"{name}.toml").read_text("utf-8")
    text, n = re.subn(
        r"max_torque_nm = \{ value = [^,]+,",
        f"max_torque_nm = {{ value = {max_torque!r},",
        text,
    )
    assert n == 1
    path = tmp_path / f"{name}-{max_torque:g}.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("name", list(SIZED))
def test_each_scenario_flies_its_wheel_model_and_fits(name):
    sc = load_scenario(SIZED[name])
    spec = WheelSpec.load(name)
    assert sc.wheels.wheel_spec == spec
    assert (sc.wheels.inertia, sc.wheels.max_torque) == (spec.inertia_kg_m2, spec.max_torque_nm)
    assert sc.wheels.max_momentum == pytest.approx(spec.momentum_capacity_nms)
    assert shortfalls(sc) == []


@pytest.mark.parametrize("name", list(SIZED))
def test_the_loops_saturation_follows_the_wheel_files_max_torque(name, tmp_path):
    spec = WheelSpec.load(name)
    peaks = {}
    for torque in (spec.max_torque_nm, spec.max_torque_nm / 2):
        sc = load_scenario(
            SIZED[name], **{"wheels.spec": str(_spec_file(tmp_path, name, torque))}
        ).with_(
            **{  # a disturbance beyond any wheel's torque: the commands hit the limit
                "spacecraft.disturbances.constant_torque": (3 * spec.max_torque_nm, 0.0, 0.0),
                "momentum.unloading": False,
            }
        )
        assert sc.wheels.max_torque == torque
        _, m = fly(sc, "lqr", duration=60.0, seed=1)
        peaks[torque] = m["torque_peak_Nm"]
    for torque, peak in peaks.items():
        assert peak == pytest.approx(torque, rel=1e-12)


def test_a_mismatch_is_one_line_naming_both_numbers(tmp_path):
    sc = load_scenario("geo-comsat", **{"wheels.spec": "rw90"})
    with pytest.raises(ConfigError) as err:
        check_wheel_fit(sc)
    text = str(err.value)
    assert (
        "\n" not in text and "0.1 N·m" in text and "0.0184 N·m" in text
    )  # 0.0138 / 0.75 (pyramid)
    assert "rw90 spec" in text and "geo-comsat" in text and "force_wheel=True" in text
    forced = check_wheel_fit(sc, force=True)
    assert [f.split(" ")[0] for f in forced] == ["FORCED:"] * 3


def test_an_old_scenario_file_with_its_own_torque_reads_with_a_warning(tmp_path):
    path = tmp_path / "old.toml"
    path.write_text('[scenario]\nbase = "geo-comsat"\n[wheels]\nmax_torque = 0.2\n')
    with pytest.warns(FormatWarning, match="wheels.spec"):
        sc = load_scenario(str(path))
    assert sc.wheels.max_torque == 0.2
    new = tmp_path / "new.toml"
    new.write_text('[scenario]\nbase = "geo-comsat"\n[wheels]\nspec = "rw90"\naxes = "pyramid"\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert (
            load_scenario(str(new)).wheels.max_torque == 0.0138
        )  # the rw90 spec's: 314 rpm/s × 4.2e-4 kg·m²


@pytest.mark.slow
def test_an_rw90_model_on_geo_comsat_exits_2_and_force_flies_it(tmp_path):
    record, folder = tmp_path / "rw90.mcap", tmp_path / "id"
    args = ["experiment", "--wheel", "rw90", "--duration", "400", "--seed", "4"]
    assert CliRunner().invoke(main, [*args, "--out", str(record)]).exit_code == 0
    r = CliRunner().invoke(main, ["identify", str(record), "--out", str(folder)])
    assert r.exit_code == 0, r.output
    model = folder / "model.json"
    sim = ["attitude", "simulate", "--scenario", "geo-comsat", "--wheel-model", str(model)]
    sim += ["--controller", "lqr", "--duration", "60"]
    r = CliRunner().invoke(main, [*sim, "--out", str(tmp_path / "a")])
    assert r.exit_code == 2
    line = r.output.strip().splitlines()[-1]
    assert "needs 0.1 N·m" in line and "model.json" in line and "rw90" in line
    # --force only overwrites outputs: the wheel is still refused
    r = CliRunner().invoke(main, [*sim, "--out", str(tmp_path / "b"), "--force"])
    assert r.exit_code == 2 and "--force-wheel" in r.output
    r = CliRunner().invoke(main, [*sim, "--out", str(tmp_path / "b"), "--force-wheel"])
    assert r.exit_code == 0, r.output
    config = json.loads((tmp_path / "b" / "metrics.json").read_text())["config"]
    assert config["wheel_forced"] and config["wheel_spec"]["name"] == "rw90"
    html = (tmp_path / "b" / "report.html").read_text()
    assert html.index("FORCED") < html.index("table-metrics")


def test_a_far_too_large_wheel_is_refused_too():
    # a T6 on the 12U cubesat: 0.31 N·m against the 0.2 mN·m it needs (1550×), and its
    # 3 mN·m Coulomb drag above that need; flown, it pointed 180° off without a word
    from rwlab.attitude.scenario import load_scenario
    from rwlab.attitude.wheel_fit import check_wheel_fit
    from rwlab.errors import ConfigError

    sc = load_scenario("geo-cubesat").with_(**{"wheels.spec": "nrwa-t6"})
    with pytest.raises(ConfigError, match=r"far too large for geo-cubesat.*1550× the 0\.0002 N·m"):
        check_wheel_fit(sc)
    forced = check_wheel_fit(sc, force=True)
    assert len(forced) == 2 and all(line.startswith("FORCED:") for line in forced)
    for spec, scenario in SIZED.items():  # each scenario flies its own class
        assert check_wheel_fit(load_scenario(scenario).with_(**{"wheels.spec": spec})) == []
