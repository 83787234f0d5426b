"""Circle-point factor bound to the pose: a track's pixels against the projected circle about the FK axis.

Keys: the ``gtsam.Pose3`` ``arm_T_camera`` and the track's 2-vector circle variable ``(d, r)``. The measurement's
line variable is not a variable here: it is the FK wrist axis (arm frame, exact kinematics) mapped into the
camera frame by the pose, :func:`line_from_pose`. This is the joint model with the kinematics as a hard
constraint: all three observable DOF of the axis (its image line *and* its tilt within the projection plane)
inform the pose, and there is no stiff tie for the optimiser to crawl along.

Residuals and the line Jacobian are :class:`.circle_track.CircleTrack`'s (one factor per track, vectorised); the
pose Jacobian is chained through ``d(line)/d(pose)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .circle import checked_track
from .circle_track import CircleTrack
from .geometry import skew


def line_from_pose(arm_T_camera: gtsam.Pose3, axis_point_arm, axis_direction_arm) -> tuple[np.ndarray, np.ndarray]:
    """Line variable of an arm-frame axis seen from ``arm_T_camera``, and its Jacobian wrt the pose tangent.

    ``X = camera_T_arm p``, ``a = camera_R_arm a_arm``; the line variable has columns ``c0 = f / |f|`` with
    ``f = X - (X . a) a`` (the foot), ``c1 = a``, ``c2 = c0 x c1`` (as :func:`.geometry.rot3_from_line`).

    A pose perturbation ``xi = (w, rho)`` gives ``dX = [X]x w - rho`` and ``da = [a]x w``; then
    ``df = dX - a (a . dX + X . da) - (X . a) da``, ``dc0 = (I - c0 c0^T) df / |f|``, ``dc1 = da``,
    ``dc2 = -[c1]x dc0 + [c0]x dc1``, and the line's own tangent (``R' = R Exp(omega)``) is
    ``omega = (c2 . dc1, c0 . dc2, c1 . dc0)``.

    Returns:
        R: (3, 3) line variable (rotation matrix).
        J: (3, 6) ``d omega / d xi``.
    """
    M = arm_T_camera.matrix()
    return _line_from_matrix(M, np.asarray(axis_point_arm, dtype=float), np.asarray(axis_direction_arm, dtype=float))


def _line_from_matrix(M: np.ndarray, p: np.ndarray, a_arm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R_ac, t = M[:3, :3], M[:3, 3]
    X = (p - t) @ R_ac
    a = a_arm @ R_ac
    a = a / np.sqrt(a @ a)
    along = X @ a
    f = X - along * a
    dist = np.sqrt(f @ f)
    if dist < 1e-12:
        raise ValueError("the wrist axis passes through the camera centre: its image is a point, not a line")
    c0, c1 = f / dist, a
    c2 = _cross(c0, c1)
    dX = np.hstack([skew(X), -np.eye(3)])
    da = np.zeros((3, 6))
    da[:, :3] = skew(a)
    df = dX - np.outer(a, a @ dX + X @ da) - along * da
    dc0 = (df - np.outer(c0, c0 @ df)) / dist
    dc2 = -skew(c1) @ dc0 + skew(c0) @ da
    J = np.vstack([c2 @ da, c0 @ dc2, c1 @ dc0])
    return np.column_stack([c0, c1, c2]), J


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


class FKAxis:
    """A measurement's FK wrist axis (arm frame) with the last :func:`line_from_pose` result cached.

    Every track factor of a measurement shares one, so the line and its Jacobian are computed once per pose
    the optimiser tries, not once per track. The cache holds only the last pose; results never depend on it.
    """

    __slots__ = ("point", "direction", "_pose", "_line")

    def __init__(self, point, direction):
        self.point = np.array(point, dtype=float).reshape(3)
        self.direction = np.array(direction, dtype=float).reshape(3)
        self.point.setflags(write=False)
        self.direction.setflags(write=False)
        self._pose: np.ndarray | None = None
        self._line: tuple[np.ndarray, np.ndarray] | None = None

    def line(self, arm_T_camera: gtsam.Pose3) -> tuple[np.ndarray, np.ndarray]:
        M = arm_T_camera.matrix()
        if self._pose is None or not np.array_equal(M, self._pose):
            self._line = _line_from_matrix(M, self.point, self.direction)
            self._pose = M
        return self._line


def make_pose_circle_point_factor(noise, pose_key: int, circle_key: int, pixels, K, axis: FKAxis | tuple,
                                  *, warm_start: bool = True) -> gtsam.CustomFactor:
    """One factor per track: its N pixels against the projected circle about the pose-mapped FK axis.

    Args:
        noise: gtsam noise model of dimension N (a ``noiseModel.Robust`` reweights the whole track).
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera``.
        circle_key: key of the track's circle variable ``(d, r)`` (offset from the axis' foot and radius, in
            units of the camera-to-axis distance, as for the line variable of :mod:`.geometry`).
        pixels: (N, 2) observed ideal (undistorted) pixels of the track.
        K: (3, 3) intrinsic matrix.
        axis: the measurement's FK wrist axis (arm frame): an :class:`FKAxis` (share one between the tracks of
            a measurement) or a ``(point, direction)`` pair.
        warm_start: as for :func:`.circle.make_circle_point_factor`.

    Returns:
        ``gtsam.CustomFactor`` with Jacobians (N, 6) wrt the Pose3 tangent and (N, 2) wrt ``(d, r)``.
    """
    pixels, K = checked_track(noise, pixels, K)
    axis = axis if isinstance(axis, FKAxis) else FKAxis(*axis)
    track = CircleTrack(K, pixels, warm_start=warm_start)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        R, J_line = axis.line(values.atPose3(keys[0]))
        d, r = values.atVector(keys[1])
        e, H_line, H_circle = track.evaluate(R, d, r, jacobians=H is not None)
        if H is not None:
            H[0] = H_line @ J_line
            H[1] = H_circle
        return e

    return gtsam.CustomFactor(noise, [pose_key, circle_key], error_func)
