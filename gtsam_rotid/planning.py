"""Plan the arm poses of a calibration and predict its accuracy before anything is recorded (docs/design.md §9).

The prediction is the information the calibration's own graph (:class:`gtsam_rotid.graph.RotIdGraph`, projected
model: a line per measurement tied to the pose) would hold at the camera's guessed pose, for noise-free spins of a
typical textured end effector (``PlanOptions.n_features`` features spread over the radius and offset ranges, seen
as the simulator sees them: while they face the camera and are inside the image), at ``pixel_sigma`` per tracked
point, with every image axis also shifted by the tracker's floor ``axis_floor_px`` (a bias its tracks share). Its
inverse is the Cramér-Rao bound of that model, which the joint estimator reaches on simulated tracks.

The plan samples arm poses inside the joint limits and keeps those that satisfy every constraint at the guess: the
spinning links inside the image with a margin at a workable distance, the spinning axis neither end-on nor
side-on, no self-collision and nothing below the floor (:class:`gtsam_rotid.collisions.ArmCollisions`), the
features' lines of sight not blocked by the arm's other links. It then chooses the ``n`` poses that minimise the
worst axis' 1σ (rotation in units of ``worst_axis_deg``, translation of ``worst_axis_mm``), averaged over camera
poses drawn from the guess' uncertainty: greedily, then by exchanges until no swap helps. Axes that all pass near
one point determine nothing along the ray to it, so the criterion never chooses them.
"""

from __future__ import annotations

import math
import multiprocessing
import re
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from .arm import Arm
from .calibration.joint import CAL3_S2_ORDER, intrinsics_prior_sigmas
from .calibration.options import (
    DEFAULT_INTRINSICS_SIGMA,
    CalibrationOptions,
    checked_intrinsics_sigma,
    checked_offset_sigma_deg,
    tracker_floor_px,
    tracker_offset_px,
)
from .calibration.stage1 import MeasuredNoise, measured_noise
from .camera import Camera
from .collisions import ArmCollisions
from .dataset import Dataset
from .errors import ArmError, InputError
from .factors import cal3_s2
from .graph import MIN_TRACK_EXTENT_PX, RotIdGraph
from .initialise import MIN_ELLIPSE_POINTS
from .simulate import SceneConfig, SpinScene
from .trackparams import CORNER_AXIS_FLOOR_PX
from .uncertainty import Observability, analyse_observability, marginal_information, pose_information

#: A camera guess farther than this (m) from the arm's base is taken for a mistake of units.
MAX_GUESS_DISTANCE_M = 20.0
#: Draws without one pose that satisfies the constraints after which the search gives up.
HOPELESS_DRAWS = 4000
#: Axes drawn for one aimed pose before it gives up (each a cheap check that the end effector would be in view)
AIM_TRIES = 200
#: the spin model the search ranks candidate poses by (the predictions use PlanOptions.spin_model)
SEARCH_SPIN_MODEL = "free"
#: the turn (degrees) between the collision checks of a spin of another joint than the wrist
SWING_STEP_DEG = 30.0
#: ``PlanOptions.refine_intrinsics``: the intrinsics the prediction frees with the pose, in Cal3_S2's tangent order
#: (fx, fy, s, cx, cy) less the skew (held, as the joint fit holds it): the information is (6+4)x(6+4)
PLAN_INTRINSICS = ("fx", "fy", "cx", "cy")
#: ... their places in Cal3_S2's tangent
_PLAN_INDICES = [CAL3_S2_ORDER.index(n) for n in PLAN_INTRINSICS]
#: the key of the intrinsics variable in the prediction's graph
_INTRINSICS_KEY = gtsam.symbol("k", 0)

#: (deg, deg, deg, mm, mm, mm) per unit of the Pose3 tangent (rad, m)
UNITS = np.array([math.degrees(1.0)] * 3 + [1000.0] * 3)


class PlanningError(InputError):
    """No plan: too few arm poses satisfy the constraints, or the inputs cannot make one."""


@dataclass(frozen=True)
class PlanOptions:
    """What a plan assumes about the recording and what it requires of a pose. Units: m, s, px, degrees."""

    #: the recording: seconds of spin per pose, frame rate, spin speed (rad/s)
    spin_seconds: float = 20.0
    fps: float = 30.0
    wrist_speed: float = 0.5
    #: pixel noise of a tracked point, and the tracker's floor on each image axis (px; 0 for simulated tracks; the
    #: default stands for the corner tracker's errors, :data:`gtsam_rotid.trackparams.CORNER_AXIS_FLOOR_PX`)
    pixel_sigma: float = 0.5
    axis_floor_px: float = CORNER_AXIS_FLOOR_PX
    #: the texture: features at these distances from the spinning axis and along it from the joint origin (m);
    #: None: the end effector's own surface (the spinning links' collision hulls: 10th-90th percentile along the
    #: axis, half to all of the 90th-percentile radius) when collisions are checked, else the simulator's
    #: (0.03, 0.06) and (0.0, 0.10)
    n_features: int = 12
    radius_range: tuple | None = None
    offset_range: tuple | None = None
    #: constraints: camera-to-wrist distance, angle of the axis to the viewing ray, image margin (px), lowest
    #: height of the spinning links (m, arm frame), floor plane height (None: no floor), largest fraction of the
    #: features' circles the arm's other links may hide
    depth_range: tuple = (0.5, 1.6)
    axis_view_angle_deg: tuple = (25.0, 75.0)
    image_margin: float = 12.0
    min_height: float = 0.05
    floor_height: float | None = 0.0
    max_hidden_fraction: float = 0.25
    #: the guess' uncertainty (1σ per axis, mm and degrees) and how many camera poses are drawn from it
    guess_sigma_mm: float = 30.0
    guess_sigma_deg: float = 3.0
    guess_samples: int = 6
    #: the search ranks candidates (choice and local steps) at the first this many of them (the guess first); the
    #: chosen poses' prediction uses all ``guess_samples``
    rank_samples: int = 3
    #: the end effector must stay inside the image by this many sigmas of its image motion under the guess' 1σ
    constraint_sigmas: float = 2.0
    #: candidate poses sampled (and the most random draws spent finding them); a worst-axis unit pair
    candidates: int = 450
    max_draws: int = 100_000
    #: the search for candidates stops after this long (s) once it has a third of them (None: never, so that a plan
    #: does not depend on the machine's speed or load); local steps after the choice
    search_seconds: float | None = 12.0
    refine_steps: int = 60
    #: processes that search for and evaluate candidates (1: this process only). Each takes its share of the
    #: candidates with its own random stream: a seed gives the same plan for the same ``jobs`` (unless a search stops
    #: at ``search_seconds``: None makes it machine-independent). Other processes are forked (Linux); where they
    #: cannot be, or other threads run in this process (a Dask worker), the shares run here in turn
    jobs: int = 2
    worst_axis_mm: float = 1.0
    worst_axis_deg: float = 0.05
    #: the prediction's frame rate (information scales with the points; fewer points, each less noisy)
    prediction_fps: float = 10.0
    #: a spinning joint with limits (the Panda's ±166°) turns back and forth over its range: the prediction then
    #: sees that arc only, as often as the spin's length allows (False: the simulator's unlimited spin)
    respect_wrist_limits: bool = True
    #: how the calibration will model the spin (``CalibrationOptions.spin_model``): "rigid" (one angle per frame
    #: shared by the features, the calibration's default) or "free" (a phase per point). The predictions use it;
    #: the search ranks candidates by the free phase's information, 3x cheaper and within ~5 % of the rigid one's
    spin_model: str = "rigid"
    #: the joints spun at every pose, one spin (one measurement) each, names (empty: the wrist only). A spin of
    #: another joint swings the hand about that joint's axis: the whole swing must stay in view, above
    #: ``min_height`` and, with collisions, clear of the arm and the floor (checked every SWING_STEP_DEG); it is
    #: predicted as the simulator's unlimited spin
    spin_joints: tuple = ()
    #: the calibration will refine the camera's intrinsics (``CalibrationOptions(refine_intrinsics=True)``: fx, fy,
    #: cx, cy under a prior of ``intrinsics_sigma`` = (focal lengths' fraction, principal point px) about the camera
    #: given): the information is that of the pose and the intrinsics, and every choice and prediction uses the
    #: pose's marginal (the intrinsics under their prior). Needs the rigid spin; the search then ranks by it too
    refine_intrinsics: bool = False
    intrinsics_sigma: tuple = DEFAULT_INTRINSICS_SIGMA
    #: the calibration will refine joint offsets (``CalibrationOptions(joint_offsets=...)``: True for every joint
    #: between the first and the spinning one, or a tuple of joint names) under a prior of
    #: ``joint_offset_sigma_deg``: the information spans them too and every choice and prediction uses the pose's
    #: marginal (the offsets under their prior), as with ``refine_intrinsics`` (both may be set)
    joint_offsets: bool | tuple = False
    joint_offset_sigma_deg: float = 1.0
    seed: int = 0

    def with_(self, **changes) -> PlanOptions:
        return replace(self, **changes)

    def scene_config(self, camera: Camera, robot: str = "kinova") -> SceneConfig:
        """The simulator's scene with this recording, texture and these constraints (``duration`` = the spin)."""
        return SceneConfig(robot=robot, camera=camera, n_features=self.n_features, radius_range=self.radius_range,
                           offset_range=self.offset_range, duration=self.spin_seconds, fps=self.fps,
                           wrist_speed=self.wrist_speed, noise_var=self.pixel_sigma**2,
                           axis_view_angle_deg=self.axis_view_angle_deg, depth_range=self.depth_range,
                           image_margin=self.image_margin, min_height=self.min_height,
                           spin_joints=tuple(self.spin_joints))

    def with_texture(self, arm: Arm, collisions: ArmCollisions | None) -> PlanOptions:
        """These options with ``radius_range`` and ``offset_range`` filled in (see their comment)."""
        if self.radius_range is not None and self.offset_range is not None:
            return self
        radius, offset = (0.03, 0.06), (0.0, 0.10)
        if collisions is not None:
            points = collisions.spinning_points(400)
            axis = arm.wrist_axis_local()
            along = points @ axis
            radial = np.linalg.norm(points - np.outer(along, axis), axis=1)
            r = float(np.percentile(radial, 90))
            radius, offset = (0.5 * r, r), (float(np.percentile(along, 10)), float(np.percentile(along, 90)))
        return replace(self, radius_range=self.radius_range or radius, offset_range=self.offset_range or offset)

    def check(self) -> None:
        positive = {"spin_seconds": self.spin_seconds, "fps": self.fps, "pixel_sigma": self.pixel_sigma,
                    "prediction_fps": self.prediction_fps, "worst_axis_mm": self.worst_axis_mm,
                    "worst_axis_deg": self.worst_axis_deg}
        for name, value in positive.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise PlanningError(f"{name} must be a positive number, got {value!r}")
        for name in ("axis_floor_px", "guess_sigma_mm", "guess_sigma_deg"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise PlanningError(f"{name} must be a number >= 0, got {value!r}")
        seconds = self.search_seconds
        if seconds is not None and not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
            raise PlanningError(f"search_seconds must be a positive number or None (no deadline), got {seconds!r}")
        if self.spin_model not in ("rigid", "free"):
            raise PlanningError(f"spin_model must be 'rigid' or 'free', got {self.spin_model!r}")
        if self.refine_intrinsics:
            if self.spin_model != "rigid":
                raise PlanningError("refine_intrinsics needs spin_model='rigid' (as the calibration does)")
            try:
                checked_intrinsics_sigma(self.intrinsics_sigma)
            except InputError as error:
                raise PlanningError(str(error)) from None
        offsets = self.joint_offsets
        if not (isinstance(offsets, bool) or (isinstance(offsets, tuple | list) and offsets
                                              and all(isinstance(j, str) for j in offsets))):
            raise PlanningError(f"joint_offsets must be True, False or a tuple of joint names, got {offsets!r}")
        try:
            checked_offset_sigma_deg(self.joint_offset_sigma_deg)
        except InputError as error:
            raise PlanningError(str(error)) from None
        if isinstance(self.spin_joints, str) or not all(isinstance(j, str) for j in self.spin_joints):
            raise PlanningError(f"spin_joints must be a tuple of joint names, got {self.spin_joints!r}")
        if self.n_features < 2 or self.guess_samples < 1 or self.candidates < 1:
            raise PlanningError("n_features must be >= 2, guess_samples and candidates >= 1")
        for name in ("rank_samples", "jobs"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise PlanningError(f"{name} must be an integer >= 1, got {value!r}")


@dataclass
class Prediction:
    """The predicted accuracy of a set of arm poses at a camera guess.

    ``covariance`` (6x6, Pose3 tangent: rotation rad then translation m in the camera frame) is the bound averaged
    over the guess samples; ``information`` is the data's at the guess itself, ``observability`` its analysis
    (undetermined directions get σ = 1000 km). ``per_pose`` holds each pose's information at the guess.
    """

    arm_T_camera: gtsam.Pose3
    joint_angles: list[np.ndarray]
    information: np.ndarray
    covariance: np.ndarray
    observability: Observability
    per_pose: list[np.ndarray]
    options: PlanOptions
    #: each pose's constraint problem at the guess (None: satisfies them all)
    problems: list[str | None] = field(default_factory=list)
    #: the prediction includes an existing calibration's information (``prior_information``)
    with_prior: bool = False
    #: the arc (deg) the spinning joint's limits allow, when shorter than the spin (it turns back and forth)
    spin_range_deg: float | None = None

    @property
    def sigma(self) -> np.ndarray:
        """1σ per tangent axis: rx, ry, rz (deg, about the camera axes), tx, ty, tz (mm, camera frame)."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0)) * UNITS

    @property
    def sigma_mm_arm(self) -> np.ndarray:
        """1σ of the camera position along the arm frame's x, y, z (mm)."""
        R = self.arm_T_camera.rotation().matrix()
        return np.sqrt(np.maximum(np.diag(R @ self.covariance[3:, 3:] @ R.T), 0.0)) * 1000.0

    @property
    def worst(self) -> tuple[float, float]:
        """(worst rotation 1σ in degrees, worst translation 1σ in mm)."""
        s = self.sigma
        return float(s[:3].max()), float(s[3:].max())


@dataclass
class Plan:
    """Chosen arm poses (``joint_angles``, model order, radians) with their :class:`Prediction`, the candidates
    they were chosen from and why the other draws were refused."""

    joint_angles: list[np.ndarray]
    prediction: Prediction
    candidates: int
    draws: int
    refused: dict[str, int]
    seconds: float
    joint_names: list[str]
    #: with an existing calibration: its predicted 1σ before the new poses (deg x3, mm x3)
    sigma_before: np.ndarray | None = None


# ------------------------------------------------------------------------------------------------- helpers
def typical_features(options: PlanOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A deterministic texture: radii, offsets and phases spread evenly (a Kronecker sequence) over their ranges."""
    n = options.n_features
    i = np.arange(n) + 0.5
    golden, plastic = 0.6180339887498949, 0.7548776662466927
    radii = options.radius_range[0] + (i / n) * np.ptp(options.radius_range)
    offsets = options.offset_range[0] + np.mod(i * golden, 1.0) * np.ptp(options.offset_range)
    phases = 2.0 * np.pi * np.mod(i * plastic, 1.0)
    return radii, offsets, phases


def _tangent(deg: float, mm: float) -> np.ndarray:
    """(deg, mm) per axis -> the Pose3 tangent's (rad x3, m x3)."""
    return np.array([math.radians(deg)] * 3 + [mm / 1000.0] * 3)


def guess_samples(guess: gtsam.Pose3, options: PlanOptions) -> list[gtsam.Pose3]:
    """The guess and ``guess_samples - 1`` camera poses drawn about it (seeded: the same each run)."""
    rng = np.random.default_rng(options.seed + 7919)
    sigma = _tangent(options.guess_sigma_deg, options.guess_sigma_mm)
    return [guess] + [guess.retract(rng.normal(size=6) * sigma) for _ in range(options.guess_samples - 1)]


def _criterion(covariances: np.ndarray, options: PlanOptions) -> np.ndarray:
    """Worst axis' 1σ in units of (``worst_axis_deg``, ``worst_axis_mm``), averaged over guess samples; any batch
    shape (..., S, 6, 6) -> (...)."""
    variances = np.diagonal(covariances, axis1=-2, axis2=-1)[..., :6] / _unit_scale(options) ** 2
    return np.sqrt(np.maximum(variances, 0.0).max(axis=-1)).mean(axis=-1)


#: A weak prior (1σ of 1000 rad and 1000 m) that keeps the exchanges' information invertible; far below any
#: spin's, it never enters a reported prediction.
REGULARISER = 1e-6 * np.eye(6)


def _pose_marginal(information: np.ndarray) -> np.ndarray:
    """(..., d, d) information of the pose and the intrinsics (their prior included) -> (..., 6, 6) the pose's
    marginal (Schur complement); a 6x6 information is returned as it is."""
    if information.shape[-1] == 6:
        return information
    A, B, C = information[..., :6, :6], information[..., :6, 6:], information[..., 6:, 6:]
    S = A - B @ np.linalg.solve(C, np.swapaxes(B, -1, -2))
    return 0.5 * (S + np.swapaxes(S, -1, -2))


def _nuisance_graph(builder: RotIdGraph, arm_T_camera: gtsam.Pose3) -> tuple[gtsam.NonlinearFactorGraph,
                                                                              gtsam.Values]:
    """An empty graph and its values for ``builder``'s measurements: the pose at ``arm_T_camera`` and, where the
    builder reads them, the intrinsics at the camera's and the offsets at zero (without their priors: the data's
    information alone)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, arm_T_camera)
    if builder.intrinsics_key is not None:
        values.insert(builder.intrinsics_key, cal3_s2(builder.camera.K))
    if builder.offset_joints:
        values.insert(builder.offsets_key, np.zeros(len(builder.offset_joints)))
    return graph, values


def _information(graph, values, builder: RotIdGraph) -> np.ndarray:
    """A graph's information on the pose (6x6), and where ``builder`` reads them on PLAN_INTRINSICS (the skew held)
    and on the offsets, in that order, everything else marginalised."""
    intrinsics, n_offsets = builder.intrinsics_key is not None, len(builder.offset_joints)
    if not intrinsics and not n_offsets:
        return pose_information(graph, values, builder.pose_key)
    keys, keep = [builder.pose_key], list(range(6))
    if intrinsics:
        keys.append(builder.intrinsics_key)
        keep += [6 + i for i in _PLAN_INDICES]
    if n_offsets:
        keys.append(builder.offsets_key)
        keep += list(range(6 + 5 * intrinsics, 6 + 5 * intrinsics + n_offsets))
    full = marginal_information(graph, values, keys, 6 + 5 * intrinsics + n_offsets)
    return full[np.ix_(keep, keep)]


def _full_prior(predictor: _Predictor, prior: np.ndarray) -> np.ndarray:
    """The prior information in the predictor's dimension: ``prior`` (6x6 on the pose, or, refining the intrinsics
    or the offsets, on the pose and those: :func:`dataset_information` with the same options) plus theirs."""
    if predictor.dim == 6:
        if prior.shape != (6, 6):
            raise PlanningError(f"prior_information must be 6x6 (the pose's), got {prior.shape}")
        return prior
    if prior.shape not in ((6, 6), (predictor.dim, predictor.dim)):
        raise PlanningError(f"prior_information must be 6x6 (the pose's) or {predictor.dim}x{predictor.dim} (the "
                            f"pose's and the {predictor.nuisance_words}), got {prior.shape}")
    return (predictor.embed(prior) if prior.shape == (6, 6) else prior) + predictor.nuisance_prior()


def _unit_scale(options: PlanOptions) -> np.ndarray:
    """The worst-axis units in the Pose3 tangent (rad, m)."""
    return _tangent(options.worst_axis_deg, options.worst_axis_mm)


class _Predictor:
    """The information of one spin at one camera pose: a noise-free simulated measurement in the calibration's
    graph."""

    def __init__(self, arm: Arm, camera: Camera, options: PlanOptions):
        self.arm, self.camera, self.options = arm, camera, options
        step = max(1, int(round(options.fps / options.prediction_fps)))
        self.fps = options.fps / step
        spin = abs(options.wrist_speed) * options.spin_seconds
        span = arm.wrist_range() if options.respect_wrist_limits else None
        #: the arc (rad) the spinning joint's limits allow, when shorter than the spin; the spin starts at a limit
        self.limited_span = span if span is not None and span < spin else None
        duration, repeats = options.spin_seconds, 1.0
        self.wrist_start = None
        if self.limited_span is not None:
            duration, repeats = self.limited_span / abs(options.wrist_speed), spin / self.limited_span
            w = arm.wrist_index
            self.wrist_start = arm.lower_limits[w] if options.wrist_speed > 0 else arm.upper_limits[w]
        self.config = options.scene_config(camera).with_(fps=self.fps, noise_var=0.0, min_track_length=3,
                                                         duration=duration)
        # fewer points, each carrying `step` points' worth (and the arc's repeats, back and forth)
        self.sigma_px = options.pixel_sigma / math.sqrt(step * repeats)
        self.features = typical_features(options)
        self.tie_covariance = 2.0 * options.axis_floor_px**2 * np.eye(2)
        self._rng = np.random.default_rng(0)
        #: how many joint offsets the calibration will refine (``joint_offsets``; ArmError for a bad name)
        self.n_offsets = 0 if options.joint_offsets is False else len(arm.offset_joints(options.joint_offsets))
        self.n_intrinsics = len(PLAN_INTRINSICS) if options.refine_intrinsics else 0
        #: the information's dimension: the pose's, the intrinsics' (PLAN_INTRINSICS) when they are refined, then
        #: the offsets'
        self.dim = 6 + self.n_intrinsics + self.n_offsets

    @property
    def nuisance_words(self) -> str:
        """What the information spans beyond the pose, in words."""
        return " and ".join(w for w, n in (("intrinsics' (refine_intrinsics)", self.n_intrinsics),
                                           ("offsets' (joint_offsets)", self.n_offsets)) if n)

    def nuisance_prior(self) -> np.ndarray:
        """(dim, dim): the intrinsics' and the offsets' prior information (zero on the pose's block; all zero
        without them)."""
        out = np.zeros((self.dim, self.dim))
        if self.n_intrinsics:
            sigmas = intrinsics_prior_sigmas(self.camera.K, PLAN_INTRINSICS, self.options.intrinsics_sigma)
            chosen = sigmas[_PLAN_INDICES]
            out[6:6 + self.n_intrinsics, 6:6 + self.n_intrinsics] = np.diag(1.0 / chosen**2)
        if self.n_offsets:
            o = 6 + self.n_intrinsics
            out[o:, o:] = np.eye(self.n_offsets) / math.radians(self.options.joint_offset_sigma_deg) ** 2
        return out

    def embed(self, pose_information: np.ndarray) -> np.ndarray:
        """A 6x6 pose information in the (dim, dim) information (unchanged without the intrinsics)."""
        if self.dim == 6:
            return pose_information
        out = np.zeros((self.dim, self.dim))
        out[:6, :6] = pose_information
        return out

    def scene(self, arm_T_camera: gtsam.Pose3) -> SpinScene:
        return SpinScene(self.config, self.arm, self._rng, arm_T_camera=arm_T_camera, features=self.features)

    def sample_scenes(self, guess: gtsam.Pose3) -> list[SpinScene]:
        """The scenes the prediction averages over: the typical texture at the guess, then a random texture (drawn
        as the simulator draws one) at each other camera pose drawn from the guess: a bound averaged over textures
        is larger than the bound of the average texture."""
        samples = guess_samples(guess, self.options)
        rng = np.random.default_rng(self.options.seed + 104729)
        return [self.scene(samples[0])] + [SpinScene(self.config, self.arm, rng, arm_T_camera=pose)
                                           for pose in samples[1:]]

    def information(self, scene: SpinScene, joint_angles, spin_model: str | None = None) -> np.ndarray:
        """The 6x6 information of the spins at ``joint_angles`` in ``scene`` (one per ``spin_joints``, the wrist's
        alone by default), with the options' spin model or ``spin_model``. With ``refine_intrinsics``: the (6+4)^2
        information of the pose and fx, fy, cx, cy (the data's alone, without their prior; the skew held), always
        with the rigid spin (the free phase leaves the intrinsics nearly free); with ``joint_offsets`` the offsets'
        too, last (:attr:`dim`)."""
        intrinsics = self.n_intrinsics > 0
        if intrinsics:
            spin_model = "rigid"

        def builder(sigma_px: float) -> RotIdGraph:
            return RotIdGraph(self.arm, self.camera, model="projected", track_sigma_px=sigma_px,
                              min_track_points=MIN_ELLIPSE_POINTS, min_track_extent_px=MIN_TRACK_EXTENT_PX,
                              spin_model=spin_model or self.options.spin_model,
                              intrinsics_key=_INTRINSICS_KEY if intrinsics else None,
                              joint_offsets=self.options.joint_offsets)

        wrist_builder = builder(self.sigma_px)
        # (the wrist's limited arc and its repeats do not apply to another joint's spin: the simulator's spin)
        other_builder = wrist_builder if self.limited_span is None else \
            builder(self.options.pixel_sigma / math.sqrt(self.options.fps / self.fps))
        graph, values = _nuisance_graph(wrist_builder, scene.arm_T_camera)
        for k, joint in enumerate(self.options.spin_joints or (None,)):
            q, spin_builder = np.array(joint_angles, dtype=float), wrist_builder
            if self.arm.spins_wrist(joint):
                if self.wrist_start is not None:
                    q[self.arm.wrist_index] = self.wrist_start
            else:
                spin_builder = other_builder
            try:
                measurement, _ = scene.measurement(q, self._rng, joint)
                spin_builder.add_measurement(graph, values, k, measurement, tie_covariance=self.tie_covariance)
            except InputError:  # fewer than two usable arcs: this spin tells nothing
                continue
        if graph.size() == 0:
            return np.zeros((self.dim, self.dim))
        return _information(graph, values, wrist_builder)


class _Constraints:
    """Whether an arm pose satisfies the plan's constraints at the guess (words when it does not)."""

    def __init__(self, predictor: _Predictor, guess: gtsam.Pose3, collisions: ArmCollisions | None):
        self.scene = predictor.scene(guess)
        o = predictor.options
        # the guess' 1σ moves the image: the end effector must stay inside by constraint_sigmas of that motion
        sigma = _tangent(o.guess_sigma_deg, o.guess_sigma_mm)
        self._moved = [predictor.scene(guess.retract(sigma[i] * np.eye(6)[i])) for i in range(6) if sigma[i] > 0]
        self.options = predictor.options
        self.collisions = collisions
        self.camera_centre = np.asarray(guess.translation(), dtype=float)
        self._local_points = None if collisions is None else collisions.spinning_points()

    def _image_motion_problem(self, joint_angles) -> str | None:
        """Words when the end effector's rims (as the simulator's check draws them) come closer to the image border
        than ``image_margin`` plus ``constraint_sigmas`` times their 1σ motion under the guess' uncertainty."""
        o = self.options
        if o.constraint_sigmas <= 0 or not self._moved:
            return None
        axis, e1, e2 = self.scene.basis(joint_angles)
        if self._rims_inside(axis.point[None], axis.direction[None], e1[None], e2[None], o.constraint_sigmas)[0]:
            return None
        return f"end effector leaves the image with the guess off by its uncertainty ({o.constraint_sigmas:g} sigma)"

    def _rims_inside(self, points, directions, e1, e2, sigmas: float) -> np.ndarray:
        """For each axis (rows of (B, 3) arrays: a point, the direction, two unit vectors perpendicular to it):
        whether the end effector's rims about it stay ``image_margin`` plus ``sigmas`` times their 1σ image motion
        (under the guess' uncertainty) inside the image, and above ``min_height``. (B,) bool."""
        o = self.options
        phases = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
        ring = o.radius_range[1] * (np.cos(phases)[None, :, None] * e1[:, None] + np.sin(phases)[None, :, None]
                                    * e2[:, None])  # (B, 24, 3)
        rims = np.concatenate([points[:, None] + d * directions[:, None] + ring for d in o.offset_range], axis=1)
        flat = rims.reshape(-1, 3)
        pixels = self.scene.project(flat)
        motion = np.sqrt(sum((scene.project(flat) - pixels) ** 2 for scene in self._moved)) if sigmas > 0 else 0.0
        camera = self.scene.camera
        low = pixels - sigmas * motion - o.image_margin
        high = pixels + sigmas * motion + o.image_margin
        inside = np.all((low >= -0.5) & (high <= np.array([camera.width, camera.height]) - 0.5), axis=1)
        return inside.reshape(len(points), -1).all(axis=1) & (rims[..., 2].min(axis=1) >= o.min_height)

    def aimed(self, rng: np.random.Generator, in_view: bool = False) -> np.ndarray | None:
        """Joint angles (inverse kinematics from a random start) that put the wrist on a random ray through the inner
        part of the image, at a random workable distance, its axis at a random workable angle to the ray; None when
        the arm cannot reach it. ``in_view``: the axis is drawn again (up to ``AIM_TRIES`` times, a cheap check
        each) until the end effector about it stays inside the image by the constraints' margin, and the inverse
        kinematics gives up early on a start that stays far from it (for the plan's many candidates; the random
        valid poses keep the plain draw)."""
        if in_view:
            axis = self._axis_in_view(rng)
            if axis is None:
                return None
            point, direction = axis
        else:
            o, camera = self.options, self.scene.camera
            pixel = np.array([camera.width, camera.height]) * rng.uniform(0.25, 0.75, size=2)
            ray = np.linalg.solve(camera.K, np.append(pixel, 1.0))
            ray = self.scene.arm_T_camera.rotation().matrix() @ (ray / np.linalg.norm(ray))
            point = self.camera_centre + rng.uniform(*o.depth_range) * ray
            angle = math.radians(rng.uniform(*o.axis_view_angle_deg))
            side = np.cross(ray, rng.normal(size=3))
            side /= np.linalg.norm(side)
            direction = math.cos(angle) * ray * rng.choice([-1.0, 1.0]) + math.sin(angle) * side
        try:
            return self.scene.arm.solve_wrist_axis(point, direction, self.scene.arm.random_joint_angles(rng),
                                                   iterations=60, tolerance=1e-4,
                                                   give_up_after=15 if in_view else None)
        except ArmError:
            return None

    def _axis_in_view(self, rng: np.random.Generator, batch: int = 50):
        """(point, direction) of an axis drawn as :meth:`aimed` draws one whose end effector stays in the image;
        None after ``AIM_TRIES`` draws."""
        o, camera = self.options, self.scene.camera
        R = self.scene.arm_T_camera.rotation().matrix()
        for _ in range(max(1, AIM_TRIES // batch)):
            pixels = np.array([camera.width, camera.height]) * rng.uniform(0.25, 0.75, size=(batch, 2))
            rays = np.linalg.solve(camera.K, np.column_stack([pixels, np.ones(batch)]).T).T
            rays = (rays / np.linalg.norm(rays, axis=1, keepdims=True)) @ R.T
            points = self.camera_centre + rng.uniform(*o.depth_range, size=batch)[:, None] * rays
            angles = np.radians(rng.uniform(*o.axis_view_angle_deg, size=batch))[:, None]
            sides = np.cross(rays, rng.normal(size=(batch, 3)))
            sides /= np.linalg.norm(sides, axis=1, keepdims=True)
            directions = np.cos(angles) * rays * rng.choice([-1.0, 1.0], size=(batch, 1)) + np.sin(angles) * sides
            e1 = np.cross(directions, sides)  # perpendicular to the direction (sides is to the ray)
            e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
            fits = np.flatnonzero(self._rims_inside(points, directions, e1, np.cross(directions, e1),
                                                    o.constraint_sigmas))
            if len(fits):
                return points[fits[0]], directions[fits[0]]
        return None

    def problem(self, joint_angles) -> str | None:
        problem = (self.scene.pose_problem(joint_angles, self.options.spin_joints)
                   or self._image_motion_problem(joint_angles))
        if problem is not None or self.collisions is None:
            return problem
        for joint in self.options.spin_joints:
            problem = None if self.scene.arm.spins_wrist(joint) else self._swing_collision(joint_angles, joint)
            if problem is not None:
                return problem
        problem = self._collision(joint_angles)
        if problem is not None:
            return problem
        arm_T_wrist = self.scene.arm.arm_T_wrist(joint_angles)
        axis = self.scene.arm.wrist_axis(joint_angles)
        points = self._local_points @ arm_T_wrist.rotation().matrix().T + arm_T_wrist.translation()
        radial = points - axis.point - np.outer((points - axis.point) @ axis.direction, axis.direction)
        facing = np.einsum("ij,ij->i", radial, self.camera_centre - points) > 0
        if not np.any(facing):
            return "no part of the end effector faces the camera"
        hidden = float(np.mean(self.collisions.hidden(joint_angles, self.camera_centre, points[facing])))
        if hidden > self.options.max_hidden_fraction:
            return (f"the arm hides too much of the end effector ({100 * hidden:.0f} %; at most "
                    f"{100 * self.options.max_hidden_fraction:.0f} % allowed)")
        return None

    def _collision(self, joint_angles, during: str = "") -> str | None:
        """Words when the arm at ``joint_angles`` hits itself or the floor (``during``: appended to them)."""
        pair = self.collisions.self_collision(joint_angles)
        if pair is not None:
            return f"self-collision of {pair[0]} and {pair[1]}{during}"
        link = self.collisions.below_floor(joint_angles)
        return None if link is None else f"{link} below the floor{during}"

    def _swing_collision(self, joint_angles, joint: str) -> str | None:
        """Words when the arm hits itself or the floor anywhere in a full turn of ``joint`` (every SWING_STEP_DEG)."""
        index = self.scene.arm.spin_index(joint)
        for turn in np.radians(np.arange(SWING_STEP_DEG, 360.0, SWING_STEP_DEG)):
            q = np.array(joint_angles, dtype=float)
            q[index] += turn
            problem = self._collision(q, f" during the {joint} spin")
            if problem is not None:
                return problem
        return None


_NUMBER = re.compile(r"(?<![\w.])-?\d+(\.\d+)?(?![\w.])")
_BRACKETED = re.compile(r" \([^()]*\d[^()]*\)")


def _reason(problem: str) -> str:
    """A refusal's kind, for counting: its words without the bracketed numbers (and any other number, not a digit
    inside a name, written #)."""
    return _NUMBER.sub("#", _BRACKETED.sub("", problem))


def _check_inputs(arm: Arm, camera: Camera, guess: gtsam.Pose3, options: PlanOptions) -> None:
    if not isinstance(arm, Arm):
        raise PlanningError(f"arm must be a gtsam_rotid Arm, got {type(arm).__name__}")
    if not isinstance(camera, Camera):
        raise PlanningError(f"camera must be a gtsam_rotid Camera, got {type(camera).__name__}")
    if not isinstance(guess, gtsam.Pose3):
        raise PlanningError(f"the camera guess must be a gtsam.Pose3 (arm_T_camera), got {type(guess).__name__}")
    distance = float(np.linalg.norm(guess.translation()))
    if not math.isfinite(distance) or distance > MAX_GUESS_DISTANCE_M:
        raise PlanningError(f"the camera guess is {distance:.4g} m from the arm's base; its X Y Z are metres (and "
                            "ROLL PITCH YAW degrees)")
    options.check()
    for joint in options.spin_joints:
        arm.spin_index(joint)  # ArmError (an InputError) names a joint the arm does not have
    if options.joint_offsets is not False:
        arm.offset_joints(options.joint_offsets)  # (likewise a joint the arm has not, or the spinning one)


# ------------------------------------------------------------------------------------------------- public
def predict_accuracy(arm: Arm, camera: Camera, arm_T_camera: gtsam.Pose3, joint_angles: Sequence,
                     options: PlanOptions | None = None, *, collisions: ArmCollisions | None = None,
                     prior_information: np.ndarray | None = None) -> Prediction:
    """The predicted 1σ of a calibration from these arm poses, before any recording (see the module's words).

    ``prior_information`` (6x6, or with ``refine_intrinsics`` / ``joint_offsets`` on those too:
    :func:`dataset_information`): an existing calibration's information, added to the poses'. Each pose's
    constraint problems at the guess are listed in ``problems`` (a pose that breaks one is still predicted).
    """
    options = (PlanOptions() if options is None else options).with_texture(arm, collisions)
    _check_inputs(arm, camera, arm_T_camera, options)
    poses = [arm.joint_angle_vector(q) for q in joint_angles]
    predictor = _Predictor(arm, camera, options)
    constraints = _Constraints(predictor, arm_T_camera, collisions)
    prior = np.zeros((6, 6)) if prior_information is None else np.asarray(prior_information, dtype=float)
    prior = _full_prior(predictor, prior)
    scenes = predictor.sample_scenes(arm_T_camera)
    infos = np.array([[predictor.information(scene, q) for scene in scenes] for q in poses])
    return _prediction(arm_T_camera, poses, infos.reshape(len(poses), len(scenes), predictor.dim, predictor.dim),
                       prior, options,
                       [constraints.problem(q) for q in poses], predictor)


def _prediction(guess, poses, infos: np.ndarray, prior: np.ndarray, options: PlanOptions, problems,
                predictor: _Predictor | None = None) -> Prediction:
    """``infos`` (poses, samples, 6, 6) -> the Prediction (the covariance averaged over the samples). Refining the
    intrinsics or the offsets: ``infos`` and ``prior`` span them too (the prior with theirs), the Prediction the
    pose's marginal; ``per_pose`` then each pose's marginal under their prior alone."""
    total = prior[None] + infos.sum(axis=0) if len(poses) else np.repeat(prior[None], infos.shape[1], axis=0)
    per_pose = [infos[k, 0] for k in range(len(poses))]
    if prior.shape[-1] > 6:
        total = _pose_marginal(total)
        nuisance_prior = prior.copy()
        nuisance_prior[:6, :6] = 0.0
        per_pose = [_pose_marginal(info + nuisance_prior) for info in per_pose]
    at_guess = total[0]
    observability = analyse_observability(at_guess, guess)
    covariances = [analyse_observability(t, guess).covariance(t) for t in total]
    span = None if predictor is None or predictor.limited_span is None else math.degrees(predictor.limited_span)
    return Prediction(guess, poses, at_guess, np.mean(covariances, axis=0), observability,
                      per_pose, options, list(problems), bool(np.any(prior[:6, :6])), span)


def plan_poses(arm: Arm, camera: Camera, arm_T_camera: gtsam.Pose3, n: int = 6, options: PlanOptions | None = None,
               *, collisions: ArmCollisions | bool | None = True, prior_information: np.ndarray | None = None,
               progress: Callable[[str, int, int], None] | None = None) -> Plan:
    """Choose ``n`` arm poses that minimise the worst axis' predicted 1σ of ``arm_T_camera`` (the guess: the camera's
    OpenCV optical frame in the arm's root frame), subject to the constraints of :class:`PlanOptions`.

    ``collisions``: True (default) loads the arm's collision meshes, an :class:`ArmCollisions` reuses one, None
    checks no collision (say so to your users). ``prior_information`` (6x6, or with ``refine_intrinsics`` /
    ``joint_offsets`` on those too: :func:`dataset_information`): an existing calibration's, for the next best
    poses. ``progress(stage, done, total)`` is called as candidates are found and evaluated. Raises
    :class:`PlanningError` when fewer than ``n`` poses satisfy the constraints.
    """
    options = PlanOptions() if options is None else options
    _check_inputs(arm, camera, arm_T_camera, options)
    if not isinstance(n, int) or n < 1:
        raise PlanningError(f"n must be a positive number of poses, got {n!r}")
    start = time.perf_counter()
    collisions = _collisions(arm, collisions, options)
    options = options.with_texture(arm, collisions)
    predictor = _Predictor(arm, camera, options)
    constraints = _Constraints(predictor, arm_T_camera, collisions)
    scenes = predictor.sample_scenes(arm_T_camera)
    ranking = scenes[:options.rank_samples]
    candidates, infos, draws, refused = _search(arm, predictor, constraints, ranking, n, options, progress)
    if len(candidates) < n:
        raise _too_few(len(candidates), draws, refused, n)
    prior = np.zeros((6, 6)) if prior_information is None else np.asarray(prior_information, dtype=float)
    prior = _full_prior(predictor, prior)
    regularised = prior + predictor.embed(REGULARISER)
    chosen = _choose(infos, regularised, n, options)
    poses, chosen_infos = _refine([candidates[c] for c in chosen], infos[chosen], regularised, predictor,
                                  constraints, ranking, rng=np.random.default_rng(options.seed + 1), options=options)
    if options.spin_model != SEARCH_SPIN_MODEL or len(ranking) < len(scenes):
        chosen_infos = np.array([[predictor.information(scene, q) for scene in scenes] for q in poses])
    prediction = _prediction(arm_T_camera, poses, chosen_infos, prior, options, [None] * n, predictor)
    before = None
    if prior_information is not None:
        before = _prediction(arm_T_camera, [], infos[:0], prior, options, []).sigma
    return Plan(poses, prediction, len(candidates), draws, refused, time.perf_counter() - start,
                list(arm.joint_names), before)


#: how long a forked search process may take after this process' own share (times that share's time, at least the
#: minimum in seconds) before its share is run here instead (:func:`_forked_shares`)
SHARE_WAIT_FACTOR = 10.0
SHARE_WAIT_MIN_S = 60.0

#: what a forked search process inherits: the arguments of _search_share (set just before the fork)
_SHARED: dict = {}


def _search_share(part: int, shared: dict | None = None):
    """One process' share of the search: its candidates (own random stream), their information at the ranking
    scenes (search spin model), its draws and refusals."""
    s = _SHARED if shared is None else shared
    arm, predictor, options, scenes = s["arm"], s["predictor"], s["options"], s["scenes"]
    rng = np.random.default_rng(options.seed) if options.jobs == 1 else \
        np.random.default_rng([options.seed, part, options.jobs])
    progress = s["progress"] if part == 0 else None
    count = s["counts"][part]
    candidates, draws, refused = _sample(arm, s["constraints"], count, s["need"], options, rng,
                                         progress=progress, strict=False, in_view=True)
    infos = np.empty((len(candidates), len(scenes), predictor.dim, predictor.dim))
    for c, q in enumerate(candidates):
        infos[c] = [predictor.information(scene, q, SEARCH_SPIN_MODEL) for scene in scenes]
        if progress is not None:
            progress("predictions", c + 1, len(candidates))
    return candidates, infos, draws, refused


def _other_threads() -> bool:
    """Whether other threads of this process are running (tqdm's monitor aside, which only sleeps): a fork copies
    whatever locks they hold (one inside a BLAS call left the forked search hanging), so the shares then run here."""
    this = threading.current_thread()
    return any(t is not this and t.is_alive() and type(t).__name__ != "TMonitor" for t in threading.enumerate())


def _share_child(part: int, writer) -> None:
    """A forked process' share, sent back through ``writer`` (an exception ends it without sending: the parent then
    runs the share itself, and meets the exception there)."""
    try:
        writer.send(_search_share(part))
    finally:
        writer.close()


def _forked_shares(jobs: int) -> list:
    """The shares of :func:`_search` (``_SHARED`` set): 1 .. jobs - 1 in forked processes, each answering through
    its own pipe, share 0 here. A process that has not answered ``SHARE_WAIT_FACTOR`` times share 0's time after it
    (at least ``SHARE_WAIT_MIN_S``), or that ended without answering, is killed and its share run here: a forked
    process can hang on a lock some thread of this one held at the fork (an intermittent 600 s hang in CI), and a
    pool would wait for it for ever. The shares' random streams are their own, so the plan is the same."""
    context = multiprocessing.get_context("fork")
    children = []
    try:
        for part in range(1, jobs):
            reader, writer = context.Pipe(duplex=False)
            process = context.Process(target=_share_child, args=(part, writer), daemon=True)
            process.start()
            writer.close()
            children.append((part, process, reader))
        start = time.perf_counter()
        parts = [_search_share(0)]
        deadline = time.perf_counter() + max(SHARE_WAIT_MIN_S, SHARE_WAIT_FACTOR * (time.perf_counter() - start))
        for part, process, reader in children:
            answer = None
            try:
                if reader.poll(max(0.0, deadline - time.perf_counter())):
                    answer = reader.recv()
            except (EOFError, OSError):  # (it ended without answering)
                pass
            if answer is None:
                warnings.warn(f"planning: search process {part} of {jobs - 1} gave no answer (exit code "
                              f"{process.exitcode}); its share runs here", RuntimeWarning, stacklevel=2)
                process.kill()
                answer = _search_share(part)
            parts.append(answer)
        return parts
    finally:
        for _, process, reader in children:
            reader.close()
            if process.is_alive():
                process.kill()
            process.join()


def _search(arm: Arm, predictor: _Predictor, constraints: _Constraints, scenes: list[SpinScene], need: int,
            options: PlanOptions, progress):
    """``options.candidates`` candidates shared among ``options.jobs`` processes (this one takes the first share;
    ``progress`` follows it): (candidates, information (C, scenes, 6, 6), draws, refusals). The other processes are
    forked, unless fork is unavailable, this process is a daemon, or other threads run here (:func:`_other_threads`):
    the shares then run here in turn (the same plan)."""
    jobs = min(options.jobs, options.candidates)
    counts = [options.candidates // jobs + (k < options.candidates % jobs) for k in range(jobs)]
    shared = {"arm": arm, "predictor": predictor, "constraints": constraints, "scenes": scenes, "options": options,
              "counts": counts, "need": -(-need // jobs), "progress": progress}
    if jobs == 1:
        parts = [_search_share(0, shared)]
    elif ("fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon
          and not _other_threads()):
        _SHARED.update(shared)
        try:
            parts = _forked_shares(jobs)
        finally:
            _SHARED.clear()
    else:
        parts = [_search_share(k, shared) for k in range(jobs)]
    candidates = [q for part in parts for q in part[0]]
    infos = np.concatenate([part[1] for part in parts]) if candidates else \
        np.empty((0, len(scenes), predictor.dim, predictor.dim))
    refused = Counter()
    for part in parts:
        refused.update(part[3])
    return candidates, infos, sum(part[2] for part in parts), dict(refused)


def _too_few(found: int, draws: int, refused: dict, need: int) -> PlanningError:
    listed = ", ".join(f"{reason} ({n})" for reason, n in Counter(refused).most_common(5))
    return PlanningError(f"only {found} of {draws} arm poses tried satisfy the constraints at this camera guess "
                         f"(need {need}); refused most often: {listed}. Check the guess (X Y Z in metres, ROLL PITCH "
                         f"YAW in degrees, the camera's optical frame, z forward, in the arm's root frame) or relax "
                         f"the constraints (depth range, image margin, view angle, guess sigma)")


def _sample(arm: Arm, constraints: _Constraints, count: int, need: int, options: PlanOptions,
            rng: np.random.Generator, *, min_separation_deg: float = 0.0, progress=None, strict: bool = True,
            in_view: bool = False):
    """Up to ``count`` random arm poses that satisfy the constraints (wrist axes at least ``min_separation_deg``
    apart); raises PlanningError with the commonest refusals when fewer than ``need`` are found (``strict``).
    ``in_view``: the aimed draws aim at axes whose end effector stays in view (:meth:`_Constraints.aimed`)."""
    candidates, directions, refused, draws = [], [], Counter(), 0
    cos_sep = math.cos(math.radians(min_separation_deg))
    deadline = math.inf if options.search_seconds is None else time.perf_counter() + options.search_seconds
    while len(candidates) < count and draws < options.max_draws:
        if len(candidates) >= max(need, count // 3) and time.perf_counter() > deadline:
            break
        if not candidates and draws >= HOPELESS_DRAWS:
            break
        # the workable region can be a small part of joint space: half the draws near a pose already found, a
        # quarter aimed by inverse kinematics at a wrist in view, a quarter anywhere
        u = rng.random()
        if candidates and u < 0.5:
            q = arm.clip_joint_angles(candidates[rng.integers(len(candidates))] + rng.normal(scale=0.2, size=arm.dof))
        elif u < 0.75:
            q = constraints.aimed(rng, in_view)
        else:
            q = arm.random_joint_angles(rng)
        draws += 1
        if q is None:
            refused["no inverse kinematics solution"] += 1
            continue
        problem = constraints.problem(q)
        if problem is None and min_separation_deg > 0:
            a = arm.wrist_axis(q).direction
            if any(abs(a @ b) > cos_sep for b in directions):
                problem = "wrist axis too close to another pose's"
            else:
                directions.append(a)
        if problem is None:
            candidates.append(q)
            if progress is not None:
                progress("candidates", len(candidates), count)
        else:
            refused[_reason(problem)] += 1
    if strict and len(candidates) < need:
        raise _too_few(len(candidates), draws, refused, need)
    return candidates, draws, dict(refused)


def random_valid_poses(arm: Arm, camera: Camera, arm_T_camera: gtsam.Pose3, n: int = 6,
                       options: PlanOptions | None = None, *, collisions: ArmCollisions | bool | None = True,
                       seed: int = 0, min_separation_deg: float = 20.0) -> list[np.ndarray]:
    """``n`` random arm poses that satisfy the plan's constraints, wrist axes at least ``min_separation_deg`` apart
    (the simulator's sampler with the plan's checks): what a user picking poses by hand might record."""
    options = PlanOptions() if options is None else options
    _check_inputs(arm, camera, arm_T_camera, options)
    collisions = _collisions(arm, collisions, options)
    options = options.with_texture(arm, collisions)
    constraints = _Constraints(_Predictor(arm, camera, options), arm_T_camera, collisions)
    poses, _, _ = _sample(arm, constraints, n, n, options, np.random.default_rng(seed),
                          min_separation_deg=min_separation_deg)
    return poses


def _collisions(arm: Arm, collisions, options: PlanOptions) -> ArmCollisions | None:
    if collisions is True:
        return ArmCollisions(arm, floor_height=options.floor_height)
    return None if collisions is False or collisions is None else collisions


def _refine(poses: list[np.ndarray], infos: np.ndarray, prior: np.ndarray, predictor: _Predictor,
            constraints: _Constraints, scenes: list[SpinScene], *, rng: np.random.Generator,
            options: PlanOptions) -> tuple[list[np.ndarray], np.ndarray]:
    """Local search after the choice: ``refine_steps`` times, one chosen pose moved by a small random step (that
    keeps every constraint) and kept if the criterion drops."""
    poses, infos = list(poses), infos.copy()
    current = float(_criterion(np.linalg.inv(prior[None] + infos.sum(axis=0)), options))
    for step in range(options.refine_steps):
        k = step % len(poses)
        trial = predictor.arm.clip_joint_angles(poses[k] + rng.normal(scale=0.1, size=len(poses[k])))
        if constraints.problem(trial) is not None:
            continue
        info = np.array([predictor.information(scene, trial, SEARCH_SPIN_MODEL) for scene in scenes])
        score = float(_criterion(np.linalg.inv(prior[None] + infos.sum(axis=0) - infos[k] + info), options))
        if score < current:
            poses[k], infos[k], current = trial, info, score
    return poses, infos


def _choose(infos: np.ndarray, prior: np.ndarray, n: int, options: PlanOptions) -> list[int]:
    """Greedy D-optimal choice of ``n`` candidates (the log-determinant of the information in worst-axis units,
    summed over the guess samples: well defined while the first poses leave directions undetermined), then
    exchanges (one pose for another) while the worst axis' 1σ drops."""
    def score(base: np.ndarray) -> np.ndarray:
        """Criterion of ``base`` (S, 6, 6) plus each candidate's information: (C,)."""
        return _criterion(np.linalg.inv(base[None] + infos), options)

    D = _unit_scale(options)
    extra = infos.shape[-1] - 6  # the intrinsics' and offsets' dimensions: the pose's marginal log-determinant
    if extra:
        D = np.concatenate([D, np.ones(extra)])
    base = np.repeat(prior[None], infos.shape[1], axis=0)
    chosen: list[int] = []
    for _ in range(n):
        scaled = (base[None] + infos) * np.outer(D, D)
        gains = -np.linalg.slogdet(scaled)[1].sum(axis=-1)
        if extra:  # log det of the pose's Schur complement = log det(all) - log det(intrinsics' block)
            gains += np.linalg.slogdet(scaled[..., 6:, 6:])[1].sum(axis=-1)
        gains[chosen] = np.inf
        best = int(np.argmin(gains))
        chosen.append(best)
        base = base + infos[best]
    current = float(_criterion(np.linalg.inv(base), options))
    for _ in range(4 * n):
        improved = False
        for slot in range(n):
            without = base - infos[chosen[slot]]
            scores = score(without)
            scores[chosen] = np.inf
            best = int(np.argmin(scores))
            if scores[best] < current * (1.0 - 1e-6):
                base = without + infos[best]
                chosen[slot] = best
                current = float(scores[best])
                improved = True
        if not improved:
            break
    return chosen


def predicted_spins(arm: Arm, camera: Camera, arm_T_camera: gtsam.Pose3, joint_angles: Sequence,
                    options: PlanOptions | None = None) -> list:
    """The noise-free tracks (:class:`gtsam_rotid.dataset.Measurement`, at ``prediction_fps``) the prediction sees
    for each pose at the guess: what the camera would record of the typical texture (for pictures)."""
    options = (PlanOptions() if options is None else options).with_texture(arm, None)
    predictor = _Predictor(arm, camera, options)
    scene = predictor.scene(arm_T_camera)
    out = []
    for q in joint_angles:
        try:
            out.append(scene.measurement(arm.joint_angle_vector(q), predictor._rng)[0])
        except InputError:  # nothing in view
            out.append(None)
    return out


def dataset_information(dataset: Dataset, arm_T_camera: gtsam.Pose3, options: PlanOptions | None = None, *,
                        measured: bool = True) -> np.ndarray:
    """The information (6x6) of an existing dataset's tracks at ``arm_T_camera``: what new poses add to. With
    ``measured`` (default) the recording is counted as ``calibrate`` would count it: each measurement at the pixel
    noise its own tracks show (its line fitted alone, :func:`gtsam_rotid.calibration.stage1.measured_noise`, without
    the tracks that fit leaves out) and with the floor and the tracks' own offsets of the dataset's tracker (its
    metadata; none where it names no tracker); otherwise at the plan's pixel noise and axis floor (quicker: no fit).
    With ``options.refine_intrinsics``, on the pose and fx, fy, cx, cy too (the rigid spin), with
    ``options.joint_offsets`` on the offsets too (in that order; without their priors, which the plan adds)."""
    options = PlanOptions() if options is None else options
    intrinsics = options.refine_intrinsics
    spin_model = "rigid" if intrinsics else options.spin_model
    builder = RotIdGraph(dataset.arm, dataset.camera, model="projected", track_sigma_px=options.pixel_sigma,
                         spin_model=spin_model, intrinsics_key=_INTRINSICS_KEY if intrinsics else None,
                         joint_offsets=options.joint_offsets)
    graph, values = _nuisance_graph(builder, arm_T_camera)
    floor_px, noise = options.axis_floor_px, [MeasuredNoise(options.pixel_sigma, {})] * len(dataset)
    if measured:
        floor_px = tracker_floor_px(dataset.metadata)
        noise = measured_noise(dataset.arm, dataset.camera, list(dataset), arm_T_camera,
                               CalibrationOptions(spin_model=spin_model,
                                                  track_offset_px=tracker_offset_px(dataset.metadata)))
    floor = 2.0 * floor_px**2 * np.eye(2)
    for k, measurement in enumerate(dataset):
        if noise[k] is None:  # (a measurement that cannot be fitted alone: calibrate leaves it out too)
            continue
        # the tracks' own offsets, as the floor, on its image axis (here in the weights: an information)
        tie = floor if noise[k].offset_covariance is None else floor + noise[k].offset_covariance
        try:
            builder.add_measurement(graph, values, k, measurement, tie_covariance=tie, skip_tracks=noise[k].outliers,
                                    track_sigmas=dict.fromkeys(range(len(measurement.tracks)), noise[k].sigma))
        except InputError:
            continue
    if graph.size() == 0:
        raise PlanningError("no measurement of the dataset has two usable tracks")
    return _information(graph, values, builder)
