"""rwlab's version, in one place below every layer (the package re-exports it; a module
that stamps it into a file imports it from here, not from the package's front door)."""

__version__ = "0.1.0"
