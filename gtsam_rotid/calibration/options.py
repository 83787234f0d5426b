"""What a calibration is asked to do: the method, the spin model, the solver settings (validated), and the error
raised when it cannot be done.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from ..errors import InputError, RotIdError
from ..graph import (
    MIN_TRACK_EXTENT_PX,
    MIN_TRACK_POINTS,
    Model,
    SpinModel,
)

MIN_MEASUREMENTS = 3
#: The intrinsics ``CalibrationOptions.refine_intrinsics`` may name (``gtsam.Cal3_S2``'s, less the skew).
INTRINSICS = ("fx", "fy", "cx", "cy")
#: The default prior 1 sigma of refined intrinsics: (focal length fraction, principal point px).
DEFAULT_INTRINSICS_SIGMA = (0.05, 20.0)
#: A focal fraction of the intrinsics' prior above this is taken for a percentage typed by mistake (5 for 5 %).
MAX_FOCAL_FRACTION = 0.5
#: Fewest tracks (all measurements) from which stage 1 estimates how much their noise levels differ.
MIN_TRACKS_FOR_SPREAD = 8


class Method(StrEnum):
    PAPER = "paper"
    WEIGHTED = "weighted"
    JOINT = "joint"


def _choice(enum: type[StrEnum], name: str, value) -> StrEnum:
    """``value`` as a member of ``enum``, or an InputError naming the option and its choices."""
    try:
        return enum(value)
    except ValueError:
        raise InputError(f"CalibrationOptions.{name} must be one of {', '.join(repr(m.value) for m in enum)}, got "
                         f"{value!r}") from None


class CalibrationError(RotIdError, RuntimeError):
    """The optimisation could not produce a trustworthy estimate (e.g. every start ended in a poor minimum)."""


@dataclass
class CalibrationOptions:
    """Solver settings; the defaults suit the reference scene."""

    max_iterations: int = 100
    #: Pose candidates from the SO(3) grid refined by LM.
    n_candidates: int = 5
    #: Extra random restarts around the best start (the paper's method).
    restarts: int = 5
    seed: int = 0
    min_track_points: int = MIN_TRACK_POINTS
    #: Tracks whose pixels span less than this image extent (px) are rejected (a few degrees of arc).
    min_track_extent_px: float = MIN_TRACK_EXTENT_PX
    #: A track whose residual RMS exceeds this multiple of its measurement's median track RMS is rejected.
    outlier_track_ratio: float = 3.0
    #: ...or whose chi-square (at the median track RMS) exceeds the upper quantile at this normal z
    #: (3.09: the 99.9 % point).
    outlier_track_z: float = 3.09
    #: A measurement whose residual scale exceeds this multiple of the median is reported as an outlier.
    outlier_measurement_ratio: float = 3.0
    #: A measurement whose stage-1 image axis and the FK axis projected by the estimate disagree beyond this
    #: chi-square (2 dof) value is an outlier (e.g. a wrong joint reading) and is left out (weighted, joint).
    outlier_measurement_chi2: float = 30.0
    #: Initial stage-2 RMS (px) above which the start is declared a poor minimum.
    max_initial_rms_px: float = 25.0
    tie_sigma_px: float = 1e-3
    #: Joint method: ``"rigid"`` spin (default: one spin angle per frame shared by all features of a spin, and one
    #: phase offset per track, docs/design.md §4; for measurements whose tracks all have frame indices, in the
    #: ``"projected"`` joint model; the others keep the free phase) or ``"free"`` phase per observation.
    spin_model: str = "rigid"
    #: LM stops when the relative decrease of the error falls below these (stage 1; everything else).
    stage1_tolerance: float = 1e-8
    #: Joint graph: ``"projected"`` (docs/design.md §4's line variables with a projected-axis tie, the circles
    #: projected out inside one factor per measurement), ``"line"`` (the same with a circle variable per track:
    #: the same solution, ~5x slower) or ``"pose"`` (circles bound to the pose through the FK axis; biased tilt
    #: with free phases), see :class:`gtsam_rotid.graph.Model`.
    joint_model: str = "projected"
    #: Features farther than this (m, median over tracks) from the wrist axis are not on an end effector: an
    #: estimate that implies them is a poor minimum (typically a camera put metres away by wrong joint angles).
    max_feature_radius_m: float = 0.5
    #: Floor of the estimated pixel noise (px), so noise-free data keeps finite weights.
    min_sigma_px: float = 1e-3
    #: weighted, joint: when the measurements' image axes disagree with the FK axes projected by the estimate
    #: beyond this upper-tail probability, the covariance is scaled by their chi-square over (dof - 2) (the mean
    #: of the understatement given the scatter; see :class:`AxisConsistency`). 0 disables the scaling (the test is
    #: still reported). None (default): 0.01, or SHORT_ARC_CONSISTENCY_P where some measurement has no arc of
    #: WEAK_ARC_DEG (see ``_calibrate``).
    axis_consistency_p: float | None = None
    #: weighted, joint: standard deviation (deg) of each joint-angle reading, independent per joint and per arm
    #: pose (encoder noise, backlash). It moves the FK wrist axis; the projected-axis ties and the stage-2 weights
    #: include that uncertainty (propagated through the kinematics). 0: the kinematics are taken as exact.
    joint_sigma_deg: float = 0.0
    #: weighted, joint: the image axes' prior floor (px). Every measurement's image axis is taken to be shifted and
    #: turned by this much (1 sigma each, at its test points), an error shared by all its tracks: a tracker's bias
    #: that no number of tracks averages out; what it passes into the estimate is added to the covariance. The
    #: axes' own test (:class:`AxisConsistency`) cannot see it on
    #: a measurement that alone determines some direction of the pose (with few poses, the precise ones do), so a
    #: prior is the only guard there. None (default): the value the tracker wrote into the dataset's metadata
    #: (``metadata["tracker"]["axis_floor_px"]``, :func:`gtsam_rotid.tracking.tracker_metadata`), else 0 (tracks of
    #: unknown origin and simulated ones, whose noise is independent by construction).
    axis_floor_px: float | None = None
    #: weighted, joint: each track's own offset (px, 1 sigma per image coordinate): every track is taken to be
    #: shifted by one image translation of its own, independent across tracks (a blob centroid pulled by shading in
    #: a recess, a corner drifting on a surface that turns towards the camera: errors that follow a track over its
    #: whole arc and that its own points cannot average out). Its information is not in the fit's weights; what it
    #: passes into the estimate (through each track's leverage on its image axis) is added to the covariance and to
    #: the axes' tests. None (default): the tracker's value in the dataset's metadata
    #: (``metadata["tracker"]["track_offset_px"]``), else 0.
    track_offset_px: float | None = None
    #: joint: refine offsets (zero-position errors common to every pose; the reading plus the offset is the joint's
    #: angle) of joints before the spinning one with the pose: ``True`` every joint between the first and the
    #: spinning one (the first joint's offset turns the arm as the pose does), or a list of joint names. None
    #: (default): the kinematics as given (:func:`gtsam_rotid.calibration.modelcheck.kinematics_check` flags offsets).
    #: See :mod:`gtsam_rotid.calibration.offsets`.
    joint_offsets: bool | tuple | list | None = None
    #: the offsets' Gaussian prior, 1 sigma (deg): how far the robot's zero positions may be off
    joint_offset_sigma_deg: float = 1.0
    #: joint: refine these of the camera's intrinsics with the pose (names from ``INTRINSICS``; ``True``: all four)
    #: from the circles' shapes and the ties, under a prior centred on the camera file's values
    #: (``intrinsics_sigma``); the others (and the skew) stay as given. Needs the rigid spin (tracks with frame
    #: indices). The result's ``camera`` is the refined camera, ``intrinsics_covariance`` its covariance.
    refine_intrinsics: bool | tuple | list = ()
    #: the intrinsics' Gaussian prior, 1 sigma: (focal length as a fraction of it, principal point in px): how far
    #: the camera file may be off
    intrinsics_sigma: tuple = DEFAULT_INTRINSICS_SIGMA
    #: joint, rigid spin: measurements that carry their spinning joint's readings (``Measurement.spin_readings``)
    #: have every frame's angle under those readings' prior (synced mode), with the clocks' offset estimated
    #: (``time_offset_s``, ``time_offset_sigma_s``). False: the readings are not used.
    sync_encoders: bool = True
    #: synced: each frame's angle's 1 sigma from the readings (deg): the encoder's noise and its stamps' jitter
    #: times the spin's speed
    encoder_sigma_deg: float = 0.05
    #: synced: the clocks' offset, camera minus encoder (s: a reading stamped t was taken when the camera's clock
    #: read t + offset; the convention of ``gtsam-rotid track --time-offset`` and of bags), the mean of its Gaussian
    #: prior of 1 sigma ``time_offset_sigma_s`` (None: known, held at ``time_offset_s``). A spin at constant speed
    #: cannot tell the offset from the features' phases: the prior then holds it (a spin that speeds up and slows
    #: down dates it).
    time_offset_s: float = 0.0
    time_offset_sigma_s: float | None = 0.1

    def __post_init__(self):
        # a misspelt choice ("rigd") must not silently run the default
        self.spin_model = _choice(SpinModel, "spin_model", self.spin_model)
        self.joint_model = _choice(Model, "joint_model", self.joint_model)
        for name in ("max_iterations", "n_candidates", "min_track_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise InputError(f"CalibrationOptions.{name} must be an integer >= 1, got {value!r}")
        for name in ("restarts", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                raise InputError(f"CalibrationOptions.{name} must be an integer >= 0, got {value!r}")
        for name in ("min_track_extent_px", "outlier_track_ratio", "outlier_track_z", "outlier_measurement_ratio",
                     "outlier_measurement_chi2", "max_initial_rms_px", "tie_sigma_px", "stage1_tolerance",
                     "max_feature_radius_m", "min_sigma_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not np.isfinite(value) \
                    or value < 0:
                raise InputError(f"CalibrationOptions.{name} must be a finite number >= 0, got {value!r}")
        if self.axis_consistency_p is not None and not 0.0 <= self.axis_consistency_p < 1.0:
            raise InputError(f"CalibrationOptions.axis_consistency_p must be in [0, 1), got {self.axis_consistency_p}")
        for name in ("axis_floor_px", "track_offset_px"):  # (None: the tracker's, from the dataset's metadata)
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int | float | np.number)
                                      or not np.isfinite(value) or value < 0):
                raise InputError(f"CalibrationOptions.{name} must be None or a finite number >= 0, got {value!r}")
        if self.joint_offsets is False:
            self.joint_offsets = None
        if self.joint_offsets is not None and self.joint_offsets is not True:
            if isinstance(self.joint_offsets, str):
                self.joint_offsets = (self.joint_offsets,)
            if not isinstance(self.joint_offsets, tuple | list) or not all(
                    isinstance(name, str) for name in self.joint_offsets):
                raise InputError(f"CalibrationOptions.joint_offsets must be None, True or a list of joint names, got "
                                 f"{self.joint_offsets!r}")
            self.joint_offsets = tuple(self.joint_offsets)
        checked_offset_sigma_deg(self.joint_offset_sigma_deg, "CalibrationOptions.joint_offset_sigma_deg")
        if self.refine_intrinsics is True:
            self.refine_intrinsics = INTRINSICS
        elif self.refine_intrinsics is False or self.refine_intrinsics is None:
            self.refine_intrinsics = ()
        if isinstance(self.refine_intrinsics, str):
            self.refine_intrinsics = tuple(n.strip() for n in self.refine_intrinsics.split(",") if n.strip())
        if not isinstance(self.refine_intrinsics, tuple | list) or not all(
                name in INTRINSICS for name in self.refine_intrinsics):
            raise InputError(f"CalibrationOptions.refine_intrinsics must be True or names among {INTRINSICS}, got "
                             f"{self.refine_intrinsics!r}")
        self.refine_intrinsics = tuple(n for n in INTRINSICS if n in self.refine_intrinsics)
        self.intrinsics_sigma = checked_intrinsics_sigma(self.intrinsics_sigma, "CalibrationOptions.intrinsics_sigma")
        if not isinstance(self.sync_encoders, bool | np.bool_):
            raise InputError(f"CalibrationOptions.sync_encoders must be True or False, got {self.sync_encoders!r}")
        for name, low in (("encoder_sigma_deg", 0.0), ("time_offset_s", -np.inf), ("time_offset_sigma_s", 0.0)):
            value = getattr(self, name)
            if name == "time_offset_sigma_s" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not np.isfinite(value) \
                    or value <= low:
                what = "a finite number of seconds" if name == "time_offset_s" else "a positive number" + (
                    " of degrees" if name == "encoder_sigma_deg" else " of seconds or None")
                raise InputError(f"CalibrationOptions.{name} must be {what}, got {value!r}")
        if self.refine_intrinsics and self.spin_model is not SpinModel.RIGID:
            raise InputError("CalibrationOptions.refine_intrinsics needs spin_model='rigid'")
        if self.refine_intrinsics and self.joint_model is not Model.PROJECTED:
            raise InputError("CalibrationOptions.refine_intrinsics needs joint_model='projected'")
        if not (np.isfinite(self.joint_sigma_deg) and self.joint_sigma_deg >= 0.0):
            raise InputError(f"CalibrationOptions.joint_sigma_deg must be a finite value >= 0 (deg), got "
                             f"{self.joint_sigma_deg}")


def checked_offset_sigma_deg(sigma, name: str = "joint_offset_sigma_deg") -> float:
    """The joint offsets' prior 1 sigma (degrees) as a float, or an InputError naming ``name``: a positive finite
    number."""
    if isinstance(sigma, bool) or not isinstance(sigma, int | float | np.number) or not np.isfinite(sigma) \
            or sigma <= 0:
        raise InputError(f"{name} must be a positive number of degrees, got {sigma!r}")
    return float(sigma)


def checked_intrinsics_sigma(sigma, name: str = "intrinsics_sigma") -> tuple[float, float]:
    """The intrinsics' prior 1 sigma ``(focal length fraction, principal point px)`` as two floats, or an InputError
    naming ``name``: two positive finite numbers, the fraction at most ``MAX_FOCAL_FRACTION`` (5 % is 0.05)."""
    try:
        values = np.asarray(sigma, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        values = np.array([])
    if isinstance(sigma, str) or values.shape != (2,) or not np.all(np.isfinite(values) & (values > 0)):
        raise InputError(f"{name} must be two positive numbers (focal length fraction, principal point px), got "
                         f"{sigma!r}")
    if values[0] > MAX_FOCAL_FRACTION:
        raise InputError(f"{name}'s focal length sigma is a fraction of the focal length (0.05 for 5 %), at most "
                         f"{MAX_FOCAL_FRACTION:g}, got {values[0]:g}")
    return float(values[0]), float(values[1])


def tracker_floor_px(metadata: dict) -> float:
    """The image axes' prior floor (px) the dataset's tracker wrote (``metadata["tracker"]["axis_floor_px"]``);
    0 when it names none."""
    return _metadata_px(metadata, "tracker", "axis_floor_px")


def tracker_offset_px(metadata: dict) -> float:
    """Each track's own offset (px) the dataset's tracker wrote (``metadata["tracker"]["track_offset_px"]``); 0
    when it names none."""
    return _metadata_px(metadata, "tracker", "track_offset_px")


def camera_motion_level_px(metadata: dict) -> float:
    """The level (px, 1 sigma per image coordinate) of the image shift per pose that the camera's measured move
    between the videos gives (``metadata["camera_motion"]["level_px"]``, :func:`gtsam_rotid.stillness.camera_motion`,
    written by ``make_dataset``); 0 where it was not measured or the camera stayed still."""
    return _metadata_px(metadata, "camera_motion", "level_px")


def with_tracker_defaults(options: CalibrationOptions, metadata: dict) -> CalibrationOptions:
    """``options`` with the tracker's values (:func:`tracker_floor_px`, :func:`tracker_offset_px`) where they are
    None."""
    if options.axis_floor_px is None:
        options = replace(options, axis_floor_px=tracker_floor_px(metadata))
    if options.track_offset_px is None:
        options = replace(options, track_offset_px=tracker_offset_px(metadata))
    return options


def _metadata_px(metadata: dict, section: str, name: str) -> float:
    entry = metadata.get(section)
    value = entry.get(name) if isinstance(entry, dict) else None
    if value is None:
        return 0.0
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
        raise InputError(f"the dataset's metadata[\"{section}\"][\"{name}\"] must be a finite number >= 0 "
                         f"(px), got {value!r}")
    return float(value)
