"""The rigid-spin variable-projection factor against the full rigid graph it projects (factors.rigid), numerical
derivatives and the truth."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, S, X
from gtsam.utils.numerical_derivative import numericalDerivative11

from gtsam_rotid.dataset import Track
from gtsam_rotid.factors import (
    RigidTracks,
    closest_phases,
    initial_spin,
    make_rigid_circle_factor,
    make_rigid_line_factor,
    rot3_from_line,
    spin_priors,
)
from gtsam_rotid.factors.coaxial import REFUSED_RESIDUAL, TRUST_RAD
from gtsam_rotid.graph import track_huber
from gtsam_rotid.simulate import reference_scene

SIGMA = 1.2
CHUNK = 32


class Measurement:
    """One measurement of a reference scene: tracks (ideal pixels and frames), the true line and circles."""

    def __init__(self, K, noisy, exact, frames, line, circles):
        self.K, self.noisy, self.exact, self.frames, self.line, self.circles = K, noisy, exact, frames, line, circles


@pytest.fixture(scope="module")
def measurement() -> Measurement:
    dataset, truth = reference_scene(seed=0, duration=10)
    camera, m_truth, m_data = dataset.camera, truth.measurements[0], dataset.measurements[0]
    camera_T_arm = truth.arm_T_camera.inverse()
    point = camera_T_arm.transformFrom(m_truth.axis_point)
    direction = camera_T_arm.rotation().matrix() @ m_truth.axis_direction
    line, distance = rot3_from_line(point, direction)
    c1 = line.matrix()[:, 1]
    circles = np.array([[(t.offset + point @ c1) / distance, t.radius / distance] for t in m_truth.tracks])
    noisy, exact, frames = [], [], []
    for j, track in enumerate(m_data.tracks):
        track = Track.from_any(track)
        noisy.append(camera.undistort_pixels(track.pixels))
        points = truth.arm_T_camera.transformTo(m_truth.feature_points(j, track.frames).T).T @ camera.K.T
        exact.append(points[:, :2] / points[:, 2:])
        frames.append(track.frames)
    return Measurement(camera.K, noisy, exact, frames, line, circles)


def start(m: Measurement, pixels, line=None):
    """RigidTracks and the starting (phi0, theta) from the closest phases on the true circles at ``line``."""
    line = m.line if line is None else line
    phases = [closest_phases(m.K, line, d, r, p) for (d, r), p in zip(m.circles, pixels, strict=True)]
    tracks = RigidTracks(list(zip(pixels, m.frames, strict=True)))
    first = int(tracks.frame_ids[0])
    init = initial_spin(list(zip(m.frames, phases, strict=True)), int(tracks.frame_ids[-1]) - first + 1, first)
    return tracks, init.phi0, init.theta[0][tracks.frame_ids - first]


def factor_for(m: Measurement, pixels, robust=None, scale=1.0, tol=1e-14):
    tracks, phi0, theta = start(m, pixels)
    return make_rigid_line_factor(L(0), tracks, m.K, m.circles * scale, phi0, theta, sigma_px=SIGMA, robust=robust,
                                  tol=tol)


def line_values(line) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(L(0), line)
    return values


def full_rigid_graph(m: Measurement, pixels, factor, values, robust=None):
    """The whole rigid graph (factors.rigid: a (d, r, phi0) variable per track, chunks of spin angles, gauge and
    unobserved-entry priors) with its values at the factor's inner solution."""
    first = int(factor.tracks.frame_ids[0])
    phases = factor.phases(values)
    per_track = np.split(phases, np.cumsum(factor.counts)[:-1])
    init = initial_spin(list(zip(m.frames, per_track, strict=True)), CHUNK, first)
    graph, full = gtsam.NonlinearFactorGraph(), gtsam.Values()
    full.insert(L(0), values.atRot3(L(0)))
    circles, phi0 = factor.circles(values), factor.phase_offsets(values)
    theta = np.full(int(factor.tracks.frame_ids[-1]) - first + 1, np.nan)
    theta[factor.tracks.frame_ids - first] = factor.spin_angles(values)
    for c, chunk in init.theta.items():
        seen = init.observed[c]
        chunk = chunk.copy()
        chunk[seen] = theta[c * CHUNK + np.flatnonzero(seen)]
        full.insert(S(c), chunk)
    for j, pixels_j in enumerate(pixels):
        full.insert(X(j), np.array([circles[j, 0], circles[j, 1], phi0[j]]))
        noise = gtsam.noiseModel.Isotropic.Sigma(2 * len(pixels_j), SIGMA)
        if robust is not None:
            noise = gtsam.noiseModel.Robust.Create(robust(2 * len(pixels_j)), noise)
        graph.add(make_rigid_circle_factor(noise, L(0), X(j), S, pixels_j, m.frames[j], m.K, CHUNK, first))
    gauge = init._replace(phi0=phi0)  # the gauge priors hold the factor's own phi0 of each component's first track
    for prior in spin_priors(gauge, lambda c: S(c), X, gauge_sigma=1e-9):
        graph.add(prior)
    return graph, full


def normal_equations(graph, values):
    """``J^T J`` and ``J^T b`` of the linearised graph, the line's three columns last."""
    ordering = gtsam.Ordering()
    for key in values.keys():
        if key != L(0):
            ordering.push_back(key)
    ordering.push_back(L(0))
    A, b = graph.linearize(values).jacobian(ordering)
    return A.T @ A, A.T @ b


def schur_on_line(graph, values):
    """Information (3x3) and gradient of the line after eliminating every other variable of the linearised graph."""
    H, g = normal_equations(graph, values)
    n = H.shape[0] - 3
    Y = np.linalg.solve(H[:n, :n], np.column_stack([H[:n, n:], g[:n]]))
    return H[n:, n:] - H[:n, n:].T @ Y[:, :3], g[n:] - H[:n, n:].T @ Y[:, 3]


def test_noise_free_pixels_give_the_truth_and_the_exact_derivative(measurement):
    """At the true line the inner solve recovers the true circles with zero residual, from circles 1 % off; there
    the Gauss-Newton variable-projection Jacobian is the exact derivative of the factor's residual."""
    m = measurement
    factor = factor_for(m, m.exact, scale=1.01)
    values = line_values(m.line)
    assert np.abs(factor.residuals(values)).max() < 1e-8
    np.testing.assert_allclose(factor.circles(values), m.circles, rtol=0, atol=1e-9)
    assert factor.factor.dim() == 2 * sum(len(p) for p in m.exact)
    A, _ = factor.factor.linearize(values).jacobian()
    J_num = numericalDerivative11(lambda x: factor.factor.unwhitenedError(line_values(x)), m.line, 1e-6)
    np.testing.assert_allclose(A, J_num, rtol=0, atol=1e-6 * np.abs(J_num).max())


def test_jacobian_is_gauss_newton_away_from_zero_residual(measurement):
    """With noise the exact derivative differs from P H_R by the residuals' second-order terms: small, not zero."""
    m = measurement
    factor = factor_for(m, m.noisy)
    values = line_values(m.line)
    A, _ = factor.factor.linearize(values).jacobian()
    J_num = numericalDerivative11(lambda x: factor.factor.unwhitenedError(line_values(x)), m.line, 1e-6)
    assert 1e-6 < np.abs(A - J_num).max() / np.abs(J_num).max() < 0.2


@pytest.mark.parametrize("robust", [None, track_huber], ids=["gaussian", "huber"])
def test_information_and_gradient_are_the_full_rigid_graphs(measurement, robust):
    """At a noisy line (half of one track displaced by 7 px, which Huber down-weights): J^T J, J^T e and the error of
    the factor are those of the whole rigid graph (factors.rigid) at the factor's inner solution, every variable but
    the line eliminated; and the inner solution is that graph's optimum at that line (its gradient there is 0)."""
    m = measurement
    pixels = list(m.noisy)
    pixels[3] = pixels[3].copy()
    pixels[3][len(pixels[3]) // 2:] += np.array([6.0, -4.0])
    line = m.line.retract(np.array([2e-4, -1e-4, 3e-4]))
    kernel = None if robust is None else (lambda n: robust(2 * n))
    factor = factor_for(m, pixels, robust=kernel)
    values = line_values(line)
    A, b = factor.factor.linearize(values).jacobian()
    graph, full = full_rigid_graph(m, pixels, factor, values, robust)
    information, gradient = schur_on_line(graph, full)
    scale = np.abs(information).max()
    np.testing.assert_allclose(A.T @ A, information, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(factor.information(values), information, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(A.T @ b, gradient, rtol=0, atol=1e-6 * np.abs(gradient).max())
    assert factor.factor.error(values) == pytest.approx(graph.error(full), rel=1e-9)
    assert factor.error(values) == pytest.approx(graph.error(full), rel=1e-9)
    # the inner variables' gradient of the whole graph vanishes at the factor's solution (the line's does not)
    _, g_full = normal_equations(graph, full)
    assert np.abs(g_full[:-3]).max() < 1e-6 * np.abs(g_full[-3:]).max()
    weights = factor.weights(values)
    if robust is None:
        np.testing.assert_array_equal(weights, 1.0)
    else:
        assert np.flatnonzero(weights < 1.0).tolist() == [3]


def test_lm_on_the_factor_reaches_the_full_rigid_graph_solution(measurement):
    """LM on the one factor and on the whole rigid graph from the same perturbed line: the same line, circles,
    error and line marginal covariance."""
    m = measurement
    begin = m.line.retract(np.array([2e-3, -1e-3, 3e-3]))
    factor = factor_for(m, m.noisy)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(100)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factor.factor)
    vp = gtsam.LevenbergMarquardtOptimizer(graph, line_values(begin), params).optimize()
    full_graph, full = full_rigid_graph(m, m.noisy, factor, line_values(begin))
    full = gtsam.LevenbergMarquardtOptimizer(full_graph, full, params).optimize()
    assert np.linalg.norm(full.atRot3(L(0)).localCoordinates(vp.atRot3(L(0)))) < 1e-8
    circles_full = np.array([full.atVector(X(j))[:2] for j in range(len(m.noisy))])
    np.testing.assert_allclose(factor.circles(vp), circles_full, rtol=0, atol=1e-7)
    assert graph.error(vp) == pytest.approx(full_graph.error(full), rel=1e-9)
    cov_full = gtsam.Marginals(full_graph, full).marginalCovariance(L(0))
    cov_vp = gtsam.Marginals(graph, vp).marginalCovariance(L(0))
    np.testing.assert_allclose(cov_vp, cov_full, rtol=0, atol=1e-6 * np.abs(cov_full).max())


def test_values_do_not_depend_on_the_history(measurement, rng):
    """Along a path of lines (LM-sized steps; each solve starts from the last linearisation point): the same error
    and circles as a fresh factor at each line."""
    m = measurement
    factor = factor_for(m, m.noisy)
    tracks, phi0, theta = start(m, m.noisy)
    line = m.line.retract(np.array([3e-3, 2e-3, -4e-3]))
    for step in (1e-2, 3e-3, 1e-3, 1e-4, 1e-6, 1e-4):
        line = line.retract(rng.normal(scale=step, size=3))
        values = line_values(line)
        factor.factor.linearize(values)
        fresh = make_rigid_line_factor(L(0), tracks, m.K, m.circles, phi0, theta, sigma_px=SIGMA, tol=1e-14)
        assert factor.factor.error(values) == pytest.approx(fresh.factor.error(values), rel=1e-10)
        np.testing.assert_allclose(factor.circles(values), fresh.circles(values), rtol=0, atol=1e-8)


def test_trial_lines_beyond_the_trust_region_are_refused(measurement):
    m = measurement
    factor = factor_for(m, m.noisy)
    factor.factor.linearize(line_values(m.line))
    far = line_values(m.line.retract(np.array([0.0, 0.0, 3.0 * TRUST_RAD])))
    np.testing.assert_array_equal(factor.factor.unwhitenedError(far), REFUSED_RESIDUAL)
    assert factor.refused == 1
    assert np.isfinite(factor.error(far)) and factor.error(far) < 1e12  # the inspection methods always solve


def test_inspection(measurement):
    m = measurement
    factor = factor_for(m, m.noisy)
    values = line_values(m.line)
    n = sum(len(p) for p in m.noisy)
    residuals = factor.residuals(values)
    assert residuals.shape == (n, 2)
    np.testing.assert_allclose(factor.factor.unwhitenedError(values), residuals.reshape(-1) / SIGMA, rtol=1e-12)
    rms = factor.track_rms(values)
    assert rms.shape == (len(m.noisy),) and np.all((0.5 * SIGMA < rms) & (rms < 2.0 * SIGMA))
    # the phases are the spin angles plus each track's offset, and the held offsets are the starting ones
    tracks, phi0, _ = start(m, m.noisy)
    held = [c[0] for c in tracks.components]
    np.testing.assert_allclose(factor.phase_offsets(values)[held], phi0[held], rtol=0, atol=1e-15)
    phases = factor.phases(values)
    expected = factor.spin_angles(values)[tracks.frame] + factor.phase_offsets(values)[tracks.track]
    np.testing.assert_allclose(np.angle(np.exp(1j * (phases - expected))), 0.0, atol=1e-12)
    assert factor.converged(values).all()
    scores = factor.track_scores(values)
    A, b = factor.factor.linearize(values).jacobian()
    np.testing.assert_allclose(scores.sum(axis=0), A.T @ b * -1.0, rtol=1e-9, atol=1e-9 * np.abs(scores).max())


def test_input_checks(measurement):
    m = measurement
    pixels, frames = m.noisy[0], m.frames[0]
    with pytest.raises(ValueError, match="track 0 sees a frame twice"):
        RigidTracks([(pixels[:2], np.array([5, 5]))])
    with pytest.raises(ValueError, match="track 1: 3 frames for 2 pixels"):
        RigidTracks([(pixels, frames), (pixels[:2], frames[:3])])
    with pytest.raises(TypeError, match="frames must be integers"):
        RigidTracks([(pixels[:2], np.array([1.0, 2.0]))])
    with pytest.raises(ValueError, match="need at least one track"):
        RigidTracks([])
    tracks = RigidTracks([(pixels, frames)])
    with pytest.raises(ValueError, match="one spin angle per frame seen"):
        make_rigid_line_factor(L(0), tracks, m.K, m.circles[:1], [0.0], np.zeros(3))
    with pytest.raises(ValueError, match="one phi0 per track"):
        make_rigid_line_factor(L(0), tracks, m.K, m.circles[:1], [0.0, 1.0], np.zeros(len(frames)))
    with pytest.raises(ValueError, match="sigma_px"):
        make_rigid_line_factor(L(0), tracks, m.K, m.circles[:1], [0.0], np.zeros(len(frames)), sigma_px=0.0)


def test_intrinsics_variable(measurement):
    """With the intrinsics a Cal3_S2 variable: noise-free pixels give zero residual at the true line and camera, and
    both Jacobians (line; fx, fy, s, cx, cy) are there the exact derivatives; with noise, at the camera's own
    intrinsics, the factor is the fixed-intrinsics one."""
    from gtsam.symbol_shorthand import K
    from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

    from gtsam_rotid.factors import cal3_s2

    m = measurement
    truth = cal3_s2(m.K)

    def values_at(line, intrinsics):
        values = line_values(line)
        values.insert(K(0), intrinsics)
        return values

    def with_intrinsics(pixels, scale=1.0):
        tracks, phi0, theta = start(m, pixels)
        return make_rigid_line_factor(L(0), tracks, m.K, m.circles * scale, phi0, theta, sigma_px=SIGMA, tol=1e-14,
                                      intrinsics_key=K(0))

    factor = with_intrinsics(m.exact, 1.01)
    values = values_at(m.line, truth)
    assert factor.factor.keys() == [L(0), K(0)]
    assert np.abs(factor.residuals(values)).max() < 1e-8
    A, _ = factor.factor.linearize(values).jacobian()
    error = lambda line, intrinsics: factor.factor.unwhitenedError(values_at(line, intrinsics))  # noqa: E731
    J_line = numericalDerivative21(error, m.line, truth, 1e-6)
    J_intrinsics = numericalDerivative22(error, m.line, truth, 1e-4)
    np.testing.assert_allclose(A[:, :3], J_line, rtol=0, atol=1e-6 * np.abs(J_line).max())
    np.testing.assert_allclose(A[:, 3:], J_intrinsics, rtol=0, atol=1e-6 * np.abs(J_intrinsics).max())
    # a camera 2 % and 6 px off: the residuals grow (the pixels see the difference), the solve still converges
    wrong = truth.retract(np.array([0.02 * m.K[0, 0], 0.02 * m.K[1, 1], 0.0, 6.0, -6.0]))
    assert np.abs(factor.residuals(values_at(m.line, wrong))).max() > 0.1
    assert np.all(factor.converged(values_at(m.line, wrong)))

    noisy, fixed = with_intrinsics(m.noisy), factor_for(m, m.noisy)
    np.testing.assert_allclose(noisy.factor.unwhitenedError(values), fixed.factor.unwhitenedError(line_values(m.line)),
                               atol=1e-9)


def test_track_translation_scores_are_the_gradients_change_when_a_track_moves(measurement):
    """V_j t is how the line's (and the intrinsics') gradient moves when every pixel of track j moves by t (the
    circles, phases and spin angles re-solved): against central differences of factors built on the moved pixels."""
    from gtsam.symbol_shorthand import K

    from gtsam_rotid.factors import cal3_s2

    m = measurement
    values = line_values(m.line)
    values.insert(K(0), cal3_s2(m.K))

    def factor_on(pixels):
        tracks, phi0, theta = start(m, m.noisy)  # the same start for every factor
        tracks = RigidTracks(list(zip(pixels, m.frames, strict=True)))
        return make_rigid_line_factor(L(0), tracks, m.K, m.circles, phi0, theta, sigma_px=SIGMA, tol=1e-14,
                                      intrinsics_key=K(0))

    # exact at zero residual; with noise first order (the projected Jacobian drops the residual-weighted second
    # derivatives, as Gauss-Newton does): within 1 % of the change's size
    for pixels, rtol, share in ((m.exact, 1e-5, 1e-6), (m.noisy, 0.0, 0.01)):
        V = factor_on(pixels).track_translation_scores(values, intrinsics=True)
        assert V.shape == (len(pixels), 8, 2)
        np.testing.assert_allclose(factor_on(pixels).track_translation_scores(values), V[:, :3], rtol=1e-12,
                                   atol=0)
        for j in (0, len(pixels) // 2):
            for u in range(2):
                def gradient(sign, j=j, u=u, pixels=pixels, step=1e-3):
                    moved = [p.copy() for p in pixels]
                    moved[j][:, u] += sign * step
                    return factor_on(moved).track_scores(values, intrinsics=True).sum(axis=0)

                numeric = (gradient(1.0) - gradient(-1.0)) / 2e-3
                np.testing.assert_allclose(V[j, :, u], numeric, rtol=rtol, atol=share * np.linalg.norm(numeric))


def test_per_track_scores_and_information_span_the_intrinsics(measurement):
    """With an intrinsics variable, each track's score and information can span it too (the cluster-robust meat
    over the line and the intrinsics together): summed, they are the linearised factor's gradient and Gauss-Newton
    Hessian over both variables; without ``intrinsics`` they are the line's block of the same."""
    from gtsam.symbol_shorthand import K

    from gtsam_rotid.factors import cal3_s2

    m = measurement
    tracks, phi0, theta = start(m, m.noisy)
    factor = make_rigid_line_factor(L(0), tracks, m.K, m.circles, phi0, theta, sigma_px=SIGMA, tol=1e-14,
                                    intrinsics_key=K(0))
    values = line_values(m.line)
    values.insert(K(0), cal3_s2(m.K))
    A, b = factor.factor.linearize(values).jacobian()
    scores = factor.track_scores(values, intrinsics=True)
    information = factor.track_information(values, intrinsics=True)
    assert scores.shape == (len(m.noisy), 8) and information.shape == (len(m.noisy), 8, 8)
    np.testing.assert_allclose(scores.sum(axis=0), -A.T @ b, rtol=1e-9, atol=1e-9 * np.abs(scores).max())
    np.testing.assert_allclose(information.sum(axis=0), A.T @ A, rtol=1e-9, atol=1e-9 * np.abs(A.T @ A).max())
    np.testing.assert_allclose(factor.track_scores(values), scores[:, :3], rtol=1e-12, atol=0)
    np.testing.assert_allclose(factor.track_information(values), information[:, :3, :3], rtol=1e-12, atol=0)
    # a fixed-intrinsics factor has only the line's columns
    assert factor_for(m, m.noisy).track_scores(line_values(m.line), intrinsics=True).shape == (len(m.noisy), 3)
