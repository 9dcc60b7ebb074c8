from rwlab.cli import run

run()
