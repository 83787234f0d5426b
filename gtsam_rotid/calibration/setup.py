"""What every stage needs of the measurements, computed once: each measurement's usable tracks, FK axis, image
axis and arcs (:class:`_Setup`), and the arc geometry.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..dataset import Measurement
from ..errors import InputError
from ..factors import (
    line_distances,
)
from ..graph import (
    PreparedMeasurement,
    axis_test_points,
)
from ..initialise import initial_image_axis, line_through_points
from .lm import _builder
from .options import MIN_MEASUREMENTS, CalibrationOptions
from .tuning import ARC_TRIM, WEAK_ARC_DEG


@dataclass(frozen=True)
class _Setup:
    """Built once per calibration (:func:`_setup`) and read by every stage; none changes it."""

    axes: list  # FK axes of the spinning joints (Line3, arm frame)
    prepared: list[PreparedMeasurement]
    centre_axes: list[np.ndarray]  # the initial image axes: lines through the tracks' ellipse centres
    #: per measurement, the axis' test points' derivative by each joint angle times its sigma, (6, n_joints), or
    #: None (exact kinematics)
    axis_noise: list[np.ndarray | None] = field(default_factory=list)
    #: the caller's index of each measurement here (measurements without enough evidence are left out before)
    index: list[int] = field(default_factory=list)
    K: np.ndarray | None = None  # the camera matrix
    #: per measurement, the longest turn of a usable track's direction of motion (deg, :func:`_turning_deg`)
    turning: list[float] = field(default_factory=list)
    #: the image axes' prior floor (px, ``CalibrationOptions.axis_floor_px`` resolved by ``calibrate``)
    floor_px: float = 0.0
    #: each track's own offset (px, ``CalibrationOptions.track_offset_px`` resolved by ``calibrate``)
    track_offset_px: float = 0.0
    #: the joint offsets the calibration refines (:class:`gtsam_rotid.calibration.offsets.OffsetsPrior`; the
    #: measurements' readings, hence ``axes``, are already shifted by its ``start``); None: the kinematics as given
    offsets: object | None = None
    #: the estimate rests on stage 1's free-phase lines and their covariances (``weighted``, or the joint fit with a
    #: free phase per observation): their covariance is jackknifed where the ellipses are thin (:func:`stage1._checked`)
    thin_check: bool = False
    #: per measurement, the joint that spun (``Measurement.spin_joint``; None: the wrist joint)
    spin_joints: list[str | None] = field(default_factory=list)
    #: with refined intrinsics, the camera as given (the prior's mean; the calibration may run from a camera refined
    #: by an earlier pass); None: the camera the stages see
    given_camera: Camera | None = None
    #: a first pass that only refines the camera for the next (the joint fit from the first start, no restarts)
    camera_pass: bool = False

    def spin_joint(self, k: int) -> str | None:
        return self.spin_joints[k] if self.spin_joints else None

    def noise(self, k: int) -> np.ndarray | None:
        return self.axis_noise[k] if self.axis_noise else None

    def tie_covariance(self, camera: Camera, k: int, line: np.ndarray | None, pose: gtsam.Pose3) -> np.ndarray | None:
        """(2, 2) covariance (px²) that the joint-angle noise gives measurement ``k``'s image axis (the
        distances of its test points, :func:`joint_tie_covariance`); None with exact kinematics."""
        return joint_tie_covariance(camera, self.axes[k], line, pose, self.noise(k))

    @property
    def floor_covariance(self) -> np.ndarray | None:
        """(2, 2) covariance (px²) of the prior floor on every image axis' test-point distances (a bias all of a
        measurement's tracks share): the axis shifted by ``floor_px`` and turned by ``floor_px`` at its test points,
        independent 1 sigma each (distances ``s + t`` and ``s - t``: ``2 floor_px² I``); None without a floor.
        Not in the fit's weights (the estimate keeps its precise axes' information): what it passes into the
        estimate is added to the covariance (:func:`stage2._prior_floor_covariance`); in the axes' test (each axis'
        distances at ``V_k + F``), whose scale and common floor then read only the scatter beyond it."""
        return 2.0 * self.floor_px**2 * np.eye(2) if self.floor_px > 0.0 else None

    @property
    def short_arc_measurements(self) -> list[int]:
        """The measurements with no track that turns by WEAK_ARC_DEG."""
        return [k for k, t in enumerate(self.turning) if t < WEAK_ARC_DEG]

    @property
    def short_arcs(self) -> bool:
        """Some measurement has no track that turns by WEAK_ARC_DEG: stage 1 is then refitted from its own
        estimate and jackknifed, and the axes' scatter scales the covariance at a lower level (``_calibrate``)."""
        return bool(self.short_arc_measurements)


def _setup(arm: Arm, camera: Camera, measurements: list[Measurement], options: CalibrationOptions,
           index: list[int] | None = None, minimum: int = MIN_MEASUREMENTS) -> _Setup:
    if len(measurements) < minimum:
        raise InputError(f"need at least {minimum} measurements (arm poses) to calibrate, "
                         f"got {len(measurements)}")
    builder = _builder(arm, camera, options)
    axes, prepared, lines = [], [], []
    for k, m in enumerate(measurements):
        axes.append(arm.wrist_axis(m.joint_angles, m.spin_joint))
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
        noise = [sigma * test_point_jacobian(arm, m.joint_angles, joint=m.spin_joint) for m in measurements]
    turning = [max((_turning_deg(t.ideal) for t in p.usable.values()), default=0.0) for p in prepared]
    index = list(range(len(measurements))) if index is None else list(index)
    return _Setup(axes, prepared, lines, noise, index, camera.K, turning=turning,
                  floor_px=float(options.axis_floor_px or 0.0),
                  track_offset_px=float(options.track_offset_px or 0.0),
                  spin_joints=[m.spin_joint for m in measurements])


def test_point_jacobian(arm: Arm, joint_angles, step: float = 1e-6, joint: str | None = None) -> np.ndarray:
    """(6, n_joints): derivative of the spinning joint's (``joint``, default the wrist) axis' two FK test points (arm
    frame, m, stacked) by each joint angle (rad), by central differences."""
    q = np.asarray(joint_angles, dtype=float)
    J = np.empty((6, q.size))
    for j in range(q.size):  # one forward kinematics per joint and side
        dq = np.zeros_like(q)
        dq[j] = step
        plus = axis_test_points(arm.wrist_axis(q + dq, joint)).ravel()
        minus = axis_test_points(arm.wrist_axis(q - dq, joint)).ravel()
        J[:, j] = (plus - minus) / (2.0 * step)
    return J


def joint_tie_covariance(camera: Camera, axis, line: np.ndarray | None, pose: gtsam.Pose3,
                         noise: np.ndarray | None, step: float = 1e-3) -> np.ndarray | None:
    """(2, 2) covariance (px²) of the distances of ``axis``' projected test points to the image ``line`` that
    the joint-angle noise causes (``noise``: :func:`test_point_jacobian` times each joint's sigma), to first order;
    None when ``noise`` is None. ``line`` None: the axis' own image under ``pose``."""
    if noise is None:
        return None
    _, D = test_point_distances(camera, axis, line, pose, noise, step)
    return D @ D.T


def test_point_distances(camera: Camera, axis, line: np.ndarray | None, pose: gtsam.Pose3, columns: np.ndarray,
                         step: float) -> tuple[np.ndarray, np.ndarray]:
    """(2,) the distances (px) of ``axis``' test points projected by ``pose`` from the image ``line`` (None: the
    axis' own image), and (2, c) their central-difference derivatives along each column of ``columns`` (6, c): a
    displacement of the two stacked test points (arm frame, m), stepped by ``step`` times it."""
    points = axis_test_points(axis)

    def projected(p):
        return camera.project(np.array([pose.transformTo(x) for x in p]), distort=False)

    line = line_through_points(projected(points)) if line is None else line

    def distances(p):
        return line_distances(line, projected(p))

    # one column per displacement: the distances' change along it
    D = np.column_stack([(distances(points + step * c.reshape(2, 3)) - distances(points - step * c.reshape(2, 3)))
                         / (2.0 * step) for c in columns.T])
    return distances(points), D


def _span_deg(phi: np.ndarray, trim: float = ARC_TRIM) -> float:
    """The arc (deg) that angles (rad) cover: cut at their largest gap, from the ``trim`` to the ``1 - trim``
    quantile (a few noisy points at an arc's ends would otherwise widen a short arc)."""
    phi = np.sort(np.mod(np.asarray(phi, dtype=float), 2.0 * np.pi))
    if len(phi) < 2:
        return 0.0
    gaps = np.diff(np.concatenate([phi, [phi[0] + 2.0 * np.pi]]))
    cut = int(np.argmax(gaps))
    unwrapped = np.concatenate([phi[cut + 1:], phi[:cut + 1] + 2.0 * np.pi])  # sorted
    return float(np.degrees(_sorted_quantile(unwrapped, 1.0 - trim) - _sorted_quantile(unwrapped, trim)))


def _sorted_quantile(a: np.ndarray, q: float) -> float:
    """``np.quantile(a, q)`` (linear interpolation) of sorted ``a``, without its overhead (called per track)."""
    position = q * (len(a) - 1)
    i = min(int(position), len(a) - 2)
    t = position - i
    low, high = float(a[i]), float(a[i + 1])
    return high - (high - low) * (1.0 - t) if t >= 0.5 else low + (high - low) * t


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
