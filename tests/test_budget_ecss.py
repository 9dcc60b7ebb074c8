"""The budget by ECSS-E-ST-60-10C (issue 44, item 1), and what a campaign says of how it ran.

Truth: traces whose indices are known in closed form (a constant, a ramp, a
square wave), reference values computed independently with scipy.stats
(binom.ppf, beta.ppf) and written here as literals, the schema, and fake
scheduler event logs.
"""

from __future__ import annotations

import json
import math

import jsonschema
import numpy as np
import pytest

from rwlab import schemas
from rwlab.attitude.scenario import load_scenario
from rwlab.campaign.budget import budget, interpretations, read_budget
from rwlab.campaign.dispersions import load_dispersions
from rwlab.campaign.engine import _lost_workers
from rwlab.campaign.indices import PointingRequirement, run_indices
from rwlab.campaign.montecarlo import Execution
from rwlab.campaign.quantiles import clopper_pearson_lower, order_statistic_bound, runs_needed
from rwlab.campaign.runs import Campaign, dispersed, fly_run, run_seeds
from rwlab.errors import ConfigError, FileFormatError

SMALLSAT = load_scenario("geo-smallsat")
REQ = PointingRequirement(drift_window_s=10.0, drift_separation_s=20.0, rpe_window_s=4.0)


def _trace(e_x, dt=1.0):
    """A trace with error ``e_x`` about x only (and the same knowledge error)."""
    t = np.arange(e_x.size) * dt
    e = np.zeros((e_x.size, 3))
    e[:, 0] = e_x
    return t, e


# -- per-run indices against closed forms ------------------------------------------------


def test_a_constant_error_has_no_rpe_and_no_drift_and_its_mean_is_itself():
    t, e = _trace(np.full(200, 0.03))
    row = run_indices(t, e, e, np.abs(e[:, 0]), 50.0, REQ, 0.1)
    assert row["steady_max_error_x_deg"] == pytest.approx(0.03)
    assert row["mpe_x_deg"] == pytest.approx(0.03) and row["mke_x_deg"] == pytest.approx(0.03)
    assert row["rpe_x_deg"] == pytest.approx(0.0, abs=1e-15)
    assert row["pde_x_deg"] == pytest.approx(0.0, abs=1e-15)
    assert row["time_within_requirement_fraction"] == 1.0


def test_a_ramp_drifts_by_its_slope_times_the_separation():
    slope = 1e-4  # °/s
    t, e = _trace(slope * np.arange(300.0))
    row = run_indices(t, e, e, np.abs(e[:, 0]), 0.0, REQ, 0.1)
    assert row["pde_x_deg"] == pytest.approx(slope * 20.0, rel=1e-9)
    assert row["kde_x_deg"] == pytest.approx(slope * 20.0, rel=1e-9)
    # a centred mean of a line is the line: no RPE
    assert row["rpe_x_deg"] == pytest.approx(0.0, abs=1e-12)


def test_a_square_wave_has_its_amplitude_as_rpe_and_its_share_of_time_inside():
    x = np.where((np.arange(400) // 50) % 2 == 0, 0.05, 0.15)  # half the time above 0.1°
    t, e = _trace(x)
    row = run_indices(t, e, None, x, 0.0, REQ, 0.1)
    assert row["time_within_requirement_fraction"] == pytest.approx(0.5)
    assert row["time_quantile_error_deg"] == pytest.approx(0.15)  # P = 0.95 over time
    # the 4 s window is 5 samples (odd: centred); across a step h it reads h · 2 / 5
    assert row["rpe_x_deg"] == pytest.approx(0.04)
    assert row["knowledge_error_x_deg"] is None and row["kde_x_deg"] is None
    assert row["settled_s"] is None  # it ends outside the bound


def test_only_the_steady_window_counts():
    x = np.concatenate([np.full(100, 2.0), np.full(100, 0.01)])  # acquisition, then steady
    t, e = _trace(x)
    row = run_indices(t, e, e, x, 100.0, REQ, 0.1)
    assert row["steady_max_error_x_deg"] == pytest.approx(0.01)
    assert row["settled_s"] == 100.0
    early = run_indices(t, e, e, x, 0.0, REQ, 0.1)
    assert early["steady_max_error_x_deg"] == pytest.approx(2.0)


def test_acquisition_is_the_first_entry_and_settling_the_end_of_the_last_miss():
    x = np.concatenate([np.full(100, 2.0), np.full(400, 0.01), np.full(10, 0.3), np.full(90, 0.01)])
    t, e = _trace(x)
    row = run_indices(t, e, e, x, 200.0, REQ, 0.1)
    assert row["acquired_s"] == 100.0  # acquisition ends before the window (200 s)
    assert row["settled_s"] == 510.0  # a miss in steady state, not a late acquisition
    never = run_indices(t, e, e, np.full(t.size, 0.5), 200.0, REQ, 0.1)
    assert never["acquired_s"] is None and never["settled_s"] is None


def test_a_drift_window_longer_than_the_steady_window_is_none_not_zero():
    t, e = _trace(np.full(20, 0.01))
    row = run_indices(t, e, e, np.abs(e[:, 0]), 0.0, REQ, 0.1)
    assert row["pde_x_deg"] is None and row["kde_x_deg"] is None


@pytest.mark.parametrize(
    "kw",
    [
        {"probability": 1.0},
        {"confidence": 0.0},
        {"interpretation": "average"},
        {"rpe_window_s": 0.0},
        {"ape_deg": -0.1},
        {"drift_separation_s": math.nan},
    ],
)
def test_bad_requirements_are_config_errors(kw):
    with pytest.raises(ConfigError):
        PointingRequirement(**kw)


# -- confidence arithmetic against independent reference values --------------------------


def test_order_statistic_ranks_and_clopper_pearson_match_scipy_reference_values():
    """Literals from scipy.stats (binom.ppf(0.95, n, p) + 1; beta.ppf(0.05, k, n − k + 1))."""
    assert order_statistic_bound(40, 0.5) == 26  # binom.ppf(0.95, 40, 0.5) = 25
    assert order_statistic_bound(40, 0.9) == 40  # binom.ppf(0.95, 40, 0.9) = 39
    assert order_statistic_bound(40, 0.95) is None  # P(X_(40) ≥ ξ) = 0.8715 < 0.95
    assert clopper_pearson_lower(40, 40) == pytest.approx(0.9278424754944854, rel=1e-12)
    assert clopper_pearson_lower(38, 40) == pytest.approx(0.8508480387267869, rel=1e-10)
    assert clopper_pearson_lower(59, 59) == pytest.approx(0.950492390111773, rel=1e-12)
    assert runs_needed(0.95) == 59  # 0.95^59 = 0.0485 ≤ 0.05 < 0.95^58


def _rows(peaks, quantiles=None, shares=None):
    n = len(peaks)
    return [
        {
            "run": i,
            "seed": 100 + i,
            "steady_max_error_deg": peaks[i],
            "time_quantile_error_deg": (quantiles or peaks)[i],
            "time_within_requirement_fraction": (shares or [1.0] * n)[i],
        }
        for i in range(n)
    ]


def test_the_three_interpretations_on_forty_runs():
    peaks = [0.05] * 38 + [0.12, 0.15]  # two runs leave the bound at some time
    quantiles = [0.04] * 38 + [0.08, 0.11]  # one of them for more than 5 % of its time
    shares = [1.0] * 38 + [0.97, 0.93]
    out = interpretations(_rows(peaks, quantiles, shares), PointingRequirement(), 0.1)
    ens, tem, mix = out["ensemble"], out["temporal"], out["mixed"]
    assert ens["estimate"] == pytest.approx(0.95) and ens["met"] and not ens["demonstrated"]
    assert ens["lower_bound"] == pytest.approx(0.8508480387267869, rel=1e-10)
    assert ens["runs_needed"] == 59
    assert [w["run"] for w in ens["worst_runs"]] == [39, 38, 0]
    assert tem["estimate"] == pytest.approx(0.11) and not tem["met"]
    assert tem["worst_runs"][0]["run"] == 39
    assert tem["share_of_runs"] == pytest.approx(39 / 40)
    mean = (38 + 0.97 + 0.93) / 40
    assert mix["estimate"] == pytest.approx(mean) and mix["met"]
    assert mix["lower_bound"] == pytest.approx(mean - math.sqrt(math.log(20) / 80))
    assert mix["runs_needed"] == 600  # ln 20 / (2 · 0.05²) = 599.1


def _full_rows(n=40):
    rng = np.random.default_rng(7)
    rows = []
    for i in range(n):
        row = {
            "run": i,
            "seed": 1000 + i,
            "steady_max_error_deg": 0.002 * (i + 1),
            "time_quantile_error_deg": 0.001 * (i + 1),
            "time_within_requirement_fraction": 1.0,
            "eclipse_s": 0.0,
            "torque_peak_Nm": 0.1,
            "wheel_momentum_peak_fraction": 0.2,
            "torque_saturated_fraction": 0.0,
            "acquired_s": 10.0 * i,
            "settled_s": 10.0 * i,
            "filter_converged_s": 5.0,
        }
        for name in ("steady_max_error", "mpe", "rpe", "pde", "knowledge_error", "mke", "kde"):
            for a in "xyz":
                row[f"{name}_{a}_deg"] = float(rng.uniform(0, 0.05))
        rows.append(row)
    return rows


def test_budget_json_opens_with_the_verdict_and_validates_against_its_schema():
    c = Campaign(SMALLSAT, (), 1000.0, steady_after=300.0)
    b = json.loads(json.dumps(budget(_full_rows(), c)))  # what the file holds
    jsonschema.validate(b, schemas.schema("budget"), cls=jsonschema.Draft202012Validator)
    assert list(b)[:5] == ["format", "requirement", "interpretation", "verdict", "steady_window"]
    assert b["format"] == "rwlab.Budget/3"
    assert (
        b["interpretation"]["name"] == "ensemble"
        and "ECSS-E-ST-60-10C" in (b["interpretation"]["reference"])
    )
    v = b["verdict"]
    assert v["met"] and not v["demonstrated"] and v["runs_needed"] == 59
    assert v["lower_bound"] == pytest.approx(0.9278424754944854)
    assert v["text"].startswith("APE ≤ 0.1° for 0.95 of the runs (ensemble): NOT DEMONSTRATED")
    assert "40 of 40 runs" in v["text"] and "92.8%" in v["text"]
    assert v["worst_runs"][0]["run"] == 39
    assert b["steady_window"]["start_s"] == 300.0
    assert b["steady_window"]["runs_acquired_after_start"] == list(range(31, 40))
    assert b["steady_window"]["runs_filter_converged_after_start"] == []
    for name in ("APE", "MPE", "RPE", "PDE", "AKE", "MKE", "KDE"):
        entry = b["indices"][name]["z"]
        assert entry["max"] == max(r[f"{_col(name)}_z_deg"] for r in _full_rows())
        assert {q["p"] for q in entry["quantiles"]} >= {0.5, 0.95}
    assert "60 s" in b["indices"]["RPE"]["definition"]
    assert set(b["other_interpretations"]) == {"temporal", "mixed"}


def _leaves(value, path=()):
    """(path, number) for every number in a parsed JSON value."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _leaves(v, (*path, i))
    elif isinstance(value, float):
        yield path, value


def test_each_number_of_the_budget_is_in_one_place():
    """Version 2 held the verdict's share under four names (verdict, interpretations,
    meets_requirement, meets_requirement_fraction), the bound twice, the per-axis maxima
    twice: version 3 says each once (a worst run's value repeats its index's max, by
    design: "the runs that set it")."""
    rows = _full_rows()
    for r in rows:  # distinct values for distinct quantities (no coincidences)
        r["torque_peak_Nm"], r["settled_s"] = 0.123, r["acquired_s"] + 1.0
    rows[0]["time_quantile_error_deg"] = 0.15
    req = PointingRequirement(probability=0.9)
    c = Campaign(SMALLSAT, (), 1000.0, steady_after=300.0, requirement=req)
    b = json.loads(json.dumps(budget(rows, c)))
    places: dict[float, list] = {}
    for path, value in _leaves(b):
        if "worst_runs" in path or "quantiles" in path or value in (0.0, 1.0):
            continue
        places.setdefault(value, []).append(path)
    twice = {v: p for v, p in places.items() if len(p) > 1}
    assert not twice
    for gone in (
        "meets_requirement",
        "meets_requirement_fraction",
        "requirement_deg",
        "APE",
        "pointing_error_deg",
        "worst_seeds",
        "runs",
        "quantiles",
        "interpretations",
    ):
        assert gone not in b
    assert "confidence" not in b["verdict"] and "runs" not in b["verdict"]


def _col(name):
    return {"APE": "steady_max_error", "AKE": "knowledge_error"}.get(name, name.lower())


def test_the_late_warnings_name_only_the_runs_that_were_late():
    """Run 4 acquired at 10 s and missed at 790–800 s, in steady state (the verdict counts
    it); run 7 first came within the bound at 500 s; run 2's filter converged at 400 s.
    With the window from 300 s, version 2 named all three as "settled or converged after
    the window's start (their statistics include acquisition)"; each warning now names
    only the runs that did what it says."""
    from rwlab.cli.montecarlo import late_warnings

    rows = _full_rows(10)
    for r in rows:
        r["acquired_s"] = r["settled_s"] = 10.0
    rows[4]["settled_s"], rows[4]["steady_max_error_deg"] = 800.0, 0.2
    rows[7]["acquired_s"] = rows[7]["settled_s"] = 500.0
    rows[2]["filter_converged_s"] = 400.0
    window = budget(rows, Campaign(SMALLSAT, (), 1000.0, steady_after=300.0))["steady_window"]
    assert window["runs_acquired_after_start"] == [7]
    assert window["runs_filter_converged_after_start"] == [2]
    assert window["settled"] == {"max_s": 800.0, "run": 4, "never_runs": []}
    acquired, filtered = late_warnings(window)
    assert "first came within the bound" in acquired and acquired.count("runs 7;") == 1
    assert "filter converge" in filtered and filtered.count("runs 2;") == 1
    assert "4" not in acquired.replace("(300 s)", "") and "4" not in filtered


def test_the_interpretation_and_rpe_bound_chosen_are_the_verdicts():
    req = PointingRequirement(interpretation="temporal", rpe_deg=0.01, probability=0.9)
    c = Campaign(SMALLSAT, (), 1000.0, requirement=req)
    b = budget(_full_rows(), c)
    assert b["interpretation"]["name"] == "temporal" and "worst run" in b["verdict"]["text"]
    assert b["verdict"]["estimate"] == pytest.approx(0.04)
    rpe = b["verdict"]["rpe"]
    assert rpe["bound_deg"] == 0.01 and not rpe["met"]  # uniform(0, 0.05) RPEs on 3 axes


def test_older_budgets_read_as_version_3_and_a_newer_one_is_refused():
    old = {"runs": 3, "requirement_deg": 0.1, "meets_requirement_fraction": 1.0}
    up = read_budget(old)
    assert up["format"] == "rwlab.Budget/3" and up["interpretation"]["name"] == "ensemble"
    assert up["requirement"]["ape_deg"] == 0.1 and "format" not in old
    assert up["campaign"]["runs"] == 3 and "meets_requirement_fraction" not in up
    v2 = {
        "format": "rwlab.Budget/2",
        "interpretation": {"name": "temporal", "statement": "s", "reference": "r"},
        "verdict": {"met": True, "estimate": 0.05, "confidence": 0.95, "runs": 4},
        "interpretations": {"ensemble": {"estimate": 1.0}, "temporal": {"estimate": 0.05}},
        "pointing_error_deg": {"total": {"mean": 0.01, "std": 0.002, "max": 0.02}},
        "quantiles": [],
        "runs": 4,
        "torque_peak_Nm": {"max": 0.1, "seed": 9},
    }
    up = read_budget(v2)
    assert up["verdict"] == {"met": True, "estimate": 0.05}
    assert up["other_interpretations"] == {"ensemble": {"estimate": 1.0}}
    assert up["total_error"]["max"] == 0.02 and up["campaign"]["runs"] == 4
    assert up["peaks"]["torque_peak_Nm"] == {"max": 0.1, "seed": 9}
    with pytest.raises(FileFormatError, match="update rwlab"):
        read_budget({"format": "rwlab.Budget/4"})


# -- the campaign's steady window and start ------------------------------------------------


def test_steady_after_must_lie_inside_the_run():
    with pytest.raises(ConfigError, match="steady_after"):
        Campaign(SMALLSAT, (), 100.0, steady_after=100.0)
    with pytest.raises(ConfigError, match="start"):
        Campaign(SMALLSAT, (), 100.0, start="warm")


def test_a_run_counts_from_steady_after_and_a_converged_start_is_on_target():
    disp = load_dispersions()
    seed = run_seeds(4, 1)[0]
    acq = Campaign(SMALLSAT, disp, 240.0, "lqg", steady_after=200.0)
    run, row = fly_run(acq, seed)
    assert run.steady_from_s == 200.0
    assert row["run.initial_error_deg"] > 0.1  # dispersed acquisition error
    conv = Campaign(SMALLSAT, disp, 240.0, "lqg", steady_after=200.0, start="converged")
    sc, values = dispersed(conv, seed)
    assert sc.run.initial_error_deg == 0.0 and sc.run.initial_rate == (0.0, 0.0, 0.0)
    assert values["run.initial_error_deg"] == 0.0 and values["run.initial_rate.x"] == 0.0
    run, row = fly_run(conv, seed)
    assert row["max_error_deg"] < 0.1 and row["settled_s"] == 0.0


# -- how the campaign ran --------------------------------------------------------------------


class _Events:
    def __init__(self, events):
        self.events = events

    def get_events(self, topic):
        assert topic == "all"
        return self.events


def test_lost_workers_come_from_the_schedulers_remove_worker_events():
    where = {"k0": 0, "k1": 1, "k2": 2}
    events = [
        (5.0, {"action": "remove-worker", "worker": "tcp://a", "expected": False,
               "processing-tasks": {"k1"}, "lost-computed-tasks": {"k0", "other"}}),
        (6.0, {"action": "remove-worker", "worker": "tcp://b", "expected": True,
               "processing-tasks": {"k2"}, "lost-computed-tasks": set()}),
        (1.0, {"action": "remove-worker", "worker": "tcp://c", "expected": False,
               "processing-tasks": {"k2"}, "lost-computed-tasks": set()}),
        (7.0, {"action": "add-worker", "worker": "tcp://d"}),
    ]  # fmt: skip
    seen: set = set()
    lost = _lost_workers(_Events(events), 2.0, where, seen)
    assert [(w.address, w.running, w.recomputed) for w in lost] == [("tcp://a", (1,), (0,))]
    assert _lost_workers(_Events(events), 2.0, where, seen) == []  # each reported once


def test_execution_counts_silent_recomputations_as_retries():
    ex = Execution(
        retries=[{"runs": [4, 5], "attempt": 1, "reason": "worker lost (KilledWorker)"}],
        lost_workers=[
            {"address": "a", "time": 1.0, "running_runs": [4, 5], "recomputed_runs": [0, 1]},
            {"address": "b", "time": 2.0, "running_runs": [8], "recomputed_runs": []},
        ],
    )
    d = ex.to_dict()
    # in runs: ours (4 and 5), the scheduler's recomputed results (0, 1) and its own
    # retry (8); one batch resubmitted by this process
    assert d["runs_flown_again"] == 2 + 2 + 1 and d["batches_resubmitted"] == 1
    assert d["retried_runs"] == [0, 1, 4, 5, 8] and d["recomputed_runs"] == [0, 1]
    assert len(d["lost_workers"]) == 2


def test_long_runs_go_few_to_a_task_and_short_ones_are_grouped():
    from rwlab.campaign.engine import batches
    from rwlab.campaign.montecarlo import tasks_per_worker

    per_worker = tasks_per_worker(40, 86400.0, 2)
    assert {len(b) for b in batches(list(range(40)), 2, per_worker)} == {1}  # day-runs: 1 a task
    assert tasks_per_worker(96, 600.0, 2) == 8  # 16 simulated hours over 2 workers
    assert tasks_per_worker(12, 200.0, 2) == 4  # the floor
    assert tasks_per_worker(10**6, 3600.0, 2) == 64  # the cap


def test_the_console_opens_with_requirement_interpretation_and_verdict(tmp_path):
    from click.testing import CliRunner

    from rwlab.cli import main

    args = ["attitude", "montecarlo", "--scenario", "geo-smallsat", "--runs", "2",
            "--duration", "120", "--workers", "1", "--seed", "3", "--steady-after", "60",
            "--interpretation", "mixed", "--out", str(tmp_path / "mc")]  # fmt: skip
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    lines = [x for x in r.stdout.splitlines() if x.strip()]
    # the verdict first, with its confidence; no share of runs before it
    assert lines[0].startswith("verdict: APE ≤ 0.1°") and "95% confidence" in lines[0]
    assert lines[1].startswith("  set by: run ")
    assert lines[2].startswith("requirement: APE ≤ 0.1°") and "t ≥ 60 s" in lines[2]
    assert lines[3].startswith("interpretation (mixed):")
    assert not any("meet" in x and "%" in x for x in lines[1:])
    b = json.loads((tmp_path / "mc" / "budget.json").read_text())
    assert b["interpretation"]["name"] == "mixed" and b["steady_window"]["start_s"] == 60.0
    html = (tmp_path / "mc" / "report.html").read_text()
    assert "of the runs meet" not in html  # the share is in the verdict, with its bound
    assert html.index(b["verdict"]["text"][:40]) < html.index("What these runs support")
    bad = CliRunner().invoke(main, [*args[:-1], str(tmp_path / "x"), "--steady-after", "120"])
    assert (
        bad.exit_code == 2
        and bad.output.startswith("error:")
        and "--steady-after must be" in bad.output
    )
