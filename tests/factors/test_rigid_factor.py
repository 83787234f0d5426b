"""Rigid-spin circle factor: phase convention, zero residual at the truth, Jacobians, LM, initial_spin."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from factor_scene import assert_jacobians_match, perpendicular_pair, values_with
from gtsam.symbol_shorthand import L, S, X

from gtsam_rotid.factors import closest_phases
from gtsam_rotid.factors.rigid import (
    chunk_segments,
    initial_spin,
    make_entries_prior,
    make_rigid_circle_factor,
    rigid_spin_residuals,
    spin_chunk_index,
    spin_priors,
)

CHUNK = 32
FIRST = 100  # absolute frame index of chunk 0, column 0
TRACK_FEATURES = (0, 1, 2)
SCENE_PHI0 = np.array([0.3, 2.0, -1.5])  # per-track phase offsets in the scene's (e1, e2) convention


def wrap(a):
    return np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi


def spin(frames):
    f = np.asarray(frames, dtype=float) - FIRST
    return 0.02 * f + 0.05 * np.sin(0.2 * f)


def track_frames():
    """Overlapping tracks over frames 100..259 (chunks 0..4); track 1 sees only even frames (odd ones of 170..199
    are seen by no track)."""
    return [np.arange(100, 170), np.arange(140, 220, 2), np.arange(200, 260)]


def scene_phase_offset(scene):
    """Factor phase = scene phase + delta: e1 of the scene's circles is cos(delta) c2 + sin(delta) c0."""
    line, _ = scene.unit_circles()
    c0, _, c2 = line.matrix().T
    e1, _ = perpendicular_pair(scene.axis_direction_arm)
    e1_cam = scene.arm_T_camera.rotation().matrix().T @ e1
    return float(np.arctan2(e1_cam @ c0, e1_cam @ c2))


def scene_tracks(scene):
    """Line, per-track truth (d, r, phi0) in the factor's convention, frames and noise-free pixels."""
    line, circles = scene.unit_circles()
    delta = scene_phase_offset(scene)
    truth, frames, pixels = [], track_frames(), []
    for t, j in enumerate(TRACK_FEATURES):
        pixels.append(scene.pixels(scene.circle_points_arm(j, spin(frames[t]) + SCENE_PHI0[t])))
        truth.append(np.array([circles[j, 0], circles[j, 1], wrap(SCENE_PHI0[t] + delta)]))
    return line, truth, frames, pixels


def chunk_values(frames_list, theta_of):
    ids = sorted({int(c) for f in frames_list for c in spin_chunk_index(f, CHUNK, FIRST)[0]})
    return {c: theta_of(FIRST + c * CHUNK + np.arange(CHUNK)) for c in ids}


def factor_for(K, t, frames, pixels, sigma=1.0, chunk_keys=S):
    noise = gtsam.noiseModel.Isotropic.Sigma(2 * len(pixels), sigma)
    return make_rigid_circle_factor(noise, L(0), X(t), chunk_keys, pixels, frames, K, CHUNK, FIRST)


def test_spin_chunk_index():
    ids, cols = spin_chunk_index(np.array([100, 131, 132, 200]), 32, first_frame=100)
    np.testing.assert_array_equal(ids, [0, 0, 1, 3])
    np.testing.assert_array_equal(cols, [0, 31, 0, 4])
    with pytest.raises(ValueError, match="before first_frame"):
        spin_chunk_index(np.array([99]), 32, first_frame=100)
    with pytest.raises(TypeError):
        spin_chunk_index(np.array([1.5]), 32)


def test_factor_convention_and_zero_residual_at_the_truth(scene):
    line, truth, frames, pixels = scene_tracks(scene)
    chunks = chunk_values(frames, spin)
    for t in range(len(truth)):
        d, r, phi0 = truth[t]
        # The factor's phases are the closest phases of the noise-free pixels: same phase convention.
        phases = closest_phases(scene.K, line, d, r, pixels[t])
        np.testing.assert_allclose(wrap(phases - spin(frames[t]) - phi0), 0.0, atol=1e-9)
        factor = factor_for(scene.K, t, frames[t], pixels[t])
        ids = np.unique(spin_chunk_index(frames[t], CHUNK, FIRST)[0])
        assert list(factor.keys()) == [L(0), X(t)] + [S(int(c)) for c in ids]
        values = values_with([(L(0), line), (X(t), truth[t])] + [(S(int(c)), chunks[int(c)]) for c in ids])
        e = factor.unwhitenedError(values)
        assert e.shape == (2 * len(pixels[t]),)
        np.testing.assert_allclose(e, 0.0, atol=1e-8)
        # Interleaved ordering: rows 2i, 2i+1 are pixel i's (du, dv).
        shifted = values_with([(L(0), line), (X(t), truth[t])]
                              + [(S(int(c)), chunks[int(c)] + (c == ids[0]) * 0.01) for c in ids])
        e = factor.unwhitenedError(shifted).reshape(-1, 2)
        pure, _, _, H_theta = rigid_spin_residuals(scene.K, line, d, r, phi0, spin(frames[t]) + 0.01, pixels[t])
        first = spin_chunk_index(frames[t], CHUNK, FIRST)[0] == ids[0]
        np.testing.assert_allclose(e[first], pure.reshape(-1, 2)[first], atol=1e-12)
        np.testing.assert_allclose(e[first], 0.01 * H_theta.reshape(-1, 2)[first], atol=2e-3)  # O(0.01^2)
        assert np.all(np.abs(e[~first]) < 1e-8)


def test_pure_function_blocks(scene):
    line, truth, frames, pixels = scene_tracks(scene)
    d, r, phi0 = truth[0]
    e, H_line, H_track, H_theta = rigid_spin_residuals(scene.K, line, d, r, phi0, spin(frames[0]), pixels[0])
    assert H_line.shape == H_track.shape == (2 * len(pixels[0]), 3)
    np.testing.assert_array_equal(H_theta, H_track[:, 2])
    e2, *rest = rigid_spin_residuals(scene.K, line, d, r, phi0, spin(frames[0]), pixels[0], jacobians=False)
    np.testing.assert_array_equal(e, e2)
    assert rest == [None, None, None]


@pytest.mark.parametrize("trial", range(4))
def test_jacobians_match_numerical(scene, trial):
    rng = np.random.default_rng(700 + trial)
    line, truth, frames, pixels = scene_tracks(scene)
    t = trial % 3
    noisy = pixels[t] + rng.normal(scale=0.8, size=pixels[t].shape)
    keys = {c: S(c) for c in range(5)} if trial % 2 else S  # a mapping or a callable
    factor = factor_for(scene.K, t, frames[t], noisy, sigma=1.3, chunk_keys=keys)
    line_p = line.retract(rng.normal(scale=0.02, size=3))
    track_p = truth[t] + rng.normal(scale=[0.01, 0.005, 0.1])
    ids = np.unique(spin_chunk_index(frames[t], CHUNK, FIRST)[0])
    chunks = chunk_values(frames, lambda f: spin(f) + rng.normal(scale=0.1, size=len(f)))
    assert_jacobians_match(factor, [(L(0), line_p), (X(t), track_p)] + [(S(int(c)), chunks[int(c)]) for c in ids])


def test_chunk_segments_split_a_track_exactly(scene):
    line, truth, frames, pixels = scene_tracks(scene)
    f, p = frames[0], pixels[0] + np.random.default_rng(1).normal(size=pixels[0].shape)  # frames 100..169: chunks 0..2
    segments = chunk_segments(f, CHUNK, 2, FIRST)
    assert [len(s) for s in segments] == [64, 6]
    np.testing.assert_array_equal(np.concatenate(segments), np.arange(len(f)))
    chunks = chunk_values(frames, spin)
    values = values_with([(L(0), line), (X(0), truth[0])] + [(S(c), chunks[c]) for c in range(3)])
    whole = factor_for(scene.K, 0, f, p).error(values)
    parts = [factor_for(scene.K, 0, f[s], p[s]) for s in segments]
    assert [len(part.keys()) for part in parts] == [4, 3]
    assert sum(part.error(values) for part in parts) == pytest.approx(whole, rel=1e-12)
    assert chunk_segments(np.zeros(0, dtype=int), CHUNK) == []


def test_checks_and_robust_noise(scene):
    with pytest.raises(ValueError, match="dimension 5 but the track has 4 pixels"):
        make_rigid_circle_factor(gtsam.noiseModel.Isotropic.Sigma(5, 1.0), L(0), X(0), S, np.zeros((4, 2)),
                                 np.arange(4), scene.K, CHUNK)
    with pytest.raises(ValueError, match="3 frames for 4 pixels"):
        make_rigid_circle_factor(gtsam.noiseModel.Isotropic.Sigma(8, 1.0), L(0), X(0), S, np.zeros((4, 2)),
                                 np.arange(3), scene.K, CHUNK)
    line, truth, frames, pixels = scene_tracks(scene)
    n = len(pixels[0])
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                            gtsam.noiseModel.Isotropic.Sigma(2 * n, 1.0))
    factor = make_rigid_circle_factor(robust, L(0), X(0), S, pixels[0] + 50.0, frames[0], scene.K, CHUNK, FIRST)
    chunks = chunk_values(frames, spin)
    values = values_with([(L(0), line), (X(0), truth[0]), (S(0), chunks[0]), (S(1), chunks[1]), (S(2), chunks[2])])
    whole = 0.5 * 2 * n * 50.0**2  # the Gaussian error of the whole track
    assert 0.0 < factor.error(values) < 0.1 * whole  # Huber reweights the track as one block


def test_lm_recovers_spin_and_tracks(scene):
    rng = np.random.default_rng(2024)
    line, truth, frames, pixels = scene_tracks(scene)
    noisy = [p + rng.normal(size=p.shape) for p in pixels]
    # Initial values: phases of the noisy pixels on the true circles, made consistent by initial_spin.
    phases = [closest_phases(scene.K, line, truth[t][0], truth[t][1], noisy[t]) for t in range(3)]
    init = initial_spin(list(zip(frames, phases, strict=True)), CHUNK, FIRST)
    assert init.components == [[0, 1, 2]]
    assert sorted(init.theta) == [0, 1, 2, 3, 4]
    unseen = FIRST + np.flatnonzero(~np.concatenate([init.observed[c] for c in range(5)]))
    np.testing.assert_array_equal(unseen, np.arange(171, 200, 2))

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorRot3(L(0), line, gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    for t in range(3):
        graph.add(factor_for(scene.K, t, frames[t], noisy[t]))
    for factor in spin_priors(init, S, X):
        graph.add(factor)
    assert graph.size() == 1 + 3 + 1 + 2  # line, tracks, one gauge, unobserved entries of chunks 2 and 3
    values = gtsam.Values()
    values.insert(L(0), line)
    for t in range(3):
        values.insert(X(t), np.array([truth[t][0] * 1.03, truth[t][1] * 0.97, init.phi0[t]]))
    for c, theta in init.theta.items():
        values.insert(S(c), theta)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    n_residuals = sum(2 * len(p) for p in pixels)
    assert 2.0 * graph.error(result) < 1.3 * n_residuals  # chi^2 ~ dof

    marginals = gtsam.Marginals(graph, result)
    gauge = truth[0][2]  # the estimate's gauge is phi0_0 = 0: theta_est = theta_true + phi0_true_0
    for t in range(3):
        est = result.atVector(X(t))
        err = est - truth[t]
        err[2] = wrap(err[2] + gauge)
        sigma = np.sqrt(np.diag(marginals.marginalCovariance(X(t))))
        if t == 0:
            assert abs(err[2]) < 1e-5 and sigma[2] < 1e-5
            err, sigma = err[:2], sigma[:2]
        assert np.all(np.abs(err) < 4.5 * sigma), (t, err / sigma)
    z = []
    for c in range(5):
        f = FIRST + c * CHUNK + np.arange(CHUNK)
        seen = init.observed[c]
        err = wrap(result.atVector(S(c)) - spin(f) - gauge)[seen]
        sigma = np.sqrt(np.diag(marginals.marginalCovariance(S(c))))
        z.append(err / sigma[seen])
        # unobserved entries stay where they started, with the free prior's sigma
        np.testing.assert_allclose(result.atVector(S(c))[~seen], init.theta[c][~seen], atol=1e-9)
        np.testing.assert_allclose(sigma[~seen], 1.0, rtol=1e-6)
    z = np.concatenate(z)
    assert np.max(np.abs(z)) < 4.5
    assert 0.3 < np.mean(z**2) < 2.0


def test_initial_spin_handles_2pi_wraps():
    rng = np.random.default_rng(5)
    frames = [np.arange(0, 60), np.arange(40, 100), np.repeat(np.arange(90, 130), 2)]  # track 2: 2 pixels a frame
    theta_true = 0.1 * np.arange(130) + 0.3 * np.sin(0.05 * np.arange(130))  # > 2 turns
    phi0_true = np.array([0.5, 3.0, -2.9])  # phase differences wrap too
    for noise in (0.0, 0.01):
        data = [(f, wrap(theta_true[f] + phi0_true[j] + rng.normal(scale=noise, size=len(f))))
                for j, f in enumerate(frames)]
        init = initial_spin(data, chunk_size=16)
        assert init.components == [[0, 1, 2]]
        assert set(init.theta) == set(range(9))  # frames 0..129 -> chunks 0..8
        theta = np.concatenate([init.theta[c] for c in range(9)])[:130]
        assert np.all(np.concatenate([init.observed[c] for c in range(9)])[:130])
        tol = 1e-12 if noise == 0.0 else 0.05
        np.testing.assert_allclose(wrap(theta - theta_true - phi0_true[0]), 0.0, atol=tol)
        np.testing.assert_allclose(wrap(init.phi0 - phi0_true + phi0_true[0]), 0.0, atol=tol)
        assert init.phi0[0] == 0.0
        assert np.all(np.abs(np.diff(theta)) < 0.5)  # unwrapped along the frames


def test_initial_spin_disconnected_components():
    frames = [np.arange(0, 41), np.arange(30, 71), np.arange(100, 151), np.arange(140, 161)]
    theta_true = 0.05 * np.arange(161)
    phi0_true = np.array([1.0, -2.0, 0.4, 2.5])
    data = [(f + 1000, wrap(theta_true[f] + phi0_true[j])) for j, f in enumerate(frames)]
    init = initial_spin(data, chunk_size=32, first_frame=1000)
    assert init.components == [[0, 1], [2, 3]]
    assert init.phi0[0] == 0.0 and init.phi0[2] == 0.0
    theta = np.concatenate([init.theta[c] for c in sorted(init.theta)])
    observed = np.concatenate([init.observed[c] for c in sorted(init.theta)])
    assert sorted(init.theta) == [0, 1, 2, 3, 4, 5]
    np.testing.assert_array_equal(np.flatnonzero(~observed[:161]), np.arange(71, 100))
    assert not observed[161:].any()
    for comp, ref in (([0, 1], 0), ([2, 3], 2)):
        f = np.concatenate([frames[j] for j in comp])
        np.testing.assert_allclose(wrap(theta[f] - theta_true[f] - phi0_true[ref]), 0.0, atol=1e-12)
        np.testing.assert_allclose(wrap(init.phi0[comp] - phi0_true[comp] + phi0_true[ref]), 0.0, atol=1e-12)
    # Unobserved entries are interpolated (finite) and get a free prior each; one gauge prior per component.
    assert np.all(np.isfinite(theta))
    priors = spin_priors(init, S, X)
    assert len(priors) == 2 + 3  # two gauges; chunks 2, 3 (unobserved 71..99) and 5 (161..191)
    dims = sorted(p.dim() for p in priors)
    assert dims == [1, 1, 4, 25, 31]


def test_entries_prior_jacobian():
    prior = make_entries_prior(S(0), [1, 3], [0.5, -0.2], 0.1)
    x = np.array([0.0, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(prior.unwhitenedError(values_with([(S(0), x)])), [0.5, 3.2])
    assert_jacobians_match(prior, [(S(0), x)])
