"""The ``rwlab`` command line: one module per command group, registered on ``main``."""

from rwlab.cli import attitude, compare, demo, hil, ident, study, testbed, wheel  # noqa: F401
from rwlab.cli._common import main

__all__ = ["main"]
