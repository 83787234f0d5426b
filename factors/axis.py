"""Projected-axis distance factors: FK wrist-axis test points, through ``camera_T_arm``, against an image line.

Residual (length M): signed pixel distances ``l . (u_i, 1)`` of the M >= 2 projected test points to the image line
``l`` (normalised, ``l1^2 + l2^2 = 1``). The line is either a measurement (two-stage methods) or comes from a Rot3
line variable (joint method). The maths lives in :func:`.geometry.axis_point_residuals`.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .geometry import (
    axis_point_residuals,
    image_line_from_rot3,
    image_line_intrinsics_jacobian,
    line_distance_covariance,
)

__all__ = ["axis_offsets_residuals", "line_distance_covariance",
           "make_axis_offsets_to_line_factor", "make_axis_offsets_to_line_variable_factor",
           "make_axis_to_line_factor", "make_axis_to_line_variable_factor"]


def _checked_points(noise, test_points_arm) -> np.ndarray:
    points = np.array(test_points_arm, dtype=float).reshape(-1, 3)
    if len(points) < 2:
        raise ValueError(f"need at least 2 test points on the axis, got {len(points)}")
    if noise.dim() != len(points):
        raise ValueError(f"noise model has dimension {noise.dim()} but there are {len(points)} test points")
    points.setflags(write=False)
    return points


def _frozen_line_and_K(line, K) -> tuple[np.ndarray, np.ndarray]:
    """The measured image line normalised (``l1^2 + l2^2 = 1``) and the intrinsic matrix, both read-only."""
    line = np.array(line, dtype=float).reshape(3)
    line = line / np.hypot(line[0], line[1])
    K = np.array(K, dtype=float).reshape(3, 3)
    line.setflags(write=False)
    K.setflags(write=False)
    return line, K


def make_axis_to_line_factor(noise, pose_key: int, test_points_arm, line, K) -> gtsam.CustomFactor:
    """Distances of projected FK axis test points to a measured image line.

    Args:
        noise: gtsam noise model of dimension M (e.g. ``noiseModel.Gaussian.Covariance`` built with
            :func:`.geometry.line_distance_covariance`).
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera``.
        test_points_arm: (M, 3) points on the FK wrist axis, arm frame.
        line: (3,) measured homogeneous image line; normalised here to ``l1^2 + l2^2 = 1``.
        K: (3, 3) intrinsic matrix.

    Returns:
        ``gtsam.CustomFactor`` with an (M, 6) Jacobian wrt the Pose3 tangent (rotation, translation).
    """
    points_arm = _checked_points(noise, test_points_arm)
    line, K = _frozen_line_and_K(line, K)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        arm_T_camera = values.atPose3(this.keys()[0])
        e, H_pose, _ = axis_point_residuals(K, arm_T_camera, points_arm, line)
        if H is not None:
            H[0] = H_pose
        return e

    return gtsam.CustomFactor(noise, [pose_key], error_func)


def _intrinsics_of(values: gtsam.Values, keys, index: int, K: np.ndarray) -> np.ndarray:
    """The intrinsic matrix: the ``gtsam.Cal3_S2`` at ``keys[index]`` if the factor has that key, else ``K``."""
    return values.atCal3_S2(keys[index]).K() if len(keys) > index else K


def make_axis_to_line_variable_factor(noise, pose_key: int, line_key: int, test_points_arm, K,
                                      intrinsics_key: int | None = None) -> gtsam.CustomFactor:
    """Distances of projected FK axis test points to the image of a Rot3 line variable.

    Args:
        noise: gtsam noise model of dimension M.
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera``.
        line_key: key of the measurement's ``gtsam.Rot3`` line variable.
        test_points_arm: (M, 3) points on the FK wrist axis, arm frame.
        K: (3, 3) intrinsic matrix.
        intrinsics_key: key of a ``gtsam.Cal3_S2`` variable that replaces ``K`` (a third Jacobian, (M, 5): only
            the focal lengths and skew change the distances, see
            :func:`.geometry.image_line_intrinsics_jacobian`).

    Returns:
        ``gtsam.CustomFactor`` with Jacobians (M, 6) wrt the Pose3 tangent and (M, 3) wrt the Rot3 tangent.
    """
    points_arm = _checked_points(noise, test_points_arm)
    K = np.array(K, dtype=float).reshape(3, 3)
    K.setflags(write=False)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        arm_T_camera = values.atPose3(keys[0])
        K_now = _intrinsics_of(values, keys, 2, K)
        line_rot = values.atRot3(keys[1])
        line, J_line = image_line_from_rot3(K_now, line_rot)
        e, H_pose, H_l = axis_point_residuals(K_now, arm_T_camera, points_arm, line)
        if H is not None:
            H[0] = H_pose
            H[1] = H_l @ J_line
            if len(keys) > 2:
                H[2] = image_line_intrinsics_jacobian(K_now, line_rot, e)
        return e

    keys = [pose_key, line_key] if intrinsics_key is None else [pose_key, line_key, intrinsics_key]
    return gtsam.CustomFactor(noise, keys, error_func)


def axis_offsets_residuals(K, arm_T_camera, axis_of, delta, line):
    """The distances at the offsets ``delta`` and their Jacobians (pose, line, offsets): ``axis_of(delta)`` gives
    the (M, 3) test points and their (M, 3, n) derivatives; ``de_i/dP_i = -H_pose[i, 3:] R^T`` (the translation
    block of the pose Jacobian is ``-de_i/dX_i``, X = R^T (P - t))."""
    points, d_points = axis_of(delta)
    e, H_pose, H_line = axis_point_residuals(K, arm_T_camera, points, line)
    de_dP = -H_pose[:, 3:] @ arm_T_camera.rotation().matrix().T          # (M, 3)
    return e, H_pose, H_line, np.einsum("mi,min->mn", de_dP, d_points)


def make_axis_offsets_to_line_factor(noise, pose_key: int, offsets_key: int, axis_of, line, K) -> gtsam.CustomFactor:
    """Distances of projected FK axis test points to a measured image line, the FK axis depending on joint offsets.

    Args:
        noise: gtsam noise model of dimension M.
        pose_key: key of the ``gtsam.Pose3`` ``arm_T_camera``.
        offsets_key: key of the joint offsets (a ``numpy`` vector of n radians, the reading plus the offset is the
            joint's angle).
        axis_of: ``delta -> (points (M, 3), d_points (M, 3, n))``: the test points (arm frame) at those offsets
            and their derivatives (e.g. from :meth:`gtsam_rotid.arm.Arm.wrist_axis_offset_derivatives`).
        line: (3,) measured homogeneous image line; normalised here.
        K: (3, 3) intrinsic matrix.

    Returns:
        ``gtsam.CustomFactor`` with Jacobians (M, 6) wrt the Pose3 tangent and (M, n) wrt the offsets.
    """
    line, K = _frozen_line_and_K(line, K)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        e, H_pose, _, H_offsets = axis_offsets_residuals(K, values.atPose3(keys[0]), axis_of, values.atVector(keys[1]),
                                                     line)
        if H is not None:
            H[0], H[1] = H_pose, H_offsets
        return e

    return gtsam.CustomFactor(noise, [pose_key, offsets_key], error_func)


def make_axis_offsets_to_line_variable_factor(noise, pose_key: int, line_key: int, offsets_key: int, axis_of,
                                              K, intrinsics_key: int | None = None) -> gtsam.CustomFactor:
    """Distances of projected FK axis test points to the image of a Rot3 line variable, the FK axis depending on
    joint offsets (see :func:`make_axis_offsets_to_line_factor` for ``offsets_key`` and ``axis_of``;
    ``intrinsics_key`` as :func:`make_axis_to_line_variable_factor`'s, a fourth Jacobian).

    Returns:
        ``gtsam.CustomFactor`` with Jacobians (M, 6) wrt the Pose3 tangent, (M, 3) wrt the Rot3 tangent and (M, n)
        wrt the offsets.
    """
    K = np.array(K, dtype=float).reshape(3, 3)
    K.setflags(write=False)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        K_now = _intrinsics_of(values, keys, 3, K)
        line_rot = values.atRot3(keys[1])
        line, J_line = image_line_from_rot3(K_now, line_rot)
        e, H_pose, H_l, H_offsets = axis_offsets_residuals(K_now, values.atPose3(keys[0]), axis_of,
                                                       values.atVector(keys[2]), line)
        if H is not None:
            H[0], H[1], H[2] = H_pose, H_l @ J_line, H_offsets
            if len(keys) > 3:
                H[3] = image_line_intrinsics_jacobian(K_now, line_rot, e)
        return e

    keys = [pose_key, line_key, offsets_key] + ([] if intrinsics_key is None else [intrinsics_key])
    return gtsam.CustomFactor(noise, keys, error_func)
