"""gtsam_rotid: target-free camera-to-arm calibration by rotation identification, on GTSAM.

The wrist spins, features on the end effector trace circles about its axis, the camera sees
ellipses, and the arm's kinematics tie each rotation axis to the camera pose ``arm_T_camera``.
See README.md and docs/design.md for conventions.
"""

from . import simulate
from .arm import Arm
from .camera import Camera
from .dataset import Dataset, Measurement, Track
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

__all__ = [
    "Arm",
    "ArmError",
    "Camera",
    "CameraError",
    "Dataset",
    "DatasetExistsError",
    "DatasetNotFoundError",
    "InputError",
    "Line3",
    "Measurement",
    "OutputError",
    "RecordingError",
    "RotIdError",
    "SimulationError",
    "Track",
    "Tracker",
    "TrackerParams",
    "ValidationError",
    "simulate",
    "track",
]
