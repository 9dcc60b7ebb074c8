import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.data import IOData
from rwlab.errors import DataError, RecordGapError
from rwlab.ident import fit_percent
from rwlab.ident.study import identification_study, physical_model
from rwlab.report.identification import FIGURES
from rwlab.signals import prbs, rate_limit
from rwlab.testbed import ExperimentConfig, RecordWriter, run_experiment
from rwlab.wheel import IdentifiedWheel
from rwlab.wheel.physics import simulate_speed_command
from tests.conftest import needs_chromium


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """`rwlab identify` on a 20-minute PRBS record of the simulated RW90 (Ts = 0.5 s)."""
    root = tmp_path_factory.mktemp("study")
    record = root / "prbs.mcap"
    run_experiment(ExperimentConfig(duration=1200, Ts=0.5, seed=5), record)
    result = CliRunner().invoke(main, ["identify", str(record), "--out", str(root / "out")])
    assert result.exit_code == 0, result.output
    return root / "out"


class _Figures(HTMLParser):
    def __init__(self):
        super().__init__()
        self.figures, self.tables, self.links, self._in = {}, set(), [], None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "figure":
            self._in = a.get("id")
        elif tag == "img" and self._in:
            self.figures[self._in] = a.get("src", "")
        elif tag == "table" and a.get("id"):
            self.tables.add(a["id"])
        for key in ("src", "href"):
            if a.get(key) and not a[key].startswith("data:"):
                self.links.append(a[key])

    def handle_endtag(self, tag):
        if tag == "figure":
            self._in = None


def test_study_picks_delay_1_and_reports_orders_fit_and_whiteness(study_dir):
    study = json.loads((study_dir / "study.json").read_text())
    assert study["delay"]["nk"] == 1
    assert set(study["delay"]["losses"]) == {str(k) for k in range(11)}
    assert [r["structure"] for r in study["orders"]] == ["ARX221", "ARX331", "ARX441", "ARX551"]
    assert all(r["fit_percent"] > 80 and r["mse"] > 0 for r in study["orders"])
    chosen = study["chosen"]
    assert chosen["structure"] == "ARX221" and chosen["fit_percent"] > 80
    assert "simplest" in chosen["reason"]
    res = study["residuals"]["ARX221"]
    assert isinstance(res["white"], bool) and 0 <= res["whiteness_p"] <= 1
    assert {o["structure"][:2] for o in study["others"]} == {"AR", "OE", "BJ"}


def test_report_has_every_figure_of_the_paper_and_no_external_links(study_dir):
    parser = _Figures()
    parser.feed((study_dir / "report.html").read_text())
    assert set(FIGURES) <= set(parser.figures)
    assert all(
        src.startswith("data:image/png;base64,") and len(src) > 2000
        for src in parser.figures.values()
    )
    assert {"table2-orders", "table3-others", "table-continuous"} <= parser.tables
    assert parser.links == []  # nothing to fetch: it opens offline


def test_model_json_is_physical_and_simulates_the_wheel(study_dir):
    info = json.loads((study_dir / "model.json").read_text())
    assert info["structure"] == "ARX221" and info["Ts"] == 0.5
    assert info["saturation"] == {
        "speed_rpm": 7800.0,
        "accel_rpm_s": 314.0,
        "source": "the record's wheel parameters",
    }
    wheel = IdentifiedWheel.from_json(study_dir / "model.json", model="linear")  # copied limits
    u = rate_limit(prbs(600, 0.5, 5000, 5, 60, seed=42), 314, 0.5, initial=0.0)
    truth = simulate_speed_command(u, 0.5, seed=42)
    assert fit_percent(truth, wheel.simulate(u)) > 85  # a new input, in rpm
    assert np.max(np.abs(wheel.simulate(np.full(200, 7800.0)))) <= 7800.0
    steps = np.diff(wheel.simulate(np.full(60, -7000.0)))
    assert np.max(np.abs(steps)) <= 314 * 0.5 + 1e-9  # the acceleration limit holds


def test_physical_model_maps_normalised_results_back_exactly():
    r = np.random.default_rng(0)
    u = 3000 * r.uniform(-1, 1, 800)
    y = np.convolve(u, [0, 0.3, 0.2])[:800] * 0.9 + 40 * r.standard_normal(800) + 100
    data = IOData(u, y, 0.5, input_names=["cmd"], output_names=["speed"])
    result = identification_study(data, orders=(2, 3), nk_max=3)
    info = physical_model(result)
    phys = IdentifiedWheel(
        result.chosen.__class__.from_dict(info["model"]),
        input_offset=info["input"]["offset"],
        output_offset=info["output"]["offset"],
        speed_limit_rpm=1e9,
        accel_limit_rpm_s=1e12,
    )
    norm = result.chosen.simulate(result.data.u[:, 0])
    expected = result.data.trend.output_to_physical(norm, result.data.time)
    phys.reset(speed_rpm=info["output"]["offset"] + 0.0)
    phys_out = [phys.step(c) for c in u]
    assert np.allclose(phys_out[:-1], expected[1:], rtol=1e-6, atol=1e-6)


def test_identify_works_on_any_siso_record_like_the_hair_dryer(tmp_path):
    r = CliRunner().invoke(
        main, ["identify", "dryer", "--preprocess", "detrend", "--out", str(tmp_path)]
    )
    assert r.exit_code == 0, r.output
    study = json.loads((tmp_path / "study.json").read_text())
    assert study["delay"]["nk"] == 3 and study["chosen"]["fit_percent"] > 70
    again = CliRunner().invoke(main, ["identify", "dryer", "--out", str(tmp_path)])
    assert again.exit_code == 2 and "exist" in again.output


def test_bad_inputs_give_clear_errors(tmp_path):
    short = IOData(
        np.random.default_rng(1).standard_normal(60),
        np.random.default_rng(2).standard_normal(60),
        0.5,
    )
    with pytest.raises(DataError, match="too short"):
        identification_study(short)
    plain = tmp_path / "plain.csv"
    plain.write_text("u,y\n" + "\n".join(f"{i % 7},{i % 5}" for i in range(300)))
    r = CliRunner().invoke(main, ["identify", str(plain), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "Ts" in r.output
    gap = tmp_path / "gap.mcap"
    with RecordWriter(gap, {"Ts": 0.5, "mode": "speed"}) as w:
        w.write("/command", {"t": 0.0, "sequence": 1, "mode": "speed", "setpoint": 10.0})
        for i, t in enumerate(np.concatenate([np.arange(0, 100, 0.1), np.arange(120, 600, 0.1)])):
            w.write(
                "/telemetry",
                {
                    "t": t,
                    "speed_rpm": 0.0,
                    "current_a": 0.0,
                    "mode": "SPEED",
                    "fault_active": False,
                    "speed_limited": False,
                    "sequence_echo": 1,
                    "counter": i % 256,
                },
            )
    from rwlab.ident.study import load_study_data

    with pytest.raises(RecordGapError, match="gap"):
        load_study_data(str(gap))


@pytest.mark.slow
@needs_chromium
def test_report_renders_in_headless_chromium_without_network(study_dir, browser):
    driver = browser(offline=True)
    driver.get((study_dir / "report.html").as_uri())
    widths = driver.execute_script(
        "return Array.from(document.images).map(i => i.complete ? i.naturalWidth : 0)"
    )
    assert len(widths) >= len(FIGURES) and min(widths) > 100
    assert re.search(r"Chosen model: ARX221", driver.page_source)
