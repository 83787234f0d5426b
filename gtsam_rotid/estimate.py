"""Estimators of ``arm_T_camera`` (docs/design.md §4): ``paper``, ``weighted`` and ``joint`` (default).

All three start from the same guess-free initial value (:mod:`gtsam_rotid.initialise`): ellipse
centres give each measurement's projected axis, the back-projected planes and the FK axes give pose
candidates on an SO(3) grid, and LM on the projected-axis distances picks the best candidate.

- ``paper``: stage 1 fits coaxial circles per measurement (Rot3 line + (d, r) per track); its
  projected axis is the measurement z_k. Stage 2: LM on the distances of projected FK test points to
  z_k, unweighted, with random restarts; covariance (JᵀJ)⁻¹ (unit noise), as the seed paper does.
- ``weighted``: the same two stages, stage 2 weighted by each line's stage-1 Marginals covariance
  scaled by the stage-1 residual variance (χ²/dof), with a Huber kernel on whole measurements.
- ``joint``: one graph with every circle-point factor and the projected-axis ties to the Pose3,
  per-measurement noise scale from the residuals, outlier tracks rejected, covariance from
  ``gtsam.Marginals`` of the whole graph.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum

import gtsam
import numpy as np

from .arm import Arm
from .camera import Camera
from .dataset import Dataset, Measurement, Track
from .errors import InputError, RotIdError
from .factors import (
    chunk_segments,
    closest_phases,
    image_line_from_rot3,
    initial_spin,
    line_distance_covariance,
    line_distances,
    make_axis_to_line_factor,
    make_axis_to_line_variable_factor,
    make_circle_point_factor,
    make_rigid_circle_factor,
    rot3_from_line,
    spin_priors,
)
from .factors.rigid import DEFAULT_CHUNK_SIZE
from .files import write_json
from .graph import (
    CIRCLE_STRIDE,
    MIN_TRACK_EXTENT_PX,
    MIN_TRACK_POINTS,
    MeasurementKeys,
    Model,
    PreparedMeasurement,
    RotIdGraph,
    align_line,
    axis_test_points,
    chi2_quantile,
    initial_circle,
    lm_params,
    tie_noise_model,
    track_huber,
)
from .initialise import initial_image_axis, line_through_points, plane_normal, pose_candidates
from .uncertainty import (
    Observability,
    analyse_observability,
    chi2_sf,
    marginal_information,
    pose_information,
    sandwich_marginal,
)

MIN_MEASUREMENTS = 3
#: Fewest tracks (all measurements) from which stage 1 estimates how much their noise levels differ.
MIN_TRACKS_FOR_SPREAD = 8


class Method(StrEnum):
    PAPER = "paper"
    WEIGHTED = "weighted"
    JOINT = "joint"


class SpinModel(StrEnum):
    """How the phases of one spin's features are modelled (``CalibrationOptions.spin_model``)."""

    #: a free phase per observation
    FREE = "free"
    #: one wrist angle per frame and one phase per track (tracks with frame indices, line model only)
    RIGID = "rigid"


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
    #: Joint method: ``"free"`` phase per observation, or ``"rigid"`` spin (one wrist angle per frame and one
    #: phase per track, docs/design.md §4; for tracks with frame indices, line model only). Rigid is slower.
    spin_model: str = "free"
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
        if not (np.isfinite(self.joint_sigma_deg) and self.joint_sigma_deg >= 0.0):
            raise InputError(f"CalibrationOptions.joint_sigma_deg must be a finite value >= 0 (deg), got "
                             f"{self.joint_sigma_deg}")


@dataclass
class MeasurementReport:
    index: int
    n_tracks: int
    n_points: int
    residual_rms_px: float
    weight: float  # 1 / sigma^2 applied to its pixels (joint) or its line (two-stage), relative to the median
    outlier: bool
    rejected_tracks: dict[int, str] = field(default_factory=dict)
    #: why the measurement is an outlier ("" when it is not)
    outlier_reason: str = ""
    #: the FK wrist axis of this arm pose (arm frame, m): a point on it and its unit direction
    axis_point: list[float] | None = None
    axis_direction: list[float] | None = None
    #: the stage-1 image axis (homogeneous line, ``l1^2 + l2^2 = 1``, ideal pixels)
    image_axis: list[float] | None = None
    #: chi-square (2 dof) of its image axis against the FK axis projected by the estimate (weighted and joint)
    axis_chi2: float | None = None
    #: the longest arc among its kept tracks (deg, about its fitted circle: :func:`circle_arc_span_deg`; about the
    #: track's own ellipse for a measurement left out before stage 1); None when unknown
    arc_span_deg: float | None = None
    #: too little evidence for a Gaussian image axis: fewer than WEAK_TRACKS kept tracks, or fewer than
    #: WEAK_MANY_TRACKS and no arc of WEAK_ARC_DEG
    weak: bool = False


@dataclass
class Alternative:
    """Another ``arm_T_camera`` that the estimator found to explain the data (a distinct local minimum).

    ``delta_chi2`` is its chi-square minus the estimate's, both on the same tracks and pixel noise (the joint
    graph, re-solved from each): ``2 ln`` of the likelihood ratio in favour of the estimate.
    """

    arm_T_camera: gtsam.Pose3
    delta_chi2: float

    def to_dict(self) -> dict:
        return {"arm_T_camera": self.arm_T_camera.matrix().tolist(), "delta_chi2": self.delta_chi2}

    @classmethod
    def from_dict(cls, data: dict) -> Alternative:
        return cls(gtsam.Pose3(np.array(data["arm_T_camera"])), float(data["delta_chi2"]))


@dataclass
class AxisConsistency:
    """Do the measurements' rotation axes agree with one ``arm_T_camera`` as closely as their pixel noise says?

    ``chi2`` sums, over the measurements used, the chi-square (2 dof) of each stage-1 image axis against the FK
    axis projected by the estimate, at the line covariance the fit assumed (pixel noise from the residuals,
    cluster-robust over tracks); ``dof`` is ``2 n - 6``. Errors the per-track noise model does not describe
    (a sub-pixel bias the tracker shares across a measurement's tracks, joint-angle or kinematic errors, wrong
    intrinsics) move whole axes and show here, while every pixel residual looks white. When the test fails
    (``p_value`` < ``CalibrationOptions.axis_consistency_p``) the axes' covariance is taken to be understated by a
    common factor k, which their scatter measures, and the covariance is multiplied by ``scale`` =
    ``chi2 / (dof - 2)``: the mean of k given the scatter (chi2 ~ k chi2(dof), Jeffreys prior 1/k: an inverse-gamma
    posterior). It is the Birge ratio ``chi2 / dof`` (as the Particle Data Group scales inconsistent measurements)
    times ``dof / (dof - 2)``: with k estimated from ``dof`` degrees of freedom the error is Student-t, not Gaussian,
    and this is the Gaussian with its second moment (with six measurements, 6 dof, the Birge ratio alone leaves the
    error's chi-square 1.5x its dof on average). With 2 dof (four measurements) k's mean is unbounded: the scale is
    then the Birge ratio and the result is not trusted (``CalibrationResult.untrusted``: ``unmeasured_scatter``).
    """

    chi2: float
    dof: int
    p_value: float
    #: the covariance was multiplied by this (1: consistent, or not scaled)
    scale: float

    @property
    def consistent(self) -> bool:
        return self.scale == 1.0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> AxisConsistency:
        return cls(float(data["chi2"]), int(data["dof"]), float(data["p_value"]), float(data["scale"]))


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
    #: why the covariance cannot be trusted although the poses determine the calibration (kind -> measurement
    #: indices involved); see :data:`UNTRUSTED_KINDS` and :func:`gtsam_rotid.words.untrusted_words`
    untrusted: dict[str, list[int]] = field(default_factory=dict)

    @property
    def ambiguous(self) -> bool:
        """True when another, distinct pose fits the data almost as well (see :data:`AMBIGUITY_CHI2`)."""
        return any(a.delta_chi2 < AMBIGUITY_CHI2 for a in self.alternatives)

    @property
    def covariance_usable(self) -> bool:
        return self.observability.is_observable and not self.ambiguous and not self.untrusted

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
            "untrusted": self.untrusted,
        }

    @classmethod
    def from_dict(cls, data: dict) -> CalibrationResult:
        if data.get("format") != "gtsam_rotid.calibration":
            raise InputError("not a gtsam_rotid calibration result (missing format marker)")
        return cls(
            arm_T_camera=gtsam.Pose3(np.array(data["arm_T_camera"])),
            covariance=np.array(data["covariance"]),
            method=data["method"],
            converged=data["converged"],
            iterations=data["iterations"],
            final_error=data["final_error"],
            sigma_px=data["sigma_px"],
            dof=data.get("dof"),
            measurements=[
                MeasurementReport(**{**m, "rejected_tracks": {int(k): v for k, v in m["rejected_tracks"].items()},
                                     "residual_rms_px": np.nan if m["residual_rms_px"] is None
                                     else m["residual_rms_px"]})
                for m in data["measurements"]
            ],
            observability=Observability.from_dict(data["observability"]),
            alternatives=[Alternative.from_dict(a) for a in data.get("alternatives", [])],
            axis_consistency=None if data.get("axis_consistency") is None
            else AxisConsistency.from_dict(data["axis_consistency"]),
            joint_sigma_deg=float(data.get("joint_sigma_deg", 0.0)),
            untrusted={str(k): [int(i) for i in v] for k, v in data.get("untrusted", {}).items()},
        )

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        write_json(path, self.to_dict(), overwrite, indent=1)

    @classmethod
    def load(cls, path: str | os.PathLike) -> CalibrationResult:
        with open(path, encoding="utf-8") as handle:
            return cls.from_dict(json.load(handle))


#: Why a determined calibration's covariance is not trusted (keys of ``CalibrationResult.untrusted``).
UNTRUSTED_KINDS = {
    "thin_evidence": "the estimate rests on weak measurements (few tracks or short arcs) that nothing vouches for",
    "inconsistent": "the measurements disagree far beyond their noise",
    "too_uncertain": "the uncertainty is too large to be a calibration",
    "unmeasured_scatter": "the measurements disagree beyond their noise and are too few to measure by how much",
}


# ---------------------------------------------------------------------------------------------------
# helpers

POSE_KEY = gtsam.symbol("T", 0)
#: Sigma (rad and m) of the weak prior that holds the pose at its start, in the joint graph, along
#: directions the data leave undetermined (information 1 against >= 1e7 for a determined direction at
#: pixel noise: no measurable pull otherwise). Stage 2 needs none: its LM damps isotropically.
ANCHOR_SIGMA = 1.0
#: LM stops once two iterations in a row move the stage-1 image axis (at the corners of the tracks'
#: bounding box) by less than this (px), or the joint pose by less than WATCH_POSE (rad and m), both per
#: pixel of residual RMS.
WATCH_LINE_PX = 1e-4
WATCH_POSE = 1e-7
#: A twin pose (see :func:`twin_pose`) is kept as a second start when LM leaves it at least this far (deg)
#: from the best start and its image-axis error is below this multiple of the best (+ 1 px^2).
TWIN_MIN_ANGLE_DEG = 10.0
TWIN_ERROR_RATIO = 4.0
#: Paper method: restart minima whose error (unit-noise px^2) is within this of the lowest are tied.
TIE_PX2 = 0.5
#: Two results turned less than this (deg) from each other are the same solution when no covariance can say.
SAME_ANGLE_DEG = 1.0
#: 99.9 % point of chi-square with 6 dof.
CHI2_6_999 = 22.457744484825326
#: At most this many starts (the best, other minima of the image-axis fit, the twin) go on to the circle fits.
MAX_STARTS = 4
#: The image-axis (stage-2) graphs hold the pose near the start along directions whose information is below this
#: fraction of the largest (reference scene: >= 8e-4; single crossing: ~3e-6), by a prior of sigma GAUGE_SIGMA
#: (rad, m); see :func:`_gauge_prior`.
WEAK_RELATIVE = 1e-4
GAUGE_SIGMA = 0.1
GAUGE_FLOOR = 1e-8
#: Stage 1 redoes a measurement with circle variables when LM on the projected model lowers the error by less than
#: this fraction (it stalled at its start).
STALL_DECREASE = 1e-3
#: LM iterations of one stage-1 round (the reference scene needs 10-40; far more only for hopeless starts, e.g.
#: wrong joint angles, which the stage-2 checks then report).
STAGE1_MAX_ITERATIONS = 60
#: Stage 1's fits of one measurement, each after rejecting the tracks the one before flagged.
STAGE1_ROUNDS = 4
#: LM iterations allowed from the twin start.
TWIN_ITERATIONS = 20
#: A measurement with fewer kept tracks than WEAK_TRACKS, or fewer than WEAK_MANY_TRACKS and no arc of WEAK_ARC_DEG,
#: is weak: its image axis need not be Gaussian (see :func:`_second_opinion`), so an inconsistency it takes part in
#: is not scaled away. Many short arcs are not weak: their errors average (the rendered reference scene's end-on pose
#: has 60 tracks of at most 50 degrees, and its covariance holds).
WEAK_TRACKS = 4
WEAK_MANY_TRACKS = 20
WEAK_ARC_DEG = 90.0
#: When the axes disagree, weak measurements are left out if at least this many strong ones remain (the pose with
#: redundancy to test it).
MIN_STRONG = 4
#: An arc's span is taken between these quantiles of its points' angles (and the upper one's complement).
ARC_TRIM = 0.05
#: An axis-consistency scale (chi2/dof) above this is not a modest understatement of the noise but a wrong model.
MAX_CONSISTENCY_SCALE = 100.0
#: A 1-sigma camera position larger than this fraction of its distance to the wrist, or a 1-sigma rotation larger
#: than MAX_SIGMA_DEG, is no calibration: an error of that size changes the geometry the covariance was linearised
#: in (a rendered Panda scene: 1 sigma of 104 mm and 6 deg at 1.16 m, 102 mm off with a chi-square of 994 in 6 dof).
MAX_RELATIVE_SIGMA = 0.05
MAX_SIGMA_DEG = 2.0
#: The cluster-robust covariance's leverage correction (CR2, :func:`_track_correlation`) takes no track's leverage
#: above this (at most a sqrt(10) larger score).
MAX_TRACK_LEVERAGE = 0.9
#: The joint fit is restarted (:func:`_restarted`) when its axis-consistency test has a P value below this.
RESTART_P = 1e-3
#: Restarts leave out, in turn, this many of the measurements that disagree most with the estimate.
RESTART_LEAVE_OUT = 3
#: A restart's start within this (m) and SAME_ANGLE_DEG of the estimate is the same start.
RESTART_SAME_M = 1e-3
#: stage 1 is fitted again from the pose its lines give while that pose moves more than these (deg, m), in at
#: most this many fits (:func:`_refined_stage1`), where some measurement has only short arcs
REFINE_DEG = 0.5
REFINE_M = 0.005
REFINE_PASSES = 6
#: the prior (rad) that holds a refit's start line while its circles settle (:func:`_stage1_round`, ``settle``)
HOLD_SIGMA_RAD = 1e-4
#: the default ``CalibrationOptions.axis_consistency_p`` with and without short arcs (see ``_calibrate``)
SHORT_ARC_CONSISTENCY_P = 0.2
LONG_ARC_CONSISTENCY_P = 0.01
#: stage 1's jackknife (:func:`_jackknife`): groups of tracks, the fewest it needs, and the point of its scatter
#: under the model beyond which it replaces the linearised line covariance
JACKKNIFE_GROUPS = 12
JACKKNIFE_MIN_GROUPS = 4
JACKKNIFE_Z = 3.40  # the normal's 99.97 % point: 99.9 % Bonferroni over the 3 directions


def _lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int, anchor: bool = False,
        diagonal_damping: bool = True, relative_tolerance: float = 1e-8, watch=None, watch_tolerance: float = 0.0):
    """LM; with ``anchor`` a weak prior at the start of ``POSE_KEY`` keeps undetermined directions still.

    Diagonal damping suits the graphs with line and circle variables (their Jacobians differ in scale by
    orders of magnitude); isotropic damping never steps along a direction of exactly zero information,
    which keeps a degenerate stage 2 where it started. ``watch(values) -> vector`` names what the solve is
    for (an image line, the pose): LM also stops once two successive iterations change it by less than
    ``watch_tolerance`` (each axis' tilt within its projection plane, a nuisance, can otherwise crawl on
    for tens of iterations); the tolerance is scaled by the residual RMS in pixels. The returned error is that
    of ``graph`` alone.
    """
    if anchor:
        anchored = gtsam.NonlinearFactorGraph()
        anchored.push_back(graph)
        anchored.add(gtsam.PriorFactorPose3(POSE_KEY, values.atPose3(POSE_KEY),
                                            gtsam.noiseModel.Isotropic.Sigma(6, ANCHOR_SIGMA)))
        result, iterations, _, converged = _lm(anchored, values, max_iterations,
                                               diagonal_damping=diagonal_damping,
                                               relative_tolerance=relative_tolerance, watch=watch,
                                               watch_tolerance=watch_tolerance)
        return result, iterations, graph.error(result), converged
    params = lm_params(max_iterations, relative_tolerance, diagonal_damping)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    if watch is None:
        result = optimizer.optimize()
        converged = optimizer.iterations() < max_iterations
        return result, optimizer.iterations(), graph.error(result), converged
    error, watched, quiet = optimizer.error(), watch(values), 0
    n_residuals = sum(graph.at(i).dim() for i in range(graph.size()))
    converged = False
    while optimizer.iterations() < max_iterations:
        optimizer.iterate()
        new_error, new_watched = optimizer.error(), watch(optimizer.values())
        # the tolerance is per pixel of residual RMS, so noise-free data converge to noise-free precision
        rms = np.sqrt(2.0 * new_error / max(n_residuals, 1))
        quiet = quiet + 1 if np.max(np.abs(new_watched - watched)) < watch_tolerance * rms else 0
        small_decrease = error - new_error <= relative_tolerance * max(error, 1e-300)
        error, watched = new_error, new_watched
        if quiet >= 2 or small_decrease or optimizer.lambda_() >= params.getlambdaUpperBound():
            converged = True
            break
    result = optimizer.values()
    return result, optimizer.iterations(), graph.error(result), converged


def _builder(arm: Arm, camera: Camera, options: CalibrationOptions, **kwargs) -> RotIdGraph:
    return RotIdGraph(arm, camera, pose_key=POSE_KEY, tie_sigma_px=options.tie_sigma_px,
                      min_track_points=options.min_track_points, min_track_extent_px=options.min_track_extent_px,
                      **kwargs)


@dataclass
class _Setup:
    axes: list  # FK wrist axes (Line3, arm frame)
    prepared: list[PreparedMeasurement]
    lines: list[np.ndarray]  # initial image axes through the ellipse centres
    #: per measurement, the axis' test points' derivative by each joint angle times its sigma, (6, n_joints), or
    #: None (exact kinematics)
    axis_noise: list[np.ndarray | None] = field(default_factory=list)
    #: the caller's index of each measurement here (measurements without enough evidence are left out before)
    index: list[int] = field(default_factory=list)
    K: np.ndarray | None = None  # the camera matrix
    #: k -> the evidence of measurements whose stage-1 fit is weak (for the words of a refusal)
    weak: dict[int, str] = field(default_factory=dict)
    #: the weak measurements left out because enough strong ones determine the pose without them
    dropped: set[int] = field(default_factory=set)
    #: k -> the longest arc (deg, ``turning``) of measurements with enough tracks but none of WEAK_ARC_DEG: a
    #: tracker's drift along short arcs can put their image axes off (for the words that name a likely cause)
    short: dict[int, float] = field(default_factory=dict)
    #: per measurement, the longest turn of a usable track's direction of motion (deg, :func:`_turning_deg`)
    turning: list[float] = field(default_factory=list)

    def noise(self, k: int) -> np.ndarray | None:
        return self.axis_noise[k] if self.axis_noise else None

    @property
    def short_arcs(self) -> bool:
        """Some measurement has no track that turns by WEAK_ARC_DEG: stage 1 is then refitted from its own
        estimate and jackknifed, and the axes' scatter scales the covariance at a lower level (``_calibrate``)."""
        return any(t < WEAK_ARC_DEG for t in self.turning)


def _setup(arm: Arm, camera: Camera, measurements: list[Measurement], options: CalibrationOptions) -> _Setup:
    if len(measurements) < MIN_MEASUREMENTS:
        raise InputError(f"need at least {MIN_MEASUREMENTS} measurements (arm poses) to calibrate, "
                         f"got {len(measurements)}")
    builder = _builder(arm, camera, options)
    axes, prepared, lines = [], [], []
    for k, m in enumerate(measurements):
        axes.append(arm.wrist_axis(m.joint_angles))
        prep = builder.prepare(m, k)
        if len(prep.usable) < 2:
            reasons = "; ".join(f"track {j}: {why}" for j, why in prep.rejected.items())
            raise InputError(f"measurement {k}: only {len(prep.usable)} usable track(s), need at least 2 "
                             f"(rejected: {reasons})")
        prepared.append(prep)
        lines.append(initial_image_axis([t.ellipse for t in prep.usable.values()]))
    noise = []
    if options.joint_sigma_deg > 0.0:
        sigma = np.radians(options.joint_sigma_deg)
        noise = [sigma * test_point_jacobian(arm, m.joint_angles) for m in measurements]
    turning = [max((_turning_deg(t.ideal) for t in p.usable.values()), default=0.0) for p in prepared]
    return _Setup(axes, prepared, lines, noise, list(range(len(measurements))), camera.K, turning=turning)


def test_point_jacobian(arm: Arm, joint_angles, step: float = 1e-6) -> np.ndarray:
    """(6, n_joints): derivative of the wrist axis' two FK test points (arm frame, m, stacked) by each joint angle
    (rad), by central differences."""
    q = np.asarray(joint_angles, dtype=float)
    J = np.empty((6, q.size))
    for j in range(q.size):  # one forward kinematics per joint and side
        dq = np.zeros_like(q)
        dq[j] = step
        plus = axis_test_points(arm.wrist_axis(q + dq)).ravel()
        minus = axis_test_points(arm.wrist_axis(q - dq)).ravel()
        J[:, j] = (plus - minus) / (2.0 * step)
    return J


def joint_tie_covariance(camera: Camera, axis, line: np.ndarray | None, pose: gtsam.Pose3,
                         noise: np.ndarray | None, step: float = 1e-3) -> np.ndarray | None:
    """(2, 2) covariance (px²) of the distances of ``axis``' projected test points to the image ``line`` that
    the joint-angle noise causes (``noise``: :func:`test_point_jacobian` times each joint's sigma), to first order;
    None when ``noise`` is None. ``line`` None: the axis' own image under ``pose``."""
    if noise is None:
        return None
    points = axis_test_points(axis)

    def projected(p):
        return camera.project(np.array([pose.transformTo(x) for x in p]), distort=False)

    line = line_through_points(projected(points)) if line is None else line

    def distances(p):
        return line_distances(line, projected(p))

    # one column per joint: the distances' change along that joint's 1-sigma displacement of the test points
    D = np.column_stack([(distances(points + step * c.reshape(2, 3)) - distances(points - step * c.reshape(2, 3)))
                         / (2.0 * step) for c in noise.T])
    return D @ D.T


def _stage2_graph(axes, lines, K, noises) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for axis, line, noise in zip(axes, lines, noises, strict=True):
        graph.add(make_axis_to_line_factor(noise, POSE_KEY, axis_test_points(axis), line, K))
    return graph


def _gauge_prior(graph: gtsam.NonlinearFactorGraph, anchor: gtsam.Pose3,
                 scale: float = 1.0) -> gtsam.PriorFactorPose3 | None:
    """A prior at ``anchor`` along the pose directions the image-axis graph leaves (nearly) undetermined there.

    Pixel noise tilts the cost along such a direction (single crossing: the camera's ray to the crossing point,
    where the noisy image axes fit better the farther the camera) and LM would slide the camera metres, even
    kilometres, along it. Directions whose information is below ``WEAK_RELATIVE`` of the largest get a prior of
    sigma ``GAUGE_SIGMA`` (rad, m); the others one of information ``GAUGE_FLOOR`` (it moves nothing there: the
    data's information is >= 1e5 times larger), so that the prior is a full-rank Gaussian. None when nothing is
    weak. ``scale`` multiplies the prior's information: a graph whose noise models are not the data's (the paper's
    unit line noise) passes the variance those units stand for, so that the prior pulls as hard, relative to the
    data, as in a graph weighted by the real noise.
    """
    values = gtsam.Values()
    values.insert(POSE_KEY, anchor)
    information = pose_information(graph, values, POSE_KEY)
    if not np.all(np.isfinite(information)):  # e.g. test points behind the camera: no sensible gauge there
        return None
    w, V = np.linalg.eigh(information)
    weak = w < WEAK_RELATIVE * max(w.max(), 1e-300)
    if not weak.any():
        return None
    prior = scale * np.where(weak, GAUGE_SIGMA**-2, GAUGE_FLOOR)
    return gtsam.PriorFactorPose3(POSE_KEY, anchor, gtsam.noiseModel.Gaussian.Information((V * prior) @ V.T))


def _stage2_minima(graph, starts, options, max_iterations: int | None = None, anchor: gtsam.Pose3 | None = None,
                   gauge_scale: float = 1.0) -> list[tuple[gtsam.Pose3, float, int, int]]:
    """LM from each start, with the :func:`_gauge_prior` at ``anchor`` (default: at the start); (pose, error,
    iterations, index of the start) per start, in the order of ``starts``."""
    out = []
    for i, start in enumerate(starts):
        values = gtsam.Values()
        values.insert(POSE_KEY, start)
        gauged = graph
        prior = _gauge_prior(graph, start if anchor is None else anchor, gauge_scale)
        if prior is not None:
            gauged = gtsam.NonlinearFactorGraph()
            gauged.push_back(graph)
            gauged.add(prior)
        result, iterations, _, _ = _lm(gauged, values, max_iterations or options.max_iterations,
                                       diagonal_damping=False)
        out.append((result.atPose3(POSE_KEY), graph.error(result), iterations, i))
    return out


def _best_stage2(graph, starts, options, max_iterations: int | None = None,
                 anchor: gtsam.Pose3 | None = None) -> tuple[gtsam.Pose3, float, int, int]:
    """(pose, error, iterations, index of the start) of the lowest error of :func:`_stage2_minima`."""
    return min(_stage2_minima(graph, starts, options, max_iterations, anchor), key=lambda m: m[1])


def _distinct(pose: gtsam.Pose3, others) -> bool:
    """``pose`` is turned more than TWIN_MIN_ANGLE_DEG from each of ``others`` (positions are not compared: along
    an undetermined direction they differ arbitrarily between starts of the same solution)."""
    return all(_turned(other, pose) > np.radians(TWIN_MIN_ANGLE_DEG) for other in others)


def _random_restarts(pose: gtsam.Pose3, n: int, rng: np.random.Generator) -> list[gtsam.Pose3]:
    out = []
    for _ in range(n):
        xi = np.concatenate([rng.normal(scale=np.radians(10.0), size=3), rng.normal(scale=0.1, size=3)])
        out.append(pose.retract(xi))
    return out


def closest_point(axes) -> np.ndarray:
    """The point with the least summed squared distance to all the (non-parallel) lines ``axes``."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for axis in axes:
        P = np.eye(3) - np.outer(axis.direction, axis.direction)
        A += P
        b += P @ axis.point
    return np.linalg.lstsq(A, b, rcond=None)[0]


def twin_pose(arm_T_camera: gtsam.Pose3, point) -> gtsam.Pose3:
    """The camera turned half a turn about its ray to ``point`` (centre fixed).

    When every wrist axis passes through ``point`` the two see the same image lines: image axes alone
    cannot tell them apart, the circles can.
    """
    t = np.asarray(arm_T_camera.translation(), dtype=float)
    ray = np.asarray(point, dtype=float) - t
    half_turn = gtsam.Rot3.AxisAngle(gtsam.Point3(ray / np.linalg.norm(ray)), np.pi)
    return gtsam.Pose3(half_turn.compose(arm_T_camera.rotation()), t)


def initial_pose(arm: Arm, camera: Camera, measurements: list[Measurement],
                 options: CalibrationOptions | None = None) -> gtsam.Pose3:
    """Guess-free initial ``arm_T_camera`` from ellipse-centre lines and FK axes (docs/design.md §5)."""
    options = CalibrationOptions() if options is None else options
    return _initial(arm, camera, measurements, options)[0][0]


def _initial(arm, camera, measurements, options, index=None) -> tuple[list[gtsam.Pose3], _Setup, list[gtsam.Pose3]]:
    """Starting poses (one, or a pose and its twin when the image axes cannot tell them apart), the setup, and
    per start the candidate it came from (before LM: the anchor of :func:`_gauge_prior`)."""
    setup = _setup(arm, camera, measurements, options)
    if index is not None:
        setup.index = list(index)
    K = camera.K
    normals = np.array([plane_normal(K, line) for line in setup.lines])
    candidates = pose_candidates(normals, setup.axes, n_best=options.n_candidates)
    if not candidates:
        raise CalibrationError("no pose candidate puts the wrist in front of the camera; check the joint angles "
                               "and that the tracks belong to the wrist")
    unit = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(setup.axes)
    graph = _stage2_graph(setup.axes, setup.lines, K, unit)
    minima = sorted(_stage2_minima(graph, candidates, options), key=lambda m: m[1])
    pose, error, _, best = minima[0]
    rms = np.sqrt(2.0 * error / (2 * len(setup.axes)))
    if rms > options.max_initial_rms_px:
        thin = [f"measurement {setup.index[k]}: {len(p.usable)} tracks, longest arc {setup.turning[k]:.0f}°"
                for k, p in enumerate(setup.prepared) if len(p.usable) < WEAK_MANY_TRACKS
                and setup.turning[k] < WEAK_ARC_DEG]
        first = ("; the tracking is the likelier cause: these measurements have few tracks and short arcs ("
                 + "; ".join(thin) + "), so their image axes (through the ellipses' centres) can be far off: "
                 "spin the wrist longer (a full turn or more) or give the hand more texture, then check joint "
                 "angles and camera intrinsics") if thin else "; check joint angles, camera intrinsics and tracks"
        raise CalibrationError(
            f"initialisation ended in a poor minimum: the FK axes miss the image axes by {rms:.1f} px RMS "
            f"(limit {options.max_initial_rms_px} px)" + first)
    # Other minima that explain the image axes about as well are kept for the circles to decide: with three
    # measurements the image axes give exactly six equations, which have several exact solutions.
    starts, anchors = [pose], [candidates[best]]
    for other, other_error, _, i in minima[1:]:
        if len(starts) < MAX_STARTS and other_error < TWIN_ERROR_RATIO * error + 1.0 and _distinct(other, starts):
            starts.append(other)
            anchors.append(candidates[i])
    # Near a single crossing the half-turned twin explains the image axes as well: keep it for the circles
    # to decide (elsewhere LM takes the twin back to ``pose``).
    # A genuine twin is a minimum next to its start; elsewhere LM would crawl back to ``pose`` for many
    # iterations, so it gets few.
    crossing = closest_point(setup.axes)
    twin, twin_error, _, _ = _best_stage2(graph, [twin_pose(pose, crossing)], options,
                                          max_iterations=TWIN_ITERATIONS)
    if len(starts) < MAX_STARTS and twin_error < TWIN_ERROR_RATIO * error + 1.0 and _distinct(twin, starts):
        starts.append(twin)
        anchors.append(twin_pose(candidates[best], crossing))
    return starts, setup, anchors


# ---------------------------------------------------------------------------------------------------
# stage 1: coaxial circles per measurement


@dataclass
class _Stage1:
    keys: MeasurementKeys
    rotation: gtsam.Rot3  # the line variable at the solution
    circles: dict[int, np.ndarray]  # track -> (d, r) at the solution
    line: np.ndarray  # (3,) image axis
    line_cov: np.ndarray  # (3, 3) its covariance at unit pixel noise
    sigma2: float  # pixel noise variance from the residuals (chi2 / dof)
    n_points: int
    outliers: dict[int, str]  # track -> reason
    iterations: int
    #: per kept track: (residual sum of squares in px^2, number of points) at the solution
    stats: dict[int, tuple[float, int]] = field(default_factory=dict)
    #: (3, 3) the line variable's information from the pixels at unit pixel noise (its tangent), and its covariance
    #: there at unit noise (with the tracks' correlation and the jackknife's excess, see :func:`_jackknife`)
    rotation_info: np.ndarray | None = None
    rotation_cov: np.ndarray | None = None
    #: (3, 3) the jackknife's excess over the linearised line covariance (tangent, in units of the pixel noise
    #: variance ``sigma2``); zero where the linearisation holds
    excess: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))


def _circles(keys: MeasurementKeys, values) -> list[np.ndarray]:
    """(d, r) of each of a measurement's tracks (in ``keys.tracks`` order) at the values."""
    if keys.coaxial is not None:
        return list(keys.coaxial.circles(values))
    return [values.atVector(c) for c in keys.circles]


def _track_stats(graph, keys: MeasurementKeys, values) -> dict[int, tuple[float, int]]:
    """Per track: (residual sum of squares in px^2, number of points)."""
    if keys.coaxial is not None:
        sse = keys.coaxial.track_sse(values)
        return {j: (float(sse[i]), int(keys.coaxial.counts[i])) for i, j in enumerate(keys.tracks)}
    out = {}
    for j, fi in zip(keys.tracks, keys.circle_factors, strict=True):
        e = graph.at(fi).unwhitenedError(values)
        out[j] = (float(e @ e), len(e))
    return out


def _cube_root_variances(stats: dict[int, tuple[float, int]], options: CalibrationOptions
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Per track (in ``stats`` order): ``y = v^(1/3) / (1 - h)`` of its residual variance ``v = sse / (n - 2)``,
    ``h = 2 / (9 (n - 2))`` (Wilson-Hilferty: nearly normal, mean ``sigma^(2/3)``), and its relative sampling
    variance ``h / (1 - h)^2`` at white noise of one variance ``sigma^2``."""
    sse = np.array([v[0] for v in stats.values()], dtype=float)
    dof = np.array([max(v[1] - 2, 1) for v in stats.values()], dtype=float)
    h = 2.0 / (9.0 * dof)
    return np.cbrt(np.maximum(sse / dof, options.min_sigma_px**2)) / (1.0 - h), h / (1.0 - h) ** 2


class FitRejection(str):
    """The reason a track is rejected for not fitting its circle (a ``str``: what the result reports). Stage 1
    re-tests these, and only these, at its final line (see :func:`_retest`); other reasons (too short, an
    outlier of the graph builder, a jackknife group) are plain strings."""

    __slots__ = ()


def _outlier_tracks(stats: dict[int, tuple[float, int]], options: CalibrationOptions,
                    spread: float = 0.0) -> dict[int, FitRejection]:
    """Tracks that do not fit: a residual RMS far above the measurement's median, or a residual variance beyond the
    99.9 % point (``outlier_track_z``) about the tracks' median (an arc of a wrong circle fits a coaxial one only
    roughly).

    The second is a chi-square test in Wilson-Hilferty form (:func:`_cube_root_variances`). ``spread``: relative
    variance, on that scale, of the good tracks' noise levels beyond chi-square sampling (a tracker measures small
    or faint dots less precisely than large, contrasty ones; see :func:`_noise_spread`); 0 tests every track at
    the one median noise level.
    """
    rms = {j: np.sqrt(sse / n) for j, (sse, n) in stats.items()}
    median = max(float(np.median(list(rms.values()))), options.min_sigma_px)
    y, sampling = _cube_root_variances(stats, options)
    centre = float(np.median(y))
    z = (y / centre - 1.0) / np.sqrt(sampling + spread)
    sigma = centre**1.5  # the median track's noise (px)
    out = {}
    for i, (j, (sse, n)) in enumerate(stats.items()):
        if rms[j] > options.outlier_track_ratio * median:
            out[j] = FitRejection(f"residual RMS {rms[j]:.2f} px > {options.outlier_track_ratio:g}x the median "
                                  f"{median:.2f} px")
        elif z[i] > options.outlier_track_z:
            limit = (1.0 + options.outlier_track_z * np.sqrt(sampling[i] + spread)) ** 1.5
            rms_j = np.sqrt(sse / max(n - 2, 1))
            levels = f" and a spread of the tracks' noise levels of {150.0 * np.sqrt(spread):.0f} %" if spread else ""
            out[j] = FitRejection(f"does not fit a circle about the axis: residual RMS {rms_j:.3f} px is "
                                  f"{rms_j / sigma:.2f}x the median track's {sigma:.3f} px, beyond the 99.9 % point "
                                  f"{limit:.2f}x for {n} points{levels}")
    return out


def _noise_spread(stats_per_measurement: list[dict[int, tuple[float, int]]], options: CalibrationOptions) -> float:
    """How much the noise level differs between good tracks, beyond chi-square sampling: the relative variance on
    the scale of :func:`_cube_root_variances`, pooled over the measurements (each track against its measurement's
    median), from the lower half of the tracks only (median to 10 % point), which wrong arcs (that only add residual)
    hardly reach: with 30 % of them it comes out ~1.4x too large, where a full-spread estimate would let them all in.

    ~0 for white pixel noise of one variance (the simulator); tracked dots differ (on the rendered reference scene the
    tracks' residual RMS spread 0.79-1.30x their measurement's median, 5-95 %, where sampling allows 0.90-1.11x).
    """
    u, sampling = [], []
    for stats in stats_per_measurement:
        if len(stats) < 3:
            continue
        y, s = _cube_root_variances(stats, options)
        u.extend(y / np.median(y) - 1.0)
        sampling.extend(s)
    if len(u) < MIN_TRACKS_FOR_SPREAD:
        return 0.0
    u, sampling = np.asarray(u), np.asarray(sampling)

    def lower_spread(spread: float) -> float:  # of the standardised values, from their lower tail (normal: 1)
        z = u / np.sqrt(sampling + spread)
        return float(np.median(z) - np.quantile(z, 0.1)) / 1.2816  # the normal's 10 % point

    if lower_spread(0.0) <= 1.0:
        return 0.0
    low, high = 0.0, 1.0
    for _ in range(40):  # bisection: the spread at which the standardised values' lower half is a unit normal's
        mid = 0.5 * (low + high)
        low, high = (mid, high) if lower_spread(mid) > 1.0 else (low, mid)
    return high


def _noise_variance(stats: dict[int, tuple[float, int]], line_dof: int, options: CalibrationOptions) -> float:
    sse = sum(v[0] for v in stats.values())
    n = sum(v[1] for v in stats.values())
    dof = max(n - line_dof - 2 * len(stats), 1)
    return max(sse / dof, options.min_sigma_px**2)


def _track_correlation(factor, values, sigma2: float = 1.0) -> np.ndarray:
    """(3, 3) information ``D`` that the line's pixels lack when their errors are correlated within a track.

    ``H = sum_j H_j`` (the factor's information, per track) assumes independent pixel errors of the factor's
    sigma. The per-track scores ``s_j`` give the cluster-robust meat ``B = sum_j s_j s_j^T`` (independent tracks,
    any correlation inside a track: a tracker's sub-pixel bias that follows its dot), with two corrections:

    - the scores are taken at the measurement's own optimum, ``s_j - H_j H^-1 sum s`` (in the joint graph the
      pose holds the line away from it, and the summed score is that pull, not noise);
    - each is corrected for its track's leverage ``A_j = H^-1/2 H_j H^-1/2`` (CR2: ``(I - A_j)^-1/2`` on the
      whitened score), so that under white noise of variance ``sigma2`` (in the factor's units) the whitened
      meat ``M = H^-1/2 B H^-1/2`` has expectation ``sigma2 I`` exactly (leverages capped at
      ``MAX_TRACK_LEVERAGE``).

    An eigenvalue of ``M / sigma2`` counts as correlation only beyond ``1 + 3 sd`` (``sd^2 = 2 sum_j h_j^2``,
    ``h_j`` the tracks' leverages along it: its scatter under white noise; a few long arcs carry most of a
    line's information). ``D = H^1/2 (M / sigma2 - (1 + 3 sd))_+ H^1/2``, so that the covariance becomes
    ``H^-1 (H + D) H^-1``; it only grows (the noise model is the floor).
    """
    per_track = factor.track_information(values)
    H = per_track.sum(axis=0)
    S = factor.track_scores(values)
    S = S - per_track @ np.linalg.lstsq(H, S.sum(axis=0), rcond=None)[0]
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    keep = w > 1e-12 * max(w.max(), 1e-300)
    root = V[:, keep] * np.sqrt(w[keep])  # H = root root^T
    W = (V[:, keep] / np.sqrt(w[keep])).T  # whitening: W H W^T = I
    Z = S @ W.T
    A = np.einsum("ab,jbc,dc->jad", W, per_track, W)
    a, Q = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
    # a track whose leverage nears 1 holds a direction alone: its score there is rounding noise, which CR2 would
    # amplify without bound (and a per-track information that is not positive semi-definite gives leverages above
    # 1: a Jaco2 dot scene with corner tracks, leverage 1.6, clipped to 1 - 1e-9, made a 0.3 mm 1 sigma 500 mm)
    unshrink = 1.0 / np.sqrt(1.0 - np.clip(a, 0.0, MAX_TRACK_LEVERAGE))
    Z = np.einsum("jab,jb,jcb,jc->ja", Q, unshrink, Q, Z)
    m, U = np.linalg.eigh(Z.T @ Z)
    h = np.einsum("ai,jab,bi->ji", U, A, U)  # leverage of each track along each eigenvector
    allowance = 3.0 * np.sqrt(2.0 * np.sum(h**2, axis=0))
    excess = np.maximum(m / sigma2 - 1.0 - allowance, 0.0)
    return root @ ((U * excess) @ U.T) @ root.T


def _axis_watch(builder: RotIdGraph, k: int, prepared):
    """What stage 1's LM watches: the image axis at the corners of the tracks' bounding box."""
    corners = np.array([np.min([t.ideal.min(axis=0) for t in prepared.usable.values()], axis=0),
                        np.max([t.ideal.max(axis=0) for t in prepared.usable.values()], axis=0)])

    def image_axis_at_corners(v):
        line, _ = image_line_from_rot3(builder.camera.K, v.atRot3(builder.line_key(k)))
        return line_distances(line, corners)

    return image_axis_at_corners


def _stage1_round(builder, measurement, k, pose, prepared, skip, line_start, circles_start, options,
                  settle: bool = False):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False,
                                   prepared=prepared, skip_tracks=skip, refine_circles=False,
                                   initial_line=line_start, initial_circles=circles_start)
    warm = 0
    if settle and circles_start is None and keys.coaxial is not None:
        # circles started from each track's rays about the start line: let them settle with the line held first
        held = gtsam.NonlinearFactorGraph()
        held.push_back(graph)
        held.add(gtsam.PriorFactorRot3(keys.line, values.atRot3(keys.line),
                                       gtsam.noiseModel.Isotropic.Sigma(3, HOLD_SIGMA_RAD)))
        values, warm, _, _ = _lm(held, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                                 relative_tolerance=options.stage1_tolerance)
    start_error = graph.error(values)
    result, it, error, _ = _lm(graph, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                               relative_tolerance=options.stage1_tolerance, watch=_axis_watch(builder, k, prepared),
                               watch_tolerance=WATCH_LINE_PX)
    return graph, keys, result, it + warm, start_error, error


def _stage1_result(builder, graph, keys, result, stats, skip, iterations, options) -> _Stage1:
    R = result.atRot3(keys.line)
    line, J = image_line_from_rot3(builder.camera.K, R)
    info = marginal_information(graph, result, keys.line, 3)  # unit pixel noise
    w, V = np.linalg.eigh(info)
    cov_R = (V / np.maximum(w, 1e-12 * max(w.max(), 1e-300))) @ V.T
    circles = dict(zip(keys.tracks, _circles(keys, result), strict=True))
    sigma2 = _noise_variance(stats, 3, options)
    if keys.coaxial is not None:  # errors shared along a track: the cluster-robust line covariance
        cov_R = cov_R + cov_R @ _track_correlation(keys.coaxial, result, sigma2) @ cov_R
    return _Stage1(keys, R, circles, line, J @ cov_R @ J.T, sigma2, sum(n for _, n in stats.values()), skip,
                   iterations, stats, info, cov_R)


def _jackknife(builder: RotIdGraph, measurement, k: int, pose: gtsam.Pose3, prepared, s: _Stage1,
               options) -> _Stage1:
    """Measurement k's line covariance checked by a delete-a-group jackknife over its tracks; where the jackknife
    exceeds the linearised covariance beyond its own sampling scatter, the jackknife's is taken.

    The linearised covariance (with the tracks' correlation, :func:`_track_correlation`) is the curvature of the
    cost at the fit. Where the line rests on a few tracks whose arcs are short, the cost is far from quadratic
    and one or two tracks can hold a direction alone; the fit then moves far more when they are left out than
    the curvature says (6 poses of 25 degree corner arcs: one line 1-1.5 px off at its test points, 7 sigma of its
    linearised covariance, 1 sigma of this jackknife's). The tracks are split into ``JACKKNIFE_GROUPS`` groups
    (round robin), the line refitted without each group from the fit, and ``C_j = (G - 1) / G sum (t_g - t)(t_g -
    t)^T`` of the tangent offsets ``t_g``. Whitened by the linearised covariance, an eigenvalue of ``C_j`` counts
    only beyond the 99.9 % point of its scatter under the model (a chi-square of G - 1 dof over G - 1,
    Bonferroni over 3 directions: ``JACKKNIFE_Z``), so that the jackknife's noise does not inflate a good
    measurement's covariance.
    """
    tracks = list(s.keys.tracks)
    groups = min(len(tracks), JACKKNIFE_GROUPS)
    if groups < JACKKNIFE_MIN_GROUPS or s.keys.coaxial is None or s.rotation_cov is None:
        return s
    offsets = []
    for g in range(groups):
        skip = {**s.outliers, **{j: "jackknife" for j in tracks[g::groups]}}
        try:
            graph, keys, result, _, _, _ = _stage1_round(builder, measurement, k, pose, prepared, skip, s.rotation,
                                                         dict(s.circles), options)
        except RotIdError:
            return s
        offsets.append(gtsam.Rot3.Logmap(s.rotation.between(result.atRot3(keys.line))))
    t = np.asarray(offsets)
    if not np.all(np.isfinite(t)):
        return s
    deviation = t - t.mean(axis=0)
    jack = (groups - 1) / groups * deviation.T @ deviation / s.sigma2  # at unit pixel noise, as rotation_cov
    w, V = np.linalg.eigh(0.5 * (s.rotation_cov + s.rotation_cov.T))
    if w.min() <= 0.0:
        return s
    root = V * np.sqrt(w)  # rotation_cov = root root^T
    inverse_root = (V / np.sqrt(w)).T
    m, U = np.linalg.eigh(inverse_root @ jack @ inverse_root.T)
    limit = chi2_quantile(groups - 1, JACKKNIFE_Z) / (groups - 1)
    grow = np.where(m > limit, m - 1.0, 0.0)
    if not grow.any():
        return s
    excess = root @ ((U * grow) @ U.T) @ root.T
    cov_R = s.rotation_cov + excess
    _, J = image_line_from_rot3(builder.camera.K, s.rotation)
    return replace(s, line_cov=J @ cov_R @ J.T, rotation_cov=cov_R, excess=excess)


def _stage1_measurement(builders: list[RotIdGraph], measurement, k, pose, prepared, options,
                        start_line: gtsam.Rot3 | None = None, settle: bool = False) -> _Stage1:
    """Coaxial circles of one measurement, rejecting outlier tracks round by round.

    ``builders``: the projected model first (fast); if LM cannot lower its error at all (wrong arcs far from
    any coaxial circle can make the projected-out circles jump between solutions from one line to the next),
    the measurement is redone with the next builder's model (circle variables that move continuously).
    """
    builder, *fallbacks = builders
    skip: dict[int, str] = {}
    iterations = 0
    line_start, circles_start = start_line, None
    rounds = 0
    while True:
        graph, keys, result, it, start_error, error = _stage1_round(builder, measurement, k, pose, prepared, skip,
                                                                    line_start, circles_start, options, settle)
        iterations += it
        # (a later round starts at the previous round's solution: a small decrease there is convergence)
        if fallbacks and rounds == 0 and error >= (1.0 - STALL_DECREASE) * start_error and start_error > 0.0:
            builder, *fallbacks = fallbacks  # stalled from the start: redo this round with the next model
            continue
        rounds += 1
        stats = _track_stats(graph, keys, result)
        new = _outlier_tracks(stats, options)
        # the last round's fit is the result: a track it flags stays in (rejecting it without a new fit would
        # report it rejected while the line and the counts still include it)
        if not new or len(stats) - len(new) < 2 or rounds == STAGE1_ROUNDS:
            break
        skip.update(new)
        line_start = result.atRot3(keys.line)  # the next round starts where this one ended
        circles_start = dict(zip(keys.tracks, _circles(keys, result), strict=True))
    return _stage1_result(builder, graph, keys, result, stats, skip, iterations, options)


#: Reasons of stage 1's fit tests (the tracks that :func:`_readmit_tracks` re-tests).
def _retest(builder: RotIdGraph, measurement, k, pose, prepared, s: _Stage1, options):
    """Every track stage 1 kept or rejected for its fit, at its final line: (stats, circles) with the rejected
    tracks' circles solved there (started from their rays about that line: the builder's start is about the FK axis
    seen from ``pose``, which can be degrees off the line of a measurement of short arcs)."""
    R = s.rotation.matrix()
    K_inv = np.linalg.inv(builder.camera.K)
    circles = dict(s.circles)
    for j, why in s.outliers.items():
        if isinstance(why, FitRejection):
            track = prepared.usable[j]
            rays = np.column_stack([track.ideal, np.ones(len(track.ideal))]) @ K_inv.T
            centre_ray = K_inv @ np.append(track.ellipse.centre, 1.0)
            circles[j] = np.array(initial_circle(R[:, 0], R[:, 1], rays, centre_ray))
    others = {j: why for j, why in s.outliers.items() if not isinstance(why, FitRejection)}
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False, prepared=prepared,
                                   skip_tracks=others, refine_circles=False, initial_line=s.rotation,
                                   initial_circles=circles)
    # each rejected track's pull on the line: its score at the line fitted without it, against the score's
    # white-noise covariance (sigma2 times its information)
    pull = {}
    if keys.coaxial is not None:
        factor = keys.coaxial
        scores, informations = factor.track_scores(values), factor.track_information(values)
        for i, j in enumerate(keys.tracks):
            if j in s.outliers:
                pull[j] = float(scores[i] @ np.linalg.pinv(informations[i]) @ scores[i]) * factor.sigma_px**2 / s.sigma2
    return _track_stats(graph, keys, values), dict(zip(keys.tracks, _circles(keys, values), strict=True)), pull


def _readmit_tracks(builders, measurements, pose, setup: _Setup, stage1: list[_Stage1], options) -> list[_Stage1]:
    """Re-test at each measurement's final line the tracks stage 1 rejected for their fit, allowing for the spread
    of the tracks' noise levels (:func:`_noise_spread`), and fit again with those that pass.

    Stage 1's rounds test every track at the one median noise level, against a line that the outliers may still
    pull: that cleans wrong arcs out, but also rejects good tracks of a tracker's noisier dots (10-20 % of the
    rendered reference scene's tracks) and, in a measurement of short arcs, tracks whose circles ran off to degenerate
    ones while LM's first round was still far from the final line. A track must also pass a score test: its
    gradient on the line (fitted without it) within the 99.9 % point of its white-noise distribution; an arc of a
    wrong circle can fit its own circle within the spread and still drag the line (30 % wrong arcs: 1.8 mm error
    instead of 0.4 mm without this test).
    """
    tested = {k: _retest(builders[0], measurements[k], k, pose, setup.prepared[k], s, options)
              for k, s in enumerate(stage1) if any(isinstance(why, FitRejection) for why in s.outliers.values())}
    if not tested:
        return stage1
    spread = _noise_spread([tested[k][0] if k in tested else s.stats for k, s in enumerate(stage1)], options)
    out = list(stage1)
    limit = chi2_quantile(3, options.outlier_track_z)
    for k, (stats, circles, pull) in tested.items():
        s = stage1[k]
        flagged = _outlier_tracks(stats, options, spread)
        # a wrong arc can fit its own circle within the noise spread and still drag the line: it is not taken back
        flagged.update({j: f"pulls the axis away from the other tracks' (score test {value:.3g} > {limit:.3g}, "
                           "3 dof, at the line fitted without it)"
                        for j, value in pull.items() if j not in flagged and value > limit})
        back = [j for j, why in s.outliers.items() if isinstance(why, FitRejection) and j not in flagged]
        s.outliers.update({j: why for j, why in flagged.items() if j in s.outliers})  # the reasons at the final line
        if not back:
            continue
        builder = builders[0] if s.keys.coaxial is not None else builders[-1]
        skip = {j: why for j, why in s.outliers.items() if j not in back}
        line_start, circles_start, iterations = s.rotation, {**s.circles, **{j: circles[j] for j in back}}, s.iterations
        for rounds in range(1, 3):
            graph, keys, result, it, _, _ = _stage1_round(builder, measurements[k], k, pose, setup.prepared[k], skip,
                                                          line_start, circles_start, options)
            iterations += it
            stats = _track_stats(graph, keys, result)
            new = _outlier_tracks(stats, options, spread)
            if not new or len(stats) - len(new) < 2 or rounds == 2:
                break
            skip.update(new)
            line_start = result.atRot3(keys.line)
            circles_start = dict(zip(keys.tracks, _circles(keys, result), strict=True))
        out[k] = _stage1_result(builder, graph, keys, result, stats, skip, iterations, options)
    return out


def _stage1(arm, camera, measurements, pose, setup: _Setup, options, image_axes: bool = True) -> list[_Stage1]:
    # Huber per whole track (at its chi-square 99.9 % point): a wrong arc that the tests let through has a bounded
    # pull; a good track is untouched
    builders = [_builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber),
                _builder(arm, camera, options, robust=track_huber)]
    stage1 = [_stage1_measurement(builders, m, k, pose, setup.prepared[k], options,
                                  _start_line(camera, setup.axes[k], setup.lines[k] if image_axes else None, pose),
                                  settle=not image_axes)
              for k, m in enumerate(measurements)]
    return _readmit_tracks(builders, measurements, pose, setup, stage1, options)


def _refined_stage1(arm, camera, measurements, start: gtsam.Pose3, setup: _Setup, options,
                    anchor) -> tuple[gtsam.Pose3, list[_Stage1]]:
    """Stage 1 from ``start``; where some measurement has only short arcs (``setup.short_arcs``), again from the
    pose its lines give (weighted stage 2, Huber on whole measurements) while that pose moves more than REFINE_DEG
    or REFINE_M (at most REFINE_PASSES fits), and the last fit jackknifed (:func:`_jackknife`). Returns the pose
    stage 1 last started from and its fit. Where every measurement has a long arc: one fit from the start.

    Each measurement's fit starts from the FK axis seen from the start. With long arcs it finds the same circles
    from anywhere near; with short ones (corner tracks of 25 degrees) it stays in a minimum near the start, and
    the initialisation from ellipse centres can be 20 degrees off: on one rendered scene three of six lines fitted
    from there were 100-13 000 chi-square off the truth, and 0-4 when fitted from the truth.
    """
    pose = start
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    everything = list(range(len(measurements)))
    stage1 = _stage1(arm, camera, measurements, pose, setup, options)
    if not setup.short_arcs:
        return pose, stage1
    for _ in range(REFINE_PASSES - 1):
        moved, _, _ = _weighted_stage2(camera, setup, stage1, everything, pose, options, anchor)
        if _turned(moved, pose) < np.radians(REFINE_DEG) and np.linalg.norm(
                moved.translation() - pose.translation()) < REFINE_M:
            break
        pose = moved
        stage1 = _stage1(arm, camera, measurements, pose, setup, options, image_axes=False)
    return pose, [_jackknife(builder, measurements[k], k, pose, setup.prepared[k], s, options)
                  for k, s in enumerate(stage1)]


def _start_line(camera: Camera, axis, image_axis: np.ndarray, pose: gtsam.Pose3) -> gtsam.Rot3:
    """Stage 1's start: the FK axis seen from ``pose``, turned onto the image axis through the ellipse centres.

    The image decides the projection plane and the pose only the tilt within it, so a poor pose (wrong joint
    angles) does not start the circles far from their tracks. Without ``image_axis`` (None), the FK axis as the
    pose sees it (a pose fitted to stage 1's lines: the axis through the centres of short arcs' ellipses can be
    far off).
    """
    camera_T_arm = pose.inverse()
    line, _ = rot3_from_line(camera_T_arm.transformFrom(axis.point),
                             camera_T_arm.rotation().matrix() @ axis.direction)
    return line if image_axis is None else align_line(line, plane_normal(camera.K, image_axis))


# ---------------------------------------------------------------------------------------------------
# stage 2 and the estimators


def _axis_distances(camera: Camera, axis, stage1: _Stage1, pose: gtsam.Pose3,
                    sigma2: float | None = None, noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distances of the projected FK test points to the stage-1 image axis, and their covariance (at the
    measurement's own pixel noise variance unless ``sigma2`` is given; plus the joint-angle noise's, ``noise`` as
    in :func:`joint_tie_covariance`)."""
    points = np.array([pose.transformTo(p) for p in axis_test_points(axis)])
    pixels = camera.project(points, distort=False)
    e = line_distances(stage1.line, pixels)
    sigma2 = stage1.sigma2 if sigma2 is None else sigma2
    cov = line_distance_covariance(stage1.line_cov * sigma2, pixels) + 1e-12 * np.eye(len(e))
    if noise is not None:
        cov = cov + joint_tie_covariance(camera, axis, stage1.line, pose, noise)
    return e, cov


def _chi2(camera, setup: _Setup, stage1, pose, sigma2: dict[int, float] | None = None) -> np.ndarray:
    """Per measurement: chi-square (2 dof) of its stage-1 image axis against the FK axis projected by ``pose``.

    The line covariance is at ``sigma2[k]`` when given; otherwise at the larger of the measurement's and the
    median pixel noise variance: the geometric distance to a strongly curved (near edge-on) projected circle
    absorbs part of the noise, so a measurement's own residuals can understate it, and a test at that scale
    would reject good data. Measurements missing from ``sigma2`` get NaN.
    """
    median = float(np.median([s.sigma2 for s in stage1]))
    out = []
    for k, (axis, s) in enumerate(zip(setup.axes, stage1, strict=True)):
        if sigma2 is not None and k not in sigma2:
            out.append(np.nan)
            continue
        variance = max(s.sigma2, median) if sigma2 is None else sigma2[k]
        e, cov = _axis_distances(camera, axis, s, pose, variance, setup.noise(k))
        out.append(float(e @ np.linalg.pinv(cov, hermitian=True) @ e))  # pinv: test points may project badly
    return np.array(out)


def _axis_consistency(camera, setup: _Setup, stage1, used: list[int], pose: gtsam.Pose3, sigma2: dict[int, float],
                      options) -> AxisConsistency | None:
    """The test of :class:`AxisConsistency` at ``pose``, each measurement's line at its pixel noise variance
    ``sigma2[k]`` (the one the fit weighted it by); None without redundancy (fewer than 4 measurements)."""
    dof = 2 * len(used) - 6
    if dof <= 0:
        return None
    chi2 = float(np.sum(_chi2(camera, setup, stage1, pose, {k: sigma2[k] for k in used})[used]))
    p = chi2_sf(chi2, dof)
    scale = 1.0
    if p < options.axis_consistency_p:  # see AxisConsistency: k's mean given the scatter, where it has one
        scale = chi2 / (dof - 2) if dof > 2 else chi2 / dof
    return AxisConsistency(chi2, dof, p, scale)


def _weighted_stage2(camera, setup: _Setup, stage1, used: list[int], start: gtsam.Pose3, options, anchor):
    """Stage 2 weighted by the stage-1 line covariances, Huber on whole measurements; returns (pose, its, graph)."""
    pose, iterations, graph = start, 0, None
    for _round in range(3):  # the distance covariance depends on where the test points project
        noises = []
        for k in used:
            _, cov = _axis_distances(camera, setup.axes[k], stage1[k], pose, noise=setup.noise(k))
            base = gtsam.noiseModel.Gaussian.Covariance(cov)
            noises.append(gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(3.0), base))
        graph = _stage2_graph([setup.axes[k] for k in used], [stage1[k].line for k in used], camera.K, noises)
        previous = pose
        pose, _, it, _ = _best_stage2(graph, [pose], options, anchor=anchor)
        iterations += it
        step = previous.localCoordinates(pose)
        if np.max(np.abs(step[:3])) < 1e-9 and np.max(np.abs(step[3:])) < 1e-9:
            break
    return pose, iterations, graph


def _span_deg(phi: np.ndarray, trim: float = ARC_TRIM) -> float:
    """The arc (deg) that angles (rad) cover: cut at their largest gap, from the ``trim`` to the ``1 - trim``
    quantile (a few noisy points at an arc's ends would otherwise widen a short arc)."""
    phi = np.sort(np.mod(np.asarray(phi, dtype=float), 2.0 * np.pi))
    if len(phi) < 2:
        return 0.0
    gaps = np.diff(np.concatenate([phi, [phi[0] + 2.0 * np.pi]]))
    cut = int(np.argmax(gaps))
    unwrapped = np.concatenate([phi[cut + 1:], phi[:cut + 1] + 2.0 * np.pi])
    low, high = np.quantile(unwrapped, [trim, 1.0 - trim])
    return float(np.degrees(high - low))


def arc_span_deg(ideal: np.ndarray, ellipse) -> float:
    """The arc (deg) that a track's points cover about its own ellipse (mapped to a circle): a rough measure for
    tracks without a circle fit (a short arc's own ellipse can be far too small, which overstates it)."""
    theta = np.radians(ellipse.angle_deg)
    c, sn = np.cos(theta), np.sin(theta)
    d = np.asarray(ideal, dtype=float) - ellipse.centre
    u = (d[:, 0] * c + d[:, 1] * sn) / (0.5 * ellipse.axes[0])
    v = (-d[:, 0] * sn + d[:, 1] * c) / (0.5 * ellipse.axes[1])
    return _span_deg(np.arctan2(v, u))


def circle_arc_span_deg(ideal: np.ndarray, K: np.ndarray, line: gtsam.Rot3, circle) -> float:
    """The arc (deg) that a track's points cover about its fitted 3-D circle: each pixel's ray met with the circle's
    plane, and the angle about the circle's centre there (``line`` and ``circle = (d, r)`` as stage 1 fits them)."""
    R = line.matrix()
    c0, c1, c2 = R[:, 0], R[:, 1], R[:, 2]
    d = float(circle[0])
    rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(K).T
    along = rays @ c1
    ok = np.abs(along) > 1e-12
    points = rays[ok] * (d / along[ok])[:, None] - (c0 + d * c1)
    return _span_deg(np.arctan2(points @ c2, points @ c0))


def _evidence(setup: _Setup, s: _Stage1, k: int, tied=None) -> tuple[float | None, bool]:
    """(longest arc in deg, weak) of measurement k's kept tracks. Each arc is measured about its stage-1 circle and,
    when ``tied = (line, circles)`` is given (the circles fitted with the line on the estimate's FK axis), about that
    circle too, and the smaller is taken: a short arc fitted with a circle far too small wraps around it."""
    spans = []
    for j in s.keys.tracks:
        ideal = setup.prepared[k].usable[j].ideal
        span = circle_arc_span_deg(ideal, setup.K, s.rotation, s.circles[j]) if j in s.circles else np.inf
        if tied is not None and j in tied[1]:
            span = min(span, circle_arc_span_deg(ideal, setup.K, tied[0], tied[1][j]))
        if np.isfinite(span):
            spans.append(span)
    longest = max(spans) if spans else None
    n = len(s.keys.tracks)
    return longest, n < WEAK_TRACKS or (n < WEAK_MANY_TRACKS and (longest is None or longest < WEAK_ARC_DEG))


def _tied_circles(arm, camera, measurements, setup: _Setup, stage1, pose: gtsam.Pose3, options, ks) -> dict:
    """k -> (line, circles) of measurement k fitted with its line on the FK axis seen from ``pose``."""
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    out = {}
    for k in ks:
        fit = _tied_fit(builder, measurements[k], k, setup.prepared[k], stage1[k], pose, options, setup, fresh=True)
        if fit is not None:
            out[k] = fit[1], fit[2]
    return out


def _named(setup: _Setup, ks) -> list[int]:
    """Internal measurement positions -> the caller's measurement indices."""
    return [setup.index[k] for k in ks] if setup.index else list(ks)


def _poor_minimum(chi2: np.ndarray, limit: float, what: str, setup: _Setup | None = None,
                  bad=()) -> CalibrationError:
    names = _named(setup, range(len(chi2))) if setup is not None else list(range(len(chi2)))
    listing = ", ".join(f"{name}: {value:.3g}" for name, value in zip(names, chi2, strict=True))
    return CalibrationError(
        f"the estimate ended in a poor minimum or the data are inconsistent: {what} (chi-square of each "
        f"measurement's image axis against the projected FK axis, 2 dof, limit {limit:g}: {listing}); check "
        "the joint angles, the intrinsics and the wrist joint (if the kinematics are known to be inaccurate, "
        "raise CalibrationOptions.outlier_measurement_chi2)" + _weak_words(setup, bad))


def _weak_words(setup: _Setup | None, bad=()) -> str:
    """For a refusal: the measurements whose evidence is thin (from ``setup.weak``), which come first, and those of
    ``bad`` whose arcs are all short (``setup.short``)."""
    if setup is None:
        return ""
    out = ""
    if setup.weak:
        named = "; ".join(f"measurement {_named(setup, [k])[0]}: {why}" for k, why in setup.weak.items())
        out += (f". But first: these measurements have too little evidence for a reliable image axis ({named}); spin "
                "the wrist longer (a full turn or more) or give the hand more texture: the tracking, more likely than "
                "the joint angles, is at fault")
    short = [k for k in bad if k in setup.short]
    if short:
        out += ". " + _short_words(setup, short)
    return out


def _short_words(setup: _Setup, ks) -> str:
    """Words for measurements of many tracks whose arcs are all short: tracking is as likely a cause as joints."""
    arcs = ", ".join(f"{_named(setup, [k])[0]}: {setup.short[k]:.0f}°" for k in ks)
    return (f"The arcs of measurement(s) {arcs} (longest) are short: a tracker's drift along short arcs can put an "
            "image axis off as far as a wrong joint angle does, so suspect the tracking as much as the joints (spin "
            "longer, a full turn or more, or track features that can be followed further)")


def _tied_fit(builder: RotIdGraph, measurement, k: int, prepared, s: _Stage1, pose: gtsam.Pose3, options,
              setup: _Setup, fresh: bool = False):
    """Measurement k's circles with its line held on the FK axis projected by ``pose`` (its tilt within the
    projection plane free; the tie as soft as the joint-angle noise makes the FK axis): (residual sum of squares in
    px^2, line variable, circles, the tie's chi-square), or None if it fails. The circles start from stage 1's, or
    with ``fresh`` from each track's rays about the FK axis (a short arc's stage-1 circle can be far too small)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(POSE_KEY, pose)
    try:
        keys = builder.add_measurement(graph, values, k, measurement, prepared=prepared, skip_tracks=s.outliers,
                                       initial_line=None if fresh else s.rotation,
                                       initial_circles=None if fresh else dict(s.circles),
                                       refine_circles=fresh, track_sigmas=dict.fromkeys(prepared.usable, 1.0),
                                       tie_covariance=joint_tie_covariance(builder.camera, setup.axes[k], s.line,
                                                                           pose, setup.noise(k)))
    except RotIdError:
        return None
    graph.add(gtsam.NonlinearEqualityPose3(POSE_KEY, pose))
    result, _, _, _ = _lm(graph, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                          relative_tolerance=options.stage1_tolerance)
    sse = sum(v[0] for v in _track_stats(graph, keys, result).values())
    if not np.isfinite(sse):
        return None
    tie = 2.0 * graph.at(keys.tie_factor).error(result) if keys.tie_factor >= 0 else 0.0
    return sse, result.atRot3(keys.line), dict(zip(keys.tracks, _circles(keys, result), strict=True)), tie


def _sse(s: _Stage1) -> float:
    return float(sum(v[0] for v in s.stats.values()))


def _second_opinion(arm, camera, measurements, setup: _Setup, stage1: list[_Stage1], k: int, pose: gtsam.Pose3,
                    options) -> tuple[_Stage1 | None, float]:
    """Measurement k's disagreement with ``pose`` as a likelihood ratio, and a better stage-1 fit if there is one.

    The linearised chi-square of an image axis (:func:`_chi2`) assumes the axis is Gaussian about the stage-1 fit.
    With few tracks or short arcs it is not: the fit can sit in a local minimum of its own (two arcs of 60 degrees
    admit several coaxial circle pairs), or the cost can rise far more slowly than its curvature says, and a good
    measurement then looks like an outlier (and gets blamed on its joint angles). This fits the measurement's
    circles with its line tied to the FK axis seen from ``pose``, then frees the line from there: if that free fit is
    better than stage 1's, stage 1 was in a local minimum and the new fit replaces it. The returned statistic is
    ``(sse_tied - sse_free) / sigma^2`` (2 dof under the model), at the larger of the measurement's and the median
    pixel noise variance as in :func:`_chi2`; inf if the tied fit fails.
    """
    s = stage1[k]
    if s.keys.coaxial is None:  # a circle-variable stage 1 (its projected fit stalled): no second opinion
        return None, np.nan
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    tied = _tied_fit(builder, measurements[k], k, setup.prepared[k], s, pose, options, setup)
    if tied is None:
        return None, np.inf
    sse_tied, line, circles, tie = tied
    graph, keys, result, it, _, _ = _stage1_round(builder, measurements[k], k, pose, setup.prepared[k], s.outliers,
                                                  line, circles, options)
    stats = _track_stats(graph, keys, result)
    refit = None
    free = _sse(s)
    new_free = float(sum(v[0] for v in stats.values()))
    if np.isfinite(new_free) and new_free < free * (1.0 - 1e-9):
        refit = _stage1_result(builder, graph, keys, result, stats, dict(s.outliers), s.iterations + it, options)
        if setup.short_arcs:  # as stage 1's own fits (``_refined_stage1``)
            refit = _jackknife(builder, measurements[k], k, pose, setup.prepared[k], refit, options)
        free = new_free
    variance = max(s.sigma2 if refit is None else refit.sigma2, float(np.median([t.sigma2 for t in stage1])))
    return refit, max(sse_tied - free, 0.0) / variance + tie


def _robust_weighted(camera, setup, stage1, start, options, anchor, second_opinion=None, drop_weak: bool = False
                     ) -> tuple[gtsam.Pose3, int, gtsam.NonlinearFactorGraph, list[int], dict[int, float]]:
    """Weighted stage 2 that leaves out measurements whose image axis disagrees with the FK axis.

    At most ``(n - 3) // 2`` measurements are left out, so that the rest still over-determine the pose and
    the test stays meaningful; more disagreement than that is reported as a poor minimum. A measurement whose
    linearised chi-square exceeds the limit gets a ``second_opinion(k, pose) -> (refit or None, statistic)``
    (:func:`_second_opinion`) before it can be left out: a better stage-1 fit found from the estimate replaces its
    own (``stage1`` is updated in place) and the likelihood-ratio statistic decides instead of the linearised one.
    """
    n = len(stage1)
    limit = options.outlier_measurement_chi2
    iterations = 0
    refitted: set[int] = set()
    setup.weak, setup.short = {}, {}
    for k, s in enumerate(stage1):
        span, weak = _evidence(setup, s, k)
        if not weak and setup.turning[k] < WEAK_ARC_DEG:
            setup.short[k] = setup.turning[k]
        if weak:
            arc = "" if span is None else f", longest arc {span:.0f}° (at most)"
            setup.weak[k] = f"{len(s.keys.tracks)} tracks{arc}"
    # with ``drop_weak``, weak measurements (their image axes need not be Gaussian) are left out when enough strong
    # ones remain
    strong = [k for k in range(n) if k not in setup.weak]
    setup.dropped = set(setup.weak) if drop_weak and setup.weak and len(strong) >= MIN_STRONG else set()
    used = [k for k in range(n) if k not in setup.dropped]
    max_excluded = max(0, (len(used) - MIN_MEASUREMENTS) // 2) + len(setup.dropped)
    while True:
        pose, it, graph = _weighted_stage2(camera, setup, stage1, used, start, options, anchor)
        iterations += it
        chi2 = _chi2(camera, setup, stage1, pose)
        bad = [k for k in used if chi2[k] > limit]
        if bad and second_opinion is not None:
            opinions = {k: second_opinion(k, pose) for k in bad}
            new = [k for k, (refit, _) in opinions.items() if refit is not None and k not in refitted]
            for k in new:
                stage1[k] = opinions[k][0]
                refitted.add(k)
            if new:  # better stage-1 fits: estimate again with them
                start = pose
                continue
            for k, (_, statistic) in opinions.items():
                if not np.isnan(statistic):
                    chi2[k] = statistic
            bad = [k for k in used if chi2[k] > limit]
        if not bad:
            break
        if n - len(used) >= max_excluded:
            gone = _named(setup, sorted(set(range(n)) - set(used)))
            left_out = f", after leaving out {gone}" if len(used) < n else ""
            raise _poor_minimum(chi2, limit, f"measurement(s) {_named(setup, bad)} disagree{left_out}", setup,
                                bad)
        # One at a time, by leave-one-out: a wrong measurement drags the pose, so the largest chi-square may
        # belong to a good one; leave out the one whose absence best reconciles the others.
        best = None
        for k in used:
            rest = [i for i in used if i != k]
            rest_pose, it, _ = _weighted_stage2(camera, setup, stage1, rest, pose, options, anchor)
            iterations += it
            rest_chi2 = _chi2(camera, setup, stage1, rest_pose)
            score = float(sum(rest_chi2[i] for i in rest))
            if best is None or score < best[0]:
                best = (score, k, rest_pose)
        used.remove(best[1])
        start = best[2]
    return pose, iterations, graph, used, {k: float(chi2[k]) for k in range(n)}


def _check_scale(result: CalibrationResult, setup: _Setup, stage1: list[_Stage1], options: CalibrationOptions) -> None:
    """Raise if the estimate implies features implausibly far from the wrist axis (metric scale check).

    The stage-1 circles are known in units of the camera-to-axis distance; the estimate fixes that distance
    (unless it is degenerate: then the report already says the position is not determined).
    """
    if not result.covariance_usable:
        return
    pose = result.arm_T_camera
    radii = []
    centre = pose.translation()
    for axis, s in zip(setup.axes, stage1, strict=True):
        distance = float(axis.distance_to(centre)[0])  # camera centre to the wrist axis
        radii.extend(abs(c[1]) * distance for c in s.circles.values())
    median = float(np.median(radii))
    if median > options.max_feature_radius_m:
        distance_to_wrist = np.median([np.linalg.norm(pose.transformTo(a.point)) for a in setup.axes])
        raise CalibrationError(
            f"the estimate ended in a poor minimum: it puts the camera {distance_to_wrist:.2f} m from the wrist, "
            f"so the tracked features would lie {median:.2f} m from the wrist axis (median; limit "
            f"{options.max_feature_radius_m} m); check the joint angles, the intrinsics and the wrist joint")


def _finish(pose, covariance, info, method, converged, iterations, error, reports, sigma_px,
            info_scale: float = 1.0, dof: int | None = None,
            consistency: AxisConsistency | None = None) -> CalibrationResult:
    """Result with the observability of ``info * info_scale`` (the scale makes it a real information); the
    covariance (of the pose, or the observability's when it is undetermined) is multiplied by
    ``consistency.scale``."""
    if not np.all(np.isfinite(info)):
        raise CalibrationError("the estimate ended in a poor minimum: the pose's information there is not finite "
                               "(the FK axes' test points project at or behind the camera); check the joint angles, "
                               "the intrinsics and the wrist joint")
    observability = analyse_observability(info * info_scale, pose)
    if covariance is None or not observability.is_observable:
        covariance = observability.covariance(info)
    if consistency is not None and observability.is_observable:
        covariance = covariance * consistency.scale
    return CalibrationResult(pose, covariance, method.value, bool(converged), int(iterations), float(error),
                             reports, observability, float(sigma_px), dof, axis_consistency=consistency)


def _graph_dof(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> int:
    """Residuals minus parameters of a graph at its values."""
    residuals = sum(graph.at(i).dim() for i in range(graph.size()))
    return int(residuals - values.dim())


def _reports(stage1: list[_Stage1], setup: _Setup, sigmas: dict[int, float], used: list[int], options,
             chi2: dict[int, float] | None = None, tied: dict | None = None) -> list[MeasurementReport]:
    median = float(np.median([sigmas[k] for k in used]))
    reports = []
    for k, s in enumerate(stage1):
        rejected = {**s.keys.rejected, **s.outliers}
        excluded = k not in used
        sigma = sigmas.get(k, np.sqrt(s.sigma2))
        reason = ""
        span, weak = _evidence(setup, s, k, None if tied is None else tied.get(k))
        weak = weak or k in setup.dropped
        if excluded and k in setup.dropped:
            reason = (f"left out: too little evidence for a reliable image axis ({setup.weak[k]}); the "
                      f"{len(used)} stronger measurements determine the pose without it")
        elif excluded:
            reason = (f"left out: its image axis disagrees with the FK axis projected by the estimate (chi-square "
                      f"{chi2[k]:.3g} > {options.outlier_measurement_chi2:g}, 2 dof); ")
            if weak:
                reason += ("its own evidence is thin (few tracks or short arcs): spin longer or add texture, and check "
                           "its joint angles only if that does not help")
            elif k in setup.short:
                reason += "its tracks or its joint angles are off. " + _short_words(setup, [k])
            else:
                reason += "check its joint angles"
        axis = setup.axes[k]
        reports.append(MeasurementReport(
            k, len(s.keys.tracks), s.n_points, float(sigma),
            0.0 if excluded else median**2 / sigma**2, excluded, rejected, reason,
            axis_point=[float(v) for v in axis.point], axis_direction=[float(v) for v in axis.direction],
            image_axis=[float(v) for v in s.line / np.hypot(s.line[0], s.line[1])],
            axis_chi2=None if chi2 is None else float(chi2[k]), arc_span_deg=span, weak=weak))
    _flag_outlier_measurements(reports, options)
    return reports


def _flag_outlier_measurements(reports: list[MeasurementReport], options: CalibrationOptions) -> None:
    median = np.median([r.residual_rms_px for r in reports])
    for r in reports:
        if not r.outlier and r.residual_rms_px > options.outlier_measurement_ratio * median:
            r.outlier = True
            r.outlier_reason = (f"residual RMS {r.residual_rms_px:.2f} px > {options.outlier_measurement_ratio:g}x "
                                f"the median {median:.2f} px")


def _paper(camera, setup, stage1, init_pose, options, anchor) -> CalibrationResult:
    """The seed's stage 2: unweighted, random restarts, covariance (J^T J)^-1 at unit noise."""
    rng = np.random.default_rng(options.seed)
    noises = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(stage1)
    graph = _stage2_graph(setup.axes, [s.line for s in stage1], camera.K, noises)
    starts = [init_pose, *_random_restarts(init_pose, options.restarts, rng)]
    # the unit line noise stands for the lines' real noise: the gauge prior is scaled to match (a prior of
    # GAUGE_SIGMA against 1 px lines would drag a weakly determined direction to the anchor)
    line_var = float(np.median([np.mean(np.diag(_axis_distances(camera, axis, s, init_pose)[1]))
                                for axis, s in zip(setup.axes, stage1, strict=True)]))
    minima = _stage2_minima(graph, starts, options, anchor=anchor, gauge_scale=line_var)
    # Minima within TIE_PX2 of the lowest fit the lines equally well (three measurements: several exact
    # solutions); the start was chosen by the circles, so the one nearest it is taken.
    lowest = min(m[1] for m in minima)
    pose, error, iterations, _ = min((m for m in minima if m[1] <= lowest + TIE_PX2),
                                     key=lambda m: _turned(m[0], init_pose))
    chi2 = _chi2(camera, setup, stage1, pose)
    if np.median(chi2) > options.outlier_measurement_chi2:  # the unweighted fit is suboptimal: judge loosely
        raise _poor_minimum(chi2, options.outlier_measurement_chi2, "most measurements disagree", setup)
    values = gtsam.Values()
    values.insert(POSE_KEY, pose)
    sigmas = {k: float(np.sqrt(s.sigma2)) for k, s in enumerate(stage1)}
    reports = _reports(stage1, setup, sigmas, list(range(len(stage1))), options)
    for r in reports:
        r.weight = 1.0
    # The paper's covariance assumes 1 px line errors; judge what is determined with the residual scale.
    dof = 2 * len(stage1) - 6
    line_var = max(2.0 * error / dof, options.min_sigma_px**2) if dof > 0 else 1.0
    return _finish(pose, None, pose_information(graph, values, POSE_KEY), Method.PAPER, True, iterations, error,
                   reports, np.median(list(sigmas.values())), info_scale=1.0 / line_var, dof=_graph_dof(graph, values))


def _opinion(arm, camera, measurements, setup, stage1, options):
    return lambda k, pose: _second_opinion(arm, camera, measurements, setup, stage1, k, pose, options)


def _weighted(arm, camera, measurements, setup, stage1, init_pose, options, anchor) -> CalibrationResult:
    pose, iterations, graph, used, chi2 = _robust_weighted(camera, setup, stage1, init_pose, options, anchor,
                                                           _opinion(arm, camera, measurements, setup, stage1, options))
    values = gtsam.Values()
    values.insert(POSE_KEY, pose)
    sigmas = {k: float(np.sqrt(s.sigma2)) for k, s in enumerate(stage1)}
    tied = _tied_circles(arm, camera, measurements, setup, stage1, pose, options, range(len(stage1)))
    reports = _reports(stage1, setup, sigmas, used, options, chi2, tied)
    consistency = _axis_consistency(camera, setup, stage1, used, pose, {k: stage1[k].sigma2 for k in used}, options)
    return _finish(pose, None, pose_information(graph, values, POSE_KEY), Method.WEIGHTED, True, iterations,
                   graph.error(values), reports, np.median([sigmas[k] for k in used]), dof=_graph_dof(graph, values),
                   consistency=consistency)


def _joint(arm, camera, measurements, setup, stage1, init_pose, options, anchor) -> CalibrationResult:
    """One graph: every circle-point factor (Huber per track) tied to the pose; Marginals of the whole graph.

    It starts from the weighted two-stage pose, within the joint problem's basin (from a few degrees off,
    circles of short arcs can run off to degenerate solutions that LM cannot leave), with the circles
    fitted at that pose (``"line"`` model: the stage-1 lines and circles, see RotIdGraph.add_measurement).
    """
    pose, iterations, _, used, chi2 = _robust_weighted(camera, setup, stage1, init_pose, options, anchor,
                                                       _opinion(arm, camera, measurements, setup, stage1, options))
    result = _joint_fit(arm, camera, measurements, setup, stage1, pose, iterations, used, chi2, options)
    if result.axis_consistency is None or result.axis_consistency.p_value >= RESTART_P:
        return result
    weak_used = [k for k in used if k in setup.weak]
    if weak_used and len([k for k in used if k not in setup.weak]) >= MIN_STRONG:
        # the axes disagree and weak measurements take part: fit the strong ones alone (the weak are named)
        pose, it, _, used, chi2 = _robust_weighted(camera, setup, stage1, pose, options, anchor,
                                                   _opinion(arm, camera, measurements, setup, stage1, options),
                                                   drop_weak=True)
        result = _joint_fit(arm, camera, measurements, setup, stage1, pose, result.iterations + it, used, chi2,
                            options)
        if result.axis_consistency is None or result.axis_consistency.p_value >= RESTART_P:
            return result
    return _restarted(arm, camera, measurements, setup, stage1, result, used, chi2, options, anchor)


def _restarted(arm, camera, measurements, setup, stage1, result, used, chi2, options, anchor) -> CalibrationResult:
    """When the measurements disagree with the joint estimate far beyond their noise, the estimate may be a local
    minimum that weak measurements (few tracks, short arcs) led stage 2 into: fit again from the stage-2 pose
    without each measurement in turn, and keep the fit of lowest chi-square on the same tracks (then re-test the
    measurements left out, which a wrong estimate blames)."""
    candidates = [result]
    worst = sorted(used, key=lambda k: -chi2.get(k, 0.0))[:RESTART_LEAVE_OUT]
    for k in worst:
        rest = [i for i in used if i != k]
        start, _, _ = _weighted_stage2(camera, setup, stage1, rest, result.arm_T_camera, options, anchor)
        if _turned(start, result.arm_T_camera) < np.radians(SAME_ANGLE_DEG) and np.linalg.norm(
                start.translation() - result.arm_T_camera.translation()) < RESTART_SAME_M:
            continue
        try:
            candidates.append(_joint_fit(arm, camera, measurements, setup, stage1, start, 0, used, chi2, options))
        except (CalibrationError, RotIdError, RuntimeError):
            continue
    if len(candidates) > 1:
        costs = _common_chi2(arm, camera, measurements, setup, candidates, options)[0]
        best = candidates[int(np.argmin(costs))]
    else:
        best = candidates[0]
    iterations = sum(c.iterations for c in candidates)
    left_out = [k for k in range(len(stage1)) if k not in used and k not in setup.dropped]
    opinions = {k: _second_opinion(arm, camera, measurements, setup, stage1, k, best.arm_T_camera, options)
                for k in left_out}
    back = [k for k, (_, statistic) in opinions.items() if statistic <= options.outlier_measurement_chi2]
    if back:
        chi2 = dict(chi2)
        for k in back:
            refit, chi2[k] = opinions[k]
            if refit is not None:
                stage1[k] = refit
        try:
            best = _joint_fit(arm, camera, measurements, setup, stage1, best.arm_T_camera, 0, sorted(used + back),
                              chi2, options)
        except (CalibrationError, RotIdError, RuntimeError):
            pass
        iterations += best.iterations
    best.iterations = iterations
    return best


def _joint_fit(arm, camera, measurements, setup, stage1, pose, iterations, used, chi2, options) -> CalibrationResult:
    """The joint graph of the measurements ``used`` from ``pose`` (see :func:`_joint`)."""
    builder = _builder(arm, camera, options, robust=track_huber, model=options.joint_model)
    sigmas = {k: float(np.sqrt(stage1[k].sigma2)) for k in used}
    circles = {k: None if builder.model is Model.POSE else dict(stage1[k].circles) for k in used}
    lines = {k: stage1[k].rotation for k in used}
    converged = True
    for _round in range(3):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(POSE_KEY, pose)
        keys = {k: builder.add_measurement(graph, values, k, measurements[k], track_sigmas=dict.fromkeys(
                    setup.prepared[k].usable, sigmas[k]), skip_tracks=stage1[k].outliers,
                    prepared=setup.prepared[k], initial_circles=circles[k], initial_line=lines[k],
                    refine_circles=circles[k] is None, tie_covariance=joint_tie_covariance(
                        camera, setup.axes[k], stage1[k].line, pose, setup.noise(k))) for k in used}
        start_pose = pose
        result, it, error, converged = _lm(
            graph, values, options.max_iterations, anchor=True, watch_tolerance=WATCH_POSE,
            watch=lambda v, start_pose=start_pose: start_pose.localCoordinates(v.atPose3(POSE_KEY)))
        iterations += it
        pose = result.atPose3(POSE_KEY)
        new_sigmas = {k: float(np.sqrt(_noise_variance(_track_stats(graph, keys[k], result), 1, options)))
                      for k in used}
        failed = [setup.index[k] if setup.index else k for k in used if not np.isfinite(new_sigmas[k])]
        if failed:
            raise CalibrationError(f"the joint fit failed: the circles of measurement(s) {failed} have no finite "
                                   "residuals at the estimate (too little evidence: few tracks or short arcs)")
        circles = {k: dict(zip(keys[k].tracks, _circles(keys[k], result), strict=True)) for k in used}
        lines = {k: None if keys[k].line is None else result.atRot3(keys[k].line) for k in used}
        stable = all(abs(new_sigmas[k] / sigmas[k] - 1.0) < 0.05 for k in used)
        sigmas = new_sigmas
        if stable:
            break
    info = pose_information(graph, result, POSE_KEY)
    tied = _tied_circles(arm, camera, measurements, setup, stage1, pose, options, range(len(stage1)))
    reports = _reports(stage1, setup, sigmas, used, options, chi2, tied)
    variances = {k: sigmas[k] ** 2 for k in used}
    if options.spin_model is SpinModel.RIGID and builder.model is not Model.POSE:
        rigid = _rigid_spin(camera, measurements, setup, keys, result, sigmas, options)
        if rigid is not None:
            pose, covariance, it, error, converged = rigid
            # the free-phase information is the one whose eigen-analysis names undetermined directions; the
            # rigid graph is too large for a dense Schur complement and has the same null directions
            return _finish(pose, covariance, info, Method.JOINT, converged, iterations + it, error, reports,
                           np.median(list(sigmas.values())),
                           consistency=_axis_consistency(camera, setup, stage1, used, pose, variances, options))
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(POSE_KEY)
    except RuntimeError:  # indeterminate: the observability analysis of ``info`` says why
        covariance = None
    # plus the jackknife's excess of each line (a variance in units of its pixel noise: information H E H)
    correlated = {keys[k].line: _track_correlation(keys[k].coaxial, result)
                  + stage1[k].rotation_info @ stage1[k].excess @ stage1[k].rotation_info / sigmas[k] ** 2
                  for k in used if keys[k].coaxial is not None}
    if covariance is not None and correlated:  # errors shared along a track: the cluster-robust covariance
        robust = sandwich_marginal(graph, result, POSE_KEY, 6, correlated)
        covariance = covariance if robust is None else robust
    return _finish(pose, covariance, info, Method.JOINT, converged, iterations, error, reports,
                   np.median(list(sigmas.values())), dof=_graph_dof(graph, result),
                   consistency=_axis_consistency(camera, setup, stage1, used, pose, variances, options))


def _rigid_spin(camera, measurements, setup, keys, free, sigmas, options):
    """The joint graph with the rigid spin (docs/design.md §4), started from the free-phase joint solution ``free``.

    Every track with frame indices gets a (d, r, phi0) variable and 2-D reprojection factors (one per
    two-chunk segment, Huber per segment) at phase ``theta_f + phi0``, the spin angles ``theta_f`` being
    shared by the measurement's tracks; tracks without frames keep their free-phase factor. Returns
    (pose, covariance or None, iterations, error, converged), or None when no track has frames.
    """
    K = camera.K
    C = DEFAULT_CHUNK_SIZE
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(POSE_KEY, free.atPose3(POSE_KEY))
    rigid_tracks = 0
    for k, keys_k in keys.items():
        R = free.atRot3(keys_k.line)
        values.insert(keys_k.line, R)
        tie_cov = joint_tie_covariance(camera, setup.axes[k], image_line_from_rot3(K, R)[0], free.atPose3(POSE_KEY),
                                       setup.noise(k))
        graph.add(make_axis_to_line_variable_factor(tie_noise_model(options.tie_sigma_px, tie_cov),
                                                    POSE_KEY, keys_k.line, axis_test_points(setup.axes[k]), K))
        spun = []
        for j, (d, r) in zip(keys_k.tracks, _circles(keys_k, free), strict=True):
            circle_key = gtsam.symbol("c", k * CIRCLE_STRIDE + j)
            ideal = setup.prepared[k].usable[j].ideal
            frames = Track.from_any(measurements[k].tracks[j]).frames
            if frames is None:
                values.insert(circle_key, np.array([d, r]))
                noise = gtsam.noiseModel.Robust.Create(track_huber(len(ideal)),
                                                       gtsam.noiseModel.Isotropic.Sigma(len(ideal), sigmas[k]))
                graph.add(make_circle_point_factor(noise, keys_k.line, circle_key, ideal, K))
                continue
            spun.append((j, d, r, ideal, frames, closest_phases(K, R, d, r, ideal)))
        if not spun:
            continue
        rigid_tracks += len(spun)
        first = int(min(t[4].min() for t in spun))
        init = initial_spin([(t[4], t[5]) for t in spun], C, first)

        def chunk_key(c, k=k):
            return gtsam.symbol("s", k * CIRCLE_STRIDE + int(c))

        track_keys = [gtsam.symbol("t", k * CIRCLE_STRIDE + t[0]) for t in spun]
        for c, theta in init.theta.items():
            values.insert(chunk_key(c), np.asarray(theta, dtype=float))
        for i, (_, d, r, ideal, frames, _) in enumerate(spun):
            values.insert(track_keys[i], np.array([d, r, init.phi0[i]]))
            for idx in chunk_segments(frames, C, 2, first):
                n = 2 * len(idx)
                noise = gtsam.noiseModel.Robust.Create(
                    gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(chi2_quantile(n))),
                    gtsam.noiseModel.Isotropic.Sigma(n, sigmas[k]))
                graph.add(make_rigid_circle_factor(noise, keys_k.line, track_keys[i], chunk_key, ideal[idx],
                                                   frames[idx], K, C, first))
        for prior in spin_priors(init, chunk_key, track_keys):
            graph.add(prior)
    if rigid_tracks == 0:
        return None
    result, iterations, error, converged = _lm(graph, values, options.max_iterations, anchor=True)
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(POSE_KEY)
    except RuntimeError:
        covariance = None
    return result.atPose3(POSE_KEY), covariance, iterations, error, converged


def calibrate(arm: Arm | Dataset, camera: Camera | None = None, measurements: list[Measurement] | None = None,
              method: str | Method = Method.JOINT, options: CalibrationOptions | None = None) -> CalibrationResult:
    """Estimate ``arm_T_camera`` from wrist spins.

    Call as ``calibrate(dataset)`` or ``calibrate(arm, camera, measurements)``.
    """
    if isinstance(arm, Dataset):
        dataset = arm
        arm, camera, measurements = dataset.arm, dataset.camera, list(dataset)
    if camera is None or measurements is None:
        raise InputError("calibrate needs a Dataset, or an Arm, a Camera and a list of Measurements")
    try:
        method = Method(method)
    except ValueError:
        raise InputError(f"unknown method {method!r}; choose one of {[m.value for m in Method]}") from None
    options = CalibrationOptions() if options is None else options
    measurements = [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements]
    # a measurement with fewer than two usable tracks has no image axis: it is left out and named, not fatal
    builder = _builder(arm, camera, options)
    prepared = [builder.prepare(m, k) for k, m in enumerate(measurements)]
    kept = [k for k, p in enumerate(prepared) if len(p.usable) >= 2]
    if len(kept) < MIN_MEASUREMENTS:
        bad = "; ".join(f"measurement {k}: only {len(p.usable)} usable track(s) (rejected: "
                        + ", ".join(f"track {j}: {why}" for j, why in p.rejected.items()) + ")"
                        for k, p in enumerate(prepared) if len(p.usable) < 2)
        raise InputError(f"need at least {MIN_MEASUREMENTS} measurements (arm poses) with at least 2 usable tracks "
                         f"each, got {len(kept)} of {len(measurements)}" + (f" ({bad})" if bad else "")
                         + "; spin the wrist longer or give the hand more texture")
    result, setup = _calibrate(arm, camera, [measurements[k] for k in kept], method, options, kept)
    for r in result.measurements:
        r.index = kept[r.index]
    for k, p in enumerate(prepared):
        if k in kept:
            continue
        axis = arm.wrist_axis(measurements[k].joint_angles)
        spans = [arc_span_deg(t.ideal, t.ellipse) for t in p.usable.values()]
        result.measurements.append(MeasurementReport(
            k, len(p.usable), sum(len(t.ideal) for t in p.usable.values()), float("nan"), 0.0, True,
            dict(p.rejected), f"left out: only {len(p.usable)} usable track(s), need at least 2 for an image axis; "
            "spin longer or give the hand more texture", axis_point=[float(v) for v in axis.point],
            axis_direction=[float(v) for v in axis.direction], arc_span_deg=max(spans) if spans else None, weak=True))
    result.measurements.sort(key=lambda r: r.index)
    result.untrusted = _untrusted(result, setup)
    return result


def _untrusted(result: CalibrationResult, setup: _Setup) -> dict[str, list[int]]:
    """The reasons (see :data:`UNTRUSTED_KINDS`) not to trust a determined result's covariance."""
    if not result.observability.is_observable or result.ambiguous:
        return {}
    out = {}
    c = result.axis_consistency
    weak = [m.index for m in result.measurements if m.weak]
    strong = [m.index for m in result.measurements if not m.weak and not m.outlier]
    # weak measurements are trusted only where strong ones determine the pose without them and the axes agree
    # (without redundancy, three measurements used, nothing tests them)
    weak_used = [m.index for m in result.measurements if m.weak and not m.outlier]
    if weak_used and (c is None or c.p_value < RESTART_P or len(strong) < MIN_MEASUREMENTS):
        out["thin_evidence"] = weak
    if c is not None and c.dof > 0 and c.chi2 / c.dof > MAX_CONSISTENCY_SCALE:
        out["inconsistent"] = [m.index for m in result.measurements if not m.outlier]
    elif c is not None and not c.consistent and c.dof <= 2:
        out["unmeasured_scatter"] = [m.index for m in result.measurements if not m.outlier]
    distance = float(np.median([np.linalg.norm(result.arm_T_camera.transformTo(a.point)) for a in setup.axes]))
    limit_mm = 1000.0 * MAX_RELATIVE_SIGMA * distance
    if (not np.all(np.isfinite(result.covariance)) or np.max(result.sigma_mm_arm) > limit_mm
            or np.max(result.sigma_deg) > MAX_SIGMA_DEG):
        out["too_uncertain"] = []
    return out


def _calibrate(arm, camera, measurements, method, options, index) -> tuple[CalibrationResult, _Setup]:
    starts, setup, anchors = _initial(arm, camera, measurements, options, index)
    # Short arcs (a tracker's drift shared by a measurement's tracks, which neither the per-track scores nor the
    # jackknife see) lower the level at which the axes' scatter scales the covariance: the test has 2 n - 6
    # dof, little power with six poses (18 rendered corner-tracked scenes: at 0.01 three of nine usable results
    # were outside their 99.9 % region, 11 mm off with a 1 sigma of 4-8 mm; at 0.2 none). They also make stage 1
    # refit itself from its own estimate (``_refined_stage1``: the axis through short arcs' ellipse centres, which
    # starts it, is unreliable).
    if options.axis_consistency_p is None:
        options = replace(options, axis_consistency_p=SHORT_ARC_CONSISTENCY_P if setup.short_arcs
                          else LONG_ARC_CONSISTENCY_P)
    runs = [_refined_stage1(arm, camera, measurements, start, setup, options, anchor)
            for start, anchor in zip(starts, anchors, strict=True)]
    alternatives = []
    if len(runs) > 1:  # the image axes cannot choose between the starts: the joint fit of the circles does
        joints, failures = [], []
        for (start, stage1), anchor in zip(runs, anchors, strict=True):
            try:  # a wrong start's circles may not fit at all: its estimate is then a poor one
                joint = _joint(arm, camera, measurements, setup, stage1, start, options, anchor)
                _check_scale(joint, setup, stage1, options)
                joints.append(joint)
            except CalibrationError as failure:
                joints.append(None)
                failures.append(failure)
        if len(failures) == len(runs):
            raise failures[0]
        best, alternatives = _choose(arm, camera, measurements, setup, joints, options)
        if method is Method.JOINT:
            joints[best].alternatives = alternatives
            joints[best].joint_sigma_deg = options.joint_sigma_deg
            return joints[best], setup
        runs, anchors = [runs[best]], [anchors[best]]
    init_pose, stage1 = runs[0]
    result = _estimate(arm, camera, measurements, method, setup, stage1, init_pose, options, anchors[0])
    _check_scale(result, setup, stage1, options)
    result.alternatives = alternatives
    result.joint_sigma_deg = 0.0 if method is Method.PAPER else options.joint_sigma_deg
    return result, setup


def _turning_deg(pixels: np.ndarray, chunks: int = 8) -> float:
    """How far a track's direction of motion turns along it (deg): the signed turns between its ``chunks``
    successive chords, summed. About the arc it spans (a full turn: 315 degrees), and unlike the arc about its own
    fitted ellipse it does not wrap around a short arc's too small ellipse."""
    if len(pixels) < 2 * chunks:
        return 0.0
    chords = np.diff(pixels[np.linspace(0, len(pixels) - 1, chunks + 1).astype(int)], axis=0)
    angles = np.arctan2(chords[:, 1], chords[:, 0])
    turns = (np.diff(angles) + np.pi) % (2.0 * np.pi) - np.pi
    return float(np.degrees(abs(np.sum(turns))))


def _turned(a: gtsam.Pose3, b: gtsam.Pose3) -> float:
    """Rotation angle (rad) between two poses."""
    return float(np.linalg.norm(a.localCoordinates(b)[:3]))


def _same_solution(result: CalibrationResult, pose: gtsam.Pose3) -> bool:
    """``pose`` is ``result``'s solution again: inside its 99.9 % region when the covariance is usable, else
    turned less than SAME_ANGLE_DEG from it (positions differ arbitrarily along undetermined directions)."""
    xi = result.arm_T_camera.localCoordinates(pose)
    if result.observability.is_observable:
        try:
            return float(xi @ np.linalg.solve(result.covariance, xi)) <= CHI2_6_999
        except np.linalg.LinAlgError:
            pass
    return float(np.linalg.norm(xi[:3])) < np.radians(SAME_ANGLE_DEG)


def _common_chi2(arm, camera, measurements, setup, results: list[CalibrationResult],
                 options) -> tuple[np.ndarray, list[gtsam.Pose3]]:
    """Chi-square and pose of each result re-solved (from its pose) on one joint graph: the measurements and tracks
    that none of ``results`` rejected, each measurement at the smallest of their pixel sigmas."""
    used = [k for k in range(len(measurements)) if not any(r.measurements[k].outlier for r in results)]
    sigmas = {k: max(min(r.measurements[k].residual_rms_px for r in results), options.min_sigma_px) for k in used}
    skip = {k: set().union(*(r.measurements[k].rejected_tracks for r in results)) for k in used}
    builder = _builder(arm, camera, options, robust=track_huber, model=options.joint_model)
    chi2, poses = [], []
    for r in results:
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(POSE_KEY, r.arm_T_camera)
        try:
            for k in used:
                builder.add_measurement(graph, values, k, measurements[k], skip_tracks=skip[k],
                                        track_sigmas=dict.fromkeys(setup.prepared[k].usable, sigmas[k]),
                                        prepared=setup.prepared[k], tie_covariance=joint_tie_covariance(
                                            camera, setup.axes[k], None, r.arm_T_camera, setup.noise(k)))
        except RotIdError:  # this pose cannot carry those tracks (e.g. an ellipse behind the camera)
            chi2.append(np.inf)
            poses.append(r.arm_T_camera)
            continue
        start = r.arm_T_camera
        solved, _, error, _ = _lm(graph, values, options.max_iterations, anchor=True, watch_tolerance=WATCH_POSE,
                                  watch=lambda v, start=start: start.localCoordinates(v.atPose3(POSE_KEY)))
        chi2.append(2.0 * error)
        poses.append(solved.atPose3(POSE_KEY))
    return np.array(chi2), poses


def _choose(arm, camera, measurements, setup, joints: list[CalibrationResult | None],
            options) -> tuple[int, list[Alternative]]:
    """The joint result that fits best and the other distinct ones as :class:`Alternative`.

    The results may have rejected different tracks and estimated different pixel noise, so their own errors are
    not comparable: each pose is re-solved on one graph (the tracks and measurements none of them rejected, one
    pixel sigma per measurement) and the chi-squares of that graph compared.
    """
    ok = [i for i, r in enumerate(joints) if r is not None]
    if len(ok) == 1:
        return ok[0], []
    results = [joints[i] for i in ok]
    chi2, poses = _common_chi2(arm, camera, measurements, setup, results, options)
    order = [int(j) for j in np.argsort(chi2)]
    best = results[order[0]]
    alternatives: list[Alternative] = []
    for j in order[1:]:
        if not np.isfinite(chi2[j]) or _same_solution(best, poses[j]) or any(
                _turned(a.arm_T_camera, poses[j]) < np.radians(SAME_ANGLE_DEG) for a in alternatives):
            continue
        alternatives.append(Alternative(poses[j], float(chi2[j] - chi2[order[0]])))
    return ok[order[0]], alternatives


def _estimate(arm, camera, measurements, method, setup, stage1, init_pose, options, anchor) -> CalibrationResult:
    if method is Method.PAPER:
        return _paper(camera, setup, stage1, init_pose, options, anchor)
    if method is Method.WEIGHTED:
        return _weighted(arm, camera, measurements, setup, stage1, init_pose, options, anchor)
    return _joint(arm, camera, measurements, setup, stage1, init_pose, options, anchor)
