"""Circle-point factor bound to the pose: line_from_pose, zero residual at the truth, Jacobians."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import assert_jacobians_match, values_with
from gtsam.symbol_shorthand import C, T
from gtsam.utils.numerical_derivative import numericalDerivative11

from gtsam_rotid.factors import FKAxis, line_from_pose, make_pose_circle_point_factor, rot3_from_line


def test_line_from_pose_matches_rot3_from_line(scene):
    R, _ = line_from_pose(scene.arm_T_camera, scene.axis_point_arm, scene.axis_direction_arm)
    expected, _ = rot3_from_line(*scene.axis_in_camera())
    np.testing.assert_allclose(R, expected.matrix(), atol=1e-12)


@pytest.mark.parametrize("trial", range(4))
def test_line_from_pose_jacobian_matches_numerical(scene, trial):
    rng = np.random.default_rng(300 + trial)
    pose = scene.arm_T_camera.retract(np.concatenate([rng.normal(scale=0.1, size=3), rng.normal(scale=0.05, size=3)]))
    R, J = line_from_pose(pose, scene.axis_point_arm, scene.axis_direction_arm)

    def omega(p):  # the line's tangent at R, as a function of the pose
        return gtsam.Rot3(R).localCoordinates(gtsam.Rot3(line_from_pose(p, scene.axis_point_arm,
                                                                        scene.axis_direction_arm)[0]))

    np.testing.assert_allclose(J, numericalDerivative11(omega, pose, 1e-6), atol=1e-7)


def track(scene, j, phases):
    return scene.pixels(scene.circle_points_arm(j, phases))


def test_zero_at_the_truth_and_signed_off_it(scene):
    _, circles = scene.unit_circles()
    for j in range(len(circles)):
        pixels = track(scene, j, np.linspace(0.2, 2.5, 40))
        factor = make_pose_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(40, 1.0), T(0), C(j), pixels,
                                               scene.K, (scene.axis_point_arm, scene.axis_direction_arm))
        values = values_with([(T(0), scene.arm_T_camera), (C(j), circles[j])])
        np.testing.assert_allclose(factor.unwhitenedError(values), 0.0, atol=1e-8)
        bigger = values_with([(T(0), scene.arm_T_camera), (C(j), circles[j] * [1.0, 1.2])])
        assert np.all(factor.unwhitenedError(bigger) < 0.0)  # observed pixels now inside the projected circle


@pytest.mark.parametrize("trial", range(5))
def test_jacobians_match_numerical(scene, trial):
    rng = np.random.default_rng(400 + trial)
    _, circles = scene.unit_circles()
    j = trial % len(circles)
    pixels = track(scene, j, np.sort(rng.uniform(-1.0, 2.0, 30))) + rng.normal(scale=0.7, size=(30, 2))
    axis = FKAxis(scene.axis_point_arm, scene.axis_direction_arm)  # shared cache: results must not depend on it
    factor = make_pose_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(30, 1.5), T(0), C(j), pixels, scene.K,
                                           axis)
    pose = scene.arm_T_camera.retract(np.concatenate([rng.normal(scale=0.03, size=3), rng.normal(scale=0.02, size=3)]))
    circle = circles[j] * (1.0 + rng.normal(scale=0.05, size=2))
    assert_jacobians_match(factor, [(T(0), pose), (C(j), circle)])


def test_noise_dimension_is_checked(scene):
    with pytest.raises(ValueError, match="dimension 3 but the track has 5 pixels"):
        make_pose_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(3, 1.0), T(0), C(0), np.zeros((5, 2)),
                                      scene.K, (scene.axis_point_arm, scene.axis_direction_arm))
