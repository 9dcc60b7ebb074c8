"""Model-based fault diagnosis of a reaction wheel.

The identified model runs beside the telemetry (:mod:`~rwlab.diagnose.residuals`);
block tests and sample tests compare it with the healthy reference measured on
the identification record (:mod:`~rwlab.diagnose.reference`), with thresholds
set from a stated false-alarm rate as measured on healthy records of other
units (:mod:`~rwlab.diagnose.calibration`, :mod:`~rwlab.diagnose.detect`); the
signature names and sizes the fault (:mod:`~rwlab.diagnose.isolate`).
:class:`Diagnoser` does it one sample at a time, live in the experiment runner
or offline over a record (:func:`diagnose`).
"""

from rwlab.diagnose.calibration import ThresholdCalibration
from rwlab.diagnose.diagnoser import Alarm, Diagnoser
from rwlab.diagnose.diagnosis import Diagnosis, diagnose, healthy_reference, measure_calibration
from rwlab.diagnose.reference import HealthyReference

__all__ = [
    "Alarm",
    "Diagnoser",
    "Diagnosis",
    "HealthyReference",
    "ThresholdCalibration",
    "diagnose",
    "healthy_reference",
    "measure_calibration",
]
