"""``python -m rwlab``: the ``rwlab`` command line."""

from rwlab.cli import main

main(prog_name="rwlab")
