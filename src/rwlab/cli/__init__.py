"""The ``rwlab`` command line: one module per command group, registered on ``main``."""

from rwlab.cli import (  # noqa: F401
    attitude,
    compare,
    demo,
    fdi,
    hil,
    ident,
    montecarlo,
    nonparametric,
    study,
    testbed,
    wheel,
)
from rwlab.cli._common import main, run

__all__ = ["main", "run"]
