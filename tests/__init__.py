"""The test suite (a package, so that test files can share helpers)."""

import sys

# Compiled modules are cached in __pycache__ (git ignores it) even where the environment
# sets PYTHONDONTWRITEBYTECODE, as some container images do: otherwise every test worker
# compiles rwlab again and pytest rewrites every test module's asserts again at each run
# (measured: collection 8.4 s → 4.4 s per worker), and each `rwlab` subprocess a test
# starts compiles what it imports.
sys.dont_write_bytecode = False
