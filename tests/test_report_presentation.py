"""Reports read by people: the verdict first, reasons as lines and tables, the main trace
on top, numbers with the digits they need (issue 45)."""

from types import SimpleNamespace

import pytest

from rwlab.report import attitude as attitude_report
from rwlab.report import diagnosis as diagnosis_report
from rwlab.report.html import Page, signed, trace_styles
from rwlab.report.model_choice import reason_clauses

# study.json's chosen.reason of `rwlab demo` (seed 1): the ~1000-character sentence
REASON = (
    "OE221+K is the simplest model (fewest parameters: 4; then ARX < ARMAX < OE < BJ, a free "
    "model before its gain-constrained twin +K) whose validation fit (72.81 %) is within 3 "
    "points of the best (73.75 %) and whose DC gain (1.0000, +0.0 %) is within 2 % of the "
    "measured steady-state gain 0.9997 (16 settled holds of the whole record); passed over "
    "for a DC gain off the measured one: OE221 (0.9638, -3.6 %); static gain constrained to "
    "K = 1.0000 ± 0.0000 measured on 10 settled holds of the estimation part (its DC gain "
    "agrees with the whole record's by construction, up to that difference; the model's "
    "covariance holds its dynamics given K, so its static gain's uncertainty is K's); its "
    "unconstrained twin OE221 fits 72.47 % with DC gain 0.9638, -3.6 %: the constraint adds "
    "0.34 points of fit; paper A's choice is not: ARX221 fits 68.68 % (5.07 points below the "
    "best), DC gain 0.9153, -8.4 %; ARX221+K fits 69.80 % (3.96 points below the best), DC "
    "gain 1.0000, +0.0 %"
)


def test_the_choice_is_cut_into_its_clauses_and_nothing_is_lost():
    clauses = reason_clauses(REASON)
    assert len(clauses) == 5
    assert clauses[0].startswith("OE221+K is the simplest model (fewest parameters: 4; then")
    assert clauses[1] == "Passed over for a DC gain off the measured one: OE221 (0.9638, -3.6 %)"
    assert "up to that difference; the model's covariance" in clauses[2]  # ; in parentheses
    assert clauses[4].startswith("Paper A's choice is not: ARX221 fits 68.68 %")
    assert "ARX221+K fits 69.80 %" in clauses[4]  # paper A's two models stay in one line

    def letters(text):
        return "".join(text.split()).replace(";", "").lower()

    assert letters("".join(clauses)) == letters(REASON)  # only the separators go
    assert reason_clauses("ARX221 is the simplest model") == ["ARX221 is the simplest model"]


@pytest.mark.parametrize(
    ("value", "text"),
    [(1.94e-5, "+1.94e-05"), (-0.012345, "-0.0123"), (0.0, "+0"), (12.5, "+12.5")],
)
def test_signed_numbers_keep_their_significant_digits(value, text):
    assert signed(value) == text


def test_each_trace_is_narrower_than_the_one_below_it_and_the_last_is_on_top():
    styles = trace_styles(4)
    widths = [s["lw"] for s in styles]
    assert widths == sorted(widths, reverse=True) and len(set(widths)) == 4
    assert [s["zorder"] for s in styles] == sorted(s["zorder"] for s in styles)
    assert styles[-1]["lw"] < 1.0 < styles[0]["lw"]


def test_the_verdict_comes_right_after_the_title():
    page = Page("A report")
    page.verdict("It works.", True)
    page.text("Details.")
    html = page.render()
    assert html.index("<h1>") < html.index('class="verdict ok"') < html.index("Details.")
    page = Page("B")
    page.verdict("Not demonstrated.", None)
    assert 'class="verdict open"' in page.render()


def _metrics(max_deg, rms_deg, met=True):
    return {"steady_max_error_deg": max_deg, "steady_rms_error_deg": rms_deg,
            "meets_requirement": met}  # fmt: skip


def test_the_attitude_verdict_names_a_failing_run_and_the_lag_cost_has_its_digits():
    metrics = {
        "lqr": _metrics(1.17e-4, 8.6e-5),
        "lqg": _metrics(0.0182, 0.009792),
        "lqg_ltr": _metrics(0.131, 0.05, met=False),
        "lqg_identified_wheel": _metrics(0.0180, 0.009811),
    }
    page = Page("att")
    attitude_report._verdict(page, metrics, 0.1)
    payload = {"identified_wheel_lag_cost_deg": 0.009811 - 0.009792}
    attitude_report._identified_wheel_note(page, metrics, payload, 0.1)
    html = page.render()
    assert 'class="verdict bad"' in html and "LQG/LTR does NOT meet ±0.1°" in html
    assert "LQR (true state) 0.000117°" in html
    assert "+1.9e-05°" in html and "+0.0000°" not in html
    assert "(+0.19 %)" in html


def test_the_diagnosis_verdict_names_each_fault_first_seen_and_thresholds_are_a_table():
    alarm = SimpleNamespace(t_s=611.5, kind="friction", detector="friction")
    later = SimpleNamespace(t_s=637.5, kind="friction", detector="slew")
    found = SimpleNamespace(alarms=[later, alarm], model_tested=lambda: True, duration_s=1200.0)
    page = Page("d")
    diagnosis_report._verdict(page, found)
    diagnosis_report._threshold_table(page, ["friction: with 100% of its tolerance", "plain"])
    html = page.render()
    assert "2 alarms, first of each fault: friction at 611.5 s (friction test)" in html
    assert 'class="verdict bad"' in html and 'id="threshold-notes"' in html
    assert "<td>friction</td><td>with 100% of its tolerance</td>" in html
    quiet = SimpleNamespace(alarms=[], model_tested=lambda: True, duration_s=900.0)
    page = Page("q")
    diagnosis_report._verdict(page, quiet)
    assert "No alarm in this 900-s record." in page.render()
