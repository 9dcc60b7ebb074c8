"""The detectors, one fault model each, registered by fault name (:mod:`.base`)."""

from rwlab.diagnose.detectors.base import REGISTRY, Detector, Fit, detector
from rwlab.diagnose.detectors.current_limit import CurrentLimit
from rwlab.diagnose.detectors.friction import Friction
from rwlab.diagnose.detectors.frozen_reading import FrozenReading
from rwlab.diagnose.detectors.lost_frames import LostFrames
from rwlab.diagnose.detectors.sensor_bias import SensorBias
from rwlab.diagnose.detectors.torque_constant import TorqueConstant

# the model-based detectors: their sizes compete by likelihood on the same residuals
MODEL_BASED = ("friction", "torque_constant", "current_limit", "speed_sensor_bias")
# the residual channels that carry each fault's signature (a fault-signature matrix by
# rows): two faults whose channels overlap compete for one event; two on disjoint
# channels can both be present
SIGNATURE = {
    "friction": frozenset({"current", "accel"}),
    "torque_constant": frozenset({"current", "accel"}),
    "current_limit": frozenset({"accel"}),
    "speed_sensor_bias": frozenset({"speed"}),
    "speed_sensor_stuck": frozenset({"reading"}),
    "telemetry_dropout": frozenset({"frames"}),
}

__all__ = [
    "MODEL_BASED",
    "REGISTRY",
    "SIGNATURE",
    "CurrentLimit",
    "Detector",
    "Fit",
    "Friction",
    "FrozenReading",
    "LostFrames",
    "SensorBias",
    "TorqueConstant",
    "detector",
]
