"""Projected-axis distance factors: zero at the truth, Jacobians, distance covariance, tiny pose solve."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import assert_jacobians_match, unit, values_with
from gtsam.symbol_shorthand import L, T

from gtsam_rotid.factors import (
    image_line_from_rot3,
    line_distance_covariance,
    make_axis_to_line_factor,
    make_axis_to_line_variable_factor,
    project,
    rot3_from_line,
)


def axis_test_points(scene, offsets=(-0.05, 0.15)) -> np.ndarray:
    """FK-style test points on the wrist axis, arm frame: (M, 3)."""
    return scene.axis_point_arm + np.outer(offsets, scene.axis_direction_arm)


def random_pose_near(arm_T_camera, rng) -> gtsam.Pose3:
    """A random Pose3 close enough to the truth to keep the wrist test points in front of the camera."""
    return arm_T_camera.retract(np.concatenate([rng.normal(scale=0.1, size=3), rng.normal(scale=0.05, size=3)]))


def test_distances_are_zero_at_the_truth(scene):
    line_cam, _ = scene.unit_circles()
    measured_line, _ = image_line_from_rot3(scene.K, line_cam)
    points_arm = axis_test_points(scene, (-0.1, 0.0, 0.1, 0.25))
    noise = gtsam.noiseModel.Isotropic.Sigma(4, 1.0)
    fixed = make_axis_to_line_factor(noise, T(0), points_arm, 7.0 * measured_line, scene.K)
    variable = make_axis_to_line_variable_factor(noise, T(0), L(0), points_arm, scene.K)
    values = values_with([(T(0), scene.arm_T_camera), (L(0), line_cam)])
    np.testing.assert_allclose(fixed.unwhitenedError(values), 0.0, atol=1e-9)
    np.testing.assert_allclose(variable.unwhitenedError(values), 0.0, atol=1e-9)
    # ...and the measured line itself is the one through the independently projected test points.
    pixels = scene.pixels(points_arm)
    np.testing.assert_allclose(pixels @ measured_line[:2] + measured_line[2], 0.0, atol=1e-9)
    # Off the truth the distances are signed pixels.
    moved = values_with([(T(0), scene.arm_T_camera.retract(np.array([0, 0, 0, 0.01, 0, 0]))), (L(0), line_cam)])
    assert np.max(np.abs(fixed.unwhitenedError(moved))) > 1.0


@pytest.mark.parametrize("trial", range(5))
def test_fixed_line_jacobian_matches_numerical(trial, scene):
    rng = np.random.default_rng(100 + trial)
    line_cam, _ = scene.unit_circles()
    measured_line, _ = image_line_from_rot3(scene.K, line_cam.retract(rng.normal(scale=0.05, size=3)))
    factor = make_axis_to_line_factor(
        gtsam.noiseModel.Isotropic.Sigma(3, 2.0), T(0), axis_test_points(scene, (-0.1, 0.05, 0.2)), measured_line,
        scene.K,
    )
    assert_jacobians_match(factor, [(T(0), random_pose_near(scene.arm_T_camera, rng))])


@pytest.mark.parametrize("trial", range(5))
def test_variable_line_jacobians_match_numerical(trial, scene):
    rng = np.random.default_rng(200 + trial)
    line_cam, _ = scene.unit_circles()
    factor = make_axis_to_line_variable_factor(
        gtsam.noiseModel.Isotropic.Sigma(2, 1.0), T(0), L(4), axis_test_points(scene), scene.K
    )
    assert_jacobians_match(factor, [
        (T(0), random_pose_near(scene.arm_T_camera, rng)),
        (L(4), line_cam.retract(rng.normal(scale=0.1, size=3))),
    ])


def test_line_distance_covariance_matches_the_line_variable_jacobian(scene):
    """Sigma_d from a Rot3 line covariance equals H_line Sigma_R H_line^T of the variable-line factor."""
    rng = np.random.default_rng(3)
    line_cam, _ = scene.unit_circles()
    points_arm = axis_test_points(scene)
    factor = make_axis_to_line_variable_factor(gtsam.noiseModel.Unit.Create(2), T(0), L(0), points_arm, scene.K)
    values = values_with([(T(0), scene.arm_T_camera), (L(0), line_cam)])
    A, _ = factor.linearize(values).jacobianUnweighted()
    H_line = A[:, 6:]
    half = rng.normal(scale=1e-3, size=(3, 3))
    rot_cov = half @ half.T
    _, J_line = image_line_from_rot3(scene.K, line_cam)
    test_pixels, _ = project(scene.K, scene.arm_T_camera.transformTo(points_arm.T).T)
    cov = line_distance_covariance(J_line @ rot_cov @ J_line.T, test_pixels)
    np.testing.assert_allclose(cov, H_line @ rot_cov @ H_line.T, rtol=1e-9, atol=1e-15)
    gtsam.noiseModel.Gaussian.Covariance(cov + 1e-6 * np.eye(2))  # usable as a noise model


def test_factories_validate_their_inputs(scene):
    with pytest.raises(ValueError, match="at least 2"):
        make_axis_to_line_factor(gtsam.noiseModel.Unit.Create(1), T(0), np.zeros((1, 3)), [1, 0, 0], scene.K)
    with pytest.raises(ValueError, match="dimension"):
        make_axis_to_line_variable_factor(gtsam.noiseModel.Unit.Create(3), T(0), L(0), np.zeros((2, 3)), scene.K)


def test_lm_recovers_pose_from_measured_lines(scene):
    """Six wrist axes (not through one point), two test points each: LM on arm_T_camera returns to the truth."""
    rng = np.random.default_rng(8)
    graph = gtsam.NonlinearFactorGraph()
    camera_T_arm = scene.camera_T_arm
    for _ in range(6):
        point_arm = scene.axis_point_arm + rng.normal(scale=0.1, size=3)
        direction_arm = unit(rng.normal(size=3))
        point_cam = camera_T_arm.transformFrom(point_arm)
        line_cam, _ = rot3_from_line(point_cam, camera_T_arm.rotation().matrix() @ direction_arm)
        measured_line, _ = image_line_from_rot3(scene.K, line_cam)
        points_arm = point_arm + np.outer([-0.05, 0.05], direction_arm)
        graph.add(make_axis_to_line_factor(gtsam.noiseModel.Isotropic.Sigma(2, 1.0), T(0), points_arm,
                                           measured_line, scene.K))
    initial = gtsam.Values()
    initial.insert(T(0), scene.arm_T_camera.retract(np.array([0.03, -0.02, 0.02, 0.02, 0.03, -0.02])))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-20)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    np.testing.assert_allclose(scene.arm_T_camera.localCoordinates(result.atPose3(T(0))), 0.0, atol=1e-7)


def kinova_axis_of(rng):
    """A Jaco2 pose's ``axis_of`` (test points and their offset derivatives, every joint before the wrist) and the
    camera looking at its wrist from 0.8 m."""
    from gtsam_rotid.arm import Arm
    from gtsam_rotid.geometry import look_at

    arm = Arm.from_robot("kinova")
    angles = arm.random_joint_angles(rng)
    joints = list(range(arm.wrist_index))
    wrist = arm.wrist_axis(angles).point
    camera = look_at(wrist + np.array([0.8, 0.1, 0.3]), wrist, np.array([0.0, 0.0, 1.0]))
    spacing = np.array([0.0, 0.1])

    def axis_of(delta):
        axis, d_point, d_direction = arm.wrist_axis_offset_derivatives(angles, joints, delta)
        return axis.points_at(spacing), d_point[None] + spacing[:, None, None] * d_direction[None]
    return axis_of, camera, len(joints)


@pytest.mark.parametrize("trial", range(3))
def test_offsets_factors_jacobians_match_numerical(trial, scene):
    """Both offset factors (measured line; line variable) against gtsam's numerical derivative, the offsets' block
    too (the FK axis moved by the offsets through the arm's kinematics)."""
    from gtsam.symbol_shorthand import O

    from gtsam_rotid.factors import make_axis_offsets_to_line_factor, make_axis_offsets_to_line_variable_factor

    rng = np.random.default_rng(300 + trial)
    axis_of, arm_T_camera, n = kinova_axis_of(rng)
    delta = np.radians(rng.normal(scale=0.5, size=n))
    pose = arm_T_camera.retract(np.concatenate([rng.normal(scale=0.01, size=3), rng.normal(scale=0.01, size=3)]))
    points, _ = axis_of(delta)
    pixels = scene.K @ np.array([arm_T_camera.transformTo(p) for p in points]).T
    line = np.cross(*(pixels.T / pixels[2][:, None]))  # the image line through the projected test points
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.5)
    fixed = make_axis_offsets_to_line_factor(noise, T(0), O(0), axis_of, line + rng.normal(scale=1e-3, size=3),
                                             scene.K)
    assert_jacobians_match(fixed, [(T(0), pose), (O(0), delta)])
    line_var = gtsam.Rot3.Expmap(rng.normal(scale=0.3, size=3))
    variable = make_axis_offsets_to_line_variable_factor(noise, T(0), L(0), O(0), axis_of, scene.K)
    assert_jacobians_match(variable, [(T(0), pose), (L(0), line_var), (O(0), delta)])
    # at zero offsets they are the exact-kinematics factors
    exact = make_axis_to_line_factor(noise, T(0), axis_of(np.zeros(n))[0], line, scene.K)
    offsets = make_axis_offsets_to_line_factor(noise, T(0), O(0), axis_of, line, scene.K)
    values = values_with([(T(0), pose), (O(0), np.zeros(n))])
    np.testing.assert_allclose(offsets.unwhitenedError(values), exact.unwhitenedError(values), atol=1e-12)


@pytest.mark.parametrize("trial", range(3))
def test_intrinsics_jacobians_match_numerical(trial, scene):
    """The tie factors with the intrinsics as a Cal3_S2 variable (skew too) against gtsam's numerical derivative, and
    their values at the camera's own intrinsics are the fixed-intrinsics factors'."""
    from gtsam.symbol_shorthand import K, O

    from gtsam_rotid.factors import cal3_s2, make_axis_offsets_to_line_variable_factor

    rng = np.random.default_rng(400 + trial)
    line_cam, _ = scene.unit_circles()
    line = line_cam.retract(rng.normal(scale=0.1, size=3))
    pose = random_pose_near(scene.arm_T_camera, rng)
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    intrinsics = cal3_s2(scene.K).retract(np.array([15.0, -8.0, 1.5, 6.0, -4.0]) * rng.uniform(0.5, 1.5))
    factor = make_axis_to_line_variable_factor(noise, T(0), L(4), axis_test_points(scene), scene.K, K(0))
    assert_jacobians_match(factor, [(T(0), pose), (L(4), line), (K(0), intrinsics)])
    fixed = make_axis_to_line_variable_factor(noise, T(0), L(4), axis_test_points(scene), scene.K)
    at_camera = values_with([(T(0), pose), (L(4), line), (K(0), cal3_s2(scene.K))])
    np.testing.assert_allclose(factor.unwhitenedError(at_camera), fixed.unwhitenedError(at_camera), atol=1e-12)

    axis_of, arm_T_camera, n = kinova_axis_of(rng)
    delta = np.radians(rng.normal(scale=0.5, size=n))
    near = arm_T_camera.retract(np.concatenate([rng.normal(scale=0.01, size=3), rng.normal(scale=0.01, size=3)]))
    offsets = make_axis_offsets_to_line_variable_factor(noise, T(0), L(0), O(0), axis_of, scene.K, K(0))
    assert_jacobians_match(offsets, [(T(0), near), (L(0), gtsam.Rot3.Expmap(rng.normal(scale=0.3, size=3))),
                                     (O(0), delta), (K(0), intrinsics)])
