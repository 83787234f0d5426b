"""calibration.stage1: outlier tracks named and left out, good tracks kept, the track-correlated (CR2) line
covariance and its jackknife."""

import json
from pathlib import Path

import gtsam
import numpy as np
import pytest
from offset_tracks import with_offsets

from gtsam_rotid import Dataset, Measurement, Track, estimate, simulate
from gtsam_rotid.calibration import initial, lm, stage1
from gtsam_rotid.calibration import joint as joint_stage
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.graph import Model, track_huber


@pytest.fixture(scope="module")
def outlier_track_scene():
    return simulate.reference_scene(seed=21, noise_var=1.5, duration=12.0, outlier_fraction=0.15)


@pytest.mark.parametrize("method", ["joint", "weighted"])
def test_outlier_tracks_are_named_and_do_not_bias(outlier_track_scene, method):
    dataset, truth = outlier_track_scene
    planted = {(k, j) for k, m in enumerate(truth.measurements) for j, t in enumerate(m.tracks) if t.is_outlier}
    assert len(planted) >= 10
    result = calibrate(dataset, method=method)
    rejected = {(m.index, j): why for m in result.measurements for j, why in m.rejected_tracks.items()}
    caught = planted & rejected.keys()
    assert len(caught) >= len(planted) // 2
    for m in result.measurements:  # every track is either used or rejected, and counted once
        assert m.n_tracks + len(m.rejected_tracks) == len(dataset[m.index].tracks)
    assert all("does not fit" in rejected[t] or "residual RMS" in rejected[t] for t in caught)
    # good tracks are rejected only for being short or still, or rarely (a 99.9 % test) for their fit
    wrongly = [why for t, why in rejected.items() if t not in planted and "points)" not in why and "barely" not in why]
    assert len(wrongly) <= 2
    error = result.error_to(truth.arm_T_camera)
    assert np.all(np.abs(error) < 4.0 * np.sqrt(np.diag(result.covariance)))


def test_good_tracks_whose_noise_levels_differ_are_kept():
    """A tracker measures small or faint dots less precisely than large, contrasty ones: white noise whose level
    differs from track to track (15 %, log-normal) is no sign of a wrong circle. Tested at one common noise level,
    stage 1 rejected 24 of these 143 tracks; allowing for the tracks' spread, 3 (the noisiest, 1.2-1.4x)."""
    dataset, truth = simulate.reference_scene(seed=0, noise_var=0.0, duration=20.0)
    rng = np.random.default_rng(1)

    def noisy_track(track):
        sigma = 0.3 * np.exp(0.15 * rng.normal())
        return Track(track.pixels + rng.normal(0.0, sigma, track.pixels.shape), track.frames)

    noisy = Dataset(dataset.arm, dataset.camera,
                    [Measurement(m.joint_angles, [noisy_track(t) for t in m.tracks]) for m in dataset])
    result = calibrate(noisy)
    n = sum(len(m.tracks) for m in noisy)
    for_fit = [why for m in result.measurements for why in m.rejected_tracks.values()
               if "does not fit" in why or "residual RMS" in why]
    assert len(for_fit) <= 0.03 * n, for_fit
    for m in result.measurements:  # every track is either used or rejected, and counted once
        assert m.n_tracks + len(m.rejected_tracks) == len(noisy[m.index].tracks)
    error = result.error_to(truth.arm_T_camera)
    assert float(error @ np.linalg.solve(result.covariance, error)) < 22.5


# ---------------------------------------------------------------------------------------------------
# pixel errors shared along a track (a tracker's bias): the cluster-robust covariance


def no_track_correlation(factor, values, sigma2=1.0, intrinsics=False) -> np.ndarray:
    """:func:`stage1._track_correlation` when the tracks' errors are taken as white."""
    return np.zeros((8, 8) if intrinsics else (3, 3))


def generalised_eigenvalues(wide, narrow) -> np.ndarray:
    L = np.linalg.cholesky(narrow)
    Li = np.linalg.inv(L)
    return np.linalg.eigvalsh(Li @ wide @ Li.T)


@pytest.mark.parametrize("method", ["joint", "weighted"])
def test_errors_shared_along_a_track_widen_the_covariance(method, monkeypatch):
    """A constant offset per track (0.2 px, as large as the white noise) is not white noise: the per-track scores
    see it and the covariance widens to cover the error. With white noise the correction barely moves it.

    60 features (~70 tracks per measurement: the scores of a dozen tracks estimate a 3x3 meat poorly), and no
    per-track chi-square rejection: it would drop the tracks whose offset shows in their residuals and keep
    those whose offset hides in the line (README, Known limits)."""
    import gtsam_rotid.estimate as estimate

    options = estimate.CalibrationOptions(outlier_track_z=1e9)
    dataset, truth = simulate.reference_scene(seed=3, noise_var=0.04, duration=10.0, n_features=60)
    biased = calibrate(with_offsets(dataset, 0.2, seed=7), method=method, options=options)
    white = calibrate(dataset, method=method, options=options)
    for module in (stage1, joint_stage):
        monkeypatch.setattr(module, "_track_correlation", no_track_correlation)
    white_model = calibrate(dataset, method=method, options=options)
    # white pixel noise: the scores agree with the white-noise information (the noise model is the floor)
    ratio = generalised_eigenvalues(white.covariance, white_model.covariance)
    assert np.all(ratio > 0.99) and np.all(ratio < 1.6), ratio
    # the same scene and white noise plus the offsets: a far wider covariance, which covers the error
    ratio = generalised_eigenvalues(biased.covariance, white.covariance)
    assert ratio.max() > 5.0, ratio
    e = biased.error_to(truth.arm_T_camera)
    assert e @ np.linalg.solve(biased.covariance, e) < 22.46  # inside the 99.9 % region


class _TracksOf:
    """A stand-in for a coaxial factor: given per-track informations (J, 3, 3) and scores (J, 3)."""

    def __init__(self, information, scores):
        self.information, self.scores = np.asarray(information, float), np.asarray(scores, float)

    def track_information(self, values, intrinsics=False):
        return self.information

    def track_scores(self, values, intrinsics=False):
        return self.scores


def test_a_track_that_holds_a_direction_alone_does_not_blow_up_the_cluster_robust_covariance():
    """CR2 divides a track's score by sqrt(1 - leverage); a track whose leverage reaches 1 (or passes it, when the
    other tracks' information is not positive semi-definite) must not turn rounding noise into an unbounded
    covariance: the correction is capped (calibration.tuning.MAX_TRACK_LEVERAGE), at most sqrt(10) on a score."""
    rng = np.random.default_rng(0)
    information = np.array([np.diag([1.0, 1.0, 1.0]) for _ in range(8)])
    information[0, 2, 2] = 12.0     # track 0 holds the third direction: leverage 12 / 10 > 1
    information[1, 2, 2] = -8.0     # (a per-track information that is not positive semi-definite)
    scores = rng.standard_normal((8, 3))
    D = stage1._track_correlation(_TracksOf(information, scores), None)
    H = information.sum(axis=0)
    whiten = np.diag(1.0 / np.sqrt(np.diag(H)))
    raw = whiten @ (scores.T @ scores) @ whiten                    # the meat without any leverage correction
    grown = np.linalg.eigvalsh(whiten @ D @ whiten).max()
    assert np.isfinite(grown) and grown <= 10.0 * np.linalg.eigvalsh(raw).max() + 1e-9, grown


def test_one_track_more_or_fewer_does_not_make_the_jackknifed_covariance_jump():
    """The jackknife's growth is continuous in its eigenvalue, and a track left out moves one group only: on three
    measurements of the blurred Jaco2 photo scene (tests/data; short corner arcs, 24-51 tracks), leaving out any
    one of eight kept tracks changes the jackknifed line's largest sigma by less than 1.4x (measured 0.79-1.21x;
    with the groups dealt round robin over the kept tracks and a threshold alone, 0.67-1.64x). Before, a rendered
    Jaco2 photo scene's verdict turned on one track that 1e-6 px of pixel noise kept or left out.

    The fit without the track starts from the full fit's line and circles and keeps its other tracks (one round):
    refitted from the start with its rounds of rejection, a measurement of short arcs can land in another minimum
    (measurement 2: the same tracks at residual cost 4.89 from the start against 3.01 after the rounds, its image
    axis 3 px apart) or keep another set of tracks (measurement 0: 23 or 24 tracks as float-level differences in
    the start circles go), which is not the jackknife's doing."""
    limit = 3.1
    m = np.linspace(0.0, 6.0, 6001)
    growth = stage1.jackknife_growth(m, limit)
    assert np.all(np.diff(growth) >= 0.0) and np.max(np.diff(growth)) < 0.01  # monotone, no jump
    assert np.all(growth[m <= 1.0 + 0.5 * (limit - 1.0)] == 0.0) and np.allclose(growth[m >= limit], m[m >= limit] - 1)
    root = Path(__file__).resolve().parents[1] / "data" / "jaco2_photo_blur_seed0"
    dataset = Dataset.load(root / "dataset")
    truth = gtsam.Pose3(np.array(json.loads((root / "truth.json").read_text())["arm_T_camera"]))
    options, measurements = estimate.CalibrationOptions(), list(dataset)
    _, setup, _ = initial._initial(dataset.arm, dataset.camera, measurements, options, list(range(len(measurements))))
    builders = stage1.stage1_builders(dataset.arm, dataset.camera, options)

    def largest_sigma(s):
        return float(np.sqrt(np.max(np.linalg.eigvalsh(s.rotation_cov * s.sigma2))))

    for k in (0, 2, 3):
        rng = np.random.default_rng(0)
        start = stage1._start_line(dataset.camera, setup.axes[k], setup.centre_axes[k], truth)
        prepared = setup.prepared[k]

        fit = stage1._stage1_measurement(builders, measurements[k], k, truth, prepared, options, start)
        full = stage1._jackknife(builders[0], measurements[k], k, truth, prepared, fit, options)
        for j in rng.choice(list(fit.keys.tracks), size=8, replace=False):
            skip = {**fit.outliers, int(j): "left out"}
            r = stage1._stage1_round(builders[0], measurements[k], k, truth, prepared, skip, fit.rotation,
                                     {i: c for i, c in fit.circles.items() if i != j}, options)
            without = stage1._stage1_result(builders[0], r.graph, r.keys, r.values,
                                            stage1._track_stats(r.graph, r.keys, r.values), skip, r.iterations,
                                            options)
            assert set(without.keys.tracks) == set(fit.keys.tracks) - {j}
            jackknifed = stage1._jackknife(builders[0], measurements[k], k, truth, prepared, without, options)
            ratio = largest_sigma(jackknifed) / largest_sigma(full)
            assert 1.0 / 1.4 < ratio < 1.4, (k, int(j), ratio)


def test_jackknife_holds_the_line_covariance_where_the_linearisation_does_not():
    """Stage 1's line covariance against the spread of the line over 30 noise draws of one measurement (its
    tracks re-noised, 1.5 px^2): the linearised covariance understates the line's weakest direction there (4.6x),
    the jackknifed one holds on every direction."""
    clean, truth = simulate.reference_scene(seed=11, noise_var=0.0, duration=12.0)
    k, options = 3, estimate.CalibrationOptions()
    _, setup, _ = initial._initial(clean.arm, clean.camera, list(clean), options, list(range(len(clean))))
    builders = [lm._builder(clean.arm, clean.camera, options, model=Model.PROJECTED, robust=track_huber),
                lm._builder(clean.arm, clean.camera, options, robust=track_huber)]
    start = stage1._start_line(clean.camera, setup.axes[k], setup.centre_axes[k], truth.arm_T_camera)
    rng = np.random.default_rng(1)
    fits = []
    for _ in range(30):
        noisy = Measurement(clean[k].joint_angles, [
            Track(np.asarray(t.pixels) + rng.normal(0.0, np.sqrt(1.5), np.shape(t.pixels)), frames=t.frames)
            for t in clean[k].tracks])
        prepared = builders[0].prepare(noisy, k)
        s = stage1._stage1_measurement(builders, noisy, k, truth.arm_T_camera, prepared, options, start)
        fits.append((s, stage1._jackknife(builders[0], noisy, k, truth.arm_T_camera, prepared, s, options)))
    offsets = np.array([gtsam.Rot3.Logmap(fits[0][0].rotation.between(s.rotation)) for s, _ in fits])
    offsets -= offsets.mean(axis=0)

    def whitened_variances(covariance):
        w, V = np.linalg.eigh(covariance)
        return (offsets @ (V / np.sqrt(w))).var(axis=0, ddof=1)

    linear = whitened_variances(np.mean([s.rotation_cov * s.sigma2 for s, _ in fits], axis=0))
    jackknifed = whitened_variances(np.mean([j.rotation_cov * j.sigma2 for _, j in fits], axis=0))
    assert linear.max() > 2.5, linear  # the case this is about: the linearisation fails here
    assert np.all(jackknifed < 2.0) and np.all(jackknifed > 0.3), jackknifed


def test_a_spin_seen_end_on_is_fitted_from_its_fk_axis_too_and_the_better_fit_kept():
    """Six 6 s spins of 7-11 tracks; measurement 1 given measurement 3's tracks (11, on their true circles at 1.2 px
    noise). Fitted from its FK axis turned onto the image axis through its ellipses' centres, 76 degrees from the FK
    axis itself, it settles in a poor minimum: 7 tracks kept at 2.75 px, an axis wide enough to agree with its wrong
    FK axis. Its noise standing out, stage 1 also fits it from the FK axis and keeps the better fit: all 11 tracks,
    near the others' noise."""
    dataset, _ = simulate.simulate(simulate.SceneConfig(duration=6.0, n_measurements=6), 9)
    ms = list(dataset)
    ms[1], ms[3] = dataset[1].replace(tracks=dataset[3].tracks), dataset[3].replace(tracks=dataset[1].tracks)
    options = estimate.CalibrationOptions()
    starts, setup, _ = initial._initial(dataset.arm, dataset.camera, ms, options, None, 3.0)
    one = stage1._stage1(dataset.arm, dataset.camera, ms, starts[0], setup, options, alternatives=False)
    both = stage1._stage1(dataset.arm, dataset.camera, ms, starts[0], setup, options)
    others = np.median([np.sqrt(s.sigma2) for k, s in enumerate(one) if k != 1])
    assert len(one[1].stats) < 11 and np.sqrt(one[1].sigma2) > 1.8 * others  # the poor minimum, from the centres
    assert len(both[1].stats) == 11 and np.sqrt(both[1].sigma2) < 1.2 * others
    assert stage1._better(both[1], one[1])
    # the others' fits do not stand out: fitted from their centres only, as before
    assert [(len(s.stats), s.sigma2) for k, s in enumerate(both) if k != 1] == \
        [(len(s.stats), s.sigma2) for k, s in enumerate(one) if k != 1]
