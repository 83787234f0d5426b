"""CircleTrack (the fast, warm-started circle-point maths): same results as the original implementation, with and
without the warm start, on eccentric (nearly edge-on) circles too; its certificates against brute force."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import reference_circle as reference
from factor_scene import K_NOMINAL, random_line_rot3, values_with
from gtsam.symbol_shorthand import C, L

from gtsam_rotid.factors import (
    CircleTrack,
    circle_point_residuals,
    circle_points,
    closest_phases,
    make_circle_point_factor,
    project,
    projected_circle,
)
from gtsam_rotid.factors.ellipse import _Ellipse

K_SKEW = np.array([[560.0, 1.5, 330.0], [0.0, 580.0, 250.0], [0.0, 0.0, 1.0]])
DENSE = np.linspace(-np.pi, np.pi, 100_000, endpoint=False)


def curve(K, R, d, r, phases=DENSE) -> np.ndarray:
    return project(K, circle_points(R, d, r, phases))[0]


def axis_ratio(K, R, d, r) -> float:
    """Minor/major axis ratio of the projected circle, from its widths over many directions (2b and 2a)."""
    points = curve(K, R, d, r, DENSE[::50])
    angles = np.linspace(0.0, np.pi, 720, endpoint=False)
    widths = np.ptp(points @ np.stack([np.cos(angles), np.sin(angles)]), axis=0)
    return float(widths.min() / widths.max())


def eccentric_circle(rng, ratio: float, K=K_NOMINAL):
    """A line variable and (d, r) whose projected circle has about the given minor/major axis ratio.

    A circle's plane contains the camera centre when d = 0 (edge-on view); the ratio grows with |d|.
    """
    while True:
        R = random_line_rot3(rng, min_forward=0.85)
        r = rng.uniform(0.04, 0.07)
        sign = rng.choice([-1.0, 1.0])
        low, high = 1e-3, 1.0
        if axis_ratio(K, R, sign * high, r) < ratio:
            continue
        for _ in range(40):  # bisection on |d|
            mid = 0.5 * (low + high)
            low, high = (mid, high) if axis_ratio(K, R, sign * mid, r) < ratio else (low, mid)
        d = sign * 0.5 * (low + high)
        if abs(axis_ratio(K, R, d, r) - ratio) < 0.02:
            return R.matrix(), d, r


def scattered_pixels(K, R, d, r, rng, n: int, spread: float = 3.0) -> np.ndarray:
    """Noisy curve pixels (normal noise of ``spread`` px) plus pixels scattered inside the curve."""
    near = curve(K, R, d, r, rng.uniform(-np.pi, np.pi, n)) + spread * rng.standard_normal((n, 2))
    points = curve(K, R, d, r, DENSE[::100])
    centre = 0.5 * (points.max(axis=0) + points.min(axis=0))
    inside = centre + (points[rng.integers(0, len(points), n)] - centre) * rng.uniform(0.0, 1.0, (n, 1))
    return np.vstack([near, inside])


def brute_force_distance(K, R, d, r, pixels) -> np.ndarray:
    """Distance to the nearest of 20 000 curve samples: never below the true distance, ~1e-4 px above it."""
    points = curve(K, R, d, r, DENSE[::5])
    best = np.empty(len(pixels))
    for start in range(0, len(pixels), 64):  # chunks keep the distance matrix small
        chunk = pixels[start:start + 64]
        best[start:start + 64] = np.sqrt(np.min(np.sum((chunk[:, None, :] - points[None]) ** 2, axis=-1), axis=1))
    return best


def random_configuration(rng, K):
    R = random_line_rot3(rng).matrix()
    d = rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 1.2)
    r = rng.choice([-1.0, 1.0]) * rng.uniform(0.02, 0.08)
    return R, d, r


def perturb(R, d, r, rng, scale):
    R_new = gtsam.Rot3(R).retract(rng.normal(scale=scale, size=3)).matrix()
    return R_new, d + scale * abs(r) * rng.normal(), r * (1.0 + scale * rng.normal())


def assert_same(result, expected, jacobian_rtol: float = 1e-6) -> None:
    e, H_line, H_circle = result
    e_ref, H_line_ref, H_circle_ref = expected
    np.testing.assert_allclose(e, e_ref, rtol=0, atol=1e-9)
    scale = max(1.0, float(np.max(np.abs(H_line_ref))))
    np.testing.assert_allclose(H_line, H_line_ref, rtol=0, atol=jacobian_rtol * scale)
    np.testing.assert_allclose(H_circle, H_circle_ref, rtol=0, atol=jacobian_rtol * scale)


# ----------------------------------------------------------------------------------------------------------------
# Same results as the original implementation
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("K", [K_NOMINAL, K_SKEW])
def test_matches_the_original_implementation(K, rng):
    for _ in range(12):
        R, d, r = random_configuration(rng, K)
        pixels = curve(K, R, d, r, rng.uniform(-np.pi, np.pi, 80)) + 1.5 * rng.standard_normal((80, 2))
        assert_same(circle_point_residuals(K, R, d, r, pixels), reference.circle_point_residuals(K, R, d, r, pixels))
        phases = closest_phases(K, R, d, r, pixels)
        phases_ref = reference.closest_phases(K, R, d, r, pixels)
        np.testing.assert_allclose(np.angle(np.exp(1j * (phases - phases_ref))), 0.0, atol=1e-9)


def test_projected_circle_matches_the_original_implementation(rng):
    for _ in range(5):
        R, d, r = random_configuration(rng, K_SKEW)
        phi = rng.uniform(-np.pi, np.pi, 9)
        expected = reference.projected_circle(K_SKEW, R, d, r, phi)
        for new, old in zip(projected_circle(K_SKEW, R, d, r, phi), expected, strict=True):
            np.testing.assert_allclose(new, old, rtol=1e-12, atol=1e-9)


# ----------------------------------------------------------------------------------------------------------------
# Warm start: results independent of the call history
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 3e-2, 0.3])
def test_warm_start_gives_the_fresh_result(scale, rng):
    """A warm-started track evaluated along a random walk (steps of ``scale``) equals a fresh evaluation."""
    for _ in range(3):
        R, d, r = random_configuration(rng, K_NOMINAL)
        pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 60, spread=2.0)
        track = CircleTrack(K_NOMINAL, pixels)
        for _ in range(6):
            candidate = perturb(R, d, r, rng, scale)
            if gtsam.Rot3(candidate[0]).matrix()[2, 0] < 0.6:  # keep the circle in front of the camera
                continue
            R, d, r = candidate
            fresh = CircleTrack(K_NOMINAL, pixels, warm_start=False).evaluate(R, d, r)
            assert_same(track.evaluate(R, d, r), fresh)
            assert_same(track.evaluate(R, d, r), fresh)  # exact repeat: the cached result


def test_warm_start_survives_jumps(rng):
    """Alternating between far-apart variables (other side of the curve, r -> -r, other d) changes nothing."""
    R, d, r = random_configuration(rng, K_NOMINAL)
    pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 80, spread=2.0)
    R2 = gtsam.Rot3(R).retract(np.array([0.0, 0.0, 0.02])).matrix()
    points = [(R, d, r), (R, d, -r), (R2, 1.3 * d, 1.2 * r), (R, -d, r), (R2, d, r), (R, d, r)]
    track = CircleTrack(K_NOMINAL, pixels)
    for R_k, d_k, r_k in points + points[::-1]:
        assert_same(track.evaluate(R_k, d_k, r_k), reference.circle_point_residuals(K_NOMINAL, R_k, d_k, r_k, pixels))


def test_factor_with_and_without_warm_start_agree(rng):
    """Through GTSAM: errors and linearisations of the warm-started and the fresh factor, along random values."""
    R, d, r = random_configuration(rng, K_NOMINAL)
    pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 50, spread=1.5)
    noise = gtsam.noiseModel.Isotropic.Sigma(len(pixels), 0.8)
    warm = make_circle_point_factor(noise, L(0), C(1), pixels, K_NOMINAL)
    cold = make_circle_point_factor(noise, L(0), C(1), pixels, K_NOMINAL, warm_start=False)
    for scale in (1e-4, 1e-2, 1e-1, 1e-4):
        R_k, d_k, r_k = perturb(R, d, r, rng, scale)
        values = values_with([(L(0), gtsam.Rot3(R_k)), (C(1), np.array([d_k, r_k]))])
        assert warm.error(values) == pytest.approx(cold.error(values), rel=1e-12, abs=1e-12)
        A_warm, b_warm = warm.linearize(values).jacobian()
        A_cold, b_cold = cold.linearize(values).jacobian()
        np.testing.assert_allclose(b_warm, b_cold, atol=1e-9)
        np.testing.assert_allclose(A_warm, A_cold, rtol=0, atol=1e-6 * np.max(np.abs(A_cold)))


def test_small_steps_need_no_fallback(rng):
    """Near the previous variables every pixel converges from the warm start in a couple of iterations."""
    R, d, r = random_configuration(rng, K_NOMINAL)
    pixels = curve(K_NOMINAL, R, d, r, rng.uniform(-np.pi, np.pi, 150)) + 1.2 * rng.standard_normal((150, 2))
    track = CircleTrack(K_NOMINAL, pixels)
    track.evaluate(R, d, r)
    cold_before, grid_before = track.cold_points, track.grid_points
    for _ in range(10):
        track.evaluate(*perturb(R, d, r, rng, 1e-4))
    assert (track.cold_points, track.grid_points) == (cold_before, grid_before)


def test_tracks_of_one_and_zero_pixels(rng):
    R, d, r = random_configuration(rng, K_NOMINAL)
    pixel = curve(K_NOMINAL, R, d, r, np.array([0.3])) + np.array([[1.0, -2.0]])
    assert_same(CircleTrack(K_NOMINAL, pixel).evaluate(R, d, r),
                reference.circle_point_residuals(K_NOMINAL, R, d, r, pixel))
    e, H_line, H_circle = CircleTrack(K_NOMINAL, np.zeros((0, 2))).evaluate(R, d, r)
    assert e.shape == (0,) and H_line.shape == (0, 3) and H_circle.shape == (0, 2)
    assert closest_phases(K_NOMINAL, R, d, r, np.zeros((0, 2))).shape == (0,)


# ----------------------------------------------------------------------------------------------------------------
# Eccentric (nearly edge-on) circles: the closest point is the global one
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("ratio", [0.1, 0.2, 0.5])
def test_eccentric_ellipse_closest_point_is_global(ratio, rng):
    for _ in range(2):
        R, d, r = eccentric_circle(rng, ratio)
        pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 150, spread=2.0)
        best = brute_force_distance(K_NOMINAL, R, d, r, pixels)
        fresh = CircleTrack(K_NOMINAL, pixels, warm_start=False)
        e, _, _ = fresh.evaluate(R, d, r)
        np.testing.assert_array_less(np.abs(e), best + 1e-9)  # the samples over-estimate the distance
        # ... and the same after a warm start from other variables (across the ellipse: r -> -r, and moved).
        track = CircleTrack(K_NOMINAL, pixels)
        track.evaluate(R, d, -r)
        track.evaluate(*perturb(R, d, r, rng, 0.05))
        assert_same(track.evaluate(R, d, r), fresh.evaluate(R, d, r))
        # Noise-free pixels: the phases come back exactly, even edge-on.
        phases = rng.uniform(-np.pi, np.pi, 100)
        found = closest_phases(K_NOMINAL, R, d, r, curve(K_NOMINAL, R, d, r, phases))
        np.testing.assert_allclose(np.angle(np.exp(1j * (found - phases))), 0.0, atol=1e-8)


def test_the_original_grid_search_misses_the_global_minimum_edge_on(rng):
    """Why the certificates and the bracketed search matter: on a ratio-0.1 ellipse the original search (nearest of
    72 phases, then Newton) sometimes ends in the other local minimum for pixels inside the curve; the new one never
    does."""
    R, d, r = eccentric_circle(rng, 0.1)
    pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 400, spread=1.0)
    best = brute_force_distance(K_NOMINAL, R, d, r, pixels)
    original = reference.closest_phases(K_NOMINAL, R, d, r, pixels)
    original_distance = np.linalg.norm(curve(K_NOMINAL, R, d, r, original) - pixels, axis=1)
    e, _, _ = circle_point_residuals(K_NOMINAL, R, d, r, pixels)
    assert np.any(original_distance > best + 1e-2)
    np.testing.assert_array_less(np.abs(e), best + 1e-9)


# ----------------------------------------------------------------------------------------------------------------
# The certificates
# ----------------------------------------------------------------------------------------------------------------


def _ellipse(K, R, d, r) -> _Ellipse:
    track = CircleTrack(K, np.zeros((1, 2)))
    return track._coefficients(np.asarray(R, dtype=float), float(d), float(r))[3]


@pytest.mark.parametrize("ratio", [0.1, 0.3, 0.8])
def test_smallest_radius_of_curvature(ratio, rng):
    """rho_min = b^2 / a of the image conic equals the smallest radius of curvature of the dense projected curve."""
    R, d, r = eccentric_circle(rng, ratio, K=K_SKEW)
    phases = DENSE[::10]
    h = 1e-4
    u = curve(K_SKEW, R, d, r, phases)
    du = (curve(K_SKEW, R, d, r, phases + h) - curve(K_SKEW, R, d, r, phases - h)) / (2 * h)
    ddu = (curve(K_SKEW, R, d, r, phases + h) - 2 * u + curve(K_SKEW, R, d, r, phases - h)) / h**2
    radius = np.linalg.norm(du, axis=1) ** 3 / np.abs(du[:, 0] * ddu[:, 1] - du[:, 1] * ddu[:, 0])
    ellipse = _ellipse(K_SKEW, R, d, r)
    assert ellipse.valid
    assert ellipse.rho_min == pytest.approx(radius.min(), rel=1e-4)


def test_same_quadrant_certificate(rng):
    """A stationary point of the distance in the pixel's quadrant of the ellipse's axes is the global minimum, and
    the global minimum is always in the pixel's quadrant (brute force over all stationary points)."""
    R, d, r = eccentric_circle(rng, 0.25)
    ellipse = _ellipse(K_NOMINAL, R, d, r)
    pixels = scattered_pixels(K_NOMINAL, R, d, r, rng, 100, spread=6.0)
    phases = DENSE[::20]
    u = curve(K_NOMINAL, R, d, r, phases)
    y = circle_points(R, d, r, phases) @ K_NOMINAL.T
    checked = 0
    for pixel in pixels:
        dist = np.linalg.norm(u - pixel, axis=1)
        minima = np.flatnonzero((dist < np.roll(dist, 1)) & (dist < np.roll(dist, -1)))
        same = ellipse.same_quadrant(np.full(len(minima), pixel[0]), np.full(len(minima), pixel[1]),
                                     y[minima, 0], y[minima, 1], y[minima, 2])
        global_min = minima[np.argmin(dist[minima])]
        assert same[minima == global_min].all()
        assert np.all(dist[minima[same]] <= dist[global_min] + 1e-6)
        checked += len(minima) > 1
    assert checked > 0  # some pixels have two local minima
