"""CoaxialTracks (all tracks of a measurement at once) and the variable-projection line factor.

Every result is compared with an independent computation: per-track CircleTrack evaluations, numerical derivatives,
Levenberg-Marquardt on the full per-track graph (line + one circle variable and one circle-point factor per track),
its Schur complement, and GTSAM's own robust noise models.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import K_NOMINAL, random_line_rot3, values_with
from gtsam.symbol_shorthand import C, L
from gtsam.utils.numerical_derivative import numericalDerivative11

import gtsam_rotid.factors.coaxial as coaxial_module
import gtsam_rotid.factors.coaxial_layout as layout_module
import gtsam_rotid.factors.coaxial_tracks as coaxial_tracks_module
from gtsam_rotid.dataset import Track
from gtsam_rotid.factors import (
    CircleTrack,
    CoaxialTracks,
    circle_points,
    closest_phases,
    make_circle_point_factor,
    make_coaxial_line_factor,
    project,
    rot3_from_line,
)
from gtsam_rotid.graph import chi2_quantile, track_huber
from gtsam_rotid.simulate import reference_scene

K_SKEW = np.array([[560.0, 1.5, 330.0], [0.0, 580.0, 250.0], [0.0, 0.0, 1.0]])
SIGMA = 1.2


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------


def curve(K, R, d, r, phases) -> np.ndarray:
    return project(K, circle_points(R, d, r, phases))[0]


def random_tracks(rng, K, R, lengths, spread=1.5):
    """Random circles (d, r) about the line R and noisy arcs of them, plus pixels scattered inside some curves."""
    m = len(lengths)
    d = rng.choice([-1.0, 1.0], m) * rng.uniform(0.05, 1.2, m)
    r = rng.choice([-1.0, 1.0], m) * rng.uniform(0.02, 0.08, m)
    tracks = []
    for j, n in enumerate(lengths):
        start = rng.uniform(-np.pi, np.pi)
        phases = start + np.sort(rng.uniform(0.0, rng.uniform(0.5, 2.0 * np.pi), n))
        pixels = curve(K, R, d[j], r[j], phases) + spread * rng.standard_normal((n, 2))
        if n > 4 and j % 2:  # a few pixels well inside the curve: some need CircleTrack's own search
            centre = curve(K, R, d[j], r[j], np.linspace(-np.pi, np.pi, 64)).mean(axis=0)
            pixels[:3] = centre + 0.3 * (pixels[:3] - centre)
        tracks.append(pixels.reshape(-1, 2))
    return tracks, d, r


def per_track(K, tracks, R, d, r, tol=1e-13):
    """e, H_R, H_dr of one fresh CircleTrack per track (tight phase tolerance), concatenated."""
    results = [CircleTrack(K, pixels, warm_start=False, tol=tol).evaluate(R, d[j], r[j])
               for j, pixels in enumerate(tracks)]
    return tuple(np.concatenate([result[i] for result in results]) for i in range(3))


def assert_same(result, expected, jacobian_rtol=1e-8) -> None:
    e, H_R, H_dr = result
    e_ref, H_R_ref, H_dr_ref = expected
    np.testing.assert_allclose(e, e_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(H_R, H_R_ref, rtol=0, atol=jacobian_rtol * max(1.0, np.abs(H_R_ref).max()))
    np.testing.assert_allclose(H_dr, H_dr_ref, rtol=0, atol=jacobian_rtol * max(1.0, np.abs(H_dr_ref).max()))


def perturb(R, d, r, rng, scale):
    R_new = gtsam.Rot3(R).retract(rng.normal(scale=scale, size=3)).matrix()
    return R_new, d + scale * np.abs(r) * rng.normal(size=len(d)), r * (1.0 + scale * rng.normal(size=len(r)))


class Measurement:
    """One measurement of the reference scene: tracks (ideal pixels), the true line and circles."""

    def __init__(self, K, noisy, exact, line, circles):
        self.K = K
        self.noisy = noisy  # undistorted noisy pixels, one array per track
        self.exact = exact  # noise-free ideal pixels of the same frames
        self.line = line
        self.circles = circles  # (m, 2) true (d, r)


@pytest.fixture(scope="module")
def measurement() -> Measurement:
    dataset, truth = reference_scene(seed=0, duration=20)
    k = 0
    camera, m_truth, m_data = dataset.camera, truth.measurements[0], dataset.measurements[k]
    camera_T_arm = truth.arm_T_camera.inverse()
    point = camera_T_arm.transformFrom(m_truth.axis_point)
    direction = camera_T_arm.rotation().matrix() @ m_truth.axis_direction
    line, distance = rot3_from_line(point, direction)
    c1 = line.matrix()[:, 1]
    circles = np.array([[(t.offset + point @ c1) / distance, t.radius / distance] for t in m_truth.tracks])
    noisy, exact = [], []
    for j, track in enumerate(m_data.tracks):
        track = Track.from_any(track)
        noisy.append(camera.undistort_pixels(track.pixels))
        X = truth.arm_T_camera.transformTo(m_truth.feature_points(j, track.frames).T).T
        y = X @ camera.K.T
        exact.append(y[:, :2] / y[:, 2:])
    return Measurement(camera.K, noisy, exact, line, circles)


def full_graph(tracks, K, sigma=SIGMA, robust=None) -> gtsam.NonlinearFactorGraph:
    """The per-track graph: one circle-point factor per track on (line L0, circle C(j))."""
    graph = gtsam.NonlinearFactorGraph()
    for j, pixels in enumerate(tracks):
        noise = gtsam.noiseModel.Isotropic.Sigma(len(pixels), sigma)
        if robust is not None:
            noise = gtsam.noiseModel.Robust.Create(robust(len(pixels)), noise)
        graph.add(make_circle_point_factor(noise, L(0), C(j), pixels, K))
    return graph


def full_values(line, circles) -> gtsam.Values:
    return values_with([(L(0), line)] + [(C(j), np.asarray(c, dtype=float)) for j, c in enumerate(circles)])


def tight_params(max_iterations=100) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(1e15)
    params.setRelativeErrorTol(1e-15)
    params.setAbsoluteErrorTol(0.0)
    return params


def schur_on_line(graph, values, n_circles):
    """Information (3x3) and gradient of the line after eliminating the circles from the linearised full graph."""
    ordering = gtsam.Ordering()
    for j in range(n_circles):
        ordering.push_back(C(j))
    ordering.push_back(L(0))
    A, b = graph.linearize(values).jacobian(ordering)
    H, g = A.T @ A, A.T @ b
    n = H.shape[0] - 3
    X = np.linalg.solve(H[:n, :n], np.column_stack([H[:n, n:], g[:n]]))
    return H[n:, n:] - H[:n, n:].T @ X[:, :3], g[n:] - H[:n, n:].T @ X[:, 3]


def vp_graph(factor) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factor.factor)
    return graph


def line_values(line) -> gtsam.Values:
    return values_with([(L(0), line)])


# ----------------------------------------------------------------------------------------------------------------
# CoaxialTracks.evaluate: the per-track CircleTrack results, all tracks at once
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("K", [K_NOMINAL, K_SKEW])
def test_evaluate_matches_per_track_circle_tracks(K, rng):
    """Random tracks (lengths 0 to 90, pixels inside the curves too) along a warm-started random walk with jumps."""
    R = random_line_rot3(rng).matrix()
    tracks, d, r = random_tracks(rng, K, R, [1, 7, 40, 0, 90, 55, 12, 33])
    coaxial = CoaxialTracks(K, tracks)
    assert len(coaxial) == sum(len(p) for p in tracks) and coaxial.n_tracks == 8
    points = [(R, d, r)]
    for scale in (1e-4, 1e-3, 1e-2, 1e-4):
        points.append(perturb(*points[-1], rng, scale))
    R2 = gtsam.Rot3(R).retract(np.array([0.0, 0.0, 0.02])).matrix()
    points += [(R, d, -r), (R2, 1.3 * d, 1.2 * r), (R, -d, r), (R, d, r)]  # other side of the curve, far moves
    for R_k, d_k, r_k in points:
        expected = per_track(K, tracks, R_k, d_k, r_k)
        assert_same(coaxial.evaluate(R_k, d_k, r_k), expected)
        assert_same(coaxial.evaluate(gtsam.Rot3(R_k), d_k, r_k), expected)  # cached, and a Rot3 works too
    assert coaxial.fallback_points > 0  # the pixels inside the curves went to CircleTrack's own search
    e, H_R, H_dr = coaxial.evaluate(R, d, r, jacobians=False)
    assert e.shape == (coaxial.n_points,) and H_R is None and H_dr is None


def test_evaluate_matches_on_the_reference_measurement(measurement, rng):
    m = measurement
    coaxial = CoaxialTracks(m.K, m.noisy)
    R, d, r = m.line.matrix(), m.circles[:, 0].copy(), m.circles[:, 1].copy()
    for _ in range(4):
        assert_same(coaxial.evaluate(R, d, r), per_track(m.K, m.noisy, R, d, r))
        R, d, r = perturb(R, d, r, rng, 1e-3)
    phases = coaxial.phases(R, d, r)
    expected = np.concatenate([closest_phases(m.K, R, d[j], r[j], p) for j, p in enumerate(m.noisy)])
    np.testing.assert_allclose(np.angle(np.exp(1j * (phases - expected))), 0.0, atol=1e-9)
    # at the truth the residuals are the pixel noise (variance 1.5 px^2)
    e, _, _ = coaxial.evaluate(m.line, m.circles[:, 0], m.circles[:, 1])
    assert 1.0 < np.sqrt(np.mean(e**2)) < 1.5


def brute_force_distance(K, R, d, r, pixels) -> np.ndarray:
    """Distance to the nearest of 20 000 curve samples: never below the true distance, ~1e-4 px above it."""
    points = curve(K, R, d, r, np.linspace(-np.pi, np.pi, 20_000, endpoint=False))
    return np.array([np.sqrt(np.min(np.sum((points - pixel) ** 2, axis=1))) for pixel in pixels])


def test_circles_partly_behind_the_camera_match_circle_track(rng):
    """Circles so large that part of them lies behind the camera (their image conic is no ellipse: a runaway short
    arc's circle) go through CircleTrack's grid search, all tracks at once: the same phases, residuals and
    Jacobians as one CircleTrack per track, from a cold start and warm after small moves."""
    R = random_line_rot3(rng).matrix()
    tracks, d, r = random_tracks(rng, K_NOMINAL, R, [30, 12, 40, 25, 8])
    coaxial = CoaxialTracks(K_NOMINAL, tracks)
    r = 50.0 * r
    assert np.all(np.isinf(coaxial._table.coefficients(R, d, r)[coaxial_tracks_module._THRESHOLD]))  # no ellipse
    for R_k, d_k, r_k in [(R, d, r), perturb(R, d, r, rng, 1e-3), perturb(R, d, r, rng, 1e-2)]:
        before = coaxial.fallback_points
        assert_same(coaxial.evaluate(R_k, d_k, r_k), per_track(K_NOMINAL, tracks, R_k, d_k, r_k))
        assert coaxial.fallback_points > before


def test_nearly_edge_on_tracks_with_pixels_inside(rng):
    """Eccentric image ellipses (circles nearly edge-on: small |d|) with pixels scattered inside: the warm and cold
    starts miss the global minimum there, the vectorised stage 1 and CircleTrack's own stages find it."""
    R = random_line_rot3(rng, min_forward=0.85).matrix()
    d = np.array([0.02, -0.03, 0.04, 0.5])
    r = np.array([0.06, 0.05, -0.07, 0.04])
    tracks = []
    for j in range(4):
        points = curve(K_NOMINAL, R, d[j], r[j], rng.uniform(-np.pi, np.pi, 80))
        centre = curve(K_NOMINAL, R, d[j], r[j], np.linspace(-np.pi, np.pi, 64, endpoint=False)).mean(axis=0)
        inside = centre + (points[:40] - centre) * rng.uniform(0.0, 1.0, (40, 1))
        tracks.append(np.vstack([points[40:] + 2.0 * rng.standard_normal((40, 2)), inside]))
    coaxial = CoaxialTracks(K_NOMINAL, tracks)
    for R_k, d_k, r_k in [(R, d, r), perturb(R, d, r, rng, 0.05), (R, d, -r), (R, d, r)]:
        e, _, _ = result = coaxial.evaluate(R_k, d_k, r_k)
        assert_same(result, per_track(K_NOMINAL, tracks, R_k, d_k, r_k), jacobian_rtol=1e-7)
    best = np.concatenate([brute_force_distance(K_NOMINAL, R, d[j], r[j], p) for j, p in enumerate(tracks)])
    np.testing.assert_array_less(np.abs(e), best + 1e-9)
    assert coaxial.restarted_points > 0 and coaxial.fallback_points > 0


def test_evaluating_a_subset_of_tracks(rng, monkeypatch):
    """Evaluating only some tracks (the others keep the last evaluation, at the same line) gives the full result."""
    subsets = []
    original = layout_module._Layout.subset
    monkeypatch.setattr(layout_module._Layout, "subset", lambda self, sel: subsets.append(sel) or original(self, sel))
    R = random_line_rot3(rng).matrix()
    tracks, d, r = random_tracks(rng, K_NOMINAL, R, [25, 60, 0, 33, 48, 7])
    coaxial = CoaxialTracks(K_NOMINAL, tracks, row_length=20)
    coaxial.evaluate(R, d, r)
    active = np.array([False, True, False, False, True, True])
    d2, r2 = np.where(active, 1.01 * d, d), np.where(active, 0.98 * r, r)
    ev = coaxial._evaluate(R, d2, r2, active)
    assert len(subsets) == 1 and set(coaxial._layout.row_track[subsets[0]]) == {1, 4, 5}
    assert_same(coaxial.evaluate(R, d2, r2), per_track(K_NOMINAL, tracks, R, d2, r2))
    gram = coaxial._gram(ev, 3)
    e, _, H_dr = per_track(K_NOMINAL, tracks, R, d2, r2)
    np.testing.assert_allclose(gram[:, 0, 0], coaxial.track_sums(e * e), rtol=1e-12)
    np.testing.assert_allclose(gram[:, 1, 2], coaxial.track_sums(H_dr[:, 0] * H_dr[:, 1]), rtol=1e-9)


def test_row_layouts_give_the_same_results(rng):
    """Any row length of the padded layout (a track split over rows, or padded) gives the same numbers."""
    R = random_line_rot3(rng).matrix()
    tracks, d, r = random_tracks(rng, K_NOMINAL, R, [5, 70, 23, 0, 41])
    expected = per_track(K_NOMINAL, tracks, R, d, r)
    for row_length in (1, 8, 23, 64, 200):
        assert_same(CoaxialTracks(K_NOMINAL, tracks, row_length=row_length).evaluate(R, d, r), expected)


def test_jacobians_match_numerical(rng):
    R = random_line_rot3(rng)
    tracks, d, r = random_tracks(rng, K_NOMINAL, R.matrix(), [30, 12, 25], spread=2.0)
    coaxial = CoaxialTracks(K_NOMINAL, tracks)
    R_eval = R.retract(rng.normal(scale=0.01, size=3))  # away from the truth: pixels off the curves
    _, H_R, H_dr = coaxial.evaluate(R_eval, d, r)
    H_R_num = numericalDerivative11(lambda x: coaxial.evaluate(x, d, r, jacobians=False)[0].copy(), R_eval, 1e-6)
    np.testing.assert_allclose(H_R, H_R_num, rtol=0, atol=1e-6 * np.abs(H_R_num).max())
    m = len(d)
    x0 = np.concatenate([d, r])
    H_num = numericalDerivative11(lambda x: coaxial.evaluate(R_eval, x[:m], x[m:], jacobians=False)[0].copy(),
                                  x0, 1e-7)
    H_expected = np.zeros_like(H_num)  # each point depends on its own track's (d, r) only
    rows = np.arange(len(coaxial))
    H_expected[rows, coaxial.track_index] = H_dr[:, 0]
    H_expected[rows, m + coaxial.track_index] = H_dr[:, 1]
    np.testing.assert_allclose(H_expected, H_num, rtol=0, atol=1e-6 * np.abs(H_num).max())


# ----------------------------------------------------------------------------------------------------------------
# solve_circles: the per-track optimum at a fixed line
# ----------------------------------------------------------------------------------------------------------------


def test_solve_circles_reaches_the_per_track_optimum(measurement):
    m = measurement
    line = m.line.retract(np.array([1e-3, -5e-4, 2e-3]))
    coaxial = CoaxialTracks(m.K, m.noisy)
    d, r = coaxial.solve_circles(line, m.circles[:, 0], m.circles[:, 1], tol=1e-16)
    assert coaxial.last_solve["converged"].all()
    # LM on the full per-track graph with the line held fixed
    graph = full_graph(m.noisy, m.K)
    graph.add(gtsam.NonlinearEqualityRot3(L(0), line))
    result = gtsam.LevenbergMarquardtOptimizer(graph, full_values(line, m.circles), tight_params()).optimize()
    expected = np.array([result.atVector(C(j)) for j in range(len(m.noisy))])
    np.testing.assert_allclose(np.column_stack([d, r]), expected, rtol=0, atol=2e-8)
    # the gradient H_c^T e of every track vanishes
    e, _, H_dr = coaxial.evaluate(line, d, r)
    gradient = np.column_stack([coaxial.track_sums(H_dr[:, 0] * e), coaxial.track_sums(H_dr[:, 1] * e)])
    scale = np.sqrt(coaxial.track_sums(H_dr[:, 0] ** 2) * coaxial.track_sums(e**2))
    assert np.all(np.abs(gradient) <= 1e-7 * scale[:, None])
    # warm start: the previous solution is the default start, and a converged start needs one evaluation
    d2, r2 = coaxial.solve_circles(line, tol=1e-16)
    assert coaxial.last_solve["evaluations"] <= 2
    np.testing.assert_allclose(np.column_stack([d2, r2]), np.column_stack([d, r]), rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# The variable-projection factor
# ----------------------------------------------------------------------------------------------------------------


def test_vp_jacobian_is_the_exact_derivative_at_zero_residual(measurement):
    """Noise-free pixels at the true line: there the Gauss-Newton variable-projection Jacobian P H_R is exact."""
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.exact, m.K, m.circles * 1.01, sigma_px=0.5)
    values = line_values(m.line)
    assert np.abs(factor.residuals(values)).max() < 1e-8
    np.testing.assert_allclose(factor.circles(values), m.circles, rtol=0, atol=1e-9)
    A, b = factor.factor.linearize(values).jacobian()
    J_num = numericalDerivative11(lambda x: factor.factor.unwhitenedError(line_values(x)), m.line, 1e-6)
    np.testing.assert_allclose(A, J_num, rtol=0, atol=1e-6 * np.abs(J_num).max())
    np.testing.assert_allclose(np.abs(A).max(), np.abs(J_num).max(), rtol=1e-6)


def test_vp_jacobian_is_gauss_newton_away_from_zero_residual(measurement):
    """With noise, the exact derivative of e(R, c*(R)) differs from P H_R by a term of the order of the residuals
    (the residuals' second derivatives that Gauss-Newton drops), small but not zero."""
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=1.0, tol=1e-16)
    values = line_values(m.line)
    A, _ = factor.factor.linearize(values).jacobian()
    J_num = numericalDerivative11(lambda x: factor.factor.unwhitenedError(line_values(x)), m.line, 1e-6)
    difference = np.abs(A - J_num).max() / np.abs(J_num).max()
    assert 1e-6 < difference < 0.1


@pytest.mark.parametrize("robust", [None, track_huber], ids=["gaussian", "huber"])
def test_information_is_the_schur_complement_of_the_full_graph(measurement, robust):
    """At a noisy point (one track displaced by 7 px, so Huber down-weights it): J^T J, the gradient and the error
    of the factor are those of the full graph (Huber per track via noiseModel.Robust) at (R, c*(R)), with the
    circles eliminated."""
    m = measurement
    tracks = list(m.noisy)
    tracks[3] = tracks[3] + np.array([6.0, -4.0])
    line = m.line.retract(np.array([2e-4, -1e-4, 3e-4]))
    factor = make_coaxial_line_factor(L(0), tracks, m.K, m.circles, sigma_px=SIGMA, robust=robust, tol=1e-16)
    values = line_values(line)
    A, b = vp_graph(factor).linearize(values).jacobian()
    graph, full = full_graph(tracks, m.K, robust=robust), full_values(line, factor.circles(values))
    information, gradient = schur_on_line(graph, full, len(tracks))
    scale = np.abs(information).max()
    np.testing.assert_allclose(A.T @ A, information, rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(factor.information(values), information, rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(A.T @ b, gradient, rtol=0, atol=1e-8 * np.abs(gradient).max())
    assert vp_graph(factor).error(values) == pytest.approx(graph.error(full), rel=1e-12)
    assert factor.error(values) == pytest.approx(graph.error(full), rel=1e-12)
    weights = factor.weights(values)
    if robust is None:
        np.testing.assert_array_equal(weights, 1.0)
    else:
        assert np.flatnonzero(weights < 1.0).tolist() == [3]


def test_lm_on_the_factor_reaches_the_full_graph_solution(measurement):
    """LM (then Gauss-Newton polishing) on one VP factor and on the full graph, from the same perturbed start: the
    same line, circles and line marginal covariance."""
    m = measurement
    start = m.line.retract(np.array([2e-3, -1e-3, 3e-3]))
    graph = full_graph(m.noisy, m.K)
    full = gtsam.LevenbergMarquardtOptimizer(graph, full_values(start, m.circles), tight_params()).optimize()
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA, tol=1e-16)
    vp = gtsam.LevenbergMarquardtOptimizer(vp_graph(factor), line_values(start), tight_params()).optimize()
    gn = gtsam.GaussNewtonParams()
    gn.setRelativeErrorTol(0.0)
    gn.setAbsoluteErrorTol(0.0)
    gn.setMaxIterations(3)
    full = gtsam.GaussNewtonOptimizer(graph, full, gn).optimize()
    vp = gtsam.GaussNewtonOptimizer(vp_graph(factor), vp, gn).optimize()
    line_full, line_vp = full.atRot3(L(0)), vp.atRot3(L(0))
    assert np.linalg.norm(line_full.localCoordinates(line_vp)) < 1e-9
    circles_full = np.array([full.atVector(C(j)) for j in range(len(m.noisy))])
    np.testing.assert_allclose(factor.circles(vp), circles_full, rtol=0, atol=1e-8)
    assert vp_graph(factor).error(vp) == pytest.approx(graph.error(full), rel=1e-12)
    cov_full = gtsam.Marginals(graph, full).marginalCovariance(L(0))
    cov_vp = gtsam.Marginals(vp_graph(factor), vp).marginalCovariance(L(0))
    np.testing.assert_allclose(cov_vp, cov_full, rtol=0, atol=1e-6 * np.abs(cov_full).max())


def test_results_do_not_depend_on_the_history(measurement, rng):
    """Along a path of lines (steps 1e-2 to 1e-6 rad, as LM's; the factor predicts each solve's start from the
    last linearisation point): the same errors, circles and Jacobians as a fresh factor at each line."""
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
    line = m.line.retract(np.array([3e-3, 2e-3, -4e-3]))
    for scale in (1e-2, 3e-3, 1e-3, 1e-4, 1e-5, 1e-6, 1e-4):
        line = line.retract(rng.normal(scale=scale, size=3))
        values = line_values(line)
        fresh = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
        assert factor.factor.error(values) == pytest.approx(fresh.factor.error(values), rel=1e-11)
        np.testing.assert_allclose(factor.circles(values), fresh.circles(values), rtol=0, atol=1e-8)
        A, _ = factor.factor.linearize(values).jacobian()
        A_fresh, _ = fresh.factor.linearize(values).jacobian()
        np.testing.assert_allclose(A, A_fresh, rtol=0, atol=1e-7 * np.abs(A_fresh).max())
    assert factor.solves == 7


@pytest.mark.parametrize("tilt_only", [False, True])
def test_value_near_a_linearisation_point_does_not_depend_on_far_lines(measurement, rng, tilt_only):
    """LM from a line ~1 deg off: after solves at lines 0.02-0.3 rad away (whose circles may fall into other local
    solutions), the factor's value at the linearisation point is unchanged, and near it (1e-10 to 1e-3 rad) it is
    a fresh factor's: its circles stay in the same local solution."""
    m = measurement
    start = m.line.retract(np.array([0.01, -0.015, 0.01]))
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA)
    values = line_values(start)
    factor.factor.linearize(values)
    error, circles = factor.factor.error(values), factor.circles(values)
    weights = np.array([0.3, 0.3, 1.0]) if tilt_only else np.ones(3)  # mostly the tilt in the projection plane
    for norm in (0.3, 0.28, 0.25, 0.2, 0.14, 0.1, 0.05, 0.02):
        w = rng.normal(size=3) * weights
        factor.error(start.retract(norm * w / np.linalg.norm(w)))  # inspection: always solves
    assert factor.solves == 9
    assert factor.factor.error(values) == error
    np.testing.assert_array_equal(factor.circles(values), circles)
    for tiny in (1e-10, 1e-6, 1e-3):
        near = line_values(start.retract(tiny * np.array([1.0, -2.0, 1.5])))
        fresh = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA)
        assert factor.factor.error(near) == pytest.approx(fresh.factor.error(near), rel=1e-9)
        np.testing.assert_allclose(factor.circles(near), fresh.circles(near), rtol=0, atol=1e-4)
        assert factor.converged(near).all()


def test_trial_steps_beyond_the_trust_region_are_refused(measurement):
    """GTSAM's error at a line further than TRUST_RAD from every anchor (linearisation points, the first line) is
    refused with a huge constant residual, without a solve; within it, at an anchor, at a cached line, through the
    inspection methods and when linearising, the factor solves."""
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA)
    first = m.line.retract(np.array([0.01, -0.015, 0.01]))
    error = factor.factor.error(line_values(first))  # the first evaluation anchors
    far = first.retract(np.array([0.0, 0.0, 2.0 * coaxial_module.TRUST_RAD]))
    inside = first.retract(np.array([0.0, 0.0, 0.5 * coaxial_module.TRUST_RAD]))
    assert factor.factor.error(line_values(far)) > 1e12 * error
    assert factor.refused == 1 and factor.solves == 1
    assert factor.factor.error(line_values(inside)) < 1e3 * error
    real = factor.error(far)  # inspection solves, and the line is then cached
    assert factor.solves == 3 and real < 1e3 * error
    assert factor.factor.error(line_values(far)) == pytest.approx(real, rel=1e-12)
    # a linearisation at the far line anchors it: lines near it are solved, the first line still is
    factor.factor.linearize(line_values(far))
    near_far = far.retract(np.array([0.0, 0.02, 0.0]))
    assert factor.factor.error(line_values(near_far)) < 1e3 * error
    assert factor.factor.error(line_values(first)) == pytest.approx(error, rel=1e-12)
    assert factor.refused == 1


def test_huber_weights_and_error(measurement):
    """Per-track Huber with k_j = sqrt(chi2_quantile(N_j)): weights min(1, k_j / |e_j|) and the error the sum of
    Huber losses (computed here independently); a generic mEstimator (Cauchy) matches GTSAM's Robust too."""
    m = measurement
    tracks = list(m.noisy)
    tracks[5] = tracks[5] + np.array([-5.0, 5.0])
    factor = make_coaxial_line_factor(L(0), tracks, m.K, m.circles, sigma_px=SIGMA, robust=track_huber)
    values = line_values(m.line)
    x = np.sqrt(factor.track_chi2(values))
    k = np.sqrt([chi2_quantile(n) for n in factor.counts])
    np.testing.assert_allclose(factor.weights(values), np.minimum(1.0, k / x), rtol=1e-12)
    assert factor.weights(values)[5] < 0.5 and np.sum(factor.weights(values) < 1.0) == 1
    loss = np.where(x <= k, 0.5 * x**2, k * x - 0.5 * k**2)
    assert factor.factor.error(values) == pytest.approx(loss.sum(), rel=1e-12)
    # thresholds as numbers, and an estimator that is not Huber (called per track)
    by_numbers = make_coaxial_line_factor(L(0), tracks, m.K, m.circles, sigma_px=SIGMA, robust=k)
    assert by_numbers.factor.error(values) == pytest.approx(loss.sum(), rel=1e-12)
    cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(15.0)
    factor = make_coaxial_line_factor(L(0), tracks, m.K, m.circles, sigma_px=SIGMA, robust=cauchy, tol=1e-16)
    graph = full_graph(tracks, m.K, robust=lambda n: cauchy)
    full = full_values(m.line, factor.circles(values))
    assert factor.factor.error(values) == pytest.approx(graph.error(full), rel=1e-12)
    information, _ = schur_on_line(graph, full, len(tracks))
    np.testing.assert_allclose(factor.information(values), information, rtol=0,
                               atol=1e-8 * np.abs(information).max())


def test_inspection(measurement):
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
    with pytest.raises(ValueError, match="not been evaluated"):
        factor.circles()
    values = line_values(m.line)
    factor.factor.error(values)
    circles = factor.circles()  # the last evaluated line
    np.testing.assert_array_equal(circles, factor.circles(values))
    e, _, _ = per_track(m.K, m.noisy, m.line.matrix(), circles[:, 0], circles[:, 1])
    np.testing.assert_allclose(factor.residuals(values), e, rtol=0, atol=1e-10)
    counts = np.array([len(p) for p in m.noisy])
    np.testing.assert_array_equal(factor.counts, counts)
    split = np.split(e, np.cumsum(counts)[:-1])
    np.testing.assert_allclose(factor.track_rms(values), [np.sqrt(np.mean(x**2)) for x in split], rtol=1e-12)
    np.testing.assert_allclose(factor.track_chi2(values), [np.sum(x**2) / SIGMA**2 for x in split], rtol=1e-12)
    phases = np.concatenate([closest_phases(m.K, m.line, *circles[j], p) for j, p in enumerate(m.noisy)])
    np.testing.assert_allclose(np.angle(np.exp(1j * (factor.phases(values) - phases))), 0.0, atol=1e-9)
    assert factor.converged(values).all()
    # the same tracks object keeps its warm start in a new factor (e.g. with a new sigma)
    again = make_coaxial_line_factor(L(0), factor.tracks, None, circles, sigma_px=2.0 * SIGMA)
    assert again.factor.error(values) == pytest.approx(factor.factor.error(values) / 4.0, rel=1e-9)


def test_input_checks(measurement):
    m = measurement
    with pytest.raises(ValueError, match="one \\(d, r\\) per track"):
        make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles[:-1])
    with pytest.raises(ValueError, match="sigma_px"):
        make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=0.0)
    with pytest.raises(ValueError, match="Huber threshold"):
        make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, robust=[1.0, 2.0])
    coaxial = CoaxialTracks(m.K, m.noisy)
    with pytest.raises(ValueError, match="one \\(d, r\\) per track"):
        coaxial.evaluate(m.line, m.circles[:-1, 0], m.circles[:-1, 1])
    with pytest.raises(ValueError, match="no previous solution"):
        coaxial.solve_circles(m.line)


# ----------------------------------------------------------------------------------------------------------------
# per-track scores: the "meat" of a cluster-robust covariance
# ----------------------------------------------------------------------------------------------------------------


def test_track_scores_are_each_tracks_gradient(measurement):
    m = measurement
    factor = make_coaxial_line_factor(L(0), m.noisy, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
    values = line_values(m.line)
    S = factor.track_scores(values)
    assert S.shape == (len(m.noisy), 3)
    circles = factor.circles(values)
    for j in range(0, len(m.noisy), 7):  # one track's graph, its circle eliminated: its gradient on the line
        _, gradient = schur_on_line(full_graph([m.noisy[j]], m.K), full_values(m.line, [circles[j]]), 1)
        np.testing.assert_allclose(S[j], -gradient, rtol=1e-6, atol=1e-9 * np.abs(gradient).max())
    A, b = vp_graph(factor).linearize(values).jacobian()
    np.testing.assert_allclose(S.sum(axis=0), -(A.T @ b), rtol=1e-8, atol=1e-9 * np.abs(A.T @ b).max())


def test_track_translation_scores_are_the_gradients_change_when_a_track_moves(measurement):
    """V_j t is how the line's gradient moves when every pixel of track j moves by t (the circles re-solved): against
    central differences of the summed scores of factors built on the moved pixels."""
    m = measurement
    values = line_values(m.line)
    # exact at zero residual; with noise the projected Jacobian drops the residual-weighted second derivatives (as
    # Gauss-Newton does, see the module's caveat): there it is first order, within 1 % of the change's size
    for pixels, rtol, share in ((m.exact, 1e-5, 1e-6), (m.noisy, 0.0, 0.01)):
        factor = make_coaxial_line_factor(L(0), pixels, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
        V = factor.track_translation_scores(values)
        assert V.shape == (len(pixels), 3, 2)
        for j in (0, len(pixels) // 2):
            for u in range(2):
                def gradient(sign, j=j, u=u, pixels=pixels, step=1e-3):
                    moved = [p.copy() for p in pixels]
                    moved[j][:, u] += sign * step
                    f = make_coaxial_line_factor(L(0), moved, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
                    return f.track_scores(values).sum(axis=0)

                numeric = (gradient(1.0) - gradient(-1.0)) / 2e-3
                np.testing.assert_allclose(V[j, :, u], numeric, rtol=rtol, atol=share * np.linalg.norm(numeric))


def test_tracks_own_translations_move_the_line_as_their_scores_say(measurement, rng):
    """Each track moved by a small image translation of its own (the pixels otherwise exact): the line the factor
    then fits moves by ``-H^-1 sum_j V_j t_j`` to first order, which is what the track-offset meat
    ``tau^2 sum_j V_j V_j^T`` propagates (calibration.stage1._track_offset_meat). (First order: at 0.05 px the
    line's weakest direction moves by 0.7 of it, at 0.01 px 0.94, at 0.002 px 0.99.)"""
    m = measurement
    values = line_values(m.line)
    factor = make_coaxial_line_factor(L(0), m.exact, m.K, m.circles, sigma_px=SIGMA, tol=1e-14)
    V, H = factor.track_translation_scores(values), factor.information(values)
    t = 0.003 * rng.standard_normal((len(m.exact), 2))
    moved = make_coaxial_line_factor(L(0), [p + t[j] for j, p in enumerate(m.exact)], m.K, m.circles,
                                     sigma_px=SIGMA, tol=1e-14)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(moved.factor)
    solved = gtsam.LevenbergMarquardtOptimizer(graph, values, tight_params()).optimize().atRot3(L(0))
    shift = m.line.localCoordinates(solved)
    predicted = -np.linalg.solve(H, np.einsum("jau,ju->a", V, t))
    assert np.linalg.norm(shift) > 1e-7  # (the translations move it)
    np.testing.assert_allclose(shift, predicted, rtol=0, atol=0.03 * np.linalg.norm(predicted))


def whitened_meat(m, offsets_px: float, draws: int, rng) -> np.ndarray:
    """Mean over noise draws of H^-1/2 (sum_j s_j s_j^T) H^-1/2 at the true line: white pixel noise of SIGMA plus
    a constant offset per track (standard deviation ``offsets_px`` per coordinate)."""
    total = np.zeros((3, 3))
    for _ in range(draws):
        tracks = [p + SIGMA * rng.standard_normal(p.shape) + offsets_px * rng.standard_normal(2) for p in m.exact]
        factor = make_coaxial_line_factor(L(0), tracks, m.K, m.circles, sigma_px=SIGMA)
        values = line_values(m.line)
        S = factor.track_scores(values)
        w, V = np.linalg.eigh(factor.information(values))
        root = (V / np.sqrt(w)) @ V.T
        total += root @ (S.T @ S) @ root
    return total / draws


def test_track_scores_estimate_the_information_under_white_noise(measurement, rng):
    """E[sum_j s_j s_j^T] = J^T J when the pixel noise is white with the assumed sigma: whitened, the identity."""
    eigenvalues = np.linalg.eigvalsh(whitened_meat(measurement, 0.0, 60, rng))
    # 60 draws: each eigenvalue of the mean is within ~0.2 of 1 (3.5 standard deviations)
    assert np.all(np.abs(eigenvalues - 1.0) < 0.25), eigenvalues


def test_track_scores_see_an_error_shared_by_a_tracks_pixels(measurement, rng):
    """A constant offset per track (a tracker's bias that follows a dot) is invisible to the white-noise
    information but not to the scores: the whitened meat grows well beyond the identity."""
    eigenvalues = np.linalg.eigvalsh(whitened_meat(measurement, 0.5 * SIGMA, 20, rng))
    assert eigenvalues.max() > 3.0, eigenvalues
