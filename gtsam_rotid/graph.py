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

from dataclasses import dataclass, field

import gtsam
import numpy as np

from .arm import Arm
from .camera import Camera
from .dataset import Measurement, Track
from .errors import InputError
from .factors import make_axis_to_line_variable_factor, make_circle_point_factor, rot3_from_line
from .initialise import MIN_ELLIPSE_POINTS, fit_ellipse

#: Distance (m) between the two FK test points on each wrist axis.
TEST_POINT_SPACING = 0.1
#: Circle variable index stride: circle key of (k, j) is symbol(c, k * CIRCLE_STRIDE + j).
CIRCLE_STRIDE = 100_000


def axis_test_points(axis) -> np.ndarray:
    """Two FK test points on a wrist axis (arm frame): its origin and one ``TEST_POINT_SPACING`` along it."""
    return axis.points_at([0.0, TEST_POINT_SPACING])


@dataclass
class MeasurementKeys:
    """What :meth:`RotIdGraph.add_measurement` made for one measurement."""

    index: int
    line: int
    circles: list[int]
    tracks: list[int]  # track index (in the measurement) of each circle
    circle_factors: list[int]  # factor index in the graph of each track's circle-point factor
    tie_factor: int
    scale: float  # camera-to-axis distance (m) of the initial line: metric = unit * scale
    rejected: dict[int, str] = field(default_factory=dict)  # track index -> reason


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


class RotIdGraph:
    """Adds rotation-identification variables and factors to a user's graph.

    Args:
        arm, camera: the arm model and the calibrated camera.
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera`` (may already be the user's variable).
        line_symbol, circle_symbol: symbol characters for the line and circle variables.
        track_sigma_px: pixel noise of the circle-point factors (an estimator rescales it).
        tie_sigma_px: stiffness of the projected-axis tie (the kinematics are taken as exact).
        min_track_points: tracks with fewer points are rejected.
        robust: optional ``gtsam.noiseModel.mEstimator`` applied per track (whole-track weighting).
    """

    def __init__(self, arm: Arm, camera: Camera, *, pose_key: int = gtsam.symbol("T", 0), line_symbol: str = "l",
                 circle_symbol: str = "c", track_sigma_px: float = 1.0, tie_sigma_px: float = 1e-3,
                 min_track_points: int = 10, robust=None):
        if line_symbol == circle_symbol:
            raise InputError("line_symbol and circle_symbol must differ")
        self.arm = arm
        self.camera = camera
        self.pose_key = pose_key
        self.line_symbol = line_symbol
        self.circle_symbol = circle_symbol
        self.track_sigma_px = float(track_sigma_px)
        self.tie_sigma_px = float(tie_sigma_px)
        self.min_track_points = max(int(min_track_points), MIN_ELLIPSE_POINTS)
        self.robust = robust

    def line_key(self, k: int) -> int:
        return gtsam.symbol(self.line_symbol, k)

    def circle_key(self, k: int, j: int) -> int:
        if not 0 <= j < CIRCLE_STRIDE:
            raise InputError(f"track index {j} out of range for circle keys")
        return gtsam.symbol(self.circle_symbol, k * CIRCLE_STRIDE + j)

    def track_noise(self, n: int, sigma: float | None = None):
        base = gtsam.noiseModel.Isotropic.Sigma(n, self.track_sigma_px if sigma is None else sigma)
        return base if self.robust is None else gtsam.noiseModel.Robust.Create(self.robust, base)

    def add_measurement(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, k: int,
                        measurement: Measurement, *, arm_T_camera: gtsam.Pose3 | None = None,
                        track_sigmas: dict[int, float] | None = None, skip_tracks=(),
                        tie: bool = True) -> MeasurementKeys:
        """Add measurement k's variables (with initial values) and factors.

        Initial values come from ``arm_T_camera`` (default: the pose already in ``values``): the FK axis
        in the camera frame gives the line, each track's ellipse gives its circle. Tracks that are too
        short or whose ellipse cannot be fitted are skipped and listed in ``rejected``; tracks in
        ``skip_tracks`` are left out silently. ``tie=False`` leaves out the projected-axis tie (stage 1
        of the two-stage methods: the line and circles alone).
        """
        if arm_T_camera is None:
            if not values.exists(self.pose_key):
                raise InputError("insert an initial arm_T_camera into values (or pass arm_T_camera=) first")
            arm_T_camera = values.atPose3(self.pose_key)
        line_key = self.line_key(k)
        if values.exists(line_key):
            raise InputError(f"measurement {k}: key {gtsam.DefaultKeyFormatter(line_key)} already exists in values")
        axis = self.arm.wrist_axis(measurement.joint_angles)
        camera_T_arm = arm_T_camera.inverse()
        point_cam = camera_T_arm.transformFrom(axis.point)
        direction_cam = camera_T_arm.rotation().matrix() @ axis.direction
        line_cam, scale = rot3_from_line(point_cam, direction_cam)
        foot_offset = point_cam @ direction_cam  # foot = point_cam - foot_offset * direction
        K = self.camera.K
        keys = MeasurementKeys(k, line_key, [], [], [], -1, scale)
        for j, track in enumerate(measurement.tracks):
            if j in skip_tracks:
                continue
            track = Track.from_any(track, measurement=k, track=j)
            if len(track) < self.min_track_points:
                keys.rejected[j] = f"too short ({len(track)} < {self.min_track_points} points)"
                continue
            ideal = self.camera.undistort_pixels(track.pixels)
            ellipse = fit_ellipse(ideal)
            if ellipse is None:
                keys.rejected[j] = "no ellipse fits its points"
                continue
            circle_key = self.circle_key(k, j)
            if values.exists(circle_key):
                raise InputError(f"measurement {k}, track {j}: key {gtsam.DefaultKeyFormatter(circle_key)} "
                                 "already exists in values")
            centre_ray = np.linalg.solve(K, np.append(ellipse.centre, 1.0))
            rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(K).T
            offset, radius = initial_circle(point_cam, direction_cam, rays, centre_ray)
            values.insert(circle_key, np.array([(offset + foot_offset) / scale, radius / scale]))
            sigma = None if track_sigmas is None else track_sigmas.get(j)
            graph.add(make_circle_point_factor(self.track_noise(len(ideal), sigma), line_key, circle_key, ideal, K))
            keys.circles.append(circle_key)
            keys.tracks.append(j)
            keys.circle_factors.append(graph.size() - 1)
        if len(keys.circles) < 2:
            raise InputError(f"measurement {k}: only {len(keys.circles)} usable track(s), need at least 2 "
                             f"(rejected: {keys.rejected})")
        values.insert(line_key, line_cam)
        if not tie:
            return keys
        tie_noise = gtsam.noiseModel.Isotropic.Sigma(2, self.tie_sigma_px)
        graph.add(make_axis_to_line_variable_factor(tie_noise, self.pose_key, line_key, axis_test_points(axis), K))
        keys.tie_factor = graph.size() - 1
        return keys
