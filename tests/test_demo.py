import json
from html.parser import HTMLParser

import pytest
from click.testing import CliRunner

from rwlab._io import output_folder
from rwlab.cli import main
from rwlab.demo import DEMO_FILES
from rwlab.wheel import RW90
from tests.conftest import needs_chromium


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links = []

    def handle_starttag(self, tag, attrs):
        href = dict(attrs).get("href")
        if href:
            self.links.append(href)


@pytest.fixture
def demo_dir(quick_demo):
    return quick_demo


@pytest.mark.slow
def test_demo_writes_every_output_and_they_agree(demo_dir):
    summary = json.loads((demo_dir / "summary.json").read_text())
    study = json.loads((demo_dir / "identification" / "study.json").read_text())
    model = json.loads((demo_dir / "identification" / "model.json").read_text())
    metrics = json.loads((demo_dir / "attitude" / "metrics.json").read_text())
    # the model flown in the attitude report is the one the identification chose
    assert (
        summary["chosen_model"]["structure"] == study["chosen"]["structure"] == model["structure"]
    )
    assert summary["chosen_model"]["fit_percent"] == pytest.approx(study["chosen"]["fit_percent"])
    assert summary["chosen_model"]["delay_nk"] == study["delay"]["nk"] == 1
    for ctl in ("lqr", "lqg", "lqg_ltr", "lqg_identified_wheel"):
        assert summary["controllers"][ctl]["steady_max_error_deg"] == pytest.approx(
            metrics[ctl]["steady_max_error_deg"]
        )
    assert summary["attitude_wheel_model"] == "identification/model.json"
    assert [r["name"] for r in summary["records"]] == [
        "speed_steps",
        "acceleration",
        "prbs",
        "chirp",
    ]
    loss = RW90.frame_loss_rate  # the realistic twin loses a frame now and then, on purpose
    assert all(
        r["lost_frames"] <= 3 + 5 * loss * r["telemetry"] and r["telemetry"] > r["commands"]
        for r in summary["records"]
    )
    hil = json.loads((demo_dir / "hil" / "metrics.json").read_text())
    assert summary["hil"]["steady_max_error_deg"] == pytest.approx(hil["steady_max_error_deg"])
    assert summary["hil"]["lost_commands"] == 0 < summary["hil"]["commands_sent"]
    parser = _Links()
    parser.feed((demo_dir / "index.html").read_text())
    files = [link.partition("#")[0] for link in parser.links]  # a link to a page's section
    assert files and all((demo_dir / f).exists() for f in files)


@pytest.mark.slow
def test_a_rerun_replaces_a_demo_but_never_a_foreign_folder(demo_dir, tmp_path):
    # the Quick start run twice: the old demo is accepted for replacement (on success only)
    with pytest.raises(RuntimeError), output_folder(demo_dir, DEMO_FILES, replace_previous=True):
        raise RuntimeError("the new demo failed")
    assert (demo_dir / "index.html").exists()
    (tmp_path / "thesis.tex").write_text("mine")
    r = CliRunner().invoke(main, ["demo", "--quick", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "not a previous demo" in r.output
    assert (tmp_path / "thesis.tex").read_text() == "mine"


@pytest.mark.slow
@needs_chromium
def test_demo_pages_open_offline_in_headless_chromium(demo_dir, browser):
    driver = browser(offline=True)
    driver.get((demo_dir / "index.html").as_uri())
    assert "Identified wheel model" in driver.find_element("id", "summary").text
    for page in ("identification/report.html", "attitude/report.html"):
        driver.get((demo_dir / page).as_uri())
        widths = driver.execute_script(
            "return Array.from(document.images).map(i => i.complete ? i.naturalWidth : 0)"
        )
        assert len(widths) >= 5 and min(widths) > 100, page


@pytest.mark.slow
def test_the_console_says_which_controller_is_the_ideal_bound(demo_dir):
    lines = (demo_dir.parent / "console.txt").read_text().splitlines()
    flagged = [line.split()[0] for line in lines if "the ideal bound" in line]
    assert flagged == ["lqr"]  # the only one fed the true state; the LQGs fly on sensors


def test_the_demos_model_diagnoses_its_own_records(demo_dir, tmp_path):
    # the model carries the healthy reference of the record it was identified on, as
    # rwlab identify's does, so the README's next step (diagnose) takes it: the demo's own
    # healthy PRBS record is healthy against it
    model = demo_dir / "identification" / "model.json"
    assert "healthy_reference" in json.loads(model.read_text())
    out = tmp_path / "diag"
    record = demo_dir / "records" / "prbs.mcap"
    result = CliRunner().invoke(
        main, ["diagnose", str(record), "--model", str(model), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert json.loads((out / "fdi.json").read_text())["events"] == []
