"""Observability analysis and the covariance it hands to the report (gtsam_rotid.uncertainty)."""

import json

import gtsam
import numpy as np

from gtsam_rotid.uncertainty import UNDETERMINED_VARIANCE, Observability, analyse_observability, loewner_max
from gtsam_rotid.words import observability_words


def information_with_null(null: np.ndarray, seed: int = 0) -> np.ndarray:
    """A well-conditioned 6x6 information (rad, m) with ``null`` (unit) as its exact null direction."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(6, 6))
    scale = np.diag([3e5] * 3 + [1e5] * 3)  # ~0.1 deg and ~3 mm
    info = scale @ (A @ A.T + 6 * np.eye(6)) @ scale / 36
    P = np.eye(6) - np.outer(null, null)
    return P @ info @ P


def test_pure_translation_null_does_not_leak_into_the_rotation_block():
    t = np.array([0.6, -0.2, -0.7])
    null = np.concatenate([np.zeros(3), t / np.linalg.norm(t)])
    info = information_with_null(null)
    # rounding in the eigen-solver gives the null eigenvector a tiny rotation part; emulate a slightly worse one
    tilt = np.concatenate([[2e-7, -1e-7, 1.5e-7], np.zeros(3)])
    noisy = null + tilt
    noisy /= np.linalg.norm(noisy)
    info = info + 1e-9 * np.outer(noisy, noisy)  # numerically zero eigenvalue, eigenvector with rotation part
    obs = analyse_observability(info, gtsam.Pose3())
    assert len(obs.unobservable_directions) == 1
    d = obs.unobservable_directions[0]
    np.testing.assert_allclose(d[:3], 0.0)
    np.testing.assert_allclose(abs(d @ null), 1.0, atol=1e-9)
    cov = obs.covariance(info)
    # rotation block: the covariance of the determined directions given the undetermined one (here, pinv)
    reference = np.linalg.pinv(information_with_null(null))[:3, :3]
    np.testing.assert_allclose(cov[:3, :3], reference, rtol=1e-6)
    assert np.all(np.degrees(np.sqrt(np.diag(cov[:3, :3]))) < 1.0)
    # the undetermined direction carries the huge variance, and only it
    np.testing.assert_allclose(null @ cov @ null, UNDETERMINED_VARIANCE, rtol=1e-6)
    assert np.all(np.sqrt(np.diag(cov[3:, 3:])) > 1e3)  # every translation axis has a part along the ray


def test_observable_information_is_inverted_exactly():
    info = information_with_null(np.eye(6)[0]) + 1e8 * np.outer(np.eye(6)[0], np.eye(6)[0])
    obs = analyse_observability(info, gtsam.Pose3())
    assert obs.is_observable
    np.testing.assert_allclose(obs.covariance(info), np.linalg.inv(info), rtol=1e-9)


def test_a_coupled_null_direction_is_not_snapped():
    """A null direction with a real rotation part (a rotation about a point away from the camera) is kept whole:
    the rotation about it is undetermined too and must be reported so."""
    null = np.array([0.3, 0.0, 0.0, 0.0, 0.5, 0.2])
    null /= np.linalg.norm(null)
    info = information_with_null(null)
    obs = analyse_observability(info, gtsam.Pose3())
    assert len(obs.unobservable_directions) == 1
    np.testing.assert_allclose(abs(obs.unobservable_directions[0] @ null), 1.0, atol=1e-9)
    cov = obs.covariance(info)
    assert np.sqrt(cov[0, 0]) > 1e3  # rotation about x undetermined


def _random_covariance(rng, n=6, spread=3.0):
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * 10.0 ** rng.uniform(-spread, 0.0, n)) @ Q.T


def test_loewner_max_is_at_least_both_and_no_more_than_needed():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = _random_covariance(rng), _random_covariance(rng)
        m = loewner_max(a, b)
        np.testing.assert_allclose(m, m.T)
        for c in (a, b):  # m - a and m - b are positive semi-definite
            assert np.linalg.eigvalsh(m - c).min() > -1e-9 * np.abs(m).max()
        # in a's whitened frame m is max(I, M): along each eigen-direction of M exactly the larger of the two
        root = np.linalg.cholesky(a)
        inverse = np.linalg.inv(root)
        w, U = np.linalg.eigh(inverse @ b @ inverse.T)
        np.testing.assert_allclose(np.diag(U.T @ inverse @ m @ inverse.T @ U), np.maximum(w, 1.0), rtol=1e-8)
    a = _random_covariance(rng)
    np.testing.assert_allclose(loewner_max(a, 0.5 * a), a, rtol=1e-10)   # b below a: a
    np.testing.assert_allclose(loewner_max(a, 2.0 * a), 2.0 * a, rtol=1e-10)  # b above a: b


def test_observability_in_words_and_a_file_written_before_the_indices():
    """The words are the report layer's (gtsam_rotid.words); the data they need survive JSON, also in a file
    written when the words were stored (``words``, no ``unobservable_indices``)."""
    null = np.array([0.3, 0.0, 0.0, 0.0, 0.5, 0.2])
    null /= np.linalg.norm(null)
    pose = gtsam.Pose3(gtsam.Rot3.Rz(0.3), np.array([0.1, 0.0, 0.2]))
    obs = analyse_observability(information_with_null(null), pose)
    words = observability_words(obs)
    assert words[0].startswith("DEGENERATE") and words[1].startswith("turning the camera")
    assert "not determined at all" in words[1]
    assert obs.unobservable_indices == [0] and obs.unobservable_sigmas == [np.inf]
    old = {k: v for k, v in obs.to_dict().items() if k != "unobservable_indices"} | {"words": ["old words"]}
    for data in (obs.to_dict(), old):
        again = Observability.from_dict(json.loads(json.dumps(data)))
        assert again.unobservable_indices == [0] and observability_words(again) == words
    determined = analyse_observability(information_with_null(null) + 1e8 * np.outer(null, null), pose)
    assert observability_words(determined) == [
        f"all six degrees of freedom of arm_T_camera are determined (condition number "
        f"{determined.condition_number:.3g})"]


def test_joint_marginal_covariance_equals_gtsams_marginals():
    """A pose, a vector and a nuisance point tied by between/prior factors: the joint covariance of the first two
    equals gtsam.Marginals' joint marginal; an indeterminate block gives None, not an exception."""
    from gtsam.symbol_shorthand import L, O, X

    from gtsam_rotid.uncertainty import joint_marginal_covariance

    rng = np.random.default_rng(3)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    values.insert(X(0), pose)
    values.insert(O(0), np.array([0.1, -0.2]))
    values.insert(L(0), gtsam.Point3(1.0, 2.0, 3.0))
    graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 0.3))))
    graph.add(gtsam.PriorFactorVector(O(0), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    graph.add(gtsam.PriorFactorPoint3(L(0), gtsam.Point3(1.0, 2.0, 3.0), gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    graph.add(gtsam.BetweenFactorPoint3(L(0), L(0), gtsam.Point3(0, 0, 0), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    graph.add(gtsam.PoseTranslationPrior3D(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    keys = [X(0), O(0)]
    expected = gtsam.Marginals(graph, values).jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
    np.testing.assert_allclose(joint_marginal_covariance(graph, values, keys, 8), expected, rtol=1e-9, atol=1e-12)
    free = gtsam.NonlinearFactorGraph()
    free.add(gtsam.PriorFactorVector(O(0), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    free.add(gtsam.PoseTranslationPrior3D(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    free.add(gtsam.PriorFactorPoint3(L(0), gtsam.Point3(1.0, 2.0, 3.0), gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    assert joint_marginal_covariance(free, values, keys, 8) is None  # the pose's rotation has no information


def test_a_held_variable_does_not_make_a_weakly_determined_one_look_null():
    """The Schur complement onto the first variable: a nuisance held by a tight prior (information 1e12, as the skew
    of refined intrinsics) next to one determined only weakly (50, a joint offset held by its prior alone) and
    coupled to the first. The weak one must be marginalised, not dropped as numerically null (which takes it as
    known and understates the first variable's variance)."""
    from gtsam_rotid.uncertainty import _schur

    H = np.array([[10.0, 0.0, 20.0], [0.0, 1e12, 0.0], [20.0, 0.0, 50.0]])
    np.testing.assert_allclose(_schur(H, 1), [[10.0 - 20.0**2 / 50.0]], rtol=1e-9)
    # a direction of the others that is truly null is still dropped (it carries no information to marginalise)
    H0 = np.array([[10.0, 0.0, 0.0], [0.0, 1e12, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(_schur(H0, 1), [[10.0]], rtol=1e-12)
