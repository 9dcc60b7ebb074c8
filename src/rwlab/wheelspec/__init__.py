"""Wheel models' datasheets: :class:`WheelSpec` and the shipped presets.

``WheelSpec.load("rw90")`` (or ``"nrwa-t6"``, ``"rw-0.01"``, or a TOML file) gives
one wheel model's numbers, each with its source; every layer of rwlab reads them
from here (:mod:`rwlab.wheelspec.spec`).
"""

from rwlab.wheelspec.spec import FORMAT, SECTIONS, TWIN_NAMES, Tolerance, WheelSpec, preset_names

__all__ = ["FORMAT", "SECTIONS", "TWIN_NAMES", "Tolerance", "WheelSpec", "preset_names"]
