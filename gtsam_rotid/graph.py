"""Graph-building API: add rotation-identification variables and factors to *your* factor graph.

``RotIdGraph`` adds, per measurement k, a ``gtsam.Rot3`` line variable (the wrist axis in the camera
frame at unit distance, see :mod:`gtsam_rotid.factors`), one ``(d, r)`` circle variable per track,
one circle-point factor per track and a projected-axis tie between the line and the Pose3
``arm_T_camera``. Keys are built from symbol characters the caller chooses; the builder refuses to
reuse a key that already exists in the caller's ``Values``.

Example::

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(X(0), initial_arm_T_camera)          # the user's own variable
    graph.add(gtsam.PriorFactorPose3(X(0), cad_pose, cad_noise))
    builder = RotIdGraph(arm, camera, pose_key=X(0))
    for k, measurement in enumerate(measurements):
        keys = builder.add_measurement(graph, values, k, measurement)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import gtsam
import numpy as np

from .arm import Arm
from .camera import Camera
from .dataset import Measurement, Track
from .errors import InputError
from .factors import (
    CoaxialLineFactor,
    EncoderPrior,
    FKAxis,
    RigidLineFactor,
    RigidTracks,
    cal3_s2,
    closest_spin,
    make_axis_offsets_to_line_variable_factor,
    make_axis_to_line_variable_factor,
    make_circle_point_factor,
    make_coaxial_line_factor,
    make_pose_circle_point_factor,
    make_rigid_line_factor,
    rot3_from_line,
)
from .initialise import MIN_ELLIPSE_POINTS, Ellipse, fit_ellipse

#: Distance (m) between the two FK test points on each wrist axis.
TEST_POINT_SPACING = 0.1
#: Circle variable index stride: circle key of (k, j) is symbol(c, k * CIRCLE_STRIDE + j).
CIRCLE_STRIDE = 100_000
#: Default fewest points of a usable track.
MIN_TRACK_POINTS = 10
#: Default smallest image extent (bounding-box diagonal, px) of a usable track. A shorter arc spans a few
#: degrees of phase only: its circle's (d, r) is nearly indeterminate and it carries almost no information.
MIN_TRACK_EXTENT_PX = 10.0
#: LM iterations of the circle refinement in :meth:`RotIdGraph.add_measurement` (a start, not a solution).
REFINE_ITERATIONS = 8


def lm_params(max_iterations: int = 100, relative_tolerance: float = 1e-8,
              diagonal_damping: bool = True) -> gtsam.LevenbergMarquardtParams:
    """Levenberg-Marquardt settings that suit these graphs (use them for your graph with the builder's factors).

    Pixel-scale Jacobians make Hessian entries ~1e8 and line and circle variables differ in scale by orders of
    magnitude: diagonal (scale-invariant) damping, and a lambda ceiling far above GTSAM's default 1e5, which
    otherwise gives up early.
    """
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setDiagonalDamping(diagonal_damping)
    params.setlambdaUpperBound(1e15)
    params.setRelativeErrorTol(relative_tolerance)
    params.setAbsoluteErrorTol(0.0)
    return params


def chi2_quantile(dof: int, z: float = 3.09) -> float:
    """Chi-square quantile (Wilson-Hilferty) at the normal's z; z = 3.09 gives the 99.9 % point."""
    h = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - h + z * np.sqrt(h)) ** 3)


def tie_noise_model(sigma_px: float, covariance: np.ndarray | None = None):
    """The projected-axis tie's noise: isotropic ``sigma_px``, plus ``covariance`` (2x2, px²) when given."""
    if covariance is None:
        return gtsam.noiseModel.Isotropic.Sigma(2, sigma_px)
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape != (2, 2) or not np.all(np.isfinite(covariance)):
        raise InputError(f"tie_covariance must be a finite 2x2 matrix (px²), got shape {covariance.shape}")
    return gtsam.noiseModel.Gaussian.Covariance(sigma_px**2 * np.eye(2) + 0.5 * (covariance + covariance.T))


def track_huber(n_points: int):
    """Huber kernel on a whole track: full weight while its chi-square is below the 99.9 % quantile."""
    return gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(chi2_quantile(n_points)))


def axis_test_points(axis) -> np.ndarray:
    """Two FK test points on a wrist axis (arm frame): its origin and one ``TEST_POINT_SPACING`` along it."""
    return axis.points_at([0.0, TEST_POINT_SPACING])


def offset_axis_test_points(arm: Arm, joint_angles, joints, spin_joint: str | None = None):
    """``delta -> (test points (2, 3), their derivatives (2, 3, n))``: :func:`axis_test_points` of the FK axis (of
    ``spin_joint``, default the wrist) at ``joint_angles`` plus the offsets ``delta`` (radians) of the joint indices
    ``joints``, and their derivatives by those offsets (:meth:`gtsam_rotid.arm.Arm.wrist_axis_offset_derivatives`);
    the ``axis_of`` of the offsets' factors (:func:`gtsam_rotid.factors.make_axis_offsets_to_line_factor`)."""
    spacing = np.array([0.0, TEST_POINT_SPACING])

    def axis_of(delta):
        axis, d_point, d_direction = arm.wrist_axis_offset_derivatives(joint_angles, joints, delta, spin_joint)
        return axis.points_at(spacing), d_point[None] + spacing[:, None, None] * d_direction[None]
    return axis_of


@dataclass
class PreparedTrack:
    """A usable track: its ideal (undistorted) pixels, its ellipse, and its pixels' frame indices (or None)."""

    ideal: np.ndarray
    ellipse: Ellipse
    frames: np.ndarray | None = None


@dataclass
class PreparedMeasurement:
    """Tracks of one measurement sorted into usable ones (by track index) and rejected ones (with reasons)."""

    usable: dict[int, PreparedTrack]
    rejected: dict[int, str]


def prepare_tracks(camera: Camera, measurement: Measurement, k: int = 0, *,
                   min_points: int = MIN_TRACK_POINTS,
                   min_extent_px: float = MIN_TRACK_EXTENT_PX) -> PreparedMeasurement:
    """Undistort every track, fit its ellipse, and reject tracks too short, too still, or without an ellipse."""
    min_points = max(int(min_points), MIN_ELLIPSE_POINTS)
    usable, rejected = {}, {}
    for j, track in enumerate(measurement.tracks):
        track = Track.from_any(track, measurement=k, track=j)
        if len(track) < min_points:
            rejected[j] = f"too short ({len(track)} < {min_points} points)"
            continue
        ideal = camera.undistort_pixels(track.pixels)
        extent = float(np.hypot(*np.ptp(ideal, axis=0)))
        if extent < min_extent_px:
            rejected[j] = f"barely moves (extent {extent:.1f} px < {min_extent_px:g} px)"
            continue
        ellipse = fit_ellipse(ideal)
        if ellipse is None:
            rejected[j] = "no ellipse fits its points"
            continue
        usable[j] = PreparedTrack(ideal, ellipse, track.frames)
    return PreparedMeasurement(usable, rejected)


@dataclass
class MeasurementKeys:
    """What :meth:`RotIdGraph.add_measurement` made for one measurement."""

    index: int
    line_key: int | None  # the key of the line variable (a Rot3); None in the pose-bound model (none)
    circles: list[int]
    tracks: list[int]  # track index (in the measurement) of each circle
    circle_factors: list[int]  # factor index in the graph of each track's circle-point factor
    tie_factor: int  # -1 when there is none
    scale: float  # camera-to-axis distance (m) of the initial line: metric = unit * scale
    rejected: dict[int, str] = field(default_factory=dict)  # track index -> reason
    #: the "projected" model's one factor for all tracks (no circle variables; ``circle_factors`` holds its
    #: index): read the circles, per-track residuals and weights from it. A :class:`RigidLineFactor` (a subclass,
    #: 2-D residuals per pixel) where the rigid spin models the measurement's phases.
    coaxial: CoaxialLineFactor | RigidLineFactor | None = None


def initial_circle(camera_point: np.ndarray, camera_direction: np.ndarray, rays: np.ndarray,
                   ellipse_centre_ray: np.ndarray) -> tuple[float, float]:
    """Metric (offset from ``camera_point`` along the axis, radius) of a track's circle from its rays.

    The offset is where the ellipse-centre ray passes closest to the axis; the radius is the median
    distance from the axis of the rays' intersections with the plane perpendicular to the axis there.
    """
    a = camera_direction
    p = camera_point
    # closest point between the axis (p + s a) and the ray (lam c): solve the 2x2 normal equations
    c = ellipse_centre_ray
    A = np.array([[a @ a, -(a @ c)], [a @ c, -(c @ c)]])
    b = np.array([-(p @ a), -(p @ c)])
    s, _ = np.linalg.solve(A, b)
    centre = p + s * a
    lam = (centre @ a) / (rays @ a)
    points = rays * lam[:, None]
    radius = float(np.median(np.linalg.norm(np.cross(points - centre, a), axis=1)))
    return float(s), radius


def initial_circles(camera_point: np.ndarray, camera_direction: np.ndarray, rays: list[np.ndarray],
                    ellipse_centre_rays: np.ndarray) -> np.ndarray:
    """(m, 2) :func:`initial_circle` of m tracks at once (``rays``: one (N_j, 3) array per track,
    ``ellipse_centre_rays``: (m, 3)): the same offsets and radii, in a few array operations for all tracks."""
    counts = np.array([len(r) for r in rays], dtype=np.int64)
    all_rays = np.concatenate(rays) if len(rays) else np.zeros((0, 3))
    return _initial_circles(camera_point, camera_direction, all_rays, counts, ellipse_centre_rays)


def _initial_circles(camera_point, camera_direction, all_rays: np.ndarray, counts: np.ndarray,
                     ellipse_centre_rays) -> np.ndarray:
    """:func:`initial_circles` of the tracks' rays concatenated (``counts``: rays per track)."""
    a, p = np.asarray(camera_direction, dtype=float), np.asarray(camera_point, dtype=float)
    c = np.asarray(ellipse_centre_rays, dtype=float).reshape(-1, 3)
    if len(c) == 0:
        return np.zeros((0, 2))
    # the 2x2 normal equations of :func:`initial_circle`, solved by Cramer's rule for every track
    aa, ac, cc, pa, pc = a @ a, c @ a, np.einsum("ij,ij->i", c, c), p @ a, c @ p
    s = (pa * cc - ac * pc) / (ac * ac - aa * cc)
    centre = p + s[:, None] * a  # (m, 3)
    track = np.repeat(np.arange(len(c)), counts)
    points = all_rays * ((centre @ a)[track] / (all_rays @ a))[:, None]
    distance = np.linalg.norm(np.cross(points - centre[track], a), axis=1)
    # each track's median: its distances sorted within the track, the middle one (or the mean of the two)
    ordered = distance[np.lexsort((distance, track))]
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    low, high = start + (counts - 1) // 2, start + counts // 2
    return np.column_stack([s, 0.5 * (ordered[low] + ordered[high])])


def axis_in_camera(axis, arm_T_camera: gtsam.Pose3) -> tuple[np.ndarray, np.ndarray]:
    """An FK axis (``point``, ``direction`` in the arm frame) in the camera frame of ``arm_T_camera``: (point,
    direction); :func:`rot3_from_line` of them is the line variable on that axis."""
    camera_T_arm = arm_T_camera.inverse()
    return camera_T_arm.transformFrom(axis.point), camera_T_arm.rotation().matrix() @ axis.direction


def align_line(line: gtsam.Rot3, plane_normal: np.ndarray) -> gtsam.Rot3:
    """The smallest rotation of a line variable that makes its projection-plane normal ``+-plane_normal``."""
    c2 = line.matrix()[:, 2]
    n = np.asarray(plane_normal, dtype=float)
    n = n / np.linalg.norm(n) * (1.0 if c2 @ n >= 0 else -1.0)
    axis = np.cross(c2, n)
    angle = np.arctan2(np.linalg.norm(axis), c2 @ n)
    if angle < 1e-15:
        return line
    return gtsam.Rot3.AxisAngle(gtsam.Point3(axis / np.linalg.norm(axis)), angle).compose(line)


class Model(StrEnum):
    """How a measurement is tied to ``arm_T_camera``."""

    #: docs/design.md §4's joint graph, the default: a Rot3 line variable per measurement with circle-point
    #: factors, tied to the pose by a stiff projected-axis factor (2 of the line's 3 observable DOF).
    LINE = "line"
    #: Circle-point factors on (pose, circle): the axis is the FK axis mapped by the pose (exact kinematics;
    #: the axis' tilt within its projection plane informs the pose too). With a free phase per observation
    #: that tilt is biased (Neyman-Scott): in the reference Monte Carlo its NEES is 7.7 against 6.0 for
    #: ``LINE``. Kept for the rigid-spin model, which removes that bias.
    POSE = "pose"
    #: ``LINE`` with the circles projected out (variable projection, :mod:`gtsam_rotid.factors.coaxial`): one
    #: factor per measurement on its line variable solves the circles inside, so the graph holds only the pose
    #: and one line per measurement. The same solution and the same pose marginal as ``LINE`` (its Gauss-Newton
    #: information is the Schur complement of ``LINE``'s), ~5x faster to optimise. The estimators use it.
    PROJECTED = "projected"


class SpinModel(StrEnum):
    """How the phases of one spin's features are modelled (``RotIdGraph(spin_model=...)``, docs/design.md §4)."""

    #: a free phase per observation: each pixel is compared with the nearest point of its circle
    FREE = "free"
    #: one spin angle per frame, shared by all the measurement's tracks, and one phase offset per track
    #: (:mod:`gtsam_rotid.factors.rigid_line`). The ``"projected"`` model, for measurements whose tracks all have
    #: frame indices; the others keep the free phase.
    RIGID = "rigid"


class RotIdGraph:
    """Adds rotation-identification variables and factors to a user's graph.

    Args:
        arm, camera: the arm model and the calibrated camera.
        model: ``"line"`` (default), ``"projected"`` (circles projected out) or ``"pose"``, see :class:`Model`.
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera`` (may already be the user's variable).
        line_symbol, circle_symbol: symbol characters for the line and circle variables.
        track_sigma_px: pixel noise of the circle-point factors (an estimator rescales it).
        tie_sigma_px: stiffness of the projected-axis tie of the ``"line"`` model (kinematics taken as exact).
        min_track_points, min_track_extent_px: tracks with fewer points, or whose pixels span a smaller
            image extent, are rejected.
        robust: optional ``gtsam.noiseModel.mEstimator`` applied per track (whole-track weighting: GTSAM
            evaluates it on the track's whole whitened norm), or a callable ``n_residuals -> mEstimator`` so that
            its threshold can follow the track length (see :func:`track_huber`; a track has one residual per
            point, two with the rigid spin).
        spin_model: ``"free"`` (default) or ``"rigid"`` (see :class:`SpinModel`; ``"projected"`` model only).
        joint_offsets: refine offsets (zero-position errors, common to every pose) of joints before the spinning
            one: ``True`` for every one between the first and the spinning one, or a list of joint names
            (``"line"`` and ``"projected"`` models; :meth:`gtsam_rotid.arm.Arm.offset_joints`). The ties then
            depend on a vector variable at ``offsets_key`` (radians, in :attr:`offset_joints` order; the reading
            plus the offset is the joint's angle): insert it with :meth:`add_offsets_prior` before the
            measurements. The first joint's offset turns the whole arm as the pose does: named, its prior holds it
            (as it holds any combination the poses do not determine).
        offsets_key: key of that variable.
        intrinsics_key: refine the camera's intrinsics: the circle factors and ties then read them from a
            ``gtsam.Cal3_S2`` variable at this key (insert it with :meth:`add_intrinsics_prior` before the
            measurements; a user's graph may share it with its own projection factors). Needs the ``"projected"``
            model with the rigid spin and tracks with frame indices (the free phase fits each point's phase
            anywhere on its ellipse and leaves the intrinsics nearly free). The tracks' pixels are undistorted with
            the camera's own intrinsics (distortion is not refined).
        encoder_sigma_deg: synced mode: a measurement whose :class:`~gtsam_rotid.measurements.SpinReadings` are
            given has its rigid spin's per-frame angles under a prior from those readings, of this sigma (degrees;
            None, the default: readings are not used). Needs the ``"projected"`` model with the rigid spin.
        time_offset_key: synced mode: the encoder clock's offset from the camera's (s, encoder minus camera: a
            frame at camera time t is read at encoder time t + offset; ``CalibrationOptions.time_offset_s`` is its
            negative, as bags state it) is a ``gtsam`` Vector1 variable at this key (insert it with
            :meth:`add_time_offset_prior` before the measurements), shared by every synced measurement; or a mapping
            clock -> key, one variable per camera clock (``SpinReadings.clock``; None is the clock of readings that
            name none), each inserted with ``add_time_offset_prior(..., clock=)``; None: the offset is
            ``time_offset_s`` (known).
        time_offset_s: synced, without ``time_offset_key``: the encoder clock's known offset from the camera's (s,
            encoder minus camera).
    """

    def __init__(self, arm: Arm, camera: Camera, *, pose_key: int = gtsam.symbol("T", 0), line_symbol: str = "l",
                 circle_symbol: str = "c", track_sigma_px: float = 1.0, tie_sigma_px: float = 1e-3,
                 min_track_points: int = MIN_TRACK_POINTS, min_track_extent_px: float = MIN_TRACK_EXTENT_PX,
                 robust=None, model: str | Model = Model.LINE, spin_model: str | SpinModel = SpinModel.FREE,
                 joint_offsets=None, offsets_key: int = gtsam.symbol("o", 0), intrinsics_key: int | None = None,
                 encoder_sigma_deg: float | None = None, time_offset_key: int | Mapping | None = None,
                 time_offset_s: float = 0.0):
        if line_symbol == circle_symbol:
            raise InputError("line_symbol and circle_symbol must differ")
        try:
            self.model = Model(model)
        except ValueError:
            raise InputError(f"unknown model {model!r}; choose one of {[m.value for m in Model]}") from None
        try:
            self.spin_model = SpinModel(spin_model)
        except ValueError:
            raise InputError(f"unknown spin_model {spin_model!r}; choose one of {[m.value for m in SpinModel]}"
                             ) from None
        for name, value in (("track_sigma_px", track_sigma_px), ("tie_sigma_px", tie_sigma_px)):
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"{name} must be a positive number of pixels, got {value!r}")
        self.arm = arm
        self.camera = camera
        self.pose_key = pose_key
        self.line_symbol = line_symbol
        self.circle_symbol = circle_symbol
        self.track_sigma_px = float(track_sigma_px)
        self.tie_sigma_px = float(tie_sigma_px)
        self.min_track_points = max(int(min_track_points), MIN_ELLIPSE_POINTS)
        self.min_track_extent_px = float(min_track_extent_px)
        self.robust = robust
        self.offsets_key = offsets_key
        self.intrinsics_key = intrinsics_key
        if intrinsics_key is not None and (self.model is not Model.PROJECTED or self.spin_model is not SpinModel.RIGID):
            raise InputError("refining the intrinsics needs model='projected' and spin_model='rigid' (got "
                             f"{self.model.value!r}, {self.spin_model.value!r})")
        if encoder_sigma_deg is not None:
            if not (np.isfinite(encoder_sigma_deg) and encoder_sigma_deg > 0):
                raise InputError(f"encoder_sigma_deg must be a positive angle in degrees, got {encoder_sigma_deg!r}")
            if self.model is not Model.PROJECTED or self.spin_model is not SpinModel.RIGID:
                raise InputError("synced mode (encoder_sigma_deg) needs model='projected' and spin_model='rigid' "
                                 f"(got {self.model.value!r}, {self.spin_model.value!r})")
        if time_offset_key is not None and encoder_sigma_deg is None:
            raise InputError("a time offset variable needs synced mode: give encoder_sigma_deg too")
        self.encoder_sigma_deg = None if encoder_sigma_deg is None else float(encoder_sigma_deg)
        if isinstance(time_offset_key, Mapping):
            if not time_offset_key or len(set(time_offset_key.values())) != len(time_offset_key):
                raise InputError(f"time_offset_key as a mapping needs one distinct key per clock, got "
                                 f"{dict(time_offset_key)!r}")
            time_offset_key = dict(time_offset_key)
        self.time_offset_key = time_offset_key
        if not np.isfinite(time_offset_s):
            raise InputError(f"time_offset_s must be finite seconds, got {time_offset_s!r}")
        self.time_offset_s = float(time_offset_s)
        self.offset_joints: list[int] = []
        if joint_offsets is not None and joint_offsets is not False:
            if self.model is Model.POSE:
                raise InputError("joint_offsets need a line variable per measurement: use model 'line' or "
                                 "'projected', not 'pose'")
            self.offset_joints = arm.offset_joints(joint_offsets)  # ArmError (an InputError) names a bad joint

    @property
    def offset_names(self) -> list[str]:
        """The joints whose offsets the graph refines, in the offsets variable's order."""
        return [self.arm.joint_names[j] for j in self.offset_joints]

    def add_offsets_prior(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                          sigma_deg: float | Sequence[float] = 1.0, mean_deg=None, initial_deg=None) -> None:
        """Insert the offsets variable (at ``initial_deg``, default the prior's mean) with a Gaussian prior of mean
        ``mean_deg`` (default zero) and ``sigma_deg`` per joint (degrees: how far the robot's zero positions may be
        off)."""
        n = len(self.offset_joints)
        if n == 0:
            raise InputError("this graph refines no joint offsets (RotIdGraph(joint_offsets=...))")
        sigma = np.broadcast_to(np.asarray(sigma_deg, dtype=float), (n,))
        if not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise InputError(f"joint offset sigmas must be positive degrees, got {np.asarray(sigma_deg).tolist()}")
        mean = np.zeros(n) if mean_deg is None else np.asarray(mean_deg, dtype=float).reshape(n)
        if values.exists(self.offsets_key):
            raise InputError(f"key {gtsam.DefaultKeyFormatter(self.offsets_key)} already exists in values")
        initial = mean if initial_deg is None else np.asarray(initial_deg, dtype=float).reshape(n)
        if not np.all(np.isfinite(mean)) or not np.all(np.isfinite(initial)):
            raise InputError("joint offsets' prior mean and initial value must be finite degrees")
        values.insert(self.offsets_key, np.radians(initial))
        graph.add(gtsam.PriorFactorVector(self.offsets_key, np.radians(mean),
                                          gtsam.noiseModel.Diagonal.Sigmas(np.radians(sigma))))

    def add_intrinsics_prior(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, sigmas,
                             mean: gtsam.Cal3_S2 | None = None, initial: gtsam.Cal3_S2 | None = None) -> None:
        """Insert the intrinsics variable (at ``initial``, default the prior's mean) with a Gaussian prior of mean
        ``mean`` (default the camera's ``K``) and ``sigmas`` (5: ``fx, fy, s, cx, cy`` in px; a tiny sigma holds
        one fixed)."""
        if self.intrinsics_key is None:
            raise InputError("this graph does not refine the intrinsics (RotIdGraph(intrinsics_key=...))")
        sigmas = np.asarray(sigmas, dtype=float).reshape(-1)
        if sigmas.shape != (5,) or not np.all(np.isfinite(sigmas) & (sigmas > 0)):
            raise InputError("intrinsics sigmas must be 5 positive pixels (fx, fy, s, cx, cy), got "
                             f"{sigmas.tolist()}")
        if values.exists(self.intrinsics_key):
            raise InputError(f"key {gtsam.DefaultKeyFormatter(self.intrinsics_key)} already exists in values")
        mean = cal3_s2(self.camera.K) if mean is None else mean
        values.insert(self.intrinsics_key, mean if initial is None else initial)
        graph.add(gtsam.PriorFactorCal3_S2(self.intrinsics_key, mean, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))

    def time_offset_key_of(self, clock: str | None = None) -> int | None:
        """The time offset variable's key for readings on ``clock`` (``SpinReadings.clock``); None where the offset
        is known (no ``time_offset_key``)."""
        if not isinstance(self.time_offset_key, dict):
            return self.time_offset_key
        if clock not in self.time_offset_key:
            raise InputError(f"no time offset variable for the clock {clock!r} (time_offset_key has "
                             f"{sorted(map(str, self.time_offset_key))})")
        return self.time_offset_key[clock]

    def add_time_offset_prior(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, sigma_s: float,
                              mean_s: float = 0.0, initial_s: float | None = None, clock: str | None = None) -> None:
        """Insert the time offset variable (s; at ``initial_s``, default the prior's mean) with a Gaussian prior of
        mean ``mean_s`` and ``sigma_s`` (how far the encoder's stamps may be from the camera's); with one variable
        per clock (``time_offset_key`` a mapping), ``clock``'s."""
        if self.time_offset_key is None:
            raise InputError("this graph has no time offset variable (RotIdGraph(time_offset_key=...))")
        key = self.time_offset_key_of(clock)
        if not (np.isfinite(sigma_s) and sigma_s > 0) or not np.isfinite(mean_s):
            raise InputError(f"the time offset's prior needs a positive sigma and a finite mean (s), got sigma "
                             f"{sigma_s!r}, mean {mean_s!r}")
        if values.exists(key):
            raise InputError(f"key {gtsam.DefaultKeyFormatter(key)} already exists in values")
        values.insert(key, np.array([mean_s if initial_s is None else float(initial_s)]))
        graph.add(gtsam.PriorFactorVector(key, np.array([float(mean_s)]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, float(sigma_s))))

    def axis_of(self, joint_angles, spin_joint: str | None = None):
        """``delta -> (test points (2, 3), their derivatives (2, 3, n))`` of the FK axis of ``spin_joint`` (default
        the wrist) at ``joint_angles`` with the offsets ``delta`` (radians) of :attr:`offset_joints`
        (:func:`offset_axis_test_points`)."""
        return offset_axis_test_points(self.arm, joint_angles, self.offset_joints, spin_joint)

    def line_key(self, k: int) -> int:
        return gtsam.symbol(self.line_symbol, k)

    def circle_key(self, k: int, j: int) -> int:
        if not 0 <= j < CIRCLE_STRIDE:
            raise InputError(f"track index {j} out of range for circle keys")
        return gtsam.symbol(self.circle_symbol, k * CIRCLE_STRIDE + j)

    def track_noise(self, n: int, sigma: float | None = None):
        """Noise model of an n-point track: isotropic, wrapped in the robust kernel if there is one."""
        base = gtsam.noiseModel.Isotropic.Sigma(n, self.track_sigma_px if sigma is None else sigma)
        if self.robust is None:
            return base
        estimator = self.robust if isinstance(self.robust, gtsam.noiseModel.mEstimator.Base) else self.robust(n)
        return gtsam.noiseModel.Robust.Create(estimator, base)

    def prepare(self, measurement: Measurement, k: int = 0) -> PreparedMeasurement:
        """Undistorted pixels and ellipses of the usable tracks (pass to :meth:`add_measurement` to reuse)."""
        return prepare_tracks(self.camera, measurement, k, min_points=self.min_track_points,
                              min_extent_px=self.min_track_extent_px)

    def add_measurement(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, k: int,
                        measurement: Measurement, *, arm_T_camera: gtsam.Pose3 | None = None,
                        track_sigmas: dict[int, float] | None = None, skip_tracks=(), tie: bool = True,
                        prepared: PreparedMeasurement | None = None,
                        initial_circles: dict[int, np.ndarray] | None = None,
                        initial_line: gtsam.Rot3 | None = None, refine_circles: bool = True,
                        tie_covariance: np.ndarray | None = None, spin_start=None) -> MeasurementKeys:
        """Add measurement k's variables (with initial values) and factors; return the keys it made.

        Initial values come from ``arm_T_camera`` (default: the pose already in ``values``): the FK axis
        in the camera frame gives the line, each track's ellipse gives its circle (unless
        ``initial_circles`` gives ``(d, r)`` for track j). With ``refine_circles`` (default) the circles are
        then fitted to the tracks with that pose held fixed (a small solve per measurement), so that the
        caller's optimisation starts consistent. Tracks that are too short, too still or without an ellipse
        are skipped and listed in ``rejected``; tracks in ``skip_tracks`` are left out silently.

        ``tie=False`` adds a free line variable and its circles only (stage 1 of the two-stage methods),
        starting at ``initial_line`` if given. Otherwise the measurement is tied to the pose as the builder's
        ``model`` says; in the ``"line"`` model, ``initial_line`` (a line variable from an earlier solve whose
        circles are ``initial_circles``) keeps its tilt within its projection plane, which the tie leaves
        free, and is turned minimally so that its image is the FK axis' image. ``prepared`` reuses
        :meth:`prepare`'s work. ``tie_covariance`` (2x2, px²) is added to the tie's ``tie_sigma_px²`` (e.g. the
        FK axis' uncertainty from the joint-angle readings, :func:`gtsam_rotid.estimate.joint_tie_covariance`).
        ``spin_start`` (rigid spin): ``(factor, values)``, a rigid-spin factor of the same tracks (another graph's,
        e.g. the same measurement without the intrinsics variable) and the values it was solved at: the new factor
        starts from its inner solution there (circles, phase offsets, spin angles) and shares its tracks, instead
        of starting from the closest phases of the start circles (a graph rebuilt at a solution, solved at once).

        Nothing is added to ``graph`` or ``values`` unless every check passes.
        """
        if arm_T_camera is None and not values.exists(self.pose_key):
            raise InputError("insert an initial arm_T_camera into values (or pass arm_T_camera=) first")
        arm_T_camera = values.atPose3(self.pose_key) if arm_T_camera is None else arm_T_camera
        bound = tie and self.model is Model.POSE
        tie_noise = tie_noise_model(self.tie_sigma_px, tie_covariance) if tie and not bound else None
        line_key = None if bound else self.line_key(k)
        if line_key is not None and values.exists(line_key):
            raise InputError(f"measurement {k}: key {gtsam.DefaultKeyFormatter(line_key)} already exists in values")
        prepared = self.prepare(measurement, k) if prepared is None else prepared
        if tie and self.offset_joints and not values.exists(self.offsets_key):
            raise InputError("insert the joint offsets first (RotIdGraph.add_offsets_prior)")
        if self.intrinsics_key is not None and not values.exists(self.intrinsics_key):
            raise InputError("insert the intrinsics first (RotIdGraph.add_intrinsics_prior)")
        readings = measurement.spin_readings
        if self.time_offset_key is not None and (readings is not None or not isinstance(self.time_offset_key, dict)):
            key = self.time_offset_key_of(None if readings is None else readings.clock)
            if not values.exists(key):
                raise InputError("insert the time offset first (RotIdGraph.add_time_offset_prior" + (
                    f", clock={readings.clock!r})" if isinstance(self.time_offset_key, dict) else ")"))
        if tie and self.offset_joints:
            axis = self.arm.wrist_axis_offset_derivatives(measurement.joint_angles, self.offset_joints,
                                                          values.atVector(self.offsets_key),
                                                          measurement.spin_joint)[0]
        else:
            axis = self.arm.wrist_axis(measurement.joint_angles, measurement.spin_joint)
        point_cam, direction_cam = axis_in_camera(axis, arm_T_camera)
        line_cam, scale = _start_line(point_cam, direction_cam, initial_line, tie, bound)
        foot_offset = point_cam @ direction_cam  # foot = point_cam - foot_offset * direction
        K = self.camera.K
        K_inv = np.linalg.inv(K)
        keys = MeasurementKeys(k, line_key, [], [], [], -1, scale, dict(prepared.rejected))
        fk_axis = FKAxis(axis.point, axis.direction)  # one line_from_pose per pose tried, for all tracks
        new_values = gtsam.Values()
        new_factors = []
        projected = self.model is Model.PROJECTED
        start_circles = []
        wanted = [j for j in prepared.usable if j not in skip_tracks
                  and (initial_circles is None or j not in initial_circles)]
        started = dict(zip(wanted, _start_circles([prepared.usable[j] for j in wanted], K_inv, point_cam,
                                                  direction_cam, foot_offset, scale), strict=True))
        for j, track in prepared.usable.items():
            if j in skip_tracks:
                continue
            circle_key = self.circle_key(k, j)
            if not projected and values.exists(circle_key):
                raise InputError(f"measurement {k}, track {j}: key {gtsam.DefaultKeyFormatter(circle_key)} "
                                 "already exists in values")
            if initial_circles is not None and j in initial_circles:
                circle = np.asarray(initial_circles[j], dtype=float).reshape(2)
            else:
                circle = started[j]
            keys.tracks.append(j)
            if projected:
                start_circles.append(circle)
                continue
            new_values.insert(circle_key, circle)
            sigma = None if track_sigmas is None else track_sigmas.get(j)
            new_factors.append(self._circle_factor(track, sigma, circle_key, line_key, fk_axis))
            keys.circles.append(circle_key)
        if len(keys.tracks) < 2:
            raise InputError(f"measurement {k}: only {len(keys.tracks)} usable track(s), need at least 2 "
                             f"(rejected: {keys.rejected})")
        if projected:
            keys.coaxial = self._coaxial(line_key, prepared, keys.tracks, start_circles, track_sigmas, line_cam,
                                         measurement, direction_cam, values, spin_start)
            new_factors.append(keys.coaxial.factor)
        elif refine_circles:
            new_values = self._refined_circles(new_factors, new_values, keys, line_key, line_cam, arm_T_camera)
        # nothing is added to the caller's graph or values before every check has passed
        _commit(graph, values, new_factors, new_values, keys, line_cam)
        if tie and not bound and self.offset_joints:
            axis_of = self.axis_of(measurement.joint_angles, measurement.spin_joint)
            graph.add(make_axis_offsets_to_line_variable_factor(tie_noise, self.pose_key, line_key, self.offsets_key,
                                                                axis_of, K, self.intrinsics_key))
            keys.tie_factor = graph.size() - 1
        elif tie and not bound:
            graph.add(make_axis_to_line_variable_factor(tie_noise, self.pose_key, line_key, axis_test_points(axis), K,
                                                        self.intrinsics_key))
            keys.tie_factor = graph.size() - 1
        return keys

    def _circle_factor(self, track, sigma: float | None, circle_key: int, line_key: int | None, fk_axis: FKAxis):
        """One track's circle-point factor: on its line variable, or (``line_key`` None: the ``"pose"`` model) on
        the pose through the FK axis."""
        noise = self.track_noise(len(track.ideal), sigma)
        if line_key is None:
            return make_pose_circle_point_factor(noise, self.pose_key, circle_key, track.ideal, self.camera.K, fk_axis)
        return make_circle_point_factor(noise, line_key, circle_key, track.ideal, self.camera.K)

    def _coaxial(self, line_key, prepared: PreparedMeasurement, tracks: list[int], start_circles: list[np.ndarray],
                 track_sigmas: dict[int, float] | None, line: gtsam.Rot3, measurement: Measurement,
                 direction_cam: np.ndarray, values: gtsam.Values, spin_start=None):
        """The projected model's one factor of a measurement: its tracks' circles (and with the rigid spin, their
        phase offsets and the spin angles) solved inside, at the median of their pixel sigmas. The rigid spin
        starts from the closest phases of the start circles at the start ``line``; synced (the measurement's spin
        readings, ``encoder_sigma_deg``), its angles follow the readings, turning right-handed about the FK axis'
        direction ``direction_cam`` (camera frame)."""
        sigmas = [self.track_sigma_px if track_sigmas is None else track_sigmas.get(j, self.track_sigma_px)
                  for j in tracks]
        ideal = [prepared.usable[j].ideal for j in tracks]
        frames = [prepared.usable[j].frames for j in tracks]
        circles = np.array(start_circles)
        if self.intrinsics_key is not None and any(f is None for f in frames):
            raise InputError("refining the intrinsics needs every track's frame indices (the rigid spin); a track "
                             "of this measurement has none")
        if self.spin_model is SpinModel.FREE or any(f is None for f in frames):
            return make_coaxial_line_factor(line_key, ideal, self.camera.K, circles,
                                            sigma_px=float(np.median(sigmas)), robust=self.robust)
        started = _started_spin(spin_start, ideal, frames)
        if started is not None:
            rigid, circles, phi0, theta = started
        else:
            rigid = RigidTracks(list(zip(ideal, frames, strict=True)))
            phi0, theta = closest_spin(rigid, self.camera.K, line, circles)
        robust = self.robust
        if callable(robust) and not isinstance(robust, gtsam.noiseModel.mEstimator.Base):
            robust = lambda n, per_residuals=self.robust: per_residuals(2 * n)  # noqa: E731  (2 residuals a point)
        encoder, time_key, offset = None, None, self.time_offset_s
        readings = measurement.spin_readings
        if self.encoder_sigma_deg is not None and readings is not None:
            # the line variable's axis (its second column) keeps its side of the FK axis while LM moves it
            sign = 1.0 if line.matrix()[:, 1] @ direction_cam >= 0 else -1.0
            encoder = EncoderPrior(readings.frame_times[rigid.frame_ids], readings.times, readings.angles,
                                   np.radians(self.encoder_sigma_deg), sign)
            if self.time_offset_key is not None:
                time_key = self.time_offset_key_of(readings.clock)
                offset = float(values.atVector(time_key)[0])
            if not encoder.covers(offset):
                k = gtsam.Symbol(line_key).index()
                raise InputError(f"measurement {k}: the spin readings ({readings.times[0]:.3f}-"
                                 f"{readings.times[-1]:.3f} s) do not cover the tracks' frames "
                                 f"({encoder.frame_times[0] + offset:.3f}-{encoder.frame_times[-1] + offset:.3f} s "
                                 f"on the encoder's clock, {offset:+.3f} s from the camera's): give the clocks' "
                                 "offset (camera minus encoder: CalibrationOptions.time_offset_s, calibrate "
                                 "--time-offset) or leave the readings out")
        return make_rigid_line_factor(line_key, rigid, self.camera.K, circles, phi0, theta,
                                      sigma_px=float(np.median(sigmas)), robust=robust,
                                      intrinsics_key=self.intrinsics_key, encoder=encoder, time_key=time_key,
                                      time_offset=offset)

    def _refined_circles(self, factors, circles: gtsam.Values, keys: MeasurementKeys, line_key, line_cam,
                         arm_T_camera) -> gtsam.Values:
        """The circles fitted to their tracks with the line (or pose) held at its initial value."""
        graph = gtsam.NonlinearFactorGraph()
        for factor in factors:
            graph.add(factor)
        values = gtsam.Values(circles)
        if line_key is None:
            graph.add(gtsam.NonlinearEqualityPose3(self.pose_key, arm_T_camera))
            values.insert(self.pose_key, arm_T_camera)
        else:
            graph.add(gtsam.NonlinearEqualityRot3(line_key, line_cam))
            values.insert(line_key, line_cam)
        params = lm_params(REFINE_ITERATIONS, relative_tolerance=1e-4)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        refined = gtsam.Values()
        for key in keys.circles:
            refined.insert(key, result.atVector(key))
        return refined


def _started_spin(spin_start, ideal: list, frames: list):
    """``(tracks, circles, phi0, theta)`` of :meth:`RotIdGraph.add_measurement`'s ``spin_start`` where its factor
    holds exactly these tracks (pixels and frames), else None."""
    if spin_start is None:
        return None
    factor, values = spin_start
    if not isinstance(factor, RigidLineFactor):
        return None
    tracks = factor.tracks
    counts = np.array([len(p) for p in ideal])
    if tracks.n_tracks != len(ideal) or not np.array_equal(tracks.counts, counts):
        return None
    if not (np.array_equal(tracks.pixels, np.concatenate(ideal))
            and np.array_equal(tracks.frame_ids[tracks.frame], np.concatenate(frames))):
        return None
    return tracks, factor.circles(values), factor.phase_offsets(values), factor.spin_angles(values)


def _commit(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, factors: list, new_values: gtsam.Values,
            keys: MeasurementKeys, line_cam: gtsam.Rot3) -> None:
    """Add a measurement's checked factors and values (its line variable, if it has one, at ``line_cam``)."""
    for factor in factors:
        graph.add(factor)
        keys.circle_factors.append(graph.size() - 1)
    if keys.line_key is not None:
        new_values.insert(keys.line_key, line_cam)
    values.insert(new_values)


def _start_circles(tracks: list, K_inv: np.ndarray, point_cam: np.ndarray, direction_cam: np.ndarray,
                   foot_offset: float, scale: float) -> np.ndarray:
    """(m, 2) the tracks' start ``(d, r)`` about the axis (camera frame, in units of the line's ``scale``) from
    their rays and their ellipse centres."""
    if not tracks:
        return np.zeros((0, 2))
    centre_rays = np.column_stack([np.array([t.ellipse.centre for t in tracks]), np.ones(len(tracks))]) @ K_inv.T
    ideal = np.concatenate([t.ideal for t in tracks])
    rays = np.column_stack([ideal, np.ones(len(ideal))]) @ K_inv.T
    circles = _initial_circles(point_cam, direction_cam, rays, np.array([len(t.ideal) for t in tracks]),
                               centre_rays)
    return np.column_stack([(circles[:, 0] + foot_offset) / scale, circles[:, 1] / scale])


def _start_line(point_cam: np.ndarray, direction_cam: np.ndarray, initial_line: gtsam.Rot3 | None, tie: bool,
                bound: bool) -> tuple[gtsam.Rot3, float]:
    """The line variable's start and scale: the FK axis in the camera frame, or ``initial_line`` (free, untied
    line), or ``initial_line`` turned minimally onto the FK axis' image (tied line model)."""
    line_cam, scale = rot3_from_line(point_cam, direction_cam)
    if initial_line is not None and not tie:
        line_cam = initial_line
    elif initial_line is not None and not bound:
        line_cam = align_line(initial_line, line_cam.matrix()[:, 2])
    return line_cam, scale
