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
# the residual channel that carries each fault's signature: two faults on different
# channels can both be present; on the same one they compete for one event
SIGNATURE = {
    "friction": "current",
    "torque_constant": "current",
    "current_limit": "accel",
    "speed_sensor_bias": "speed",
    "speed_sensor_stuck": "reading",
    "telemetry_dropout": "frames",
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
