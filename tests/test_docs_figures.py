"""Every figure a page shows is made by the documentation build from the code (no stale PNG)."""

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"

_spec = importlib.util.spec_from_file_location("docs_figures", DOCS / "figures.py")
assert _spec is not None and _spec.loader is not None
figures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(figures)

GENERATED = ("_build", "auto_examples", "api")  # the build's own outputs


def _pages() -> list[Path]:
    pages = [ROOT / "README.md"]
    for path in sorted(DOCS.rglob("*")):
        rel = path.relative_to(DOCS)
        if path.suffix in (".md", ".rst") and rel.parts[0] not in GENERATED:
            pages.append(path)
    return pages


def _images(text: str) -> list[str]:
    markdown = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text)
    tags = re.findall(r'<img[^>]*\bsrc="([^"]+)"', text)
    directives = re.findall(r"^\.\. (?:image|figure):: (\S+)", text, re.M)
    return [i for i in markdown + tags + directives if not i.startswith(("http", "data:"))]


def _built() -> set[Path]:
    return {(DOCS / name).resolve() for name in figures.FIGURES}


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_image_a_page_shows_is_made_by_the_docs_build(page):
    shown = [(page.parent / image).resolve() for image in _images(page.read_text())]
    stale = [str(p.relative_to(ROOT)) for p in shown if p not in _built()]
    missing = [str(p.relative_to(ROOT)) for p in shown if not p.exists()]
    assert not missing, f"{page.name} shows images that do not exist: {missing}"
    assert not stale, f"{page.name} shows images that docs/figures.py does not make: {stale}"


def test_the_readme_shows_the_workflow_and_the_tour():
    shown = {(ROOT / i).resolve() for i in _images((ROOT / "README.md").read_text())}
    assert _built() <= shown, sorted(str(p) for p in _built() - shown)


def test_no_committed_png_outside_the_builds_list():
    committed = {
        p.resolve() for p in DOCS.rglob("*.png") if p.relative_to(DOCS).parts[0] not in GENERATED
    }
    assert committed <= _built(), sorted(str(p) for p in committed - _built())


def test_the_build_runs_every_command_of_the_readme_tour_as_written():
    readme = (ROOT / "README.md").read_text()
    block = readme.split("## A tour of the commands", 1)[1].split("```", 2)[1]
    lines = [ln.split("#")[0].split() for ln in block.splitlines() if ln.startswith("rwlab")]
    for words in figures.TOUR:
        assert ["rwlab", *words] in lines, f"the README's tour lacks rwlab {' '.join(words)}"


def test_the_build_makes_and_finds_figures(tmp_path):
    figures.draw_workflow(tmp_path / "workflow.png")
    assert (tmp_path / "workflow.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    from rwlab.report.html import Page, figure

    page = Page("t")
    fig, ax = figure()
    ax.plot([0, 1], [1, 0])
    page.figure(fig, "fig-x", "a caption")
    page.save(tmp_path / "report.html")
    found = figures.report_figures(tmp_path / "report.html")
    assert list(found) == ["fig-x"]
    assert found["fig-x"][:8] == b"\x89PNG\r\n\x1a\n"
