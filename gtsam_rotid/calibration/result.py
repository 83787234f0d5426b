"""What a calibration returns: the pose, its covariance and the evidence behind them, as data (the words are in
:mod:`gtsam_rotid.words`); saved and loaded as JSON.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from enum import StrEnum

import gtsam
import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..files import write_json
from ..uncertainty import (
    Observability,
)


class OutlierKind(StrEnum):
    """Why a measurement is an outlier (``MeasurementReport.outlier_kind``); the numbers the words need are in
    ``MeasurementReport.outlier_values`` (:func:`gtsam_rotid.words.outlier_words` says it)."""

    #: left out before stage 1: fewer than two usable tracks (no image axis)
    FEW_TRACKS = "few_tracks"
    #: left out: too little evidence for a Gaussian image axis, and enough strong measurements without it
    #: (values: ``used``, how many measurements the estimate used)
    THIN = "thin"
    #: left out: its image axis disagrees with the FK axis projected by the estimate (values: ``limit``, the
    #: chi-square limit; ``short_arc_deg`` when all its arcs are short and its evidence is not thin)
    DISAGREES = "disagrees"
    #: still used: its residual RMS exceeds ``ratio`` times the ``median`` of the measurements' (values)
    RESIDUAL = "residual"
    #: a result file written before the kinds existed: its words (values: ``text``)
    TEXT = "text"


@dataclass
class MeasurementReport:
    index: int
    n_tracks: int
    n_points: int
    residual_rms_px: float
    weight: float  # 1 / sigma^2 applied to its pixels (joint) or its line (two-stage), relative to the median
    outlier: bool
    rejected_tracks: dict[int, str] = field(default_factory=dict)
    #: why the measurement is an outlier (an :class:`OutlierKind` value, "" when it is not) and the numbers that the
    #: words of that reason need
    outlier_kind: str = ""
    outlier_values: dict[str, float | str] = field(default_factory=dict)
    #: the joint that spun (``Measurement.spin_joint``; None: the wrist)
    spin_joint: str | None = None
    #: the FK axis of the spinning joint at this arm pose (arm frame, m): a point on it and its unit direction
    axis_point: list[float] | None = None
    axis_direction: list[float] | None = None
    #: the stage-1 image axis (homogeneous line, ``l1^2 + l2^2 = 1``, ideal pixels)
    image_axis: list[float] | None = None
    #: chi-square (2 dof) of its image axis against the FK axis projected by the estimate (weighted and joint)
    axis_chi2: float | None = None
    #: the covariance (px^2, 2x2) of the distances from its image axis of its FK axis' two test points
    #: (:func:`gtsam_rotid.graph.axis_test_points`) projected by the estimate: its pixel noise at the variance the
    #: fit weighted it by and the joint-angle noise, without the prior floor (``axis_floor_px``); for comparing its
    #: image axis with where another ``arm_T_camera`` (a ground truth) puts the FK axis. Weighted and joint, the
    #: measurements used; None otherwise
    axis_test_covariance: list[list[float]] | None = None
    #: the covariance (px^2, 2x2) that its tracks' own offsets (``track_offset_px``) give the same distances (the
    #: calibration adds it to ``axis_test_covariance`` in the axes' test and in what it passes into the estimate);
    #: None without them
    axis_offset_covariance: list[list[float]] | None = None
    #: the longest arc among its kept tracks (deg, about its fitted circle: :func:`circle_arc_span_deg`; about the
    #: track's own ellipse for a measurement left out before stage 1); None when unknown
    arc_span_deg: float | None = None
    #: too little evidence for a Gaussian image axis: fewer than WEAK_TRACKS kept tracks, or fewer than
    #: WEAK_MANY_TRACKS and no arc of WEAK_ARC_DEG
    weak: bool = False

    @property
    def used(self) -> bool:
        """Whether the estimate uses this measurement (weight > 0). An ``outlier`` for its residual RMS alone is
        still used, down-weighted by its own pixel noise; one left out has weight 0."""
        return self.weight > 0.0


@dataclass
class Alternative:
    """Another ``arm_T_camera`` that the estimator found to explain the data (a distinct local minimum).

    ``delta_chi2`` is its chi-square minus the estimate's, both on the same tracks and pixel noise (the joint
    graph, re-solved from each): ``2 ln`` of the likelihood ratio in favour of the estimate. Where the robust fit
    reached it by leaving out another measurement than the estimate does, ``left_out`` is that measurement's index
    and ``instead_of`` the one the estimate's fit left out at that step (one of the two is wrong, the data do not say
    which); None for another minimum of the same measurements.
    """

    arm_T_camera: gtsam.Pose3
    delta_chi2: float
    left_out: int | None = None
    instead_of: int | None = None

    def to_dict(self) -> dict:
        out = {"arm_T_camera": self.arm_T_camera.matrix().tolist(), "delta_chi2": self.delta_chi2}
        if self.left_out is not None:
            out.update(left_out=self.left_out, instead_of=self.instead_of)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Alternative:
        def index(key):
            return None if data.get(key) is None else int(data[key])

        return cls(gtsam.Pose3(_rigid(data["arm_T_camera"])), float(data["delta_chi2"]), index("left_out"),
                   index("instead_of"))


@dataclass
class AxisConsistency:
    """Do the measurements' rotation axes agree with one ``arm_T_camera`` as closely as their pixel noise says?

    ``chi2`` sums, over the measurements used, the chi-square (2 dof) of each stage-1 image axis against the FK
    axis projected by the pose that fits those axes best (to first order from the estimate), at the line covariance
    the fit assumed (pixel noise from the residuals, cluster-robust over tracks); ``dof`` is ``2 n - 6`` (infinite
    ``chi2``, ``p_value`` 0: the FK axes do not project at the estimate). Errors the per-track noise model does not
    describe (a sub-pixel bias the tracker shares across a measurement's tracks, joint-angle or kinematic errors, wrong
    intrinsics) move whole axes and show here, while every pixel residual looks white. When the test fails
    (``p_value`` < ``CalibrationOptions.axis_consistency_p``, ``consistent`` False) the axes' covariance is taken to
    be understated by a common factor k, which their scatter measures, and the covariance is multiplied by ``scale`` =
    ``chi2 / (dof - 2)``: the mean of k given the scatter (chi2 ~ k chi2(dof), Jeffreys prior 1/k: an inverse-gamma
    posterior). It is the Birge ratio ``chi2 / dof`` (as the Particle Data Group scales inconsistent measurements)
    times ``dof / (dof - 2)``: with k estimated from ``dof`` degrees of freedom the error is Student-t, not Gaussian,
    and this is the Gaussian with its second moment (with six measurements, 6 dof, the Birge ratio alone leaves the
    error's chi-square 1.5x its dof on average). With 2 dof (four measurements) k's mean is unbounded: the scale is
    then the Birge ratio and the result is not trusted (``CalibrationResult.untrusted``: ``unmeasured_scatter``).

    Below the test's threshold ``c0`` (the chi-square at that P) the same reading is taken in part, so that the
    covariance does not jump where the verdict turns (a Jaco2 text scene at P 0.26 against a level of 0.2 kept its
    bare covariance, its error at chi-square 40 under it, where at P 0.19 it would have had all of the scale and the
    floor below): of the excess ``chi2 - (dof - 2)`` a share rising linearly in the chi-square from 0 at upper-tail
    probability min(0.5, 4 x the level) (``tuning.AXIS_SCALE_RAMP``) to all of it at ``c0``
    (:func:`.stage2.axis_excess`). ``scale`` is then ``1 + share x excess / (dof - 2)``, and the floor below takes
    ``share x excess`` off the chi-square instead of bringing it to ``dof - 2``. ``consistent`` stays the test's
    verdict, and so do the verdicts that read it (a troubled result's restarts, the model checks' reading of the
    scatter, ``unmeasured_scatter``, the scale at which the tracks' shapes are judged).

    A common factor is one reading of the scatter; a common floor is the other: a bias that a measurement's tracks
    share (a tracker's drift as the surface turns) does not shrink with more tracks, so the axis of
    a pose with a hundred tracks is no better than that floor, and a factor on its tiny covariance leaves it far too
    confident (a Jaco2 text scene: four axes 0.2-0.3 px off at their test points, 3-4x their 1 sigma; the scaled
    covariance put the error at chi-square 29). ``floor_px`` is the ``tau`` (px) that, added in quadrature to every
    projected test point's distance, brings the chi-square at the estimate to ``dof - 2`` (the same mean given the
    scatter), and the covariance is the larger, direction by direction, of the scaled one and the one with that
    floor (:func:`gtsam_rotid.uncertainty.loewner_max`). Where each track's own offset is declared
    (``CalibrationOptions.track_offset_px`` > 0, as the corner tracker's datasets do), that drift is in the
    covariance already, and the scatter is read by the scale alone (``floor_px`` 0): read as a floor as well, it
    widened the rendered ambient scenes' covariances up to 4x in sigma where the scale alone held their errors.
    """

    chi2: float
    dof: int
    p_value: float
    #: the covariance was multiplied by this (1: consistent, or not scaled)
    scale: float
    #: the axes' common floor (px at the test points; 0: none applied)
    floor_px: float = 0.0
    #: the pose covariance (6x6, Pose3 tangent) that floor adds; used when the result is assembled, not saved
    floor_covariance: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: the test's verdict: ``p_value`` at or above the level it was made at (None: read off ``scale`` == 1, as in
    #: results saved before the scale was continuous in the chi-square)
    passed: bool | None = None
    #: the same axes, every measurement's (the left-out ones too), tested with the camera's focal length and principal
    #: point free (:func:`gtsam_rotid.calibration.modelcheck.intrinsics_check`); None where not run
    intrinsics: dict | None = None
    #: the same axes with an offset of each joint before the spinning one free
    #: (:func:`gtsam_rotid.calibration.modelcheck.kinematics_check`); None where not run
    kinematics: dict | None = None

    @property
    def consistent(self) -> bool:
        """The axes passed the test (their scatter may still have widened the covariance a little, see above)."""
        return self.scale == 1.0 if self.passed is None else bool(self.passed)

    def to_dict(self) -> dict:
        out = {"chi2": self.chi2, "dof": self.dof, "p_value": self.p_value, "scale": self.scale,
               "floor_px": self.floor_px, "consistent": self.consistent}
        if self.intrinsics is not None:
            out["intrinsics"] = dict(self.intrinsics)
        if self.kinematics is not None:
            out["kinematics"] = dict(self.kinematics)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> AxisConsistency:
        intrinsics, kinematics = data.get("intrinsics"), data.get("kinematics")
        passed = data.get("consistent")
        return cls(float(data["chi2"]), int(data["dof"]), float(data["p_value"]), float(data["scale"]),
                   float(data.get("floor_px", 0.0)), intrinsics=None if intrinsics is None else dict(intrinsics),
                   kinematics=None if kinematics is None else dict(kinematics),
                   passed=None if passed is None else bool(passed))


#: The image shift per pose (px) a result's words weigh (``CalibrationResult.image_shift_excess``): about what a
#: camera turning 0.01 degrees between poses gives at a focal length of 570 px.
IMAGE_SHIFT_PX = 0.1

#: An alternative whose chi-square exceeds the estimate's by less than this (likelihood ratio 1000:1) makes the
#: calibration ambiguous: the data cannot tell the two apart.
AMBIGUITY_CHI2 = 2.0 * np.log(1000.0)


@dataclass
class CalibrationResult:
    """``arm_T_camera`` (camera pose in the arm-base frame) with its covariance and diagnostics."""

    arm_T_camera: gtsam.Pose3
    covariance: np.ndarray  # 6x6, Pose3 tangent: rotation (rad) then translation (m, camera frame)
    method: str
    converged: bool
    iterations: int
    final_error: float
    measurements: list[MeasurementReport]
    observability: Observability
    sigma_px: float  # pixel noise estimated from the residuals
    #: residual degrees of freedom of ``final_error``'s graph (residuals minus parameters); 2 * final_error is
    #: its chi-square at the noise the graph assumed
    dof: int | None = None
    #: other local minima the estimator examined (several starts), with how much worse they fit
    alternatives: list[Alternative] = field(default_factory=list)
    #: weighted, joint: the test of the axes against one pose, and the covariance scale it applied
    axis_consistency: AxisConsistency | None = None
    #: the joint-angle sigma (deg) propagated into the covariance (CalibrationOptions.joint_sigma_deg); 0: the
    #: kinematics were taken as exact (always so for ``paper``)
    joint_sigma_deg: float = 0.0
    #: the image axes' prior floor (px) the covariance includes (CalibrationOptions.axis_floor_px, resolved)
    axis_floor_px: float = 0.0
    #: each track's own offset (px) the covariance includes (CalibrationOptions.track_offset_px, resolved)
    track_offset_px: float = 0.0
    #: why the covariance cannot be trusted although the poses determine the calibration (kind -> measurement
    #: indices involved); see :data:`UNTRUSTED_KINDS` and :func:`gtsam_rotid.words.untrusted_words`
    untrusted: dict[str, list[int]] = field(default_factory=dict)
    #: the robot calibrated (:meth:`gtsam_rotid.arm.Arm.description`: name, root link, spinning joint, the links
    #: fixed to the root, a URDF's hash); {} in files written before it was recorded
    robot: dict = field(default_factory=dict)
    #: the dataset calibrated (``path``, ``sha256`` of its files), when it was read from disk ({} otherwise)
    dataset: dict = field(default_factory=dict)
    #: the joint offsets refined with the pose (``CalibrationOptions.joint_offsets``): joint name -> offset (rad; the
    #: reading plus it is the joint's angle); None: the kinematics were taken as given
    joint_offsets: dict[str, float] | None = None
    #: their covariance (rad², in ``joint_offsets``' order; scaled with the pose's when the axes' scatter scaled it)
    joint_offsets_covariance: np.ndarray | None = None
    #: their prior 1 sigma (deg, mean 0)
    joint_offset_sigma_deg: float = 0.0
    #: their cross-covariance with the pose (6 x n: Pose3 tangent by offsets), for re-checking the calibration
    pose_offsets_covariance: np.ndarray | None = None
    #: per refined joint, its URDF ``<origin>`` turned by the offset about its axis (``xyz`` m, ``rpy`` rad, in the
    #: parent link's frame): with it the reading is the joint's angle
    joint_offsets_origins: dict | None = None
    #: the intrinsics refined with the pose (``CalibrationOptions.refine_intrinsics``), in ``INTRINSICS`` order;
    #: () : the camera was taken as given
    refined_intrinsics: tuple = ()
    #: the camera with those intrinsics refined (None: as given)
    camera: Camera | None = None
    #: their covariance (px², in ``refined_intrinsics``' order; scaled with the pose's when the axes' scatter scaled
    #: it)
    intrinsics_covariance: np.ndarray | None = None
    #: their prior 1 sigma (focal fraction, principal point px), centred on the camera file's values
    intrinsics_prior_sigma: tuple | None = None
    #: the camera file's values of the refined intrinsics (name -> px), the prior's mean
    given_intrinsics: dict = field(default_factory=dict)
    #: joint, intrinsics as given: what the tracks' shapes say of them (the intrinsics' Gauss-Newton change from the
    #: estimate with them free, ``change`` and ``sigma`` per name in px, its Wald ``chi2`` for ``dof``, ``p_value``);
    #: None: not checked
    intrinsics_shapes: dict | None = None
    #: joint, synced (``CalibrationOptions.sync_encoders``): the measurements whose spin readings put a prior on
    #: their rigid spin's angles; () : none
    synced: tuple = ()
    #: the clocks' offset, camera minus encoder (s: a reading stamped t was taken when the camera's clock read t +
    #: offset; as ``CalibrationOptions.time_offset_s``), estimated (or held, ``time_offset_sigma_s`` None) in the
    #: synced fit; None: not synced
    time_offset_s: float | None = None
    #: its 1 sigma (s; scaled with the pose's when the axes' scatter scaled it); None: held or not synced
    time_offset_sigma_s: float | None = None
    #: its prior's 1 sigma (s, ``CalibrationOptions.time_offset_sigma_s``); None: held or not synced
    time_offset_prior_sigma_s: float | None = None
    #: the share of the offset's information that the readings' own noise makes (above 0.25 the readings cannot
    #: date the frames and ``time_offset_sigma_s`` is the prior's); None: held or not synced
    time_offset_noise_share: float | None = None
    #: synced with named camera clocks (``SpinReadings.clock``: videos placed on a joint time series one by one),
    #: each clock's offset: clock -> {"offset_s" (camera minus encoder, as ``time_offset_s``), "sigma_s",
    #: "noise_share", "measurements" (its spins)}; the single-offset fields above hold only where there is one
    #: clock. None: one unnamed clock, or not synced
    time_offsets: dict | None = None
    #: the measurements carry spin readings that this method does not use (only ``joint`` with the rigid spin does)
    readings_ignored: bool = False
    #: measurements whose readings were not used: measurement -> {"chi2", "dof"} where they disagreed with their
    #: tracks' spin (the likelihood ratio of their prior, and its degrees of freedom), {"why": "cover", "readings",
    #: "frames"} where they did not cover its frames (first and last, s on the encoder's clock)
    readings_refused: dict = field(default_factory=dict)
    #: two measurements given in each other's place (videos or joint rows in the wrong order, :mod:`.swaps`): with
    #: them exchanged the calibration is sound. ``measurements`` (their indices), ``miss_px`` (the FK axes' miss of
    #: the image axes through the ellipses' centres as given), ``swapped_miss_px`` (exchanged), ``next_miss_px``
    #: (the next best exchange), ``sigma_mm`` (the exchanged calibration's largest 1 sigma); None: not found, or not
    #: looked for (a sound result)
    swapped: dict | None = None
    #: the pose covariance (6x6, Pose3 tangent) per px² of an image shift common to each pose's tracks and
    #: independent across poses (a camera that turns or moves a little between poses): what such a shift would add
    #: to ``covariance``, which the axes' test all but cannot see (README, "An image shift per pose"); None where
    #: not computed (``paper``, an undetermined pose, files written before it was)
    image_shift_covariance: np.ndarray | None = None
    #: where joint offsets or intrinsics were refined, the same per px² for them: ``"offsets"`` (n x n rad², as
    #: ``joint_offsets_covariance``), ``"cross"`` (6 x n, as ``pose_offsets_covariance``), ``"intrinsics"`` (as
    #: ``intrinsics_covariance``); None otherwise
    image_shift_nuisance: dict | None = None
    #: the camera's move between the videos as their still background showed it (the dataset's
    #: ``metadata["camera_motion"]``, :func:`gtsam_rotid.stillness.camera_motion`: ``shifts_px``, ``sigma_px``,
    #: ``floor_px``, ``bound_px``, ...); None where it was not measured
    camera_motion: dict | None = None

    @property
    def intrinsics(self) -> dict[str, float]:
        """The refined intrinsics: name -> value (px); {} when the camera was taken as given."""
        if self.camera is None:
            return {}
        every = self.camera.intrinsics
        return {name: every[name] for name in self.refined_intrinsics}

    @property
    def intrinsics_sigma(self) -> dict[str, float]:
        """1 sigma (px) of each refined intrinsic; {} without refinement or covariance."""
        if not self.refined_intrinsics or self.intrinsics_covariance is None:
            return {}
        return dict(zip(self.refined_intrinsics, np.sqrt(np.diag(self.intrinsics_covariance)).tolist(), strict=True))

    @property
    def ambiguous(self) -> bool:
        """True when another, distinct pose fits the data almost as well (see :data:`AMBIGUITY_CHI2`)."""
        return any(a.delta_chi2 < AMBIGUITY_CHI2 for a in self.alternatives)

    @property
    def covariance_usable(self) -> bool:
        return self.observability.is_observable and not self.ambiguous and not self.untrusted

    @property
    def joint_offsets_sigma_deg(self) -> dict[str, float]:
        """1σ of each refined joint offset (deg); {} when none was refined."""
        if self.joint_offsets is None or self.joint_offsets_covariance is None:
            return {}
        return dict(zip(self.joint_offsets, np.degrees(np.sqrt(np.diag(self.joint_offsets_covariance))).tolist(),
                        strict=True))

    @property
    def sigma_deg(self) -> np.ndarray:
        """1σ of the rotation (roll, pitch, yaw about the camera axes), degrees."""
        return np.degrees(np.sqrt(np.diag(self.covariance)[:3]))

    @property
    def sigma_mm(self) -> np.ndarray:
        """1σ of the translation, mm, in the camera frame (GTSAM's tangent)."""
        return 1000.0 * np.sqrt(np.diag(self.covariance)[3:])

    @property
    def sigma_mm_arm(self) -> np.ndarray:
        """1σ of the camera position in the arm-base frame, mm."""
        R = self.arm_T_camera.rotation().matrix()
        return 1000.0 * np.sqrt(np.diag(R @ self.covariance[3:, 3:] @ R.T))

    def image_shift_sigma(self, px: float = IMAGE_SHIFT_PX) -> tuple[np.ndarray, np.ndarray] | None:
        """The 1σ (camera position in the arm-base frame, mm; rotation about the camera axes, deg) that an image
        shift of ``px`` per pose (``image_shift_covariance``) would add; None where it was not computed."""
        if self.image_shift_covariance is None:
            return None
        S = px**2 * np.asarray(self.image_shift_covariance)
        R = self.arm_T_camera.rotation().matrix()
        return (1000.0 * np.sqrt(np.maximum(np.diag(R @ S[3:, 3:] @ R.T), 0.0)),
                np.degrees(np.sqrt(np.maximum(np.diag(S)[:3], 0.0))))

    def image_shift_excess(self, px: float = IMAGE_SHIFT_PX) -> float | None:
        """How far an image shift of ``px`` per pose would exceed the covariance: the largest, over the pose's
        directions, of the variance it adds over ``covariance``'s (1: as large as the 1σ along some direction; the
        largest generalised eigenvalue). None where it was not computed or the covariance is not positive
        definite."""
        if self.image_shift_covariance is None:
            return None
        try:
            L = np.linalg.cholesky(0.5 * (self.covariance + self.covariance.T))
        except np.linalg.LinAlgError:
            return None
        A = np.linalg.solve(L, np.linalg.solve(L, px**2 * np.asarray(self.image_shift_covariance)).T)
        return float(np.max(np.linalg.eigvalsh(0.5 * (A + A.T))))

    def error_to(self, arm_T_camera_true: gtsam.Pose3) -> np.ndarray:
        """Tangent-space error (rotation rad, translation m) of this estimate against a reference pose."""
        return arm_T_camera_true.localCoordinates(self.arm_T_camera)

    def to_dict(self) -> dict:
        return {
            "format": "gtsam_rotid.calibration",
            "version": 1,
            "method": self.method,
            "arm_T_camera": self.arm_T_camera.matrix().tolist(),
            "covariance": self.covariance.tolist(),
            "covariance_order": "Pose3 tangent: rx, ry, rz (rad), tx, ty, tz (m, camera frame)",
            "covariance_usable": self.covariance_usable,
            "sigma_mm_arm": self.sigma_mm_arm.tolist(),
            "sigma_deg": self.sigma_deg.tolist(),
            "converged": self.converged,
            "iterations": self.iterations,
            "final_error": self.final_error,
            "sigma_px": self.sigma_px,
            "dof": self.dof,
            "measurements": [
                {**asdict(m), "rejected_tracks": {str(k): v for k, v in m.rejected_tracks.items()},
                 "residual_rms_px": m.residual_rms_px if np.isfinite(m.residual_rms_px) else None}
                for m in self.measurements
            ],
            "observability": self.observability.to_dict(),
            "ambiguous": self.ambiguous,
            "alternatives": [a.to_dict() for a in self.alternatives],
            "axis_consistency": None if self.axis_consistency is None else self.axis_consistency.to_dict(),
            "joint_sigma_deg": self.joint_sigma_deg,
            "axis_floor_px": self.axis_floor_px,
            "track_offset_px": self.track_offset_px,
            "untrusted": self.untrusted,
            "robot": self.robot,
            "dataset": self.dataset,
            "joint_offsets": self.joint_offsets,
            "joint_offsets_covariance": None if self.joint_offsets_covariance is None
            else np.asarray(self.joint_offsets_covariance).tolist(),
            "joint_offset_sigma_deg": self.joint_offset_sigma_deg,
            "pose_offsets_covariance": None if self.pose_offsets_covariance is None
            else np.asarray(self.pose_offsets_covariance).tolist(),
            "joint_offsets_origins": self.joint_offsets_origins,
            "refined_intrinsics": list(self.refined_intrinsics),
            "camera": None if self.camera is None else self.camera.to_dict(),
            "intrinsics_covariance": None if self.intrinsics_covariance is None
            else np.asarray(self.intrinsics_covariance).tolist(),
            "intrinsics_prior_sigma": None if self.intrinsics_prior_sigma is None
            else list(self.intrinsics_prior_sigma),
            "given_intrinsics": self.given_intrinsics,
            "intrinsics_shapes": self.intrinsics_shapes,
            "synced": list(self.synced),
            "time_offset_s": self.time_offset_s,
            "time_offset_sigma_s": self.time_offset_sigma_s,
            "time_offset_prior_sigma_s": self.time_offset_prior_sigma_s,
            "time_offset_noise_share": self.time_offset_noise_share,
            "time_offsets": self.time_offsets,
            "readings_refused": {str(k): v for k, v in self.readings_refused.items()},
            "readings_ignored": self.readings_ignored,
            "swapped": self.swapped,
            "image_shift_covariance": None if self.image_shift_covariance is None
            else np.asarray(self.image_shift_covariance).tolist(),
            "image_shift_nuisance": None if self.image_shift_nuisance is None
            else {k: np.asarray(v).tolist() for k, v in self.image_shift_nuisance.items()},
            "camera_motion": self.camera_motion,
        }

    @classmethod
    def from_dict(cls, data: dict) -> CalibrationResult:
        if data.get("format") != "gtsam_rotid.calibration":
            raise InputError("not a gtsam_rotid calibration result (missing format marker)")
        return cls(
            arm_T_camera=gtsam.Pose3(_rigid(data["arm_T_camera"])),
            covariance=np.array(data["covariance"]),
            method=data["method"],
            converged=data["converged"],
            iterations=data["iterations"],
            final_error=data["final_error"],
            sigma_px=data["sigma_px"],
            dof=data.get("dof"),
            measurements=[_measurement_from_dict(m) for m in data["measurements"]],
            observability=Observability.from_dict(data["observability"]),
            alternatives=[Alternative.from_dict(a) for a in data.get("alternatives", [])],
            axis_consistency=None if data.get("axis_consistency") is None
            else AxisConsistency.from_dict(data["axis_consistency"]),
            joint_sigma_deg=float(data.get("joint_sigma_deg", 0.0)),
            axis_floor_px=float(data.get("axis_floor_px", 0.0)),
            track_offset_px=float(data.get("track_offset_px", 0.0)),
            untrusted={str(k): [int(i) for i in v] for k, v in data.get("untrusted", {}).items()},
            robot=dict(data.get("robot") or {}),
            dataset=dict(data.get("dataset") or {}),
            joint_offsets=None if data.get("joint_offsets") is None
            else {str(k): float(v) for k, v in data["joint_offsets"].items()},
            joint_offsets_covariance=None if data.get("joint_offsets_covariance") is None
            else np.array(data["joint_offsets_covariance"], dtype=float),
            joint_offset_sigma_deg=float(data.get("joint_offset_sigma_deg", 0.0)),
            pose_offsets_covariance=None if data.get("pose_offsets_covariance") is None
            else np.array(data["pose_offsets_covariance"], dtype=float),
            joint_offsets_origins=None if data.get("joint_offsets_origins") is None
            else {str(k): {"xyz": [float(x) for x in v["xyz"]], "rpy": [float(x) for x in v["rpy"]]}
                  for k, v in data["joint_offsets_origins"].items()},
            refined_intrinsics=tuple(str(n) for n in data.get("refined_intrinsics") or ()),
            camera=None if data.get("camera") is None else Camera.from_dict(data["camera"]),
            intrinsics_covariance=None if data.get("intrinsics_covariance") is None
            else np.array(data["intrinsics_covariance"], dtype=float),
            intrinsics_prior_sigma=None if data.get("intrinsics_prior_sigma") is None
            else tuple(float(x) for x in data["intrinsics_prior_sigma"]),
            given_intrinsics={str(k): float(v) for k, v in (data.get("given_intrinsics") or {}).items()},
            intrinsics_shapes=data.get("intrinsics_shapes"),
            synced=tuple(int(k) for k in data.get("synced") or ()),
            time_offset_s=None if data.get("time_offset_s") is None else float(data["time_offset_s"]),
            time_offset_sigma_s=None if data.get("time_offset_sigma_s") is None
            else float(data["time_offset_sigma_s"]),
            time_offset_prior_sigma_s=None if data.get("time_offset_prior_sigma_s") is None
            else float(data["time_offset_prior_sigma_s"]),
            time_offset_noise_share=None if data.get("time_offset_noise_share") is None
            else float(data["time_offset_noise_share"]),
            time_offsets=None if data.get("time_offsets") is None else {
                str(c): {"offset_s": float(v["offset_s"]),
                         "sigma_s": None if v.get("sigma_s") is None else float(v["sigma_s"]),
                         "noise_share": None if v.get("noise_share") is None else float(v["noise_share"]),
                         "measurements": [int(k) for k in v.get("measurements") or ()]}
                for c, v in data["time_offsets"].items()},
            readings_refused={int(k): dict(v) for k, v in (data.get("readings_refused") or {}).items()},
            readings_ignored=bool(data.get("readings_ignored", False)),
            swapped=None if data.get("swapped") is None else {
                "measurements": [int(k) for k in data["swapped"]["measurements"]],
                **{k: None if data["swapped"].get(k) is None else float(data["swapped"][k])
                   for k in ("miss_px", "swapped_miss_px", "next_miss_px", "sigma_mm")}},
            image_shift_covariance=None if data.get("image_shift_covariance") is None
            else np.array(data["image_shift_covariance"], dtype=float),
            image_shift_nuisance=None if data.get("image_shift_nuisance") is None
            else {str(k): np.array(v, dtype=float) for k, v in data["image_shift_nuisance"].items()},
            camera_motion=None if data.get("camera_motion") is None else dict(data["camera_motion"]),
        )

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        write_json(path, self.to_dict(), overwrite, indent=1)

    @classmethod
    def load(cls, path: str | os.PathLike) -> CalibrationResult:
        with open(path, encoding="utf-8") as handle:
            return cls.from_dict(json.load(handle))


#: Why a determined calibration's covariance is not trusted (keys of ``CalibrationResult.untrusted``).
UNTRUSTED_KINDS = {
    "swapped": "two measurements look swapped: each one's tracks fit the other's joint angles (videos or joint rows "
               "in the wrong order)",
    "thin_evidence": "the estimate rests on weak measurements (few tracks or short arcs) that nothing vouches for",
    "inconsistent": "the measurements disagree far beyond their noise",
    "inconsistent_after_outliers": "with the measurements that disagree left out, the others still disagree far "
                                   "beyond their noise: more than one measurement is wrong, or the model (camera, "
                                   "kinematics) is off",
    "too_uncertain": "the uncertainty is too large to be a calibration",
    "unmeasured_scatter": "the measurements disagree beyond their noise and are too few to measure by how much",
    "intrinsics": "the camera's focal length or principal point explains the axes' disagreement better than the "
                  "joint angles do",
    "kinematics": "offsets of the joints' zero positions explain the axes' disagreement better than one wrong "
                  "measurement does",
    "camera_or_measurement": "changed intrinsics explain the axes' disagreement, and so does one wrong measurement "
                             "(still used, or left out where the camera's explanation puts the camera elsewhere)",
    "intrinsics_shapes": "the tracks' shapes ask for other intrinsics than the camera file's, by more than their "
                         "uncertainty and than a calibrated camera is off",
    "kinematics_or_measurement": "offsets of the joints' zero positions explain the axes' disagreement, and so does "
                                 "one wrong measurement: the two put the camera apart beyond its covariance",
}


def _measurement_from_dict(m: dict) -> MeasurementReport:
    """A measurement's report from a result file; a file of before the outlier kinds keeps its words (TEXT)."""
    m = dict(m)
    text = m.pop("outlier_reason", None)
    if text and not m.get("outlier_kind"):
        m["outlier_kind"], m["outlier_values"] = OutlierKind.TEXT.value, {"text": str(text)}
    return MeasurementReport(**{**m, "rejected_tracks": {int(k): v for k, v in m["rejected_tracks"].items()},
                                "residual_rms_px": np.nan if m["residual_rms_px"] is None else m["residual_rms_px"]})


def _rigid(matrix) -> np.ndarray:
    """A result file's ``arm_T_camera`` as a 4x4 array, or an InputError saying how it is not a rigid transform (a
    rotation and a translation): gtsam would take a scaled or sheared matrix without a word."""
    M = np.array(matrix, dtype=float)
    if M.shape != (4, 4):
        raise InputError(f"arm_T_camera must be a 4x4 matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InputError("arm_T_camera has NaN or infinite entries")
    R = M[:3, :3]
    problems = []
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        problems.append(f"its last row is {M[3].tolist()}, not [0, 0, 0, 1]")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        problems.append(f"its 3x3 block is not orthonormal (R^T R - I up to {np.max(np.abs(R.T @ R - np.eye(3))):.3g})")
    elif np.linalg.det(R) < 0:
        problems.append("its 3x3 block is a reflection (determinant -1)")
    if problems:
        raise InputError("arm_T_camera is not a rigid transform: " + "; ".join(problems))
    return M
