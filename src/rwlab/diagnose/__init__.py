"""Model-based fault diagnosis of a reaction wheel.

The identified model runs beside the telemetry (:mod:`~rwlab.diagnose.residuals`),
sequential tests watch the residuals with thresholds set from a stated
false-alarm rate (:mod:`~rwlab.diagnose.detect`), and the residual signature
names the likely fault (:mod:`~rwlab.diagnose.isolate`). :class:`Diagnoser`
does it one sample at a time, live in the experiment runner or offline over a
record (:func:`diagnose`).
"""

from rwlab.diagnose.diagnoser import Alarm, Diagnoser, Diagnosis, diagnose

__all__ = ["Alarm", "Diagnoser", "Diagnosis", "diagnose"]
