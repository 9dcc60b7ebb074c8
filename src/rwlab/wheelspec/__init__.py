"""Wheel models' datasheets: :class:`WheelSpec` and the shipped presets.

``WheelSpec.load("rw90")`` (or ``"nrwa-t6"``, ``"rw-0.01"``, or a TOML file) gives
one wheel model's numbers, each with its source; every layer of rwlab reads them
from here. The record is :mod:`rwlab.wheelspec.spec`, its fields
:mod:`rwlab.wheelspec.fields`, their checks :mod:`rwlab.wheelspec.checks`, its files
(presets, a lab's TOML, writing one out) :mod:`rwlab.wheelspec.files`.
"""

from rwlab.wheelspec.fields import FORMAT, SECTIONS, TWIN_NAMES
from rwlab.wheelspec.files import preset_names
from rwlab.wheelspec.spec import Tolerance, WheelSpec

__all__ = ["FORMAT", "SECTIONS", "TWIN_NAMES", "Tolerance", "WheelSpec", "preset_names"]
