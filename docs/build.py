"""Build the documentation site offline: ``python docs/build.py`` → docs/_build/html.

First makes every figure the pages show, the README's included (``docs/figures.py``:
it runs the README's tour of the commands and cuts each figure from the report the
command wrote), then runs the example gallery (its figures are computed, not stored),
generates the API reference from the numpydoc docstrings and fails on any Sphinx
warning.
Needs ``pip install -e ".[docs]"``; nothing is downloaded while building.
"""

import shutil
import sys
from pathlib import Path

from sphinx.cmd.build import build_main

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS))

import figures  # noqa: E402  (docs/figures.py, beside this script)


def main(argv: list[str]) -> int:
    """Build the HTML site; ``--clean`` first removes the previous build and gallery."""
    if "--clean" in argv:
        for folder in ("_build", "auto_examples", "api"):
            shutil.rmtree(DOCS / folder, ignore_errors=True)
    figures.build()
    out = DOCS / "_build" / "html"
    return build_main(["-b", "html", "-W", "--keep-going", "-q", str(DOCS), str(out)])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
