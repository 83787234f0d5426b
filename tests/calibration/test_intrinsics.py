"""Intrinsics refined with the pose (CalibrationOptions.refine_intrinsics) against the camera the simulator used,
which the estimator never sees: it is given a camera whose focal length and principal point are off."""

import numpy as np
import pytest
from shift_refits import refitted_shift_covariance

from gtsam_rotid import Dataset, InputError, simulate
from gtsam_rotid.calibration import CalibrationOptions
from gtsam_rotid.calibration.result import CalibrationResult
from gtsam_rotid.camerafiles import load_camera
from gtsam_rotid.errors import RotIdError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.export import export_result
from gtsam_rotid.report import make_report
from gtsam_rotid.words import summary

NAMES = ("fx", "fy", "cx", "cy")
CHI2_999_6 = 22.46  # the 99.9 % points of the chi-square for 6, 4 and 3 dof
CHI2_999_4 = 18.47
CHI2_999_3 = 16.27


@pytest.fixture(scope="module")
def scene():
    return simulate.reference_scene(seed=0, duration=20.0)


def with_camera(dataset, focal=1.0, cx=0.0):
    return Dataset(dataset.arm, dataset.camera.with_intrinsics_changed(focal, cx), list(dataset))


def chi2_of_error(result, truth):
    e = result.error_to(truth.arm_T_camera)
    return float(e @ np.linalg.solve(result.covariance, e))


def intrinsics_chi2(result, camera) -> float:
    miss = np.array([result.intrinsics[n] - camera.intrinsics[n] for n in result.refined_intrinsics])
    return float(miss @ np.linalg.solve(result.intrinsics_covariance, miss))


def test_a_wrong_camera_refined_with_the_pose_holds_its_covariance(scene, tmp_path):
    dataset, truth = scene
    given = with_camera(dataset, 1.03, 10.0)
    try:  # what is at stake: the camera as given gives no confident number (here: another pose fits as well)
        exact = calibrate(given)
        assert not exact.covariance_usable and chi2_of_error(exact, truth) > CHI2_999_6
    except RotIdError:
        pass
    result = calibrate(given, options=CalibrationOptions(refine_intrinsics=True))
    assert result.covariance_usable, (result.untrusted, result.ambiguous)
    assert chi2_of_error(result, truth) < CHI2_999_6
    assert result.refined_intrinsics == NAMES
    assert intrinsics_chi2(result, dataset.camera) < CHI2_999_4
    assert all(1.0 < s < 20.0 for s in result.intrinsics_sigma.values())  # the data's, well inside the prior
    assert result.given_intrinsics == {n: given.camera.intrinsics[n] for n in NAMES}
    assert all(m.used for m in result.measurements)  # none left out for the camera's error
    words = summary(result)
    assert "intrinsics refined with the pose" in words
    assert f"fx: {result.intrinsics['fx']:.2f} px +- {result.intrinsics_sigma['fx']:.2f} px" in words
    assert "intrinsics" not in result.untrusted

    result.save(tmp_path / "r.json")
    loaded = CalibrationResult.load(tmp_path / "r.json")
    assert loaded.intrinsics == result.intrinsics and loaded.refined_intrinsics == NAMES
    np.testing.assert_array_equal(loaded.intrinsics_covariance, result.intrinsics_covariance)
    assert make_report(loaded).to_dict()["intrinsics"]["cx"] == pytest.approx(result.intrinsics["cx"])
    (tmp_path / "camera.yaml").write_text(export_result(loaded, "camera"))
    camera = load_camera(tmp_path / "camera.yaml")
    np.testing.assert_allclose(camera.K, result.camera.K, rtol=1e-10)
    assert (camera.width, camera.height) == (dataset.camera.width, dataset.camera.height)


def test_the_true_camera_refined_stays_within_its_covariance_of_itself(scene):
    dataset, truth = scene
    result = calibrate(dataset, options=CalibrationOptions(refine_intrinsics=("fx", "cx")))
    assert result.refined_intrinsics == ("fx", "cx")
    assert intrinsics_chi2(result, dataset.camera) < 13.82  # 99.9 %, 2 dof
    assert result.camera.K[1, 1] == dataset.camera.K[1, 1] and result.camera.K[1, 2] == dataset.camera.K[1, 2]
    assert chi2_of_error(result, truth) < CHI2_999_6
    exact = calibrate(dataset)  # refining costs precision (the focal length and the depth trade off)
    assert np.max(result.sigma_mm_arm) > np.max(exact.sigma_mm_arm)


def test_intrinsics_options_name_what_is_wrong(scene):
    dataset, _ = scene
    with pytest.raises(InputError, match="refined no intrinsics"):
        export_result(calibrate(dataset), "camera")
    with pytest.raises(InputError, match="joint method only"):
        calibrate(dataset, method="weighted", options=CalibrationOptions(refine_intrinsics=True))
    with pytest.raises(InputError, match="refine_intrinsics must be True or names among"):
        CalibrationOptions(refine_intrinsics=("fx", "k1"))
    with pytest.raises(InputError, match="needs spin_model='rigid'"):
        CalibrationOptions(refine_intrinsics=True, spin_model="free")
    with pytest.raises(InputError, match="intrinsics_sigma must be"):
        CalibrationOptions(refine_intrinsics=True, intrinsics_sigma=(0.05, -1.0))
    with pytest.raises(InputError, match=r"a fraction of the focal length \(0.05 for 5 %\)"):
        CalibrationOptions(refine_intrinsics=True, intrinsics_sigma=(5.0, 20.0))
    assert CalibrationOptions(refine_intrinsics="fx, cy").refine_intrinsics == ("fx", "cy")


def test_a_wrong_camera_that_the_tracks_shapes_refute_is_flagged_and_the_true_one_is_not():
    """Focal length 2 % short: the axes still agree with one pose (17 mm off at chi-square 470 without this check),
    but the tracks' shapes ask for the focal length back; with the true camera they do not."""
    dataset, truth = simulate.reference_scene(seed=2, duration=20.0)
    exact = calibrate(dataset)
    shapes = exact.intrinsics_shapes
    assert exact.covariance_usable and shapes is not None and not shapes["flagged"]
    assert shapes["chi2"] < CHI2_999_3 and shapes["dof"] == 3
    assert 1.0 < shapes["mm_per_focal_percent"] < 50.0  # the pose moves with the focal length (depth)
    assert "intrinsics: the camera file's taken as exact" in summary(exact)
    wrong = calibrate(with_camera(dataset, 0.98))
    assert chi2_of_error(wrong, truth) > CHI2_999_6  # what is at stake
    assert not wrong.covariance_usable and "intrinsics_shapes" in wrong.untrusted
    change = wrong.intrinsics_shapes["change"]
    assert change["fx"] > 0.01 * 0.98 * dataset.camera.K[0, 0]  # back towards the true focal length
    words = summary(wrong)
    assert "the tracks' shapes ask for other intrinsics" in words and "--refine-intrinsics" in words
    assert CalibrationResult.from_dict(wrong.to_dict()).untrusted == wrong.untrusted


def test_track_correlation_with_the_intrinsics_free_stays_a_bounded_correction(monkeypatch):
    """The cluster-robust covariance with the intrinsics free: a line's excess meat spans the intrinsics too.

    On white simulated noise the per-track scores agree with the noise model but for the odd line whose scores
    pass their test by chance (12 poses of 12 s spins: one of them, a 64 % excess along one direction). Confined
    to the line's block, that meat made the pose's 1 sigma ten times the plain covariance's (30 mm, the error 3.9
    mm) and fx's larger than its prior's, because the factor ties the line to the intrinsics; over both, the
    correction stays a modest widening, as it is with the camera fixed. (The axes' scatter is left out of both: at
    P 0.014 it scales them by 1.87 and gives them a floor, which the larger, direction by direction, of the two mixes
    differently into each.)"""
    from test_stage1 import no_track_correlation

    from gtsam_rotid.calibration import joint as joint_stage

    dataset, truth = simulate.reference_scene(seed=0, n_measurements=12, duration=12.0)
    options = CalibrationOptions(refine_intrinsics=True, axis_consistency_p=0.0)
    robust = calibrate(dataset, options=options)
    monkeypatch.setattr(joint_stage, "_track_correlation", no_track_correlation)
    plain = calibrate(dataset, options=options)
    L = np.linalg.cholesky(plain.covariance)
    ratio = np.linalg.eigvalsh(np.linalg.solve(L, np.linalg.solve(L, robust.covariance).T))
    assert np.all(ratio > 0.99) and np.all(ratio < 1.6), ratio
    assert all(robust.intrinsics_sigma[n] < 0.5 * 0.05 * dataset.camera.intrinsics[n] for n in ("fx", "fy"))
    assert robust.covariance_usable and chi2_of_error(robust, truth) < CHI2_999_6


def test_offsets_and_intrinsics_refined_at_six_planned_poses_hold_their_covariance():
    """Six Jaco2 poses planned for the offsets and the intrinsics (``plan --refine-intrinsics --joint-offsets``,
    kept in tests/data), readings 0.5 deg off on every joint before the wrist, the camera file 3 % / 10 px off, both
    refined. The offset of the second joint turns the arm almost as the pose does (held by its prior alone), next
    to the skew held at 1e-6 px: GTSAM's Cholesky gave up on the marginals and the Schur complement took that
    offset's directions for numerically null, so the result was called usable 3.4 mm off at a chi-square of 74,
    with no covariance for the intrinsics."""
    import sys
    from pathlib import Path

    from gtsam_rotid.arm import Arm
    from gtsam_rotid.recordings import read_joint_file
    from gtsam_rotid.simulate import SceneConfig, simulate

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from ambient import relaxed
    from refinement import offset_readings

    arm = Arm.from_robot("kinova")
    poses = read_joint_file(Path(__file__).resolve().parents[1] / "data" / "jaco2_planned_offsets_intrinsics.csv",
                            arm).positions
    config = relaxed(SceneConfig(robot="kinova", duration=12.0, noise_var=1.5)).with_(
        joint_angles=tuple(tuple(q) for q in poses), n_measurements=len(poses))
    dataset, truth = simulate(config, seed=1000, arm=arm)
    readings, _, _ = offset_readings(dataset, dataset.camera.with_intrinsics_changed(1.03, 10.0), 0.5, seed=0)
    result = calibrate(readings, options=CalibrationOptions(refine_intrinsics=True, joint_offsets=True))
    assert result.intrinsics_covariance is not None and set(result.intrinsics_sigma) == set(NAMES)
    assert intrinsics_chi2(result, dataset.camera) < CHI2_999_4
    assert not result.covariance_usable or chi2_of_error(result, truth) < CHI2_999_6


def test_an_image_shift_per_pose_is_counted_for_the_pose_and_the_intrinsics_together():
    """With the intrinsics refined, an image shift per pose moves the pose and the intrinsics together (a shift of
    every pose alike is a move of the principal point): ``image_shift_covariance`` and
    ``image_shift_nuisance["intrinsics"]`` are computed through the joint graph. The ground truth is the refined
    calibration fitted again with each pose's pixels moved by 0.05 px along x and along y in turn (the sum of the
    outer products of those moves per px): within 15 % per 1σ, to first order. A measured camera move adds its
    level squared times them."""
    dataset, _ = simulate.reference_scene(seed=0, duration=12.0)
    options = CalibrationOptions(refine_intrinsics=True)
    base = calibrate(dataset, options=options)
    names = list(base.refined_intrinsics)
    assert names == list(NAMES)
    moved = refitted_shift_covariance(dataset, base, lambda r: [r.intrinsics[n] for n in names], options=options)
    blocks = base.image_shift_nuisance
    assert sorted(blocks) == ["intrinsics"] and blocks["intrinsics"].shape == (4, 4)
    predicted = np.concatenate([np.diag(base.image_shift_covariance), np.diag(blocks["intrinsics"])])
    np.testing.assert_allclose(np.sqrt(predicted), np.sqrt(np.diag(moved)), rtol=0.15)
    level = 0.07
    measured = calibrate(Dataset(dataset.arm, dataset.camera, list(dataset),
                                 metadata={"camera_motion": {"floor_px": 0.15, "level_px": level, "bound_px": 0.02}}),
                         options=options)
    np.testing.assert_allclose(measured.intrinsics_covariance,
                               base.intrinsics_covariance + level**2 * blocks["intrinsics"])
