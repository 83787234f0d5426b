"""gtsam_rotid: target-free camera-to-arm calibration by rotation identification, on GTSAM.

The wrist spins, features on the end effector trace circles about its axis, the camera sees
ellipses, and the arm's kinematics tie each rotation axis to the camera pose ``arm_T_camera``.
See README.md and docs/design.md for conventions.
"""

from . import simulate
from .arm import Arm
from .camera import Camera
from .dataset import Dataset, Measurement, SpinReadings, Track
from .errors import (
    ArmError,
    CameraError,
    DatasetExistsError,
    DatasetNotFoundError,
    InputError,
    OutputError,
    RecordingError,
    RotIdError,
    SimulationError,
    ValidationError,
)
from .geometry import Line3
from .tracking import Tracker, TrackerParams, track

__version__ = "0.1.0"

#: The calibration's names, importable from here (``gtsam_rotid.calibrate``) but loaded on first use: the estimator
#: pulls in every factor and graph module, which ``import gtsam_rotid`` (and the CLI's start) need not pay for.
_CALIBRATION = ("CalibrationError", "CalibrationOptions", "CalibrationResult", "Method", "calibrate")


#: ... and the result's words: ``gtsam_rotid.summary(result)``, ``gtsam_rotid.make_report(result, dataset)``.
_WORDS = {"summary": "words", "make_report": "report"}


def __getattr__(name: str):
    if name in _CALIBRATION:
        from . import calibration

        return getattr(calibration, name)
    if name in _WORDS:
        import importlib

        return getattr(importlib.import_module(f".{_WORDS[name]}", __name__), name)
    raise AttributeError(f"module 'gtsam_rotid' has no attribute {name!r}")

__all__ = [
    "Arm",
    "ArmError",
    "CalibrationError",
    "CalibrationOptions",
    "CalibrationResult",
    "Camera",
    "CameraError",
    "Dataset",
    "DatasetExistsError",
    "DatasetNotFoundError",
    "InputError",
    "Line3",
    "Measurement",
    "Method",
    "OutputError",
    "RecordingError",
    "RotIdError",
    "SimulationError",
    "SpinReadings",
    "Track",
    "Tracker",
    "TrackerParams",
    "ValidationError",
    "calibrate",
    "make_report",
    "simulate",
    "summary",
    "track",
]
