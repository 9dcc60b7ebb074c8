"""Build the documentation site offline: ``python docs/build.py`` → docs/_build/html.

Runs the example gallery (its figures are computed, not stored), generates the
API reference from the numpydoc docstrings and fails on any Sphinx warning.
Needs ``pip install -e ".[docs]"``; nothing is downloaded while building.
"""

import shutil
import sys
from pathlib import Path

from sphinx.cmd.build import build_main

DOCS = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    """Build the HTML site; ``--clean`` first removes the previous build and gallery."""
    if "--clean" in argv:
        for folder in ("_build", "auto_examples", "api"):
            shutil.rmtree(DOCS / folder, ignore_errors=True)
    out = DOCS / "_build" / "html"
    return build_main(["-b", "html", "-W", "--keep-going", "-q", str(DOCS), str(out)])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
