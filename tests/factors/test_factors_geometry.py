"""Pure geometry of factors/: projection, line variables, projected circles, closest phases."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import K_NOMINAL, random_line_rot3, unit
from gtsam.utils.numerical_derivative import numericalDerivative11

from gtsam_rotid.factors import (
    circle_point_residuals,
    circle_points,
    closest_phases,
    image_line_from_rot3,
    line_distance_covariance,
    line_distances,
    line_points,
    project,
    projected_circle,
    rot3_from_line,
    transform_to_camera,
)

K_SKEW = np.array([[560.0, 1.5, 330.0], [0.0, 580.0, 250.0], [0.0, 0.0, 1.0]])


def wrapped(angle):
    return np.mod(np.asarray(angle) + np.pi, 2.0 * np.pi) - np.pi


@pytest.mark.parametrize("K", [K_NOMINAL, K_SKEW])
def test_project_jacobian_matches_numerical(K, rng):
    X = np.column_stack([rng.uniform(-0.5, 0.5, 5), rng.uniform(-0.5, 0.5, 5), rng.uniform(0.6, 2.0, 5)])
    u, J = project(K, X)
    np.testing.assert_allclose(u, (X @ K.T)[:, :2] / X[:, 2:], rtol=1e-12)
    for i in range(len(X)):
        J_num = numericalDerivative11(lambda x: project(K, x)[0], X[i], 1e-6)
        np.testing.assert_allclose(J[i], J_num, rtol=1e-6, atol=1e-6)


def test_circle_points_lie_on_the_coaxial_circle(rng):
    R = random_line_rot3(rng)
    c0, c1, c2 = R.matrix().T
    d, r = 0.3, 0.05
    phi = rng.uniform(-np.pi, np.pi, 20)
    X = circle_points(R, d, r, phi)
    centre = c0 + d * c1
    np.testing.assert_allclose(np.linalg.norm(X - centre, axis=1), r, rtol=1e-12)
    np.testing.assert_allclose((X - centre) @ c1, 0.0, atol=1e-14)
    np.testing.assert_allclose(X[0], centre + r * (np.cos(phi[0]) * c2 + np.sin(phi[0]) * c0), atol=1e-14)
    np.testing.assert_allclose(line_points(R, [0.0, d]), [c0, centre], atol=1e-15)


@pytest.mark.parametrize("K", [K_NOMINAL, K_SKEW])
def test_image_line_contains_projected_line_points(K, rng):
    for _ in range(5):
        R = random_line_rot3(rng)
        line, _ = image_line_from_rot3(K, R)
        assert np.hypot(line[0], line[1]) == pytest.approx(1.0, abs=1e-14)
        # Sign convention: l is a positive multiple of K^-T c2.
        m = np.linalg.solve(K.T, R.matrix()[:, 2])
        assert np.allclose(np.cross(line, m), 0.0, atol=1e-12) and line @ m > 0
        X = line_points(R, np.linspace(-0.5, 0.5, 11))
        u, _ = project(K, X)
        np.testing.assert_allclose(line_distances(line, u), 0.0, atol=1e-9)


@pytest.mark.parametrize("K", [K_NOMINAL, K_SKEW])
def test_image_line_jacobian_matches_numerical(K, rng):
    for _ in range(5):
        R = random_line_rot3(rng)
        _, J = image_line_from_rot3(K, R)
        J_num = numericalDerivative11(lambda rot: image_line_from_rot3(K, rot)[0], R, 1e-6)
        np.testing.assert_allclose(J, J_num, rtol=1e-6, atol=1e-9)


def test_projected_circle_derivatives_match_numerical(rng):
    R = random_line_rot3(rng)
    phi = rng.uniform(-np.pi, np.pi, 7)
    u, du, ddu = projected_circle(K_SKEW, R, -0.4, 0.06, phi)
    np.testing.assert_allclose(u, project(K_SKEW, circle_points(R, -0.4, 0.06, phi))[0], rtol=1e-12)
    h = 1e-5
    for value, derivative, k in ((u, du, 0), (du, ddu, 1)):
        plus = projected_circle(K_SKEW, R, -0.4, 0.06, phi + h)[k]
        minus = projected_circle(K_SKEW, R, -0.4, 0.06, phi - h)[k]
        np.testing.assert_allclose(derivative, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-6)
        assert value.shape == derivative.shape == (7, 2)


@pytest.mark.parametrize("d", [0.25, -0.6, 1.0])
def test_closest_phases_recover_noise_free_phases(d, rng):
    for _ in range(4):
        R = random_line_rot3(rng)
        r = rng.uniform(0.03, 0.06)
        phi_true = rng.uniform(-np.pi, np.pi, 200)
        pixels, _ = project(K_NOMINAL, circle_points(R, d, r, phi_true))
        phi = closest_phases(K_NOMINAL, R, d, r, pixels)
        np.testing.assert_allclose(wrapped(phi - phi_true), 0.0, atol=1e-9)
        e, _, _ = circle_point_residuals(K_NOMINAL, R, d, r, pixels, jacobians=False)
        assert np.max(np.abs(e)) < 1e-9


def test_residual_equals_known_perpendicular_offset(rng):
    """Points pushed off the curve along its (independently computed) normal: residual = offset, + outside."""
    for d in (0.3, -0.8):
        R = random_line_rot3(rng)
        r = 0.05
        phi = np.linspace(-np.pi, np.pi, 90, endpoint=False)
        u, _ = project(K_NOMINAL, circle_points(R, d, r, phi))
        h = 1e-6
        tangent = (project(K_NOMINAL, circle_points(R, d, r, phi + h))[0]
                   - project(K_NOMINAL, circle_points(R, d, r, phi - h))[0]) / (2 * h)
        normal = np.column_stack([tangent[:, 1], -tangent[:, 0]]) / np.linalg.norm(tangent, axis=1)[:, None]
        inside_point = u.mean(axis=0)  # the projected circle is a convex ellipse: its centroid is inside
        normal *= np.sign(np.sum(normal * (u - inside_point), axis=1))[:, None]  # outward
        radius_of_curvature = np.min(np.linalg.norm(u - inside_point, axis=1))
        offsets = rng.uniform(-0.3, 0.3, len(phi)) * min(radius_of_curvature, 3.0)
        e, _, _ = circle_point_residuals(K_NOMINAL, R, d, r, u + offsets[:, None] * normal, jacobians=False)
        np.testing.assert_allclose(e, offsets, atol=1e-8)


def test_closest_phase_is_the_global_minimum(rng):
    """Against a dense brute-force search, for pixels scattered around (and inside) the projected circle."""
    R = random_line_rot3(rng)
    d, r = 0.5, 0.05
    dense = np.linspace(-np.pi, np.pi, 200_000, endpoint=False)
    curve, _ = project(K_NOMINAL, circle_points(R, d, r, dense))
    centre = curve.mean(axis=0)
    pixels = centre + (curve[rng.integers(0, len(dense), 300)] - centre) * rng.uniform(0.3, 1.5, (300, 1))
    phi = closest_phases(K_NOMINAL, R, d, r, pixels)
    best = np.min(np.linalg.norm(pixels[:, None, :] - curve[None, ::50, :], axis=-1), axis=1)
    found = np.linalg.norm(project(K_NOMINAL, circle_points(R, d, r, phi))[0] - pixels, axis=1)
    assert np.all(found <= best + 1e-9)


def test_rot3_from_line_gauges_and_scale(rng):
    direction = unit(rng.normal(size=3))
    foot = unit(np.cross(direction, rng.normal(size=3))) * 1.7
    point = foot + 0.4 * direction
    R, distance = rot3_from_line(point, 3.0 * direction)
    c0, c1, c2 = R.matrix().T
    assert distance == pytest.approx(1.7)
    np.testing.assert_allclose(c0 * distance, foot, atol=1e-12)
    np.testing.assert_allclose(c1, direction, atol=1e-12)
    np.testing.assert_allclose(c2, np.cross(c0, c1), atol=1e-12)
    assert np.linalg.det(R.matrix()) == pytest.approx(1.0)
    # Metric circle about the line -> unit-scale (d, r): same camera-frame points divided by the distance.
    d_metric, r_metric = 0.1, 0.05
    d_unit, r_unit = (d_metric + point @ c1) / distance, r_metric / distance
    X_unit = circle_points(R, d_unit, r_unit, np.linspace(0, 6, 7))
    centre_metric = point + d_metric * direction
    np.testing.assert_allclose(np.linalg.norm(X_unit * distance - centre_metric, axis=1), r_metric, atol=1e-12)
    np.testing.assert_allclose((X_unit * distance - centre_metric) @ direction, 0.0, atol=1e-12)
    with pytest.raises(ValueError):
        rot3_from_line([0.0, 0.0, 2.0], [0.0, 0.0, 1.0])


def test_metric_circles_project_onto_the_unit_scale_circles(scene):
    """A feature circle built in the arm frame and imaged through arm_T_camera matches its unit-scale model."""
    line_cam, circles = scene.unit_circles()
    for j, (d, r) in enumerate(circles):
        pixels = scene.pixels(scene.circle_points_arm(j, np.linspace(-np.pi, np.pi, 50)))
        e, _, _ = circle_point_residuals(scene.K, line_cam, d, r, pixels, jacobians=False)
        assert np.max(np.abs(e)) < 1e-9


def test_transform_to_camera_matches_gtsam(rng):
    arm_T_camera = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    points = rng.normal(size=(4, 3))
    X, J = transform_to_camera(arm_T_camera, points)
    for i, p in enumerate(points):
        H_pose, H_point = np.zeros((3, 6), order="F"), np.zeros((3, 3), order="F")
        np.testing.assert_allclose(X[i], arm_T_camera.transformTo(p, H_pose, H_point), atol=1e-12)
        np.testing.assert_allclose(J[i], H_pose, atol=1e-12)


def test_line_distance_covariance_is_first_order_exact(rng):
    """Distances are linear in the line: sampled covariance matches A Sigma A^T."""
    A_half = rng.normal(size=(3, 3)) * np.array([1e-3, 1e-3, 0.5])
    line_cov = A_half @ A_half.T
    pixels = rng.uniform(0, 640, (3, 2))
    cov = line_distance_covariance(line_cov, pixels)
    line = unit([0.6, -0.8, 0.0]) + np.array([0.0, 0.0, -100.0])
    samples = rng.multivariate_normal(np.zeros(3), line_cov, 20000)
    distances = line_distances(line, pixels)[None, :] + samples @ np.column_stack([pixels, np.ones(3)]).T
    np.testing.assert_allclose(line_distances(line + samples[0], pixels), distances[0], atol=1e-9)
    np.testing.assert_allclose(np.cov(distances.T), cov, rtol=0.05, atol=0.02 * np.max(cov))
    assert cov.shape == (3, 3) and np.allclose(cov, cov.T)
