"""Reports read by people: the verdict first, reasons as lines and tables, the main trace
on top, numbers with the digits they need (issue 45)."""

from types import SimpleNamespace

import pytest
from matplotlib.ticker import LogFormatterMathtext

from rwlab.report import attitude as attitude_report
from rwlab.report import diagnosis as diagnosis_report
from rwlab.report.html import Page, PlainLogLabels, figure, render_pngs, signed, trace_styles
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
    alarm = SimpleNamespace(
        t_s=611.5,
        kind="friction",
        detector="friction",
        magnitude=2.13,
        ci=(1.8, 2.4),
        unit="factor",
    )
    later = SimpleNamespace(
        t_s=637.5, kind="friction", detector="slew", magnitude=None, ci=None, unit="factor"
    )
    found = SimpleNamespace(alarms=[later, alarm], model_tested=lambda: True, duration_s=1200.0)
    page = Page("d")
    diagnosis_report._verdict(page, found)
    diagnosis_report._threshold_table(page, ["friction: with 100% of its tolerance", "plain"])
    html = page.render()
    assert "2 alarms, first of each fault: friction ×2.13 (95 % CI 1.8 … 2.4) at 611.5 s" in html
    assert 'class="verdict bad"' in html and 'id="threshold-notes"' in html
    assert "<td>friction</td><td>with 100% of its tolerance</td>" in html
    quiet = SimpleNamespace(alarms=[], model_tested=lambda: True, duration_s=900.0)
    page = Page("q")
    diagnosis_report._verdict(page, quiet)
    assert "No alarm in this 900-s record." in page.render()


def _log_axis_labels(scale: str, values) -> tuple[list[str], list[str]]:
    import matplotlib.pyplot as plt

    fig, ax = figure()
    ax.plot([0, 1], values)
    ax.set_yscale(scale, **({"linthresh": 0.1} if scale == "symlog" else {}))
    for axis in (ax.xaxis, ax.yaxis):
        if isinstance(axis.get_major_formatter(), LogFormatterMathtext):
            axis.set_major_formatter(PlainLogLabels(axis.get_major_formatter()))
            axis.set_minor_formatter(PlainLogLabels(axis.get_minor_formatter()))
    fig.canvas.draw()
    major = [t.get_text() for t in ax.yaxis.get_majorticklabels()]
    minor = [t.get_text() for t in ax.yaxis.get_minorticklabels() if t.get_text()]
    plt.close(fig)
    return major, minor


def test_log_axes_are_labelled_in_plain_superscripts_as_matplotlib_labels_them():
    major, _ = _log_axis_labels("log", [1e-5, 10.0])
    assert major[1:-1] == ["10⁻⁵", "10⁻⁴", "10⁻³", "10⁻²", "10⁻¹", "10⁰", "10¹"]
    _, minor = _log_axis_labels("log", [0.002, 0.004])  # under a decade: minor labels too
    assert minor[:3] == ["2×10⁻³", "3×10⁻³", "4×10⁻³"]
    major, _ = _log_axis_labels("symlog", [-100.0, 100.0])
    assert major == ["−10²", "−10¹", "−10⁰", "−10⁻¹", "0", "10⁻¹", "10⁰", "10¹", "10²"]


class _Labelled(LogFormatterMathtext):
    """A log formatter that writes one given label."""

    def __init__(self, label: str) -> None:
        super().__init__()
        self.label = label

    def __call__(self, x, pos=None) -> str:
        return self.label


@pytest.mark.parametrize(
    "label, text",
    [
        (r"$\mathdefault{2\times10^{-3}}$", "2×10⁻³"),
        (r"$\mathdefault{-10^{12}}$", "−10¹²"),
        (r"$\mathdefault{e^{2}}$", "e²"),
        (r"$\mathdefault{10^{0.30}}$", r"$\mathdefault{10^{0.30}}$"),  # stays mathtext
        (r"$\mathdefault{\sqrt{2}}$", r"$\mathdefault{\sqrt{2}}$"),
        ("1e-3", "1e-3"),
    ],
)
def test_a_log_label_is_plain_text_where_it_can_be_and_mathtext_where_not(label, text):
    assert PlainLogLabels(_Labelled(label))(1.0) == text


def test_report_figures_with_log_axes_are_drawn_without_mathtext(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("mathtext parsed")

    monkeypatch.setattr("matplotlib.mathtext.MathTextParser.parse", refuse)
    fig, axes = figure(nrows=2)
    axes[0].semilogy([1.0, 2.0], [1e-3, 10.0])
    axes[1].set_yscale("symlog", linthresh=0.1)
    axes[1].plot([0.0, 1.0], [-50.0, 50.0])
    (png,) = render_pngs([fig], processes=1)
    assert png.startswith(b"\x89PNG")
