"""``python -m rwlab``: the ``rwlab`` command line."""

from rwlab.cli import run

run()
