"""The ``rwlab`` command line: one module per command group, registered on ``main``."""

from rwlab.cli import attitude, demo, hil, ident, study, testbed, wheel  # noqa: F401  (registers)
from rwlab.cli._common import main

__all__ = ["main"]
