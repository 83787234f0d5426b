"""Circle-point factor: Jacobians, zero residual on the curve, LM recovery, robust noise models."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import assert_jacobians_match, random_line_rot3, values_with
from gtsam.symbol_shorthand import C, L

from gtsam_rotid.factors import circle_points, make_circle_point_factor, project


def track_pixels(K, line_cam, d, r, n, rng, sigma=0.0):
    phases = rng.uniform(-np.pi, np.pi, n)
    pixels, _ = project(K, circle_points(line_cam, d, r, phases))
    return pixels + sigma * rng.standard_normal(pixels.shape)


@pytest.mark.parametrize("trial", range(6))
def test_jacobians_match_numerical(trial, scene):
    rng = np.random.default_rng(trial)
    line_cam = random_line_rot3(rng)
    d = rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.8)
    r = rng.uniform(0.03, 0.06)
    pixels = track_pixels(scene.K, line_cam, d, r, 40, rng, sigma=1.0)
    factor = make_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(40, 0.7), L(0), C(3), pixels, scene.K)
    # Evaluate away from the truth too: the observed pixels are then far from the curve.
    for line_value, circle_value in (
        (line_cam, np.array([d, r])),
        (line_cam.retract(rng.normal(scale=0.02, size=3)), np.array([d + 0.02, r * 1.1])),
    ):
        assert_jacobians_match(factor, [(L(0), line_value), (C(3), circle_value)])


def test_residual_is_zero_on_the_curve_and_whitened_by_noise(scene):
    line_cam, circles = scene.unit_circles()
    rng = np.random.default_rng(5)
    d, r = circles[2]
    pixels = track_pixels(scene.K, line_cam, d, r, 30, rng)
    factor = make_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(30, 0.5), L(1), C(2), pixels, scene.K)
    values = values_with([(L(1), line_cam), (C(2), np.array([d, r]))])
    e = factor.unwhitenedError(values)
    assert e.shape == (30,) and np.max(np.abs(e)) < 1e-9
    shifted = values_with([(L(1), line_cam), (C(2), np.array([d, r * 1.05]))])
    e_shifted = factor.unwhitenedError(shifted)
    assert factor.error(shifted) == pytest.approx(0.5 * np.sum((e_shifted / 0.5) ** 2))


def test_noise_dimension_must_match_the_track(scene):
    with pytest.raises(ValueError, match="dimension"):
        make_circle_point_factor(gtsam.noiseModel.Isotropic.Sigma(3, 1.0), L(0), C(0), np.zeros((4, 2)), scene.K)


def build_graph(scene, tracks, noise_for):
    graph = gtsam.NonlinearFactorGraph()
    for j, pixels in enumerate(tracks):
        graph.add(make_circle_point_factor(noise_for(len(pixels)), L(0), C(j), pixels, scene.K))
    return graph


def perturbed_start(line_cam, circles, rng):
    initial = gtsam.Values()
    initial.insert(L(0), line_cam.retract(rng.normal(scale=0.03, size=3)))
    for j, (d, r) in enumerate(circles):
        initial.insert(C(j), np.array([d + rng.normal(scale=0.03), r * (1.0 + rng.normal(scale=0.1))]))
    return initial


def lm_params() -> gtsam.LevenbergMarquardtParams:
    """Pixel-scale Jacobians give Hessians ~1e8: GTSAM's default lambda ceiling (1e5) gives up too early."""
    params = gtsam.LevenbergMarquardtParams()
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(1e15)
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-20)
    return params


def rotation_error(a: gtsam.Rot3, b: gtsam.Rot3) -> float:
    return float(np.linalg.norm(a.localCoordinates(b)))


def test_lm_recovers_noise_free_measurement(scene):
    """One noise-free measurement, 4 tracks, circle factors only: LM returns to the truth; Marginals is posed."""
    rng = np.random.default_rng(11)
    line_cam, circles = scene.unit_circles()
    tracks = [track_pixels(scene.K, line_cam, d, r, 60, rng) for d, r in circles]
    graph = build_graph(scene, tracks, lambda n: gtsam.noiseModel.Isotropic.Sigma(n, 1.0))
    initial = perturbed_start(line_cam, circles, rng)
    assert graph.error(initial) > 1.0
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params()).optimize()
    assert graph.error(result) < 1e-14
    assert rotation_error(result.atRot3(L(0)), line_cam) < 1e-7
    for j, (d, r) in enumerate(circles):
        d_hat, r_hat = result.atVector(C(j))
        # (d, r) and (d, -r) are the same circle (phase shifted by pi): compare |r|.
        np.testing.assert_allclose([d_hat, abs(r_hat)], [d, r], atol=1e-7)
    marginals = gtsam.Marginals(graph, result)
    cov = marginals.marginalCovariance(L(0))
    assert cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(cov) > 0)


def test_robust_noise_model_downweights_a_bad_track(scene):
    """GTSAM's Robust loss acts on a factor's whole Mahalanobis norm, so here it rejects whole tracks.

    Four good tracks plus one track shifted by ~18 px (a wrong association): with a Cauchy kernel the line comes
    back to the truth, with a plain Gaussian model it is pulled away.
    """
    rng = np.random.default_rng(12)
    line_cam, circles = scene.unit_circles()
    tracks = [track_pixels(scene.K, line_cam, d, r, 60, rng, sigma=0.1) for d, r in circles]
    tracks.append(track_pixels(scene.K, line_cam, *circles[1], 60, rng, sigma=0.1) + np.array([15.0, -10.0]))
    circles = np.vstack([circles, circles[1]])
    initial = perturbed_start(line_cam, circles, rng)

    def robust(n):
        return gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(3.0 * np.sqrt(n)), gtsam.noiseModel.Isotropic.Sigma(n, 0.1)
        )

    robust_graph = build_graph(scene, tracks, robust)
    gaussian_graph = build_graph(scene, tracks, lambda n: gtsam.noiseModel.Isotropic.Sigma(n, 0.1))
    bad_robust, bad_gaussian = robust_graph.at(4), gaussian_graph.at(4)
    assert bad_robust.error(initial) < 0.01 * bad_gaussian.error(initial)
    np.testing.assert_allclose(bad_robust.unwhitenedError(initial), bad_gaussian.unwhitenedError(initial))
    assert bad_robust.linearize(initial).rows() == len(tracks[4])

    robust_result = gtsam.LevenbergMarquardtOptimizer(robust_graph, initial, lm_params()).optimize()
    gaussian_result = gtsam.LevenbergMarquardtOptimizer(gaussian_graph, initial, lm_params()).optimize()
    robust_error = rotation_error(robust_result.atRot3(L(0)), line_cam)
    gaussian_error = rotation_error(gaussian_result.atRot3(L(0)), line_cam)
    print(f"line rotation error: robust {robust_error:.2e} rad, Gaussian {gaussian_error:.2e} rad")
    assert robust_error < 0.2 * gaussian_error
